//! The classification subsystem's error type.

use std::path::PathBuf;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum ClassifyError {
    #[error(transparent)]
    Image(#[from] crate::imgio::ImageError),
    #[error("cannot read {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
    #[error("cannot parse {path}: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("{path}: palette version {got} is not supported (expected {expected})")]
    PaletteVersion { path: PathBuf, got: u32, expected: u32 },
    #[error("{path}: picks version {got} is not supported (expected {expected})")]
    PicksVersion { path: PathBuf, got: u32, expected: u32 },
    #[error("label map {path} must be an 8-bit greyscale PNG, found {found}")]
    LabelFormat { path: PathBuf, found: String },
    #[error("label map has {got} pixels, expected {expected} ({width}x{height})")]
    LabelSize { got: usize, expected: usize, width: u32, height: u32 },
    #[error("{count} colour classes given (expected 2..={max})")]
    ClassCount { count: usize, max: usize },
    #[error("colour '{name}' has no picked pixels (each colour needs at least one)")]
    NoPicks { name: String },
    #[error("pick ({x}, {y}) of colour '{name}' lies outside the {width}x{height} image")]
    PickOutside { name: String, x: i64, y: i64, width: u32, height: u32 },
    #[error("colour '{name}' is defined twice")]
    DuplicateName { name: String },
    #[error(
        "colours '{a}' and '{b}' have the same representative colour (xyY distance {distance:.2e}); \
         pick pixels that show the difference, or merge the two colours"
    )]
    Degenerate { a: String, b: String, distance: f64 },
    #[error("the picked pixels of colour '{name}' are black; no chromaticity can be measured")]
    BlackPick { name: String },
    #[error("stroke image {path}: colour #{rgb} is not one of the colours named in the picks")]
    UnknownStroke { path: PathBuf, rgb: String },
    #[error("mask is {got_w}x{got_h}, the photo is {want_w}x{want_h}")]
    MaskSize { got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("classify option {name} = {problem}")]
    Option { name: &'static str, problem: String },
    #[error("the mask leaves no pixel of the object to classify")]
    EmptyMask,
}
