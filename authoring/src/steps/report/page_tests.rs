//! Tests of the page: captions, colour bars, certificates, escaping, links.

use restage_authoring::calibrate::decode::DecodeQuality;
use restage_authoring::calibrate::photometric::{LuxFigures, ProjectorPhotometry};
use restage_authoring::calibrate::selfcal::Conditioning;
use restage_authoring::compensate::Stats;

use restage_authoring::calibrate::report::{PANEL, panel_height};
use restage_authoring::compensate::report::heat;

use super::*;

fn scene(id: &str, name: &str, peak: f64) -> Scene {
    let dir = format!("comp/{id}");
    Scene {
        id: id.into(),
        name: name.into(),
        summary: Summary {
            version: 1,
            e_bound_lux: 150.0,
            m: "8".into(),
            margin: 0.05,
            meter_accuracy: 0.1,
            clip_fraction: 0.01,
            certificate_reduction: 2,
            stats: Stats {
                covered_points: 1000,
                limited_by_bound: 10,
                peak_lux: peak,
                peak_black_lux: 3.25,
                room_lux: 0.5,
                certificate_points: 250,
                e_bound_lux: 150.0,
                limit_lux: 142.5,
                scale: 0.61234,
                ..Stats::default()
            },
        },
        frames: (0..2).map(|k| format!("{dir}/proj{k}.png")).collect(),
        report: (id == "restored").then(|| format!("{dir}/report")),
        check_line: Some(format!("step 6 compensate {id} (1.0 s): TRUE peak 120.0 lx")),
        dir,
    }
}

/// Inputs like a demo with two projectors writes; every picture the page shows exists.
fn example() -> Inputs {
    let mut pictures = BTreeMap::new();
    let cam = (800, 600);
    let ph = panel_height(cam.0, cam.1);
    for (rel, size) in [
        ("before_restored_target.png", (4 + 4 * 324, 4 + 244)),
        ("capture_contact_sheet.png", (4 + 3 * 204, 4 + 3 * 154)),
        ("stage/report.png", (3 * PANEL, 2 * ph)),
        ("stage/response_proj0.png", (560, 420)),
        ("stage/response_proj1.png", (560, 420)),
        ("stage/footprint_proj0.png", (140, 105)),
        ("stage/footprint_proj1.png", (140, 105)),
        ("classify/preview.png", cam),
        ("classify/labels.png", cam),
        ("restore/before_after.png", (2 * cam.0 + BEFORE_AFTER_GAP, cam.1)),
        ("restore/restored.png", cam),
        ("relit.png", cam),
        ("comp/restored/report/irradiance.png", cam),
        ("comp/restored/report/weights_proj0.png", cam),
        ("comp/restored/report/weights_proj1.png", cam),
    ] {
        pictures.insert(rel.to_string(), size);
    }
    for id in ["original", "restored"] {
        for k in 0..2 {
            pictures.insert(format!("comp/{id}/proj{k}.png"), (140, 105));
        }
    }
    let response: [Vec<f32>; 3] =
        std::array::from_fn(|c| (0..256).map(|v| (v as f32 / 255.0).powf(2.0 + c as f32 * 0.1)).collect());
    let projector =
        Projector { width: 140, height: 105, black: [0.003; 3], response, footprint_scale: Some(7.3) };
    let decode = |k: u32| DecodeQuality {
        projector: k,
        pixels: 480_000,
        lit: 200_000,
        decoded: 190_000,
        phase_steps: 8,
        ..DecodeQuality::default()
    };
    let conditioning = |k: u32| Conditioning {
        projector: k,
        f_std_px: 1.5,
        cx_std_px: 0.7,
        cy_std_px: 2.1,
        cx_std_data_only_px: f64::NAN,
        homography_fraction: 0.2,
        rotation_std_deg: 0.01,
        translation_std: 0.2,
    };
    let photometry = |k: usize| ProjectorPhotometry {
        correspondences_disagreeing: 0,
        correspondences_refined: 1000,
        coverage_of_lit_pixels: 0.97,
        dot_spacing: 8,
        dots_off_object: 10,
        dots_predicted: 300,
        dots_snapped: 280,
        filled_pixels: 120,
        leakage: Some([[1.0, 0.01, 0.0], [0.02, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        lux: Some(LuxFigures {
            distance_mm: 1050.0,
            lux_at_1m: 450.0,
            moved_px: if k == 1 { 5.0 } else { 0.0 },
            reading: 410.2,
            reference_pixel: [400, 300],
            requested_pixel: Some(if k == 1 { [400, 305] } else { [400, 300] }),
        }),
        projector: k,
        refine_median_shift_px: 0.1,
        vignetting_coefficient: Some(0.2),
    };
    Inputs {
        object: Some("virtual stage vase (seed 1)".into()),
        capture_source: Some("virtual stage: vase, seed 1".into()),
        camera: Some(cam),
        pictures,
        sheet_columns: vec![vec!["white".into(), "black".into(), "dots every 8 px".into()]; 2],
        geometry: Some(GeometryReport {
            decode: vec![decode(0), decode(1)],
            adjustment_rms_px: 0.12,
            adjustment_iterations: 9,
            dense_rms_px: 0.2,
            points: 150_000,
            rejected_by_residual: 12,
            rejected_by_depth: 3,
            scale_mm: 612.5,
            conditioning: vec![conditioning(0), conditioning(1)],
            rig_epipolar_median_px: Vec::new(),
            warnings: vec!["projector 1: few phase steps".into()],
        }),
        photometric: Some(PhotometricSummary {
            projectors: vec![photometry(0), photometry(1)],
            stray_lux: [0.5, 0.5, 0.5],
            version: 1,
            warnings: vec![],
        }),
        projectors: vec![projector.clone(), projector],
        depth_mm: Some((812.0, 1004.0)),
        scenes: vec![scene("original", "As found", 141.0), scene("restored", "Restored", 142.4)],
        bundle: Some(Bundle {
            file: "demo.restage".into(),
            bytes: 12_345_678,
            description: "bundle.toml".into(),
            trust: "trust/".into(),
            keys: "keys/".into(),
            policy_class: Some("low".into()),
            policy: Some(ExposurePolicy::cie157(restage_shared::policy::Sensitivity::Low)),
            verify_line: Some("step 8 verify (2.0 s): bundle verified".into()),
        }),
        summary_txt: Some("step 3 classify\nstep 8 verify\n".into()),
        files: vec![
            Entry { name: "capture".into(), bytes: 922_000_000, dir: true },
            Entry { name: "summary.txt".into(), bytes: 2000, dir: false },
        ],
    }
}

/// Each `<figure>` of the page, from its opening to its closing tag.
fn figures(html: &str) -> Vec<&str> {
    html.split("<figure>").skip(1).map(|f| &f[..f.find("</figure>").expect("figure closed")]).collect()
}

#[test]
fn every_picture_is_shown_in_a_figure_with_a_caption_and_alt_text() {
    let inp = example();
    let html = render(&inp);
    let figs = figures(&html);
    for rel in inp.pictures.keys() {
        if rel == "classify/labels.png" || rel.starts_with("stage/response_proj") {
            // Linked, not shown: the labels are class numbers; the responses are drawn from
            // the model as plots.
            assert!(html.contains(&format!(r#"href="{rel}""#)), "{rel} not linked");
            continue;
        }
        let shown: Vec<&&str> =
            figs.iter().filter(|f| f.contains(&format!(r#"<image href="{rel}""#))).collect();
        assert!(!shown.is_empty(), "{rel} is not shown");
        for f in shown {
            let caption = &f[f.find("<figcaption>").unwrap_or_else(|| panic!("{rel}: no caption"))..];
            assert!(caption.len() > 80, "{rel}: caption too short: {caption}");
        }
    }
    // Every figure has a caption; every picture panel and plot has alt text.
    assert!(figs.iter().all(|f| f.contains("<figcaption>")));
    let panels = html.matches(r#"role="img""#).count();
    assert_eq!(panels, html.matches("<title id=").count());
    assert!(panels > 20, "{panels}");
    assert!(!html.contains(MISSING), "nothing is missing in the example");
    // Axes with units: camera pixels on the pictures of the object, projector pixels on frames.
    assert!(html.contains("camera x (px)") && html.contains("projector y (px)"));
    assert!(html.contains("input value (8-bit, 0–255)") && html.contains("relative output"));
}

#[test]
fn the_irradiance_bar_runs_from_0_to_e_bound_in_lux_with_the_allowed_level_marked() {
    let html = render(&example());
    let fig = figures(&html).into_iter().find(|f| f.contains("report/irradiance.png")).unwrap();
    let bar = &fig[fig.find(r#"<svg class="bar""#).unwrap()..];
    assert!(bar.contains("Illuminance (lux)"), "{bar}");
    for tick in [">0</text>", ">50</text>", ">100</text>", ">150</text>", ">allowed 142.5 lx</text>"] {
        assert!(bar.contains(tick), "{tick} missing: {bar}");
    }
    // The gradient is compensate::report::heat, stop for stop.
    for i in 0..=20 {
        let c = heat(i as f64 / 20.0);
        assert!(
            bar.contains(&format!(
                r#"offset="{:.4}" stop-color="rgb({},{},{})""#,
                i as f64 / 20.0,
                c[0],
                c[1],
                c[2]
            )),
            "stop {i}"
        );
    }
    assert!(bar.contains("rgb(20,24,32)") && bar.contains("no projector reaches"));
    // The footprint bar ends at its scale, the depth bar spans the depths in mm, the weights 0..1.
    assert!(html.contains(">7.3</text>") && html.contains("camera pixels&#39; worth of light"));
    assert!(
        html.contains(">812</text>")
            && html.contains(">1004</text>")
            && html.contains("Depth, distance from the camera (mm)")
    );
    assert!(html.contains("Weight w (share of the point&#39;s light)"));
}

#[test]
fn the_certificate_says_what_was_found_allowed_and_assumed() {
    let mut inp = example();
    let html = render(&inp);
    assert!(html.contains("Peak illuminance found: <strong>142.40 lx</strong>. Allowed: <strong>142.50 lx</strong> (E_bound 150.0 lx less 10.00 % for the lux meter's accuracy and the 5.00 % safety margin)"), "{html}");
    assert!(
        html.contains("What is guaranteed") && html.contains("Under which assumptions a certificate holds")
    );
    assert!(html.contains("about 14 hours of showing a day and 4213 hours a year"), "{html}");
    assert!(html.contains("250 certificate points") && html.contains("2 × 2 camera pixels"));
    assert!(html.contains("TRUE peak 120.0 lx"));
    assert!(!html.contains("ABOVE"));
    inp.scenes[0].summary.stats.peak_lux = 143.0;
    let html = render(&inp);
    assert!(html.contains("ABOVE the allowed level"));
    // What stays dark is named, where the figures count it.
    assert!(!html.contains("why the rest are not"), "figures without the count show no row");
    inp.scenes[0].summary.stats.unlit =
        restage_authoring::compensate::Unlit { asked: 1000, no_surface: 12, no_projector: 3, no_gain: 0 };
    let html = render(&inp);
    assert!(
        html.contains(
            "985 of 1000 px lit (98.50 %); unlit: 12 no surface reconstructed, 3 no projector reaches"
        ),
        "{html}"
    );
}

#[test]
fn names_and_paths_from_files_are_escaped() {
    let mut inp = example();
    let evil = "<script>alert(1)</script>";
    inp.object = Some(evil.into());
    inp.capture_source = Some(evil.into());
    inp.scenes.push(scene("<script>", evil, 100.0));
    let frame = "comp/<script>/proj0.png".to_string();
    inp.pictures.insert(frame.clone(), (140, 105));
    inp.geometry.as_mut().unwrap().warnings.push(evil.into());
    inp.summary_txt = Some(format!("</pre>{evil}"));
    inp.files.push(Entry { name: "<script>".into(), bytes: 1, dir: true });
    let html = render(&inp);
    assert!(!html.to_lowercase().contains("<script"), "unescaped markup");
    assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
    assert!(html.contains(r#"<image href="comp/%3Cscript%3E/proj0.png""#));
    assert!(html.contains(r##"href="#scene-%3Cscript%3E""##) && html.contains(r#"id="scene-%3Cscript%3E""#));
}

#[test]
fn a_lux_reference_that_was_moved_says_so() {
    let html = render(&example());
    assert!(
        html.contains(
            "(requested (400, 305) decoded no surface; used the nearest decoded pixel, 5.0 px away)"
        ),
        "{html}"
    );
    assert_eq!(html.matches("requested (").count(), 1, "only projector 1's reference moved");
}

#[test]
fn a_folder_with_nothing_in_it_says_what_is_missing() {
    let html = render(&Inputs::default());
    assert!(html.contains(&format!("<code>before_restored_target.png</code> {MISSING}")));
    assert!(html.contains(&format!("<code>stage/report.png</code> {MISSING}")));
    assert!(html.contains("<h2>What to do next</h2>") && html.ends_with("</html>\n"));
}

#[test]
fn links_are_relative_and_the_next_steps_are_there() {
    let html = render(&example());
    for h in html.split("href=\"").skip(1).map(|s| &s[..s.find('"').unwrap()]) {
        assert!(!h.starts_with('/') && !h.contains("://"), "not relative: {h}");
    }
    assert!(html.contains("restage-author gui &lt;this folder&gt;"));
    assert!(html.contains(
        "restage-author verify &lt;this folder&gt;/demo.restage --trust &lt;this folder&gt;/trust"
    ));
    assert!(html.contains(r#"<a href="comp/restored/report/index.html">"#));
    assert!(html.contains("922.0 MB"));
}
