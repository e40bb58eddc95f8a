//! Correctly signed bundles whose light certificate or light model lies — zero coefficients,
//! coefficients under any plausible floor, empty blocks, a single 1-pixel block, all-zero
//! responses, responses that are zero below full white — with full-white frames: the
//! appliance's `verify` refuses each one naming what is wrong, and the appliance started with
//! one as its active bundle refuses to load it and keeps every output dark.

mod appliance_common;

use std::process::Command;
use std::time::Duration;

use appliance_common::{BIN, Stage, ask, wait_status};
use restage_shared::bundle::example::{ExampleSpec, Lie, lying_writer};
use restage_shared::keys::signing_key_from_seed;

/// The part of the refusal each lie must produce.
fn expected(lie: Lie) -> &'static str {
    match lie {
        Lie::ZeroCoefficients => "has L_ik = 0",
        Lie::TinyCoefficients => "scene original, projector 0: pixel (0, 0) is lit",
        Lie::EmptyBlocks => "scene original, projector 0: pixel (0, 0) is lit",
        Lie::OnePixelBlock => "scene original, projector 0: pixel (1, 0) is lit",
        Lie::ZeroResponses => "projector 0 channel 0: the response reaches only 0 at 255",
        Lie::ResponsesOnlyAtFull => "under the plausibility floor",
    }
}

/// A stage whose active bundle is `lie`'s, signed by the stage's trusted key.
fn lying_stage(lie: Lie) -> Stage {
    let stage = Stage::new(ExampleSpec::small());
    // The same key the stage trusts (appliance_common signs with seed 7).
    let key = signing_key_from_seed([7; 32]);
    let f = std::fs::File::create(stage.path("state/active.bundle")).unwrap();
    lying_writer(&ExampleSpec { version: 4, ..ExampleSpec::small() }, lie).unwrap().write(&key, f).unwrap();
    stage
}

/// The appliance binary's `verify` of the stage's active bundle.
fn verify(stage: &Stage) -> std::process::Output {
    Command::new(BIN)
        .arg("verify")
        .arg(stage.path("state/active.bundle"))
        .arg("--trust")
        .arg(stage.path("trust"))
        .output()
        .unwrap()
}

#[test]
fn appliance_verify_refuses_each_lying_certificate() {
    for lie in Lie::ALL {
        let stage = lying_stage(lie);
        let o = verify(&stage);
        let out = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(!o.status.success(), "{lie:?} verified: {out}");
        assert!(out.contains("refused") && out.contains(expected(lie)), "{lie:?}: {out}");
        assert!(!out.contains("OK:"), "{lie:?}: {out}");
    }
    // The same stage with its honest bundle verifies (the refusals are the lies').
    let stage = Stage::new(ExampleSpec::small());
    let o = verify(&stage);
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("OK:"), "{o:?}");
}

#[test]
fn appliance_refuses_to_load_each_lying_certificate_and_stays_dark() {
    for lie in Lie::ALL {
        let stage = lying_stage(lie);
        let sock = stage.path("control.sock");
        let config = stage.config("", "", &format!("control_socket = {sock:?}"));
        let mut child = stage.spawn(&config);
        let v = wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "dark");
        let detail = v["detail"].as_str().unwrap_or_default().to_string();
        // A press does nothing.
        let pressed = ask(&sock, "press", Duration::from_secs(5)).unwrap_or_default();
        let after = wait_status(&sock, Duration::from_secs(5), |_| true);
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(detail.contains("refused") && detail.contains(expected(lie)), "{lie:?}: {detail}");
        assert!(pressed.contains("dark") && after["state"] == "dark", "{lie:?}: {pressed} {after}");
        // The refusal is recorded (an alert about the dark stage may follow it).
        let events = v["ledger"]["last_events"].as_array().cloned().unwrap_or_default();
        assert!(events.iter().any(|e| e["kind"] == "refused"), "{lie:?}: {v}");
        let recs = stage.records();
        assert!(recs.iter().all(|r| r.frames.is_empty()), "{lie:?}: an output was lit: {:?}", recs.last());
    }
}
