//! Putting a verified bundle in place of the active one: copied beside it in pieces flushed
//! to the disk as they go, then renamed over it. A crash leaves the old bundle or the new one,
//! and the running appliance's ledger commits never wait behind the copy's write-back.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

/// Bytes copied between flushes. Every change of light waits for its ledger reservation to
/// reach the disk, and an fsync waits behind what the filesystem holds dirty: a bundle copied
/// in one piece (600 MB) held a showing's light 250-630 ms past its timer.
pub const FLUSH_BYTES: u64 = 8 << 20;

/// Copies `src` beside `target` (a hidden `.install-PID.tmp`), flushing every
/// [`FLUSH_BYTES`], renames it over `target` and flushes the directory. On an error the
/// temporary file is removed and `target` is untouched.
pub fn put_in_place(src: &Path, target: &Path) -> std::io::Result<()> {
    let dir = target.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp = dir.join(format!(".install-{}.tmp", std::process::id()));
    let copy = || -> std::io::Result<()> {
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
        std::fs::rename(&tmp, target)?;
        File::open(dir)?.sync_all()
    };
    let result = copy();
    if result.is_err() {
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
        put_in_place(&src, &target).unwrap();
        assert!(std::fs::read(&target).unwrap() == data);
        assert!(leftovers(dir.path()).is_empty());
    }

    #[test]
    fn a_failed_copy_leaves_the_old_bundle_and_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("active.bundle");
        std::fs::write(&target, b"old").unwrap();
        let err = put_in_place(&dir.path().join("missing.bundle"), &target).unwrap_err();
        assert_eq!(err.kind(), std::io::ErrorKind::NotFound);
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert!(leftovers(dir.path()).is_empty());
    }
}
