//! The interactive tool's project folder: the capture set, the stage model and every step's
//! inputs and outputs as the files the command line reads and writes; `project.toml` with the
//! tool's parameters; `steps.sh`, the command lines that reproduce every output from them.
//!
//! Layout (paths relative to the project; the demo's `out/demo` is a project too):
//!
//! | path | what |
//! | --- | --- |
//! | `project.toml` | [`ProjectFile`]: where the photo, capture set and stage model are, every parameter |
//! | `capture/` | the capture set (optional: a photo-only project classifies and restores) |
//! | `stage/` | the stage model compensation uses |
//! | `mask/outline.json`, `mask/{object_mask.png,mask.json}` | the object outline, the mask step's mask |
//! | `classify/picks.json`, `classify/{labels,palette,preview}` | picks, classification |
//! | `restore/hints.png`, `restore/{labels,restored,before_after}.png` | hint strokes, restoration |
//! | `relight/lighting.toml`, `relight/relit.png` | the virtual lighting, the relit variant |
//! | `comp/<scene>/` | one scene's frames, certificate and report |
//! | `preview/<scene>.png`, `preview/<scene>_linear.png` | what a visitor sees (virtual stage) |

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use restage_authoring::classify::{Palette, Picks, output_paths};
use restage_authoring::relight::Lighting;
use restage_authoring::restore::io::{RESTORED_FILE, display_colours, load_hints};
use restage_authoring::segment::Outline;
use restage_authoring::stage_sim::{GROUND_TRUTH_DIR, TRUTH_FILE};
use serde::{Deserialize, Serialize};

use super::doc::{HintLayer, NO_HINT, Scene, Settings, Small, Step, Steps, empty_picks};

pub const PROJECT_FILE: &str = "project.toml";
pub const PROJECT_VERSION: u32 = 1;
pub const STEPS_SCRIPT: &str = "steps.sh";
pub const CLASSIFY_DIR: &str = "classify";
pub const PICKS_FILE: &str = "classify/picks.json";
pub const RESTORE_DIR: &str = "restore";
pub const HINTS_FILE: &str = "restore/hints.png";
pub const LIGHTING_FILE: &str = "relight/lighting.toml";
pub const MASK_DIR: &str = "mask";
pub const OUTLINE_FILE: &str = "mask/outline.json";
pub const OBJECT_MASK_FILE: &str = "mask/object_mask.png";
pub const RELIT_FILE: &str = "relight/relit.png";

/// Where a project's inputs are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Paths {
    /// The diffusely lit photo (16-bit linear or 8-bit sRGB PNG).
    pub photo: PathBuf,
    /// The capture set folder, if the project has one.
    pub capture: Option<PathBuf>,
    /// The stage model folder (`stage.bin`), if the project has one.
    pub stage: Option<PathBuf>,
    /// Where that stage model came from, for people.
    #[serde(default)]
    pub stage_note: String,
    /// Object mask (non-zero = object) for classification, restoration and compensation,
    /// when the project brings its own; without one, a project with a stage model makes it
    /// with the mask step (`mask/object_mask.png`), as does any project with an outline.
    pub mask: Option<PathBuf>,
}

/// `project.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectFile {
    pub version: u32,
    pub paths: Paths,
    #[serde(default)]
    pub settings: Settings,
}

/// Something wrong with a project's files, found when opening it. The tool shows these and
/// goes on with what it could read; a file it could not read is kept aside before anything
/// is written over it.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem {
    pub path: PathBuf,
    pub message: String,
}

/// An open project folder.
#[derive(Clone, Debug)]
pub struct Project {
    pub dir: PathBuf,
    pub paths: Paths,
    pub photo_size: (u32, u32),
    /// Files that could not be read at opening (kept aside, as `<name>.unreadable`, before
    /// the tool first writes over them).
    pub unreadable: Vec<PathBuf>,
    /// The hint layer and class colours last written to `restore/hints.png` by this value, so
    /// a run whose strokes did not change does not encode the PNG again.
    hints_written: Option<(Vec<u8>, Vec<[u8; 3]>)>,
}

/// An opened project: the folder, the document read from it, and what was wrong.
pub struct Opened {
    pub project: Project,
    pub small: Small,
    pub hints: HintLayer,
    pub problems: Vec<Problem>,
}

impl Project {
    pub fn path(&self, rel: impl AsRef<Path>) -> PathBuf {
        self.dir.join(rel)
    }

    /// Opens `dir`: its `project.toml`, or a folder laid out like the demo's output (a
    /// `capture/` set and `stage/`), for which one is written.
    pub fn open(dir: &Path) -> Result<Opened> {
        let dir = std::fs::canonicalize(dir).with_context(|| format!("project folder {}", dir.display()))?;
        let file_path = dir.join(PROJECT_FILE);
        let file = if file_path.is_file() {
            let text = std::fs::read_to_string(&file_path)
                .with_context(|| format!("reading {}", file_path.display()))?;
            let f: ProjectFile = toml::from_str(&text)
                .with_context(|| format!("{} is not a valid project file", file_path.display()))?;
            if f.version != PROJECT_VERSION {
                bail!(
                    "{}: project version {} (this tool reads {PROJECT_VERSION})",
                    file_path.display(),
                    f.version
                );
            }
            f
        } else {
            let f = from_layout(&dir)?;
            write_project_file(&dir, &f)?;
            f
        };
        let photo = dir.join(&file.paths.photo);
        let (w, h) = image::image_dimensions(&photo)
            .with_context(|| format!("the project's photo {} cannot be read", photo.display()))?;
        let mut project = Project {
            dir,
            paths: file.paths,
            photo_size: (w, h),
            unreadable: Vec::new(),
            hints_written: None,
        };
        let mut problems = Vec::new();
        let mut note = |project: &mut Project, path: PathBuf, message: String| {
            project.unreadable.push(path.clone());
            problems.push(Problem { path, message });
        };

        let picks_path = project.path(PICKS_FILE);
        let picks = if picks_path.is_file() {
            match Picks::load(&picks_path) {
                Ok(p) => p,
                Err(e) => {
                    note(&mut project, picks_path, format!("{e:#}; starting with no picks"));
                    empty_picks()
                }
            }
        } else {
            empty_picks()
        };
        let lighting_path = project.path(LIGHTING_FILE);
        let lighting = if lighting_path.is_file() {
            match std::fs::read_to_string(&lighting_path)
                .map_err(anyhow::Error::from)
                .and_then(|t| toml::from_str::<Lighting>(&t).map_err(anyhow::Error::from))
            {
                Ok(l) => l,
                Err(e) => {
                    note(
                        &mut project,
                        lighting_path,
                        format!("not a lighting file ({e}); using the default lighting"),
                    );
                    Lighting::default()
                }
            }
        } else {
            Lighting::default()
        };
        let hints_path = project.path(HINTS_FILE);
        let hints = if hints_path.is_file() {
            match project.load_hint_layer(&picks) {
                Ok(h) => h,
                Err(e) => {
                    note(&mut project, hints_path, format!("{e:#}; starting with no hint strokes"));
                    HintLayer::empty(w, h)
                }
            }
        } else {
            HintLayer::empty(w, h)
        };
        let outline_path = project.path(OUTLINE_FILE);
        let outline = if outline_path.is_file() {
            match Outline::load(&outline_path) {
                Ok(o) => o,
                Err(e) => {
                    note(&mut project, outline_path, format!("{e:#}; starting with no outline"));
                    Outline::default()
                }
            }
        } else {
            Outline::default()
        };
        Ok(Opened {
            project,
            small: Small { settings: file.settings, picks, lighting, outline },
            hints,
            problems,
        })
    }

    fn load_hint_layer(&self, picks: &Picks) -> Result<HintLayer> {
        let (w, h) = self.photo_size;
        let colours = self.class_colours(picks);
        let map = load_hints(&self.path(HINTS_FILE), w, h, &colours)?;
        Ok(HintLayer { width: w, height: h, labels: map.labels })
    }

    /// The display colour of every class: the picks' restored colours where given, else the
    /// classification's (exactly what `restore` matches hint strokes against).
    pub fn class_colours(&self, picks: &Picks) -> Vec<[u8; 3]> {
        let palette_path = output_paths(&self.path(CLASSIFY_DIR)).1;
        match Palette::load(&palette_path) {
            Ok(p) if p.classes.len() == picks.colours.len() => display_colours(&p, Some(picks)),
            _ => picks
                .colours
                .iter()
                .enumerate()
                .map(|(i, c)| c.display_srgb8.unwrap_or(restage_authoring::color::categorical(i)))
                .collect(),
        }
    }

    /// Writes the document's inputs (project.toml, picks, lighting, hint strokes) and
    /// `steps.sh`. A file that could not be read at opening is first moved aside.
    pub fn save(&mut self, small: &Small, hints: &HintLayer) -> Result<()> {
        for p in std::mem::take(&mut self.unreadable) {
            if p.exists() {
                let aside = PathBuf::from(format!("{}.unreadable", p.display()));
                std::fs::rename(&p, &aside).with_context(|| {
                    format!("keeping the unreadable {} as {}", p.display(), aside.display())
                })?;
                tracing::warn!("kept the unreadable {} as {}", p.display(), aside.display());
            }
        }
        let file = ProjectFile {
            version: PROJECT_VERSION,
            paths: self.paths.clone(),
            settings: small.settings.clone(),
        };
        write_project_file(&self.dir, &file)?;
        std::fs::create_dir_all(self.path(CLASSIFY_DIR))?;
        small.picks.save(&self.path(PICKS_FILE))?;
        let lighting = self.path(LIGHTING_FILE);
        std::fs::create_dir_all(lighting.parent().expect("inside the project"))?;
        write_if_changed(&lighting, toml::to_string(&small.lighting)?.as_bytes())?;
        self.write_hints(small, hints)?;
        let outline = self.path(OUTLINE_FILE);
        if small.outline.polygons.is_empty() {
            if outline.exists() {
                std::fs::remove_file(&outline).with_context(|| format!("removing {}", outline.display()))?;
            }
        } else {
            std::fs::create_dir_all(self.path(MASK_DIR))?;
            let text = serde_json::to_string_pretty(&small.outline).context("writing the outline")?;
            write_if_changed(&outline, (text + "\n").as_bytes())?;
        }
        let script = self.steps_script(small, hints);
        write_if_changed(&self.path(STEPS_SCRIPT), script.as_bytes())?;
        Ok(())
    }

    /// Writes the hint strokes PNG in the classes' current display colours (what `restore`
    /// matches strokes against), or removes it when there is no stroke.
    pub fn write_hints(&mut self, small: &Small, hints: &HintLayer) -> Result<()> {
        let path = self.path(HINTS_FILE);
        if hints.labels.iter().any(|&l| l != NO_HINT) {
            let colours = self.class_colours(&small.picks);
            if path.is_file()
                && self.hints_written.as_ref().is_some_and(|(l, c)| *l == hints.labels && *c == colours)
            {
                return Ok(());
            }
            std::fs::create_dir_all(self.path(RESTORE_DIR))?;
            save_png_fast(&hints.to_rgba(&colours), &path)?;
            self.hints_written = Some((hints.labels.clone(), colours));
            Ok(())
        } else if path.exists() {
            self.hints_written = None;
            std::fs::remove_file(&path).with_context(|| format!("removing {}", path.display()))
        } else {
            Ok(())
        }
    }

    /// Whether the mask step makes the project's object mask: with an outline, or with a
    /// stage model and no mask of the project's own.
    pub fn runs_mask_step(&self, small: &Small) -> bool {
        !small.outline.polygons.is_empty()
            || (self.paths.stage.is_some()
                && self.paths.mask.as_ref().is_none_or(|m| m == Path::new(OBJECT_MASK_FILE)))
    }

    /// The object mask the steps read, if any (relative to the project).
    pub fn mask_file(&self, small: &Small) -> Option<PathBuf> {
        if self.runs_mask_step(small) { Some(OBJECT_MASK_FILE.into()) } else { self.paths.mask.clone() }
    }

    /// The mask the window shows: the mask step's when it made one, else the project's own.
    pub fn shown_mask(&self) -> Option<PathBuf> {
        let made = self.path(OBJECT_MASK_FILE);
        if made.is_file() { Some(made) } else { self.paths.mask.as_ref().map(|m| self.path(m)) }
    }

    /// The mask step's command line (before `--force`).
    fn mask_line(&self, small: &Small, p: &dyn Fn(&Path) -> String) -> Vec<String> {
        let mut a = vec!["mask".to_string()];
        match &self.paths.stage {
            Some(s) => a.extend(["--stage".into(), p(s)]),
            None => a.extend(["--photo".into(), p(&self.paths.photo)]),
        }
        if !small.outline.polygons.is_empty() {
            a.extend(["--outline".into(), p(Path::new(OUTLINE_FILE))]);
        }
        a.extend(["--out".into(), p(Path::new(MASK_DIR))]);
        a
    }

    /// Whether the project can make a step at all (what it lacks, if not).
    pub fn can_run(&self, step: Step, small: &Small) -> Result<(), String> {
        let s = &small.settings;
        match step {
            Step::Classify if small.picks.colours.is_empty() => {
                Err("no colour classes yet: add one and pick pixels".into())
            }
            Step::Classify => {
                match small.picks.colours.iter().find(|c| c.pixels.is_empty() && c.rects.is_empty()) {
                    Some(c) => Err(format!("colour '{}' has no picked pixels", c.name)),
                    None => Ok(()),
                }
            }
            Step::Relight | Step::CompRelit if !s.relight.enabled => Err("relighting is switched off".into()),
            Step::Relight | Step::CompOriginal | Step::CompRestored | Step::CompRelit
                if self.paths.stage.is_none() =>
            {
                Err("the project has no stage model (calibrate the stage first)".into())
            }
            _ => Ok(()),
        }
    }

    /// Steps whose outputs are not on disk (among those the project can make).
    pub fn missing_steps(&self, small: &Small) -> Steps {
        Step::ALL
            .into_iter()
            .filter(|&s| self.can_run(s, small).is_ok() && !self.outputs(s).iter().all(|p| p.is_file()))
            .collect()
    }

    /// The files that stand for a step's output.
    pub fn outputs(&self, step: Step) -> Vec<PathBuf> {
        match step {
            Step::Classify => {
                let (l, p, v) = output_paths(&self.path(CLASSIFY_DIR));
                vec![l, p, v]
            }
            Step::Restore => vec![self.path(RESTORE_DIR).join(RESTORED_FILE)],
            Step::Relight => vec![self.path(RELIT_FILE)],
            s => {
                let sc = s.scene().expect("a compensation step");
                let mut v = vec![
                    self.comp_dir(sc).join(restage_authoring::compensate::io::frame_file(0)),
                    self.comp_dir(sc).join(restage_authoring::compensate::io::CERTIFICATE_FILE),
                ];
                if self.has_virtual_stage() {
                    v.push(self.preview_file(sc).0);
                }
                v
            }
        }
    }

    pub fn comp_dir(&self, scene: Scene) -> PathBuf {
        self.path("comp").join(scene.id())
    }

    /// The visitor preview of a scene: (8-bit sRGB, 16-bit linear).
    pub fn preview_file(&self, scene: Scene) -> (PathBuf, PathBuf) {
        let d = self.path("preview");
        (d.join(format!("{}.png", scene.id())), d.join(format!("{}_linear.png", scene.id())))
    }

    /// A capture simulated by the virtual stage carries its true physics, which renders
    /// what a visitor would see.
    pub fn has_virtual_stage(&self) -> bool {
        self.paths
            .capture
            .as_ref()
            .is_some_and(|c| self.path(c).join(GROUND_TRUTH_DIR).join(TRUTH_FILE).is_file())
    }

    /// The `restage-author` command line (after the program name) that makes a step, with
    /// every path under `base` (the project folder for running here, empty for `steps.sh`).
    /// A compensation step has a second line on a virtual stage: the visitor preview.
    /// Each line ends in `--force`: a project's steps replace their own earlier outputs.
    pub fn commands(&self, step: Step, small: &Small, hints: &HintLayer, base: &Path) -> Vec<Vec<String>> {
        let mut lines = self.step_lines(step, small, hints, base);
        for line in &mut lines {
            line.push("--force".into());
        }
        lines
    }

    fn step_lines(&self, step: Step, small: &Small, hints: &HintLayer, base: &Path) -> Vec<Vec<String>> {
        let p = |rel: &Path| base.join(rel).display().to_string();
        let s = &small.settings;
        let photo = p(&self.paths.photo);
        let n = |v: f64| v.to_string();
        match step {
            Step::Classify => {
                let mut a = vec![
                    "classify".into(),
                    photo,
                    "--picks".into(),
                    p(Path::new(PICKS_FILE)),
                    "--out".into(),
                    p(Path::new(CLASSIFY_DIR)),
                    "--max-iterations".into(),
                    s.classify.max_iterations.to_string(),
                    "--prior-picks".into(),
                    n(s.classify.prior_picks),
                ];
                // The loss classes (the restore panel's "loss" boxes) also tell cracks from dark paint.
                for k in &s.restore.loss {
                    a.extend(["--loss".into(), k.to_string()]);
                }
                let mask = self.mask_file(small);
                if let Some(m) = &mask {
                    a.extend(["--mask".into(), p(m)]);
                }
                if self.runs_mask_step(small) { vec![self.mask_line(small, &p), a] } else { vec![a] }
            }
            Step::Restore => {
                let r = &s.restore;
                let mut a = vec![
                    "restore".into(),
                    p(Path::new(CLASSIFY_DIR)),
                    "--out".into(),
                    p(Path::new(RESTORE_DIR)),
                    "--alpha".into(),
                    n(r.alpha),
                    "--beta".into(),
                    n(r.beta),
                    "--neighbours".into(),
                    r.neighbours.to_string(),
                    "--scale".into(),
                    n(r.scale),
                    "--grid".into(),
                    r.grid.clone(),
                    "--picks".into(),
                    p(Path::new(PICKS_FILE)),
                ];
                if let Some(g) = r.gamma {
                    a.extend(["--gamma".into(), n(g)]);
                }
                for k in &r.loss {
                    a.extend(["--loss".into(), k.to_string()]);
                }
                if let Some(b) = r.background {
                    a.extend(["--background".into(), b.to_string()]);
                }
                for region in &r.regions {
                    a.extend(["--region".into(), region.to_cli()]);
                }
                if !hints.is_empty() {
                    a.extend(["--hints".into(), p(Path::new(HINTS_FILE))]);
                }
                if let Some(m) = self.mask_file(small) {
                    a.extend(["--mask".into(), p(&m)]);
                }
                vec![a]
            }
            Step::Relight => {
                let stage = self.paths.stage.as_ref().map(|s| p(s)).unwrap_or_default();
                vec![vec![
                    "relight".into(),
                    stage,
                    p(&Path::new(RESTORE_DIR).join(RESTORED_FILE)),
                    "--lighting".into(),
                    p(Path::new(LIGHTING_FILE)),
                    "--photo".into(),
                    photo,
                    "--noise".into(),
                    n(s.relight.noise),
                    "--noise-radius".into(),
                    s.relight.noise_radius.to_string(),
                    "--device".into(),
                    s.compensate.device.clone(),
                    "--out".into(),
                    p(Path::new(RELIT_FILE)),
                ]]
            }
            step => {
                let scene = step.scene().expect("a compensation step");
                let c = &s.compensate;
                let target = match scene {
                    Scene::Original => photo,
                    Scene::Restored => p(&Path::new(RESTORE_DIR).join(RESTORED_FILE)),
                    Scene::Relit => p(Path::new(RELIT_FILE)),
                };
                let rel = |abs: PathBuf| p(abs.strip_prefix(&self.dir).expect("inside the project"));
                let comp = rel(self.comp_dir(scene));
                let mut lines = vec![vec![
                    "compensate".into(),
                    self.paths.stage.as_ref().map(|s| p(s)).unwrap_or_default(),
                    target,
                    "--ebound-lux".into(),
                    n(c.e_bound_lux),
                    "--m".into(),
                    c.m.map_or("inf".into(), n),
                    "--margin".into(),
                    n(c.margin),
                    "--clip-fraction".into(),
                    n(c.clip_fraction),
                    "--reduction".into(),
                    c.reduction.to_string(),
                    "--device".into(),
                    c.device.clone(),
                    "--out".into(),
                    comp.clone(),
                ]];
                if c.auto_clip {
                    lines[0].push("--auto-clip".into());
                }
                if let Some(m) = self.mask_file(small) {
                    lines[0].extend(["--mask".into(), p(&m)]);
                    // Compensating the photo needs no classification: make the mask here
                    // when classifying cannot.
                    if scene == Scene::Original
                        && self.runs_mask_step(small)
                        && self.can_run(Step::Classify, small).is_err()
                    {
                        lines.insert(0, self.mask_line(small, &p));
                    }
                }
                if let (true, Some(capture)) = (self.has_virtual_stage(), &self.paths.capture) {
                    let (srgb, linear) = self.preview_file(scene);
                    lines.push(vec![
                        "render".into(),
                        "--capture".into(),
                        p(capture),
                        "--frames".into(),
                        comp,
                        "--out".into(),
                        rel(linear),
                        "--preview".into(),
                        rel(srgb),
                    ]);
                }
                lines
            }
        }
    }

    /// `steps.sh`: every step's command lines, in run order, for the steps the project can run.
    pub fn steps_script(&self, small: &Small, hints: &HintLayer) -> String {
        let mut out = String::from(
            "#!/bin/sh\n# Written by `restage-author gui`: reproduces every output of this project from its saved\n\
             # inputs with the command line, byte for byte. RESTAGE_AUTHOR names the program.\nset -e\n\
             cd \"$(dirname \"$0\")\"\nA=\"${RESTAGE_AUTHOR:-restage-author}\"\nmkdir -p preview\n",
        );
        for step in Step::ALL {
            if let Err(why) = self.can_run(step, small) {
                out.push_str(&format!("# {}: skipped ({why})\n", step.name()));
                continue;
            }
            for line in self.commands(step, small, hints, Path::new("")) {
                let quoted: Vec<String> = line.iter().map(|a| shell_quote(a)).collect();
                out.push_str(&format!("\"$A\" {}\n", quoted.join(" ")));
            }
        }
        out
    }

    /// Makes a new project from a capture folder (copied in as `capture/` unless it is already
    /// inside `dir`) and, optionally, a stage model folder.
    pub fn create_from_capture(dir: &Path, capture: &Path, stage: Option<&Path>) -> Result<Opened> {
        let manifest = restage_authoring::capture_set::CaptureManifest::load(capture)
            .with_context(|| format!("{} is not a capture set", capture.display()))?;
        let dir = new_project_dir(dir)?;
        let capture = std::fs::canonicalize(capture)?;
        let rel_capture = match capture.strip_prefix(&dir) {
            Ok(rel) => rel.to_path_buf(),
            Err(_) => {
                copy_dir(&capture, &dir.join("capture"))?;
                PathBuf::from("capture")
            }
        };
        let stage_rel = match stage {
            Some(s) => {
                let s = std::fs::canonicalize(s)?;
                restage_authoring::stage_model::StageModel::load(&s)
                    .with_context(|| format!("{} is not a stage model", s.display()))?;
                match s.strip_prefix(&dir) {
                    Ok(rel) => Some(rel.to_path_buf()),
                    Err(_) => {
                        copy_dir(&s, &dir.join("stage"))?;
                        Some(PathBuf::from("stage"))
                    }
                }
            }
            None => None,
        };
        let paths = Paths {
            photo: rel_capture.join(&manifest.photo),
            capture: Some(rel_capture),
            stage_note: if stage_rel.is_some() { "calibrated".into() } else { String::new() },
            stage: stage_rel,
            mask: None,
        };
        write_project_file(
            &dir,
            &ProjectFile { version: PROJECT_VERSION, paths, settings: Settings::default() },
        )?;
        Project::open(&dir)
    }

    /// Makes a project on the virtual stage: a simulated capture set, the stage's TRUE model
    /// as the stage model (the demo's substitute for calibration; `calibrate` replaces it),
    /// starting picks drawn from its ground truth (the demo's stand-in for a conservator's
    /// clicks) and a new signing key. Every step is then missing, to be run.
    pub fn create_virtual(
        dir: &Path,
        scene: &restage_authoring::stage_sim::SceneConfig,
        acq: &restage_authoring::acquire::AcquireConfig,
    ) -> Result<Opened> {
        let dir = new_project_dir(dir)?;
        let capture = dir.join("capture");
        let manifest = crate::steps::simulate::simulate(scene, acq, &capture, &crate::steps::Quiet)?;
        let truth = capture.join(GROUND_TRUTH_DIR).join("stage");
        restage_authoring::stage_model::StageModel::load(&truth)
            .with_context(|| format!("reading {}", truth.display()))?
            .save(&dir.join("stage"))
            .context("writing the project's stage model")?;
        let (picks, mask, _) =
            crate::steps::classify::picks_from_ground_truth(&capture, &dir.join(CLASSIFY_DIR), scene.seed)?;
        let mut settings = Settings::default();
        if let Some(k) = Picks::load(&picks)?.colours.iter().position(|c| c.name == "clay") {
            settings.restore.loss = vec![k as u8];
        }
        let name = scene.scene.name();
        settings.export.object_id = format!("virtual-{name}-{}", scene.seed);
        settings.export.object_name = format!("virtual stage {name} (seed {})", scene.seed);
        let paths = Paths {
            photo: PathBuf::from("capture").join(&manifest.photo),
            capture: Some("capture".into()),
            stage: Some("stage".into()),
            stage_note: "the virtual stage's TRUE model (ground truth); calibrate to use a measured one"
                .into(),
            mask: Some(mask.strip_prefix(&dir).expect("inside the project").to_path_buf()),
        };
        let mut project = Project {
            dir: dir.clone(),
            paths: paths.clone(),
            photo_size: (0, 0),
            unreadable: vec![],
            hints_written: None,
        };
        let (key, trust) = new_key(&project, "project")?;
        settings.export.key = key;
        settings.export.trust = trust;
        project.photo_size = (scene.camera[0], scene.camera[1]);
        write_project_file(&dir, &ProjectFile { version: PROJECT_VERSION, paths, settings })?;
        Project::open(&dir)
    }

    /// Makes a photo-only project on the virtual stage: its diffusely lit photo at the
    /// camera's size (a 10 MP photo is cheap this way, with no structured light), the demo's
    /// stand-in picks and object mask; classification and restoration only.
    pub fn create_virtual_photo(
        dir: &Path,
        scene: &restage_authoring::stage_sim::SceneConfig,
    ) -> Result<Opened> {
        let dir = new_project_dir(dir)?;
        let stage = restage_authoring::stage_sim::VirtualStage::new(scene)?;
        let photo = stage.capture(&stage.black_frames(), true, 0)?;
        photo.save_linear16(&dir.join("photo.png"))?;
        let (picks, present) = crate::steps::demo_chain::stand_in_picks(&stage, scene.seed)?;
        std::fs::create_dir_all(dir.join(CLASSIFY_DIR))?;
        picks.save(&dir.join(PICKS_FILE))?;
        let cam = stage.camera();
        let mask = image::GrayImage::from_fn(cam.width, cam.height, |x, y| {
            image::Luma([if stage.pixels()[(y * cam.width + x) as usize].is_object() { 255 } else { 0 }])
        });
        let mask_rel = PathBuf::from("classify/mask.png");
        mask.save(dir.join(&mask_rel)).context("writing the object mask")?;
        let mut settings = Settings::default();
        settings.relight.enabled = false;
        settings.restore.loss =
            present.iter().position(|&c| c == stage.palette().clay).map(|k| k as u8).into_iter().collect();
        let paths = Paths {
            photo: "photo.png".into(),
            capture: None,
            stage: None,
            stage_note: String::new(),
            mask: Some(mask_rel),
        };
        write_project_file(&dir, &ProjectFile { version: PROJECT_VERSION, paths, settings })?;
        Project::open(&dir)
    }

    /// Makes a photo-only project (classification and restoration; no compensation).
    pub fn create_from_photo(dir: &Path, photo: &Path) -> Result<Opened> {
        image::image_dimensions(photo)
            .with_context(|| format!("{} is not a readable image", photo.display()))?;
        let dir = &new_project_dir(dir)?;
        let name = photo.file_name().context("the photo has no file name")?;
        std::fs::copy(photo, dir.join(name)).with_context(|| format!("copying {}", photo.display()))?;
        let paths = Paths {
            photo: PathBuf::from(name),
            capture: None,
            stage: None,
            stage_note: String::new(),
            mask: None,
        };
        write_project_file(
            dir,
            &ProjectFile { version: PROJECT_VERSION, paths, settings: Settings::default() },
        )?;
        Project::open(dir)
    }
}

/// The folder of a new project, created if needed; one that already holds a project is
/// refused rather than written over.
/// A new signing key for the project: `keys/<name>.pem`, its public half also in `trust/`.
pub fn new_key(project: &Project, name: &str) -> Result<(String, String)> {
    let keys = project.path("keys");
    let trust = project.path("trust");
    std::fs::create_dir_all(&keys)?;
    std::fs::create_dir_all(&trust)?;
    let (_, _, public) = crate::steps::keygen::generate(&keys.join(name))?;
    let name_pub = public.file_name().context("public key file name")?;
    std::fs::copy(&public, trust.join(name_pub)).with_context(|| format!("copying {}", public.display()))?;
    Ok((format!("keys/{name}.pem"), "trust".into()))
}

fn new_project_dir(dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let dir = std::fs::canonicalize(dir)?;
    if dir.join(PROJECT_FILE).exists() {
        bail!("{} already holds a project: open it, or choose another folder", dir.display());
    }
    Ok(dir)
}

/// A project file for a folder laid out like the demo's output.
fn from_layout(dir: &Path) -> Result<ProjectFile> {
    let capture = dir.join("capture");
    let manifest = restage_authoring::capture_set::CaptureManifest::load(&capture)
        .with_context(|| {
            format!(
                "{} has neither a {PROJECT_FILE} nor a capture set in capture/; make a project with \
                 `restage-author gui DIR --new-virtual vase`, `--from-capture CAPTURE` or `--from-photo PHOTO`",
                dir.display()
            )
        })?;
    let (stage, stage_note) = if dir.join("stage/stage.bin").is_file() {
        (Some(PathBuf::from("stage")), "calibrated".to_string())
    } else {
        (None, String::new())
    };
    let mask = ["classify/object_mask.png", "classify/mask.png"]
        .into_iter()
        .map(PathBuf::from)
        .find(|m| dir.join(m).is_file());
    let mut settings = Settings::default();
    // Keep the demo's loss class (bare clay) when its picks name one.
    if let Ok(p) = Picks::load(&dir.join(PICKS_FILE))
        && let Some(k) = p.colours.iter().position(|c| c.name == "clay")
    {
        settings.restore.loss = vec![k as u8];
    }
    Ok(ProjectFile {
        version: PROJECT_VERSION,
        paths: Paths {
            photo: PathBuf::from("capture").join(manifest.photo),
            capture: Some("capture".into()),
            stage,
            stage_note,
            mask,
        },
        settings,
    })
}

fn write_project_file(dir: &Path, f: &ProjectFile) -> Result<()> {
    let text = format!(
        "# restage-author gui project (the tool rewrites this file; every setting is a CLI option).\n{}",
        toml::to_string(f).context("serialising the project file")?
    );
    write_if_changed(&dir.join(PROJECT_FILE), text.as_bytes())
}

/// Writes a file only when its bytes change (keeps times and avoids needless I/O).
fn write_if_changed(path: &Path, bytes: &[u8]) -> Result<()> {
    if std::fs::read(path).ok().as_deref() == Some(bytes) {
        return Ok(());
    }
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

fn copy_dir(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
    for e in std::fs::read_dir(from).with_context(|| format!("reading {}", from.display()))? {
        let e = e?;
        let target = to.join(e.file_name());
        if e.file_type()?.is_dir() {
            copy_dir(&e.path(), &target)?;
        } else {
            std::fs::copy(e.path(), &target).with_context(|| format!("copying {}", e.path().display()))?;
        }
    }
    Ok(())
}

/// Writes an RGBA PNG with fast compression (hint strokes are rewritten on every stroke, and
/// are an input: only their pixels matter).
pub fn save_png_fast(img: &image::RgbaImage, path: &Path) -> Result<()> {
    use image::ImageEncoder;
    let file = std::fs::File::create(path).with_context(|| format!("writing {}", path.display()))?;
    image::codecs::png::PngEncoder::new_with_quality(
        std::io::BufWriter::new(file),
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgba8)
    .with_context(|| format!("writing {}", path.display()))
}

/// Single-quotes a word for sh.
pub fn shell_quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=:,@+".contains(c)) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_quoting() {
        assert_eq!(shell_quote("classify/picks.json"), "classify/picks.json");
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
    }
}
