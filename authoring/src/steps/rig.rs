//! `restage-author rig CAPTURE... --out RIG_DIR`: calibrates the rig (projector intrinsics and
//! poses relative to the camera) once from one or more captures through it — a non-planar
//! scene, or two or more poses of a flat board — and saves `rig.json` for `calibrate --rig`.
//! With `--chessboard` the board's printed squares do the work (the camera is calibrated too
//! unless it is given); without, the scene's depth does (self-calibration).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::calibrate::board::{self, Board, BoardPose};
use restage_authoring::calibrate::decode::{
    self, CaptureImages, DecodeParams, PatternImages, ProjectorDecode,
};
use restage_authoring::calibrate::geometry;
use restage_authoring::calibrate::rig::{Rig, RigCapture, RigUnits};
use restage_authoring::calibrate::selfcal::{KnownLength, SelfCalParams};
use restage_authoring::calibrate::triangulate::{self, TriangulateParams};
use restage_authoring::capture_set::{CameraIntrinsics, CaptureManifest, MANIFEST_FILE, Pattern};

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
    #[arg(long, requires = "projector_size")]
    pub opencv_order: bool,
    /// Projector resolution WIDTHxHEIGHT (with --opencv-order).
    #[arg(long, value_parser = super::decode::parse_size)]
    pub projector_size: Option<(u32, u32)>,
    /// Camera intrinsics FX,FY,CX,CY in pixels (with --opencv-order; optional with --chessboard,
    /// which then calibrates the camera too).
    #[arg(long, value_parser = super::decode::parse_intrinsics)]
    pub camera_intrinsics: Option<[f64; 4]>,
    /// Camera lens distortion K1,K2,P1,P2,K3 (OpenCV's model; with --opencv-order).
    #[arg(long, value_parser = parse_distortion)]
    pub camera_distortion: Option<[f64; 5]>,
    /// Calibrate from a printed chessboard in every capture (two or more poses): its inner
    /// corners across and down, COLSxROWS (a board of 10x8 squares has 9x7). Its squares give
    /// the scale, so it takes no --known-distance-mm.
    #[arg(long, value_parser = super::decode::parse_size, requires = "square_mm", conflicts_with = "known_distance_mm")]
    pub chessboard: Option<(u32, u32)>,
    /// Side of one chessboard square, millimetres (measure the print).
    #[arg(long, requires = "chessboard")]
    pub square_mm: Option<f64>,
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
    /// `None` for a foreign capture without given intrinsics (a board calibrates the camera).
    camera: Option<CameraIntrinsics>,
    size: (u32, u32),
    projectors: Vec<(u32, u32)>,
    decodes: Vec<ProjectorDecode>,
    /// The first projector's full-white image, where a chessboard is looked for.
    white: Option<Vec<f32>>,
}

fn decode_one(args: &RigArgs, dir: &Path, params: &DecodeParams) -> Result<Decoded> {
    let name = dir.display().to_string();
    if args.opencv_order {
        let (pw, ph) = args.projector_size.expect("clap");
        let files = super::decode::image_files(dir)?;
        let projector = decode::opencv_order(&files, pw, ph)?;
        let (w, h) =
            image::image_dimensions(&files[0]).with_context(|| format!("reading {}", files[0].display()))?;
        let camera = match args.camera_intrinsics {
            Some([fx, fy, cx, cy]) => {
                let camera = CameraIntrinsics {
                    distortion: args.camera_distortion.unwrap_or([0.0; 5]),
                    ..CameraIntrinsics::pinhole(w, h, fx, fy, cx, cy)
                };
                camera.check().map_err(anyhow::Error::msg).context("--camera-intrinsics")?;
                Some(camera)
            }
            None if args.chessboard.is_some() => None,
            None => bail!(
                "--opencv-order needs --camera-intrinsics FX,FY,CX,CY (or a --chessboard in the captures, \
                 which calibrates the camera too)"
            ),
        };
        let images =
            CaptureImages { dir: Path::new(""), projector: &projector, width: w, height: h, raw: true };
        let d = decode::decode_projector(&images, 0, pw, ph, params)?;
        let white = white_image(args, &images)?;
        return Ok(Decoded {
            name,
            camera,
            size: (w, h),
            projectors: vec![(pw, ph)],
            decodes: vec![d],
            white,
        });
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
    let (w, h) = (manifest.camera.width, manifest.camera.height);
    let white = match manifest.projectors.first() {
        Some(p) => white_image(args, &CaptureImages { dir, projector: p, width: w, height: h, raw: false })?,
        None => None,
    };
    Ok(Decoded { name, camera: Some(manifest.camera), size: (w, h), projectors, decodes, white })
}

/// The decoded captures as the rig solvers take them, with the camera `camera` when given (a
/// board calibration's), else each capture's own.
fn rig_captures<'a>(decoded: &'a [Decoded], camera: Option<&'a CameraIntrinsics>) -> Vec<RigCapture<'a>> {
    decoded
        .iter()
        .map(|d| RigCapture {
            name: d.name.clone(),
            camera: camera
                .or(d.camera.as_ref())
                .expect("decode_one requires a camera unless a board gives one"),
            projectors: d.projectors.clone(),
            decodes: &d.decodes,
        })
        .collect()
}

/// The full-white image, when a chessboard is to be found in it.
fn white_image(args: &RigArgs, images: &CaptureImages) -> Result<Option<Vec<f32>>> {
    if args.chessboard.is_none() {
        return Ok(None);
    }
    Ok(Some(
        images
            .grey(&Pattern::White)?
            .context("the capture has no full-white image to find the chessboard in")?,
    ))
}

/// The rig from the chessboard in every capture (Moreno & Taubin): corners in the white image,
/// carried into each projector, then Zhang and one adjustment.
fn board_rig(args: &RigArgs, decoded: &[Decoded]) -> Result<Rig> {
    let ((cols, rows), square_mm) = (args.chessboard.expect("caller"), args.square_mm.expect("clap"));
    let board = Board { cols, rows, square_mm };
    let first = &decoded[0];
    let mut poses = Vec::new();
    for d in decoded {
        if d.size != first.size || d.projectors != first.projectors || d.camera != first.camera {
            bail!("{}: its camera or projectors differ from {}'s: one rig, one camera", d.name, first.name);
        }
        let (w, h) = d.size;
        let corners = board::find_corners(d.white.as_deref().expect("read with --chessboard"), w, h, &board)
            .with_context(|| format!("finding the chessboard in {}", d.name))?;
        let maps: Vec<Vec<[f32; 2]>> = d.decodes.iter().map(ProjectorDecode::pairs).collect();
        let refs: Vec<&[[f32; 2]]> = maps.iter().map(Vec::as_slice).collect();
        let pose = BoardPose::new(corners, &refs, w);
        for (k, seen) in pose.projectors.iter().enumerate() {
            tracing::info!(
                "{}: {} corners, projector {k} carries {}",
                d.name,
                pose.corners.len(),
                seen.iter().flatten().count()
            );
        }
        poses.push(pose);
    }
    let cal = board::calibrate(&poses, first.size, &first.projectors, first.camera.as_ref())
        .context("calibrating the rig from the chessboard")?;
    let c = &cal.camera;
    let s = cal.camera_std;
    if first.camera.is_none() {
        tracing::info!(
            "camera: fx {:.1} +- {:.1}, fy {:.1} +- {:.1}, cx {:.1} +- {:.1}, cy {:.1} +- {:.1} px, k1 {:.4} +- {:.4}, \
             k2 {:.4} +- {:.4}",
            c.fx,
            s[0],
            c.fy,
            s[1],
            c.cx,
            s[2],
            c.cy,
            s[3],
            c.distortion[0],
            s[4],
            c.distortion[1],
            s[5]
        );
    }
    tracing::info!(
        "corner residuals: camera RMS {:.3} px, projectors {:?} px",
        cal.camera_rms_px,
        cal.projector_rms_px.iter().map(|r| format!("{r:.3}")).collect::<Vec<_>>()
    );
    let captures = rig_captures(decoded, Some(&cal.camera));
    let rig = Rig::from_board(&captures, &board, cal.clone());
    board_check(&rig, decoded, &poses, &cal);
    Ok(rig)
}

/// The independent check of a board calibration: the board triangulated from all its decoded
/// pixels (camera and projector together, not the corners) against the board the camera's
/// corners alone place: how flat it comes out, how far it is turned and moved from that.
fn board_check(rig: &Rig, decoded: &[Decoded], poses: &[BoardPose], cal: &board::BoardCalibration) {
    let Ok(geo) = rig.geometry(None) else { return };
    let w = rig.camera.width as usize;
    for ((d, pose), (r, t)) in decoded.iter().zip(poses).zip(&cal.poses) {
        let maps: Vec<Vec<[f32; 2]>> = d.decodes.iter().map(ProjectorDecode::pairs).collect();
        let refs: Vec<&[[f32; 2]]> = maps.iter().map(Vec::as_slice).collect();
        let dense = triangulate::triangulate(&rig.camera, &geo, &refs, &TriangulateParams::default());
        let quad = board::outline(&pose.corners);
        let inside: Vec<[f32; 3]> = dense
            .points
            .iter()
            .enumerate()
            .filter(|(i, p)| p[2].is_finite() && board::inside(&quad, [(i % w) as f64, (i / w) as f64]))
            .map(|(_, p)| *p)
            .collect();
        let plane = triangulate::largest_plane(&inside, 7);
        let normal = r.column(2).into_owned();
        let turned = plane.normal.dot(&normal).abs().min(1.0).acos().to_degrees();
        let offsets: Vec<f64> = inside
            .iter()
            .map(|p| (nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - t).dot(&normal))
            .collect();
        let mean = offsets.iter().sum::<f64>() / offsets.len().max(1) as f64;
        tracing::info!(
            "{}: the board from {} decoded pixels: flat to {:.3} mm RMS ({:.0} % within the plane), turned \
             {turned:.2} deg and {mean:+.2} mm off the board the camera's corners place",
            d.name,
            inside.len(),
            plane.rms,
            100.0 * plane.fraction
        );
    }
}

/// Runs the step; returns the rig (also written to `OUT/rig.json`).
pub fn run(args: &RigArgs, progress: &dyn Progress) -> Result<Rig> {
    if let Some(mm) = args.known_distance_mm
        && !(mm.is_finite() && mm > 0.0)
    {
        bail!("--known-distance-mm {mm}: expected the camera-to-projector lens distance in millimetres");
    }
    if let Some(s) = args.square_mm
        && !(s.is_finite() && s > 0.0)
    {
        bail!("--square-mm {s}: expected the side of one printed square in millimetres");
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
    let rig = if args.chessboard.is_some() {
        board_rig(args, &decoded)?
    } else {
        let captures = rig_captures(&decoded, None);
        let known =
            args.known_distance_mm.map(|mm| KnownLength::Baseline { projector: args.known_projector, mm });
        Rig::calibrate(&captures, &SelfCalParams::default(), params.min_contrast, known.as_ref())
            .context("calibrating the rig")?
    };
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
        let dense = triangulate::triangulate(&rig.camera, &geo, &refs, &TriangulateParams::default());
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
