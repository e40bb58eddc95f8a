//! Evaluation of compensation against true physics: what a visitor sees (rendered with the
//! stage's true geometry, responses and blur) against the restored target, the true peak
//! irradiance against E_bound, and the brightness/smoothness trade-off over m (paper Fig. 8).

use image::RgbImage;

use super::Metric;
use crate::color::{ciede2000, linear_srgb_to_lab};
use crate::compensate::synthetic::SyntheticStage;
use crate::compensate::{self, CompensateError, Compensation, Exponent, Params, Prepared};
use crate::imgio::LinearImage;
use crate::stage_model::StageModel;

const STEP: &str = "compensate";

/// The true stage, as only evaluation may see it.
pub trait TruePhysics {
    /// True irradiance (lux per channel, room light included) at every camera pixel when the
    /// projectors show `frames`; NaN or 0 off the object.
    fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]>;
    /// What the camera (a visitor at its place) sees, linear camera values.
    fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]>;
}

impl TruePhysics for SyntheticStage {
    fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]> {
        SyntheticStage::true_lux(self, frames)
    }

    fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]> {
        SyntheticStage::view(self, frames)
    }
}

/// Colour error of the visitor's view against the target on covered pixels, after the
/// compensation's global scale (the visitor's eye adapts to overall brightness).
pub fn colour_error(comp: &Compensation, view: &[[f32; 3]], target: &LinearImage) -> (f64, f64, usize) {
    let s = comp.stats.scale;
    let kn = comp.frames.len();
    let mut de: Vec<f64> = (0..view.len())
        .filter(|&i| comp.weights[i * kn..(i + 1) * kn].iter().any(|&w| w > 0.0) && s > 0.0)
        .map(|i| {
            let v = view[i].map(|c| c as f64 / s);
            let t = target.data[i].map(|c| c as f64);
            ciede2000(linear_srgb_to_lab(v), linear_srgb_to_lab(t))
        })
        .filter(|d| d.is_finite())
        .collect();
    if de.is_empty() {
        return (f64::NAN, f64::NAN, 0);
    }
    de.sort_by(f64::total_cmp);
    let mean = de.iter().sum::<f64>() / de.len() as f64;
    let p95 = de[((de.len() as f64 * 0.95) as usize).min(de.len() - 1)];
    (mean, p95, de.len())
}

/// Highest true irradiance (lux, max channel, room light included) on the object.
pub fn true_peak(truth: &dyn TruePhysics, frames: &[RgbImage]) -> f64 {
    truth
        .true_lux(frames)
        .iter()
        .filter(|e| e.iter().all(|v| v.is_finite()))
        .map(|e| compensate::guarantee::bound_lux(*e))
        .fold(0.0, f64::max)
}

/// Root-mean-square change of the weights between neighbouring covered pixels, summed over
/// projectors: 0 for constant weights; a hard switch between projectors scores high, a
/// gradual blend low (the Dirichlet energy of the weight maps).
pub fn weight_roughness(comp: &Compensation, width: u32) -> f64 {
    let kn = comp.frames.len();
    let n = comp.weights.len() / kn;
    let w = width as usize;
    let covered = |i: usize| comp.weights[i * kn..(i + 1) * kn].iter().any(|&x| x > 0.0);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for i in 0..n {
        if !covered(i) {
            continue;
        }
        for j in [i + 1, i + w] {
            if j < n && (j != i + 1 || j % w != 0) && covered(j) {
                let d: f64 = (0..kn)
                    .map(|k| (comp.weights[i * kn + k] - comp.weights[j * kn + k]) as f64)
                    .map(|d| d * d)
                    .sum();
                sum += d;
                count += 1;
            }
        }
    }
    (sum / count.max(1) as f64).sqrt()
}

/// Mean luminance (Y, camera units) of the view over covered pixels.
pub fn mean_luminance(comp: &Compensation, view: &[[f32; 3]]) -> f64 {
    let kn = comp.frames.len();
    let (mut sum, mut count) = (0.0, 0usize);
    for (i, v) in view.iter().enumerate() {
        if comp.weights[i * kn..(i + 1) * kn].iter().any(|&w| w > 0.0) {
            sum += 0.2126 * v[0] as f64 + 0.7152 * v[1] as f64 + 0.0722 * v[2] as f64;
            count += 1;
        }
    }
    sum / count.max(1) as f64
}

/// The figures for one scene: colour error and true peak at the user's m, the fraction of
/// points limited by the bound, and the m trade-off. `label` names the scene in the rows.
pub fn evaluate(
    label: &str,
    truth: &dyn TruePhysics,
    model: &StageModel,
    target: &LinearImage,
    params: &Params,
) -> Result<Vec<Metric>, CompensateError> {
    let prep = Prepared::new(model, params.reduction)?;
    let comp = compensate::compensate_prepared(model, &prep, target, params)?;
    let view = truth.view(&comp.frames);
    let (mean, p95, n) = colour_error(&comp, &view, target);
    let name = |s: &str| format!("{label}: {s}");
    let mut rows = vec![
        Metric::below(STEP, &name(&format!("CIEDE2000 mean (m = {})", params.m)), mean, "dE00", 3.0),
        Metric::info(STEP, &name("CIEDE2000 p95"), p95, "dE00"),
        Metric::info(STEP, &name("covered pixels"), n as f64, "px"),
    ];
    let tp = true_peak(truth, &comp.frames);
    rows.push(Metric::info(STEP, &name("E_bound"), params.e_bound_lux, "lx"));
    rows.push(Metric::info(STEP, &name("recomputed peak (certificate)"), comp.stats.peak_lux, "lx"));
    rows.push(Metric {
        target: Some(format!("<= {}", params.e_bound_lux)),
        pass: Some(tp <= params.e_bound_lux),
        ..Metric::info(STEP, &name("true peak irradiance"), tp, "lx")
    });
    let cov = comp.stats.covered_points.max(1) as f64;
    rows.push(Metric::info(
        STEP,
        &name("fraction limited by the bound"),
        comp.stats.limited_by_bound as f64 / cov,
        "",
    ));
    rows.push(Metric::info(
        STEP,
        &name("fraction limited by saturation"),
        comp.stats.limited_by_saturation as f64 / cov,
        "",
    ));
    rows.extend(tradeoff(label, truth, model, &prep, target, params)?);
    Ok(rows)
}

/// Brightness and smoothness for m in {0, 1, 2, 5, 8, inf}, at a bound high enough that only
/// the projectors' output limits brightness (with a bound that binds, every m reaches the
/// same irradiance: the weights only decide which projector supplies it).
pub fn tradeoff(
    label: &str,
    truth: &dyn TruePhysics,
    model: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Vec<Metric>, CompensateError> {
    let kn = prep.geometry.projectors;
    let full: f64 = (0..prep.geometry.points)
        .map(|i| (0..kn).map(|k| prep.geometry.eta[i * kn + k] as f64).sum::<f64>())
        .fold(0.0, f64::max);
    let e_bound = (2.0 * full).clamp(params.e_bound_lux, 1e6);
    let ms = [0.0, 1.0, 2.0, 5.0, 8.0, f64::INFINITY];
    let mut lum = Vec::new();
    let mut rough = Vec::new();
    let mut rows = Vec::new();
    for m in ms {
        let m = if m.is_finite() { Exponent::Finite(m) } else { Exponent::Infinite };
        let p = Params { e_bound_lux: e_bound, m, ..params.clone() };
        let comp = compensate::compensate_prepared(model, prep, target, &p)?;
        let view = truth.view(&comp.frames);
        lum.push(mean_luminance(&comp, &view));
        rough.push(weight_roughness(&comp, model.camera.width));
        let (de, _, _) = colour_error(&comp, &view, target);
        rows.push(Metric::info(
            STEP,
            &format!("{label}: m = {m}: mean luminance"),
            lum[lum.len() - 1],
            "cam",
        ));
        rows.push(Metric::info(
            STEP,
            &format!("{label}: m = {m}: weight roughness"),
            rough[rough.len() - 1],
            "",
        ));
        rows.push(Metric::info(STEP, &format!("{label}: m = {m}: CIEDE2000 mean"), de, "dE00"));
    }
    let (l8, linf) = (lum[4], lum[5]);
    rows.push(Metric::at_least(STEP, &format!("{label}: brightness m=8 / m=inf"), l8 / linf, "", 0.9));
    let (r1, r8, rinf) = (rough[1], rough[4], rough[5]);
    rows.push(Metric::below(
        STEP,
        &format!("{label}: roughness (m=8 - m=1) / (m=inf - m=1)"),
        (r8 - r1) / (rinf - r1),
        "",
        0.5,
    ));
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::{SyntheticSpec, build};

    #[test]
    fn synthetic_scene_evaluates_within_targets() {
        let s =
            build(&SyntheticSpec { camera: (64, 48), projector: (56, 42), ..SyntheticSpec::small(3, 21) });
        let cam = &s.model.camera;
        let mut t = LinearImage::new(cam.width, cam.height).unwrap();
        // The painted pattern without its grain, a little brighter: what a restoration asks.
        for (v, a) in t.data.iter_mut().zip(&s.albedo) {
            *v = if a[0].is_finite() { a.map(|c| (c * 0.8).min(1.0)) } else { [0.0; 3] };
        }
        let p = Params::new(400.0, Exponent::Finite(8.0), 0.05).unwrap();
        let rows = evaluate("sphere", &s, &s.model, &t, &p).unwrap();
        let get = |n: &str| rows.iter().find(|r| r.name.contains(n)).unwrap_or_else(|| panic!("{n}"));
        assert_eq!(get("true peak").pass, Some(true));
        let de = get("CIEDE2000 mean (m = 8)").value;
        assert!(de.is_finite() && de > 0.0, "{de}");
        assert!(rows.iter().any(|r| r.name.contains("m = inf: mean luminance")));
    }
}
