//! The surface radiance model (paper §5.1.1) evaluated once per stage: for every object
//! point (camera pixel) and projector, the paper's efficiency `L_ik = 1 / A_ik` with
//! `A_ik = (rho d_ik / cos theta_ik)^2`, the physical efficiency in lux per unit of relative
//! output, and the projector pixel that lights the point.

use rayon::prelude::*;

use crate::stage_model::{ProjectorModel, StageModel};

/// Per point and projector, row-major `[point * projectors + k]`.
#[derive(Clone, Debug)]
pub struct Geometry {
    pub points: usize,
    pub projectors: usize,
    /// Paper's `L_ik` (1 / mm^2 of one projector pixel's footprint); 0 where k does not see i.
    pub l: Vec<f32>,
    /// Lux at the point per unit of relative projector output (`response` scale) from the
    /// projector pixel that lights it: `lux_at_1m * vignetting * cos(theta) / (d / 1 m)^2`.
    pub eta: Vec<f32>,
    /// Projector pixel coordinate (continuous, pixel centres at integers); NaN where unseen.
    pub coord: Vec<[f32; 2]>,
    /// Half-extent (projector pixels, x and y) of the camera pixel's footprint in the
    /// projector image, from the neighbouring correspondences: 0.5 where the camera samples
    /// the surface at least as finely as the projector, up to [`MAX_HALF`] where coarser.
    pub half: Vec<[f32; 2]>,
}

/// Largest footprint half-extent used (projector pixels); beyond it a camera pixel is
/// treated as sampling only the centre of its footprint.
pub const MAX_HALF: f32 = 4.0;

impl Geometry {
    /// Evaluates the model from the stage's points, normals, poses and measured
    /// correspondences. A projector "sees" a point where calibration measured a
    /// correspondence and the surface faces it (the measured visibility includes shadows).
    pub fn new(stage: &StageModel) -> Self {
        let n = stage.pixel_count();
        let kn = stage.projectors.len();
        let centres: Vec<[f64; 3]> = stage.projectors.iter().map(ProjectorModel::centre).collect();
        let mut l = vec![0.0f32; n * kn];
        let mut eta = vec![0.0f32; n * kn];
        let mut coord = vec![[f32::NAN; 2]; n * kn];
        l.par_chunks_mut(kn).zip(eta.par_chunks_mut(kn)).zip(coord.par_chunks_mut(kn)).enumerate().for_each(
            |(i, ((l, eta), coord))| {
                let x = stage.points[i].map(f64::from);
                let nrm = stage.normals[i].map(f64::from);
                if !x.iter().chain(&nrm).all(|v| v.is_finite()) {
                    return;
                }
                for k in 0..kn {
                    let c = stage.correspondences[k][i];
                    if !(c[0].is_finite() && c[1].is_finite()) {
                        continue;
                    }
                    let p = &stage.projectors[k];
                    let d = [centres[k][0] - x[0], centres[k][1] - x[1], centres[k][2] - x[2]];
                    let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    let cos = (nrm[0] * d[0] + nrm[1] * d[1] + nrm[2] * d[2]) / dist;
                    if !(cos > 0.0 && dist > 0.0) {
                        continue;
                    }
                    let rho = 1.0 / p.f;
                    let area = (rho * dist / cos).powi(2);
                    l[k] = (1.0 / area) as f32;
                    let vig = vignetting(p, c);
                    eta[k] = (p.lux_at_1m * vig * cos / (dist / 1000.0).powi(2)) as f32;
                    coord[k] = c;
                }
            },
        );
        let half = footprint_half_extents(&coord, kn, stage.camera.width as usize);
        Self { points: n, projectors: kn, l, eta, coord, half }
    }

    /// Whether any projector lights point `i`.
    pub fn covered(&self, i: usize) -> bool {
        self.eta[i * self.projectors..(i + 1) * self.projectors].iter().any(|&e| e > 0.0)
    }
}

/// Per point and projector, half the largest step to a seen 4-neighbour's coordinate.
fn footprint_half_extents(coord: &[[f32; 2]], kn: usize, w: usize) -> Vec<[f32; 2]> {
    let n = coord.len() / kn.max(1);
    (0..n * kn)
        .into_par_iter()
        .map(|ik| {
            let (i, k) = (ik / kn, ik % kn);
            let c = coord[ik];
            let mut h = [0.5f32; 2];
            if !c[0].is_finite() {
                return h;
            }
            let (x, y) = (i % w, i / w);
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (i + w < n).then(|| i + w),
            ];
            for j in neighbours.into_iter().flatten() {
                let d = coord[j * kn + k];
                if d[0].is_finite() {
                    h[0] = h[0].max(0.5 * (d[0] - c[0]).abs());
                    h[1] = h[1].max(0.5 * (d[1] - c[1]).abs());
                }
            }
            h.map(|v| v.min(MAX_HALF))
        })
        .collect()
}

/// Relative output of the projector pixel nearest to `c` (1 when not measured).
pub fn vignetting(p: &ProjectorModel, c: [f32; 2]) -> f64 {
    if p.vignetting.is_empty() {
        return 1.0;
    }
    let x = (c[0].round().max(0.0) as usize).min(p.width as usize - 1);
    let y = (c[1].round().max(0.0) as usize).min(p.height as usize - 1);
    p.vignetting.get(y * p.width as usize + x).map_or(1.0, |&v| v as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::{SyntheticStage, synthetic_stage};

    #[test]
    fn head_on_point_follows_inverse_square_and_paper_area() {
        let s: SyntheticStage = synthetic_stage(1, 3);
        let g = Geometry::new(&s.model);
        let p = &s.model.projectors[0];
        let c = p.centre();
        // Check every covered point against a direct evaluation of the formulas.
        let mut checked = 0;
        for i in 0..g.points {
            if g.eta[i] <= 0.0 {
                continue;
            }
            let x = s.model.points[i].map(f64::from);
            let n = s.model.normals[i].map(f64::from);
            let d = [c[0] - x[0], c[1] - x[1], c[2] - x[2]];
            let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let cos = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / dist;
            let want_l = (cos * p.f / dist).powi(2);
            assert!((g.l[i] as f64 / want_l - 1.0).abs() < 1e-4);
            let want_eta = p.lux_at_1m * vignetting(p, g.coord[i]) * cos * 1e6 / (dist * dist);
            assert!((g.eta[i] as f64 / want_eta - 1.0).abs() < 1e-4);
            checked += 1;
        }
        assert!(checked > 100);
    }

    #[test]
    fn unseen_points_get_nothing() {
        let s = synthetic_stage(3, 5);
        let g = Geometry::new(&s.model);
        for i in 0..g.points {
            for k in 0..3 {
                if s.model.correspondences[k][i][0].is_nan() {
                    assert_eq!(g.eta[i * 3 + k], 0.0);
                    assert_eq!(g.l[i * 3 + k], 0.0);
                }
            }
        }
    }
}
