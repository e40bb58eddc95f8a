//! Footprint-aware compensation: the formula's frames refined so that the *blurred,
//! superimposed* light of all projectors matches each point's demand, using the footprints
//! the transport step measured (the idea of Aliaga et al. 2012 and of Zhang & Nayar's defocus
//! compensation). The formula treats every projector pixel as landing on one camera pixel;
//! a real pixel lands as a blurred blob, so light meant for a dark chip spills into its
//! rim (a bright halo) and the chip stays dim. Here the modelled light of the frames is
//! compared with the demand and the difference sent back through the footprints, a few
//! rounds of projected Landweber iteration that keep every output within `0..=1`, each
//! point's shortfall weighed as the eye sees it (times its gain, over the light it shows to
//! the 2/3), so that a chip's bare clay, which needs far more light than the paint beside it,
//! does not buy its last few percent with a halo on its neighbours.
//!
//! The demand is the formula's (scale, nearest view out of reach, headroom under the
//! bound), so the refined frames aim at the same light. Sharper frames have brighter peaks,
//! and the light certificate charges every point with the brightest pixel that can reach it;
//! so each
//! pixel is held under a cap that keeps every certificate point whose block holds it within
//! the limit (`caps`), and the refinement never leaves the guarantee more to dim than the
//! formula did. The guarantee is still enforced on the result as on any frames: the bound
//! holds whatever the refinement does.
//!
//! The same light model predicts what the camera sees from any frames ([`modelled_view`]):
//! `--auto-clip` judges each candidate clip fraction's frames by it.

use image::RgbImage;
use rayon::prelude::*;

use super::{Draft, Params, Prepared};
use crate::stage_model::StageModel;

/// Rounds of refinement when the user does not say. The mismatch falls fastest in the first
/// few and then by 0.4-1.5 % of itself a round: on nine calibrated captures at 150 lx, 16
/// rounds lowered every mean and p95 against 8 and 32 lowered them a little more, at 0.1 s
/// a round for three 1400x1050 frames on 2 cores (README, "Compensation").
pub const DEFAULT_ROUNDS: u32 = 16;

/// Over-relaxation of each round's correction.
const RELAX: f32 = 1.5;

/// The least light seen (camera units, 1 = full scale) a point's weight is taken at, so that
/// a point asking for none does not take all the weight.
const DARKEST_SEEN: f32 = 1e-4;

/// What a refinement did, for the report and the log.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Refinement {
    pub rounds: u32,
    /// Modelled mismatch of the formula's frames (each pixel held under its cap, as the
    /// guarantee would dim it): the sum over work points and channels of
    /// |demand - modelled light|, over the sum of the demand (a fraction).
    pub mismatch_before: f64,
    /// The same after the last round.
    pub mismatch_after: f64,
}

/// A camera pixel's measured shares from one projector must add up to at least this for its
/// footprint to count as measured (the transport step misses dots smeared at grazing angles
/// and dots it cannot fill); below it the formula's own assumption stands there — the pixel gets
/// the output at its correspondence — and the refinement leaves that projector's share alone.
pub const MIN_MEASURED_SHARE: f32 = 0.5;

/// One projector's transport turned around: per camera pixel, the projector pixels that
/// reach it and the light each output unit gives it there (its measured share, the shares
/// made to add up to 1, times the pixel's coefficient `eta`; compressed sparse rows over
/// camera pixels), and the sum of its measured shares (0 where none was measured).
struct Columns {
    start: Vec<u32>,
    pixel: Vec<u32>,
    light: Vec<f32>,
    sum: Vec<f32>,
}

impl Columns {
    fn measured(&self, i: usize) -> bool {
        self.sum[i] >= MIN_MEASURED_SHARE
    }
}

fn columns(stage: &StageModel, prep: &Prepared, k: usize) -> Columns {
    let t = &stage.transport[k];
    let (n, kn) = (prep.geometry.points, prep.geometry.projectors);
    let keep = |e: usize| {
        let j = t.camera_pixel[e] as usize;
        j < n && t.weight[e] > 0.0 && prep.geometry.eta[j * kn + k] > 0.0
    };
    let mut start = vec![0u32; n + 1];
    let mut sum = vec![0f32; n];
    for e in 0..t.camera_pixel.len() {
        if keep(e) {
            start[t.camera_pixel[e] as usize + 1] += 1;
            sum[t.camera_pixel[e] as usize] += t.weight[e];
        }
    }
    for j in 0..n {
        start[j + 1] += start[j];
    }
    let total = start[n] as usize;
    let (mut pixel, mut light) = (vec![0u32; total], vec![0f32; total]);
    let mut next = start.clone();
    for q in 0..t.row_start.len() - 1 {
        for e in t.row_start[q] as usize..t.row_start[q + 1] as usize {
            if keep(e) {
                let j = t.camera_pixel[e] as usize;
                let at = next[j] as usize;
                (pixel[at], light[at]) = (q as u32, t.weight[e] / sum[j] * prep.geometry.eta[j * kn + k]);
                next[j] += 1;
            }
        }
    }
    Columns { start, pixel, light, sum }
}

/// Bilinear sample of a projector's outputs at `c` (pixel centres at integers), clamped to
/// the image: the light the formula assumes a point gets.
fn bilinear(out: &[[f32; 3]], w: usize, h: usize, c: [f32; 2]) -> [f32; 3] {
    let axis = |t: f32, n: usize| {
        let t = t.clamp(0.0, (n - 1) as f32);
        let i = (t as usize).min(n.saturating_sub(2));
        (i, (i + 1).min(n - 1), t - i as f32)
    };
    let ((x0, x1, fx), (y0, y1, fy)) = (axis(c[0], w), axis(c[1], h));
    let at = |x: usize, y: usize| out[y * w + x];
    std::array::from_fn(|ch| {
        (at(x0, y0)[ch] * (1.0 - fx) + at(x1, y0)[ch] * fx) * (1.0 - fy)
            + (at(x0, y1)[ch] * (1.0 - fx) + at(x1, y1)[ch] * fx) * fy
    })
}

/// Relative outputs above black of each projector's 8-bit frame, per pixel.
fn outputs(stage: &StageModel, frames: &[RgbImage]) -> Vec<Vec<[f32; 3]>> {
    frames
        .iter()
        .zip(&stage.projectors)
        .map(|(f, p)| f.pixels().map(|q| std::array::from_fn(|c| p.response[c][q.0[c] as usize])).collect())
        .collect()
}

/// The light the outputs `out` give camera pixel `i` above black, in units of the gain (what
/// [`demands`] asks for): per projector its coefficient times the output through the pixel's
/// measured footprint (`cols`; empty when none was measured) or, where none is, at its
/// correspondence, as the formula assumes.
fn delivered(
    stage: &StageModel,
    geom: &super::geometry::Geometry,
    cols: &[Columns],
    out: &[Vec<[f32; 3]>],
    i: usize,
) -> [f32; 3] {
    let kn = geom.projectors;
    let mut e = [0.0f32; 3];
    for (k, out) in out.iter().enumerate() {
        let eta = geom.eta[i * kn + k];
        if eta <= 0.0 {
            continue;
        }
        match cols.get(k).filter(|col| col.measured(i)) {
            Some(col) => {
                for a in col.start[i] as usize..col.start[i + 1] as usize {
                    let o = out[col.pixel[a] as usize];
                    (0..3).for_each(|c| e[c] += col.light[a] * o[c]);
                }
            }
            None => {
                let p = &stage.projectors[k];
                let o = bilinear(out, p.width as usize, p.height as usize, geom.coord[i * kn + k]);
                (0..3).for_each(|c| e[c] += eta * o[c]);
            }
        }
    }
    e
}

/// Every projector's measured footprints turned around per camera pixel (empty where the
/// model has none, and the formula's assumption stands): built once, read by the refinement
/// and by each [`modelled_view`].
pub struct Footprints(Vec<Columns>);

impl Footprints {
    pub fn of(stage: &StageModel, prep: &Prepared) -> Self {
        Footprints(if has_footprints(stage) {
            (0..prep.geometry.projectors).into_par_iter().map(|k| columns(stage, prep, k)).collect()
        } else {
            Vec::new()
        })
    }
}

/// What the stage model says the camera sees at each of the points `idx` when the projectors
/// show `frames`: black level and room light (`stage.ambient`) plus the gain times the
/// delivered light, blurred through the measured footprints where the model has them.
pub fn modelled_view(
    stage: &StageModel,
    prep: &Prepared,
    footprints: &Footprints,
    frames: &[RgbImage],
    idx: &[u32],
) -> Vec<[f64; 3]> {
    let out = outputs(stage, frames);
    idx.par_iter()
        .map(|&i| {
            let i = i as usize;
            let e = delivered(stage, &prep.geometry, &footprints.0, &out, i);
            std::array::from_fn(|c| {
                f64::from(stage.ambient[i][c]) + f64::from(stage.gain[i][c]) * f64::from(e[c])
            })
        })
        .collect()
}

/// Whether every projector has a measured transport of its size.
pub fn has_footprints(stage: &StageModel) -> bool {
    stage.projectors.iter().zip(&stage.transport).all(|(p, t)| {
        t.row_start.len() == p.width as usize * p.height as usize + 1
            && t.row_start.last().is_some_and(|&e| e as usize == t.camera_pixel.len())
            && t.camera_pixel.len() == t.weight.len()
    }) && stage.transport.len() == stage.projectors.len()
}

/// Refines `draft.frames` in place over `params.footprint_rounds` rounds towards the demand
/// they were made for (`draft.demand`), through the stage's `footprints`
/// ([`Footprints::of`]); `None` (frames untouched) when no rounds are asked for or the model
/// has no measured footprints.
pub fn refine(
    stage: &StageModel,
    prep: &Prepared,
    footprints: &Footprints,
    params: &Params,
    draft: &mut Draft,
) -> Option<Refinement> {
    if params.footprint_rounds == 0 || !has_footprints(stage) {
        return None;
    }
    let geom = &prep.geometry;
    let (n, kn) = (geom.points, geom.projectors);
    // Per camera pixel: its demand, NaN where compensation does not work.
    let mut want = vec![[f32::NAN; 3]; n];
    for (&i, d) in draft.idx.iter().zip(&draft.demand) {
        want[i as usize] = d.map(|v| v as f32);
    }
    let cols = &footprints.0;
    let mut out = outputs(stage, &draft.frames);

    // Per camera pixel, demand minus the light the footprints say the outputs give.
    let residual = |out: &[Vec<[f32; 3]>]| -> Vec<[f32; 3]> {
        (0..n)
            .into_par_iter()
            .map(|i| {
                if want[i][0].is_nan() {
                    return [0.0; 3];
                }
                let e = delivered(stage, geom, cols, out, i);
                std::array::from_fn(|c| want[i][c] - e[c])
            })
            .collect()
    };
    let mismatch = |res: &[[f32; 3]]| -> f64 {
        let (mut miss, mut total) = (0.0f64, 0.0f64);
        for (r, w) in res.iter().zip(&want) {
            if !w[0].is_nan() {
                miss += r.iter().map(|v| v.abs() as f64).sum::<f64>();
                total += w.iter().map(|&v| v as f64).sum::<f64>();
            }
        }
        if total > 0.0 { miss / total } else { 0.0 }
    };

    // The formula's frames where the certificate passes, as the guarantee would leave them
    // (a pixel over its cap dimmed to it): the starting point, and the mismatch to beat.
    let caps = caps(prep, &out, params.limit());
    for (o, cap) in out.iter_mut().zip(&caps) {
        o.par_iter_mut().zip(cap).for_each(|(o, cap)| (0..3).for_each(|c| o[c] = o[c].min(cap[c])));
    }
    let mut res = residual(&out);
    let before = mismatch(&res);
    // How much each point's shortfall counts, per channel: as the eye sees it. Times the gain
    // it is what the camera sees (in light alone, a chip's bare clay, which asks for far more
    // light than the paint beside it, outweighed the halo its light spills there); and
    // lightness (CIELAB's L*) goes as the cube root of the light seen, so a step in it weighs
    // as that light to the -2/3 (the dark paint under the black level needs its share too).
    // Squared, as the shortfall is.
    let weigh: Vec<[f32; 3]> = (0..n)
        .into_par_iter()
        .map(|i| {
            std::array::from_fn(|c| {
                let g = stage.gain[i][c];
                let seen = (stage.ambient[i][c] + g * want[i][c].max(0.0)).max(DARKEST_SEEN);
                g * g * seen.powf(-4.0 / 3.0)
            })
        })
        .collect();
    // Each projector takes its Eq. 12 share of every point's shortfall, in its own output
    // units, averaged over its pixel's footprint on the worked points, each point weighed as
    // above: projector pixel q moves by RELAX `sum_e w_e v_i s_ik r_i / sum_e w_e v_i` over
    // its transport entries e, where i is the entry's camera pixel, w_e its weight over i's
    // sum of measured shares, v_i the point's weight, s_ik = Eq. 12 weight / eta_ik the
    // projector's share of the point's light and r_i the shortfall. Only r_i changes from
    // round to round, so the rest is worked out once: per camera pixel `v_i s_ik / sum` (`pull`;
    // 0 where the projector does not work it) and per projector pixel RELAX over the
    // denominator (`step`), and a round is one pass over the entries.
    let (pull, step): (Vec<_>, Vec<_>) = (0..kn)
        .map(|k| {
            let col = &cols[k];
            let (pull, norm): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..n)
                .into_par_iter()
                .map(|i| {
                    let eta = geom.eta[i * kn + k];
                    if want[i][0].is_nan() || !col.measured(i) || eta <= 0.0 {
                        return ([0.0; 3], [0.0; 3]);
                    }
                    let (v, share) = (weigh[i], draft.weights[i * kn + k] / eta);
                    (v.map(|v| v * share / col.sum[i]), v.map(|v| v / col.sum[i]))
                })
                .unzip();
            let t = &stage.transport[k];
            let step = (0..t.row_start.len() - 1)
                .into_par_iter()
                .map(|q| {
                    let mut den = [0.0f32; 3];
                    for e in t.row_start[q] as usize..t.row_start[q + 1] as usize {
                        if let Some(v) = norm.get(t.camera_pixel[e] as usize) {
                            (0..3).for_each(|c| den[c] += t.weight[e] * v[c]);
                        }
                    }
                    den.map(|d| if d > 0.0 { RELAX / d } else { 0.0 })
                })
                .collect::<Vec<[f32; 3]>>();
            (pull, step)
        })
        .unzip();
    // Per camera pixel, this round: its pull on the projector times its shortfall.
    let mut pulled = vec![[0.0f32; 3]; n];
    for _ in 0..params.footprint_rounds {
        for (k, o) in out.iter_mut().enumerate() {
            pulled
                .par_iter_mut()
                .zip(&pull[k])
                .zip(&res)
                .for_each(|((g, p), r)| *g = std::array::from_fn(|c| p[c] * r[c]));
            let t = &stage.transport[k];
            o.par_iter_mut().zip(&step[k]).enumerate().for_each(|(q, (o, step))| {
                if step.iter().all(|&s| s == 0.0) {
                    return;
                }
                let mut num = [0.0f32; 3];
                for e in t.row_start[q] as usize..t.row_start[q + 1] as usize {
                    if let Some(g) = pulled.get(t.camera_pixel[e] as usize) {
                        (0..3).for_each(|c| num[c] += t.weight[e] * g[c]);
                    }
                }
                for c in 0..3 {
                    if step[c] > 0.0 {
                        o[c] = (o[c] + step[c] * num[c]).clamp(0.0, caps[k][q][c]);
                    }
                }
            });
        }
        res = residual(&out);
    }
    let after = mismatch(&res);
    draft.frames = (0..kn)
        .into_par_iter()
        .map(|k| {
            let p = &stage.projectors[k];
            let inv = &prep.inverse[k];
            let mut frame = RgbImage::new(p.width, p.height);
            for ((px, o), cap) in frame.pixels_mut().zip(&out[k]).zip(&caps[k]) {
                px.0 = std::array::from_fn(|c| {
                    let v = inv[c].nearest(o[c]);
                    if inv[c].output(v) > cap[c] { inv[c].floor(cap[c]) } else { v }
                });
            }
            frame
        })
        .collect();
    tracing::info!(
        rounds = params.footprint_rounds,
        mismatch_before = before,
        mismatch_after = after,
        "compensation: refined on the measured footprints"
    );
    Some(Refinement { rounds: params.footprint_rounds, mismatch_before: before, mismatch_after: after })
}

/// Per projector pixel and channel, the most relative output it may take so that no
/// certificate point goes over `limit`: a point's light is its floor and room light plus, per
/// projector, its coefficient times the brightest output in its block; what the point has to
/// spare at `out` is shared evenly among the projectors that reach it, and a pixel's cap is
/// the lowest any of its points allows (at most 1). Where `out` is already over, the cap is
/// below its current brightest pixel, as the guarantee would dim it.
fn caps(prep: &Prepared, out: &[Vec<[f32; 3]>], limit: f64) -> Vec<Vec<[f32; 3]>> {
    let cert = &prep.certificate;
    let kn = cert.projectors.len();
    let room = cert.ambient_lux;
    // Per point and projector, the cap its block's pixels take (infinite: no limit there).
    let per_point: Vec<[f32; 3]> = (0..cert.points())
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut brightest = vec![[0.0f32; 3]; kn];
            let mut reach = 0usize;
            let mut light = [0.0f64; 3];
            for (k, (w, _, blocks)) in cert.projectors.iter().enumerate() {
                let b = blocks[i];
                if b.is_empty() {
                    continue;
                }
                reach += 1;
                for y in b.y0 as usize..b.y1 as usize {
                    for o in &out[k][y * *w as usize + b.x0 as usize..y * *w as usize + b.x1 as usize] {
                        (0..3).for_each(|c| brightest[k][c] = brightest[k][c].max(o[c]));
                    }
                }
                (0..3).for_each(|c| light[c] += b.lux_per_unit as f64 * brightest[k][c] as f64);
            }
            let spare: [f64; 3] = std::array::from_fn(|c| limit - room - prep.floor[i][c] - light[c]);
            (0..kn).map(move |k| {
                let coef = cert.projectors[k].2[i].lux_per_unit as f64;
                std::array::from_fn(|c| {
                    if coef > 0.0 {
                        (brightest[k][c] as f64 + spare[c] / reach.max(1) as f64 / coef).max(0.0) as f32
                    } else {
                        f32::INFINITY
                    }
                })
            })
        })
        .collect();
    cert.projectors
        .par_iter()
        .enumerate()
        .map(|(k, (w, h, blocks))| {
            let mut cap = vec![[1.0f32; 3]; (*w * *h) as usize];
            for (i, b) in blocks.iter().enumerate() {
                if b.is_empty() {
                    continue;
                }
                let v = per_point[i * kn + k];
                for y in b.y0 as usize..b.y1 as usize {
                    for q in &mut cap[y * *w as usize + b.x0 as usize..y * *w as usize + b.x1 as usize] {
                        (0..3).for_each(|c| q[c] = q[c].min(v[c]));
                    }
                }
            }
            cap
        })
        .collect()
}
