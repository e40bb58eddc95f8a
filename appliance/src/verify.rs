//! `restage-appliance verify`: the player's own verification of a bundle file (signature,
//! validity, every section, every scene's light check), as a report. In the library so the
//! end-to-end tests' stand-in binary runs exactly what the appliance's `verify` runs.

use std::path::Path;

use restage_shared::bundle::{BundleFileError, Limits, VerifyOptions, describe, verify_file};
use restage_shared::light::StageLimits;

/// Verifies `bundle` against the trust directory at `now_unix_s` under `stage`, and returns
/// the summary `verify` prints (ending in an `OK:` line).
pub fn verify_report(
    bundle: &Path,
    trust: &Path,
    now_unix_s: i64,
    stage: StageLimits,
) -> Result<String, BundleFileError> {
    let opts =
        VerifyOptions { limits: Limits { stage, ..Limits::default() }, ..VerifyOptions::at(now_unix_s) };
    let v = verify_file(bundle, trust, &opts)?;
    let mut out = describe(&v.manifest, Some(&v.peaks));
    out.push_str(&format!("OK: signature verified with key {}\n", v.key_id));
    Ok(out)
}
