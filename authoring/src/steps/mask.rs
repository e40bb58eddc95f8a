//! The mask step (`restage-author mask --stage STAGE [--outline OUTLINE.json] --out DIR`):
//! which camera pixels are the painted object — the automatic proposal from the stage
//! model's geometry, or the conservator's outline — as `object_mask.png` (255 = object) and
//! `mask.json` (what was found and decided).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::segment::{
    self, MASK_FILE, MaskSummary, Outline, SUMMARY_FILE, SegmentParams, Segmentation,
};
use restage_authoring::stage_model::{STAGE_FILE, StageModel};

use super::Progress;

#[derive(Args, Debug, Clone)]
pub struct MaskArgs {
    /// The stage model: its folder, or its stage.bin (needed for the automatic proposal).
    #[arg(long, required_unless_present = "photo")]
    pub stage: Option<PathBuf>,
    /// Without a stage model: the photo whose size the outline is drawn on (the mask is then
    /// the outline alone).
    #[arg(long, requires = "outline", conflicts_with = "stage")]
    pub photo: Option<PathBuf>,
    /// The conservator's outline (JSON list of polygons in camera pixels; docs/formats.md):
    /// inside the polygons is object, replacing the automatic proposal.
    #[arg(long)]
    pub outline: Option<PathBuf>,
    /// Keep the outline exactly as drawn (by default the pixels on supports the proposal
    /// removed, such as a plinth's top inside a loose outline, are taken off).
    #[arg(long)]
    pub no_trim: bool,
    /// Pixels taken off the proposal's silhouette.
    #[arg(long, default_value_t = 0)]
    pub erode: u32,
    /// Seed of the plane search (the same seed gives the same mask).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output folder for object_mask.png and mask.json (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
}

impl MaskArgs {
    /// The proposal's parameters these arguments ask for.
    pub fn params(&self) -> SegmentParams {
        SegmentParams { seed: self.seed, erode: self.erode, ..SegmentParams::default() }
    }
}

/// What the mask step did.
#[derive(Debug)]
pub struct MaskStepSummary {
    pub summary: MaskSummary,
    pub mask_path: PathBuf,
    pub compute: Duration,
}

impl std::fmt::Display for MaskStepSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.summary;
        let removed: Vec<String> = s
            .planes
            .iter()
            .filter(|p| p.removed)
            .map(|p| {
                format!(
                    "{} px, normal ({:.2}, {:.2}, {:.2})",
                    p.region_pixels, p.normal[0], p.normal[1], p.normal[2]
                )
            })
            .collect();
        write!(
            f,
            "object mask from the {}: {} px object of {} px reconstructed; {} support{} removed{}; \
             {} component{} dropped ({} px); {} hole px filled",
            s.source,
            s.object_pixels,
            s.reconstructed_pixels,
            removed.len(),
            if removed.len() == 1 { "" } else { "s" },
            if removed.is_empty() { String::new() } else { format!(" [{}]", removed.join("; ")) },
            s.dropped_components,
            if s.dropped_components == 1 { "" } else { "s" },
            s.dropped_pixels,
            s.holes_filled,
        )?;
        if let Some(o) = &s.outline {
            write!(
                f,
                "; outline: {} polygons, {} px inside, {} px trimmed",
                o.polygons, o.inside_pixels, o.trimmed_pixels
            )?;
        }
        write!(f, "; {} ({:.3} s)", self.mask_path.display(), self.compute.as_secs_f64())
    }
}

/// Reads a stage model from its folder or its `stage.bin`.
pub fn load_stage(path: &Path) -> Result<StageModel> {
    let dir = if path.is_file() {
        if path.file_name().is_none_or(|n| n != STAGE_FILE) {
            bail!("{}: expected a stage model folder or its {STAGE_FILE}", path.display());
        }
        path.parent().unwrap_or(Path::new("."))
    } else {
        path
    };
    StageModel::load(dir).with_context(|| format!("loading the stage model {}", path.display()))
}

/// Runs the step as its arguments say.
pub fn run(args: &MaskArgs, progress: &dyn Progress) -> Result<MaskStepSummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    let outline = match &args.outline {
        Some(p) => Some(Outline::load(p).context("reading the outline")?),
        None => None,
    };
    let (seg, compute) = match (&args.stage, &args.photo, &outline) {
        (Some(stage), _, _) => {
            progress.stage("loading the stage model");
            let stage = load_stage(stage)?;
            progress.stage("finding the object");
            let t0 = Instant::now();
            (segment_stage(&stage, outline.as_ref(), args)?, t0.elapsed())
        }
        (None, Some(photo), Some(outline)) => {
            let (w, h) = image::image_dimensions(photo)
                .with_context(|| format!("reading the size of {}", photo.display()))?;
            let t0 = Instant::now();
            (segment::outline_only(w, h, outline).context("applying the outline")?, t0.elapsed())
        }
        _ => bail!("the mask step needs --stage (a proposal), or --photo with --outline"),
    };
    progress.stage("writing the mask");
    let mask_path = write(&args.out, &seg)?;
    Ok(MaskStepSummary { summary: seg.summary, mask_path, compute })
}

/// The proposal on `stage`, replaced by `outline` where given.
pub fn segment_stage(stage: &StageModel, outline: Option<&Outline>, args: &MaskArgs) -> Result<Segmentation> {
    let proposal = segment::propose(stage, &args.params()).context("proposing the object mask")?;
    Ok(match outline {
        Some(o) => segment::apply_outline(&proposal, o, !args.no_trim).context("applying the outline")?,
        None => proposal,
    })
}

/// Writes `object_mask.png` and `mask.json` into `out`; returns the mask's path.
pub fn write(out: &Path, seg: &Segmentation) -> Result<PathBuf> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mask_path = out.join(MASK_FILE);
    segment::save_mask(&mask_path, seg.width, seg.height, &seg.mask)?;
    let json_path = out.join(SUMMARY_FILE);
    let text = serde_json::to_string_pretty(&seg.summary).context("writing the mask summary")?;
    std::fs::write(&json_path, text + "\n").with_context(|| format!("writing {}", json_path.display()))?;
    Ok(mask_path)
}
