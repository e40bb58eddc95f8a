//! The camera's response from exposure brackets (Debevec & Malik 1997), and the merge of
//! brackets into linear radiance through it: how 8-bit images from any camera become linear.
//!
//! Conventions. `g(z) = ln E + ln Δt` per channel; the inverse response we hand out is
//! `h(z) = exp(g(z) - g(255))`: the exposure (radiance times time) that gives code `z`,
//! relative to the exposure that just saturates that channel. A merged radiance is `h(z)/Δt`
//! with `Δt` in seconds. Channels are normalised each at its own saturation, so their
//! relative scale (white balance) is the camera's, and calibration's per-pixel gain absorbs it.

use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::imgio::LinearImage;

/// Code values of an 8-bit camera.
pub const CODES: usize = 256;
/// Version of the response file (`response.json`).
pub const RESPONSE_VERSION: u32 = 1;
/// The codes over which a recovered response is judged: the ends are clipped by black and
/// saturation, where no response is determined.
pub const JUDGED_CODES: RangeInclusive<usize> = 10..=245;

#[derive(Debug, Error)]
pub enum ResponseError {
    #[error("{count} exposure brackets (expected at least 2, with different exposure times)")]
    TooFewBrackets { count: usize },
    #[error(
        "all {count} brackets have the same exposure time {seconds} s; a response needs at least \
         two different exposure times"
    )]
    EqualExposures { count: usize, seconds: f64 },
    #[error("bracket {index}: exposure time {seconds} s is not a positive finite number of seconds")]
    BadExposure { index: usize, seconds: f64 },
    #[error("bracket {index} is {got_w}x{got_h}, bracket 0 is {want_w}x{want_h}")]
    Size { index: usize, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("bracket {index} holds {got} pixels, expected {want} for its size")]
    DataLength { index: usize, got: usize, want: usize },
    #[error("smoothness lambda {0} is invalid (expected a finite number >= 0)")]
    BadLambda(f64),
    #[error("sample count {0} is invalid (expected 16..=100000)")]
    BadSamples(usize),
    #[error(
        "channel {channel}: only {usable} sample pixels are neither black nor saturated in at least \
         two brackets (expected >= 16); widen the bracket or light the scene"
    )]
    TooFewSamples { channel: usize, usable: usize },
    #[error("channel {channel}: the response system is singular (no bracket overlaps another)")]
    Singular { channel: usize },
    #[error("response channel {channel} code {code}: {value} is not a positive finite exposure")]
    NotFinite { channel: usize, code: usize, value: f64 },
    #[error("cannot read or write response file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a valid response file: {source}")]
    Parse { path: PathBuf, source: serde_json::Error },
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
}

/// One exposure of a static scene: 8-bit codes per pixel and channel, and its exposure time.
#[derive(Clone, Debug, PartialEq)]
pub struct Bracket {
    pub width: u32,
    pub height: u32,
    /// Row-major `[r, g, b]` codes.
    pub codes: Vec<[u8; 3]>,
    pub exposure_s: f64,
}

/// Parameters of the Debevec–Malik solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DebevecParams {
    /// Sample pixels per channel, chosen deterministically (stratified by code value in the
    /// middle exposure). Their log radiances are eliminated in closed form, so many are cheap.
    pub samples: usize,
    /// Smoothness weight `λ` on the hat-weighted second difference of `g`, per unit of data
    /// weight: the data term grows with `samples x brackets`, so λ is scaled by
    /// `samples x brackets / 256` (observations per code) to mean the same for any sampling.
    pub lambda: f64,
}

impl Default for DebevecParams {
    fn default() -> Self {
        Self { samples: 1000, lambda: 1.0 }
    }
}

/// A recovered camera response (`response.json`, version 1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraResponse {
    pub version: u32,
    /// Per channel (r, g, b), 256 entries: `h(z)`, the exposure giving code `z` relative to
    /// the exposure that saturates the channel (so `h(255) = 1`).
    pub inverse: [Vec<f64>; 3],
    /// How it was found, e.g. "Debevec-Malik, 9 brackets, 1000 samples, lambda 1".
    pub method: String,
    /// RMS residual of the fit in natural-log units per channel (0.01 is 1 %).
    pub residual_rms: [f64; 3],
}

impl CameraResponse {
    /// Checks the shape and values: 256 positive finite entries per channel.
    pub fn check(&self) -> Result<(), ResponseError> {
        for (channel, h) in self.inverse.iter().enumerate() {
            if h.len() != CODES {
                return Err(ResponseError::NotFinite { channel, code: h.len(), value: f64::NAN });
            }
            if let Some((code, &value)) = h.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
                return Err(ResponseError::NotFinite { channel, code, value });
            }
        }
        Ok(())
    }

    pub fn load(path: &Path) -> Result<Self, ResponseError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ResponseError::Io { path: path.into(), source })?;
        let r: Self = serde_json::from_str(&text)
            .map_err(|source| ResponseError::Parse { path: path.into(), source })?;
        if r.version != RESPONSE_VERSION {
            return Err(ResponseError::Invalid {
                path: path.into(),
                problem: format!(
                    "response version {} is not supported (expected {RESPONSE_VERSION})",
                    r.version
                ),
            });
        }
        r.check().map_err(|e| ResponseError::Invalid { path: path.into(), problem: e.to_string() })?;
        Ok(r)
    }

    pub fn save(&self, path: &Path) -> Result<(), ResponseError> {
        let text = serde_json::to_string_pretty(self).expect("response serialises");
        std::fs::write(path, text).map_err(|source| ResponseError::Io { path: path.into(), source })
    }
}

/// Debevec's hat: full weight mid-range, none at the black and saturated ends.
pub fn hat(z: u8) -> f64 {
    let z = z as f64;
    z.min(255.0 - z)
}

/// Checks brackets for a merge (one is enough) and returns their common size.
fn check_brackets(brackets: &[Bracket]) -> Result<(u32, u32), ResponseError> {
    let first = brackets.first().ok_or(ResponseError::TooFewBrackets { count: 0 })?;
    for (index, b) in brackets.iter().enumerate() {
        if (b.width, b.height) != (first.width, first.height) {
            return Err(ResponseError::Size {
                index,
                got_w: b.width,
                got_h: b.height,
                want_w: first.width,
                want_h: first.height,
            });
        }
        let want = b.width as usize * b.height as usize;
        if b.codes.len() != want {
            return Err(ResponseError::DataLength { index, got: b.codes.len(), want });
        }
        if !(b.exposure_s.is_finite() && b.exposure_s > 0.0) {
            return Err(ResponseError::BadExposure { index, seconds: b.exposure_s });
        }
    }
    Ok((first.width, first.height))
}

/// Recovers the response per channel by Debevec–Malik: least squares on
/// `w(z_ij) (g(z_ij) - ln E_i - ln Δt_j)` plus `λ w(z) g''(z)`, with `g(128) = 0`.
pub fn recover_debevec(
    brackets: &[Bracket],
    params: &DebevecParams,
) -> Result<CameraResponse, ResponseError> {
    if brackets.len() < 2 {
        return Err(ResponseError::TooFewBrackets { count: brackets.len() });
    }
    check_brackets(brackets)?;
    let t0 = brackets[0].exposure_s;
    if brackets.iter().all(|b| b.exposure_s == t0) {
        return Err(ResponseError::EqualExposures { count: brackets.len(), seconds: t0 });
    }
    if !(params.lambda.is_finite() && params.lambda >= 0.0) {
        return Err(ResponseError::BadLambda(params.lambda));
    }
    if !(16..=100_000).contains(&params.samples) {
        return Err(ResponseError::BadSamples(params.samples));
    }
    let mut inverse: [Vec<f64>; 3] = Default::default();
    let mut residual_rms = [0.0; 3];
    for c in 0..3 {
        let samples = sample_pixels(brackets, c, params.samples);
        if samples.len() < 16 {
            return Err(ResponseError::TooFewSamples { channel: c, usable: samples.len() });
        }
        let (g, rms) = solve_channel(brackets, c, &samples, params.lambda)?;
        let top = g[CODES - 1];
        inverse[c] = g.iter().map(|v| (v - top).exp()).collect();
        residual_rms[c] = rms;
        tracing::debug!("response channel {c}: {} samples, residual {:.4} (ln)", samples.len(), rms);
    }
    let r = CameraResponse {
        version: RESPONSE_VERSION,
        inverse,
        method: format!(
            "Debevec-Malik, {} brackets, {} samples, lambda {}",
            brackets.len(),
            params.samples,
            params.lambda
        ),
        residual_rms,
    };
    r.check()?;
    Ok(r)
}

/// Pixels for channel `c`, stratified by their code in the middle exposure (32 bands of 8
/// codes, every k-th pixel of a band in scan order) so dark and bright codes are both
/// represented; a pixel counts only if at least two brackets see it neither black nor
/// saturated, and only once per distinct set of codes.
fn sample_pixels(brackets: &[Bracket], c: usize, want: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..brackets.len()).collect();
    order.sort_by(|&a, &b| brackets[a].exposure_s.total_cmp(&brackets[b].exposure_s));
    let mid = &brackets[order[order.len() / 2]];
    let usable = |i: usize| brackets.iter().filter(|b| hat(b.codes[i][c]) > 0.0).count() >= 2;
    // Pixels with the same codes in every bracket carry the same information: a uniform wall
    // would otherwise weight its one quantisation error hundreds of times (it biased the
    // dark codes by several per cent on the virtual stage). Keep the first of each.
    let mut seen = std::collections::HashSet::new();
    let mut bands: Vec<Vec<usize>> = vec![Vec::new(); 32];
    for (i, px) in mid.codes.iter().enumerate() {
        let key: Vec<u8> = brackets.iter().map(|b| b.codes[i][c]).collect();
        if usable(i) && seen.insert(key) {
            bands[px[c] as usize / 8].push(i);
        }
    }
    // Spread the budget evenly over the bands that have pixels; small bands give all theirs
    // and leave the rest to the others.
    let mut budget = want;
    let mut open: Vec<&Vec<usize>> = bands.iter().filter(|b| !b.is_empty()).collect();
    open.sort_by_key(|b| b.len());
    let mut out = Vec::with_capacity(want);
    let n_open = open.len();
    for (k, band) in open.into_iter().enumerate() {
        let share = budget / (n_open - k);
        let take = share.min(band.len());
        let step = band.len() as f64 / take.max(1) as f64;
        out.extend((0..take).map(|j| band[(j as f64 * step) as usize]));
        budget -= take;
    }
    out.sort_unstable();
    out
}

/// Sample `i`'s usable observations in channel `c`: (code, squared hat weight, ln Δt) per
/// bracket where the code is neither black nor saturated. Fills `obs` (reused between samples).
fn observations(brackets: &[Bracket], ln_t: &[f64], i: usize, c: usize, obs: &mut Vec<(usize, f64, f64)>) {
    obs.clear();
    obs.extend(brackets.iter().zip(ln_t).filter_map(|(b, &lt)| {
        let z = b.codes[i][c];
        let w = hat(z);
        (w > 0.0).then_some((z as usize, w * w, lt))
    }));
}

/// Solves one channel: the log radiances of the samples only meet `g` through their own
/// rows, so they are eliminated in closed form (Schur complement) and a 256x256 system is
/// left. Returns `g` and the RMS data residual (ln units).
fn solve_channel(
    brackets: &[Bracket],
    c: usize,
    samples: &[usize],
    lambda: f64,
) -> Result<(Vec<f64>, f64), ResponseError> {
    let ln_t: Vec<f64> = brackets.iter().map(|b| b.exposure_s.ln()).collect();
    let mut s = DMatrix::<f64>::zeros(CODES, CODES);
    let mut rhs = DVector::<f64>::zeros(CODES);
    let mut obs: Vec<(usize, f64, f64)> = Vec::with_capacity(brackets.len());
    for &i in samples {
        observations(brackets, &ln_t, i, c, &mut obs);
        // Normal equations of the rows `w (g(z) - x_i) = w ln Δt`: G gets w² on the diagonal,
        // the x_i block is the scalar d = Σ w², and the coupling is -w².
        let d: f64 = obs.iter().map(|o| o.1).sum();
        let rx: f64 = -obs.iter().map(|o| o.1 * o.2).sum::<f64>();
        for &(za, wa, lt) in &obs {
            s[(za, za)] += wa;
            rhs[za] += wa * lt + wa * rx / d;
            for &(zb, wb, _) in &obs {
                s[(za, zb)] -= wa * wb / d;
            }
        }
    }
    // Smoothness, scaled to the observations per code so λ means the same for any sampling.
    let per_code = (samples.len() * brackets.len()) as f64 / CODES as f64;
    let lam2 = lambda * lambda * per_code;
    for z in 1..CODES - 1 {
        let w = hat(z as u8).max(1.0);
        let k = lam2 * w * w;
        let v = [(z - 1, 1.0), (z, -2.0), (z + 1, 1.0)];
        for &(a, va) in &v {
            for &(b, vb) in &v {
                s[(a, b)] += k * va * vb;
            }
        }
    }
    // g(128) = 0 fixes the free offset of ln E against g.
    s[(128, 128)] += 1.0;
    let g = s.clone().cholesky().map(|ch| ch.solve(&rhs)).ok_or(ResponseError::Singular { channel: c })?;
    if g.iter().any(|v| !v.is_finite()) {
        return Err(ResponseError::Singular { channel: c });
    }
    // Residual: each sample's ln E is the weighted mean of g(z) - ln Δt over its brackets.
    let (mut sum, mut weight) = (0.0, 0.0);
    for &i in samples {
        observations(brackets, &ln_t, i, c, &mut obs);
        let d: f64 = obs.iter().map(|o| o.1).sum();
        let x = obs.iter().map(|o| o.1 * (g[o.0] - o.2)).sum::<f64>() / d;
        for &(z, w, lt) in &obs {
            sum += w * (g[z] - x - lt).powi(2);
            weight += w;
        }
    }
    Ok((g.iter().copied().collect(), (sum / weight).sqrt()))
}

/// What a merge could not measure: pixel-channels saturated in every bracket (their value is
/// a lower bound from the shortest exposure) or black in every bracket (an upper bound from
/// the longest).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MergeReport {
    pub saturated: usize,
    pub black: usize,
}

/// Merges brackets into linear radiance `h(z)/Δt` (units: channel saturation per second),
/// averaging `ln h(z) - ln Δt` over brackets with the hat weight, as Debevec and OpenCV's
/// `MergeDebevec` do, so black and saturated codes do not count. One bracket is allowed: it
/// is simply linearised.
pub fn merge_debevec(
    brackets: &[Bracket],
    response: &CameraResponse,
) -> Result<(LinearImage, MergeReport), ResponseError> {
    let (width, height) = check_brackets(brackets)?;
    response.check()?;
    let ln_h: [Vec<f64>; 3] = [0, 1, 2].map(|c| response.inverse[c].iter().map(|v| v.ln()).collect());
    let ln_t: Vec<f64> = brackets.iter().map(|b| b.exposure_s.ln()).collect();
    let shortest = (0..brackets.len()).min_by(|&a, &b| ln_t[a].total_cmp(&ln_t[b])).expect("one bracket");
    let longest = (0..brackets.len()).max_by(|&a, &b| ln_t[a].total_cmp(&ln_t[b])).expect("one bracket");
    let mut report = MergeReport::default();
    let data = (0..width as usize * height as usize)
        .map(|i| {
            [0, 1, 2].map(|c| {
                let (mut sum, mut weight) = (0.0, 0.0);
                for (b, lt) in brackets.iter().zip(&ln_t) {
                    let z = b.codes[i][c];
                    let w = hat(z);
                    sum += w * (ln_h[c][z as usize] - lt);
                    weight += w;
                }
                let ln_e = if weight > 0.0 {
                    sum / weight
                } else if brackets[shortest].codes[i][c] == 255 {
                    report.saturated += 1;
                    ln_h[c][255] - ln_t[shortest]
                } else {
                    report.black += 1;
                    ln_h[c][brackets[longest].codes[i][c] as usize] - ln_t[longest]
                };
                ln_e.exp() as f32
            })
        })
        .collect();
    Ok((LinearImage { width, height, data }, report))
}

/// The error of a recovered inverse response against the true one over `codes`: the largest
/// relative error `|h(z) / (s t(z)) - 1|`, after the one scale `s` (geometric mean of
/// `h / t`) that the response leaves free. 0.01 is 1 %.
pub fn response_error(recovered: &[f64], truth: &[f64], codes: RangeInclusive<usize>) -> f64 {
    let n = codes.clone().count() as f64;
    let ln_s = codes.clone().map(|z| (recovered[z] / truth[z]).ln()).sum::<f64>() / n;
    codes.map(|z| ((recovered[z] / truth[z]).ln() - ln_s).exp() - 1.0).fold(0.0, |m, e| m.max(e.abs()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera with a known response: `code = round(255 (x^(1/γ)))` with a shoulder, no
    /// noise, over a radiance ramp. Per channel different, none of them sRGB.
    fn code(c: usize, x: f64) -> u8 {
        let (g, s) = ([2.0, 2.3, 1.8][c], [0.8, 0.6, 1.2][c]);
        let u = x.clamp(0.0, 1.0).powf(1.0 / g);
        (255.0 * (1.0 + s) * u / (u + s)).round().clamp(0.0, 255.0) as u8
    }

    fn truth(c: usize) -> Vec<f64> {
        let (g, s) = ([2.0, 2.3, 1.8][c], [0.8, 0.6, 1.2][c]);
        (0..CODES)
            .map(|z| {
                let f = z as f64 / 255.0;
                (s * f / (1.0 + s - f)).powf(g)
            })
            .collect()
    }

    fn brackets(times: &[f64]) -> Vec<Bracket> {
        let (w, h) = (64u32, 48u32);
        // Radiances spread log-uniformly over four decades, in a scrambled order.
        let e: Vec<f64> = (0..w * h)
            .map(|i| 10f64.powf(-4.0 + 4.0 * ((i * 7919) % (w * h)) as f64 / (w * h) as f64))
            .collect();
        times
            .iter()
            .map(|&t| Bracket {
                width: w,
                height: h,
                codes: e.iter().map(|&e| [0, 1, 2].map(|c| code(c, e * t))).collect(),
                exposure_s: t,
            })
            .collect()
    }

    const TIMES: [f64; 7] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

    #[test]
    fn recovers_a_known_response_within_one_percent() {
        let b = brackets(&TIMES);
        let r = recover_debevec(&b, &DebevecParams::default()).unwrap();
        for c in 0..3 {
            let err = response_error(&r.inverse[c], &truth(c), JUDGED_CODES);
            assert!(err < 0.01, "channel {c}: {:.3} %", 100.0 * err);
            assert!((r.inverse[c][255] - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_flat_response_is_far_from_the_truth() {
        // The metric can fail: a linear guess is tens of percent off this camera.
        let linear: Vec<f64> = (0..CODES).map(|z| z as f64 / 255.0).collect();
        assert!(response_error(&linear, &truth(0), JUDGED_CODES) > 0.3);
    }

    #[test]
    fn merge_returns_the_radiance_within_a_percent() {
        let b = brackets(&TIMES);
        let r = CameraResponse {
            version: RESPONSE_VERSION,
            // Code 0 stands for "below code 1": half of it, so every entry is positive.
            inverse: [0, 1, 2].map(|c| {
                let mut t = truth(c);
                t[0] = t[1] / 2.0;
                t
            }),
            method: "true".into(),
            residual_rms: [0.0; 3],
        };
        let (img, report) = merge_debevec(&b, &r).unwrap();
        let (w, h) = (64u32, 48u32);
        let mut worst: f64 = 0.0;
        for i in 0..(w * h) as usize {
            let e = 10f64.powf(-4.0 + 4.0 * ((i as u32 * 7919) % (w * h)) as f64 / (w * h) as f64);
            // Pixels the brackets see mid-range somewhere; the darkest are black everywhere.
            if e * 16.0 > 0.01 && e * 0.25 < 0.9 {
                worst = worst.max((img.data[i][1] as f64 / e - 1.0).abs());
            }
        }
        assert!(worst < 0.03, "worst {:.2} %", 100.0 * worst);
        assert_eq!(report.saturated, 0);
    }

    #[test]
    fn bad_brackets_are_refused_with_what_is_wrong() {
        let b = brackets(&TIMES);
        let p = DebevecParams::default();
        assert!(matches!(recover_debevec(&b[..1], &p), Err(ResponseError::TooFewBrackets { count: 1 })));
        let mut same = b[..3].to_vec();
        same.iter_mut().for_each(|x| x.exposure_s = 0.5);
        let e = recover_debevec(&same, &p).unwrap_err();
        assert!(matches!(e, ResponseError::EqualExposures { .. }), "{e}");
        let mut nan = b.clone();
        nan[2].exposure_s = f64::NAN;
        assert!(matches!(recover_debevec(&nan, &p), Err(ResponseError::BadExposure { index: 2, .. })));
        let mut small = b.clone();
        small[1].width = 32;
        assert!(matches!(recover_debevec(&small, &p), Err(ResponseError::Size { index: 1, .. })));
        let mut short = b.clone();
        short[3].codes.pop();
        assert!(matches!(recover_debevec(&short, &p), Err(ResponseError::DataLength { index: 3, .. })));
        let e = recover_debevec(&b, &DebevecParams { lambda: f64::NAN, ..p.clone() }).unwrap_err();
        assert!(e.to_string().contains(">= 0"), "{e}");
        // All black: nothing to fit.
        let mut black = b.clone();
        black.iter_mut().for_each(|x| x.codes.iter_mut().for_each(|v| *v = [0; 3]));
        assert!(matches!(recover_debevec(&black, &p), Err(ResponseError::TooFewSamples { .. })));
    }

    #[test]
    fn response_file_round_trips_and_refuses_nan() {
        let dir = tempfile::tempdir().unwrap();
        let r = recover_debevec(&brackets(&TIMES[..4]), &DebevecParams::default()).unwrap();
        let path = dir.path().join("response.json");
        r.save(&path).unwrap();
        // JSON keeps each value to the last bit or one ulp.
        let back = CameraResponse::load(&path).unwrap();
        for c in 0..3 {
            let worst = back.inverse[c]
                .iter()
                .zip(&r.inverse[c])
                .map(|(a, b)| (a / b - 1.0).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-14, "{worst}");
        }
        assert_eq!((&back.method, back.residual_rms), (&r.method, r.residual_rms));
        let mut bad = r.clone();
        bad.inverse[1][40] = f64::NAN;
        assert!(matches!(bad.check(), Err(ResponseError::NotFinite { channel: 1, code: 40, .. })));
        bad.inverse[1][40] = -1.0;
        bad.save(&path).unwrap();
        let e = CameraResponse::load(&path).unwrap_err().to_string();
        assert!(e.contains("response.json") && e.contains("code 40"), "{e}");
    }
}
