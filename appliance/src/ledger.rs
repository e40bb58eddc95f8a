//! The lux-hour ledger: an SQLite database (WAL, synchronous=FULL) in the state directory.
//!
//! Exposure is reserve-then-commit: a row `[start, end]` at a lux level is written before the
//! light goes on, extended before it runs out, and shrunk to the actual end once the light is
//! off. After a crash the reservation stands, so exposure is over-counted, never under-counted.
//! It also holds the highest accepted bundle version per object (anti-rollback), the object
//! this stage is pinned to, the showings, budget warnings, notable events and one row per run
//! (its clock anchor), for `status` and audits.
//!
//! The invariant (ARCHITECTURE.md, "Light accounting"): for every interval in which any
//! projector emits light, the ledger holds at least that interval's lux·h. A commit records
//! the actual end, even past the reservation (a stalled process); times are ledger time
//! (`clock`), which no wall-clock step moves; a missing or emptied ledger on a stage that has
//! played is refused until an operator acknowledges it (`open_stage`, `reset_acknowledged`).

use std::path::{Path, PathBuf};

use rusqlite::{Connection, OpenFlags, OptionalExtension, params};
use serde::Serialize;
use thiserror::Error;

use crate::player::{Accountant, LeaseId, LightKind, Refusal};
use crate::zone::LocalZone;

/// Schema versions, in order; `MIGRATIONS[i]` takes `user_version` i to i+1.
const MIGRATIONS: &[&str] = &[
    // 1: exposure, accepted versions, active bundle, showings, warnings, events.
    "CREATE TABLE exposure (
        id INTEGER PRIMARY KEY,
        object TEXT NOT NULL,
        kind TEXT NOT NULL,
        label TEXT NOT NULL,
        lux REAL NOT NULL CHECK (lux >= 0),
        start_ms INTEGER NOT NULL,
        end_ms INTEGER NOT NULL CHECK (end_ms >= start_ms),
        committed INTEGER NOT NULL DEFAULT 0 CHECK (committed IN (0, 1))
    );
    CREATE INDEX exposure_end ON exposure (object, end_ms);
    CREATE TABLE accepted_version (
        object TEXT PRIMARY KEY,
        version INTEGER NOT NULL,
        bundle_hash TEXT NOT NULL,
        accepted_ms INTEGER NOT NULL
    );
    CREATE TABLE active_bundle (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        object TEXT NOT NULL,
        version INTEGER NOT NULL,
        bundle_hash TEXT NOT NULL,
        path TEXT NOT NULL,
        loaded_ms INTEGER NOT NULL,
        daily_lux_hours REAL NOT NULL,
        annual_lux_hours REAL NOT NULL,
        warn_at TEXT NOT NULL
    );
    CREATE TABLE showing (
        id INTEGER PRIMARY KEY,
        object TEXT NOT NULL,
        started_ms INTEGER NOT NULL,
        ended_ms INTEGER NOT NULL,
        scenes TEXT NOT NULL,
        ended_by TEXT NOT NULL
    );
    CREATE TABLE warning (
        id INTEGER PRIMARY KEY,
        at_ms INTEGER NOT NULL,
        object TEXT NOT NULL,
        budget TEXT NOT NULL,
        period TEXT NOT NULL,
        threshold REAL NOT NULL,
        used REAL NOT NULL,
        budget_lux_hours REAL NOT NULL,
        UNIQUE (object, budget, period, threshold)
    );
    CREATE TABLE event (
        id INTEGER PRIMARY KEY,
        at_ms INTEGER NOT NULL,
        kind TEXT NOT NULL,
        detail TEXT NOT NULL
    );",
    // 2: key/value facts (ledger id, pinned object) and one row per run (its clock anchor).
    "CREATE TABLE meta (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL
    );
    CREATE TABLE run (
        id INTEGER PRIMARY KEY,
        ledger_ms INTEGER NOT NULL,
        boot_ms INTEGER NOT NULL,
        wall_ms INTEGER NOT NULL,
        pid INTEGER NOT NULL
    );",
];

/// The schema version this program writes.
pub const SCHEMA_VERSION: u32 = MIGRATIONS.len() as u32;

const MS_PER_DAY: i64 = 86_400_000;
const MS_PER_HOUR: f64 = 3_600_000.0;
/// The annual budget is over any 365 days (rolling), so no new-year reset lets light surge.
const YEAR_MS: i64 = 365 * MS_PER_DAY;
/// How long a write waits for another process's lock (tools; the player sets its own, short).
const TOOL_BUSY_MS: u64 = 5_000;
/// The file beside the ledger naming the ledger id this stage writes to.
pub const GUARD_FILE: &str = "ledger.id";
/// The ledger file in the state directory.
pub const LEDGER_FILE: &str = "ledger.sqlite";
/// The active bundle in the state directory (where `install` puts it).
pub const ACTIVE_BUNDLE_FILE: &str = "active.bundle";

#[derive(Debug, Error)]
pub enum LedgerError {
    #[error("ledger {path}: cannot open: {source}")]
    Open { path: PathBuf, source: rusqlite::Error },
    #[error("ledger {path}: {source}")]
    Sql { path: PathBuf, source: rusqlite::Error },
    #[error("ledger {path}: schema version {found} is newer than this program's (1..={supported})")]
    SchemaTooNew { path: PathBuf, found: u32, supported: u32 },
    #[error("ledger {path}: integrity check failed: {detail}")]
    Corrupt { path: PathBuf, detail: String },
    #[error("bundle for object {object}: version {offered} is older than the accepted version {accepted}")]
    Rollback { object: String, offered: u64, accepted: u64 },
    #[error(
        "bundle for object {object}: version {version} was accepted with a different content ({accepted_hash})"
    )]
    SameVersionDifferentContent { object: String, version: u64, accepted_hash: String },
    #[error(
        "ledger {path} is missing or empty, but this stage has played before ({evidence}): its light \
         history and anti-rollback record would be lost, so no light until an operator runs \
         `restage-appliance ledger-reset --config FILE --reason \"...\"`"
    )]
    Missing { path: PathBuf, evidence: String },
    #[error(
        "ledger {path} has id {found}, but {guard} names {expected}: the ledger was replaced; \
         no light until an operator runs `restage-appliance ledger-reset --config FILE --reason \"...\"`"
    )]
    Replaced { path: PathBuf, guard: PathBuf, expected: String, found: String },
    #[error("ledger guard {path}: {source}")]
    Guard { path: PathBuf, source: std::io::Error },
}

/// The budgets the ledger enforces (from the active bundle's policy).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Budgets {
    pub daily_lux_hours: f64,
    pub annual_lux_hours: f64,
    pub warn_at: Vec<f64>,
}

/// The active bundle as recorded.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ActiveBundle {
    pub object: String,
    pub version: u64,
    pub bundle_hash: String,
    pub path: String,
    pub loaded_ms: i64,
    pub budgets: Budgets,
}

#[derive(Clone, Debug, Serialize)]
pub struct ShowingRecord {
    pub started_ms: i64,
    pub ended_ms: i64,
    pub scenes: String,
    pub ended_by: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct WarningRecord {
    pub at_ms: i64,
    pub budget: String,
    pub period: String,
    pub threshold: f64,
    pub used: f64,
    pub budget_lux_hours: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct EventRecord {
    pub at_ms: i64,
    pub kind: String,
    pub detail: String,
}

/// One reservation (committed or standing).
#[derive(Clone, Debug, Serialize)]
pub struct ExposureRow {
    pub kind: String,
    pub label: String,
    pub lux: f64,
    pub start_ms: i64,
    pub end_ms: i64,
    pub committed: bool,
}

/// What `status` prints.
#[derive(Clone, Debug, Serialize)]
pub struct LedgerStatus {
    pub schema_version: u32,
    pub active: Option<ActiveBundle>,
    /// Local calendar day (YYYY-MM-DD) the daily figures are for.
    pub day: String,
    /// The zone local days are kept in (IANA name, or "UTC+01" for a fixed offset).
    pub time_zone: String,
    /// The status's time, local, e.g. "2026-03-29 10:15 CEST".
    pub now_local: String,
    pub day_used_lux_hours: f64,
    pub day_left_lux_hours: Option<f64>,
    pub year_used_lux_hours: f64,
    pub year_left_lux_hours: Option<f64>,
    pub total_lux_hours: f64,
    /// Reservations never committed (a crash or power cut; counted in full).
    pub open_reservations: u64,
    pub warnings: Vec<WarningRecord>,
    pub last_showings: Vec<ShowingRecord>,
    pub last_events: Vec<EventRecord>,
}

/// The ledger.
#[derive(Debug)]
pub struct Ledger {
    conn: Connection,
    path: PathBuf,
    /// Local days (the daily budget) begin at this zone's midnight.
    zone: LocalZone,
    /// Object and budgets in force (set when a bundle is activated); no light without them.
    active: Option<(String, Budgets)>,
}

impl Ledger {
    /// Opens (creating if needed) the ledger at `path` and brings its schema up to date.
    /// Tools and tests; the stage opens its ledger with [`Ledger::open_stage`].
    pub fn open(path: &Path, zone: LocalZone) -> Result<Ledger, LedgerError> {
        let conn =
            Connection::open(path).map_err(|source| LedgerError::Open { path: path.into(), source })?;
        Self::setup(conn, path, zone, true)
    }

    /// Opens the stage's ledger in `state_dir`, refusing to start a fresh one where the stage
    /// has kept one before: the guard file (`ledger.id`, written durably when the ledger was
    /// first opened here) names the ledger, so a ledger deleted, truncated or swapped for
    /// another (a restored backup) is refused rather than silently replaced. A first start
    /// creates both. (Deleting the guard too is an operator's act outside the appliance.)
    pub fn open_stage(state_dir: &Path, zone: LocalZone) -> Result<Ledger, LedgerError> {
        let path = state_dir.join(LEDGER_FILE);
        let guard = state_dir.join(GUARD_FILE);
        let has_ledger = std::fs::metadata(&path).is_ok_and(|m| m.len() > 0);
        let guard_id = read_guard(&guard)?;
        if let (false, Some(id)) = (has_ledger, &guard_id) {
            return Err(LedgerError::Missing {
                path,
                evidence: format!("{} names ledger {id}", guard.display()),
            });
        }
        let ledger = Self::open(&path, zone)?;
        let id = ledger.ledger_id()?;
        match guard_id {
            Some(expected) if expected != id => {
                Err(LedgerError::Replaced { path, guard, expected, found: id })
            }
            Some(_) => Ok(ledger),
            None => {
                write_guard(&guard, &id)?;
                Ok(ledger)
            }
        }
    }

    /// An operator's acknowledgement that the stage's ledger is lost or replaced: whatever
    /// ledger file is there is kept aside (renamed, never deleted), a fresh ledger is created
    /// with the acknowledgement as its first event, and the guard names it. Returns the
    /// ledger and where the old file went.
    pub fn reset_acknowledged(
        state_dir: &Path,
        zone: LocalZone,
        reason: &str,
        now_ms: i64,
    ) -> Result<(Ledger, Vec<PathBuf>), LedgerError> {
        let path = state_dir.join(LEDGER_FILE);
        let guard = state_dir.join(GUARD_FILE);
        let old_id = read_guard(&guard)?;
        let mut kept = Vec::new();
        for suffix in ["", "-wal", "-shm"] {
            let from = state_dir.join(format!("{LEDGER_FILE}{suffix}"));
            if from.exists() {
                let to = state_dir.join(format!("{LEDGER_FILE}.replaced-{now_ms}{suffix}"));
                std::fs::rename(&from, &to).map_err(|source| LedgerError::Guard { path: from, source })?;
                kept.push(to);
            }
        }
        let mut ledger = Self::open(&path, zone)?;
        let id = ledger.ledger_id()?;
        let detail = format!(
            "ledger reset acknowledged by an operator: {reason}; previous ledger {}; old files kept: {}",
            old_id.as_deref().unwrap_or("unknown"),
            if kept.is_empty() {
                "none".to_string()
            } else {
                kept.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            }
        );
        ledger.log_event(now_ms, "ledger-reset", &detail)?;
        write_guard(&guard, &id)?;
        Ok((ledger, kept))
    }

    /// Waits at most `ms` for another process's write lock (the player keeps this short: a
    /// lock holder must never keep light on unpaid or hold up a blank).
    pub fn set_busy_timeout(&self, ms: u64) -> Result<(), LedgerError> {
        self.conn.busy_timeout(std::time::Duration::from_millis(ms)).map_err(self.sql())
    }

    /// This ledger's id (made when it was created).
    pub fn ledger_id(&self) -> Result<String, LedgerError> {
        if let Some(id) = self.meta("ledger_id")? {
            return Ok(id);
        }
        let seed = format!(
            "{:?} {} {} {}",
            std::time::SystemTime::now(),
            std::process::id(),
            crate::clock::boot_us(),
            self.path.display()
        );
        let id = blake3::hash(seed.as_bytes()).to_hex()[..32].to_string();
        self.conn
            .execute("INSERT OR IGNORE INTO meta (key, value) VALUES ('ledger_id', ?1)", [&id])
            .map_err(self.sql())?;
        self.meta("ledger_id")?.ok_or_else(|| LedgerError::Corrupt {
            path: self.path.clone(),
            detail: "ledger id not stored".into(),
        })
    }

    fn meta(&self, key: &str) -> Result<Option<String>, LedgerError> {
        self.conn
            .query_row("SELECT value FROM meta WHERE key = ?1", [key], |r| r.get(0))
            .optional()
            .map_err(self.sql())
    }

    /// The object this stage's budgets are pinned to (the first accepted, or the configured).
    pub fn pinned_object(&self) -> Result<Option<String>, LedgerError> {
        self.meta("pinned_object")
    }

    /// Pins the stage to `object` (recorded as an event when it changes).
    pub fn pin_object(&mut self, object: &str, now_ms: i64, why: &str) -> Result<(), LedgerError> {
        let old = self.pinned_object()?;
        if old.as_deref() == Some(object) {
            return Ok(());
        }
        self.conn
            .execute(
                "INSERT INTO meta (key, value) VALUES ('pinned_object', ?1)
                 ON CONFLICT (key) DO UPDATE SET value = ?1",
                [object],
            )
            .map_err(self.sql())?;
        let detail = format!("object pinned to {object} (was {}): {why}", old.as_deref().unwrap_or("none"));
        self.log_event(now_ms, "object-pin", &detail)
    }

    /// The latest ledger time this ledger has seen (runs, reservations, events, showings):
    /// ledger time never restarts below it.
    pub fn high_water_ms(&self) -> Result<i64, LedgerError> {
        self.conn
            .query_row(
                "SELECT MAX(COALESCE((SELECT MAX(ledger_ms) FROM run), 0),
                            COALESCE((SELECT MAX(start_ms) FROM exposure), 0),
                            COALESCE((SELECT MAX(at_ms) FROM event), 0),
                            COALESCE((SELECT MAX(ended_ms) FROM showing), 0))",
                [],
                |r| r.get(0),
            )
            .map_err(self.sql())
    }

    /// Records a run's start and its clock anchor (ledger time `ledger_ms` was boot-clock
    /// `boot_ms`; the wall clock read `wall_ms`).
    pub fn record_run(&mut self, ledger_ms: i64, boot_ms: u64, wall_ms: i64) -> Result<(), LedgerError> {
        self.conn
            .execute(
                "INSERT INTO run (ledger_ms, boot_ms, wall_ms, pid) VALUES (?1, ?2, ?3, ?4)",
                params![ledger_ms, boot_ms as i64, wall_ms, std::process::id()],
            )
            .map_err(self.sql())?;
        Ok(())
    }

    /// Every run's clock anchor `(ledger_ms, boot_ms)`, oldest first (audits, tests).
    pub fn runs(&self) -> Result<Vec<(i64, u64)>, LedgerError> {
        self.conn
            .prepare("SELECT ledger_ms, boot_ms FROM run ORDER BY id")
            .and_then(|mut s| s.query_map([], |r| Ok((r.get(0)?, r.get::<_, i64>(1)? as u64)))?.collect())
            .map_err(self.sql())
    }

    /// Opens an existing ledger read-only (for `status` while the appliance runs).
    pub fn open_read_only(path: &Path, zone: LocalZone) -> Result<Ledger, LedgerError> {
        let conn = Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_ONLY)
            .map_err(|source| LedgerError::Open { path: path.into(), source })?;
        Self::setup(conn, path, zone, false)
    }

    /// A ledger in memory (tests).
    pub fn open_in_memory(zone: LocalZone) -> Result<Ledger, LedgerError> {
        let path = Path::new(":memory:");
        let conn =
            Connection::open_in_memory().map_err(|source| LedgerError::Open { path: path.into(), source })?;
        Self::setup(conn, path, zone, true)
    }

    fn setup(conn: Connection, path: &Path, zone: LocalZone, write: bool) -> Result<Ledger, LedgerError> {
        let sql = |source| LedgerError::Sql { path: path.into(), source };
        conn.busy_timeout(std::time::Duration::from_millis(TOOL_BUSY_MS)).map_err(sql)?;
        if write {
            // WAL: readers (status) never block the player; FULL: a committed reservation
            // survives a power cut.
            conn.pragma_update(None, "journal_mode", "WAL").map_err(sql)?;
            conn.pragma_update(None, "synchronous", synchronous()).map_err(sql)?;
        }
        let mut ledger = Ledger { conn, path: path.into(), zone, active: None };
        ledger.migrate(write)?;
        if let Some(a) = ledger.active_bundle()? {
            ledger.active = Some((a.object, a.budgets));
        }
        Ok(ledger)
    }

    fn sql(&self) -> impl Fn(rusqlite::Error) -> LedgerError + '_ {
        |source| LedgerError::Sql { path: self.path.clone(), source }
    }

    fn migrate(&mut self, write: bool) -> Result<(), LedgerError> {
        let found: u32 =
            self.conn.pragma_query_value(None, "user_version", |r| r.get(0)).map_err(self.sql())?;
        if found > SCHEMA_VERSION {
            return Err(LedgerError::SchemaTooNew {
                path: self.path.clone(),
                found,
                supported: SCHEMA_VERSION,
            });
        }
        if !write {
            return Ok(());
        }
        for (i, step) in MIGRATIONS.iter().enumerate().skip(found as usize) {
            let path = self.path.clone();
            let sql = |source| LedgerError::Sql { path: path.clone(), source };
            let tx = self.conn.transaction().map_err(sql)?;
            tx.execute_batch(step).map_err(sql)?;
            tx.pragma_update(None, "user_version", (i + 1) as u32).map_err(sql)?;
            tx.commit().map_err(sql)?;
            tracing::info!(version = i + 1, "ledger schema migrated");
        }
        Ok(())
    }

    /// SQLite's own consistency check.
    pub fn integrity_check(&self) -> Result<(), LedgerError> {
        let rows: Vec<String> = self
            .conn
            .prepare("PRAGMA integrity_check")
            .and_then(|mut s| s.query_map([], |r| r.get(0))?.collect())
            .map_err(self.sql())?;
        if rows == ["ok"] {
            Ok(())
        } else {
            Err(LedgerError::Corrupt { path: self.path.clone(), detail: rows.join("; ") })
        }
    }

    /// The highest accepted version for `object`, if any.
    pub fn accepted_version(&self, object: &str) -> Result<Option<u64>, LedgerError> {
        self.conn
            .query_row("SELECT version FROM accepted_version WHERE object = ?1", [object], |r| {
                r.get::<_, i64>(0)
            })
            .optional()
            .map(|v| v.map(|v| v as u64))
            .map_err(self.sql())
    }

    /// Refuses a bundle version below the highest accepted one for its object (or the same
    /// version with different content).
    pub fn check_version(&self, object: &str, version: u64, bundle_hash: &str) -> Result<(), LedgerError> {
        let row: Option<(i64, String)> = self
            .conn
            .query_row("SELECT version, bundle_hash FROM accepted_version WHERE object = ?1", [object], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })
            .optional()
            .map_err(self.sql())?;
        match row {
            Some((accepted, _)) if (accepted as u64) > version => Err(LedgerError::Rollback {
                object: object.into(),
                offered: version,
                accepted: accepted as u64,
            }),
            Some((accepted, hash)) if accepted as u64 == version && hash != bundle_hash => {
                Err(LedgerError::SameVersionDifferentContent {
                    object: object.into(),
                    version,
                    accepted_hash: hash,
                })
            }
            _ => Ok(()),
        }
    }

    /// Records `version` as accepted for `object` (only after everything verified).
    pub fn accept_version(
        &mut self,
        object: &str,
        version: u64,
        bundle_hash: &str,
        now_ms: i64,
    ) -> Result<(), LedgerError> {
        self.check_version(object, version, bundle_hash)?;
        self.conn
            .execute(
                "INSERT INTO accepted_version (object, version, bundle_hash, accepted_ms) VALUES (?1, ?2, ?3, ?4)
                 ON CONFLICT (object) DO UPDATE SET version = ?2, bundle_hash = ?3, accepted_ms = ?4",
                params![object, version as i64, bundle_hash, now_ms],
            )
            .map_err(self.sql())?;
        Ok(())
    }

    /// Makes `bundle` the one whose budgets are enforced (and reported by `status`).
    pub fn set_active(&mut self, bundle: &ActiveBundle) -> Result<(), LedgerError> {
        let warn = serde_json::to_string(&bundle.budgets.warn_at).unwrap_or_else(|_| "[]".into());
        self.conn
            .execute(
                "INSERT OR REPLACE INTO active_bundle
                 (id, object, version, bundle_hash, path, loaded_ms, daily_lux_hours, annual_lux_hours, warn_at)
                 VALUES (1, ?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![
                    bundle.object,
                    bundle.version as i64,
                    bundle.bundle_hash,
                    bundle.path,
                    bundle.loaded_ms,
                    bundle.budgets.daily_lux_hours,
                    bundle.budgets.annual_lux_hours,
                    warn
                ],
            )
            .map_err(self.sql())?;
        self.active = Some((bundle.object.clone(), bundle.budgets.clone()));
        Ok(())
    }

    pub fn active_bundle(&self) -> Result<Option<ActiveBundle>, LedgerError> {
        self.conn
            .query_row(
                "SELECT object, version, bundle_hash, path, loaded_ms, daily_lux_hours, annual_lux_hours, warn_at
                 FROM active_bundle WHERE id = 1",
                [],
                |r| {
                    let warn: String = r.get(7)?;
                    Ok(ActiveBundle {
                        object: r.get(0)?,
                        version: r.get::<_, i64>(1)? as u64,
                        bundle_hash: r.get(2)?,
                        path: r.get(3)?,
                        loaded_ms: r.get(4)?,
                        budgets: Budgets {
                            daily_lux_hours: r.get(5)?,
                            annual_lux_hours: r.get(6)?,
                            warn_at: serde_json::from_str(&warn).unwrap_or_default(),
                        },
                    })
                },
            )
            .optional()
            .map_err(self.sql())
    }

    /// Records a notable event (load, refusal, fault) for `status`.
    pub fn log_event(&mut self, at_ms: i64, kind: &str, detail: &str) -> Result<(), LedgerError> {
        self.conn
            .execute(
                "INSERT INTO event (at_ms, kind, detail) VALUES (?1, ?2, ?3)",
                params![at_ms, kind, detail],
            )
            .map_err(self.sql())?;
        Ok(())
    }

    /// Lux-hours charged to `object` within `[from_ms, to_ms)`, reservations counted in full.
    pub fn used(&self, object: &str, from_ms: i64, to_ms: i64) -> Result<f64, LedgerError> {
        let lux_ms: f64 = self
            .conn
            .query_row(
                "SELECT COALESCE(SUM(lux * (MIN(end_ms, ?3) - MAX(start_ms, ?2))), 0.0) FROM exposure
                 WHERE object = ?1 AND end_ms > ?2 AND start_ms < ?3",
                params![object, from_ms, to_ms],
                |r| r.get(0),
            )
            .map_err(self.sql())?;
        Ok(lux_ms / MS_PER_HOUR)
    }

    /// Every exposure row of `object`, in order: for audits and tests.
    pub fn exposure_rows(&self, object: &str) -> Result<Vec<ExposureRow>, LedgerError> {
        let rows = self.exposure_where("object = ?1 ORDER BY id", params![object])?;
        Ok(rows.into_iter().map(|(_, r)| r).collect())
    }

    /// Every exposure row of every object overlapping `[from_ms, to_ms)`, in order of start:
    /// the light history `ledger export` writes.
    pub fn history(&self, from_ms: i64, to_ms: i64) -> Result<Vec<(String, ExposureRow)>, LedgerError> {
        self.exposure_where("end_ms > ?1 AND start_ms < ?2 ORDER BY start_ms, id", params![from_ms, to_ms])
    }

    /// Exposure rows (with their object) selected by an SQL condition of this module's own.
    fn exposure_where(
        &self,
        condition: &str,
        args: &[&dyn rusqlite::ToSql],
    ) -> Result<Vec<(String, ExposureRow)>, LedgerError> {
        let sql = format!(
            "SELECT object, kind, label, lux, start_ms, end_ms, committed FROM exposure WHERE {condition}"
        );
        self.conn
            .prepare(&sql)
            .and_then(|mut s| {
                s.query_map(args, |r| {
                    Ok((
                        r.get(0)?,
                        ExposureRow {
                            kind: r.get(1)?,
                            label: r.get(2)?,
                            lux: r.get(3)?,
                            start_ms: r.get(4)?,
                            end_ms: r.get(5)?,
                            committed: r.get::<_, i64>(6)? == 1,
                        },
                    ))
                })?
                .collect()
            })
            .map_err(self.sql())
    }

    /// Every lux-hour ever charged to `object`.
    pub fn total(&self, object: &str) -> Result<f64, LedgerError> {
        self.used(object, i64::MIN / 2, i64::MAX / 2)
    }

    /// Start (unix ms) of the local day containing `t_ms`.
    pub fn day_start(&self, t_ms: i64) -> i64 {
        self.zone.day_start(t_ms)
    }

    /// The zone local days are kept in.
    pub fn zone(&self) -> &LocalZone {
        &self.zone
    }

    /// Lux-hours charged to `object` on the local day containing `t_ms` (23 or 25 hours
    /// long on a daylight-saving change day).
    fn day_used(&self, object: &str, t_ms: i64) -> Result<f64, LedgerError> {
        let (start, end) = self.zone.day_bounds(t_ms);
        self.used(object, start, end)
    }

    fn day_name(&self, t_ms: i64) -> String {
        self.zone.local_date(t_ms)
    }

    /// Would `extra_lux_ms` more, charged at `[from, until]`, fit both budgets?
    fn check_budgets(&self, from: i64, until: i64, extra_lux_ms: f64) -> Result<(), Refusal> {
        let Some((object, b)) = &self.active else {
            return Err(Refusal::Exhausted("no active bundle: no budget to charge".into()));
        };
        let fail = |e: LedgerError| Refusal::Failed(e.to_string());
        let extra = extra_lux_ms / MS_PER_HOUR;
        let day_used = self.day_used(object, from).map_err(fail)?;
        if day_used + extra > b.daily_lux_hours {
            return Err(Refusal::Exhausted(format!(
                "daily budget: {day_used:.4} of {:.4} lx·h used on {}, {extra:.4} more asked",
                b.daily_lux_hours,
                self.day_name(from)
            )));
        }
        let year_used = self.used(object, until - YEAR_MS, until).map_err(fail)?;
        if year_used + extra > b.annual_lux_hours {
            return Err(Refusal::Exhausted(format!(
                "annual budget: {year_used:.4} of {:.4} lx·h used in the last 365 days, {extra:.4} more asked",
                b.annual_lux_hours
            )));
        }
        Ok(())
    }

    /// Logs and records a warning for each threshold crossed (once per day, or per week for
    /// the annual budget).
    fn warn_if_needed(&mut self, at: i64) -> Result<(), LedgerError> {
        let Some((object, b)) = self.active.clone() else { return Ok(()) };
        let day_used = self.day_used(&object, at)?;
        let year_used = self.used(&object, at - YEAR_MS, at)?;
        let week = at.div_euclid(7 * MS_PER_DAY);
        let checks = [
            ("daily", self.day_name(at), day_used, b.daily_lux_hours),
            ("annual", format!("week-{week}"), year_used, b.annual_lux_hours),
        ];
        for (budget, period, used, limit) in checks {
            for &threshold in &b.warn_at {
                if limit > 0.0 && used >= threshold * limit {
                    let n = self
                        .conn
                        .execute(
                            "INSERT OR IGNORE INTO warning (at_ms, object, budget, period, threshold, used, budget_lux_hours)
                             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                            params![at, object, budget, period, threshold, used, limit],
                        )
                        .map_err(self.sql())?;
                    if n > 0 {
                        tracing::warn!(
                            budget,
                            percent = threshold * 100.0,
                            used_lux_hours = used,
                            budget_lux_hours = limit,
                            "light budget warning"
                        );
                    }
                }
            }
        }
        Ok(())
    }

    /// The report `status` prints.
    pub fn status(&self, now_ms: i64) -> Result<LedgerStatus, LedgerError> {
        let active = self.active_bundle()?;
        let object = active.as_ref().map(|a| a.object.clone()).unwrap_or_default();
        let day_used = self.day_used(&object, now_ms)?;
        let year_used = self.used(&object, now_ms - YEAR_MS, now_ms)?;
        let total = self.total(&object)?;
        let open: i64 = self
            .conn
            .query_row("SELECT COUNT(*) FROM exposure WHERE committed = 0", [], |r| r.get(0))
            .map_err(self.sql())?;
        let warnings = self
            .conn
            .prepare(
                "SELECT at_ms, budget, period, threshold, used, budget_lux_hours FROM warning
                 WHERE at_ms >= ?1 ORDER BY at_ms DESC LIMIT 20",
            )
            .and_then(|mut s| {
                s.query_map([now_ms - 7 * MS_PER_DAY], |r| {
                    Ok(WarningRecord {
                        at_ms: r.get(0)?,
                        budget: r.get(1)?,
                        period: r.get(2)?,
                        threshold: r.get(3)?,
                        used: r.get(4)?,
                        budget_lux_hours: r.get(5)?,
                    })
                })?
                .collect()
            })
            .map_err(self.sql())?;
        let last_showings = self
            .conn
            .prepare("SELECT started_ms, ended_ms, scenes, ended_by FROM showing ORDER BY id DESC LIMIT 10")
            .and_then(|mut s| {
                s.query_map([], |r| {
                    Ok(ShowingRecord {
                        started_ms: r.get(0)?,
                        ended_ms: r.get(1)?,
                        scenes: r.get(2)?,
                        ended_by: r.get(3)?,
                    })
                })?
                .collect()
            })
            .map_err(self.sql())?;
        let last_events = self
            .conn
            .prepare("SELECT at_ms, kind, detail FROM event ORDER BY id DESC LIMIT 10")
            .and_then(|mut s| {
                s.query_map([], |r| Ok(EventRecord { at_ms: r.get(0)?, kind: r.get(1)?, detail: r.get(2)? }))?
                    .collect()
            })
            .map_err(self.sql())?;
        let budgets = active.as_ref().map(|a| a.budgets.clone());
        Ok(LedgerStatus {
            schema_version: SCHEMA_VERSION,
            day: self.day_name(now_ms),
            time_zone: self.zone.name(),
            now_local: self.zone.local_time(now_ms),
            day_used_lux_hours: day_used,
            day_left_lux_hours: budgets.as_ref().map(|b| (b.daily_lux_hours - day_used).max(0.0)),
            year_used_lux_hours: year_used,
            year_left_lux_hours: budgets.as_ref().map(|b| (b.annual_lux_hours - year_used).max(0.0)),
            total_lux_hours: total,
            open_reservations: open as u64,
            active,
            warnings,
            last_showings,
            last_events,
        })
    }
}

impl Accountant for Ledger {
    fn reserve(
        &mut self,
        kind: LightKind,
        label: &str,
        lux: f64,
        from: i64,
        until: i64,
    ) -> Result<LeaseId, Refusal> {
        if !(lux.is_finite() && lux >= 0.0) || until < from {
            return Err(Refusal::Failed(format!("bad reservation: {lux} lx over [{from}, {until}]")));
        }
        self.check_budgets(from, until, lux * (until - from) as f64)?;
        let object = self.active.as_ref().map(|(o, _)| o.clone()).unwrap_or_default();
        self.conn
            .execute(
                "INSERT INTO exposure (object, kind, label, lux, start_ms, end_ms) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![object, kind.as_str(), label, lux, from, until],
            )
            .map_err(|e| Refusal::Failed(format!("{}: {e}", self.path.display())))?;
        let id = self.conn.last_insert_rowid();
        if let Err(e) = self.warn_if_needed(until) {
            tracing::warn!(%e, "could not record a budget warning");
        }
        Ok(id)
    }

    fn extend(&mut self, lease: LeaseId, until: i64) -> Result<(), Refusal> {
        let (lux, end): (f64, i64) = self
            .conn
            .query_row("SELECT lux, end_ms FROM exposure WHERE id = ?1", [lease], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })
            .map_err(|e| Refusal::Failed(format!("{}: lease {lease}: {e}", self.path.display())))?;
        if until <= end {
            return Ok(());
        }
        self.check_budgets(end, until, lux * (until - end) as f64)?;
        self.conn
            .execute("UPDATE exposure SET end_ms = ?2 WHERE id = ?1 AND end_ms < ?2", params![lease, until])
            .map_err(|e| Refusal::Failed(format!("{}: {e}", self.path.display())))?;
        if let Err(e) = self.warn_if_needed(until) {
            tracing::warn!(%e, "could not record a budget warning");
        }
        Ok(())
    }

    fn commit(&mut self, lease: LeaseId, end: i64) -> Result<(), Refusal> {
        // The actual end, also past the reservation's: a process stalled while lit (stopped,
        // starved) kept the light on beyond what it had reserved, and that light was paid
        // for by nobody else. Never below the start.
        self.conn
            .execute(
                "UPDATE exposure SET end_ms = MAX(start_ms, ?2), committed = 1 WHERE id = ?1",
                params![lease, end],
            )
            .map_err(|e| Refusal::Failed(format!("{}: {e}", self.path.display())))?;
        Ok(())
    }

    fn record_showing(
        &mut self,
        started: i64,
        ended: i64,
        scenes: &[String],
        ended_by: &str,
    ) -> Result<(), Refusal> {
        let object = self.active.as_ref().map(|(o, _)| o.clone()).unwrap_or_default();
        self.conn
            .execute(
                "INSERT INTO showing (object, started_ms, ended_ms, scenes, ended_by) VALUES (?1, ?2, ?3, ?4, ?5)",
                params![object, started, ended, scenes.join(","), ended_by],
            )
            .map_err(|e| Refusal::Failed(format!("{}: {e}", self.path.display())))?;
        Ok(())
    }

    fn last_showing_end(&self) -> Option<i64> {
        let object = self.active.as_ref().map(|(o, _)| o.clone())?;
        self.conn
            .query_row(
                "SELECT MAX(end_ms) FROM exposure WHERE object = ?1 AND kind IN ('showing', 'fade')",
                [object],
                |r| r.get::<_, Option<i64>>(0),
            )
            .map_err(|e| tracing::warn!(%e, "could not read the last showing's end"))
            .ok()
            .flatten()
    }
}

/// The ledger id a guard file names, if there is one.
fn read_guard(guard: &Path) -> Result<Option<String>, LedgerError> {
    match std::fs::read_to_string(guard) {
        Ok(s) => Ok(Some(s.trim().to_string())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(LedgerError::Guard { path: guard.into(), source }),
    }
}

/// Writes the guard durably (temporary file, fsync, rename, fsync of the directory).
fn write_guard(guard: &Path, id: &str) -> Result<(), LedgerError> {
    let err = |source| LedgerError::Guard { path: guard.into(), source };
    let dir = guard.parent().unwrap_or(Path::new("."));
    let tmp = dir.join(format!(".{GUARD_FILE}.tmp"));
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        std::io::Write::write_all(&mut f, format!("{id}\n").as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, guard)?;
        std::fs::File::open(dir)?.sync_all()
    };
    write().map_err(err)
}

/// `FULL`; only a debug build started with `RESTAGE_TEST_ONLY_LEDGER_SYNCHRONOUS_OFF=1` uses
/// `OFF`, for tests/tests/power_qemu.rs to show that its power-cut check can fail.
fn synchronous() -> &'static str {
    if cfg!(debug_assertions)
        && std::env::var_os("RESTAGE_TEST_ONLY_LEDGER_SYNCHRONOUS_OFF").is_some_and(|v| v == "1")
    {
        tracing::warn!("RESTAGE_TEST_ONLY_LEDGER_SYNCHRONOUS_OFF=1 (test only): ledger synchronous=OFF");
        return "OFF";
    }
    "FULL"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn active(daily: f64, annual: f64) -> ActiveBundle {
        ActiveBundle {
            object: "vase".into(),
            version: 1,
            bundle_hash: "h".into(),
            path: "/b".into(),
            loaded_ms: 0,
            budgets: Budgets { daily_lux_hours: daily, annual_lux_hours: annual, warn_at: vec![0.75, 0.9] },
        }
    }

    const H: i64 = 3_600_000;

    #[test]
    fn reserve_counts_in_full_until_committed() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(1000.0, 10_000.0)).unwrap();
        let id = l.reserve(LightKind::Showing, "r1", 100.0, 0, H).unwrap();
        assert!((l.total("vase").unwrap() - 100.0).abs() < 1e-9);
        l.commit(id, H / 2).unwrap();
        assert!((l.total("vase").unwrap() - 50.0).abs() < 1e-9);
        // A commit never goes below the start.
        l.commit(id, -H).unwrap();
        assert!(l.total("vase").unwrap().abs() < 1e-9);
        l.extend(id, H).unwrap();
        assert!((l.total("vase").unwrap() - 100.0).abs() < 1e-9);
    }

    #[test]
    fn commit_records_the_actual_end_past_the_reservation() {
        // A process stalled while lit: its light outlasted the reservation. The commit pays
        // for all of it (a clamp to the reservation was how stalled light went unpaid).
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(1000.0, 10_000.0)).unwrap();
        let id = l.reserve(LightKind::Showing, "r1", 100.0, 0, H).unwrap();
        l.commit(id, 3 * H).unwrap();
        assert!((l.total("vase").unwrap() - 300.0).abs() < 1e-9, "{}", l.total("vase").unwrap());
        assert_eq!(l.last_showing_end(), Some(3 * H));
    }

    #[test]
    fn a_lost_or_replaced_ledger_is_refused_until_acknowledged() {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path();
        let ledger_path = state.join(LEDGER_FILE);
        // First start: ledger and guard created.
        let first_id = {
            let mut l = Ledger::open_stage(state, LocalZone::utc()).unwrap();
            l.set_active(&active(1000.0, 10_000.0)).unwrap();
            l.accept_version("vase", 7, "h7", 0).unwrap();
            l.ledger_id().unwrap()
        };
        assert_eq!(std::fs::read_to_string(state.join(GUARD_FILE)).unwrap().trim(), first_id);
        Ledger::open_stage(state, LocalZone::utc()).unwrap();
        // Truncated to nothing.
        let good = std::fs::read(&ledger_path).unwrap();
        std::fs::write(&ledger_path, b"").unwrap();
        let e = Ledger::open_stage(state, LocalZone::utc()).unwrap_err();
        assert!(matches!(e, LedgerError::Missing { .. }), "{e}");
        assert!(e.to_string().contains("ledger-reset"), "{e}");
        // Deleted.
        std::fs::remove_file(&ledger_path).unwrap();
        assert!(matches!(Ledger::open_stage(state, LocalZone::utc()), Err(LedgerError::Missing { .. })));
        assert!(!ledger_path.exists(), "a refused open creates nothing");
        // Another ledger put in its place (a backup from elsewhere).
        Ledger::open(&ledger_path, LocalZone::utc()).unwrap();
        let e = Ledger::open_stage(state, LocalZone::utc()).unwrap_err();
        assert!(matches!(e, LedgerError::Replaced { .. }), "{e}");
        // The operator acknowledges: the stray file is kept aside, the new ledger says why.
        std::fs::write(&ledger_path, &good).unwrap();
        let _ = std::fs::remove_file(state.join(format!("{LEDGER_FILE}-wal")));
        let (l, kept) =
            Ledger::reset_acknowledged(state, LocalZone::utc(), "disk swapped, ticket 12", 5).unwrap();
        assert_eq!(kept.len(), 1);
        assert!(kept[0].exists());
        assert_ne!(l.ledger_id().unwrap(), first_id);
        let ev = l.status(10).unwrap().last_events;
        assert!(ev.iter().any(|e| e.kind == "ledger-reset" && e.detail.contains("ticket 12")), "{ev:?}");
        drop(l);
        Ledger::open_stage(state, LocalZone::utc()).unwrap();
    }

    #[test]
    fn high_water_mark_follows_everything_recorded() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        assert_eq!(l.high_water_ms().unwrap(), 0);
        l.set_active(&active(1000.0, 10_000.0)).unwrap();
        l.record_run(1_000, 5, 999).unwrap();
        assert_eq!(l.high_water_ms().unwrap(), 1_000);
        l.reserve(LightKind::Idle, "black", 1.0, 2_000, 9_000).unwrap();
        assert_eq!(l.high_water_ms().unwrap(), 2_000);
        l.log_event(4_000, "x", "y").unwrap();
        assert_eq!(l.high_water_ms().unwrap(), 4_000);
        assert_eq!(l.runs().unwrap(), vec![(1_000, 5)]);
    }

    #[test]
    fn object_pin_is_recorded_with_an_event() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        assert_eq!(l.pinned_object().unwrap(), None);
        l.pin_object("vase", 1, "first").unwrap();
        l.pin_object("vase", 2, "again").unwrap();
        assert_eq!(l.pinned_object().unwrap().as_deref(), Some("vase"));
        l.pin_object("jar", 3, "configured").unwrap();
        assert_eq!(l.pinned_object().unwrap().as_deref(), Some("jar"));
        let ev = l.status(4).unwrap().last_events;
        assert_eq!(ev.iter().filter(|e| e.kind == "object-pin").count(), 2);
    }

    #[test]
    fn daily_budget_refuses_and_resets_next_day() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(150.0, 10_000.0)).unwrap();
        let a = l.reserve(LightKind::Showing, "r1", 100.0, 0, H).unwrap();
        l.commit(a, H).unwrap();
        let e = l.reserve(LightKind::Showing, "r1", 100.0, H, 2 * H).unwrap_err();
        assert!(matches!(&e, Refusal::Exhausted(m) if m.contains("daily")), "{e:?}");
        // 50 lx·h are left: half an hour at 100 lx fits.
        l.reserve(LightKind::Showing, "r1", 100.0, H, H + H / 2).unwrap();
        // The next day starts afresh.
        l.reserve(LightKind::Showing, "r1", 100.0, 24 * H, 25 * H).unwrap();
    }

    #[test]
    fn local_day_follows_utc_offset() {
        let l = Ledger::open_in_memory(LocalZone::fixed_offset_minutes(120).unwrap()).unwrap();
        // 23:00 UTC is 01:00 the next day at UTC+2.
        assert_eq!(l.day_start(23 * H), 22 * H);
        assert_eq!(l.day_name(23 * H), "1970-01-02");
    }

    /// Unix ms of an RFC 3339 instant.
    fn utc(s: &str) -> i64 {
        s.parse::<jiff::Timestamp>().unwrap().as_millisecond()
    }

    /// Spends 100 lx for an hour from `at` if the daily budget (150 lx·h) allows it.
    fn hour_at(l: &mut Ledger, at: &str) -> Result<(), Refusal> {
        let from = utc(at);
        let id = l.reserve(LightKind::Showing, "r1", 100.0, from, from + H)?;
        l.commit(id, from + H)
    }

    #[test]
    fn daily_budget_resets_at_local_midnight_across_spring_forward() {
        let mut l = Ledger::open_in_memory(LocalZone::named("Europe/Amsterdam").unwrap()).unwrap();
        l.set_active(&active(150.0, 1e9)).unwrap();
        // Saturday 2026-03-28, CET: 23:00-24:00 local, then the 29th begins at 23:00Z.
        hour_at(&mut l, "2026-03-28T22:00:00Z").unwrap();
        hour_at(&mut l, "2026-03-28T23:00:00Z").unwrap();
        // Sunday 2026-03-29 is 23 hours long (02:00 CET -> 03:00 CEST); 22:00 CEST is 20:00Z.
        let e = hour_at(&mut l, "2026-03-29T20:00:00Z").unwrap_err();
        assert!(matches!(&e, Refusal::Exhausted(m) if m.contains("2026-03-29")), "{e:?}");
        assert_eq!(l.status(utc("2026-03-29T20:00:00Z")).unwrap().day, "2026-03-29");
        // Local midnight is 22:00Z now (a fixed UTC+1 would still say 23:00 on the 29th).
        hour_at(&mut l, "2026-03-29T22:00:00Z").unwrap();
        let s = l.status(utc("2026-03-29T22:30:00Z")).unwrap();
        assert_eq!((s.day.as_str(), s.day_used_lux_hours), ("2026-03-30", 100.0));
        assert_eq!(s.now_local, "2026-03-30 00:30 CEST");
        assert_eq!(s.time_zone, "Europe/Amsterdam");
    }

    #[test]
    fn daily_budget_resets_at_local_midnight_across_fall_back() {
        let mut l = Ledger::open_in_memory(LocalZone::named("Europe/Amsterdam").unwrap()).unwrap();
        l.set_active(&active(150.0, 1e9)).unwrap();
        // Sunday 2026-10-25 is 25 hours long: [22:00Z on the 24th, 23:00Z on the 25th).
        hour_at(&mut l, "2026-10-24T21:00:00Z").unwrap();
        hour_at(&mut l, "2026-10-24T22:00:00Z").unwrap();
        hour_at(&mut l, "2026-10-25T21:00:00Z").unwrap_err();
        // 23:00 CET on the 25th is still the 25th (a fixed UTC+2 would have reset at 22:00Z).
        let e = hour_at(&mut l, "2026-10-25T22:00:00Z").unwrap_err();
        assert!(matches!(&e, Refusal::Exhausted(m) if m.contains("2026-10-25")), "{e:?}");
        hour_at(&mut l, "2026-10-25T23:00:00Z").unwrap();
        assert_eq!(l.status(utc("2026-10-25T23:30:00Z")).unwrap().day, "2026-10-26");
        // New York too: Sunday 2026-11-01 runs [04:00Z, 05:00Z on the 2nd).
        let mut l = Ledger::open_in_memory(LocalZone::named("America/New_York").unwrap()).unwrap();
        l.set_active(&active(150.0, 1e9)).unwrap();
        hour_at(&mut l, "2026-11-01T04:00:00Z").unwrap();
        hour_at(&mut l, "2026-11-02T04:00:00Z").unwrap_err();
        hour_at(&mut l, "2026-11-02T05:00:00Z").unwrap();
    }

    #[test]
    fn annual_budget_is_rolling() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(1000.0, 150.0)).unwrap();
        l.reserve(LightKind::Idle, "black", 100.0, 0, H).unwrap();
        let e = l.reserve(LightKind::Showing, "r1", 100.0, 100 * 24 * H, 100 * 24 * H + H).unwrap_err();
        assert!(matches!(&e, Refusal::Exhausted(m) if m.contains("annual")), "{e:?}");
        l.reserve(LightKind::Showing, "r1", 100.0, 366 * 24 * H, 366 * 24 * H + H).unwrap();
    }

    #[test]
    fn warnings_at_thresholds_once_per_day() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(100.0, 1e9)).unwrap();
        let id = l.reserve(LightKind::Showing, "r1", 100.0, 0, H * 7 / 10).unwrap();
        assert!(l.status(H).unwrap().warnings.is_empty());
        l.extend(id, H * 8 / 10).unwrap();
        l.extend(id, H * 85 / 100).unwrap();
        let w = l.status(H).unwrap().warnings;
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].threshold, 0.75);
        l.extend(id, H * 95 / 100).unwrap();
        assert_eq!(l.status(H).unwrap().warnings.len(), 2);
    }

    #[test]
    fn anti_rollback() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.accept_version("vase", 3, "aaa", 0).unwrap();
        l.check_version("vase", 3, "aaa").unwrap();
        l.check_version("vase", 4, "bbb").unwrap();
        l.check_version("other", 1, "ccc").unwrap();
        assert!(matches!(l.check_version("vase", 2, "x"), Err(LedgerError::Rollback { accepted: 3, .. })));
        assert!(matches!(
            l.check_version("vase", 3, "x"),
            Err(LedgerError::SameVersionDifferentContent { .. })
        ));
        l.accept_version("vase", 5, "ddd", 1).unwrap();
        assert!(l.check_version("vase", 4, "bbb").is_err());
    }

    #[test]
    fn no_light_without_an_active_bundle() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        assert!(matches!(l.reserve(LightKind::Idle, "black", 1.0, 0, 1000), Err(Refusal::Exhausted(_))));
    }

    #[test]
    fn reopen_keeps_everything_and_schema_version() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ledger.sqlite");
        {
            let mut l = Ledger::open(&p, LocalZone::utc()).unwrap();
            l.set_active(&active(1000.0, 10_000.0)).unwrap();
            l.reserve(LightKind::Showing, "r1", 36.0, 0, 100_000).unwrap();
        }
        let l = Ledger::open(&p, LocalZone::utc()).unwrap();
        l.integrity_check().unwrap();
        assert!((l.total("vase").unwrap() - 1.0).abs() < 1e-9);
        let s = l.status(0).unwrap();
        assert_eq!(s.schema_version, SCHEMA_VERSION);
        assert_eq!(s.open_reservations, 1);
        let ro = Ledger::open_read_only(&p, LocalZone::utc()).unwrap();
        assert!((ro.total("vase").unwrap() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_schema_1_ledger_is_migrated_with_its_history() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ledger.sqlite");
        {
            let c = Connection::open(&p).unwrap();
            c.execute_batch(MIGRATIONS[0]).unwrap();
            c.pragma_update(None, "user_version", 1).unwrap();
            c.execute(
                "INSERT INTO exposure (object, kind, label, lux, start_ms, end_ms, committed)
                 VALUES ('vase', 'showing', 'r1', 36.0, 0, 100000, 1)",
                [],
            )
            .unwrap();
        }
        let l = Ledger::open(&p, LocalZone::utc()).unwrap();
        assert_eq!(l.status(0).unwrap().schema_version, SCHEMA_VERSION);
        assert!((l.total("vase").unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(l.high_water_ms().unwrap(), 0);
        assert!(!l.ledger_id().unwrap().is_empty());
    }

    #[test]
    fn newer_schema_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ledger.sqlite");
        Connection::open(&p).unwrap().pragma_update(None, "user_version", 99).unwrap();
        let e = Ledger::open(&p, LocalZone::utc()).unwrap_err();
        assert!(matches!(e, LedgerError::SchemaTooNew { found: 99, .. }), "{e}");
    }

    #[test]
    fn full_database_is_a_failure_not_a_grant() {
        let mut l = Ledger::open_in_memory(LocalZone::utc()).unwrap();
        l.set_active(&active(1e9, 1e9)).unwrap();
        // SQLite reports a full disk as SQLITE_FULL; a page cap gives the same error.
        let pages: i64 = l.conn.pragma_query_value(None, "page_count", |r| r.get(0)).unwrap();
        l.conn.pragma_update(None, "max_page_count", pages).unwrap();
        let mut failed = false;
        for i in 0..10_000 {
            match l.reserve(LightKind::Showing, &"x".repeat(200), 1.0, i, i + 1) {
                Ok(_) => {}
                Err(Refusal::Failed(m)) => {
                    assert!(m.contains("full"), "{m}");
                    failed = true;
                    break;
                }
                Err(e) => panic!("{e:?}"),
            }
        }
        assert!(failed);
    }
}
