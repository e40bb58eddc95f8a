//! End to end through the `restage-author` binary: the virtual stage's capture sets are
//! reproducible whatever the thread count, `render` agrees with the captures, and bad input
//! ends with a clear error.

use std::path::Path;

use image::{Rgb, RgbImage};
use restage_authoring::capture_set::{CaptureManifest, Pattern};
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_model::StageModel;
use restage_tests::{files_under, run_author};

/// A tiny capture: 64x48 camera, three 48x36 projectors, few dots and ramps.
const TINY: &[&str] = &[
    "--camera",
    "64x48",
    "--projector",
    "48x36",
    "--dot-spacing",
    "2",
    "--ramp-levels",
    "3",
    "--phase-steps",
    "4",
];

fn simulate(out: &Path, extra: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let mut args = vec!["simulate", "--out", out.to_str().unwrap(), "--seed", "11"];
    // TINY's flag-value pairs, unless `extra` sets the same flag.
    for pair in TINY.chunks(2) {
        if !extra.contains(&pair[0]) {
            args.extend_from_slice(pair);
        }
    }
    args.extend_from_slice(extra);
    run_author(&args, env)
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn same_seed_gives_byte_identical_captures_whatever_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let oa = simulate(&a, &["--scene", "jar"], &[("RAYON_NUM_THREADS", "1")]);
    assert!(oa.status.success(), "{}", stderr(&oa));
    let ob = simulate(&b, &["--scene", "jar"], &[("RAYON_NUM_THREADS", "2")]);
    assert!(ob.status.success(), "{}", stderr(&ob));
    let files = files_under(&a);
    assert_eq!(files, files_under(&b));
    let manifest = CaptureManifest::load(&a).unwrap();
    let images = 1 + manifest.projectors.iter().map(|p| p.shots.len()).sum::<usize>();
    assert!(files.len() > images, "every image plus manifest and ground truth");
    for f in &files {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{} differs",
            f.display()
        );
    }
    // A different seed changes the captures.
    let c = dir.path().join("c");
    let mut args = vec!["simulate", "--out", c.to_str().unwrap(), "--seed", "12", "--scene", "jar"];
    args.extend_from_slice(TINY);
    assert!(run_author(&args, &[]).status.success());
    assert_ne!(std::fs::read(a.join("photo.png")).unwrap(), std::fs::read(c.join("photo.png")).unwrap());
}

#[test]
fn capture_set_is_complete_and_render_matches_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("cap");
    let o = simulate(&cap, &[], &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = CaptureManifest::load(&cap).unwrap();
    assert_eq!(m.projectors.len(), 3);
    for p in &m.projectors {
        for pat in [Pattern::White, Pattern::Black, Pattern::Dots { spacing: 2, dx: 1, dy: 1 }] {
            let f = p.find(&pat).unwrap_or_else(|| panic!("{pat:?} captured"));
            LinearImage::load_sized(&cap.join(f), 64, 48).unwrap();
        }
    }
    let gt = cap.join("ground-truth");
    let truth = StageModel::load(&gt.join("stage")).unwrap();
    for f in ["labels_pristine.png", "labels_deteriorated.png", "palette.json", "truth.json"] {
        assert!(gt.join(f).is_file(), "{f}");
    }

    // Projector 1 white, the others black: render agrees with the true stage model
    // (camera value = gain * irradiance above black + ambient) and with the noisy capture.
    let frames = dir.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for k in 0..3 {
        let v = if k == 1 { 255 } else { 0 };
        RgbImage::from_pixel(48, 36, Rgb([v; 3])).save(frames.join(format!("proj{k}.png"))).unwrap();
    }
    let out = dir.path().join("seen.png");
    let args = ["render", "--capture", cap.to_str().unwrap(), "--frames", frames.to_str().unwrap()];
    let o = run_author(&[&args[..], &["--out", out.to_str().unwrap()]].concat(), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let seen = LinearImage::load_sized(&out, 64, 48).unwrap();
    let white = LinearImage::load(&cap.join(m.projectors[1].find(&Pattern::White).unwrap())).unwrap();
    let p = &truth.projectors[1];
    let (mut n, mut err_capture) = (0, 0.0);
    for i in 0..seen.data.len() {
        let c = truth.correspondences[1][i];
        if c[0].is_nan() {
            continue;
        }
        // Irradiance above black at the centre of the pixel's footprint (no blur, no area).
        let [x, y, z] = truth.points[i];
        let pp = |r: usize| {
            p.rotation[r][0] * x as f64 + p.rotation[r][1] * y as f64 + p.rotation[r][2] * z as f64
        };
        let xp = [pp(0) + p.translation[0], pp(1) + p.translation[1], pp(2) + p.translation[2]];
        let d = (xp[0] * xp[0] + xp[1] * xp[1] + xp[2] * xp[2]).sqrt();
        let to = [xp[0] / d, xp[1] / d, xp[2] / d];
        // Normal in the projector frame.
        let nm = truth.normals[i];
        let nr = |r: usize| {
            p.rotation[r][0] * nm[0] as f64
                + p.rotation[r][1] * nm[1] as f64
                + p.rotation[r][2] * nm[2] as f64
        };
        let cos = -(nr(0) * to[0] + nr(1) * to[1] + nr(2) * to[2]);
        let (u, v) = (c[0].round() as usize, c[1].round() as usize);
        let vig = p.vignetting[v.min(35) * 48 + u.min(47)] as f64;
        let e = p.lux_at_1m * vig * cos / (d / 1000.0).powi(2);
        let predicted = truth.gain[i][1] as f64 * e + truth.ambient[i][1] as f64;
        let got = seen.data[i][1] as f64;
        // Blur and footprint averaging make edges differ; the bulk must agree closely.
        if (got - predicted).abs() < 0.05 * predicted + 2e-3 {
            n += 1;
        }
        err_capture += (white.data[i][1] as f64 - got).abs();
    }
    let lit = truth.correspondences[1].iter().filter(|c| !c[0].is_nan()).count();
    assert!(lit > 300, "projector 1 lights {lit} pixels");
    assert!(n as f64 > 0.8 * lit as f64, "{n} of {lit} pixels agree with the stage model");
    assert!(err_capture / (lit as f64) < 0.01, "capture = render + noise");
}

#[test]
fn bad_input_ends_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x");
    let o = simulate(&out, &["--scene", "teapot"], &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("unknown scene \"teapot\""), "{}", stderr(&o));

    for (flag, size) in [("--camera", "0x48"), ("--projector", "100000x100000"), ("--camera", "64x0")] {
        let o = simulate(&out, &[flag, size], &[]);
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains("out of range") && e.contains("expected"), "{size}: {e}");
        assert!(!e.contains("panicked"), "{e}");
    }

    // An output folder that cannot be created: its parent is a file.
    let file = dir.path().join("plain-file");
    std::fs::write(&file, b"not a folder").unwrap();
    let o = simulate(&file.join("cap"), &[], &[]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("plain-file") && !e.contains("panicked"), "{e}");

    // Frames folder with a missing, then a wrongly sized frame.
    let cap = dir.path().join("cap");
    assert!(
        simulate(&cap, &["--projectors", "2", "--camera", "32x24", "--dot-spacing", "2"], &[])
            .status
            .success()
    );
    let frames = dir.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    RgbImage::new(48, 36).save(frames.join("proj0.png")).unwrap();
    let img = dir.path().join("seen.png");
    let render = || {
        run_author(
            &[
                "render",
                "--capture",
                cap.to_str().unwrap(),
                "--frames",
                frames.to_str().unwrap(),
                "--out",
                img.to_str().unwrap(),
            ],
            &[],
        )
    };
    let o = render();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("missing frame for projector 1") && stderr(&o).contains("proj1.png"),
        "{}",
        stderr(&o)
    );
    RgbImage::new(40, 36).save(frames.join("proj1.png")).unwrap();
    let o = render();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is 40x36, but projector 1 is 48x36"), "{}", stderr(&o));
    RgbImage::new(48, 36).save(frames.join("proj1.png")).unwrap();
    assert!(render().status.success());

    // A capture folder without ground truth.
    let o = run_author(
        &[
            "render",
            "--capture",
            dir.path().to_str().unwrap(),
            "--frames",
            frames.to_str().unwrap(),
            "--out",
            "x.png",
        ],
        &[],
    );
    assert!(!o.status.success());
    assert!(stderr(&o).contains("truth.json"), "{}", stderr(&o));
}
