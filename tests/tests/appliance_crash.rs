//! The appliance as a real process under an adversary, for `RESTAGE_CRASH_ROUNDS` rounds
//! (default 60; the README gives a full run's figures): each round starts it, waits for light,
//! then at seeded random moments presses (sometimes at 50 per second), stops it with SIGSTOP
//! (then SIGKILL, as a watchdog would, or SIGCONT past its lease), holds the ledger's write
//! lock from another process, or asks for a reload during a showing, and finally kills it
//! with SIGKILL. After every restart the
//! ledger passes SQLite's integrity check, and every lit instant the recorder saw — timed by
//! the kernel's boot clock, not the appliance's — is covered by ledger rows paying its lux.

mod appliance_common;

use std::io::Write;
use std::time::{Duration, Instant};

use appliance_common::{OBJECT, Stage};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use restage_appliance::ledger::Ledger;
use restage_shared::bundle::example::ExampleSpec;

/// The longest stop before the emulated watchdog kills the process (ms). The config's
/// lease slack (`renew_ahead_ms` 2500) less the appliance's kill-to-dark allowance must cover
/// it, as `ledger.max_watchdog_ms` requires of systemd's `WatchdogSec`.
const WATCHDOG_MS: u64 = 500;

fn rounds() -> usize {
    std::env::var("RESTAGE_CRASH_ROUNDS").ok().and_then(|v| v.parse().ok()).unwrap_or(60)
}

/// Waits until the recorder logged a record after `after` records with light (or `limit`).
fn wait_for_light(stage: &Stage, after: usize, limit: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if stage.records().iter().skip(after).any(|r| !r.frames.is_empty()) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

fn sleep_ms(ms: u64) {
    std::thread::sleep(Duration::from_millis(ms));
}

#[derive(Default, Debug)]
struct Tally {
    plain: usize,
    flood: usize,
    stall_kill: usize,
    stall_resume: usize,
    lock: usize,
    reload: usize,
    lit_at_kill: usize,
}

#[test]
fn adversarial_kills_stalls_and_lock_holders_never_under_count() {
    let stage = Stage::new(ExampleSpec::small());
    // Short showings and fades, so kills land in every phase; leases short enough that
    // stalls outlast them.
    let config = stage.config(
        "fade_ms = 100\nfade_fps = 50\nmin_press_interval_ms = 20\nmax_showing_ms = 300",
        "reserve_ms = 3000\nrenew_ahead_ms = 2500\nbusy_timeout_ms = 50",
        "stdin = true",
    );
    let ledger_path = stage.path("state/ledger.sqlite");
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let n = rounds();
    let mut t = Tally::default();
    let started = Instant::now();
    for round in 0..n {
        let before = stage.records().len();
        let mut child = stage.spawn(&config);
        let pid = Pid::from_raw(child.id() as i32);
        let mut stdin = child.stdin.take().unwrap();
        let press = |s: &mut std::process::ChildStdin| {
            let _ = s.write_all(b"press\n");
        };
        // Sometimes during start-up; otherwise once the idle scene is lit.
        if rng.gen_bool(0.1) {
            sleep_ms(rng.gen_range(0..300));
        } else {
            wait_for_light(&stage, before, Duration::from_secs(20));
        }
        match rng.gen_range(0..6) {
            0 => {
                t.plain += 1;
                for _ in 0..rng.gen_range(0..4) {
                    press(&mut stdin);
                    sleep_ms(rng.gen_range(0..250));
                }
                sleep_ms(rng.gen_range(0..400));
            }
            1 => {
                t.flood += 1;
                for _ in 0..rng.gen_range(5..60) {
                    press(&mut stdin);
                    sleep_ms(20);
                }
            }
            2 => {
                t.stall_kill += 1;
                press(&mut stdin);
                sleep_ms(rng.gen_range(0..350));
                kill(pid, Signal::SIGSTOP).unwrap();
                sleep_ms(rng.gen_range(50..=WATCHDOG_MS));
            }
            4 => {
                // A reload (operator, SIGHUP) during a showing: verified on a worker, swapped in
                // after the showing; killed at a random moment on the way.
                t.reload += 1;
                press(&mut stdin);
                sleep_ms(rng.gen_range(0..150));
                let _ = stdin.write_all(b"reload\n");
                sleep_ms(rng.gen_range(0..600));
            }
            3 => {
                t.stall_resume += 1;
                press(&mut stdin);
                sleep_ms(rng.gen_range(0..350));
                kill(pid, Signal::SIGSTOP).unwrap();
                // Longer than a lease and than a showing.
                sleep_ms(rng.gen_range(500..4_000));
                kill(pid, Signal::SIGCONT).unwrap();
                sleep_ms(rng.gen_range(100..600));
            }
            _ => {
                t.lock += 1;
                press(&mut stdin);
                sleep_ms(rng.gen_range(0..200));
                // Another process holds the ledger's write lock (an operator's sqlite3, a
                // backup tool), longer than the lease's slack: the appliance must go dark
                // rather than wait with light on. Half the time it is killed while the lock
                // is still held.
                let kill_while_locked = rng.gen_bool(0.5);
                let hold = rng.gen_range(3_000..4_500);
                let lock = rusqlite::Connection::open(&ledger_path)
                    .ok()
                    .filter(|c| c.execute_batch("BEGIN IMMEDIATE").is_ok());
                sleep_ms(hold);
                if kill_while_locked {
                    child.kill().unwrap();
                }
                if let Some(c) = lock {
                    let _ = c.execute_batch("ROLLBACK");
                }
                sleep_ms(rng.gen_range(0..300));
            }
        }
        let _ = child.kill();
        child.wait().unwrap();
        // The light is certainly off once the process is gone.
        if stage.records().last().is_some_and(|r| !r.frames.is_empty()) {
            t.lit_at_kill += 1;
        }
        stage.mark_dark();

        // Restart's view of the ledger: opens (recovering the WAL), passes the integrity
        // check, and covers every lit stretch so far.
        if ledger_path.exists() {
            let ledger = Ledger::open(&ledger_path, restage_appliance::zone::LocalZone::utc())
                .unwrap_or_else(|e| panic!("round {round}: {e}"));
            ledger.integrity_check().unwrap_or_else(|e| panic!("round {round}: {e}"));
            if round % 10 == 9 {
                stage.assert_every_lit_stretch_paid(&ledger);
            }
        }
    }
    let ledger = Ledger::open(&ledger_path, restage_appliance::zone::LocalZone::utc()).unwrap();
    ledger.integrity_check().unwrap();
    let recorded = ledger.total(OBJECT).unwrap();
    let seen = stage.true_exposure();
    let status = ledger.status(0).unwrap();
    let checked = stage.assert_every_lit_stretch_paid(&ledger);
    eprintln!(
        "FIGURES crash: {n} rounds in {:.0} s ({t:?}); {checked} lit stretches checked, 0 under-counted; \
         recorded {recorded:.6} lx·h, seen {seen:.6} lx·h, over-count ratio {:.3}; {} open reservations",
        started.elapsed().as_secs_f64(),
        recorded / seen.max(1e-12),
        status.open_reservations,
    );
    assert!(seen > 0.0, "the recorder saw no light: the test exercised nothing");
    assert!(recorded >= seen, "ledger {recorded} lx·h < seen {seen} lx·h");
    // Adaptive, not timing-bound: every kill while lit left at least one lit stretch to check,
    // and most rounds waited for light before the adversary acted.
    assert!(t.lit_at_kill * 4 >= n, "only {} of {n} kills while lit", t.lit_at_kill);
    assert!(checked >= t.lit_at_kill, "{checked} lit stretches for {} kills while lit", t.lit_at_kill);
    // A restoration was shown at some point (presses worked).
    let restorations = stage
        .records()
        .iter()
        .filter(|r| !r.frames.is_empty())
        .map(|r| r.frames.clone())
        .collect::<std::collections::HashSet<_>>()
        .len();
    assert!(restorations >= 3, "only {restorations} distinct frame sets shown");
}
