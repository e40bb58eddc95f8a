//! Frozen format fixtures: a version-1 bundle written once (`tests/fixtures/bundle-v1/`)
//! and read back with today's code. A change to the reader or the manifest that can no longer
//! read a bundle already out in the field fails here. Never regenerate the fixture to make
//! these tests pass: a new format version gets a new fixture beside this one
//! (docs/formats.md, "Bumping a version").
//!
//! The fixture was written by the ignored test below, which refuses to overwrite it:
//!
//! ```text
//! RESTAGE_REGENERATE_FIXTURES=1 cargo test -p restage-shared --test format_fixtures -- --ignored regenerate
//! ```

use std::path::{Path, PathBuf};

use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame, example_info};
use restage_shared::bundle::{
    BundleError, BundleFileError, BundleWriter, Compression, PixelFormat, SceneKind, SectionKind,
    VerifyOptions, hex, verify_file,
};
use restage_shared::keys::{KeyId, SigningKey, load_public_key, public_key_to_pem, signing_key_from_seed};

/// The fixture's signing key (its public half is checked in as `trust/fixture.pub.pem`).
const SEED: [u8; 32] = [11; 32];
/// When the fixture was made (2026-12-01 00:00:00 UTC) and when it expires (2100-01-01).
const CREATED: i64 = 1_796_083_200;
const EXPIRES: i64 = 4_102_444_800;
/// The time the tests verify at (2027-01-01 00:00:00 UTC).
const NOW: i64 = 1_798_761_600;
/// A real 2x2 grey PNG: the preview of scene 0.
const PREVIEW_PNG: [u8; 71] = [
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52, 0x00,
    0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x08, 0x00, 0x00, 0x00, 0x00, 0x57, 0xdd, 0x52, 0xf8, 0x00,
    0x00, 0x00, 0x0e, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x68, 0x68, 0x60, 0x68, 0x68, 0x00, 0x00,
    0x06, 0x06, 0x02, 0x01, 0x31, 0xa9, 0x1e, 0xa1, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae,
    0x42, 0x60, 0x82,
];

/// What the fixture holds, as written: checked against the file by the tests.
const FILE_BLAKE3: &str = "fbd04365d7c51fc0f557e63583caa1e2fc3139e6c43cdde9691b9535c3984821";
const MANIFEST_BLAKE3: &str = "14735d01864efe9534a0f78c40a442ae9f1fcf3cee7041a53950237d7e730cbd";
const SECTION_BLAKE3: [&str; 6] = [
    "18cb45bab4a38e9d0d80b6cbf84a6320a9d05c005f2bd65773e9c506d00bf3fa",
    "d5df2f23ca48bbb5cf437bf0af723f215ffc81de4b2d2b998a9df29b4acb9d49",
    "4016c0219b5529b8acbb5d4ad7108efb52de9b395d7060a6672a75becb760a17",
    "3a52aa2c0a9d57e507f56de79fe7e2c65ff85a42ca400f26558a82a0eb9f054a",
    "f47a38e57743a3e297f5f4863f98eb4681a7290a937cbc4f6f0f54524b2e75e1",
    "47a224f1e984158c6e1828e8aa2137696a10ee8fc0453d7be089871830ca4c8d",
];
/// BLAKE3 of each frame's raw (decompressed) bytes, scene-major.
const FRAME_RAW_BLAKE3: [&str; 4] = [
    "7ed8970f0dc52bd668a625a6b23e0d8e04979c82f7607b8fff5cc1278835bda3",
    "6a09e0650d46b9973f01296a7e8e64954e245732931d4a891507f679c34dc1b8",
    "4a35802e6bb2adf28c5748c8e20c07fd2f6eb82578d92f3caf22dade4b182e28",
    "9f342fb5662e2425b523d0fb5b63131b2206cd44bce99de3444d677ff1ae6749",
];
/// Each scene's peak irradiance (lux) the light check recomputes from the certificate. A
/// deliberate change to the light check may move these: update them, never the fixture.
const PEAKS_LUX: [f64; 2] = [22.789085190743208, 25.016539078205824];

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/bundle-v1")
}

fn bundle_path() -> PathBuf {
    dir().join("tiny.restage")
}

fn trust_dir() -> PathBuf {
    dir().join("trust")
}

fn key() -> SigningKey {
    signing_key_from_seed(SEED)
}

fn spec() -> ExampleSpec {
    ExampleSpec {
        projectors: 2,
        scenes: 2,
        width: 8,
        height: 6,
        step: 2,
        version: 1,
        created_unix_s: CREATED,
        expires_unix_s: Some(EXPIRES),
        ..ExampleSpec::small()
    }
}

/// Writes the fixture (only when RESTAGE_REGENERATE_FIXTURES=1 or it does not exist yet) and
/// prints the values the tests expect.
#[test]
#[ignore = "writes the checked-in fixture; see the module docs"]
fn regenerate_bundle_v1_fixture() {
    let path = bundle_path();
    let allowed = std::env::var_os("RESTAGE_REGENERATE_FIXTURES").is_some_and(|v| v == "1");
    assert!(
        allowed || !path.exists(),
        "{} exists: set RESTAGE_REGENERATE_FIXTURES=1 to overwrite it (a frozen fixture is only \
         rewritten on purpose, and the old one is kept under its own name)",
        path.display()
    );
    let spec = spec();
    let mut info = example_info(&spec);
    info.object.id = "fixture-jar".into();
    info.object.name = "Format fixture jar".into();
    info.generator = "restage-shared format_fixtures (frozen)".into();
    let mut w = BundleWriter::new(info, example_certificate(&spec)).zstd(3);
    w.add_scene(
        "original",
        "As found",
        SceneKind::Original,
        vec![example_frame(&spec, 0, 0), example_frame(&spec, 0, 1)],
    )
    .unwrap();
    w.add_scene(
        "restored-1",
        "Restored",
        SceneKind::Restoration,
        vec![example_frame(&spec, 1, 0), example_frame(&spec, 1, 1)],
    )
    .unwrap();
    w.set_preview("original", PREVIEW_PNG.to_vec()).unwrap();
    std::fs::create_dir_all(trust_dir()).unwrap();
    let mut bytes = Vec::new();
    let manifest = w.write(&key(), &mut bytes).unwrap();
    std::fs::write(&path, &bytes).unwrap();
    std::fs::write(trust_dir().join("fixture.pub.pem"), public_key_to_pem(&key().verifying_key())).unwrap();
    let v = verify_file(&path, &trust_dir(), &VerifyOptions::at(NOW)).unwrap();
    println!("{} bytes", bytes.len());
    println!("FILE_BLAKE3 {}", blake3::hash(&bytes).to_hex());
    println!("MANIFEST_BLAKE3 {}", hex(&v.manifest_hash));
    for s in &manifest.sections {
        println!("section {:?} {:?} {} {}", s.kind, s.compression, s.stored_len, hex(&s.blake3));
    }
    for s in 0..2 {
        for k in 0..2 {
            println!("raw frame {s} {k} {}", blake3::hash(&example_frame(&spec, s, k)).to_hex());
        }
    }
    for p in &v.peaks {
        println!("peak {:?}", p.lux);
    }
}

#[test]
fn bundle_v1_fixture_verifies_and_reads_back() {
    let bytes = std::fs::read(bundle_path()).unwrap();
    assert_eq!(blake3::hash(&bytes).to_hex().as_str(), FILE_BLAKE3, "the frozen fixture was changed");
    // The header says format version 1, whatever the current version is.
    assert_eq!(&bytes[..8], b"RSTGBNDL");
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 1);

    let trusted = load_public_key(&trust_dir().join("fixture.pub.pem")).unwrap();
    assert_eq!(trusted, key().verifying_key(), "the checked-in key is the fixture seed's");
    let v = verify_file(&bundle_path(), &trust_dir(), &VerifyOptions::at(NOW)).unwrap();
    assert!(v.summary().authenticated);
    assert_eq!(v.key_id, KeyId::of(&trusted));
    assert_eq!(hex(&v.manifest_hash), MANIFEST_BLAKE3);

    let m = &v.manifest;
    assert_eq!((m.object.id.as_str(), m.object.name.as_str()), ("fixture-jar", "Format fixture jar"));
    assert_eq!((m.version, m.created_unix_s), (1, CREATED));
    assert_eq!((m.not_before_unix_s, m.expires_unix_s), (None, Some(EXPIRES)));
    assert_eq!(m.key_id, v.key_id);
    assert_eq!(m.generator, "restage-shared format_fixtures (frozen)");
    let projectors: Vec<_> =
        m.projectors.iter().map(|p| (p.name.as_str(), p.width, p.height, p.refresh_mhz, p.format)).collect();
    assert_eq!(
        projectors,
        [("p0", 8, 6, 60_000, PixelFormat::Xrgb8888), ("p1", 8, 6, 60_000, PixelFormat::Xrgb8888)]
    );
    let connectors: Vec<_> = m.projectors.iter().map(|p| p.connector.as_deref()).collect();
    assert_eq!(connectors, [Some("HDMI-A-1"), Some("HDMI-A-2")]);
    let scenes: Vec<_> = m
        .scenes
        .iter()
        .map(|s| (s.id.as_str(), s.name.as_str(), s.kind, s.frames.clone(), s.preview))
        .collect();
    assert_eq!(
        scenes,
        [
            ("original", "As found", SceneKind::Original, vec![1, 2], Some(5)),
            ("restored-1", "Restored", SceneKind::Restoration, vec![3, 4], None),
        ]
    );
    let kinds: Vec<_> = m.sections.iter().map(|s| s.kind).collect();
    assert_eq!(
        kinds,
        [
            SectionKind::Certificate,
            SectionKind::Frame { scene: 0, projector: 0 },
            SectionKind::Frame { scene: 0, projector: 1 },
            SectionKind::Frame { scene: 1, projector: 0 },
            SectionKind::Frame { scene: 1, projector: 1 },
            SectionKind::Preview { scene: 0 },
        ]
    );
    let hashes: Vec<String> = m.sections.iter().map(|s| hex(&s.blake3)).collect();
    assert_eq!(hashes, SECTION_BLAKE3);
    assert!(m.sections.iter().any(|s| s.compression == Compression::Zstd), "the fixture covers zstd");
    assert_eq!(m.light.e_bound_lux, 50.0);
    assert_eq!(m.light.projectors.len(), 2);
    assert_eq!(m.policy.max_showing_s, 60);

    // The certificate section and every scene's peak, recomputed by today's light check.
    assert_eq!(v.certificate.points, 12);
    assert_eq!(v.certificate.projectors.len(), 2);
    let peaks: Vec<f64> = v.peaks.iter().map(|p| p.lux).collect();
    for (got, want) in peaks.iter().zip(PEAKS_LUX) {
        assert!((got - want).abs() < 1e-6, "peaks {peaks:?}, recorded {PEAKS_LUX:?}");
    }
    assert_eq!(peaks.len(), 2);

    // Frames (decompressed) and the preview read back, hashed again on each read.
    let mut v = v;
    for (i, want) in FRAME_RAW_BLAKE3.iter().enumerate() {
        let frame = v.read_frame(i / 2, i % 2).unwrap();
        assert_eq!(frame.len(), 8 * 6 * 4);
        assert_eq!(blake3::hash(&frame).to_hex().as_str(), *want, "scene {} projector {}", i / 2, i % 2);
    }
    assert_eq!(v.read_section(5).unwrap(), PREVIEW_PNG);
}

#[test]
fn bundle_v1_fixture_is_refused_when_expired_or_changed() {
    let e = verify_file(&bundle_path(), &trust_dir(), &VerifyOptions::at(EXPIRES)).unwrap_err();
    assert!(matches!(e, BundleFileError::Refused { problem: BundleError::Expired { .. }, .. }), "{e}");

    let bytes = std::fs::read(bundle_path()).unwrap();
    let manifest_len = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let tmp = tempfile::tempdir().unwrap();
    // A byte of the signed manifest, and the last byte of the last section (the preview).
    for (at, refused) in
        [(40, "signature"), (32 + manifest_len + 80 + 20, "section"), (bytes.len() - 1, "section")]
    {
        let mut copy = bytes.clone();
        copy[at] ^= 0x01;
        let path = tmp.path().join(format!("flipped-{at}.restage"));
        std::fs::write(&path, &copy).unwrap();
        let e = verify_file(&path, &trust_dir(), &VerifyOptions::at(NOW)).unwrap_err();
        let BundleFileError::Refused { problem, .. } = &e else { panic!("byte {at}: {e}") };
        let ok = match refused {
            "signature" => matches!(problem, BundleError::BadSignature { .. }),
            _ => matches!(problem, BundleError::SectionHash { .. }),
        };
        assert!(ok, "byte {at}: {e}");
    }
    // The untouched file still verifies (the copies were changed, not the fixture).
    verify_file(&bundle_path(), &trust_dir(), &VerifyOptions::at(NOW)).unwrap();
}
