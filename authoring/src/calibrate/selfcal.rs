//! Projector self-calibration from camera-to-projector correspondences: focal length,
//! principal point (lens shift) and pose of every projector, with a calibrated camera.
//!
//! Robust initialisation per projector (RANSAC fundamental matrix, then the focal length and
//! vertical principal point that make `K_p^T F K_c` closest to an essential matrix, with the
//! principal point horizontally centred), then one Levenberg-Marquardt bundle adjustment over
//! all projectors jointly: their correspondences share 3D points through the camera, which is
//! what pins down `f, cx, cy` (one calibrated view plus one projector does not). The
//! horizontally centred lens shift stays in as a weak prior; the result reports how well
//! each parameter is determined. Scale is arbitrary (projector 0's baseline is 1) until
//! the one measured length gives the factor ([`scale_for`]).

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, SymmetricEigen, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{CalibrateError, IllPosed, SolverError};
use crate::capture_set::CameraIntrinsics;

/// One projector's correspondences: per camera pixel (row-major) the projector coordinate
/// seen there, NaN where not decoded.
#[derive(Clone, Copy, Debug)]
pub struct ProjectorObservations<'a> {
    pub width: u32,
    pub height: u32,
    pub map: &'a [[f32; 2]],
}

#[derive(Clone, Debug, PartialEq)]
pub struct SelfCalParams {
    /// Camera pixels used in the bundle adjustment (a regular subsample of the decoded ones).
    pub max_points: usize,
    /// Prior on `cx`: centred, with this standard deviation as a fraction of the width.
    pub cx_prior_sigma: f64,
    /// RANSAC threshold (projector px) for the fundamental matrix and the planarity test.
    pub ransac_threshold_px: f64,
    pub ransac_iterations: usize,
    /// Huber threshold (projector px) of the bundle adjustment.
    pub huber_px: f64,
    pub max_iterations: usize,
    /// A projector is planar (ill-posed) when a homography explains this fraction of its inliers.
    pub planar_fraction: f64,
    pub seed: u64,
}

impl Default for SelfCalParams {
    fn default() -> Self {
        Self {
            max_points: 6000,
            cx_prior_sigma: 0.02,
            ransac_threshold_px: 1.5,
            ransac_iterations: 400,
            huber_px: 1.0,
            max_iterations: 100,
            planar_fraction: 0.9,
            seed: 7,
        }
    }
}

/// A projector's calibrated geometry: `X_p = rotation * X_c + translation`.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectorGeometry {
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl ProjectorGeometry {
    /// Projects a camera-frame point; `None` behind the projector.
    pub fn project(&self, x: &Vector3<f64>) -> Option<[f64; 2]> {
        let y = self.rotation * x + self.translation;
        (y.z > 1e-9).then(|| [self.f * y.x / y.z + self.cx, self.f * y.y / y.z + self.cy])
    }

    /// Centre of projection in the camera frame.
    pub fn centre(&self) -> Vector3<f64> {
        -self.rotation.transpose() * self.translation
    }

    /// The rotation as rows, as the stage model and `rig.json` store it.
    pub fn rotation_rows(&self) -> [[f64; 3]; 3] {
        std::array::from_fn(|r| std::array::from_fn(|c| self.rotation[(r, c)]))
    }
}

/// A stage model's projector as the solver sees it (the inverse of what `build_model` stores).
impl From<&crate::stage_model::ProjectorModel> for ProjectorGeometry {
    fn from(p: &crate::stage_model::ProjectorModel) -> Self {
        Self {
            width: p.width,
            height: p.height,
            f: p.f,
            cx: p.cx,
            cy: p.cy,
            rotation: Matrix3::from_fn(|r, c| p.rotation[r][c]),
            translation: Vector3::from(p.translation),
        }
    }
}

/// How well the solution is determined, per projector (standard deviations from the
/// Gauss-Newton covariance at the optimum, gauge fixed by the scale).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Conditioning {
    pub projector: u32,
    #[serde(deserialize_with = "super::nan_if_null")]
    pub f_std_px: f64,
    #[serde(deserialize_with = "super::nan_if_null")]
    pub cx_std_px: f64,
    #[serde(deserialize_with = "super::nan_if_null")]
    pub cy_std_px: f64,
    /// `cx`'s standard deviation from the data alone, without the centred prior (infinite when
    /// the data cannot determine it).
    #[serde(deserialize_with = "super::nan_if_null")]
    pub cx_std_data_only_px: f64,
    /// Fraction of this projector's inliers a single homography explains (1 = planar scene).
    #[serde(deserialize_with = "super::nan_if_null")]
    pub homography_fraction: f64,
    /// The pose's standard deviations: rotation (degrees, root sum of the three axes) and
    /// translation (root sum of the three components, in the model's units; the scale's own
    /// error not included). Absent in older reports.
    #[serde(default, deserialize_with = "super::nan_if_null")]
    pub rotation_std_deg: f64,
    #[serde(default, deserialize_with = "super::nan_if_null")]
    pub translation_std: f64,
}

#[derive(Clone, Debug)]
pub struct SelfCalResult {
    pub projectors: Vec<ProjectorGeometry>,
    /// RMS reprojection error (projector px) over inlier observations of the adjustment.
    pub rms_px: f64,
    pub observations: usize,
    pub inliers: usize,
    pub iterations: usize,
    pub conditioning: Vec<Conditioning>,
    /// Per projector: RMS reprojection error (projector px) of its inlier observations.
    pub per_projector_rms_px: Vec<f64>,
    pub warnings: Vec<String>,
}

/// Unit-depth camera ray through a pixel: `X = z * ray` (lens distortion removed).
pub fn camera_ray(cam: &CameraIntrinsics, u: f64, v: f64) -> Vector3<f64> {
    let [x, y] = cam.undistort(u, v);
    Vector3::new(x, y, 1.0)
}

/// The ideal pinhole pixel of a camera ray (what the two-view geometry is fitted on).
fn pinhole_pixel(cam: &CameraIntrinsics, ray: &Vector3<f64>) -> [f64; 2] {
    [ray.x / ray.z * cam.fx + cam.cx, ray.y / ray.z * cam.fy + cam.cy]
}

/// Unit-depth ray of an ideal pinhole pixel (the inverse of [`pinhole_pixel`]).
fn pinhole_ray(cam: &CameraIntrinsics, p: [f64; 2]) -> Vector3<f64> {
    Vector3::new((p[0] - cam.cx) / cam.fx, (p[1] - cam.cy) / cam.fy, 1.0)
}

fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

fn kp(f: f64, cx: f64, cy: f64) -> Matrix3<f64> {
    Matrix3::new(f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0)
}

fn kc(c: &CameraIntrinsics) -> Matrix3<f64> {
    Matrix3::new(c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0)
}

/// Hartley normalisation: translate to the centroid, scale to mean distance sqrt(2).
fn normaliser(pts: &[[f64; 2]]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p[0] / n, a.1 + p[1] / n));
    let d = pts.iter().map(|p| (p[0] - mx).hypot(p[1] - my)).sum::<f64>() / n;
    let s = if d > 1e-12 { std::f64::consts::SQRT_2 / d } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

fn apply(t: &Matrix3<f64>, p: [f64; 2]) -> [f64; 2] {
    [t[(0, 0)] * p[0] + t[(0, 2)], t[(1, 1)] * p[1] + t[(1, 2)]]
}

/// Null vector of the 9-column system with rows `rows` (smallest eigenvector of A^T A).
fn null_vector9(rows: impl Iterator<Item = [f64; 9]>) -> [f64; 9] {
    let mut ata = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    for r in rows {
        let v = nalgebra::SVector::<f64, 9>::from(r);
        ata += v * v.transpose();
    }
    let eig = SymmetricEigen::new(ata);
    let k = eig.eigenvalues.imin();
    let mut out = [0.0; 9];
    for (i, o) in out.iter_mut().enumerate() {
        *o = eig.eigenvectors[(i, k)];
    }
    out
}

/// Fundamental matrix with `x_p^T F x_c = 0` from at least 8 pairs (normalised 8-point, rank 2).
fn fundamental(cam: &[[f64; 2]], proj: &[[f64; 2]]) -> Matrix3<f64> {
    let (t1, t2) = (normaliser(cam), normaliser(proj));
    let f = null_vector9(cam.iter().zip(proj).map(|(a, b)| {
        let (a, b) = (apply(&t1, *a), apply(&t2, *b));
        [b[0] * a[0], b[0] * a[1], b[0], b[1] * a[0], b[1] * a[1], b[1], a[0], a[1], 1.0]
    }));
    let f = Matrix3::from_row_slice(&f);
    let svd = f.svd(true, true);
    let (u, v_t) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let mut s = svd.singular_values;
    s[2] = 0.0;
    let f = u * Matrix3::from_diagonal(&s) * v_t;
    t2.transpose() * f * t1
}

/// Sampson distance (px) of a pair to a fundamental matrix.
fn sampson(f: &Matrix3<f64>, c: [f64; 2], p: [f64; 2]) -> f64 {
    let (x1, x2) = (Vector3::new(c[0], c[1], 1.0), Vector3::new(p[0], p[1], 1.0));
    let fx1 = f * x1;
    let ftx2 = f.transpose() * x2;
    let e = x2.dot(&fx1);
    let d = fx1.x * fx1.x + fx1.y * fx1.y + ftx2.x * ftx2.x + ftx2.y * ftx2.y;
    (e * e / d.max(1e-30)).sqrt()
}

/// Homography `x_p ~ H x_c` from at least 4 pairs (normalised DLT).
pub(crate) fn homography(cam: &[[f64; 2]], proj: &[[f64; 2]]) -> Matrix3<f64> {
    let (t1, t2) = (normaliser(cam), normaliser(proj));
    let rows = cam.iter().zip(proj).flat_map(|(a, b)| {
        let (a, b) = (apply(&t1, *a), apply(&t2, *b));
        [
            [a[0], a[1], 1.0, 0.0, 0.0, 0.0, -b[0] * a[0], -b[0] * a[1], -b[0]],
            [0.0, 0.0, 0.0, a[0], a[1], 1.0, -b[1] * a[0], -b[1] * a[1], -b[1]],
        ]
    });
    let h = Matrix3::from_row_slice(&null_vector9(rows));
    t2.try_inverse().unwrap_or_else(Matrix3::identity) * h * t1
}

fn transfer(h: &Matrix3<f64>, c: [f64; 2], p: [f64; 2]) -> f64 {
    let y = h * Vector3::new(c[0], c[1], 1.0);
    if y.z.abs() < 1e-12 {
        return f64::INFINITY;
    }
    (y.x / y.z - p[0]).hypot(y.y / y.z - p[1])
}

/// Fits a two-view model to point pairs.
type Fit = dyn Fn(&[[f64; 2]], &[[f64; 2]]) -> Matrix3<f64>;
/// Error (px) of one pair under a model.
type PairError = dyn Fn(&Matrix3<f64>, [f64; 2], [f64; 2]) -> f64;

/// A RANSAC problem: minimal sample size, model fit and error, inlier threshold.
struct Ransac<'a> {
    k: usize,
    fit: &'a Fit,
    err: &'a PairError,
    threshold: f64,
    iterations: usize,
}

/// RANSAC over minimal samples; returns the best model refitted on its inliers, and the
/// inlier mask.
fn ransac(
    cam: &[[f64; 2]],
    proj: &[[f64; 2]],
    problem: &Ransac,
    rng: &mut ChaCha8Rng,
) -> (Matrix3<f64>, Vec<bool>) {
    let Ransac { k, fit, err, threshold, iterations } = *problem;
    let n = cam.len();
    let mut best: (usize, Matrix3<f64>) = (0, Matrix3::identity());
    let mut idx = vec![0usize; k];
    for _ in 0..iterations {
        for i in idx.iter_mut() {
            *i = rng.gen_range(0..n);
        }
        let (c, p): (Vec<_>, Vec<_>) = idx.iter().map(|&i| (cam[i], proj[i])).unzip();
        let m = fit(&c, &p);
        let count = (0..n).filter(|&i| err(&m, cam[i], proj[i]) < threshold).count();
        if count > best.0 {
            best = (count, m);
        }
    }
    let mut mask: Vec<bool> = (0..n).map(|i| err(&best.1, cam[i], proj[i]) < threshold).collect();
    let (c, p): (Vec<_>, Vec<_>) = (0..n).filter(|&i| mask[i]).map(|i| (cam[i], proj[i])).unzip();
    if c.len() >= k {
        let refit = fit(&c, &p);
        let refit_mask: Vec<bool> = (0..n).map(|i| err(&refit, cam[i], proj[i]) < threshold).collect();
        if refit_mask.iter().filter(|&&m| m).count() >= c.len() {
            return (refit, refit_mask);
        }
        mask = (0..n).map(|i| err(&best.1, cam[i], proj[i]) < threshold).collect();
    }
    (best.1, mask)
}

/// Depth along the camera ray `ray` that best explains projector-normalised point `xp`.
fn depth_from(r: &Matrix3<f64>, t: &Vector3<f64>, ray: &Vector3<f64>, xp: &Vector3<f64>) -> f64 {
    let a = xp.cross(&(r * ray));
    let b = xp.cross(t);
    -a.dot(&b) / a.dot(&a).max(1e-30)
}

struct Sample {
    ray: Vector3<f64>,
    /// (projector, observed projector pixel)
    obs: Vec<(usize, [f64; 2])>,
}

/// Initial geometry of one projector from its correspondences (cx centred, unit baseline).
fn initialise(
    cam: &CameraIntrinsics,
    width: u32,
    height: u32,
    cpx: &[[f64; 2]],
    ppx: &[[f64; 2]],
    inliers: &[bool],
    f_mat: &Matrix3<f64>,
) -> Option<ProjectorGeometry> {
    let (w, h) = (width as f64, height as f64);
    let cx = (w - 1.0) / 2.0;
    let kcam = kc(cam);
    let score = |f: f64, cy: f64| {
        let e = kp(f, cx, cy).transpose() * f_mat * kcam;
        let s = e.singular_values();
        let mut s: Vec<f64> = s.iter().copied().collect();
        s.sort_by(|a, b| b.total_cmp(a));
        (s[0] - s[1]) / (s[0] + s[1]).max(1e-30)
    };
    // Coarse grid (log-spaced focal lengths, lens shift from -0.5h to 2h), then refinement.
    let mut best = (f64::INFINITY, w, h / 2.0);
    for i in 0..90 {
        let f = w * 0.3 * (20.0f64).powf(i as f64 / 89.0);
        for j in 0..=100 {
            let cy = -0.5 * h + 2.5 * h * j as f64 / 100.0;
            let s = score(f, cy);
            if s < best.0 {
                best = (s, f, cy);
            }
        }
    }
    let (mut df, mut dcy) = (best.1 * 0.04, h * 0.025);
    for _ in 0..40 {
        let mut improved = false;
        for (a, b) in [(df, 0.0), (-df, 0.0), (0.0, dcy), (0.0, -dcy)] {
            let s = score(best.1 + a, best.2 + b);
            if s < best.0 {
                best = (s, best.1 + a, best.2 + b);
                improved = true;
            }
        }
        if !improved {
            df *= 0.5;
            dcy *= 0.5;
        }
    }
    let (f, cy) = (best.1, best.2);
    let kpm = kp(f, cx, cy);
    let e = kpm.transpose() * f_mat * kcam;
    let svd = e.svd(true, true);
    let (mut u, mut v_t) = (svd.u?, svd.v_t?);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if v_t.determinant() < 0.0 {
        v_t = -v_t;
    }
    let wm = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let kinv = kpm.try_inverse()?;
    let t0: Vector3<f64> = u.column(2).into();
    let mut choice: Option<(usize, Matrix3<f64>, Vector3<f64>)> = None;
    for r in [u * wm * v_t, u * wm.transpose() * v_t] {
        for t in [t0, -t0] {
            let good = (0..cpx.len())
                .filter(|&i| inliers[i])
                .step_by(7)
                .filter(|&i| {
                    let ray = pinhole_ray(cam, cpx[i]);
                    let xp = kinv * Vector3::new(ppx[i][0], ppx[i][1], 1.0);
                    let z = depth_from(&r, &t, &ray, &xp);
                    z > 0.0 && (r * (ray * z) + t).z > 0.0
                })
                .count();
            if choice.as_ref().is_none_or(|c| good > c.0) {
                choice = Some((good, r, t));
            }
        }
    }
    let (_, rotation, translation) = choice?;
    Some(ProjectorGeometry { width, height, f, cx, cy, rotation, translation: translation.normalize() })
}

const NP: usize = 9;

/// Residual (2), Jacobian w.r.t. the projector's parameters (2 x 9) and w.r.t. depth (2).
type Linearised = ([f64; 2], [[f64; NP]; 2], [f64; 2]);

/// Residual of one observation and its Jacobians (w.r.t. the projector's 9 parameters and
/// the point's depth).
fn residual(g: &ProjectorGeometry, ray: &Vector3<f64>, z: f64, obs: [f64; 2]) -> Option<Linearised> {
    let x = ray * z;
    let a = g.rotation * x;
    let y = a + g.translation;
    if y.z <= 1e-9 {
        return None;
    }
    let (iz, f) = (1.0 / y.z, g.f);
    let r = [f * y.x * iz + g.cx - obs[0], f * y.y * iz + g.cy - obs[1]];
    let dy = [[f * iz, 0.0, -f * y.x * iz * iz], [0.0, f * iz, -f * y.y * iz * iz]];
    let dw = -skew(&a);
    let dz = g.rotation * ray;
    let mut jc = [[0.0; NP]; 2];
    let mut jz = [0.0; 2];
    for k in 0..2 {
        jc[k][0] = if k == 0 { y.x * iz } else { y.y * iz };
        jc[k][1] = if k == 0 { 1.0 } else { 0.0 };
        jc[k][2] = if k == 0 { 0.0 } else { 1.0 };
        for c in 0..3 {
            let mut s = 0.0;
            for m in 0..3 {
                s += dy[k][m] * dw[(m, c)];
            }
            jc[k][3 + c] = s;
            jc[k][6 + c] = dy[k][c];
        }
        jz[k] = dy[k][0] * dz.x + dy[k][1] * dz.y + dy[k][2] * dz.z;
    }
    Some((r, jc, jz))
}

fn huber_weight(norm: f64, delta: f64) -> f64 {
    if norm <= delta { 1.0 } else { delta / norm }
}

fn huber_cost(norm: f64, delta: f64) -> f64 {
    if norm <= delta { 0.5 * norm * norm } else { delta * (norm - 0.5 * delta) }
}

struct Problem<'a> {
    samples: &'a [Sample],
    cx_prior: Vec<(f64, f64)>,
    huber: f64,
}

impl Problem<'_> {
    fn cost(&self, geo: &[ProjectorGeometry], z: &[f64]) -> f64 {
        let mut c = 0.0;
        for (s, &zi) in self.samples.iter().zip(z) {
            for &(k, o) in &s.obs {
                match residual(&geo[k], &s.ray, zi, o) {
                    Some((r, _, _)) => c += huber_cost(r[0].hypot(r[1]), self.huber),
                    None => c += 1e6,
                }
            }
        }
        for (g, &(mean, sigma)) in geo.iter().zip(&self.cx_prior) {
            c += 0.5 * ((g.cx - mean) / sigma).powi(2);
        }
        c + 0.5 * (GAUGE * (geo[0].translation.norm() - 1.0)).powi(2)
    }

    /// Reduced (camera-block) normal equations after eliminating the depths.
    /// Returns (S, rhs, per-point data for back-substitution).
    fn normal_equations(
        &self,
        geo: &[ProjectorGeometry],
        z: &[f64],
        lambda: f64,
        with_prior: bool,
    ) -> (DMatrix<f64>, DVector<f64>, Vec<PointBlock>) {
        let n = geo.len() * NP;
        let mut s = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        let mut per_point = Vec::with_capacity(self.samples.len());
        for (smp, &zi) in self.samples.iter().zip(z) {
            let mut v = 0.0;
            let mut gz = 0.0;
            let mut ws: Vec<(usize, [f64; NP])> = Vec::with_capacity(smp.obs.len());
            for &(k, o) in &smp.obs {
                let Some((r, jc, jz)) = residual(&geo[k], &smp.ray, zi, o) else { continue };
                let w = huber_weight(r[0].hypot(r[1]), self.huber);
                let mut wk = [0.0; NP];
                for row in 0..2 {
                    v += w * jz[row] * jz[row];
                    gz += w * jz[row] * r[row];
                    for a in 0..NP {
                        wk[a] += w * jc[row][a] * jz[row];
                        g[k * NP + a] += w * jc[row][a] * r[row];
                        for b in 0..NP {
                            s[(k * NP + a, k * NP + b)] += w * jc[row][a] * jc[row][b];
                        }
                    }
                }
                ws.push((k, wk));
            }
            let vd = v * (1.0 + lambda) + 1e-12;
            for (ka, wa) in &ws {
                for a in 0..NP {
                    g[ka * NP + a] -= wa[a] * gz / vd;
                    for (kb, wb) in &ws {
                        for b in 0..NP {
                            s[(ka * NP + a, kb * NP + b)] -= wa[a] * wb[b] / vd;
                        }
                    }
                }
            }
            per_point.push((vd, gz, ws));
        }
        if with_prior {
            for (k, (gk, &(mean, sigma))) in geo.iter().zip(&self.cx_prior).enumerate() {
                s[(k * NP + 1, k * NP + 1)] += 1.0 / (sigma * sigma);
                g[k * NP + 1] += (gk.cx - mean) / (sigma * sigma);
            }
        }
        // Gauge: projector 0's baseline has length 1.
        let t0 = geo[0].translation;
        let jg = t0 / t0.norm() * GAUGE;
        let rg = GAUGE * (t0.norm() - 1.0);
        for a in 0..3 {
            g[6 + a] += jg[a] * rg;
            for b in 0..3 {
                s[(6 + a, 6 + b)] += jg[a] * jg[b];
            }
        }
        (s, g, per_point)
    }
}

const GAUGE: f64 = 1e3;

/// A point's eliminated block: damped `J_z^T J_z`, `J_z^T r`, and per projector `J_c^T J_z`.
type PointBlock = (f64, f64, Vec<(usize, [f64; NP])>);

fn step(geo: &[ProjectorGeometry], delta: &DVector<f64>) -> Vec<ProjectorGeometry> {
    geo.iter()
        .enumerate()
        .map(|(k, g)| {
            let d = |i| delta[k * NP + i];
            let w = Vector3::new(d(3), d(4), d(5));
            ProjectorGeometry {
                f: g.f + d(0),
                cx: g.cx + d(1),
                cy: g.cy + d(2),
                rotation: Rotation3::new(w).matrix() * g.rotation,
                translation: g.translation + Vector3::new(d(6), d(7), d(8)),
                ..g.clone()
            }
        })
        .collect()
}

/// Self-calibrates every projector jointly from dense correspondences, in named stages:
/// subsample the correspondences, initialise each projector from its epipolar geometry
/// (refusing a planar scene), bring all projectors into one scale, adjust everything jointly,
/// then measure how well the data determine each projector.
pub fn self_calibrate(
    cam: &CameraIntrinsics,
    projectors: &[ProjectorObservations],
    params: &SelfCalParams,
) -> Result<SelfCalResult, CalibrateError> {
    self_calibrate_poses(cam, &[projectors], params)
}

/// [`self_calibrate`] over several captures made through one fixed rig (the camera and the
/// projectors not moved, the scene moved or changed between them): every capture's
/// correspondences constrain the same projectors, each capture's points have their own depths.
/// Two poses of a flat board, each planar and ill-posed alone, together determine the rig.
pub fn self_calibrate_poses(
    cam: &CameraIntrinsics,
    poses: &[&[ProjectorObservations]],
    params: &SelfCalParams,
) -> Result<SelfCalResult, CalibrateError> {
    let Some(projectors) = poses.first() else {
        return Err(IllPosed::TooFewCorrespondences { projector: 0, sampled: 0 }.into());
    };
    let per_pose = SelfCalParams { max_points: params.max_points / poses.len(), ..params.clone() };
    let mut samples = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        if pose.len() != projectors.len() {
            return Err(
                SolverError::PoseProjectors { pose: i, got: pose.len(), want: projectors.len() }.into()
            );
        }
        samples.extend(subsample(cam, pose, &per_pose)?);
    }
    let mut warnings = Vec::new();
    let (mut geo, homography_fraction) = initialise_all(cam, projectors, &samples, params, &mut warnings)?;
    common_scale(&mut geo, &samples)?;
    let z = initial_depths(&geo, &samples);
    if projectors.len() == 1 {
        warnings.push(
            "one projector: its horizontal principal point comes from the centred-lens-shift prior, \
             not from the data (a calibrated camera and one projector do not determine f, cx and cy)"
                .into(),
        );
    }
    let problem = Problem {
        samples: &samples,
        cx_prior: geo
            .iter()
            .map(|g| ((g.width as f64 - 1.0) / 2.0, params.cx_prior_sigma * g.width as f64))
            .collect(),
        huber: params.huber_px,
    };
    let (geo, z, iterations) = adjust(&problem, geo, z, params);
    let fit = fit_statistics(&problem, &geo, &z, params);
    let conditioning = conditioning(&problem, &geo, &z, fit.sigma2, &homography_fraction);
    check_conditioning(&geo, &conditioning, &mut warnings)?;
    for (k, (n, s2)) in fit.per_projector.iter().enumerate() {
        tracing::info!(
            "projector {k}: {n} inlier observations, RMS {:.3} px",
            (s2 / (*n).max(1) as f64).sqrt()
        );
    }
    Ok(SelfCalResult {
        projectors: geo,
        rms_px: fit.rms_px,
        observations: fit.observations,
        inliers: fit.inliers,
        iterations,
        conditioning,
        per_projector_rms_px: fit
            .per_projector
            .iter()
            .map(|(n, s2)| (s2 / (*n).max(1) as f64).sqrt())
            .collect(),
        warnings,
    })
}

/// Stage 1: a regular subsample of the decoded camera pixels (every `stride`-th pixel on both
/// axes, about `params.max_points` of them), each with its ray and what every projector saw.
fn subsample(
    cam: &CameraIntrinsics,
    projectors: &[ProjectorObservations],
    params: &SelfCalParams,
) -> Result<Vec<Sample>, CalibrateError> {
    let pixels = cam.width as usize * cam.height as usize;
    for (k, p) in projectors.iter().enumerate() {
        if p.map.len() != pixels {
            return Err(SolverError::MapSize { projector: k, got: p.map.len(), want: pixels }.into());
        }
    }
    let valid = |k: usize, i: usize| {
        let m = projectors[k].map[i];
        m[0].is_finite() && m[1].is_finite()
    };
    let decoded = (0..pixels).filter(|&i| (0..projectors.len()).any(|k| valid(k, i))).count();
    let stride = ((decoded as f64 / params.max_points as f64).sqrt().floor() as usize).max(1);
    let mut samples = Vec::new();
    for v in (stride / 2..cam.height as usize).step_by(stride) {
        for u in (stride / 2..cam.width as usize).step_by(stride) {
            let i = v * cam.width as usize + u;
            let obs: Vec<(usize, [f64; 2])> = (0..projectors.len())
                .filter(|&k| valid(k, i))
                .map(|k| (k, [projectors[k].map[i][0] as f64, projectors[k].map[i][1] as f64]))
                .collect();
            if !obs.is_empty() {
                samples.push(Sample { ray: camera_ray(cam, u as f64, v as f64), obs });
            }
        }
    }
    Ok(samples)
}

/// Stage 2: each projector's initial geometry (unit baseline) from a RANSAC fundamental
/// matrix; refuses a projector that sees too little or a (nearly) planar scene. Returns the
/// geometries and, per projector, the fraction of inliers one homography explains.
fn initialise_all(
    cam: &CameraIntrinsics,
    projectors: &[ProjectorObservations],
    samples: &[Sample],
    params: &SelfCalParams,
    warnings: &mut Vec<String>,
) -> Result<(Vec<ProjectorGeometry>, Vec<f64>), CalibrateError> {
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mut geo = Vec::new();
    let mut homography_fraction = Vec::new();
    for (k, p) in projectors.iter().enumerate() {
        let (cpx, ppx): (Vec<[f64; 2]>, Vec<[f64; 2]>) = samples
            .iter()
            .filter_map(|s| s.obs.iter().find(|o| o.0 == k).map(|o| (pinhole_pixel(cam, &s.ray), o.1)))
            .unzip();
        if cpx.len() < 50 {
            return Err(IllPosed::TooFewCorrespondences { projector: k, sampled: cpx.len() }.into());
        }
        let th = params.ransac_threshold_px;
        let iterations = params.ransac_iterations;
        let f_problem = Ransac { k: 8, fit: &fundamental, err: &sampson, threshold: th, iterations };
        let (f_mat, inl) = ransac(&cpx, &ppx, &f_problem, &mut rng);
        let n_in = inl.iter().filter(|&&m| m).count();
        let h_problem = Ransac { k: 4, fit: &homography, err: &transfer, threshold: th, iterations };
        let (_, hin) = ransac(&cpx, &ppx, &h_problem, &mut rng);
        let h_in = hin.iter().zip(&inl).filter(|(h, f)| **h && **f).count();
        let frac = h_in as f64 / n_in.max(1) as f64;
        homography_fraction.push(frac);
        tracing::info!(
            "projector {k}: {} correspondences, {n_in} fundamental-matrix inliers, homography explains {:.1} %",
            cpx.len(),
            100.0 * frac
        );
        if frac >= params.planar_fraction {
            return Err(IllPosed::Planar { projector: k, percent: 100.0 * frac, threshold_px: th }.into());
        }
        if (n_in as f64) < 0.5 * cpx.len() as f64 {
            warnings.push(format!(
                "projector {k}: only {n_in} of {} correspondences fit one epipolar geometry",
                cpx.len()
            ));
        }
        let g = initialise(cam, p.width, p.height, &cpx, &ppx, &inl, &f_mat)
            .ok_or(SolverError::Decomposition { projector: k })?;
        tracing::debug!("projector {k}: initial f {:.1} cy {:.1}", g.f, g.cy);
        geo.push(g);
    }
    Ok((geo, homography_fraction))
}

/// Depth along a sample's ray of what projector `k` saw there, by its geometry `g`.
fn depth(g: &ProjectorGeometry, s: &Sample, k: usize) -> Option<f64> {
    s.obs.iter().find(|o| o.0 == k).map(|o| {
        let xp = Vector3::new((o.1[0] - g.cx) / g.f, (o.1[1] - g.cy) / g.f, 1.0);
        depth_from(&g.rotation, &g.translation, &s.ray, &xp)
    })
}

/// Stage 3: one scale for all projectors, chaining the depths of shared points from
/// projector 0 outwards.
fn common_scale(geo: &mut [ProjectorGeometry], samples: &[Sample]) -> Result<(), CalibrateError> {
    let mut scaled = vec![false; geo.len()];
    scaled[0] = true;
    for _ in 0..geo.len() {
        for k in 1..geo.len() {
            if scaled[k] {
                continue;
            }
            let mut ratios: Vec<f64> = Vec::new();
            for s in samples {
                let Some(zk) = depth(&geo[k], s, k) else { continue };
                let refs: Vec<f64> =
                    (0..geo.len()).filter(|&j| scaled[j]).filter_map(|j| depth(&geo[j], s, j)).collect();
                if let Some(&zr) = refs.first()
                    && zk > 0.0
                    && zr > 0.0
                {
                    ratios.push(zr / zk);
                }
            }
            if ratios.len() >= 20 {
                let mid = ratios.len() / 2;
                let r = *ratios.select_nth_unstable_by(mid, f64::total_cmp).1;
                geo[k].translation *= r;
                scaled[k] = true;
            }
        }
    }
    match scaled.iter().position(|s| !s) {
        Some(k) => Err(IllPosed::NoCommonScale { projector: k }.into()),
        None => Ok(()),
    }
}

/// Stage 4: each sample's starting depth, the median over the projectors that saw it (1 when
/// none gives a positive depth).
fn initial_depths(geo: &[ProjectorGeometry], samples: &[Sample]) -> Vec<f64> {
    samples
        .iter()
        .map(|s| {
            let mut d: Vec<f64> =
                s.obs.iter().filter_map(|o| depth(&geo[o.0], s, o.0)).filter(|z| *z > 0.0).collect();
            if d.is_empty() {
                1.0
            } else {
                d.sort_by(f64::total_cmp);
                d[d.len() / 2]
            }
        })
        .collect()
}

/// Stage 5: Levenberg-Marquardt over every projector's parameters and every sample's depth
/// (the depths eliminated by their Schur complement). Returns the adjusted geometry and depths
/// and the iterations run.
fn adjust(
    problem: &Problem,
    mut geo: Vec<ProjectorGeometry>,
    mut z: Vec<f64>,
    params: &SelfCalParams,
) -> (Vec<ProjectorGeometry>, Vec<f64>, usize) {
    let mut cost = problem.cost(&geo, &z);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for it in 0..params.max_iterations {
        iterations = it + 1;
        let (mut s, g, per_point) = problem.normal_equations(&geo, &z, lambda, true);
        for i in 0..s.nrows() {
            s[(i, i)] += lambda * s[(i, i)].max(1e-9);
        }
        let Some(chol) = s.clone().cholesky() else {
            lambda *= 10.0;
            continue;
        };
        let delta = -chol.solve(&g);
        let new_geo = step(&geo, &delta);
        let new_z: Vec<f64> = per_point
            .iter()
            .zip(&z)
            .map(|((vd, gz, ws), &zi)| {
                let mut acc = *gz;
                for (k, wk) in ws {
                    for a in 0..NP {
                        acc += wk[a] * delta[k * NP + a];
                    }
                }
                zi - acc / vd
            })
            .collect();
        let new_cost = problem.cost(&new_geo, &new_z);
        if new_cost < cost {
            let gain = (cost - new_cost) / cost.max(1e-30);
            geo = new_geo;
            z = new_z;
            cost = new_cost;
            lambda = (lambda / 3.0).max(1e-9);
            if gain < 1e-10 {
                break;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e8 {
                break;
            }
        }
    }
    (geo, z, iterations)
}

/// How well the adjusted model fits its observations.
struct FitStatistics {
    observations: usize,
    /// Observations within three Huber widths.
    inliers: usize,
    rms_px: f64,
    /// Variance per residual component of the inliers, px² (floored).
    sigma2: f64,
    /// Per projector: inlier observations and their sum of squared residuals.
    per_projector: Vec<(usize, f64)>,
}

/// Stage 6: residual statistics of the adjusted model.
fn fit_statistics(
    problem: &Problem,
    geo: &[ProjectorGeometry],
    z: &[f64],
    params: &SelfCalParams,
) -> FitStatistics {
    let (mut n_obs, mut n_in, mut sum2) = (0, 0, 0.0);
    let mut per_sum = vec![(0usize, 0.0f64); geo.len()];
    for (s, &zi) in problem.samples.iter().zip(z) {
        for &(k, o) in &s.obs {
            n_obs += 1;
            if let Some((r, _, _)) = residual(&geo[k], &s.ray, zi, o) {
                let e2 = r[0] * r[0] + r[1] * r[1];
                if e2.sqrt() < 3.0 * params.huber_px {
                    n_in += 1;
                    sum2 += e2;
                    per_sum[k].0 += 1;
                    per_sum[k].1 += e2;
                }
            }
        }
    }
    FitStatistics {
        observations: n_obs,
        inliers: n_in,
        rms_px: (sum2 / n_in.max(1) as f64).sqrt(),
        sigma2: (sum2 / (2 * n_in).max(1) as f64).max(1e-8),
        per_projector: per_sum,
    }
}

/// Stage 7: each projector's intrinsics' standard deviations from the Gauss-Newton covariance
/// at the optimum, and what the data alone say about `cx`.
fn conditioning(
    problem: &Problem,
    geo: &[ProjectorGeometry],
    z: &[f64],
    sigma2: f64,
    homography_fraction: &[f64],
) -> Vec<Conditioning> {
    let (s_prior, _, _) = problem.normal_equations(geo, z, 0.0, true);
    let (s_data, _, _) = problem.normal_equations(geo, z, 0.0, false);
    let cov = s_prior.clone().cholesky().map(|c| c.inverse());
    let std = |i: usize| {
        cov.as_ref().map_or(f64::INFINITY, |c| {
            let v = c[(i, i)] * sigma2;
            if v.is_finite() && v >= 0.0 { v.sqrt() } else { f64::INFINITY }
        })
    };
    // Information the data alone carry about `cx`: the Schur complement of every other
    // parameter. Zero (infinite deviation) when only the prior fixes it.
    let cx_data_only = |k: usize| {
        let c = k * NP + 1;
        let others: Vec<usize> = (0..s_data.nrows()).filter(|&i| i != c).collect();
        let s_oo = s_data.select_rows(&others).select_columns(&others);
        let s_oc = s_data.select_rows(&others).column(c).into_owned();
        let Some(chol) = s_oo.cholesky() else { return f64::INFINITY };
        let info = s_data[(c, c)] - s_oc.dot(&chol.solve(&s_oc));
        if info > 1e-9 * s_data[(c, c)].max(1e-30) { (sigma2 / info).sqrt() } else { f64::INFINITY }
    };
    (0..geo.len())
        .map(|k| Conditioning {
            projector: k as u32,
            f_std_px: std(k * NP),
            cx_std_px: std(k * NP + 1),
            cy_std_px: std(k * NP + 2),
            cx_std_data_only_px: cx_data_only(k),
            homography_fraction: homography_fraction[k],
            rotation_std_deg: (3..6).map(|i| std(k * NP + i).powi(2)).sum::<f64>().sqrt().to_degrees(),
            translation_std: (6..9).map(|i| std(k * NP + i).powi(2)).sum::<f64>().sqrt(),
        })
        .collect()
}

/// Stage 8: refuses intrinsics the data do not determine (rather than hand out a
/// confident-looking wrong model) and warns about poorly determined ones.
fn check_conditioning(
    geo: &[ProjectorGeometry],
    conditioning: &[Conditioning],
    warnings: &mut Vec<String>,
) -> Result<(), CalibrateError> {
    for c in conditioning {
        let g = &geo[c.projector as usize];
        let (w, h) = (g.width as f64, g.height as f64);
        if c.f_std_px > 0.01 * g.f || c.cy_std_px > 0.05 * h || c.cx_std_px > 0.05 * w {
            return Err(IllPosed::Undetermined {
                projector: c.projector as usize,
                f: g.f,
                f_std: c.f_std_px,
                cx: g.cx,
                cx_std: c.cx_std_px,
                cy: g.cy,
                cy_std: c.cy_std_px,
                homography_percent: 100.0 * c.homography_fraction,
            }
            .into());
        }
        if c.f_std_px > 0.002 * g.f {
            warnings.push(format!(
                "projector {}: focal length poorly determined (f = {:.1} +- {:.1} px); the object may be \
                 too flat or too small in this projector's view",
                c.projector, g.f, c.f_std_px
            ));
        }
        if c.cy_std_px > 0.005 * h {
            warnings.push(format!(
                "projector {}: vertical principal point poorly determined (cy = {:.1} +- {:.1} px)",
                c.projector, g.cy, c.cy_std_px
            ));
        }
    }
    Ok(())
}

/// The one length the user measured, which fixes the scale.
#[derive(Clone, Debug, PartialEq)]
pub enum KnownLength {
    /// Distance (mm) from the camera's centre of projection to projector `projector`'s.
    Baseline { projector: usize, mm: f64 },
}

/// Scale factor from solver units to millimetres.
pub fn scale_for(geo: &[ProjectorGeometry], known: &KnownLength) -> Result<f64, CalibrateError> {
    match *known {
        KnownLength::Baseline { projector, mm } => {
            if !(mm.is_finite() && mm > 0.0) {
                return Err(CalibrateError::KnownLength(format!("{mm} mm is not a positive length")));
            }
            let g = geo.get(projector).ok_or_else(|| {
                CalibrateError::KnownLength(format!(
                    "projector {projector} does not exist (expected 0..{})",
                    geo.len()
                ))
            })?;
            Ok(mm / g.translation.norm())
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn test_camera() -> CameraIntrinsics {
        CameraIntrinsics {
            width: 320,
            height: 240,
            fx: 400.0,
            fy: 400.0,
            cx: 159.5,
            cy: 119.5,
            distortion: [0.0; 5],
        }
    }

    /// A projector at `centre` (camera frame, mm) looking at `target`.
    pub(crate) fn look_at(
        centre: Vector3<f64>,
        target: Vector3<f64>,
        w: u32,
        h: u32,
        f: f64,
        cy: f64,
    ) -> ProjectorGeometry {
        let zc = (target - centre).normalize();
        let xc = Vector3::new(0.0, 1.0, 0.0).cross(&zc).normalize();
        let yc = zc.cross(&xc);
        let r = Matrix3::from_rows(&[xc.transpose(), yc.transpose(), zc.transpose()]);
        ProjectorGeometry {
            width: w,
            height: h,
            f,
            cx: (w as f64 - 1.0) / 2.0,
            cy,
            rotation: r,
            translation: -(r * centre),
        }
    }

    /// Surface seen by camera pixel (u, v): a bumpy sphere-like object in front of a wall.
    pub(crate) fn scene_depth(cam: &CameraIntrinsics, u: f64, v: f64, planar: bool) -> f64 {
        let ray = camera_ray(cam, u, v);
        if planar {
            return 1000.0 / (1.0 + 0.2 * ray.x);
        }
        // Sphere of radius 180 at (0, 0, 900), else a wall at 1150.
        let c = Vector3::new(0.0, 0.0, 900.0);
        let d = ray.normalize();
        let b = d.dot(&c);
        let disc = b * b - (c.norm_squared() - 180.0 * 180.0);
        if disc > 0.0 { (b - disc.sqrt()) * d.z } else { 1150.0 }
    }

    pub(crate) fn synthetic(
        cam: &CameraIntrinsics,
        truth: &[ProjectorGeometry],
        noise: f64,
        planar: bool,
        seed: u64,
    ) -> Vec<Vec<[f32; 2]>> {
        synthetic_with(cam, truth, noise, seed, &|u, v| scene_depth(cam, u, v, planar))
    }

    /// Noisy correspondences of a scene given by its depth along each camera pixel's ray.
    pub(crate) fn synthetic_with(
        cam: &CameraIntrinsics,
        truth: &[ProjectorGeometry],
        noise: f64,
        seed: u64,
        depth: &dyn Fn(f64, f64) -> f64,
    ) -> Vec<Vec<[f32; 2]>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut gauss = move || {
            let (a, b): (f64, f64) = (rng.r#gen::<f64>().max(1e-12), rng.r#gen());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        truth
            .iter()
            .map(|g| {
                let mut out = vec![[f32::NAN; 2]; (cam.width * cam.height) as usize];
                for v in 0..cam.height {
                    for u in 0..cam.width {
                        let z = depth(u as f64, v as f64);
                        let x = camera_ray(cam, u as f64, v as f64) * z;
                        if let Some(p) = g.project(&x)
                            && p[0] >= -0.5
                            && p[1] >= -0.5
                            && p[0] < g.width as f64 - 0.5
                            && p[1] < g.height as f64 - 0.5
                        {
                            out[(v * cam.width + u) as usize] =
                                [(p[0] + noise * gauss()) as f32, (p[1] + noise * gauss()) as f32];
                        }
                    }
                }
                out
            })
            .collect()
    }

    pub(crate) fn three_projectors() -> Vec<ProjectorGeometry> {
        let target = Vector3::new(0.0, 0.0, 900.0);
        vec![
            look_at(Vector3::new(-450.0, -60.0, 80.0), target, 800, 600, 1100.0, 400.0),
            look_at(Vector3::new(420.0, -80.0, 40.0), target, 800, 600, 1250.0, 430.0),
            ProjectorGeometry {
                // Off-centre horizontally: the joint solve must find it against the prior.
                cx: 412.0,
                ..look_at(Vector3::new(30.0, -420.0, 150.0), target, 800, 600, 1000.0, 380.0)
            },
        ]
    }

    fn observations<'a>(
        truth: &[ProjectorGeometry],
        maps: &'a [Vec<[f32; 2]>],
    ) -> Vec<ProjectorObservations<'a>> {
        truth
            .iter()
            .zip(maps)
            .map(|(g, m)| ProjectorObservations { width: g.width, height: g.height, map: m })
            .collect()
    }

    /// Intrinsics within 0.5 % (f) and 3 px (cx, cy), centres within 2 mm, rotations within
    /// 0.1 deg of the truth, RMS under 0.1 px.
    fn assert_recovered(res: &SelfCalResult, truth: &[ProjectorGeometry]) {
        let scale =
            scale_for(&res.projectors, &KnownLength::Baseline { projector: 0, mm: truth[0].centre().norm() })
                .unwrap();
        assert!(res.rms_px < 0.1, "rms {}", res.rms_px);
        for (g, t) in res.projectors.iter().zip(truth) {
            assert!((g.f - t.f).abs() / t.f < 0.005, "f {} vs {}", g.f, t.f);
            assert!((g.cy - t.cy).abs() < 3.0, "cy {} vs {}", g.cy, t.cy);
            assert!((g.cx - t.cx).abs() < 3.0, "cx {} vs {}", g.cx, t.cx);
            let c = g.centre() * scale;
            assert!((c - t.centre()).norm() < 2.0, "centre {c} vs {}", t.centre());
            let dr = Rotation3::from_matrix(&(g.rotation * t.rotation.transpose())).angle();
            assert!(dr.to_degrees() < 0.1, "rotation off by {} deg", dr.to_degrees());
        }
    }

    #[test]
    fn recovers_three_projectors_from_noisy_correspondences() {
        let cam = test_camera();
        let truth = three_projectors();
        let maps = synthetic(&cam, &truth, 0.05, false, 11);
        let obs = observations(&truth, &maps);
        let res =
            self_calibrate(&cam, &obs, &SelfCalParams { max_points: 3000, ..Default::default() }).unwrap();
        assert_recovered(&res, &truth);
        assert!(res.conditioning.iter().all(|c| c.cx_std_data_only_px.is_finite()));
    }

    #[test]
    fn one_projector_uses_the_prior_and_says_so() {
        let cam = test_camera();
        let truth = vec![three_projectors().remove(0)];
        let maps = synthetic(&cam, &truth, 0.05, false, 14);
        let obs = observations(&truth, &maps);
        let res =
            self_calibrate(&cam, &obs, &SelfCalParams { max_points: 3000, ..Default::default() }).unwrap();
        let (g, t) = (&res.projectors[0], &truth[0]);
        assert!((g.f - t.f).abs() / t.f < 0.005, "f {} vs {}", g.f, t.f);
        assert!((g.cy - t.cy).abs() < 3.0, "cy {} vs {}", g.cy, t.cy);
        assert!(res.warnings.iter().any(|w| w.contains("one projector")), "{:?}", res.warnings);
        // The data alone say (next to) nothing about cx: the prior carries it.
        let c = &res.conditioning[0];
        assert!(c.cx_std_data_only_px > 10.0 * c.cx_std_px, "{c:?}");
    }

    #[test]
    fn a_nearly_planar_object_gets_a_conditioning_warning() {
        // A shallow bump (10 mm over a 1 m plane, 0.3 px noise): not planar enough for the homography test, far
        // too flat to separate focal length from distance.
        let cam = test_camera();
        let truth = three_projectors();
        let mut maps = synthetic(&cam, &truth, 0.3, true, 15);
        let bumped = |u: f64, v: f64| {
            let r2 = ((u - 160.0).powi(2) + (v - 120.0).powi(2)) / (80.0f64 * 80.0);
            1000.0 / (1.0 + 0.2 * camera_ray(&cam, u, v).x) - 10.0 * (-r2).exp()
        };
        for (g, m) in truth.iter().zip(maps.iter_mut()) {
            for v in 0..cam.height {
                for u in 0..cam.width {
                    let i = (v * cam.width + u) as usize;
                    if m[i][0].is_finite() {
                        let x = camera_ray(&cam, u as f64, v as f64) * bumped(u as f64, v as f64);
                        let p = g.project(&x).unwrap();
                        // Keep the noise drawn for the plane.
                        let x0 = camera_ray(&cam, u as f64, v as f64)
                            * scene_depth(&cam, u as f64, v as f64, true);
                        let p0 = g.project(&x0).unwrap().map(|c| c as f32);
                        m[i] = [p[0] as f32 + (m[i][0] - p0[0]), p[1] as f32 + (m[i][1] - p0[1])];
                    }
                }
            }
        }
        let obs = observations(&truth, &maps);
        match self_calibrate(&cam, &obs, &SelfCalParams { max_points: 3000, ..Default::default() }) {
            Err(e) => assert!(matches!(e, CalibrateError::IllPosed(_)), "{e}"),
            Ok(res) => assert!(
                res.warnings.iter().any(|w| w.contains("poorly determined")),
                "{:?} {:?}",
                res.warnings,
                res.conditioning
            ),
        }
    }

    #[test]
    fn a_planar_scene_is_reported_ill_posed() {
        let cam = test_camera();
        let truth = three_projectors();
        let maps = synthetic(&cam, &truth, 0.05, true, 12);
        let obs = observations(&truth, &maps);
        let err = self_calibrate(&cam, &obs, &SelfCalParams { max_points: 2000, ..Default::default() })
            .unwrap_err();
        assert!(matches!(err, CalibrateError::IllPosed(_)), "{err}");
        assert!(err.to_string().contains("planar"), "{err}");
    }

    /// Depth along pixel `(u, v)`'s ray of the plane `n . X = d` (a flat board in one pose).
    fn board_depth(cam: &CameraIntrinsics, n: Vector3<f64>, d: f64) -> impl Fn(f64, f64) -> f64 {
        move |u, v| d / n.dot(&camera_ray(cam, u, v))
    }

    #[test]
    fn two_poses_of_a_flat_board_calibrate_the_rig_that_one_pose_cannot() {
        // A camera with a real lens: the rays must be undistorted for the planes to stay planes.
        let cam = CameraIntrinsics { distortion: [0.10, -0.19, -0.002, -0.003, 0.046], ..test_camera() };
        let truth = three_projectors();
        let tilts = [Vector3::new(0.25, 0.05, 1.0), Vector3::new(-0.15, 0.3, 1.0)];
        let maps: Vec<Vec<Vec<[f32; 2]>>> = tilts
            .iter()
            .enumerate()
            .map(|(i, n)| {
                synthetic_with(&cam, &truth, 0.05, 20 + i as u64, &board_depth(&cam, n.normalize(), 950.0))
            })
            .collect();
        let obs: Vec<Vec<ProjectorObservations>> = maps.iter().map(|m| observations(&truth, m)).collect();
        let params = SelfCalParams { max_points: 4000, ..Default::default() };
        for one in &obs {
            let err = self_calibrate(&cam, one, &params).unwrap_err();
            assert!(err.to_string().contains("planar"), "{err}");
        }
        let poses: Vec<&[ProjectorObservations]> = obs.iter().map(Vec::as_slice).collect();
        let res = self_calibrate_poses(&cam, &poses, &params).unwrap();
        assert_recovered(&res, &truth);
        // The same boards read through a pinhole camera (the lens ignored) do not fit as well.
        let pinhole = CameraIntrinsics { distortion: [0.0; 5], ..cam.clone() };
        let bent = self_calibrate_poses(&pinhole, &poses, &params).map_or(f64::INFINITY, |r| r.rms_px);
        assert!(bent > 5.0 * res.rms_px, "ignoring the lens: rms {bent} vs {}", res.rms_px);
    }

    #[test]
    fn a_projector_that_sees_nothing_is_named() {
        let cam = test_camera();
        let truth = three_projectors();
        let mut maps = synthetic(&cam, &truth, 0.05, false, 13);
        maps[1].iter_mut().for_each(|m| *m = [f32::NAN; 2]);
        let obs = observations(&truth, &maps);
        let err = self_calibrate(&cam, &obs, &SelfCalParams { max_points: 2000, ..Default::default() })
            .unwrap_err();
        assert!(err.to_string().contains("projector 1"), "{err}");
    }

    #[test]
    fn bad_known_lengths_are_refused() {
        let g = three_projectors();
        assert!(scale_for(&g, &KnownLength::Baseline { projector: 5, mm: 100.0 }).is_err());
        assert!(scale_for(&g, &KnownLength::Baseline { projector: 0, mm: -1.0 }).is_err());
    }
}
