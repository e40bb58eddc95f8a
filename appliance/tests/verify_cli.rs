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
    example_writer(&ExampleSpec::small())
        .unwrap()
        .write(&key, std::fs::File::create(&good).unwrap())
        .unwrap();
    let (ok, out) = verify(&good, &trust);
    assert!(ok && out.contains("OK: signature verified") && out.contains("peak"), "{out}");

    let bad = dir.path().join("bad.restage");
    let spec = ExampleSpec { lux_per_unit: 40.0, ..ExampleSpec::small() };
    example_writer(&spec)
        .unwrap()
        .skip_bound_check_for_test_fixtures()
        .write(&key, std::fs::File::create(&bad).unwrap())
        .unwrap();
    let (ok, out) = verify(&bad, &trust);
    assert!(!ok && out.contains("exceeds the allowed 47.50 lx"), "{out}");
}

/// Correctly signed bundles whose certificate or light model lies (the cases the light check's
/// coverage and response tests exist for) are refused by the real binary, naming the scene,
/// projector and pixel where there is one.
#[test]
fn verify_refuses_lying_certificates() {
    use restage_shared::bundle::example::{Lie, lying_writer};
    let dir = tempfile::tempdir().unwrap();
    let key = signing_key_from_seed([3; 32]);
    let trust = dir.path().join("trust");
    std::fs::create_dir(&trust).unwrap();
    std::fs::write(trust.join("k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
    for lie in Lie::ALL {
        let path = dir.path().join(format!("{lie:?}.restage"));
        lying_writer(&ExampleSpec::small(), lie)
            .unwrap()
            .write(&key, std::fs::File::create(&path).unwrap())
            .unwrap();
        let (ok, out) = verify(&path, &trust);
        let want = match lie {
            Lie::ZeroCoefficients => "projector 0 point 0: block [0, 7) x [0, 7) has L_ik = 0",
            Lie::TinyCoefficients => {
                "scene original, projector 0: pixel (0, 0) is lit (r, g, b = [254, 254, 254]) but the blocks covering it have L_ik of at most 0.000000001"
            }
            Lie::EmptyBlocks => {
                "scene original, projector 0: pixel (0, 0) is lit (r, g, b = [254, 254, 254]) but no block"
            }
            Lie::OnePixelBlock => "scene original, projector 0: pixel (1, 0) is lit",
            Lie::ZeroResponses => "the response reaches only 0 at 255",
            Lie::ResponsesOnlyAtFull => "the response at value 65 is 0, under the plausibility floor",
        };
        assert!(!ok && out.contains(want), "{lie:?}: {out}");
    }
    // A throw limit tighter than the bundle's coefficients imply refuses an honest bundle too:
    // the limits are the stage's.
    let good = dir.path().join("good.restage");
    example_writer(&ExampleSpec::small())
        .unwrap()
        .write(&key, std::fs::File::create(&good).unwrap())
        .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_restage-appliance"))
        .arg("verify")
        .arg(&good)
        .arg("--trust")
        .arg(&trust)
        .args(["--max-throw-m", "1", "--min-cos", "1"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && out.contains("under the floor 400.0000"), "{out}");
}
