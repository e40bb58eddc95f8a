//! `restage-author gui [PROJECT_DIR]`: the conservator's interactive tool (paper §4-5) over a
//! project folder — colour picks, regions, hint strokes, parameters and the virtual lighting,
//! with every step run in the background by the same code and command lines as the CLI.
//! The window (winit + wgpu + egui, through eframe) is `app`; everything it edits and runs is
//! window-free (`doc`, `project`, `jobs`, `views`, `export`) and tested without one.

pub mod doc;
pub mod export;
pub mod jobs;
pub mod project;
pub mod views;

#[cfg(feature = "gui")]
mod app;
#[cfg(feature = "gui")]
mod gpu;

#[cfg(test)]
mod tests;

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, bail};
use restage_authoring::acquire::AcquireConfig;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, SceneName};

use crate::steps::simulate::Size;
use doc::Steps;
use project::{Opened, Project};

#[derive(clap::Args, Debug, Clone)]
pub struct GuiArgs {
    /// The project folder (see `--new-virtual`, `--from-capture`, `--from-photo` to make one;
    /// the demo's output folder opens as a project too).
    #[arg(default_value = "restage-project")]
    pub project: PathBuf,
    /// Make the project on the virtual stage: vase, bowl or jar.
    #[arg(long, value_name = "SCENE")]
    pub new_virtual: Option<String>,
    /// Seed of the virtual stage.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// With --new-virtual: only the photo (no structured light, no stage model), e.g. for a
    /// 10 MP photo: classification and restoration only.
    #[arg(long)]
    pub photo_only: bool,
    /// Virtual camera size.
    #[arg(long, default_value = "400x300")]
    pub camera: Size,
    /// Virtual projector size.
    #[arg(long, default_value = "512x384")]
    pub projector: Size,
    /// Make the project from a capture folder (capture.json), copied in unless inside it.
    #[arg(long, value_name = "CAPTURE_DIR")]
    pub from_capture: Option<PathBuf>,
    /// With --from-capture: the calibrated stage model folder.
    #[arg(long, value_name = "STAGE_DIR")]
    pub stage: Option<PathBuf>,
    /// Make a photo-only project (classification and restoration, no compensation).
    #[arg(long, value_name = "PHOTO")]
    pub from_photo: Option<PathBuf>,
    /// Run every missing step at once instead of offering to.
    #[arg(long)]
    pub run_missing: bool,
    /// No window: make or open the project, run what --run-missing asks, and exit.
    #[arg(long)]
    pub no_window: bool,
    /// Scripted session: show every view, save a screenshot of each into DIR, and exit.
    #[arg(long, value_name = "DIR")]
    pub screenshots: Option<PathBuf>,
    /// Scripted benchmark: pan the photo, paint a hint stroke while panning and one with the
    /// view still, lower E_bound when there is a stage model, and write the frame times and
    /// the stroke-to-picture latencies to this JSON file, then exit.
    #[arg(long, value_name = "JSON")]
    pub bench: Option<PathBuf>,
    /// Window size in points.
    #[arg(long, default_value = "1280x800")]
    pub window: Size,
}

pub fn run(args: GuiArgs) -> Result<()> {
    if !args.no_window {
        // Before any work: simulating a project takes a minute, then the window could not open.
        check_display()?;
    }
    let opened = open_or_create(&args)?;
    for p in &opened.problems {
        tracing::warn!("{}: {}", p.path.display(), p.message);
    }
    if args.no_window {
        if !args.run_missing {
            bail!("--no-window does nothing without --run-missing");
        }
        return run_missing_headless(opened);
    }
    #[cfg(feature = "gui")]
    {
        app::run_window(opened, &args)
    }
    #[cfg(not(feature = "gui"))]
    {
        bail!(
            "this restage-author was built without the window (feature `gui`); use --no-window --run-missing"
        )
    }
}

/// Checks that a window can open here: a display server to show it and a Vulkan driver to
/// draw it (the window draws with wgpu on Vulkan). Names what to do otherwise.
fn check_display() -> Result<()> {
    if !cfg!(target_os = "linux") {
        return Ok(());
    }
    let set = |v: &str| std::env::var_os(v).is_some_and(|x| !x.is_empty());
    if !set("DISPLAY") && !set("WAYLAND_DISPLAY") {
        bail!(
            "no display to open the window on (neither DISPLAY nor WAYLAND_DISPLAY is set, as over \
             SSH or on a server): run the tool on the computer's desktop or with `ssh -X`, or run the \
             project's steps without a window: --no-window --run-missing"
        );
    }
    let icd_dirs = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"];
    let has_driver = set("VK_ICD_FILENAMES")
        || set("VK_DRIVER_FILES")
        || icd_dirs.iter().any(|d| std::fs::read_dir(d).is_ok_and(|mut e| e.next().is_some()));
    if !has_driver {
        bail!(
            "no Vulkan driver is installed (nothing in /usr/share/vulkan/icd.d), and the window \
             draws with Vulkan: install your graphics card's Vulkan driver, or Mesa's for any \
             computer (`sudo apt-get install mesa-vulkan-drivers` on Debian or Ubuntu); or run the \
             project's steps without a window: --no-window --run-missing"
        );
    }
    Ok(())
}

fn open_or_create(args: &GuiArgs) -> Result<Opened> {
    let made = [args.new_virtual.is_some(), args.from_capture.is_some(), args.from_photo.is_some()];
    if made.iter().filter(|m| **m).count() > 1 {
        bail!("choose one of --new-virtual, --from-capture and --from-photo");
    }
    if let Some(scene) = &args.new_virtual {
        let scene = SceneConfig {
            scene: scene.parse::<SceneName>()?,
            seed: args.seed,
            camera: args.camera.0,
            projector: args.projector.0,
            projectors: 3,
            deteriorate: true,
            plinth: false,
            rig: RigVariation::Seeded,
        };
        scene.validate()?;
        if args.photo_only {
            return Project::create_virtual_photo(&args.project, &scene);
        }
        // Coarse dots and few ramp levels: the project's stage model is the virtual stage's
        // own, so the structured light is only kept for a later calibration.
        let acq = AcquireConfig { dot_spacing: 8, ramp_levels: 9, ..AcquireConfig::default() };
        return Project::create_virtual(&args.project, &scene, &acq);
    }
    if let Some(capture) = &args.from_capture {
        return Project::create_from_capture(&args.project, capture, args.stage.as_deref());
    }
    if let Some(photo) = &args.from_photo {
        return Project::create_from_photo(&args.project, photo);
    }
    Project::open(&args.project)
}

/// Runs every missing step in this thread, printing progress, for scripts and tests.
fn run_missing_headless(opened: Opened) -> Result<()> {
    let Opened { project, small, hints, .. } = opened;
    let steps = project.missing_steps(&small).with_dependents();
    let mut runner = jobs::Runner::new(project);
    let req = jobs::Request { generation: 1, steps, small, hints: Arc::new(hints), visible: None };
    let mut failure = None;
    let left = runner.run(&req, || false, &mut |m| match m {
        jobs::Msg::Progress { done, total, step, .. } => eprintln!("[{}/{total}] {}", done + 1, step.name()),
        jobs::Msg::StepDone { step, seconds, .. } => {
            eprintln!("      {} done in {seconds:.2} s", step.name())
        }
        jobs::Msg::Failed { message, .. } => failure = Some(message),
        jobs::Msg::Unreadable { message, .. } => eprintln!("warning: {message}"),
        _ => {}
    });
    if let Some(f) = failure {
        bail!("{f}");
    }
    if left != Steps::NONE {
        bail!("not every step ran");
    }
    eprintln!("project {} is up to date", runner.project.dir.display());
    Ok(())
}
