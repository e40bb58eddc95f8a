//! Writes the benchmark bundle — 3 scenes x 3 projectors x 1400x1050, zstd — and a trust
//! directory, for measuring `restage-appliance verify` with `/usr/bin/time -v`:
//!
//! ```sh
//! cargo run --release -p restage-shared --example bench_bundle -- out/bench
//! /usr/bin/time -v target/release/restage-appliance verify out/bench/bench.restage --trust out/bench/trust
//! ```

use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};

/// The benchmark's bundle shape (also used by `benches/verify.rs`).
fn spec() -> ExampleSpec {
    ExampleSpec { projectors: 3, scenes: 3, width: 1400, height: 1050, step: 4, ..ExampleSpec::small() }
}

fn main() -> std::io::Result<()> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "out/bench".into()));
    let uncompressed = std::env::args().any(|a| a == "--uncompressed");
    std::fs::create_dir_all(dir.join("trust"))?;
    let key = signing_key_from_seed([1; 32]);
    std::fs::write(dir.join("trust/bench.pem"), public_key_to_pem(&key.verifying_key()))?;
    let w = example_writer(&spec()).map_err(std::io::Error::other)?;
    let w = if uncompressed { w } else { w.zstd(3) };
    let path = dir.join("bench.restage");
    let m = w.write(&key, std::io::BufWriter::new(std::fs::File::create(&path)?)).expect("bundle writes");
    let largest = m.sections.iter().map(|s| s.stored_len.max(s.raw_len)).max().unwrap_or(0);
    eprintln!(
        "wrote {} ({} bytes; largest section {largest} bytes)",
        path.display(),
        std::fs::metadata(&path)?.len()
    );
    Ok(())
}
