//! What the light check costs at the size of a stage with three 1920x1080 projectors: building
//! the coverage maps (once per certificate), one scene's coverage pass, one scene's per-point
//! sums, and the whole check of a scene. Prints figures; asserts nothing about time. Run:
//! `cargo test --release -p restage-shared --test light_check_cost -- --ignored --nocapture`.

use std::time::Instant;

use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame};
use restage_shared::light::{
    Coverage, LightCheck, StageLimits, XrgbFrame, example_light_model, max_irradiance,
};

/// Median wall time of `n` runs of `f`, in ms.
fn median_ms(n: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..n)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[n / 2]
}

#[test]
#[ignore = "prints timing figures; run in release with --nocapture"]
fn light_check_cost_three_1080p_projectors() {
    // Points every 4 projector pixels, each with a 9x9 block: 130 k points, blocks covering
    // every pixel about 5 times (a real certificate's overlap is a few times).
    let spec = ExampleSpec { projectors: 3, width: 1920, height: 1080, step: 4, ..ExampleSpec::small() };
    let light = example_light_model(3, 50.0);
    let cert = example_certificate(&spec);
    let frames: Vec<Vec<u8>> = (0..3).map(|k| example_frame(&spec, 0, k)).collect();
    let views: Vec<XrgbFrame> =
        frames.iter().map(|f| XrgbFrame { width: spec.width, height: spec.height, xrgb: f }).collect();
    let area: u64 =
        cert.projectors[0].footprints.iter().map(|f| u64::from(f.x1 - f.x0) * u64::from(f.y1 - f.y0)).sum();
    let limits = StageLimits::default();
    let check = LightCheck::new(&light, &cert, &limits).unwrap();
    let peak = check.check_scene("s", &views).unwrap();
    let n = 7;
    let build = median_ms(n, || drop(Coverage::new(&light, &[&cert], &limits).unwrap()));
    let pass = median_ms(n, || {
        for (k, v) in views.iter().enumerate() {
            check.coverage().check_frame("s", k, *v).unwrap();
        }
    });
    let sums = median_ms(n, || {
        max_irradiance(&light, &cert, &views).unwrap();
    });
    let scene = median_ms(n, || {
        check.check_scene("s", &views).unwrap();
    });
    println!(
        "light check, 3 x {}x{}, {} points, blocks {:.1} x the pixels per projector, peak {:.2} lx:\n  \
         coverage maps, once per certificate (validation included): {build:.1} ms\n  \
         coverage pass, one scene: {pass:.1} ms\n  \
         per-point sums, one scene: {sums:.1} ms\n  \
         whole scene check (pass + sums + bound): {scene:.1} ms\n  \
         coverage memory: {:.1} MB",
        spec.width,
        spec.height,
        cert.points,
        area as f64 / f64::from(spec.width * spec.height),
        peak.lux,
        3.0 * f64::from(spec.width * spec.height) / 1e6,
    );
}
