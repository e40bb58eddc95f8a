//! Compensation speed: 3 frames of 1400x1050 from a 1600x1200 target (the brief's target:
//! under 0.5 s on the CPU path on the 2-core authoring machine), and the once-per-stage
//! preparation (geometry, inverse responses, light certificate) measured separately; the
//! per-pixel part alone on the CPU and, where an adapter exists, on the GPU; and the whole
//! with the footprint-aware refinement on a stage with measured footprints.

use criterion::{Criterion, criterion_group, criterion_main};
use restage_authoring::compensate::synthetic::{SyntheticSpec, build};
use restage_authoring::compensate::{
    AutoClip, Exponent, Params, Prepared, compensate_on, compensate_prepared, draft_cpu,
};
use restage_authoring::gpu::{self, Device};
use restage_authoring::imgio::LinearImage;

fn bench(c: &mut Criterion) {
    // `RUST_LOG=restage_authoring=debug` shows compensation's own step timings.
    if std::env::var_os("RUST_LOG").is_some() {
        tracing_subscriber::fmt()
            .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
            .with_writer(std::io::stderr)
            .init();
    }
    let spec = SyntheticSpec {
        camera: (1600, 1200),
        projector: (1400, 1050),
        with_transport: false,
        ..SyntheticSpec::small(3, 7)
    };
    let s = build(&spec);
    let mut target = LinearImage::new(1600, 1200).unwrap();
    for (v, a) in target.data.iter_mut().zip(&s.albedo) {
        *v = if a[0].is_finite() { a.map(|c| 0.8 * c) } else { [0.0; 3] };
    }
    // One clip fraction unless a row says otherwise, so that the rows time the same work.
    let params =
        Params { auto_clip: AutoClip::Off, ..Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap() };
    let prep = Prepared::new(&s.model, params.reduction).unwrap();
    let mut g = c.benchmark_group("compensate");
    g.sample_size(10);
    g.bench_function("3 x 1400x1050 frames from 1600x1200", |b| {
        b.iter(|| compensate_prepared(&s.model, &prep, &target, &params).unwrap())
    });
    // With the model choosing the clip fraction: the formula's frames at each candidate
    // fraction (`AUTO_CLIP`, then halfway to the best's neighbours) judged by their modelled
    // view, the chosen one finished.
    let auto = Params { auto_clip: AutoClip::Always, ..params.clone() };
    g.bench_function("3 x 1400x1050 frames from 1600x1200, auto clip", |b| {
        b.iter(|| compensate_prepared(&s.model, &prep, &target, &auto).unwrap())
    });
    g.bench_function("per-pixel part only (CPU draft, before the guarantee)", |b| {
        b.iter(|| draft_cpu(&s.model, &prep, &target, &params).unwrap())
    });
    // The GPU path where an adapter exists (lavapipe on CPU-only machines): the per-pixel part
    // alone and the whole compensation (the guarantee stays on the CPU).
    match gpu::shared() {
        Ok(dev) => {
            eprintln!("GPU adapter: {} ({:?})", dev.info.name, dev.info.device_type);
            // How far the paths are apart at this size (the tests hold them within one level).
            let c = draft_cpu(&s.model, &prep, &target, &params).unwrap();
            let d =
                restage_authoring::compensate::gpu::draft(dev, &s.model, &prep, &target, &params).unwrap();
            let (mut worst, mut differ, mut total) = (0u8, 0usize, 0usize);
            for (a, b) in c.frames.iter().zip(&d.frames) {
                for (x, y) in a.as_raw().iter().zip(b.as_raw()) {
                    worst = worst.max(x.abs_diff(*y));
                    differ += (x != y) as usize;
                    total += 1;
                }
            }
            eprintln!(
                "GPU vs CPU frames: max difference {worst} level(s), {differ} of {total} values differ"
            );
            g.bench_function("per-pixel part only (GPU draft)", |b| {
                b.iter(|| {
                    restage_authoring::compensate::gpu::draft(dev, &s.model, &prep, &target, &params).unwrap()
                })
            });
            g.bench_function("3 x 1400x1050 frames, GPU path", |b| {
                b.iter(|| compensate_on(&s.model, &prep, &target, &params, Device::Gpu).unwrap())
            });
        }
        Err(e) => eprintln!("no GPU adapter ({e}): GPU benches skipped"),
    }
    g.bench_function("prepare stage (geometry, certificate)", |b| {
        b.iter(|| Prepared::new(&s.model, params.reduction).unwrap())
    });
    // The same stage with measured footprints (blur of radius 1.5 projector pixels): the
    // formula's frames refined in `footprint_rounds` rounds (the default, or
    // `RESTAGE_BENCH_ROUNDS` to time another count).
    let mut with_footprints = s.model.clone();
    with_footprints.transport =
        build(&SyntheticSpec { with_transport: true, ..spec.clone() }).model.transport;
    let prep = Prepared::new(&with_footprints, params.reduction).unwrap();
    let rounds =
        std::env::var("RESTAGE_BENCH_ROUNDS").ok().map(|v| v.parse().expect("RESTAGE_BENCH_ROUNDS: a count"));
    let params = Params { footprint_rounds: rounds.unwrap_or(params.footprint_rounds), ..params };
    let auto = Params { footprint_rounds: params.footprint_rounds, ..auto };
    g.bench_function(
        format!("3 x 1400x1050 frames from 1600x1200, {} footprint rounds", params.footprint_rounds),
        |b| b.iter(|| compensate_prepared(&with_footprints, &prep, &target, &params).unwrap()),
    );
    // The model choosing as well: the candidates judged on the formula, only the chosen one
    // refined.
    g.bench_function(
        format!(
            "3 x 1400x1050 frames from 1600x1200, {} footprint rounds, auto clip",
            params.footprint_rounds
        ),
        |b| b.iter(|| compensate_prepared(&with_footprints, &prep, &target, &auto).unwrap()),
    );
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
