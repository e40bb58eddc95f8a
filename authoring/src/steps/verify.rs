//! `restage-author verify BUNDLE --trust DIR`: the appliance's own verification (signature,
//! validity, version, every section hash, every scene's light check: lit pixels vouched for
//! by the certificate, peak within the bound), run on the workstation.

use std::path::PathBuf;

use anyhow::Result;
use restage_shared::bundle::{Limits, VerifyOptions, verify_file};
use restage_shared::light::{DEFAULT_MAX_THROW_M, DEFAULT_MIN_COS, StageLimits};

#[derive(Debug, clap::Args)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct VerifyArgs {
    pub bundle: PathBuf,
    /// Directory of trusted public keys (*.pem, SPKI).
    #[arg(long)]
    pub trust: PathBuf,
    /// Check validity at this Unix time instead of now.
    #[arg(long)]
    pub now: Option<i64>,
    /// Refuse versions below this one (as an appliance that accepted it would).
    #[arg(long)]
    pub accepted_version: Option<u64>,
    /// The stage's farthest projector throw in metres (the appliance's `[light_check]`).
    #[arg(long, default_value_t = DEFAULT_MAX_THROW_M)]
    pub max_throw_m: f64,
    /// The appliance's `[light_check] min_cos`.
    #[arg(long, default_value_t = DEFAULT_MIN_COS)]
    pub min_cos: f64,
}

/// Verifies and returns the lines `verify` prints.
pub fn report(args: &VerifyArgs) -> Result<String> {
    use std::fmt::Write as _;
    let now = match args.now {
        Some(t) => t,
        None => super::now_unix_s()?,
    };
    let accepted = args.accepted_version;
    let last = move |_: &str| accepted;
    let stage = StageLimits { max_throw_m: args.max_throw_m, min_cos: args.min_cos };
    let opts = VerifyOptions {
        now_unix_s: now,
        last_accepted: &last,
        limits: Limits { stage, ..Limits::default() },
    };
    let v = verify_file(&args.bundle, &args.trust, &opts)?;
    let m = &v.manifest;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "OK {}: object {} version {}, {} scenes on {} projectors, signed by key {}",
        args.bundle.display(),
        m.object.id,
        m.version,
        m.scenes.len(),
        m.projectors.len(),
        v.key_id
    );
    for (s, p) in m.scenes.iter().zip(&v.peaks) {
        let _ =
            writeln!(out, "  {:<16} peak {:.2} lx (allowed {:.2} lx)", s.id, p.lux, m.light.allowed_lux());
    }
    Ok(out)
}
