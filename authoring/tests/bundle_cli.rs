//! The bundle commands end to end through the real binary: keygen, bundle (from frame PNGs,
//! a certificate file, a stage model and a description), inspect, verify; and the refusals
//! a conservator meets (over-bound frames, a key not trusted).

use std::path::Path;
use std::process::Command;

use restage_authoring::capture_set::CameraIntrinsics;
use restage_authoring::stage_model::{ProjectorModel, StageModel, Transport};
use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame};

fn author(args: &[&str], dir: &Path) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-author")).args(args).current_dir(dir).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    (o.status.success(), text)
}

fn stage(spec: &ExampleSpec) -> StageModel {
    let ramp: Vec<f32> = (0..256).map(|i| (i as f32 / 255.0).powf(2.2)).collect();
    let proj = ProjectorModel {
        width: spec.width,
        height: spec.height,
        f: 40.0,
        cx: 16.0,
        cy: 12.0,
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
        response: [ramp.clone(), ramp.clone(), ramp],
        black: [0.01; 3],
        lux_at_1m: 400.0,
        vignetting: vec![],
    };
    StageModel {
        camera: CameraIntrinsics {
            width: 1,
            height: 1,
            fx: 10.0,
            fy: 10.0,
            cx: 0.0,
            cy: 0.0,
            distortion: [0.0; 5],
        },
        projectors: vec![proj; spec.projectors],
        points: vec![[0.0, 0.0, 500.0]],
        normals: vec![[0.0, 0.0, -1.0]],
        correspondences: vec![vec![[1.0, 1.0]]; spec.projectors],
        transport: vec![Transport::default(); spec.projectors],
        gain: vec![],
        ambient: vec![],
        provenance: "bundle_cli test".into(),
    }
}

/// Writes the stage model, certificate, frames and a description into `dir`.
fn inputs(dir: &Path, spec: &ExampleSpec) {
    stage(spec).save(&dir.join("stage")).unwrap();
    std::fs::write(dir.join("certificate.bin"), example_certificate(spec).to_bytes()).unwrap();
    let mut scenes = String::new();
    for (s, (id, kind)) in [("original", "original"), ("restored", "restoration")].into_iter().enumerate() {
        let mut frames = Vec::new();
        for k in 0..spec.projectors {
            let xrgb = example_frame(spec, s, k);
            let rgb: Vec<u8> = xrgb.chunks_exact(4).flat_map(|p| [p[2], p[1], p[0]]).collect();
            let name = format!("{id}-p{k}.png");
            image::RgbImage::from_raw(spec.width, spec.height, rgb).unwrap().save(dir.join(&name)).unwrap();
            frames.push(format!("{name:?}"));
        }
        scenes += &format!(
            "[[scenes]]\nid = {id:?}\nname = \"{id} scene\"\nkind = {kind:?}\nframes = [{}]\n\n",
            frames.join(", ")
        );
    }
    let projectors: String = (0..spec.projectors)
        .map(|k| {
            format!(
                "[[projectors]]\nname = \"p{k}\"\nrefresh_hz = 60.0\nconnector = \"Virtual-{}\"\n\n",
                k + 1
            )
        })
        .collect();
    let desc = format!(
        "version = 7\nstage = \"stage\"\ncertificate = \"certificate.bin\"\nvalid_days = 30\n\n\
         [object]\nid = \"jar-17\"\nname = \"Test jar\"\n\n\
         [light]\ne_bound_lux = 50.0\nsafety_margin = 0.05\n\n\
         [policy]\nclass = \"medium\"\nmax_showing_s = 45\nidle = \"scene:original\"\n\n{projectors}{scenes}"
    );
    std::fs::write(dir.join("bundle.toml"), desc).unwrap();
}

#[test]
fn keygen_bundle_inspect_verify() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = ExampleSpec::small();
    inputs(d, &spec);
    let (ok, out) = author(&["keygen", "--out", "conservator"], d);
    assert!(ok, "{out}");
    assert!(d.join("conservator.pem").exists() && d.join("conservator.pub.pem").exists());
    let (ok, out) = author(&["keygen", "--out", "conservator"], d);
    assert!(!ok && out.contains("already exists"), "{out}");

    let (ok, out) = author(
        &[
            "bundle",
            "bundle.toml",
            "--key",
            "conservator.pem",
            "--out",
            "jar.restage",
            "--created",
            "1700000000",
        ],
        d,
    );
    assert!(ok, "{out}");
    std::fs::create_dir(d.join("trust")).unwrap();
    std::fs::copy(d.join("conservator.pub.pem"), d.join("trust/conservator.pem")).unwrap();

    let (ok, out) = author(&["inspect", "jar.restage"], d);
    assert!(ok, "{out}");
    assert!(out.contains("jar-17") && out.contains("NOT CHECKED") && out.contains("peak"), "{out}");
    assert!(out.contains("Virtual-2") && out.contains("scene original") && out.contains("45 s"), "{out}");
    let (ok, out) = author(&["inspect", "jar.restage", "--trust", "trust", "--now", "1700000100"], d);
    assert!(ok && out.contains("signature: verified"), "{out}");

    // Valid for 30 days from the given creation time.
    let (ok, out) = author(&["verify", "jar.restage", "--trust", "trust", "--now", "1700000100"], d);
    assert!(ok && out.starts_with("OK") && out.contains("version 7"), "{out}");
    let (ok, out) = author(&["verify", "jar.restage", "--trust", "trust", "--now", "1800000000"], d);
    assert!(!ok && out.contains("expired"), "{out}");
    let (ok, out) = author(
        &["verify", "jar.restage", "--trust", "trust", "--now", "1700000100", "--accepted-version", "8"],
        d,
    );
    assert!(!ok && out.contains("rollback"), "{out}");

    // A key that is not trusted.
    author(&["keygen", "--out", "stranger"], d);
    let (ok, out) = author(
        &["bundle", "bundle.toml", "--key", "stranger.pem", "--out", "s.restage", "--created", "1700000000"],
        d,
    );
    assert!(ok, "{out}");
    let (ok, out) = author(&["verify", "s.restage", "--trust", "trust", "--now", "1700000100"], d);
    assert!(!ok && out.contains("not in the trust store"), "{out}");
}

#[test]
fn bundle_refuses_frames_over_the_bound() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 2 x 40 lx per unit at full white is over 47.5 lx.
    let spec = ExampleSpec { lux_per_unit: 40.0, ..ExampleSpec::small() };
    inputs(d, &spec);
    author(&["keygen", "--out", "k"], d);
    let (ok, out) = author(&["bundle", "bundle.toml", "--key", "k.pem", "--out", "x.restage"], d);
    assert!(!ok && out.contains("exceeds the allowed"), "{out}");
    assert!(!d.join("x.restage").exists());
}
