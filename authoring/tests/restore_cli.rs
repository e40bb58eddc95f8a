//! `restage-author restore` end to end through the real binary: a chipped, noisy label map
//! with its palette is restored into labels, image and before/after sheet; bad inputs are
//! refused with messages that name the problem.

use std::path::Path;
use std::process::Command;

use restage_authoring::classify::{LabelMap, PALETTE_VERSION, Palette, PaletteClass};

fn author(args: &[&str], dir: &Path) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-author")).args(args).current_dir(dir).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    (o.status.success(), text)
}

fn class(name: &str, rgb: [f64; 3]) -> PaletteClass {
    PaletteClass {
        name: name.into(),
        representative_xyy: [0.33, 0.33, rgb[1]],
        mean_linear_rgb: rgb,
        pixels: 0,
        display_srgb8: None,
    }
}

/// Clay (0) with two black (1) bands, chipped, and stray black specks.
fn classified(dir: &Path, labels: impl Fn(u32, u32) -> u8) -> (LabelMap, LabelMap) {
    let (w, h) = (120, 80);
    let truth = |_x: u32, y: u32| u8::from((16..30).contains(&y) || (46..60).contains(&y));
    let data: Vec<u8> = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| labels(x, y)).collect();
    let pristine: Vec<u8> =
        (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| truth(x, y)).collect();
    std::fs::create_dir_all(dir).unwrap();
    let map = LabelMap::from_vec(w, h, data).unwrap();
    map.save(&dir.join("labels.png")).unwrap();
    Palette {
        version: PALETTE_VERSION,
        classes: vec![class("clay", [0.5, 0.35, 0.2]), class("black", [0.03, 0.03, 0.03])],
        weights: [0.3, 0.3, 0.4],
        channel_scale: [0.003, 0.003, 0.05],
        iterations: 3,
        converged: true,
    }
    .save(&dir.join("palette.json"))
    .unwrap();
    (map, LabelMap::from_vec(w, h, pristine).unwrap())
}

fn damaged(x: u32, y: u32) -> u8 {
    let band = (16..30).contains(&y) || (46..60).contains(&y);
    let chip =
        (30..36).contains(&x) && (16..20).contains(&y) || (70..73).contains(&x) && (50..53).contains(&y);
    let speck = (x * 31 + y * 17).is_multiple_of(97);
    u8::from(band != (chip || speck))
}

#[test]
fn restores_a_chipped_label_map_and_writes_three_pictures() {
    let tmp = tempfile::tempdir().unwrap();
    let cls = tmp.path().join("classify");
    let (before, pristine) = classified(&cls, damaged);
    let out = tmp.path().join("restored");
    let (ok, text) = author(&["restore", "classify", "--out", "restored", "--grid", "2x2"], tmp.path());
    assert!(ok, "{text}");
    assert!(text.contains("restored") && text.contains("moves"), "{text}");
    let after = LabelMap::load(&out.join("labels.png")).unwrap();
    let wrong = |m: &LabelMap| m.data.iter().zip(&pristine.data).filter(|(a, b)| a != b).count();
    assert!(wrong(&after) * 3 < wrong(&before), "{} -> {}", wrong(&before), wrong(&after));
    let img = image::open(out.join("restored.png")).unwrap();
    assert_eq!((img.width(), img.height()), (120, 80));
    let sheet = image::open(out.join("before_after.png")).unwrap();
    assert_eq!((sheet.width(), sheet.height()), (248, 80));

    // A region leaves everything outside it alone.
    let (ok, text) =
        author(&["restore", "classify", "--out", "r2", "--region", "rect:0,0,60,80@0"], tmp.path());
    assert!(ok, "{text}");
    let part = LabelMap::load(&tmp.path().join("r2/labels.png")).unwrap();
    for y in 0..80 {
        for x in 60..120 {
            assert_eq!(part.get(x, y), before.get(x, y));
        }
    }
}

#[test]
fn bad_inputs_are_refused_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    classified(&tmp.path().join("c"), |x, y| if x == 5 && y == 7 { 4 } else { damaged(x, y) });
    let (ok, text) = author(&["restore", "c", "--out", "o"], tmp.path());
    assert!(!ok && text.contains("label 4 at pixel (5, 7)") && text.contains("labels.png"), "{text}");

    classified(&tmp.path().join("good"), damaged);
    let (ok, text) = author(&["restore", "good", "--out", "o", "--alpha", "0"], tmp.path());
    assert!(!ok && text.contains("alpha 0 is out of range"), "{text}");
    let (ok, text) = author(&["restore", "good", "--out", "o", "--beta", "0.5"], tmp.path());
    assert!(!ok && text.contains("beta 0.5 is out of range"), "{text}");
    let (ok, text) = author(&["restore", "good", "--out", "o", "--region", "rect:100,0,50,10"], tmp.path());
    assert!(!ok && text.contains("outside the 120x80 image"), "{text}");

    let mut strokes = image::RgbaImage::new(120, 80);
    strokes.put_pixel(3, 4, image::Rgba([255, 0, 0, 255]));
    strokes.save(tmp.path().join("hints.png")).unwrap();
    let (ok, text) = author(&["restore", "good", "--out", "o", "--hints", "hints.png"], tmp.path());
    assert!(!ok && text.contains("hints.png") && text.contains("not a class colour"), "{text}");
}
