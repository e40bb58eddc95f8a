//! `restage-author inspect BUNDLE [--trust DIR]`: a human summary of a bundle — scenes,
//! projectors, policy, peak lux per scene, section hashes. Without `--trust` the signature
//! is not checked (and the summary says so); hashes and the bound always are.

use std::path::PathBuf;

use anyhow::Result;
use restage_shared::bundle::{VerifyOptions, describe, inspect_file, verify_file};

#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    pub bundle: PathBuf,
    /// Trust directory of public keys; when given, the signature and validity are checked.
    #[arg(long)]
    pub trust: Option<PathBuf>,
    /// With --trust: check validity at this Unix time instead of now.
    #[arg(long)]
    pub now: Option<i64>,
}

pub fn run(args: &InspectArgs) -> Result<()> {
    let v = match &args.trust {
        Some(dir) => verify_file(
            &args.bundle,
            dir,
            &VerifyOptions::at(match args.now {
                Some(t) => t,
                None => crate::steps::now_unix_s()?,
            }),
        )?,
        None => inspect_file(&args.bundle)?,
    };
    print!("{}", describe(&v.manifest, Some(&v.peaks)));
    if v.authenticated {
        println!("signature: verified with key {}", v.key_id);
    } else {
        println!("signature: NOT CHECKED (no --trust); hashes and light bound checked");
    }
    Ok(())
}
