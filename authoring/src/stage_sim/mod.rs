//! The virtual stage: a physically based, seeded simulator of the whole stage (object,
//! projectors, camera) that writes the same capture set as real hardware plus the ground
//! truth only tests and `eval` read. See ARCHITECTURE.md, "Virtual stage".
//!
//! Geometry is precomputed once per scene (per camera pixel: surface point, normal, albedo,
//! and for every projector the pixel footprint and the factor `lux_at_1m * cos / d^2`, zero
//! where the projector cannot see the point), so each capture is a cheap gather.

pub mod bounce;
pub mod foreign;
pub mod geometry;
pub mod optics;
pub mod paint;
mod truth;

use std::path::{Path, PathBuf};
use std::str::FromStr;

use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use self::geometry::{Part, Profile, Scene, Shape, Solid, V3};
use self::optics::{CameraSpec, Integrator, ProjectorSpec, SimProjector};
use self::paint::{Design, Deterioration, Palette};
use self::paint::{PANEL_RADIUS_MM, PANEL_THICKNESS_MM, PANEL_UNROLL_MM};
use crate::acquire::{self, AcquireConfig, AcquireError};
use crate::calibrate::response::Bracket;
use crate::capture_set::{CameraIntrinsics, CaptureManifest};
use crate::hw::{Camera, DiffuseLight, HwError, ProjectorOutput};
use crate::imgio::{ImageError, LinearImage};
use crate::stage_model::{StageModel, StageModelError, Transport};

pub use self::truth::{GROUND_TRUTH_DIR, LUX_METER_FILE, TRUTH_FILE, Truth, load_config};

/// Accepted camera sizes (each side).
pub const CAMERA_RANGE: std::ops::RangeInclusive<u32> = 16..=8192;
/// Accepted projector sizes (each side).
pub const PROJECTOR_RANGE: std::ops::RangeInclusive<u32> = 16..=4096;
/// Accepted projector counts.
pub const PROJECTOR_COUNT_RANGE: std::ops::RangeInclusive<u32> = 1..=8;

#[derive(Debug, Error)]
pub enum StageSimError {
    #[error("unknown scene {name:?} (expected one of: vase, bowl, jar, panel)")]
    UnknownScene { name: String },
    #[error("the virtual stage has no {0}")]
    Unsupported(String),
    #[error("{what} resolution {width}x{height} is out of range (expected {min}..={max} on each side)")]
    Resolution { what: &'static str, width: u32, height: u32, min: u32, max: u32 },
    #[error("projector count {0} is out of range (expected 1..=8)")]
    ProjectorCount(u32),
    #[error("{count} frames given for {expected} projectors")]
    FrameCount { count: usize, expected: usize },
    #[error(transparent)]
    Hw(#[from] HwError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    StageModel(#[from] StageModelError),
    #[error(transparent)]
    Acquire(#[from] AcquireError),
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {problem}")]
    Truth { path: PathBuf, problem: String },
    #[error("lux meter at camera pixel {pixel:?}: {problem}")]
    LuxMeter { pixel: [u32; 2], problem: String },
    #[error("the virtual camera has no 8-bit output (set CameraSpec::codes for exposure brackets)")]
    NoCodeCamera,
}

/// The simulated lux-meter readings: where the meter was held and one reading (lux) per
/// projector at full white.
#[derive(Clone, Debug, PartialEq)]
pub struct LuxMeterSession {
    /// Camera pixel whose surface point the meter was held at.
    pub pixel: [u32; 2],
    pub readings: Vec<f64>,
}

/// The built-in objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum SceneName {
    Vase,
    Bowl,
    Jar,
    /// A flat painted panel (a painting, a tile) tilted back like on an easel: planar, so its
    /// capture calibrates only through a saved rig.
    Panel,
}

impl SceneName {
    /// The round objects, which the evaluations run over.
    pub const ALL: [SceneName; 3] = [SceneName::Vase, SceneName::Bowl, SceneName::Jar];
    /// Every built-in scene.
    pub const NAMED: [SceneName; 4] = [SceneName::Vase, SceneName::Bowl, SceneName::Jar, SceneName::Panel];

    pub fn profile(self) -> Profile {
        match self {
            SceneName::Vase => Profile::Vase,
            SceneName::Bowl => Profile::Bowl,
            SceneName::Jar => Profile::Jar,
            SceneName::Panel => Profile::Cylinder { radius: PANEL_RADIUS_MM, height: PANEL_THICKNESS_MM },
        }
    }

    pub fn design(self) -> Design {
        match self {
            SceneName::Vase => Design::Vase,
            SceneName::Bowl => Design::Bowl,
            SceneName::Jar => Design::Jar,
            SceneName::Panel => Design::Panel,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SceneName::Vase => "vase",
            SceneName::Bowl => "bowl",
            SceneName::Jar => "jar",
            SceneName::Panel => "panel",
        }
    }
}

impl FromStr for SceneName {
    type Err = StageSimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::NAMED
            .into_iter()
            .find(|n| n.name() == s.to_ascii_lowercase())
            .ok_or_else(|| StageSimError::UnknownScene { name: s.into() })
    }
}

/// Everything that defines a built-in virtual stage. The same config always gives the same
/// stage, captures included.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    pub scene: SceneName,
    pub seed: u64,
    /// Camera `[width, height]`.
    pub camera: [u32; 2],
    /// Every projector's `[width, height]`.
    pub projector: [u32; 2],
    pub projectors: u32,
    /// Whether the object is deteriorated (otherwise it shows its pristine paint).
    pub deteriorate: bool,
    /// Whether the object stands on a grey plinth (seen and lit, not part of the object,
    /// reflecting light onto it). Absent in older configs: no plinth.
    #[serde(default)]
    pub plinth: bool,
    /// Whether the rig and the object vary with the seed. Absent in older configs: nominal.
    #[serde(default)]
    pub rig: RigVariation,
}

/// Whether a built-in stage's geometry comes from its seed as well as its paint and
/// deterioration, so that a new seed also tests calibration on a new rig.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum RigVariation {
    /// The same projector placement, lenses and object form at every seed.
    #[default]
    Nominal,
    /// Drawn from the seed alone (so every scene at one seed shares the rig): each
    /// projector's azimuth ±4°, elevation ±3°, distance ±60 mm and focal length ±6 %; the
    /// camera's focal length ±5 %; the round objects' radius ±8 % and a taper of ±12 %.
    Seeded,
}

impl RigVariation {
    /// Applies the variation to the built-in projector and camera specs; returns the shape
    /// of a round object.
    fn apply(self, seed: u64, projectors: &mut [ProjectorSpec], camera: &mut CameraSpec) -> Shape {
        if self == RigVariation::Nominal {
            return Shape::NOMINAL;
        }
        // Its own stream: paint, deterioration and radiometry draw as they always did.
        let mut rng = ChaCha8Rng::seed_from_u64(mix(seed, 0x51a6_0000));
        camera.focal_per_height *= 1.0 + rng.gen_range(-0.05..0.05);
        let shape = Shape { scale: 1.0 + rng.gen_range(-0.08..0.08), taper: rng.gen_range(-0.12..0.12) };
        for p in projectors {
            p.azimuth_deg += rng.gen_range(-4.0..4.0);
            p.elevation_deg += rng.gen_range(-3.0..3.0);
            p.distance_mm += rng.gen_range(-60.0..60.0);
            p.focal_per_height *= 1.0 + rng.gen_range(-0.06..0.06);
        }
        shape
    }
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            scene: SceneName::Vase,
            seed: 1,
            camera: [1024, 768],
            projector: [1400, 1050],
            projectors: 3,
            deteriorate: true,
            plinth: false,
            rig: RigVariation::Nominal,
        }
    }
}

impl SceneConfig {
    /// A tiny stage for tests in other modules: camera 160x120, projectors 128x96.
    pub fn tiny(scene: SceneName, seed: u64) -> Self {
        Self { scene, seed, camera: [160, 120], projector: [128, 96], ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), StageSimError> {
        let check = |what, [w, h]: [u32; 2], range: &std::ops::RangeInclusive<u32>| {
            if range.contains(&w) && range.contains(&h) {
                Ok(())
            } else {
                Err(StageSimError::Resolution {
                    what,
                    width: w,
                    height: h,
                    min: *range.start(),
                    max: *range.end(),
                })
            }
        };
        check("camera", self.camera, &CAMERA_RANGE)?;
        check("projector", self.projector, &PROJECTOR_RANGE)?;
        if !PROJECTOR_COUNT_RANGE.contains(&self.projectors) {
            return Err(StageSimError::ProjectorCount(self.projectors));
        }
        if self.plinth && self.scene == SceneName::Panel {
            return Err(StageSimError::Unsupported(
                "panel on a plinth (a panel hangs or stands on an easel)".into(),
            ));
        }
        Ok(())
    }
}

/// A stage described part by part; built-in scenes come from [`SceneConfig`], tests build
/// their own (a flat board, an occluder, an ideal projector).
#[derive(Clone, Debug)]
pub struct Setup {
    pub label: String,
    pub seed: u64,
    pub camera: CameraIntrinsics,
    pub camera_spec: CameraSpec,
    pub projectors: Vec<SimProjector>,
    /// The specs the projectors were built from (empty for hand-built projectors).
    pub projector_specs: Vec<ProjectorSpec>,
    pub scene: Scene,
    pub design: Design,
    pub deterioration: Deterioration,
    /// Illuminance of the room's diffuse light (for the photo), lux.
    pub diffuse_lux: f64,
    /// Stray room light that is always there, lux.
    pub stray_lux: f64,
    /// The support the object stands on, if any (one of `scene`'s solids).
    pub plinth: Option<Plinth>,
}

/// A round grey plinth: a solid of the scene that is not the object. Its top must be the
/// base plane of solid 0, centred on its axis (the interreflection model assumes so).
#[derive(Clone, Debug)]
pub struct Plinth {
    /// Index of the plinth in the scene's solids.
    pub solid: usize,
    pub albedo: f32,
    /// Radius of its top, mm.
    pub radius: f64,
}

/// The built-in plinth: a 320 mm radius, 60 mm tall disc of grey (albedo 0.5).
pub const PLINTH_RADIUS_MM: f64 = 320.0;
pub const PLINTH_HEIGHT_MM: f64 = 60.0;
pub const PLINTH_ALBEDO: f32 = 0.5;

/// Centre of the object in the camera frame, mm.
pub const OBJECT_CENTRE: [f64; 3] = [0.0, 0.0, 900.0];
/// The camera looks down on the object by this angle (the object's axis leans towards it).
pub const VIEW_DOWN_DEG: f64 = 4.0;

impl Setup {
    pub fn from_config(cfg: &SceneConfig) -> Result<Self, StageSimError> {
        cfg.validate()?;
        let mut camera_spec = CameraSpec::default();
        let n = cfg.projectors as usize;
        let mut projector_specs: Vec<ProjectorSpec> =
            (0..n).map(|k| ProjectorSpec::default_for(k, n, cfg.seed)).collect();
        let shape = cfg.rig.apply(cfg.seed, &mut projector_specs, &mut camera_spec);
        let (centre, up) = object_axis();
        let profile = cfg.scene.profile();
        let height = profile.height();
        let (solid, painted_height) = if cfg.scene == SceneName::Panel {
            // The panel faces the camera, tilted back 15 degrees and turned 8 degrees to the side.
            let normal = nalgebra::Rotation3::from_euler_angles(-15f64.to_radians(), 8f64.to_radians(), 0.0)
                * V3::new(0.0, 0.0, -1.0);
            let base = centre - normal * (height * 0.5);
            (Solid::new(profile, base, normal, V3::new(1.0, 0.0, 0.0)), 2.0 * PANEL_RADIUS_MM)
        } else {
            (Solid::shaped(profile, shape, centre - up * (height * 0.5), up, -centre), height)
        };
        let base = solid.base;
        let mut solids = vec![solid];
        let plinth = cfg.plinth.then(|| {
            solids.push(Solid::new(
                Profile::Cylinder { radius: PLINTH_RADIUS_MM, height: PLINTH_HEIGHT_MM },
                base - up * PLINTH_HEIGHT_MM,
                up,
                -centre,
            ));
            Plinth { solid: 1, albedo: PLINTH_ALBEDO, radius: PLINTH_RADIUS_MM }
        });
        let projectors = build_projectors(&projector_specs, cfg.projector);
        Ok(Self {
            label: format!(
                "virtual stage: {}{}, seed {}{}",
                cfg.scene.name(),
                if cfg.plinth { " on a plinth" } else { "" },
                cfg.seed,
                if cfg.rig == RigVariation::Seeded { ", rig from the seed" } else { "" },
            ),
            seed: cfg.seed,
            camera: camera_spec.intrinsics(cfg.camera[0], cfg.camera[1]),
            camera_spec,
            projectors,
            projector_specs,
            scene: Scene { solids },
            design: cfg.scene.design(),
            deterioration: if cfg.deteriorate {
                Deterioration::generate(cfg.seed, painted_height)
            } else {
                Deterioration::none()
            },
            diffuse_lux: 350.0,
            stray_lux: 0.5,
            plinth,
        })
    }
}

impl Setup {
    /// The same stage with its projectors placed and built from `specs` instead (each at the
    /// resolution of the setup's first projector): stages the built-in layout does not cover,
    /// such as a projector beside the object lighting what the camera sees at a grazing angle.
    pub fn with_projector_specs(mut self, specs: Vec<ProjectorSpec>) -> Self {
        let size = self.projectors.first().map_or([800, 600], |p| [p.width, p.height]);
        self.projectors = build_projectors(&specs, size);
        self.projector_specs = specs;
        self
    }
}

/// The built-in object's centre and axis (camera frame): every scene stands there.
fn object_axis() -> (V3, V3) {
    let down = VIEW_DOWN_DEG.to_radians();
    (V3::from(OBJECT_CENTRE), V3::new(0.0, -down.cos(), -down.sin()))
}

fn build_projectors(specs: &[ProjectorSpec], size: [u32; 2]) -> Vec<SimProjector> {
    let (centre, up) = object_axis();
    specs.iter().map(|s| SimProjector::from_spec(s, size[0], size[1], &centre, &up)).collect()
}

/// What a camera pixel mostly sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seen {
    Nothing,
    Object,
    /// The plinth: lit and seen like the object, but not part of it (label 255).
    Plinth,
}

/// What the camera pixel sees, fixed for the scene.
#[derive(Clone, Copy, Debug)]
pub struct PixelTruth {
    /// Surface point (mm, camera frame); NaN where the pixel sees no object.
    pub point: [f32; 3],
    pub normal: [f32; 3],
    pub albedo: [f32; 3],
    pub albedo_pristine: [f32; 3],
    /// Class indices; 255 where no object.
    pub label: u8,
    pub label_pristine: u8,
    pub chipped: bool,
    pub cracked: bool,
    pub stain: f32,
    pub fade: f32,
    /// Fraction of the pixel's area on the object: 1 inside it, 0 where the pixel sees none
    /// of it, between on its silhouette.
    pub coverage: f32,
    /// Whether the pixel's area holds more than one surface or paint (chip rims, paint
    /// edges, silhouettes): it was sub-sampled, `albedo` is the area mean (no object counts
    /// 0), labels and wear are the majority of the object's sub-samples, `label` is 255 when
    /// less than half of the pixel is on the object, and `point`/`normal` are still the
    /// centre ray's.
    pub mixed: bool,
    /// Object, plinth or nothing: what most of the pixel's area sees.
    pub seen: Seen,
}

impl PixelTruth {
    const EMPTY: Self = Self {
        point: [f32::NAN; 3],
        normal: [f32::NAN; 3],
        albedo: [0.0; 3],
        albedo_pristine: [0.0; 3],
        label: 255,
        label_pristine: 255,
        chipped: false,
        cracked: false,
        stain: 0.0,
        fade: 0.0,
        coverage: 0.0,
        mixed: false,
        seen: Seen::Nothing,
    };

    /// Whether (most of) the pixel is on the object; false on the plinth and off both.
    pub fn is_object(&self) -> bool {
        self.label != 255
    }
}

/// The highest irradiance anywhere on the lit object surface
/// ([`VirtualStage::surface_peak`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePeak {
    /// Lux: the largest channel, room stray light included.
    pub lux: f64,
    /// Lux per channel at the peak.
    pub rgb: [f64; 3],
    /// The peak's surface point and outward normal (camera frame, mm); NaN when no
    /// projector ray reaches the object (then `lux` is the stray light alone).
    pub point_mm: [f64; 3],
    pub normal: [f64; 3],
    /// The projector whose ray found the point, and where on its image (pixels).
    pub projector: usize,
    pub projector_px: [f64; 2],
    /// How many surface points were evaluated.
    pub samples: usize,
}

impl SurfacePeak {
    /// The higher of two candidates; on a tie the first (so reductions in a fixed order are
    /// deterministic whatever the thread count).
    fn better(a: Option<Self>, b: Option<Self>) -> Option<Self> {
        match (a, b) {
            (Some(a), Some(b)) => Some(if b.lux > a.lux { b } else { a }),
            (a, b) => a.or(b),
        }
    }
}

/// One projector as seen from one camera pixel: where the pixel's footprint falls on the
/// projector image and how much light a unit of projector output gives there.
#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    u: f32,
    v: f32,
    hx: f32,
    hy: f32,
    /// `lux_at_1m * cos(theta) / (d / 1000)^2`; 0 where the projector cannot light the point.
    g: f32,
}

/// The virtual stage with its geometry precomputed.
#[derive(Debug)]
pub struct VirtualStage {
    setup: Setup,
    config: Option<SceneConfig>,
    palette: Palette,
    pixels: Vec<PixelTruth>,
    /// Per projector, per camera pixel.
    samples: Vec<Vec<Sample>>,
    /// The sub-samples of pixels whose area spans a geometric edge.
    sub: SubSamples,
    /// Per projector: irradiance (lux) while the projector shows black.
    black_lux: Vec<Lux>,
    /// Interreflection from the plinth, when there is one.
    bounce: Option<BounceState>,
}

/// The plinth's interreflection as the stage uses it.
#[derive(Debug)]
struct BounceState {
    transfer: bounce::Bounce,
    /// Per projector, per plinth patch: how the projector lights it (point sample: `u`, `v`,
    /// `g`; `g` is 0 where it does not).
    patches: Vec<Vec<Sample>>,
    /// Where each camera pixel's and sub-sample's point falls on the receiver grid.
    pixel: Vec<Option<bounce::Interp>>,
    sub: Vec<Option<bounce::Interp>>,
}

/// Sub-pixels per side of a mixed camera pixel.
const SUB_N: usize = 5;
/// Sub-samples of a mixed camera pixel.
const SUB_COUNT: usize = SUB_N * SUB_N;
/// Depth difference (mm) between neighbouring probes of one pixel that counts as an edge
/// (an occluding contour); a grazing surface changes depth by a few mm across a pixel.
const DEPTH_JUMP_MM: f64 = 5.0;

/// Sub-samples of the camera pixels whose area spans a geometric edge (a silhouette, an
/// occluding contour, a change of solid or part): there the irradiance differs across the
/// pixel, so each sub-sample is lit on its own. Pixels mixed only in paint keep one
/// irradiance (it is smooth across them) and an area-mean albedo.
#[derive(Debug, Default)]
struct SubSamples {
    /// Per such pixel: its index and the range of its sub-samples that hit a surface
    /// (the others see nothing and contribute 0 to its value).
    pixels: Vec<(usize, std::ops::Range<usize>)>,
    /// Per sub-sample that hit a surface.
    albedo: Vec<[f32; 3]>,
    /// Per projector, per sub-sample.
    samples: Vec<Vec<Sample>>,
}

/// Irradiance (lux per channel) from one projector at every camera pixel and sub-sample.
#[derive(Debug, Clone)]
struct Lux {
    /// Per camera pixel; for a pixel with sub-samples, their mean over those that hit.
    pixel: Vec<[f32; 3]>,
    /// Per sub-sample ([`SubSamples`]).
    sub: Vec<[f32; 3]>,
    /// Per plinth patch (direct light on it; empty without a plinth).
    patch: Vec<[f32; 3]>,
}

/// What one ray from the camera found, reduced to what tells edges apart.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Probe {
    /// Solid, part, deteriorated label, chipped, cracked; None for no hit.
    key: Option<(usize, Part, u8, bool, bool)>,
    t: f64,
}

impl Probe {
    fn new(hit: Option<&geometry::Hit>, truth: &PixelTruth) -> Self {
        Self {
            key: hit.map(|h| (h.solid, h.part, truth.label, truth.chipped, truth.cracked)),
            t: hit.map_or(f64::INFINITY, |h| h.t),
        }
    }

    fn same_geometry(&self, o: &Self) -> bool {
        match (self.key, o.key) {
            (None, None) => true,
            (Some(a), Some(b)) => a.0 == b.0 && a.1 == b.1 && (self.t - o.t).abs() < DEPTH_JUMP_MM,
            _ => false,
        }
    }

    fn same(&self, o: &Self) -> bool {
        self.same_geometry(o) && self.key == o.key
    }
}

/// A camera pixel as built: its representative hit (the centre ray's), its truth, and for a
/// geometrically mixed pixel its sub-samples' hits and truths with their positions.
type BuiltPixel = (Option<geometry::Hit>, PixelTruth, Option<Vec<(geometry::Hit, PixelTruth, [f64; 2])>>);

impl VirtualStage {
    /// Builds a built-in scene.
    pub fn new(cfg: &SceneConfig) -> Result<Self, StageSimError> {
        let mut s = Self::from_setup(Setup::from_config(cfg)?);
        s.config = Some(cfg.clone());
        Ok(s)
    }

    /// Builds a stage from explicit parts and precomputes its geometry.
    pub fn from_setup(setup: Setup) -> Self {
        let cam = setup.camera.clone();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let palette = setup.design.palette();
        let far = 1.0e5;
        let look = |x: f64, y: f64| {
            let hit = setup.scene.cast(&V3::zeros(), &ray(&cam, x, y), far);
            let truth = hit.map_or(PixelTruth::EMPTY, |hit| surface(&setup, &palette, &hit));
            (hit, truth)
        };
        // Probes at the pixel corners (shared between neighbours: about one more ray per
        // pixel) find the pixels whose area holds more than one surface or paint.
        let cw = w + 1;
        let corners: Vec<Probe> = (0..cw * (h + 1))
            .into_par_iter()
            .map(|i| {
                let (hit, truth) = look((i % cw) as f64 - 0.5, (i / cw) as f64 - 0.5);
                Probe::new(hit.as_ref(), &truth)
            })
            .collect();
        let built: Vec<BuiltPixel> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (hit, truth) = look(x as f64, y as f64);
                let centre = Probe::new(hit.as_ref(), &truth);
                let around = [y * cw + x, y * cw + x + 1, (y + 1) * cw + x, (y + 1) * cw + x + 1];
                if around.iter().all(|&c| corners[c].same(&centre)) {
                    return (hit, truth, None);
                }
                mixed_pixel(&setup, &palette, &cam, x, y, hit, truth, &corners, &around)
            })
            .collect();
        let footprint = |p: &SimProjector, x: f64, y: f64, hit: &geometry::Hit, half: f64| {
            sample(&setup.scene, &cam, p, x, y, hit, half)
        };
        let samples: Vec<Vec<Sample>> = setup
            .projectors
            .iter()
            .map(|p| {
                built
                    .par_iter()
                    .enumerate()
                    .map(|(i, (hit, _, _))| match hit {
                        Some(hit) => footprint(p, (i % w) as f64, (i / w) as f64, hit, 0.5),
                        None => Sample::default(),
                    })
                    .collect()
            })
            .collect();
        let mut sub = SubSamples::default();
        let mut sub_hits = Vec::new();
        for (i, (_, _, subs)) in built.iter().enumerate() {
            if let Some(subs) = subs {
                let start = sub.albedo.len();
                for (hit, truth, at) in subs {
                    sub.albedo.push(truth.albedo);
                    sub_hits.push((i, *hit, *at));
                }
                sub.pixels.push((i, start..sub.albedo.len()));
            }
        }
        let half = 0.5 / SUB_N as f64;
        sub.samples = setup
            .projectors
            .iter()
            .map(|p| {
                sub_hits
                    .par_iter()
                    .map(|(i, hit, at)| {
                        footprint(p, (i % w) as f64 + at[0], (i / w) as f64 + at[1], hit, half)
                    })
                    .collect()
            })
            .collect();
        let bounce = setup.plinth.as_ref().map(|plinth| {
            let object = (0..setup.scene.solids.len()).find(|&i| i != plinth.solid).unwrap_or(0);
            let transfer = bounce::Bounce::new(&setup.scene, object, plinth.radius, plinth.albedo as f64);
            let patches = setup
                .projectors
                .iter()
                .map(|p| {
                    transfer
                        .patches
                        .par_iter()
                        .map(|q| point_sample(&setup.scene, p, q, &transfer.up))
                        .collect()
                })
                .collect();
            let interp = |h: &geometry::Hit| transfer.interp(&setup.scene, h.solid, h.part, &h.point);
            let pixel = built.par_iter().map(|(h, _, _)| h.as_ref().and_then(interp)).collect();
            let sub = sub_hits.par_iter().map(|(_, h, _)| interp(h)).collect();
            BounceState { transfer, patches, pixel, sub }
        });
        let pixels = built.into_iter().map(|(_, truth, _)| truth).collect();
        let mut stage =
            Self { setup, config: None, palette, pixels, samples, sub, black_lux: vec![], bounce };
        stage.black_lux = (0..stage.setup.projectors.len())
            .map(|k| {
                let p = &stage.setup.projectors[k];
                let black = RgbImage::new(p.width, p.height);
                stage.projector_lux(k, &black)
            })
            .collect();
        stage
    }

    pub fn setup(&self) -> &Setup {
        &self.setup
    }

    pub fn config(&self) -> Option<&SceneConfig> {
        self.config.as_ref()
    }

    pub fn camera(&self) -> &CameraIntrinsics {
        &self.setup.camera
    }

    pub fn palette(&self) -> &Palette {
        &self.palette
    }

    pub fn pixels(&self) -> &[PixelTruth] {
        &self.pixels
    }

    pub fn projector_count(&self) -> usize {
        self.setup.projectors.len()
    }

    /// Checks one frame per projector, each at its projector's resolution.
    pub fn check_frames(&self, frames: &[RgbImage]) -> Result<(), StageSimError> {
        if frames.len() != self.projector_count() {
            return Err(StageSimError::FrameCount { count: frames.len(), expected: self.projector_count() });
        }
        for (k, (f, p)) in frames.iter().zip(&self.setup.projectors).enumerate() {
            if f.dimensions() != (p.width, p.height) {
                return Err(HwError::FrameSize {
                    projector: k,
                    got_w: f.width(),
                    got_h: f.height(),
                    want_w: p.width,
                    want_h: p.height,
                }
                .into());
            }
        }
        Ok(())
    }

    /// Irradiance in lux at each camera pixel's surface point from projector `k` showing
    /// `frame` (black level included).
    fn projector_lux(&self, k: usize, frame: &RgbImage) -> Lux {
        let p = &self.setup.projectors[k];
        let light = p.light(frame);
        let integ = Integrator::new(&light, p.width as usize, p.height as usize);
        let gather = |s: &Sample| {
            if s.g <= 0.0 {
                return [0.0; 3];
            }
            let m = integ.box_mean(s.u as f64, s.v as f64, s.hx as f64, s.hy as f64);
            m.map(|c| (c * s.g as f64) as f32)
        };
        let mut pixel: Vec<[f32; 3]> = self.samples[k].par_iter().map(gather).collect();
        let sub: Vec<[f32; 3]> = self.sub.samples[k].par_iter().map(gather).collect();
        self.sub_means(&mut pixel, &sub);
        let patch = self.bounce.as_ref().map_or_else(Vec::new, |b| {
            b.patches[k].iter().map(|s| point_light(&light, p, s).map(|v| v as f32)).collect()
        });
        Lux { pixel, sub, patch }
    }

    /// Sets each sub-sampled pixel to the mean of its sub-samples that hit a surface.
    fn sub_means(&self, pixel: &mut [[f32; 3]], sub: &[[f32; 3]]) {
        for (i, range) in &self.sub.pixels {
            if !range.is_empty() {
                let n = range.len() as f32;
                pixel[*i] =
                    sub[range.clone()].iter().fold([0.0; 3], |a, e| [0, 1, 2].map(|c| a[c] + e[c] / n));
            }
        }
    }

    /// What a lux meter reads (lux) held at camera pixel `pixel`'s surface point with its
    /// sensor facing projector `facing`, while projector `white` shows full white and every
    /// other projector black (`white = None`: all black), room stray light on, diffuse light
    /// off — the conservator's reading for `calibrate --lux-white`, with the true physics.
    /// Each projector is a point source: its light on the sensor is its irradiance on the
    /// surface there divided by the surface's cosine and multiplied by the sensor's; stray
    /// light reads the same in every direction. Photopic: Rec. 709 luminance of the channels.
    pub fn lux_meter(
        &self,
        pixel: [u32; 2],
        white: Option<usize>,
        facing: usize,
    ) -> Result<f64, StageSimError> {
        let cam = &self.setup.camera;
        let err = |problem: String| StageSimError::LuxMeter { pixel, problem };
        if pixel[0] >= cam.width || pixel[1] >= cam.height {
            return Err(err(format!("outside the {}x{} camera image", cam.width, cam.height)));
        }
        let n = self.projector_count();
        if facing >= n || white.is_some_and(|k| k >= n) {
            return Err(err(format!("no such projector (expected 0..{n})")));
        }
        let i = (pixel[1] * cam.width + pixel[0]) as usize;
        let px = &self.pixels[i];
        if !px.is_object() {
            return Err(err("not on the object".into()));
        }
        let x = V3::from(px.point.map(f64::from));
        let normal = V3::from(px.normal.map(f64::from));
        let dir = |k: usize| (self.setup.projectors[k].centre - x).normalize();
        let sensor = dir(facing);
        let mut reading = self.setup.stray_lux;
        for k in 0..n {
            let cos_surface = normal.dot(&dir(k));
            if self.samples[k][i].g <= 0.0 || cos_surface <= 0.0 {
                continue; // this projector does not light the point
            }
            let e = if white == Some(k) {
                let p = &self.setup.projectors[k];
                self.projector_lux(k, &RgbImage::from_pixel(p.width, p.height, image::Rgb([255; 3]))).pixel[i]
            } else {
                self.black_lux[k].pixel[i]
            };
            let y = crate::color::luminance(e.map(f64::from));
            reading += y / cos_surface * sensor.dot(&dir(k)).max(0.0);
        }
        Ok(reading)
    }

    /// The conservator's lux-meter session on this stage: the meter held at the surface point
    /// every projector lights nearest the camera's principal point, facing each projector in
    /// turn while it shows full white ([`lux_meter`](Self::lux_meter)). `None` when no point
    /// is lit by all projectors.
    pub fn lux_meter_session(&self) -> Result<Option<LuxMeterSession>, StageSimError> {
        let cam = &self.setup.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let lit_by_all = |i: usize| {
            let p = &self.pixels[i];
            p.is_object() && p.coverage >= 1.0 && self.samples.iter().all(|s| s[i].g > 0.0)
        };
        let d = |i: usize| ((i % w) as f64 - cam.cx).powi(2) + ((i / w) as f64 - cam.cy).powi(2);
        let Some(i) =
            (0..w * h).filter(|&i| lit_by_all(i)).min_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)))
        else {
            return Ok(None);
        };
        let pixel = [(i % w) as u32, (i / w) as u32];
        let readings = (0..self.projector_count())
            .map(|k| self.lux_meter(pixel, Some(k), k))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Some(LuxMeterSession { pixel, readings }))
    }

    /// Irradiance in lux per camera pixel from all projectors showing `frames` (their black
    /// level included, room light excluded). Zero where no object.
    /// At a pixel whose area spans a geometric edge it is the mean over the surface it sees.
    pub fn irradiance(&self, frames: &[RgbImage]) -> Result<Vec<[f32; 3]>, StageSimError> {
        Ok(self.total_lux(frames)?.pixel)
    }

    /// [`irradiance`](Self::irradiance) at every pixel and sub-sample.
    fn total_lux(&self, frames: &[RgbImage]) -> Result<Lux, StageSimError> {
        self.check_frames(frames)?;
        let mut total = Lux {
            pixel: vec![[0.0f32; 3]; self.pixels.len()],
            sub: vec![[0.0f32; 3]; self.sub.albedo.len()],
            patch: vec![[0.0f32; 3]; self.bounce.as_ref().map_or(0, |b| b.transfer.patches.len())],
        };
        let add = |t: &mut Vec<[f32; 3]>, l: &[[f32; 3]]| {
            t.par_iter_mut().zip(l.par_iter()).for_each(|(t, l)| {
                for c in 0..3 {
                    t[c] += l[c];
                }
            })
        };
        for (k, f) in frames.iter().enumerate() {
            let computed;
            let lux: &Lux = if f.as_raw().iter().all(|&v| v == 0) {
                &self.black_lux[k]
            } else {
                computed = self.projector_lux(k, f);
                &computed
            };
            add(&mut total.pixel, &lux.pixel);
            add(&mut total.sub, &lux.sub);
            add(&mut total.patch, &lux.patch);
        }
        if let Some(b) = &self.bounce {
            // One bounce: the plinth's direct light, reflected onto the object.
            let field = b.transfer.field(&total.patch);
            let bounce = |t: &mut [f32; 3], at: &Option<bounce::Interp>| {
                if let Some(at) = at {
                    let e = bounce::sample(&field, at);
                    (0..3).for_each(|c| t[c] += e[c]);
                }
            };
            total.pixel.par_iter_mut().zip(b.pixel.par_iter()).for_each(|(t, at)| bounce(t, at));
            total.sub.par_iter_mut().zip(b.sub.par_iter()).for_each(|(t, at)| bounce(t, at));
            let sub = std::mem::take(&mut total.sub);
            self.sub_means(&mut total.pixel, &sub);
            total.sub = sub;
        }
        Ok(total)
    }

    /// Point irradiance (lux per channel, room stray light included) at surface point `x` with
    /// outward normal `n` from every projector, each showing the light image in `lights`
    /// (from [`SimProjector::light`]), plus the plinth's bounce from `field`. Projector
    /// `lit_by` is known to reach `x` (its ray found it), so its visibility test is skipped.
    fn point_lux(
        &self,
        lights: &[Vec<[f32; 3]>],
        hit: &geometry::Hit,
        lit_by: Option<usize>,
        field: Option<&[[f32; 3]]>,
    ) -> [f64; 3] {
        let (x, n) = (&hit.point, &hit.normal);
        let stray = self.setup.stray_lux;
        let mut e = [stray; 3];
        if let (Some(b), Some(field)) = (&self.bounce, field)
            && let Some(at) = b.transfer.interp(&self.setup.scene, hit.solid, hit.part, x)
        {
            let v = bounce::sample(field, &at);
            (0..3).for_each(|c| e[c] += v[c] as f64);
        }
        for (k, (p, light)) in self.setup.projectors.iter().zip(lights).enumerate() {
            let to = p.centre - x;
            let d = to.norm();
            let cos = n.dot(&to) / d;
            if cos <= 0.0 {
                continue;
            }
            let Some(uv) = p.project(x) else { continue };
            if !p.on_image(uv) || (lit_by != Some(k) && !self.setup.scene.visible(x, n, &p.centre)) {
                continue;
            }
            let l = optics::bilinear(light, p.width as usize, p.height as usize, uv[0], uv[1]);
            let g = p.lux_at_1m * cos / (d / 1000.0).powi(2);
            for c in 0..3 {
                e[c] += l[c] * g;
            }
        }
        e
    }

    /// The true peak irradiance over the whole lit object surface with `frames` shown,
    /// independent of the camera: every projector's pixels are cast into the scene at their
    /// centre and at 2x2 sub-pixel positions around it; at each first hit on the object the point irradiance from all
    /// projectors (visibility, cosine, inverse square, the blurred light image sampled
    /// bilinearly) plus the room's stray light is summed; the peak is the largest channel of
    /// the largest sample (the scalar of [`crate::compensate::guarantee::bound_lux`]); the
    /// plinth's interreflection is included where there is one, the plinth itself is not
    /// the object and is not counted.
    /// Surface the camera cannot see (the far side, grazing silhouettes) counts as much as
    /// surface it can. Deterministic: ties go to the lowest projector, row, column, sub-pixel.
    pub fn surface_peak(&self, frames: &[RgbImage]) -> Result<SurfacePeak, StageSimError> {
        self.check_frames(frames)?;
        let lights: Vec<Vec<[f32; 3]>> =
            self.setup.projectors.iter().zip(frames).map(|(p, f)| p.light(f)).collect();
        let field = self.bounce.as_ref().map(|b| {
            let patch: Vec<[f32; 3]> = (0..b.transfer.patches.len())
                .map(|i| {
                    let mut e = [0.0f32; 3];
                    for (k, p) in self.setup.projectors.iter().enumerate() {
                        let l = point_light(&lights[k], p, &b.patches[k][i]);
                        (0..3).for_each(|c| e[c] += l[c] as f32);
                    }
                    e
                })
                .collect();
            b.transfer.field(&patch)
        });
        let (centre, radius) = self.setup.scene.bounding_sphere();
        // The centre too: a bilinear light image peaks at pixel centres, and a bright pixel
        // among darker ones sampled only a quarter pixel off read up to 25 % of the contrast
        // low (the peak at camera pixels then came out above the "whole surface" one).
        const SUB: [[f64; 2]; 5] = [[0.0, 0.0], [-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]];
        let mut best: Option<SurfacePeak> = None;
        let mut count = 0usize;
        for (j, p) in self.setup.projectors.iter().enumerate() {
            let (w, h) = (p.width as usize, p.height as usize);
            let oc = centre - p.centre;
            let (row_best, n) = (0..h)
                .into_par_iter()
                .map(|y| {
                    let mut best: Option<SurfacePeak> = None;
                    let mut n = 0usize;
                    for x in 0..w {
                        for o in SUB {
                            let uv = [x as f64 + o[0], y as f64 + o[1]];
                            let dir = p.ray(uv[0], uv[1]);
                            // Rays that miss the bounding sphere cannot hit the object.
                            let along = oc.dot(&dir);
                            if (oc - dir * along).norm_squared() > radius * radius {
                                continue;
                            }
                            let Some(hit) = self.setup.scene.cast(&p.centre, &dir, along + radius + 1.0)
                            else {
                                continue;
                            };
                            if !self.is_object_solid(hit.solid) {
                                continue;
                            }
                            n += 1;
                            let rgb = self.point_lux(&lights, &hit, Some(j), field.as_deref());
                            let lux = rgb[0].max(rgb[1]).max(rgb[2]);
                            if best.as_ref().is_none_or(|b| lux > b.lux) {
                                best = Some(SurfacePeak {
                                    lux,
                                    rgb,
                                    point_mm: hit.point.into(),
                                    normal: hit.normal.into(),
                                    projector: j,
                                    projector_px: uv,
                                    samples: 0,
                                });
                            }
                        }
                    }
                    (best, n)
                })
                // Rows are reduced in order and ties keep the earlier one: deterministic.
                .reduce(|| (None, 0), |a, b| (SurfacePeak::better(a.0, b.0), a.1 + b.1));
            best = SurfacePeak::better(best, row_best);
            count += n;
        }
        let stray = self.setup.stray_lux;
        Ok(match best {
            Some(b) => SurfacePeak { samples: count, ..b },
            None => SurfacePeak {
                lux: stray,
                rgb: [stray; 3],
                point_mm: [f64::NAN; 3],
                normal: [f64::NAN; 3],
                projector: 0,
                projector_px: [f64::NAN; 2],
                samples: 0,
            },
        })
    }

    /// Whether solid `i` of the scene is part of the object (and not its support).
    fn is_object_solid(&self, i: usize) -> bool {
        self.setup.plinth.as_ref().is_none_or(|p| p.solid != i)
    }

    /// The noise-free camera image with `frames` shown and the room's diffuse light on or off:
    /// `gain_per_lux * albedo * (projector irradiance + room light)`, clipped at full scale.
    /// A pixel integrates over its area: where that spans a geometric edge, each sub-sample
    /// adds its own albedo times its own irradiance (sub-samples that see nothing add 0).
    pub fn render(&self, frames: &[RgbImage], diffuse: bool) -> Result<LinearImage, StageSimError> {
        let mut img = self.render_unclipped(frames, diffuse)?;
        img.data.iter_mut().for_each(|p| *p = p.map(|c| c.min(1.0)));
        Ok(img)
    }

    /// [`render`](Self::render) without the clip at full scale: the light an exposure of any
    /// length integrates (exposure brackets scale it, then saturate).
    pub fn render_unclipped(&self, frames: &[RgbImage], diffuse: bool) -> Result<LinearImage, StageSimError> {
        let e = self.total_lux(frames)?;
        let room = self.setup.stray_lux + if diffuse { self.setup.diffuse_lux } else { 0.0 };
        let k = self.setup.camera_spec.gain_per_lux;
        let cam = &self.setup.camera;
        let mut data: Vec<[f32; 3]> = self
            .pixels
            .par_iter()
            .zip(e.pixel.par_iter())
            .map(|(p, e)| [0, 1, 2].map(|c| (k * p.albedo[c] as f64 * (e[c] as f64 + room)) as f32))
            .collect();
        for (i, range) in &self.sub.pixels {
            let mut v = [0.0f64; 3];
            for s in range.clone() {
                for (c, v) in v.iter_mut().enumerate() {
                    *v += self.sub.albedo[s][c] as f64 * (e.sub[s][c] as f64 + room);
                }
            }
            data[*i] = v.map(|v| (k * v / SUB_COUNT as f64) as f32);
        }
        Ok(LinearImage { width: cam.width, height: cam.height, data })
    }

    /// A camera exposure: [`render`](Self::render) plus seeded noise for shot number `shot`
    /// (the same shot number always gives the same noise, whatever the thread count).
    pub fn capture(
        &self,
        frames: &[RgbImage],
        diffuse: bool,
        shot: u64,
    ) -> Result<LinearImage, StageSimError> {
        let mut img = self.render(frames, diffuse)?;
        let spec = &self.setup.camera_spec;
        let seed = mix(self.setup.seed, shot);
        let w = img.width as usize;
        img.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let mut rng = ChaCha8Rng::seed_from_u64(mix(seed, y as u64));
            for px in row {
                for c in px.iter_mut() {
                    let sd = (spec.read_noise.powi(2) + spec.shot_noise * (*c as f64).max(0.0)).sqrt();
                    *c = (*c as f64 + sd * normal(&mut rng)).clamp(0.0, 1.0) as f32;
                }
            }
        });
        Ok(img)
    }

    /// Exposure brackets through the camera's 8-bit output (`CameraSpec::codes`), one per
    /// exposure time in seconds, each with its own noise (from `shot` on).
    pub fn brackets(
        &self,
        frames: &[RgbImage],
        diffuse: bool,
        exposures_s: &[f64],
        shot: u64,
    ) -> Result<Vec<Bracket>, StageSimError> {
        let Some(cam) = &self.setup.camera_spec.codes else {
            return Err(StageSimError::NoCodeCamera);
        };
        let linear = self.render_unclipped(frames, diffuse)?;
        Ok(exposures_s
            .iter()
            .enumerate()
            .map(|(j, &t)| cam.expose(&linear, t, mix(self.setup.seed, shot + j as u64)))
            .collect())
    }

    /// Black frames for every projector.
    pub fn black_frames(&self) -> Vec<RgbImage> {
        self.setup.projectors.iter().map(|p| RgbImage::new(p.width, p.height)).collect()
    }

    /// The true stage model (what a perfect calibration would find).
    pub fn truth(&self) -> StageModel {
        let k = self.setup.camera_spec.gain_per_lux as f32;
        let ambient = self.render(&self.black_frames(), false).expect("black frames fit").data;
        StageModel {
            camera: self.setup.camera.clone(),
            projectors: self.setup.projectors.iter().map(|p| p.model()).collect(),
            points: self.pixels.iter().map(|p| p.point).collect(),
            normals: self.pixels.iter().map(|p| p.normal).collect(),
            correspondences: self
                .samples
                .iter()
                .map(|s| s.iter().map(|s| if s.g > 0.0 { [s.u, s.v] } else { [f32::NAN; 2] }).collect())
                .collect(),
            transport: vec![Transport::default(); self.projector_count()],
            gain: self.pixels.iter().map(|p| p.albedo.map(|a| a * k)).collect(),
            ambient,
            provenance: format!("ground truth of {}", self.setup.label),
        }
    }

    /// The light transport a perfect dot measurement would find, per projector: for every
    /// camera pixel that projector lights, each projector pixel's share of its light — the
    /// lens's Gaussian blur followed by the camera pixel's box over its footprint, as
    /// [`Self::render`] gathers light (at the pixel's centre sample; the sub-samples of pixels
    /// on an edge are not followed). Shares below 1e-4 are dropped, the rest sum to 1.
    pub fn true_transport(&self) -> Vec<Transport> {
        (0..self.projector_count()).map(|k| self.true_footprints(k)).collect()
    }

    fn true_footprints(&self, k: usize) -> Transport {
        let p = &self.setup.projectors[k];
        let (w, h) = (p.width as usize, p.height as usize);
        let sigma = p.blur_px;
        // The blur's kernel as `optics::gaussian_blur` applies it.
        let (r, kernel): (i64, Vec<f64>) = if sigma <= 0.05 {
            (0, vec![1.0])
        } else {
            let r = (3.0 * sigma).ceil() as i64;
            let k: Vec<f64> = (-r..=r).map(|i| (-(i as f64).powi(2) / (2.0 * sigma * sigma)).exp()).collect();
            let sum: f64 = k.iter().sum();
            (r, k.iter().map(|v| v / sum).collect())
        };
        // Along one axis: per source pixel, its share of the box [c - half, c + half] after
        // the blur (cells are pixel-sized, centred on integers, as the integrator reads them).
        let axis = |c: f64, half: f64, n: usize| -> Vec<(usize, f64)> {
            let (lo, hi) = (c - half.max(1e-3), c + half.max(1e-3));
            let mut out: Vec<(usize, f64)> = Vec::new();
            for cell in (lo + 0.5).floor() as i64..=(hi + 0.5).floor() as i64 {
                let overlap = (hi.min(cell as f64 + 0.5) - lo.max(cell as f64 - 0.5)).max(0.0) / (hi - lo);
                if overlap <= 0.0 || cell < 0 || cell >= n as i64 {
                    continue;
                }
                for (j, kv) in kernel.iter().enumerate() {
                    let src = cell + r - j as i64;
                    if src < 0 || src >= n as i64 {
                        continue;
                    }
                    match out.iter_mut().find(|e| e.0 == src as usize) {
                        Some(e) => e.1 += overlap * kv,
                        None => out.push((src as usize, overlap * kv)),
                    }
                }
            }
            out
        };
        let per_pixel: Vec<Vec<(u32, f32)>> = self.samples[k]
            .par_iter()
            .map(|s| {
                if s.g <= 0.0 {
                    return Vec::new();
                }
                let (xs, ys) = (axis(s.u as f64, s.hx as f64, w), axis(s.v as f64, s.hy as f64, h));
                let mut e: Vec<(u32, f32)> = Vec::new();
                for &(y, wy) in &ys {
                    for &(x, wx) in &xs {
                        e.push(((y * w + x) as u32, (wx * wy) as f32));
                    }
                }
                let sum: f32 = e.iter().map(|v| v.1).sum();
                e.retain(|v| v.1 >= 1e-4 * sum);
                let sum: f32 = e.iter().map(|v| v.1).sum();
                e.iter_mut().for_each(|v| v.1 /= sum);
                e
            })
            .collect();
        let mut row_start = vec![0u32; w * h + 1];
        for e in per_pixel.iter().flatten() {
            row_start[e.0 as usize + 1] += 1;
        }
        for q in 0..w * h {
            row_start[q + 1] += row_start[q];
        }
        let total = row_start[w * h] as usize;
        let (mut camera_pixel, mut weight) = (vec![0u32; total], vec![0f32; total]);
        let mut next = row_start.clone();
        for (i, entries) in per_pixel.iter().enumerate() {
            for &(q, wt) in entries {
                let at = next[q as usize] as usize;
                (camera_pixel[at], weight[at]) = (i as u32, wt);
                next[q as usize] += 1;
            }
        }
        Transport { row_start, camera_pixel, weight }
    }

    /// Writes the ground-truth folder (`dir/ground-truth/`): see ARCHITECTURE.md.
    pub fn write_ground_truth(&self, dir: &Path) -> Result<(), StageSimError> {
        truth::write(self, &dir.join(GROUND_TRUTH_DIR))
    }

    /// Writes a whole capture set into `dir` (created if needed): ground truth first, then
    /// the acquisition loop over this stage's simulated hardware. `progress(done, total)`.
    pub fn write_capture_set(
        &self,
        dir: &Path,
        cfg: &AcquireConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<CaptureManifest, StageSimError> {
        std::fs::create_dir_all(dir).map_err(|source| StageSimError::Io { path: dir.into(), source })?;
        self.write_ground_truth(dir)?;
        let mut rig = SimRig::new(self);
        let mut clock = crate::hw::FakeClock::default();
        Ok(acquire::acquire(&mut rig, &mut clock, cfg, dir, &self.setup.label, progress)?)
    }
}

/// The virtual stage as hardware: projectors that hold frames, a camera that captures them.
#[derive(Debug)]
pub struct SimRig<'a> {
    stage: &'a VirtualStage,
    frames: Vec<RgbImage>,
    diffuse: bool,
    shots: u64,
}

impl<'a> SimRig<'a> {
    pub fn new(stage: &'a VirtualStage) -> Self {
        Self { stage, frames: stage.black_frames(), diffuse: false, shots: 0 }
    }
}

impl Camera for SimRig<'_> {
    fn intrinsics(&self) -> CameraIntrinsics {
        self.stage.setup.camera.clone()
    }

    fn grab(&mut self) -> Result<LinearImage, HwError> {
        let img = self
            .stage
            .capture(&self.frames, self.diffuse, self.shots)
            .map_err(|e| HwError::Device { device: "virtual camera".into(), problem: e.to_string() })?;
        self.shots += 1;
        Ok(img)
    }
}

impl ProjectorOutput for SimRig<'_> {
    fn projector_count(&self) -> usize {
        self.frames.len()
    }

    fn resolution(&self, projector: usize) -> Result<(u32, u32), HwError> {
        let p = self
            .stage
            .setup
            .projectors
            .get(projector)
            .ok_or(HwError::NoSuchProjector { projector, count: self.frames.len() })?;
        Ok((p.width, p.height))
    }

    fn show(&mut self, projector: usize, frame: &RgbImage) -> Result<(), HwError> {
        let (w, h) = self.resolution(projector)?;
        if frame.dimensions() != (w, h) {
            return Err(HwError::FrameSize {
                projector,
                got_w: frame.width(),
                got_h: frame.height(),
                want_w: w,
                want_h: h,
            });
        }
        self.frames[projector].clone_from(frame);
        Ok(())
    }
}

impl DiffuseLight for SimRig<'_> {
    fn set_diffuse(&mut self, on: bool) -> Result<(), HwError> {
        self.diffuse = on;
        Ok(())
    }
}

/// Unit ray through camera pixel `(x, y)`.
pub fn ray(cam: &CameraIntrinsics, x: f64, y: f64) -> V3 {
    V3::new((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0).normalize()
}

fn surface(setup: &Setup, palette: &Palette, hit: &geometry::Hit) -> PixelTruth {
    let f = |v: V3| [v.x as f32, v.y as f32, v.z as f32];
    if let Some(plinth) = setup.plinth.as_ref().filter(|p| p.solid == hit.solid) {
        return PixelTruth {
            point: f(hit.point),
            normal: f(hit.normal),
            albedo: [plinth.albedo; 3],
            albedo_pristine: [plinth.albedo; 3],
            seen: Seen::Plinth,
            ..PixelTruth::EMPTY
        };
    }
    let solid = &setup.scene.solids[hit.solid];
    let (mut h, _, mut theta) = solid.local(&hit.point);
    let mut r = solid.radius_at(h);
    let pristine = match (hit.part, setup.design) {
        // A panel is painted on its face, unrolled onto a cylinder (see `PANEL_UNROLL_MM`).
        (Part::Top, Design::Panel) => {
            let d = hit.point - solid.base;
            (theta, h, r) =
                (d.dot(&solid.e1) / PANEL_UNROLL_MM, d.dot(&solid.e2) + PANEL_RADIUS_MM, PANEL_UNROLL_MM);
            setup.design.class_at(theta, h, r)
        }
        (Part::Side, Design::Panel) => palette.clay,
        (Part::Side, _) => setup.design.class_at(theta, h, r),
        // The caps are unpainted clay (the camera rarely sees them).
        (Part::Bottom | Part::Top, _) => palette.clay,
    };
    let (albedo, label, wear) = setup.deterioration.apply(palette, pristine, theta, h, r);
    let albedo_pristine = palette.classes[pristine as usize].albedo;
    PixelTruth {
        point: f(hit.point),
        normal: f(hit.normal),
        albedo,
        albedo_pristine,
        label,
        label_pristine: pristine,
        chipped: wear.chipped,
        cracked: wear.cracked,
        stain: wear.stain as f32,
        fade: wear.fade as f32,
        coverage: 1.0,
        mixed: false,
        seen: Seen::Object,
    }
}

/// Sub-samples camera pixel `(x, y)`, whose probes disagree, on a `SUB_N x SUB_N` grid
/// and sums up its truth (see [`PixelTruth::mixed`]). Sub-samples that share the centre's
/// geometry with all corner probes are taken on the centre hit's tangent plane (no ray
/// cast: only the paint differs); otherwise every sub-sample is cast and kept, for
/// per-sub-sample lighting.
#[allow(clippy::too_many_arguments)]
fn mixed_pixel(
    setup: &Setup,
    palette: &Palette,
    cam: &CameraIntrinsics,
    x: usize,
    y: usize,
    hit: Option<geometry::Hit>,
    truth: PixelTruth,
    corners: &[Probe],
    around: &[usize; 4],
) -> BuiltPixel {
    let centre = Probe::new(hit.as_ref(), &truth);
    let flat = around.iter().all(|&c| corners[c].same_geometry(&centre));
    let offset = |j: usize| (j as f64 + 0.5) / SUB_N as f64 - 0.5;
    let subs: Vec<(Option<geometry::Hit>, PixelTruth, [f64; 2])> = (0..SUB_COUNT)
        .map(|j| {
            let at = [offset(j % SUB_N), offset(j / SUB_N)];
            let r = ray(cam, x as f64 + at[0], y as f64 + at[1]);
            let h = match (&hit, flat) {
                (Some(c), true) => {
                    // The sub-ray on the centre hit's tangent plane: the same surface, and
                    // within microns of it at a pixel's scale.
                    let den = c.normal.dot(&r);
                    (den.abs() > 1e-9).then(|| {
                        let t = c.normal.dot(&c.point) / den;
                        geometry::Hit { t, point: r * t, ..*c }
                    })
                }
                (None, true) => None,
                (_, false) => setup.scene.cast(&V3::zeros(), &r, 1.0e5),
            };
            let tr = h.map_or(PixelTruth::EMPTY, |h| surface(setup, palette, &h));
            (h, tr, at)
        })
        .collect();
    let n = SUB_COUNT as f32;
    let object: Vec<&PixelTruth> = subs.iter().map(|s| &s.1).filter(|t| t.is_object()).collect();
    let mean = |f: &dyn Fn(&PixelTruth) -> [f32; 3]| {
        subs.iter().fold([0.0f32; 3], |a, s| {
            let v = f(&s.1);
            [0, 1, 2].map(|c| a[c] + v[c] / n)
        })
    };
    // The most frequent value among the object's sub-samples; ties go to the lowest.
    let majority = |f: &dyn Fn(&PixelTruth) -> u8| {
        let mut count = [0u16; 256];
        object.iter().for_each(|t| count[f(t) as usize] += 1);
        (0..=255u8).rev().max_by_key(|&v| count[v as usize]).unwrap_or(255)
    };
    let m = object.len() as f32;
    let on_object = object.len() * 2 >= SUB_COUNT;
    let share = |f: &dyn Fn(&PixelTruth) -> bool| object.iter().filter(|t| f(t)).count() * 2 > object.len();
    let avg = |f: &dyn Fn(&PixelTruth) -> f32| object.iter().map(|t| f(t)).sum::<f32>() / m.max(1.0);
    let summed = PixelTruth {
        point: truth.point,
        normal: truth.normal,
        albedo: mean(&|t| t.albedo),
        albedo_pristine: mean(&|t| t.albedo_pristine),
        label: if on_object { majority(&|t| t.label) } else { 255 },
        label_pristine: if on_object { majority(&|t| t.label_pristine) } else { 255 },
        chipped: on_object && share(&|t| t.chipped),
        cracked: on_object && share(&|t| t.cracked),
        stain: avg(&|t| t.stain),
        fade: avg(&|t| t.fade),
        coverage: m / n,
        mixed: true,
        seen: {
            let count = |k: Seen| subs.iter().filter(|s| s.1.seen == k).count();
            let (plinth, nothing) = (count(Seen::Plinth), count(Seen::Nothing));
            if on_object {
                Seen::Object
            } else if plinth > 0 && plinth >= nothing {
                Seen::Plinth
            } else {
                Seen::Nothing
            }
        },
    };
    let kept = (!flat).then(|| subs.iter().filter_map(|(h, t, at)| h.map(|h| (h, *t, *at))).collect());
    (hit, summed, kept)
}

/// Where the footprint of the camera pixel (or sub-pixel, of half-width `half` pixels)
/// centred at `(x, y)` lands on projector `p` and how strongly it is lit.
fn sample(
    scene: &Scene,
    cam: &CameraIntrinsics,
    p: &SimProjector,
    x: f64,
    y: f64,
    hit: &geometry::Hit,
    half: f64,
) -> Sample {
    let Some(uv) = p.project(&hit.point) else { return Sample::default() };
    if !p.on_image(uv) {
        return Sample::default();
    }
    let to = p.centre - hit.point;
    let d = to.norm();
    let cos = hit.normal.dot(&(to / d));
    if cos <= 0.0 || !scene.visible(&hit.point, &hit.normal, &p.centre) {
        return Sample::default();
    }
    // The pixel's footprint: project its edges, moved on the tangent plane, to the projector.
    let n = hit.normal;
    let np = n.dot(&hit.point);
    let on_plane = |xx: f64, yy: f64| {
        let r = ray(cam, xx, yy);
        let den = n.dot(&r);
        (den.abs() > 1e-9).then(|| r * (np / den)).and_then(|q| p.project(&q))
    };
    let (hx, hy) =
        match (on_plane(x + half, y), on_plane(x - half, y), on_plane(x, y + half), on_plane(x, y - half)) {
            (Some(a1), Some(a0), Some(b1), Some(b0)) => {
                let (ax, ay) = (a1[0] - a0[0], a1[1] - a0[1]);
                let (bx, by) = (b1[0] - b0[0], b1[1] - b0[1]);
                (0.5 * (ax.abs() + bx.abs()), 0.5 * (ay.abs() + by.abs()))
            }
            _ => (2.0 * half, 2.0 * half),
        };
    Sample {
        u: uv[0] as f32,
        v: uv[1] as f32,
        hx: hx.clamp(0.05 * 2.0 * half, 64.0) as f32,
        hy: hy.clamp(0.05 * 2.0 * half, 64.0) as f32,
        g: (p.lux_at_1m * cos / (d / 1000.0).powi(2)) as f32,
    }
}

/// How projector `p` lights the point `x` (outward normal `n`): its image position and
/// `lux_at_1m * cos / d^2`, with `g` 0 where it cannot (behind, off the image, shadowed).
fn point_sample(scene: &Scene, p: &SimProjector, x: &V3, n: &V3) -> Sample {
    let to = p.centre - x;
    let d = to.norm();
    let cos = n.dot(&to) / d;
    let Some(uv) = p.project(x) else { return Sample::default() };
    if cos <= 0.0 || !p.on_image(uv) || !scene.visible(x, n, &p.centre) {
        return Sample::default();
    }
    let g = (p.lux_at_1m * cos / (d / 1000.0).powi(2)) as f32;
    Sample { u: uv[0] as f32, v: uv[1] as f32, hx: 0.0, hy: 0.0, g }
}

/// Point irradiance (lux per channel) of a [`point_sample`] from projector `p`'s light image.
fn point_light(light: &[[f32; 3]], p: &SimProjector, s: &Sample) -> [f64; 3] {
    if s.g <= 0.0 {
        return [0.0; 3];
    }
    let l = optics::bilinear(light, p.width as usize, p.height as usize, s.u as f64, s.v as f64);
    l.map(|c| c * s.g as f64)
}

/// Mixes a seed and a counter into a new seed (SplitMix64 finaliser).
pub(crate) fn mix(seed: u64, n: u64) -> u64 {
    let mut z = seed ^ n.wrapping_add(0x9E37_79B9_7F4A_7C15).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A standard normal sample (Box-Muller; one of the pair is enough here).
pub(crate) fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.r#gen::<f64>().max(1e-300);
    let u2: f64 = rng.r#gen();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests;
