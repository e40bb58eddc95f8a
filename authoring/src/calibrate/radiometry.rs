//! Radiometric calibration (paper §5.2, after Nayar et al. 2003 with a diagonal colour-mixing
//! matrix): from gray ramps per projector channel, a monotonic response curve per projector
//! and channel; the per-camera-pixel gain (camera value per lux) and ambient offset; the
//! measured off-diagonal colour leakage.
//!
//! Model per camera pixel p, channel c, projector k showing level v on channel c only:
//! `I(p) = lit_k(p) * response_k,c(v) + black(p)`, where `lit_k = full - black` is the pixel's
//! response to the full (255) level. So each ramp image gives one ratio of sums over all
//! well-lit, unsaturated pixels, which is the response at that level.

use std::collections::BTreeMap;

use rayon::prelude::*;
use thiserror::Error;

use crate::calibrate::transport::SATURATED;
use crate::imgio::LinearImage;
use crate::stage_model::StageModel;

#[derive(Debug, Error)]
pub enum RadiometryError {
    #[error("projector {projector}: {image} is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    Size { projector: usize, image: String, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("projector {projector}: ramp channel {channel} is invalid (expected 0..=2)")]
    Channel { projector: usize, channel: u8 },
    #[error(
        "projector {projector}, channel {channel}: no pixel is lit above the noise in {full} \
         (is the projector on and aimed at the object?)"
    )]
    NotLit { projector: usize, channel: usize, full: String },
    #[error(
        "projector {projector}, channel {channel}: {full} is saturated on {percent:.1} % of the lit \
         pixels (expected < 50 %); lower the camera exposure"
    )]
    Saturated { projector: usize, channel: usize, full: String, percent: f64 },
    #[error(
        "projector {projector}, channel {channel}: only {found} ramp levels between 1 and 254 \
         (expected at least 2) — the response curve cannot be interpolated"
    )]
    TooFewLevels { projector: usize, channel: usize, found: usize },
    #[error("projector {projector}, channel {channel}: level {level} appears twice ({first} and {second})")]
    DuplicateLevel { projector: usize, channel: usize, level: u8, first: String, second: String },
    #[error("gain: {0}")]
    Gain(String),
}

/// The widest stretch of levels without a ramp image that is fitted without a warning: the
/// curve is smooth in log-log, and the acquisition's default levels (`patterns::ramp_levels`,
/// 9 or more) are at most 60 apart, at the bright end.
const MAX_LEVEL_GAP: u8 = 64;

/// Standard errors by which a ramp level's mean output must exceed black to be fitted.
const SIGNIFICANT: f64 = 3.0;

/// The sums one ramp image contributes.
#[derive(Clone, Debug)]
pub struct LevelSample {
    pub channel: u8,
    pub level: u8,
    pub name: String,
    /// Per camera channel: sum over that channel's mask of `I - black`.
    pub sum: [f64; 3],
    /// Per camera channel: sum over that channel's mask of `(I - black)^2`.
    pub sum_sq: [f64; 3],
    /// Saturated pixels inside the ramp channel's mask.
    pub saturated: usize,
}

/// Collects a projector's ramp images (in any order, one at a time, so memory stays small)
/// and fits its response curves.
#[derive(Clone, Debug)]
pub struct ResponseBuilder {
    pub projector: usize,
    width: u32,
    height: u32,
    black: Vec<[f32; 3]>,
    /// `full - black` per channel, from each channel's 255 ramp (or the white image).
    lit: Vec<[f32; 3]>,
    /// Per channel: pixels used (well lit, not saturated in the full image).
    mask: [Vec<bool>; 3],
    /// Per channel: sum of `lit` over the mask.
    lit_sum: [f64; 3],
    full_names: [String; 3],
    samples: [BTreeMap<u8, LevelSample>; 3],
    pub warnings: Vec<String>,
}

/// What radiometric calibration learns about one projector.
#[derive(Clone, Debug)]
pub struct ProjectorRadiometry {
    /// Per channel, 256 entries: strictly increasing, 0 at level 0, 1 at level 255.
    pub response: [Vec<f32>; 3],
    /// Per channel, the measured (level, relative output) points the curve goes through.
    pub measured: [Vec<(u8, f32)>; 3],
    /// `leakage[c_cam][c_proj]`: camera channel `c_cam`'s response to projector channel
    /// `c_proj` at full level, relative to its response to its own channel (diagonal = 1).
    pub leakage: [[f32; 3]; 3],
    /// Per camera pixel and channel: `full - black`, the camera value added by full output.
    pub lit: Vec<[f32; 3]>,
    pub warnings: Vec<String>,
}

impl ProjectorRadiometry {
    /// Largest off-diagonal leakage.
    pub fn max_leakage(&self) -> f32 {
        let mut m = 0.0f32;
        for (a, row) in self.leakage.iter().enumerate() {
            for (b, v) in row.iter().enumerate() {
                if a != b {
                    m = m.max(v.abs());
                }
            }
        }
        m
    }
}

fn check_size(
    projector: usize,
    name: &str,
    img: &LinearImage,
    w: u32,
    h: u32,
) -> Result<(), RadiometryError> {
    if img.width != w || img.height != h {
        return Err(RadiometryError::Size {
            projector,
            image: name.into(),
            got_w: img.width,
            got_h: img.height,
            want_w: w,
            want_h: h,
        });
    }
    Ok(())
}

impl ResponseBuilder {
    /// `full[c]`: the image of channel c at level 255 (the ramp's top, or the white image) and
    /// its name. A pixel is used when its full response is at least `min_lit` above black and
    /// unsaturated.
    pub fn new(
        projector: usize,
        black: &LinearImage,
        full: [(&LinearImage, &str); 3],
        min_lit: f32,
    ) -> Result<Self, RadiometryError> {
        let (w, h) = (black.width, black.height);
        for (img, name) in full {
            check_size(projector, name, img, w, h)?;
        }
        let n = black.data.len();
        let mut lit = vec![[0.0f32; 3]; n];
        let mut mask: [Vec<bool>; 3] = std::array::from_fn(|_| vec![false; n]);
        let mut lit_sum = [0.0f64; 3];
        let mut warnings = Vec::new();
        for c in 0..3 {
            let (img, name) = full[c];
            let (mut lit_px, mut sat_px) = (0usize, 0usize);
            for i in 0..n {
                let l = img.data[i][c] - black.data[i][c];
                lit[i][c] = l;
                if l >= min_lit {
                    lit_px += 1;
                    if img.data[i][c] >= SATURATED {
                        sat_px += 1;
                    } else {
                        mask[c][i] = true;
                        lit_sum[c] += l as f64;
                    }
                }
            }
            if lit_px == 0 {
                return Err(RadiometryError::NotLit { projector, channel: c, full: name.into() });
            }
            let percent = 100.0 * sat_px as f64 / lit_px as f64;
            if percent >= 50.0 {
                return Err(RadiometryError::Saturated { projector, channel: c, full: name.into(), percent });
            }
            if sat_px > 0 {
                warnings.push(format!(
                    "projector {projector}, channel {c}: {name} is saturated on {percent:.2} % of the lit \
                     pixels; they are left out of the response fit and their gain is too low"
                ));
            }
        }
        Ok(Self {
            projector,
            width: w,
            height: h,
            black: black.data.clone(),
            lit,
            mask,
            lit_sum,
            full_names: full.map(|(_, n)| n.to_string()),
            samples: Default::default(),
            warnings,
        })
    }

    /// Measures one ramp image (pure, so images can be measured in parallel).
    pub fn measure(
        &self,
        channel: u8,
        level: u8,
        image: &LinearImage,
        name: &str,
    ) -> Result<LevelSample, RadiometryError> {
        if channel > 2 {
            return Err(RadiometryError::Channel { projector: self.projector, channel });
        }
        check_size(self.projector, name, image, self.width, self.height)?;
        let (mut sum, mut sum_sq) = ([0.0f64; 3], [0.0f64; 3]);
        let mut saturated = 0;
        for (i, (p, b)) in image.data.iter().zip(&self.black).enumerate() {
            for c in 0..3 {
                if self.mask[c][i] {
                    let d = (p[c] - b[c]) as f64;
                    sum[c] += d;
                    sum_sq[c] += d * d;
                    if c == channel as usize && p[c] >= SATURATED {
                        saturated += 1;
                    }
                }
            }
        }
        Ok(LevelSample { channel, level, name: name.into(), sum, sum_sq, saturated })
    }

    pub fn insert(&mut self, s: LevelSample) -> Result<(), RadiometryError> {
        let c = s.channel as usize;
        if s.saturated > 0 {
            self.warnings.push(format!(
                "projector {}: {}: {} saturated pixels at level {} of channel {c}",
                self.projector, s.name, s.saturated, s.level
            ));
        }
        if let Some(first) = self.samples[c].get(&s.level) {
            return Err(RadiometryError::DuplicateLevel {
                projector: self.projector,
                channel: c,
                level: s.level,
                first: first.name.clone(),
                second: s.name,
            });
        }
        self.samples[c].insert(s.level, s);
        Ok(())
    }

    /// Fits the curves; warns about wide gaps between captured levels.
    pub fn finish(mut self) -> Result<ProjectorRadiometry, RadiometryError> {
        let k = self.projector;
        let mut measured: [Vec<(u8, f32)>; 3] = Default::default();
        let mut response: [Vec<f32>; 3] = Default::default();
        let mut leakage = [[0.0f32; 3]; 3];
        for c in 0..3 {
            let inner = self.samples[c].keys().filter(|&&l| l != 0 && l != 255).count();
            if inner < 2 {
                return Err(RadiometryError::TooFewLevels { projector: k, channel: c, found: inner });
            }
            let ratio = |s: &LevelSample| (s.sum[c] / self.lit_sum[c]) as f32;
            // The fit takes the levels whose output stands out of the noise: a mean difference
            // from black of more than three standard errors over the pixels (the dark levels of
            // a noisy camera measure nothing, and the curve continues below the first level
            // that does as a power law).
            let n = self.mask[c].iter().filter(|&&m| m).count().max(2) as f64;
            let spread = |s: &LevelSample| (s.sum_sq[c] - s.sum[c] * s.sum[c] / n).max(0.0).sqrt();
            let kept: Vec<&LevelSample> =
                self.samples[c].values().filter(|s| s.sum[c] > SIGNIFICANT * spread(s)).collect();
            let significant: Vec<(u8, f32)> = kept.iter().map(|s| (s.level, ratio(s))).collect();
            // A level brighter than a higher one beyond its noise and by a tenth is not noise:
            // an image filed under the wrong level, or the projector changed mode between shots.
            // The fit pools it flat (monotonic, reading those levels too bright, so frames light
            // them darker), and says so.
            for w in kept.windows(2) {
                let (a, b) = (w[0], w[1]);
                if a.sum[c] > 1.1 * b.sum[c] && a.sum[c] - b.sum[c] > SIGNIFICANT * (spread(a) + spread(b)) {
                    self.warnings.push(format!(
                        "projector {k}, channel {c}: level {} ({}) measured brighter than level {} ({}): \
                         {:.4} against {:.4} of full output; an image filed under the wrong level or \
                         out of order? The response is pooled flat there",
                        a.level,
                        a.name,
                        b.level,
                        b.name,
                        ratio(a),
                        ratio(b),
                    ));
                }
            }
            let mut levels: Vec<u8> = self.samples[c].keys().copied().collect();
            levels.extend([0, 255]);
            levels.sort_unstable();
            levels.dedup();
            if let Some(gap) = levels.windows(2).map(|w| w[1] - w[0]).max().filter(|&g| g > MAX_LEVEL_GAP) {
                let missing: Vec<String> = levels
                    .windows(2)
                    .filter(|w| w[1] - w[0] == gap)
                    .map(|w| format!("{}..{}", w[0], w[1]))
                    .collect();
                self.warnings.push(format!(
                    "projector {k}, channel {c}: no ramp level captured in {} ({gap} levels apart; \
                     the curve is interpolated there)",
                    missing.join(", ")
                ));
            }
            // Leakage: the other camera channels at this channel's top captured level.
            let top = self.samples[c].values().next_back().expect("at least two levels");
            response[c] = fit_response(&significant);
            let r_top = response[c][top.level as usize].max(1e-6);
            for (cc, row) in leakage.iter_mut().enumerate() {
                row[c] = if cc == c { 1.0 } else { (top.sum[cc] / self.lit_sum[cc]) as f32 / r_top };
            }
            // Every level measured, noise included, for the plot.
            measured[c] = self.samples[c].values().map(|s| (s.level, ratio(s))).collect();
        }
        let _ = &self.full_names;
        Ok(ProjectorRadiometry { response, measured, leakage, lit: self.lit, warnings: self.warnings })
    }
}

/// A monotonic 256-entry response from measured `(level, relative output)` points: values
/// clamped to 0..=1, pooled to be non-decreasing (pool-adjacent-violators), interpolated with
/// monotone cubic Hermite splines (Fritsch–Carlson) in log level against log output, then made
/// strictly increasing so it can be inverted. `r[0] = 0` and `r[255] = 1` by definition
/// (outputs are relative to full above black).
///
/// Why log-log: a projector's response is close to a power law (a display gamma), which is a
/// straight line there, while a curve through the measured values themselves is nearly
/// straight between 0 and the first ramp level and reads the dark end several times too bright
/// (level 8 of a 2.2 gamma from levels 0, 32, ...: 4x). At a low light bound most frame values
/// are in that stretch. Below the lowest level measured above zero the curve continues as the
/// power law of the first measured stretch (its exponent at least 1: no display is brighter
/// near black than a straight line to it).
pub fn fit_response(points: &[(u8, f32)]) -> Vec<f32> {
    let mut pts: BTreeMap<u8, (f64, f64)> = BTreeMap::new();
    for &(l, v) in points {
        let e = pts.entry(l).or_insert((0.0, 0.0));
        e.0 += v.clamp(0.0, 1.0) as f64;
        e.1 += 1.0;
    }
    pts.insert(0, (0.0, 1.0));
    pts.insert(255, (1.0, 1.0));
    // Pool adjacent violators: blocks of (sum of values, weight, first level, last level).
    let mut blocks: Vec<(f64, f64, Vec<u8>)> = Vec::new();
    for (&l, &(s, n)) in &pts {
        blocks.push((s / n * n, n, vec![l]));
        while blocks.len() > 1 {
            let b = blocks.len();
            if blocks[b - 2].0 / blocks[b - 2].1 <= blocks[b - 1].0 / blocks[b - 1].1 {
                break;
            }
            let last = blocks.pop().expect("two blocks");
            let prev = blocks.last_mut().expect("one block");
            prev.0 += last.0;
            prev.1 += last.1;
            prev.2.extend(last.2);
        }
    }
    let xs: Vec<f64> = blocks.iter().flat_map(|b| b.2.iter().map(|&l| l as f64)).collect();
    let ys: Vec<f64> = blocks.iter().flat_map(|b| std::iter::repeat_n(b.0 / b.1, b.2.len())).collect();
    // The log-log curve starts at the lowest level with a positive output (255 always has 1).
    let first = (1..xs.len()).find(|&i| ys[i] > 0.0).expect("255 is measured as 1");
    let (lx, ly): (Vec<f64>, Vec<f64>) =
        xs[first..].iter().zip(&ys[first..]).map(|(x, y)| (x.ln(), y.ln())).unzip();
    let x0 = xs[first];
    let mut r: Vec<f64> = if lx.len() < 2 {
        // Nothing measured above black below full: a straight line from the last level
        // measured as black.
        let z = xs[first - 1];
        (0..256).map(|v| ((v as f64 - z) / (255.0 - z)).max(0.0)).collect()
    } else {
        let exponent = ((ly[1] - ly[0]) / (lx[1] - lx[0])).max(1.0);
        let upper = monotone_cubic(&lx, &ly, (x0 as usize..256).map(|v| (v as f64).ln()));
        (0..x0 as usize)
            .map(|v| ys[first] * (v as f64 / x0).powf(exponent))
            .chain(upper.into_iter().map(f64::exp))
            .collect()
    };
    // Strictly increasing, then renormalised so the ends stay exactly 0 and 1.
    let eps = 1e-6;
    for i in 1..256 {
        if r[i] < r[i - 1] + eps {
            r[i] = r[i - 1] + eps;
        }
    }
    let (lo, hi) = (r[0], r[255]);
    r.iter().map(|v| ((v - lo) / (hi - lo)) as f32).collect()
}

/// Fritsch–Carlson monotone cubic interpolation of sorted, non-decreasing points, evaluated at
/// `at` (at least two points).
fn monotone_cubic(xs: &[f64], ys: &[f64], at: impl Iterator<Item = f64>) -> Vec<f64> {
    let n = xs.len();
    let delta: Vec<f64> = (0..n - 1).map(|i| (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])).collect();
    let mut m = vec![0.0; n];
    m[0] = delta[0];
    m[n - 1] = delta[n - 2];
    for i in 1..n - 1 {
        m[i] = if delta[i - 1] * delta[i] <= 0.0 { 0.0 } else { (delta[i - 1] + delta[i]) / 2.0 };
    }
    for i in 0..n - 1 {
        if delta[i] == 0.0 {
            m[i] = 0.0;
            m[i + 1] = 0.0;
            continue;
        }
        let (a, b) = (m[i] / delta[i], m[i + 1] / delta[i]);
        let s = a * a + b * b;
        if s > 9.0 {
            let t = 3.0 / s.sqrt();
            m[i] = t * a * delta[i];
            m[i + 1] = t * b * delta[i];
        }
    }
    at.map(|x| {
        let i = match xs.partition_point(|&xi| xi <= x) {
            0 => 0,
            k => (k - 1).min(n - 2),
        };
        let h = xs[i + 1] - xs[i];
        let t = (x - xs[i]) / h;
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * ys[i]
            + (t3 - 2.0 * t2 + t) * h * m[i]
            + (-2.0 * t3 + 3.0 * t2) * ys[i + 1]
            + (t3 - t2) * h * m[i + 1]
    })
    .collect()
}

/// The fractional 8-bit input that gives relative output `y` on a strictly increasing
/// response (linear between entries; clamped to 0..=255).
pub fn invert_response(response: &[f32], y: f32) -> f32 {
    let n = response.len();
    if y <= response[0] {
        return 0.0;
    }
    if y >= response[n - 1] {
        return (n - 1) as f32;
    }
    let i = response.partition_point(|&r| r <= y).max(1) - 1;
    let (a, b) = (response[i], response[i + 1]);
    i as f32 + if b > a { (y - a) / (b - a) } else { 0.0 }
}

/// Ambient per camera pixel (camera value with every projector black): the mean of the
/// projectors' black images.
pub fn ambient_map(blacks: &[&LinearImage]) -> Vec<[f32; 3]> {
    let n = blacks[0].data.len();
    let k = blacks.len() as f32;
    (0..n)
        .map(|i| {
            let mut s = [0.0f32; 3];
            for b in blacks {
                for (c, v) in s.iter_mut().enumerate() {
                    *v += b.data[i][c] / k;
                }
            }
            s
        })
        .collect()
}

/// Full-white irradiance in lux from projector `k` at camera pixel `i` of `model`, from its
/// geometry, vignetting and `lux_at_1m` (above black); `None` where unknown or grazing.
pub fn full_irradiance(model: &StageModel, k: usize, i: usize) -> Option<f64> {
    let p = &model.projectors[k];
    let u = model.correspondences[k][i];
    let (x, n) = (model.points[i], model.normals[i]);
    if !(u[0].is_finite() && x[0].is_finite() && n[0].is_finite()) {
        return None;
    }
    let centre = p.centre();
    let to: [f64; 3] = std::array::from_fn(|j| centre[j] - x[j] as f64);
    let d = (to[0] * to[0] + to[1] * to[1] + to[2] * to[2]).sqrt();
    let cos = (n[0] as f64 * to[0] + n[1] as f64 * to[1] + n[2] as f64 * to[2]) / d;
    if cos < 0.05 {
        return None;
    }
    let vig = vignetting_at(p.width, p.height, &p.vignetting, u);
    Some(p.lux_at_1m * vig * cos / (d / 1000.0).powi(2))
}

/// Bilinear lookup of a projector's vignetting map at projector coordinate `u` (1 when empty).
pub fn vignetting_at(width: u32, height: u32, map: &[f32], u: [f32; 2]) -> f64 {
    if map.len() != width as usize * height as usize || map.is_empty() {
        return 1.0;
    }
    let x = (u[0] as f64).clamp(0.0, width as f64 - 1.0);
    let y = (u[1] as f64).clamp(0.0, height as f64 - 1.0);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(width as usize - 1), (y0 + 1).min(height as usize - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |xx: usize, yy: usize| map[yy * width as usize + xx] as f64;
    (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy)
        + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy
}

/// Per camera pixel gain (camera value per lux, per channel): the least-squares scale between
/// each projector's measured `lit` and its modelled full-white irradiance, over the projectors
/// that light the pixel (the brightest dominate). NaN where no projector lights it.
pub fn gain_map(model: &StageModel, lit: &[&[[f32; 3]]]) -> Result<Vec<[f32; 3]>, RadiometryError> {
    let n = model.pixel_count();
    if lit.len() != model.projectors.len() || lit.iter().any(|l| l.len() != n) {
        return Err(RadiometryError::Gain(format!(
            "{} lit maps for {} projectors (each {} pixels expected)",
            lit.len(),
            model.projectors.len(),
            n
        )));
    }
    Ok((0..n)
        .into_par_iter()
        .map(|i| {
            let (mut num, mut den) = ([0.0f64; 3], 0.0f64);
            for (k, l) in lit.iter().enumerate() {
                if let Some(e) = full_irradiance(model, k, i) {
                    for c in 0..3 {
                        num[c] += l[i][c] as f64 * e;
                    }
                    den += e * e;
                }
            }
            if den > 0.0 { num.map(|v| (v / den) as f32) } else { [f32::NAN; 3] }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    fn gamma(v: f32) -> f32 {
        (v / 255.0).powf(2.2)
    }

    /// Ramp images of a synthetic object: per-pixel albedo and light falloff, ambient, noise.
    fn scene(levels: &[u8], noise: f32, leak: f32) -> (ResponseBuilder, [Vec<f32>; 3]) {
        let (w, h) = (40, 30);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let strength: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let lit = if i % w < 4 { 0.0 } else { rng.gen_range(0.2f32..0.6) };
                [lit, lit * 0.8, lit * 0.7]
            })
            .collect();
        let truth: [Vec<f32>; 3] = [
            (0..256).map(|v| gamma(v as f32)).collect(),
            (0..256).map(|v| (v as f32 / 255.0).powf(1.8)).collect(),
            (0..256).map(|v| 0.5 * (v as f32 / 255.0) + 0.5 * gamma(v as f32)).collect(),
        ];
        let shot = |out: [f32; 3], rng: &mut ChaCha8Rng| {
            let mut img = LinearImage::new(w, h).unwrap();
            for (px, s) in img.data.iter_mut().zip(&strength) {
                *px = std::array::from_fn(|c| {
                    let mix = out[c] + leak * (out[(c + 1) % 3] + out[(c + 2) % 3]);
                    (0.03 + s[c] * mix + noise * rng.gen_range(-1.7f32..1.7)).clamp(0.0, 1.0)
                });
            }
            img
        };
        let black = shot([0.0; 3], &mut rng);
        let full: Vec<LinearImage> = (0..3)
            .map(|c| {
                let mut o = [0.0; 3];
                o[c] = 1.0;
                shot(o, &mut rng)
            })
            .collect();
        let mut b = ResponseBuilder::new(
            1,
            &black,
            [(&full[0], "r255.png"), (&full[1], "g255.png"), (&full[2], "b255.png")],
            0.05,
        )
        .unwrap();
        for c in 0..3u8 {
            for &l in levels {
                let mut o = [0.0; 3];
                o[c as usize] = truth[c as usize][l as usize];
                let img = shot(o, &mut rng);
                let s = b.measure(c, l, &img, &format!("proj1/ramp_c{c}_{l:03}.png")).unwrap();
                b.insert(s).unwrap();
            }
        }
        (b, truth)
    }

    fn max_error(fit: &[f32], truth: &[f32]) -> f32 {
        fit.iter().zip(truth).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max)
    }

    #[test]
    fn full_ramp_recovers_response_within_a_fraction_of_a_percent() {
        let levels: Vec<u8> = (1..=255).collect();
        let (b, truth) = scene(&levels, 0.003, 0.0);
        let r = b.finish().unwrap();
        for (c, t) in truth.iter().enumerate() {
            let e = max_error(&r.response[c], t);
            assert!(e < 0.003, "channel {c}: max error {e}");
        }
        assert!(r.max_leakage() < 0.01, "{:?}", r.leakage);
    }

    /// At a low light bound most frame values lie at the dark end: the light a level gives
    /// there, black level included (0.002 of full output, a 500:1 projector), must be right in
    /// relative terms, not only within a hundredth of full output. The default levels hold it
    /// for a power law and for a curve that straightens towards black; evenly spaced levels
    /// leave the latter to the fit's guess below level 32.
    #[test]
    fn the_dark_end_keeps_the_light_it_gives() {
        let black = 0.002f32;
        let worst = |levels: &[u8], noise: f32, c: usize| {
            let (b, truth) = scene(levels, noise, 0.0);
            let r = b.finish().unwrap();
            [2usize, 4, 8, 16, 24, 40]
                .iter()
                .map(|&v| ((black + r.response[c][v]) / (black + truth[c][v]) - 1.0).abs())
                .fold(0.0f32, f32::max)
        };
        for noise in [0.0005, 0.002] {
            // Gamma 2.2, gamma 1.8, half linear and half gamma 2.2.
            for c in 0..3 {
                let e = worst(&crate::patterns::ramp_levels(9), noise, c);
                assert!(e < 0.05, "default levels, noise {noise}, channel {c}: {:.1} % off", 100.0 * e);
            }
            let even: Vec<u8> = (0..9).map(|i| (i * 255 / 8) as u8).collect();
            let e = worst(&even, noise, 2);
            assert!(
                e > 0.10,
                "even levels, noise {noise}: the straightening curve is {:.1} % off",
                100.0 * e
            );
        }
    }

    /// A lying input that is well formed: the image of level 195 filed as level 20.
    #[test]
    fn a_ramp_image_filed_under_the_wrong_level_is_named() {
        let levels: Vec<u8> = crate::patterns::ramp_levels(9);
        let (mut b, _) = scene(&levels, 0.002, 0.0);
        assert!(b.clone().finish().unwrap().warnings.is_empty());
        let mut liar = b.samples[0][&195].clone();
        (liar.level, liar.name) = (20, "proj1/ramp_c0_195.png".into());
        b.insert(liar).unwrap();
        let r = b.finish().unwrap();
        let all = r.warnings.join("\n");
        assert!(
            all.contains("channel 0: level 20 (proj1/ramp_c0_195.png) measured brighter than level 36"),
            "{all}"
        );
        assert!(r.response[0].windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn sparse_ramp_is_interpolated_and_leakage_reported() {
        let levels: Vec<u8> = (0..16).map(|i| (i * 16) as u8).chain([255]).collect();
        let (b, truth) = scene(&levels, 0.002, 0.04);
        let r = b.finish().unwrap();
        for (c, t) in truth.iter().enumerate() {
            let e = max_error(&r.response[c], t);
            assert!(e < 0.01, "channel {c}: max error {e}");
        }
        for (a, row) in r.leakage.iter().enumerate() {
            for (bb, v) in row.iter().enumerate() {
                let want = if a == bb { 1.0 } else { 0.04 };
                assert!((v - want).abs() < 0.01, "leakage[{a}][{bb}] = {v}, want {want}");
            }
        }
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    }

    #[test]
    fn missing_levels_warn_and_too_few_fail_naming_the_projector() {
        let (b, _) = scene(&[0, 16, 32, 200, 255], 0.002, 0.0);
        let r = b.finish().unwrap();
        let all = r.warnings.join("\n");
        assert!(all.contains("projector 1, channel 0") && all.contains("32..200"), "{all}");
        let (b, _) = scene(&[0, 128, 255], 0.002, 0.0);
        let err = b.finish().unwrap_err().to_string();
        assert!(err.contains("projector 1, channel 0") && err.contains("only 1 ramp levels"), "{err}");
    }

    #[test]
    fn saturated_full_image_is_refused_naming_it() {
        let black = LinearImage::new(8, 8).unwrap();
        let mut white = LinearImage::new(8, 8).unwrap();
        for p in &mut white.data {
            *p = [1.0, 0.5, 0.5];
        }
        let err = ResponseBuilder::new(2, &black, [(&white, "proj2/white.png"); 3], 0.05).unwrap_err();
        assert!(
            err.to_string().contains("proj2/white.png") && err.to_string().contains("saturated"),
            "{err}"
        );
    }

    #[test]
    fn inverse_round_trips() {
        let r = fit_response(&[(64, 0.05), (128, 0.22), (192, 0.52)]);
        for v in 0..=255 {
            assert!((invert_response(&r, r[v]) - v as f32).abs() < 1e-3, "level {v}");
        }
    }

    proptest! {
        #[test]
        fn noisy_samples_fit_a_monotonic_invertible_curve(
            g in 0.5f32..3.0,
            noise in 0.0f32..0.05,
            step in 1usize..40,
            seed in any::<u64>(),
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let pts: Vec<(u8, f32)> = (0..=255usize)
                .step_by(step)
                .map(|l| (l as u8, (l as f32 / 255.0).powf(g) + noise * rng.gen_range(-1.0f32..1.0)))
                .collect();
            let r = fit_response(&pts);
            prop_assert_eq!(r.len(), 256);
            prop_assert_eq!(r[0], 0.0);
            prop_assert!((r[255] - 1.0).abs() < 1e-6);
            for v in 1..256 {
                prop_assert!(r[v] > r[v - 1], "not increasing at {}: {} {}", v, r[v - 1], r[v]);
            }
            for v in 0..256 {
                let back = invert_response(&r, r[v]);
                prop_assert!((back - v as f32).abs() < 1e-2, "level {} came back as {}", v, back);
            }
        }
    }
}
