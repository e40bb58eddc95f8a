//! The whole light check of a bundle's scenes: every lit projector pixel must be vouched for
//! by the certificate ([`Coverage`]), and every certificate point must stay under the bound
//! (the per-point sums of [`super::max_irradiance`]). [`LightCheck`] runs both; the bundle
//! writer, the reader's `verify` (so `restage-author verify`, `restage-appliance verify`) and
//! the appliance's load all go through it.
//!
//! # Why coverage
//!
//! The per-point sums only look inside the certificate's blocks. A certificate whose blocks
//! miss the lit pixels (empty blocks, one 1-pixel block) or whose coefficients are zero would
//! charge a full-white scene nothing. So, per projector, the check builds once per
//! certificate a map of which pixels some non-empty block covers with a plausible
//! coefficient, and refuses a scene with a lit pixel outside it.
//!
//! - **Lit** means any of the pixel's R, G, B values is above 0. The declared response is not
//!   used for this: it is signed data too, and a curve flat at 0 up to 254 would otherwise
//!   exempt every pixel below full white. Pixels at 0 emit only the projector's black level,
//!   which lands mostly off the object; the certificate's blocks are trusted for where black
//!   light reaches.
//! - **Plausible** means `L_ik >= L_floor_k = lux_at_1m_k * min_cos / max_throw_m^2`
//!   ([`StageLimits`]): the irradiance per unit of response of a surface at the farthest
//!   throw the stage allows, at the most grazing angle (times vignetting) at which a lit pixel
//!   may still reach its brightest certificate point. A coefficient under that is not a stage
//!   this appliance can be standing in; zero coefficients on non-empty blocks are refused
//!   outright ([`LightCertificate::check_coefficients`]).
//!
//! What it guarantees: every pixel a scene lights is charged, at every certificate point whose
//! block holds it, at least `L_floor_k` times its (running-max) response, and the scene's peak
//! over those points is under the bound. What it assumes (trusts from the signed data): the
//! certificate's geometry (which points a pixel reaches: a lit pixel also reaches points whose
//! blocks miss it), coefficients at or above the floor (an honest `L_ik` can be up to
//! `(max_throw_m / d)^2 / min_cos` times the floor, so a liar can under-state by at most that
//! factor), `lux_at_1m`, the black level, and the response below 255 beyond the plausibility
//! floor of [`LightModel::check_responses`]. The limits are the appliance's, not the bundle's.
//!
//! These tests are the light check's, not the formats' (`validate`): a bundle that fails
//! them is well-formed, so the refusal fixtures can be written and signed, and the reader
//! refuses it here.
//!
//! Cost: building the map is one sweep over each projector's pixels plus two events per block
//! (`O(pixels + points)`, independent of the blocks' area); checking a frame is one pass over
//! its pixels. Memory: one byte per projector pixel, plus the blocks under the floor (for
//! messages; none in an honest certificate).

use super::{
    Footprint, LightCertificate, LightError, LightModel, PeakIrradiance, RESPONSE_LEVELS, SceneIrradiance,
    XrgbFrame, check_bound,
};

/// Default farthest throw (projector to any point it lights), metres: larger than any
/// museum stage we plan for, so only absurd coefficients are refused out of the box. Sites
/// set their own (appliance config `[light_check]`) for a tighter floor.
pub const DEFAULT_MAX_THROW_M: f64 = 10.0;
/// Default smallest `cos(theta) * vignetting` at a lit pixel's brightest certificate point.
/// Rim pixels of a curved object light it at grazing angles; 0.01 (89.4 degrees) leaves room
/// for a high-resolution projector's silhouette pixels.
pub const DEFAULT_MIN_COS: f64 = 0.01;

/// What the appliance assumes about the physical stage, independently of the bundle: the
/// bounds that make a certificate's coefficient too small to be true.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageLimits {
    /// Farthest distance from a projector to any surface point it lights, metres.
    pub max_throw_m: f64,
    /// Smallest `cos(theta) * vignetting` of the brightest certificate point a lit pixel
    /// reaches, in `(0, 1]`.
    pub min_cos: f64,
}

impl Default for StageLimits {
    fn default() -> Self {
        Self { max_throw_m: DEFAULT_MAX_THROW_M, min_cos: DEFAULT_MIN_COS }
    }
}

impl StageLimits {
    /// Checks ranges: `0 < max_throw_m <= 1000`, `0 < min_cos <= 1`.
    pub fn validate(&self) -> Result<(), LightError> {
        if !(self.max_throw_m.is_finite() && self.max_throw_m > 0.0 && self.max_throw_m <= 1000.0) {
            return Err(LightError::Limits(format!(
                "max_throw_m {} (expected 0 < max_throw_m <= 1000 metres)",
                self.max_throw_m
            )));
        }
        if !(self.min_cos > 0.0 && self.min_cos <= 1.0) {
            return Err(LightError::Limits(format!("min_cos {} (expected 0 < min_cos <= 1)", self.min_cos)));
        }
        Ok(())
    }

    /// `L_floor` for a projector of `lux_at_1m`: lux per unit of response at the farthest
    /// throw and the most grazing angle allowed.
    pub fn floor(&self, lux_at_1m: f64) -> f64 {
        lux_at_1m * self.min_cos / (self.max_throw_m * self.max_throw_m)
    }
}

/// Per pixel: no non-empty block covers it.
const NONE: u8 = 0;
/// Covered, but only by blocks whose coefficient is under the floor.
const UNDER: u8 = 1;
/// Covered by at least one block at or above the floor.
const OK: u8 = 2;

#[derive(Clone, Debug)]
struct ProjectorCoverage {
    width: u32,
    height: u32,
    floor: f64,
    /// Per pixel, row-major: [`NONE`], [`UNDER`] or [`OK`].
    state: Vec<u8>,
    /// The non-empty blocks under the floor, kept only to say in a refusal how small the
    /// best coefficient at a pixel was (an honest certificate has none or few).
    under: Vec<Footprint>,
}

/// A lit pixel the certificate does not vouch for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnvouchedPixel {
    pub projector: usize,
    pub x: u32,
    pub y: u32,
    /// Device values (r, g, b).
    pub rgb: [u8; 3],
    /// The largest coefficient among the blocks covering it; `None` when no block does.
    pub best_lux_per_unit: Option<f32>,
    /// The projector's `L_floor`.
    pub floor_lux_per_unit: f64,
}

impl UnvouchedPixel {
    /// The refusal, naming the scene.
    pub fn error(&self, scene: &str) -> LightError {
        let (scene, projector, x, y, rgb) = (scene.to_owned(), self.projector, self.x, self.y, self.rgb);
        match self.best_lux_per_unit {
            None => LightError::Uncovered { scene, projector, x, y, rgb },
            Some(best) => LightError::UnderStated {
                scene,
                projector,
                x,
                y,
                rgb,
                best_lux_per_unit: best,
                floor_lux_per_unit: self.floor_lux_per_unit,
            },
        }
    }
}

/// Which projector pixels a certificate vouches for (see the module docs): built once per
/// certificate, then each frame is checked in one pass.
#[derive(Clone, Debug)]
pub struct Coverage {
    projectors: Vec<ProjectorCoverage>,
}

/// One row-sweep event: a block entering (`delta = 1`) or leaving (`-1`) at a row.
#[derive(Clone, Copy)]
struct Event {
    x0: u16,
    x1: u16,
    delta: i32,
    ok: bool,
}

impl Coverage {
    /// The coverage of the union of `parts`' blocks: one certificate, or the consecutive
    /// parts of one (compensation checks parts in parallel). Validates the light model, the
    /// limits and every part (sizes, blocks inside the frames), so no input can make it panic,
    /// and refuses what the light check refuses before any frame: responses
    /// ([`LightModel::check_responses`]) and zero coefficients
    /// ([`LightCertificate::check_coefficients`]).
    pub fn new(
        light: &LightModel,
        parts: &[&LightCertificate],
        limits: &StageLimits,
    ) -> Result<Self, LightError> {
        limits.validate()?;
        light.validate()?;
        light.check_responses()?;
        let Some(first) = parts.first() else {
            return Err(LightError::Certificate("no certificate to build the coverage from".into()));
        };
        for p in parts {
            p.validate()?;
            p.check_coefficients()?;
            let same = p.projectors.len() == light.projectors.len()
                && p.projectors
                    .iter()
                    .zip(&first.projectors)
                    .all(|(a, b)| (a.width, a.height) == (b.width, b.height));
            if !same {
                return Err(LightError::Certificate(format!(
                    "certificate parts disagree: {} projector maps for {} projectors in the light model, or sizes differ",
                    p.projectors.len(),
                    light.projectors.len()
                )));
            }
        }
        let projectors = first
            .projectors
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let floor = limits.floor(light.projectors[k].lux_at_1m);
                let blocks = parts.iter().flat_map(|p| p.projectors[k].footprints.iter());
                sweep(m.width, m.height, floor, blocks)
            })
            .collect();
        Ok(Self { projectors })
    }

    /// Whether pixel `(x, y)` of projector `k` may be lit: a non-empty block with a
    /// coefficient at or above the floor covers it. False outside the frame.
    pub fn is_vouched(&self, k: usize, x: u32, y: u32) -> bool {
        self.projectors.get(k).is_some_and(|p| {
            x < p.width && y < p.height && p.state[y as usize * p.width as usize + x as usize] == OK
        })
    }

    /// The first lit pixel of projector `k`'s frame (in raster order) that the certificate
    /// does not vouch for, if any.
    pub fn first_unvouched(
        &self,
        k: usize,
        frame: XrgbFrame<'_>,
    ) -> Result<Option<UnvouchedPixel>, LightError> {
        let Some(p) = self.projectors.get(k) else {
            return Err(LightError::FrameCount { expected: self.projectors.len(), got: k + 1 });
        };
        frame.check_size(k, p.width, p.height)?;
        let w = p.width as usize;
        // Bytes B, G, R, X: any colour byte above 0 is light above black.
        let bad = frame
            .xrgb
            .chunks_exact(4)
            .zip(&p.state)
            .position(|(px, &s)| s != OK && (px[0] | px[1] | px[2]) != 0);
        Ok(bad.map(|i| {
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            let px = &frame.xrgb[i * 4..i * 4 + 4];
            let best = (p.state[i] == UNDER).then(|| {
                p.under
                    .iter()
                    .filter(|f| {
                        (f.x0 as u32..f.x1 as u32).contains(&x) && (f.y0 as u32..f.y1 as u32).contains(&y)
                    })
                    .map(|f| f.lux_per_unit)
                    .fold(0.0f32, f32::max)
            });
            UnvouchedPixel {
                projector: k,
                x,
                y,
                rgb: [px[2], px[1], px[0]],
                best_lux_per_unit: best,
                floor_lux_per_unit: p.floor,
            }
        }))
    }

    /// Refuses projector `k`'s frame of `scene` if it lights a pixel the certificate does not
    /// vouch for ([`LightError::Uncovered`] or [`LightError::UnderStated`]).
    pub fn check_frame(&self, scene: &str, k: usize, frame: XrgbFrame<'_>) -> Result<(), LightError> {
        match self.first_unvouched(k, frame)? {
            None => Ok(()),
            Some(px) => Err(px.error(scene)),
        }
    }
}

/// The coverage map of one projector: a sweep down the rows keeping, per column, a difference
/// array of how many blocks (and how many at or above the floor) are active; blocks enter at
/// `y0` and leave at `y1`. `O(width * height + blocks)`.
fn sweep<'b>(
    width: u32,
    height: u32,
    floor: f64,
    blocks: impl Iterator<Item = &'b Footprint> + Clone,
) -> ProjectorCoverage {
    let (w, h) = (width as usize, height as usize);
    let ok = |f: &Footprint| f64::from(f.lux_per_unit) >= floor;
    // Events bucketed by row (counting sort): rows 0..h; a block leaving at y1 == h needs none.
    let mut start = vec![0u32; h + 1];
    for f in blocks.clone().filter(|f| !f.is_empty()) {
        start[f.y0 as usize] += 1;
        if (f.y1 as usize) < h {
            start[f.y1 as usize] += 1;
        }
    }
    let mut total = 0u32;
    for s in start.iter_mut() {
        let n = *s;
        *s = total;
        total += n;
    }
    let mut next = start.clone();
    let mut events = vec![Event { x0: 0, x1: 0, delta: 0, ok: false }; total as usize];
    let mut under = Vec::new();
    for f in blocks.filter(|f| !f.is_empty()) {
        let e = Event { x0: f.x0, x1: f.x1, delta: 1, ok: ok(f) };
        let at = &mut next[f.y0 as usize];
        events[*at as usize] = e;
        *at += 1;
        if (f.y1 as usize) < h {
            let at = &mut next[f.y1 as usize];
            events[*at as usize] = Event { delta: -1, ..e };
            *at += 1;
        }
        if !e.ok {
            under.push(*f);
        }
    }
    let mut any = vec![0i32; w + 1];
    let mut good = vec![0i32; w + 1];
    let mut state = vec![NONE; w * h];
    for (y, row) in state.chunks_exact_mut(w.max(1)).enumerate().take(h) {
        for e in &events[start[y] as usize..start[y + 1] as usize] {
            any[e.x0 as usize] += e.delta;
            any[e.x1 as usize] -= e.delta;
            if e.ok {
                good[e.x0 as usize] += e.delta;
                good[e.x1 as usize] -= e.delta;
            }
        }
        let (mut a, mut g) = (0i32, 0i32);
        for ((s, da), dg) in row.iter_mut().zip(&any).zip(&good) {
            a += da;
            g += dg;
            *s = if g > 0 {
                OK
            } else if a > 0 {
                UNDER
            } else {
                NONE
            };
        }
    }
    ProjectorCoverage { width, height, floor, state, under }
}

/// The light check of one certificate: its coverage maps and the per-point sums, for any
/// number of scenes.
#[derive(Debug)]
pub struct LightCheck<'a> {
    light: &'a LightModel,
    cert: &'a LightCertificate,
    tables: Vec<[[f64; RESPONSE_LEVELS]; 3]>,
    coverage: Coverage,
}

impl<'a> LightCheck<'a> {
    /// Validates the light model, the certificate (and that they describe the same
    /// projectors) and the limits, and builds the coverage maps.
    pub fn new(
        light: &'a LightModel,
        cert: &'a LightCertificate,
        limits: &StageLimits,
    ) -> Result<Self, LightError> {
        let coverage = Coverage::new(light, &[cert], limits)?;
        Ok(Self { light, cert, tables: light.tables(), coverage })
    }

    pub fn coverage(&self) -> &Coverage {
        &self.coverage
    }

    /// Starts checking scene `scene` frame by frame (a streaming reader holds one frame at a
    /// time).
    pub fn scene(&self, scene: &str) -> SceneCheck<'_> {
        SceneCheck {
            coverage: &self.coverage,
            light: self.light,
            scene: scene.to_owned(),
            sums: SceneIrradiance::start(self.light, self.cert, self.tables.clone()),
        }
    }

    /// Checks a whole scene given as one frame per projector: coverage, peak, bound.
    pub fn check_scene(&self, scene: &str, frames: &[XrgbFrame<'_>]) -> Result<PeakIrradiance, LightError> {
        if frames.len() != self.cert.projectors.len() {
            return Err(LightError::FrameCount { expected: self.cert.projectors.len(), got: frames.len() });
        }
        let mut s = self.scene(scene);
        for (k, f) in frames.iter().enumerate() {
            s.add(k, *f)?;
        }
        s.finish()
    }
}

/// One scene in progress (see [`LightCheck::scene`]).
#[derive(Debug)]
pub struct SceneCheck<'c> {
    coverage: &'c Coverage,
    light: &'c LightModel,
    scene: String,
    sums: SceneIrradiance<'c>,
}

impl SceneCheck<'_> {
    /// Adds projector `k`'s frame: refused if the wrong size, given twice, or lighting a pixel
    /// the certificate does not vouch for.
    pub fn add(&mut self, k: usize, frame: XrgbFrame<'_>) -> Result<(), LightError> {
        self.sums.add(k, frame)?;
        self.coverage.check_frame(&self.scene, k, frame)
    }

    /// The scene's peak once every frame was added, refused if over the bound.
    pub fn finish(self) -> Result<PeakIrradiance, LightError> {
        let peak = self.sums.finish()?;
        check_bound(self.light, &self.scene, &peak)?;
        Ok(peak)
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::light::{CertificateMap, LuxWeighting, example_light_model};

    /// Floor of `example_light_model` (lux_at_1m 400) under default limits: 0.04.
    const FLOOR: f32 = 0.04;

    /// Whether a coefficient passes that floor, exactly as the check compares.
    fn plausible(l: f32) -> bool {
        f64::from(l) >= StageLimits::default().floor(400.0)
    }

    fn cert(w: u32, h: u32, blocks: Vec<Vec<Footprint>>) -> LightCertificate {
        let points = blocks[0].len() as u32;
        LightCertificate {
            points,
            point_px: vec![],
            projectors: blocks
                .into_iter()
                .map(|footprints| CertificateMap { width: w, height: h, footprints })
                .collect(),
        }
    }

    fn fp(x0: u16, y0: u16, x1: u16, y1: u16, l: f32) -> Footprint {
        Footprint { x0, y0, x1, y1, lux_per_unit: l }
    }

    /// An XRGB frame, every pixel `rgb` except those listed.
    fn frame(w: u32, h: u32, rgb: [u8; 3], except: &[(u32, u32, [u8; 3])]) -> Vec<u8> {
        let mut f: Vec<u8> = (0..w * h).flat_map(|_| [rgb[2], rgb[1], rgb[0], 0]).collect();
        for &(x, y, c) in except {
            let i = ((y * w + x) * 4) as usize;
            f[i..i + 4].copy_from_slice(&[c[2], c[1], c[0], 0]);
        }
        f
    }

    fn check(
        light: &LightModel,
        c: &LightCertificate,
        frames: &[Vec<u8>],
    ) -> Result<PeakIrradiance, LightError> {
        let (w, h) = (c.projectors[0].width, c.projectors[0].height);
        let views: Vec<XrgbFrame> =
            frames.iter().map(|f| XrgbFrame { width: w, height: h, xrgb: f }).collect();
        LightCheck::new(light, c, &StageLimits::default())?.check_scene("s1", &views)
    }

    #[test]
    fn covered_scene_passes_with_the_same_peak_as_the_sums() {
        let light = example_light_model(1, 100.0);
        let c = cert(4, 3, vec![vec![fp(0, 0, 2, 3, 10.0), fp(2, 0, 4, 3, 20.0)]]);
        let f = frame(4, 3, [255, 255, 255], &[]);
        let peak = check(&light, &c, std::slice::from_ref(&f)).unwrap();
        let sums =
            crate::light::max_irradiance(&light, &c, &[XrgbFrame { width: 4, height: 3, xrgb: &f }]).unwrap();
        assert_eq!(peak, sums);
        assert!((peak.lux - 20.0 * 1.01).abs() < 1e-4);
    }

    #[test]
    fn lit_pixel_outside_every_block_is_refused_naming_scene_projector_pixel() {
        let light = example_light_model(2, 100.0);
        // Projector 1's blocks miss column 3 of row 1.
        let c = cert(4, 3, vec![vec![fp(0, 0, 4, 3, 1.0)], vec![fp(0, 0, 3, 3, 1.0)]]);
        let dark_but = frame(4, 3, [0, 0, 0], &[(3, 1, [0, 7, 0])]);
        let err = check(&light, &c, &[frame(4, 3, [9, 9, 9], &[]), dark_but.clone()]).unwrap_err();
        assert_eq!(
            err,
            LightError::Uncovered { scene: "s1".into(), projector: 1, x: 3, y: 1, rgb: [0, 7, 0] }
        );
        let msg = err.to_string();
        assert!(msg.contains("scene s1") && msg.contains("projector 1") && msg.contains("(3, 1)"), "{msg}");
        // The same pixel at 0 is black light, which may land outside the blocks.
        check(&light, &c, &[frame(4, 3, [9, 9, 9], &[]), frame(4, 3, [0, 0, 0], &[])]).unwrap();
        // The X byte is not light.
        let mut x_only = frame(4, 3, [0, 0, 0], &[]);
        x_only[(4 + 3) * 4 + 3] = 255;
        check(&light, &c, &[frame(4, 3, [9, 9, 9], &[]), x_only]).unwrap();
    }

    #[test]
    fn empty_blocks_and_a_one_pixel_block_do_not_cover_a_white_frame() {
        let light = example_light_model(1, 100.0);
        let white = frame(5, 4, [255; 3], &[]);
        let empty = cert(5, 4, vec![vec![Footprint::default(); 3]]);
        assert!(matches!(
            check(&light, &empty, std::slice::from_ref(&white)),
            Err(LightError::Uncovered { x: 0, y: 0, .. })
        ));
        let one = cert(5, 4, vec![vec![fp(0, 0, 1, 1, 30.0), Footprint::default()]]);
        assert!(matches!(
            check(&light, &one, std::slice::from_ref(&white)),
            Err(LightError::Uncovered { x: 1, y: 0, .. })
        ));
        // What the sums alone say about that white frame: 0 lx and 30.3 lx.
        let view = [XrgbFrame { width: 5, height: 4, xrgb: &white }];
        assert_eq!(crate::light::max_irradiance(&light, &empty, &view).unwrap().lux, 0.0);
    }

    #[test]
    fn zero_coefficients_are_refused_and_tiny_ones_are_under_stated() {
        let light = example_light_model(1, 100.0);
        let white = frame(3, 2, [255; 3], &[]);
        let zero = cert(3, 2, vec![vec![fp(0, 0, 3, 2, 0.0)]]);
        assert_eq!(
            check(&light, &zero, std::slice::from_ref(&white)).unwrap_err(),
            LightError::ZeroCoefficient { projector: 0, point: 0, x0: 0, y0: 0, x1: 3, y1: 2 }
        );
        // Two blocks under the floor over (1, 0): the message names the larger coefficient.
        let tiny = cert(3, 2, vec![vec![fp(1, 0, 3, 2, 1e-3), fp(0, 0, 2, 1, 2e-3), fp(0, 0, 1, 2, 1.0)]]);
        match check(&light, &tiny, std::slice::from_ref(&white)).unwrap_err() {
            LightError::UnderStated {
                scene,
                projector: 0,
                x: 1,
                y: 0,
                best_lux_per_unit,
                floor_lux_per_unit,
                ..
            } => {
                assert_eq!(scene, "s1");
                assert_eq!(best_lux_per_unit, 2e-3);
                assert!((floor_lux_per_unit - f64::from(FLOOR)).abs() < 1e-6);
            }
            e => panic!("{e}"),
        }
    }

    #[test]
    fn the_floor_follows_the_stage_limits() {
        let light = example_light_model(1, 100.0);
        let c = cert(2, 2, vec![vec![fp(0, 0, 2, 2, 0.5)]]);
        let white = frame(2, 2, [255; 3], &[]);
        let view = [XrgbFrame { width: 2, height: 2, xrgb: &white }];
        // Default: 400 * 0.01 / 10^2 = 0.04 <= 0.5.
        LightCheck::new(&light, &c, &StageLimits::default()).unwrap().check_scene("s", &view).unwrap();
        // A 2 m stage facing the projector: 400 * 0.2 / 4 = 20 > 0.5.
        let near = StageLimits { max_throw_m: 2.0, min_cos: 0.2 };
        let e = LightCheck::new(&light, &c, &near).unwrap().check_scene("s", &view).unwrap_err();
        assert!(
            matches!(e, LightError::UnderStated { floor_lux_per_unit, .. } if (floor_lux_per_unit - 20.0).abs() < 1e-9),
            "{e}"
        );
        for bad in [
            StageLimits { max_throw_m: 0.0, min_cos: 0.1 },
            StageLimits { max_throw_m: 3.0, min_cos: f64::NAN },
        ] {
            assert!(matches!(LightCheck::new(&light, &c, &bad), Err(LightError::Limits(_))));
        }
    }

    #[test]
    fn responses_must_reach_full_output_and_stay_plausible() {
        let mut light = example_light_model(2, 100.0);
        light.projectors[1].response[2] = vec![0.0; RESPONSE_LEVELS];
        // Well-formed (so it can be signed), refused by the check.
        light.validate().unwrap();
        let c = cert(2, 2, vec![vec![fp(0, 0, 2, 2, 1.0)]; 2]);
        assert!(matches!(
            LightCheck::new(&light, &c, &StageLimits::default()),
            Err(LightError::ResponseShort { .. })
        ));
        assert_eq!(
            light.check_responses().unwrap_err(),
            LightError::ResponseShort { projector: 1, channel: 2, reached: 0.0 }
        );
        light.projectors[1].response[2] =
            (0..RESPONSE_LEVELS).map(|v| if v == 255 { 1.0 } else { 0.0 }).collect();
        assert!(matches!(
            light.check_responses().unwrap_err(),
            LightError::ResponseImplausible { projector: 1, channel: 2, value: 65, .. }
        ));
        // Gamma 1.8 to 2.6 (the virtual stage's range), a linear curve, a crushed black end and
        // a curve just under full at 255 all pass.
        for g in [1.0f32, 1.8, 2.2, 2.6] {
            light.projectors[1].response[2] =
                (0..RESPONSE_LEVELS).map(|v| (v as f32 / 255.0).powf(g)).collect();
            light.check_responses().unwrap();
        }
        light.projectors[1].response[2] =
            (0..RESPONSE_LEVELS).map(|v| 0.995 * ((v as f32 - 24.0).max(0.0) / 231.0).powf(2.4)).collect();
        light.check_responses().unwrap();
    }

    #[test]
    fn coverage_of_parts_is_the_coverage_of_the_whole() {
        let light = example_light_model(1, 100.0);
        let whole = cert(6, 2, vec![vec![fp(0, 0, 3, 2, 1.0), fp(3, 0, 6, 2, 1.0)]]);
        let a = cert(6, 2, vec![vec![fp(0, 0, 3, 2, 1.0)]]);
        let b = cert(6, 2, vec![vec![fp(3, 0, 6, 2, 1.0)]]);
        let l = StageLimits::default();
        let (cw, cp) =
            (Coverage::new(&light, &[&whole], &l).unwrap(), Coverage::new(&light, &[&a, &b], &l).unwrap());
        let ca = Coverage::new(&light, &[&a], &l).unwrap();
        for y in 0..2 {
            for x in 0..6 {
                assert_eq!(cw.is_vouched(0, x, y), cp.is_vouched(0, x, y));
                assert_eq!(ca.is_vouched(0, x, y), x < 3);
            }
        }
        assert!(!cw.is_vouched(0, 6, 0) && !cw.is_vouched(1, 0, 0));
    }

    /// Brute force: the largest coefficient of projector `k`'s blocks holding `(x, y)`.
    fn best_at(c: &LightCertificate, k: usize, x: u16, y: u16) -> Option<f32> {
        c.projectors[k]
            .footprints
            .iter()
            .filter(|f| !f.is_empty() && (f.x0..f.x1).contains(&x) && (f.y0..f.y1).contains(&y))
            .map(|f| f.lux_per_unit)
            .reduce(f32::max)
    }

    proptest! {
        /// For random certificates and frames: the check accepts exactly when every lit pixel
        /// lies in a block at or above the floor; then its peak is at least the light any lit
        /// pixel alone gives any point whose block holds it (the per-pixel truth); otherwise
        /// it names the first such pixel (projector order, then raster order), correctly.
        #[test]
        fn accepts_exactly_vouched_scenes_and_bounds_every_lit_pixel(
            seed in any::<u64>(),
            n_proj in 1usize..4,
            pts in 1u32..10,
            only_vouched in any::<bool>(),
        ) {
            use rand::{Rng, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let (w, h) = (rng.gen_range(1u32..12), rng.gen_range(1u32..9));
            let mut light = example_light_model(n_proj, 1e6);
            light.ambient_lux = rng.gen_range(0.0..2.0);
            if rng.gen_bool(0.5) {
                light.weighting = LuxWeighting::Shares([0.3, 0.6, 0.1]);
            }
            let blocks: Vec<Vec<Footprint>> = (0..n_proj).map(|_| (0..pts).map(|_| {
                if rng.gen_bool(0.15) {
                    return Footprint::default();
                }
                let x0 = rng.gen_range(0..w as u16);
                let y0 = rng.gen_range(0..h as u16);
                let l = if rng.gen_bool(0.3) { rng.gen_range(0.001..FLOOR) } else { rng.gen_range(FLOOR..5.0) };
                fp(x0, y0, rng.gen_range(x0 + 1..=w as u16), rng.gen_range(y0 + 1..=h as u16), l)
            }).collect()).collect();
            let c = cert(w, h, blocks);
            let frames: Vec<Vec<u8>> = (0..n_proj).map(|k| {
                let mut f = vec![0u8; (w * h * 4) as usize];
                for y in 0..h as u16 {
                    for x in 0..w as u16 {
                        let allowed = !only_vouched || best_at(&c, k, x, y).is_some_and(plausible);
                        if allowed && rng.gen_bool(0.4) {
                            let i = (y as usize * w as usize + x as usize) * 4;
                            // Sometimes one channel only, sometimes a low value.
                            let v: [u8; 3] = std::array::from_fn(|_| if rng.gen_bool(0.5) { rng.r#gen() } else { 0 });
                            f[i..i + 3].copy_from_slice(&v);
                        }
                    }
                }
                f
            }).collect();
            let lit = |k: usize, x: u16, y: u16| {
                let i = (y as usize * w as usize + x as usize) * 4;
                frames[k][i] | frames[k][i + 1] | frames[k][i + 2] != 0
            };
            // The first unvouched lit pixel, brute force.
            let mut first = None;
            'outer: for k in 0..n_proj {
                for y in 0..h as u16 {
                    for x in 0..w as u16 {
                        if lit(k, x, y) && !best_at(&c, k, x, y).is_some_and(plausible) {
                            first = Some((k, x, y));
                            break 'outer;
                        }
                    }
                }
            }
            match (check(&light, &c, &frames), first) {
                (Ok(peak), None) => {
                    let tables = light.tables();
                    for k in 0..n_proj {
                        for y in 0..h as u16 {
                            for x in 0..w as u16 {
                                if !lit(k, x, y) {
                                    continue;
                                }
                                let i = (y as usize * w as usize + x as usize) * 4;
                                let v = [frames[k][i + 2], frames[k][i + 1], frames[k][i]];
                                for f in c.projectors[k].footprints.iter().filter(|f| {
                                    !f.is_empty() && (f.x0..f.x1).contains(&x) && (f.y0..f.y1).contains(&y)
                                }) {
                                    let e: [f64; 3] = std::array::from_fn(|ch| f64::from(f.lux_per_unit) * tables[k][ch][v[ch] as usize]);
                                    let truth = light.ambient_lux + light.weighting.combine(e);
                                    prop_assert!(peak.lux >= truth * (1.0 - 1e-12), "{} < {truth}", peak.lux);
                                }
                            }
                        }
                    }
                }
                (Err(LightError::Uncovered { projector, x, y, .. }), Some((k, bx, by))) => {
                    prop_assert_eq!((projector, x, y), (k, u32::from(bx), u32::from(by)));
                    prop_assert!(best_at(&c, k, bx, by).is_none());
                }
                (Err(LightError::UnderStated { projector, x, y, best_lux_per_unit, .. }), Some((k, bx, by))) => {
                    prop_assert_eq!((projector, x, y), (k, u32::from(bx), u32::from(by)));
                    prop_assert_eq!(Some(best_lux_per_unit), best_at(&c, k, bx, by));
                }
                (got, want) => prop_assert!(false, "check {:?}, brute force {:?}", got, want),
            }
            if only_vouched {
                prop_assert!(first.is_none());
            }
        }
    }
}
