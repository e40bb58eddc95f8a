//! The decoder on a real capture made by another tool (kamino410/procam-calibration, OpenCV
//! `GrayCodePattern` order; see `shared/data/real/procam-graycode-plane/README.md`), through
//! the CLI: the pixels restage decodes beyond OpenCV's are as consistent with their
//! neighbours as the ones both decode.
//!
//! And the rig from both poses of the board (`rig --chessboard`), against the calibration the
//! data's authors made with OpenCV (`sample_data/calibration_result.xml` in their repository).
//!
//! `--strict` (reject every weak bit, as OpenCV does) decodes exactly OpenCV's pixels on this
//! capture (`bench/peers/decode_peers.py`: 735,662 on pose 0, identical values), so it stands in
//! for OpenCV here, which the tests cannot depend on.

use std::path::{Path, PathBuf};
use std::process::Command;

use restage_authoring::calibrate::decode::{self, DecodeQuality, MAP_SCALE};
use restage_tests::author_bin;

/// The real capture's folder: `RESTAGE_REAL_DATA` or the workspace's sibling `shared/data/real`
/// (None, said on stderr, where it is missing).
fn pose(name: &str) -> Option<PathBuf> {
    let root = std::env::var_os("RESTAGE_REAL_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/real"));
    let dir = root.join("procam-graycode-plane").join(name);
    let found = dir.join("graycode_41.png").exists().then_some(dir);
    if found.is_none() {
        eprintln!(
            "SKIPPED: no real capture (set RESTAGE_REAL_DATA to the folder holding procam-graycode-plane)"
        );
    }
    found
}

fn decode_cli(capture: &Path, out: &Path, extra: &[&str]) -> (DecodeQuality, Vec<f32>, Vec<f32>) {
    let status = Command::new(author_bin())
        .args(["decode", "--opencv-order", "--projector-size", "1024x768", "--out"])
        .arg(out)
        .arg(capture)
        .args(extra)
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(out.join("decode.json")).unwrap();
    let mut q: Vec<DecodeQuality> = serde_json::from_str(&text).unwrap();
    let map = |name: &str| -> Vec<f32> {
        let img = image::open(out.join(name)).unwrap().to_luma16();
        img.pixels().map(|p| if p.0[0] == 0 { f32::NAN } else { (p.0[0] as f32 - 1.0) / MAP_SCALE }).collect()
    };
    (q.remove(0), map("proj0_x.png"), map("proj0_y.png"))
}

#[test]
fn extra_pixels_on_a_real_capture_are_as_consistent_as_the_common_ones() {
    let Some(capture) = pose("capture") else { return };
    let dir = tempfile::tempdir().unwrap();
    let (strict, sx, _) = decode_cli(&capture, &dir.path().join("strict"), &["--strict"]);
    let (q, x, y) = decode_cli(&capture, &dir.path().join("default"), &[]);
    assert_eq!(strict.decoded, 735_662, "OpenCV decodes 735,662 pixels here");
    assert_eq!(q.lit, q.decoded + q.weak + q.out_of_range + q.weak_inconsistent + q.phase_rejected, "{q:?}");
    // Coverage: 1.18x OpenCV's when measured (1.22x before the neighbourhood check).
    assert!(q.decoded as f64 > 1.15 * strict.decoded as f64, "{q:?}");
    let bad = decode::inconsistent_pixels(&x, &y, 1280, 1024);
    let (mut common, mut extra) = ((0usize, 0usize), (0usize, 0usize));
    for i in 0..x.len() {
        if !x[i].is_finite() {
            continue;
        }
        let set = if sx[i].is_finite() { &mut common } else { &mut extra };
        set.0 += 1;
        set.1 += usize::from(bad[i]);
    }
    let pct = |(n, b): (usize, usize)| 100.0 * b as f64 / n as f64;
    eprintln!("inconsistent: common {:.4} %, restage-only {:.4} %", pct(common), pct(extra));
    assert_eq!(common.0, strict.decoded, "every pixel strict decodes is decoded by default");
    assert!(pct(extra) <= 2.0 * pct(common), "restage-only {} % vs common {} %", pct(extra), pct(common));
    assert!((q.inconsistent as f64 - (common.1 + extra.1) as f64 / q.decoded as f64).abs() < 1e-6, "{q:?}");
    // decode.json's split (no weak bit vs weak bit kept) is the same split here: the pixels
    // read with no weak bit are exactly OpenCV's.
    assert!((100.0 * q.inconsistent_confident as f64 - pct(common)).abs() < 1e-4, "{q:?}");
    assert!((100.0 * q.inconsistent_weak as f64 - pct(extra)).abs() < 1e-4, "{q:?}");
    assert_eq!(q.one_weak_bit, extra.0, "{q:?}");
}

#[test]
fn mistaken_inputs_get_messages_that_say_what_to_do() {
    let Some(capture) = pose("capture") else { return };
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(author_bin()).arg("decode").arg(&capture).args(args).output().unwrap();
        (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let out = dir.path().join("a");
    let out = out.to_str().unwrap();
    let (ok, err) = run(&["--out", out]);
    assert!(!ok && err.contains("no capture.json") && err.contains("--opencv-order"), "{err}");
    let (ok, err) = run(&["--opencv-order", "--projector-size", "0x768", "--out", out]);
    assert!(!ok && err.contains("--projector-size") && err.contains("zero side"), "{err}");
    let (ok, err) = run(&["--opencv-order", "--projector-size", "768x1024", "--out", out, "--force"]);
    assert!(ok && err.contains("768x1024") && err.contains("looks transposed"), "{err}");
}

/// `rig --chessboard` on the two real poses: Moreno-Taubin corners and Zhang, camera calibrated
/// too. OpenCV's calibration of the same images by the data's authors (calibrateCamera and
/// stereoCalibrate, 5 distortion terms each) gives the camera fx 3452.4, fy 3449.9 px and the
/// projector's centre (-30.4, 206.6, 50.1) mm in the camera frame at 25 mm squares. Their
/// projector intrinsics (f 3954, cy 1358 on a 768-row projector) are not a reference: two poses
/// cannot carry 5 distortion terms per device.
#[test]
fn the_real_rig_calibrates_from_two_poses_of_its_chessboard() {
    let (Some(a), Some(b)) = (pose("capture"), pose("capture_1")) else { return };
    let dir = tempfile::tempdir().unwrap();
    let rig_cli = |out: &str, extra: &[&str]| {
        Command::new(author_bin())
            .args(["rig", "--opencv-order", "--projector-size", "1024x768", "--chessboard", "9x7"])
            .args(["--square-mm", "25", "--out"])
            .arg(dir.path().join(out))
            .args([&a, &b])
            .args(extra)
            .output()
            .unwrap()
    };
    let run = rig_cli("board", &[]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let rig = restage_authoring::calibrate::rig::Rig::load(&dir.path().join("board")).unwrap();
    let fit = rig.board.as_ref().unwrap();
    let p = &rig.projectors[0];
    let s = &p.conditioning;
    eprintln!(
        "camera fx {:.1} fy {:.1} ({:.3} px RMS); projector f {:.1} +- {:.1}, cy {:.1} +- {:.1} ({:.3} px RMS), \
         centre {:?}, epipolar median {:.3} px",
        rig.camera.fx,
        rig.camera.fy,
        fit.camera_rms_px,
        p.f,
        s.f_std_px,
        p.cy,
        s.cy_std_px,
        p.rms_px,
        p.geometry().centre(),
        p.epipolar_median_px
    );
    assert_eq!((fit.poses, fit.projector_corners[0] >= 80), (2, true), "{fit:?}");
    assert!(fit.camera_rms_px < 0.5 && p.rms_px < 0.5, "{fit:?} {}", p.rms_px);
    assert!((rig.camera.fx / 3452.4 - 1.0).abs() < 0.01 && (rig.camera.fy / 3449.9 - 1.0).abs() < 0.01);
    assert!(s.f_std_px < 0.01 * p.f && s.cy_std_px < 0.02 * 768.0 && s.cx_std_px < 0.02 * 1024.0, "{s:?}");
    let c = p.geometry().centre();
    assert!((c.x + 30.4).abs() < 10.0 && (c.y - 206.6).abs() < 10.0 && (c.z - 50.1).abs() < 40.0, "{c}");
    // Every decoded pixel (not only the corners) lies on the rig's epipolar lines.
    assert!(p.epipolar_median_px < 1.0, "{}", p.epipolar_median_px);

    // The camera of the folder's camera_config.json is another camera (it says 960 rows, the
    // images have 1024): held fixed, the board refuses it rather than bend the projector.
    let wrong = rig_cli(
        "wrong",
        &[
            "--camera-intrinsics",
            "744.28,741.75,634.20,473.02",
            "--camera-distortion=0.1041,-0.193,-0.0024,-0.0037,0.046",
        ],
    );
    assert!(!wrong.status.success());
    assert!(String::from_utf8_lossy(&wrong.stderr).contains("do not determine projector 0"));
}
