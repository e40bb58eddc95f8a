//! The tool without a window: a small virtual-stage project, edits through the document, the
//! worker's runs (which steps an edit re-runs, the visible region first, cancel), files it
//! could not read, export, and the round trip through `steps.sh` with the real CLI.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use restage_authoring::acquire::AcquireConfig;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, SceneName};

use super::doc::{Doc, HintDiff, RegionSpec, Scene, Step, Steps};
use super::jobs::{Msg, Request, Runner};
use super::project::{Opened, PICKS_FILE, Project};

/// A small virtual project with every step run once; each test works on its own copy.
fn template() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    let (_, p) = DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("project");
        let scene = SceneConfig {
            scene: SceneName::Vase,
            seed: 3,
            camera: [200, 150],
            projector: [160, 120],
            projectors: 3,
            deteriorate: true,
            plinth: false,
            rig: RigVariation::Nominal,
        };
        let acq = AcquireConfig { dot_spacing: 4, ramp_levels: 5, ..AcquireConfig::default() };
        let opened = Project::create_virtual(&dir, &scene, &acq).unwrap();
        assert_eq!(opened.project.missing_steps(&opened.small), all_steps());
        let (msgs, left) = run(&opened, all_steps(), None);
        assert_eq!(left, Steps::NONE, "{msgs:?}");
        (tmp, dir)
    });
    p
}

fn all_steps() -> Steps {
    Step::ALL.into_iter().collect()
}

fn copy_of_template() -> (tempfile::TempDir, Opened) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("p");
    copy(template(), &dir);
    let opened = Project::open(&dir).unwrap();
    (tmp, opened)
}

fn copy(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

fn request(doc: &Doc, generation: u64, steps: Steps, visible: Option<[u32; 4]>) -> Request {
    Request { generation, steps, small: doc.small.clone(), hints: Arc::new(doc.hints.clone()), visible }
}

fn run_doc(project: &Project, doc: &Doc, steps: Steps, visible: Option<[u32; 4]>) -> (Vec<Msg>, Steps) {
    let mut msgs = Vec::new();
    let left =
        Runner::new(project.clone()).run(&request(doc, 1, steps, visible), || false, &mut |m| msgs.push(m));
    (msgs, left)
}

/// Runs `req` with a `stop` that says no at its first call and yes from its second on (a
/// newer request or Cancel arriving after the first check); also returns how often it was asked.
fn run_stopped_at_second_check(project: &Project, req: &Request) -> (Vec<Msg>, Steps, usize) {
    let mut calls = 0;
    let mut msgs = Vec::new();
    let left = Runner::new(project.clone()).run(
        req,
        || {
            calls += 1;
            calls > 1
        },
        &mut |m| msgs.push(m),
    );
    (msgs, left, calls)
}

/// Class 1 painted across the middle of the object; the steps it makes stale.
fn stroke_across_the_middle(doc: &mut Doc, (w, h): (u32, u32)) -> Steps {
    let mut diff = HintDiff::default();
    doc.hints.stroke([w as f64 * 0.4, h as f64 * 0.5], [w as f64 * 0.6, h as f64 * 0.5], 3.0, 1, &mut diff);
    doc.commit_stroke(diff)
}

fn run(o: &Opened, steps: Steps, visible: Option<[u32; 4]>) -> (Vec<Msg>, Steps) {
    run_doc(&o.project, &Doc::new(o.small.clone(), o.hints.clone()), steps, visible)
}

fn done_steps(msgs: &[Msg]) -> Vec<Step> {
    msgs.iter().filter_map(|m| if let Msg::StepDone { step, .. } = m { Some(*step) } else { None }).collect()
}

/// Every output file (not the inputs the tool writes) by relative path.
fn outputs(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for sub in ["classify", "restore", "relight", "comp", "preview"] {
        collect(dir, &dir.join(sub), &mut out);
    }
    let inputs = ["classify/picks.json", "classify/mask.png", "restore/hints.png", "relight/lighting.toml"];
    out.retain(|p, _| !inputs.iter().any(|i| p == Path::new(i)));
    out
}

fn collect(base: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for e in rd {
        let p = e.unwrap().path();
        if p.is_dir() {
            collect(base, &p, out);
        } else {
            out.insert(p.strip_prefix(base).unwrap().to_path_buf(), std::fs::read(&p).unwrap());
        }
    }
}

#[test]
fn a_parameter_change_reruns_only_what_depends_on_it() {
    let (_tmp, o) = copy_of_template();
    assert_eq!(o.project.missing_steps(&o.small), Steps::NONE);
    let mut doc = Doc::new(o.small.clone(), o.hints.clone());
    let before = outputs(&o.project.dir);

    let stale = doc.edit(|s| s.settings.compensate.e_bound_lux = 60.0);
    let (msgs, _) = run_doc(&o.project, &doc, stale, None);
    assert_eq!(done_steps(&msgs), vec![Step::CompOriginal, Step::CompRestored, Step::CompRelit]);
    let after = outputs(&o.project.dir);
    // Classification and restoration untouched; every scene's frames changed, within the new bound.
    for p in ["classify/labels.png", "restore/labels.png", "relight/relit.png"] {
        assert_eq!(before[Path::new(p)], after[Path::new(p)], "{p} changed");
    }
    assert_ne!(before[Path::new("comp/restored/proj0.png")], after[Path::new("comp/restored/proj0.png")]);
    let figures: Vec<_> = msgs
        .iter()
        .filter_map(|m| if let Msg::Figures { figures, .. } = m { Some(figures.clone()) } else { None })
        .collect();
    assert_eq!(figures.len(), 3);
    assert!(
        figures.iter().all(|f| f.peak_lux <= 60.0 * (1.0 - 0.05) + 1e-9 && f.e_bound_lux == 60.0),
        "{figures:?}"
    );

    // Letting the model choose the clip fraction compensates every scene again, with
    // `--auto-clip` on each compensate line; the fraction it took is one it judged.
    let stale = doc.edit(|s| s.settings.compensate.auto_clip = true);
    let lines = o.project.commands(Step::CompRestored, &doc.small, &o.hints, Path::new(""));
    assert!(lines[0].iter().any(|a| a == "--auto-clip"), "{lines:?}");
    let (msgs, _) = run_doc(&o.project, &doc, stale, None);
    assert_eq!(done_steps(&msgs), vec![Step::CompOriginal, Step::CompRestored, Step::CompRelit]);
    let summary =
        restage_authoring::compensate::io::Summary::load(&o.project.dir.join("comp/restored")).unwrap();
    let judged: Vec<f64> = summary.stats.clip_judged.iter().map(|j| j[0]).collect();
    assert!(judged.contains(&summary.clip_fraction), "{} of {judged:?}", summary.clip_fraction);
    assert!(summary.stats.peak_lux <= 60.0 * (1.0 - 0.05) + 1e-9);

    let stale = doc.edit(|s| s.settings.restore.alpha = 6.0);
    let (msgs, _) = run_doc(&o.project, &doc, stale, None);
    assert_eq!(done_steps(&msgs), vec![Step::Restore, Step::Relight, Step::CompRestored, Step::CompRelit]);

    let stale = doc.edit(|s| s.settings.relight.noise = 0.0);
    let (msgs, _) = run_doc(&o.project, &doc, stale, None);
    assert_eq!(done_steps(&msgs), vec![Step::Relight, Step::CompRelit]);

    // Undo brings the document back and makes the same steps stale again.
    assert_eq!(doc.undo(), Steps::from_iter([Step::Relight, Step::CompRelit]));
    assert_eq!(doc.small.settings.relight.noise, 0.3);
}

#[test]
fn a_hint_stroke_restores_the_visible_region_first() {
    let (_tmp, o) = copy_of_template();
    let mut doc = Doc::new(o.small.clone(), o.hints.clone());
    let (w, h) = o.project.photo_size;
    let stale = stroke_across_the_middle(&mut doc, (w, h));
    assert!(
        stale.contains(Step::Restore)
            && !stale.contains(Step::Classify)
            && !stale.contains(Step::CompOriginal)
    );
    let visible = [w / 4, h / 4, w / 2, h / 2];
    let (msgs, left) = run_doc(&o.project, &doc, stale, Some(visible));
    assert_eq!(left, Steps::NONE);
    let partial =
        msgs.iter().position(|m| matches!(m, Msg::Partial { .. })).expect("a visible-region result");
    let full = msgs.iter().position(|m| matches!(m, Msg::StepDone { step: Step::Restore, .. })).unwrap();
    assert!(partial < full);
    let Msg::Partial { rect, image, .. } = &msgs[partial] else { unreachable!() };
    assert_eq!(*rect, visible);
    assert_eq!((image.width(), image.height()), (visible[2], visible[3]));
    // The stroke is in the restoration: its pixels show class 1's colour.
    let restored = image::open(o.project.path("restore/restored.png")).unwrap().to_rgb8();
    let colours = o.project.class_colours(&doc.small.picks);
    let c = restored.get_pixel(w / 2, h / 2).0;
    assert_eq!(c, colours[1], "restored pixel under the stroke");
    // The visible part agrees with the whole restoration inside, away from its border.
    let inner = (visible[0] + 8..visible[0] + visible[2] - 8)
        .flat_map(|x| (visible[1] + 8..visible[1] + visible[3] - 8).map(move |y| (x, y)));
    let (mut same, mut n) = (0, 0);
    for (x, y) in inner {
        n += 1;
        let p = image.get_pixel(x - visible[0], y - visible[1]).0;
        same += usize::from([p[0], p[1], p[2]] == restored.get_pixel(x, y).0);
    }
    assert!(same as f64 >= 0.97 * n as f64, "visible region vs whole: {same} of {n} equal");
}

#[test]
fn cancel_stops_between_steps_and_keeps_what_is_left_stale() {
    let (_tmp, o) = copy_of_template();
    let doc = Doc::new(o.small.clone(), o.hints.clone());
    let steps = Steps::from_iter([Step::Restore]).with_dependents();
    let (msgs, left, _) = run_stopped_at_second_check(&o.project, &request(&doc, 7, steps, None));
    assert_eq!(done_steps(&msgs), vec![Step::Restore]);
    assert!(matches!(msgs.last(), Some(Msg::Cancelled { generation: 7 })));
    assert_eq!(left, Steps::from_iter([Step::Relight, Step::CompRestored, Step::CompRelit]));
}

#[test]
fn a_newer_request_supersedes_the_whole_restoration_once_its_visible_region_is_shown() {
    let (_tmp, o) = copy_of_template();
    let mut doc = Doc::new(o.small.clone(), o.hints.clone());
    let (w, h) = o.project.photo_size;
    let steps = stroke_across_the_middle(&mut doc, (w, h));
    let before = std::fs::read(o.project.path("restore/restored.png")).unwrap();
    // Asked before the step (no) and once the visible region is out (yes: a newer stroke).
    let req = request(&doc, 3, steps, Some([w / 4, h / 4, w / 2, h / 2]));
    let (msgs, left, calls) = run_stopped_at_second_check(&o.project, &req);
    assert_eq!(calls, 2);
    assert!(msgs.iter().any(|m| matches!(m, Msg::Partial { generation: 3, .. })));
    assert!(done_steps(&msgs).is_empty(), "{msgs:?}");
    assert!(matches!(msgs.last(), Some(Msg::Cancelled { generation: 3 })));
    // The whole restoration did not run: still stale, its output untouched.
    assert_eq!(left, steps);
    assert_eq!(std::fs::read(o.project.path("restore/restored.png")).unwrap(), before);
}

#[test]
fn picks_regions_and_hints_round_trip_through_the_cli_byte_for_byte() {
    let (_tmp, o) = copy_of_template();
    let mut doc = Doc::new(o.small.clone(), o.hints.clone());
    let (w, h) = o.project.photo_size;
    // A conservator's session: one more pick, a new restored colour, a region, a stroke.
    doc.edit(|s| {
        s.picks.colours[0].pixels.push([w as i64 / 2, 5]);
        s.picks.colours[1].display_srgb8 = Some([200, 40, 30]);
        s.settings.restore.regions.push(RegionSpec::Rect {
            x: 10,
            y: 10,
            width: w - 20,
            height: h - 20,
            background: Some(0),
        });
        s.settings.restore.alpha = 3.0;
        s.settings.compensate.m = None;
    });
    let mut diff = HintDiff::default();
    doc.hints.stroke([50.0, 60.0], [90.0, 70.0], 2.0, 1, &mut diff);
    doc.commit_stroke(diff);
    let (msgs, left) = run_doc(&o.project, &doc, all_steps(), None);
    assert_eq!(left, Steps::NONE, "{msgs:?}");
    let tool = outputs(&o.project.dir);
    assert!(tool.len() > 20);

    // What the tool saved, and nothing it computed, goes to a fresh folder; steps.sh remakes the rest.
    let tmp2 = tempfile::tempdir().unwrap();
    let dir2 = tmp2.path().join("cli");
    copy(&o.project.dir, &dir2);
    for sub in ["restore/labels.png", "restore/restored.png", "restore/before_after.png", "relight/relit.png"]
    {
        std::fs::remove_file(dir2.join(sub)).unwrap();
    }
    for sub in ["comp", "preview"] {
        std::fs::remove_dir_all(dir2.join(sub)).unwrap();
    }
    for f in ["labels.png", "palette.json", "preview.png"] {
        std::fs::remove_file(dir2.join("classify").join(f)).unwrap();
    }
    let exe = cli_binary();
    let st = std::process::Command::new("sh")
        .arg(dir2.join("steps.sh"))
        .env("RESTAGE_AUTHOR", &exe)
        .status()
        .unwrap();
    assert!(st.success(), "steps.sh failed");
    let cli = outputs(&dir2);
    assert_eq!(tool.keys().collect::<Vec<_>>(), cli.keys().collect::<Vec<_>>());
    for (p, bytes) in &tool {
        assert!(bytes == &cli[p], "{} differs between the tool and the CLI", p.display());
    }
    let script = std::fs::read_to_string(dir2.join("steps.sh")).unwrap();
    assert!(
        script.contains("--region rect:10,10,")
            && script.contains("--hints restore/hints.png")
            && script.contains("--m inf"),
        "{script}"
    );
}

/// The `restage-author` binary beside this test binary (cargo builds it for the crate's
/// integration tests).
fn cli_binary() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap().parent().unwrap();
    let bin = dir.join(format!("restage-author{}", std::env::consts::EXE_SUFFIX));
    assert!(bin.is_file(), "{} is missing: build it first (cargo build -p restage-authoring)", bin.display());
    bin
}

#[test]
fn unreadable_files_are_named_kept_and_nothing_else_is_lost() {
    let (_tmp, o) = copy_of_template();
    let dir = o.project.dir.clone();
    let picks = dir.join(PICKS_FILE);
    std::fs::write(&picks, b"{ this is not json").unwrap();
    std::fs::write(dir.join("relight/lighting.toml"), b"ambient = \"bright\"").unwrap();
    let o2 = Project::open(&dir).unwrap();
    assert_eq!(o2.problems.len(), 2, "{:?}", o2.problems);
    assert!(
        o2.problems[0].path.ends_with(PICKS_FILE) && o2.problems[0].message.contains("picks.json"),
        "{:?}",
        o2.problems
    );
    assert!(o2.small.picks.colours.is_empty());
    // Everything else still opens: settings, hints, and the outputs stay on disk.
    assert_eq!(o2.small.settings, o.small.settings);
    assert_eq!(o2.project.missing_steps(&o2.small), Steps::NONE);
    let mut p = o2.project.clone();
    p.save(&o2.small, &o2.hints).unwrap();
    assert_eq!(std::fs::read(dir.join("classify/picks.json.unreadable")).unwrap(), b"{ this is not json");
    assert!(dir.join("relight/lighting.toml.unreadable").is_file());

    // A corrupt output: the picture cannot be shown, the message names it, the step can re-run.
    std::fs::write(dir.join("restore/restored.png"), b"not a png").unwrap();
    let runner = Runner::new(Project::open(&dir).unwrap().project);
    let mut msgs = Vec::new();
    runner.load_views(Step::Restore, &mut |m| msgs.push(m));
    assert!(
        matches!(&msgs[..], [Msg::Unreadable { step: Step::Restore, message }] if message.contains("restored.png")),
        "{msgs:?}"
    );

    // A project folder with missing steps lists them.
    std::fs::remove_dir_all(dir.join("comp")).unwrap();
    let o3 = Project::open(&dir).unwrap();
    assert_eq!(
        o3.project.missing_steps(&o3.small),
        Steps::from_iter([Step::CompOriginal, Step::CompRestored, Step::CompRelit])
    );

    // Not a project at all.
    let empty = tempfile::tempdir().unwrap();
    let err = Project::open(empty.path()).err().unwrap();
    assert!(format!("{err:#}").contains("--new-virtual"), "{err:#}");
}

#[test]
fn export_writes_and_verifies_a_signed_bundle() {
    let (_tmp, o) = copy_of_template();
    let mut s = o.small.settings.clone();
    s.export.scenes = vec![Scene::Original, Scene::Restored];
    let text = super::export::write_and_verify(&o.project, &s).unwrap();
    assert!(text.contains("OK ") && text.contains("restored") && text.contains("peak"), "{text}");
    assert!(o.project.path("bundle.restage").is_file());
    let summary = super::export::policy_summary(&s.export, Some(100.0)).unwrap();
    assert!(summary.contains("lx·h") && summary.contains("a day"), "{summary}");
    // A scene that was never compensated is refused, naming it.
    std::fs::remove_dir_all(o.project.comp_dir(Scene::Restored)).unwrap();
    let err = super::export::write_and_verify(&o.project, &s).unwrap_err();
    assert!(format!("{err:#}").contains("restored"), "{err:#}");
}

#[test]
fn a_demo_layout_and_a_capture_folder_open_as_projects() {
    let (_tmp, o) = copy_of_template();
    let dir = o.project.dir.clone();
    // The demo's output has no project.toml: one is made from the layout.
    std::fs::remove_file(dir.join(super::project::PROJECT_FILE)).unwrap();
    let o2 = Project::open(&dir).unwrap();
    assert!(dir.join(super::project::PROJECT_FILE).is_file());
    assert_eq!(o2.project.paths.stage.as_deref(), Some(Path::new("stage")));
    assert_eq!(o2.project.paths.photo, Path::new("capture/photo.png"));
    assert_eq!(o2.small.settings.restore.loss, o.small.settings.restore.loss, "the clay class stays loss");
    // A capture folder and its stage model, copied into a new project.
    let tmp = tempfile::tempdir().unwrap();
    let o3 =
        Project::create_from_capture(&tmp.path().join("new"), &dir.join("capture"), Some(&dir.join("stage")))
            .unwrap();
    assert!(o3.project.has_virtual_stage());
    assert!(o3.small.picks.colours.is_empty());
    assert!(o3.project.missing_steps(&o3.small).contains(Step::CompOriginal));
    assert!(o3.project.path("stage/stage.bin").is_file());
}
