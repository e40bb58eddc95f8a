//! `restage-author compensate --device ...` through the real binary: with no usable GPU
//! adapter (`WGPU_BACKEND=gl`, a backend this build does not include), `auto` falls back to
//! the CPU path and says so in the log, and `gpu` is refused with a clear message.

use std::path::Path;
use std::process::Command;

use restage_authoring::compensate::synthetic::{SyntheticSpec, build};
use restage_authoring::imgio::LinearImage;

fn author(args: &[&str], dir: &Path, no_gpu: bool) -> (bool, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_restage-author"));
    cmd.args(args).current_dir(dir).env("RUST_LOG", "info");
    if no_gpu {
        cmd.env("WGPU_BACKEND", "gl");
    }
    let o = cmd.output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    (o.status.success(), text)
}

#[test]
fn auto_falls_back_to_the_cpu_and_gpu_is_refused_without_an_adapter() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let s = build(&SyntheticSpec { camera: (64, 48), projector: (56, 42), ..SyntheticSpec::small(3, 9) });
    s.model.save(&dir.join("stage")).unwrap();
    let cam = &s.model.camera;
    let mut t = LinearImage::new(cam.width, cam.height).unwrap();
    for (v, a) in t.data.iter_mut().zip(&s.albedo) {
        *v = if a[0].is_finite() { a.map(|c| 0.8 * c) } else { [0.0; 3] };
    }
    t.save_srgb8(&dir.join("restored.png"), 1.0).unwrap();
    let run = |device: &str, out: &str, no_gpu: bool| {
        author(
            &["compensate", "stage", "restored.png", "--ebound-lux", "150", "--device", device, "--out", out],
            dir,
            no_gpu,
        )
    };
    let (ok, text) = run("cpu", "cpu", false);
    assert!(ok, "{text}");
    let (ok, text) = run("auto", "auto", true);
    assert!(ok, "{text}");
    assert!(text.contains("no GPU adapter"), "the fallback is logged: {text}");
    assert_eq!(text.matches("no GPU adapter").count(), 1, "said once: {text}");
    for k in 0..3 {
        let a = image::open(dir.join(format!("cpu/proj{k}.png"))).unwrap();
        let b = image::open(dir.join(format!("auto/proj{k}.png"))).unwrap();
        assert_eq!(a, b, "auto without an adapter is the CPU path");
    }
    let (ok, text) = run("gpu", "gpu", true);
    assert!(!ok, "--device gpu without an adapter must fail");
    assert!(text.contains("no GPU adapter could be opened") && text.contains("--device cpu"), "{text}");
}
