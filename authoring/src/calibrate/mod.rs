//! Calibration (paper §3 and §5.2): from a capture set to a stage model — geometry, light
//! transport, projector responses, per-pixel gain and ambient, lux scale. One submodule per
//! step; the `calibrate` command runs them in sequence.

pub mod decode;
pub mod geometry;
pub mod lux;
pub mod photometric;
pub mod ply;
pub mod radiometry;
pub mod report;
pub mod selfcal;
pub mod transport;
pub mod triangulate;

use std::path::PathBuf;

use thiserror::Error;

use crate::capture_set::CaptureSetError;
use crate::imgio::ImageError;

/// Everything that can stop a calibration step.
#[derive(Debug, Error)]
pub enum CalibrateError {
    #[error(transparent)]
    Capture(#[from] CaptureSetError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("projector {projector}: the capture has no image for {pattern}")]
    MissingPattern { projector: u32, pattern: String },
    #[error("{path}: {problem}")]
    BadInput { path: PathBuf, problem: String },
    #[error(
        "projector {projector}: no contrast between the white and black images ({lit} of {pixels} \
         pixels differ by at least {threshold}); is the projector on and pointed at the object?"
    )]
    NoContrast { projector: u32, lit: usize, pixels: usize, threshold: f32 },
    #[error("self-calibration is ill-posed: {0}")]
    IllPosed(String),
    #[error("self-calibration failed: {0}")]
    Solver(String),
    #[error("known length: {0}")]
    KnownLength(String),
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}
