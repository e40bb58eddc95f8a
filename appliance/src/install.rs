//! Putting a verified bundle in place of the active one (`restage-appliance install`, the
//! bundle inbox): verified, copied beside the active one in pieces flushed to the disk as they
//! go, the copy verified again, then renamed over it. A crash leaves the old bundle or the new
//! one, and the running appliance's ledger commits never wait behind the copy's write-back.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use restage_shared::text::printable;
use thiserror::Error;

use crate::ledger::Ledger;
use crate::loader::{self, LoadError, LoadOptions};

#[derive(Debug, Error)]
pub enum InstallError {
    /// The bundle itself was refused (the message names it and why).
    #[error(transparent)]
    Refused(Box<LoadError>),
    #[error("installing {src} as {target}: {source}")]
    Copy { src: PathBuf, target: PathBuf, source: std::io::Error },
    /// The copy did not verify though the original did: it changed while being copied.
    #[error("the copy of {src} does not verify (did it change while being copied?): {source}")]
    Changed { src: PathBuf, source: Box<LoadError> },
}

/// Verifies `src` as the appliance loads a bundle (signature, validity, version, object,
/// every scene's light check) and puts it in place of `target`; the copy is verified again
/// before it replaces anything. Returns what was installed, for people: object, version,
/// scenes and the manifest hash's start.
pub fn install_verified(
    src: &Path,
    target: &Path,
    trust_dir: &Path,
    ledger: &Ledger,
    now_unix_ms: i64,
    opts: &LoadOptions,
) -> Result<String, InstallError> {
    let refused = |e| InstallError::Refused(Box::new(e));
    let (verified, hash) =
        loader::open_verified(src, trust_dir, ledger, now_unix_ms, opts).map_err(refused)?;
    let m = &verified.manifest;
    loader::check_object(src, ledger, opts.object_id.as_deref(), &m.object.id).map_err(refused)?;
    let what = format!(
        "{} version {} ({} scenes), manifest {}",
        printable(&m.object.id),
        m.version,
        m.scenes.len(),
        &hash[..16]
    );
    drop(verified);
    let mut changed = None;
    let check = |copy: &Path| match loader::open_verified(copy, trust_dir, ledger, now_unix_ms, opts) {
        Ok((_, h)) if h == hash => true,
        Ok(_) => false,
        Err(e) => {
            changed = Some(e);
            false
        }
    };
    match put_in_place(src, target, check) {
        Ok(true) => Ok(what),
        Ok(false) => Err(InstallError::Changed {
            src: src.into(),
            source: Box::new(changed.unwrap_or_else(|| LoadError::Unplayable {
                path: src.into(),
                problem: "its copy has another manifest".into(),
            })),
        }),
        Err(source) => Err(InstallError::Copy { src: src.into(), target: target.into(), source }),
    }
}

/// Bytes copied between flushes. Every change of light waits for its ledger reservation to
/// reach the disk, and an fsync waits behind what the filesystem holds dirty: a 600 MB bundle
/// copied in one piece held a 400 ms showing for 448-753 ms (in these pieces 400-407 ms).
pub const FLUSH_BYTES: u64 = 8 << 20;

/// Copies `src` beside `target` (a hidden `.install-PID.tmp`), flushing every
/// [`FLUSH_BYTES`]; if `check` accepts the copy, renames it over `target` and flushes the
/// directory. Returns `check`'s verdict. On an error or a refusal the temporary file is
/// removed and `target` is untouched.
pub fn put_in_place(src: &Path, target: &Path, check: impl FnOnce(&Path) -> bool) -> std::io::Result<bool> {
    let dir = target.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp = dir.join(format!(".install-{}.tmp", std::process::id()));
    let copy = || -> std::io::Result<bool> {
        let mut from = File::open(src)?;
        let mut to = File::create(&tmp)?;
        let mut piece = Vec::with_capacity(FLUSH_BYTES as usize);
        loop {
            piece.clear();
            if (&mut from).take(FLUSH_BYTES).read_to_end(&mut piece)? == 0 {
                break;
            }
            to.write_all(&piece)?;
            to.sync_data()?;
        }
        to.sync_all()?;
        if !check(&tmp) {
            return Ok(false);
        }
        std::fs::rename(&tmp, target)?;
        File::open(dir)?.sync_all()?;
        Ok(true)
    };
    let result = copy();
    if !matches!(result, Ok(true)) {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leftovers(dir: &Path) -> Vec<String> {
        std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(".install-"))
            .collect()
    }

    #[test]
    fn a_copy_across_pieces_replaces_the_target_whole() {
        let dir = tempfile::tempdir().unwrap();
        let (src, target) = (dir.path().join("new.bundle"), dir.path().join("active.bundle"));
        let data: Vec<u8> = (0..2 * FLUSH_BYTES + 123).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&src, &data).unwrap();
        std::fs::write(&target, b"old").unwrap();
        // A refused copy leaves the old bundle.
        assert!(!put_in_place(&src, &target, |_| false).unwrap());
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert!(leftovers(dir.path()).is_empty());
        // The check sees the whole copy.
        assert!(put_in_place(&src, &target, |copy| std::fs::read(copy).unwrap() == data).unwrap());
        assert!(std::fs::read(&target).unwrap() == data);
        assert!(leftovers(dir.path()).is_empty());
    }

    #[test]
    fn a_failed_copy_leaves_the_old_bundle_and_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("active.bundle");
        std::fs::write(&target, b"old").unwrap();
        let err = put_in_place(&dir.path().join("missing.bundle"), &target, |_| true).unwrap_err();
        assert_eq!(err.kind(), std::io::ErrorKind::NotFound);
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert!(leftovers(dir.path()).is_empty());
    }
}
