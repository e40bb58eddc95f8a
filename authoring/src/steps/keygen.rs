//! `restage-author keygen --out NAME`: a new Ed25519 signing key, `NAME.pem` (PKCS#8,
//! mode 0600) and `NAME.pub.pem` (SPKI, for the appliance's trust directory).

use std::path::PathBuf;

use anyhow::{Context, Result};
use rand::RngCore;
use restage_shared::keys::{KeyId, signing_key_from_seed, write_keypair};

#[derive(Debug, clap::Args)]
pub struct KeygenArgs {
    /// Path and stem of the key files: NAME.pem and NAME.pub.pem (never overwritten).
    #[arg(long)]
    pub out: PathBuf,
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
