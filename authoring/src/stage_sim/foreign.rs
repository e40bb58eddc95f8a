//! The virtual stage seen through a foreign camera: the 8-bit non-linear camera's images of
//! projector 0's patterns at several exposure times, laid out as `import` reads them.

use std::path::Path;

use super::{StageSimError, VirtualStage};
use crate::import::{EXPOSURE_FILE, ExposureSidecar, PatternOrder, sequence};
use crate::patterns;

/// Writes `dir/e<j>/NNN.png` (8-bit RGB) for each exposure time `exposures_s[j]` with its
/// `exposure.json`: optionally the diffusely lit photo first, then the patterns of `order`
/// on projector 0 (the others black). Returns the number of images written.
pub fn write_foreign_capture(
    stage: &VirtualStage,
    dir: &Path,
    order: PatternOrder,
    exposures_s: &[f64],
    photo_first: bool,
) -> Result<usize, StageSimError> {
    let p = &stage.setup().projectors[0];
    let (w, h) = (p.width, p.height);
    let full = match order {
        PatternOrder::Opencv => {
            2 * (crate::capture_set::gray_bits(w) + crate::capture_set::gray_bits(h)) as usize + 2
        }
        PatternOrder::Restage => {
            2 + 2 * (crate::capture_set::gray_bits(w) + crate::capture_set::gray_bits(h)) as usize
        }
    };
    let patterns =
        sequence(order, w, h, full).map_err(|problem| StageSimError::Truth { path: dir.into(), problem })?;
    let io = |path: &Path, source| StageSimError::Io { path: path.into(), source };
    let folders: Vec<_> = (0..exposures_s.len()).map(|j| dir.join(format!("e{j}"))).collect();
    for (f, &t) in folders.iter().zip(exposures_s) {
        std::fs::create_dir_all(f).map_err(|e| io(f, e))?;
        let text =
            serde_json::to_string_pretty(&ExposureSidecar { exposure_s: t }).expect("sidecar serialises");
        std::fs::write(f.join(EXPOSURE_FILE), text).map_err(|e| io(&f.join(EXPOSURE_FILE), e))?;
    }
    let mut scenes: Vec<(Vec<image::RgbImage>, bool)> = Vec::new();
    if photo_first {
        scenes.push((stage.black_frames(), true));
    }
    for pattern in &patterns {
        let mut frames = stage.black_frames();
        frames[0] = patterns::render(pattern, w, h);
        scenes.push((frames, false));
    }
    let mut written = 0;
    for (i, (frames, diffuse)) in scenes.iter().enumerate() {
        let brackets = stage.brackets(frames, *diffuse, exposures_s, 1000 * i as u64)?;
        for (b, f) in brackets.iter().zip(&folders) {
            let path = f.join(format!("{i:03}.png"));
            let img = image::RgbImage::from_fn(b.width, b.height, |x, y| {
                image::Rgb(b.codes[(y * b.width + x) as usize])
            });
            img.save(&path)
                .map_err(|source| StageSimError::Image(crate::imgio::ImageError::Write { path, source }))?;
            written += 1;
        }
    }
    tracing::info!("wrote {written} 8-bit images of the virtual camera to {}", dir.display());
    Ok(written)
}

#[cfg(test)]
mod tests {
    use image::{Rgb, RgbImage};

    use super::super::optics::CodeCamera;
    use super::super::{SceneConfig, SceneName};
    use super::*;
    use crate::calibrate::response::{DebevecParams, JUDGED_CODES, recover_debevec, response_error};

    fn nonlinear_stage() -> VirtualStage {
        let mut setup = super::super::Setup::from_config(&SceneConfig::tiny(SceneName::Vase, 5)).unwrap();
        setup.camera_spec.codes = Some(CodeCamera::default());
        VirtualStage::from_setup(setup)
    }

    /// The headline figure: brackets of the white pattern from the non-linear virtual camera
    /// give back its true response within 1 % over codes 10..=245.
    #[test]
    fn the_nonlinear_virtual_camera_response_is_recovered_within_one_percent() {
        let stage = nonlinear_stage();
        let truth = stage.setup().camera_spec.codes.as_ref().unwrap().curve.inverse();
        let mut frames = stage.black_frames();
        frames[0] = RgbImage::from_pixel(128, 96, Rgb([255; 3]));
        // Half-stop steps from 1/128 s to 16 s: every code sees many radiances.
        let times: Vec<f64> = (-14..=8).map(|k| 2f64.powf(k as f64 / 2.0)).collect();
        let brackets = stage.brackets(&frames, false, &times, 0).unwrap();
        let r = recover_debevec(&brackets, &DebevecParams::default()).unwrap();
        let err: Vec<f64> = (0..3).map(|c| response_error(&r.inverse[c], &truth[c], JUDGED_CODES)).collect();
        eprintln!(
            "recovered response error (max over codes 10..=245): r {:.3} %, g {:.3} %, b {:.3} %",
            100.0 * err[0],
            100.0 * err[1],
            100.0 * err[2]
        );
        assert!(err.iter().all(|&e| e < 0.01), "{err:?}");
        // For the OpenCV peer (bench/peers/response_peers.py): the brackets as `import` reads
        // them, our response and the truth.
        if let Some(dir) = std::env::var_os("RESTAGE_WRITE_BRACKETS") {
            let dir = std::path::PathBuf::from(dir);
            for (j, b) in brackets.iter().enumerate() {
                let sub = dir.join(format!("e{j:02}"));
                std::fs::create_dir_all(&sub).unwrap();
                RgbImage::from_fn(b.width, b.height, |x, y| Rgb(b.codes[(y * b.width + x) as usize]))
                    .save(sub.join("white.png"))
                    .unwrap();
                let sidecar = serde_json::to_string(&ExposureSidecar { exposure_s: b.exposure_s }).unwrap();
                std::fs::write(sub.join(EXPOSURE_FILE), sidecar).unwrap();
            }
            r.save(&dir.join("response.json")).unwrap();
            let t = crate::calibrate::response::CameraResponse {
                inverse: truth.clone(),
                method: "true curve".into(),
                ..r.clone()
            };
            t.save(&dir.join("truth.json")).unwrap();
        }
        // Noisier sensors bias the dark codes (noise moves darker pixels into them): shown,
        // not judged.
        for (read_noise, shot_noise) in [(1.0e-5, 5.0e-6), (3.0e-5, 2.0e-5)] {
            let mut setup = super::super::Setup::from_config(&SceneConfig::tiny(SceneName::Vase, 5)).unwrap();
            setup.camera_spec.codes = Some(CodeCamera { read_noise, shot_noise, ..CodeCamera::default() });
            let b = VirtualStage::from_setup(setup).brackets(&frames, false, &times, 0).unwrap();
            let r = recover_debevec(&b, &DebevecParams::default()).unwrap();
            let e: Vec<f64> =
                (0..3).map(|c| 100.0 * response_error(&r.inverse[c], &truth[c], JUDGED_CODES)).collect();
            eprintln!("with read noise {read_noise}, shot noise {shot_noise}: {e:.3?} %");
        }
        // The camera is far from what `capture` assumed before: sRGB is off by far more.
        let srgb: Vec<f64> =
            (0..256).map(|z| crate::imgio::srgb_to_linear(z as f32 / 255.0) as f64).collect();
        let srgb_err = response_error(&srgb, &truth[1], JUDGED_CODES);
        eprintln!("assuming sRGB instead: {:.1} %", 100.0 * srgb_err);
        assert!(srgb_err > 0.1, "{srgb_err}");
    }

    #[test]
    fn default_captures_are_linear_and_brackets_need_the_code_camera() {
        let plain = VirtualStage::new(&SceneConfig::tiny(SceneName::Vase, 5)).unwrap();
        let frames = plain.black_frames();
        assert!(matches!(plain.brackets(&frames, true, &[1.0], 0), Err(StageSimError::NoCodeCamera)));
        // The 8-bit output does not touch the linear captures.
        let coded = nonlinear_stage();
        assert_eq!(plain.capture(&frames, true, 3).unwrap(), coded.capture(&frames, true, 3).unwrap());
        // Saturation: a long exposure clips the lit object at 255, a short one does not.
        let b = coded.brackets(&frames, true, &[1.0 / 64.0, 64.0], 0).unwrap();
        let max = |b: &crate::calibrate::response::Bracket| b.codes.iter().map(|p| p[1]).max().unwrap();
        assert!(max(&b[0]) < 255 && max(&b[1]) == 255);
    }
}
