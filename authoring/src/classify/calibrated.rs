//! Ours (paper §4.1): representatives from the picks, Eq. 1's weights by LM, then k-means in
//! xyY under those weights, seeded by the representatives.
//!
//! Units (the paper leaves them open): each channel of xyY is divided by the picks' pooled
//! within-colour standard deviation of that channel ([`Palette::channel_scale`]) before
//! Eq. 1 is applied. In raw xyY, luminance differences (tenths) dwarf chromaticity
//! differences (hundredths), and shading across a curved object varies luminance far more
//! than chromaticity; in units of each channel's own spread the LM fit weighs what actually
//! separates the colours on this object. With one pick per colour there is no spread to
//! measure, and the scales fall back to `[1, 1, brightest representative's Y]`.
//!
//! Each colour's own spread (our addition; the paper uses one distance for all colours): in
//! Eq. 1's weighted space a colour's picks also show how that paint varies on this object —
//! fading drags red towards the slip along a line, dark paint has noisy chromaticity, chipped
//! clay hardly varies. One isotropic distance for all colours cannot hold that: on the
//! virtual bowl it sent 17 % of the faded red to the clay, which sits nearer the faded red
//! than the red's own mean does. So each colour gets a covariance `Σ_c = (S_c + ν τ² I) /
//! (n_c - 1 + ν)`: the scatter `S_c` of its `n_c` picks shrunk towards Eq. 1's own metric
//! (`τ² I`, `τ²` the pooled within-colour variance per channel) with the strength of `ν`
//! pseudo-picks ([`ClassifyOptions::prior_picks`]); pixels go to the colour of least
//! squared Mahalanobis distance `(f - μ_c)^T Σ_c^-1 (f - μ_c)`. With one pick per colour, or
//! `ν = ∞`, every `Σ_c` is the same multiple of `I` and this is exactly Eq. 1's nearest
//! representative.

use tracing::{info, warn};

use nalgebra::{Matrix3, Vector3};

use super::kmeans::{Features, Precision, lloyd_metric, mahalanobis2};
use super::weights::{fit_weights, pair_differences};
use super::{ClassifyError, LabelMap, MASKED, PALETTE_VERSION, Palette, PaletteClass, Picks, ReviewRegion};
use crate::color::{D65_XY, SRGB_TO_XYZ, linear_srgb_to_xyy};
use crate::imgio::LinearImage;

/// Most colour classes (label 255 is reserved for "not object").
pub const MAX_CLASSES: usize = 254;

/// Two representatives closer than this in (x, y, Y / y_scale) are the same colour.
pub const MIN_SEPARATION: f64 = 1e-3;

#[derive(Clone, Debug)]
pub struct ClassifyOptions {
    /// Cap on k-means iterations. The default, 1, assigns each pixel to the nearest
    /// representative under the calibrated distance and stops: on the virtual stage's
    /// deteriorated scenes further Lloyd iterations (the paper's k-means) let centroids drift
    /// towards faded and stained paint and cost 2 points of accuracy (see
    /// `restage-author eval classify` with `--max-iterations`).
    pub max_iterations: u32,
    /// `ν`: how many pseudo-picks of Eq. 1's isotropic metric each colour's covariance is
    /// shrunk towards (see the module notes). `f64::INFINITY` gives the paper's plain Eq. 1
    /// distance for every colour. 3 by default: with 12 picks per colour, 2 to 5 give the
    /// same accuracy on the virtual stage's scenes; far more loses the per-colour spread.
    pub prior_picks: f64,
    /// Relabel mixed pixels at paint edges and the silhouette by linear unmixing of the
    /// paints beside them ([`super::edges`]); on by default. Off: the paper's per-pixel rule
    /// alone (`restage-author eval classify` reports both).
    pub unmix_edges: bool,
    /// Give faded or stained paint its paint's class: regions whose colour runs on without a
    /// step into a neighbouring paint ([`super::regions`]), shapes faded evenly towards the
    /// ground around them ([`super::islands`]) and paint faded into its ground's class
    /// ([`super::within`]); on by default.
    pub merge_soft: bool,
    /// The loss classes (bare substrate that chips and cracks expose, the restoration's
    /// `loss_classes`), by index into the picks. A crack is a groove one or two pixels wide:
    /// its substrate is in shadow and has no pure pixel to take its colour from, so edge
    /// unmixing also tries each loss class at its open-chip colour darkened down to 0.4x.
    /// Empty: no class is treated so.
    pub loss: Vec<u8>,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        Self {
            max_iterations: 1,
            prior_picks: DEFAULT_PRIOR_PICKS,
            unmix_edges: true,
            merge_soft: true,
            loss: Vec::new(),
        }
    }
}

/// 99 % point of chi-square with 3 degrees of freedom: a pixel nearer its class than this
/// (squared Mahalanobis distance) looks like that class's picks.
const TYPICAL_CHI2: f32 = 11.34;

/// Default [`ClassifyOptions::prior_picks`].
pub const DEFAULT_PRIOR_PICKS: f64 = 3.0;

/// Label map plus palette.
#[derive(Clone, Debug)]
pub struct Classification {
    pub labels: LabelMap,
    pub palette: Palette,
    /// The regions whose class the context passes changed from the one their colour gave
    /// ([`super::review`]), largest first: where a pick confirms or corrects the result.
    pub review: Vec<ReviewRegion>,
    /// The per-pixel rule's labels, before those passes (what `review` compares with).
    pub by_colour: LabelMap,
}

/// Per-pixel xyY as f32, with black at the D65 chromaticity (see [`crate::color::xyz_to_xyy`]).
#[inline]
pub fn xyy_f32(rgb: [f32; 3]) -> [f32; 3] {
    const M: [[f32; 3]; 3] = {
        let m = SRGB_TO_XYZ;
        let mut out = [[0f32; 3]; 3];
        let mut i = 0;
        while i < 9 {
            out[i / 3][i % 3] = m[i / 3][i % 3] as f32;
            i += 1;
        }
        out
    };
    let m = M;
    let x = m[0][0] * rgb[0] + m[0][1] * rgb[1] + m[0][2] * rgb[2];
    let y = m[1][0] * rgb[0] + m[1][1] * rgb[1] + m[1][2] * rgb[2];
    let z = m[2][0] * rgb[0] + m[2][1] * rgb[1] + m[2][2] * rgb[2];
    let s = x + y + z;
    if s > 1e-9 { [x / s, y / s, y] } else { [D65_XY[0] as f32, D65_XY[1] as f32, y] }
}

/// Pooled within-colour standard deviation of the picks' x, y and Y (floored so that no
/// channel's scale vanishes); `[1, 1, y_max]` when no colour has two picks.
fn channel_scale(photo: &LinearImage, idx: &[Vec<usize>], reps: &[[f64; 3]], y_max: f64) -> [f64; 3] {
    let mut ss = [0f64; 3];
    let mut dof = 0usize;
    for (pix, rep) in idx.iter().zip(reps) {
        for &i in pix {
            let v = xyy_f32(photo.data[i]);
            for j in 0..3 {
                ss[j] += (v[j] as f64 - rep[j]).powi(2);
            }
        }
        dof += pix.len() - 1;
    }
    if dof == 0 {
        return [1.0, 1.0, y_max];
    }
    let floor = [1e-4, 1e-4, 1e-4 * y_max];
    [0, 1, 2].map(|j| (ss[j] / dof as f64).sqrt().max(floor[j]))
}

/// Each colour's mean and precision in the weighted feature space, and the prior's variance.
struct ClassMetrics {
    means: Vec<[f32; 3]>,
    precisions: Vec<Precision>,
    tau2: f64,
}

/// Each colour's mean and metric (precision) in the weighted feature space, from its picks:
/// the covariance of the picks shrunk towards Eq. 1's isotropic metric by `prior_picks`
/// pseudo-picks (module notes). The precisions are scaled so that the isotropic prior is
/// the identity, which keeps the feature units of plain Eq. 1; the scale, `τ²`, is returned
/// too (a squared distance under these precisions over `τ²` is the Mahalanobis distance).
fn class_metrics(
    features: &Features,
    idx: &[Vec<usize>],
    prior_picks: f64,
) -> Result<ClassMetrics, ClassifyError> {
    if prior_picks.is_nan() || prior_picks <= 0.0 {
        return Err(ClassifyError::Option {
            name: "prior_picks",
            problem: format!("{prior_picks} (expected > 0, or infinity for the plain Eq. 1 distance)"),
        });
    }
    let stats: Vec<(Vector3<f64>, Matrix3<f64>, usize)> = idx
        .iter()
        .map(|pix| {
            let f: Vec<Vector3<f64>> =
                pix.iter().map(|&i| Vector3::from(features.get(i).map(f64::from))).collect();
            let mean = f.iter().sum::<Vector3<f64>>() / f.len() as f64;
            let scatter = f.iter().map(|v| (v - mean) * (v - mean).transpose()).sum::<Matrix3<f64>>();
            (mean, scatter, f.len())
        })
        .collect();
    let dof: usize = stats.iter().map(|s| s.2 - 1).sum();
    let pooled = stats.iter().map(|s| s.1).sum::<Matrix3<f64>>();
    // The prior's variance per channel; any positive value when no colour has two picks
    // (then every covariance is this same isotropic one and only Eq. 1 decides).
    let tau2 = if dof > 0 { (pooled.trace() / (3 * dof) as f64).max(1e-12) } else { 1.0 };
    let mut init = Vec::with_capacity(stats.len());
    let mut metrics = Vec::with_capacity(stats.len());
    for (mean, scatter, n) in &stats {
        init.push([mean[0] as f32, mean[1] as f32, mean[2] as f32]);
        let precision = if prior_picks.is_infinite() || dof == 0 {
            Matrix3::identity()
        } else {
            // In units of tau2: (S / tau2 + nu I) / (n - 1 + nu), inverted.
            let cov = (scatter / tau2 + Matrix3::identity() * prior_picks) / ((n - 1) as f64 + prior_picks);
            cov.try_inverse().unwrap_or_else(Matrix3::identity)
        };
        let p = precision.map(|v| v as f32);
        metrics.push([p[(0, 0)], p[(1, 1)], p[(2, 2)], p[(0, 1)], p[(0, 2)], p[(1, 2)]]);
    }
    Ok(ClassMetrics { means: init, precisions: metrics, tau2 })
}

/// Mean linear RGB of the given pixels.
fn mean_rgb(photo: &LinearImage, idx: &[usize]) -> [f64; 3] {
    let mut s = [0f64; 3];
    for &i in idx {
        for (acc, v) in s.iter_mut().zip(photo.data[i]) {
            *acc += v as f64;
        }
    }
    s.map(|v| v / idx.len() as f64)
}

/// Builds the initial label buffer from an optional object mask (true = object).
pub fn initial_labels(n: usize, mask: Option<&[bool]>) -> Result<Vec<u8>, ClassifyError> {
    let labels: Vec<u8> = match mask {
        Some(m) => m.iter().map(|&inside| if inside { 0 } else { MASKED }).collect(),
        None => vec![0; n],
    };
    if labels.iter().all(|&l| l == MASKED) {
        return Err(ClassifyError::EmptyMask);
    }
    Ok(labels)
}

/// Classifies every object pixel of `photo` into one of the picked colours.
/// `mask`, if given, has one entry per pixel (true = object); other pixels get [`MASKED`].
pub fn classify(
    photo: &LinearImage,
    picks: &Picks,
    mask: Option<&[bool]>,
    opts: &ClassifyOptions,
) -> Result<Classification, ClassifyError> {
    let (w, h) = (photo.width, photo.height);
    let k = picks.colours.len();
    if !(2..=MAX_CLASSES).contains(&k) {
        return Err(ClassifyError::ClassCount { count: k, max: MAX_CLASSES });
    }
    if let Some(&c) = opts.loss.iter().find(|&&c| c as usize >= k) {
        return Err(ClassifyError::Option {
            name: "loss",
            problem: format!("class {c} (the picks name {k} classes, 0 to {})", k - 1),
        });
    }
    if let Some(m) = mask
        && m.len() != photo.data.len()
    {
        return Err(ClassifyError::LabelSize {
            got: m.len(),
            expected: photo.data.len(),
            width: w,
            height: h,
        });
    }
    let idx = picks.pixel_indices(w, h)?;
    let reps_rgb: Vec<[f64; 3]> = idx.iter().map(|i| mean_rgb(photo, i)).collect();
    let reps_xyy: Vec<[f64; 3]> = reps_rgb.iter().map(|&c| linear_srgb_to_xyy(c)).collect();
    let y_max = reps_xyy.iter().map(|c| c[2]).fold(0.0, f64::max).max(1e-6);
    let unit: Vec<[f64; 3]> = reps_xyy.iter().map(|c| [c[0], c[1], c[2] / y_max]).collect();

    // Same representative: no distance can separate them (and 1/D has no value).
    let mut p = 0;
    for i in 0..k {
        for j in i + 1..k {
            let s = pair_differences(&[unit[i], unit[j]])[0];
            let distance = (s[0] + s[1] + s[2]).sqrt();
            if distance < MIN_SEPARATION {
                return Err(ClassifyError::Degenerate {
                    a: picks.colours[i].name.clone(),
                    b: picks.colours[j].name.clone(),
                    distance,
                });
            }
            p += 1;
        }
    }
    debug_assert_eq!(p, k * (k - 1) / 2);
    let chroma_spread =
        unit.iter().map(|c| (c[0] - unit[0][0]).abs() + (c[1] - unit[0][1]).abs()).sum::<f64>();
    if chroma_spread < 1e-4 {
        warn!("the picked colours share one chromaticity (greyscale photo?): classifying by luminance");
    }
    let scale = channel_scale(photo, &idx, &reps_xyy, y_max);
    let scaled: Vec<[f64; 3]> = reps_xyy.iter().map(|c| [0, 1, 2].map(|j| c[j] / scale[j])).collect();

    let fit = fit_weights(&scaled);
    let sw: [f32; 3] = [0, 1, 2].map(|j| (fit.weights[j].sqrt() / scale[j]) as f32);
    info!(weights = ?fit.weights, lm_iterations = fit.iterations, "fitted Eq. 1 weights");

    let features = Features::from_pixels(&photo.data, |rgb| {
        let v = xyy_f32(rgb);
        [v[0] * sw[0], v[1] * sw[1], v[2] * sw[2]]
    });
    let ClassMetrics { means: mut init, precisions: metrics, tau2 } =
        class_metrics(&features, &idx, opts.prior_picks)?;
    if opts.prior_picks.is_infinite() {
        // The paper's path exactly: each colour at its representative (the picks averaged in
        // linear RGB, then xyY), not at the mean of the picks' xyY.
        init = reps_xyy.iter().map(|c| [0, 1, 2].map(|j| c[j] as f32 * sw[j])).collect();
    }
    let mut labels = initial_labels(photo.data.len(), mask)?;
    let mut res = lloyd_metric(&features, &init, Some(&metrics), &mut labels, opts.max_iterations);
    let by_colour = labels.clone();
    if opts.merge_soft {
        // Pixels within the spread of their class's picks (squared Mahalanobis distance
        // under the 99 % point of chi-square with 3 degrees of freedom).
        let limit = TYPICAL_CHI2 * tau2 as f32;
        let typical: Vec<bool> = labels
            .iter()
            .enumerate()
            .map(|(i, &l)| {
                metrics
                    .get(l as usize)
                    .is_some_and(|p| mahalanobis2(features.get(i), res.centroids[l as usize], p) < limit)
            })
            .collect();
        let changed =
            super::regions::merge_soft_regions(photo, &mut labels, k, &reps_rgb, &idx, &typical, &opts.loss);
        info!(changed, "relabelled faded or stained regions");
        let changed =
            super::islands::relabel_faded_islands(photo, &mut labels, k, &reps_rgb, &idx, &opts.loss);
        info!(changed, "relabelled evenly faded islands");
        let changed = super::within::relabel_faded_within(photo, &mut labels, k, &reps_rgb, &idx, &opts.loss);
        info!(changed, "relabelled faded paint within its ground");
    }
    let review = super::review::relabelled_regions(&by_colour, &labels, w as usize, h as usize);
    // Edges after regions: the edge pass takes each mixed pixel's paints from the classes
    // beside it, which must already be right (unmixing first also fixes rows of mixed pixels
    // that tie a faded band to the ground, but it lost more than it gained on held-out seeds).
    if opts.unmix_edges {
        let changed = super::edges::unmix_edges(photo, &mut labels, mask, k, &opts.loss);
        info!(changed, "relabelled mixed edge pixels");
    }
    res.counts = vec![0; k];
    for &l in labels.iter().filter(|&&l| (l as usize) < k) {
        res.counts[l as usize] += 1;
    }
    let labels = LabelMap::from_vec(w, h, labels)?;
    let means = class_mean_rgb(photo, &labels, k);
    let classes = picks
        .colours
        .iter()
        .enumerate()
        .map(|(i, c)| PaletteClass {
            name: c.name.clone(),
            representative_xyy: reps_xyy[i],
            mean_linear_rgb: if res.counts[i] > 0 { means[i] } else { reps_rgb[i] },
            pixels: res.counts[i],
            display_srgb8: c.display_srgb8,
        })
        .collect();
    let palette = Palette {
        version: PALETTE_VERSION,
        classes,
        weights: fit.weights,
        channel_scale: scale,
        iterations: res.iterations,
        converged: res.converged,
    };
    let by_colour = LabelMap::from_vec(w, h, by_colour)?;
    Ok(Classification { labels, palette, review, by_colour })
}

/// Mean linear RGB of each class's pixels (zero for an empty class); chunked, deterministic.
pub fn class_mean_rgb(photo: &LinearImage, labels: &LabelMap, k: usize) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    let partials: Vec<Vec<[f64; 4]>> = labels
        .data
        .par_chunks(1 << 15)
        .zip(photo.data.par_chunks(1 << 15))
        .map(|(lab, px)| {
            let mut s = vec![[0f64; 4]; k];
            for (&l, p) in lab.iter().zip(px) {
                if let Some(t) = s.get_mut(l as usize) {
                    for c in 0..3 {
                        t[c] += p[c] as f64;
                    }
                    t[3] += 1.0;
                }
            }
            s
        })
        .collect();
    let mut total = vec![[0f64; 4]; k];
    for s in partials {
        for (t, v) in total.iter_mut().zip(&s) {
            for c in 0..4 {
                t[c] += v[c];
            }
        }
    }
    total
        .iter()
        .map(|t| if t[3] > 0.0 { [t[0] / t[3], t[1] / t[3], t[2] / t[3]] } else { [0.0; 3] })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::picks_from_labels;
    use crate::classify::synthetic::{POTTERY_PAINTS, painted_pattern};

    fn names(k: usize) -> Vec<String> {
        (0..k).map(|i| format!("paint {i}")).collect()
    }

    fn accuracy(a: &LabelMap, b: &LabelMap) -> f64 {
        a.data.iter().zip(&b.data).filter(|(x, y)| x == y).count() as f64 / a.data.len() as f64
    }

    #[test]
    fn classifies_a_shaded_noisy_pattern() {
        let scene = painted_pattern(160, 120, &POTTERY_PAINTS, 0.04, 7).unwrap();
        let picks = picks_from_labels(&scene.truth, &names(5), &[], 4, 1).unwrap();
        let out = classify(&scene.photo, &picks, None, &ClassifyOptions::default()).unwrap();
        let acc = accuracy(&out.labels, &scene.truth);
        assert!(acc > 0.99, "accuracy {acc}");
        let p = &out.palette;
        assert_eq!(p.iterations, 1, "{p:?}");
        let full = classify(
            &scene.photo,
            &picks,
            None,
            &ClassifyOptions { max_iterations: 50, ..Default::default() },
        )
        .unwrap();
        assert!(full.palette.converged && full.palette.iterations >= 2, "{:?}", full.palette);
        assert!(accuracy(&full.labels, &scene.truth) > 0.99);
        assert!((p.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12 && p.weights.iter().all(|&w| w > 0.0));
        assert_eq!(p.classes.iter().map(|c| c.pixels).sum::<u64>(), 160 * 120);
        // Deterministic, whatever the thread count.
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let again =
            pool.install(|| classify(&scene.photo, &picks, None, &ClassifyOptions::default())).unwrap();
        assert_eq!(again.labels, out.labels);
        assert_eq!(again.palette, out.palette);
    }

    #[test]
    fn mask_excludes_pixels_and_greyscale_is_classified_by_luminance() {
        let greys = [[0.01f32; 3], [0.12; 3], [0.8; 3]];
        let scene = painted_pattern(90, 60, &greys, 0.03, 3).unwrap();
        let picks = picks_from_labels(&scene.truth, &names(3), &[], 3, 2).unwrap();
        let mask: Vec<bool> = (0..90 * 60).map(|i| i % 90 < 80).collect();
        let out = classify(&scene.photo, &picks, Some(&mask), &ClassifyOptions::default()).unwrap();
        assert!(out.palette.weights[2] > 0.9, "{:?}", out.palette.weights);
        for (i, &l) in out.labels.data.iter().enumerate() {
            if mask[i] {
                assert_eq!(l, scene.truth.data[i], "pixel {i}");
            } else {
                assert_eq!(l, MASKED);
            }
        }
        let none = vec![false; 90 * 60];
        let err = classify(&scene.photo, &picks, Some(&none), &ClassifyOptions::default()).unwrap_err();
        assert!(err.to_string().contains("no pixel"), "{err}");
    }

    #[test]
    fn bad_picks_are_refused_clearly() {
        let scene = painted_pattern(40, 30, &POTTERY_PAINTS[..3], 0.02, 5).unwrap();
        let mut picks = picks_from_labels(&scene.truth, &names(3), &[], 2, 2).unwrap();
        // Fewer picks than colours: one colour lost its pixels.
        let mut fewer = picks.clone();
        fewer.colours[1].pixels.clear();
        let err = classify(&scene.photo, &fewer, None, &ClassifyOptions::default()).unwrap_err();
        assert!(err.to_string().contains("'paint 1' has no picked pixels"), "{err}");
        // A single colour is not a classification.
        let mut one = picks.clone();
        one.colours.truncate(1);
        let err = classify(&scene.photo, &one, None, &ClassifyOptions::default()).unwrap_err();
        assert!(err.to_string().contains("expected 2..=254"), "{err}");
        // Outside the image.
        let mut outside = picks.clone();
        outside.colours[0].pixels.push([40, 3]);
        let err = classify(&scene.photo, &outside, None, &ClassifyOptions::default()).unwrap_err();
        assert!(err.to_string().contains("(40, 3)") && err.to_string().contains("40x30"), "{err}");
        // Two colours with the same representative: the same pixels picked for both.
        picks.colours[2].pixels = picks.colours[0].pixels.clone();
        let err = classify(&scene.photo, &picks, None, &ClassifyOptions::default()).unwrap_err();
        assert!(err.to_string().contains("'paint 0' and 'paint 2' have the same representative"), "{err}");
    }
}
