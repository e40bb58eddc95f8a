//! `restage-appliance`: the stage machine's program.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "restage-appliance", version, about = "Play a signed restage bundle on the stage")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Verify a bundle (signature, validity, every section, every scene's light bound) with
    /// the same code the player loads bundles with.
    Verify {
        bundle: PathBuf,
        /// Directory of trusted public keys (*.pem, SPKI).
        #[arg(long)]
        trust: PathBuf,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Verify { bundle, trust } => verify(&bundle, &trust),
    }
}

fn verify(bundle: &std::path::Path, trust: &std::path::Path) -> Result<()> {
    use anyhow::Context;
    use restage_shared::bundle::{VerifyOptions, describe, verify_file};
    // The one time of this load, taken before anything is read.
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs() as i64;
    let v = verify_file(bundle, trust, &VerifyOptions::at(now))?;
    print!("{}", describe(&v.manifest, Some(&v.peaks)));
    println!("OK: signature verified with key {}", v.key_id);
    Ok(())
}
