//! The player: a pure state machine. Events and the time come in, output commands come out;
//! every lit moment is covered by an exposure reservation taken through an `Accountant`
//! before the light goes on (reserve, then switch the light, then commit the old lease).
//!
//! States: dark (no bundle, or stopped), idle, showing, ending (cross-fade), cooldown,
//! budget exhausted, fault, closed (outside opening hours). The exposure timer ends every
//! showing at the policy maximum whatever the button does: presses only ever start or cycle
//! a showing. Closing time ends a showing with its normal fade, to dark; while closed there
//! is no light and no reservation, and presses are refused with the reason.
//!
//! Dependencies go one way: the player uses `show` (the content and [`Look`]); `show` knows
//! nothing of the player.

use std::sync::Arc;

use crate::show::{Look, Show};

pub use crate::clock::{Clock, Now};

/// What can happen to the player.
#[derive(Clone, Debug)]
pub enum Event {
    /// The visitor's button went down (an edge; a held button sends nothing more).
    Press,
    /// The button came up. Ignored: only presses matter, so a stuck button cannot extend light.
    Release,
    /// Time passed (a deadline from `next_deadline` was reached).
    Tick,
    /// Operator stop: dark at once, until a reload.
    Stop,
    /// A new verified bundle: dark at once, then idle with it.
    Load(Arc<Show>),
    /// No usable bundle (refused, missing): dark.
    Unload(String),
    /// Something failed (output, ledger): dark at once, until a reload.
    Fault(String),
    /// Opening hours ended (`reason`, e.g. "closed: opens Tue 10:00"): a showing fades out,
    /// then dark until `Open`.
    Close { reason: String },
    /// Opening hours began: back to idle (after any cooldown still running).
    Open,
    /// Operator: show projector `projector`'s commissioning pattern for `ms` (from idle only;
    /// paid like any light), then back to idle.
    Identify { projector: usize, ms: u64 },
}

/// What the outputs must do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    Show(Look),
    /// A cross-fade frame: `from` mixed towards `to` by `t` in linear light.
    Fade {
        from: Look,
        to: Look,
        t: f32,
    },
}

/// Why the ledger said no.
#[derive(Clone, Debug, PartialEq)]
pub enum Refusal {
    /// A budget has no room: its name and the numbers.
    Exhausted(String),
    /// The ledger could not record (disk full, I/O): a fault.
    Failed(String),
}

/// What light is being paid for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightKind {
    Showing,
    Fade,
    Idle,
    Identify,
}

impl LightKind {
    pub fn as_str(self) -> &'static str {
        match self {
            LightKind::Showing => "showing",
            LightKind::Fade => "fade",
            LightKind::Idle => "idle",
            LightKind::Identify => "identify",
        }
    }
}

/// Opaque id of a reservation.
pub type LeaseId = i64;

/// How the player pays for light (the ledger, or a fake in tests).
pub trait Accountant {
    /// Reserves `lux` from `from_unix_ms` to `until_unix_ms` if the budgets allow it.
    fn reserve(
        &mut self,
        kind: LightKind,
        scene: &str,
        lux: f64,
        from_unix_ms: i64,
        until_unix_ms: i64,
    ) -> Result<LeaseId, Refusal>;
    /// Extends a lease (same lux) to `until_unix_ms` if the budgets allow it.
    fn extend(&mut self, lease: LeaseId, until_unix_ms: i64) -> Result<(), Refusal>;
    /// The light of `lease` ended at `end_unix_ms`: commit the actual exposure.
    fn commit(&mut self, lease: LeaseId, end_unix_ms: i64) -> Result<(), Refusal>;
    /// A showing finished (for the status report).
    fn record_showing(
        &mut self,
        started_unix_ms: i64,
        ended_unix_ms: i64,
        scenes: &[String],
        ended_by: &str,
    ) -> Result<(), Refusal>;
    /// When the last showing's light (showing or fade reservations) ended, as recorded: the
    /// cooldown runs from there, across restarts and reloads.
    fn last_showing_end(&self) -> Option<i64>;
}

/// Player timing (from the config) on top of the bundle's policy.
#[derive(Clone, Debug)]
pub struct PlayerSettings {
    pub fade_ms: u64,
    pub fade_fps: u32,
    pub min_press_interval_ms: u64,
    pub max_showing_ms: Option<u64>,
    pub cooldown_ms: Option<u64>,
    pub reserve_ms: u64,
    pub renew_ahead_ms: u64,
    /// Time from a blank command to the light being off at the object (display pipeline and
    /// projector latency): commits pay until `now + this`.
    pub light_off_latency_ms: u64,
}

/// The dark state's reason after an operator's stop (not an alert: someone chose it).
pub const STOPPED: &str = "stopped by operator";

/// How often an exhausted budget is looked at again.
pub const EXHAUSTED_RETRY_MS: u64 = 60_000;

/// The state, as reported by `status`.
#[derive(Clone, Debug, PartialEq)]
pub enum State {
    Dark {
        reason: String,
    },
    Idle,
    Showing {
        scene: usize,
        started: Now,
        scenes: Vec<usize>,
        last_change_ms: u64,
    },
    Ending {
        from: usize,
        to: Look,
        fade_start_ms: u64,
        step: u32,
        steps: u32,
    },
    Cooldown {
        until_ms: u64,
    },
    /// The operator's commissioning pattern on one projector, until `until_ms`.
    Identifying {
        projector: usize,
        until_ms: u64,
    },
    Exhausted {
        reason: String,
        retry_ms: u64,
    },
    Fault {
        reason: String,
    },
    /// Outside opening hours: dark, presses refused with `reason`.
    Closed {
        reason: String,
    },
}

impl State {
    pub fn name(&self) -> &'static str {
        match self {
            State::Dark { .. } => "dark",
            State::Idle => "idle",
            State::Showing { .. } => "showing",
            State::Ending { .. } => "ending",
            State::Cooldown { .. } => "cooldown",
            State::Identifying { .. } => "identifying",
            State::Exhausted { .. } => "budget-exhausted",
            State::Fault { .. } => "fault",
            State::Closed { .. } => "closed",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Lease {
    id: LeaseId,
    lux: f64,
    until_mono_ms: u64,
}

/// The player.
#[derive(Debug)]
pub struct Player {
    settings: PlayerSettings,
    show: Option<Arc<Show>>,
    state: State,
    look: Look,
    lease: Option<Lease>,
    /// Last press accepted (start or cycle), for the press-rate limit.
    last_press_ms: Option<u64>,
    /// Ledger writes that wait until the outputs have carried out the commands: commits of
    /// leases whose light has been switched away (so a committed end is never before the
    /// light's) and showing records (so no write delays a blank).
    deferred: Vec<Deferred>,
    /// Outside opening hours (why, for refusals), whatever the state; `None`: open.
    closed: Option<String>,
}

/// A ledger write done by `settle`, after the outputs acted.
#[derive(Clone, Debug, PartialEq)]
enum Deferred {
    Commit(LeaseId),
    Showing { started: i64, ended: i64, scenes: Vec<String>, ended_by: String },
}

impl Player {
    /// A player with nothing loaded: dark.
    pub fn new(settings: PlayerSettings) -> Player {
        Player {
            settings,
            show: None,
            state: State::Dark { reason: "no bundle loaded".into() },
            look: Look::Off,
            lease: None,
            last_press_ms: None,
            deferred: Vec::new(),
            closed: None,
        }
    }

    /// Commits the exposure of leases whose light is off, at `now` plus the light-off
    /// latency, and records finished showings: call it after the outputs carried out the
    /// commands `handle` returned. A failed commit leaves the reservation standing (an
    /// over-count), so it is only logged.
    pub fn settle(&mut self, now: Now, acct: &mut dyn Accountant) {
        // One millisecond more: `unix_ms` is truncated, the light's true end is not.
        let end = now.unix_ms + self.settings.light_off_latency_ms as i64 + 1;
        for d in std::mem::take(&mut self.deferred) {
            match d {
                Deferred::Commit(id) => {
                    if let Err(e) = acct.commit(id, end) {
                        tracing::error!(?e, lease = id, "could not commit exposure; the reservation stands");
                    }
                }
                Deferred::Showing { started, ended, scenes, ended_by } => {
                    if let Err(e) = acct.record_showing(started, ended, &scenes, &ended_by) {
                        tracing::warn!(?e, "could not record the showing");
                    }
                }
            }
        }
    }

    /// Whether `settle` has ledger writes waiting.
    pub fn has_deferred(&self) -> bool {
        !self.deferred.is_empty()
    }

    pub fn state(&self) -> &State {
        &self.state
    }

    /// Outside opening hours (the visitor's button is refused; its LED can say so).
    pub fn is_closed(&self) -> bool {
        self.closed.is_some()
    }

    /// Why presses are refused for opening hours, while closed.
    pub fn closed_reason(&self) -> Option<&str> {
        self.closed.as_deref()
    }

    /// What the outputs show now.
    pub fn look(&self) -> Look {
        self.look
    }

    pub fn show(&self) -> Option<&Arc<Show>> {
        self.show.as_ref()
    }

    /// Peak lux the current lease pays for (0 when dark).
    pub fn leased_lux(&self) -> f64 {
        self.lease.map(|l| l.lux).unwrap_or(0.0)
    }

    /// Longest continuous lit showing, fade included: the bundle's, or the config's if shorter.
    pub fn max_showing_ms(&self) -> u64 {
        let policy = self.show.as_ref().map(|s| s.policy.max_showing_ms).unwrap_or(0);
        self.settings.max_showing_ms.map_or(policy, |c| c.min(policy))
    }

    fn cooldown_ms(&self) -> u64 {
        let policy = self.show.as_ref().map(|s| s.policy.cooldown_ms).unwrap_or(0);
        self.settings.cooldown_ms.map_or(policy, |c| c.max(policy))
    }

    /// The fade fits inside the showing's maximum: at most half of it.
    fn fade_ms(&self) -> u64 {
        self.settings.fade_ms.min(self.max_showing_ms() / 2)
    }

    /// When the player next needs a `Tick` (monotonic ms), if ever.
    pub fn next_deadline(&self) -> Option<u64> {
        let renew = self.lease.map(|l| l.until_mono_ms.saturating_sub(self.settings.renew_ahead_ms));
        match (self.state_deadline(), renew) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The state's own next deadline (timer, fade frame, cooldown, budget retry).
    fn state_deadline(&self) -> Option<u64> {
        match &self.state {
            State::Showing { started, .. } => {
                Some(started.mono_ms + self.max_showing_ms().saturating_sub(self.fade_ms()))
            }
            State::Ending { fade_start_ms, step, steps, .. } => {
                // Rounded up, so the frame computed at the deadline is the next one.
                Some(fade_start_ms + (self.fade_ms() * u64::from(step + 1)).div_ceil(u64::from(*steps)))
            }
            State::Cooldown { until_ms } | State::Identifying { until_ms, .. } => Some(*until_ms),
            State::Exhausted { retry_ms, .. } => Some(*retry_ms),
            State::Dark { .. } | State::Idle | State::Fault { .. } | State::Closed { .. } => None,
        }
    }

    /// Handles one event at `now`; returns what the outputs must do, in order.
    pub fn handle(&mut self, now: Now, event: Event, acct: &mut dyn Accountant) -> Vec<Command> {
        let mut out = Vec::new();
        match event {
            Event::Press => self.press(now, acct, &mut out),
            Event::Release => {}
            Event::Tick => {}
            Event::Identify { projector, ms } => self.identify(now, projector, ms, acct, &mut out),
            Event::Stop => self.go_dark(now, &mut out, State::Dark { reason: STOPPED.into() }, "stop"),
            Event::Fault(reason) => {
                tracing::error!(%reason, "fault: outputs dark");
                self.go_dark(now, &mut out, State::Fault { reason }, "fault")
            }
            Event::Unload(reason) => {
                self.go_dark(now, &mut out, State::Dark { reason }, "reload");
                self.show = None;
            }
            Event::Load(show) => {
                self.go_dark(now, &mut out, State::Dark { reason: "loading".into() }, "reload");
                self.show = Some(show);
                self.last_press_ms = None;
                self.resume(now, acct, &mut out);
            }
            Event::Close { reason } => self.close(now, reason, acct, &mut out),
            Event::Open => {
                if self.closed.take().is_some() && matches!(self.state, State::Closed { .. }) {
                    tracing::info!("opening hours began");
                    self.resume(now, acct, &mut out);
                }
            }
        }
        self.run_timers(now, acct, &mut out);
        self.maintain_lease(now, acct, &mut out);
        out
    }

    /// Idle (or closed, outside opening hours), unless the cooldown after the last showing
    /// is still running: it holds across reloads, restarts and closing times.
    fn resume(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        self.enter_idle(now, acct, out);
        if self.state == State::Idle
            && let Some(end) = acct.last_showing_end()
        {
            let left = end + self.cooldown_ms() as i64 - now.unix_ms;
            if left > 0 {
                self.state = State::Cooldown { until_ms: now.mono_ms + left as u64 };
            }
        }
    }

    /// Closing time: a showing ends with its normal fade (to dark), anything else goes dark
    /// now. A fade already running finishes, then goes dark; an operator's stop or a fault
    /// keeps its own state (and reason) until it is cleared, then the stage stays closed.
    fn close(&mut self, now: Now, reason: String, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        tracing::info!(%reason, "opening hours ended");
        self.closed = Some(reason.clone());
        match self.state.clone() {
            State::Showing { scene, .. } => {
                self.finish_showing(now, "closing");
                self.begin_ending(now, scene, Look::Off, acct, out);
            }
            State::Ending { .. } | State::Dark { .. } | State::Fault { .. } => {}
            // The commissioning pattern is an operator's, not a showing: no fade.
            State::Idle
            | State::Cooldown { .. }
            | State::Identifying { .. }
            | State::Exhausted { .. }
            | State::Closed { .. } => self.go_dark(now, out, State::Closed { reason }, "closing"),
        }
    }

    fn press(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        if let Some(reason) = &self.closed {
            tracing::info!(%reason, "press refused: outside opening hours");
            return;
        }
        let Some(show) = self.show.clone() else { return };
        let cycle = show.cycle();
        if cycle.is_empty() {
            return;
        }
        // A bouncing, flooding or stuck input cannot strobe the object or hammer the ledger.
        if let Some(last) = self.last_press_ms
            && now.mono_ms < last + self.settings.min_press_interval_ms
        {
            return;
        }
        match &self.state {
            State::Idle => {
                self.last_press_ms = Some(now.mono_ms);
                let scene = cycle[0];
                match self.switch_light(now, Look::Scene(scene), LightKind::Showing, acct, out) {
                    Ok(()) => {
                        tracing::info!(scene = %restage_shared::text::printable(&show.scenes[scene].id), "showing started");
                        self.state = State::Showing {
                            scene,
                            started: now,
                            scenes: vec![scene],
                            last_change_ms: now.mono_ms,
                        };
                    }
                    Err(r) => self.refused(now, r, out),
                }
            }
            State::Showing { scene, started, scenes, .. } => {
                self.last_press_ms = Some(now.mono_ms);
                let pos = cycle.iter().position(|s| s == scene).unwrap_or(0);
                let next = cycle[(pos + 1) % cycle.len()];
                if next == *scene {
                    return;
                }
                let (started, mut scenes) = (*started, scenes.clone());
                match self.switch_light(now, Look::Scene(next), LightKind::Showing, acct, out) {
                    Ok(()) => {
                        scenes.push(next);
                        self.state =
                            State::Showing { scene: next, started, scenes, last_change_ms: now.mono_ms };
                    }
                    // The scene on show is paid for until its lease runs out: keep it. Going
                    // dark here and starting afresh on the next press would strobe the object.
                    Err(Refusal::Exhausted(reason)) => {
                        tracing::warn!(%reason, "no budget for the next scene; the current one stays");
                    }
                    Err(r) => self.refused(now, r, out),
                }
            }
            // The showing is over, or light is not allowed now (an exhausted budget is looked
            // at again by its own timer, never by a press): presses do nothing.
            State::Ending { .. }
            | State::Cooldown { .. }
            | State::Identifying { .. }
            | State::Dark { .. }
            | State::Fault { .. }
            | State::Exhausted { .. }
            | State::Closed { .. } => {}
        }
    }

    /// The commissioning pattern: only from idle (never during or right after a showing), only
    /// for a projector with a pattern within the bound, paid at the pattern's peak. It is
    /// light on the object like a showing's, so the policy's longest showing caps it and a
    /// cooldown follows it.
    fn identify(&mut self, now: Now, k: usize, ms: u64, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        let has_pattern = self.show.as_ref().is_some_and(|s| s.identify.get(k).is_some_and(Option::is_some));
        if self.state != State::Idle || !has_pattern {
            return;
        }
        match self.switch_light(now, Look::Identify(k), LightKind::Identify, acct, out) {
            Ok(()) => {
                let until_ms = now.mono_ms + ms.min(self.max_showing_ms());
                self.state = State::Identifying { projector: k, until_ms };
            }
            Err(r) => self.refused(now, r, out),
        }
    }

    fn run_timers(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        // Several deadlines may have passed (a late tick): handle them in order.
        for _ in 0..10_000 {
            let Some(deadline) = self.state_deadline() else { return };
            if now.mono_ms < deadline {
                return;
            }
            match self.state.clone() {
                State::Showing { scene, .. } => {
                    self.finish_showing(now, "timer");
                    let to = self.idle_look();
                    self.begin_ending(now, scene, to, acct, out);
                }
                State::Ending { from, to, fade_start_ms, step, steps } => {
                    // Only the latest due frame is worth showing after a late tick.
                    let elapsed = now.mono_ms - fade_start_ms;
                    let due = (elapsed * u64::from(steps) / self.fade_ms().max(1)) as u32;
                    if due >= steps {
                        self.end_fade(now, acct, out);
                    } else if due <= step {
                        return;
                    } else {
                        let t = due as f32 / steps as f32;
                        out.push(Command::Fade { from: Look::Scene(from), to, t });
                        self.state = State::Ending { from, to, fade_start_ms, step: due, steps };
                    }
                }
                State::Cooldown { .. } => self.enter_idle(now, acct, out),
                // Like a showing's end: the idle look, then the object rests.
                State::Identifying { .. } => self.end_fade(now, acct, out),
                State::Exhausted { .. } => self.enter_idle(now, acct, out),
                State::Dark { .. } | State::Idle | State::Fault { .. } | State::Closed { .. } => return,
            }
        }
    }

    /// Fades from scene `from` to `to` (the idle look, or dark at closing time).
    fn begin_ending(
        &mut self,
        now: Now,
        from: usize,
        to: Look,
        acct: &mut dyn Accountant,
        out: &mut Vec<Command>,
    ) {
        let fade_ms = self.fade_ms();
        let steps = ((fade_ms * u64::from(self.settings.fade_fps)).div_ceil(1000)).max(1) as u32;
        if fade_ms == 0 || steps < 2 {
            self.end_fade(now, acct, out);
            return;
        }
        // The fade's light is bounded by the brighter of its ends; pay for that.
        let lux = self.look_lux(Look::Scene(from)).max(self.look_lux(to));
        match self.reserve_and_commit(
            now,
            lux,
            LightKind::Fade,
            &format!("fade:{}", self.scene_id(from)),
            acct,
        ) {
            Ok(()) => {
                self.state = State::Ending { from, to, fade_start_ms: now.mono_ms, step: 0, steps };
            }
            Err(r) => self.refused(now, r, out),
        }
    }

    fn end_fade(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        if let Some(reason) = self.closed.clone() {
            self.go_dark(now, out, State::Closed { reason }, "closing");
            return;
        }
        let to = self.idle_look();
        match self.switch_light(now, to, LightKind::Idle, acct, out) {
            Ok(()) => self.state = State::Cooldown { until_ms: now.mono_ms + self.cooldown_ms() },
            Err(r) => self.refused(now, r, out),
        }
    }

    fn enter_idle(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        if self.show.is_none() {
            return;
        }
        if let Some(reason) = self.closed.clone() {
            self.go_dark(now, out, State::Closed { reason }, "closing");
            return;
        }
        let look = self.idle_look();
        match self.switch_light(now, look, LightKind::Idle, acct, out) {
            Ok(()) => self.state = State::Idle,
            Err(r) => self.refused(now, r, out),
        }
    }

    fn refused(&mut self, now: Now, refusal: Refusal, out: &mut Vec<Command>) {
        match refusal {
            Refusal::Exhausted(reason) => {
                tracing::warn!(%reason, "light budget exhausted: outputs dark");
                let retry_ms = now.mono_ms + EXHAUSTED_RETRY_MS;
                self.go_dark(now, out, State::Exhausted { reason, retry_ms }, "budget");
            }
            Refusal::Failed(reason) => {
                tracing::error!(%reason, "ledger failed: outputs dark");
                self.go_dark(now, out, State::Fault { reason: format!("ledger: {reason}") }, "fault");
            }
        }
    }

    /// Outputs off at once; the ledger hears of it in `settle`, after the outputs acted (a
    /// failing or locked ledger cannot keep light on or delay the blank).
    fn go_dark(&mut self, now: Now, out: &mut Vec<Command>, state: State, why: &str) {
        if self.look != Look::Off || self.lease.is_some() {
            out.push(Command::Show(Look::Off));
            self.look = Look::Off;
        }
        if matches!(self.state, State::Showing { .. }) {
            self.finish_showing(now, why);
        }
        if let Some(old) = self.lease.take() {
            self.deferred.push(Deferred::Commit(old.id));
        }
        self.state = state;
    }

    /// Queues the showing's record for `settle` (after the outputs acted).
    fn finish_showing(&mut self, now: Now, why: &str) {
        if let State::Showing { started, scenes, .. } = &self.state {
            let ids: Vec<String> = scenes.iter().map(|&s| self.scene_id(s)).collect();
            tracing::info!(ended_by = why, ms = now.mono_ms - started.mono_ms, "showing ended");
            self.deferred.push(Deferred::Showing {
                started: started.unix_ms,
                ended: now.unix_ms,
                scenes: ids,
                ended_by: why.into(),
            });
        }
    }

    /// Reserve light for `look`, switch to it, then commit the previous lease.
    fn switch_light(
        &mut self,
        now: Now,
        look: Look,
        kind: LightKind,
        acct: &mut dyn Accountant,
        out: &mut Vec<Command>,
    ) -> Result<(), Refusal> {
        if look == Look::Off {
            out.push(Command::Show(Look::Off));
            self.look = Look::Off;
            if let Some(old) = self.lease.take() {
                self.deferred.push(Deferred::Commit(old.id));
            }
            return Ok(());
        }
        let label = match look {
            Look::Scene(s) => self.scene_id(s),
            Look::Identify(k) => format!("identify:{k}"),
            _ => "black".into(),
        };
        self.reserve_and_commit(now, self.look_lux(look), kind, &label, acct)?;
        out.push(Command::Show(look));
        self.look = look;
        Ok(())
    }

    /// Takes a new lease at `lux` from now and queues the previous one for commit (so the
    /// light is covered at every instant, by both around the switch).
    fn reserve_and_commit(
        &mut self,
        now: Now,
        lux: f64,
        kind: LightKind,
        label: &str,
        acct: &mut dyn Accountant,
    ) -> Result<(), Refusal> {
        let until = now.plus(self.settings.reserve_ms);
        let id = acct.reserve(kind, label, lux, now.unix_ms, until.unix_ms)?;
        let new = Lease { id, lux, until_mono_ms: until.mono_ms };
        if let Some(old) = self.lease.replace(new) {
            self.deferred.push(Deferred::Commit(old.id));
        }
        Ok(())
    }

    fn maintain_lease(&mut self, now: Now, acct: &mut dyn Accountant, out: &mut Vec<Command>) {
        let Some(lease) = self.lease else { return };
        if now.mono_ms + self.settings.renew_ahead_ms < lease.until_mono_ms {
            return;
        }
        if now.mono_ms > lease.until_mono_ms {
            // The process did not run while its lease ran out (stopped, starved, suspended):
            // the light stayed on. The extension below, or the commit of the actual end if it
            // is refused, records that time; say so.
            tracing::error!(
                overrun_ms = now.mono_ms - lease.until_mono_ms,
                "exposure lease ran out while lit (the appliance was stalled); paying the actual time"
            );
        }
        let until = now.plus(self.settings.reserve_ms);
        match acct.extend(lease.id, until.unix_ms) {
            Ok(()) => self.lease = Some(Lease { until_mono_ms: until.mono_ms, ..lease }),
            Err(r) => self.refused(now, r, out),
        }
    }

    fn idle_look(&self) -> Look {
        match self.show.as_ref().map(|s| s.idle) {
            Some(Look::Scene(i)) if i < self.show.as_ref().map_or(0, |s| s.scenes.len()) => Look::Scene(i),
            Some(Look::Black) => Look::Black,
            _ => Look::Off,
        }
    }

    fn look_lux(&self, look: Look) -> f64 {
        let Some(show) = &self.show else { return 0.0 };
        match look {
            Look::Scene(i) => show.scenes[i].peak_lux.max(show.black_lux),
            Look::Black => show.black_lux,
            Look::Off => 0.0,
            // Its peak counts the other projectors' black level (their frames are black).
            Look::Identify(k) => show
                .identify
                .get(k)
                .copied()
                .flatten()
                .map_or(f64::INFINITY, |p| p.peak_lux)
                .max(show.black_lux),
        }
    }

    fn scene_id(&self, i: usize) -> String {
        self.show.as_ref().map(|s| s.scenes[i].id.clone()).unwrap_or_default()
    }
}

#[cfg(test)]
#[path = "player_tests.rs"]
mod tests;
