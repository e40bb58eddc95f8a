//! The appliance as a real process, killed with SIGKILL at 200 seeded random moments (while
//! starting, idle, showing, fading): after every restart the ledger passes SQLite's integrity
//! check, and the exposure it recorded is never below the light the recorder saw.

mod appliance_common;

use std::io::Write;
use std::time::{Duration, Instant};

use appliance_common::{OBJECT, Stage, unix_us};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use restage_appliance::ledger::Ledger;
use restage_shared::bundle::example::ExampleSpec;

#[test]
fn sigkill_at_random_moments_never_corrupts_or_under_counts() {
    let stage = Stage::new(ExampleSpec::small());
    // Short showings and fades, so kills land in every phase; reservations far longer than
    // one process lives (a reservation must outlast any stall of the process).
    let config = stage.config(
        "fade_ms = 100\nfade_fps = 50\nmin_press_interval_ms = 20\nmax_showing_ms = 300",
        "reserve_ms = 3000\nrenew_ahead_ms = 2500",
        "stdin = true",
    );
    let ledger_path = stage.path("state/ledger.sqlite");
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut lit_at_kill = 0;
    for round in 0..200 {
        let mut child = stage.spawn(&config);
        let start = Instant::now();
        // Mostly early (start-up, first showing), sometimes late enough for fades and ends.
        let span = if rng.gen_bool(0.85) { 160 } else { 600 };
        let kill_after = Duration::from_millis(rng.gen_range(0..span));
        let mut presses: Vec<Duration> =
            (0..rng.gen_range(0..4)).map(|_| Duration::from_millis(rng.gen_range(0..span))).collect();
        presses.sort();
        let mut stdin = child.stdin.take().unwrap();
        for p in presses.into_iter().filter(|p| *p < kill_after) {
            std::thread::sleep(p.saturating_sub(start.elapsed()));
            let _ = stdin.write_all(b"press\n");
        }
        std::thread::sleep(kill_after.saturating_sub(start.elapsed()));
        child.kill().unwrap();
        child.wait().unwrap();
        // The light is certainly off once the process is gone.
        let records = stage.records();
        if records.last().is_some_and(|r| !r.frames.is_empty()) {
            lit_at_kill += 1;
        }
        stage.mark_dark(unix_us());

        // Restart's view of the ledger: opens (recovering the WAL), passes the integrity
        // check, and holds at least what was shown so far.
        if ledger_path.exists() {
            let ledger = Ledger::open(&ledger_path, 0).unwrap_or_else(|e| panic!("round {round}: {e}"));
            ledger.integrity_check().unwrap_or_else(|e| panic!("round {round}: {e}"));
            if round % 20 == 19 {
                let recorded = ledger.total(OBJECT).unwrap();
                let seen = stage.true_exposure();
                assert!(recorded >= seen, "round {round}: ledger {recorded} lx·h < seen {seen} lx·h");
            }
        }
    }
    let ledger = Ledger::open(&ledger_path, 0).unwrap();
    ledger.integrity_check().unwrap();
    let recorded = ledger.total(OBJECT).unwrap();
    let seen = stage.true_exposure();
    let status = ledger.status(0).unwrap();
    eprintln!(
        "200 kills ({lit_at_kill} while lit): recorded {recorded:.6} lx·h, seen {seen:.6} lx·h, \
         {} open reservations, {} recent showings",
        status.open_reservations,
        status.last_showings.len()
    );
    assert!(seen > 0.0, "the recorder saw no light: the test exercised nothing");
    assert!(lit_at_kill >= 50, "only {lit_at_kill} kills while lit");
    assert!(recorded >= seen, "ledger {recorded} lx·h < seen {seen} lx·h");
    // Stronger than the totals: every lit instant is covered by rows paying its lux.
    let checked = stage.assert_every_lit_stretch_paid(&ledger.exposure_rows(OBJECT).unwrap());
    assert!(checked >= 200, "only {checked} lit stretches");
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
