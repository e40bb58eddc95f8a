//! File input/output of the restore step: label maps as 8-bit grey PNG, hint strokes and
//! region masks as PNG, pictures as 8-bit sRGB PNG. Every error names the file.

use std::path::{Path, PathBuf};

use image::RgbImage;
use thiserror::Error;

use super::{HintMap, LabelMap, RestoreError, hints_from_rgba};
use crate::imgio::ImageError;

#[derive(Debug, Error)]
pub enum RestoreIoError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    #[error("{path}: {source}")]
    Restore { path: PathBuf, source: RestoreError },
}

fn read(path: &Path) -> Result<image::DynamicImage, RestoreIoError> {
    image::open(path).map_err(|source| ImageError::Read { path: path.into(), source }.into())
}

/// Reads an 8-bit grey label map (class index per pixel, 255 = masked).
pub fn load_labels(path: &Path) -> Result<LabelMap, RestoreIoError> {
    let img = read(path)?;
    if img.color() != image::ColorType::L8 {
        return Err(RestoreIoError::Invalid {
            path: path.into(),
            problem: format!("label map must be 8-bit grey, found {:?}", img.color()),
        });
    }
    let (w, h) = (img.width(), img.height());
    LabelMap::new(w, h, img.into_luma8().into_raw())
        .map_err(|source| RestoreIoError::Restore { path: path.into(), source })
}

/// Writes a label map as an 8-bit grey PNG.
pub fn save_labels(path: &Path, labels: &LabelMap) -> Result<(), RestoreIoError> {
    let img = image::GrayImage::from_raw(labels.width, labels.height, labels.data.clone())
        .expect("label map size was checked on construction");
    img.save(path).map_err(|source| ImageError::Write { path: path.into(), source }.into())
}

/// Reads hint strokes (RGBA PNG; transparent = no stroke) against the classes' colours.
pub fn load_hints(
    path: &Path,
    width: u32,
    height: u32,
    class_colours: &[[u8; 3]],
) -> Result<HintMap, RestoreIoError> {
    let img = read(path)?;
    if !img.color().has_alpha() {
        return Err(RestoreIoError::Invalid {
            path: path.into(),
            problem: "hint strokes need an alpha channel (transparent = no stroke)".into(),
        });
    }
    if img.width() != width || img.height() != height {
        return Err(ImageError::Size {
            path: path.into(),
            got_w: img.width(),
            got_h: img.height(),
            want_w: width,
            want_h: height,
        }
        .into());
    }
    let px: Vec<[u8; 4]> = img.to_rgba8().pixels().map(|p| p.0).collect();
    hints_from_rgba(width, height, &px, class_colours)
        .map_err(|source| RestoreIoError::Restore { path: path.into(), source })
}

/// Reads a region mask (any PNG; a pixel is inside when its grey value is at least 128).
pub fn load_mask(path: &Path, width: u32, height: u32) -> Result<Vec<bool>, RestoreIoError> {
    let img = read(path)?;
    if img.width() != width || img.height() != height {
        return Err(ImageError::Size {
            path: path.into(),
            got_w: img.width(),
            got_h: img.height(),
            want_w: width,
            want_h: height,
        }
        .into());
    }
    Ok(img.to_luma8().pixels().map(|p| p.0[0] >= 128).collect())
}

/// Writes an 8-bit sRGB picture.
pub fn save_rgb(path: &Path, img: &RgbImage) -> Result<(), RestoreIoError> {
    img.save(path).map_err(|source| ImageError::Write { path: path.into(), source }.into())
}
