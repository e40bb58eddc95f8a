//! `restage-author keygen --out NAME`: a new Ed25519 signing key, `NAME.pem` (PKCS#8,
//! mode 0600) and `NAME.pub.pem` (SPKI, for the appliance's trust directory).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rand::RngCore;
use restage_shared::keys::{KeyId, signing_key_from_seed, write_keypair};

#[derive(Debug, clap::Args)]
pub struct KeygenArgs {
    /// Path and name of the key without extension (e.g. keys/museum-2026): writes NAME.pem
    /// and NAME.pub.pem, never over existing files. A folder (existing, or ending in /) gets
    /// FOLDER/restage-key.pem and FOLDER/restage-key.pub.pem.
    #[arg(long)]
    pub out: PathBuf,
}

/// The name keygen gives a key written into a folder.
pub const FOLDER_KEY_NAME: &str = "restage-key";

/// The key files' stem for `--out`: a folder gets [`FOLDER_KEY_NAME`] inside it; a name with
/// a key file's extension is refused, since `NAME.pub` would get the PRIVATE key as
/// `NAME.pub.pem`.
pub fn stem_for(out: &Path) -> Result<PathBuf> {
    let text = out.to_string_lossy();
    if out.is_dir() || text.ends_with('/') || text.ends_with(std::path::MAIN_SEPARATOR) {
        return Ok(out.join(FOLDER_KEY_NAME));
    }
    let name = out.file_name().map(|n| n.to_string_lossy().to_lowercase()).unwrap_or_default();
    if [".pem", ".pub", ".key"].iter().any(|ext| name.ends_with(ext)) {
        anyhow::bail!(
            "--out {}: give the key's name without an extension (e.g. --out keys/museum-2026); \
             keygen writes NAME.pem (the private key) and NAME.pub.pem (the public key)",
            out.display()
        );
    }
    Ok(out.to_path_buf())
}

/// A new random key pair at `stem`.pem / `stem`.pub.pem: (key id, private, public).
pub fn generate(stem: &std::path::Path) -> Result<(KeyId, PathBuf, PathBuf)> {
    let mut seed = [0u8; 32];
    rand::rngs::OsRng.fill_bytes(&mut seed);
    let key = signing_key_from_seed(seed);
    seed.fill(0);
    let (private, public) = write_keypair(&key, stem).context("writing the key pair")?;
    Ok((KeyId::of(&key.verifying_key()), private, public))
}
