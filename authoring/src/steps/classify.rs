//! The classify step (`restage-author classify PHOTO --picks PICKS --out DIR`): colour
//! classification of a diffusely lit photo (paper §4.1) into `labels.png`, `palette.json` and
//! `preview.png`, and the regions to confirm (`review.json`, `review.png`).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::Progress;

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::classify::{self, ClassifyOptions, Picks};
use restage_authoring::imgio::LinearImage;
use tracing::info;

#[derive(Args, Debug)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct ClassifyArgs {
    /// The photo: 16-bit linear PNG (a capture set's `photo.png`) or 8-bit sRGB PNG.
    pub photo: PathBuf,
    /// Colour picks: `picks.json` or a strokes PNG (one stroke colour per class).
    #[arg(long)]
    pub picks: PathBuf,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Object mask: 8-bit PNG of the photo's size, non-zero = object. Other pixels get label 255.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Cap on k-means iterations; 1 = nearest calibrated representative (measured best on
    /// the virtual stage), 50 = Lloyd's k-means to convergence as in the paper.
    #[arg(long, default_value_t = 1)]
    pub max_iterations: u32,
    /// How many pseudo-picks of the plain Eq. 1 distance each colour's own spread (the
    /// covariance of its picks) is shrunk towards; `inf` = the paper's Eq. 1 for every colour.
    #[arg(long, default_value_t = classify::DEFAULT_PRIOR_PICKS)]
    pub prior_picks: f64,
    /// A class that is loss (bare substrate: clay in chips and cracks), by index in the picks
    /// (repeat for several; as `restore --loss`). Thin dark lines of it, cracks in shadow,
    /// are then told from dark paint.
    #[arg(long = "loss")]
    pub loss: Vec<u8>,
}

/// What one classification run did, for the summary line and the demo.
#[derive(Debug)]
pub struct ClassifySummary {
    pub classes: usize,
    pub weights: [f64; 3],
    pub iterations: u32,
    pub converged: bool,
    /// Time of the classification itself (no file I/O).
    pub compute: Duration,
    /// Regions the context passes relabelled, listed in `review.json` for the conservator.
    pub review: usize,
}

impl std::fmt::Display for ClassifySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "classified into {} colours; weights a1={:.4} a2={:.4} a3={:.4}; {} k-means iterations{}; {:.3} s",
            self.classes,
            self.weights[0],
            self.weights[1],
            self.weights[2],
            self.iterations,
            match (self.converged, self.iterations) {
                (true, _) => "",
                (false, 1) => " (one assignment pass)",
                (false, _) => " (not converged)",
            },
            self.compute.as_secs_f64()
        )?;
        if self.review > 0 {
            write!(
                f,
                "; {} regions relabelled by their surroundings, to confirm with a pick (review.json, review.png)",
                self.review
            )?;
        }
        Ok(())
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &ClassifyArgs, progress: &dyn Progress) -> Result<ClassifySummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    let opts = ClassifyOptions {
        max_iterations: args.max_iterations,
        prior_picks: args.prior_picks,
        loss: args.loss.clone(),
        ..Default::default()
    };
    classify_files(&args.photo, &args.picks, args.mask.as_deref(), &args.out, &opts, progress)
}

/// Reads the photo, picks and mask, classifies and writes the three outputs into `out`.
pub fn classify_files(
    photo_path: &Path,
    picks_path: &Path,
    mask_path: Option<&Path>,
    out: &Path,
    opts: &ClassifyOptions,
    progress: &dyn Progress,
) -> Result<ClassifySummary> {
    progress.stage("reading photo and picks");
    let photo =
        LinearImage::load(photo_path).with_context(|| format!("reading photo {}", photo_path.display()))?;
    let picks = Picks::load(picks_path).with_context(|| format!("reading picks {}", picks_path.display()))?;
    let mask = match mask_path {
        Some(p) => Some(load_mask(p, photo.width, photo.height)?),
        None => None,
    };
    progress.stage("fitting weights and clustering");
    let t0 = Instant::now();
    let result = classify::classify(&photo, &picks, mask.as_deref(), opts).with_context(|| {
        format!("classifying {} with picks {}", photo_path.display(), picks_path.display())
    })?;
    let compute = t0.elapsed();
    progress.stage("writing outputs");
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (labels_path, palette_path, preview_path) = classify::output_paths(out);
    result.labels.save(&labels_path)?;
    result.palette.save(&palette_path)?;
    let preview = classify::preview(&result.labels, &result.palette);
    preview.save(&preview_path).with_context(|| format!("writing {}", preview_path.display()))?;
    let (review_json, review_png) = classify::review::output_paths(out);
    classify::Review::new(&result.review, &result.palette).save(&review_json)?;
    classify::review::review_image(&preview, &result.review, &result.by_colour.data, &result.labels.data)
        .save(&review_png)
        .with_context(|| format!("writing {}", review_png.display()))?;
    for r in result.review.iter().take(3) {
        let name = |c: u8| result.palette.classes.get(c as usize).map_or("?", |p| p.name.as_str());
        info!(
            pixels = r.pixels,
            at = ?r.pick_at,
            "a region its colour calls {} was given {} by its surroundings: a pick there confirms or corrects it",
            name(r.by_colour),
            name(r.given)
        );
    }
    let p = &result.palette;
    Ok(ClassifySummary {
        classes: p.classes.len(),
        weights: p.weights,
        iterations: p.iterations,
        converged: p.converged,
        compute,
        review: result.review.len(),
    })
}

/// An object mask: any 8-bit or 16-bit PNG of the photo's size; non-zero (any channel) = object.
pub fn load_mask(path: &Path, width: u32, height: u32) -> Result<Vec<bool>> {
    let img = image::open(path).with_context(|| format!("reading mask {}", path.display()))?.to_luma8();
    if img.dimensions() != (width, height) {
        bail!("mask {} is {}x{}, the photo is {width}x{height}", path.display(), img.width(), img.height());
    }
    Ok(img.pixels().map(|p| p.0[0] != 0).collect())
}

/// The demo's stand-in for the conservator: picks (a handful of pixels per colour, seeded)
/// and the object mask, derived from the virtual stage's ground truth in `capture_dir`, written
/// as `picks.json` and `mask.png` into `out`. Returns their paths and the loss classes (the
/// stage's bare clay) as indices into the picks.
pub fn picks_from_ground_truth(
    capture_dir: &Path,
    out: &Path,
    seed: u64,
) -> Result<(PathBuf, PathBuf, Vec<u8>)> {
    use restage_authoring::eval::classify::{PICKS_PER_CLASS, capture_case};
    let case = capture_case(capture_dir)
        .with_context(|| format!("reading ground truth of {}", capture_dir.display()))?;
    let hist = case.truth.histogram(case.names.len());
    let present: Vec<usize> = (0..case.names.len()).filter(|&c| hist[c] > 0).collect();
    let mut dense = case.truth.clone();
    for l in dense.data.iter_mut() {
        if let Some(d) = present.iter().position(|&c| c == *l as usize) {
            *l = d as u8;
        }
    }
    let names: Vec<String> = present.iter().map(|&c| case.names[c].clone()).collect();
    let display: Vec<Option<[u8; 3]>> = present.iter().map(|&c| case.display[c]).collect();
    let picks = classify::picks_from_labels(&dense, &names, &display, PICKS_PER_CLASS, seed)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let picks_path = out.join("picks.json");
    picks.save(&picks_path)?;
    let mask: Vec<u8> =
        case.truth.data.iter().map(|&l| if l == classify::MASKED { 0 } else { 255 }).collect();
    let mask_path = out.join("mask.png");
    image::GrayImage::from_raw(case.truth.width, case.truth.height, mask)
        .expect("one byte per pixel")
        .save(&mask_path)
        .with_context(|| format!("writing {}", mask_path.display()))?;
    let loss =
        present.iter().enumerate().filter(|(_, c)| case.loss.contains(&(**c as u8))).map(|(d, _)| d as u8);
    Ok((picks_path, mask_path, loss.collect()))
}
