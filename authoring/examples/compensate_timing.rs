//! Phase timings of one bench-sized compensation (run with RUST_LOG=debug, release).

use restage_authoring::compensate::synthetic::{SyntheticSpec, build};
use restage_authoring::compensate::{Exponent, Params, Prepared, compensate_prepared};
use restage_authoring::imgio::LinearImage;

fn main() {
    tracing_subscriber::fmt().with_env_filter(tracing_subscriber::EnvFilter::from_default_env()).init();
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
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let c = compensate_prepared(&s.model, &prep, &target, &params).unwrap();
        eprintln!(
            "total {:.1} ms, rounds {}, points {}",
            t.elapsed().as_secs_f64() * 1e3,
            c.stats.rounds,
            c.stats.certificate_points
        );
    }
}
