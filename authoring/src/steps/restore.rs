//! The restore step (`restage-author restore CLASSIFY_DIR --out DIR`): contour restoration of a classified label
//! map (paper §4.2-4.4) into `labels.png`, `restored.png` and `before_after.png`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::Progress;

use anyhow::{Context, Result, bail};
use clap::Args;
use restage_authoring::classify::Picks;
use restage_authoring::restore::io::{
    BEFORE_AFTER_FILE, LABELS_FILE, RESTORED_FILE, class_info, display_colours, load_classified, load_hints,
    load_mask, save_rgb,
};
use restage_authoring::restore::{
    self, ClassInfo, HintMap, LabelMap, MASKED, Region, RestoreParams, RestoreStats, Shape,
};

#[derive(Args, Debug, Clone)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct RestoreArgs {
    /// The classification's output directory (`labels.png`, `palette.json`).
    pub classify_dir: PathBuf,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Stop when every contour point's energy is at most alpha (> 0; paper 1..8). Smaller
    /// smooths more: with --scale 10, alpha 2 smooths bends tighter than 5 px radius.
    #[arg(long, default_value_t = 2.0)]
    pub alpha: f64,
    /// Emphasis on keeping the spacing to neighbouring contours (>= 1; paper 1.5..8).
    #[arg(long, default_value_t = 3.0)]
    pub beta: f64,
    /// Compensation-compliant changes: no pixel may get brighter than its original class by
    /// more than this relative luminance (0..1). Off when not given.
    #[arg(long)]
    pub gamma: Option<f64>,
    /// Segments on each side whose normals are averaged for the curvature.
    #[arg(long, default_value_t = 3)]
    pub neighbours: usize,
    /// Length unit of the curvature in px (a circle of radius r has kappa = scale / r).
    #[arg(long, default_value_t = 10.0)]
    pub scale: f64,
    /// A class that stands for loss (bare clay in chips and cracks), repeatable: each of its
    /// pixels takes the nearest other class before the contours are smoothed.
    #[arg(long = "loss")]
    pub loss: Vec<u8>,
    /// Region to restore, repeatable: `rect:X,Y,W,H`, `poly:X1,Y1,X2,Y2,X3,Y3,...` (pixel
    /// coordinates) or `mask:PATH.png`; append `@K` for its background class. Default: the
    /// whole image.
    #[arg(long = "region")]
    pub regions: Vec<String>,
    /// Background class for regions that do not name one (default: each region's most
    /// common class).
    #[arg(long)]
    pub background: Option<u8>,
    /// Hint strokes: RGBA PNG of the label map's size painted in class display colours.
    #[arg(long)]
    pub hints: Option<PathBuf>,
    /// Picks file whose `display_srgb8` colours the restored image (revives faded paint).
    #[arg(long)]
    pub picks: Option<PathBuf>,
    /// Grid of cells `GxH` (§4.3), or `auto` for cells of about 256 px.
    #[arg(long, default_value = "auto")]
    pub grid: String,
    /// Object mask (the mask step's `object_mask.png`; non-zero = object): pixels outside are
    /// not restored (black in the outputs) and never lend their colour to a fill.
    #[arg(long)]
    pub mask: Option<PathBuf>,
}

/// What one restoration run did.
#[derive(Debug)]
pub struct RestoreSummary {
    pub stats: RestoreStats,
    pub changed_pixels: usize,
    /// Classified pixels the mask took out (not restored, black in the outputs).
    pub masked_pixels: usize,
    pub compute: Duration,
}

impl std::fmt::Display for RestoreSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.stats;
        write!(
            f,
            "restored {} contours ({} points, {} anchors) in {} cells: {} moves, {} points dropped, \
             {} holes filled, {} specks removed, {} pixels kept by gamma{}; {} pixels changed{}; {:.3} s",
            s.contours,
            s.points,
            s.anchors,
            s.cells,
            s.moves,
            s.removed_points,
            s.holes_filled,
            s.specks_removed,
            s.clamped_pixels,
            if s.capped_cells > 0 {
                format!(" ({} cells hit the move cap)", s.capped_cells)
            } else {
                String::new()
            },
            self.changed_pixels,
            if self.masked_pixels > 0 {
                format!("; {} pixels outside the object mask left out", self.masked_pixels)
            } else {
                String::new()
            },
            self.compute.as_secs_f64()
        )
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &RestoreArgs, progress: &dyn Progress) -> Result<RestoreSummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    restore_files(args, progress)
}

/// Parses `GxH` or `auto` (cells of about 256 px for a `w` x `h` image).
pub fn parse_grid(text: &str, w: u32, h: u32) -> Result<(u32, u32)> {
    if text == "auto" {
        return Ok((w.div_ceil(256).max(1), h.div_ceil(256).max(1)));
    }
    let Some((g, hh)) = text.split_once(['x', 'X']) else {
        bail!("--grid {text}: expected GxH (e.g. 8x8) or auto")
    };
    let g: u32 = g.trim().parse().with_context(|| format!("--grid {text}: bad column count"))?;
    let hh: u32 = hh.trim().parse().with_context(|| format!("--grid {text}: bad row count"))?;
    Ok((g, hh))
}

/// Parses one `--region` (see [`RestoreArgs::regions`]).
pub fn parse_region(text: &str, w: u32, h: u32, background: Option<u8>) -> Result<Region> {
    let (body, bg) = match text.rsplit_once('@') {
        Some((b, k)) => {
            (b, Some(k.trim().parse::<u8>().with_context(|| format!("--region {text}: bad class after @"))?))
        }
        None => (text, background),
    };
    let Some((kind, rest)) = body.split_once(':') else {
        bail!("--region {text}: expected rect:X,Y,W,H, poly:X1,Y1,... or mask:PATH")
    };
    let numbers = || -> Result<Vec<f64>> {
        rest.split(',')
            .map(|v| {
                v.trim().parse::<f64>().with_context(|| format!("--region {text}: '{v}' is not a number"))
            })
            .collect()
    };
    let shape = match kind {
        "rect" => {
            let v = numbers()?;
            if v.len() != 4 || v.iter().any(|x| *x < 0.0 || x.fract() != 0.0) {
                bail!("--region {text}: rect needs 4 non-negative integers X,Y,W,H");
            }
            Shape::Rect { x: v[0] as u32, y: v[1] as u32, width: v[2] as u32, height: v[3] as u32 }
        }
        "poly" => {
            let v = numbers()?;
            if v.len() < 6 || v.len() % 2 != 0 {
                bail!("--region {text}: poly needs at least 3 X,Y pairs");
            }
            Shape::Polygon(v.chunks_exact(2).map(|p| [p[0], p[1]]).collect())
        }
        "mask" => Shape::Mask { width: w, height: h, inside: load_mask(Path::new(rest), w, h)? },
        other => bail!("--region {text}: unknown kind '{other}' (rect, poly or mask)"),
    };
    Ok(Region { shape, background: bg })
}

/// What the restore step reads, parsed and checked: the classification, its display
/// colours, the regions, the hint strokes and the parameters.
pub struct RestoreInputs {
    pub labels: LabelMap,
    pub info: ClassInfo,
    pub colours: Vec<[u8; 3]>,
    pub regions: Vec<Region>,
    pub hints: Option<HintMap>,
    pub params: RestoreParams,
    /// Classified pixels the object mask took out (already [`MASKED`] in `labels`).
    pub masked_pixels: usize,
}

/// Reads and checks everything `args` names.
pub fn load_inputs(args: &RestoreArgs) -> Result<RestoreInputs> {
    let (mut labels, palette) = load_classified(&args.classify_dir)
        .with_context(|| format!("reading classification {}", args.classify_dir.display()))?;
    // Outside the object mask nothing is paint: masked before anything reads the labels, so
    // those pixels are neither restored nor a source of fill.
    let mut masked_pixels = 0;
    if let Some(p) = &args.mask {
        let inside = restage_authoring::segment::load_mask(p, labels.width, labels.height)
            .with_context(|| format!("reading the object mask for {}", args.classify_dir.display()))?;
        for (l, &m) in labels.data.iter_mut().zip(&inside) {
            if !m && *l != MASKED {
                *l = MASKED;
                masked_pixels += 1;
            }
        }
    }
    let picks = match &args.picks {
        Some(p) => Some(Picks::load(p).with_context(|| format!("reading picks {}", p.display()))?),
        None => None,
    };
    let colours = display_colours(&palette, picks.as_ref());
    let (w, h) = (labels.width, labels.height);
    let regions: Vec<Region> =
        args.regions.iter().map(|r| parse_region(r, w, h, args.background)).collect::<Result<_>>()?;
    let regions = if regions.is_empty() && args.background.is_some() {
        vec![Region { shape: Shape::Whole, background: args.background }]
    } else {
        regions
    };
    let hints = match &args.hints {
        Some(p) => Some(load_hints(p, w, h, &colours).context("reading hint strokes")?),
        None => None,
    };
    let params = RestoreParams {
        alpha: args.alpha,
        beta: args.beta,
        gamma: args.gamma,
        neighbours: args.neighbours,
        scale_px: args.scale,
        loss_classes: args.loss.clone(),
        grid: parse_grid(&args.grid, w, h)?,
        ..RestoreParams::default()
    };
    Ok(RestoreInputs { labels, info: class_info(&palette), colours, regions, hints, params, masked_pixels })
}

/// Reads the classification, restores it and writes the three outputs into `args.out`.
pub fn restore_files(args: &RestoreArgs, progress: &dyn Progress) -> Result<RestoreSummary> {
    progress.stage("reading the classification");
    let RestoreInputs { labels, info, colours, regions, hints, params, masked_pixels } = load_inputs(args)?;
    let (w, h) = (labels.width, labels.height);
    progress.stage(&format!("restoring {w}x{h} in {}x{} cells", params.grid.0, params.grid.1));
    let t0 = Instant::now();
    let mut restored = restore::restore(&labels, &info, &regions, hints.as_ref(), &params)
        .with_context(|| format!("restoring {}", args.classify_dir.display()))?;
    if masked_pixels > 0 {
        // Restoration never grows paint over masked pixels; held here whatever it does.
        for (r, &l) in restored.labels.data.iter_mut().zip(&labels.data) {
            if l == MASKED {
                *r = MASKED;
            }
        }
    }
    let compute = t0.elapsed();
    progress.stage("writing outputs");
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    restored.labels.save(&args.out.join(LABELS_FILE))?;
    save_rgb(&args.out.join(RESTORED_FILE), &restore::render_labels(&restored.labels, &colours))?;
    save_rgb(&args.out.join(BEFORE_AFTER_FILE), &restore::before_after(&labels, &restored.labels, &colours))?;
    let changed_pixels = labels.data.iter().zip(&restored.labels.data).filter(|(a, b)| a != b).count();
    Ok(RestoreSummary { stats: restored.stats, changed_pixels, masked_pixels, compute })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_and_grids_parse() {
        let r = parse_region("rect:1,2,30,40@3", 100, 100, None).unwrap();
        assert_eq!(r.shape, Shape::Rect { x: 1, y: 2, width: 30, height: 40 });
        assert_eq!(r.background, Some(3));
        let p = parse_region("poly:0,0,10,0,5,8", 100, 100, Some(1)).unwrap();
        assert_eq!(p.background, Some(1));
        assert!(parse_region("circle:1,2", 100, 100, None).unwrap_err().to_string().contains("unknown kind"));
        assert!(parse_region("rect:1,2,3", 100, 100, None).is_err());
        assert_eq!(parse_grid("8x6", 10, 10).unwrap(), (8, 6));
        assert_eq!(parse_grid("auto", 2000, 300).unwrap(), (8, 2));
        assert!(parse_grid("8", 10, 10).is_err());
    }
}
