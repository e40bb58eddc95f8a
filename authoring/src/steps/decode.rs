//! The decode step (`restage-author decode`): structured-light images to correspondence maps and a coverage
//! report, for our capture sets and for Gray-code captures in OpenCV's order.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::calibrate::CalibrateError;
use restage_authoring::calibrate::decode::{self, CaptureImages, DecodeParams, DecodeQuality};
use restage_authoring::calibrate::selfcal::{self, ProjectorObservations, SelfCalParams};
use restage_authoring::capture_set::{CameraIntrinsics, CaptureManifest, MANIFEST_FILE};

use super::Progress;

#[derive(Args)]
pub struct DecodeArgs {
    /// A capture directory (with capture.json), or with --opencv-order a folder of images.
    pub capture: PathBuf,
    /// Output folder for proj<k>_x.png, proj<k>_y.png, proj<k>_coverage.png and decode.json.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// The folder holds a Gray-code sequence in OpenCV structured_light.GrayCodePattern order
    /// (pairs pattern/inverse, MSB first, columns then rows, then white and black), taken in
    /// file-name order.
    #[arg(long)]
    pub opencv_order: bool,
    /// Projector resolution WIDTHxHEIGHT (required with --opencv-order).
    #[arg(long, value_parser = parse_size)]
    pub projector_size: Option<(u32, u32)>,
    /// Use OpenCV's default thresholds (black 40, white 5 of 255); default with --opencv-order.
    #[arg(long)]
    pub opencv_thresholds: bool,
    /// Decode like OpenCV: reject any pixel with a weak bit instead of allowing one at a stripe
    /// boundary.
    #[arg(long)]
    pub strict: bool,
    /// Camera intrinsics FX,FY,CX,CY (pixels): also try projector self-calibration from the
    /// decoded correspondences and report whether it is well posed (a planar scene is not).
    #[arg(long, value_parser = parse_intrinsics)]
    pub camera_intrinsics: Option<[f64; 4]>,
}

pub fn parse_intrinsics(s: &str) -> Result<[f64; 4], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e}"))?;
    v.try_into().map_err(|_| format!("'{s}' is not FX,FY,CX,CY"))
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once('x').ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT"))?;
    let p = |v: &str| v.trim().parse::<u32>().map_err(|_| format!("'{s}' is not WIDTHxHEIGHT"));
    let (w, h) = (p(w)?, p(h)?);
    if w == 0 || h == 0 {
        return Err(format!("'{s}' has a zero side (a projector is at least 1x1 pixels)"));
    }
    Ok((w, h))
}

/// Runs the step as its arguments say; returns each projector's decode quality (also written
/// to `decode.json`).
pub fn run(args: &DecodeArgs, progress: &dyn Progress) -> Result<Vec<DecodeQuality>> {
    super::check_out(&args.out, args.overwrite.force)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut params = if args.opencv_order || args.opencv_thresholds {
        DecodeParams::opencv_defaults()
    } else {
        DecodeParams::default()
    };
    if args.strict {
        params.max_weak_bits = 0;
    }
    let mut qualities: Vec<DecodeQuality> = Vec::new();
    if args.opencv_order {
        let Some((pw, ph)) = args.projector_size else {
            bail!("--opencv-order needs --projector-size WIDTHxHEIGHT (e.g. 1024x768)");
        };
        let files = image_files(&args.capture)?;
        let projector = decode::opencv_order(&files, pw, ph)?;
        let first =
            image::image_dimensions(&files[0]).with_context(|| format!("reading {}", files[0].display()))?;
        let images = CaptureImages {
            dir: Path::new(""),
            projector: &projector,
            width: first.0,
            height: first.1,
            raw: true,
        };
        let d = decode::decode_projector(&images, 0, pw, ph, &params)?;
        decode::save_maps(&d, 0, pw, ph, &args.out)?;
        if let Some([fx, fy, cx, cy]) = args.camera_intrinsics {
            let cam =
                CameraIntrinsics { width: first.0, height: first.1, fx, fy, cx, cy, distortion: [0.0; 5] };
            selfcal_check(&cam, &d, pw, ph, &args.out)?;
        }
        qualities.push(d.quality);
    } else {
        // A folder of images from another tool is the likely mistake here; say how to read it.
        if !args.capture.join(MANIFEST_FILE).exists() {
            bail!(
                "{} has no {MANIFEST_FILE}, so it is not a restage capture set; if it holds a Gray-code \
                 sequence in OpenCV GrayCodePattern order, add --opencv-order --projector-size WIDTHxHEIGHT",
                args.capture.display()
            );
        }
        let manifest = CaptureManifest::load(&args.capture)?;
        progress.stage("decoding");
        let total = manifest.projectors.len() as u64;
        for (done, p) in manifest.projectors.iter().enumerate() {
            progress.count(done as u64, total);
            let images = CaptureImages {
                dir: &args.capture,
                projector: p,
                width: manifest.camera.width,
                height: manifest.camera.height,
                raw: false,
            };
            let d = decode::decode_projector(&images, p.index, p.width, p.height, &params)?;
            decode::save_maps(&d, p.index, p.width, p.height, &args.out)?;
            qualities.push(d.quality);
        }
    }
    for q in &qualities {
        for w in &q.warnings {
            tracing::warn!("{w}");
        }
        tracing::info!(
            "projector {}: {} of {} pixels decoded, {:.3} % inconsistent with their neighbours \
             ({:.3} % of those read with no weak bit, {:.3} % of those kept with one) \
             ({} lit, {} of them faint, {} weak, {} out of range, {} phase-rejected, {} weak and inconsistent)",
            q.projector,
            q.decoded,
            q.pixels,
            100.0 * q.inconsistent,
            100.0 * q.inconsistent_confident,
            100.0 * q.inconsistent_weak,
            q.lit,
            q.faint,
            q.weak,
            q.out_of_range,
            q.phase_rejected,
            q.weak_inconsistent
        );
    }
    let path = args.out.join("decode.json");
    std::fs::write(&path, serde_json::to_string_pretty(&qualities)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(qualities)
}

/// Tries self-calibration on one projector's correspondences and records the verdict in
/// `selfcal.json`: the figures if it is well posed, the reason if not.
fn selfcal_check(
    cam: &CameraIntrinsics,
    d: &decode::ProjectorDecode,
    pw: u32,
    ph: u32,
    out: &Path,
) -> Result<()> {
    let map = d.pairs();
    let obs = [ProjectorObservations { width: pw, height: ph, map: &map }];
    let verdict = match selfcal::self_calibrate(cam, &obs, &SelfCalParams::default()) {
        Ok(r) => {
            let g = &r.projectors[0];
            tracing::info!(
                "self-calibration: f {:.1} cx {:.1} cy {:.1}, RMS {:.3} px",
                g.f,
                g.cx,
                g.cy,
                r.rms_px
            );
            serde_json::json!({"well_posed": true, "f": g.f, "cx": g.cx, "cy": g.cy, "rms_px": r.rms_px,
                "conditioning": r.conditioning, "warnings": r.warnings})
        }
        Err(e @ CalibrateError::IllPosed(_)) => {
            tracing::warn!("{e}");
            serde_json::json!({"well_posed": false, "reason": e.to_string()})
        }
        Err(e) => return Err(e.into()),
    };
    let path = out.join("selfcal.json");
    std::fs::write(&path, serde_json::to_string_pretty(&verdict)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// PNG files of a folder in file-name order.
pub fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{} holds no PNG images", dir.display());
    }
    Ok(files)
}
