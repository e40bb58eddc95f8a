//! Verifying a bundle file against a trust directory, inspecting one nobody vouches for, and
//! the human summary that `restage-author inspect`/`verify` and `restage-appliance verify`
//! print — one implementation for both binaries. Every name from the bundle is printed
//! through [`printable`]: the file's author must not be able to write to the terminal.

use std::fmt::Write as _;
use std::fs::File;
use std::path::{Path, PathBuf};

use thiserror::Error;

use super::{
    BundleError, BundleReader, Compression, InspectedBundle, Limits, Manifest, SectionKind, VerifiedBundle,
    VerifyOptions,
};
use crate::keys::{KeyError, TrustStore, is_demo_key};
use crate::light::{LuxWeighting, PeakIrradiance};
use crate::policy::IdleMode;
use crate::text::printable;
use crate::time::format_utc;

/// Why an inspected bundle's light bound was not checked (its summary says so).
pub const LIGHT_NOT_CHECKED: &str = "the signature was not verified, and the light check (which unpacks every \
     frame) runs only on a bundle signed by a trusted key; give a trust directory to check it";

/// A bundle file refused, naming the file.
#[derive(Debug, Error)]
pub enum BundleFileError {
    #[error("cannot open bundle {path}: {error}")]
    Open { path: PathBuf, error: std::io::Error },
    #[error(transparent)]
    Trust(#[from] KeyError),
    // The cause is in the message, not chained, so it is printed once.
    #[error("bundle {path} refused: {problem}")]
    Refused { path: PathBuf, problem: BundleError },
}

/// Opens `path`, loads the trust directory, and verifies everything (signature, validity at
/// `opts.now_unix_s`, version, every section, every scene's bound). Sections are not kept.
pub fn verify_file(
    path: &Path,
    trust_dir: &Path,
    opts: &VerifyOptions<'_>,
) -> Result<VerifiedBundle<File>, BundleFileError> {
    let trust = TrustStore::load_dir(trust_dir)?;
    let f = File::open(path).map_err(|error| BundleFileError::Open { path: path.into(), error })?;
    let refused = |problem| BundleFileError::Refused { path: path.into(), problem };
    BundleReader::open(f, &trust, opts).map_err(refused)?.verify(|_| Ok(())).map_err(refused)
}

/// Describes a bundle file without a trust store, cheaply whoever made it: header and
/// manifest decoded and validated, every section's hash checked; nothing unpacked, no light
/// check ([`BundleReader::inspect`]). For describing a bundle only: never play it.
pub fn inspect_file(path: &Path) -> Result<InspectedBundle, BundleFileError> {
    let f = File::open(path).map_err(|error| BundleFileError::Open { path: path.into(), error })?;
    let refused = |problem| BundleFileError::Refused { path: path.into(), problem };
    BundleReader::open_unauthenticated(f, Limits::default()).and_then(BundleReader::inspect).map_err(refused)
}

impl InspectedBundle {
    /// [`describe`] without peaks, then what was and was not checked: the signature, the
    /// hashes, the light bound (and why not).
    pub fn describe(&self) -> String {
        let mut s = describe(&self.manifest, None);
        let w = &mut s;
        if self.authenticated {
            let _ = writeln!(w, "signature verified with key {}", self.key_id);
        } else {
            let _ =
                writeln!(w, "signature NOT CHECKED (no trust directory): anyone could have made this file");
        }
        let _ = writeln!(w, "hashes    every section matches the manifest (nothing unpacked)");
        let _ = writeln!(w, "bound     NOT CHECKED: {LIGHT_NOT_CHECKED}");
        s
    }
}

/// Lowercase hex of `b`, two digits a byte (hashes in summaries, logs and the ledger).
pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// The line [`describe`] prints under the key id of a bundle signed with the public demo key.
pub const DEMO_KEY_LINE: &str = "signature DEMO KEY — its private half is public, anyone can sign with it; \
     for trying restage only, never for an object on show";

/// A multi-line human summary: object, validity, key (loudly, when it is the public demo
/// key), projectors, scenes with their peak lux (when given), light model, policy, sections
/// with hashes. Names from the bundle are escaped ([`printable`]).
pub fn describe(m: &Manifest, peaks: Option<&[PeakIrradiance]>) -> String {
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(
        w,
        "object    {} ({}), bundle version {}",
        printable(&m.object.id),
        printable(&m.object.name),
        m.version
    );
    let _ = writeln!(w, "created   {}", format_utc(m.created_unix_s));
    let _ = writeln!(
        w,
        "valid     from {} until {}",
        m.not_before_unix_s.map_or("creation".into(), format_utc),
        m.expires_unix_s.map_or("no expiry".into(), format_utc)
    );
    let _ = writeln!(w, "key id    {}", m.key_id);
    if is_demo_key(&m.key_id) {
        let _ = writeln!(w, "{DEMO_KEY_LINE}");
    }
    let _ = writeln!(w, "generator {}", printable(&m.generator));
    let _ = writeln!(w, "projectors:");
    for (k, p) in m.projectors.iter().enumerate() {
        let _ = writeln!(
            w,
            "  {k}: {:<10} {}x{} @ {:.3} Hz {:?} connector {}  lux_at_1m {:.1}",
            printable(&p.name),
            p.width,
            p.height,
            f64::from(p.refresh_mhz) / 1000.0,
            p.format,
            p.connector.as_deref().map_or("(any)".into(), printable),
            m.light.projectors.get(k).map_or(f64::NAN, |l| l.lux_at_1m)
        );
    }
    let allowed = m.light.allowed_lux();
    let _ = writeln!(
        w,
        "light     E_bound {} lx, margin {:.1} %, allowed {:.2} lx, ambient {} lx, lux from {}",
        m.light.e_bound_lux,
        m.light.safety_margin * 100.0,
        allowed,
        m.light.ambient_lux,
        match m.light.weighting {
            LuxWeighting::MaxChannel => "the brightest channel".to_string(),
            LuxWeighting::Shares(sh) => format!("channel shares {sh:?}"),
        }
    );
    let _ = writeln!(w, "scenes:");
    for (i, sc) in m.scenes.iter().enumerate() {
        let peak = match peaks.and_then(|p| p.get(i)) {
            Some(p) => format!(
                "peak {:.2} lx ({:.0} % of allowed){}",
                p.lux,
                100.0 * p.lux / allowed,
                p.pixel.map_or(String::new(), |[x, y]| format!(" at camera pixel ({x}, {y})"))
            ),
            None => "peak not computed".into(),
        };
        let _ = writeln!(
            w,
            "  {i}: {:<16} {:<12} {:<24} {peak}",
            printable(&sc.id),
            format!("{:?}", sc.kind),
            printable(&sc.name)
        );
    }
    let p = &m.policy;
    let _ = writeln!(
        w,
        "policy    showings up to {} s, cooldown {} s, budgets {} lx·h/day and {} lx·h/year, warn at {}, idle {}",
        p.max_showing_s,
        p.cooldown_s,
        p.daily_budget_lxh,
        p.annual_budget_lxh,
        p.warn_at.iter().map(|x| format!("{:.0} %", x * 100.0)).collect::<Vec<_>>().join(", "),
        match &p.idle {
            IdleMode::ProjectorsOff => "projectors off".to_string(),
            IdleMode::Black => "black (projectors on)".to_string(),
            IdleMode::Scene(id) => format!("scene {}", printable(id)),
        }
    );
    let _ = writeln!(w, "sections:");
    for (i, sec) in m.sections.iter().enumerate() {
        let what = match sec.kind {
            SectionKind::Certificate => "light certificate".to_string(),
            SectionKind::Frame { scene, projector } => format!(
                "frame {} / {}",
                m.scenes.get(scene as usize).map_or("?".into(), |s| printable(&s.id)),
                m.projectors.get(projector as usize).map_or("?".into(), |p| printable(&p.name))
            ),
            SectionKind::Preview { scene } => {
                format!("preview {}", m.scenes.get(scene as usize).map_or("?".into(), |s| printable(&s.id)))
            }
        };
        let comp = match sec.compression {
            Compression::None => String::new(),
            Compression::Zstd => format!(" (zstd from {})", sec.raw_len),
        };
        let _ = writeln!(
            w,
            "  {i:>3}: {what:<32} {:>10} bytes{comp}  blake3 {}",
            sec.stored_len,
            hex(&sec.blake3)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundle::example::{ExampleSpec, example_writer};
    use crate::keys::{demo_signing_key, signing_key_from_seed};

    #[test]
    fn utc_dates() {
        assert_eq!(super::super::utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(super::super::utc(-1), "1969-12-31 23:59:59 UTC");
    }

    fn manifest(key: &ed25519_dalek::SigningKey) -> Manifest {
        example_writer(&ExampleSpec::small()).unwrap().write(key, Vec::new()).unwrap()
    }

    /// A user's report: a crafted object name printed a fake "signature: verified" line over
    /// the real one. Every bundle-supplied string is escaped.
    #[test]
    fn names_from_a_bundle_cannot_write_to_the_terminal() {
        let evil = "\u{1b}[2K\rsignature: verified";
        let mut m = manifest(&signing_key_from_seed([1; 32]));
        m.object.name = evil.into();
        m.generator = format!("gen{evil}");
        m.projectors[0].name = format!("p\u{9b}31m{evil}");
        m.projectors[1].connector = Some(format!("HDMI\u{7}\u{7f}{evil}"));
        m.scenes[0].name = format!("x\u{202e}gpj.exe\u{2066}{evil}");
        // Ids are validated to [A-Za-z0-9._-] on open; describe escapes them anyway.
        m.scenes[1].id = format!("r\n{evil}");
        m.object.id = format!("o\t{evil}");
        let out = describe(&m, None);
        let bad: Vec<char> = out.chars().filter(|&c| c != '\n' && crate::text::is_unsafe(c)).collect();
        assert!(bad.is_empty(), "{bad:?} in\n{out}");
        assert_eq!(
            out.lines().count(),
            describe(&manifest(&signing_key_from_seed([1; 32])), None).lines().count()
        );
        assert!(!out.lines().any(|l| l.starts_with("signature")), "{out}");
        assert!(out.contains("(\\u{1b}[2K\\rsignature: verified)"), "{out}");
        assert!(out.contains("x\\u{202e}gpj.exe\\u{2066}"), "{out}");
        assert!(out.contains("HDMI\\u{7}\\u{7f}"), "{out}");
        assert!(out.contains("p\\u{9b}31m"), "{out}");
    }

    #[test]
    fn the_demo_key_is_said_loudly() {
        let demo = describe(&manifest(&demo_signing_key()), None);
        assert!(
            demo.contains(&format!("key id    {}\n{DEMO_KEY_LINE}\n", crate::keys::DEMO_KEY_ID)),
            "{demo}"
        );
        assert!(DEMO_KEY_LINE.contains("DEMO KEY") && DEMO_KEY_LINE.contains("anyone can sign"));
        let other = describe(&manifest(&signing_key_from_seed([1; 32])), None);
        assert!(!other.contains("DEMO"), "{other}");
    }
}
