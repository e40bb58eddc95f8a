//! Wall-clock steps through the running appliance: its clocks are injected
//! (`runtime::run_with` with a steppable wall clock; the machine's clock is not touched), the
//! headless recorder times light by the kernel's boot clock. Steps back and forward of 1 h,
//! 25 h and 400 days, during showings and with the budget exhausted: no recorded interval
//! shrinks or stretches, every lit instant stays paid, and no step re-opens a budget.

mod appliance_common;

use std::path::Path;
use std::time::Duration;

use appliance_common::{OBJECT, Stage, ask, boot_us, ledger_us, wait_status};
use restage_appliance::clock::SteppableTime;
use restage_appliance::config::Config;
use restage_appliance::ledger::Ledger;
use restage_shared::bundle::example::ExampleSpec;
use restage_shared::policy::{ExposurePolicy, IdleMode};

const H: i64 = 3_600_000;
const STEPS: [i64; 6] = [-H, H, -25 * H, 25 * H, -400 * 24 * H, 400 * 24 * H];

/// Runs the appliance in this process on `time`, on its own thread, until the test ends.
fn start(config: &Path, time: SteppableTime) {
    let config = Config::load(config).unwrap();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        if let Err(e) = rt.block_on(restage_appliance::runtime::run_with(config, time)) {
            eprintln!("appliance stopped: {e}");
        }
    });
}

#[test]
fn clock_steps_during_showings_neither_shrink_nor_stretch_them() {
    let stage = Stage::new(ExampleSpec::small());
    let sock = stage.path("control.sock");
    let config = stage.config(
        "fade_ms = 100\nfade_fps = 20\nmin_press_interval_ms = 20",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let time = SteppableTime::new();
    start(&config, time.clone());
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    for step in STEPS {
        assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
        std::thread::sleep(Duration::from_millis(300));
        time.step(step);
        wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "idle");
    }
    let v = wait_status(&sock, Duration::from_secs(5), |_| true);
    assert!(v["wall_skew_ms"].as_i64().unwrap().abs() < 5_000, "the steps cancel out: {v}");
    stage.mark_dark();
    let ledger =
        Ledger::open(&stage.path("state/ledger.sqlite"), restage_appliance::zone::LocalZone::utc()).unwrap();
    let checked = stage.assert_every_lit_stretch_paid(&ledger);
    let status = ledger.status(i64::MAX / 4).unwrap();
    let showings: Vec<i64> = status.last_showings.iter().map(|s| s.ended_ms - s.started_ms).collect();
    eprintln!(
        "FIGURES clock: showings {showings:?} ms over steps {STEPS:?} ms; {checked} lit stretches paid"
    );
    assert_eq!(showings.len(), STEPS.len());
    // Each showing lasted its second (less the fade), whatever the wall clock did meanwhile.
    assert!(showings.iter().all(|&ms| (850..=1_300).contains(&ms)), "{showings:?}");
    let clock_events = status.last_events.iter().filter(|e| e.kind == "clock").count();
    assert!(clock_events >= 5, "each step is reported: {:?}", status.last_events);
    // The rows are as long as the light: over-count stays small (up to now: the idle scene's
    // reservation runs ahead of it).
    let now_ms = (ledger_us(&ledger.runs().unwrap(), boot_us()).unwrap() / 1000) as i64;
    let recorded = ledger.used(OBJECT, i64::MIN / 2, now_ms).unwrap();
    let seen = stage.true_exposure();
    assert!(recorded >= seen && recorded < seen * 1.5 + 1e-3, "recorded {recorded} lx·h, seen {seen} lx·h");
}

#[test]
fn no_clock_step_reopens_an_exhausted_budget() {
    let stage = Stage::new(ExampleSpec::small());
    // Idle off (charged nothing); a budget for about two showings' reservations.
    let lux = stage.scene_lux(1);
    let reserve_ms = 2_500.0;
    let budget = 2.5 * lux * reserve_ms / 3.6e6;
    let policy = ExposurePolicy {
        max_showing_s: 1,
        cooldown_s: 0,
        daily_budget_lxh: budget,
        annual_budget_lxh: budget,
        warn_at: vec![0.75, 0.9],
        idle: IdleMode::ProjectorsOff,
    };
    let spec = ExampleSpec { version: 4, ..ExampleSpec::small() };
    stage.write_bundle_with(&spec, OBJECT, &stage.path("state/active.bundle"), policy);
    let sock = stage.path("control.sock");
    let config = stage.config(
        "fade_ms = 0\nmin_press_interval_ms = 20",
        "reserve_ms = 2500\nrenew_ahead_ms = 2000",
        &format!("control_socket = {sock:?}"),
    );
    let time = SteppableTime::new();
    start(&config, time.clone());
    wait_status(&sock, Duration::from_secs(30), |v| v["state"] == "idle");
    // Spend the budget.
    for _ in 0..10 {
        let a = ask(&sock, "press", Duration::from_secs(5)).unwrap();
        if a.contains("budget-exhausted") {
            break;
        }
        wait_status(&sock, Duration::from_secs(10), |v| v["state"] != "showing");
    }
    wait_status(&sock, Duration::from_secs(5), |v| v["state"] == "budget-exhausted");
    let shown = stage.showing_stretches_ms(None).len();
    assert!(shown >= 1, "the budget allowed light before it ran out");
    for step in STEPS {
        time.step(step);
        // A reload looks at the budget afresh (idle is off: it reserves nothing), then a press
        // asks for light in ledger time, which the step did not move.
        assert!(ask(&sock, "reload", Duration::from_secs(30)).unwrap().starts_with("ok"));
        wait_status(&sock, Duration::from_secs(5), |v| v["state"] == "idle");
        let a = ask(&sock, "press", Duration::from_secs(5)).unwrap();
        assert!(a.contains("budget-exhausted"), "after a {step} ms step: {a}");
    }
    std::thread::sleep(Duration::from_millis(200));
    stage.mark_dark();
    assert_eq!(stage.showing_stretches_ms(None).len(), shown, "a clock step re-opened the budget");
    let ledger =
        Ledger::open(&stage.path("state/ledger.sqlite"), restage_appliance::zone::LocalZone::utc()).unwrap();
    stage.assert_every_lit_stretch_paid(&ledger);
}
