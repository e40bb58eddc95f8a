//! Files of the compensation step: `FRAMES_DIR/proj<k>.png` (one 8-bit RGB frame per
//! projector, device values as shown), `compensation.json` (parameters and figures), and the
//! light certificate beside them.

use std::path::{Path, PathBuf};

use image::RgbImage;
use serde::Serialize;

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

#[derive(Serialize)]
struct Summary<'a> {
    e_bound_lux: f64,
    m: String,
    margin: f64,
    clip_fraction: f64,
    certificate_reduction: u32,
    stats: &'a Stats,
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
        e_bound_lux: params.e_bound_lux,
        m: params.m.to_string(),
        margin: params.margin,
        clip_fraction: params.clip_fraction,
        certificate_reduction: params.reduction,
        stats: &comp.stats,
    };
    let p = dir.join(SUMMARY_FILE);
    std::fs::write(&p, serde_json::to_string_pretty(&summary).expect("summary serialises"))
        .map_err(|e| io_err(&p, e))?;
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
