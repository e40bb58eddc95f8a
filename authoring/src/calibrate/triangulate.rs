//! Dense triangulation: every decoded camera pixel, from all projectors that see it, along the
//! camera ray; outlier rejection by reprojection residual and by depth against the pixel's
//! neighbours; normals from local plane fits on the pixel grid.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::selfcal::{ProjectorGeometry, camera_ray};
use crate::capture_set::CameraIntrinsics;

#[derive(Clone, Debug, PartialEq)]
pub struct TriangulateParams {
    /// An observation whose reprojection error exceeds this (projector px) is dropped.
    pub max_residual_px: f64,
    /// A point further than this fraction of its depth from the median depth of its 5x5
    /// neighbours is dropped (isolated specks, mixed pixels at depth edges).
    pub max_depth_deviation: f64,
    /// Half-size of the window for normal fits (pixels).
    pub normal_radius: usize,
}

impl Default for TriangulateParams {
    fn default() -> Self {
        Self { max_residual_px: 2.0, max_depth_deviation: 0.01, normal_radius: 3 }
    }
}

/// Dense geometry in the camera frame, per camera pixel (row-major), NaN where unknown.
#[derive(Clone, Debug)]
pub struct DenseGeometry {
    pub points: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Per projector, per pixel: reprojection error (px) of the kept observation, NaN if none.
    pub residuals: Vec<Vec<f32>>,
    pub valid: usize,
    pub rejected_residual: usize,
    pub rejected_depth: usize,
}

impl DenseGeometry {
    /// RMS reprojection error over all kept observations.
    pub fn rms_px(&self) -> f64 {
        let (n, s) = self
            .residuals
            .iter()
            .flatten()
            .filter(|r| r.is_finite())
            .fold((0usize, 0.0f64), |(n, s), &r| (n + 1, s + (r as f64) * (r as f64)));
        (s / n.max(1) as f64).sqrt()
    }
}

/// Depth along `ray` from the observations (projector, pixel), least squares in projector
/// pixels; returns the depth and each observation's residual.
pub(crate) fn solve_depth(
    geo: &[ProjectorGeometry],
    ray: &Vector3<f64>,
    obs: &[(usize, [f64; 2])],
) -> Option<(f64, Vec<f64>)> {
    // Linear start: x_p x (R X + t) = 0 with X = z ray.
    let (mut num, mut den) = (0.0, 0.0);
    for &(k, p) in obs {
        let g = &geo[k];
        let xp = Vector3::new((p[0] - g.cx) / g.f, (p[1] - g.cy) / g.f, 1.0);
        let a = xp.cross(&(g.rotation * ray)) * g.f;
        let b = xp.cross(&g.translation) * g.f;
        num -= a.dot(&b);
        den += a.dot(&a);
    }
    if den <= 0.0 {
        return None;
    }
    let mut z = num / den;
    for _ in 0..4 {
        let (mut jr, mut jj) = (0.0, 0.0);
        for &(k, p) in obs {
            let g = &geo[k];
            let d = g.rotation * ray;
            let y = d * z + g.translation;
            if y.z <= 1e-9 {
                return None;
            }
            let r = [g.f * y.x / y.z + g.cx - p[0], g.f * y.y / y.z + g.cy - p[1]];
            let j =
                [g.f * (d.x * y.z - y.x * d.z) / (y.z * y.z), g.f * (d.y * y.z - y.y * d.z) / (y.z * y.z)];
            jr += j[0] * r[0] + j[1] * r[1];
            jj += j[0] * j[0] + j[1] * j[1];
        }
        if jj <= 0.0 {
            return None;
        }
        z -= jr / jj;
    }
    if !(z.is_finite() && z > 0.0) {
        return None;
    }
    let res = obs
        .iter()
        .map(|&(k, p)| geo[k].project(&(ray * z)).map_or(f64::INFINITY, |q| (q[0] - p[0]).hypot(q[1] - p[1])))
        .collect();
    Some((z, res))
}

/// Triangulates every camera pixel that at least one projector decoded.
pub fn triangulate(
    cam: &CameraIntrinsics,
    geo: &[ProjectorGeometry],
    maps: &[&[[f32; 2]]],
    params: &TriangulateParams,
) -> DenseGeometry {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let n = w * h;
    struct Px {
        z: f64,
        kept: Vec<(usize, f64)>,
        rejected: bool,
    }
    let solved: Vec<Option<Px>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut obs: Vec<(usize, [f64; 2])> = maps
                .iter()
                .enumerate()
                .filter(|(_, m)| m[i][0].is_finite() && m[i][1].is_finite())
                .map(|(k, m)| (k, [m[i][0] as f64, m[i][1] as f64]))
                .collect();
            if obs.is_empty() {
                return None;
            }
            let ray = camera_ray(cam, (i % w) as f64, (i / w) as f64);
            let mut rejected = false;
            loop {
                let (z, res) = solve_depth(geo, &ray, &obs)?;
                let worst = (0..res.len()).max_by(|&a, &b| res[a].total_cmp(&res[b]))?;
                if res[worst] <= params.max_residual_px {
                    let kept = obs.iter().zip(&res).map(|(o, &r)| (o.0, r)).collect();
                    return Some(Px { z, kept, rejected });
                }
                rejected = true;
                obs.remove(worst);
                if obs.is_empty() {
                    return Some(Px { z: f64::NAN, kept: Vec::new(), rejected });
                }
            }
        })
        .collect();
    let rejected_residual = solved.iter().filter(|p| p.as_ref().is_some_and(|p| p.kept.is_empty())).count();
    let depth: Vec<f64> = solved
        .iter()
        .map(|p| p.as_ref().map_or(f64::NAN, |p| if p.kept.is_empty() { f64::NAN } else { p.z }))
        .collect();
    // Depth outliers against the 5x5 neighbourhood median.
    let keep: Vec<bool> = (0..n)
        .into_par_iter()
        .map(|i| {
            let z = depth[i];
            if !z.is_finite() {
                return false;
            }
            let (x, y) = (i % w, i / w);
            let mut nb: Vec<f64> = Vec::with_capacity(24);
            for yy in y.saturating_sub(2)..(y + 3).min(h) {
                for xx in x.saturating_sub(2)..(x + 3).min(w) {
                    let j = yy * w + xx;
                    if j != i && depth[j].is_finite() {
                        nb.push(depth[j]);
                    }
                }
            }
            if nb.len() < 3 {
                return false;
            }
            let mid = nb.len() / 2;
            let med = *nb.select_nth_unstable_by(mid, f64::total_cmp).1;
            (z - med).abs() <= params.max_depth_deviation * z
        })
        .collect();
    let rejected_depth = (0..n).filter(|&i| depth[i].is_finite() && !keep[i]).count();
    let points: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            if keep[i] {
                let p = camera_ray(cam, (i % w) as f64, (i / w) as f64) * depth[i];
                [p.x as f32, p.y as f32, p.z as f32]
            } else {
                [f32::NAN; 3]
            }
        })
        .collect();
    let mut residuals = vec![vec![f32::NAN; n]; maps.len()];
    for (i, p) in solved.iter().enumerate() {
        if let Some(p) = p
            && keep[i]
        {
            for &(k, r) in &p.kept {
                residuals[k][i] = r as f32;
            }
        }
    }
    let normals = normals_from_points(w, h, &points, params.normal_radius);
    let valid = keep.iter().filter(|&&k| k).count();
    let _ = solved.iter().filter(|p| p.as_ref().is_some_and(|p| p.rejected)).count();
    DenseGeometry { points, normals, residuals, valid, rejected_residual, rejected_depth }
}

/// Unit normals from plane fits over a `(2r+1)^2` pixel window, ignoring neighbours across
/// depth edges, oriented towards the camera.
pub fn normals_from_points(w: usize, h: usize, points: &[[f32; 3]], r: usize) -> Vec<[f32; 3]> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let p = points[i];
            if !p[2].is_finite() {
                return [f32::NAN; 3];
            }
            let (x, y) = (i % w, i / w);
            let pc = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let mut pts: Vec<Vector3<f64>> = Vec::with_capacity((2 * r + 1) * (2 * r + 1));
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    let q = points[yy * w + xx];
                    if q[2].is_finite() && ((q[2] - p[2]).abs() as f64) < 0.03 * pc.z {
                        pts.push(Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64));
                    }
                }
            }
            if pts.len() < 6 {
                return [f32::NAN; 3];
            }
            let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
            let mut cov = Matrix3::zeros();
            for q in &pts {
                let d = q - mean;
                cov += d * d.transpose();
            }
            let eig = SymmetricEigen::new(cov);
            let k = eig.eigenvalues.imin();
            let mut n: Vector3<f64> = eig.eigenvectors.column(k).into();
            if n.dot(&pc) > 0.0 {
                n = -n;
            }
            [n.x as f32, n.y as f32, n.z as f32]
        })
        .collect()
}

/// The largest plane among the points (found by RANSAC, refitted by least squares): what
/// fraction of the points lie within 0.5 % of the median depth of it, and their RMS distance
/// from it. A flat board triangulated with the right rig comes out flat.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneFit {
    pub fraction: f64,
    pub rms: f64,
    pub normal: Vector3<f64>,
}

pub fn largest_plane(points: &[[f32; 3]], seed: u64) -> PlaneFit {
    use rand::{Rng, SeedableRng};
    let pts: Vec<Vector3<f64>> = points
        .iter()
        .filter(|p| p[2].is_finite())
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let none = PlaneFit { fraction: 0.0, rms: f64::NAN, normal: Vector3::zeros() };
    if pts.len() < 3 {
        return none;
    }
    let step = (pts.len() / 5000).max(1);
    let sample: Vec<Vector3<f64>> = pts.iter().step_by(step).copied().collect();
    let mut z: Vec<f64> = sample.iter().map(|p| p.z).collect();
    let mid = z.len() / 2;
    let threshold = 0.005 * z.select_nth_unstable_by(mid, f64::total_cmp).1.abs();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut best: Option<(usize, Vector3<f64>, f64)> = None;
    for _ in 0..300 {
        let [a, b, c] = [0; 3].map(|_| sample[rng.gen_range(0..sample.len())]);
        let n = (b - a).cross(&(c - a));
        if n.norm() < 1e-12 {
            continue;
        }
        let n = n.normalize();
        let d = n.dot(&a);
        let count = sample.iter().filter(|p| (n.dot(p) - d).abs() < threshold).count();
        if best.is_none_or(|b| count > b.0) {
            best = Some((count, n, d));
        }
    }
    let Some((_, mut n, mut d)) = best else { return none };
    // Two least-squares refits on the inliers (smallest eigenvector of their scatter).
    for _ in 0..2 {
        let inl: Vec<&Vector3<f64>> = pts.iter().filter(|p| (n.dot(p) - d).abs() < threshold).collect();
        if inl.len() < 3 {
            return none;
        }
        let c = inl.iter().fold(Vector3::zeros(), |s, p| s + **p) / inl.len() as f64;
        let scatter = inl.iter().fold(Matrix3::zeros(), |s, p| s + (**p - c) * (**p - c).transpose());
        let eig = SymmetricEigen::new(scatter);
        n = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        d = n.dot(&c);
    }
    let dist: Vec<f64> = pts.iter().map(|p| (n.dot(p) - d).abs()).filter(|&e| e < threshold).collect();
    PlaneFit {
        fraction: dist.len() as f64 / pts.len() as f64,
        rms: (dist.iter().map(|e| e * e).sum::<f64>() / dist.len().max(1) as f64).sqrt(),
        normal: n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::selfcal::tests::{scene_depth, synthetic, test_camera, three_projectors};

    #[test]
    fn triangulates_the_true_surface_and_its_normals() {
        let cam = test_camera();
        let truth = three_projectors();
        let mut maps = synthetic(&cam, &truth, 0.05, false, 21);
        // Gross outliers in one projector's map must be rejected, not averaged in.
        for i in (0..maps[0].len()).step_by(97) {
            if maps[0][i][0].is_finite() {
                maps[0][i][0] += 25.0;
            }
        }
        let refs: Vec<&[[f32; 2]]> = maps.iter().map(|m| m.as_slice()).collect();
        let d = triangulate(&cam, &truth, &refs, &TriangulateParams::default());
        assert!(d.rms_px() < 0.1, "rms {}", d.rms_px());
        let (mut errs, mut angles) = (Vec::new(), Vec::new());
        let c = Vector3::new(0.0, 0.0, 900.0);
        for v in 0..cam.height {
            for u in 0..cam.width {
                let i = (v * cam.width + u) as usize;
                let p = d.points[i];
                if !p[2].is_finite() {
                    continue;
                }
                let z = scene_depth(&cam, u as f64, v as f64, false);
                errs.push((p[2] as f64 - z).abs());
                let pv = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                let n = d.normals[i];
                if n[0].is_finite() && z < 1100.0 {
                    let truth_n = (pv - c).normalize();
                    let nv = Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
                    angles.push(nv.dot(&truth_n).clamp(-1.0, 1.0).acos().to_degrees());
                }
            }
        }
        errs.sort_by(f64::total_cmp);
        angles.sort_by(f64::total_cmp);
        assert!(d.valid > 60_000, "valid {}", d.valid);
        assert!(errs[errs.len() / 2] < 0.2, "median depth error {}", errs[errs.len() / 2]);
        assert!(angles[angles.len() / 2] < 2.0, "median normal error {}", angles[angles.len() / 2]);
    }

    #[test]
    fn the_largest_plane_is_found_among_clutter() {
        // A tilted board (2/3 of the points, 0.1 mm noise) in front of a sphere-ish bump.
        let mut pts = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let (x, y) = (i as f64 * 5.0 - 150.0, j as f64 * 5.0 - 150.0);
                let noise = 0.1 * (((i * 7 + j * 13) % 11) as f64 / 5.0 - 1.0);
                pts.push([x as f32, y as f32, (1000.0 + 0.3 * x - 0.2 * y + noise) as f32]);
                if (i + j) % 2 == 0 {
                    pts.push([x as f32, y as f32, (800.0 + 0.002 * (x * x + y * y)) as f32]);
                }
            }
        }
        pts.push([f32::NAN; 3]);
        let fit = largest_plane(&pts, 3);
        assert!((fit.fraction - 2.0 / 3.0).abs() < 0.02, "{fit:?}");
        assert!(fit.rms < 0.1, "{fit:?}");
        let n = Vector3::new(-0.3, 0.2, 1.0).normalize();
        assert!(fit.normal.dot(&n).abs() > 0.9999, "{fit:?}");
    }
}
