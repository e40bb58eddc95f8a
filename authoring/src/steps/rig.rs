//! `restage-author rig CAPTURE... --out RIG_DIR`: calibrates the rig (projector intrinsics and
//! poses relative to the camera) once from one or more captures through it — a non-planar
//! scene, or two or more poses of a flat board — and saves `rig.json` for `calibrate --rig`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::calibrate::decode::{self, CaptureImages, DecodeParams, ProjectorDecode};
use restage_authoring::calibrate::geometry;
use restage_authoring::calibrate::rig::{Rig, RigCapture, RigUnits};
use restage_authoring::calibrate::selfcal::{KnownLength, SelfCalParams};
use restage_authoring::calibrate::triangulate::{self, TriangulateParams};
use restage_authoring::capture_set::{CameraIntrinsics, CaptureManifest, MANIFEST_FILE};

use super::Progress;

#[derive(Args)]
#[command(allow_negative_numbers = true)]
pub struct RigArgs {
    /// Capture directories (with capture.json) made through the same rig, or with
    /// --opencv-order folders of images; two or more poses of a flat board, or one non-planar scene.
    #[arg(required = true)]
    pub captures: Vec<PathBuf>,
    /// Folder to write rig.json into.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Distance in millimetres from the camera's lens to projector --known-projector's; without
    /// it the rig is in units of that baseline and `calibrate --rig` asks for the length.
    #[arg(long)]
    pub known_distance_mm: Option<f64>,
    #[arg(long, default_value_t = 0)]
    pub known_projector: usize,
    /// The folders hold one projector's Gray-code sequence each, in OpenCV GrayCodePattern order.
    #[arg(long, requires_all = ["projector_size", "camera_intrinsics"])]
    pub opencv_order: bool,
    /// Projector resolution WIDTHxHEIGHT (with --opencv-order).
    #[arg(long, value_parser = super::decode::parse_size)]
    pub projector_size: Option<(u32, u32)>,
    /// Camera intrinsics FX,FY,CX,CY in pixels (with --opencv-order).
    #[arg(long, value_parser = super::decode::parse_intrinsics)]
    pub camera_intrinsics: Option<[f64; 4]>,
    /// Camera lens distortion K1,K2,P1,P2,K3 (OpenCV's model; with --opencv-order).
    #[arg(long, value_parser = parse_distortion)]
    pub camera_distortion: Option<[f64; 5]>,
}

fn parse_distortion(s: &str) -> Result<[f64; 5], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e}"))?;
    let d: [f64; 5] = v.try_into().map_err(|_| format!("'{s}' is not K1,K2,P1,P2,K3"))?;
    if d.iter().all(|k| k.is_finite()) { Ok(d) } else { Err(format!("'{s}' is not finite")) }
}

/// One capture, read and decoded.
struct Decoded {
    name: String,
    camera: CameraIntrinsics,
    projectors: Vec<(u32, u32)>,
    decodes: Vec<ProjectorDecode>,
}

fn decode_one(args: &RigArgs, dir: &Path, params: &DecodeParams) -> Result<Decoded> {
    let name = dir.display().to_string();
    if args.opencv_order {
        let ((pw, ph), [fx, fy, cx, cy]) =
            (args.projector_size.expect("clap"), args.camera_intrinsics.expect("clap"));
        let files = super::decode::image_files(dir)?;
        let projector = decode::opencv_order(&files, pw, ph)?;
        let (w, h) =
            image::image_dimensions(&files[0]).with_context(|| format!("reading {}", files[0].display()))?;
        let camera = CameraIntrinsics {
            distortion: args.camera_distortion.unwrap_or([0.0; 5]),
            ..CameraIntrinsics::pinhole(w, h, fx, fy, cx, cy)
        };
        camera.check().map_err(anyhow::Error::msg).context("--camera-intrinsics")?;
        let images =
            CaptureImages { dir: Path::new(""), projector: &projector, width: w, height: h, raw: true };
        let d = decode::decode_projector(&images, 0, pw, ph, params)?;
        return Ok(Decoded { name, camera, projectors: vec![(pw, ph)], decodes: vec![d] });
    }
    if !dir.join(MANIFEST_FILE).exists() {
        bail!(
            "{name} has no {MANIFEST_FILE}; for a folder of Gray-code images in OpenCV order add \
             --opencv-order --projector-size WxH --camera-intrinsics FX,FY,CX,CY"
        );
    }
    let manifest = CaptureManifest::load(dir)?;
    let decodes = geometry::decode_capture(dir, &manifest, params, &mut |_| {})?;
    let projectors = manifest.projectors.iter().map(|p| (p.width, p.height)).collect();
    Ok(Decoded { name, camera: manifest.camera, projectors, decodes })
}

/// Runs the step; returns the rig (also written to `OUT/rig.json`).
pub fn run(args: &RigArgs, progress: &dyn Progress) -> Result<Rig> {
    if let Some(mm) = args.known_distance_mm
        && !(mm.is_finite() && mm > 0.0)
    {
        bail!("--known-distance-mm {mm}: expected the camera-to-projector lens distance in millimetres");
    }
    super::check_out(&args.out, args.overwrite.force)?;
    let params = if args.opencv_order { DecodeParams::opencv_defaults() } else { DecodeParams::default() };
    let mut decoded = Vec::new();
    progress.stage("decoding");
    for (i, dir) in args.captures.iter().enumerate() {
        progress.count(i as u64, args.captures.len() as u64);
        decoded.push(decode_one(args, dir, &params).with_context(|| format!("decoding {}", dir.display()))?);
    }
    progress.stage("solving the rig");
    let captures: Vec<RigCapture> = decoded
        .iter()
        .map(|d| RigCapture {
            name: d.name.clone(),
            camera: &d.camera,
            projectors: d.projectors.clone(),
            decodes: &d.decodes,
        })
        .collect();
    let known =
        args.known_distance_mm.map(|mm| KnownLength::Baseline { projector: args.known_projector, mm });
    let rig = Rig::calibrate(&captures, &SelfCalParams::default(), params.min_contrast, known.as_ref())
        .context("calibrating the rig")?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let path = rig.save(&args.out)?;
    report(&rig, &decoded);
    tracing::info!("wrote {}", path.display());
    Ok(rig)
}

/// Logs the rig and, per capture, how well the rig explains it: the triangulated points'
/// reprojection RMS and, for a flat board, how flat the largest plane comes out.
fn report(rig: &Rig, decoded: &[Decoded]) {
    let unit = match rig.units {
        RigUnits::Millimetres => "mm",
        RigUnits::Baseline => "baselines",
    };
    for (k, p) in rig.projectors.iter().enumerate() {
        let g = p.geometry();
        let c = g.centre();
        let angle = nalgebra::Rotation3::from_matrix(&g.rotation).angle().to_degrees();
        let s = &p.conditioning;
        tracing::info!(
            "projector {k}: f {:.1} +- {:.1} px, cx {:.1} +- {:.1}, cy {:.1} +- {:.1}; centre ({:.4}, {:.4}, {:.4}) \
             +- {:.4} {unit}, turned {angle:.2} +- {:.3} deg from the camera; RMS {:.3} px, epipolar median {:.3} px",
            p.f,
            s.f_std_px,
            p.cx,
            s.cx_std_px,
            p.cy,
            s.cy_std_px,
            c.x,
            c.y,
            c.z,
            s.translation_std,
            s.rotation_std_deg,
            p.rms_px,
            p.epipolar_median_px
        );
    }
    let Ok(geo) =
        rig.geometry(None).or_else(|_| rig.geometry(Some(&KnownLength::Baseline { projector: 0, mm: 1.0 })))
    else {
        return;
    };
    for d in decoded {
        let maps: Vec<Vec<[f32; 2]>> = d.decodes.iter().map(ProjectorDecode::pairs).collect();
        let refs: Vec<&[[f32; 2]]> = maps.iter().map(Vec::as_slice).collect();
        let dense = triangulate::triangulate(&d.camera, &geo, &refs, &TriangulateParams::default());
        let flat = triangulate::largest_plane(&dense.points, 7);
        tracing::info!(
            "{}: {} points, reprojection RMS {:.3} px; largest plane {:.0} % of the points, their distance \
             from it RMS {:.4} {unit} (a flat board comes out flat when the rig is right)",
            d.name,
            dense.valid,
            dense.rms_px(),
            100.0 * flat.fraction,
            flat.rms
        );
    }
}
