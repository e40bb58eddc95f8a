//! Describing a file nobody vouches for costs one hash pass over it, whatever it holds: a user
//! inspected small crafted files that took seconds of CPU and hundreds of MB to describe.
//!
//! Figures (`examples/inspect_cost.rs`, release, `/usr/bin/time -v`, this 2-core machine
//! under other builds; files from [`inflating_bundle`]: 8 projectors of 4096 x 4096, black
//! zstd frames, "heavy" = a certificate whose blocks read 16 pixels per projector pixel):
//!
//! | file | before: `inspect` unpacked and light-checked | after: hashes only |
//! | --- | --- | --- |
//! | heavy, 1 scene, 142 KB | 6.40 s CPU, 262 MB peak RSS | < 0.01 s CPU, 3.0 MB |
//! | heavy, 8 scenes, 261 KB | 37.6 s CPU, 262 MB | < 0.01 s CPU, 2.8 MB |
//! | light, 64 scenes, 1.1 MB (32 GiB unpacked) | 8.6 s CPU, 200 MB | < 0.01 s CPU, 2.8 MB |
//! | heavy, 64 scenes, 1.2 MB | (about 5 min CPU, not run) | < 0.01 s CPU, 2.8 MB |
//!
//! A trusted `verify` of these still does all of it (signature first, then sizes, then
//! hashes, unpacking and the light check): heavy, 1 scene, 4.1 s CPU and 262 MB.

use std::io::{Cursor, Read, Seek, SeekFrom};

use restage_shared::bundle::example::{ExampleSpec, Lie, inflating_bundle, lying_writer};
use restage_shared::bundle::{
    BundleError, BundleReader, LIGHT_NOT_CHECKED, Limits, VerifyOptions, inspect_file, verify_file,
};
use restage_shared::keys::{TrustStore, public_key_to_pem, signing_key_from_seed};

/// Counts the bytes read through it.
struct Counting<R> {
    inner: R,
    read: u64,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read += n as u64;
        Ok(n)
    }
}

impl<R: Seek> Seek for Counting<R> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

/// 64 scenes of 8 frames that unpack to 64 MiB each, in 1.1 MB: inspection reads the file
/// once and unpacks nothing (before, this took 8.6 s of CPU in release and far longer here).
#[test]
fn an_inflating_file_is_inspected_by_one_hash_pass() {
    let key = signing_key_from_seed([5; 32]);
    let mut bytes = Vec::new();
    let written = inflating_bundle(64, false, &key, &mut bytes).unwrap();
    assert!(bytes.len() < 1_200_000, "{}", bytes.len());
    let mut src = Counting { inner: Cursor::new(&bytes), read: 0 };
    let r = BundleReader::open_unauthenticated(&mut src, Limits::default()).unwrap();
    let inspected = r.inspect().unwrap();
    assert_eq!(inspected.manifest, written);
    assert!(!inspected.authenticated);
    assert_eq!(src.read, bytes.len() as u64, "each byte read once (and nothing past the end)");

    let summary = inspected.summary();
    assert!(!summary.light_checked && !summary.authenticated && summary.hashes_checked);
    assert_eq!(summary.light_not_checked.as_deref(), Some(LIGHT_NOT_CHECKED));
    let text = inspected.describe();
    assert!(text.contains("signature NOT CHECKED") && text.contains("bound     NOT CHECKED: "), "{text}");
    assert!(text.contains("peak not computed"), "{text}");
}

/// The light check needs a verified signature: an unauthenticated reader cannot be
/// `verify`-ed, and inspecting a correctly signed over-bound bundle from an unknown key
/// describes it without judging its light (the summary says it was not checked).
#[test]
fn the_light_check_runs_only_after_the_signature() {
    let key = signing_key_from_seed([6; 32]);
    let mut bytes = Vec::new();
    lying_writer(&ExampleSpec::small(), Lie::ZeroCoefficients).unwrap().write(&key, &mut bytes).unwrap();
    let e = BundleReader::open_unauthenticated(Cursor::new(&bytes), Limits::default())
        .unwrap()
        .verify(|_| Ok(()))
        .unwrap_err();
    assert!(matches!(e, BundleError::Unauthenticated), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lying.restage");
    std::fs::write(&path, &bytes).unwrap();
    let inspected = inspect_file(&path).unwrap();
    assert!(!inspected.summary().light_checked);
    // With the key trusted, the same file gets the whole check, and is refused.
    let trust = dir.path().join("trust");
    std::fs::create_dir(&trust).unwrap();
    std::fs::write(trust.join("k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
    let e = verify_file(&path, &trust, &VerifyOptions::at(1_800_000_000)).unwrap_err().to_string();
    assert!(e.contains("L_ik = 0"), "{e}");
}

/// Inspection still checks every section's hash, and names the section in plain words.
#[test]
fn inspection_checks_hashes() {
    let key = signing_key_from_seed([7; 32]);
    let mut bytes = Vec::new();
    let m = inflating_bundle(2, false, &key, &mut bytes).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    let e = BundleReader::open_unauthenticated(Cursor::new(&bytes), Limits::default())
        .unwrap()
        .inspect()
        .unwrap_err();
    let i = m.sections.len() - 1;
    assert!(matches!(e, BundleError::SectionHash { index, .. } if index == i), "{e}");
    assert_eq!(
        e.to_string(),
        "section 16 (frame of scene 1 's1', projector 7 'p7'): BLAKE3 hash does not match the manifest"
    );
    // A trusted reader can be inspected too (cheap; `verify` is the full check).
    let mut trust = TrustStore::new();
    trust.insert(key.verifying_key(), "k");
    bytes[last] ^= 1;
    let r = BundleReader::open(Cursor::new(&bytes), &trust, &VerifyOptions::at(0)).unwrap();
    assert!(r.inspect().unwrap().authenticated);
}
