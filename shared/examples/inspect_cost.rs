//! What inspecting or verifying a small file that inflates to the reader's limits costs
//! ([`inflating_bundle`]): run each step under `/usr/bin/time -v` for CPU time and peak memory.
//!
//! ```sh
//! cargo build --release -p restage-shared --example inspect_cost
//! B=target/release/examples/inspect_cost
//! $B make /tmp/inflating.restage 10 light /tmp/trust   # 10 scenes: 80 frames, 190 KB
//! $B make /tmp/heavy.restage 10 heavy /tmp/trust      # and a certificate at the work bound
//! /usr/bin/time -v $B inspect /tmp/inflating.restage
//! /usr/bin/time -v $B verify /tmp/inflating.restage /tmp/trust
//! ```

use std::path::Path;
use std::time::Instant;

use restage_shared::bundle::example::inflating_bundle;
use restage_shared::bundle::{VerifyOptions, inspect_file, verify_file};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let start = Instant::now();
    match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        [_, "make", out, scenes, cert, trust] => {
            let key = signing_key_from_seed([5; 32]);
            inflating_bundle(scenes.parse()?, *cert == "heavy", &key, std::fs::File::create(out)?)?;
            std::fs::create_dir_all(trust)?;
            std::fs::write(Path::new(trust).join("k.pem"), public_key_to_pem(&key.verifying_key()))?;
            println!("{out}: {} bytes", std::fs::metadata(out)?.len());
        }
        [_, "inspect", file] => {
            let v = inspect_file(Path::new(file))?;
            println!("inspected {} scenes in {:.2} s", v.manifest.scenes.len(), start.elapsed().as_secs_f64());
        }
        [_, "verify", file, trust] => {
            let v = verify_file(Path::new(file), Path::new(trust), &VerifyOptions::at(1_800_000_000))?;
            println!("verified {} scenes in {:.2} s", v.manifest.scenes.len(), start.elapsed().as_secs_f64());
        }
        _ => return Err("usage: inspect_cost make OUT SCENES light|heavy TRUST_DIR | inspect FILE | verify FILE TRUST_DIR".into()),
    }
    Ok(())
}
