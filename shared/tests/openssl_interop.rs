//! Interoperability with OpenSSL, a tool no one here wrote: keys made by `openssl genpkey`
//! sign restage bundles that restage verifies, OpenSSL's signature over a bundle's signed
//! bytes is the one restage writes, and OpenSSL verifies restage's signatures and reads
//! restage's key files. Skips (saying so) only where the `openssl` command is absent;
//! `.ci/run` installs it.

use std::io::Cursor;
use std::path::Path;
use std::process::Command;

use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::bundle::{BundleReader, HEADER_LEN, SIGNATURE_BLOCK_LEN, VerifyOptions};
use restage_shared::keys::{
    KeyId, TrustStore, load_private_key, load_public_key, public_key_to_pem, signing_key_from_seed,
    write_keypair,
};

fn openssl(args: &[&str], dir: &Path) -> Option<std::process::Output> {
    match Command::new("openssl").args(args).current_dir(dir).output() {
        Ok(o) => Some(o),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => panic!("cannot run openssl: {e}"),
    }
}

fn have_openssl() -> bool {
    let ok = Command::new("openssl").arg("version").output().is_ok();
    if !ok {
        eprintln!("SKIPPED: the `openssl` command is not installed (`.ci/run` installs it)");
    }
    ok
}

fn run(args: &[&str], dir: &Path) -> String {
    let o = openssl(args, dir).expect("openssl present");
    assert!(o.status.success(), "openssl {args:?} failed: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Splits a bundle into (signed bytes = header + manifest, key id, signature).
fn split(bytes: &[u8]) -> (Vec<u8>, [u8; 16], Vec<u8>) {
    let mlen = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let end = HEADER_LEN as usize + mlen;
    let id: [u8; 16] = bytes[end..end + 16].try_into().unwrap();
    let sig = bytes[end + 16..end + SIGNATURE_BLOCK_LEN as usize].to_vec();
    (bytes[..end].to_vec(), id, sig)
}

#[test]
fn openssl_keys_and_signatures_verify_in_restage() {
    if !have_openssl() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    run(&["genpkey", "-algorithm", "ed25519", "-out", "ossl.pem"], d);
    run(&["pkey", "-in", "ossl.pem", "-pubout", "-out", "ossl.pub.pem"], d);
    let private = load_private_key(&d.join("ossl.pem")).unwrap();
    let public = load_public_key(&d.join("ossl.pub.pem")).unwrap();
    assert_eq!(private.verifying_key(), public);

    // A bundle signed with the OpenSSL-made key; then its signature replaced by the one
    // `openssl pkeyutl -sign -rawin` makes over the same signed bytes.
    let mut bytes = Vec::new();
    example_writer(&ExampleSpec::small()).unwrap().write(&private, &mut bytes).unwrap();
    let (signed, id, ours) = split(&bytes);
    assert_eq!(KeyId(id), KeyId::of(&public));
    std::fs::write(d.join("signed.bin"), &signed).unwrap();
    run(&["pkeyutl", "-sign", "-rawin", "-inkey", "ossl.pem", "-in", "signed.bin", "-out", "ossl.sig"], d);
    let theirs = std::fs::read(d.join("ossl.sig")).unwrap();
    assert_eq!(theirs.len(), 64);
    // Ed25519 is deterministic: the same key over the same bytes gives the same signature.
    assert_eq!(theirs, ours);
    let at = signed.len() + 16;
    bytes[at..at + 64].copy_from_slice(&theirs);

    let trust_dir = d.join("trust");
    std::fs::create_dir(&trust_dir).unwrap();
    std::fs::copy(d.join("ossl.pub.pem"), trust_dir.join("ossl.pem")).unwrap();
    let trust = TrustStore::load_dir(&trust_dir).unwrap();
    let v = BundleReader::open(Cursor::new(bytes.clone()), &trust, &VerifyOptions::at(0))
        .unwrap()
        .verify(|_| Ok(()))
        .unwrap();
    assert_eq!(v.key_id, KeyId::of(&public));

    // OpenSSL's signature over different bytes is refused.
    std::fs::write(d.join("other.bin"), b"something else").unwrap();
    run(&["pkeyutl", "-sign", "-rawin", "-inkey", "ossl.pem", "-in", "other.bin", "-out", "other.sig"], d);
    bytes[at..at + 64].copy_from_slice(&std::fs::read(d.join("other.sig")).unwrap());
    assert!(BundleReader::open(Cursor::new(bytes), &trust, &VerifyOptions::at(0)).is_err());
}

#[test]
fn openssl_verifies_restage_signatures_and_reads_restage_keys() {
    if !have_openssl() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let key = signing_key_from_seed([5; 32]);
    let (private, public) = write_keypair(&key, &d.join("restage")).unwrap();
    // OpenSSL reads restage's private key and derives the same public key file.
    let derived = run(&["pkey", "-in", private.to_str().unwrap(), "-pubout"], d);
    assert_eq!(derived, public_key_to_pem(&key.verifying_key()));
    assert_eq!(std::fs::read_to_string(&public).unwrap(), derived);

    let mut bytes = Vec::new();
    example_writer(&ExampleSpec::small()).unwrap().write(&key, &mut bytes).unwrap();
    let (signed, _, sig) = split(&bytes);
    std::fs::write(d.join("signed.bin"), &signed).unwrap();
    std::fs::write(d.join("restage.sig"), &sig).unwrap();
    let verify = |file: &str| {
        openssl(
            &[
                "pkeyutl",
                "-verify",
                "-pubin",
                "-inkey",
                public.to_str().unwrap(),
                "-rawin",
                "-in",
                file,
                "-sigfile",
                "restage.sig",
            ],
            d,
        )
        .unwrap()
    };
    let o = verify("signed.bin");
    assert!(
        o.status.success(),
        "openssl refused restage's signature: {}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("Signature Verified Successfully"));
    // And OpenSSL refuses it over one changed byte.
    let mut tampered = signed.clone();
    tampered[40] ^= 1;
    std::fs::write(d.join("tampered.bin"), &tampered).unwrap();
    assert!(!verify("tampered.bin").status.success());
}
