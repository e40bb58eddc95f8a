//! Evaluation of compensation against true physics: what a visitor sees (rendered with the
//! stage's true geometry, responses and blur) against the restored target, the true peak
//! irradiance against E_bound, and the brightness/smoothness trade-off over m (paper Fig. 8).

use std::path::Path;

use image::RgbImage;

use super::Metric;
use crate::color::{ciede2000, linear_srgb_to_lab};
use crate::compensate::synthetic::SyntheticStage;
use crate::compensate::{self, CompensateError, Compensation, Exponent, Params, Prepared};
use crate::imgio::LinearImage;
use crate::stage_model::StageModel;
use crate::stage_sim::{RigVariation, SceneConfig, SceneName, VirtualStage};

const STEP: &str = "compensate";

/// The true stage, as only evaluation may see it.
pub trait TruePhysics {
    /// True irradiance (lux per channel, room light included) at every camera pixel when the
    /// projectors show `frames`; NaN or 0 off the object.
    fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]>;
    /// What the camera (a visitor at its place) sees, linear camera values.
    fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]>;
    /// The true peak irradiance (lux, max channel, room light included) over the whole lit
    /// surface, wherever the light lands, seen by the camera or not. A stage that knows no
    /// surface beyond the camera's pixels (the synthetic one) returns its camera-pixel peak.
    fn surface_peak_lux(&self, frames: &[RgbImage]) -> f64;
    /// Which camera pixels see a chip (paint lost down to the ground), where the stage knows;
    /// `None` where it does not.
    fn chipped(&self) -> Option<Vec<bool>> {
        None
    }
}

impl TruePhysics for VirtualStage {
    fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]> {
        let room = self.setup().stray_lux;
        let e = self.irradiance(frames).expect("frames were made for this stage");
        e.iter()
            .zip(self.pixels())
            .map(|(e, p)| if p.is_object() { e.map(|v| v as f64 + room) } else { [f64::NAN; 3] })
            .collect()
    }

    fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]> {
        self.render(frames, false).expect("frames were made for this stage").data
    }

    fn surface_peak_lux(&self, frames: &[RgbImage]) -> f64 {
        self.surface_peak(frames).expect("frames were made for this stage").lux
    }

    fn chipped(&self) -> Option<Vec<bool>> {
        Some(self.pixels().iter().map(|p| p.is_object() && p.chipped).collect())
    }
}

/// The ideal restoration of a virtual stage's object as the camera should see it: its
/// pristine paint (albedo, the area mean on mixed pixels), 0 off the object and on the
/// plinth.
pub fn pristine_target(stage: &VirtualStage) -> LinearImage {
    let cam = stage.camera();
    let data =
        stage.pixels().iter().map(|p| if p.is_object() { p.albedo_pristine } else { [0.0; 3] }).collect();
    LinearImage { width: cam.width, height: cam.height, data }
}

/// A built-in scene at the evaluation's size (camera 480x360, projectors 560x420): the size of
/// the compensation figures here and of the probes that take them apart.
pub fn eval_scene(scene: SceneName, seed: u64, rig: RigVariation) -> SceneConfig {
    SceneConfig { scene, seed, camera: [480, 360], projector: [560, 420], rig, ..SceneConfig::default() }
}

/// Every built-in scene at an evaluation size (camera 480x360, projectors 560x420), and the
/// vase again standing on the grey plinth: the object's pristine paint as the target (0 on
/// the plinth, which is not to be lit), compensated with the TRUE stage model (geometry,
/// responses; it knows nothing of interreflection) by the formula, and again refined on the
/// stage's true footprints ([`VirtualStage::true_transport`]), judged with the true physics.
pub fn evaluate_builtin(
    seed: u64,
    rig: RigVariation,
    params: &Params,
) -> Result<Vec<Metric>, CompensateError> {
    let mut rows = Vec::new();
    let cases = SceneName::ALL.into_iter().map(|scene| (scene, false)).chain([(SceneName::Vase, true)]);
    for (scene, plinth) in cases {
        let cfg = SceneConfig { plinth, ..eval_scene(scene, seed, rig) };
        let stage = VirtualStage::new(&cfg).expect("built-in scene configuration is valid");
        let model = stage.truth();
        let target = pristine_target(&stage);
        let label = if plinth { format!("{} on a plinth", scene.name()) } else { scene.name().to_string() };
        rows.extend(evaluate(&label, &stage, &model, &target, params)?);
        // Side by side: the same true model with the footprints a perfect transport
        // measurement would give, refined on them.
        if params.footprint_rounds > 0 {
            let with_footprints = StageModel { transport: stage.true_transport(), ..model };
            let prep = Prepared::new(&with_footprints, params.reduction)?;
            let label = format!("{label}, {} footprint rounds", params.footprint_rounds);
            rows.extend(visitor_view(&label, &stage, &with_footprints, &prep, &target, params)?);
        }
    }
    Ok(rows)
}

impl TruePhysics for SyntheticStage {
    fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]> {
        SyntheticStage::true_lux(self, frames)
    }

    fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]> {
        SyntheticStage::view(self, frames)
    }

    /// The synthetic stage is a height field seen only through the camera's pixels: its
    /// whole lit surface is what the camera sees, so the camera-pixel peak.
    fn surface_peak_lux(&self, frames: &[RgbImage]) -> f64 {
        true_peak(self, frames)
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

/// The view over the object's pixels (where the target is not black): see [`whole_object`].
#[derive(Clone, Copy, Debug)]
pub struct WholeObject {
    /// The share of the object's pixels the compensation lights (some projector has weight).
    pub lit_share: f64,
    /// Mean CIEDE2000 over every object pixel, lit or not.
    pub mean: f64,
    /// Mean CIEDE2000 over the lit object pixels only: the covered pixels without those off
    /// the object (the target black there, the view only spill from the lit edge beside them).
    pub lit_mean: f64,
    /// The object's pixels.
    pub pixels: usize,
}

/// Over every pixel of the object (where the target is not black), not only those the model
/// covers: the share the compensation lights and the mean CIEDE2000 of what the visitor sees,
/// after the global scale, over all of them and over the lit ones. An object pixel the model
/// leaves unlit shows room light only and counts as the error it is.
pub fn whole_object(comp: &Compensation, view: &[[f32; 3]], target: &LinearImage) -> WholeObject {
    let s = comp.stats.scale;
    let kn = comp.frames.len();
    let object: Vec<usize> = (0..view.len()).filter(|&i| target.data[i].iter().any(|&c| c > 0.0)).collect();
    if object.is_empty() || s <= 0.0 {
        return WholeObject { lit_share: f64::NAN, mean: f64::NAN, lit_mean: f64::NAN, pixels: object.len() };
    }
    let lit: Vec<usize> = object
        .iter()
        .copied()
        .filter(|&i| comp.weights[i * kn..(i + 1) * kn].iter().any(|&w| w > 0.0))
        .collect();
    let (mean, _) = region_error(comp, view, target, &object);
    let (lit_mean, _) = region_error(comp, view, target, &lit);
    WholeObject { lit_share: lit.len() as f64 / object.len() as f64, mean, lit_mean, pixels: object.len() }
}

/// Over the camera pixels `pixels`, lit or not: the mean CIEDE2000 of the view (after the
/// global scale) against the target, and the view's mean luminance over the target's (above
/// 1: brighter than the target, as a halo is).
pub fn region_error(
    comp: &Compensation,
    view: &[[f32; 3]],
    target: &LinearImage,
    pixels: &[usize],
) -> (f64, f64) {
    let s = comp.stats.scale;
    if pixels.is_empty() || s <= 0.0 {
        return (f64::NAN, f64::NAN);
    }
    let (mut de, mut seen, mut wanted) = (0.0, 0.0, 0.0);
    for &i in pixels {
        let v = view[i].map(|c| c as f64 / s);
        let t = target.data[i].map(f64::from);
        let d = ciede2000(linear_srgb_to_lab(v), linear_srgb_to_lab(t));
        if d.is_finite() {
            de += d;
        }
        seen += crate::color::luminance(v);
        wanted += crate::color::luminance(t);
    }
    (de / pixels.len() as f64, seen / wanted)
}

/// Width of the ring around chips whose error is reported apart (camera pixels): where a
/// projector pixel's blurred footprint spills the chip's compensation onto the paint around
/// it, or the paint's onto the chip.
pub const CHIP_RING_PX: i64 = 2;

/// The chipped object pixels, and the ring of object pixels within [`CHIP_RING_PX`]
/// (Euclidean, pixel centres) of a chip but not in one. `object` says which pixels count.
pub fn chip_regions(chipped: &[bool], object: &[bool], width: usize) -> (Vec<usize>, Vec<usize>) {
    let height = chipped.len() / width.max(1);
    let r = CHIP_RING_PX;
    let near_chip = |i: usize| {
        let (x, y) = ((i % width) as i64, (i / width) as i64);
        (-r..=r).any(|dy| {
            (-r..=r).any(|dx| {
                let (u, v) = (x + dx, y + dy);
                dx * dx + dy * dy <= r * r
                    && (0..width as i64).contains(&u)
                    && (0..height as i64).contains(&v)
                    && chipped[v as usize * width + u as usize]
            })
        })
    };
    let chips = (0..chipped.len()).filter(|&i| object[i] && chipped[i]).collect();
    let ring = (0..chipped.len()).filter(|&i| object[i] && !chipped[i] && near_chip(i)).collect();
    (chips, ring)
}

/// The ring's pixels split into those with a 4-neighbour in a chip and the rest.
pub fn ring_by_distance(chipped: &[bool], ring: &[usize], width: usize) -> (Vec<usize>, Vec<usize>) {
    let n = chipped.len();
    let beside = |i: usize| {
        (!i.is_multiple_of(width) && chipped[i - 1])
            || (i % width + 1 < width && chipped[i + 1])
            || (i >= width && chipped[i - width])
            || (i + width < n && chipped[i + width])
    };
    ring.iter().partition(|&&i| beside(i))
}

/// Highest true irradiance (lux, max channel, room light included) at the camera's pixels on
/// the object (the surface the camera does not see is not counted: see
/// [`TruePhysics::surface_peak_lux`]).
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

/// Light the projectors emit for `frames` above black: per projector, its brightness
/// (`lux_at_1m`) times the summed relative output of its pixels, luminance-weighted
/// (Rec. 709 weights over the channels' responses). Proportional to emitted lumens.
pub fn emitted_light(model: &StageModel, frames: &[RgbImage]) -> f64 {
    const Y: [f64; 3] = crate::color::REC709_LUMA;
    model
        .projectors
        .iter()
        .zip(frames)
        .map(|(p, f)| {
            let sum: f64 = f
                .pixels()
                .map(|px| (0..3).map(|c| Y[c] * p.response[c][px.0[c] as usize] as f64).sum::<f64>())
                .sum();
            p.lux_at_1m * sum
        })
        .sum()
}

/// Mean luminance (Y, camera units) of the view over covered pixels.
pub fn mean_luminance(comp: &Compensation, view: &[[f32; 3]]) -> f64 {
    let kn = comp.frames.len();
    let (mut sum, mut count) = (0.0, 0usize);
    for (i, v) in view.iter().enumerate() {
        if comp.weights[i * kn..(i + 1) * kn].iter().any(|&w| w > 0.0) {
            sum += crate::color::luminance(v.map(f64::from));
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
    let mut rows = visitor_view(label, truth, model, &prep, target, params)?;
    rows.extend(tradeoff(label, truth, model, &prep, target, params)?);
    Ok(rows)
}

/// What the visitor sees at the user's m: colour error on the pixels the model covers and over
/// the whole object, how much of the object is lit, the true peaks against E_bound, and the
/// fractions limited by the bound and by saturation.
pub fn visitor_view(
    label: &str,
    truth: &dyn TruePhysics,
    model: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Vec<Metric>, CompensateError> {
    let comp = compensate::compensate_prepared(model, prep, target, params)?;
    let view = truth.view(&comp.frames);
    let (mean, p95, n) = colour_error(&comp, &view, target);
    let whole = whole_object(&comp, &view, target);
    let name = |s: &str| format!("{label}: {s}");
    let mut rows = vec![
        Metric::below(STEP, &name(&format!("CIEDE2000 mean (m = {})", params.m)), mean, "dE00", 3.0),
        Metric::info(STEP, &name("CIEDE2000 p95"), p95, "dE00"),
        Metric::info(STEP, &name("covered pixels"), n as f64, "px"),
        Metric::info(STEP, &name("object pixels"), whole.pixels as f64, "px"),
        Metric::info(STEP, &name("object pixels lit"), 100.0 * whole.lit_share, "%"),
        Metric::info(
            STEP,
            &name("CIEDE2000 mean over the whole object, unlit pixels included"),
            whole.mean,
            "dE00",
        ),
        Metric::info(STEP, &name("CIEDE2000 mean over the object's lit pixels"), whole.lit_mean, "dE00"),
    ];
    // Where the target is darker than the projectors' black level and the room: the share,
    // and the error there (a low bound lowers the scale while the black level stays).
    let dark = compensate::below_black(model, target, &comp.weights, comp.stats.scale);
    rows.push(Metric::info(
        STEP,
        &name("covered pixels asking for less light than the black level gives"),
        100.0 * dark.len() as f64 / n.max(1) as f64,
        "%",
    ));
    if !dark.is_empty() {
        let (de, _) = region_error(&comp, &view, target, &dark);
        rows.push(Metric::info(STEP, &name("CIEDE2000 mean there"), de, "dE00"));
    }
    if let Some(chipped) = truth.chipped() {
        let object: Vec<bool> = target.data.iter().map(|t| t.iter().any(|&c| c > 0.0)).collect();
        let (chips, ring) = chip_regions(&chipped, &object, target.width as usize);
        let (chip_de, chip_bright) = region_error(&comp, &view, target, &chips);
        let (ring_de, ring_bright) = region_error(&comp, &view, target, &ring);
        // The ring's pixels beside a chip (a 4-neighbour chipped) take the most of the light
        // spilled from it, and may hold some of its clay (a camera pixel counts as chipped
        // where most of its area is).
        let (beside, beyond) = ring_by_distance(&chipped, &ring, target.width as usize);
        let (beside_de, beside_bright) = region_error(&comp, &view, target, &beside);
        let (beyond_de, beyond_bright) = region_error(&comp, &view, target, &beyond);
        rows.extend([
            Metric::info(STEP, &name("CIEDE2000 mean in the ring's pixels beside a chip"), beside_de, "dE00"),
            Metric::info(STEP, &name("luminance there over the target's"), 100.0 * beside_bright, "%"),
            Metric::info(STEP, &name("CIEDE2000 mean in the ring's pixels beyond them"), beyond_de, "dE00"),
            Metric::info(STEP, &name("luminance beyond them over the target's"), 100.0 * beyond_bright, "%"),
        ]);
        rows.extend([
            Metric::info(STEP, &name("chip pixels"), chips.len() as f64, "px"),
            Metric::info(STEP, &name("CIEDE2000 mean in chips"), chip_de, "dE00"),
            Metric::info(STEP, &name("luminance in chips over the target's"), 100.0 * chip_bright, "%"),
            Metric::below(
                STEP,
                &name(&format!("CIEDE2000 mean in a {CHIP_RING_PX} px ring around chips")),
                ring_de,
                "dE00",
                3.0,
            ),
            Metric::info(
                STEP,
                &name("luminance in the chip ring over the target's"),
                100.0 * ring_bright,
                "%",
            ),
        ]);
    }
    if let Some(r) = comp.stats.refinement {
        rows.extend([
            Metric::info(STEP, &name("modelled mismatch, formula's frames"), 100.0 * r.mismatch_before, "%"),
            Metric::info(STEP, &name("modelled mismatch, refined frames"), 100.0 * r.mismatch_after, "%"),
        ]);
    }
    let camera_peak = true_peak(truth, &comp.frames);
    let surface_peak = truth.surface_peak_lux(&comp.frames);
    rows.push(Metric::info(STEP, &name("E_bound"), params.e_bound_lux, "lx"));
    rows.push(Metric::info(STEP, &name("recomputed peak (certificate)"), comp.stats.peak_lux, "lx"));
    rows.push(Metric::info(STEP, &name("true peak at camera pixels"), camera_peak, "lx"));
    // The bound protects the object wherever light lands, so the pass/fail row is the peak
    // over the whole lit surface, not only the part the camera sees.
    rows.push(Metric {
        target: Some(format!("<= {}", params.e_bound_lux)),
        pass: Some(surface_peak <= params.e_bound_lux),
        ..Metric::info(STEP, &name("true peak over the whole lit surface"), surface_peak, "lx")
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
    // The brightness the chosen clip fraction buys: the global scale, and at the other
    // fractions as a ratio to it (the visitor's view is judged after the scale, so a dimmer
    // object is not an error above; it is what the scale trades).
    rows.push(Metric::info(STEP, &name("global scale"), comp.stats.scale, ""));
    for c in &comp.stats.scale_by_clip {
        rows.push(Metric::info(
            STEP,
            &name(&format!("global scale at clip fraction {} %, over the chosen", 100.0 * c[0])),
            c[1] / comp.stats.scale,
            "",
        ));
    }
    Ok(rows)
}

/// A simulated capture's stage compensated for its pristine paint with its true model and
/// with `calibrated` (what `calibrate` made of the capture), all judged with the capture's
/// true physics: the rows of [`visitor_view`], labelled "true model", "calibrated, formula"
/// and, where the model has measured footprints, "calibrated, N footprint rounds".
pub fn evaluate_capture(
    capture: &Path,
    calibrated: &StageModel,
    params: &Params,
) -> anyhow::Result<Vec<Metric>> {
    let config = crate::stage_sim::load_config(capture)?;
    let stage = VirtualStage::new(&config)?;
    let truth = stage.truth();
    let (cam, cal) = (&truth.camera, &calibrated.camera);
    // Calibration takes the camera's intrinsics from the capture: a model of another capture
    // of the same sizes (another seed's rig) has another lens.
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
    if (cam.width, cam.height) != (cal.width, cal.height)
        || calibrated.projectors.len() != truth.projectors.len()
        || !(same(cam.fx, cal.fx) && same(cam.fy, cal.fy) && same(cam.cx, cal.cx) && same(cam.cy, cal.cy))
    {
        anyhow::bail!(
            "the calibrated model ({}x{} camera, fx {:.2}, {} projectors) is not of the capture in {} \
             ({}x{}, fx {:.2}, {})",
            cal.width,
            cal.height,
            cal.fx,
            calibrated.projectors.len(),
            capture.display(),
            cam.width,
            cam.height,
            cam.fx,
            truth.projectors.len()
        );
    }
    let target = pristine_target(&stage);
    let mut rows = Vec::new();
    let prep = Prepared::new(&truth, params.reduction)?;
    rows.extend(visitor_view("true model", &stage, &truth, &prep, &target, params)?);
    // The calibrated model with the paper's formula alone and, side by side, refined on the
    // footprints its transport step measured.
    let prep = Prepared::new(calibrated, params.reduction)?;
    let formula = Params { footprint_rounds: 0, ..params.clone() };
    rows.extend(visitor_view("calibrated, formula", &stage, calibrated, &prep, &target, &formula)?);
    if params.footprint_rounds > 0 && compensate::footprint::has_footprints(calibrated) {
        let label = format!("calibrated, {} footprint rounds", params.footprint_rounds);
        rows.extend(visitor_view(&label, &stage, calibrated, &prep, &target, params)?);
    }
    Ok(rows)
}

/// Brightness and smoothness for m in {0, 1, 2, 5, 8, inf} (paper Fig. 8), three ways:
/// - "light efficiency": the brightness the visitor sees above the black-frame view per unit
///   of light the projectors emit — the paper's sense of brightness ("energy wasted on
///   grazing angles"); m = infinity maximises it. The 90 % target is judged on it.
/// - "mean luminance at the bound": the visitor's mean luminance with the user's E_bound;
///   where the bound binds, every m reaches about the same irradiance (weights only decide
///   which projector supplies it).
/// - "mean luminance, saturation-limited": with a bound high enough that only the
///   projectors' maximum output limits brightness; blending projectors adds their outputs,
///   so finite m can beat m = infinity here.
///
/// Smoothness is the weight maps' roughness ([`weight_roughness`]).
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
    let e_sat = (2.0 * full).clamp(params.e_bound_lux, 1e6);
    let black: Vec<RgbImage> = model.projectors.iter().map(|p| RgbImage::new(p.width, p.height)).collect();
    let ms = [0.0, 1.0, 2.0, 5.0, 8.0, f64::INFINITY];
    let (mut eff, mut lum_bound, mut lum_sat, mut rough) = (vec![], vec![], vec![], vec![]);
    let mut rows = Vec::new();
    for m in ms {
        let m = if m.is_finite() { Exponent::Finite(m) } else { Exponent::Infinite };
        // At the user's bound.
        let p = Params { m, ..params.clone() };
        let comp = compensate::compensate_prepared(model, prep, target, &p)?;
        let view = truth.view(&comp.frames);
        let lum = mean_luminance(&comp, &view);
        let lum_black = mean_luminance(&comp, &truth.view(&black));
        let n_cov = comp.weights.chunks(kn).filter(|w| w.iter().any(|&x| x > 0.0)).count() as f64;
        eff.push((lum - lum_black) * n_cov / emitted_light(model, &comp.frames).max(1e-12));
        lum_bound.push(lum);
        rough.push(weight_roughness(&comp, model.camera.width));
        let (de, _, _) = colour_error(&comp, &view, target);
        // Saturation-limited.
        let p = Params { e_bound_lux: e_sat, m, ..params.clone() };
        let comp = compensate::compensate_prepared(model, prep, target, &p)?;
        lum_sat.push(mean_luminance(&comp, &truth.view(&comp.frames)));
        let row = |what: &str, v: f64, unit: &str| {
            Metric::info(STEP, &format!("{label}: m = {m}: {what}"), v, unit)
        };
        rows.push(row("mean luminance at the bound", lum, "cam"));
        rows.push(row("mean luminance, saturation-limited", lum_sat[lum_sat.len() - 1], "cam"));
        rows.push(row("weight roughness", rough[rough.len() - 1], ""));
        rows.push(row("CIEDE2000 mean", de, "dE00"));
    }
    for (i, m) in ms.iter().enumerate() {
        let m = if m.is_finite() { format!("{m}") } else { "inf".into() };
        rows.push(Metric::info(
            STEP,
            &format!("{label}: m = {m}: light efficiency / m=inf"),
            eff[i] / eff[5],
            "",
        ));
    }
    rows.push(Metric::at_least(
        STEP,
        &format!("{label}: light efficiency m=8 / m=inf"),
        eff[4] / eff[5],
        "",
        0.9,
    ));
    rows.push(Metric::info(
        STEP,
        &format!("{label}: luminance at the bound m=8 / m=inf"),
        lum_bound[4] / lum_bound[5],
        "",
    ));
    rows.push(Metric::info(
        STEP,
        &format!("{label}: luminance saturation-limited m=8 / m=inf"),
        lum_sat[4] / lum_sat[5],
        "",
    ));
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

    /// A calibrated model that lost a patch of its surface leaves that patch unlit: the
    /// covered-pixel error does not see it, the whole-object rows do.
    #[test]
    fn a_hole_in_the_calibrated_model_shows_as_unlit_object() {
        let cfg = SceneConfig { rig: RigVariation::Seeded, ..SceneConfig::tiny(SceneName::Jar, 4) };
        let stage = VirtualStage::new(&cfg).unwrap();
        let dir = tempfile::tempdir().unwrap();
        stage.write_ground_truth(dir.path()).unwrap();
        let mut holed = stage.truth();
        let w = holed.camera.width as usize;
        let object: Vec<usize> =
            (0..holed.points.len()).filter(|&i| holed.points[i][0].is_finite()).collect();
        let centre = object[object.len() / 2];
        let mut punched = 0;
        for i in object {
            if (i % w).abs_diff(centre % w) < 12 && (i / w).abs_diff(centre / w) < 12 {
                holed.points[i] = [f32::NAN; 3];
                holed.normals[i] = [f32::NAN; 3];
                punched += 1;
            }
        }
        let params = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
        let rows = evaluate_capture(dir.path(), &holed, &params).unwrap();
        let get = |label: &str, what: &str| {
            rows.iter()
                .find(|m| m.name == format!("{label}: {what}"))
                .unwrap_or_else(|| panic!("{label}: {what}"))
                .value
        };
        let object_px = get("true model", "object pixels");
        let (lit_true, lit_cal) =
            (get("true model", "object pixels lit"), get("calibrated, formula", "object pixels lit"));
        assert!(lit_true > 97.0, "{}", crate::eval::table(&rows));
        let lost = (lit_true - lit_cal) / 100.0 * object_px;
        assert!(
            lost >= 0.9 * punched as f64,
            "{lost} px unlit for {punched} punched\n{}",
            crate::eval::table(&rows)
        );
        let whole = "CIEDE2000 mean over the whole object, unlit pixels included";
        assert!(
            get("calibrated, formula", whole) > get("true model", whole) + 1.0,
            "{}",
            crate::eval::table(&rows)
        );
        // The lit pixels' mean leaves the hole out: it is the whole object's but for it.
        let lit = "CIEDE2000 mean over the object's lit pixels";
        assert!(
            get("calibrated, formula", lit) < get("calibrated, formula", whole) - 0.5,
            "{}",
            crate::eval::table(&rows)
        );
        // A model of another capture is refused, naming it: another size, or the same size
        // on another seed's rig (another lens).
        for other in
            [SceneConfig { camera: [200, 150], ..cfg.clone() }, SceneConfig { seed: 5, ..cfg.clone() }]
        {
            let other = VirtualStage::new(&other).unwrap().truth();
            let err = evaluate_capture(dir.path(), &other, &params).unwrap_err();
            assert!(format!("{err:#}").contains("not of the capture"), "{err:#}");
        }
    }

    #[test]
    fn the_chip_ring_is_the_object_within_two_pixels_of_a_chip() {
        let (w, h) = (9, 7);
        let mut chipped = vec![false; w * h];
        chipped[3 * w + 4] = true;
        let mut object = vec![true; w * h];
        object[3 * w + 6] = false; // two to the right: off the object
        let (chips, ring) = chip_regions(&chipped, &object, w);
        assert_eq!(chips, vec![3 * w + 4]);
        // The disc of radius 2 holds 13 pixel centres: less the chip and the pixel off the object.
        assert_eq!(ring.len(), 11, "{ring:?}");
        for &i in &ring {
            let (dx, dy) = ((i % w) as i64 - 4, (i / w) as i64 - 3);
            assert!(dx * dx + dy * dy <= 4 && object[i] && !chipped[i]);
        }
        // Beside the chip: its four 4-neighbours; the other seven lie beyond them.
        let (beside, beyond) = ring_by_distance(&chipped, &ring, w);
        assert_eq!(beside, vec![2 * w + 4, 3 * w + 3, 3 * w + 5, 4 * w + 4]);
        assert_eq!(beyond.len(), 7, "{beyond:?}");
        // A chip on the border: the ring stays inside the image.
        let mut corner = vec![false; w * h];
        corner[0] = true;
        let (_, ring) = chip_regions(&corner, &vec![true; w * h], w);
        assert_eq!(ring.len(), 5, "{ring:?}");
    }

    /// The chip rows count the stage's chipped pixels, and the ring row sees light spilled
    /// around the chips that the rest of the object does not show.
    #[test]
    fn chips_and_their_rings_are_reported_apart() {
        let cfg = SceneConfig::tiny(SceneName::Bowl, 2);
        let stage = VirtualStage::new(&cfg).unwrap();
        let model = stage.truth();
        let target = pristine_target(&stage);
        let params = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
        let prep = Prepared::new(&model, params.reduction).unwrap();
        let rows = visitor_view("bowl", &stage, &model, &prep, &target, &params).unwrap();
        let get = |what: &str| rows.iter().find(|m| m.name == format!("bowl: {what}")).unwrap().value;
        let chipped = stage.pixels().iter().filter(|p| p.is_object() && p.chipped).count();
        assert!(chipped > 20, "the scene has chips");
        assert_eq!(get("chip pixels"), chipped as f64);
        let ring = get("CIEDE2000 mean in a 2 px ring around chips");
        assert!(
            ring.is_finite() && get("CIEDE2000 mean in chips").is_finite(),
            "{}",
            crate::eval::table(&rows)
        );

        // Light added on the ring alone raises the ring's error and leaves the whole object's
        // nearly as it was.
        let comp = compensate::compensate_prepared(&model, &prep, &target, &params).unwrap();
        let mut view = stage.view(&comp.frames);
        let object: Vec<bool> = target.data.iter().map(|t| t.iter().any(|&c| c > 0.0)).collect();
        let chipped: Vec<bool> = TruePhysics::chipped(&stage).unwrap();
        let (_, ring_px) = chip_regions(&chipped, &object, target.width as usize);
        let (before, _) = region_error(&comp, &view, &target, &ring_px);
        for &i in &ring_px {
            view[i] = view[i].map(|c| c * 1.5);
        }
        let (after, bright) = region_error(&comp, &view, &target, &ring_px);
        assert!(after > before + 2.0 && bright > 1.2, "{before} -> {after}, {bright}");
    }

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
        assert_eq!(get("true peak over the whole lit surface").pass, Some(true));
        // The synthetic stage has no surface beyond its pixels: both peaks agree.
        assert_eq!(get("true peak at camera pixels").value, get("whole lit surface").value);
        let de = get("CIEDE2000 mean (m = 8)").value;
        assert!(de.is_finite() && de > 0.0, "{de}");
        assert!(rows.iter().any(|r| r.name.contains("m = inf: mean luminance")));
    }

    /// The tester's case: the lux meter read 10 % low, so every projector's calibrated
    /// brightness is 10 % low; with the default meter accuracy the TRUE peak stays under
    /// E_bound. And the margin is what keeps it there: a meter reading 20 % low, declared
    /// (`--meter-accuracy 0.2`), stays under; taken as exact (`--meter-accuracy 0`), the same
    /// stage goes over. (At 10 % the certificate's own conservatism — coefficients bounded over
    /// each pixel's stretch of surface — already absorbs most of the error on this stage.)
    #[test]
    fn meter_accuracy_keeps_the_true_peak_under_e_bound_when_the_meter_read_low() {
        let cfg = SceneConfig {
            camera: [480, 360],
            projector: [560, 420],
            ..SceneConfig::tiny(SceneName::Vase, 1)
        };
        let stage = VirtualStage::new(&cfg).unwrap();
        let target = pristine_target(&stage);
        let run = |reading: f64, p: &Params| {
            let mut model = stage.truth();
            for pr in &mut model.projectors {
                pr.lux_at_1m *= reading;
            }
            let c = compensate::compensate(&model, &target, p).unwrap();
            (true_peak(&stage, &c.frames), c.stats)
        };
        let p = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
        let (tp, stats) = run(0.9, &p);
        // The bound must bind, or the test would prove nothing.
        assert!(stats.limited_by_bound > 0 && stats.peak_lux > 0.95 * p.limit(), "{stats:?}");
        assert!(tp <= 150.0, "true peak {tp} lx > E_bound 150 lx (certificate peak {})", stats.peak_lux);
        let (tp, stats) = run(0.8, &p.clone().with_meter_accuracy(0.2).unwrap());
        assert!(tp <= 150.0, "20 % low, declared: true peak {tp} lx (certificate {})", stats.peak_lux);
        let (tp0, stats0) = run(0.8, &p.clone().with_meter_accuracy(0.0).unwrap());
        assert!(
            tp0 > 150.0,
            "20 % low, taken as exact: true peak {tp0} lx (certificate {})",
            stats0.peak_lux
        );
    }
}

/// The light bound over the whole surface on the built-in scenes (issue "The light bound on
/// physics we did not write"): the true peak wherever the light lands, the camera's far side
/// and grazing silhouettes included, stays under E_bound with the true stage model.
#[cfg(test)]
mod whole_surface {
    use super::*;

    #[test]
    fn true_peak_over_the_whole_surface_stays_under_the_bound_on_every_scene() {
        let cases = SceneName::ALL.into_iter().flat_map(|s| [(s, 1, false), (s, 5, false)]);
        // The vase on its plinth: light bounced off the plinth counts too.
        for (scene, seed, plinth) in cases.chain([(SceneName::Vase, 1, true)]) {
            let stage = VirtualStage::new(&coarse(scene, seed, plinth)).unwrap();
            check(&stage, &format!("{} seed {seed} plinth {plinth}", scene.name()));
        }
    }

    /// The independent renderer's overshoot, staged: one projector stands beside the object
    /// (85 degrees round from the camera), so it lights head-on the strip the camera sees at
    /// a grazing angle near the silhouette, and a second projector adds to it. One point and
    /// one normal per camera pixel there underestimates the light over the pixel's stretch
    /// of surface, and past the silhouette the light lands where the camera sees nothing.
    #[test]
    fn a_projector_beside_the_object_stays_under_the_bound_at_the_grazing_silhouette() {
        for (scene, seed) in [(SceneName::Vase, 1), (SceneName::Jar, 5)] {
            let cfg = coarse(scene, seed, false);
            let setup = crate::stage_sim::Setup::from_config(&cfg).unwrap();
            let mut specs = setup.projector_specs.clone();
            specs[2].azimuth_deg = 85.0;
            specs[2].elevation_deg = 6.0;
            specs[1].azimuth_deg = 40.0;
            let stage = VirtualStage::from_setup(setup.with_projector_specs(specs));
            check(&stage, &format!("{} seed {seed}, a projector at 85 degrees", scene.name()));
        }
    }

    /// Coarse projectors make each pixel's footprint large: the hardest case.
    fn coarse(scene: SceneName, seed: u64, plinth: bool) -> SceneConfig {
        SceneConfig {
            scene,
            seed,
            camera: [200, 150],
            projector: [160, 120],
            plinth,
            // The README's table of these peaks is on the nominal rig.
            rig: RigVariation::Nominal,
            ..SceneConfig::default()
        }
    }

    /// Compensates `stage` from its true model, as a real decode leaves it, with the meter
    /// exact and reading 10 % low, and checks the true peak over the whole lit surface.
    fn check(stage: &VirtualStage, label: &str) {
        let p = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
        // As a real decode leaves it: surface the camera sees at more than 80 degrees is not
        // reconstructed (the tester's path-traced vase lost its neck's silhouette so).
        let mut model = stage.truth();
        for i in 0..model.points.len() {
            let (x, n) = (model.points[i].map(f64::from), model.normals[i].map(f64::from));
            let d = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
            if -(x[0] * n[0] + x[1] * n[1] + x[2] * n[2]) / d < 0.17 {
                model.points[i] = [f32::NAN; 3];
                model.normals[i] = [f32::NAN; 3];
                for c in &mut model.correspondences {
                    c[i] = [f32::NAN; 2];
                }
            }
        }
        // With the meter exact and reading 10 % low (every projector's calibrated brightness
        // 10 % low, so the frames come out brighter): the default meter accuracy covers it.
        for reading in [1.0, 0.9] {
            let mut model = model.clone();
            for pr in &mut model.projectors {
                pr.lux_at_1m *= reading;
            }
            let comp = compensate::compensate(&model, &pristine_target(stage), &p).unwrap();
            let peak = stage.surface_peak(&comp.frames).unwrap();
            let at_pixels = true_peak(stage, &comp.frames);
            eprintln!(
                "FIGURES {label}, meter reading {reading}: true peak over the surface {:.1} lx, at camera \
                 pixels {:.1} lx, certificate {:.1} lx",
                peak.lux, at_pixels, comp.stats.peak_lux
            );
            // The whole surface includes every camera pixel's point: its peak is no lower
            // (1 % for the camera pixels' box-filtered light against point samples).
            assert!(peak.lux >= 0.99 * at_pixels, "surface {:.1} lx < pixels {at_pixels:.1} lx", peak.lux);
            assert!(
                peak.lux <= p.e_bound_lux,
                "{label}, reading {reading}: true peak {:.1} lx at {:?} (projector {} pixel {:?}) > {} lx",
                peak.lux,
                peak.point_mm,
                peak.projector,
                peak.projector_px,
                p.e_bound_lux
            );
            // The bound does not darken the object: most of it is still lit.
            assert!(comp.stats.covered_points > 1000, "{}", comp.stats.covered_points);
        }
    }
}
