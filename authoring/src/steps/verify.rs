//! `restage-author verify BUNDLE --trust DIR`: the appliance's own verification (signature,
//! validity, version, every section hash, every scene's light check: lit pixels vouched for
//! by the certificate, peak within the bound), run on the workstation.

use std::path::PathBuf;

use anyhow::Result;
use restage_shared::bundle::{BundleSummary, DEMO_KEY_LINE, Limits, VerifyOptions, verify_file};
use restage_shared::light::{DEFAULT_MAX_THROW_M, DEFAULT_MIN_COS, StageLimits};
use restage_shared::text::printable;
use restage_shared::time::format_utc;

#[derive(Debug, clap::Args)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct VerifyArgs {
    pub bundle: PathBuf,
    /// Directory of trusted public keys (*.pem, SPKI).
    #[arg(long)]
    pub trust: PathBuf,
    /// Check validity at this time instead of now: 2027-12-31, 2027-12-31T10:00:00Z or Unix
    /// seconds (always UTC).
    #[arg(long, value_parser = parse_time)]
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
    /// Print the summary as JSON (versioned: `summary_version`) instead of lines.
    #[arg(long)]
    pub json: bool,
}

impl VerifyArgs {
    /// Verification of `bundle` against `trust` now, with the appliance's default limits (as
    /// the demo and the window run it after signing).
    pub fn now_with_defaults(bundle: PathBuf, trust: PathBuf) -> VerifyArgs {
        VerifyArgs {
            bundle,
            trust,
            now: None,
            accepted_version: None,
            max_throw_m: DEFAULT_MAX_THROW_M,
            min_cos: DEFAULT_MIN_COS,
            json: false,
        }
    }
}

/// A time on the command line (`--now`): a date, a date and time, or Unix seconds, in UTC.
pub fn parse_time(text: &str) -> Result<i64, String> {
    restage_shared::time::parse_instant(text).map_err(|e| e.to_string())
}

/// Verifies and returns the lines `verify` prints.
pub fn report(args: &VerifyArgs) -> Result<String> {
    Ok(verify(args)?.0)
}

/// Verifies as the appliance would; returns the lines `verify` prints and the summary.
pub fn verify(args: &VerifyArgs) -> Result<(String, BundleSummary)> {
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
    let summary = v.summary();
    let m = &v.manifest;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "OK {}: object {} version {}, {} scenes on {} projectors, signed by key {}",
        args.bundle.display(),
        printable(&m.object.id),
        m.version,
        m.scenes.len(),
        m.projectors.len(),
        v.key_id
    );
    if summary.demo_key {
        let _ = writeln!(out, "  {DEMO_KEY_LINE}");
    }
    let _ = writeln!(
        out,
        "  valid at {}{}",
        format_utc(now),
        summary.valid_until_utc.as_ref().map(|t| format!(", until {t}")).unwrap_or_default()
    );
    for (s, p) in m.scenes.iter().zip(&v.peaks) {
        let _ = writeln!(
            out,
            "  {:<16} peak {:.2} lx (allowed {:.2} lx)",
            printable(&s.id),
            p.lux,
            m.light.allowed_lux()
        );
    }
    Ok((out, summary))
}
