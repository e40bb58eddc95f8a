//! `restage-author calibrate CAPTURE_DIR --out STAGE_DIR`: the stage model from a capture
//! set, as a clear sequence of steps (decode, self-calibrate and triangulate, then light
//! transport, responses, vignetting, black levels, lux and gain when a lux reading is given,
//! then save with PNG reports and a PLY model).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use restage_authoring::calibrate::CalibrateError;
use restage_authoring::calibrate::geometry::{self, GeometryOptions, GeometryReport};
use restage_authoring::calibrate::lux::LuxReadings;
use restage_authoring::calibrate::photometric;
use restage_authoring::calibrate::rig::Rig;
use restage_authoring::calibrate::selfcal::KnownLength;
use restage_authoring::calibrate::transport::SnapParams;
use restage_authoring::calibrate::{ply, report};
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_model::StageModel;

use super::Progress;

#[derive(Args)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct CalibrateArgs {
    /// Capture directory (with capture.json).
    pub capture: PathBuf,
    /// Stage directory to write: stage.bin, stage.json, model.ply, report.png, report.json.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// The one length that fixes the scale: the distance in millimetres from the camera's
    /// centre of projection (its lens) to the lens of projector --known-projector, measured
    /// with a tape. Everything else is calibrated from the images.
    /// With --rig: optional, it rescales the rig (needed when the rig has no length).
    #[arg(long, required_unless_present = "rig")]
    pub known_distance_mm: Option<f64>,
    /// Which projector --known-distance-mm refers to.
    #[arg(long, default_value_t = 0)]
    pub known_projector: usize,
    /// Lux-meter readings at full white, one per projector (`0=420,1=395,2=410`), the meter at
    /// the object's centre facing the projector. Enables the photometric steps (paper §5.2).
    #[arg(long, conflicts_with = "lux_file")]
    pub lux_white: Option<String>,
    /// The same readings as a TOML file, optionally with the reference pixel, the meter's
    /// orientation and an ambient reading (see `calibrate::lux`).
    #[arg(long)]
    pub lux_file: Option<PathBuf>,
    /// A rig calibrated once with `restage-author rig` (its rig.json or folder): the geometry is
    /// triangulated with it instead of self-calibrated from this capture, so flat objects
    /// (paintings, panels) calibrate too. A projector moved since is named and refused.
    #[arg(long)]
    pub rig: Option<PathBuf>,
}

/// Where the projectors' geometry comes from.
pub enum GeometrySource {
    /// Self-calibration from this capture, scaled by the measured length.
    SelfCalibrate(KnownLength),
    /// A saved rig (`path` for messages), rescaled by the length if one is given.
    Rig { rig: Box<Rig>, path: PathBuf, known: Option<KnownLength> },
}

/// Runs calibration; the demo calls this too. Without lux readings only the geometry is
/// calibrated.
pub fn calibrate(
    capture: &Path,
    out: &Path,
    source: GeometrySource,
    lux: Option<&LuxReadings>,
    progress: &dyn Progress,
) -> Result<GeometryReport> {
    let started = std::time::Instant::now();
    // Step 1: the capture set.
    let manifest = CaptureManifest::load(capture)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let options = match &source {
        GeometrySource::SelfCalibrate(known) => GeometryOptions::new(known.clone()),
        // The length is the rig's; this one is never used.
        GeometrySource::Rig { .. } => GeometryOptions::new(KnownLength::Baseline { projector: 0, mm: 1.0 }),
    };

    // Step 2: decode structured light, projector by projector.
    progress.stage("decoding");
    let total = manifest.projectors.len() as u64;
    let decodes = geometry::decode_capture(capture, &manifest, &options.decode, &mut |k| {
        progress.count(k as u64, total)
    })
    .with_context(|| format!("decoding {}", capture.display()))?;
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

    // Step 3: self-calibrate all projectors jointly, scale, triangulate (or, with a saved rig,
    // check it still holds and triangulate with it).
    let (mut model, mut report, mut dense) = match &source {
        GeometrySource::SelfCalibrate(_) => {
            progress.stage("self-calibrating and triangulating");
            let (model, report, dense, _) = geometry::solve_geometry(&manifest, &decodes, &options)
                .map_err(|e| match e {
                    CalibrateError::IllPosed(_) => anyhow::Error::new(e).context(
                        "a flat object (a painting, a panel) cannot calibrate the rig by itself: calibrate the \
                         rig once with `restage-author rig` (a round object, or two or more poses of a flat \
                         board) and pass --rig",
                    ),
                    e => e.into(),
                })
                .with_context(|| format!("calibrating {}", capture.display()))?;
            (model, report, dense)
        }
        GeometrySource::Rig { rig, path, known } => {
            progress.stage("checking the rig and triangulating");
            geometry::solve_with_rig(&manifest, &decodes, rig, path, known.as_ref(), &options.triangulate)
                .with_context(|| {
                    format!("calibrating {} with the rig {}", capture.display(), path.display())
                })?
        }
    };

    // Step 4: light transport (refining the correspondences), responses, vignetting, black
    // levels, lux and gain.
    if let Some(lux) = lux {
        let show = |stage: &str, done: usize, total: usize| {
            progress.stage(stage);
            progress.count(done as u64, total as u64);
        };
        let (photo, refined) = photometric::calibrate_photometry(
            capture,
            &manifest,
            &mut model,
            lux,
            &SnapParams::default(),
            &options.triangulate,
            &show,
        )
        .with_context(|| format!("photometric calibration of {}", capture.display()))?;
        // The model's points are now those of the refined correspondences: report them.
        report.dense_rms_px = refined.rms_px();
        report.points = refined.valid;
        report.rejected_by_residual = refined.rejected_residual;
        report.rejected_by_depth = refined.rejected_depth;
        dense = refined;
        let sizes: Vec<(u32, u32)> = manifest.projectors.iter().map(|p| (p.width, p.height)).collect();
        photo
            .save(out, &sizes)
            .with_context(|| format!("writing the photometric report in {}", out.display()))?;
        for (k, t) in photo.transport.iter().enumerate() {
            tracing::info!(
                "projector {k}: {} of {} dots snapped, transport covers {:.1} % of its lit pixels, \
                 lux_at_1m {:.1}, leakage {:.2} %",
                t.dots,
                t.predicted,
                100.0 * t.coverage,
                model.projectors[k].lux_at_1m,
                100.0 * photo.radiometry[k].max_leakage()
            );
        }
    } else {
        tracing::warn!(
            "no --lux-white or --lux-file: only the geometry is calibrated (no light transport, \
             responses or gain)"
        );
    }

    // Step 5: save the model, the report and the PLY.
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

/// Runs the step as its arguments say.
pub fn run(args: &CalibrateArgs, progress: &dyn Progress) -> Result<GeometryReport> {
    // Everything that can be checked is checked before the minutes of decoding.
    if let Some(mm) = args.known_distance_mm
        && !(mm.is_finite() && mm > 0.0)
    {
        anyhow::bail!(
            "--known-distance-mm {mm}: expected the camera-to-projector lens distance in millimetres, \
             a positive number (e.g. 600)"
        );
    }
    super::check_out(&args.out, args.overwrite.force)?;
    let known =
        args.known_distance_mm.map(|mm| KnownLength::Baseline { projector: args.known_projector, mm });
    let source = match (&args.rig, known) {
        (Some(path), known) => {
            let rig = Rig::load(path)?;
            // A rig without a length needs one now: say so before the minutes of decoding.
            rig.geometry(known.as_ref())?;
            GeometrySource::Rig { rig: Box::new(rig), path: path.clone(), known }
        }
        (None, Some(known)) => GeometrySource::SelfCalibrate(known),
        (None, None) => anyhow::bail!("--known-distance-mm is needed without --rig"),
    };
    let lux = match (&args.lux_white, &args.lux_file) {
        (Some(text), _) => Some(LuxReadings::parse(text)?),
        (None, Some(path)) => Some(LuxReadings::load(path)?),
        (None, None) => None,
    };
    calibrate(&args.capture, &args.out, source, lux.as_ref(), progress)
}
