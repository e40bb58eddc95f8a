//! Light-bounded compensation (paper §5.1, with the brief's fixes): from a stage model and a
//! restored image, one 8-bit frame per projector that makes the object look restored, as
//! bright as the light bound and the projectors allow, smooth across overlaps (Eq. 12), and
//! never above `E_bound` per unit area — checked on the final frames (see [`guarantee`]).
//!
//! How a frame is made: each object point i (camera pixel) needs irradiance
//! `D_i = (s G_i - ambient_i) / gain_i` above black, per channel, for the camera to see
//! `s G_i`. Projector k supplies the share `w_ik` of it, so its relative output (response
//! scale) is `w_ik D_i / eta_ik`, where `eta_ik` is the lux the pixel gives per unit output.
//! The global scale `s` is the largest that keeps every point under the bound (black level
//! included, fix 2) and every projector unsaturated (fix 1) — except for a user-chosen small
//! fraction of points (`clip_fraction`), which get the view nearest their target that they
//! can ([`gamut`]) instead of darkening the whole object. Outputs of the points falling on
//! one projector pixel are averaged (tent splatting over each camera pixel's footprint),
//! pixels lighting no object point stay black, and outputs go through the inverse responses
//! to 8-bit values.

pub mod certificate;
pub mod footprint;
pub mod gamut;
pub mod geometry;
pub mod gpu;
pub mod guarantee;
pub mod io;
pub mod landing;
pub mod report;
pub mod response;
pub mod synthetic;
pub mod weights;

use image::RgbImage;
use rayon::prelude::*;
use restage_shared::light::{LightError, LightModel, check_bound};
use thiserror::Error;

pub use self::certificate::Certificate;
pub use self::geometry::Geometry;
pub use self::guarantee::Enforcement;
use self::guarantee::bound_lux;
use self::response::InverseResponse;
pub use self::weights::Exponent;
use crate::gpu::{Device, GpuError};
use crate::imgio::LinearImage;
use crate::stage_model::{StageModel, StageModelError};

#[derive(Debug, Error)]
pub enum CompensateError {
    #[error(
        "restored image is {got_w}x{got_h} but the stage model's camera is {want_w}x{want_h} \
         (the restored image must be in camera space)"
    )]
    SizeMismatch { got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("E_bound {0} lux is invalid (expected a finite number of lux > 0)")]
    BadBound(f64),
    #[error("safety margin {0} is invalid (expected a fraction 0 <= margin <= 0.5, e.g. 0.05)")]
    BadMargin(f64),
    #[error(
        "lux-meter accuracy {0} is invalid (expected a fraction 0 <= accuracy < 0.5, e.g. 0.10 for \
         a class-B meter)"
    )]
    BadMeterAccuracy(f64),
    #[error(
        "lux-meter accuracy {accuracy} and safety margin {margin} together hold back {combined:.3} \
         of E_bound, more than the 0.5 a bundle's light model accepts; lower one of them"
    )]
    CombinedMargin { accuracy: f64, margin: f64, combined: f64 },
    #[error("smoothness exponent m = {0} is invalid (expected a number >= 0, or infinity)")]
    BadExponent(f64),
    #[error("clip fraction {0} is invalid (expected 0 <= fraction <= 0.5)")]
    BadClipFraction(f64),
    #[error("certificate reduction {0} is invalid (expected 1..=16 camera pixels per point)")]
    BadReduction(u32),
    #[error("{0} footprint rounds is invalid (expected 0..={MAX_FOOTPRINT_ROUNDS}; 0 is the formula alone)")]
    BadFootprintRounds(u32),
    #[error(
        "the projectors' black level (plus {room_lux:.2} lux of room light) alone gives \
         {black_lux:.2} lux at camera pixel ({x}, {y}), above the usable bound {limit:.2} lux \
         (E_bound {e_bound} lux less the {margin:.4} held back for the margin and the lux \
         meter's accuracy): no frames can stay under this \
         bound; raise E_bound, dim the room or switch projectors off"
    )]
    BlackAboveBound { black_lux: f64, room_lux: f64, x: u32, y: u32, limit: f64, e_bound: f64, margin: f64 },
    #[error(
        "the stage model has no radiometric calibration (per-pixel gain has {got} entries, \
         expected {want}); run calibration with gray ramps first"
    )]
    NoGain { got: usize, want: usize },
    #[error("no object point is lit by any projector: the stage model has no coverage")]
    NoCoverage,
    #[error("the object mask has {got} pixels, the target image {want} (both must be camera size)")]
    MaskSize { got: usize, want: usize },
    #[error(
        "the independent light check refused the frames ({0}); this is a bug in compensation \
         — no frames were written"
    )]
    IndependentCheck(LightError),
    #[error(transparent)]
    Stage(#[from] StageModelError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// What the conservator chooses.
#[derive(Clone, Debug)]
pub struct Params {
    /// Maximum irradiance per unit area, lux.
    pub e_bound_lux: f64,
    /// Smoothness exponent of Eq. 12.
    pub m: Exponent,
    /// Safety margin: the recomputed irradiance must stay at or below
    /// `E_bound * (1 - meter_accuracy) * (1 - margin)`.
    pub margin: f64,
    /// Relative accuracy of the lux meter that calibrated `lux_at_1m` (a fraction): a reading
    /// low by this share makes every modelled lux low by the factor `1 - meter_accuracy`, so the
    /// modelled peak must stay under `E_bound * (1 - meter_accuracy)`.
    pub meter_accuracy: f64,
    /// Fraction of object points that may be dimmed locally (below the global scale) so that
    /// a few hard points do not darken the whole object; 0 is the paper's pure global scale.
    pub clip_fraction: f64,
    /// Whether the model may choose a larger fraction ([`AutoClip`]).
    pub auto_clip: AutoClip,
    /// Camera pixels per light-certificate point along each axis (1 = every object point).
    pub reduction: u32,
    /// Rounds of footprint-aware refinement on the measured transport ([`footprint`]); 0 is
    /// the paper's per-pixel formula alone. Ignored when the model has no transport.
    pub footprint_rounds: u32,
}

/// The most rounds of footprint-aware refinement accepted (each costs about what the draft does).
pub const MAX_FOOTPRINT_ROUNDS: u32 = 64;

/// Default share of object points that may be dimmed on their own ([`Params::clip_fraction`]).
pub const DEFAULT_CLIP_FRACTION: f64 = 0.01;

/// When the stage model may choose a larger clip fraction than the one asked ([`AUTO_CLIP`],
/// never less): at a low bound the projectors' black level and the room lift a dim object,
/// and a brighter scale with more points dimmed on their own shows it better. Each candidate's
/// formula frames are judged by their modelled view against the target (`choose_clip`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum AutoClip {
    /// Always the asked fraction.
    Off,
    /// Only where more than 5 % of the lit points (`LIFTED_SHARE`) ask, at the asked fraction,
    /// for less light than the black level and the room give: there the choice is worth its
    /// cost (the formula at about ten fractions, one more refinement); elsewhere it costs nothing.
    #[default]
    Lifted,
    /// Always judge every candidate.
    Always,
}

/// The share of lit points below the black level ([`below_black`]) above which compensation
/// warns and [`AutoClip::Lifted`] lets the model choose the clip fraction.
pub const LIFTED_SHARE: f64 = 0.05;

/// The lux meter's accuracy assumed unless told: a class-B illuminance meter. DIN 5032-7
/// (1985 edition) sets the total error limits ("Gesamtfehler") of its classes L, A, B and C at
/// 3 %, 5 %, 10 % and 20 % (the table as reproduced in the MX-Elektronik Minilux manual,
/// manuals.online/mx-elektronik/measuring-instrument/minilux/user-manual/1no14); the 2017
/// edition reworks the classification but class B remains the usual field instrument (e.g.
/// Benning's "Luxmeter B"). A museum's handheld meter is at best that, so 10 %.
pub const DEFAULT_METER_ACCURACY: f64 = 0.10;

/// The share of E_bound held back when the meter may read low by `meter_accuracy` and
/// `margin` is kept on top: `1 - (1 - meter_accuracy) (1 - margin)`. The bundle's light model
/// carries this as its safety margin, so the appliance enforces the same limit.
pub fn combined_margin(margin: f64, meter_accuracy: f64) -> f64 {
    1.0 - (1.0 - meter_accuracy) * (1.0 - margin)
}

impl Params {
    /// Parameters with the default clip fraction, reduction and [`DEFAULT_METER_ACCURACY`].
    pub fn new(e_bound_lux: f64, m: Exponent, margin: f64) -> Result<Self, CompensateError> {
        let p = Self {
            e_bound_lux,
            m,
            margin,
            meter_accuracy: DEFAULT_METER_ACCURACY,
            clip_fraction: DEFAULT_CLIP_FRACTION,
            auto_clip: AutoClip::default(),
            reduction: 2,
            footprint_rounds: footprint::DEFAULT_ROUNDS,
        };
        p.validate()?;
        Ok(p)
    }

    /// The same parameters for a meter of relative accuracy `u` (a fraction, e.g. 0.10).
    pub fn with_meter_accuracy(self, u: f64) -> Result<Self, CompensateError> {
        let p = Self { meter_accuracy: u, ..self };
        p.validate()?;
        Ok(p)
    }

    /// The margin the bundle's light model carries: see [`combined_margin`].
    pub fn combined_margin(&self) -> f64 {
        combined_margin(self.margin, self.meter_accuracy)
    }

    pub fn validate(&self) -> Result<(), CompensateError> {
        if !(self.e_bound_lux.is_finite() && self.e_bound_lux > 0.0) {
            return Err(CompensateError::BadBound(self.e_bound_lux));
        }
        if !(0.0..=0.5).contains(&self.margin) {
            return Err(CompensateError::BadMargin(self.margin));
        }
        // `contains` is false for NaN; infinities are outside the range.
        if !(0.0..0.5).contains(&self.meter_accuracy) {
            return Err(CompensateError::BadMeterAccuracy(self.meter_accuracy));
        }
        let combined = self.combined_margin();
        if combined > 0.5 {
            return Err(CompensateError::CombinedMargin {
                accuracy: self.meter_accuracy,
                margin: self.margin,
                combined,
            });
        }
        if !(0.0..=0.5).contains(&self.clip_fraction) {
            return Err(CompensateError::BadClipFraction(self.clip_fraction));
        }
        if !(1..=16).contains(&self.reduction) {
            return Err(CompensateError::BadReduction(self.reduction));
        }
        if self.footprint_rounds > MAX_FOOTPRINT_ROUNDS {
            return Err(CompensateError::BadFootprintRounds(self.footprint_rounds));
        }
        if let Exponent::Finite(m) = self.m
            && !(m.is_finite() && m >= 0.0)
        {
            return Err(CompensateError::BadExponent(m));
        }
        Ok(())
    }

    /// The limit the final frames are held to, lux: `E_bound (1 - u) (1 - margin)`, computed
    /// as the bundle's light model computes its allowed lux from the combined margin, so the
    /// two agree to the last bit.
    pub fn limit(&self) -> f64 {
        self.e_bound_lux * (1.0 - self.combined_margin())
    }
}

/// Figures about one compensation.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stats {
    /// Object points lit by at least one projector and with a calibrated gain.
    pub covered_points: usize,
    /// Covered points whose target needed more light than the bound allows at scale `s`.
    pub limited_by_bound: usize,
    /// Covered points whose target needed more output than a projector has at scale `s`.
    pub limited_by_saturation: usize,
    /// Highest recomputed irradiance of the final frames, lux.
    pub peak_lux: f64,
    /// Highest irradiance with every frame black (black level plus room light), lux.
    pub peak_black_lux: f64,
    /// Room light counted everywhere (estimated from the stage model's ambient), lux.
    pub room_lux: f64,
    pub certificate_points: usize,
    pub e_bound_lux: f64,
    pub limit_lux: f64,
    /// Global scale s: camera value per unit of the target's linear value.
    pub scale: f64,
    pub rounds: u32,
    pub dimmed_pixels: usize,
    /// Lit pixels set black because the certificate could not vouch for them in the
    /// appliance's light check (`restage_shared::light::Coverage`); 0 in practice.
    pub unvouched_pixels: usize,
    /// Projector pixels the draft lit whose light would land on surface the model does not
    /// know (unseen, unreconstructed, past a silhouette), set black.
    #[serde(default)]
    pub unseen_dark_pixels: usize,
    /// Certificate points standing for unknown surface beside the known landing.
    #[serde(default)]
    pub unseen_points: usize,
    /// The footprint-aware refinement, if it ran (the model has measured footprints and
    /// rounds were asked for).
    #[serde(default)]
    pub refinement: Option<footprint::Refinement>,
    /// The pixels the target asks to light that stay without light, and why.
    #[serde(default)]
    pub unlit: Unlit,
    /// Covered points whose target, at scale `s`, is darker than the projectors' black level
    /// and the room already light them ([`below_black`]): no frame can take light away, so
    /// they show lifted. A low bound lowers `s` while the black level stays.
    #[serde(default)]
    pub below_black: usize,
    /// `[clip fraction, global scale]` at each of [`CLIP_CURVE`]: how bright the whole object
    /// would be had another fraction of points been allowed to dim locally (empty in files
    /// written before it was kept).
    #[serde(default)]
    pub scale_by_clip: Vec<[f64; 2]>,
    /// The clip fraction the scale was taken at: `Params::clip_fraction`, or the one the model
    /// chose ([`Params::auto_clip`]).
    #[serde(default)]
    pub clip_fraction: f64,
    /// `[clip fraction, modelled CIEDE2000 of its formula frames]` of each candidate the model
    /// judged, in order ([`AutoClip`]); empty where it kept the asked fraction without judging.
    #[serde(default)]
    pub clip_judged: Vec<[f64; 2]>,
    /// `[clip fraction, modelled CIEDE2000 after the footprint rounds]` of the best of
    /// `clip_judged` and the fractions judged next to it on either side, which were refined
    /// and judged again (the lowest taken); empty where nothing was refined.
    #[serde(default)]
    pub clip_refined: Vec<[f64; 2]>,
}

/// The covered camera pixels (some weight) whose target at scale `scale` asks, in some
/// channel, for less than the camera sees there with every projector black (`stage.ambient`:
/// black level plus room light).
pub fn below_black(stage: &StageModel, target: &LinearImage, weights: &[f32], scale: f64) -> Vec<usize> {
    let kn = weights.len() / target.data.len().max(1);
    (0..target.data.len())
        .filter(|&i| weights[i * kn..(i + 1) * kn].iter().any(|&w| w > 0.0))
        .filter(|&i| (0..3).any(|c| scale * f64::from(target.data[i][c]) < f64::from(stage.ambient[i][c])))
        .collect()
}

/// The pixels the target asks to light (a finite target: inside the object mask where one
/// is given, [`mask_target`]) that compensation cannot work on ([`work_points`]), by why:
/// what a conservator reads before trusting the view, and what no projector reaches named
/// as such. `asked - total()` is `Stats::covered_points`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Unlit {
    /// Pixels the target asks to light.
    pub asked: usize,
    /// Of them, where calibration reconstructed no surface (typically the silhouette's rim).
    pub no_surface: usize,
    /// A known surface point no projector's measured correspondence reaches (shadowed,
    /// facing away, outside every projector's image).
    pub no_projector: usize,
    /// Reached, but calibration measured no reflectance (gain) there.
    pub no_gain: usize,
}

impl Unlit {
    /// Counts the asked pixels of `target` compensation cannot work on, by their first reason
    /// in the order of the fields.
    pub fn count(stage: &StageModel, geom: &Geometry, target: &LinearImage) -> Unlit {
        let mut u = Unlit::default();
        for (i, t) in target.data.iter().enumerate() {
            if !t.iter().all(|v| v.is_finite()) {
                continue;
            }
            u.asked += 1;
            let reason = if !stage.points.get(i).is_some_and(|p| p.iter().all(|v| v.is_finite())) {
                &mut u.no_surface
            } else if !geom.covered(i) {
                &mut u.no_projector
            } else if !stage.gain.get(i).is_some_and(|g| g.iter().all(|g| g.is_finite() && *g > 0.0)) {
                &mut u.no_gain
            } else {
                continue;
            };
            *reason += 1;
        }
        u
    }

    pub fn total(&self) -> usize {
        self.no_surface + self.no_projector + self.no_gain
    }

    /// Share of the asked pixels that are lit (1 where none were asked).
    pub fn lit_share(&self) -> f64 {
        if self.asked == 0 { 1.0 } else { 1.0 - self.total() as f64 / self.asked as f64 }
    }
}

impl std::fmt::Display for Unlit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of {} px lit ({:.2} %)",
            self.asked - self.total(),
            self.asked,
            100.0 * self.lit_share()
        )?;
        let parts: Vec<String> = [
            (self.no_surface, "no surface reconstructed"),
            (self.no_projector, "no projector reaches"),
            (self.no_gain, "no reflectance measured"),
        ]
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, why)| format!("{n} {why}"))
        .collect();
        if !parts.is_empty() {
            write!(f, "; unlit: {}", parts.join(", "))?;
        }
        Ok(())
    }
}

/// The result: frames and what is needed to report on them.
#[derive(Clone, Debug)]
pub struct Compensation {
    /// One 8-bit RGB frame per projector, at the projector's resolution.
    pub frames: Vec<RgbImage>,
    /// Per point and projector (`[i * projectors + k]`), the weight `w_ik` of Eq. 12.
    pub weights: Vec<f32>,
    /// Per camera pixel, the recomputed irradiance of the final frames at its certificate
    /// point (lux, conservative); 0 where no projector reaches.
    pub lux: Vec<f64>,
    /// The light model the bundle carries (responses, black, E_bound, margin, room light).
    pub light: LightModel,
    pub stats: Stats,
}

/// Stage data that do not depend on the target: geometry, inverse responses, certificate.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub geometry: Geometry,
    pub inverse: Vec<[InverseResponse; 3]>,
    pub certificate: Certificate,
    /// Per certificate point, black-level irradiance (lux per channel, room light excluded).
    pub floor: Vec<[f64; 3]>,
    /// The certificate in the bundle's format, in parts for the parallel independent check.
    pub shared_parts: Vec<(u32, restage_shared::light::LightCertificate)>,
    /// Per projector, which pixels' light lands on known surface (the others stay black).
    pub landings: Vec<landing::Landing>,
}

impl Prepared {
    /// `reduction`: camera pixels per certificate point along each axis.
    pub fn new(stage: &StageModel, reduction: u32) -> Result<Self, CompensateError> {
        stage.validate()?;
        if !(1..=16).contains(&reduction) {
            return Err(CompensateError::BadReduction(reduction));
        }
        let n = stage.pixel_count();
        if stage.gain.len() != n || stage.ambient.len() != n {
            return Err(CompensateError::NoGain { got: stage.gain.len().min(stage.ambient.len()), want: n });
        }
        let geometry = Geometry::new(stage);
        let inverse = stage
            .projectors
            .iter()
            .map(|p| std::array::from_fn(|c| InverseResponse::new(&p.response[c])))
            .collect();
        let room = room_lux(stage, &geometry);
        let landings: Vec<landing::Landing> = (0..stage.projectors.len())
            .into_par_iter()
            .map(|k| landing::landing(stage, &geometry, k))
            .collect();
        let certificate = certificate::build(stage, &geometry, &landings, reduction, room);
        let floor = guarantee::floor_lux(stage, &certificate);
        let shared_parts = certificate.to_shared_parts();
        Ok(Self { geometry, inverse, certificate, floor, shared_parts, landings })
    }
}

/// Room light (lux) from the stage model: per covered pixel, what its ambient camera value
/// says beyond the projectors' black level; the 99.5th percentile over the object, so a few
/// noisy dark pixels do not dominate. Counted toward the bound at every point.
fn room_lux(stage: &StageModel, geom: &Geometry) -> f64 {
    let kn = geom.projectors;
    let mut v: Vec<f64> = (0..geom.points)
        .into_par_iter()
        .filter_map(|i| {
            if !geom.covered(i) || !stage.gain[i].iter().all(|g| g.is_finite() && *g > 0.0) {
                return None;
            }
            let mut best = 0.0f64;
            for c in 0..3 {
                let black: f64 =
                    (0..kn).map(|k| geom.eta[i * kn + k] as f64 * stage.projectors[k].black[c] as f64).sum();
                best = best.max(stage.ambient[i][c] as f64 / stage.gain[i][c] as f64 - black);
            }
            Some(best)
        })
        .collect();
    if v.is_empty() {
        return 0.0;
    }
    let q = ((v.len() as f64 * 0.995) as usize).min(v.len() - 1);
    let (_, &mut r, _) = v.select_nth_unstable_by(q, f64::total_cmp);
    r.max(0.0)
}

/// Computes one frame per projector for `target` (linear RGB in camera space).
pub fn compensate(
    stage: &StageModel,
    target: &LinearImage,
    params: &Params,
) -> Result<Compensation, CompensateError> {
    params.validate()?;
    let prep = Prepared::new(stage, params.reduction)?;
    compensate_prepared(stage, &prep, target, params)
}

/// [`compensate`] with the target-independent work done once, on the CPU reference path.
pub fn compensate_prepared(
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Compensation, CompensateError> {
    compensate_on(stage, prep, target, params, Device::Cpu)
}

/// [`compensate_prepared`] with the per-pixel work on `device`. Whichever path made the
/// frames, the guarantee and the independent check below run on the CPU: they are the
/// authority.
pub fn compensate_on(
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
    device: Device,
) -> Result<Compensation, CompensateError> {
    params.validate()?;
    let cam = &stage.camera;
    if target.width != cam.width || target.height != cam.height {
        return Err(CompensateError::SizeMismatch {
            got_w: target.width,
            got_h: target.height,
            want_w: cam.width,
            want_h: cam.height,
        });
    }
    let limit = params.limit();

    // Fix 2: black level (and room light) is light too. Refuse when it alone breaks the bound.
    let cert = &prep.certificate;
    let room = cert.ambient_lux;
    let (worst, peak_black) = prep
        .floor
        .iter()
        .enumerate()
        .map(|(i, b)| (i, room + bound_lux(*b)))
        .fold((0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a });
    if peak_black > limit {
        let [x, y] = cert.point_px[worst];
        return Err(CompensateError::BlackAboveBound {
            black_lux: peak_black,
            room_lux: room,
            x: x as u32,
            y: y as u32,
            limit,
            e_bound: params.e_bound_lux,
            margin: params.combined_margin(),
        });
    }
    let t0 = std::time::Instant::now();
    let device = crate::gpu::select(device)?;
    // The draft at one clip fraction: weights, global scale, the formula's frames.
    let draft_at = |clip_fraction: f64| -> Result<Draft, CompensateError> {
        let p = Params { clip_fraction, auto_clip: AutoClip::Off, ..params.clone() };
        match device {
            Some(g) => gpu::draft(g, stage, prep, target, &p),
            None => draft_cpu(stage, prep, target, &p),
        }
    };
    // The footprints turned around once, where a refinement or a judgement needs them.
    let footprints = std::cell::LazyCell::new(|| footprint::Footprints::of(stage, prep));
    // A draft refined over `rounds`, unseen light darkened, and the guarantee on the 8-bit
    // frames (fix 3). `refine` does nothing at 0 rounds either; asking first keeps the
    // footprints unbuilt where no round and no judgement needs them.
    let finish = |mut draft: Draft, rounds: u32| -> Candidate {
        let p = Params { footprint_rounds: rounds, ..params.clone() };
        let refinement =
            (rounds > 0).then(|| footprint::refine(stage, prep, &footprints, &p, &mut draft)).flatten();
        // Light that would land where the model cannot bound it stays dark.
        let unseen_dark = guarantee::darken_unknown(&prep.landings, &mut draft.frames);
        tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: draft done");
        let enf = guarantee::enforce(cert, &prep.inverse, &prep.floor, &mut draft.frames, limit);
        tracing::debug!(
            ms = t0.elapsed().as_secs_f64() * 1e3,
            rounds = enf.rounds,
            "compensate: guarantee done"
        );
        Candidate { draft, refinement, unseen_dark, enf }
    };
    let asked = draft_at(params.clip_fraction)?;
    let asked_dark = below_black(stage, target, &asked.weights, asked.scale).len();
    let choose = match params.auto_clip {
        AutoClip::Off => false,
        AutoClip::Always => true,
        AutoClip::Lifted => {
            let lifts = lifted(asked_dark, asked.covered);
            if lifts {
                tracing::info!(
                    below_black = asked_dark,
                    covered = asked.covered,
                    "the black level lifts {:.1} % of the lit points: the model chooses the clip fraction",
                    100.0 * asked_dark as f64 / asked.covered.max(1) as f64
                );
            }
            lifts
        }
    };
    let (chosen, clip_judged, clip_refined, dark) = if choose {
        let ClipChoice { chosen: c, judged, refined } =
            choose_clip(stage, prep, &footprints, target, params, asked, &draft_at, &finish)?;
        let dark = below_black(stage, target, &c.draft.weights, c.draft.scale).len();
        (c, judged, refined, dark)
    } else {
        (finish(asked, params.footprint_rounds), Vec::new(), Vec::new(), asked_dark)
    };
    let Candidate { draft, refinement, unseen_dark, enf } = chosen;
    let Draft { weights, mut frames, scale, covered, by_bound, by_sat, curve, clip_fraction, .. } = draft;
    if let Some(note) = clip_tradeoff(&curve, clip_fraction, scale) {
        tracing::info!("{note}");
    }
    let unlit = Unlit::count(stage, &prep.geometry, target);
    if lifted(dark, covered) {
        tracing::warn!(
            "{dark} of {covered} lit points ({:.1} %) ask for less light than the projectors' black level \
             and the room give at this bound: they will look lifted (a higher bound, fewer or \
             deeper-black projectors, or a darker room help)",
            100.0 * dark as f64 / covered.max(1) as f64
        );
    }
    let lux: Vec<f64> = cert
        .point_of_pixel
        .iter()
        .map(|&pt| if pt == u32::MAX { 0.0 } else { enf.lux[pt as usize] })
        .collect();
    let peak_lux = enf.lux.iter().copied().fold(0.0, f64::max);
    // The appliance's own check, written independently of ours, must agree before anything
    // leaves this function: first its coverage test (lit pixels the certificate cannot vouch
    // for go black), then the whole check.
    let light = certificate::light_model(stage, params.e_bound_lux, params.combined_margin(), room);
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: enforce done");
    let coverage = certificate::coverage_of_parts(&light, &prep.shared_parts)
        .map_err(CompensateError::IndependentCheck)?;
    let unvouched = guarantee::darken_unvouched(&coverage, &mut frames);
    if unvouched > 0 {
        tracing::warn!(
            pixels = unvouched,
            "compensation: lit pixels the certificate cannot vouch for set black"
        );
    }
    let independent = certificate::independent_peak_parts(&light, &prep.shared_parts, &coverage, &frames)
        .and_then(|peak| check_bound(&light, "compensation", &peak).map(|()| peak))
        .map_err(CompensateError::IndependentCheck)?;
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: independent check done");
    debug_assert!(independent.lux >= peak_lux - 1e-6 * peak_lux.max(1.0));
    tracing::info!(
        scale,
        peak_lux,
        limit,
        rounds = enf.rounds,
        dimmed = enf.dimmed_pixels,
        covered,
        by_bound,
        by_sat,
        below_black = dark,
        %unlit,
        "compensation done"
    );
    Ok(Compensation {
        frames,
        weights,
        lux,
        light,
        stats: Stats {
            covered_points: covered,
            limited_by_bound: by_bound,
            limited_by_saturation: by_sat,
            peak_lux,
            peak_black_lux: peak_black,
            room_lux: room,
            certificate_points: cert.points(),
            e_bound_lux: params.e_bound_lux,
            limit_lux: limit,
            scale,
            rounds: enf.rounds,
            dimmed_pixels: enf.dimmed_pixels,
            unvouched_pixels: unvouched,
            unseen_dark_pixels: unseen_dark,
            unseen_points: cert.points() - cert.first_unseen,
            refinement,
            unlit,
            below_black: dark,
            scale_by_clip: curve,
            clip_fraction,
            clip_judged,
            clip_refined,
        },
    })
}

/// The clip fraction whose frames the stage model judges best, finished: every one of
/// [`AUTO_CLIP`] from the asked fraction up, then halfway to each neighbour of the best (the
/// error turns sharply where the scale's curve has a knee, e.g. 8.3 at 2 % and 2.4 at 3 % on a
/// calibrated jar at 50 lx), each judged on the formula's frames under the guarantee
/// ([`view_error`] of the [`footprint::modelled_view`]). The footprint rounds cost several
/// times the formula and improve some fractions more than others, and the formula's errors
/// near its best differ by less than that (0.007 between 2 and 2.5 % on the bowl at seed 47,
/// where the refined frames put 2.5 % ahead by 0.015), so the best and the fractions judged
/// next to it on either side are refined and judged again, and the best of them taken.
/// Returns it, each judged `[fraction, modelled error of the formula's frames]` in order of
/// fraction, and the refined ones' `[fraction, modelled error]` in the order they were refined
/// (the formula's order; empty where the stage has no footprints or no rounds are asked for).
/// Where none can be judged (no point, no scale: every error infinite) the asked fraction
/// stays; the first of equals is the smaller fraction.
#[allow(clippy::too_many_arguments)]
fn choose_clip(
    stage: &StageModel,
    prep: &Prepared,
    footprints: &footprint::Footprints,
    target: &LinearImage,
    params: &Params,
    asked: Draft,
    draft_at: &impl Fn(f64) -> Result<Draft, CompensateError>,
    finish: &impl Fn(Draft, u32) -> Candidate,
) -> Result<ClipChoice, CompensateError> {
    let idx = work_points(stage, &prep.geometry, target);
    let sample: Vec<u32> = idx.iter().step_by(idx.len().div_ceil(AUTO_SAMPLES).max(1)).copied().collect();
    let error_of = |c: &Candidate, rounds: u32| -> f64 {
        let view = footprint::modelled_view(stage, prep, footprints, &c.draft.frames, &sample);
        let error = view_error(target, &sample, &view, c.draft.scale);
        tracing::info!(
            clip_fraction = c.draft.clip_fraction,
            scale = c.draft.scale,
            rounds,
            modelled_delta_e = error,
            "auto clip: candidate"
        );
        error
    };
    // Each draft is dropped once judged (a candidate's frames and weights are tens of MB).
    let judge = |draft: Draft| -> [f64; 2] {
        let c = finish(draft, 0);
        [c.draft.clip_fraction, error_of(&c, 0)]
    };
    let grid: Vec<f64> = std::iter::once(asked.clip_fraction)
        .chain(AUTO_CLIP.iter().copied().filter(|&f| f > asked.clip_fraction))
        .collect();
    let mut judged = vec![judge(asked)];
    for &f in &grid[1..] {
        judged.push(judge(draft_at(f)?));
    }
    let by_error = |judged: &[[f64; 2]]| {
        let mut order: Vec<[f64; 2]> = judged.to_vec();
        // Stable: among equals the smaller fraction (the grid's order) first.
        order.sort_by(|a, b| a[1].total_cmp(&b[1]));
        order
    };
    let at = grid.iter().position(|&f| f == by_error(&judged)[0][0]).unwrap_or(0);
    for n in [at.checked_sub(1), Some(at + 1)].into_iter().flatten().filter(|&n| n < grid.len()) {
        judged.push(judge(draft_at(0.5 * (grid[n] + grid[at]))?));
    }
    judged.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let order = by_error(&judged);
    let refines = params.footprint_rounds > 0 && footprint::has_footprints(stage);
    // The formula's best and the fractions judged next to it on either side, best first.
    let first = judged.iter().position(|j| j[0] == order[0][0]).unwrap_or(0);
    let bracket: Vec<[f64; 2]> = order
        .iter()
        .filter(|j| judged.iter().position(|k| k[0] == j[0]).is_some_and(|n| n.abs_diff(first) <= 1))
        .copied()
        .collect();
    let mut best: Option<(f64, Candidate)> = None;
    let mut refined = Vec::new();
    for j in bracket.iter().take(if refines { 3 } else { 1 }) {
        let c = finish(draft_at(j[0])?, params.footprint_rounds);
        let error = if refines { error_of(&c, params.footprint_rounds) } else { j[1] };
        if refines {
            refined.push([j[0], error]);
        }
        let better =
            best.as_ref().is_none_or(|b| error < b.0 || (error == b.0 && j[0] < b.1.draft.clip_fraction));
        if better {
            best = Some((error, c));
        }
    }
    let (_, chosen) = best.expect("the asked fraction is judged");
    tracing::info!(
        clip_fraction = chosen.draft.clip_fraction,
        "clip fraction chosen by the modelled view (at least {:.2} %)",
        100.0 * grid[0]
    );
    Ok(ClipChoice { chosen, judged, refined })
}

/// What [`choose_clip`] took, and what it judged on the way ([`Stats::clip_judged`],
/// [`Stats::clip_refined`]).
struct ClipChoice {
    chosen: Candidate,
    judged: Vec<[f64; 2]>,
    refined: Vec<[f64; 2]>,
}

/// One clip fraction's compensation up to the guarantee: its draft (frames refined, unseen
/// light darkened, the guarantee enforced), and what those steps did.
struct Candidate {
    draft: Draft,
    refinement: Option<footprint::Refinement>,
    unseen_dark: usize,
    enf: guarantee::Enforcement,
}

/// Whether `dark` of `covered` lit points below the black level are more than [`LIFTED_SHARE`].
fn lifted(dark: usize, covered: usize) -> bool {
    dark as f64 > LIFTED_SHARE * covered as f64
}

/// Compensation before the guarantee: the weights, the global scale and the frames as
/// computed (averaged and quantised), from either path.
#[derive(Clone, Debug)]
pub struct Draft {
    pub weights: Vec<f32>,
    pub frames: Vec<RgbImage>,
    pub scale: f64,
    pub covered: usize,
    pub by_bound: usize,
    pub by_sat: usize,
    /// `[clip fraction, scale]` at each of [`CLIP_CURVE`].
    pub curve: Vec<[f64; 2]>,
    /// The clip fraction `scale` was taken at.
    pub clip_fraction: f64,
    /// The work points ([`work_points`]) and the demand the frames were made for at each
    /// ([`demands`]): the footprint refinement aims at the same light.
    pub idx: Vec<u32>,
    pub demand: Vec<[f64; 3]>,
}

/// `target` with every pixel outside `mask` (per camera pixel, row-major, true = object)
/// made non-finite: compensation does not work on those points ([`work_points`]), so
/// projector pixels that would light only them stay dark. They stay in the light
/// certificate, and the bound holds there as everywhere.
pub fn mask_target(target: &LinearImage, mask: &[bool]) -> Result<LinearImage, CompensateError> {
    if mask.len() != target.data.len() {
        return Err(CompensateError::MaskSize { got: mask.len(), want: target.data.len() });
    }
    let mut out = target.clone();
    for (v, &inside) in out.data.iter_mut().zip(mask) {
        if !inside {
            *v = [f32::NAN; 3];
        }
    }
    Ok(out)
}

/// The object points compensation works on (covered, calibrated, finite target: outside an
/// object mask the target is not finite, [`mask_target`]), in raster order; [`Unlit`] names
/// why the others asked for are not.
pub fn work_points(stage: &StageModel, geom: &Geometry, target: &LinearImage) -> Vec<u32> {
    (0..geom.points as u32)
        .into_par_iter()
        .filter(|&i| {
            let i = i as usize;
            geom.covered(i)
                && stage.gain[i].iter().all(|g| g.is_finite() && *g > 0.0)
                && target.data[i].iter().all(|v| v.is_finite())
        })
        .collect()
}

/// Clip fractions at which the global scale is also worked out and reported beside the one
/// chosen ([`Stats::scale_by_clip`]): where a few percent of the object is chipped or
/// stained, the points that need the most light are about that many, and the scale moves
/// steeply with the fraction. Who chooses the fraction should see what it trades.
pub const CLIP_CURVE: [f64; 6] = [0.0, 0.0025, 0.005, 0.01, 0.02, 0.05];

/// The global scale chosen from every point's caps, and what it would be at other clip
/// fractions.
#[derive(Clone, Debug)]
pub struct ScaleChoice {
    pub scale: f64,
    /// Points the bound limits below `scale`.
    pub by_bound: usize,
    /// Points a projector's saturation limits below `scale`.
    pub by_sat: usize,
    /// `[clip fraction, scale]` at each of [`CLIP_CURVE`].
    pub curve: Vec<[f64; 2]>,
}

/// Where another clip fraction of [`Stats::scale_by_clip`] would change the whole object's
/// brightness by a quarter or more (the next fraction down, or the first one up that does), a
/// sentence saying so for whoever chooses the fraction; `None` where the scale is flat.
pub fn clip_tradeoff(curve: &[[f64; 2]], clip_fraction: f64, scale: f64) -> Option<String> {
    if scale <= 0.0 {
        return None;
    }
    let below = curve.iter().rev().find(|c| c[0] < clip_fraction).filter(|c| c[1] / scale <= 0.8);
    let above = curve.iter().find(|c| c[0] > clip_fraction && c[1] / scale >= 1.25);
    let said: Vec<String> = [below, above]
        .into_iter()
        .flatten()
        .map(|c| format!("{:.2} % would make it {:.2}x as bright", 100.0 * c[0], c[1] / scale))
        .collect();
    (!said.is_empty()).then(|| {
        format!(
            "at a clip fraction of {:.2} % the whole object's brightness is set by its hardest \
             points (chips, stains, surface turned away): {}; a higher fraction dims more \
             points on their own (--clip-fraction)",
            100.0 * clip_fraction,
            said.join(", "),
        )
    })
}

/// [`Stats::scale_by_clip`] for people, as ratios to the chosen `scale`: "0.00 %: 0.06×,
/// 0.25 %: 0.55×, …" (empty where there is none, as in files written before it was kept).
pub fn clip_curve_text(curve: &[[f64; 2]], scale: f64) -> String {
    if scale <= 0.0 {
        return String::new();
    }
    curve
        .iter()
        .map(|c| format!("{:.2} %: {:.2}×", 100.0 * c[0], c[1] / scale))
        .collect::<Vec<_>>()
        .join(", ")
}

/// What both reports call [`Stats::clip_judged`].
pub const CLIP_JUDGED_CAPTION: &str = "clip fraction chosen by the modelled view (mean CIEDE2000 of \
     each fraction's formula frames; where footprints were measured, the best and its neighbours \
     judged again after the footprint rounds)";

/// The candidates the model judged ([`Stats::clip_judged`]) and those it refined
/// ([`Stats::clip_refined`]) as one line for logs and reports, e.g. `1.00 %: ΔE 3.41, 2.00 %:
/// ΔE 2.97; after the footprint rounds 2.00 %: ΔE 2.60, 1.00 %: ΔE 2.71`; empty where it
/// judged none.
pub fn clip_judged_text(judged: &[[f64; 2]], refined: &[[f64; 2]]) -> String {
    let list = |l: &[[f64; 2]]| {
        l.iter().map(|c| format!("{:.2} %: ΔE {:.2}", 100.0 * c[0], c[1])).collect::<Vec<_>>().join(", ")
    };
    if refined.is_empty() {
        list(judged)
    } else {
        format!("{}; after the footprint rounds {}", list(judged), list(refined))
    }
}

/// The grid of clip fractions [`AutoClip`] judges (those below the asked one left out; then
/// halfway to the best's neighbours): the default and larger, never dimmer than the default,
/// in steps of about a third up to 10 %, where more points dimmed on their own no longer paid
/// on any scene tried.
pub const AUTO_CLIP: [f64; 8] = [DEFAULT_CLIP_FRACTION, 0.015, 0.02, 0.03, 0.04, 0.05, 0.07, 0.10];

/// Most object points the modelled view is judged on per candidate (an even subsample
/// beyond), so the choice costs little beside compensating.
pub const AUTO_SAMPLES: usize = 1 << 16;

/// Mean CIEDE2000 between the target and `view` (what the stage model says the camera sees at
/// the points `idx`, [`footprint::modelled_view`]) divided by the global scale `scale`: the
/// visitor's eye adapts to the overall brightness, so what counts is how the light follows
/// the target, lifted by the black level where the target is darker, dimmed where a point
/// could not take the scale. Summed in order (independent of the thread count).
pub fn view_error(target: &LinearImage, idx: &[u32], view: &[[f64; 3]], scale: f64) -> f64 {
    if scale <= 0.0 || idx.is_empty() {
        return f64::INFINITY;
    }
    let errors: Vec<f64> = idx
        .par_iter()
        .zip(view)
        .map(|(&i, v)| {
            let t = target.data[i as usize].map(|v| f64::from(v.max(0.0)));
            crate::color::ciede2000(
                crate::color::linear_srgb_to_lab(v.map(|v| v / scale)),
                crate::color::linear_srgb_to_lab(t),
            )
        })
        .collect();
    errors.iter().sum::<f64>() / errors.len() as f64
}

/// The global scale from every point's (bound, saturation) caps: the `clip_fraction`
/// quantile of their minimum; how many points each cap limits below it; and the same
/// quantile at each of [`CLIP_CURVE`].
pub fn global_scale(caps: &[(f64, f64)], clip_fraction: f64) -> ScaleChoice {
    let covered = caps.len();
    let index = |fraction: f64| ((fraction * covered as f64).floor() as usize).min(covered - 1);
    let mut per_point: Vec<f64> = caps.iter().map(|(b, s)| b.min(*s)).collect();
    // Order only the lowest values the quantiles read (a few percent): linear time, as one
    // selection was.
    let last = CLIP_CURVE.iter().chain([&clip_fraction]).map(|&f| index(f)).max().unwrap_or(0);
    per_point.select_nth_unstable_by(last, f64::total_cmp);
    per_point[..last].sort_unstable_by(f64::total_cmp);
    let at = |fraction: f64| {
        let s = per_point[index(fraction)];
        if s.is_finite() { s.max(0.0) } else { 0.0 }
    };
    let scale = at(clip_fraction);
    let tol = 1.0 + 1e-9;
    let by_bound = caps.iter().filter(|(b, _)| b * tol < scale).count();
    let by_sat = caps.iter().filter(|(_, s)| s * tol < scale).count();
    let curve = CLIP_CURVE.iter().map(|&f| [f, at(f)]).collect();
    ScaleChoice { scale, by_bound, by_sat, curve }
}

/// Per point, the light available under the bound (lux per channel, above the floor of its
/// certificate point), divided by how much the certificate will over-count this point's
/// light (its coefficient over this pixel's own efficiency, per projector, weighted): the
/// frames then mostly pass the check as made, and enforcement only mops up.
fn headroom(prep: &Prepared, weights: &[f32], limit: f64, i: usize) -> [f64; 3] {
    let (geom, cert) = (&prep.geometry, &prep.certificate);
    let kn = geom.projectors;
    let pt = cert.point_of_pixel[i] as usize;
    let mut rho = 0.0f64;
    for k in 0..kn {
        let (w, eta) = (weights[i * kn + k] as f64, geom.eta[i * kn + k] as f64);
        if w > 0.0 && eta > 0.0 {
            rho += w * cert.projectors[k].2[pt].lux_per_unit as f64 / eta;
        }
    }
    let rho = rho.max(1.0);
    std::array::from_fn(|c| (limit - cert.ambient_lux - prep.floor[pt][c]).max(0.0) / rho)
}

/// Per work point (`idx`), the irradiance it needs above black at global scale `scale` (lux
/// per channel). Where the bound or a projector's output cannot give it, or the target lies
/// below the black level and the room light, the point gets the light whose view is nearest
/// its target within what it can get ([`gamut::nearest_view`]).
pub fn demands(
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    weights: &[f32],
    scale: f64,
    limit: f64,
    idx: &[u32],
) -> Vec<[f64; 3]> {
    let geom = &prep.geometry;
    let kn = geom.projectors;
    idx.par_iter()
        .map(|&i| {
            let i = i as usize;
            if scale <= 0.0 {
                return [0.0; 3];
            }
            let (g, a, t) = (stage.gain[i], stage.ambient[i], target.data[i]);
            // Per channel the most light the point can take: its headroom under the bound,
            // and what each projector's share can give at full output.
            let mut cap = headroom(prep, weights, limit, i);
            for k in 0..kn {
                let w = weights[i * kn + k] as f64;
                if w > 0.0 {
                    let most = geom.eta[i * kn + k] as f64 / w;
                    cap.iter_mut().for_each(|c| *c = c.min(most));
                }
            }
            let need = |c: usize| (scale * t[c].max(0.0) as f64 - a[c] as f64) / g[c] as f64;
            if (0..3).all(|c| (0.0..=cap[c]).contains(&need(c))) {
                return std::array::from_fn(need);
            }
            let view = gamut::nearest_view(
                t.map(f64::from),
                std::array::from_fn(|c| a[c] as f64 / scale),
                std::array::from_fn(|c| (g[c] as f64 * cap[c] + a[c] as f64) / scale),
            );
            std::array::from_fn(|c| ((scale * view[c] - a[c] as f64) / g[c] as f64).clamp(0.0, cap[c]))
        })
        .collect()
}

/// The per-point part of a draft, shared by both paths: the weights (Eq. 12), the work
/// points, the global scale from their caps, and each work point's demand ([`demands`]).
pub struct PointPlan {
    pub weights: Vec<f32>,
    pub idx: Vec<u32>,
    pub scale: ScaleChoice,
    pub demand: Vec<[f64; 3]>,
}

/// [`PointPlan`] for `target` at `params`: always on the CPU, so that both paths splat the
/// same demands (where a point cannot get its light, what it gets is a search whose choice
/// can jump between two nearly equal views, [`gamut`]).
pub fn plan_points(
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<PointPlan, CompensateError> {
    let geom = &prep.geometry;
    let (n, kn) = (geom.points, geom.projectors);
    let limit = params.limit();
    let t0 = std::time::Instant::now();
    let mut weights = vec![0.0f32; n * kn];
    weights
        .par_chunks_mut(kn)
        .zip(geom.l.par_chunks(kn))
        .for_each(|(w, l)| weights::point_weights(l, params.m, w));
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: weights done");

    let idx = work_points(stage, geom, target);
    if idx.is_empty() {
        return Err(CompensateError::NoCoverage);
    }
    let headroom = |i: usize| headroom(prep, &weights, limit, i);

    // Per point, the largest scale it can take under the bound and under saturation.
    let caps: Vec<(f64, f64)> = idx
        .par_iter()
        .map(|&i| {
            let i = i as usize;
            let (g, a, t, b) = (stage.gain[i], stage.ambient[i], target.data[i], headroom(i));
            let mut bound = f64::INFINITY;
            let mut sat = f64::INFINITY;
            for c in 0..3 {
                let tc = t[c].max(0.0) as f64;
                if tc <= 0.0 {
                    continue;
                }
                let (gc, ac) = (g[c] as f64, a[c] as f64);
                bound = bound.min((b[c] * gc + ac) / tc);
                for k in 0..kn {
                    let w = weights[i * kn + k] as f64;
                    if w > 0.0 {
                        sat = sat.min((geom.eta[i * kn + k] as f64 * gc / w + ac) / tc);
                    }
                }
            }
            (bound, sat)
        })
        .collect();
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: caps done");
    let scale = global_scale(&caps, params.clip_fraction);
    let demand = demands(stage, prep, target, &weights, scale.scale, limit, &idx);
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: demand done");
    Ok(PointPlan { weights, idx, scale, demand })
}

/// The CPU reference for the per-pixel work: the points' plan ([`plan_points`]), splat,
/// quantisation.
pub fn draft_cpu(
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Draft, CompensateError> {
    let geom = &prep.geometry;
    let kn = geom.projectors;
    let t0 = std::time::Instant::now();
    let PointPlan { weights, idx, scale, demand } = plan_points(stage, prep, target, params)?;
    let ScaleChoice { scale, by_bound, by_sat, curve } = scale;
    let (covered, clip_fraction) = (idx.len(), params.clip_fraction);

    // Splat each point's relative output onto the projector pixels around it (averaging).
    let frames: Vec<RgbImage> = (0..kn)
        .into_par_iter()
        .map(|k| {
            let p = &stage.projectors[k];
            let (pw, ph) = (p.width as usize, p.height as usize);
            let mut acc = vec![[0.0f32; 4]; pw * ph];
            for (&i, d) in idx.iter().zip(&demand) {
                let i = i as usize;
                let eta = geom.eta[i * kn + k];
                if eta <= 0.0 {
                    continue;
                }
                let w = weights[i * kn + k] as f64;
                let r = d.map(|v| (w * v / eta as f64) as f32);
                // Tent splat over the camera pixel's footprint: bilinear when the camera samples
                // finer than the projector, wider (no holes) when coarser.
                let c = geom.coord[i * kn + k];
                let hf = geom.half[i * kn + k];
                let (rx, ry) = (hf[0] + 0.5, hf[1] + 0.5);
                let (xa, xb) =
                    (((c[0] - rx).ceil() as i64).max(0), ((c[0] + rx).floor() as i64).min(pw as i64 - 1));
                let (ya, yb) =
                    (((c[1] - ry).ceil() as i64).max(0), ((c[1] + ry).floor() as i64).min(ph as i64 - 1));
                for y in ya..=yb {
                    let wy = 1.0 - (y as f32 - c[1]).abs() / ry;
                    for x in xa..=xb {
                        let bw = wy * (1.0 - (x as f32 - c[0]).abs() / rx);
                        if bw <= 0.0 {
                            continue;
                        }
                        let a = &mut acc[y as usize * pw + x as usize];
                        for ch in 0..3 {
                            a[ch] += bw * r[ch];
                        }
                        a[3] += bw;
                    }
                }
            }
            let inv = &prep.inverse[k];
            let mut frame = RgbImage::new(p.width, p.height);
            for (px, a) in frame.pixels_mut().zip(&acc) {
                if a[3] > 0.0 {
                    px.0 = std::array::from_fn(|ch| inv[ch].nearest(a[ch] / a[3]));
                }
            }
            frame
        })
        .collect();
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate: splat done (CPU)");
    Ok(Draft { weights, frames, scale, covered, by_bound, by_sat, curve, clip_fraction, idx, demand })
}

#[cfg(test)]
mod tests;
