//! Bad set-ups give clear errors and dark outputs: a bad config, a missing trust directory, a
//! state directory that is not usable, a full disk (a file-size limit: SQLite reports it as
//! it reports a full disk), a bundle older than the accepted one, and a tampered bundle.

mod appliance_common;

use std::process::{Command, Stdio};
use std::time::Duration;

use appliance_common::{BIN, Stage, ask, wait_status};
use restage_shared::bundle::example::ExampleSpec;

fn run_to_exit(config: &std::path::Path) -> (bool, String) {
    let o = Command::new(BIN).args(["run", "--config"]).arg(config).stdin(Stdio::null()).output().unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn nothing_lit(stage: &Stage) -> bool {
    stage.records().iter().all(|r| r.frames.is_empty())
}

#[test]
fn bad_config_is_refused_naming_file_and_key() {
    let stage = Stage::new(ExampleSpec::small());
    let p = stage.path("bad.toml");
    std::fs::write(
        &p,
        "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[player]\nfade_fps = 1000\n[output]\nkind = \"window\"\n",
    )
    .unwrap();
    let (ok, err) = run_to_exit(&p);
    assert!(!ok);
    assert!(err.contains("bad.toml") && err.contains("player.fade_fps") && err.contains("1..=120"), "{err}");
    std::fs::write(
        &p,
        "trust_dir = \"/t\"\nstate_dir = \"/s\"\nbundel = \"x\"\n[output]\nkind = \"window\"\n",
    )
    .unwrap();
    let (ok, err) = run_to_exit(&p);
    assert!(!ok && err.contains("bundel"), "{err}");
    let (ok, err) = run_to_exit(&stage.path("missing.toml"));
    assert!(!ok && err.contains("missing.toml"), "{err}");
}

#[test]
fn unusable_state_directory_is_refused_with_outputs_dark() {
    let stage = Stage::new(ExampleSpec::small());
    let config = stage.config("", "", "");
    // A state directory that is a file.
    let text = std::fs::read_to_string(&config).unwrap();
    let file = stage.path("not-a-dir");
    std::fs::write(&file, "").unwrap();
    std::fs::write(&config, text.replace(&format!("{:?}", stage.path("state")), &format!("{file:?}")))
        .unwrap();
    let (ok, err) = run_to_exit(&config);
    assert!(!ok);
    assert!(
        err.contains("state directory") && err.contains("not-a-dir") && err.contains("not a directory"),
        "{err}"
    );
    let recs = stage.records();
    assert!(!recs.is_empty() && nothing_lit(&stage), "outputs blanked and never lit");
    // A missing one.
    std::fs::write(&config, text.replace(&format!("{:?}", stage.path("state")), "\"/nonexistent/restage\""))
        .unwrap();
    let (ok, err) = run_to_exit(&config);
    assert!(!ok && err.contains("/nonexistent/restage"), "{err}");
    assert!(nothing_lit(&stage));
}

#[test]
fn missing_trust_directory_runs_dark_and_says_why() {
    let stage = Stage::new(ExampleSpec::small());
    std::fs::remove_dir_all(stage.path("trust")).unwrap();
    let sock = stage.path("control.sock");
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let mut child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(20), |v| v["state"] == "dark");
    assert!(v["detail"].as_str().unwrap().contains("trust directory"), "{v}");
    // A press does nothing.
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("dark"));
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(nothing_lit(&stage));
}

#[test]
fn full_disk_faults_to_dark_with_the_reason() {
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    // Renewing often makes the ledger's WAL grow past the limit within a second or two.
    let config =
        stage.config("", "reserve_ms = 2500\nrenew_ahead_ms = 2000", &format!("control_socket = {sock:?}"));
    let mut child = Command::new("prlimit")
        .arg("--fsize=196608")
        .arg("--")
        .arg(BIN)
        .args(["run", "--config"])
        .arg(&config)
        .stdin(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("prlimit (util-linux)");
    let v = wait_status(&sock, Duration::from_secs(60), |v| v["state"] == "fault");
    let detail = v["detail"].as_str().unwrap();
    // EFBIG reads as "disk I/O error", ENOSPC as "database or disk is full".
    assert!(
        detail.contains("ledger") && (detail.contains("full") || detail.contains("I/O error")),
        "{detail}"
    );
    child.kill().unwrap();
    child.wait().unwrap();
    let recs = stage.records();
    assert!(recs.iter().any(|r| !r.frames.is_empty()), "it was lit before the disk filled");
    assert!(recs.last().unwrap().frames.is_empty(), "dark after the fault");
}

#[test]
fn older_or_tampered_bundle_keeps_the_previous_good_one() {
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let mut child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(20), |v| v["state"] == "idle");
    assert_eq!(v["bundle"]["version"], 3);
    // Tamper with the active file: reload refuses, the loaded bundle stays and plays.
    let path = stage.path("state/active.bundle");
    let good = std::fs::read(&path).unwrap();
    let mut bad = good.clone();
    let n = bad.len();
    bad[n - 10] ^= 0x40;
    std::fs::write(&path, &bad).unwrap();
    let a = ask(&sock, "reload", Duration::from_secs(5)).unwrap();
    assert!(a.starts_with("error:") && a.contains("refused"), "{a}");
    let v = wait_status(&sock, Duration::from_secs(5), |_| true);
    assert_eq!(v["state"], "idle");
    let events = v["ledger"]["last_events"].as_array().cloned().unwrap_or_default();
    assert!(events.iter().any(|e| e["kind"] == "refused"), "{v}");
    child.kill().unwrap();
    child.wait().unwrap();

    // An older version of the same object, correctly signed: refused by the ledger's record.
    let older = Stage::new(ExampleSpec { version: 2, ..ExampleSpec::small() });
    std::fs::copy(older.path("state/active.bundle"), &path).unwrap();
    let mut child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(20), |v| v["state"] == "dark");
    let d = v["detail"].as_str().unwrap();
    assert!(d.contains("version 2") && d.contains("3"), "{d}");
    child.kill().unwrap();
    child.wait().unwrap();
}
