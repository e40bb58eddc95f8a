//! Writes seed inputs for the fuzz targets in `fuzz/`: small valid bundles (plain and zstd,
//! signed with the fuzz harness's trusted test key) for `reader`, and the same split as
//! `u32 manifest length ‖ manifest ‖ payload` for `signed`.
//!
//! ```sh
//! cargo run -p restage-shared --example fuzz_seeds -- fuzz/corpus
//! ```

use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::bundle::{HEADER_LEN, SIGNATURE_BLOCK_LEN};
use restage_shared::keys::signing_key_from_seed;

fn main() -> std::io::Result<()> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "fuzz/corpus".into()));
    std::fs::create_dir_all(dir.join("reader"))?;
    std::fs::create_dir_all(dir.join("signed"))?;
    let key = signing_key_from_seed([42; 32]);
    for (name, zstd) in [("plain", false), ("zstd", true)] {
        let spec = ExampleSpec { width: 12, height: 9, step: 3, ..ExampleSpec::small() };
        let mut w = example_writer(&spec).expect("example bundle");
        w.set_preview("original", b"preview".to_vec()).expect("scene exists");
        let w = if zstd { w.zstd(3) } else { w };
        let mut bytes = Vec::new();
        w.write(&key, &mut bytes).expect("bundle writes");
        std::fs::write(dir.join(format!("reader/small-{name}.restage")), &bytes)?;
        let mlen = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes")) as usize;
        let m_start = HEADER_LEN as usize;
        let p_start = m_start + mlen + SIGNATURE_BLOCK_LEN as usize;
        let mut seed = (mlen as u32).to_le_bytes().to_vec();
        seed.extend_from_slice(&bytes[m_start..m_start + mlen]);
        seed.extend_from_slice(&bytes[p_start..]);
        std::fs::write(dir.join(format!("signed/small-{name}.bin")), seed)?;
    }
    eprintln!("seeds in {}", dir.display());
    Ok(())
}
