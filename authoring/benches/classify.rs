//! Classification speed: a 10 MP photo (3872 x 2592, the paper's Canon XTi) with 5 colours,
//! ours (fit + one calibrated assignment pass, the default; and Lloyd to convergence) and the
//! k-means++ RGB baseline. Target: ours < 1 s.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use restage_authoring::classify::baseline::{BaselineSpace, kmeans_baseline};
use restage_authoring::classify::synthetic::{POTTERY_PAINTS, painted_pattern};
use restage_authoring::classify::{ClassifyOptions, classify, picks_from_labels};

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("classify");
    group.sample_size(10);
    for (w, h) in [(1296u32, 864u32), (3872, 2592)] {
        let scene = painted_pattern(w, h, &POTTERY_PAINTS, 0.04, 1).expect("synthetic scene");
        let names: Vec<String> = (0..5).map(|i| format!("paint {i}")).collect();
        let picks = picks_from_labels(&scene.truth, &names, &[], 8, 1).expect("picks");
        let mp = format!("{:.1}MP", (w * h) as f64 / 1e6);
        group.throughput(Throughput::Elements(u64::from(w * h)));
        group.bench_function(format!("ours/{mp}/5 colours"), |b| {
            b.iter(|| classify(&scene.photo, &picks, None, &ClassifyOptions::default()).expect("classify"))
        });
        group.bench_function(format!("ours, Lloyd to convergence/{mp}/5 colours"), |b| {
            b.iter(|| {
                classify(
                    &scene.photo,
                    &picks,
                    None,
                    &ClassifyOptions { max_iterations: 50, ..Default::default() },
                )
                .expect("classify")
            })
        });
        group.bench_function(format!("kmeans++ rgb/{mp}/5 colours"), |b| {
            b.iter(|| kmeans_baseline(&scene.photo, 5, None, BaselineSpace::Rgb, 1, 50).expect("baseline"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
