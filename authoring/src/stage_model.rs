//! The stage model: everything calibration learns about the stage and compensation needs —
//! geometry per camera pixel, projector intrinsics and poses, light transport, responses.
//!
//! Saved as `STAGE_DIR/stage.bin`: the 8-byte magic `RSTGMDL\0`, a little-endian u32 format
//! version, then the [`StageModel`] in postcard. `stage.json` beside it is a human summary
//! (never read back). Units and frames: ARCHITECTURE.md ("Units and frames").

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::capture_set::CameraIntrinsics;

pub const STAGE_FILE: &str = "stage.bin";
pub const STAGE_MAGIC: &[u8; 8] = b"RSTGMDL\0";
pub const STAGE_VERSION: u32 = 1;

#[derive(Debug, Error)]
pub enum StageModelError {
    #[error("cannot access {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a restage stage model (bad magic)")]
    Magic { path: PathBuf },
    #[error("{path}: stage model version {found} is not supported (expected {STAGE_VERSION})")]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: corrupt stage model: {source}")]
    Decode { path: PathBuf, source: postcard::Error },
    #[error("{path}: corrupt stage model: {bytes} unexpected bytes after it (a lens distortion is 40)")]
    Trailing { path: PathBuf, bytes: usize },
    #[error("stage model is inconsistent: {0}")]
    Inconsistent(String),
}

/// A projector's geometry and radiometry as calibrated.
///
/// Pose: a point `X_c` in the camera frame (mm) is `X_p = rotation * X_c + translation` in the
/// projector's frame (+x right, +y down, +z out of the lens). Intrinsics in the OpenCV
/// convention (integer coordinates are pixel centres), square pixels, zero skew.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProjectorModel {
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    /// Row-major 3x3 rotation, camera frame to projector frame.
    pub rotation: [[f64; 3]; 3],
    /// Millimetres.
    pub translation: [f64; 3],
    /// Per channel (r, g, b), 256 entries: light output for each 8-bit input, relative to the
    /// output at 255 above black (so `response[c][255] == 1`, `response[c][0] == 0`),
    /// monotonic non-decreasing.
    pub response: [Vec<f32>; 3],
    /// Black level per channel, in the same relative units as `response` (light at input 0).
    pub black: [f32; 3],
    /// Illuminance in lux that this projector's full-white pixel at the image centre gives
    /// on a surface 1 m away, facing it (luminous intensity, candela). Irradiance at a
    /// point: `lux_at_1m * vignetting * response * cos(theta) / (d / 1000 mm)^2`.
    pub lux_at_1m: f64,
    /// Optional per-projector-pixel relative output (vignetting), `width * height`, row-major;
    /// empty means uniform 1.
    pub vignetting: Vec<f32>,
}

/// Sparse light transport of one projector: for each projector pixel, the camera pixels its
/// light reaches and the weights (compressed sparse rows over projector pixels).
///
/// `weight` for projector pixel q at camera pixel p is q's share of p's full-white irradiance
/// from this projector (`(dot - black) / (white - black)`), so the weights of all q at one
/// camera pixel sum to about 1 and a row's sum is q's footprint in camera pixels' worth of light.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transport {
    /// `width * height + 1` offsets into `camera_pixel` / `weight`; empty if not measured.
    pub row_start: Vec<u32>,
    /// Camera pixel index `y * camera_width + x`.
    pub camera_pixel: Vec<u32>,
    pub weight: Vec<f32>,
}

/// The calibrated stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageModel {
    /// In `stage.bin` as version 1 wrote it (a pinhole); a lens distortion follows the
    /// postcard body (see [`StageModel::save`]).
    #[serde(with = "pinhole_wire")]
    pub camera: CameraIntrinsics,
    pub projectors: Vec<ProjectorModel>,
    /// Per camera pixel (row-major): surface point in the camera frame, millimetres; NaN where
    /// the pixel sees no reconstructed surface.
    pub points: Vec<[f32; 3]>,
    /// Per camera pixel: unit outward normal (towards the camera side); NaN where unknown.
    pub normals: Vec<[f32; 3]>,
    /// Per projector, per camera pixel: projector pixel coordinate seen there, NaN if none.
    pub correspondences: Vec<Vec<[f32; 2]>>,
    /// Per projector; may be empty (`row_start` empty) when only geometry is calibrated.
    pub transport: Vec<Transport>,
    /// Per camera pixel: linear camera value per unit lux of irradiance (albedo times camera
    /// gain), so a camera value `v` under irradiance `E` lux is `v = gain * E + ambient`.
    pub gain: Vec<[f32; 3]>,
    /// Per camera pixel: camera value with every projector black (ambient plus black level).
    pub ambient: Vec<[f32; 3]>,
    /// Free text on where this came from (capture, tool version, ground truth or estimate).
    pub provenance: String,
}

impl ProjectorModel {
    /// The centre of projection (the lens) in the camera frame, mm: `C = -R^T t`.
    pub fn centre(&self) -> [f64; 3] {
        let (r, t) = (&self.rotation, &self.translation);
        std::array::from_fn(|j| -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]))
    }
}

impl StageModel {
    pub fn pixel_count(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize
    }

    /// Checks that every per-pixel array has the camera's size and every per-projector array
    /// one entry per projector.
    pub fn validate(&self) -> Result<(), StageModelError> {
        let n = self.pixel_count();
        let bad = |what: &str, got: usize, want: usize| {
            Err(StageModelError::Inconsistent(format!("{what} has {got} entries, expected {want}")))
        };
        if self.projectors.is_empty() || self.projectors.len() > 8 {
            return bad("projectors", self.projectors.len(), 3);
        }
        for (what, len) in [("points", self.points.len()), ("normals", self.normals.len())] {
            if len != n {
                return bad(what, len, n);
            }
        }
        for (what, len) in [("gain", self.gain.len()), ("ambient", self.ambient.len())] {
            if len != n && len != 0 {
                return bad(what, len, n);
            }
        }
        if self.correspondences.len() != self.projectors.len() {
            return bad("correspondences", self.correspondences.len(), self.projectors.len());
        }
        for c in &self.correspondences {
            if c.len() != n {
                return bad("correspondence map", c.len(), n);
            }
        }
        for p in &self.projectors {
            for c in &p.response {
                if c.len() != 256 {
                    return bad("response curve", c.len(), 256);
                }
            }
        }
        Ok(())
    }

    pub fn save(&self, dir: &Path) -> Result<(), StageModelError> {
        std::fs::create_dir_all(dir).map_err(|source| StageModelError::Io { path: dir.into(), source })?;
        let path = dir.join(STAGE_FILE);
        let mut bytes = STAGE_MAGIC.to_vec();
        bytes.extend_from_slice(&STAGE_VERSION.to_le_bytes());
        bytes.extend(postcard::to_stdvec(self).expect("stage model serialises"));
        // Version 1 had no lens distortion: it follows the body, so version-1 files still read.
        if self.camera.distortion.iter().any(|&k| k != 0.0) {
            bytes.extend(self.camera.distortion.iter().flat_map(|k| k.to_le_bytes()));
        }
        std::fs::write(&path, bytes).map_err(|source| StageModelError::Io { path, source })
    }

    pub fn load(dir: &Path) -> Result<Self, StageModelError> {
        let path = dir.join(STAGE_FILE);
        let bytes =
            std::fs::read(&path).map_err(|source| StageModelError::Io { path: path.clone(), source })?;
        if bytes.len() < 12 || &bytes[..8] != STAGE_MAGIC {
            return Err(StageModelError::Magic { path });
        }
        let found = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if found != STAGE_VERSION {
            return Err(StageModelError::Version { path, found });
        }
        let (mut model, rest): (Self, &[u8]) = postcard::take_from_bytes(&bytes[12..])
            .map_err(|source| StageModelError::Decode { path: path.clone(), source })?;
        match rest.len() {
            0 => {}
            40 => {
                for (k, b) in model.camera.distortion.iter_mut().zip(rest.chunks_exact(8)) {
                    *k = f64::from_le_bytes(b.try_into().expect("8 bytes"));
                }
            }
            n => return Err(StageModelError::Trailing { path, bytes: n }),
        }
        model.validate()?;
        Ok(model)
    }
}

/// The camera as `stage.bin` version 1 stores it: the six pinhole fields.
mod pinhole_wire {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    use crate::capture_set::CameraIntrinsics;

    #[derive(Serialize, Deserialize)]
    struct Pinhole {
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    }

    pub(super) fn serialize<S: Serializer>(c: &CameraIntrinsics, s: S) -> Result<S::Ok, S::Error> {
        Pinhole { width: c.width, height: c.height, fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy }.serialize(s)
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<CameraIntrinsics, D::Error> {
        let p = Pinhole::deserialize(d)?;
        Ok(CameraIntrinsics::pinhole(p.width, p.height, p.fx, p.fy, p.cx, p.cy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> StageModel {
        let ramp: Vec<f32> = (0..256).map(|i| (i as f32 / 255.0).powf(2.2)).collect();
        StageModel {
            camera: CameraIntrinsics {
                width: 2,
                height: 1,
                fx: 10.0,
                fy: 10.0,
                cx: 0.5,
                cy: 0.0,
                distortion: [0.0; 5],
            },
            projectors: vec![ProjectorModel {
                width: 4,
                height: 3,
                f: 8.0,
                cx: 1.5,
                cy: 2.0,
                rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                translation: [100.0, 0.0, 0.0],
                response: [ramp.clone(), ramp.clone(), ramp],
                black: [0.01; 3],
                lux_at_1m: 400.0,
                vignetting: vec![],
            }],
            points: vec![[0.0, 0.0, 500.0], [f32::NAN; 3]],
            normals: vec![[0.0, 0.0, -1.0], [f32::NAN; 3]],
            correspondences: vec![vec![[1.0, 1.0], [f32::NAN; 2]]],
            transport: vec![Transport::default()],
            gain: vec![[0.001; 3]; 2],
            ambient: vec![[0.0; 3]; 2],
            provenance: "test".into(),
        }
    }

    /// The model frozen in `tests/fixtures/stage-v1/stage.bin`: [`tiny`] with every optional
    /// part filled (transport, vignetting).
    fn fixture() -> StageModel {
        let mut m = tiny();
        m.provenance = "frozen fixture, stage.bin version 1".into();
        m.projectors[0].vignetting = (0..12).map(|i| 1.0 - 0.01 * i as f32).collect();
        let mut row_start = vec![0u32; 13];
        row_start[5..].fill(1);
        m.transport = vec![Transport { row_start, camera_pixel: vec![0], weight: vec![0.75] }];
        m
    }

    /// A stage model written by version 1 of the format keeps reading as the same model; a
    /// later format needs a new fixture beside this one (docs/formats.md).
    /// `RESTAGE_WRITE_FIXTURES=1` writes the fixture again (only ever for a new version).
    #[test]
    fn the_frozen_version_1_stage_model_still_reads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/stage-v1");
        if std::env::var_os("RESTAGE_WRITE_FIXTURES").is_some() {
            fixture().save(&dir).unwrap();
        }
        let loaded = StageModel::load(&dir).unwrap();
        // Debug, not PartialEq: NaN marks pixels without surface.
        assert_eq!(format!("{loaded:?}"), format!("{:?}", fixture()));
        let bytes = std::fs::read(dir.join(STAGE_FILE)).unwrap();
        assert_eq!(&bytes[8..12], &1u32.to_le_bytes(), "the fixture is version 1");

        // A newer version is refused by name, not misread.
        let tmp = tempfile::tempdir().unwrap();
        let mut newer = bytes.clone();
        newer[8..12].copy_from_slice(&2u32.to_le_bytes());
        std::fs::write(tmp.path().join(STAGE_FILE), newer).unwrap();
        let e = StageModel::load(tmp.path()).unwrap_err().to_string();
        assert!(e.contains("version 2"), "{e}");
    }

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let m = tiny();
        m.save(dir.path()).unwrap();
        let back = StageModel::load(dir.path()).unwrap();
        assert_eq!(back.projectors, m.projectors);
        assert!(back.points[1][0].is_nan());
        // A real lens's distortion comes back too (after the version-1 body).
        let mut lens = m.clone();
        lens.camera.distortion = [0.1, -0.2, 0.001, -0.002, 0.05];
        lens.save(dir.path()).unwrap();
        assert_eq!(StageModel::load(dir.path()).unwrap().camera, lens.camera);
        let mut bytes = std::fs::read(dir.path().join(STAGE_FILE)).unwrap();
        bytes.pop();
        std::fs::write(dir.path().join(STAGE_FILE), bytes).unwrap();
        assert!(matches!(StageModel::load(dir.path()), Err(StageModelError::Trailing { bytes: 39, .. })));
    }

    #[test]
    fn corrupt_and_inconsistent_models_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(STAGE_FILE), b"garbage!").unwrap();
        assert!(matches!(StageModel::load(dir.path()), Err(StageModelError::Magic { .. })));
        let mut m = tiny();
        m.points.pop();
        assert!(m.validate().is_err());
    }
}
