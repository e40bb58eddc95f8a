//! End to end across crates: the virtual stage's true stage model → compensation of the
//! object's pristine look and of its as-found look → a signed bundle from the authoring
//! side's export code → the appliance played headless as a real process, the button pressed
//! on its control socket → the recorded frames shown on the virtual stage with its true
//! physics: what a visitor sees is closer to the restoration than the original scene, and the
//! true irradiance of every recorded frame set (fades included) stays within E_bound.

mod appliance_common;

use std::collections::HashSet;
use std::path::Path;
use std::time::Duration;

use appliance_common::{OBJECT, Stage, ask, unix_us, wait_status};
use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use restage_authoring::color::{ciede2000, linear_srgb_to_lab};
use restage_authoring::compensate::guarantee::bound_lux;
use restage_authoring::compensate::{self, Compensation, Exponent, Params, Prepared};
use restage_authoring::eval::compensate::colour_error;
use restage_authoring::export::{BundleDescription, build_writer};
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_sim::{SceneConfig, SceneName, VirtualStage};
use restage_shared::bundle::example::ExampleSpec;
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};
use restage_shared::light::LightCertificate;

/// Maximum irradiance per unit area, lux (a sensitive object: well below full white).
const E_BOUND: f64 = 50.0;
const MARGIN: f64 = 0.05;

/// The object's albedo (pristine or as found) as a camera-space target; 0 off the object.
fn albedo_target(stage: &VirtualStage, pristine: bool) -> LinearImage {
    let cam = stage.camera();
    let mut t = LinearImage::new(cam.width, cam.height).unwrap();
    for (v, p) in t.data.iter_mut().zip(stage.pixels()) {
        if p.is_object() {
            *v = if pristine { p.albedo_pristine } else { p.albedo };
        }
    }
    t
}

/// XRGB8888 (bytes B, G, R, X) as the recorder wrote it → the renderer's 8-bit RGB frame.
fn rgb_from_recording(path: &Path, width: u32, height: u32) -> RgbImage {
    let xrgb = std::fs::read(path).unwrap();
    assert_eq!(xrgb.len(), (width * height * 4) as usize, "{}", path.display());
    let rgb = xrgb.chunks_exact(4).flat_map(|p| [p[2], p[1], p[0]]).collect();
    RgbImage::from_raw(width, height, rgb).unwrap()
}

/// Mean CIEDE2000 between two albedo images over the object (the deterioration's own size).
fn mean_de(a: &LinearImage, b: &LinearImage) -> f64 {
    let lab = |v: [f32; 3]| linear_srgb_to_lab(v.map(f64::from));
    let de: Vec<f64> = a
        .data
        .iter()
        .zip(&b.data)
        .filter(|(x, _)| x.iter().any(|&c| c > 0.0))
        .map(|(x, y)| ciede2000(lab(*x), lab(*y)))
        .collect();
    de.iter().sum::<f64>() / de.len().max(1) as f64
}

/// Highest true irradiance (lux, brightest channel, room light included) on the object.
fn true_peak(stage: &VirtualStage, frames: &[RgbImage]) -> f64 {
    let room = stage.setup().stray_lux;
    stage
        .irradiance(frames)
        .unwrap()
        .iter()
        .zip(stage.pixels())
        .filter(|(_, p)| p.is_object())
        .map(|(e, _)| bound_lux(e.map(|c| c as f64 + room)))
        .fold(0.0, f64::max)
}

#[test]
fn authored_bundle_played_by_the_appliance_restores_what_a_visitor_sees() {
    // Author: the true stage model of a tiny deteriorated jar, two compensations.
    let vs = VirtualStage::new(&SceneConfig::tiny(SceneName::Jar, 5)).unwrap();
    let model = vs.truth();
    let params = Params::new(E_BOUND, Exponent::Finite(8.0), MARGIN).unwrap();
    let prep = Prepared::new(&model, params.reduction).unwrap();
    let pristine = albedo_target(&vs, true);
    let as_found = albedo_target(&vs, false);
    let comp = |t: &LinearImage| compensate::compensate_prepared(&model, &prep, t, &params).unwrap();
    let (restored, original): (Compensation, Compensation) = (comp(&pristine), comp(&as_found));

    // Export: stage model, frames and certificate on disk, a description, a signed bundle.
    let n = model.projectors.len();
    let (pw, ph) = (model.projectors[0].width, model.projectors[0].height);
    // The recorder's frame sizes (the shared test stage reads frames by this spec).
    let spec = ExampleSpec { projectors: n, scenes: 2, width: pw, height: ph, ..ExampleSpec::small() };
    let dir = tempfile::tempdir().unwrap();
    for d in ["trust", "state", "rec", "author"] {
        std::fs::create_dir(dir.path().join(d)).unwrap();
    }
    let author = dir.path().join("author");
    model.save(&author.join("stage")).unwrap();
    compensate::io::save(&author.join("comp/original"), &original, &params, &prep).unwrap();
    compensate::io::save(&author.join("comp/restored"), &restored, &params, &prep).unwrap();
    let frames_toml = |scene: &str| {
        (0..n)
            .map(|k| format!("\"comp/{scene}/{}\"", compensate::io::frame_file(k)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let projectors_toml: String = (0..n).map(|k| format!("[[projectors]]\nname = \"p{k}\"\n")).collect();
    let desc_text = format!(
        "version = 1\nstage = \"stage\"\ncertificate = \"comp/restored/{cert}\"\n\
         [object]\nid = \"{OBJECT}\"\nname = \"Virtual jar\"\n\
         [light]\ne_bound_lux = {E_BOUND}\nsafety_margin = {MARGIN}\nambient_lux = {room}\n\
         [policy]\nclass = \"high\"\nmax_showing_s = 60\ncooldown_s = 0\ndaily_budget_lxh = 1000.0\n\
         annual_budget_lxh = 100000.0\nidle = \"scene:original\"\n{projectors_toml}\
         [[scenes]]\nid = \"original\"\nname = \"As found\"\nkind = \"original\"\nframes = [{fo}]\n\
         [[scenes]]\nid = \"restored\"\nname = \"Restored\"\nkind = \"restoration\"\nframes = [{fr}]\n",
        cert = compensate::io::CERTIFICATE_FILE,
        room = restored.stats.room_lux,
        fo = frames_toml("original"),
        fr = frames_toml("restored"),
    );
    let desc_path = author.join("bundle.toml");
    std::fs::write(&desc_path, desc_text).unwrap();
    let desc = BundleDescription::load(&desc_path).unwrap();
    let key = signing_key_from_seed(ChaCha8Rng::seed_from_u64(9).r#gen());
    std::fs::write(dir.path().join("trust/author.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
    let created = (unix_us() / 1_000_000) as i64 - 60;
    let writer = build_writer(&desc_path, &desc, created, "authored_bundle_playback test").unwrap();
    let manifest =
        writer.write(&key, std::fs::File::create(dir.path().join("state/active.bundle")).unwrap()).unwrap();
    let light = manifest.light;
    let cert = LightCertificate::from_bytes(&std::fs::read(&desc.certificate).unwrap()).unwrap();

    // Play: idle shows the original scene; a press shows the restoration until the timer
    // ends it with a cross-fade back to idle.
    let stage = Stage { dir, spec, light, cert };
    let sock = stage.path("control.sock");
    let config = stage.config(
        "fade_ms = 300\nfade_fps = 10\nmax_showing_ms = 800",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let mut child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    let pressed_us = unix_us();
    let answer = ask(&sock, "press", Duration::from_secs(5)).unwrap();
    wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "showing");
    wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "idle");
    child.kill().unwrap();
    child.wait().unwrap();
    let stderr = std::fs::read_to_string(stage.path("stderr.log")).unwrap_or_default();

    // Read what was shown.
    let recs = stage.records();
    let lit: Vec<_> = recs.iter().filter(|r| !r.frames.is_empty()).collect();
    let idle_set = &lit.first().unwrap_or_else(|| panic!("nothing shown; press: {answer}; {stderr}")).frames;
    let shown_set = &lit
        .iter()
        .find(|r| r.unix_us >= pressed_us && r.frames != *idle_set)
        .unwrap_or_else(|| panic!("no new frames after the press ({answer}); {stderr}"))
        .frames;
    let load = |set: &[String]| -> Vec<RgbImage> {
        set.iter().map(|f| rgb_from_recording(&stage.path("rec/frames").join(f), pw, ph)).collect()
    };
    let (idle_frames, shown_frames) = (load(idle_set), load(shown_set));
    // The appliance played the authored frames bit for bit.
    assert!(idle_frames == original.frames, "idle frames differ from the authored original scene");
    assert!(shown_frames == restored.frames, "shown frames differ from the authored restoration");

    // What a visitor sees (the camera's place, room light only besides the projectors).
    let view = |frames: &[RgbImage]| vs.render(frames, false).unwrap().data;
    let (de_restored, _, covered) = colour_error(&restored, &view(&shown_frames), &pristine);
    let (de_original, _, _) = colour_error(&original, &view(&idle_frames), &pristine);
    // The deterioration's own distance from the pristine look: the original scene shows it.
    let de_as_found = mean_de(&as_found, &pristine);

    // True light of every frame set the recorder saw (idle, showing, each fade frame).
    let sets: HashSet<&Vec<String>> = lit.iter().map(|r| &r.frames).collect();
    let mut peaks: Vec<f64> = sets.iter().map(|s| true_peak(&vs, &load(s))).collect();
    peaks.sort_by(f64::total_cmp);
    let shown_peak = true_peak(&vs, &shown_frames);
    let mut lux_cache = std::collections::HashMap::new();
    let cert_peak = sets.iter().map(|s| stage.lux_of(s, &mut lux_cache)).fold(0.0, f64::max);
    eprintln!(
        "{covered} covered pixels: CIEDE2000 mean vs restoration target: restoration shown {de_restored:.2}, \
         original scene {de_original:.2} (deterioration itself {de_as_found:.2}); true peak lux: \
         restoration {shown_peak:.2}, all {} recorded sets {:.2}..={:.2}, certificate {cert_peak:.2}, \
         E_bound {E_BOUND}",
        sets.len(),
        peaks[0],
        peaks[peaks.len() - 1]
    );

    assert!(covered > 2000, "only {covered} object pixels compared");
    assert!(sets.len() >= 3, "idle, showing and fade frames expected, saw {} sets", sets.len());
    // The original scene shows the deterioration (plus compensation's own error); showing the
    // restoration must take away at least half of the deterioration's size as seen.
    assert!(
        de_original - de_restored > 0.5 * de_as_found,
        "restoration {de_restored} dE00 vs original scene {de_original} dE00: not closer by half the \
         deterioration ({de_as_found} dE00)"
    );
    // Light: under the bound (truth and the appliance's certificate), and the bound is used.
    assert!(peaks[peaks.len() - 1] <= E_BOUND, "true peak {} lx > E_bound", peaks[peaks.len() - 1]);
    assert!(cert_peak <= E_BOUND * (1.0 - MARGIN), "certificate peak {cert_peak} lx over the limit");
    assert!(shown_peak > 0.5 * E_BOUND, "restoration peak {shown_peak} lx: the bound is barely used");
}
