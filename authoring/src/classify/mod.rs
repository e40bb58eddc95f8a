//! Colour classification (paper §4.1): every pixel of the diffusely lit photo assigned to one of
//! the few paint colours the conservator names by picking example pixels.
//!
//! Output contract (read by the restoration step): a [`LabelMap`] (`labels.png`, 8-bit grey,
//! value = class index, [`MASKED`] = not object) and a [`Palette`] (`palette.json`).

pub mod baseline;
pub mod calibrated;
pub mod edges;
mod error;
pub mod islands;
pub mod kmeans;
mod palette;
pub mod picks;
pub mod regions;
pub mod review;
pub mod synthetic;
pub mod weights;
pub mod within;

pub use calibrated::{Classification, ClassifyOptions, DEFAULT_PRIOR_PICKS, classify};
pub use error::ClassifyError;
pub use palette::{LabelMap, MASKED, PALETTE_VERSION, Palette, PaletteClass, output_paths, preview};
pub use picks::{PickColour, PickRect, Picks, picks_from_labels};
pub use review::{Review, ReviewRegion};
pub use weights::{WeightFit, fit_weights};
