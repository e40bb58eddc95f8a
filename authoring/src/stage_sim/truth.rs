//! The virtual stage's ground-truth folder: the true stage model, label maps, palette,
//! albedo images and `truth.json` (parameters and deterioration statistics). Only tests and
//! `eval` read it; `render` reads the scene config back from `truth.json`.

use std::path::Path;

use image::GrayImage;
use serde::{Deserialize, Serialize};

use super::optics::{CameraSpec, ProjectorSpec};
use super::paint::Palette;
use super::{SceneConfig, StageSimError, VirtualStage};
use crate::capture_set::CameraIntrinsics;
use crate::imgio::LinearImage;

/// Folder inside a capture directory.
pub const GROUND_TRUTH_DIR: &str = "ground-truth";
pub const TRUTH_FILE: &str = "truth.json";

/// A projector as `truth.json` describes it (no per-pixel arrays; those are in `stage.bin`).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorTruth {
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    /// Centre of projection in the camera frame, mm.
    pub centre: [f64; 3],
    pub lux_at_1m: f64,
    pub black: [f32; 3],
    pub blur_px: f64,
    /// How it was built (None for hand-built projectors).
    pub spec: Option<ProjectorSpec>,
}

/// Deterioration statistics over the object's camera pixels.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WearStats {
    pub object_pixels: u64,
    /// Fractions of object pixels.
    pub chipped: f64,
    pub cracked: f64,
    /// Pixels whose class differs between pristine and deteriorated labels.
    pub label_changed: f64,
    /// Stain weight above 0.1.
    pub stained: f64,
    /// Fading above 0.05.
    pub faded: f64,
    pub chips: usize,
    pub cracks: usize,
    pub stains: usize,
}

/// `truth.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Truth {
    /// The built-in scene config (None for hand-built stages, which `render` cannot rebuild).
    pub config: Option<SceneConfig>,
    pub label: String,
    pub camera: CameraIntrinsics,
    pub camera_spec: CameraSpec,
    pub projectors: Vec<ProjectorTruth>,
    pub diffuse_lux: f64,
    pub stray_lux: f64,
    pub palette: Palette,
    pub wear: WearStats,
}

/// Reads the scene config back from `capture_dir/ground-truth/truth.json`.
pub fn load_config(capture_dir: &Path) -> Result<SceneConfig, StageSimError> {
    let path = capture_dir.join(GROUND_TRUTH_DIR).join(TRUTH_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| StageSimError::Truth {
        path: path.clone(),
        problem: format!("cannot read the virtual stage's ground truth ({e}); was this capture simulated?"),
    })?;
    let truth: Truth = serde_json::from_str(&text).map_err(|e| StageSimError::Truth {
        path: path.clone(),
        problem: format!("not a truth file: {e}"),
    })?;
    truth.config.ok_or(StageSimError::Truth { path, problem: "no scene config (hand-built stage)".into() })
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StageSimError + '_ {
    move |source| StageSimError::Io { path: path.into(), source }
}

/// The simulated lux-meter readings in the ground-truth folder (a `calibrate --lux-file`).
pub const LUX_METER_FILE: &str = "lux_meter.toml";

pub(super) fn write(stage: &VirtualStage, dir: &Path) -> Result<(), StageSimError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let setup = stage.setup();
    let cam = setup.camera.clone();
    stage.truth().save(&dir.join("stage"))?;

    let px = stage.pixels();
    for (name, pristine) in [("labels_pristine.png", true), ("labels_deteriorated.png", false)] {
        let img = GrayImage::from_fn(cam.width, cam.height, |x, y| {
            let p = &px[(y * cam.width + x) as usize];
            image::Luma([if pristine { p.label_pristine } else { p.label }])
        });
        let path = dir.join(name);
        img.save(&path).map_err(|source| crate::imgio::ImageError::Write { path, source })?;
    }
    for (name, pristine) in [("albedo_pristine.png", true), ("albedo_deteriorated.png", false)] {
        let img = LinearImage {
            width: cam.width,
            height: cam.height,
            data: px.iter().map(|p| if pristine { p.albedo_pristine } else { p.albedo }).collect(),
        };
        img.save_linear16(&dir.join(name))?;
    }
    // The lux meter's readings in `calibrate --lux-file` form (see calibrate::lux).
    if let Some(super::LuxMeterSession { pixel, readings }) = stage.lux_meter_session()? {
        let mut text = format!(
            "# What a lux meter reads on this virtual stage (true physics): held at camera pixel\n\
             # {pixel:?}'s surface point, facing each projector in turn at full white, the others\n\
             # black, room stray light on. For `restage-author calibrate --lux-file`.\n\
             reference_pixel = [{}, {}]\nmeter = \"facing-projector\"\n[white]\n",
            pixel[0], pixel[1]
        );
        for (k, v) in readings.iter().enumerate() {
            text.push_str(&format!("{k} = {v:.3}\n"));
        }
        let path = dir.join(LUX_METER_FILE);
        std::fs::write(&path, text).map_err(io(&path))?;
    }
    let palette_path = dir.join("palette.json");
    let text = serde_json::to_string_pretty(stage.palette()).expect("palette serialises");
    std::fs::write(&palette_path, text).map_err(io(&palette_path))?;

    let obj: Vec<_> = px.iter().filter(|p| p.is_object()).collect();
    let n = obj.len().max(1) as f64;
    let frac = |f: &dyn Fn(&&super::PixelTruth) -> bool| obj.iter().filter(|p| f(p)).count() as f64 / n;
    let d = &setup.deterioration;
    let wear = WearStats {
        object_pixels: obj.len() as u64,
        chipped: frac(&|p| p.chipped),
        cracked: frac(&|p| p.cracked),
        label_changed: frac(&|p| p.label != p.label_pristine),
        stained: frac(&|p| p.stain > 0.1),
        faded: frac(&|p| p.fade > 0.05),
        chips: d.chips.len(),
        cracks: d.cracks.len(),
        stains: d.stains.len(),
    };
    let projectors = setup
        .projectors
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let m = p.model();
            ProjectorTruth {
                width: p.width,
                height: p.height,
                f: p.f,
                cx: p.cx,
                cy: p.cy,
                rotation: m.rotation,
                translation: m.translation,
                centre: [p.centre.x, p.centre.y, p.centre.z],
                lux_at_1m: p.lux_at_1m,
                black: p.black,
                blur_px: p.blur_px,
                spec: setup.projector_specs.get(k).cloned(),
            }
        })
        .collect();
    let truth = Truth {
        config: stage.config().cloned(),
        label: setup.label.clone(),
        camera: cam,
        camera_spec: setup.camera_spec.clone(),
        projectors,
        diffuse_lux: setup.diffuse_lux,
        stray_lux: setup.stray_lux,
        palette: stage.palette().clone(),
        wear,
    };
    let path = dir.join(TRUTH_FILE);
    let text = serde_json::to_string_pretty(&truth).expect("truth serialises");
    std::fs::write(&path, text).map_err(io(&path))
}
