//! Verify-and-load speed of a full-size bundle: 3 scenes x 3 projectors x 1400x1050
//! (XRGB8888, 5.9 MB per frame), stored plain and zstd-compressed. Target: < 1 s.

use std::io::Cursor;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::bundle::{BundleReader, VerifyOptions};
use restage_shared::keys::{TrustStore, signing_key_from_seed};

fn bench(c: &mut Criterion) {
    let spec =
        ExampleSpec { projectors: 3, scenes: 3, width: 1400, height: 1050, step: 4, ..ExampleSpec::small() };
    let key = signing_key_from_seed([1; 32]);
    let mut trust = TrustStore::new();
    trust.insert(key.verifying_key(), "bench");
    let mut g = c.benchmark_group("verify_load_3x3x1400x1050");
    g.sample_size(10);
    for (name, zstd) in [("plain", false), ("zstd3", true)] {
        let w = example_writer(&spec).unwrap();
        let w = if zstd { w.zstd(3) } else { w };
        let mut bytes = Vec::new();
        w.write(&key, &mut bytes).unwrap();
        g.throughput(Throughput::Bytes(bytes.len() as u64));
        g.bench_function(name, |b| {
            b.iter(|| {
                let r = BundleReader::open(Cursor::new(&bytes), &trust, &VerifyOptions::at(0)).unwrap();
                let v = r.verify(|_| Ok(())).unwrap();
                assert_eq!(v.peaks.len(), 3);
                v.peaks[0].lux
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
