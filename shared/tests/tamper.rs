//! The tamper matrix: every way a bundle can be damaged or forged is refused with a specific
//! error, and none panics. Plus a proptest of random mutations.

use std::io::Cursor;

use proptest::prelude::*;
use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::bundle::{
    BundleError, BundleReader, HEADER_LEN, Limits, Manifest, SIGNATURE_BLOCK_LEN, VerifiedBundle,
    VerifyOptions,
};
use restage_shared::keys::{KeyId, SigningKey, TrustStore, signing_key_from_seed};
use restage_shared::light::LightError;

const NOW: i64 = 1_750_000_000;

fn key() -> SigningKey {
    signing_key_from_seed([42; 32])
}

fn trust() -> TrustStore {
    let mut t = TrustStore::new();
    t.insert(key().verifying_key(), "trusted.pem");
    // A second trusted key: rotation must not weaken anything.
    t.insert(signing_key_from_seed([43; 32]).verifying_key(), "next.pem");
    t
}

struct Fixture {
    bytes: Vec<u8>,
    manifest: Manifest,
    manifest_len: usize,
}

impl Fixture {
    fn new(spec: &ExampleSpec, zstd: bool) -> Self {
        let mut w = example_writer(spec).unwrap();
        w.set_preview("original", (0..200u8).collect()).unwrap();
        let w = if zstd { w.zstd(3) } else { w };
        let mut bytes = Vec::new();
        let manifest = w.write(&key(), &mut bytes).unwrap();
        let manifest_len = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
        Self { bytes, manifest, manifest_len }
    }

    fn payload_start(&self) -> usize {
        HEADER_LEN as usize + self.manifest_len + SIGNATURE_BLOCK_LEN as usize
    }

    /// (start, end) of each section in the file.
    fn sections(&self) -> Vec<(usize, usize)> {
        let mut at = self.payload_start();
        self.manifest
            .sections
            .iter()
            .map(|s| {
                let r = (at, at + s.stored_len as usize);
                at = r.1;
                r
            })
            .collect()
    }
}

fn load_with(bytes: &[u8], opts: &VerifyOptions<'_>) -> Result<VerifiedBundle<Cursor<Vec<u8>>>, BundleError> {
    BundleReader::open(Cursor::new(bytes.to_vec()), &trust(), opts)?.verify(|_| Ok(()))
}

fn load(bytes: &[u8]) -> Result<VerifiedBundle<Cursor<Vec<u8>>>, BundleError> {
    load_with(bytes, &VerifyOptions::at(NOW))
}

fn flipped(bytes: &[u8], at: usize, mask: u8) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[at] ^= mask;
    b
}

fn fixtures() -> Vec<Fixture> {
    vec![Fixture::new(&ExampleSpec::small(), false), Fixture::new(&ExampleSpec::small(), true)]
}

#[test]
fn the_untouched_bundle_loads() {
    for f in fixtures() {
        let v = load(&f.bytes).unwrap();
        assert_eq!(v.manifest, f.manifest);
    }
}

#[test]
fn every_header_byte_changed_is_refused() {
    for f in fixtures() {
        for at in 0..HEADER_LEN as usize {
            for mask in [0x01, 0x80, 0xff] {
                let e = load(&flipped(&f.bytes, at, mask)).unwrap_err();
                let ok = match at {
                    0..8 => matches!(e, BundleError::BadMagic),
                    8..12 => matches!(e, BundleError::UnsupportedVersion { .. }),
                    12..16 => matches!(e, BundleError::ReservedFlags { .. }),
                    // A different manifest length: over the cap, past the end, or the
                    // signature (which covers the header) fails.
                    16..24 => matches!(
                        e,
                        BundleError::ManifestTooLarge { .. }
                            | BundleError::Truncated { .. }
                            | BundleError::BadSignature { .. }
                            | BundleError::UnknownKey { .. }
                    ),
                    _ => matches!(e, BundleError::SignatureLength { .. }),
                };
                assert!(ok, "header byte {at} ^ {mask:#x}: unexpected {e:?}");
            }
        }
    }
}

#[test]
fn every_manifest_byte_changed_fails_the_signature() {
    for f in fixtures() {
        for at in HEADER_LEN as usize..HEADER_LEN as usize + f.manifest_len {
            let e = load(&flipped(&f.bytes, at, 0x10)).unwrap_err();
            assert!(matches!(e, BundleError::BadSignature { .. }), "manifest byte {at}: {e:?}");
        }
    }
}

#[test]
fn every_signature_block_byte_changed_is_refused() {
    for f in fixtures() {
        let start = HEADER_LEN as usize + f.manifest_len;
        for at in start..start + SIGNATURE_BLOCK_LEN as usize {
            for mask in [0x01, 0x80] {
                let e = load(&flipped(&f.bytes, at, mask)).unwrap_err();
                if at < start + 16 {
                    assert!(matches!(e, BundleError::UnknownKey { .. }), "key id byte {at}: {e:?}");
                } else {
                    assert!(matches!(e, BundleError::BadSignature { .. }), "signature byte {at}: {e:?}");
                }
            }
        }
    }
}

#[test]
fn sampled_payload_bytes_changed_fail_that_sections_hash() {
    for f in fixtures() {
        for (i, (a, b)) in f.sections().into_iter().enumerate() {
            let len = b - a;
            let mut offsets: Vec<usize> = (0..len).step_by((len / 24).max(1)).collect();
            offsets.extend([len - 1, len / 2]);
            for o in offsets {
                let e = load(&flipped(&f.bytes, a + o, 0x04)).unwrap_err();
                assert!(
                    matches!(e, BundleError::SectionHash { index, .. } if index == i),
                    "section {i} byte {o}: {e:?}"
                );
            }
        }
    }
}

#[test]
fn truncation_anywhere_is_refused() {
    for f in fixtures() {
        let p = f.payload_start();
        let mut cuts = vec![0, 1, 8, 31, 32, 33, 32 + f.manifest_len / 2, p - 80, p - 1, p];
        for (a, b) in f.sections() {
            cuts.extend([a, a + 1, (a + b) / 2, b - 1]);
        }
        for cut in cuts {
            if cut >= f.bytes.len() {
                continue;
            }
            let e = load(&f.bytes[..cut]).unwrap_err();
            assert!(matches!(e, BundleError::Truncated { .. }), "cut at {cut}: {e:?}");
        }
    }
}

#[test]
fn appended_bytes_are_refused() {
    for f in fixtures() {
        for extra in [1usize, 7, 4096] {
            let mut b = f.bytes.clone();
            b.extend(std::iter::repeat_n(0u8, extra));
            let e = load(&b).unwrap_err();
            assert!(matches!(e, BundleError::TrailingBytes { extra: x } if x == extra as u64), "{e:?}");
        }
    }
}

#[test]
fn swapped_sections_are_refused() {
    let f = Fixture::new(&ExampleSpec::small(), false);
    let s = f.sections();
    // Scene 0 projector 0 and scene 1 projector 0: same length, different content.
    let (a, b) = (s[1], s[3]);
    let mut bytes = f.bytes.clone();
    let first = bytes[a.0..a.1].to_vec();
    bytes.copy_within(b.0..b.1, a.0);
    bytes[b.0..b.1].copy_from_slice(&first);
    let e = load(&bytes).unwrap_err();
    assert!(matches!(e, BundleError::SectionHash { index: 1, .. }), "{e:?}");
}

#[test]
fn untrusted_and_unknown_keys_are_refused() {
    let stranger = signing_key_from_seed([7; 32]);
    let mut bytes = Vec::new();
    example_writer(&ExampleSpec::small()).unwrap().write(&stranger, &mut bytes).unwrap();
    let e = load(&bytes).unwrap_err();
    assert!(
        matches!(e, BundleError::UnknownKey { key_id } if key_id == KeyId::of(&stranger.verifying_key())),
        "{e:?}"
    );
    // The stranger's signature under a trusted key's id.
    let f = Fixture::new(&ExampleSpec::small(), false);
    let mut forged = bytes.clone();
    let mlen = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let at = HEADER_LEN as usize + mlen;
    forged[at..at + 16].copy_from_slice(&KeyId::of(&key().verifying_key()).0);
    let e = load(&forged).unwrap_err();
    assert!(matches!(e, BundleError::BadSignature { .. }), "{e:?}");
    // An id no one has.
    let mut unknown = f.bytes.clone();
    let at = HEADER_LEN as usize + f.manifest_len;
    unknown[at..at + 16].copy_from_slice(&[0xAB; 16]);
    let e = load(&unknown).unwrap_err();
    assert!(matches!(e, BundleError::UnknownKey { .. }), "{e:?}");
}

#[test]
fn expired_and_not_yet_valid_are_refused_at_the_one_time_given() {
    let spec =
        ExampleSpec { not_before_unix_s: Some(2_000), expires_unix_s: Some(3_000), ..ExampleSpec::small() };
    let f = Fixture::new(&spec, false);
    let at = |t| load_with(&f.bytes, &VerifyOptions::at(t));
    assert!(matches!(at(1_999).unwrap_err(), BundleError::NotYetValid { not_before: 2_000, now: 1_999 }));
    at(2_000).unwrap();
    at(2_999).unwrap();
    assert!(matches!(at(3_000).unwrap_err(), BundleError::Expired { expires: 3_000, now: 3_000 }));
}

#[test]
fn a_lower_version_than_accepted_is_refused() {
    let f = Fixture::new(&ExampleSpec { version: 5, ..ExampleSpec::small() }, false);
    for (accepted, ok) in [(None, true), (Some(4), true), (Some(5), true), (Some(6), false)] {
        let last = move |id: &str| if id == "test-jar-1" { accepted } else { Some(u64::MAX) };
        let o = VerifyOptions { now_unix_s: NOW, last_accepted: &last, limits: Limits::default() };
        match load_with(&f.bytes, &o) {
            Ok(v) => assert!(ok && v.manifest.version == 5),
            Err(e) => assert!(
                !ok && matches!(e, BundleError::Rollback { version: 5, accepted: 6, .. }),
                "accepted {accepted:?}: {e:?}"
            ),
        }
    }
}

#[test]
fn a_huge_manifest_length_is_refused_before_reading() {
    let f = Fixture::new(&ExampleSpec::small(), false);
    for len in [u64::MAX, 1 << 40, (1 << 20) + 1] {
        let mut b = f.bytes.clone();
        b[16..24].copy_from_slice(&len.to_le_bytes());
        let e = load(&b).unwrap_err();
        assert!(matches!(e, BundleError::ManifestTooLarge { len: l, .. } if l == len), "{e:?}");
    }
    // And a tighter cap configured by the caller.
    let o =
        VerifyOptions { limits: Limits { max_manifest: 64, ..Limits::default() }, ..VerifyOptions::at(NOW) };
    assert!(matches!(load_with(&f.bytes, &o).unwrap_err(), BundleError::ManifestTooLarge { .. }));
}

#[test]
fn a_validly_signed_scene_over_the_bound_is_refused() {
    // 2 projectors x 40 lx per unit x 1.01 = 80.8 lx at full white; allowed 47.5 lx.
    let spec = ExampleSpec { lux_per_unit: 40.0, ..ExampleSpec::small() };
    let mut bytes = Vec::new();
    example_writer(&spec).unwrap().skip_bound_check_for_test_fixtures().write(&key(), &mut bytes).unwrap();
    // The signature and hashes are fine: open succeeds, the bound check refuses.
    let r = BundleReader::open(Cursor::new(bytes.clone()), &trust(), &VerifyOptions::at(NOW)).unwrap();
    let e = r.verify(|_| Ok(())).unwrap_err();
    match e {
        BundleError::Light(LightError::OverBound { scene, peak_lux, allowed_lux, .. }) => {
            assert_eq!(scene, "original");
            assert!(peak_lux > allowed_lux && (allowed_lux - 47.5).abs() < 1e-9, "{peak_lux} {allowed_lux}");
        }
        e => panic!("expected OverBound, got {e:?}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Random byte edits, insertions, deletions and truncations: the reader never panics,
    /// and anything it accepts is byte-for-byte the original.
    #[test]
    fn random_mutations_never_pass(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), 0u8..4, any::<u8>()), 1..6),
        zstd in any::<bool>(),
    ) {
        thread_local! {
            static FIX: Vec<Vec<u8>> = fixtures().into_iter().map(|f| f.bytes).collect();
        }
        let original = FIX.with(|f| f[usize::from(zstd)].clone());
        let mut b = original.clone();
        for (at, op, v) in edits {
            if b.is_empty() { break; }
            let i = at.index(b.len());
            match op {
                0 => b[i] ^= v | 1,
                1 => b.insert(i, v),
                2 => { b.remove(i); }
                _ => b.truncate(i),
            }
        }
        let r = load(&b);
        prop_assert!(r.is_err() || b == original, "a mutated bundle was accepted");
    }
}
