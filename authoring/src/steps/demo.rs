//! `restage-author demo`: the whole chain on the virtual stage, one step after another.
//! Today: simulate the default scene at a demo-sized capture and write a contact sheet of
//! the capture set. Each later step appends its call to [`run`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use restage_authoring::acquire::AcquireConfig;
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::contact_sheet;
use restage_authoring::gpu::Device;
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, SceneName};

use super::Progress;
use super::demo_chain::ChainSummary;
use super::simulate;

#[derive(clap::Args, Clone, Debug)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct Args {
    /// Output folder for every step's results.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seed of the simulated stage.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where compensation and relighting do their per-pixel work (auto: a hardware GPU if
    /// there is one, else the CPU; gpu: any adapter, lavapipe included).
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    pub device: Device,
    /// Write into an output folder that holds files but is not an earlier demo's. The demo
    /// still deletes nothing there; it replaces the files it writes.
    #[arg(long)]
    pub force: bool,
}

/// The file that marks a folder as the demo's: running the demo again there replaces the
/// demo's own files without `--force`.
pub const MARKER_FILE: &str = ".restage-demo";

/// Checks the output folder before any work and marks it as the demo's: it must be new,
/// empty, an earlier demo's (it holds [`MARKER_FILE`]), or `--force` was given. Returns the
/// folder as an absolute path (files the demo writes name each other by path).
pub fn prepare_out(args: &Args) -> Result<PathBuf> {
    if args.out.is_file() {
        anyhow::bail!("{} is a file; the demo needs a folder for its outputs", args.out.display());
    }
    let marked = args.out.join(MARKER_FILE).is_file();
    let empty = std::fs::read_dir(&args.out).map_or(true, |mut d| d.next().is_none());
    if !(marked || empty || args.force) {
        anyhow::bail!(
            "{} already holds files that are not an earlier demo's; choose a new folder \
             (e.g. --out out/demo2), or pass --force to write the demo's files among them \
             (nothing there is deleted)",
            args.out.display()
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
    let marker = args.out.join(MARKER_FILE);
    std::fs::write(
        &marker,
        "Written by `restage-author demo`: running the demo again here replaces the files it \
         wrote and deletes nothing.\n",
    )
    .with_context(|| format!("cannot write {}", marker.display()))?;
    std::fs::canonicalize(&args.out)
        .with_context(|| format!("cannot resolve output folder {}", args.out.display()))
}

/// The demo's capture: paper-sized projectors, a smaller camera and coarser dot grids and
/// ramps than `simulate`'s defaults, so the whole chain runs in minutes on two cores.
pub fn demo_configs(seed: u64) -> (SceneConfig, AcquireConfig) {
    let scene = SceneConfig {
        scene: SceneName::Vase,
        seed,
        camera: [800, 600],
        projector: [1400, 1050],
        projectors: 3,
        deteriorate: true,
        plinth: false,
        // The reference rig: the README's demo figures and the window's screenshots are of it.
        rig: RigVariation::Nominal,
    };
    let acq = AcquireConfig { dot_spacing: 8, ramp_levels: 9, ..AcquireConfig::default() };
    (scene, acq)
}

/// Runs the whole chain; returns what it has to say (the cli prints it).
pub fn run(args: &Args, progress: &dyn Progress) -> Result<ChainSummary> {
    let start = Instant::now();
    let out = prepare_out(args)?;
    let args = &Args { out, ..args.clone() };
    let capture_dir = args.out.join("capture");

    // Step 1: the virtual stage writes a capture set (and its ground truth).
    let (scene, acq) = demo_configs(args.seed);
    let manifest = simulate::simulate(&scene, &acq, &capture_dir, progress)?;
    let sheet = args.out.join("capture_contact_sheet.png");
    write_contact_sheet(&manifest, &capture_dir, &sheet)?;
    tracing::info!("step 1 (simulate) done at {:.1} s: {}", start.elapsed().as_secs_f64(), sheet.display());
    let images = 1 + manifest.projectors.iter().map(|p| p.shots.len()).sum::<usize>();
    let mut head = format!(
        "1 simulate    {images} camera images of the virtual {} (seed {}), {} projectors\n",
        scene.scene.name(),
        args.seed,
        scene.projectors
    );

    // Step 2: calibrate the stage's geometry. The one length a conservator measures with a tape
    // (camera lens to projector 0's lens) comes from the simulated setup.
    let setup = restage_authoring::stage_sim::Setup::from_config(&scene)?;
    let baseline_mm = setup.projectors[0].centre.norm();
    let stage_dir = args.out.join("stage");
    let known =
        restage_authoring::calibrate::selfcal::KnownLength::Baseline { projector: 0, mm: baseline_mm };
    // The conservator's lux-meter readings (one per projector at full white), taken on the
    // virtual stage with its true physics; calibrate turns them into the lux scale.
    let lux = simulated_lux_readings(&restage_authoring::stage_sim::VirtualStage::new(&scene)?)?;
    tracing::info!(
        "lux meter at camera pixel {:?}, facing each projector in turn: {}",
        lux.reference_pixel,
        lux.white.iter().map(|(k, v)| format!("{k}={v:.1}")).collect::<Vec<_>>().join(",")
    );
    let report = super::calibrate::calibrate(
        &capture_dir,
        &stage_dir,
        super::calibrate::GeometrySource::SelfCalibrate(known),
        Some(&lux),
        progress,
    )?;
    tracing::info!(
        "step 2 (calibrate) done at {:.1} s: {} points, reprojection RMS {:.3} px, {}",
        start.elapsed().as_secs_f64(),
        report.points,
        report.dense_rms_px,
        stage_dir.join("report.png").display()
    );
    head.push_str(&format!(
        "2 calibrate   {} surface points, reprojection error {:.2} px\n",
        report.points, report.dense_rms_px
    ));

    // Step 3: colour classification, with picks the virtual stage derives from its ground truth.
    let classify_dir = args.out.join("classify");
    let (picks, mask, loss) =
        super::classify::picks_from_ground_truth(&capture_dir, &classify_dir, args.seed)?;
    let summary = super::classify::classify_files(
        &capture_dir.join(&manifest.photo),
        &picks,
        Some(&mask),
        &classify_dir,
        &restage_authoring::classify::ClassifyOptions { loss, ..Default::default() },
        progress,
    )?;
    tracing::info!("step 3 (classify) done at {:.1} s: {summary}", start.elapsed().as_secs_f64());

    let mut summary = super::demo_chain::run_chain(
        &args.out,
        &capture_dir,
        &scene,
        &manifest,
        args.seed,
        args.device,
        start,
        &head,
        progress,
    )?;

    // Last: one page that shows every step's pictures and figures, read back from the files.
    progress.stage("writing the report");
    let index = super::report::write(&args.out)?;
    summary.summary.push_str(&format!("report: open {} in a browser\n", index.display()));

    tracing::info!(
        "demo finished in {:.1} s; results in {}",
        start.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(summary)
}

/// The lux-meter readings the virtual stage simulates (see `VirtualStage::lux_meter_session`).
/// No ambient reading is given, so calibration counts the other projectors' black light and
/// the stray light as this projector's (a little more lux than true: the safe side).
pub fn simulated_lux_readings(
    stage: &restage_authoring::stage_sim::VirtualStage,
) -> Result<restage_authoring::calibrate::lux::LuxReadings> {
    use restage_authoring::calibrate::lux::{LuxReadings, Meter};
    let restage_authoring::stage_sim::LuxMeterSession { pixel, readings: values } = stage
        .lux_meter_session()?
        .context("no surface point is lit by every projector: nowhere to hold the lux meter")?;
    Ok(LuxReadings {
        white: values.into_iter().enumerate().collect(),
        reference_pixel: Some(pixel),
        meter: Meter::FacingProjector,
        ambient: None,
    })
}

/// Writes a contact sheet of a capture set: the photo, then one row per projector.
pub fn write_contact_sheet(manifest: &CaptureManifest, dir: &Path, out: &Path) -> Result<()> {
    let tile = 200;
    let gain = 1.6;
    let load = |rel: &Path| LinearImage::load(&dir.join(rel)).context("reading a capture image");
    let mut rows = vec![vec![contact_sheet::thumbnail(&load(&manifest.photo)?, tile, gain)]];
    for (k, p) in manifest.projectors.iter().enumerate() {
        let mut row = Vec::new();
        for pat in contact_sheet::sheet_patterns(manifest, k) {
            let file = p.find(&pat).expect("sheet patterns were captured");
            row.push(contact_sheet::thumbnail(&load(file)?, tile, gain));
        }
        rows.push(row);
    }
    let sheet = contact_sheet::grid(&rows);
    sheet.save(out).with_context(|| format!("cannot write {}", out.display()))?;
    Ok(())
}
