//! Where projector light lands, bounded: the certificate's coefficients taken as the worst
//! case over each camera pixel's stretch of surface (its neighbours' normals and distances,
//! and no trust in normals the camera sees at grazing angles), and, per projector, which
//! pixels' light lands on surface the model knows. Light that would land elsewhere (unseen or
//! unreconstructed surface, past a silhouette) cannot be bounded from the model: those pixels
//! stay dark, and the certificate charges the ring of them next to the known surface at the
//! worst geometry around it (see docs/compensate.md, "Bounding the light where it lands").

use rayon::prelude::*;

use super::geometry::{Geometry, vignetting};
use crate::stage_model::{ProjectorModel, StageModel};

/// Below this cosine between a point's normal and its ray to the camera (75 degrees) the
/// normal is not trusted: one camera pixel then spans a long, curving stretch of surface,
/// and reconstructed normals there are poor. The coefficient assumes the surface faces the
/// projector.
pub const GRAZING_COS: f64 = 0.26;

/// Allowance for normal error on top of the spread of the neighbours' normals, radians (3
/// degrees): a reconstructed normal is a fit over a few noisy points.
pub const NORMAL_SLACK_RAD: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// Surface no camera pixel reconstructs, beside surface that is known, is assumed no nearer
/// to a projector than this fraction of the known surface's distance: it may turn towards
/// the projector or stand out from the known surface, but not by a fifth of the throw.
pub const UNSEEN_NEAR: f64 = 0.8;

/// Fewest reconstructed 8-neighbours a point needs for its normal to be trusted; at the edge
/// of the reconstruction (silhouettes, holes) the normal is an extrapolation.
const MIN_NEIGHBOURS: usize = 5;

/// Per point and projector (`[i * projectors + k]`), an upper bound of the lux per unit of
/// relative output anywhere on the stretch of surface camera pixel `i` spans, lit by `k`:
/// `lux_at_1m * vignetting * cos_bound / d_min^2`, with `d_min` the nearest of the point and
/// its reconstructed neighbours, `cos_bound` the cosine to the projector reduced by the
/// spread of the neighbours' normals (plus [`NORMAL_SLACK_RAD`]), and 1 where the camera sees
/// the surface at a grazing angle or the point lies at the edge of the reconstruction.
/// Zero where `k` does not light the point (as `Geometry::eta`).
pub fn bound_eta(stage: &StageModel, geom: &Geometry) -> Vec<f32> {
    let (kn, w) = (geom.projectors, stage.camera.width as usize);
    let n = geom.points;
    let centres: Vec<[f64; 3]> = stage.projectors.iter().map(ProjectorModel::centre).collect();
    let point = |i: usize| stage.points[i].map(f64::from);
    let normal = |i: usize| stage.normals[i].map(f64::from);
    let finite = |v: &[f64; 3]| v.iter().all(|c| c.is_finite());
    let mut out = vec![0.0f32; n * kn];
    out.par_chunks_mut(kn).enumerate().for_each(|(i, out)| {
        if !(0..kn).any(|k| geom.eta[i * kn + k] > 0.0) {
            return;
        }
        let (x, nrm) = (point(i), normal(i));
        let (cx, cy) = (i % w, i / w);
        let mut neighbours = Vec::with_capacity(8);
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let (nx, ny) = (cx as i64 + dx, cy as i64 + dy);
                if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w as i64 || ny as usize * w >= n {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                let (p, m) = (point(j), normal(j));
                if finite(&p) && finite(&m) {
                    neighbours.push(j);
                }
            }
        }
        // The camera looks from the origin of the camera frame.
        let dist = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        let cos_cam = -(nrm[0] * x[0] + nrm[1] * x[1] + nrm[2] * x[2]) / dist;
        let trusted = cos_cam >= GRAZING_COS && neighbours.len() >= MIN_NEIGHBOURS;
        let spread = neighbours
            .iter()
            .map(|&j| {
                let m = normal(j);
                let c = (nrm[0] * m[0] + nrm[1] * m[1] + nrm[2] * m[2]).clamp(-1.0, 1.0);
                c.acos()
            })
            .fold(0.0f64, f64::max)
            + NORMAL_SLACK_RAD;
        for k in 0..kn {
            if geom.eta[i * kn + k] <= 0.0 {
                continue;
            }
            let p = &stage.projectors[k];
            let c = centres[k];
            let to = |v: [f64; 3]| {
                let d = [c[0] - v[0], c[1] - v[1], c[2] - v[2]];
                (d, (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
            };
            let (d, dist_k) = to(x);
            let d_min = neighbours.iter().map(|&j| to(point(j)).1).fold(dist_k, f64::min);
            let cos_bound = if trusted {
                let cos = ((nrm[0] * d[0] + nrm[1] * d[1] + nrm[2] * d[2]) / dist_k).clamp(-1.0, 1.0);
                (cos.acos() - spread).max(0.0).cos()
            } else {
                1.0
            };
            let vig = std::iter::once(i)
                .chain(neighbours.iter().copied())
                .map(|j| geom.coord[j * kn + k])
                .filter(|c| c[0].is_finite())
                .map(|c| vignetting(p, c))
                .fold(0.0f64, f64::max);
            let eta = p.lux_at_1m * vig * cos_bound / (d_min / 1000.0).powi(2);
            // Never below the model's own efficiency at the point.
            out[k] = (eta as f32).max(geom.eta[i * kn + k]);
        }
    });
    out
}

/// One projector's landing map.
#[derive(Clone, Debug)]
pub struct Landing {
    pub width: u32,
    pub height: u32,
    /// Per projector pixel: its light lands on surface the model reconstructed (its whole
    /// footprint, one pixel of blur included). Only these pixels may be lit.
    pub known: Vec<bool>,
    /// Per projector pixel, a camera pixel whose footprint touches it (`u32::MAX`: none), to
    /// name where in the camera image an unknown pixel's light would land beside.
    pub near_camera_pixel: Vec<u32>,
    /// Per projector pixel, the distance (mm) from the projector to the nearest reconstructed
    /// point whose footprint touches it (infinite: none).
    pub distance_mm: Vec<f32>,
}

impl Landing {
    /// Pixels that are not known but touch a known one (8-neighbourhood): where a lit pixel's
    /// blur can spill onto surface the model does not know.
    pub fn ring(&self) -> Vec<(u32, u32)> {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                if self.known[y * w + x] {
                    continue;
                }
                let touches = (y.saturating_sub(1)..=(y + 1).min(h - 1))
                    .any(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).any(|xx| self.known[yy * w + xx]));
                if touches {
                    out.push((x as u32, y as u32));
                }
            }
        }
        out
    }

    /// Worst-case lux per unit of relative output of the light of unknown pixel `(x, y)`:
    /// a surface facing the projector at [`UNSEEN_NEAR`] of the distance of the nearest known
    /// surface around the pixel (its 3x3 neighbourhood), at the projector's brightest
    /// vignetting. `None` when no known surface is around it.
    pub fn unseen_eta(&self, p: &ProjectorModel, x: u32, y: u32) -> Option<f64> {
        let (w, h) = (self.width, self.height);
        let d = (y.saturating_sub(1)..=(y + 1).min(h - 1))
            .flat_map(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).map(move |xx| (yy * w + xx) as usize))
            .map(|i| self.distance_mm[i])
            .fold(f32::INFINITY, f32::min);
        if !d.is_finite() {
            return None;
        }
        let vig = p.vignetting.iter().copied().fold(0.0f32, f32::max);
        let vig = if p.vignetting.is_empty() { 1.0 } else { f64::from(vig).max(1.0) };
        Some(p.lux_at_1m * vig / (UNSEEN_NEAR * f64::from(d) / 1000.0).powi(2))
    }
}

/// The landing map of projector `k`: the projector pixels each reconstructed camera pixel's
/// footprint touches (`Geometry::coord` +- `Geometry::half`), small holes between them
/// closed (decode gaps on dark paint: the surface there is the surface around them), then
/// eroded by one pixel for lens blur, so a known pixel's light, blur included, falls on
/// known surface.
pub fn landing(stage: &StageModel, geom: &Geometry, k: usize) -> Landing {
    let p = &stage.projectors[k];
    let (w, h) = (p.width as usize, p.height as usize);
    let kn = geom.projectors;
    let mut near = vec![u32::MAX; w * h];
    let mut distance = vec![f32::INFINITY; w * h];
    let centre = p.centre();
    for i in 0..geom.points {
        if geom.eta[i * kn + k] <= 0.0 {
            continue;
        }
        let x = stage.points[i].map(f64::from);
        let d = ((centre[0] - x[0]).powi(2) + (centre[1] - x[1]).powi(2) + (centre[2] - x[2]).powi(2)).sqrt();
        let c = geom.coord[i * kn + k];
        let hf = geom.half[i * kn + k];
        // Projector pixels whose square overlaps the footprint [c - hf, c + hf].
        let span = |c: f32, hf: f32, n: usize| {
            let a = ((c - hf - 0.5).floor() as i64 + 1).max(0);
            let b = ((c + hf + 0.5).ceil() as i64 - 1).min(n as i64 - 1);
            (a, b)
        };
        let (xa, xb) = span(c[0], hf[0], w);
        let (ya, yb) = span(c[1], hf[1], h);
        for y in ya..=yb {
            for x in xa..=xb {
                let j = y as usize * w + x as usize;
                if near[j] == u32::MAX {
                    near[j] = i as u32;
                }
                distance[j] = distance[j].min(d as f32);
            }
        }
    }
    let marked: Vec<bool> = near.iter().map(|&m| m != u32::MAX).collect();
    let closed = close_small_gaps(&marked, w, h);
    let known = erode(&closed, w, h);
    Landing { width: p.width, height: p.height, known, near_camera_pixel: near, distance_mm: distance }
}

/// Largest gap (pixels) between marked pixels, along a row or a column, that is closed.
const MAX_GAP: usize = 2;

/// Marks every unmarked pixel that has marked pixels within [`MAX_GAP`] on both sides along
/// its row and along its column: a decode hole inside the surface, not an edge of it.
fn close_small_gaps(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            if m[i] {
                return true;
            }
            let (x, y) = (i % w, i / w);
            let left = (1..=MAX_GAP).any(|d| x >= d && m[i - d]);
            let right = (1..=MAX_GAP).any(|d| x + d < w && m[i + d]);
            let up = (1..=MAX_GAP).any(|d| y >= d && m[i - d * w]);
            let down = (1..=MAX_GAP).any(|d| y + d < h && m[i + d * w]);
            left && right && up && down
        })
        .collect()
}

/// A pixel stays only if it and its 8 neighbours are all set (the image border counts as
/// unset: light past the frame's edge is no concern, but a pixel there has no known side).
fn erode(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if !m[i] || x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
                return false;
            }
            (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| m[yy * w + xx]))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::synthetic_stage;

    #[test]
    fn erosion_keeps_the_inside_of_a_block() {
        let (w, h) = (8, 6);
        let m: Vec<bool> =
            (0..w * h).map(|i| (1..7).contains(&(i % w)) && (1..5).contains(&(i / w))).collect();
        let e = erode(&m, w, h);
        let kept: Vec<usize> = (0..w * h).filter(|&i| e[i]).collect();
        // Rows 2..=3, columns 2..=5.
        assert_eq!(kept, vec![18, 19, 20, 21, 26, 27, 28, 29]);
    }

    #[test]
    fn small_holes_close_and_edges_do_not() {
        let (w, h) = (10, 10);
        let mut m = vec![true; w * h];
        m[5 * w + 5] = false; // a one-pixel decode hole
        for y in 0..h {
            m[y * w + 9] = false; // the surface's edge
        }
        let c = close_small_gaps(&m, w, h);
        assert!(c[5 * w + 5]);
        assert!((0..h).all(|y| !c[y * w + 9]));
    }

    #[test]
    fn bound_is_never_below_the_model_and_grows_at_grazing_points() {
        let s = synthetic_stage(3, 5);
        let g = Geometry::new(&s.model);
        let b = bound_eta(&s.model, &g);
        let mut raised = 0;
        for (e, b) in g.eta.iter().zip(&b) {
            assert!(*b >= *e, "bound {b} below the model's {e}");
            if *e > 0.0 && *b > 1.02 * *e {
                raised += 1;
            }
            if *e == 0.0 {
                assert_eq!(*b, 0.0);
            }
        }
        assert!(raised > 0, "a curved synthetic object has points where the bound must exceed the model");
    }

    #[test]
    fn known_pixels_lie_inside_the_lit_footprints() {
        let s = synthetic_stage(2, 3);
        let g = Geometry::new(&s.model);
        for k in 0..2 {
            let l = landing(&s.model, &g, k);
            let known = l.known.iter().filter(|&&v| v).count();
            assert!(known > 0);
            let w = l.width as usize;
            for (i, &kn) in l.known.iter().enumerate() {
                if kn {
                    let (x, y) = (i % w, i / w);
                    let near = (y.saturating_sub(MAX_GAP)..=y + MAX_GAP).any(|yy| {
                        (x.saturating_sub(MAX_GAP)..=x + MAX_GAP)
                            .any(|xx| l.near_camera_pixel.get(yy * w + xx).is_some_and(|&c| c != u32::MAX))
                    });
                    assert!(near, "known pixel ({x}, {y}) with no footprint near it");
                }
            }
            // The ring surrounds the known set and is disjoint from it.
            for (x, y) in l.ring() {
                assert!(!l.known[y as usize * l.width as usize + x as usize]);
            }
        }
    }
}
