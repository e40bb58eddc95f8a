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
}

impl Geometry {
    /// Evaluates the model from the stage's points, normals, poses and measured
    /// correspondences. A projector "sees" a point where calibration measured a
    /// correspondence and the surface faces it (the measured visibility includes shadows).
    pub fn new(stage: &StageModel) -> Self {
        let n = stage.pixel_count();
        let kn = stage.projectors.len();
        let centres: Vec<[f64; 3]> = stage.projectors.iter().map(centre).collect();
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
        Self { points: n, projectors: kn, l, eta, coord }
    }

    /// Whether any projector lights point `i`.
    pub fn covered(&self, i: usize) -> bool {
        self.eta[i * self.projectors..(i + 1) * self.projectors].iter().any(|&e| e > 0.0)
    }
}

/// A projector's centre of projection in the camera frame: `C = -R^T t`.
pub fn centre(p: &ProjectorModel) -> [f64; 3] {
    let (r, t) = (&p.rotation, &p.translation);
    let mut c = [0.0; 3];
    for (j, cj) in c.iter_mut().enumerate() {
        *cj = -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]);
    }
    c
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
        let c = centre(p);
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
