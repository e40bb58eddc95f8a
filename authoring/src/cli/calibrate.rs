//! `restage-author calibrate CAPTURE_DIR --out STAGE_DIR`: the stage model from a capture
//! set, as a clear sequence of steps (decode, self-calibrate and triangulate, then save with
//! a PNG report and a PLY model).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use restage_authoring::calibrate::geometry::{self, GeometryOptions, GeometryReport};
use restage_authoring::calibrate::selfcal::KnownLength;
use restage_authoring::calibrate::{ply, report};
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_model::StageModel;

#[derive(Args)]
pub struct CalibrateArgs {
    /// Capture directory (with capture.json).
    pub capture: PathBuf,
    /// Stage directory to write: stage.bin, stage.json, model.ply, report.png, report.json.
    #[arg(long)]
    pub out: PathBuf,
    /// The one length that fixes the scale: the distance in millimetres from the camera's
    /// centre of projection (its lens) to the lens of projector --known-projector, measured
    /// with a tape. Everything else is calibrated from the images.
    #[arg(long)]
    pub known_distance_mm: f64,
    /// Which projector --known-distance-mm refers to.
    #[arg(long, default_value_t = 0)]
    pub known_projector: usize,
}

/// Runs calibration; the demo calls this too.
pub fn calibrate(capture: &Path, out: &Path, known: KnownLength) -> Result<GeometryReport> {
    let started = std::time::Instant::now();
    // Step 1: the capture set.
    let manifest = CaptureManifest::load(capture)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let options = GeometryOptions::new(known);

    // Step 2: decode structured light, projector by projector.
    let bar = crate::cli::progress(manifest.projectors.len() as u64, "decoding");
    let decodes =
        geometry::decode_capture(capture, &manifest, &options.decode, &mut |k| bar.set_position(k as u64))
            .with_context(|| format!("decoding {}", capture.display()))?;
    bar.finish_and_clear();
    for d in &decodes {
        let q = &d.quality;
        tracing::info!(
            "projector {}: {} of {} camera pixels decoded (phase {} steps, linearised {})",
            q.projector,
            q.decoded,
            q.pixels,
            q.phase_steps,
            q.linearised
        );
    }

    // Step 3: self-calibrate all projectors jointly, scale, triangulate.
    let spinner = indicatif::ProgressBar::new_spinner().with_message("self-calibrating and triangulating");
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let (model, report, dense, _) = geometry::solve_geometry(&manifest, &decodes, &options)
        .with_context(|| format!("calibrating {}", capture.display()))?;
    spinner.finish_and_clear();

    // Step 4: save the model, the report and the PLY.
    save(&model, out)?;
    let sizes: Vec<(u32, u32)> = manifest.projectors.iter().map(|p| (p.width, p.height)).collect();
    let png = out.join("report.png");
    report::render(&decodes, &dense, &sizes)
        .save(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    let colours =
        LinearImage::load_sized(&capture.join(&manifest.photo), model.camera.width, model.camera.height)
            .map(|photo| photo.to_srgb8(1.0).pixels().map(|p| p.0).collect::<Vec<[u8; 3]>>())
            .map_err(|e| tracing::warn!("no colours for the PLY: {e}"))
            .ok();
    let n = ply::save_ply(&out.join("model.ply"), &model.points, &model.normals, colours.as_deref())?;
    let json = out.join("report.json");
    std::fs::write(&json, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", json.display()))?;

    for w in &report.warnings {
        tracing::warn!("{w}");
    }
    tracing::info!(
        "calibrated in {:.1} s: {} points ({n} in model.ply), reprojection RMS {:.3} px (adjustment {:.3} px)",
        started.elapsed().as_secs_f64(),
        report.points,
        report.dense_rms_px,
        report.adjustment_rms_px
    );
    for (p, c) in model.projectors.iter().zip(&report.conditioning) {
        tracing::info!(
            "projector {}: f {:.1} +- {:.2} px, cx {:.1} +- {:.2}, cy {:.1} +- {:.2}, baseline {:.1} mm",
            c.projector,
            p.f,
            c.f_std_px,
            p.cx,
            c.cx_std_px,
            p.cy,
            c.cy_std_px,
            (p.translation[0].powi(2) + p.translation[1].powi(2) + p.translation[2].powi(2)).sqrt()
        );
    }
    Ok(report)
}

/// Writes stage.bin and its human summary stage.json.
fn save(model: &StageModel, out: &Path) -> Result<()> {
    model.save(out)?;
    let summary = serde_json::json!({
        "note": "human summary of stage.bin (never read back)",
        "provenance": model.provenance,
        "camera": model.camera,
        "points": model.points.iter().filter(|p| p[2].is_finite()).count(),
        "projectors": model.projectors.iter().map(|p| serde_json::json!({
            "width": p.width, "height": p.height, "f": p.f, "cx": p.cx, "cy": p.cy,
            "rotation": p.rotation, "translation_mm": p.translation,
        })).collect::<Vec<_>>(),
    });
    let path = out.join("stage.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", path.display()))
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let known = KnownLength::Baseline { projector: args.known_projector, mm: args.known_distance_mm };
    calibrate(&args.capture, &args.out, known).map(|_| ())
}
