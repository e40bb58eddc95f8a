//! Import of a capture made with any camera: folders of 8-bit images (PNG, JPEG, TIFF) in a
//! documented pattern order, one folder per exposure time, linearised through the camera's
//! response and merged across exposures into a standard capture set (16-bit linear PNGs).
//!
//! Layout read (docs/capture.md, "Importing"):
//! ```text
//! FOLDER/                 one exposure: the images directly in FOLDER, or
//! FOLDER/<any>/           one subfolder per exposure time, each the whole sequence
//!   *.png|jpg|jpeg|tif|tiff   in file-name order: [photo,] then the patterns in ORDER
//!   exposure.json         {"exposure_s": 0.01}, for images without EXIF ExposureTime
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::acquire::{self, AcquireConfig, PHOTO_FILE};
use crate::calibrate::response::{self, Bracket, CameraResponse, DebevecParams, MergeReport, ResponseError};
use crate::capture_set::{
    Axis, CAMERA_FILE, CAPTURE_VERSION, CameraIntrinsics, CaptureManifest, CaptureSetError, Pattern,
    ProjectorCapture, gray_bits,
};
use crate::imgio::{ImageError, LinearImage};

/// The sidecar giving a folder's exposure time where its images carry no EXIF.
pub const EXPOSURE_FILE: &str = "exposure.json";
/// The response an import used, saved beside `capture.json`.
pub const RESPONSE_FILE: &str = "response.json";
const EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "tif", "tiff"];

#[derive(Debug, Error)]
pub enum ImportError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("cannot read image {path}: {source}")]
    Decode { path: PathBuf, source: image::ImageError },
    #[error(
        "{path} is a 16-bit image; import reads a camera's 8-bit output (16-bit files are taken as linear already: put them in a capture set directly)"
    )]
    NotEightBit { path: PathBuf },
    #[error(
        "{path} has no EXIF ExposureTime and its folder has no {EXPOSURE_FILE} (e.g. {{\"exposure_s\": 0.01}})"
    )]
    NoExposure { path: PathBuf },
    #[error("{path} is not a valid {EXPOSURE_FILE}: {problem}")]
    BadSidecar { path: PathBuf, problem: String },
    #[error("{path}: {problem}")]
    Layout { path: PathBuf, problem: String },
    #[error("image {path} is {got_w}x{got_h}, the first image is {want_w}x{want_h}")]
    Size { path: PathBuf, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("{path}: {source}")]
    Response { path: PathBuf, source: ResponseError },
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    CaptureSet(#[from] CaptureSetError),
}

/// The order of the images in each exposure folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum PatternOrder {
    /// Restage's acquisition order (`acquire::plan`, default settings): white, black, Gray
    /// pairs (pattern, inverse; MSB first) for columns then rows, then optionally phase
    /// shifts, dots and ramps; the folder may stop after any of those groups.
    Restage,
    /// OpenCV `structured_light.GrayCodePattern`: Gray pairs for columns then rows, then
    /// white and black.
    Opencv,
}

/// The patterns of a sequence of `count` images in `order` for a projector of `width x height`.
pub fn sequence(order: PatternOrder, width: u32, height: u32, count: usize) -> Result<Vec<Pattern>, String> {
    let gray = |out: &mut Vec<Pattern>| {
        for (axis, extent) in [(Axis::X, width), (Axis::Y, height)] {
            for bit in 0..gray_bits(extent) {
                for inverted in [false, true] {
                    out.push(Pattern::GrayCode { axis, bit, inverted });
                }
            }
        }
    };
    match order {
        PatternOrder::Opencv => {
            let mut p = Vec::new();
            gray(&mut p);
            p.extend([Pattern::White, Pattern::Black]);
            if p.len() != count {
                return Err(format!(
                    "{count} pattern images for a {width}x{height} projector in OpenCV GrayCodePattern order \
                     (expected exactly {})",
                    p.len()
                ));
            }
            Ok(p)
        }
        PatternOrder::Restage => {
            let cfg = AcquireConfig::default();
            let all: Vec<Pattern> =
                acquire::plan(0, width, height, &cfg).into_iter().map(|s| s.pattern).collect();
            let g = 2 + 2 * (gray_bits(width) + gray_bits(height)) as usize;
            let ends = [
                g,
                g + 2 * cfg.phase_steps as usize,
                g + 2 * cfg.phase_steps as usize + (cfg.dot_spacing * cfg.dot_spacing) as usize,
                all.len(),
            ];
            if !ends.contains(&count) {
                return Err(format!(
                    "{count} pattern images for a {width}x{height} projector in restage order (expected one \
                     of {ends:?}: white, black and Gray codes, then phase, dots, ramps)"
                ));
            }
            Ok(all[..count].to_vec())
        }
    }
}

/// `exposure.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExposureSidecar {
    pub exposure_s: f64,
}

/// One exposure folder: its images in file-name order and each one's exposure time.
#[derive(Clone, Debug)]
pub struct ExposureSet {
    pub dir: PathBuf,
    pub files: Vec<PathBuf>,
    pub exposures_s: Vec<f64>,
}

/// Finds the exposure folders of `folder` (itself if it holds images, else its subfolders in
/// name order) and each image's exposure time: EXIF `ExposureTime` if present, else the
/// folder's `exposure.json`.
pub fn scan(folder: &Path) -> Result<Vec<ExposureSet>, ImportError> {
    let entries = |dir: &Path| -> Result<Vec<PathBuf>, ImportError> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|source| ImportError::Io { path: dir.into(), source })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        v.sort();
        Ok(v)
    };
    let is_image = |p: &Path| {
        p.is_file()
            && p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
    };
    let top = entries(folder)?;
    let dirs: Vec<PathBuf> = if top.iter().any(|p| is_image(p)) {
        vec![folder.to_path_buf()]
    } else {
        top.into_iter().filter(|p| p.is_dir()).collect()
    };
    let mut sets = Vec::new();
    for dir in dirs {
        let files: Vec<PathBuf> = entries(&dir)?.into_iter().filter(|p| is_image(p)).collect();
        if files.is_empty() {
            continue;
        }
        let sidecar = read_sidecar(&dir)?;
        let exposures_s = files
            .iter()
            .map(|f| match exif_exposure(f) {
                Some(t) => Ok(t),
                None => sidecar.ok_or_else(|| ImportError::NoExposure { path: f.clone() }),
            })
            .collect::<Result<Vec<f64>, _>>()?;
        sets.push(ExposureSet { dir, files, exposures_s });
    }
    if sets.is_empty() {
        return Err(ImportError::Layout {
            path: folder.into(),
            problem: "holds no PNG, JPEG or TIFF images, nor subfolders with them".into(),
        });
    }
    let n = sets[0].files.len();
    if let Some(bad) = sets.iter().find(|s| s.files.len() != n) {
        return Err(ImportError::Layout {
            path: bad.dir.clone(),
            problem: format!(
                "{} images, but {} holds {n}: every exposure folder holds the whole sequence",
                bad.files.len(),
                sets[0].dir.display()
            ),
        });
    }
    Ok(sets)
}

fn read_sidecar(dir: &Path) -> Result<Option<f64>, ImportError> {
    let path = dir.join(EXPOSURE_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).map_err(|source| ImportError::Io { path: path.clone(), source })?;
    let s: ExposureSidecar = serde_json::from_str(&text)
        .map_err(|e| ImportError::BadSidecar { path: path.clone(), problem: e.to_string() })?;
    if !(s.exposure_s.is_finite() && s.exposure_s > 0.0) {
        return Err(ImportError::BadSidecar {
            path,
            problem: format!("exposure_s {} is not a positive number of seconds", s.exposure_s),
        });
    }
    Ok(Some(s.exposure_s))
}

/// EXIF `ExposureTime` in seconds, if the file carries a usable one.
pub fn exif_exposure(path: &Path) -> Option<f64> {
    let file = std::fs::File::open(path).ok()?;
    let exif = exif::Reader::new().read_from_container(&mut std::io::BufReader::new(file)).ok()?;
    let field = exif.get_field(exif::Tag::ExposureTime, exif::In::PRIMARY)?;
    match &field.value {
        exif::Value::Rational(v) => v.first().map(|r| r.to_f64()).filter(|t| t.is_finite() && *t > 0.0),
        _ => None,
    }
}

/// Reads an 8-bit image's codes; refuses 16-bit files.
pub fn load_bracket(path: &Path, exposure_s: f64) -> Result<Bracket, ImportError> {
    let img = image::open(path).map_err(|source| ImportError::Decode { path: path.into(), source })?;
    if matches!(
        img.color(),
        image::ColorType::L16 | image::ColorType::La16 | image::ColorType::Rgb16 | image::ColorType::Rgba16
    ) {
        return Err(ImportError::NotEightBit { path: path.into() });
    }
    let rgb = img.to_rgb8();
    Ok(Bracket {
        width: rgb.width(),
        height: rgb.height(),
        codes: rgb.pixels().map(|p| p.0).collect(),
        exposure_s,
    })
}

/// Where the response comes from.
#[derive(Clone, Debug)]
pub enum ResponseSource {
    /// A saved `response.json`.
    File(PathBuf),
    /// Recovered from the brackets of the white pattern of this import.
    Recover(DebevecParams),
}

/// What to import.
#[derive(Clone, Debug)]
pub struct ImportSpec {
    pub order: PatternOrder,
    pub projector: (u32, u32),
    /// The first image of each folder is the diffusely lit photo.
    pub photo_first: bool,
    pub camera: CameraIntrinsics,
    pub response: ResponseSource,
}

/// What an import did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImportSummary {
    pub exposures: usize,
    pub images: usize,
    /// Linear 1.0 is the light that saturates the camera at this exposure time (the shortest).
    pub full_scale_exposure_s: f64,
    pub merge: MergeReport,
    pub response_method: String,
}

/// Imports `folder` into the capture directory `out` (created): one projector, index 0.
pub fn import(folder: &Path, out: &Path, spec: &ImportSpec) -> Result<ImportSummary, ImportError> {
    let sets = scan(folder)?;
    let n = sets[0].files.len();
    let skip = usize::from(spec.photo_first);
    let (pw, ph) = spec.projector;
    let patterns = sequence(spec.order, pw, ph, n.saturating_sub(skip))
        .map_err(|problem| ImportError::Layout { path: sets[0].dir.clone(), problem })?;
    let brackets_of = |i: usize| -> Result<Vec<Bracket>, ImportError> {
        let mut v = Vec::with_capacity(sets.len());
        for s in &sets {
            let b = load_bracket(&s.files[i], s.exposures_s[i])?;
            if (b.width, b.height) != (spec.camera.width, spec.camera.height) {
                return Err(ImportError::Size {
                    path: s.files[i].clone(),
                    got_w: b.width,
                    got_h: b.height,
                    want_w: spec.camera.width,
                    want_h: spec.camera.height,
                });
            }
            v.push(b);
        }
        Ok(v)
    };
    let white = skip + patterns.iter().position(|p| *p == Pattern::White).expect("every order has white");
    let response = match &spec.response {
        ResponseSource::File(path) => CameraResponse::load(path)
            .map_err(|source| ImportError::Response { path: path.clone(), source })?,
        ResponseSource::Recover(params) => {
            let b = brackets_of(white)?;
            let r = response::recover_debevec(&b, params)
                .map_err(|source| ImportError::Response { path: sets[0].files[white].clone(), source })?;
            tracing::info!("recovered the camera response: {} (residual {:?} ln)", r.method, r.residual_rms);
            r
        }
    };
    std::fs::create_dir_all(out.join("proj0"))
        .map_err(|source| ImportError::Io { path: out.join("proj0"), source })?;
    response
        .save(&out.join(RESPONSE_FILE))
        .map_err(|source| ImportError::Response { path: out.join(RESPONSE_FILE), source })?;
    let t_min = sets.iter().flat_map(|s| s.exposures_s.iter().copied()).fold(f64::INFINITY, f64::min);
    let mut merge = MergeReport::default();
    let mut write = |i: usize, file: &Path| -> Result<(), ImportError> {
        let b = brackets_of(i)?;
        let (mut img, report) = response::merge_debevec(&b, &response)
            .map_err(|source| ImportError::Response { path: sets[0].files[i].clone(), source })?;
        merge.saturated += report.saturated;
        merge.black += report.black;
        // One scale for the whole set, so images stay comparable: light that saturates the
        // shortest exposure is 1.0.
        img.data.iter_mut().for_each(|p| *p = p.map(|c| (c as f64 * t_min) as f32));
        LinearImage::save_linear16(&img, &out.join(file))?;
        Ok(())
    };
    let mut shots = Vec::with_capacity(patterns.len());
    for (k, pattern) in patterns.into_iter().enumerate() {
        let shot = acquire::shot(0, pattern);
        write(skip + k, &shot.file)?;
        shots.push(shot);
    }
    let photo: PathBuf = if spec.photo_first {
        write(0, Path::new(PHOTO_FILE))?;
        PHOTO_FILE.into()
    } else {
        tracing::warn!(
            "no diffusely lit photo in {} (--photo-first): the white pattern stands in for it",
            folder.display()
        );
        acquire::shot(0, Pattern::White).file
    };
    let camera_path = out.join(CAMERA_FILE);
    std::fs::write(&camera_path, serde_json::to_string_pretty(&spec.camera).expect("intrinsics serialise"))
        .map_err(|source| ImportError::Io { path: camera_path, source })?;
    let manifest = CaptureManifest {
        version: CAPTURE_VERSION,
        source: format!(
            "import of {} ({} exposures, {:?} order, response: {}){}",
            folder.display(),
            sets.len(),
            spec.order,
            response.method,
            if spec.photo_first { "" } else { "; photo: the white pattern" }
        ),
        camera: spec.camera.clone(),
        photo,
        projectors: vec![ProjectorCapture { index: 0, width: pw, height: ph, shots }],
    };
    manifest.save(out)?;
    if merge.saturated + merge.black > 0 {
        tracing::warn!(
            "{} pixel-channels saturated and {} black in every exposure (bounds only there)",
            merge.saturated,
            merge.black
        );
    }
    Ok(ImportSummary {
        exposures: sets.len(),
        images: n * sets.len(),
        full_scale_exposure_s: t_min,
        merge,
        response_method: response.method,
    })
}

#[cfg(test)]
mod tests;
