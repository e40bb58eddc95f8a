//! `restage-appliance verify BUNDLE --trust DIR` accepts a good bundle and refuses a
//! validly signed one whose scene is over the light bound (the shared reader's check).

use std::process::Command;

use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};

fn verify(bundle: &std::path::Path, trust: &std::path::Path) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-appliance"))
        .arg("verify")
        .arg(bundle)
        .arg("--trust")
        .arg(trust)
        .output()
        .unwrap();
    (
        o.status.success(),
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)),
    )
}

#[test]
fn verify_accepts_good_and_refuses_over_bound() {
    let dir = tempfile::tempdir().unwrap();
    let key = signing_key_from_seed([3; 32]);
    let trust = dir.path().join("trust");
    std::fs::create_dir(&trust).unwrap();
    std::fs::write(trust.join("k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();

    let good = dir.path().join("good.restage");
    example_writer(&ExampleSpec::small()).write(&key, std::fs::File::create(&good).unwrap()).unwrap();
    let (ok, out) = verify(&good, &trust);
    assert!(ok && out.contains("OK: signature verified") && out.contains("peak"), "{out}");

    let bad = dir.path().join("bad.restage");
    let spec = ExampleSpec { lux_per_unit: 40.0, ..ExampleSpec::small() };
    example_writer(&spec)
        .skip_bound_check_for_test_fixtures()
        .write(&key, std::fs::File::create(&bad).unwrap())
        .unwrap();
    let (ok, out) = verify(&bad, &trust);
    assert!(!ok && out.contains("exceeds the allowed 47.50 lx"), "{out}");
}
