//! The appliance's event loop (tokio, one thread): inputs, timers and signals in; the player
//! decides; the outputs show; the ledger pays. Outputs are blanked before anything else and
//! on every fault; systemd hears READY once the outputs are up, and watchdog pings from here.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use thiserror::Error;
use tokio::signal::unix::{SignalKind, signal};
use tokio::sync::mpsc;

use crate::config::{Config, LEDGER_FILE, OutputConfig};
use crate::input::{self, Control, InputEvent};
use crate::ledger::{Ledger, LedgerError};
use crate::loader::{self, FrameStore};
use crate::notify::Notifier;
use crate::output::headless::HeadlessOutput;
use crate::output::{FrameRef, Output, OutputError};
use crate::player::{Clock, Command, Event, Look, Player, PlayerSettings, State, SystemClock};
use crate::show::{Show, mix_linear};

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
    #[error("event loop: {0}")]
    Io(#[from] std::io::Error),
}

/// Microseconds of CLOCK_MONOTONIC (log timestamps comparable with DRM flip events).
fn monotonic_us() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000 + t.tv_nsec() as u64 / 1000)
        .unwrap_or(0)
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

/// Everything the loop owns.
pub struct App {
    config: Config,
    clock: SystemClock,
    ledger: Ledger,
    output: Box<dyn Output>,
    player: Player,
    store: Option<FrameStore>,
    /// Black frames (allocated when first needed).
    black: Option<Arc<Vec<Vec<u8>>>>,
    /// Cross-fade buffers, kept only while fading.
    fade: Vec<Vec<u8>>,
    notifier: Notifier,
    last_status: String,
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
                    let refs = refs(&show, &frames);
                    self.output.show(&refs).map_err(|e| e.to_string())?;
                }
                Command::Fade { from, to, t } => {
                    let show = self.show()?;
                    let (a, b) = (self.frames(from)?, self.frames(to)?);
                    if self.fade.len() != a.len() {
                        self.fade = a.iter().map(|f| vec![0u8; f.len()]).collect();
                    }
                    for (k, out) in self.fade.iter_mut().enumerate() {
                        mix_linear(&a[k], &b[k], t, &show.responses[k], out);
                    }
                    let refs = refs(&show, &self.fade);
                    self.output.show(&refs).map_err(|e| e.to_string())?;
                }
            }
        }
        Ok(())
    }

    fn show(&self) -> Result<Arc<Show>, String> {
        self.player.show().cloned().ok_or_else(|| "no bundle loaded".to_string())
    }

    fn frames(&mut self, look: Look) -> Result<Arc<Vec<Vec<u8>>>, String> {
        let show = self.show()?;
        match look {
            Look::Scene(s) => {
                let store = self.store.as_mut().ok_or("no bundle loaded")?;
                store.scene(s).map_err(|e| format!("bundle frames of scene {}: {e}", show.scenes[s].id))
            }
            Look::Black | Look::Off => {
                let black = self.black.get_or_insert_with(|| {
                    Arc::new(
                        show.projectors
                            .iter()
                            .map(|&(w, h)| vec![0u8; w as usize * h as usize * 4])
                            .collect(),
                    )
                });
                Ok(black.clone())
            }
        }
    }

    /// Loads (or reloads) the configured bundle; a refused one leaves the previous in place.
    fn reload(&mut self) -> Result<(), String> {
        let now = self.now();
        let path = self.config.bundle_path();
        let result = loader::load(
            &path,
            &self.config.trust_dir,
            &mut self.ledger,
            now.unix_ms,
            self.config.light_check.limits(),
            self.config.player.idle,
            |show| self.output.set_modes(&show.projectors).map_err(|e| e.to_string()),
        );
        match result {
            Ok(loaded) => {
                let _ = self.ledger.log_event(
                    now.unix_ms,
                    "load",
                    &format!(
                        "{} version {} ({})",
                        loaded.show.object_id,
                        loaded.show.version,
                        path.display()
                    ),
                );
                self.black = None;
                self.store = Some(loaded.store);
                self.step(Event::Load(loaded.show));
                Ok(())
            }
            Err(e) => Err(self.refused(e.to_string())),
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
            State::Dark { reason } | State::Fault { reason } | State::Exhausted { reason, .. } => {
                (self.player.state().name(), Some(reason.clone()))
            }
            s => (s.name(), None),
        };
        let show = self.player.show().map(|s| {
            serde_json::json!({
                "object": s.object_id, "version": s.version, "bundle_hash": s.bundle_hash,
                "scenes": s.scenes.iter().map(|x| serde_json::json!({"id": x.id, "peak_lux": x.peak_lux})).collect::<Vec<_>>(),
            })
        });
        let ledger = self.ledger.status(now.unix_ms).map_err(|e| e.to_string());
        let v = serde_json::json!({
            "state": state,
            "detail": detail,
            "look": format!("{:?}", self.player.look()),
            "leased_lux": self.player.leased_lux(),
            "bundle": show,
            "ledger": match ledger { Ok(l) => serde_json::to_value(l).unwrap_or_default(), Err(e) => serde_json::json!({"error": e}) },
        });
        v.to_string()
    }

    fn report_status(&mut self) {
        let s = match self.player.state() {
            State::Dark { reason } => format!("dark: {reason}"),
            State::Fault { reason } => format!("fault: {reason}"),
            State::Exhausted { reason, .. } => format!("budget exhausted: {reason}"),
            s => s.name().to_string(),
        };
        if s != self.last_status {
            self.notifier.status(&s);
            self.last_status = s;
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
                        format!("ok {}", self.player.state().name())
                    }
                    Control::Stop => {
                        self.step(Event::Stop);
                        "ok dark".to_string()
                    }
                    Control::Reload => match self.reload() {
                        Ok(()) => format!("ok {}", self.player.state().name()),
                        Err(e) => format!("error: {e}"),
                    },
                    Control::Status => self.status_json(),
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
        match (tick, expiry) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn tick(&mut self) {
        let now = self.now();
        if let Some(e) = self.player.show().and_then(|s| s.expires_unix_ms)
            && now.unix_ms >= e
            && !matches!(self.player.state(), State::Dark { .. })
        {
            let msg = format!("bundle expired at {} (Unix ms)", e);
            tracing::error!("{msg}");
            let _ = self.ledger.log_event(now.unix_ms, "refused", &msg);
            self.store = None;
            self.step(Event::Unload(msg));
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

fn refs<'a>(show: &Show, frames: &'a [Vec<u8>]) -> Vec<FrameRef<'a>> {
    frames
        .iter()
        .zip(&show.projectors)
        .map(|(f, &(width, height))| FrameRef { width, height, xrgb: f })
        .collect()
}

/// Runs the appliance on a single-threaded tokio runtime until it stops.
pub fn run_blocking(config: Config) -> Result<(), RunError> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    rt.block_on(run(config))
}

/// Runs the appliance until SIGTERM/SIGINT (or the development window closes).
pub async fn run(config: Config) -> Result<(), RunError> {
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
    check_state_dir(&config.state_dir)?;
    let ledger = Ledger::open(&config.state_dir.join(LEDGER_FILE), config.ledger.utc_offset_minutes)?;
    ledger.integrity_check()?;
    start_inputs(&config, &tx)?;

    let p = &config.player;
    let settings = PlayerSettings {
        fade_ms: p.fade_ms,
        fade_fps: p.fade_fps,
        min_press_interval_ms: p.min_press_interval_ms,
        max_showing_ms: p.max_showing_ms,
        cooldown_ms: p.cooldown_ms,
        reserve_ms: config.ledger.reserve_ms,
        renew_ahead_ms: config.ledger.renew_ahead_ms,
    };
    let notifier = Notifier::from_env();
    let watchdog = notifier.watchdog_interval();
    let mut app = App {
        clock: SystemClock::new(),
        ledger,
        output,
        player: Player::new(settings),
        store: None,
        black: None,
        fade: Vec::new(),
        notifier,
        last_status: String::new(),
        config,
    };
    if let Err(e) = app.reload() {
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
            _ = sleep => app.tick(),
            _ = term.recv() => { app.shutdown(); break; }
            _ = int.recv() => { app.shutdown(); break; }
            _ = hup.recv() => { let _ = app.reload(); }
        }
        if let Some(w) = watchdog
            && last_ping.elapsed() >= w
        {
            app.notifier.ping();
            last_ping = std::time::Instant::now();
        }
    }
    tracing::info!("appliance stopped; outputs dark");
    Ok(())
}

fn start_inputs(config: &Config, tx: &input::InputSender) -> Result<(), RunError> {
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
        tokio::spawn(input::serial::run(s.path.clone(), s.baud, tx.clone()));
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
    Ok(())
}
