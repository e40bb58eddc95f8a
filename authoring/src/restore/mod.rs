//! Restoration of a classified label map by contour energy minimisation (paper §4.2-4.4):
//! patches of one colour inside a region are outlined, their contours smoothed under the
//! energy `e = kappa * R * B`, and rasterised back over the region's background colour.
//!
//! Per region, in this order: loss classes (bare clay) filled from the nearest other class,
//! after thin lines across them are bridged;
//! specks removed (smallest first) and small holes filled; the contours minimised and
//! rasterised back over the background; specks and holes once more; the gamma guarantee.
//!
//! Units (so that the paper's ranges behave as it describes, see [`RestoreParams`]):
//! - `kappa` is a turning angle over arc length, expressed relative to a length scale:
//!   `kappa = scale_px * theta / L` (theta in radians, L in px). A circle of radius r px has
//!   `kappa = scale_px / r`; with the default `scale_px = 10`, `alpha = 2` lets a lone contour
//!   keep bends of radius above 5 px and smooths tighter ones, `alpha = 1` smooths up to
//!   10 px, `alpha = 8` only bends under 1.25 px. Smaller alpha smooths more (paper §4.2).
//! - `R` is dimensionless (Eq. 5); distances inside it are in pixels, so `beta (1 + |d - d*|)`
//!   grows by `beta` per pixel of disagreement with the smoothed spacing.
//! - `B` compares intensities as relative luminance Y of the class colours (0..1 of the
//!   camera's full scale, linear light); `gamma` is in the same units.
//!
//! Coordinates: pixels are row-major with integer pixel-centre coordinates (ARCHITECTURE.md).
//! Contours are traced along pixel sides on the *corner lattice*, where lattice point
//! `(u, v)` is pixel coordinate `(u - 0.5, v - 0.5)`; the minimisation's points start at the
//! midpoints of those sides.

mod cleanup;
mod contour;
mod energy;
mod grid;
mod hints;
pub mod io;
mod raster;
mod region;
mod render;
pub mod synthetic;

use thiserror::Error;

pub use cleanup::{fill_holes, fill_losses, remove_specks};
pub use contour::{Contour, Patch, trace_patches};
pub use hints::{HintMap, hints_from_rgba};
pub use region::{Region, Shape};
pub use render::{BEFORE_AFTER_GAP, before_after, boundary_mask, render_labels};

pub use crate::classify::{LabelMap, MASKED};

#[derive(Debug, Error)]
pub enum RestoreError {
    #[error("alpha {0} is out of range (expected > 0, typically 1..=8)")]
    Alpha(f64),
    #[error("beta {0} is out of range (expected >= 1, typically 1.5..=8)")]
    Beta(f64),
    #[error("gamma {0} is out of range (expected >= 0, a luminance tolerance in 0..=1)")]
    Gamma(f64),
    #[error("neighbours {0} is out of range (expected 1..=64)")]
    Neighbours(usize),
    #[error("scale_px {0} is out of range (expected > 0)")]
    Scale(f64),
    #[error("expansion {0} is out of range (expected 0..=0.5 of a cell)")]
    Expansion(f64),
    #[error("grid {0}x{1} is out of range (expected 1..=256 cells on each side)")]
    Grid(u32, u32),
    #[error(
        "label map is {width}x{height} with {len} labels (expected width*height labels, 1..=32768 a side)"
    )]
    LabelSize { width: u32, height: u32, len: usize },
    #[error("label {label} at pixel ({x}, {y}) is not a class (palette has {classes} classes; 255 = masked)")]
    LabelNotInPalette { label: u8, x: u32, y: u32, classes: usize },
    #[error("palette has {0} classes (expected 1..=255)")]
    PaletteSize(usize),
    #[error("region {index}: {problem}")]
    Region { index: usize, problem: String },
    #[error("background class {background} is not a class (palette has {classes} classes)")]
    Background { background: u8, classes: usize },
    #[error("hint map is {got_w}x{got_h}, expected {want_w}x{want_h} like the label map")]
    HintSize { got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("hint colour {rgb:?} at pixel ({x}, {y}) is not a class colour (classes: {classes:?})")]
    HintColour { rgb: [u8; 3], x: u32, y: u32, classes: Vec<[u8; 3]> },
    #[error("hint label {label} at pixel ({x}, {y}) is not a class (palette has {classes} classes)")]
    HintLabel { label: u8, x: u32, y: u32, classes: usize },
}

/// Checks a label map against a palette of `classes` entries: every label a class or masked.
pub fn check_labels(labels: &LabelMap, classes: usize) -> Result<(), RestoreError> {
    if classes == 0 || classes > 255 {
        return Err(RestoreError::PaletteSize(classes));
    }
    if labels.data.len() != labels.width as usize * labels.height as usize {
        return Err(RestoreError::LabelSize {
            width: labels.width,
            height: labels.height,
            len: labels.data.len(),
        });
    }
    if let Some(i) = labels.data.iter().position(|&l| l != MASKED && l as usize >= classes) {
        let w = labels.width as usize;
        return Err(RestoreError::LabelNotInPalette {
            label: labels.data[i],
            x: (i % w) as u32,
            y: (i / w) as u32,
            classes,
        });
    }
    Ok(())
}

/// Parameters of the minimisation. Defaults are the paper's typical values where it gives
/// them (alpha 2, beta 3, 25 % cell expansion, 0.2 px point removal).
#[derive(Clone, Debug, PartialEq)]
pub struct RestoreParams {
    /// Stop when every contour point's energy is at most alpha (> 0; paper: 1..8, typically 2).
    /// Smaller alpha smooths more.
    pub alpha: f64,
    /// Emphasis on keeping the smoothed spacing to neighbouring contours (>= 1; paper 1.5..8).
    /// Larger beta keeps contours in their spatial relationship.
    pub beta: f64,
    /// Tolerance on brightening for compensation-compliant changes (Eq. 6), in relative
    /// luminance; `None` switches the B term off.
    pub gamma: Option<f64>,
    /// Segments on each side averaged into the normals used for the curvature (>= 1).
    pub neighbours: usize,
    /// Length unit of kappa in px: a circle of radius r px has kappa = scale_px / r.
    pub scale_px: f64,
    /// How far (px) to look for the closest visible point on a neighbouring contour.
    pub reach_px: f64,
    /// Contour points on each side combined (Gaussian-weighted median) into the smoothed
    /// spacing d*.
    pub spacing_window: usize,
    /// Grid of g x h cells (§4.3); (1, 1) processes a region as one cell.
    pub grid: (u32, u32),
    /// Expansion of each cell to the right and bottom, as a fraction of its size (§4.3).
    pub expansion: f64,
    /// Points closer than this (px) to a neighbour on their contour are removed.
    pub min_spacing_px: f64,
    /// Background holes enclosed by one class up to this area (px) are filled.
    pub max_hole_px: usize,
    /// Components smaller than this area (px) are merged into their surroundings.
    pub min_speck_px: usize,
    /// No contour point moves further than this (px) from where it started (a guard the
    /// paper does not have: without it, Laplacian flow retracts thin stripes from their ends
    /// and shrinks lone dots to nothing).
    pub max_shift_px: f64,
    /// Safety cap on the number of moves, per initial contour point.
    pub max_moves_per_point: usize,
    /// Classes that stand for loss (e.g. bare clay showing through chips and cracks): inside
    /// a region each loss pixel takes the class of the nearest pixel that is not loss, before
    /// the minimisation smooths the contours through the filled chips.
    pub loss_classes: Vec<u8>,
}

impl Default for RestoreParams {
    fn default() -> Self {
        Self {
            alpha: 2.0,
            beta: 3.0,
            gamma: None,
            neighbours: 3,

            reach_px: 48.0,
            spacing_window: 24,
            grid: (1, 1),
            expansion: 0.25,
            min_spacing_px: 0.2,
            scale_px: 10.0,
            max_hole_px: 64,
            min_speck_px: 8,
            max_shift_px: 4.0,
            max_moves_per_point: 40,
            loss_classes: Vec::new(),
        }
    }
}

impl RestoreParams {
    pub fn validate(&self) -> Result<(), RestoreError> {
        if !(self.alpha > 0.0 && self.alpha.is_finite()) {
            return Err(RestoreError::Alpha(self.alpha));
        }
        if !(self.beta >= 1.0 && self.beta.is_finite()) {
            return Err(RestoreError::Beta(self.beta));
        }
        if let Some(g) = self.gamma
            && !(g >= 0.0 && g.is_finite())
        {
            return Err(RestoreError::Gamma(g));
        }
        if !(1..=64).contains(&self.neighbours) {
            return Err(RestoreError::Neighbours(self.neighbours));
        }
        if !(self.scale_px > 0.0 && self.scale_px.is_finite()) {
            return Err(RestoreError::Scale(self.scale_px));
        }
        if !(0.0..=0.5).contains(&self.expansion) {
            return Err(RestoreError::Expansion(self.expansion));
        }
        let (g, h) = self.grid;
        if !(1..=256).contains(&g) || !(1..=256).contains(&h) {
            return Err(RestoreError::Grid(g, h));
        }
        Ok(())
    }
}

/// What the step needs to know about the classes: how bright each is (relative luminance,
/// for the B term) — one entry per class index.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassInfo {
    pub luminance: Vec<f64>,
}

/// Counts of what the minimisation did, for logs and evaluation.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RestoreStats {
    pub cells: usize,
    pub contours: usize,
    pub points: usize,
    pub anchors: usize,
    pub moves: usize,
    pub removed_points: usize,
    /// Cells that hit the move cap before every energy fell to alpha.
    pub capped_cells: usize,
    pub holes_filled: usize,
    pub specks_removed: usize,
    /// Loss pixels (`loss_classes`) filled with the nearest class before the minimisation.
    pub loss_filled: usize,
    /// Pixels put back to their original class because they would brighten beyond gamma.
    pub clamped_pixels: usize,
}

/// The restored label map and what it took.
#[derive(Clone, Debug)]
pub struct Restored {
    pub labels: LabelMap,
    pub stats: RestoreStats,
}

/// Restores `labels` inside each region in turn (the whole image when `regions` is empty).
///
/// `hints` (same size, `None` = no stroke) are painted over the labels first (§4.4); the B
/// term always compares against the original `labels`, which stand for the physical object.
pub fn restore(
    labels: &LabelMap,
    classes: &ClassInfo,
    regions: &[Region],
    hints: Option<&HintMap>,
    params: &RestoreParams,
) -> Result<Restored, RestoreError> {
    params.validate()?;
    let n_classes = classes.luminance.len();
    check_labels(labels, n_classes)?;
    let whole = [Region::whole()];
    let regions = if regions.is_empty() { &whole[..] } else { regions };
    let (w, h) = (labels.width, labels.height);
    let mut masks = Vec::with_capacity(regions.len());
    for (index, r) in regions.iter().enumerate() {
        if let Some(b) = r.background
            && b as usize >= n_classes
        {
            return Err(RestoreError::Background { background: b, classes: n_classes });
        }
        masks.push(r.mask(w, h).map_err(|problem| RestoreError::Region { index, problem })?);
    }
    let mut work = labels.data.clone();
    if let Some(hm) = hints {
        hm.check(w, h, n_classes)?;
        hm.apply(&mut work);
    }
    if let Some(&k) = params.loss_classes.iter().find(|&&k| k as usize >= n_classes) {
        return Err(RestoreError::Background { background: k, classes: n_classes });
    }
    let mut stats = RestoreStats::default();
    for (r, mask) in regions.iter().zip(&masks) {
        let fallback = r.background.unwrap_or_else(|| region::majority(&work, mask, n_classes));
        stats.loss_filled += fill_losses(&mut work, w, h, mask, &params.loss_classes, fallback);
        let background = r.background.unwrap_or_else(|| region::majority(&work, mask, n_classes));
        // Noise removal and hole filling first (the classification's specks and the chips'
        // holes are not contours to smooth: Laplacian flow would shrink each speck's contour
        // and grow each hole's, rather than remove them), then the contours, then once more
        // for what rasterising back left at anchors.
        stats.specks_removed += remove_specks(&mut work, w, h, mask, params.min_speck_px);
        stats.holes_filled += fill_holes(&mut work, w, h, mask, background, params.max_hole_px);
        grid::restore_region(&mut work, &labels.data, w, h, mask, background, classes, params, &mut stats);
        stats.specks_removed += remove_specks(&mut work, w, h, mask, params.min_speck_px);
        stats.holes_filled += fill_holes(&mut work, w, h, mask, background, params.max_hole_px);
        if let Some(gamma) = params.gamma {
            stats.clamped_pixels += cleanup::clamp_brightening(&mut work, &labels.data, mask, classes, gamma);
        }
    }
    Ok(Restored { labels: LabelMap { width: w, height: h, data: work }, stats })
}

#[cfg(test)]
mod tests;
