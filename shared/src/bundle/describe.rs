//! Verifying a bundle file against a trust directory, and the human summary that
//! `restage-author inspect`/`verify` and `restage-appliance verify` print — one
//! implementation for both binaries.

use std::fmt::Write as _;
use std::fs::File;
use std::path::{Path, PathBuf};

use thiserror::Error;

use super::{
    BundleError, BundleReader, Compression, Limits, Manifest, SectionKind, VerifiedBundle, VerifyOptions,
};
use crate::keys::{KeyError, TrustStore};
use crate::light::{LuxWeighting, PeakIrradiance};
use crate::policy::IdleMode;

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

/// Like [`verify_file`] without a trust store: for describing a bundle only.
pub fn inspect_file(path: &Path) -> Result<VerifiedBundle<File>, BundleFileError> {
    let f = File::open(path).map_err(|error| BundleFileError::Open { path: path.into(), error })?;
    let refused = |problem| BundleFileError::Refused { path: path.into(), problem };
    BundleReader::open_unauthenticated(f, Limits::default())
        .map_err(refused)?
        .verify(|_| Ok(()))
        .map_err(refused)
}

/// `YYYY-MM-DD HH:MM:SS UTC` for Unix seconds (proleptic Gregorian, no time zones).
pub fn utc(unix_s: i64) -> String {
    let days = unix_s.div_euclid(86_400);
    let secs = unix_s.rem_euclid(86_400);
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC", secs / 3600, secs / 60 % 60, secs % 60)
}

/// Lowercase hex of `b`, two digits a byte (hashes in summaries, logs and the ledger).
pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// A multi-line human summary: object, validity, key, projectors, scenes with their peak
/// lux (when given), light model, policy, sections with hashes.
pub fn describe(m: &Manifest, peaks: Option<&[PeakIrradiance]>) -> String {
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(w, "object    {} ({}), bundle version {}", m.object.id, m.object.name, m.version);
    let _ = writeln!(w, "created   {}", utc(m.created_unix_s));
    let _ = writeln!(
        w,
        "valid     from {} until {}",
        m.not_before_unix_s.map_or("creation".into(), utc),
        m.expires_unix_s.map_or("no expiry".into(), utc)
    );
    let _ = writeln!(w, "key id    {}", m.key_id);
    let _ = writeln!(w, "generator {}", m.generator);
    let _ = writeln!(w, "projectors:");
    for (k, p) in m.projectors.iter().enumerate() {
        let _ = writeln!(
            w,
            "  {k}: {:<10} {}x{} @ {:.3} Hz {:?} connector {}  lux_at_1m {:.1}",
            p.name,
            p.width,
            p.height,
            f64::from(p.refresh_mhz) / 1000.0,
            p.format,
            p.connector.as_deref().unwrap_or("(any)"),
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
        let _ = writeln!(w, "  {i}: {:<16} {:<12} {:<24} {peak}", sc.id, format!("{:?}", sc.kind), sc.name);
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
            IdleMode::Scene(id) => format!("scene {id}"),
        }
    );
    let _ = writeln!(w, "sections:");
    for (i, sec) in m.sections.iter().enumerate() {
        let what = match sec.kind {
            SectionKind::Certificate => "light certificate".to_string(),
            SectionKind::Frame { scene, projector } => format!(
                "frame {} / {}",
                m.scenes.get(scene as usize).map_or("?", |s| s.id.as_str()),
                m.projectors.get(projector as usize).map_or("?", |p| p.name.as_str())
            ),
            SectionKind::Preview { scene } => {
                format!("preview {}", m.scenes.get(scene as usize).map_or("?", |s| s.id.as_str()))
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

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(utc(1_767_225_599), "2025-12-31 23:59:59 UTC");
        assert_eq!(utc(-1), "1969-12-31 23:59:59 UTC");
    }
}
