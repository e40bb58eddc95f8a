//! `restage-author inspect BUNDLE [--trust DIR] [--json]`: a human (or JSON) summary of a
//! bundle — scenes, projectors, policy, section hashes. Without `--trust` the file is only
//! inspected: hashes checked, nothing unpacked, signature and light bound not checked (and the
//! summary says so); with it, it is verified exactly as `verify` does, peaks included.

use std::path::PathBuf;

use anyhow::Result;
use restage_shared::bundle::{VerifyOptions, describe, inspect_file, verify_file};

#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    pub bundle: PathBuf,
    /// Trust directory of public keys; when given, the signature, validity and the light bound
    /// are checked.
    #[arg(long)]
    pub trust: Option<PathBuf>,
    /// With --trust: check validity at this time instead of now (2027-12-31, 2027-12-31T10:00:00Z
    /// or Unix seconds; UTC).
    #[arg(long, value_parser = crate::steps::verify::parse_time)]
    pub now: Option<i64>,
    /// Print the summary as JSON (versioned: `summary_version`).
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &InspectArgs) -> Result<()> {
    let (text, summary) = match &args.trust {
        Some(dir) => {
            let now = match args.now {
                Some(t) => t,
                None => crate::steps::now_unix_s()?,
            };
            let v = verify_file(&args.bundle, dir, &VerifyOptions::at(now))?;
            let text = format!(
                "{}signature: verified with key {}\n",
                describe(&v.manifest, Some(&v.peaks)),
                v.key_id
            );
            (text, v.summary())
        }
        None => {
            let v = inspect_file(&args.bundle)?;
            (v.describe(), v.summary())
        }
    };
    if args.json {
        println!("{}", summary.to_json()?);
    } else {
        print!("{text}");
    }
    Ok(())
}
