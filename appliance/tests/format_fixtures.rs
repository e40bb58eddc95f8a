//! Frozen format fixture: a schema-2 ledger (`tests/fixtures/ledger-schema-2.sqlite`, the
//! SQLite file a stage keeps in its state directory) written once with two showings, a fade,
//! a reservation a crash left open, a budget warning, events and two runs, then read back with
//! today's code. A schema change that can no longer read, migrate or extend a ledger already
//! out in the field fails here. Never regenerate the fixture to make these tests pass: a new
//! schema version gets a new fixture beside this one (docs/formats.md, "Bumping a version").
//!
//! The fixture was written by the ignored test below, which refuses to overwrite it:
//!
//! ```text
//! RESTAGE_REGENERATE_FIXTURES=1 cargo test -p restage-appliance --test format_fixtures -- --ignored regenerate
//! ```

use std::path::{Path, PathBuf};

use restage_appliance::ledger::{
    ActiveBundle, Budgets, GUARD_FILE, LEDGER_FILE, Ledger, LedgerError, SCHEMA_VERSION,
};
use restage_appliance::player::{Accountant, LightKind};
use restage_appliance::zone::LocalZone;

/// The schema the fixture was written with (SQLite's `user_version`).
const FIXTURE_SCHEMA: u32 = 2;
/// 2026-06-01 10:00:00 UTC, Unix ms: the first run's start.
const T0: i64 = 1_780_308_000_000;
const S: i64 = 1_000;
const H: i64 = 3_600_000;
const OBJECT: &str = "fixture-jar";
const HASH: &str = "a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1a1";
const BUNDLE_PATH: &str = "/var/lib/restage/state/active.bundle";
/// The id the ledger gave itself when it was written.
const LEDGER_ID: &str = "5bdbbcbedb268841fdc56a867a4f36d1";

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ledger-schema-2.sqlite")
}

fn active() -> ActiveBundle {
    ActiveBundle {
        object: OBJECT.into(),
        version: 3,
        bundle_hash: HASH.into(),
        path: BUNDLE_PATH.into(),
        loaded_ms: T0,
        budgets: Budgets { daily_lux_hours: 0.8, annual_lux_hours: 15_000.0, warn_at: vec![0.75, 0.9] },
    }
}

/// Lux-hours of `lux` held for `ms`.
fn lxh(lux: f64, ms: i64) -> f64 {
    lux * ms as f64 / H as f64
}

/// Writes the fixture (only when RESTAGE_REGENERATE_FIXTURES=1 or it does not exist yet) and
/// prints the ledger id the tests expect.
#[test]
#[ignore = "writes the checked-in fixture; see the module docs"]
fn regenerate_ledger_schema_2_fixture() {
    let path = fixture();
    let allowed = std::env::var_os("RESTAGE_REGENERATE_FIXTURES").is_some_and(|v| v == "1");
    assert!(
        allowed || !path.exists(),
        "{} exists: set RESTAGE_REGENERATE_FIXTURES=1 to overwrite it (a frozen fixture is only \
         rewritten on purpose, and the old one is kept under its own name)",
        path.display()
    );
    assert_eq!(SCHEMA_VERSION, FIXTURE_SCHEMA, "today's schema is newer: give it its own fixture");
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join(LEDGER_FILE);
    let mut l = Ledger::open(&tmp, LocalZone::utc()).unwrap();
    // The first run: a bundle accepted and loaded.
    l.record_run(T0, 5_000, T0).unwrap();
    l.check_version(OBJECT, 3, HASH).unwrap();
    l.accept_version(OBJECT, 3, HASH, T0).unwrap();
    l.pin_object(OBJECT, T0, "the first accepted bundle").unwrap();
    l.set_active(&active()).unwrap();
    l.log_event(T0, "load", &format!("{OBJECT} version 3 ({BUNDLE_PATH})")).unwrap();
    // Showing 1: reserved, extended, ended by the timer at 30 s.
    let a = l.reserve(LightKind::Showing, "restored-1", 40.0, T0 + 60 * S, T0 + 65 * S).unwrap();
    l.extend(a, T0 + 95 * S).unwrap();
    l.commit(a, T0 + 90 * S).unwrap();
    l.record_showing(T0 + 60 * S, T0 + 90 * S, &["restored-1".into()], "timer").unwrap();
    // Showing 2: its reservation crosses 75 % of the daily budget (a warning); stopped at 20 s,
    // then a one-second fade.
    let b = l.reserve(LightKind::Showing, "relit-1", 45.0, T0 + H, T0 + H + 30 * S).unwrap();
    l.commit(b, T0 + H + 20 * S).unwrap();
    let f = l.reserve(LightKind::Fade, "relit-1", 45.0, T0 + H + 20 * S, T0 + H + 21 * S).unwrap();
    l.commit(f, T0 + H + 21 * S).unwrap();
    l.record_showing(T0 + H, T0 + H + 21 * S, &["restored-1".into(), "relit-1".into()], "stop").unwrap();
    // Idle light reserved, then a crash: the reservation is never committed.
    l.reserve(LightKind::Idle, "black", 0.5, T0 + 2 * H, T0 + 2 * H + 5 * S).unwrap();
    // The second run, after the crash.
    l.record_run(T0 + 2 * H + 60 * S, 9_000, T0 + 2 * H + 60 * S).unwrap();
    l.log_event(T0 + 2 * H + 60 * S, "fault", "output: projector 2 lost (fixture)").unwrap();
    let id = l.ledger_id().unwrap();
    drop(l);
    let wal = dir.path().join(format!("{LEDGER_FILE}-wal"));
    assert!(
        !wal.exists() || wal.metadata().unwrap().len() == 0,
        "the WAL was not checkpointed into the file"
    );
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::copy(&tmp, &path).unwrap();
    println!("LEDGER_ID {id}");
    println!("{} bytes", std::fs::metadata(&path).unwrap().len());
}

/// A copy of the fixture in a fresh directory (opening a ledger writes beside it).
fn copy() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(LEDGER_FILE);
    std::fs::copy(fixture(), &p).unwrap();
    (dir, p)
}

#[test]
fn ledger_schema_2_fixture_reads_back_as_recorded() {
    let bytes = std::fs::read(fixture()).unwrap();
    assert_eq!(&bytes[..16], b"SQLite format 3\0");
    // SQLite's header: user_version (big-endian) at 60 is the ledger's schema version.
    assert_eq!(u32::from_be_bytes(bytes[60..64].try_into().unwrap()), FIXTURE_SCHEMA);

    let (_dir, p) = copy();
    let l = Ledger::open(&p, LocalZone::utc()).unwrap();
    l.integrity_check().unwrap();
    assert_eq!(l.ledger_id().unwrap(), LEDGER_ID);
    assert_eq!(l.active_bundle().unwrap(), Some(active()));
    assert_eq!(l.accepted_version(OBJECT).unwrap(), Some(3));
    assert_eq!(l.pinned_object().unwrap().as_deref(), Some(OBJECT));
    assert_eq!(l.runs().unwrap(), [(T0, 5_000), (T0 + 2 * H + 60 * S, 9_000)]);
    assert_eq!(l.high_water_ms().unwrap(), T0 + 2 * H + 60 * S);
    assert_eq!(l.last_showing_end(), Some(T0 + H + 21 * S));

    let rows: Vec<_> = l
        .exposure_rows(OBJECT)
        .unwrap()
        .into_iter()
        .map(|r| (r.kind, r.label, r.lux, r.start_ms - T0, r.end_ms - T0, r.committed))
        .collect();
    let row = |k: &str, l: &str, lux, a, b, c| (k.to_string(), l.to_string(), lux, a, b, c);
    assert_eq!(
        rows,
        [
            row("showing", "restored-1", 40.0, 60 * S, 90 * S, true),
            row("showing", "relit-1", 45.0, H, H + 20 * S, true),
            row("fade", "relit-1", 45.0, H + 20 * S, H + 21 * S, true),
            row("idle", "black", 0.5, 2 * H, 2 * H + 5 * S, false),
        ]
    );
    assert_eq!(l.history(T0, T0 + 3 * H).unwrap().len(), 4);

    let used = lxh(40.0, 30 * S) + lxh(45.0, 21 * S) + lxh(0.5, 5 * S);
    let s = l.status(T0 + 3 * H).unwrap();
    assert_eq!(s.schema_version, SCHEMA_VERSION);
    assert_eq!(s.day, "2026-06-01");
    assert!((s.day_used_lux_hours - used).abs() < 1e-9, "{} vs {used}", s.day_used_lux_hours);
    assert!((s.year_used_lux_hours - used).abs() < 1e-9);
    assert!((s.total_lux_hours - used).abs() < 1e-9);
    assert!((s.day_left_lux_hours.unwrap() - (0.8 - used)).abs() < 1e-9);
    assert_eq!(s.open_reservations, 1);
    let shown: Vec<_> = s
        .last_showings
        .iter()
        .map(|r| (r.started_ms - T0, r.ended_ms - T0, r.scenes.as_str(), r.ended_by.as_str()))
        .collect();
    assert_eq!(
        shown,
        [(H, H + 21 * S, "restored-1,relit-1", "stop"), (60 * S, 90 * S, "restored-1", "timer")]
    );
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    let w = &s.warnings[0];
    assert_eq!((w.budget.as_str(), w.period.as_str(), w.threshold), ("daily", "2026-06-01", 0.75));
    assert_eq!((w.at_ms, w.budget_lux_hours), (T0 + H + 30 * S, 0.8));
    assert!((w.used - (lxh(40.0, 30 * S) + lxh(45.0, 30 * S))).abs() < 1e-9, "{w:?}");
    let events: Vec<_> = s.last_events.iter().map(|e| (e.at_ms - T0, e.kind.as_str())).collect();
    assert_eq!(events, [(2 * H + 60 * S, "fault"), (0, "load"), (0, "object-pin")]);
    assert_eq!(s.last_events[1].detail, format!("{OBJECT} version 3 ({BUNDLE_PATH})"));
}

#[test]
fn ledger_schema_2_fixture_keeps_working() {
    let (dir, p) = copy();
    // The stage's own way in: the ledger is adopted and the guard names it.
    let mut l = Ledger::open_stage(dir.path(), LocalZone::utc()).unwrap();
    assert_eq!(std::fs::read_to_string(dir.path().join(GUARD_FILE)).unwrap().trim(), LEDGER_ID);
    // Anti-rollback still holds.
    assert!(matches!(l.check_version(OBJECT, 2, "b2"), Err(LedgerError::Rollback { accepted: 3, .. })));
    l.check_version(OBJECT, 3, HASH).unwrap();
    // The daily budget of the recorded day has no room for another 30 s at 45 lx.
    let before = l.status(T0 + 3 * H).unwrap().total_lux_hours;
    assert!(l.reserve(LightKind::Showing, "relit-1", 45.0, T0 + 3 * H, T0 + 3 * H + 30 * S).is_err());
    // The next day: a new showing is recorded.
    let d1 = T0 + 24 * H;
    let a = l.reserve(LightKind::Showing, "restored-1", 40.0, d1, d1 + 5 * S).unwrap();
    l.extend(a, d1 + 35 * S).unwrap();
    l.commit(a, d1 + 30 * S).unwrap();
    l.record_showing(d1, d1 + 30 * S, &["restored-1".into()], "timer").unwrap();
    l.record_run(d1 + H, 1_000, d1 + H).unwrap();
    drop(l);

    let l = Ledger::open(&p, LocalZone::utc()).unwrap();
    l.integrity_check().unwrap();
    let s = l.status(d1 + H).unwrap();
    assert_eq!(s.day, "2026-06-02");
    assert!((s.day_used_lux_hours - lxh(40.0, 30 * S)).abs() < 1e-9);
    assert!((s.total_lux_hours - before - lxh(40.0, 30 * S)).abs() < 1e-9);
    assert_eq!(s.last_showings.len(), 3);
    assert_eq!(s.last_showings[0].started_ms, d1);
    assert_eq!(s.open_reservations, 1, "the crash's reservation stays counted in full");
    assert_eq!(l.runs().unwrap().len(), 3);
    drop(l);
    // Read-only, as `restage-appliance status` opens it beside a running appliance.
    let ro = Ledger::open_read_only(&p, LocalZone::utc()).unwrap();
    assert_eq!(ro.status(d1 + H).unwrap().last_showings.len(), 3);
}
