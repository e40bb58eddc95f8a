//! The capture set: what acquisition writes (from real hardware or the virtual stage) and
//! calibration reads. One JSON manifest names every image and the pattern it shows.
//!
//! Layout of a capture directory (version 1):
//! ```text
//! capture.json            this manifest
//! camera.json             the camera calibration file (CameraIntrinsics)
//! photo.png               diffusely lit photo, 16-bit linear RGB
//! proj<k>/<name>.png      camera images of projector k showing a pattern, 16-bit linear
//! ground-truth/           virtual stage only; read by tests and eval, never by the steps
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub const CAPTURE_VERSION: u32 = 1;
pub const MANIFEST_FILE: &str = "capture.json";
pub const CAMERA_FILE: &str = "camera.json";

#[derive(Debug, Error)]
pub enum CaptureSetError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a valid capture file: {source}")]
    Parse { path: PathBuf, source: serde_json::Error },
    #[error("{path}: capture version {found} is not supported (expected {CAPTURE_VERSION})")]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
}

/// Pinhole camera intrinsics in the OpenCV convention: integer pixel coordinates are pixel
/// centres, +x right, +y down; no distortion (undistort before, if a real lens needs it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraIntrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl CameraIntrinsics {
    /// Reads a camera calibration file (`camera.json` layout) and checks it is usable.
    pub fn load(path: &Path) -> Result<Self, CaptureSetError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| CaptureSetError::Io { path: path.into(), source })?;
        let cam: Self = serde_json::from_str(&text)
            .map_err(|source| CaptureSetError::Parse { path: path.into(), source })?;
        cam.check().map_err(|problem| CaptureSetError::Invalid { path: path.into(), problem })?;
        Ok(cam)
    }

    /// Positive finite focal lengths, a principal point inside the image, a non-empty image.
    pub fn check(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("camera size {}x{} is empty", self.width, self.height));
        }
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx > 0.0 && self.fy > 0.0) {
            return Err(format!("focal lengths fx={} fy={} must be positive pixels", self.fx, self.fy));
        }
        let inside = |c: f64, n: u32| c.is_finite() && (-0.5..=n as f64 - 0.5).contains(&c);
        if !inside(self.cx, self.width) || !inside(self.cy, self.height) {
            return Err(format!(
                "principal point ({}, {}) lies outside the {}x{} image",
                self.cx, self.cy, self.width, self.height
            ));
        }
        Ok(())
    }
}

/// Which axis of the projector image a structured-light pattern encodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[serde(deny_unknown_fields)]
pub enum Axis {
    /// Columns (projector x).
    X,
    /// Rows (projector y).
    Y,
}

/// A projector pattern, described precisely enough to regenerate it.
///
/// Conventions (shared by generation and decoding):
/// - Gray code: `n = ceil(log2(extent))` bits; bit index 0 is the most significant. The pattern
///   for bit `b` is white at projector coordinate `c` when bit `n-1-b` of `c ^ (c >> 1)` is 1;
///   `inverted` shows the complement.
/// - Phase shift: value `0.5 + 0.5 * cos(2π c / period - 2π step / steps)` in the projector's
///   8-bit input scale (rounded), the same on all channels.
/// - Dots: single white projector pixels where `x % spacing == dx && y % spacing == dy`.
/// - Ramp: channel `channel` (0 r, 1 g, 2 b; 3 all three) at 8-bit `level`, others 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum Pattern {
    White,
    Black,
    GrayCode { axis: Axis, bit: u32, inverted: bool },
    Phase { axis: Axis, period: u32, step: u32, steps: u32 },
    Dots { spacing: u32, dx: u32, dy: u32 },
    Ramp { channel: u8, level: u8 },
}

/// One camera image of one projector's pattern.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Shot {
    pub pattern: Pattern,
    /// Path relative to the capture directory.
    pub file: PathBuf,
}

/// Everything captured for one projector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorCapture {
    pub index: u32,
    /// Projector resolution (the patterns' size).
    pub width: u32,
    pub height: u32,
    pub shots: Vec<Shot>,
}

/// The manifest, `capture.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureManifest {
    pub version: u32,
    /// Free text: "virtual stage: vase, seed 7" or the camera device.
    pub source: String,
    pub camera: CameraIntrinsics,
    /// The diffusely lit photo, relative path.
    pub photo: PathBuf,
    pub projectors: Vec<ProjectorCapture>,
}

impl CaptureManifest {
    pub fn load(dir: &Path) -> Result<Self, CaptureSetError> {
        let path = dir.join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path)
            .map_err(|source| CaptureSetError::Io { path: path.clone(), source })?;
        let m: Self = serde_json::from_str(&text)
            .map_err(|source| CaptureSetError::Parse { path: path.clone(), source })?;
        if m.version != CAPTURE_VERSION {
            return Err(CaptureSetError::Version { path, found: m.version });
        }
        if m.projectors.is_empty() {
            return Err(CaptureSetError::Invalid { path, problem: "no projectors (expected 1..=8)".into() });
        }
        Ok(m)
    }

    pub fn save(&self, dir: &Path) -> Result<(), CaptureSetError> {
        let path = dir.join(MANIFEST_FILE);
        let text = serde_json::to_string_pretty(self).expect("manifest serialises");
        std::fs::write(&path, text).map_err(|source| CaptureSetError::Io { path, source })
    }
}

impl ProjectorCapture {
    /// The file showing `pattern`, if it was captured.
    pub fn find(&self, pattern: &Pattern) -> Option<&Path> {
        self.shots.iter().find(|s| &s.pattern == pattern).map(|s| s.file.as_path())
    }
}

/// Number of Gray-code bits for a projector extent (columns or rows).
pub fn gray_bits(extent: u32) -> u32 {
    32 - (extent.max(2) - 1).leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gray_bits_cover_extent() {
        assert_eq!(gray_bits(1024), 10);
        assert_eq!(gray_bits(1400), 11);
        assert_eq!(gray_bits(1050), 11);
        assert_eq!(gray_bits(2), 1);
    }

    #[test]
    fn manifest_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let m = CaptureManifest {
            version: CAPTURE_VERSION,
            source: "test".into(),
            camera: CameraIntrinsics { width: 4, height: 3, fx: 5.0, fy: 5.0, cx: 1.5, cy: 1.0 },
            photo: "photo.png".into(),
            projectors: vec![ProjectorCapture {
                index: 0,
                width: 8,
                height: 6,
                shots: vec![Shot {
                    pattern: Pattern::GrayCode { axis: Axis::X, bit: 0, inverted: true },
                    file: "proj0/gx00i.png".into(),
                }],
            }],
        };
        m.save(dir.path()).unwrap();
        let back = CaptureManifest::load(dir.path()).unwrap();
        assert_eq!(back, m);
        assert!(
            back.projectors[0].find(&Pattern::GrayCode { axis: Axis::X, bit: 0, inverted: true }).is_some()
        );
    }
}
