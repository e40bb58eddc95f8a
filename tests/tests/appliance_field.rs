//! What a gallery does to the appliance, through the real process: a reload of a slow-to-verify
//! bundle while lit, a lost or replaced ledger, a bundle re-signed for another object, a
//! restart in the middle of a cooldown. Each checks the light the recorder saw against the
//! ledger, and each fails on the behaviour it replaced (see the comments).

mod appliance_common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{RwLock, RwLockReadGuard};
use std::time::{Duration, Instant};

use appliance_common::{BIN, OBJECT, Stage, ask, wait_status};
use restage_appliance::ledger::Ledger;
use restage_shared::bundle::example::ExampleSpec;
use restage_shared::bundle::{VerifyOptions, verify_file};

fn run_to_exit(config: &Path) -> (bool, String) {
    let o = Command::new(BIN).args(["run", "--config"]).arg(config).stdin(Stdio::null()).output().unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// The slow-reload test measures when the timer ends a showing, so it runs alone: the other
/// tests' appliances on a 2-core machine held its event loop off the CPU for 750 ms (a showing
/// of 1148 ms), which says nothing about the appliance. The others may run together.
static TIMING: RwLock<()> = RwLock::new(());

fn shared_slot() -> RwLockReadGuard<'static, ()> {
    TIMING.read().unwrap_or_else(|e| e.into_inner())
}

fn stop(mut child: std::process::Child) {
    let _ = child.kill();
    let _ = child.wait();
}

/// A stage with showings of 400 ms (the configuration shortens the bundle's second) and a
/// control socket, and a newer bundle of the same object, version 4, that takes seconds to
/// verify and to copy (60 large scenes, 600 MB: 3-4.5 s to verify on a 2-core machine, debug
/// build). Returns the stage, its socket, its configuration and the new bundle.
fn large_bundle_stage() -> (Stage, std::path::PathBuf, std::path::PathBuf, std::path::PathBuf) {
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let config = stage.config(
        "fade_ms = 100\nfade_fps = 20\nmin_press_interval_ms = 20\nmax_showing_ms = 400",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let spec =
        ExampleSpec { scenes: 60, width: 1280, height: 960, step: 2, version: 4, ..ExampleSpec::small() };
    let bundle = stage.path("large.bundle");
    stage.write_bundle(&spec, OBJECT, &bundle);
    (stage, sock, config, bundle)
}

#[test]
fn a_slow_reload_while_lit_never_extends_a_showing() {
    let _alone = TIMING.write().unwrap_or_else(|e| e.into_inner());
    let (stage, sock, config, slow) = large_bundle_stage();
    let t = Instant::now();
    verify_file(&slow, &stage.path("trust"), &VerifyOptions::at(1_800_000_000)).unwrap();
    let verify_s = t.elapsed().as_secs_f64();

    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    // Installed as an installer does: written and synced first, renamed in place during the
    // showing. Copying the bundle during the showing left its 600 MB dirty on the same
    // filesystem, and the ledger's reservation for the fade waited behind their write-back
    // in its fsync: 650-1030 ms showings, from the disk, not from verification.
    std::fs::copy(&slow, stage.path("state/.next.bundle")).unwrap();
    std::fs::File::open(stage.path("state/.next.bundle")).unwrap().sync_all().unwrap();
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
    std::fs::rename(stage.path("state/.next.bundle"), stage.path("state/active.bundle")).unwrap();
    let asked = Instant::now();
    // While the worker verifies, the loop answers and the timer runs.
    let sock2 = sock.clone();
    let reload = std::thread::spawn(move || ask(&sock2, "reload", Duration::from_secs(120)));
    std::thread::sleep(Duration::from_millis(100));
    let t = Instant::now();
    let v = wait_status(&sock, Duration::from_secs(5), |v| v["reload_pending"] == true);
    let answered_in = t.elapsed().as_secs_f64();
    assert_eq!(v["bundle"]["version"], 3, "the old bundle plays until the new one is verified");
    let answer = reload.join().unwrap().expect("reload answer");
    assert!(answer.starts_with("ok"), "{answer}");
    let reload_s = asked.elapsed().as_secs_f64();
    let v = wait_status(&sock, Duration::from_secs(5), |v| v["bundle"]["version"] == 4);
    assert!(v["state"] == "idle" || v["state"] == "cooldown", "{v}");
    stop(child);
    stage.mark_dark();

    let stretches = stage.showing_stretches_ms(Some(&stage.first_lit()));
    eprintln!(
        "FIGURES reload: verification alone {verify_s:.2} s, reload answered after {reload_s:.2} s, \
         status answered in {answered_in:.3} s meanwhile; showings {stretches:?} ms (limit 400 ms)"
    );
    assert!(!stretches.is_empty(), "the press showed a restoration");
    // The timer ended the showing while the bundle was still being verified (verifying on
    // the event loop, as before, let the showing run for the whole verification). Later
    // stretches are the new bundle's idle scene (other frames).
    // The slack is for a loop sharing a 2-core machine with the verification worker and
    // the test harness (401-402 ms measured alone on an idle one). Verifying on the loop
    // would hold the showing for the whole verification.
    assert!(stretches[0] <= 400.0 + 600.0 && stretches[0] < 500.0 * verify_s, "{stretches:?}");
    assert!(verify_s > 1.0, "the slow bundle verified in {verify_s:.2} s: the test shows nothing");
    let ledger =
        Ledger::open(&stage.path("state/ledger.sqlite"), restage_appliance::zone::LocalZone::utc()).unwrap();
    // Paid up to the new bundle's first frame (whose light the stage's model does not know).
    let recs = stage.records();
    let size = format!("-{}x{}.xrgb", stage.spec.width, stage.spec.height);
    let first_new =
        recs.iter().position(|r| r.frames.iter().any(|f| !f.ends_with(&size))).unwrap_or(recs.len() - 1);
    stage.assert_paid(&ledger, &recs[..=first_new]);
    // The new bundle went in after the showing ended, not during it.
    let s = ledger.status(i64::MAX / 4).unwrap();
    let ended = s.last_showings.first().expect("the showing was recorded").ended_ms;
    let loaded = s.last_events.iter().find(|e| e.kind == "load" && e.detail.contains("version 4")).unwrap();
    assert!(loaded.at_ms >= ended, "swapped in at {} during the showing (ended {ended})", loaded.at_ms);
}

/// An operator installs a large bundle while a visitor watches, and the new bundle plays after
/// the reload. Every change of light waits for its ledger reservation to reach the disk
/// (fsync), and an fsync waits behind whatever the filesystem has dirty: copied in one piece,
/// the bundle's 600 MB of write-back held the fade's reservation, and the showing's full
/// light, past its timer.
#[test]
fn installing_a_large_bundle_while_lit_never_extends_a_showing() {
    let _alone = TIMING.write().unwrap_or_else(|e| e.into_inner());
    let (stage, sock, config, big) = large_bundle_stage();
    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");

    // The copy `restage-appliance install` makes once the bundle verified.
    let mut install = Command::new(BIN)
        .arg("install")
        .arg(&big)
        .arg("--to")
        .arg(stage.path("state/active.bundle"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The visitor presses as the copy begins (the installer's temporary file appears).
    let copying = || {
        std::fs::read_dir(stage.path("state"))
            .unwrap()
            .flatten()
            .any(|e| e.file_name().to_string_lossy().starts_with(".install-"))
    };
    let t = Instant::now();
    while !copying() {
        if install.try_wait().unwrap().is_some() {
            let out = install.wait_with_output().unwrap();
            panic!(
                "the installer finished before its copy was seen: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        assert!(t.elapsed() < Duration::from_secs(120), "no copy within 120 s");
        std::thread::sleep(Duration::from_millis(2));
    }
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
    let out = install.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(ask(&sock, "reload", Duration::from_secs(120)).unwrap().starts_with("ok"));
    wait_status(&sock, Duration::from_secs(60), |v| v["bundle"]["version"] == 4);
    stop(child);
    stage.mark_dark();

    let stretches = stage.showing_stretches_ms(Some(&stage.first_lit()));
    eprintln!("FIGURES install while lit: showings {stretches:?} ms (limit 400 ms)");
    // The same slack as the slow reload's: a loop sharing two cores with the installer. It
    // catches a gross stall only: on an idle 2-core machine the copy in flushed pieces gave
    // 400-407 ms, the copy in one piece 448-753 ms (the CI machine once 1028 ms).
    assert!(!stretches.is_empty() && stretches[0] <= 400.0 + 600.0, "{stretches:?}");
}

#[test]
fn a_lost_ledger_refuses_light_until_an_operator_acknowledges() {
    let _slot = shared_slot();
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
    stop(child);
    stage.mark_dark();
    let ledger_path = stage.path("state/ledger.sqlite");
    let lit_before = stage.records().len();

    // Truncated to nothing, then deleted: both refused, nothing lit, nothing created.
    for damage in ["truncate", "delete"] {
        match damage {
            "truncate" => std::fs::write(&ledger_path, b"").unwrap(),
            _ => std::fs::remove_file(&ledger_path).unwrap(),
        }
        for f in ["ledger.sqlite-wal", "ledger.sqlite-shm"] {
            let _ = std::fs::remove_file(stage.path("state").join(f));
        }
        let (ok, err) = run_to_exit(&config);
        assert!(!ok, "{damage}: started with a lost ledger");
        assert!(err.contains("ledger-reset") && err.contains("ledger.sqlite"), "{damage}: {err}");
        assert!(
            stage.records()[lit_before..].iter().all(|r| r.frames.is_empty()),
            "{damage}: light with a lost ledger"
        );
    }
    // The operator acknowledges with the real binary; the reason is in the new ledger.
    let out = Command::new(restage_tests::appliance_bin())
        .args(["ledger-reset", "--config"])
        .arg(&config)
        .args(["--reason", "test: ledger lost"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    let events = v["ledger"]["last_events"].as_array().unwrap();
    assert!(
        events
            .iter()
            .any(|e| e["kind"] == "ledger-reset"
                && e["detail"].as_str().unwrap().contains("test: ledger lost"))
    );
    stop(child);
}

#[test]
fn a_bundle_resigned_for_another_object_gets_no_fresh_budget() {
    let _slot = shared_slot();
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    // The same content, correctly signed, under a new object id (and a higher version).
    let spec = ExampleSpec { version: 9, ..ExampleSpec::small() };
    stage.write_bundle(&spec, "test-jar-1-fresh-budget", &stage.path("state/active.bundle"));
    let answer = ask(&sock, "reload", Duration::from_secs(30)).unwrap();
    assert!(answer.contains("pinned to \"test-jar-1\""), "{answer}");
    let v = wait_status(&sock, Duration::from_secs(5), |v| v["state"] == "idle");
    assert_eq!(v["bundle"]["object"], OBJECT, "the pinned object's bundle keeps playing");
    stop(child);
    // A restart does not forget the pin.
    let (ok, err) = {
        let mut child = stage.spawn(&config);
        let v = wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "dark");
        let _ = child.kill();
        let _ = child.wait();
        (v["detail"].as_str().is_some_and(|d| d.contains("pinned")), v.to_string())
    };
    assert!(ok, "{err}");
    // Configuring the new object is the operator's way to move the stage on (recorded).
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&config, format!("object_id = \"test-jar-1-fresh-budget\"\n{text}")).unwrap();
    let child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    assert_eq!(v["bundle"]["object"], "test-jar-1-fresh-budget");
    stop(child);
}

#[test]
fn a_restart_during_a_cooldown_keeps_it() {
    let _slot = shared_slot();
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    // The configured cooldown lengthens the bundle's (0 s) to a minute.
    let config = stage.config(
        "fade_ms = 100\nfade_fps = 20\ncooldown_ms = 60000",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
    wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "cooldown");
    stop(child);
    stage.mark_dark();
    let shown_before = stage.showing_stretches_ms(Some(&stage.first_lit())).len();
    // Restarted (a crash, an update) and pressed at once: still cooling down.
    let child = stage.spawn(&config);
    let v = wait_status(&sock, Duration::from_secs(30), |v| v["state"] != "dark");
    assert_eq!(v["state"], "cooldown", "{v}");
    let answer = ask(&sock, "press", Duration::from_secs(5)).unwrap();
    assert!(answer.contains("cooldown"), "{answer}");
    std::thread::sleep(Duration::from_millis(300));
    stop(child);
    stage.mark_dark();
    assert_eq!(
        stage.showing_stretches_ms(Some(&stage.first_lit())).len(),
        shown_before,
        "a showing started during the cooldown"
    );
}

/// An operator drops bundles into the inbox. A correctly signed bundle with one byte changed
/// is refused: named in the ledger's events, moved to `refused/` with why, the old bundle
/// playing on. One copied slowly (five pieces two seconds apart) is not taken half-copied;
/// once whole it is installed, moved to `installed/`, and plays.
#[test]
fn the_inbox_refuses_a_tampered_bundle_and_installs_a_whole_one() {
    let _slot = shared_slot();
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let inbox = stage.path("inbox");
    std::fs::create_dir(&inbox).unwrap();
    let config = stage.config("", "", &format!("control_socket = {sock:?}"));
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&config, format!("inbox_dir = {inbox:?}\n{text}")).unwrap();
    let child = stage.spawn(&config);
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");

    let v4 = stage.path("v4.bundle");
    stage.write_bundle(&ExampleSpec { version: 4, ..ExampleSpec::small() }, OBJECT, &v4);
    let bytes = std::fs::read(&v4).unwrap();
    let mut tampered = bytes.clone();
    let mid = tampered.len() / 2;
    tampered[mid] ^= 0x40;
    std::fs::write(inbox.join("tampered.bundle"), &tampered).unwrap();
    let note = inbox.join("refused/tampered.bundle.txt");
    let t = Instant::now();
    while !note.exists() {
        assert!(t.elapsed() < Duration::from_secs(60), "the tampered bundle was not refused");
        std::thread::sleep(Duration::from_millis(50));
    }
    let why = std::fs::read_to_string(&note).unwrap();
    assert!(why.contains("tampered.bundle"), "{why}");
    assert!(inbox.join("refused/tampered.bundle").exists() && !inbox.join("tampered.bundle").exists());
    let v = wait_status(&sock, Duration::from_secs(5), |_| true);
    assert_eq!(v["bundle"]["version"], 3, "the old bundle plays on: {v}");
    assert_eq!(v["inbox"]["dir"], inbox.to_str().unwrap(), "status names the inbox: {v}");
    let last = &v["inbox"]["last"];
    assert!(last["installed"] == false && last["file"].as_str().unwrap().ends_with("tampered.bundle"), "{v}");
    assert!(last["detail"].as_str().unwrap().contains("refused/tampered.bundle"), "says where it went: {v}");

    // A slow copy, five pieces two seconds apart: the inbox scans (every 5 s) see it
    // incomplete at least once, and must not take it while it grows.
    let slow = inbox.join("slow.bundle");
    let mut f = std::fs::File::create(&slow).unwrap();
    for piece in bytes.chunks(bytes.len().div_ceil(5)) {
        use std::io::Write;
        assert!(!inbox.join("refused/slow.bundle").exists(), "taken half-copied");
        f.write_all(piece).unwrap();
        f.flush().unwrap();
        std::thread::sleep(Duration::from_secs(2));
    }
    drop(f);
    let v = wait_status(&sock, Duration::from_secs(60), |v| v["bundle"]["version"] == 4);
    assert!(v["inbox"]["last"]["installed"] == true, "the last outcome follows: {v}");
    assert!(inbox.join("installed/slow.bundle").exists() && !inbox.join("refused/slow.bundle").exists());
    stop(child);

    let ledger =
        Ledger::open(&stage.path("state/ledger.sqlite"), restage_appliance::zone::LocalZone::utc()).unwrap();
    let events = ledger.status(i64::MAX / 4).unwrap().last_events;
    let said = |kind: &str, what: &str| events.iter().any(|e| e.kind == kind && e.detail.contains(what));
    assert!(said("refused", "tampered.bundle"), "{events:?}");
    assert!(said("install", "slow.bundle"), "{events:?}");
    assert!(said("load", "version 4"), "{events:?}");
}
