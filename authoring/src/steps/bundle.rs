//! `restage-author bundle DESCRIPTION.toml --key KEY.pem --out BUNDLE`: signs compensation's
//! frames and light certificate into a bundle (the description format is in
//! `authoring::export`). Every scene is checked against the bound before anything is written.

use std::path::PathBuf;

use anyhow::{Context, Result};
use restage_authoring::export::{BundleDescription, build_writer};
use restage_shared::keys::load_private_key;

#[derive(Debug, clap::Args)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct BundleArgs {
    /// The bundle description (TOML).
    pub description: PathBuf,
    /// The signing key (PKCS#8 PEM, e.g. from `restage-author keygen` or `openssl genpkey`).
    #[arg(long)]
    pub key: PathBuf,
    /// Where to write the bundle (written beside it, then renamed into place).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// zstd level per section (0 stores frames uncompressed).
    #[arg(long, default_value_t = 3)]
    pub zstd: i32,
    /// Creation time, Unix seconds (default: now); expiry counts from it.
    #[arg(long)]
    pub created: Option<i64>,
}

/// Signs and writes the bundle `args` describe; returns its manifest.
pub fn write(args: &BundleArgs) -> Result<restage_shared::bundle::Manifest> {
    super::check_out(&args.out, args.overwrite.force)?;
    let created = match args.created {
        Some(t) => t,
        None => super::now_unix_s()?,
    };
    let key = load_private_key(&args.key)?;
    let desc = BundleDescription::load(&args.description)?;
    let generator = format!("restage-author {}", env!("CARGO_PKG_VERSION"));
    let mut writer = build_writer(&args.description, &desc, created, &generator)?;
    if args.zstd > 0 {
        writer = writer.zstd(args.zstd);
    }
    let tmp = args.out.with_extension("partial");
    let written = (|| -> Result<_> {
        let file = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let mut out = std::io::BufWriter::new(file);
        let manifest =
            writer.write(&key, &mut out).with_context(|| format!("writing {}", args.out.display()))?;
        let file = out.into_inner().map_err(|e| e.into_error()).context("flushing the bundle")?;
        file.sync_all().context("syncing the bundle")?;
        Ok(manifest)
    })();
    let manifest = match written {
        Ok(m) => m,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    std::fs::rename(&tmp, &args.out).with_context(|| format!("renaming into {}", args.out.display()))?;
    Ok(manifest)
}
