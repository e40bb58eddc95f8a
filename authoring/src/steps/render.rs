//! The render step (`restage-author render`): what the camera (a visitor at the camera's place) sees when the
//! projectors show given frames, rendered with the virtual stage's TRUE physics (rebuilt from
//! the capture's `ground-truth/truth.json`). Frames are `FRAMES_DIR/proj<k>.png`, 8-bit RGB
//! device values at each projector's resolution.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use image::RgbImage;
use restage_authoring::stage_sim::{self, VirtualStage};

use super::Progress;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A capture directory written by `simulate` (its `ground-truth/` defines the stage).
    #[arg(long)]
    pub capture: PathBuf,
    /// Folder with one frame per projector: `proj0.png`, `proj1.png`, ...
    #[arg(long)]
    pub frames: PathBuf,
    /// Output camera image: 16-bit linear PNG.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Also write an 8-bit sRGB version for people to look at.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Turn the room's diffuse light on (as for the photo).
    #[arg(long)]
    pub diffuse: bool,
    /// Add the camera's seeded noise (shot number `N`) instead of the noise-free image.
    #[arg(long, value_name = "N")]
    pub noise_shot: Option<u64>,
}

/// The frame file for projector `k`.
pub fn frame_path(dir: &Path, k: usize) -> PathBuf {
    dir.join(format!("proj{k}.png"))
}

/// Reads one 8-bit RGB frame per projector, refusing missing or wrongly sized frames.
pub fn load_frames(stage: &VirtualStage, dir: &Path) -> Result<Vec<RgbImage>> {
    let mut frames = Vec::new();
    for (k, p) in stage.setup().projectors.iter().enumerate() {
        let path = frame_path(dir, k);
        if !path.is_file() {
            bail!(
                "missing frame for projector {k}: {} (expected one {}x{} PNG per projector, proj0.png .. proj{}.png)",
                path.display(),
                p.width,
                p.height,
                stage.projector_count() - 1
            );
        }
        let img = image::open(&path).with_context(|| format!("cannot read frame {}", path.display()))?;
        if (img.width(), img.height()) != (p.width, p.height) {
            bail!(
                "frame {} is {}x{}, but projector {k} is {}x{}",
                path.display(),
                img.width(),
                img.height(),
                p.width,
                p.height
            );
        }
        frames.push(img.to_rgb8());
    }
    Ok(frames)
}

/// Where one render wrote its image.
#[derive(Debug)]
pub struct RenderSummary {
    pub out: PathBuf,
}

impl std::fmt::Display for RenderSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rendered {}", self.out.display())
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &Args, progress: &dyn Progress) -> Result<RenderSummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    if let Some(p) = &args.preview {
        super::check_out(p, args.overwrite.force)?;
    }
    progress.stage("building the virtual stage");
    let config = stage_sim::load_config(&args.capture)?;
    let stage = VirtualStage::new(&config)?;
    progress.stage("rendering");
    run_with(args, &stage)
}

/// The command's work with the virtual stage already built (the interactive tool keeps it).
pub fn run_with(args: &Args, stage: &VirtualStage) -> Result<RenderSummary> {
    let frames = load_frames(stage, &args.frames)?;
    let img = match args.noise_shot {
        Some(shot) => stage.capture(&frames, args.diffuse, shot)?,
        None => stage.render(&frames, args.diffuse)?,
    };
    img.save_linear16(&args.out)?;
    if let Some(preview) = &args.preview {
        img.save_srgb8(preview, 1.0)?;
    }
    Ok(RenderSummary { out: args.out.clone() })
}
