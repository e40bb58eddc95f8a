//! The interactive tool's document: everything the conservator edits (colour picks, regions,
//! hint strokes, every step's parameters, the virtual lighting), its undo/redo history, and
//! which steps an edit makes stale. Pure state: no window, no files, no threads.

use restage_authoring::classify::{PickColour, Picks, picks::PICKS_VERSION};
use restage_authoring::relight::{Light, Lighting};
use restage_authoring::segment::Outline;
use serde::{Deserialize, Serialize};

/// No hint at this pixel (the same value the label maps use for "not object").
pub const NO_HINT: u8 = 255;

/// The steps the tool runs, in an order where every step comes after its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Step {
    Classify,
    Restore,
    Relight,
    /// Compensation of the photo as found (the bundle's "original" scene).
    CompOriginal,
    CompRestored,
    CompRelit,
}

impl Step {
    pub const ALL: [Step; 6] = [
        Step::Classify,
        Step::Restore,
        Step::Relight,
        Step::CompOriginal,
        Step::CompRestored,
        Step::CompRelit,
    ];

    /// The steps whose outputs this step reads.
    pub fn inputs(self) -> &'static [Step] {
        match self {
            Step::Classify | Step::CompOriginal => &[],
            Step::Restore => &[Step::Classify],
            Step::Relight | Step::CompRestored => &[Step::Restore],
            Step::CompRelit => &[Step::Relight],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Step::Classify => "classify",
            Step::Restore => "restore",
            Step::Relight => "relight",
            Step::CompOriginal => "compensate original",
            Step::CompRestored => "compensate restored",
            Step::CompRelit => "compensate relit",
        }
    }

    /// The bundle scene a compensation step makes, if it is one.
    pub fn scene(self) -> Option<Scene> {
        match self {
            Step::CompOriginal => Some(Scene::Original),
            Step::CompRestored => Some(Scene::Restored),
            Step::CompRelit => Some(Scene::Relit),
            _ => None,
        }
    }

    fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// The scenes a project can put into a bundle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum Scene {
    Original,
    Restored,
    Relit,
}

impl Scene {
    pub const ALL: [Scene; 3] = [Scene::Original, Scene::Restored, Scene::Relit];

    pub fn id(self) -> &'static str {
        match self {
            Scene::Original => "original",
            Scene::Restored => "restored",
            Scene::Relit => "relit",
        }
    }

    /// The name visitors' staff see, and the bundle's scene kind.
    pub fn title(self) -> &'static str {
        match self {
            Scene::Original => "As found",
            Scene::Restored => "Restored",
            Scene::Relit => "Restored, relit",
        }
    }

    pub fn kind(self) -> &'static str {
        match self {
            Scene::Original => "original",
            Scene::Restored => "restoration",
            Scene::Relit => "relit",
        }
    }
}

/// A set of steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Steps(u8);

impl Steps {
    pub const NONE: Steps = Steps(0);

    pub fn contains(self, s: Step) -> bool {
        self.0 & s.bit() != 0
    }

    pub fn insert(&mut self, s: Step) {
        self.0 |= s.bit();
    }

    pub fn remove(&mut self, s: Step) {
        self.0 &= !s.bit();
    }

    pub fn union(self, o: Steps) -> Steps {
        Steps(self.0 | o.0)
    }

    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The steps in run order.
    pub fn iter(self) -> impl Iterator<Item = Step> {
        Step::ALL.into_iter().filter(move |s| self.contains(*s))
    }

    pub fn len(self) -> usize {
        self.0.count_ones() as usize
    }

    /// These steps and every step that reads, directly or not, what they make.
    pub fn with_dependents(self) -> Steps {
        let mut out = self;
        // ALL is in dependency order, so one pass reaches the fixed point.
        for s in Step::ALL {
            if s.inputs().iter().any(|i| out.contains(*i)) {
                out.insert(s);
            }
        }
        out
    }
}

impl FromIterator<Step> for Steps {
    fn from_iter<I: IntoIterator<Item = Step>>(iter: I) -> Self {
        let mut s = Steps::NONE;
        iter.into_iter().for_each(|x| s.insert(x));
        s
    }
}

/// A restoration region as the tool edits it; written as the CLI's `--region` text.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum RegionSpec {
    Rect { x: u32, y: u32, width: u32, height: u32, background: Option<u8> },
    Polygon { points: Vec<[f64; 2]>, background: Option<u8> },
}

impl RegionSpec {
    /// The CLI's `--region` argument for this region.
    pub fn to_cli(&self) -> String {
        let (body, bg) = match self {
            RegionSpec::Rect { x, y, width, height, background } => {
                (format!("rect:{x},{y},{width},{height}"), background)
            }
            RegionSpec::Polygon { points, background } => {
                let v: Vec<String> =
                    points.iter().flat_map(|p| [p[0].to_string(), p[1].to_string()]).collect();
                (format!("poly:{}", v.join(",")), background)
            }
        };
        match bg {
            Some(k) => format!("{body}@{k}"),
            None => body,
        }
    }

    pub fn background_mut(&mut self) -> &mut Option<u8> {
        match self {
            RegionSpec::Rect { background, .. } | RegionSpec::Polygon { background, .. } => background,
        }
    }
}

/// `[classify]` of `project.toml`: the options of `restage-author classify`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClassifySettings {
    pub max_iterations: u32,
    pub prior_picks: f64,
}

impl Default for ClassifySettings {
    fn default() -> Self {
        let o = restage_authoring::classify::ClassifyOptions::default();
        Self { max_iterations: o.max_iterations, prior_picks: o.prior_picks }
    }
}

/// `[restore]`: the options of `restage-author restore`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RestoreSettings {
    pub alpha: f64,
    pub beta: f64,
    pub gamma: Option<f64>,
    pub neighbours: usize,
    pub scale: f64,
    /// Classes standing for loss (bare clay).
    pub loss: Vec<u8>,
    /// `auto` or `GxH`.
    pub grid: String,
    pub background: Option<u8>,
    pub regions: Vec<RegionSpec>,
}

impl Default for RestoreSettings {
    fn default() -> Self {
        let d = restage_authoring::restore::RestoreParams::default();
        Self {
            alpha: d.alpha,
            beta: d.beta,
            gamma: d.gamma,
            neighbours: d.neighbours,
            scale: d.scale_px,
            loss: Vec::new(),
            grid: "auto".into(),
            background: None,
            regions: Vec::new(),
        }
    }
}

/// `[relight]`: whether the project has a relit scene, and its noise infusion. The lighting
/// itself is `relight/lighting.toml`, the CLI's `--lighting` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelightSettings {
    pub enabled: bool,
    pub noise: f64,
    pub noise_radius: usize,
}

impl Default for RelightSettings {
    fn default() -> Self {
        Self { enabled: true, noise: 0.3, noise_radius: 3 }
    }
}

/// `[compensate]`: the options of `restage-author compensate`, shared by every scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CompensateSettings {
    pub e_bound_lux: f64,
    /// `m` of Eq. 12; `None` = infinity.
    pub m: Option<f64>,
    pub margin: f64,
    pub clip_fraction: f64,
    /// `--auto-clip`: the stage model always chooses the clip fraction (unset: only where the
    /// black level lifts the view, `compensate`'s default).
    pub auto_clip: bool,
    pub reduction: u32,
    /// `auto`, `cpu` or `gpu`.
    pub device: String,
}

impl Default for CompensateSettings {
    fn default() -> Self {
        Self {
            e_bound_lux: 150.0,
            m: Some(8.0),
            margin: 0.05,
            clip_fraction: restage_authoring::compensate::DEFAULT_CLIP_FRACTION,
            auto_clip: false,
            reduction: 2,
            device: "auto".into(),
        }
    }
}

/// `[export]`: what goes into the signed bundle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExportSettings {
    pub object_id: String,
    pub object_name: String,
    pub version: u64,
    pub valid_days: u32,
    pub scenes: Vec<Scene>,
    /// Signing key (PKCS#8 PEM), relative to the project or absolute.
    pub key: String,
    /// Trusted public keys to verify against (the appliance's trust directory).
    pub trust: String,
    /// CIE 157 sensitivity class of the object (`high`, `medium`, `low`) and overrides.
    pub policy_class: String,
    pub max_showing_s: Option<u32>,
    pub cooldown_s: Option<u32>,
    pub daily_budget_lxh: Option<f64>,
    pub annual_budget_lxh: Option<f64>,
    pub out: String,
}

impl Default for ExportSettings {
    fn default() -> Self {
        Self {
            object_id: "object".into(),
            object_name: "object".into(),
            version: 1,
            valid_days: 365,
            scenes: Scene::ALL.to_vec(),
            key: String::new(),
            trust: String::new(),
            policy_class: "high".into(),
            max_showing_s: None,
            cooldown_s: None,
            daily_budget_lxh: None,
            annual_budget_lxh: None,
            out: "bundle.restage".into(),
        }
    }
}

/// Every parameter of `project.toml`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Settings {
    pub classify: ClassifySettings,
    pub restore: RestoreSettings,
    pub relight: RelightSettings,
    pub compensate: CompensateSettings,
    pub export: ExportSettings,
}

/// The small, snapshot-able part of the document (undo keeps whole copies of it).
#[derive(Clone, Debug, PartialEq)]
pub struct Small {
    pub settings: Settings,
    pub picks: Picks,
    pub lighting: Lighting,
    /// The conservator's object outline (empty: the mask step's automatic proposal, or the
    /// project's own mask).
    pub outline: Outline,
}

/// Hint strokes: one class per pixel or [`NO_HINT`], the label map's size.
#[derive(Clone, Debug, PartialEq)]
pub struct HintLayer {
    pub width: u32,
    pub height: u32,
    pub labels: Vec<u8>,
}

impl HintLayer {
    pub fn empty(width: u32, height: u32) -> Self {
        Self { width, height, labels: vec![NO_HINT; width as usize * height as usize] }
    }

    pub fn is_empty(&self) -> bool {
        self.labels.iter().all(|&l| l == NO_HINT)
    }

    /// Paints a round dab of radius `r` px at `(x, y)` (pixel centres inside the disc) with
    /// `value` (a class, or [`NO_HINT`] to erase), recording each changed pixel in `diff`.
    pub fn dab(&mut self, x: f64, y: f64, r: f64, value: u8, diff: &mut HintDiff) {
        let (w, h) = (self.width as i64, self.height as i64);
        let (x0, x1) = ((x - r).ceil() as i64, (x + r).floor() as i64);
        let (y0, y1) = ((y - r).ceil() as i64, (y + r).floor() as i64);
        for py in y0.max(0)..=y1.min(h - 1) {
            for px in x0.max(0)..=x1.min(w - 1) {
                let (dx, dy) = (px as f64 - x, py as f64 - y);
                if dx * dx + dy * dy > r * r {
                    continue;
                }
                let i = (py * w + px) as usize;
                if self.labels[i] != value {
                    diff.record(i as u32, self.labels[i], value);
                    self.labels[i] = value;
                }
            }
        }
    }

    /// A stroke from `a` to `b`: dabs every half radius along the segment.
    pub fn stroke(&mut self, a: [f64; 2], b: [f64; 2], r: f64, value: u8, diff: &mut HintDiff) {
        let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        let n = (len / (0.5 * r.max(0.5))).ceil().max(1.0) as usize;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            self.dab(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), r, value, diff);
        }
    }

    /// Erases every stroke, recording the change.
    pub fn clear(&mut self, diff: &mut HintDiff) {
        for (i, l) in self.labels.iter_mut().enumerate() {
            if *l != NO_HINT {
                diff.changes.push((i as u32, *l, NO_HINT));
                *l = NO_HINT;
            }
        }
    }

    /// The hint strokes PNG the CLI reads: each hinted pixel in its class's display colour,
    /// opaque; everything else transparent.
    pub fn to_rgba(&self, colours: &[[u8; 3]]) -> image::RgbaImage {
        let mut img = image::RgbaImage::new(self.width, self.height);
        for (p, &l) in img.pixels_mut().zip(&self.labels) {
            if let Some(c) = colours.get(l as usize) {
                p.0 = [c[0], c[1], c[2], 255];
            }
        }
        img
    }
}

/// The pixels one stroke changed: index, value before, value after.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HintDiff {
    pub changes: Vec<(u32, u8, u8)>,
}

impl HintDiff {
    fn record(&mut self, i: u32, old: u8, new: u8) {
        // A pixel painted twice in one stroke keeps its first "before".
        if let Some(c) = self.changes.iter_mut().rev().take(64).find(|c| c.0 == i) {
            c.2 = new;
        } else {
            self.changes.push((i, old, new));
        }
    }

    pub fn is_empty(&self) -> bool {
        self.changes.is_empty()
    }

    fn apply(&self, layer: &mut HintLayer, forward: bool) {
        // Undo walks backwards so a pixel recorded twice ends at its first "before".
        if forward {
            self.changes.iter().for_each(|&(i, _, new)| layer.labels[i as usize] = new);
        } else {
            self.changes.iter().rev().for_each(|&(i, old, _)| layer.labels[i as usize] = old);
        }
    }
}

/// One undoable edit.
#[derive(Clone, Debug)]
enum Edit {
    Small { before: Box<Small>, after: Box<Small> },
    Hints(HintDiff),
}

/// What the conservator edits, with undo and redo.
#[derive(Clone, Debug)]
pub struct Doc {
    pub small: Small,
    pub hints: HintLayer,
    undo: Vec<Edit>,
    redo: Vec<Edit>,
}

/// Undo keeps this many edits.
const UNDO_DEPTH: usize = 200;

impl Doc {
    pub fn new(small: Small, hints: HintLayer) -> Self {
        Self { small, hints, undo: Vec::new(), redo: Vec::new() }
    }

    pub fn can_undo(&self) -> bool {
        !self.undo.is_empty()
    }

    pub fn can_redo(&self) -> bool {
        !self.redo.is_empty()
    }

    fn push(&mut self, e: Edit) {
        self.undo.push(e);
        if self.undo.len() > UNDO_DEPTH {
            self.undo.remove(0);
        }
        self.redo.clear();
    }

    /// Applies a change to the settings, picks or lighting as one undoable edit and returns
    /// the steps it makes stale (with their dependents).
    pub fn edit(&mut self, f: impl FnOnce(&mut Small)) -> Steps {
        let before = self.small.clone();
        f(&mut self.small);
        let stale = stale_steps(&before, &self.small);
        if before != self.small {
            self.push(Edit::Small { before: Box::new(before), after: Box::new(self.small.clone()) });
        }
        stale
    }

    /// Records a finished hint stroke (already painted into `hints`) as one undoable edit.
    pub fn commit_stroke(&mut self, diff: HintDiff) -> Steps {
        if diff.is_empty() {
            return Steps::NONE;
        }
        self.push(Edit::Hints(diff));
        hint_steps()
    }

    /// Undoes the last edit; returns the steps it makes stale.
    pub fn undo(&mut self) -> Steps {
        let Some(e) = self.undo.pop() else { return Steps::NONE };
        let stale = self.revert(&e, false);
        self.redo.push(e);
        stale
    }

    pub fn redo(&mut self) -> Steps {
        let Some(e) = self.redo.pop() else { return Steps::NONE };
        let stale = self.revert(&e, true);
        self.undo.push(e);
        stale
    }

    fn revert(&mut self, e: &Edit, forward: bool) -> Steps {
        match e {
            Edit::Small { before, after } => {
                let (from, to) = if forward { (before, after) } else { (after, before) };
                self.small = (**to).clone();
                stale_steps(from, to)
            }
            Edit::Hints(d) => {
                d.apply(&mut self.hints, forward);
                hint_steps()
            }
        }
    }
}

fn hint_steps() -> Steps {
    Steps::from_iter([Step::Restore]).with_dependents()
}

/// The steps whose outputs differ between the two documents (each step's own inputs
/// compared), with their dependents.
pub fn stale_steps(a: &Small, b: &Small) -> Steps {
    let (sa, sb) = (&a.settings, &b.settings);
    let mut s = Steps::NONE;
    // Picks carry the display colours, which the palette records: any change reclassifies.
    if a.picks != b.picks || sa.classify != sb.classify {
        s.insert(Step::Classify);
    }
    // The object mask (made before classifying) limits classification and compensation.
    if a.outline != b.outline {
        s.insert(Step::Classify);
        s.insert(Step::CompOriginal);
    }
    if sa.restore != sb.restore {
        s.insert(Step::Restore);
    }
    if a.lighting != b.lighting || sa.relight != sb.relight {
        s.insert(Step::Relight);
        s.insert(Step::CompRelit);
    }
    if sa.compensate != sb.compensate {
        s.insert(Step::CompOriginal);
        s.insert(Step::CompRestored);
        s.insert(Step::CompRelit);
    }
    s.with_dependents()
}

/// A new colour class with a distinct default name.
pub fn new_class(picks: &Picks) -> PickColour {
    let mut n = picks.colours.len() + 1;
    while picks.colours.iter().any(|c| c.name == format!("colour {n}")) {
        n += 1;
    }
    PickColour {
        name: format!("colour {n}"),
        display_srgb8: None,
        pixels: Vec::new(),
        rects: Vec::new(),
        stroke_srgb8: None,
    }
}

/// Empty picks of the current version.
pub fn empty_picks() -> Picks {
    Picks { version: PICKS_VERSION, colours: Vec::new(), strokes: None }
}

/// The direction (camera frame) of a directional light coming from azimuth `az` degrees
/// (0 = from the camera, positive = from the right as the camera sees it) and elevation
/// `el` degrees above the camera's horizon.
pub fn light_direction(az_deg: f64, el_deg: f64) -> [f64; 3] {
    let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
    // The light travels from its source towards the object: from the right means -x.
    [-az.sin() * el.cos(), el.sin(), az.cos() * el.cos()]
}

/// Inverse of [`light_direction`] (degrees).
pub fn light_angles(d: [f64; 3]) -> (f64, f64) {
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
    let (x, y, z) = (d[0] / n, d[1] / n, d[2] / n);
    ((-x).atan2(z).to_degrees(), y.clamp(-1.0, 1.0).asin().to_degrees())
}

/// A directional light from the given angles, white of the given strength.
pub fn directional(az_deg: f64, el_deg: f64, strength: f64) -> Light {
    Light::Directional { direction: light_direction(az_deg, el_deg), colour: [strength; 3] }
}

/// A scene's light figures, from its `compensation.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFigures {
    pub peak_lux: f64,
    pub limit_lux: f64,
    pub e_bound_lux: f64,
    pub scale: f64,
    /// Fraction of the covered points whose target needed more light than the bound allows.
    pub limited_by_bound: f64,
    /// Where another clip fraction would change the whole object's brightness by a quarter or
    /// more, what it would be (`compensate::clip_tradeoff`).
    pub clip_note: Option<String>,
}

impl SceneFigures {
    pub fn of(s: &restage_authoring::compensate::io::Summary) -> SceneFigures {
        let t = &s.stats;
        SceneFigures {
            peak_lux: t.peak_lux,
            limit_lux: t.limit_lux,
            e_bound_lux: s.e_bound_lux,
            scale: t.scale,
            limited_by_bound: t.limited_by_bound as f64 / t.covered_points.max(1) as f64,
            clip_note: restage_authoring::compensate::clip_tradeoff(
                &t.scale_by_clip,
                s.clip_fraction,
                t.scale,
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> Small {
        let mut picks = empty_picks();
        picks.colours.push(new_class(&picks));
        Small {
            settings: Settings::default(),
            picks,
            lighting: Lighting::default(),
            outline: Outline::default(),
        }
    }

    #[test]
    fn dependents_follow_the_data_flow() {
        let s = Steps::from_iter([Step::Classify]).with_dependents();
        assert_eq!(
            s,
            Steps::from_iter([
                Step::Classify,
                Step::Restore,
                Step::Relight,
                Step::CompRestored,
                Step::CompRelit
            ])
        );
        assert!(!s.contains(Step::CompOriginal));
        let r = Steps::from_iter([Step::Relight]).with_dependents();
        assert_eq!(r.iter().collect::<Vec<_>>(), vec![Step::Relight, Step::CompRelit]);
    }

    #[test]
    fn each_parameter_makes_only_its_steps_stale() {
        let mut d = Doc::new(small(), HintLayer::empty(8, 8));
        assert_eq!(d.edit(|s| s.settings.restore.alpha = 4.0), hint_steps());
        let comp = d.edit(|s| s.settings.compensate.m = None);
        assert_eq!(comp, Steps::from_iter([Step::CompOriginal, Step::CompRestored, Step::CompRelit]));
        let relight = d.edit(|s| s.settings.relight.noise = 0.5);
        assert_eq!(relight, Steps::from_iter([Step::Relight, Step::CompRelit]));
        let picks = d.edit(|s| s.picks.colours[0].pixels.push([1, 2]));
        assert!(picks.contains(Step::Classify) && picks.contains(Step::CompRelit));
        assert!(!picks.contains(Step::CompOriginal));
        // The outline makes the mask, which classification and every compensation read.
        let outline = d.edit(|s| s.outline.polygons.push(vec![[0.0, 0.0], [4.0, 0.0], [2.0, 3.0]]));
        assert_eq!(outline, Steps::from_iter(Step::ALL));
        // No change, nothing stale, nothing recorded.
        assert_eq!(d.edit(|s| s.settings.restore.alpha = 4.0), Steps::NONE);
        let mut undone = 0;
        while d.can_undo() {
            d.undo();
            undone += 1;
        }
        assert_eq!(undone, 5);
        assert_eq!(d.small, small());
    }

    #[test]
    fn undo_and_redo_restore_hints_exactly() {
        let mut d = Doc::new(small(), HintLayer::empty(32, 20));
        let mut diff = HintDiff::default();
        d.hints.stroke([3.0, 3.0], [20.0, 10.0], 2.5, 0, &mut diff);
        let painted = d.hints.clone();
        assert!(!painted.is_empty());
        assert_eq!(d.commit_stroke(diff), hint_steps());
        // Erase across the stroke, then undo both.
        let mut erase = HintDiff::default();
        d.hints.stroke([0.0, 6.0], [31.0, 6.0], 3.0, NO_HINT, &mut erase);
        d.commit_stroke(erase);
        assert_ne!(d.hints, painted);
        d.undo();
        assert_eq!(d.hints, painted);
        d.undo();
        assert!(d.hints.is_empty());
        d.redo();
        assert_eq!(d.hints, painted);
        // A new edit clears the redo stack.
        d.edit(|s| s.settings.restore.beta = 5.0);
        assert!(!d.can_redo());
    }

    #[test]
    fn hints_png_uses_display_colours_and_transparency() {
        let mut h = HintLayer::empty(4, 2);
        h.labels[1] = 1;
        let img = h.to_rgba(&[[1, 2, 3], [200, 100, 50]]);
        assert_eq!(img.get_pixel(1, 0).0, [200, 100, 50, 255]);
        assert_eq!(img.get_pixel(0, 0).0[3], 0);
    }

    #[test]
    fn regions_write_the_cli_syntax() {
        let r = RegionSpec::Rect { x: 1, y: 2, width: 30, height: 40, background: Some(3) };
        assert_eq!(r.to_cli(), "rect:1,2,30,40@3");
        let p = RegionSpec::Polygon { points: vec![[0.0, 0.0], [10.5, 0.0], [5.0, 8.0]], background: None };
        assert_eq!(p.to_cli(), "poly:0,0,10.5,0,5,8");
    }

    #[test]
    fn light_angles_round_trip() {
        for (az, el) in [(0.0, 30.0), (-45.0, 10.0), (120.0, 60.0)] {
            let (a, e) = light_angles(light_direction(az, el));
            assert!((a - az).abs() < 1e-9 && (e - el).abs() < 1e-9, "{az} {el} -> {a} {e}");
        }
        // From the upper left behind the camera, as relight's own default describes it.
        let d = light_direction(-45.0, 30.0);
        assert!(d[0] > 0.0 && d[1] > 0.0 && d[2] > 0.0);
    }
}
