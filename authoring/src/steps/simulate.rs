//! `restage-author simulate`: builds a virtual stage from a built-in scene and seed and writes
//! its capture set (plus `ground-truth/`) exactly as real acquisition would.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::Progress;
use anyhow::{Context, Result};
use restage_authoring::acquire::AcquireConfig;
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, VirtualStage};

/// A `WIDTHxHEIGHT` size on the command line.
#[derive(Clone, Copy, Debug)]
pub struct Size(pub [u32; 2]);

impl std::str::FromStr for Size {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("{s:?} is not WIDTHxHEIGHT"))?;
        let p = |v: &str| v.trim().parse::<u32>().map_err(|e| format!("{s:?}: {v:?} is not a size ({e})"));
        Ok(Size([p(w)?, p(h)?]))
    }
}

/// The patterns to capture; the same options for the virtual stage and real hardware.
#[derive(clap::Args, Debug)]
pub struct PatternArgs {
    /// Dot-grid spacing in projector pixels (spacing^2 dot images per projector).
    #[arg(long, default_value_t = 16)]
    pub dot_spacing: u32,
    /// Phase-shift period in projector pixels.
    #[arg(long, default_value_t = 16)]
    pub phase_period: u32,
    #[arg(long, default_value_t = 8)]
    pub phase_steps: u32,
    /// Gray-ramp levels per channel.
    #[arg(long, default_value_t = 17)]
    pub ramp_levels: u32,
}

impl PatternArgs {
    /// The acquisition settings, checked, with `settle` between showing and grabbing.
    pub fn config(&self, settle: std::time::Duration) -> Result<AcquireConfig> {
        let acq = AcquireConfig {
            dot_spacing: self.dot_spacing,
            phase_period: self.phase_period,
            phase_steps: self.phase_steps,
            ramp_levels: self.ramp_levels,
            settle,
        };
        acq.validate()?;
        Ok(acq)
    }
}

#[derive(clap::Args, Debug)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct Args {
    /// Built-in object: vase, bowl or jar, or a flat painted panel (calibrates only through a
    /// saved rig: `restage-author rig`).
    #[arg(long, default_value = "vase")]
    pub scene: String,
    /// Seed for the deterioration, the projectors' radiometry and the camera noise, and
    /// (with `--rig seeded`) the rig's placement and lenses and the object's form.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// `seeded`: projector placement and lenses, the camera's focal length and the object's
    /// form vary with the seed; `nominal`: the demo's rig at every seed.
    #[arg(long, value_enum, default_value = "seeded")]
    pub rig: RigVariation,
    /// Capture directory to write (created if needed; files in it are replaced).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Camera resolution.
    #[arg(long, default_value = "1024x768")]
    pub camera: Size,
    /// Resolution of every projector.
    #[arg(long, default_value = "1400x1050")]
    pub projector: Size,
    /// Number of projectors around the object.
    #[arg(long, default_value_t = 3)]
    pub projectors: u32,
    #[command(flatten)]
    pub patterns: PatternArgs,
    /// Simulate the object in its pristine state (no deterioration).
    #[arg(long)]
    pub pristine: bool,
    /// Stand the object on a grey plinth: seen and lit like the object but not part of it,
    /// and reflecting light onto it (one bounce of interreflection).
    #[arg(long)]
    pub plinth: bool,
}

impl Args {
    pub fn configs(&self) -> Result<(SceneConfig, AcquireConfig)> {
        let scene = SceneConfig {
            scene: self.scene.parse()?,
            seed: self.seed,
            camera: self.camera.0,
            projector: self.projector.0,
            projectors: self.projectors,
            deteriorate: !self.pristine,
            plinth: self.plinth,
            rig: self.rig,
        };
        scene.validate()?;
        let acq = self.patterns.config(AcquireConfig::default().settle)?;
        Ok((scene, acq))
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &Args, progress: &dyn Progress) -> Result<CaptureManifest> {
    let (scene, acq) = args.configs()?;
    super::check_out(&args.out, args.overwrite.force)?;
    simulate(&scene, &acq, &args.out, progress)
}

/// Simulates `scene` and writes its capture set to `out`; returns the manifest.
pub fn simulate(
    scene: &SceneConfig,
    acq: &AcquireConfig,
    out: &Path,
    progress: &dyn Progress,
) -> Result<CaptureManifest> {
    let start = Instant::now();
    std::fs::create_dir_all(out).with_context(|| format!("cannot create output folder {}", out.display()))?;
    tracing::info!(
        "building the virtual stage: {} seed {}, camera {}x{}, {} projectors {}x{}",
        scene.scene.name(),
        scene.seed,
        scene.camera[0],
        scene.camera[1],
        scene.projectors,
        scene.projector[0],
        scene.projector[1]
    );
    let stage = VirtualStage::new(scene)?;
    tracing::info!("geometry ready in {:.1} s", start.elapsed().as_secs_f64());
    progress.stage("capturing");
    let manifest = stage
        .write_capture_set(out, acq, &mut |done, total| progress.count(done as u64, total as u64))
        .with_context(|| format!("writing the capture set to {}", out.display()))?;
    let images = 1 + manifest.projectors.iter().map(|p| p.shots.len()).sum::<usize>();
    tracing::info!(
        "wrote {images} camera images to {} in {:.1} s",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(manifest)
}
