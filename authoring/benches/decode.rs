//! Decoding speed: Gray code + 8-step phase shift on both axes, per camera pixel, for a few
//! camera sizes (projector 1400x1050, the brief's).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use restage_authoring::calibrate::decode::{self, DecodeParams, MemoryImages};
use restage_authoring::capture_set::Pattern;

/// Camera pixel (u, v) sees projector pixel (1.3 u + 5, 1.3 v + 7) through a gamma 2.2 response.
fn capture(width: u32, height: u32) -> MemoryImages {
    let (pw, ph) = (1400, 1050);
    let images = decode::standard_patterns(pw, ph, 16, 8)
        .into_iter()
        .map(|p| {
            let img = (0..height)
                .flat_map(|v| (0..width).map(move |u| (u, v)))
                .map(|(u, v)| {
                    let (x, y) = ((1.3 * u as f32 + 5.0) as u32, (1.3 * v as f32 + 7.0) as u32);
                    let level = if x < pw && y < ph { decode::pattern_value(&p, x, y, pw, ph) } else { 0 };
                    0.02 + 0.6 * (level as f32 / 255.0).powf(2.2)
                })
                .collect();
            (p, img)
        })
        .collect::<Vec<(Pattern, Vec<f32>)>>();
    MemoryImages { width, height, images }
}

fn bench_decode(c: &mut Criterion) {
    let mut group = c.benchmark_group("decode_projector");
    group.sample_size(10);
    for (w, h) in [(320, 240), (1024, 768)] {
        let images = capture(w, h);
        group.throughput(Throughput::Elements(w as u64 * h as u64));
        group.bench_with_input(BenchmarkId::from_parameter(format!("{w}x{h}")), &images, |b, images| {
            b.iter(|| decode::decode_projector(images, 0, 1400, 1050, &DecodeParams::default()).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench_decode);
criterion_main!(benches);
