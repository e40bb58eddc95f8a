//! The appliance's event loop (tokio, one thread): inputs, timers and signals in; the player
//! decides; the outputs show; the ledger pays. Outputs are blanked before anything else and
//! on every fault; systemd hears READY once the outputs are up, and watchdog pings from here.
//! Nothing slow runs on this thread: a reload's verification runs on a worker thread and the
//! new bundle is swapped in between showings; the ledger waits at most `busy_timeout_ms` for
//! another process's lock.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use restage_shared::text::printable;
use thiserror::Error;
use tokio::signal::unix::{SignalKind, signal};
use tokio::sync::{mpsc, watch};

use crate::alert_command::{self, AlertCommand};
use crate::alerts::{AlertSettings, Alerts, BudgetUse, Facts, ProjectorProblem};
use crate::clock::{Clock, LedgerClock, SystemTime, TimeSource, monotonic_us};
use crate::config::{Config, LEDGER_FILE, OutputConfig};
use crate::feedback::{self, Availability};
use crate::inbox::Inbox;
use crate::input::{self, Control, InputEvent};
use crate::install;
use crate::ledger::LedgerStatus;
use crate::ledger::{Ledger, LedgerError};
use crate::loader::{self, FrameStore, LoadError, Prepared};
use crate::notify::Notifier;
use crate::output::headless::HeadlessOutput;
use crate::output::{FrameRef, Output, OutputError};
use crate::pjlink::{PjlinkControl, ProjectorStatus, Want};
use crate::player::{Command, Event, Player, PlayerSettings, STOPPED, State};
use crate::show::{Look, Show, mix_linear};
use crate::status::{self, Snapshot};

/// After a ledger fault (a lock held too long, an I/O error), light is tried again this
/// long later: a transient fault must not leave an unattended stage dark for good.
pub const LEDGER_RETRY_MS: u64 = 30_000;
/// How often alerts, the projectors and the status page are looked at (ms), besides at every
/// change of state: the page reloads every 10 s.
const HOUSEKEEPING_MS: u64 = 5_000;
/// A wall-clock step larger than this (ms) is logged as an event.
const CLOCK_STEP_REPORT_MS: i64 = 2_000;

#[derive(Debug, Error)]
pub enum RunError {
    #[error("state directory {path}: {problem}")]
    StateDir { path: PathBuf, problem: String },
    #[error(transparent)]
    Ledger(#[from] LedgerError),
    #[error("output: {0}")]
    Output(#[from] OutputError),
    #[error("output kind {kind:?} is not built into this binary: {hint}")]
    OutputUnavailable { kind: &'static str, hint: &'static str },
    #[error("control socket {path}: {source}")]
    Socket { path: PathBuf, source: std::io::Error },
    #[error("input: {0}")]
    Input(String),
    #[error(
        "systemd's watchdog timeout ({timeout_ms} ms) is longer than the exposure lease slack covers \
         ({max_ms} ms = ledger.renew_ahead_ms {renew_ahead_ms} less {kill_ms} ms from kill to dark): a stalled \
         appliance could keep light on unpaid; lower WatchdogSec or raise renew_ahead_ms"
    )]
    Watchdog { timeout_ms: u64, max_ms: u64, renew_ahead_ms: u64, kill_ms: u64 },
    #[error("event loop: {0}")]
    Io(#[from] std::io::Error),
}

/// Checks that the state directory exists and is readable and writable.
pub fn check_state_dir(dir: &Path) -> Result<(), RunError> {
    let err = |problem: String| RunError::StateDir { path: dir.into(), problem };
    let meta = std::fs::metadata(dir).map_err(|e| err(e.to_string()))?;
    if !meta.is_dir() {
        return Err(err("not a directory".into()));
    }
    std::fs::read_dir(dir).map_err(|e| err(format!("cannot read: {e}")))?;
    let probe = dir.join(".restage-write-probe");
    std::fs::write(&probe, b"").map_err(|e| err(format!("cannot write: {e}")))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Opens the configured output, blanked.
pub fn open_output(config: &Config, inputs: &input::InputSender) -> Result<Box<dyn Output>, RunError> {
    let _ = inputs;
    let mut out: Box<dyn Output> = match &config.output {
        OutputConfig::Headless { dir, projectors } => Box::new(HeadlessOutput::open(dir, *projectors)?),
        #[cfg(feature = "window")]
        OutputConfig::Window { projectors } => {
            Box::new(crate::output::window::WindowOutput::open(*projectors, inputs.clone())?)
        }
        #[cfg(not(feature = "window"))]
        OutputConfig::Window { .. } => {
            return Err(RunError::OutputUnavailable { kind: "window", hint: "build with --features window" });
        }
        #[cfg(target_os = "linux")]
        OutputConfig::Kms { card, connectors, atomic } => {
            Box::new(crate::output::kms::KmsOutput::open(card, connectors, *atomic, Some(inputs.clone()))?)
        }
        #[cfg(not(target_os = "linux"))]
        OutputConfig::Kms { .. } => {
            return Err(RunError::OutputUnavailable { kind: "kms", hint: "DRM/KMS needs Linux" });
        }
    };
    out.blank()?;
    Ok(out)
}

/// What a worker thread verifies a bundle with: the configured bundle's path (what it loads,
/// or where it installs), the trust, the ledger's path and the load options, at one time.
struct LoadJob {
    now_unix_ms: i64,
    bundle: PathBuf,
    trust: PathBuf,
    ledger_path: PathBuf,
    zone: crate::zone::LocalZone,
    opts: loader::LoadOptions,
}

impl LoadJob {
    /// Its own read-only connection: the loop's connection stays the loop's.
    fn ledger(&self) -> Result<Ledger, crate::ledger::LedgerError> {
        Ledger::open_read_only(&self.ledger_path, self.zone.clone())
    }
}

/// A reload in progress: verification on a worker thread, then activation between showings.
#[derive(Default)]
struct Reload {
    /// A worker is verifying a bundle.
    in_flight: bool,
    /// Another reload was asked for while one was in flight.
    again: bool,
    /// Operators waiting for the outcome (control socket, stdin).
    replies: Vec<tokio::sync::oneshot::Sender<String>>,
    /// Verified, waiting for the current showing to end.
    parked: Option<Prepared>,
}

/// Everything the loop owns.
pub struct App {
    config: Config,
    clock: Box<dyn Clock>,
    ledger: Ledger,
    output: Box<dyn Output>,
    player: Player,
    store: Option<FrameStore>,
    /// Zeros for black frames, one buffer for every projector (allocated when first needed).
    black: Option<Arc<Vec<u8>>>,
    /// Cross-fade buffers, kept only while fading.
    fade: Vec<Vec<u8>>,
    notifier: Notifier,
    last_status: String,
    reload: Reload,
    /// Verified bundles (or why not) from reload workers.
    prepared_tx: mpsc::Sender<Result<Prepared, LoadError>>,
    /// The bundle inbox, if configured, and the file its worker is installing.
    inbox: Option<Inbox>,
    inbox_busy: Option<PathBuf>,
    /// The last file the inbox finished with, and what became of it (status page, `status`).
    inbox_last: Option<status::InboxOutcome>,
    /// Inbox installs' outcomes: what was installed, or why the file was refused.
    inbox_tx: mpsc::Sender<Result<String, String>>,
    /// When light is tried again after a ledger fault (monotonic ms).
    ledger_retry_ms: Option<u64>,
    /// The wall clock's distance from ledger time when last reported.
    reported_skew_ms: i64,
    /// When the opening hours next change (ledger Unix ms); `None`: no change ahead.
    hours_change_ms: Option<i64>,
    /// What the visitor's button box shows (serial `LED` lines, the GPIO LED).
    availability: watch::Sender<Availability>,
    /// Operator alerts (budgets, expiry, projectors, faults) and the command that hears them.
    alerts: Alerts,
    alert_command: Option<AlertCommand>,
    /// When the periodic checks (alerts, projectors, status page) run next (monotonic ms).
    next_housekeeping_ms: u64,
    /// The projectors' own control (PJLink), if configured.
    pjlink: Option<PjlinkControl>,
    /// The status page's latest snapshot (read by the HTTP server, if enabled).
    snapshot: watch::Sender<Arc<Snapshot>>,
    /// Monotonic ms at start (the status page's uptime).
    started_mono_ms: u64,
}

impl std::fmt::Debug for App {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("App").field("state", self.player.state()).finish()
    }
}

impl App {
    fn now(&self) -> crate::player::Now {
        self.clock.now()
    }

    /// Feeds one event to the player, carries out its commands, then commits exposure.
    fn step(&mut self, event: Event) {
        let now = self.now();
        let commands = self.player.handle(now, event, &mut self.ledger);
        if let Err(e) = self.apply(&commands) {
            self.output_fault(e);
        } else {
            self.player.settle(self.now(), &mut self.ledger);
            self.report_status();
        }
        self.watch_ledger_fault();
    }

    /// Schedules a retry after a ledger fault; forgets it once the player left the fault.
    fn watch_ledger_fault(&mut self) {
        match self.player.state() {
            State::Fault { reason } if reason.starts_with("ledger:") => {
                if self.ledger_retry_ms.is_none() {
                    self.ledger_retry_ms = Some(self.now().mono_ms + LEDGER_RETRY_MS);
                }
            }
            _ => self.ledger_retry_ms = None,
        }
    }

    /// An output failed: dark first; the player then goes to its fault state (and asks for
    /// dark again).
    fn output_fault(&mut self, e: String) {
        let now = self.now();
        tracing::error!("output fault: {e}");
        let _ = self.output.blank();
        let commands = self.player.handle(self.now(), Event::Fault(e.clone()), &mut self.ledger);
        for c in commands {
            if let Command::Show(Look::Off) = c {
                let _ = self.output.blank();
            }
        }
        let _ = self.ledger.log_event(now.unix_ms, "fault", &e);
        self.player.settle(self.now(), &mut self.ledger);
        self.report_status();
    }

    fn apply(&mut self, commands: &[Command]) -> Result<(), String> {
        for c in commands {
            match *c {
                Command::Show(Look::Off) => {
                    self.fade = Vec::new();
                    self.output.blank().map_err(|e| e.to_string())?;
                }
                Command::Show(look) => {
                    self.fade = Vec::new();
                    let frames = self.frames(look)?;
                    let show = self.show()?;
                    let refs = refs(&show, |k| frames.get(k));
                    self.output.show(&refs).map_err(|e| e.to_string())?;
                }
                Command::Fade { from, to, t } => {
                    let show = self.show()?;
                    let (a, b) = (self.frames(from)?, self.frames(to)?);
                    if self.fade.len() != show.projectors.len() {
                        self.fade = show
                            .projectors
                            .iter()
                            .map(|&(w, h)| vec![0u8; w as usize * h as usize * 4])
                            .collect();
                    }
                    for (k, out) in self.fade.iter_mut().enumerate() {
                        mix_linear(a.get(k), b.get(k), t, &show.responses[k], out);
                    }
                    let fade = &self.fade;
                    let refs = refs(&show, |k| &fade[k]);
                    self.output.show(&refs).map_err(|e| e.to_string())?;
                }
            }
        }
        Ok(())
    }

    fn show(&self) -> Result<Arc<Show>, String> {
        self.player.show().cloned().ok_or_else(|| "no bundle loaded".to_string())
    }

    fn frames(&mut self, look: Look) -> Result<LookFrames, String> {
        let show = self.show()?;
        match look {
            Look::Scene(s) => {
                let store = self.store.as_mut().ok_or("no bundle loaded")?;
                let frames = store
                    .scene(s)
                    .map_err(|e| format!("bundle frames of scene {}: {e}", printable(&show.scenes[s].id)))?;
                Ok(LookFrames::Scene(frames))
            }
            Look::Identify(k) => {
                let pattern = show.identify.get(k).copied().flatten().ok_or("no commissioning pattern")?;
                let store = self.store.as_ref().ok_or("no bundle loaded")?;
                let frames = store
                    .identify(k, pattern)
                    .map_err(|e| format!("commissioning pattern of projector {}: {e}", k + 1))?;
                Ok(LookFrames::Scene(frames))
            }
            Look::Black | Look::Off => {
                // One buffer of zeros serves every projector (each takes its own length).
                let len =
                    show.projectors.iter().map(|&(w, h)| w as usize * h as usize * 4).max().unwrap_or(0);
                let black = self.black.get_or_insert_with(|| Arc::new(vec![0u8; len]));
                Ok(LookFrames::Black(black.clone(), show))
            }
        }
    }

    /// Starts verifying the configured bundle on a worker thread; the outcome comes back as
    /// a message (`prepared`). `reply` hears it once the bundle is active or refused.
    fn start_reload(&mut self, reply: Option<tokio::sync::oneshot::Sender<String>>) {
        self.reload.replies.extend(reply);
        if self.reload.in_flight {
            self.reload.again = true;
            return;
        }
        self.reload.in_flight = true;
        let job = self.load_job();
        let tx = self.prepared_tx.clone();
        let worker = move || {
            let result = job.ledger().map_err(LoadError::Ledger).and_then(|ledger| {
                loader::prepare(&job.bundle, &job.trust, &ledger, job.now_unix_ms, &job.opts)
            });
            let _ = tx.blocking_send(result);
        };
        if let Err(e) = std::thread::Builder::new().name("restage-verify".into()).spawn(worker) {
            self.reload.in_flight = false;
            let msg = self.refused(format!("cannot start verifying the bundle: {e}"));
            self.answer_reload(format!("error: {msg}"));
        }
    }

    /// What a worker thread needs to verify a bundle against the ledger, off the loop.
    fn load_job(&self) -> LoadJob {
        LoadJob {
            now_unix_ms: self.now().unix_ms,
            bundle: self.config.bundle_path(),
            trust: self.config.trust_dir.clone(),
            ledger_path: self.config.state_dir.join(LEDGER_FILE),
            zone: self.config.local_zone().clone(),
            opts: self.load_options(),
        }
    }

    /// Takes a bundle that has stood unchanged in the inbox for `inbox::SETTLE_MS` and
    /// installs it on a worker thread (verified, copied, the copy verified, renamed over the
    /// active bundle); `inbox_done` hears the outcome. One at a time.
    fn scan_inbox(&mut self) {
        if self.inbox_busy.is_some() {
            return;
        }
        let now = self.now();
        let Some(file) = self.inbox.as_mut().and_then(|i| i.next_ready(now.mono_ms)) else { return };
        tracing::info!(file = %file.display(), "bundle inbox: installing");
        let job = self.load_job();
        let tx = self.inbox_tx.clone();
        let src = file.clone();
        let worker = move || {
            let result = job.ledger().map_err(|e| format!("ledger: {e}")).and_then(|ledger| {
                install::install_verified(&src, &job.bundle, &job.trust, &ledger, job.now_unix_ms, &job.opts)
                    .map_err(|e| e.to_string())
            });
            let _ = tx.blocking_send(result);
        };
        match std::thread::Builder::new().name("restage-inbox".into()).spawn(worker) {
            Ok(_) => self.inbox_busy = Some(file),
            Err(e) => tracing::error!(file = %file.display(), "bundle inbox: cannot start installing: {e}"),
        }
    }

    /// An inbox install finished: the file leaves the inbox (to `installed/` or `refused/`),
    /// the journal and the ledger's events say what happened, and an installed bundle is
    /// reloaded (it plays from the next showing, as after `install`).
    fn inbox_done(&mut self, result: Result<String, String>) {
        let Some(file) = self.inbox_busy.take() else { return };
        let now = self.now();
        let moved = self.inbox.as_mut().map(|i| i.finish(&file, result.as_ref().err().map(String::as_str)));
        let whereto = match moved {
            Some(Ok(to)) => format!("moved to {}", to.display()),
            Some(Err(e)) => e,
            None => String::new(),
        };
        self.inbox_last = Some(status::InboxOutcome {
            at: self.config.local_zone().local_time(now.unix_ms),
            file: file.display().to_string(),
            installed: result.is_ok(),
            detail: match &result {
                Ok(what) | Err(what) => format!("{what}; {whereto}"),
            },
        });
        match result {
            Ok(what) => {
                let msg = format!("inbox: {} installed: {what}; {whereto}", file.display());
                tracing::info!("{msg}");
                let _ = self.ledger.log_event(now.unix_ms, "install", &msg);
                self.start_reload(None);
            }
            Err(why) => {
                let msg = format!("inbox: {} refused: {why}; {whereto}", file.display());
                tracing::error!("{msg}");
                let _ = self.ledger.log_event(now.unix_ms, "refused", &msg);
            }
        }
    }

    /// Verifies and activates the configured bundle on this thread (at start, before any
    /// light, when nothing else needs the loop).
    fn load_now(&mut self) -> Result<(), String> {
        let now = self.now();
        let c = &self.config;
        let prepared =
            loader::prepare(&c.bundle_path(), &c.trust_dir, &self.ledger, now.unix_ms, &self.load_options());
        match prepared {
            Ok(p) => {
                self.reload.parked = Some(p);
                self.activate_parked().unwrap_or(Ok(()))
            }
            Err(e) => Err(self.refused(e.to_string())),
        }
    }

    /// The configuration's say on loading; the memory limit is the cgroup's (systemd's
    /// `MemoryMax`), so a bundle that would get the appliance killed is refused instead.
    fn load_options(&self) -> loader::LoadOptions {
        loader::LoadOptions {
            memory: crate::memory::cgroup_limit()
                .map(|l| (l, matches!(self.config.output, OutputConfig::Kms { .. }))),
            ..loader::LoadOptions::from_config(&self.config)
        }
    }

    /// A worker finished verifying.
    fn prepared(&mut self, result: Result<Prepared, LoadError>) {
        self.reload.in_flight = false;
        match result {
            Ok(p) => {
                self.reload.parked = Some(p);
                self.activate_parked();
            }
            Err(e) => {
                let msg = self.refused(e.to_string());
                self.answer_reload(format!("error: {msg}"));
            }
        }
        if std::mem::take(&mut self.reload.again) {
            self.start_reload(None);
        }
    }

    /// Makes the parked bundle active unless a showing is on (it then waits for the showing
    /// to end: a reload never cuts, extends or restarts a showing). `None`: nothing done.
    fn activate_parked(&mut self) -> Option<Result<(), String>> {
        if matches!(self.player.state(), State::Showing { .. } | State::Ending { .. }) {
            return None;
        }
        let mut prepared = self.reload.parked.take()?;
        // The old bundle's frames go first (they are read again if this one is refused), so
        // two bundles' frames are never in memory at once.
        if let Some(store) = self.store.as_mut() {
            store.release();
        }
        if let Err(e) = prepared.preload() {
            let msg = self.refused(e.to_string());
            self.answer_reload(format!("error: {msg}"));
            return Some(Err(msg));
        }
        let now = self.now();
        let path = self.config.bundle_path();
        let object = self.config.object_id.clone();
        let output = &mut self.output;
        let result = loader::activate(prepared, &mut self.ledger, now.unix_ms, object.as_deref(), |show| {
            output.set_modes(&show.projectors).map_err(|e| e.to_string())
        });
        let outcome = match result {
            Ok(loaded) => {
                let _ = self.ledger.log_event(
                    now.unix_ms,
                    "load",
                    &format!(
                        "{} version {} ({})",
                        printable(&loaded.show.object_id),
                        loaded.show.version,
                        path.display()
                    ),
                );
                self.black = None;
                self.store = Some(loaded.store);
                self.step(Event::Load(loaded.show));
                self.answer_reload(format!("ok {}", self.player.state().name()));
                Ok(())
            }
            Err(e) => {
                let msg = self.refused(e.to_string());
                self.answer_reload(format!("error: {msg}"));
                Err(msg)
            }
        };
        Some(outcome)
    }

    fn answer_reload(&mut self, answer: String) {
        for r in self.reload.replies.drain(..) {
            let _ = r.send(answer.clone());
        }
    }

    fn refused(&mut self, msg: String) -> String {
        tracing::error!("{msg}");
        let _ = self.ledger.log_event(self.now().unix_ms, "refused", &msg);
        match self.player.show().cloned() {
            // The previous good bundle stays; if stopped or faulted, it resumes.
            Some(show) if matches!(self.player.state(), State::Dark { .. } | State::Fault { .. }) => {
                self.step(Event::Load(show));
            }
            Some(_) => {}
            None => self.step(Event::Unload(msg.clone())),
        }
        msg
    }

    fn status_json(&self) -> String {
        let now = self.now();
        let (state, detail) = match self.player.state() {
            State::Dark { reason }
            | State::Fault { reason }
            | State::Exhausted { reason, .. }
            | State::Closed { reason } => (self.player.state().name(), Some(reason.clone())),
            s => (s.name(), None),
        };
        let show = self.player.show().map(|s| {
            serde_json::json!({
                "object": s.object_id, "version": s.version, "bundle_hash": s.bundle_hash,
                "scenes": s.scenes.iter().map(|x| serde_json::json!({"id": x.id, "peak_lux": x.peak_lux})).collect::<Vec<_>>(),
            })
        });
        let ledger = self.ledger.status(now.unix_ms).map_err(|e| e.to_string());
        let zone = self.config.local_zone();
        let opening = self.config.opening_hours().at(now.unix_ms);
        let v = serde_json::json!({
            "open": opening.open,
            "next_change": opening.next_change_ms.map(|t| zone.local_time(t)),
            "time_zone": zone.name(),
            "state": state,
            "detail": detail,
            "ledger_time_ms": now.unix_ms,
            "wall_skew_ms": self.clock.wall_skew_ms(),
            "reload_pending": self.reload.in_flight || self.reload.parked.is_some(),
            "inbox": self.inbox_info(),
            "look": format!("{:?}", self.player.look()),
            "leased_lux": self.player.leased_lux(),
            "bundle": show,
            "ledger": match ledger { Ok(l) => serde_json::to_value(l).unwrap_or_default(), Err(e) => serde_json::json!({"error": e}) },
        });
        v.to_string()
    }

    fn report_status(&mut self) {
        feedback::publish(
            &self.availability,
            feedback::availability(self.player.state(), self.player.is_closed()),
        );
        let s = match self.player.state() {
            State::Dark { reason } => format!("dark: {reason}"),
            State::Fault { reason } => format!("fault: {reason}"),
            State::Exhausted { reason, .. } => format!("budget exhausted: {reason}"),
            State::Closed { reason } => reason.clone(),
            s => s.name().to_string(),
        };
        if s != self.last_status {
            self.notifier.status(&s);
            self.last_status = s;
            // A new state may raise or clear an alert: look now, not at the next round.
            self.next_housekeeping_ms = 0;
        }
    }

    /// The periodic checks: alerts from the ledger's budgets, the bundle's expiry, the
    /// player's faults and the clock. Also run at once when the player's state changes.
    fn housekeeping(&mut self) {
        let now = self.now();
        self.next_housekeeping_ms = now.mono_ms + HOUSEKEEPING_MS;
        self.scan_inbox();
        let (mut ledger_fault, mut fault, mut dark) = (None, None, None);
        match self.player.state() {
            State::Fault { reason } if reason.starts_with("ledger:") => ledger_fault = Some(reason.clone()),
            State::Fault { reason } => fault = Some(reason.clone()),
            State::Dark { reason } if reason != STOPPED => dark = Some(reason.clone()),
            _ => {}
        }
        let ledger_status = self.ledger.status(now.unix_ms);
        let budgets = match &ledger_status {
            Ok(s) => BudgetUse::from_status(s),
            Err(e) => {
                ledger_fault.get_or_insert_with(|| format!("ledger: {e}"));
                Vec::new()
            }
        };
        let projectors = self.pjlink.as_ref().map(PjlinkControl::statuses).unwrap_or_default();
        let facts = Facts {
            budgets,
            bundle_expires_ms: self.player.show().and_then(|s| s.expires_unix_ms),
            projectors: projectors.iter().filter_map(projector_problem).collect(),
            ledger_fault,
            fault,
            dark,
            clock_skew_ms: self.clock.wall_skew_ms(),
        };
        let changes = self.alerts.observe(&facts, now.unix_ms);
        for a in &changes.raised {
            let _ = self.ledger.log_event(now.unix_ms, "alert", &a.message);
        }
        alert_command::dispatch(&changes, self.alert_command.as_ref());
        let opening = self.config.opening_hours().at(now.unix_ms);
        self.drive_projectors(&opening);
        self.publish_snapshot(&opening, ledger_status.as_ref().map_err(|e| e.to_string()), &projectors);
    }

    /// What the projectors themselves should do (PJLink): powered on from `power_on_lead_s`
    /// before opening until closing, in standby otherwise; picture muted whenever the stage
    /// is dark for a reason (a second dark layer under a fault, a stop, closed hours, an
    /// exhausted budget, no bundle).
    fn drive_projectors(&self, opening: &crate::hours::Opening) {
        let Some(pj) = &self.pjlink else { return };
        let now = self.now().unix_ms;
        let lead_ms = self.config.pjlink.as_ref().map_or(0, |c| c.power_on_lead_s * 1000) as i64;
        let wanted_on = opening.open || self.config.opening_hours().at(now + lead_ms).open;
        pj.want(if wanted_on { Want::On } else { Want::Standby });
        // Not between showings (a dark idle look): unmuting takes a network round trip, and
        // a visitor's press must light the object at once.
        let dark_for_a_reason = matches!(
            self.player.state(),
            State::Fault { .. } | State::Dark { .. } | State::Closed { .. } | State::Exhausted { .. }
        );
        pj.want(Want::Mute(dark_for_a_reason));
    }

    /// The inbox's state as the status page and the control socket's `status` report it.
    fn inbox_info(&self) -> Option<status::InboxInfo> {
        self.inbox.as_ref().map(|i| status::InboxInfo {
            dir: i.dir().display().to_string(),
            installing: self.inbox_busy.as_ref().map(|f| f.display().to_string()),
            problem: i.problem().map(str::to_string),
            last: self.inbox_last.clone(),
        })
    }

    /// Publishes what the status page shows now.
    fn publish_snapshot(
        &self,
        opening: &crate::hours::Opening,
        ledger: Result<&LedgerStatus, String>,
        projectors: &[ProjectorStatus],
    ) {
        let now = self.now();
        let zone = self.config.local_zone();
        let local = |t: i64| zone.local_time(t);
        let alerts = self.alerts.active();
        let parts = status::Parts {
            name: self.config.name.as_deref(),
            version: env!("CARGO_PKG_VERSION"),
            uptime_s: now.mono_ms.saturating_sub(self.started_mono_ms) / 1000,
            now_ms: now.unix_ms,
            zone: &zone.name(),
            local: &local,
            state: self.player.state(),
            opening: status::opening(opening, &local),
            ledger,
            show: self.player.show().map(|s| s.as_ref()),
            projectors,
            alerts: &alerts,
            inbox: self.inbox_info(),
        };
        self.snapshot.send_replace(Arc::new(status::snapshot(&parts)));
    }

    /// Reports a wall-clock step (ledger time does not follow it; see `clock`).
    fn watch_clock(&mut self) {
        let skew = self.clock.wall_skew_ms();
        if (skew - self.reported_skew_ms).abs() > CLOCK_STEP_REPORT_MS {
            let detail = format!(
                "the wall clock is {:+.1} s from ledger time (was {:+.1} s); ledger time is kept",
                skew as f64 / 1000.0,
                self.reported_skew_ms as f64 / 1000.0
            );
            tracing::warn!("{detail}");
            let _ = self.ledger.log_event(self.now().unix_ms, "clock", &detail);
            self.reported_skew_ms = skew;
        }
    }

    fn input(&mut self, e: InputEvent) -> bool {
        match e {
            InputEvent::Press { source } => {
                // CLOCK_MONOTONIC, the clock of the KMS output's flip timestamps: press to
                // light is read off the logs.
                tracing::info!(source, mono_us = monotonic_us(), "press");
                self.step(Event::Press);
            }
            InputEvent::Release { .. } => self.step(Event::Release),
            InputEvent::Control { command, reply } => {
                let answer = match command {
                    Control::Press => {
                        self.step(Event::Press);
                        match self.player.closed_reason() {
                            Some(reason) => format!("ok {} ({reason})", self.player.state().name()),
                            None => format!("ok {}", self.player.state().name()),
                        }
                    }
                    Control::Stop => {
                        self.step(Event::Stop);
                        "ok dark".to_string()
                    }
                    Control::Reload => {
                        // Answered when the bundle is active or refused.
                        self.start_reload(reply);
                        return true;
                    }
                    Control::Status => self.status_json(),
                    Control::Identify { projector, seconds } => self.identify(projector, seconds),
                };
                if let Some(r) = reply {
                    let _ = r.send(answer);
                }
            }
            InputEvent::Quit => return false,
            InputEvent::OutputsChanged => {
                if let Err(e) = self.output.reprobe() {
                    self.output_fault(format!("after a hot-plug: {e}"));
                }
            }
        }
        true
    }

    /// The operator's `identify K S`: projector K (1-based) shows its commissioning pattern
    /// for S seconds, if the player is idle; the answer says what happened.
    fn identify(&mut self, projector: u8, seconds: u16) -> String {
        let Some(show) = self.player.show().cloned() else {
            return "error: no bundle loaded".into();
        };
        let k = usize::from(projector) - 1;
        let Some(pattern) = show.identify.get(k) else {
            return format!("error: the bundle has {} projectors, not {projector}", show.projectors.len());
        };
        let Some(pattern) = pattern else {
            return format!("error: projector {projector} has no pixel it may light within the bound");
        };
        self.step(Event::Identify { projector: k, ms: u64::from(seconds) * 1000 });
        match self.player.state() {
            State::Identifying { .. } => {
                let _ = self.ledger.log_event(
                    self.now().unix_ms,
                    "identify",
                    &format!("projector {projector} for {seconds} s at {:.1} lx", pattern.peak_lux),
                );
                format!(
                    "ok identifying projector {projector} for {seconds} s ({:.1} lx peak, paid)",
                    pattern.peak_lux
                )
            }
            s => format!("error: not idle ({}); try again when the player is idle", s.name()),
        }
    }

    /// Milliseconds until the player needs a tick or the bundle expires.
    fn wait_ms(&self) -> Option<u64> {
        let now = self.now();
        let tick = self.player.next_deadline().map(|d| d.saturating_sub(now.mono_ms));
        let expiry = self
            .player
            .show()
            .and_then(|s| s.expires_unix_ms)
            .filter(|_| !matches!(self.player.state(), State::Dark { .. }))
            .map(|e| (e - now.unix_ms).max(0) as u64);
        let retry = self.ledger_retry_ms.map(|r| r.saturating_sub(now.mono_ms));
        let housekeeping = Some(self.next_housekeeping_ms.saturating_sub(now.mono_ms));
        let hours = self.hours_change_ms.map(|t| (t - now.unix_ms).max(0) as u64);
        [tick, expiry, retry, housekeeping, hours].into_iter().flatten().min()
    }

    /// Opening hours: tells the player when they begin or end (in ledger time, which no
    /// wall-clock step moves) and sets the timer for the next change.
    fn watch_hours(&mut self) {
        let now = self.now();
        let opening = self.config.opening_hours().at(now.unix_ms);
        self.hours_change_ms = opening.next_change_ms;
        if opening.open {
            if self.player.is_closed() {
                tracing::info!(reason = %opening.reason, "opening hours began");
                self.step(Event::Open);
            }
        } else if self.player.closed_reason() != Some(opening.reason.as_str()) {
            self.step(Event::Close { reason: opening.reason });
        }
    }

    fn tick(&mut self) {
        let now = self.now();
        if self.hours_change_ms.is_some_and(|t| now.unix_ms >= t) {
            self.watch_hours();
        }
        if let Some(e) = self.player.show().and_then(|s| s.expires_unix_ms)
            && now.unix_ms >= e
            && !matches!(self.player.state(), State::Dark { .. })
        {
            let msg =
                format!("the bundle expired on {}", restage_shared::time::format_utc(e.div_euclid(1000)));
            tracing::error!("{msg}");
            let _ = self.ledger.log_event(now.unix_ms, "refused", &msg);
            self.store = None;
            self.step(Event::Unload(msg));
            return;
        }
        if let Some(at) = self.ledger_retry_ms
            && now.mono_ms >= at
            && let Some(show) = self.player.show().cloned()
        {
            tracing::info!("retrying light after a ledger fault");
            self.ledger_retry_ms = None;
            self.step(Event::Load(show));
            return;
        }
        self.step(Event::Tick);
    }

    /// Dark, commit, and tell systemd.
    fn shutdown(&mut self) {
        self.notifier.stopping();
        self.step(Event::Stop);
        let _ = self.output.blank();
    }
}

/// What an operator must hear about a projector: lost after trying, or reporting a fault.
/// Before the first poll a projector is not yet known, which is no problem.
fn projector_problem(s: &ProjectorStatus) -> Option<ProjectorProblem> {
    let problem = match (&s.last_error, s.reachable, s.failures) {
        (Some(e), _, _) => e.clone(),
        (None, false, f) if f > 0 => format!("unreachable at {}", s.address),
        _ => return None,
    };
    Some(ProjectorProblem { name: s.name.clone(), problem })
}

/// A look's frames: a scene's from the store, or black from one shared buffer of zeros.
enum LookFrames {
    Scene(Arc<Vec<Vec<u8>>>),
    Black(Arc<Vec<u8>>, Arc<Show>),
}

impl LookFrames {
    /// Projector `k`'s frame.
    fn get(&self, k: usize) -> &[u8] {
        match self {
            LookFrames::Scene(f) => &f[k],
            LookFrames::Black(zeros, show) => {
                let (w, h) = show.projectors[k];
                &zeros[..w as usize * h as usize * 4]
            }
        }
    }
}

fn refs<'a>(show: &Show, frame: impl Fn(usize) -> &'a [u8]) -> Vec<FrameRef<'a>> {
    show.projectors
        .iter()
        .enumerate()
        .map(|(k, &(width, height))| FrameRef { width, height, xrgb: frame(k) })
        .collect()
}

/// Runs the appliance on a single-threaded tokio runtime until it stops.
pub fn run_blocking(config: Config) -> Result<(), RunError> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    rt.block_on(run(config))
}

/// Runs the appliance on the machine's clocks until SIGTERM/SIGINT (or the development window
/// closes).
pub async fn run(config: Config) -> Result<(), RunError> {
    run_with(config, SystemTime).await
}

/// Runs the appliance with `time` as its clocks (tests step the wall clock through this).
pub async fn run_with<S: TimeSource + Clone + 'static>(config: Config, time: S) -> Result<(), RunError> {
    // A file-size limit (or quota) must give write errors, not kill the process with the
    // projectors lit: handle SIGXFSZ (25 on Linux) instead of taking its default action.
    let _xfsz = signal(SignalKind::from_raw(25))?;
    let mut term = signal(SignalKind::terminate())?;
    let mut int = signal(SignalKind::interrupt())?;
    let mut hup = signal(SignalKind::hangup())?;

    tracing::info!(mono_us = monotonic_us(), "appliance starting");
    // Outputs first, blanked: whatever fails next, the projectors are dark.
    let (tx, mut rx) = mpsc::channel(input::CHANNEL_CAPACITY);
    let output = open_output(&config, &tx)?;
    let notifier = Notifier::from_env();
    if let Some(t) = notifier.watchdog_timeout() {
        let (timeout_ms, max_ms) = (t.as_millis() as u64, config.ledger.max_watchdog_ms());
        if timeout_ms > max_ms {
            return Err(RunError::Watchdog {
                timeout_ms,
                max_ms,
                renew_ahead_ms: config.ledger.renew_ahead_ms,
                kill_ms: crate::config::KILL_TO_DARK_MS,
            });
        }
    }
    check_state_dir(&config.state_dir)?;
    let mut ledger = Ledger::open_stage(&config.state_dir, config.local_zone().clone())?;
    ledger.integrity_check()?;
    ledger.set_busy_timeout(config.ledger.busy_timeout_ms)?;
    let wall_ms = time.wall_ms();
    let clock = LedgerClock::new(time.clone(), ledger.high_water_ms()?);
    let (anchor_ms, anchor_boot_ms) = clock.anchor();
    ledger.record_run(anchor_ms, anchor_boot_ms, wall_ms)?;
    if anchor_ms > wall_ms + CLOCK_STEP_REPORT_MS {
        let detail = format!(
            "the wall clock reads {:.1} s before the ledger's last recorded time; ledger time continues from there",
            (anchor_ms - wall_ms) as f64 / 1000.0
        );
        tracing::warn!("{detail}");
        ledger.log_event(anchor_ms, "clock", &detail)?;
    }
    tracing::info!(ledger_ms = anchor_ms, boot_ms = anchor_boot_ms, "ledger clock anchored");
    // Out of order until the player says otherwise.
    let (availability_tx, availability_rx) = watch::channel(Availability::OutOfOrder);
    start_inputs(&config, &tx, &availability_rx)?;

    let p = &config.player;
    let settings = PlayerSettings {
        fade_ms: p.fade_ms,
        fade_fps: p.fade_fps,
        min_press_interval_ms: p.min_press_interval_ms,
        max_showing_ms: p.max_showing_ms,
        cooldown_ms: p.cooldown_ms,
        reserve_ms: config.ledger.reserve_ms,
        renew_ahead_ms: config.ledger.renew_ahead_ms,
        light_off_latency_ms: config.ledger.light_off_latency_ms,
    };
    let watchdog = notifier.watchdog_interval();
    let (prepared_tx, mut prepared_rx) = mpsc::channel(4);
    let (inbox_tx, mut inbox_rx) = mpsc::channel(1);
    let inbox_dir = config.inbox_dir.clone();
    if let Some(d) = &inbox_dir {
        tracing::info!(dir = %d.display(), "bundle inbox: watching");
    }
    let reported_skew_ms = clock.wall_skew_ms();
    let config_alerts = config.alerts.clone();
    let pjlink = config
        .pjlink
        .as_ref()
        .map(|c| PjlinkControl::spawn(&c.specs(), c.timing(), Arc::new(time.clone()) as Arc<dyn TimeSource>));
    let started = clock.now();
    let zone = config.local_zone().clone();
    let (snapshot, snapshot_rx) = watch::channel(Arc::new(status::Snapshot::starting(
        env!("CARGO_PKG_VERSION"),
        status::Clock {
            local: zone.local_time(started.unix_ms),
            zone: zone.name(),
            unix_ms: started.unix_ms,
        },
    )));
    // A status page that cannot listen (a port taken) is logged; the stage plays on.
    let status_server = match config.status.enabled {
        true => match status::bind(config.status.listen).await {
            Ok(listener) => {
                tracing::info!(listen = %config.status.listen, "status page listening");
                Some(tokio::spawn(status::serve(listener, snapshot_rx, status::Limits::default())))
            }
            Err(e) => {
                tracing::error!("status page: {e}");
                None
            }
        },
        false => None,
    };
    let mut app = App {
        clock: Box::new(clock),
        ledger,
        output,
        player: Player::new(settings),
        store: None,
        black: None,
        fade: Vec::new(),
        notifier,
        last_status: String::new(),
        config,
        reload: Reload::default(),
        prepared_tx,
        inbox: inbox_dir.as_deref().map(Inbox::new),
        inbox_busy: None,
        inbox_last: None,
        inbox_tx,
        ledger_retry_ms: None,
        reported_skew_ms,
        hours_change_ms: None,
        availability: availability_tx,
        alerts: Alerts::new(AlertSettings::from(&config_alerts)),
        alert_command: AlertCommand::from_config(&config_alerts),
        next_housekeeping_ms: 0,
        pjlink,
        snapshot,
        started_mono_ms: started.mono_ms,
    };
    // Closed before the bundle loads: outside opening hours the first light never comes on.
    app.watch_hours();
    if let Err(e) = app.load_now() {
        tracing::warn!("starting dark: {e}");
    }
    app.notifier.ready(&app.last_status.clone());
    tracing::info!(state = app.player.state().name(), "appliance running");

    let mut last_ping = std::time::Instant::now();
    loop {
        let mut wait = app.wait_ms().map(Duration::from_millis);
        if let Some(w) = watchdog {
            let left = w.saturating_sub(last_ping.elapsed());
            wait = Some(wait.map_or(left, |x| x.min(left)));
        }
        let sleep = async {
            match wait {
                Some(d) => tokio::time::sleep(d).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            ev = rx.recv() => match ev {
                Some(e) => if !app.input(e) { app.shutdown(); break; },
                None => { app.shutdown(); break; }
            },
            Some(result) = prepared_rx.recv() => app.prepared(result),
            Some(result) = inbox_rx.recv() => app.inbox_done(result),
            _ = sleep => app.tick(),
            _ = term.recv() => { app.shutdown(); break; }
            _ = int.recv() => { app.shutdown(); break; }
            _ = hup.recv() => app.start_reload(None),
        }
        // A bundle verified during a showing goes in once it has ended.
        if app.reload.parked.is_some() {
            app.activate_parked();
        }
        app.watch_clock();
        if app.now().mono_ms >= app.next_housekeeping_ms {
            app.housekeeping();
        }
        if let Some(w) = watchdog
            && last_ping.elapsed() >= w
        {
            app.notifier.ping();
            last_ping = std::time::Instant::now();
        }
    }
    // The projectors' own mute as the second dark layer while the service is down; a
    // restart unmutes them once light is wanted again.
    if let Some(pj) = &app.pjlink {
        pj.want(Want::Mute(true));
        if !pj.wait_settled(Duration::from_secs(2)).await {
            tracing::warn!("not every projector confirmed its AV mute before exit");
        }
    }
    if let Some(s) = status_server {
        s.abort();
    }
    tracing::info!("appliance stopped; outputs dark");
    Ok(())
}

fn start_inputs(
    config: &Config,
    tx: &input::InputSender,
    availability: &watch::Receiver<Availability>,
) -> Result<(), RunError> {
    let i = &config.inputs;
    if i.stdin {
        tokio::spawn(input::stdin::run(tx.clone()));
    }
    if let Some(path) = &i.control_socket {
        let listener =
            input::socket::bind(path).map_err(|source| RunError::Socket { path: path.clone(), source })?;
        tokio::spawn(input::socket::run(listener, path.clone(), tx.clone()));
    }
    if let Some(s) = &i.serial {
        tokio::spawn(input::serial::run(s.path.clone(), s.baud, tx.clone(), availability.clone()));
    }
    if let Some(e) = &i.evdev {
        let keys = input::evdev::parse_keys(&e.keys).map_err(RunError::Input)?;
        tokio::spawn(input::evdev::run(e.path.clone(), keys, tx.clone()));
    }
    #[cfg(feature = "gpio")]
    if let Some(g) = &i.gpio {
        let pin = input::gpio::start(g, tx.clone())
            .map_err(|e| RunError::Input(format!("GPIO pin {}: {e}", g.pin)))?;
        // The pin must live as long as the program for its interrupts to keep coming.
        std::mem::forget(pin);
    }
    #[cfg(not(feature = "gpio"))]
    if i.gpio.is_some() {
        return Err(RunError::Input("[inputs.gpio] needs a build with --features gpio".into()));
    }
    #[cfg(feature = "gpio")]
    if let Some(pin) = config.feedback.gpio_led_pin {
        let led = feedback::GpioLed::open(pin).map_err(|e| RunError::Input(e.to_string()))?;
        tokio::spawn(feedback::run_led(led, availability.clone()));
    }
    #[cfg(not(feature = "gpio"))]
    if config.feedback.gpio_led_pin.is_some() {
        return Err(RunError::Input("[feedback] gpio_led_pin needs a build with --features gpio".into()));
    }
    Ok(())
}
