//! The light guarantee (brief §5.1, fix 3): the irradiance per unit area at every point of
//! the light certificate is recomputed from the final 8-bit frames — through the responses,
//! the black level, the room light and each point's measured footprint, taking the brightest
//! pixel of the footprint (conservative) — and any point over the limit has the pixels that
//! can light it dimmed, rounding down, until nothing is over. The formula that made the
//! frames is not trusted.

use image::RgbImage;
use rayon::prelude::*;
use restage_shared::light::Coverage;

use super::certificate::Certificate;
use super::response::InverseResponse;
use crate::stage_model::StageModel;

/// The scalar the bound applies to: the largest of the three channel irradiances (each in
/// full-white lux units). Conservative: never below the photometric illuminance of a mix of
/// the primaries, whatever their luminance shares (`LuxWeighting::MaxChannel` in the
/// bundle's light model).
pub fn bound_lux(e: [f64; 3]) -> f64 {
    e[0].max(e[1]).max(e[2])
}

/// Per certificate point, the light no frame can remove (black level of every projector that
/// reaches it, lux per channel; room light excluded).
pub fn floor_lux(stage: &StageModel, cert: &Certificate) -> Vec<[f64; 3]> {
    (0..cert.points())
        .into_par_iter()
        .map(|i| {
            let mut f = [0.0f64; 3];
            for (k, (_, _, blocks)) in cert.projectors.iter().enumerate() {
                let b = blocks[i];
                if !b.is_empty() {
                    for (c, fc) in f.iter_mut().enumerate() {
                        *fc += b.lux_per_unit as f64 * stage.projectors[k].black[c] as f64;
                    }
                }
            }
            f
        })
        .collect()
}

/// Per certificate point, the projected light above black (lux per channel): per projector,
/// the coefficient times the brightest output in the point's block, per channel.
pub fn projected_lux(cert: &Certificate, inv: &[[InverseResponse; 3]], frames: &[RgbImage]) -> Vec<[f64; 3]> {
    (0..cert.points())
        .into_par_iter()
        .map(|i| {
            let mut e = [0.0f64; 3];
            for (k, (w, _, blocks)) in cert.projectors.iter().enumerate() {
                let b = blocks[i];
                if b.is_empty() {
                    continue;
                }
                let raw = frames[k].as_raw();
                let mut m = [0u8; 3];
                for y in b.y0 as usize..b.y1 as usize {
                    let row =
                        &raw[(y * *w as usize + b.x0 as usize) * 3..(y * *w as usize + b.x1 as usize) * 3];
                    for p in row.chunks_exact(3) {
                        m = [m[0].max(p[0]), m[1].max(p[1]), m[2].max(p[2])];
                    }
                }
                for c in 0..3 {
                    e[c] += b.lux_per_unit as f64 * inv[k][c].output(m[c]) as f64;
                }
            }
            e
        })
        .collect()
}

/// What enforcing the bound did.
#[derive(Clone, Debug, Default)]
pub struct Enforcement {
    /// Check-and-correct rounds run (the last one found nothing over the limit).
    pub rounds: u32,
    /// Projector pixels dimmed by the correction, all projectors together.
    pub dimmed_pixels: usize,
    /// Per certificate point, the recomputed irradiance (lux, room light included).
    pub lux: Vec<f64>,
}

/// Rounds of dimming before the fallback (pixels that can light a still-offending point go
/// black). One round suffices in exact arithmetic: dimming only lowers light anywhere.
const MAX_ROUNDS: u32 = 8;

/// Recomputes and corrects `frames` in place until every certificate point is at or below
/// `limit` lux. The floor (`floor` plus room light) must itself be within the limit (checked
/// by the caller), so the fallback — every block of an offending point black — terminates.
pub fn enforce(
    cert: &Certificate,
    inv: &[[InverseResponse; 3]],
    floor: &[[f64; 3]],
    frames: &mut [RgbImage],
    limit: f64,
) -> Enforcement {
    let mut report = Enforcement::default();
    let room = cert.ambient_lux;
    loop {
        report.rounds += 1;
        let proj = projected_lux(cert, inv, frames);
        let total = |i: usize| room + bound_lux(std::array::from_fn(|c| floor[i][c] + proj[i][c]));
        // Per point, the factor its projected light must be scaled by (1 = fine).
        let factor: Vec<f32> = (0..cert.points())
            .into_par_iter()
            .map(|i| {
                if total(i) <= limit {
                    return 1.0;
                }
                let mut g = 1.0f64;
                for c in 0..3 {
                    if room + floor[i][c] + proj[i][c] > limit && proj[i][c] > 0.0 {
                        g = g.min(((limit - room - floor[i][c]) / proj[i][c]).max(0.0));
                    }
                }
                // A hair below, so float rounding cannot leave it a hair above.
                (g * (1.0 - 1e-5)) as f32
            })
            .collect();
        let offenders = factor.iter().filter(|&&f| f < 1.0).count();
        if offenders == 0 {
            report.lux = (0..cert.points()).map(total).collect();
            return report;
        }
        let fallback = report.rounds >= MAX_ROUNDS;
        tracing::debug!(round = report.rounds, offenders, fallback, "light bound: correcting frames");
        let dimmed: usize = frames
            .par_iter_mut()
            .zip(&cert.projectors)
            .enumerate()
            .map(|(k, (frame, (w, h, blocks)))| {
                let (w, h) = (*w as usize, *h as usize);
                let mut pf = vec![1.0f32; w * h];
                for (b, &f) in blocks.iter().zip(&factor) {
                    if f < 1.0 && !b.is_empty() {
                        for y in b.y0 as usize..b.y1 as usize {
                            for v in &mut pf[y * w + b.x0 as usize..y * w + b.x1 as usize] {
                                *v = v.min(f);
                            }
                        }
                    }
                }
                let raw: &mut [u8] = frame;
                let mut count = 0;
                for (px, &f) in pf.iter().enumerate() {
                    if f >= 1.0 {
                        continue;
                    }
                    let mut changed = false;
                    for c in 0..3 {
                        let v = &mut raw[px * 3 + c];
                        let new = if fallback { 0 } else { inv[k][c].floor(f * inv[k][c].output(*v)) };
                        changed |= new != *v;
                        *v = new;
                    }
                    count += changed as usize;
                }
                count
            })
            .sum();
        report.dimmed_pixels += dimmed;
    }
}

/// Sets to black every lit pixel whose light would land on surface the model does not know
/// (`Landing::known` false). Only lowers light. Returns how many pixels it changed.
pub fn darken_unknown(landings: &[super::landing::Landing], frames: &mut [RgbImage]) -> usize {
    frames
        .par_iter_mut()
        .zip(landings)
        .map(|(frame, l)| {
            let mut n = 0;
            for (px, &known) in frame.pixels_mut().zip(&l.known) {
                if !known && px.0 != [0; 3] {
                    px.0 = [0; 3];
                    n += 1;
                }
            }
            n
        })
        .sum()
}

/// Sets to black every lit pixel the certificate does not vouch for in the appliance's light
/// check (`Coverage`): pixels outside every block (none, by construction: a point's block holds
/// its splat support) or inside only blocks whose coefficient is under the appliance's floor
/// (light that reaches only grazing points of a very far stage). Only lowers light, so the
/// bound still holds. Returns how many pixels it changed.
pub fn darken_unvouched(coverage: &Coverage, frames: &mut [RgbImage]) -> usize {
    frames
        .par_iter_mut()
        .enumerate()
        .map(|(k, frame)| {
            let w = frame.width();
            let mut n = 0;
            for (i, px) in frame.pixels_mut().enumerate() {
                let (x, y) = (i as u32 % w, i as u32 / w);
                if px.0 != [0; 3] && !coverage.is_vouched(k, x, y) {
                    px.0 = [0; 3];
                    n += 1;
                }
            }
            n
        })
        .sum()
}
