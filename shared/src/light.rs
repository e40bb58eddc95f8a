//! The light model shared by authoring and appliance: response curves, irradiance per unit
//! area in lux, the light certificate, and the independent light check ([`LightCheck`]) that
//! the appliance runs on every scene before showing it.
//!
//! Irradiance is in lux throughout (see ARCHITECTURE.md, "Units and frames").
//!
//! # The model
//!
//! For object point `i` and projector `k`, the certificate holds a rectangular *block* of
//! projector pixels and a coefficient `L_ik` (lux per unit of relative response). The
//! block contains every projector pixel whose light (after blur) reaches any part of the
//! surface patch that point `i` stands for, and `L_ik` is an upper bound over that patch of
//! `lux_at_1m * vignetting * cos(theta) / (d_mm / 1000)^2`. Per channel `c`, in "full-white
//! lux" units:
//!
//! ```text
//! E_ic = ambient + sum_k L_ik * (black_kc + response_kc(max over block_ik of channel c))
//! ```
//!
//! and the irradiance in lux is `E_i = combine(E_i0, E_i1, E_i2)` by the model's
//! [`LuxWeighting`]. `response_kc` is made non-decreasing by a running maximum, so the
//! value at the block's maximum bounds every pixel of the block. Because a blur kernel's
//! weights sum to at most 1, the light a point receives from projector `k` is at most
//! `L_ik` times the brightest response in its block: the sums over-estimate, never
//! under-estimate — *for the pixels the blocks hold*. [`max_irradiance`] is these sums alone.
//!
//! # The check
//!
//! The sums trust the certificate to hold every lit pixel in some block, with a true
//! coefficient. [`LightCheck`] does not: it also refuses a scene that lights a pixel no block
//! covers, or that only blocks with an implausibly small coefficient cover
//! ([`check`] module docs: what it guarantees and assumes), zero coefficients
//! ([`LightCertificate::check_coefficients`]), and response curves that do not reach full
//! output at 255 or lie under a plausibility floor ([`LightModel::check_responses`]). A scene
//! is allowed when all of that holds and
//! `max_i E_i <= e_bound_lux * (1 - safety_margin)`.

pub mod check;

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use self::check::{
    Coverage, DEFAULT_MAX_THROW_M, DEFAULT_MIN_COS, LightCheck, SceneCheck, StageLimits, UnvouchedPixel,
};

/// Seconds in one hour: exposure budgets are in lux-hours (CIE 157:2004).
pub const SECONDS_PER_HOUR: f64 = 3600.0;
/// Entries in a response curve: one per 8-bit device value.
pub const RESPONSE_LEVELS: usize = 256;
/// Most certificate points accepted (a 2048 x 2048 sampling grid).
pub const MAX_CERT_POINTS: u32 = 1 << 22;
/// Each projector's certificate may read at most `max(WORK_FACTOR * width * height,
/// MIN_WORK)` pixels in total over all blocks, so the check's cost is bounded by the frame
/// size (a real certificate's blocks overlap only a few times).
pub const WORK_FACTOR: u64 = 16;
/// See [`WORK_FACTOR`].
pub const MIN_WORK: u64 = 1 << 20;
/// Each channel's running-max response must reach this at 255: responses are relative to the
/// output at 255 above black, so an honest curve ends at 1 (a measured one within noise).
pub const RESPONSE_FULL_MIN: f32 = 0.99;
/// Below this value the response may be anything (projectors crush their darkest values).
pub const RESPONSE_FLOOR_KNEE: u8 = 64;
/// Above the knee the running-max response must be at least
/// `RESPONSE_FULL_MIN * ((v - knee) / (255 - knee))^RESPONSE_FLOOR_GAMMA`: far under any
/// projector we know (gamma 1.8 to 2.6, S-curves), it stops a signed curve from charging
/// mid-level values as nearly black.
pub const RESPONSE_FLOOR_GAMMA: f32 = 4.0;

/// The least running-max response an honest curve has at value `v`.
pub fn response_floor(v: usize) -> f32 {
    let knee = usize::from(RESPONSE_FLOOR_KNEE);
    if v <= knee {
        return 0.0;
    }
    let x = (v.min(255) - knee) as f32 / (255 - knee) as f32;
    RESPONSE_FULL_MIN * x.powf(RESPONSE_FLOOR_GAMMA)
}

/// Exposure in lux-hours of `lux` held for `seconds`.
pub fn lux_hours(lux: f64, seconds: f64) -> f64 {
    lux * seconds / SECONDS_PER_HOUR
}

#[derive(Debug, Error, Clone, PartialEq)]
pub enum LightError {
    #[error("light model: {0}")]
    Model(String),
    #[error("light certificate: {0}")]
    Certificate(String),
    #[error(
        "projector {projector}: frame is {got_w}x{got_h} with {got_len} bytes, expected {want_w}x{want_h} XRGB8888"
    )]
    FrameSize { projector: usize, got_w: u32, got_h: u32, got_len: usize, want_w: u32, want_h: u32 },
    #[error("expected {expected} frames (one per projector), got {got}")]
    FrameCount { expected: usize, got: usize },
    #[error("projector {projector}'s frame was given twice for one scene")]
    FrameTwice { projector: usize },
    #[error(
        "scene {scene}: peak irradiance {peak_lux:.2} lx exceeds the allowed {allowed_lux:.2} lx (E_bound {e_bound_lux} lx less the safety margin)"
    )]
    OverBound { scene: String, peak_lux: f64, allowed_lux: f64, e_bound_lux: f64 },
    #[error(
        "light model: projector {projector} channel {channel}: the response reaches only {reached} at 255 (expected at least {RESPONSE_FULL_MIN}: responses are relative to the output at 255 above black)"
    )]
    ResponseShort { projector: usize, channel: usize, reached: f32 },
    #[error(
        "light model: projector {projector} channel {channel}: the response at value {value} is {response}, under the plausibility floor {floor} (it would charge mid-level light as nearly black)"
    )]
    ResponseImplausible { projector: usize, channel: usize, value: usize, response: f32, floor: f32 },
    #[error(
        "light certificate: projector {projector} point {point}: block [{x0}, {x1}) x [{y0}, {y1}) has L_ik = 0 (a non-empty block says the light reaches the point, so it cannot be zero)"
    )]
    ZeroCoefficient { projector: usize, point: usize, x0: u16, y0: u16, x1: u16, y1: u16 },
    #[error(
        "scene {scene}, projector {projector}: pixel ({x}, {y}) is lit (r, g, b = {rgb:?}) but no block of the light certificate covers it, so nothing bounds its light"
    )]
    Uncovered { scene: String, projector: usize, x: u32, y: u32, rgb: [u8; 3] },
    #[error(
        "scene {scene}, projector {projector}: pixel ({x}, {y}) is lit (r, g, b = {rgb:?}) but the blocks covering it have L_ik of at most {best_lux_per_unit} lx per unit, under the floor {floor_lux_per_unit:.4} (lux_at_1m * min_cos / max_throw^2): the certificate under-states its light"
    )]
    UnderStated {
        scene: String,
        projector: usize,
        x: u32,
        y: u32,
        rgb: [u8; 3],
        best_lux_per_unit: f32,
        floor_lux_per_unit: f64,
    },
    #[error("stage limits: {0}")]
    Limits(String),
}

/// One projector's radiometry, as calibrated.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProjectorLight {
    /// Per channel (r, g, b), [`RESPONSE_LEVELS`] entries: light output for each 8-bit
    /// value relative to the output at 255 above black (so normally `[0] == 0` and
    /// `[255] == 1`). The check uses the running maximum, so a slightly non-monotonic
    /// measured curve stays conservative; the light check requires the running maximum to
    /// reach [`RESPONSE_FULL_MIN`] at 255 and stay above [`response_floor`]
    /// ([`LightModel::check_responses`]).
    pub response: [Vec<f32>; 3],
    /// Light at input 0 per channel, in the same relative units as `response`. It counts
    /// toward the bound wherever the projector reaches.
    pub black: [f32; 3],
    /// Illuminance (lux) of the full-white centre pixel on a surface 1 m away facing the
    /// projector, from the lux-meter calibration. Informational here: the certificate's
    /// `L_ik` already includes it.
    pub lux_at_1m: f64,
}

/// How the three per-channel irradiances (each in full-white lux units) combine into lux.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum LuxWeighting {
    /// `lux = max_c E_c`: needs no colour calibration and is conservative for any
    /// projector primaries (the true lux is a convex mix of the channels).
    MaxChannel,
    /// `lux = sum_c share_c * E_c` with each channel's measured share of full-white lux
    /// (lux-meter reading of each primary at 255 over the full-white reading). Shares are in
    /// `[0, 1]` and sum to at least 0.999 (a sum above 1 only over-counts).
    Shares([f32; 3]),
}

impl LuxWeighting {
    /// Lux from per-channel irradiances.
    pub fn combine(&self, e: [f64; 3]) -> f64 {
        match self {
            LuxWeighting::MaxChannel => e[0].max(e[1]).max(e[2]),
            LuxWeighting::Shares(s) => e.iter().zip(s).map(|(e, s)| e * f64::from(*s)).sum(),
        }
    }
}

/// A lux-meter reading used to calibrate `lux_at_1m` (kept as provenance).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LuxMeterReading {
    pub projector: u32,
    /// The device value shown (r, g, b).
    pub value: [u8; 3],
    pub measured_lux: f64,
    /// Where and how it was measured, e.g. "reference card at camera pixel (812, 604)".
    pub note: String,
}

/// The light model in the manifest: what the bound check needs besides the certificate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightModel {
    /// One per projector, in the manifest's projector order.
    pub projectors: Vec<ProjectorLight>,
    pub weighting: LuxWeighting,
    /// The maximum irradiance per unit area the object may receive, lux.
    pub e_bound_lux: f64,
    /// Fraction of `e_bound_lux` kept in reserve, in `[0, 0.5]`: scenes must stay under
    /// `e_bound_lux * (1 - safety_margin)`.
    pub safety_margin: f64,
    /// Room light at every point not from the projectors, lux; counted toward the bound.
    pub ambient_lux: f64,
    pub lux_meter: Vec<LuxMeterReading>,
}

impl LightModel {
    /// The most lux any point may receive in any scene.
    pub fn allowed_lux(&self) -> f64 {
        self.e_bound_lux * (1.0 - self.safety_margin)
    }

    /// Checks ranges; says which value is wrong and what is accepted.
    pub fn validate(&self) -> Result<(), LightError> {
        let bad = |s: String| Err(LightError::Model(s));
        if !(self.e_bound_lux.is_finite() && self.e_bound_lux > 0.0 && self.e_bound_lux <= 1e6) {
            return bad(format!("E_bound {} lx (expected 0 < E_bound <= 1e6)", self.e_bound_lux));
        }
        if !(0.0..=0.5).contains(&self.safety_margin) {
            return bad(format!("safety margin {} (expected 0..=0.5)", self.safety_margin));
        }
        if !(self.ambient_lux.is_finite() && self.ambient_lux >= 0.0) {
            return bad(format!("ambient {} lx (expected finite, >= 0)", self.ambient_lux));
        }
        if let LuxWeighting::Shares(s) = self.weighting {
            let sum: f32 = s.iter().sum();
            if s.iter().any(|v| !(0.0..=1.0).contains(v)) || sum.is_nan() || sum < 0.999 {
                return bad(format!("channel lux shares {s:?} (expected each 0..=1, sum >= 0.999)"));
            }
        }
        for (k, p) in self.projectors.iter().enumerate() {
            for (c, curve) in p.response.iter().enumerate() {
                if curve.len() != RESPONSE_LEVELS {
                    return bad(format!(
                        "projector {k} channel {c}: response has {} entries (expected {RESPONSE_LEVELS})",
                        curve.len()
                    ));
                }
                if curve.iter().any(|v| !(v.is_finite() && (0.0..=16.0).contains(v))) {
                    return bad(format!("projector {k} channel {c}: response values must be in 0..=16"));
                }
            }
            if p.black.iter().any(|v| !(v.is_finite() && (0.0..=16.0).contains(v))) {
                return bad(format!("projector {k}: black level {:?} (expected 0..=16)", p.black));
            }
            if !(p.lux_at_1m.is_finite() && p.lux_at_1m > 0.0) {
                return bad(format!("projector {k}: lux_at_1m {} (expected > 0)", p.lux_at_1m));
            }
        }
        Ok(())
    }

    /// The light check's test of the responses (beyond [`LightModel::validate`]'s ranges):
    /// each channel's running maximum reaches [`RESPONSE_FULL_MIN`] at 255 and never falls
    /// under [`response_floor`]. A curve that never reaches full output charges full white as
    /// less (all-zero: as nothing); one under the floor charges mid-level values as black.
    pub fn check_responses(&self) -> Result<(), LightError> {
        for (k, p) in self.projectors.iter().enumerate() {
            for (c, curve) in p.response.iter().enumerate() {
                // f32::max skips NaN, so a NaN curve reaches only its numbers.
                let reached = curve.iter().copied().fold(0.0f32, f32::max);
                if reached < RESPONSE_FULL_MIN {
                    return Err(LightError::ResponseShort { projector: k, channel: c, reached });
                }
                let mut run = 0.0f32;
                for (v, r) in curve.iter().enumerate() {
                    run = run.max(*r);
                    let floor = response_floor(v);
                    if run < floor {
                        return Err(LightError::ResponseImplausible {
                            projector: k,
                            channel: c,
                            value: v,
                            response: run,
                            floor,
                        });
                    }
                }
            }
        }
        Ok(())
    }

    /// Per projector, per channel, per value: `black + running max of response`, the
    /// conservative relative light used by the check.
    pub(crate) fn tables(&self) -> Vec<[[f64; RESPONSE_LEVELS]; 3]> {
        self.projectors
            .iter()
            .map(|p| {
                let mut t = [[0.0; RESPONSE_LEVELS]; 3];
                for ((tc, curve), black) in t.iter_mut().zip(&p.response).zip(p.black) {
                    let mut run = 0.0f64;
                    for (tv, r) in tc.iter_mut().zip(curve) {
                        run = run.max(f64::from(*r));
                        *tv = f64::from(black) + run;
                    }
                }
                t
            })
            .collect()
    }
}

/// Where projector `k`'s light reaches certificate point `i`: the pixel block
/// `[x0, x1) x [y0, y1)` and the coefficient `L_ik`. An empty block (`x0 == x1` or
/// `y0 == y1`) means the projector does not reach the point (no light, not even black).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Footprint {
    pub x0: u16,
    pub y0: u16,
    pub x1: u16,
    pub y1: u16,
    /// `L_ik`: lux per unit of relative response, an upper bound over the point's patch.
    pub lux_per_unit: f32,
}

impl Footprint {
    pub fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }

    fn area(&self) -> u64 {
        if self.is_empty() { 0 } else { u64::from(self.x1 - self.x0) * u64::from(self.y1 - self.y0) }
    }
}

/// One projector's part of the certificate: a footprint for every certificate point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CertificateMap {
    pub width: u32,
    pub height: u32,
    /// `points` entries, in certificate point order.
    pub footprints: Vec<Footprint>,
}

/// Enough of the stage for the appliance to recompute every scene's irradiance per unit area
/// by itself: object points at reduced resolution, each with its footprint in every
/// projector. Produced by compensation, stored as a bundle section, checked on load.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightCertificate {
    /// Number of object points.
    pub points: u32,
    /// Optional (empty or `points` entries): each point's camera pixel, for messages and
    /// maps ("peak at camera pixel (812, 604)").
    pub point_px: Vec<[u16; 2]>,
    /// One per projector, in the manifest's projector order.
    pub projectors: Vec<CertificateMap>,
}

impl LightCertificate {
    /// Checks sizes, blocks inside the frames, finite non-negative coefficients, and the
    /// work bound ([`WORK_FACTOR`]). What the light check adds is in [`LightCheck`].
    pub fn validate(&self) -> Result<(), LightError> {
        let bad = |s: String| Err(LightError::Certificate(s));
        if self.points == 0 || self.points > MAX_CERT_POINTS {
            return bad(format!("{} points (expected 1..={MAX_CERT_POINTS})", self.points));
        }
        let n = self.points as usize;
        if !self.point_px.is_empty() && self.point_px.len() != n {
            return bad(format!("{} point pixels for {n} points (expected 0 or {n})", self.point_px.len()));
        }
        for (k, m) in self.projectors.iter().enumerate() {
            if m.footprints.len() != n {
                return bad(format!("projector {k}: {} footprints for {n} points", m.footprints.len()));
            }
            if m.width == 0
                || m.height == 0
                || m.width > u32::from(u16::MAX)
                || m.height > u32::from(u16::MAX)
            {
                return bad(format!(
                    "projector {k}: size {}x{} (expected 1..=65535 each)",
                    m.width, m.height
                ));
            }
            let mut work = 0u64;
            for (i, f) in m.footprints.iter().enumerate() {
                if !f.is_empty() && (u32::from(f.x1) > m.width || u32::from(f.y1) > m.height) {
                    return bad(format!(
                        "projector {k} point {i}: block [{}, {}) x [{}, {}) outside {}x{}",
                        f.x0, f.x1, f.y0, f.y1, m.width, m.height
                    ));
                }
                if !(f.lux_per_unit.is_finite() && f.lux_per_unit >= 0.0) {
                    return bad(format!(
                        "projector {k} point {i}: L_ik {} (expected finite, >= 0)",
                        f.lux_per_unit
                    ));
                }
                work += f.area();
            }
            let max_work = (WORK_FACTOR * u64::from(m.width) * u64::from(m.height)).max(MIN_WORK);
            if work > max_work {
                return bad(format!("projector {k}: blocks cover {work} pixels in all (at most {max_work})"));
            }
        }
        Ok(())
    }

    /// The light check's test of the coefficients: a non-empty block says the projector's
    /// light reaches the point, so its `L_ik` cannot be 0.
    pub fn check_coefficients(&self) -> Result<(), LightError> {
        for (k, m) in self.projectors.iter().enumerate() {
            if let Some((i, f)) =
                m.footprints.iter().enumerate().find(|(_, f)| !f.is_empty() && f.lux_per_unit == 0.0)
            {
                let (x0, y0, x1, y1) = (f.x0, f.y0, f.x1, f.y1);
                return Err(LightError::ZeroCoefficient { projector: k, point: i, x0, y0, x1, y1 });
            }
        }
        Ok(())
    }

    /// Checks that this certificate fits a light model and a list of projector sizes.
    pub fn validate_for(&self, light: &LightModel, sizes: &[(u32, u32)]) -> Result<(), LightError> {
        self.validate()?;
        if self.projectors.len() != sizes.len() || light.projectors.len() != sizes.len() {
            return Err(LightError::Certificate(format!(
                "{} projector maps, {} in the light model, {} projectors (must be equal)",
                self.projectors.len(),
                light.projectors.len(),
                sizes.len()
            )));
        }
        for (k, (m, &(w, h))) in self.projectors.iter().zip(sizes).enumerate() {
            if (m.width, m.height) != (w, h) {
                return Err(LightError::Certificate(format!(
                    "projector {k}: map is {}x{}, the projector is {w}x{h}",
                    m.width, m.height
                )));
            }
        }
        Ok(())
    }

    /// Encodes to postcard (the bundle's certificate section; also `certificate.bin` files).
    // Cannot fail: postcard into a Vec errs only on a custom Serialize error; these derived impls have none.
    #[allow(clippy::expect_used)]
    pub fn to_bytes(&self) -> Vec<u8> {
        postcard::to_stdvec(self).expect("a certificate always serialises")
    }

    /// Decodes and validates.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, LightError> {
        let c: Self = postcard::from_bytes(bytes)
            .map_err(|e| LightError::Certificate(format!("cannot decode: {e}")))?;
        c.validate()?;
        Ok(c)
    }
}

/// A frame in scan-out layout: XRGB8888, little-endian (bytes B, G, R, X), row-major,
/// stride `width * 4` — the same layout as the appliance's `FrameRef`.
#[derive(Clone, Copy, Debug)]
pub struct XrgbFrame<'a> {
    pub width: u32,
    pub height: u32,
    pub xrgb: &'a [u8],
}

impl XrgbFrame<'_> {
    /// Refuses a frame that is not `width` x `height` XRGB8888 (projector `k`'s size).
    pub(crate) fn check_size(&self, k: usize, width: u32, height: u32) -> Result<(), LightError> {
        let len = width as usize * height as usize * 4;
        if self.width != width || self.height != height || self.xrgb.len() != len {
            return Err(LightError::FrameSize {
                projector: k,
                got_w: self.width,
                got_h: self.height,
                got_len: self.xrgb.len(),
                want_w: width,
                want_h: height,
            });
        }
        Ok(())
    }
}

/// Converts tightly packed 8-bit RGB to XRGB8888 (X = 0).
pub fn xrgb_from_rgb(rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(rgb.len() / 3 * 4);
    for p in rgb.chunks_exact(3) {
        out.extend_from_slice(&[p[2], p[1], p[0], 0]);
    }
    out
}

/// The brightest point of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeakIrradiance {
    /// Lux at the brightest certificate point (ambient included).
    pub lux: f64,
    /// Its index in the certificate.
    pub point: u32,
    /// Its camera pixel, when the certificate names one.
    pub pixel: Option<[u16; 2]>,
}

/// Accumulates one scene's per-point sums projector by projector, so a streaming reader needs
/// only one frame at a time. [`max_irradiance`] is this with all frames at once; the check
/// ([`SceneCheck`]) wraps it with the coverage test. Not public: alone it trusts the
/// certificate's coverage.
#[derive(Debug)]
pub(crate) struct SceneIrradiance<'a> {
    light: &'a LightModel,
    cert: &'a LightCertificate,
    tables: Vec<[[f64; RESPONSE_LEVELS]; 3]>,
    /// Per point, per channel, full-white lux units.
    acc: Vec<[f64; 3]>,
    seen: Vec<bool>,
}

impl<'a> SceneIrradiance<'a> {
    /// Starts a scene. The light model and certificate are validated here.
    pub(crate) fn new(light: &'a LightModel, cert: &'a LightCertificate) -> Result<Self, LightError> {
        light.validate()?;
        cert.validate()?;
        if cert.projectors.len() != light.projectors.len() {
            return Err(LightError::Certificate(format!(
                "{} projector maps for {} projectors in the light model",
                cert.projectors.len(),
                light.projectors.len()
            )));
        }
        Ok(Self::start(light, cert, light.tables()))
    }

    /// Starts a scene whose light model and certificate were validated together (as
    /// [`LightCheck::new`] does) with `tables` from [`LightModel::tables`].
    pub(crate) fn start(
        light: &'a LightModel,
        cert: &'a LightCertificate,
        tables: Vec<[[f64; RESPONSE_LEVELS]; 3]>,
    ) -> Self {
        Self {
            light,
            cert,
            tables,
            acc: vec![[0.0; 3]; cert.points as usize],
            seen: vec![false; cert.projectors.len()],
        }
    }

    /// Adds projector `k`'s frame.
    pub(crate) fn add(&mut self, k: usize, frame: XrgbFrame<'_>) -> Result<(), LightError> {
        let Some(map) = self.cert.projectors.get(k) else {
            return Err(LightError::FrameCount { expected: self.cert.projectors.len(), got: k + 1 });
        };
        frame.check_size(k, map.width, map.height)?;
        let w = map.width as usize;
        if std::mem::replace(&mut self.seen[k], true) {
            return Err(LightError::FrameTwice { projector: k });
        }
        let table = &self.tables[k];
        for (acc, f) in self.acc.iter_mut().zip(&map.footprints) {
            if f.is_empty() {
                continue;
            }
            // Max per channel over the block (bytes B, G, R, X).
            let mut m = [0u8; 3];
            for y in f.y0 as usize..f.y1 as usize {
                let row = &frame.xrgb[(y * w + f.x0 as usize) * 4..(y * w + f.x1 as usize) * 4];
                for p in row.chunks_exact(4) {
                    m[0] = m[0].max(p[2]);
                    m[1] = m[1].max(p[1]);
                    m[2] = m[2].max(p[0]);
                }
            }
            let l = f64::from(f.lux_per_unit);
            for c in 0..3 {
                acc[c] += l * table[c][m[c] as usize];
            }
        }
        Ok(())
    }

    /// The scene's peak, once every projector's frame was added.
    pub(crate) fn finish(self) -> Result<PeakIrradiance, LightError> {
        let got = self.seen.iter().filter(|s| **s).count();
        if got != self.seen.len() {
            return Err(LightError::FrameCount { expected: self.seen.len(), got });
        }
        let ambient = self.light.ambient_lux;
        let mut best = PeakIrradiance { lux: f64::NEG_INFINITY, point: 0, pixel: None };
        for (i, e) in self.acc.iter().enumerate() {
            let lux = ambient + self.light.weighting.combine(*e);
            // `>` keeps the first maximum, so the answer does not depend on evaluation order.
            if lux > best.lux {
                best = PeakIrradiance { lux, point: i as u32, pixel: self.cert.point_px.get(i).copied() };
            }
        }
        Ok(best)
    }
}

/// Peak irradiance in lux over the certificate's points for a scene given as one frame per
/// projector (in projector order): the per-point sums only, conservative over each point's
/// patch for the pixels its blocks hold (see the module docs). It trusts the certificate's
/// coverage: a bundle is judged by [`LightCheck`], which adds the coverage test. Uses: the
/// black level's light (all-zero frames light nothing), compensation's parallel check on
/// parts of a certificate (with [`Coverage`] over the whole), tests.
pub fn max_irradiance(
    light: &LightModel,
    cert: &LightCertificate,
    frames: &[XrgbFrame<'_>],
) -> Result<PeakIrradiance, LightError> {
    if frames.len() != cert.projectors.len() {
        return Err(LightError::FrameCount { expected: cert.projectors.len(), got: frames.len() });
    }
    let mut s = SceneIrradiance::new(light, cert)?;
    for (k, f) in frames.iter().enumerate() {
        s.add(k, *f)?;
    }
    s.finish()
}

/// Refuses a scene whose peak exceeds the light model's allowed lux.
pub fn check_bound(light: &LightModel, scene: &str, peak: &PeakIrradiance) -> Result<(), LightError> {
    let allowed = light.allowed_lux();
    // NaN never passes.
    if peak.lux <= allowed {
        Ok(())
    } else {
        Err(LightError::OverBound {
            scene: scene.to_owned(),
            peak_lux: peak.lux,
            allowed_lux: allowed,
            e_bound_lux: light.e_bound_lux,
        })
    }
}

/// A linear-response test model: `n` projectors, gamma-2.2 responses, black 0.01 on every
/// channel, max-channel weighting.
pub fn example_light_model(n: usize, e_bound_lux: f64) -> LightModel {
    let ramp: Vec<f32> = (0..RESPONSE_LEVELS).map(|i| (i as f32 / 255.0).powf(2.2)).collect();
    LightModel {
        projectors: (0..n)
            .map(|_| ProjectorLight {
                response: [ramp.clone(), ramp.clone(), ramp.clone()],
                black: [0.01; 3],
                lux_at_1m: 400.0,
            })
            .collect(),
        weighting: LuxWeighting::MaxChannel,
        e_bound_lux,
        safety_margin: 0.05,
        ambient_lux: 0.0,
        lux_meter: vec![],
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    #[test]
    fn reciprocity_of_exposure() {
        // 50 lx for 10 h equals 250 lx for 2 h (the brief's damage-by-product rule).
        assert!((lux_hours(50.0, 36_000.0) - lux_hours(250.0, 7_200.0)).abs() < 1e-9);
    }

    fn one_point_cert(w: u32, h: u32, block: Footprint, k: usize) -> LightCertificate {
        LightCertificate {
            points: 1,
            point_px: vec![[3, 4]],
            projectors: (0..k)
                .map(|_| CertificateMap { width: w, height: h, footprints: vec![block] })
                .collect(),
        }
    }

    #[test]
    fn full_white_gives_l_times_one_plus_black() {
        let light = example_light_model(1, 100.0);
        let cert = one_point_cert(4, 4, Footprint { x0: 1, y0: 1, x1: 3, y1: 3, lux_per_unit: 40.0 }, 1);
        let frame = vec![255u8; 4 * 4 * 4];
        let peak = max_irradiance(&light, &cert, &[XrgbFrame { width: 4, height: 4, xrgb: &frame }]).unwrap();
        assert!((peak.lux - 40.0 * 1.01).abs() < 1e-4, "{}", peak.lux);
        assert_eq!(peak.pixel, Some([3, 4]));
    }

    #[test]
    fn block_max_is_taken_per_channel_and_outside_pixels_are_ignored() {
        let light = example_light_model(1, 100.0);
        let cert = one_point_cert(4, 1, Footprint { x0: 1, y0: 0, x1: 3, y1: 1, lux_per_unit: 10.0 }, 1);
        // Pixel 0 (outside) full white; pixel 1 red 255; pixel 2 green 255.
        let frame = [255, 255, 255, 0, 0, 0, 255, 0, 0, 255, 0, 0, 0, 0, 0, 0];
        let peak = max_irradiance(&light, &cert, &[XrgbFrame { width: 4, height: 1, xrgb: &frame }]).unwrap();
        // Max channel: r = g = 1.01, b = black only.
        assert!((peak.lux - 10.1).abs() < 1e-4);
        let mut shares = light.clone();
        shares.weighting = LuxWeighting::Shares([0.25, 0.7, 0.05]);
        let p2 = max_irradiance(&shares, &cert, &[XrgbFrame { width: 4, height: 1, xrgb: &frame }]).unwrap();
        let want = 10.0 * (0.25 * 1.01 + 0.7 * 1.01 + 0.05 * 0.01);
        assert!((p2.lux - want).abs() < 1e-4, "{} vs {want}", p2.lux);
    }

    #[test]
    fn over_bound_scene_is_refused_and_margin_applies() {
        let light = example_light_model(2, 50.0); // allowed 47.5
        let cert = one_point_cert(2, 2, Footprint { x0: 0, y0: 0, x1: 2, y1: 2, lux_per_unit: 24.0 }, 2);
        let white = vec![255u8; 16];
        let frames = [XrgbFrame { width: 2, height: 2, xrgb: &white }; 2];
        let peak = max_irradiance(&light, &cert, &frames).unwrap();
        assert!((peak.lux - 48.48).abs() < 1e-3);
        assert!(matches!(check_bound(&light, "s", &peak), Err(LightError::OverBound { .. })));
        let dark = vec![0u8; 16];
        let peak =
            max_irradiance(&light, &cert, &[XrgbFrame { width: 2, height: 2, xrgb: &dark }; 2]).unwrap();
        check_bound(&light, "s", &peak).unwrap();
    }

    #[test]
    fn bad_inputs_are_refused() {
        let light = example_light_model(1, 50.0);
        let cert = one_point_cert(2, 2, Footprint { x0: 0, y0: 0, x1: 3, y1: 2, lux_per_unit: 1.0 }, 1);
        assert!(cert.validate().is_err());
        let cert = one_point_cert(2, 2, Footprint { x0: 0, y0: 0, x1: 2, y1: 2, lux_per_unit: f32::NAN }, 1);
        assert!(cert.validate().is_err());
        let cert = one_point_cert(2, 2, Footprint { x0: 0, y0: 0, x1: 2, y1: 2, lux_per_unit: 1.0 }, 1);
        let short = vec![0u8; 15];
        assert!(matches!(
            max_irradiance(&light, &cert, &[XrgbFrame { width: 2, height: 2, xrgb: &short }]),
            Err(LightError::FrameSize { .. })
        ));
        assert!(matches!(max_irradiance(&light, &cert, &[]), Err(LightError::FrameCount { .. })));
        let mut l2 = light.clone();
        l2.safety_margin = 0.9;
        assert!(l2.validate().is_err());
        let mut l3 = light;
        l3.projectors[0].response[1].pop();
        assert!(l3.validate().is_err());
    }

    #[test]
    fn certificate_round_trips() {
        let cert = one_point_cert(7, 5, Footprint { x0: 1, y0: 2, x1: 3, y1: 4, lux_per_unit: 2.5 }, 3);
        assert_eq!(LightCertificate::from_bytes(&cert.to_bytes()).unwrap(), cert);
        assert!(LightCertificate::from_bytes(&[1, 2, 3]).is_err());
    }

    /// Reference: the brute-force irradiance of a single point, every pixel of every block
    /// evaluated separately with the raw (not running-max) response.
    fn reference(light: &LightModel, cert: &LightCertificate, frames: &[Vec<u8>], i: usize) -> f64 {
        let mut e_proj = [0.0f64; 3];
        for (k, m) in cert.projectors.iter().enumerate() {
            let f = m.footprints[i];
            if f.is_empty() {
                continue;
            }
            let mut best = [0.0f64; 3];
            for y in f.y0..f.y1 {
                for x in f.x0..f.x1 {
                    let p = &frames[k][(y as usize * m.width as usize + x as usize) * 4..][..4];
                    for (c, v) in [p[2], p[1], p[0]].into_iter().enumerate() {
                        let r = f64::from(light.projectors[k].response[c][v as usize]);
                        best[c] = best[c].max(r);
                    }
                }
            }
            for c in 0..3 {
                e_proj[c] += f64::from(f.lux_per_unit) * (f64::from(light.projectors[k].black[c]) + best[c]);
            }
        }
        light.ambient_lux + light.weighting.combine(e_proj)
    }

    proptest! {
        /// The streaming check equals a brute-force reference (monotone responses) and
        /// never falls below it.
        #[test]
        fn matches_brute_force(seed in any::<u64>(), n_proj in 1usize..4, pts in 1u32..12) {
            use rand::{Rng, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let (w, h) = (9u32, 7u32);
            let mut light = example_light_model(n_proj, 100.0);
            light.ambient_lux = rng.gen_range(0.0..3.0);
            let frames: Vec<Vec<u8>> = (0..n_proj).map(|_| (0..w * h * 4).map(|_| rng.r#gen()).collect()).collect();
            let cert = LightCertificate {
                points: pts,
                point_px: vec![],
                projectors: (0..n_proj).map(|_| CertificateMap {
                    width: w,
                    height: h,
                    footprints: (0..pts).map(|_| {
                        let x0 = rng.gen_range(0..w as u16);
                        let y0 = rng.gen_range(0..h as u16);
                        Footprint {
                            x0, y0,
                            x1: rng.gen_range(x0..=w as u16),
                            y1: rng.gen_range(y0..=h as u16),
                            lux_per_unit: rng.gen_range(0.0..30.0),
                        }
                    }).collect(),
                }).collect(),
            };
            let views: Vec<XrgbFrame> = frames.iter().map(|f| XrgbFrame { width: w, height: h, xrgb: f }).collect();
            let peak = max_irradiance(&light, &cert, &views).unwrap();
            let want = (0..pts as usize).map(|i| reference(&light, &cert, &frames, i)).fold(f64::NEG_INFINITY, f64::max);
            prop_assert!((peak.lux - want).abs() <= 1e-9 * want.max(1.0), "{} vs {}", peak.lux, want);
        }
    }
}
