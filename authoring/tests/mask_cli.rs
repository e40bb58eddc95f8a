//! `restage-author mask` then `compensate --mask` through the real binary: the outline makes
//! the object mask, and with it the frames light no projector pixel that reaches only points
//! outside the mask (without it they do).

use std::path::Path;
use std::process::Command;

use restage_authoring::compensate::synthetic::{SyntheticSpec, build};
use restage_authoring::imgio::LinearImage;
use restage_authoring::segment::{Outline, load_mask};
use restage_authoring::stage_model::StageModel;

fn author(args: &[&str], dir: &Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-author"))
        .args(args)
        .current_dir(dir)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "restage-author {}:\n{text}", args.join(" "));
    text
}

#[test]
fn compensation_with_a_mask_leaves_dark_what_lights_only_the_outside() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let s = build(&SyntheticSpec { camera: (64, 48), projector: (56, 42), ..SyntheticSpec::small(2, 4) });
    s.model.save(&dir.join("stage")).unwrap();
    let cam = &s.model.camera;
    let mut t = LinearImage::new(cam.width, cam.height).unwrap();
    for (v, a) in t.data.iter_mut().zip(&s.albedo) {
        *v = if a[0].is_finite() { a.map(|c| 0.8 * c) } else { [0.0; 3] };
    }
    t.save_srgb8(&dir.join("restored.png"), 1.0).unwrap();
    // The conservator outlines the left half of the picture.
    let half = cam.width as f64 / 2.0;
    let outline = Outline { polygons: vec![vec![[-1.0, -1.0], [half, -1.0], [half, 99.0], [-1.0, 99.0]]] };
    outline.save(&dir.join("outline.json")).unwrap();
    let said = author(&["mask", "--stage", "stage", "--outline", "outline.json", "--out", "mask"], dir);
    assert!(said.contains("object mask from the outline"), "{said}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("mask/mask.json")).unwrap()).unwrap();
    assert_eq!(summary["source"], "outline");
    let mask = load_mask(&dir.join("mask/object_mask.png"), cam.width, cam.height).unwrap();
    let model = StageModel::load(&dir.join("stage")).unwrap();
    let inside = mask.iter().zip(&model.points).filter(|(m, p)| **m && p[2].is_finite()).count();
    let outside = mask.iter().zip(&model.points).filter(|(m, p)| !**m && p[2].is_finite()).count();
    assert!(inside > 100 && outside > 100, "{inside} object points inside the mask, {outside} outside");

    let comp = |out: &str, with_mask: bool| {
        let mut a = vec![
            "compensate",
            "stage",
            "restored.png",
            "--ebound-lux",
            // The synthetic stage's projectors have black levels up to 2 %: at 150 lx their
            // black alone, charged at the whole-footprint coefficients, is over the bound.
            "400",
            "--device",
            "cpu",
            "--out",
            out,
        ];
        if with_mask {
            a.extend(["--mask", "mask/object_mask.png"]);
        }
        author(&a, dir);
    };
    comp("full", false);
    comp("masked", true);

    let mut far_without_mask = 0;
    for (k, p) in model.projectors.iter().enumerate() {
        // Projector pixels within 3 px of where a point inside the mask falls.
        let (pw, ph) = (p.width as i64, p.height as i64);
        let mut near = vec![false; (pw * ph) as usize];
        for (i, c) in model.correspondences[k].iter().enumerate() {
            if !mask[i] || !c[0].is_finite() {
                continue;
            }
            let (u, v) = (c[0].round() as i64, c[1].round() as i64);
            for y in (v - 3).max(0)..=(v + 3).min(ph - 1) {
                for x in (u - 3).max(0)..=(u + 3).min(pw - 1) {
                    near[(y * pw + x) as usize] = true;
                }
            }
        }
        let lit_far = |out: &str| {
            let f = image::open(dir.join(format!("{out}/proj{k}.png"))).unwrap().to_rgb8();
            let lit = f.pixels().filter(|q| q.0.iter().any(|&c| c > 0)).count();
            let far = f.pixels().zip(&near).filter(|(q, n)| !**n && q.0.iter().any(|&c| c > 0)).count();
            (lit, far)
        };
        let (lit_full, far_full) = lit_far("full");
        let (lit_masked, far_masked) = lit_far("masked");
        far_without_mask += far_full;
        assert!(lit_full > 0, "projector {k} lights nothing");
        assert!(lit_masked > 0, "projector {k}: the object inside the mask is still lit");
        assert_eq!(far_masked, 0, "projector {k}: {far_masked} px light only points outside the mask");
    }
    assert!(far_without_mask > 0, "without the mask some projector lights the outside");
}
