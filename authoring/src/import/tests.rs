//! Import tests: the virtual non-linear camera end to end, EXIF exposure times, layouts refused.

use image::{Rgb, RgbImage};

use super::*;
use crate::calibrate::decode::{CaptureImages, DecodeParams, decode_projector};
use crate::stage_sim::foreign::write_foreign_capture;
use crate::stage_sim::optics::CodeCamera;
use crate::stage_sim::{SceneConfig, SceneName, Setup, VirtualStage};

fn nonlinear_stage() -> VirtualStage {
    let mut setup = Setup::from_config(&SceneConfig::tiny(SceneName::Jar, 4)).unwrap();
    setup.camera_spec.codes = Some(CodeCamera::default());
    VirtualStage::from_setup(setup)
}

/// Share of pixels the truth says projector 0 lights that decode within 1 projector pixel.
fn decoded_share(stage: &VirtualStage, dir: &Path) -> f64 {
    let manifest = CaptureManifest::load(dir).unwrap();
    let p = &manifest.projectors[0];
    let images = CaptureImages {
        dir,
        projector: p,
        width: manifest.camera.width,
        height: manifest.camera.height,
        raw: false,
    };
    let d = decode_projector(&images, 0, p.width, p.height, &DecodeParams::default()).unwrap();
    let truth = &stage.truth().correspondences[0];
    let (mut seen, mut good) = (0, 0);
    for (i, t) in truth.iter().enumerate() {
        if t[0].is_finite() && d.contrast[i] > 0.02 {
            seen += 1;
            if d.is_valid(i) && (d.x[i] - t[0]).abs() <= 1.0 && (d.y[i] - t[1]).abs() <= 1.0 {
                good += 1;
            }
        }
    }
    good as f64 / seen.max(1) as f64
}

/// Virtual non-linear camera, OpenCV order, three exposures → import (response recovered
/// from the white pattern) → the capture set decodes like a native one.
#[test]
fn a_foreign_capture_of_the_nonlinear_camera_imports_and_decodes() {
    let stage = nonlinear_stage();
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("raw");
    let times = [1.0 / 8.0, 0.5, 2.0, 8.0];
    let n = write_foreign_capture(&stage, &raw, PatternOrder::Opencv, &times, true).unwrap();
    assert_eq!(n, 4 * (1 + 2 * (7 + 7) + 2));
    let out = dir.path().join("capture");
    let spec = ImportSpec {
        order: PatternOrder::Opencv,
        projector: (128, 96),
        photo_first: true,
        camera: stage.camera().clone(),
        response: ResponseSource::Recover(DebevecParams::default()),
    };
    let summary = import(&raw, &out, &spec).unwrap();
    assert_eq!((summary.exposures, summary.full_scale_exposure_s), (4, 0.125));
    // The saved response is close to the camera's true one.
    let r = CameraResponse::load(&out.join(RESPONSE_FILE)).unwrap();
    let truth = stage.setup().camera_spec.codes.as_ref().unwrap().curve.inverse();
    let err = response::response_error(&r.inverse[1], &truth[1], response::JUDGED_CODES);
    // Four whole-stop exposures are fewer than a response calibration wants (the headline
    // figure uses 23 half-stop brackets); good enough to linearise for decoding.
    assert!(err < 0.05, "green response {:.2} % off", 100.0 * err);
    let share = decoded_share(&stage, &out);
    eprintln!(
        "imported foreign capture: {:.1} % of lit pixels decode within 1 px; response {:.2} % off",
        100.0 * share,
        100.0 * err
    );
    assert!(share > 0.9, "{share}");
    // Linear: the merged photo is proportional to the true noise-free render where both are
    // well exposed (one scale for all pixels).
    let photo = LinearImage::load(&out.join(PHOTO_FILE)).unwrap();
    let clean = stage.render_unclipped(&stage.black_frames(), true).unwrap();
    let ratios: Vec<f64> = photo
        .data
        .iter()
        .zip(&clean.data)
        .filter(|(_, c)| c[1] > 0.05 && c[1] * 8.0 < 1.0)
        .map(|(p, c)| p[1] as f64 / c[1] as f64)
        .collect();
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    let spread = ratios.iter().map(|r| (r / mean - 1.0).abs()).fold(0.0, f64::max);
    assert!(ratios.len() > 500 && spread < 0.05, "{} pixels, spread {spread}", ratios.len());
}

#[test]
fn restage_order_and_a_saved_response_import_too() {
    let stage = nonlinear_stage();
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("raw");
    write_foreign_capture(&stage, &raw, PatternOrder::Restage, &[0.5, 2.0], false).unwrap();
    let curve = stage.setup().camera_spec.codes.as_ref().unwrap().curve.clone();
    let mut inverse = curve.inverse();
    inverse.iter_mut().for_each(|h| h[0] = h[1] / 2.0);
    let saved = CameraResponse { version: 1, inverse, method: "true curve".into(), residual_rms: [0.0; 3] };
    let path = dir.path().join("resp.json");
    saved.save(&path).unwrap();
    let spec = ImportSpec {
        order: PatternOrder::Restage,
        projector: (128, 96),
        photo_first: false,
        camera: stage.camera().clone(),
        response: ResponseSource::File(path),
    };
    let out = dir.path().join("capture");
    import(&raw, &out, &spec).unwrap();
    let m = CaptureManifest::load(&out).unwrap();
    assert_eq!(m.photo, Path::new("proj0/white.png"));
    assert!(m.source.contains("true curve"), "{}", m.source);
    assert!(decoded_share(&stage, &out) > 0.9);
    // A wrong projector size does not fit the image count, and says what would.
    let bad = ImportSpec { projector: (300, 96), ..spec };
    let e = import(&raw, &dir.path().join("bad"), &bad).unwrap_err().to_string();
    assert!(e.contains("restage order") && e.contains("expected one of"), "{e}");
}

#[test]
fn exposure_comes_from_exif_else_the_sidecar_else_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    // A JPEG with an EXIF APP1 segment holding ExposureTime 1/125 s.
    let field = exif::Field {
        tag: exif::Tag::ExposureTime,
        ifd_num: exif::In::PRIMARY,
        value: exif::Value::Rational(vec![exif::Rational { num: 1, denom: 125 }]),
    };
    let mut writer = exif::experimental::Writer::new();
    writer.push_field(&field);
    let mut tiff = std::io::Cursor::new(Vec::new());
    writer.write(&mut tiff, false).unwrap();
    let mut jpeg = Vec::new();
    RgbImage::from_pixel(8, 6, Rgb([90, 120, 200]))
        .write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .unwrap();
    let payload = [b"Exif\0\0".as_slice(), tiff.get_ref()].concat();
    let len = (payload.len() + 2) as u16;
    let with_exif = [&jpeg[..2], &[0xff, 0xe1], &len.to_be_bytes(), &payload, &jpeg[2..]].concat();
    let a = dir.path().join("a.jpg");
    std::fs::write(&a, with_exif).unwrap();
    assert_eq!(exif_exposure(&a), Some(1.0 / 125.0));
    // Its pixels still read, 8-bit.
    assert_eq!(load_bracket(&a, 0.008).unwrap().codes.len(), 48);
    // A PNG without EXIF in the same folder and no sidecar: refused, naming the file.
    let b = dir.path().join("b.png");
    RgbImage::new(8, 6).save(&b).unwrap();
    let e = scan(dir.path()).unwrap_err().to_string();
    assert!(e.contains("b.png") && e.contains(EXPOSURE_FILE), "{e}");
    std::fs::write(dir.path().join(EXPOSURE_FILE), r#"{"exposure_s": 0.02}"#).unwrap();
    let sets = scan(dir.path()).unwrap();
    assert_eq!(sets[0].exposures_s, vec![1.0 / 125.0, 0.02]);
    std::fs::write(dir.path().join(EXPOSURE_FILE), r#"{"exposure_s": -1}"#).unwrap();
    assert!(scan(dir.path()).unwrap_err().to_string().contains("positive"));
}

#[test]
fn opencv_order_matches_the_decoders_mapping() {
    let files: Vec<PathBuf> = (0..42).map(|i| format!("{i:02}.png").into()).collect();
    let cap = crate::calibrate::decode::opencv_order(&files, 1024, 768).unwrap();
    let ours = sequence(PatternOrder::Opencv, 1024, 768, 42).unwrap();
    let theirs: Vec<Pattern> = cap.shots.into_iter().map(|s| s.pattern).collect();
    assert_eq!(ours, theirs);
    assert!(sequence(PatternOrder::Opencv, 1024, 768, 41).is_err());
}
