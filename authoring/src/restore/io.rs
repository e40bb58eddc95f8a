//! File input/output of the restore step: the classification's output directory (label map
//! and palette), hint strokes and region masks as PNG, results as PNG. Errors name the file.

use std::path::{Path, PathBuf};

use image::RgbImage;
use thiserror::Error;

use super::{ClassInfo, HintMap, LabelMap, RestoreError, check_labels, hints_from_rgba};
use crate::classify::{ClassifyError, Palette, Picks, output_paths};
use crate::imgio::ImageError;

#[derive(Debug, Error)]
pub enum RestoreIoError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Classify(#[from] ClassifyError),
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    #[error("{path}: {source}")]
    Restore { path: PathBuf, source: RestoreError },
}

/// Output file names of the restore step inside its output directory.
pub const LABELS_FILE: &str = "labels.png";
pub const RESTORED_FILE: &str = "restored.png";
pub const BEFORE_AFTER_FILE: &str = "before_after.png";

/// The classification's output read back: its label map and palette, checked to agree.
pub fn load_classified(dir: &Path) -> Result<(LabelMap, Palette), RestoreIoError> {
    let (labels_path, palette_path, _) = output_paths(dir);
    let labels = LabelMap::load(&labels_path)?;
    let palette = Palette::load(&palette_path)?;
    check_labels(&labels, palette.classes.len())
        .map_err(|source| RestoreIoError::Restore { path: labels_path.clone(), source })?;
    Ok((labels, palette))
}

/// What the step needs from a palette: each class's relative luminance (for B).
pub fn class_info(palette: &Palette) -> ClassInfo {
    ClassInfo {
        luminance: palette
            .classes
            .iter()
            .map(|c| crate::color::linear_srgb_to_xyz(c.mean_linear_rgb)[1])
            .collect(),
    }
}

/// Display colours (8-bit sRGB) per class: the picks file's restored colours where it gives
/// them (to revive faded paint), else the palette's.
pub fn display_colours(palette: &Palette, picks: Option<&Picks>) -> Vec<[u8; 3]> {
    (0..palette.classes.len())
        .map(|i| {
            picks
                .and_then(|p| p.colours.get(i))
                .and_then(|c| c.display_srgb8)
                .unwrap_or_else(|| palette.display_colour(i))
        })
        .collect()
}

fn read_sized(path: &Path, width: u32, height: u32) -> Result<image::DynamicImage, RestoreIoError> {
    Ok(crate::imgio::open_sized(path, width, height)?)
}

/// Reads hint strokes (RGBA PNG; transparent = no stroke) against the classes' colours.
pub fn load_hints(
    path: &Path,
    width: u32,
    height: u32,
    class_colours: &[[u8; 3]],
) -> Result<HintMap, RestoreIoError> {
    let img = read_sized(path, width, height)?;
    if !img.color().has_alpha() {
        return Err(RestoreIoError::Invalid {
            path: path.into(),
            problem: "hint strokes need an alpha channel (transparent = no stroke)".into(),
        });
    }
    let px: Vec<[u8; 4]> = img.to_rgba8().pixels().map(|p| p.0).collect();
    hints_from_rgba(width, height, &px, class_colours)
        .map_err(|source| RestoreIoError::Restore { path: path.into(), source })
}

/// Reads a region mask (any PNG; a pixel is inside when its grey value is at least 128).
pub fn load_mask(path: &Path, width: u32, height: u32) -> Result<Vec<bool>, RestoreIoError> {
    let img = read_sized(path, width, height)?;
    Ok(img.to_luma8().pixels().map(|p| p.0[0] >= 128).collect())
}

/// Writes an 8-bit sRGB picture.
pub fn save_rgb(path: &Path, img: &RgbImage) -> Result<(), RestoreIoError> {
    img.save(path).map_err(|source| ImageError::Write { path: path.into(), source }.into())
}
