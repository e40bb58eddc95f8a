//! Compensation speed: 3 frames of 1400x1050 from a 1600x1200 target (the brief's target:
//! under 0.5 s on the CPU path on the 2-core authoring machine), and the once-per-stage
//! preparation (geometry, inverse responses, light certificate) measured separately.

use criterion::{Criterion, criterion_group, criterion_main};
use restage_authoring::compensate::synthetic::{SyntheticSpec, build};
use restage_authoring::compensate::{Exponent, Params, Prepared, compensate_prepared};
use restage_authoring::imgio::LinearImage;

fn bench(c: &mut Criterion) {
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
    let params = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
    let prep = Prepared::new(&s.model, params.reduction).unwrap();
    let mut g = c.benchmark_group("compensate");
    g.sample_size(10);
    g.bench_function("3 x 1400x1050 frames from 1600x1200", |b| {
        b.iter(|| compensate_prepared(&s.model, &prep, &target, &params).unwrap())
    });
    g.bench_function("prepare stage (geometry, certificate)", |b| {
        b.iter(|| Prepared::new(&s.model, params.reduction).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
