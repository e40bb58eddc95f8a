//! The demo's chain after calibration: classify, restore, relight, compensate three scenes on
//! the calibrated stage model, bundle with a demo key, verify, render what a visitor sees with
//! the virtual stage's TRUE physics, and write a contact sheet and a one-screen summary. Every
//! figure in the summary is measured here, never assumed.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::classify::{LabelMap, picks_from_labels};
use restage_authoring::compensate::{self, Exponent, Params, Prepared};
use restage_authoring::contact_sheet;
use restage_authoring::eval::compensate::{TruePhysics, colour_error, region_error, true_peak, whole_object};
use restage_authoring::export::{
    BundleDescription, LightDesc, ObjectDesc, PolicyDesc, ProjectorDesc, SceneDesc,
};
use restage_authoring::gpu::Device;
use restage_authoring::imgio::LinearImage;
use restage_authoring::relight::{self, Lighting};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::{SceneConfig, VirtualStage};

use super::Progress;

/// Light bound of the demo's bundle, lux (CIE 157 "low sensitivity" is 200 lx).
const E_BOUND_LUX: f64 = 150.0;
const MARGIN: f64 = 0.05;

/// What the demo's chain printed in its steps: the bundle's description, the verification's
/// lines and the one-screen summary (also written as `summary.txt`).
#[derive(Debug, Default)]
pub struct ChainSummary {
    pub bundle: String,
    pub verified: String,
    pub summary: String,
}

impl std::fmt::Display for ChainSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}{}\n{}", self.bundle, self.verified, self.summary)
    }
}

#[allow(clippy::too_many_arguments)]
pub fn run_chain(
    out: &Path,
    capture_dir: &Path,
    scene: &SceneConfig,
    manifest: &CaptureManifest,
    seed: u64,
    device: Device,
    start: Instant,
    head: &str,
    progress: &dyn Progress,
) -> Result<ChainSummary> {
    let mut summary = head.to_string();
    let mut log = |line: String| {
        summary.push_str(&line);
        summary.push('\n');
    };
    let at = || start.elapsed().as_secs_f64();
    let stage = VirtualStage::new(scene)?;

    // Step 2: calibration. Everything from here on (mask, relight, compensation, the bundle)
    // uses the CALIBRATED stage model `calibrate` wrote to stage/, as on a real stage; only the
    // visitor view is rendered with the virtual stage's true physics, standing in for the real
    // object under the real projectors. The summary compares the calibrated lux scale with the
    // truth, which only a virtual stage knows.
    let calibrated_dir = out.join("stage");
    let model = StageModel::load(&calibrated_dir)
        .with_context(|| format!("reading the calibrated stage model {}", calibrated_dir.display()))?;
    let truth_dir = capture_dir.join("ground-truth").join("stage");
    let truth = StageModel::load(&truth_dir).with_context(|| format!("reading {}", truth_dir.display()))?;
    let lux_parts: Vec<String> = model
        .projectors
        .iter()
        .zip(&truth.projectors)
        .enumerate()
        .map(|(k, (c, t))| {
            format!(
                "proj {k} {:.1} (true {:.1}, {:+.2} %)",
                c.lux_at_1m,
                t.lux_at_1m,
                100.0 * (c.lux_at_1m - t.lux_at_1m) / t.lux_at_1m
            )
        })
        .collect();
    tracing::info!(
        "compensation model: the CALIBRATED stage model ({}); lux scale from the simulated lux-meter readings, lx at 1 m: {}",
        calibrated_dir.display(),
        lux_parts.join(", ")
    );
    log("              compensation below uses the CALIBRATED stage model (stage/), end to end".to_string());
    // Demos before 2026-12 compensated on a substitute model written here; in the demo's own
    // folder it would now only mislead (the report and the interactive tool would not use it).
    let substitute = out.join("compensation-stage");
    if substitute.join("stage.bin").is_file() {
        std::fs::remove_dir_all(&substitute)
            .with_context(|| format!("removing an earlier demo's {}", substitute.display()))?;
    }

    // Step 3: classify the photo. A conservator's colour picks are stood in for by pixels
    // drawn from the ground-truth label map of the deteriorated object.
    let cam = stage.camera().clone();
    let palette = stage.palette();
    let (picks, present) = stand_in_picks(&stage, seed)?;
    let classify_dir = out.join("classify");
    std::fs::create_dir_all(&classify_dir)?;
    let picks_path = classify_dir.join("picks.json");
    picks.save(&picks_path)?;
    // The object mask: the mask step's automatic proposal on the CALIBRATED model, used when
    // it agrees with the virtual stage's ground-truth object mask on at least 99 % of the
    // pixels (the summary gives the figure); otherwise the ground truth, and the summary says so.
    let mask_path = classify_dir.join("object_mask.png");
    let truth_mask: Vec<bool> = stage.pixels().iter().map(|p| p.is_object()).collect();
    let (object_mask, mask_line) = demo_mask(&model, &truth_mask, &out.join("mask"))?;
    restage_authoring::segment::save_mask(&mask_path, cam.width, cam.height, &object_mask)?;
    tracing::info!("step 3 mask: {mask_line}");
    log(format!("3 mask        {mask_line}"));
    let photo_path = capture_dir.join(&manifest.photo);
    // The bare clay that chips and cracks expose is loss, as a conservator would say.
    let loss: Vec<u8> =
        present.iter().position(|&c| c == palette.clay).map(|k| k as u8).into_iter().collect();
    let cls = super::classify::classify_files(
        &photo_path,
        &picks_path,
        Some(&mask_path),
        &classify_dir,
        &restage_authoring::classify::ClassifyOptions { loss: loss.clone(), ..Default::default() },
        progress,
    )?;
    tracing::info!(
        "step 3 classify ({:.1} s): {cls}; picks drawn from the ground-truth label map (stand-in for clicks)",
        at()
    );
    log(format!(
        "3 classify    {} paint colours; the picks are stood in by the virtual stage's ground truth",
        cls.classes
    ));

    // Step 4: restore.
    let restore_dir = out.join("restore");
    let defaults = restage_authoring::restore::RestoreParams::default();
    let rargs = super::restore::RestoreArgs {
        classify_dir: classify_dir.clone(),
        out: restore_dir.clone(),
        alpha: defaults.alpha,
        beta: defaults.beta,
        gamma: None,
        neighbours: defaults.neighbours,
        scale: defaults.scale_px,
        loss,
        regions: vec![],
        background: None,
        hints: None,
        picks: Some(picks_path.clone()),
        grid: "auto".into(),
        mask: Some(mask_path.clone()),
        overwrite: super::Overwrite { force: true },
    };
    let rs = super::restore::restore_files(&rargs, progress)?;
    tracing::info!("step 4 restore ({:.1} s): {rs}", at());
    log(format!(
        "4 restore     {} colour boundaries smoothed, {} specks removed: {} pixels changed",
        rs.stats.contours, rs.stats.specks_removed, rs.changed_pixels
    ));
    let restored =
        LinearImage::load(&restore_dir.join("restored.png")).context("reading the restored image")?;
    let photo = LinearImage::load(&photo_path)?;

    // Step 5: relight one variant (soft key light, a third of the photo's material noise).
    let relit = relight::relight_on(&model, &restored, &Lighting::default(), device)?;
    let relit = relight::infuse_noise(&model, &relit, &photo, 0.3, 3)?;
    relit.save_srgb8(&out.join("relit.png"), 1.0)?;
    tracing::info!("step 5 relight ({:.1} s): soft key light + 30 % of the photo's material noise", at());
    log("5 relight     a soft key light, with 30 % of the photo's surface texture".to_string());

    // Step 6: compensate three scenes under one bound.
    let params = Params::new(E_BOUND_LUX, Exponent::Finite(8.0), MARGIN)?;
    let prep = Prepared::new(&model, params.reduction)?;
    let comp_dir = out.join("comp");
    // The "original" scene shows the object as photographed (even diffuse light): target = photo.
    let scenes = [
        ("original", "As found", "original", &photo),
        ("restored", "Restored", "restoration", &restored),
        ("relit", "Restored, relit", "relit", &relit),
    ];
    let mut views = Vec::new();
    for (id, _, _, target) in &scenes {
        // Only the object is lit (the mask's outside: no work points, dark projector pixels).
        let target = compensate::mask_target(target, &object_mask)?;
        let comp = compensate::compensate_on(&model, &prep, &target, &params, device)?;
        let dir = comp_dir.join(id);
        compensate::io::save(&dir, &comp, &params, &prep)?;
        if *id == "restored" {
            compensate::report::save(
                &dir.join("report"),
                &comp,
                &prep.geometry,
                &params,
                cam.width,
                cam.height,
            )?;
        }
        // Step 9 (per scene): what a visitor sees, rendered with the TRUE physics.
        let view = TruePhysics::view(&stage, &comp.frames);
        let (de_mean, de_p95, n) = colour_error(&comp, &view, &target);
        let whole = whole_object(&comp, &view, &target);
        let (de_object, object_px) = (whole.mean, whole.pixels);
        let tp = true_peak(&stage, &comp.frames);
        let s = &comp.stats;
        // The pixels asking for less light than the black level and room give: shown lifted.
        let dark = compensate::below_black(&model, &target, &comp.weights, s.scale);
        let dark_text = if dark.is_empty() {
            "none".to_string()
        } else {
            let (de, _) = region_error(&comp, &view, &target, &dark);
            format!(
                "{:.2} % (CIEDE2000 {de:.2} there)",
                100.0 * dark.len() as f64 / s.covered_points.max(1) as f64
            )
        };
        tracing::info!(
            "step 6 compensate {id:<8} ({:.1} s): certificate peak {:.1} lx, TRUE peak {:.1} lx (E_bound {E_BOUND_LUX} lx); \
             visitor view vs target CIEDE2000 mean {de_mean:.2}, p95 {de_p95:.2} over {n} lit px, \
             {de_object:.2} over all {object_px} px of the mask; mask {}; limited by bound {:.2} %; \
             darker than the black level {dark_text}",
            at(),
            s.peak_lux,
            tp,
            s.unlit,
            100.0 * s.limited_by_bound as f64 / s.covered_points.max(1) as f64,
        );
        log(format!(
            "6 compensate  {id:<8} brightest point {:.1} lx, allowed {:.1} (bound {E_BOUND_LUX} lx less \
             {:.0} % lux-meter accuracy and {:.0} % margin), truly {tp:.1}; lit {:.2} % of the mask; \
             colour difference {de_mean:.1} ΔE00 where lit, {de_object:.1} over the whole mask",
            s.peak_lux,
            s.limit_lux,
            100.0 * params.meter_accuracy,
            100.0 * params.margin,
            100.0 * s.unlit.lit_share()
        ));
        let img = LinearImage {
            width: cam.width,
            height: cam.height,
            data: view.iter().map(|v| v.map(|c| c / comp.stats.scale as f32)).collect(),
        };
        views.push(img);
    }
    std::fs::copy(
        comp_dir.join("restored").join(compensate::io::CERTIFICATE_FILE),
        comp_dir.join(compensate::io::CERTIFICATE_FILE),
    )?;

    // Step 7: bundle with the public demo key (never a production key).
    // Only the demo's own key files are replaced; anything else in keys/ and trust/ stays.
    let keys = out.join("keys");
    let trust = out.join("trust");
    for d in [&keys, &trust] {
        std::fs::create_dir_all(d)?;
    }
    for own in [keys.join("demo.pem"), keys.join("demo.pub.pem"), trust.join("demo.pub.pem")] {
        if own.is_file() {
            std::fs::remove_file(&own).with_context(|| format!("replacing {}", own.display()))?;
        }
    }
    // The one public demo key: every summary names it, and an appliance refuses it unless
    // its configuration says `allow_demo_key = true`.
    let key = restage_shared::keys::demo_signing_key();
    let (private, public) = restage_shared::keys::write_keypair(&key, &keys.join("demo"))?;
    std::fs::copy(&public, trust.join("demo.pub.pem"))?;
    let room = prep.certificate.ambient_lux;
    let desc = BundleDescription {
        version: 1,
        stage: calibrated_dir.clone(),
        certificate: comp_dir.join(compensate::io::CERTIFICATE_FILE),
        valid_days: Some(365),
        not_before_unix_s: None,
        object: ObjectDesc {
            id: format!("demo-{}", scene.scene.name()),
            name: format!("virtual stage {} (seed {seed})", scene.scene.name()),
        },
        light: LightDesc {
            e_bound_lux: E_BOUND_LUX,
            // The margin and the meter's accuracy together, so the appliance enforces the
            // limit compensation held the frames to.
            safety_margin: params.combined_margin(),
            ambient_lux: room,
            lux_shares: None,
        },
        policy: PolicyDesc::default(),
        projectors: (0..model.projectors.len())
            .map(|k| ProjectorDesc { name: format!("projector-{k}"), refresh_hz: 60.0, connector: None })
            .collect(),
        scenes: scenes
            .iter()
            .map(|(id, name, kind, _)| SceneDesc {
                id: id.to_string(),
                name: name.to_string(),
                kind: kind.to_string(),
                frames: (0..model.projectors.len())
                    .map(|k| comp_dir.join(id).join(compensate::io::frame_file(k)))
                    .collect(),
                preview: None,
            })
            .collect(),
    };
    let desc = toml::to_string(&desc).context("writing the bundle description")?;
    let desc_path = out.join("bundle.toml");
    std::fs::write(&desc_path, desc)?;
    let bundle_path = out.join("demo.restage");
    progress.stage("signing the bundle");
    let bundle_manifest = super::bundle::write(&super::bundle::BundleArgs {
        description: desc_path,
        key: private,
        out: bundle_path.clone(),
        zstd: 3,
        created: None,
        overwrite: super::Overwrite { force: true },
    })?;
    let bundle = format!(
        "{}wrote {}\n",
        restage_shared::bundle::describe(&bundle_manifest, None),
        bundle_path.display()
    );
    let size = std::fs::metadata(&bundle_path)?.len();
    tracing::info!(
        "step 7 bundle ({:.1} s): {} ({:.1} MB), signed with a demo key",
        at(),
        bundle_path.display(),
        size as f64 / 1e6
    );
    log(format!(
        "7 bundle      demo.restage ({:.1} MB), signed with the DEMO key: for trying restage only",
        size as f64 / 1e6
    ));

    // Step 8: verify as the appliance would (signature, hashes, every scene's light check).
    progress.stage("verifying the bundle");
    let verified = super::verify::report(&super::verify::VerifyArgs::now_with_defaults(
        bundle_path.clone(),
        trust.clone(),
    ))?;
    tracing::info!("step 8 verify ({:.1} s): bundle verified against {}", at(), trust.display());
    log("8 verify      the bundle passes the appliance's checks: signature, hashes, light bound".to_string());

    // Step 9: contact sheet — before (photo), target (restored), what a visitor sees.
    let tile = 320;
    let row = vec![
        contact_sheet::thumbnail(&photo, tile, 1.0),
        contact_sheet::thumbnail(&restored, tile, 1.0),
        contact_sheet::thumbnail(&views[1], tile, 1.0),
        contact_sheet::thumbnail(&views[2], tile, 1.0),
    ];
    let sheet_path = out.join("before_restored_target.png");
    contact_sheet::grid(&[row]).save(&sheet_path)?;
    tracing::info!(
        "step 9 render ({:.1} s): {} — photo (before) | restored target | visitor view, restored | visitor view, relit (true physics, brightness normalised by the scale)",
        at(),
        sheet_path.display()
    );
    log("9 view        before_restored_target.png: photo | restored target | what a visitor sees, restored | relit"
        .to_string());
    log(format!("done in {:.0} s; everything is in {}", at(), out.display()));
    let summary_path = out.join("summary.txt");
    std::fs::write(&summary_path, &summary)?;
    Ok(ChainSummary { bundle, verified, summary })
}

/// The demo's object mask and a line on where it came from: the proposal on the calibrated
/// model (also written to `mask_dir` as the mask step writes it) when it agrees with the
/// ground truth `truth` on at least [`MASK_AGREEMENT`] of the pixels, else `truth`.
pub fn demo_mask(calibrated: &StageModel, truth: &[bool], mask_dir: &Path) -> Result<(Vec<bool>, String)> {
    use restage_authoring::segment::{SegmentParams, propose};
    let proposal = propose(calibrated, &SegmentParams::default());
    let seg = match proposal {
        Ok(seg) if seg.mask.len() == truth.len() => seg,
        Ok(_) => return Ok((truth.to_vec(), "ground truth (the calibrated model's camera differs)".into())),
        Err(e) => return Ok((truth.to_vec(), format!("ground truth (no proposal: {e})"))),
    };
    let agree = seg.mask.iter().zip(truth).filter(|(a, b)| a == b).count() as f64 / truth.len() as f64;
    let object = truth.iter().filter(|&&t| t).count().max(1);
    let kept = seg.mask.iter().zip(truth).filter(|(m, t)| **m && **t).count() as f64 / object as f64;
    if agree >= MASK_AGREEMENT {
        super::mask::write(mask_dir, &seg)?;
        Ok((
            seg.mask,
            format!(
                "proposed from the calibrated model: {:.2} % of pixels agree with the ground truth, \
                 {:.2} % of the object kept",
                100.0 * agree,
                100.0 * kept
            ),
        ))
    } else {
        Ok((
            truth.to_vec(),
            format!(
                "ground truth: the calibrated model's proposal agrees on only {:.2} % of pixels",
                100.0 * agree
            ),
        ))
    }
}

/// Agreement with the ground truth the demo asks of the mask proposal before it uses it.
pub const MASK_AGREEMENT: f64 = 0.99;

/// The demo's stand-in for a conservator's clicks: 12 seeded pixels per paint colour present
/// on the object, drawn from the virtual stage's deteriorated labels (with their true display
/// colours). Returns the picks and the palette indices of the colours, in pick order.
pub fn stand_in_picks(
    stage: &VirtualStage,
    seed: u64,
) -> Result<(restage_authoring::classify::Picks, Vec<u8>)> {
    let cam = stage.camera();
    let palette = stage.palette();
    let raw: Vec<u8> = stage.pixels().iter().map(|p| p.label).collect();
    let present: Vec<u8> = (0..palette.classes.len() as u8).filter(|c| raw.contains(c)).collect();
    let remap = |l: u8| present.iter().position(|&c| c == l).map_or(255, |i| i as u8);
    let labels =
        LabelMap { width: cam.width, height: cam.height, data: raw.iter().map(|&l| remap(l)).collect() };
    let names: Vec<String> = present.iter().map(|&c| palette.classes[c as usize].name.clone()).collect();
    let display: Vec<Option<[u8; 3]>> =
        present.iter().map(|&c| Some(palette.classes[c as usize].srgb)).collect();
    Ok((picks_from_labels(&labels, &names, &display, 12, seed)?, present))
}
