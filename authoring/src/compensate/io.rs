//! Files of the compensation step: `FRAMES_DIR/proj<k>.png` (one 8-bit RGB frame per
//! projector, device values as shown), `compensation.json` (parameters and figures), and the
//! light certificate beside them.

use std::path::{Path, PathBuf};

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::{Compensation, Params, Prepared, Stats};
use crate::imgio::ImageError;

/// Name of projector k's frame in a frames folder.
pub fn frame_file(k: usize) -> String {
    format!("proj{k}.png")
}

pub const SUMMARY_FILE: &str = "compensation.json";
/// The light certificate (`restage_shared::light::LightCertificate`, postcard), for the bundle.
pub const CERTIFICATE_FILE: &str = "certificate.bin";
/// The light model (`restage_shared::light::LightModel`, JSON): E_bound, margin, room light.
pub const LIGHT_FILE: &str = "light.json";

/// Version of [`Summary`]; a reader refuses a newer one. Files written before the field
/// existed read as version 1 (the same fields). 2: `meter_accuracy` (version 1 files read
/// with 0, the meter taken as exact, as they were computed).
pub const SUMMARY_VERSION: u32 = 2;

/// `compensation.json`: the parameters a compensation ran with and its figures (read back by
/// the window and by its bundle export).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Summary {
    #[serde(default = "first_version")]
    pub version: u32,
    pub e_bound_lux: f64,
    /// The smoothness exponent m as written on the command line (`8`, `inf`).
    pub m: String,
    pub margin: f64,
    /// The lux meter's relative accuracy the limit allowed for (0 in version 1 files).
    #[serde(default)]
    pub meter_accuracy: f64,
    pub clip_fraction: f64,
    pub certificate_reduction: u32,
    pub stats: Stats,
}

fn first_version() -> u32 {
    1
}

/// Why a `compensation.json` could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SummaryError {
    #[error("cannot read {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a compensation summary: {source}")]
    Parse { path: PathBuf, source: serde_json::Error },
    #[error(
        "{path} is a version {version} compensation summary; this restage-author reads up to version {SUMMARY_VERSION}"
    )]
    Version { path: PathBuf, version: u32 },
}

impl Summary {
    /// The share of E_bound held back: margin and meter accuracy together.
    pub fn combined_margin(&self) -> f64 {
        super::combined_margin(self.margin, self.meter_accuracy)
    }

    /// Reads `dir/compensation.json`.
    pub fn load(dir: &Path) -> Result<Summary, SummaryError> {
        let path = dir.join(SUMMARY_FILE);
        let text = std::fs::read_to_string(&path)
            .map_err(|source| SummaryError::Read { path: path.clone(), source })?;
        let s: Summary = serde_json::from_str(&text)
            .map_err(|source| SummaryError::Parse { path: path.clone(), source })?;
        if s.version > SUMMARY_VERSION {
            return Err(SummaryError::Version { path, version: s.version });
        }
        Ok(s)
    }
}

/// Writes the frames, `compensation.json`, `certificate.bin` and `light.json` into `dir`
/// (created if needed).
pub fn save(
    dir: &Path,
    comp: &Compensation,
    params: &Params,
    prep: &Prepared,
) -> Result<Vec<PathBuf>, ImageError> {
    let io_err = |path: &Path, e: std::io::Error| ImageError::Write { path: path.into(), source: e.into() };
    std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
    let mut out = Vec::new();
    for (k, f) in comp.frames.iter().enumerate() {
        let p = dir.join(frame_file(k));
        f.save(&p).map_err(|source| ImageError::Write { path: p.clone(), source })?;
        out.push(p);
    }
    let summary = Summary {
        version: SUMMARY_VERSION,
        e_bound_lux: params.e_bound_lux,
        m: params.m.to_string(),
        margin: params.margin,
        meter_accuracy: params.meter_accuracy,
        // The fraction the scale was taken at (the model's choice with `auto_clip`).
        clip_fraction: comp.stats.clip_fraction,
        certificate_reduction: params.reduction,
        stats: comp.stats.clone(),
    };
    let p = dir.join(SUMMARY_FILE);
    let json = serde_json::to_string_pretty(&summary).map_err(|e| io_err(&p, e.into()))?;
    std::fs::write(&p, json).map_err(|e| io_err(&p, e))?;
    out.push(p);
    let p = dir.join(CERTIFICATE_FILE);
    std::fs::write(&p, prep.certificate.to_shared().to_bytes()).map_err(|e| io_err(&p, e))?;
    out.push(p);
    let p = dir.join(LIGHT_FILE);
    std::fs::write(&p, serde_json::to_string_pretty(&comp.light).expect("light model serialises"))
        .map_err(|e| io_err(&p, e))?;
    out.push(p);
    Ok(out)
}

/// Reads `count` frames, checking each against its projector's size.
pub fn load_frames(dir: &Path, sizes: &[(u32, u32)]) -> Result<Vec<RgbImage>, ImageError> {
    sizes
        .iter()
        .enumerate()
        .map(|(k, &(w, h))| {
            let p = dir.join(frame_file(k));
            let img =
                image::open(&p).map_err(|source| ImageError::Read { path: p.clone(), source })?.to_rgb8();
            if img.dimensions() != (w, h) {
                return Err(ImageError::Size {
                    path: p,
                    got_w: img.width(),
                    got_h: img.height(),
                    want_w: w,
                    want_h: h,
                });
            }
            Ok(img)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, json: &str) {
        std::fs::write(dir.join(SUMMARY_FILE), json).unwrap();
    }

    #[test]
    fn the_summary_reads_back_and_refuses_what_it_does_not_know() {
        let dir = tempfile::tempdir().unwrap();
        let s = Summary {
            version: SUMMARY_VERSION,
            e_bound_lux: 150.0,
            m: "8".into(),
            margin: 0.05,
            meter_accuracy: 0.1,
            clip_fraction: 0.01,
            certificate_reduction: 2,
            stats: Stats { peak_lux: 139.5, covered_points: 10, ..Stats::default() },
        };
        let json = serde_json::to_string_pretty(&s).unwrap();
        write(dir.path(), &json);
        let back = Summary::load(dir.path()).unwrap();
        assert_eq!((back.version, back.stats.peak_lux, back.m.as_str()), (2, 139.5, "8"));
        assert_eq!(back.meter_accuracy, 0.1);
        assert!((back.combined_margin() - 0.145).abs() < 1e-12);

        // Version 1, written before the meter's accuracy was allowed for: read with 0.
        let v1 = json.replace("\"version\": 2", "\"version\": 1").replace("\"meter_accuracy\": 0.1,", "");
        assert_ne!(v1, json);
        write(dir.path(), &v1);
        let back = Summary::load(dir.path()).unwrap();
        assert_eq!((back.version, back.meter_accuracy), (1, 0.0));
        // Written before the version field: version 1.
        write(dir.path(), &v1.replace("\"version\": 1,", ""));
        assert_eq!(Summary::load(dir.path()).unwrap().version, 1);
        // A newer version, a misspelt field and a missing file are refused by name.
        write(dir.path(), &json.replace("\"version\": 2", "\"version\": 3"));
        let e = Summary::load(dir.path()).unwrap_err().to_string();
        assert!(e.contains("version 3"), "{e}");
        write(dir.path(), &json.replace("peak_lux", "peak_lx"));
        let e = Summary::load(dir.path()).unwrap_err().to_string();
        assert!(e.contains("peak_lx") && e.contains("compensation.json"), "{e}");
        std::fs::remove_file(dir.path().join(SUMMARY_FILE)).unwrap();
        assert!(matches!(Summary::load(dir.path()), Err(SummaryError::Read { .. })));
    }
}
