//! Restoration speed: a synthetic damaged pattern restored with default parameters and the
//! CLI's automatic grid, at 1 MP and 4 MP (target: 4 MP in under 2 s on 2 cores).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use restage_authoring::restore::synthetic::damaged_pattern;
use restage_authoring::restore::{ClassInfo, RestoreParams, restore};

fn bench(c: &mut Criterion) {
    let classes = ClassInfo { luminance: vec![0.35, 0.03, 0.1] };
    let mut group = c.benchmark_group("restore");
    group.sample_size(10);
    for side in [1024u32, 2048] {
        let scene = damaged_pattern(side, side, 48.0, 1);
        let grid = (side.div_ceil(256), side.div_ceil(256));
        let params = RestoreParams { grid, ..RestoreParams::default() };
        group.throughput(Throughput::Elements(side as u64 * side as u64));
        group.bench_function(format!("{side}x{side}"), |b| {
            b.iter(|| restore(&scene.damaged, &classes, &[], None, &params).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
