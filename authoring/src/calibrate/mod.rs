//! Calibration (paper §3 and §5.2): from a capture set to a stage model — geometry, light
//! transport, projector responses, per-pixel gain and ambient, lux scale. One submodule per
//! step; the `calibrate` command runs them in sequence.

pub mod board;
pub mod decode;
pub mod fill;
pub mod fulllight;
pub mod geometry;
pub mod lux;
pub mod photometric;
pub mod ply;
pub mod radiometry;
pub mod report;
pub mod response;
pub mod rig;
pub mod selfcal;
pub mod transport;
pub mod triangulate;

use std::path::PathBuf;

use thiserror::Error;

use crate::capture_set::CaptureSetError;
use crate::imgio::ImageError;

/// Reads a JSON number written from a float that may have been NaN or infinite (serde_json
/// writes those as `null`) back as NaN, so reports with "not determined" figures still read.
pub(crate) fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// [`nan_if_null`] for `f32` fields.
pub(crate) fn nan_if_null_f32<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
    Ok(<Option<f32> as serde::Deserialize>::deserialize(d)?.unwrap_or(f32::NAN))
}

/// Why self-calibration cannot determine the stage from these correspondences: the scene or
/// the view, not the software, is at fault, and the message says what to change.
#[derive(Debug, Error)]
pub enum IllPosed {
    #[error(
        "projector {projector} has only {sampled} sampled correspondences (needs >= 50): does it see the object?"
    )]
    TooFewCorrespondences { projector: usize, sampled: usize },
    #[error(
        "projector {projector}: {percent:.1} % of its correspondences fit one homography within \
         {threshold_px} px, so the scene is (nearly) planar and focal length, lens shift and pose \
         cannot be separated; calibrate with a non-planar object in view"
    )]
    Planar { projector: usize, percent: f64, threshold_px: f64 },
    #[error(
        "projector {projector} shares too few lit surface points with the others to put it in the same scale"
    )]
    NoCommonScale { projector: usize },
    #[error(
        "projector {projector}: the correspondences do not determine its intrinsics (f = {f:.1} +- \
         {f_std:.1} px, cx = {cx:.1} +- {cx_std:.1} px, cy = {cy:.1} +- {cy_std:.1} px; a homography \
         explains {homography_percent:.0} % of them): the scene is too flat or too small; calibrate \
         with a larger non-planar object in view"
    )]
    Undetermined {
        projector: usize,
        f: f64,
        f_std: f64,
        cx: f64,
        cx_std: f64,
        cy: f64,
        cy_std: f64,
        homography_percent: f64,
    },
}

/// A self-calibration that could not run to its end on inputs it should handle.
#[derive(Debug, Error)]
pub enum SolverError {
    #[error("projector {projector}: correspondence map has {got} entries, expected {want}")]
    MapSize { projector: usize, got: usize, want: usize },
    #[error("capture {pose} has {got} projectors where the first has {want} (one rig, the same projectors)")]
    PoseProjectors { pose: usize, got: usize, want: usize },
    #[error("projector {projector}: essential-matrix decomposition failed")]
    Decomposition { projector: usize },
    #[error("the solved stage model is inconsistent: {0}")]
    Model(#[from] crate::stage_model::StageModelError),
}

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
    IllPosed(#[from] IllPosed),
    #[error("self-calibration failed: {0}")]
    Solver(#[from] SolverError),
    #[error(
        "the rig has moved since it was calibrated: {moved} (medians, projector px); calibrate the \
         rig again (`restage-author rig`)"
    )]
    RigMoved { moved: String },
    #[error("board calibration: {0}")]
    Board(#[from] board::BoardError),
    #[error("known length: {0}")]
    KnownLength(String),
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}
