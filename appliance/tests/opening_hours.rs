//! Opening hours through the real event loop (`runtime::run_with` on a wall clock set to the
//! nights Europe/Amsterdam changes its clocks): the stage opens when the clocks spring
//! forward, stays open through the repeated hour in autumn, and at closing time a showing
//! fades out, the stage goes dark and presses are refused with the reason. The bundle is
//! written with `restage_shared`'s synthetic example; the ledger is read afterwards.

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use restage_appliance::clock::{SteppableTime, SystemTime, TimeSource};
use restage_appliance::config::Config;
use restage_appliance::ledger::Ledger;
use restage_appliance::zone::LocalZone;
use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame, example_info};
use restage_shared::bundle::{BundleWriter, SceneKind};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};
use restage_shared::policy::{ExposurePolicy, IdleMode};

const OBJECT: &str = "test-jar-1";
const FADE_MS: i64 = 400;

fn unix_ms(rfc3339: &str) -> i64 {
    rfc3339.parse::<jiff::Timestamp>().unwrap().as_millisecond()
}

/// A stage in a temporary folder: trusted key, a signed 3-scene bundle (idle = the original
/// scene, 30 s showings, no cooldown, large budgets) and a configuration with `hours`.
struct Stage {
    dir: tempfile::TempDir,
}

impl Stage {
    fn new(hours: &str) -> Stage {
        let dir = tempfile::tempdir().unwrap();
        for d in ["trust", "state", "rec"] {
            std::fs::create_dir(dir.path().join(d)).unwrap();
        }
        let key = signing_key_from_seed([7; 32]);
        std::fs::write(dir.path().join("trust/test.pub.pem"), public_key_to_pem(&key.verifying_key()))
            .unwrap();
        let spec = ExampleSpec::small();
        let mut info = example_info(&spec);
        info.object.id = OBJECT.into();
        info.policy = ExposurePolicy {
            max_showing_s: 30,
            cooldown_s: 0,
            daily_budget_lxh: 1e6,
            annual_budget_lxh: 1e7,
            warn_at: vec![0.75, 0.9],
            idle: IdleMode::Scene("original".into()),
        };
        let mut w = BundleWriter::new(info, example_certificate(&spec));
        for s in 0..3 {
            let frames = (0..spec.projectors).map(|k| example_frame(&spec, s % spec.scenes, k)).collect();
            let (id, kind) = if s == 0 {
                ("original".to_string(), SceneKind::Original)
            } else {
                (format!("restored-{s}"), SceneKind::Restoration)
            };
            w.add_scene(&id, &id, kind, frames).unwrap();
        }
        w.write(&key, std::fs::File::create(dir.path().join("state/active.bundle")).unwrap()).unwrap();
        let stage = Stage { dir };
        let config = format!(
            "trust_dir = {:?}\nstate_dir = {:?}\ntime_zone = \"Europe/Amsterdam\"\n\
             [player]\nfade_ms = {FADE_MS}\nfade_fps = 20\nmin_press_interval_ms = 20\n\
             [output]\nkind = \"headless\"\ndir = {:?}\nprojectors = {}\n\
             [inputs]\ncontrol_socket = {:?}\n[hours]\n{hours}\n",
            stage.path("trust"),
            stage.path("state"),
            stage.path("rec"),
            spec.projectors,
            stage.socket(),
        );
        std::fs::write(stage.path("config.toml"), config).unwrap();
        stage
    }

    fn path(&self, p: &str) -> PathBuf {
        self.dir.path().join(p)
    }

    fn socket(&self) -> PathBuf {
        self.path("control.sock")
    }

    /// Runs the appliance in this process with its wall clock at `wall` (ledger time follows
    /// the monotonic clock from there), on its own thread until the test ends.
    fn start(&self, wall: &str) {
        let time = SteppableTime::new();
        time.step(unix_ms(wall) - SystemTime.wall_ms());
        let config = Config::load(&self.path("config.toml")).unwrap();
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
            if let Err(e) = rt.block_on(restage_appliance::runtime::run_with(config, time)) {
                eprintln!("appliance stopped: {e}");
            }
        });
    }

    fn ask(&self, command: &str) -> String {
        common::ask(&self.socket(), command, Duration::from_secs(20))
            .expect("an answer on the control socket")
    }

    /// Waits until the status satisfies `f`.
    fn wait_status(&self, timeout: Duration, f: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
        let start = Instant::now();
        loop {
            let v: serde_json::Value = serde_json::from_str(&self.ask("status")).expect("status is JSON");
            if f(&v) {
                return v;
            }
            assert!(start.elapsed() < timeout, "status never matched; last: {v}");
            std::thread::sleep(Duration::from_millis(30));
        }
    }

    fn ledger(&self) -> Ledger {
        Ledger::open(&self.path("state/ledger.sqlite"), LocalZone::named("Europe/Amsterdam").unwrap())
            .unwrap()
    }
}

#[test]
fn the_stage_opens_when_the_clocks_spring_forward() {
    // Sunday 2026-03-29, 01:59:50 CET; at 01:00Z the clocks go from 02:00 CET to 03:00 CEST,
    // so an interval from 02:30 opens at 03:00 CEST.
    let stage = Stage::new("sun = [\"02:30-18:00\"]");
    stage.start("2026-03-29T00:59:50Z");
    let v = stage.wait_status(Duration::from_secs(30), |v| v["state"] == "closed");
    assert_eq!(v["open"], false, "{v}");
    assert_eq!(v["time_zone"], "Europe/Amsterdam");
    assert_eq!(v["next_change"], "2026-03-29 03:00 CEST", "{v}");
    assert_eq!(v["look"], "Off");
    let answer = stage.ask("press");
    assert_eq!(answer, "ok closed (closed: opens Sun 03:00)");
    let v = stage.wait_status(Duration::from_secs(15), |v| v["state"] == "idle");
    assert_eq!(v["open"], true, "{v}");
    assert_eq!(v["next_change"], "2026-03-29 18:00 CEST", "{v}");
    assert_eq!(v["ledger"]["day"], "2026-03-29");
    assert!(stage.ask("press").contains("showing"));
    std::thread::sleep(Duration::from_millis(200));
    // Nothing was lit, or reserved, before the opening.
    let opened = unix_ms("2026-03-29T01:00:00Z");
    let rows = stage.ledger().exposure_rows(OBJECT).unwrap();
    assert!(rows.len() >= 2, "{rows:?}");
    assert!(rows.iter().all(|r| r.start_ms >= opened), "{rows:?}");
}

#[test]
fn closing_time_fades_a_showing_out_and_refuses_presses() {
    // Sunday 2026-03-29, 17:59:50 CEST: closing at 18:00 (16:00Z); next opening Monday 10:00.
    let stage = Stage::new("mon = [\"10:00-17:00\"]\nsun = [\"02:30-18:00\"]");
    stage.start("2026-03-29T15:59:50Z");
    let v = stage.wait_status(Duration::from_secs(30), |v| v["state"] == "idle");
    assert_eq!(v["next_change"], "2026-03-29 18:00 CEST", "{v}");
    assert!(stage.ask("press").contains("showing"));
    let v = stage.wait_status(Duration::from_secs(15), |v| v["state"] == "closed");
    assert_eq!(v["open"], false);
    assert_eq!(v["detail"], "closed: opens Mon 10:00");
    assert_eq!(v["next_change"], "2026-03-30 10:00 CEST", "{v}");
    assert_eq!(stage.ask("press"), "ok closed (closed: opens Mon 10:00)");
    std::thread::sleep(Duration::from_millis(200));
    let closed = unix_ms("2026-03-29T16:00:00Z");
    let ledger = stage.ledger();
    let status = ledger.status(closed + 60_000).unwrap();
    let showing = &status.last_showings[0];
    assert_eq!(showing.ended_by, "closing");
    assert!((closed..closed + 1_000).contains(&showing.ended_ms), "{showing:?}");
    // The showing faded out (a fade reservation), then nothing: every row is committed and
    // ends by the fade's end plus the light-off latency (and some scheduling slack).
    let rows = ledger.exposure_rows(OBJECT).unwrap();
    assert!(rows.iter().any(|r| r.kind == "fade" && r.start_ms >= closed), "{rows:?}");
    assert!(rows.iter().all(|r| r.committed && r.end_ms <= closed + FADE_MS + 2_000), "{rows:?}");
}

#[test]
fn the_stage_stays_open_through_the_repeated_hour() {
    // Sunday 2026-10-25, 02:59:50 CEST; at 01:00Z the clocks go back to 02:00 CET. Open
    // 02:30 CEST to 03:30 CET: two hours of real time, no change at the clock change.
    let stage = Stage::new("sun = [\"02:30-03:30\"]");
    stage.start("2026-10-25T00:59:50Z");
    let v = stage.wait_status(Duration::from_secs(30), |v| v["state"] == "idle");
    assert_eq!(v["next_change"], "2026-10-25 03:30 CET", "{v}");
    assert!(v["ledger"]["now_local"].as_str().unwrap().ends_with("CEST"), "{v}");
    let v = stage.wait_status(Duration::from_secs(15), |v| {
        v["ledger"]["now_local"].as_str().is_some_and(|t| t.ends_with("CET"))
    });
    assert_eq!(v["state"], "idle", "{v}");
    assert_eq!(v["open"], true);
    assert_eq!(v["ledger"]["day"], "2026-10-25");
    assert!(v["ledger"]["now_local"].as_str().unwrap().starts_with("2026-10-25 02:00"), "{v}");
}
