//! `restage-appliance verify`: the player's own verification of a bundle file (signature,
//! the demo key refused unless allowed, validity, every section, every scene's light check),
//! as a report. In the library so the end-to-end tests' stand-in binary runs exactly what the
//! appliance's `verify` runs.

use std::path::Path;

use restage_shared::bundle::{Limits, VerifyOptions, describe};
use restage_shared::keys::is_demo_key;
use restage_shared::light::StageLimits;

use crate::loader::{LoadError, open_trusted};

/// Verifies `bundle` against the trust directory at `now_unix_s` under `stage`, refusing the
/// public demo key unless `allow_demo_key` (as the loader does with the configuration's
/// `allow_demo_key`), and returns the summary `verify` prints (ending in an `OK:` line).
pub fn verify_report(
    bundle: &Path,
    trust: &Path,
    now_unix_s: i64,
    stage: StageLimits,
    allow_demo_key: bool,
) -> Result<String, LoadError> {
    let opts =
        VerifyOptions { limits: Limits { stage, ..Limits::default() }, ..VerifyOptions::at(now_unix_s) };
    let v = open_trusted(bundle, trust, &opts, allow_demo_key)?
        .verify(|_| Ok(()))
        .map_err(|source| LoadError::Refused { path: bundle.into(), source })?;
    let mut out = describe(&v.manifest, Some(&v.peaks));
    let demo =
        if is_demo_key(&v.key_id) { " (the public DEMO KEY, allowed by --allow-demo-key)" } else { "" };
    out.push_str(&format!("OK: signature verified with key {}{demo}\n", v.key_id));
    Ok(out)
}
