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
/// centres, +x right, +y down; with a real lens, OpenCV's radial and tangential distortion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraIntrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Lens distortion `[k1, k2, p1, p2, k3]` in OpenCV's model (absent: none). Calibration
    /// undistorts camera rays with it; everything downstream works per camera pixel.
    #[serde(default, skip_serializing_if = "no_distortion")]
    pub distortion: [f64; 5],
}

fn no_distortion(d: &[f64; 5]) -> bool {
    d.iter().all(|&k| k == 0.0)
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
        if !self.distortion.iter().all(|k| k.is_finite()) {
            return Err(format!("distortion {:?} is not finite", self.distortion));
        }
        Ok(())
    }

    /// A camera without lens distortion.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { width, height, fx, fy, cx, cy, distortion: [0.0; 5] }
    }

    /// Normalised image coordinates `(x, y)` (the ray `(x, y, 1)`) of pixel `(u, v)`, lens
    /// distortion removed by OpenCV's fixed-point iteration (`undistortPoints`).
    pub fn undistort(&self, u: f64, v: f64) -> [f64; 2] {
        let (x0, y0) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        if no_distortion(&self.distortion) {
            return [x0, y0];
        }
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (mut x, mut y) = (x0, y0);
        // The iteration contracts by about k1 r^2 per step: slow at the corners of a wide lens.
        for _ in 0..200 {
            let r2 = x * x + y * y;
            let radial = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2;
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let next = ((x0 - dx) / radial, (y0 - dy) / radial);
            let moved = (next.0 - x).abs() + (next.1 - y).abs();
            (x, y) = next;
            if moved < 1e-15 {
                break;
            }
        }
        [x, y]
    }

    /// Pixel of normalised image coordinates `(x, y)`: the inverse of [`Self::undistort`].
    pub fn distort(&self, x: f64, y: f64) -> [f64; 2] {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2;
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        [self.fx * xd + self.cx, self.fy * yd + self.cy]
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
    fn undistortion_inverts_opencvs_lens_model() {
        // The real rig's camera (procam-graycode-plane): tens of pixels of distortion at the corners.
        let cam = CameraIntrinsics {
            distortion: [0.104, -0.193, -0.0024, -0.0037, 0.046],
            ..CameraIntrinsics::pinhole(1280, 1024, 744.3, 741.8, 634.2, 473.0)
        };
        for (u, v) in [(0.0, 0.0), (1279.0, 1023.0), (640.0, 20.0), (634.2, 473.0), (100.0, 900.0)] {
            let [x, y] = cam.undistort(u, v);
            let back = cam.distort(x, y);
            assert!((back[0] - u).abs() < 1e-6 && (back[1] - v).abs() < 1e-6, "({u}, {v}) -> {back:?}");
        }
        // The top-left corner is about 50 px from where a pinhole would put it.
        let [x, y] = cam.undistort(0.0, 0.0);
        let moved = (x * 744.3 + 634.2).hypot(y * 741.8 + 473.0);
        assert!(moved > 20.0, "the corner moves {moved} px");
        let json = serde_json::to_string(&CameraIntrinsics::pinhole(4, 3, 5.0, 5.0, 1.5, 1.0)).unwrap();
        assert!(!json.contains("distortion"), "{json}");
    }

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
            camera: CameraIntrinsics {
                width: 4,
                height: 3,
                fx: 5.0,
                fy: 5.0,
                cx: 1.5,
                cy: 1.0,
                distortion: [0.0; 5],
            },
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
