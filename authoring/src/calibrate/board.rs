//! Board calibration of a rig (Moreno & Taubin 2012): a printed chessboard seen in two or more
//! poses under the Gray codes. Its inner corners, found in the camera's white image and carried
//! into each projector by a local homography of the decoded correspondences around them, are
//! points of known metric shape. Each pose gives the camera and every projector a
//! plane-to-image homography, which (Zhang 2000) determines their intrinsics where a flat scene
//! without a known pattern cannot; one Levenberg-Marquardt adjustment then refines the camera,
//! the projectors and the board poses together. Units: board millimetres, pixel centres.

use calib_targets_chessboard::{
    ChessboardDetector, ChessboardParams, GrayImageView, default_chess_config, detect_corners,
};
use nalgebra::{DMatrix, DVector, Matrix3, Matrix4, Rotation3, SymmetricEigen, Vector3, Vector4};
use thiserror::Error;

use super::selfcal::{Conditioning, ProjectorGeometry, homography};
use crate::capture_set::CameraIntrinsics;

/// A printed chessboard: inner corners across and down, and the side of one square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Board {
    pub cols: u32,
    pub rows: u32,
    pub square_mm: f64,
}

#[derive(Debug, Error)]
pub enum BoardError {
    #[error(
        "a chessboard needs at least 3x3 inner corners and a positive square size (got {cols}x{rows}, {square_mm} mm)"
    )]
    BadBoard { cols: u32, rows: u32, square_mm: f64 },
    #[error(
        "no {cols}x{rows} chessboard in the white image ({found} inner corners labelled): is the whole board \
         in view, lit and sharp, and are {cols}x{rows} its inner corners (squares minus one each way)?"
    )]
    NotFound { cols: u32, rows: u32, found: usize },
    #[error("board calibration needs two or more poses of the board, tilted differently (got {0})")]
    TooFewPoses(usize),
    #[error(
        "pose {pose}: projector {projector} carries {seen} of the board's corners (needs {need}); move the \
         board into that projector's light"
    )]
    TooFewCorners { pose: usize, projector: usize, seen: usize, need: usize },
    #[error("the board poses do not determine {what}; tilt the board differently between poses")]
    Degenerate { what: String },
}

/// One inner corner: where it is on the board (mm) and where the camera sees it (px).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardCorner {
    pub board: [f64; 2],
    pub camera: [f64; 2],
}

/// Finds the board's inner corners in a grey camera image (linear or not: only edges matter).
/// Every corner must be found; the labelling starts at one corner of the board (which one
/// does not matter: each pose gets its own board frame).
pub fn find_corners(
    grey: &[f32],
    width: u32,
    height: u32,
    board: &Board,
) -> Result<Vec<BoardCorner>, BoardError> {
    if board.cols < 3 || board.rows < 3 || !(board.square_mm.is_finite() && board.square_mm > 0.0) {
        return Err(BoardError::BadBoard { cols: board.cols, rows: board.rows, square_mm: board.square_mm });
    }
    // 8 bits with the brightest 0.5 % at full scale, whatever the capture's exposure.
    let mut sorted: Vec<f32> = grey.iter().copied().filter(|v| v.is_finite()).collect();
    let top = if sorted.is_empty() {
        1.0
    } else {
        let k = ((sorted.len() as f64 * 0.995) as usize).min(sorted.len() - 1);
        *sorted.select_nth_unstable_by(k, f32::total_cmp).1
    };
    let scale = if top > 0.0 { 255.0 / top } else { 1.0 };
    let bytes: Vec<u8> = grey.iter().map(|v| (v * scale).clamp(0.0, 255.0) as u8).collect();
    let view = GrayImageView { width: width as usize, height: height as usize, data: &bytes };
    let raw = detect_corners(&view, &default_chess_config());
    let want = (board.cols * board.rows) as usize;
    let mut params = ChessboardParams::default();
    params.min_labeled_corners = want;
    let not_found = |found| BoardError::NotFound { cols: board.cols, rows: board.rows, found };
    let detector = ChessboardDetector::new(params).map_err(|_| not_found(0))?;
    let det = detector.detect(&raw).ok_or_else(|| not_found(0))?;
    // The board is the one complete COLSxROWS block of labels (the detector may label a stray
    // corner beyond the board's edge: the print's margin, a tape's corner).
    let labels: std::collections::HashSet<(i32, i32)> =
        det.corners.iter().map(|c| (c.grid.u, c.grid.v)).collect();
    let (lo_u, lo_v) = labels.iter().fold((i32::MAX, i32::MAX), |a, l| (a.0.min(l.0), a.1.min(l.1)));
    let (hi_u, hi_v) = labels.iter().fold((i32::MIN, i32::MIN), |a, l| (a.0.max(l.0), a.1.max(l.1)));
    let mut blocks = Vec::new();
    for (bw, bh) in [(board.cols as i32, board.rows as i32), (board.rows as i32, board.cols as i32)] {
        for u0 in lo_u..=hi_u - bw + 1 {
            for v0 in lo_v..=hi_v - bh + 1 {
                if (u0..u0 + bw).all(|u| (v0..v0 + bh).all(|v| labels.contains(&(u, v)))) {
                    blocks.push((u0, v0, bw, bh));
                }
            }
        }
        if board.cols == board.rows {
            break;
        }
    }
    let [(u0, v0, bw, bh)] = blocks[..] else { return Err(not_found(det.corners.len())) };
    let inside = |c: &&calib_targets_chessboard::ChessboardCorner| {
        (u0..u0 + bw).contains(&c.grid.u) && (v0..v0 + bh).contains(&c.grid.v)
    };
    // The refinement window: a quarter of the corners' spacing in the image.
    let pitch = det.cell_size.map_or(20.0, |c| c as f64);
    let half = ((pitch / 4.0).round() as i64).clamp(2, 10);
    Ok(det
        .corners
        .iter()
        .filter(inside)
        .map(|c| BoardCorner {
            board: [(c.grid.u - u0) as f64 * board.square_mm, (c.grid.v - v0) as f64 * board.square_mm],
            camera: refine(grey, width, height, [c.position.x as f64, c.position.y as f64], half),
        })
        .collect())
}

/// Sub-pixel saddle point (as OpenCV's `cornerSubPix`): the point every image gradient in a
/// Gaussian-weighted window is orthogonal to the line from it, `sum(g g^T) q = sum(g g^T p)`.
/// The detector's own estimate scatters by a few tenths of a pixel; this brings it to hundredths.
fn refine(grey: &[f32], width: u32, height: u32, at: [f64; 2], half: i64) -> [f64; 2] {
    let (w, h) = (width as i64, height as i64);
    let at_px = |u: i64, v: i64| grey[(v * w + u) as usize] as f64;
    let sigma2 = 2.0 * (half as f64 / 1.5).powi(2);
    let mut q = at;
    for _ in 0..30 {
        let (cu, cv) = (q[0].round() as i64, q[1].round() as i64);
        let mut a = nalgebra::Matrix2::<f64>::zeros();
        let mut b = nalgebra::Vector2::<f64>::zeros();
        for v in (cv - half).max(1)..=(cv + half).min(h - 2) {
            for u in (cu - half).max(1)..=(cu + half).min(w - 2) {
                let g = nalgebra::Vector2::new(
                    (at_px(u + 1, v) - at_px(u - 1, v)) / 2.0,
                    (at_px(u, v + 1) - at_px(u, v - 1)) / 2.0,
                );
                let wt = (-((u as f64 - q[0]).powi(2) + (v as f64 - q[1]).powi(2)) / sigma2).exp();
                let gg = g * g.transpose() * wt;
                a += gg;
                b += gg * nalgebra::Vector2::new(u as f64, v as f64);
            }
        }
        let Some(next) = a.try_inverse().map(|ai| ai * b) else { return at };
        let moved = (next.x - q[0]).hypot(next.y - q[1]);
        if !moved.is_finite() || (next.x - at[0]).hypot(next.y - at[1]) > half as f64 {
            return at;
        }
        q = [next.x, next.y];
        if moved < 1e-4 {
            break;
        }
    }
    q
}

/// Where a projector saw a camera point (Moreno & Taubin's local homography): a homography
/// fitted to the decoded correspondences in a `(2 half + 1)²` window around it, refitted without
/// the outliers. `None` when fewer than half the window decoded or fits.
pub fn projector_corner(map: &[[f32; 2]], width: u32, at: [f64; 2], half: usize) -> Option<[f64; 2]> {
    let w = width as i64;
    let h = map.len() as i64 / w.max(1);
    let (cu, cv) = (at[0].round() as i64, at[1].round() as i64);
    let r = half as i64;
    let (mut cam, mut proj) = (Vec::new(), Vec::new());
    for v in (cv - r).max(0)..=(cv + r).min(h - 1) {
        for u in (cu - r).max(0)..=(cu + r).min(w - 1) {
            let m = map[(v * w + u) as usize];
            if m[0].is_finite() && m[1].is_finite() {
                cam.push([u as f64, v as f64]);
                proj.push([m[0] as f64, m[1] as f64]);
            }
        }
    }
    let need = ((2 * r + 1) * (2 * r + 1) / 2) as usize;
    if cam.len() < need.max(8) {
        return None;
    }
    // Decode errors (a wrong bit near a square's edge) are tens of px off: drop whatever lies
    // well beyond the typical residual and refit, twice.
    let mut hm = homography(&cam, &proj);
    for _ in 0..2 {
        let err: Vec<f64> = (0..cam.len())
            .map(|i| transfer(&hm, cam[i]).map_or(f64::INFINITY, |p| dist(p, proj[i])))
            .collect();
        let mut sorted = err.clone();
        sorted.sort_by(f64::total_cmp);
        let limit = (3.0 * sorted[sorted.len() / 2]).max(1.0);
        let (c, p): (Vec<_>, Vec<_>) =
            (0..cam.len()).filter(|&i| err[i] < limit).map(|i| (cam[i], proj[i])).unzip();
        if c.len() < need.max(8) {
            return None;
        }
        hm = homography(&c, &p);
    }
    transfer(&hm, at)
}

/// The board's outline in the camera: its four outermost corners, in order around it.
pub fn outline(corners: &[BoardCorner]) -> [[f64; 2]; 4] {
    let pick = |sx: f64, sy: f64| {
        corners
            .iter()
            .max_by(|a, b| {
                (sx * a.board[0] + sy * a.board[1]).total_cmp(&(sx * b.board[0] + sy * b.board[1]))
            })
            .map_or([0.0; 2], |c| c.camera)
    };
    [pick(-1.0, -1.0), pick(1.0, -1.0), pick(1.0, 1.0), pick(-1.0, 1.0)]
}

/// Whether a camera pixel lies inside a convex outline.
pub fn inside(quad: &[[f64; 2]; 4], p: [f64; 2]) -> bool {
    let side = |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let s: Vec<f64> = (0..4).map(|i| side(quad[i], quad[(i + 1) % 4])).collect();
    s.iter().all(|&v| v >= 0.0) || s.iter().all(|&v| v <= 0.0)
}

fn transfer(h: &Matrix3<f64>, p: [f64; 2]) -> Option<[f64; 2]> {
    let y = h * Vector3::new(p[0], p[1], 1.0);
    (y.z.abs() > 1e-12).then(|| [y.x / y.z, y.y / y.z])
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// One pose of the board: its corners in the camera, and where each projector saw them
/// (`projectors[k][j]` for corner `j`; `None` where projector `k` did not decode around it).
#[derive(Clone, Debug)]
pub struct BoardPose {
    pub corners: Vec<BoardCorner>,
    pub projectors: Vec<Vec<Option<[f64; 2]>>>,
}

impl BoardPose {
    /// Carries every corner into every projector through its decoded map (camera-sized,
    /// row-major). The window grows with the camera: 1/160 of its width each side, at least 5 px.
    pub fn new(corners: Vec<BoardCorner>, maps: &[&[[f32; 2]]], camera_width: u32) -> Self {
        let half = ((camera_width as f64 / 160.0).ceil() as usize).max(5);
        let projectors = maps
            .iter()
            .map(|m| corners.iter().map(|c| projector_corner(m, camera_width, c.camera, half)).collect())
            .collect();
        Self { corners, projectors }
    }
}

/// The camera and projectors from a board calibration, with how well they are determined.
#[derive(Clone, Debug)]
pub struct BoardCalibration {
    pub camera: CameraIntrinsics,
    /// Standard deviations of fx, fy, cx, cy (px), k1, k2; zero when the camera was given.
    pub camera_std: [f64; 6],
    pub projectors: Vec<ProjectorGeometry>,
    pub conditioning: Vec<Conditioning>,
    /// RMS reprojection error of the corners in the camera (px).
    pub camera_rms_px: f64,
    /// Per projector: RMS reprojection error of its corners (projector px), and how many.
    pub projector_rms_px: Vec<f64>,
    pub projector_corners: Vec<usize>,
    /// Board-to-camera pose of every pose: `X_c = R X_b + t` (mm).
    pub poses: Vec<(Matrix3<f64>, Vector3<f64>)>,
}

/// Least corners a projector must carry in every pose.
const MIN_CORNERS: usize = 6;

/// Calibrates the camera (unless `camera` is given, then it is held fixed) and every projector
/// from two or more board poses.
pub fn calibrate(
    poses: &[BoardPose],
    camera_size: (u32, u32),
    projector_sizes: &[(u32, u32)],
    camera: Option<&CameraIntrinsics>,
) -> Result<BoardCalibration, BoardError> {
    if poses.len() < 2 {
        return Err(BoardError::TooFewPoses(poses.len()));
    }
    for (i, p) in poses.iter().enumerate() {
        for (k, seen) in p.projectors.iter().enumerate() {
            let n = seen.iter().flatten().count();
            if n < MIN_CORNERS {
                return Err(BoardError::TooFewCorners { pose: i, projector: k, seen: n, need: MIN_CORNERS });
            }
        }
    }
    let degenerate = |what: &str| BoardError::Degenerate { what: what.into() };
    // The camera: given, or Zhang's closed form on the board-to-camera homographies.
    let cam0 = match camera {
        Some(c) => c.clone(),
        None => {
            let hs: Vec<Matrix3<f64>> = poses
                .iter()
                .map(|p| {
                    let (b, c): (Vec<_>, Vec<_>) = p.corners.iter().map(|c| (c.board, c.camera)).unzip();
                    homography(&b, &c)
                })
                .collect();
            let (f, cx, cy) =
                zhang(&hs, camera_size).ok_or_else(|| degenerate("the camera's focal length"))?;
            CameraIntrinsics::pinhole(camera_size.0, camera_size.1, f, f, cx, cy)
        }
    };
    // Board poses from the camera: the homography of undistorted normalised coordinates.
    let board_poses: Vec<(Matrix3<f64>, Vector3<f64>)> = poses
        .iter()
        .map(|p| {
            let (b, n): (Vec<_>, Vec<_>) =
                p.corners.iter().map(|c| (c.board, cam0.undistort(c.camera[0], c.camera[1]))).unzip();
            pose_from_homography(&Matrix3::identity(), &homography(&b, &n))
        })
        .collect::<Option<_>>()
        .ok_or_else(|| degenerate("the board's poses"))?;
    // Each projector: Zhang on its board-to-projector homographies, then its pose relative
    // to the camera through the first board pose.
    let mut projectors = Vec::new();
    for (k, &(pw, ph)) in projector_sizes.iter().enumerate() {
        let what = || degenerate(&format!("projector {k}'s intrinsics"));
        let hs: Vec<Matrix3<f64>> = poses
            .iter()
            .map(|p| {
                let (b, q): (Vec<_>, Vec<_>) = p
                    .corners
                    .iter()
                    .zip(&p.projectors[k])
                    .filter_map(|(c, q)| q.map(|q| (c.board, q)))
                    .unzip();
                homography(&b, &q)
            })
            .collect();
        let (f, cx, cy) = zhang(&hs, (pw, ph)).ok_or_else(what)?;
        let kp = Matrix3::new(f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0);
        let (rp, tp) = pose_from_homography(&kp, &hs[0]).ok_or_else(what)?;
        let (rc, tc) = board_poses[0];
        let rotation = rp * rc.transpose();
        projectors.push(ProjectorGeometry {
            width: pw,
            height: ph,
            f,
            cx,
            cy,
            rotation,
            translation: tp - rotation * tc,
        });
    }
    let start = State { camera: cam0, projectors, poses: board_poses };
    let problem = Problem { poses, free_camera: camera.is_none() };
    let (state, jtj, ssr, m) = problem.adjust(start);
    let n = problem.parameters(&state);
    let sigma2 = ssr / (m.saturating_sub(n)).max(1) as f64;
    let cov = jtj.clone().cholesky().map(|c| c.inverse());
    let std = |i: usize| {
        cov.as_ref().map_or(f64::INFINITY, |c| {
            let v = c[(i, i)] * sigma2;
            if v.is_finite() && v >= 0.0 { v.sqrt() } else { f64::INFINITY }
        })
    };
    let cam_n = problem.camera_parameters();
    let camera_std = std::array::from_fn(|i| if cam_n > 0 { std(i) } else { 0.0 });
    let conditioning: Vec<Conditioning> = (0..state.projectors.len())
        .map(|k| {
            let o = cam_n + k * NP;
            Conditioning {
                projector: k as u32,
                f_std_px: std(o),
                cx_std_px: std(o + 1),
                cy_std_px: std(o + 2),
                cx_std_data_only_px: std(o + 1),
                // Not measured: the board's known shape, not the scene's depth, does the work.
                homography_fraction: f64::NAN,
                rotation_std_deg: (3..6).map(|i| std(o + i).powi(2)).sum::<f64>().sqrt().to_degrees(),
                translation_std: (6..9).map(|i| std(o + i).powi(2)).sum::<f64>().sqrt(),
            }
        })
        .collect();
    let (camera_rms_px, projector_rms_px, projector_corners) = problem.rms(&state);
    for (k, c) in conditioning.iter().enumerate() {
        let g: &ProjectorGeometry = &state.projectors[k];
        if !(c.f_std_px < 0.01 * g.f
            && c.cy_std_px < 0.05 * g.height as f64
            && c.cx_std_px < 0.05 * g.width as f64)
        {
            return Err(degenerate(&format!(
                "projector {k} (f {:.1} +- {:.1}, cx {:.1} +- {:.1}, cy {:.1} +- {:.1} px)",
                g.f, c.f_std_px, g.cx, c.cx_std_px, g.cy, c.cy_std_px
            )));
        }
    }
    Ok(BoardCalibration {
        camera: state.camera,
        camera_std,
        projectors: state.projectors,
        conditioning,
        camera_rms_px,
        projector_rms_px,
        projector_corners,
        poses: state.poses,
    })
}

/// Zhang's closed form with square pixels and no skew: `B = K^-T K^-1` has four unknowns up
/// to scale, each homography gives two equations. Returns `(f, cx, cy)`; `None` when the
/// homographies do not determine them. Pixels are normalised by the image size first.
fn zhang(hs: &[Matrix3<f64>], size: (u32, u32)) -> Option<(f64, f64, f64)> {
    let s = size.0.max(size.1) as f64;
    let (ox, oy) = ((size.0 as f64 - 1.0) / 2.0, (size.1 as f64 - 1.0) / 2.0);
    let t = Matrix3::new(1.0 / s, 0.0, -ox / s, 0.0, 1.0 / s, -oy / s, 0.0, 0.0, 1.0);
    let v = |h: &Matrix3<f64>, i: usize, j: usize| {
        let (a, b) = (h.column(i), h.column(j));
        Vector4::new(
            a[0] * b[0] + a[1] * b[1],
            a[0] * b[2] + a[2] * b[0],
            a[1] * b[2] + a[2] * b[1],
            a[2] * b[2],
        )
    };
    let mut ata = Matrix4::<f64>::zeros();
    for h in hs {
        let h = t * h;
        let h = h / h.norm();
        for row in [v(&h, 0, 1), v(&h, 0, 0) - v(&h, 1, 1)] {
            ata += row * row.transpose();
        }
    }
    let eig = SymmetricEigen::new(ata);
    let mut b: Vector4<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into();
    if b[0] < 0.0 {
        b = -b;
    }
    if b[0] <= 1e-12 {
        return None;
    }
    let (cx, cy) = (-b[1] / b[0], -b[2] / b[0]);
    let f2 = b[3] / b[0] - cx * cx - cy * cy;
    (f2 > 0.0).then(|| (f2.sqrt() * s, cx * s + ox, cy * s + oy))
}

/// Board-to-device pose from the board-to-pixel homography and the intrinsics, board in front.
fn pose_from_homography(k: &Matrix3<f64>, h: &Matrix3<f64>) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let m = k.try_inverse()? * h;
    let norm = m.column(0).norm();
    if norm < 1e-15 {
        return None;
    }
    let sign = if m[(2, 2)] < 0.0 { -1.0 } else { 1.0 };
    let m = m * (sign / norm);
    let (r1, r2): (Vector3<f64>, Vector3<f64>) = (m.column(0).into(), m.column(1).into());
    let approx = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = approx.svd(true, true);
    let mut r = svd.u? * svd.v_t?;
    if r.determinant() < 0.0 {
        r = -r;
    }
    Some((r, m.column(2).into()))
}

/// Parameters per projector: f, cx, cy, rotation increment (3), translation (3).
const NP: usize = 9;
/// Parameters of a free camera: fx, fy, cx, cy, k1, k2.
const NC: usize = 6;

#[derive(Clone)]
struct State {
    camera: CameraIntrinsics,
    projectors: Vec<ProjectorGeometry>,
    poses: Vec<(Matrix3<f64>, Vector3<f64>)>,
}

struct Problem<'a> {
    poses: &'a [BoardPose],
    free_camera: bool,
}

impl Problem<'_> {
    fn camera_parameters(&self) -> usize {
        if self.free_camera { NC } else { 0 }
    }

    fn parameters(&self, s: &State) -> usize {
        self.camera_parameters() + NP * s.projectors.len() + 6 * s.poses.len()
    }

    fn step(&self, s: &State, d: &DVector<f64>) -> State {
        let mut out = s.clone();
        let mut o = 0;
        if self.free_camera {
            let c = &mut out.camera;
            c.fx += d[0];
            c.fy += d[1];
            c.cx += d[2];
            c.cy += d[3];
            c.distortion[0] += d[4];
            c.distortion[1] += d[5];
            o = NC;
        }
        for g in &mut out.projectors {
            g.f += d[o];
            g.cx += d[o + 1];
            g.cy += d[o + 2];
            g.rotation = Rotation3::new(Vector3::new(d[o + 3], d[o + 4], d[o + 5])).matrix() * g.rotation;
            g.translation += Vector3::new(d[o + 6], d[o + 7], d[o + 8]);
            o += NP;
        }
        for (r, t) in &mut out.poses {
            *r = Rotation3::new(Vector3::new(d[o], d[o + 1], d[o + 2])).matrix() * *r;
            *t += Vector3::new(d[o + 3], d[o + 4], d[o + 5]);
            o += 6;
        }
        out
    }

    /// Every residual (px): per pose, per corner, the camera's then each seeing projector's.
    fn residuals(&self, s: &State) -> Vec<f64> {
        let mut r = Vec::new();
        for (pose, (rot, t)) in self.poses.iter().zip(&s.poses) {
            for (j, c) in pose.corners.iter().enumerate() {
                let x = rot * Vector3::new(c.board[0], c.board[1], 0.0) + t;
                let p = if x.z > 1e-9 { s.camera.distort(x.x / x.z, x.y / x.z) } else { [1e6, 1e6] };
                r.extend([p[0] - c.camera[0], p[1] - c.camera[1]]);
                for (g, seen) in s.projectors.iter().zip(&pose.projectors) {
                    if let Some(q) = seen[j] {
                        let p = g.project(&x).unwrap_or([1e6, 1e6]);
                        r.extend([p[0] - q[0], p[1] - q[1]]);
                    }
                }
            }
        }
        r
    }

    /// Levenberg-Marquardt with a central-difference Jacobian (a few hundred residuals, a few
    /// dozen parameters). Returns the state, `J^T J` at it, the sum of squares and the count
    /// of residuals.
    fn adjust(&self, mut s: State) -> (State, DMatrix<f64>, f64, usize) {
        let n = self.parameters(&s);
        let mut r = DVector::from_vec(self.residuals(&s));
        let mut cost = r.norm_squared();
        let mut lambda = 1e-3;
        for _ in 0..200 {
            let j = self.jacobian(&s, r.len());
            let jtj = j.transpose() * &j;
            let g = j.transpose() * &r;
            let mut accepted = false;
            while lambda < 1e10 {
                let mut a = jtj.clone();
                for i in 0..n {
                    a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
                }
                let Some(delta) = a.cholesky().map(|c| -c.solve(&g)) else {
                    lambda *= 10.0;
                    continue;
                };
                let next = self.step(&s, &delta);
                let rn = DVector::from_vec(self.residuals(&next));
                let cn = rn.norm_squared();
                if rn.len() == r.len() && cn < cost {
                    let gain = (cost - cn) / cost.max(1e-30);
                    s = next;
                    r = rn;
                    cost = cn;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = gain > 1e-12;
                    break;
                }
                lambda *= 4.0;
            }
            if !accepted {
                break;
            }
        }
        let j = self.jacobian(&s, r.len());
        (s, j.transpose() * &j, cost, r.len())
    }

    fn jacobian(&self, s: &State, m: usize) -> DMatrix<f64> {
        let n = self.parameters(s);
        let mut j = DMatrix::zeros(m, n);
        for c in 0..n {
            // Intrinsics in px and distortion need a larger step than rotations (radians).
            let h = if c < self.camera_parameters() && c >= 4 { 1e-6 } else { 1e-5 };
            let mut d = DVector::zeros(n);
            d[c] = h;
            let plus = self.residuals(&self.step(s, &d));
            d[c] = -h;
            let minus = self.residuals(&self.step(s, &d));
            for i in 0..m {
                j[(i, c)] = (plus[i] - minus[i]) / (2.0 * h);
            }
        }
        j
    }

    /// Camera RMS, per projector RMS and corner count.
    fn rms(&self, s: &State) -> (f64, Vec<f64>, Vec<usize>) {
        let (mut cam, mut nc) = (0.0, 0usize);
        let mut proj = vec![(0.0, 0usize); s.projectors.len()];
        for (pose, (rot, t)) in self.poses.iter().zip(&s.poses) {
            for (j, c) in pose.corners.iter().enumerate() {
                let x = rot * Vector3::new(c.board[0], c.board[1], 0.0) + t;
                let p = s.camera.distort(x.x / x.z, x.y / x.z);
                cam += dist(p, c.camera).powi(2);
                nc += 1;
                for (k, (g, seen)) in s.projectors.iter().zip(&pose.projectors).enumerate() {
                    if let (Some(q), Some(p)) = (seen[j], g.project(&x)) {
                        proj[k].0 += dist(p, q).powi(2);
                        proj[k].1 += 1;
                    }
                }
            }
        }
        (
            (cam / nc.max(1) as f64).sqrt(),
            proj.iter().map(|(e, n)| (e / (*n).max(1) as f64).sqrt()).collect(),
            proj.iter().map(|p| p.1).collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn gauss(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
        sigma * crate::stage_sim::normal(rng)
    }

    const BOARD: Board = Board { cols: 9, rows: 7, square_mm: 25.0 };

    fn camera() -> CameraIntrinsics {
        CameraIntrinsics {
            distortion: [-0.12, 0.08, 0.0, 0.0, 0.0],
            ..CameraIntrinsics::pinhole(1280, 1024, 1500.0, 1497.0, 652.0, 500.0)
        }
    }

    fn projector() -> ProjectorGeometry {
        ProjectorGeometry {
            width: 1024,
            height: 768,
            f: 1800.0,
            cx: 511.5,
            cy: 740.0,
            rotation: *Rotation3::from_euler_angles(0.02, -0.15, 0.01).matrix(),
            translation: Vector3::new(160.0, -30.0, 20.0),
        }
    }

    /// Board poses about 700 mm away, tilted differently.
    fn poses() -> Vec<(Matrix3<f64>, Vector3<f64>)> {
        [(0.05, 0.3, 0.02, -80.0), (-0.35, -0.05, 0.1, -120.0), (0.2, -0.25, -0.05, -60.0)]
            .iter()
            .map(|&(a, b, c, x)| {
                (*Rotation3::from_euler_angles(a, b, c).matrix(), Vector3::new(x, -60.0, 700.0))
            })
            .collect()
    }

    fn observe(
        cam: &CameraIntrinsics,
        g: &ProjectorGeometry,
        pose: &(Matrix3<f64>, Vector3<f64>),
        noise: f64,
        rng: &mut ChaCha8Rng,
    ) -> BoardPose {
        let mut corners = Vec::new();
        let mut seen = Vec::new();
        for v in 0..BOARD.rows {
            for u in 0..BOARD.cols {
                let b = [u as f64 * BOARD.square_mm, v as f64 * BOARD.square_mm];
                let x = pose.0 * Vector3::new(b[0], b[1], 0.0) + pose.1;
                let c = cam.distort(x.x / x.z, x.y / x.z);
                corners.push(BoardCorner {
                    board: b,
                    camera: [c[0] + gauss(rng, noise), c[1] + gauss(rng, noise)],
                });
                seen.push(g.project(&x).map(|p| [p[0] + gauss(rng, noise), p[1] + gauss(rng, noise)]));
            }
        }
        BoardPose { corners, projectors: vec![seen] }
    }

    #[test]
    fn two_board_poses_determine_camera_and_projector() {
        let (cam, g) = (camera(), projector());
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let obs: Vec<BoardPose> = poses()[..2].iter().map(|p| observe(&cam, &g, p, 0.1, &mut rng)).collect();
        let cal = calibrate(&obs, (1280, 1024), &[(1024, 768)], None).unwrap();
        let p = &cal.projectors[0];
        let c = &cal.conditioning[0];
        assert!(
            (p.f - g.f).abs() < 3.0 * c.f_std_px.max(1.0) && (p.f - g.f).abs() / g.f < 0.01,
            "f {} +- {}",
            p.f,
            c.f_std_px
        );
        assert!((p.cy - g.cy).abs() < 3.0 * c.cy_std_px.max(2.0), "cy {} +- {}", p.cy, c.cy_std_px);
        assert!((p.centre() - g.centre()).norm() < 5.0, "centre {} vs {}", p.centre(), g.centre());
        assert!((cal.camera.fx - cam.fx).abs() / cam.fx < 0.01, "camera f {}", cal.camera.fx);
        assert!(
            cal.camera_rms_px < 0.2 && cal.projector_rms_px[0] < 0.2,
            "{} {:?}",
            cal.camera_rms_px,
            cal.projector_rms_px
        );
        // A third pose tightens the projector's focal length.
        let obs3: Vec<BoardPose> = poses().iter().map(|p| observe(&cam, &g, p, 0.1, &mut rng)).collect();
        let cal3 = calibrate(&obs3, (1280, 1024), &[(1024, 768)], Some(&cam)).unwrap();
        assert!(
            cal3.conditioning[0].f_std_px < c.f_std_px,
            "{} vs {}",
            cal3.conditioning[0].f_std_px,
            c.f_std_px
        );
        assert!((cal3.projectors[0].f - g.f).abs() / g.f < 0.005);
        assert_eq!(cal3.camera_std, [0.0; 6]);
    }

    #[test]
    fn one_pose_or_parallel_poses_are_refused() {
        let (cam, g) = (camera(), projector());
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let one = vec![observe(&cam, &g, &poses()[0], 0.1, &mut rng)];
        assert!(matches!(
            calibrate(&one, (1280, 1024), &[(1024, 768)], None),
            Err(BoardError::TooFewPoses(1))
        ));
        // The same tilt twice, only moved sideways: no new constraint on the intrinsics.
        let p = poses()[0];
        let shifted = (p.0, p.1 + Vector3::new(40.0, 10.0, 0.0));
        let twins = vec![observe(&cam, &g, &p, 0.1, &mut rng), observe(&cam, &g, &shifted, 0.1, &mut rng)];
        let err = calibrate(&twins, (1280, 1024), &[(1024, 768)], None).unwrap_err();
        assert!(matches!(err, BoardError::Degenerate { .. }), "{err}");
        // A projector that carries almost no corners is named.
        let mut blind = vec![
            observe(&cam, &g, &poses()[0], 0.1, &mut rng),
            observe(&cam, &g, &poses()[1], 0.1, &mut rng),
        ];
        for q in blind[1].projectors[0].iter_mut().skip(4) {
            *q = None;
        }
        let err = calibrate(&blind, (1280, 1024), &[(1024, 768)], None).unwrap_err().to_string();
        assert!(err.contains("pose 1: projector 0 carries 4"), "{err}");
    }

    /// A chessboard rendered through a homography (16x supersampled), inner corners returned.
    fn render(h: &Matrix3<f64>, w: u32, ht: u32) -> Vec<f32> {
        let hinv = h.try_inverse().unwrap();
        let s = BOARD.square_mm;
        let mut img = vec![0.0f32; (w * ht) as usize];
        for v in 0..ht {
            for u in 0..w {
                let mut acc = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let p = hinv
                            * Vector3::new(
                                u as f64 - 0.375 + 0.25 * sx as f64,
                                v as f64 - 0.375 + 0.25 * sy as f64,
                                1.0,
                            );
                        let (bx, by) = (p.x / p.z / s + 1.0, p.y / p.z / s + 1.0);
                        let inside = (0.0..(BOARD.cols + 1) as f64).contains(&bx)
                            && (0.0..(BOARD.rows + 1) as f64).contains(&by);
                        let dark = inside && (bx.floor() as i64 + by.floor() as i64) % 2 == 0;
                        acc += if dark { 0.05 } else { 0.8 };
                    }
                }
                img[(v * w + u) as usize] = acc / 16.0;
            }
        }
        img
    }

    #[test]
    fn corners_are_found_at_pixel_centres_and_carried_into_the_projector() {
        // Board (mm) to camera pixels: a tilted view, corners well inside the frame.
        let h = Matrix3::new(2.2, 0.3, 150.0, -0.2, 2.0, 120.0, 0.0004, 0.0003, 1.0);
        let (w, ht) = (800, 600);
        let grey = render(&h, w, ht);
        let corners = find_corners(&grey, w, ht, &BOARD).unwrap();
        assert_eq!(corners.len(), 63);
        let truth: Vec<[f64; 2]> = (0..BOARD.rows)
            .flat_map(|v| (0..BOARD.cols).map(move |u| [u as f64 * 25.0, v as f64 * 25.0]))
            .map(|b| transfer(&h, b).unwrap())
            .collect();
        let worst = corners
            .iter()
            .map(|c| truth.iter().map(|t| dist(*t, c.camera)).fold(f64::INFINITY, f64::min))
            .fold(0.0, f64::max);
        // cornerSubPix-style refinement: a few hundredths of a pixel on a clean render.
        assert!(worst < 0.08, "worst corner {worst:.3} px from the truth");
        // The labelling is a square grid of the board's pitch, whichever corner it starts at.
        let hb = homography(
            &corners.iter().map(|c| c.board).collect::<Vec<_>>(),
            &corners.iter().map(|c| c.camera).collect::<Vec<_>>(),
        );
        assert!(corners.iter().all(|c| dist(transfer(&hb, c.board).unwrap(), c.camera) < 0.1));
        // Wrong board size or a blank image: named, not guessed.
        let err =
            find_corners(&grey, w, ht, &Board { cols: 8, rows: 7, square_mm: 25.0 }).unwrap_err().to_string();
        assert!(err.contains("8x7"), "{err}");
        assert!(find_corners(&vec![0.5; (w * ht) as usize], w, ht, &BOARD).is_err());

        // A projector whose columns and rows are a homography of the camera pixels: the local
        // homography recovers where it saw a corner, even with a few decode errors around it.
        let hp = Matrix3::new(1.1, 0.05, 30.0, -0.02, 1.05, 12.0, 0.0001, -0.00005, 1.0);
        let mut map: Vec<[f32; 2]> = (0..w * ht)
            .map(|i| {
                let p = transfer(&hp, [(i % w) as f64, (i / w) as f64]).unwrap();
                [p[0] as f32, p[1] as f32]
            })
            .collect();
        let at = [400.37, 300.81];
        for i in [299 * w + 398, 302 * w + 401, 301 * w + 395] {
            map[i as usize][0] += 37.0;
        }
        let p = projector_corner(&map, w, at, 5).unwrap();
        assert!(dist(p, transfer(&hp, at).unwrap()) < 0.01, "{p:?}");
        let holes: Vec<[f32; 2]> =
            map.iter().enumerate().map(|(i, m)| if i % 3 == 0 { *m } else { [f32::NAN; 2] }).collect();
        assert!(projector_corner(&holes, w, at, 5).is_none());
    }
}
