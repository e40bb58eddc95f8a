//! The projector controller: one task per projector that polls it and steers it towards
//! what the event loop wants (power, AV mute), publishing a `ProjectorStatus` on a watch
//! channel. Asking never blocks; a silent, garbled or refusing projector is reported and
//! retried with backoff, never waited on by the caller.

use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::client::{Info, PjlinkError, Projector, Session};
use super::protocol::{Class, ErrCode, ErrorStatus, Lamp, PowerState};
use crate::clock::TimeSource;

/// What the event loop asks of the projectors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Want {
    /// Power on (before opening). The projector is ready once it reports power on.
    On,
    /// Standby (after closing). A warming projector is switched off once on; a cooling one
    /// is left to cool.
    Standby,
    /// AV mute, the second dark layer: true on any fault and on exit, false only when light
    /// is wanted. Applied only while the projector is on (projectors refuse it otherwise).
    Mute(bool),
}

/// The wanted power state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PowerWant {
    On,
    Standby,
}

/// What is wanted of one projector. `None`: leave it as found (the state at start, until
/// the event loop says otherwise).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Desired {
    pub power: Option<PowerWant>,
    pub mute: Option<bool>,
}

impl Desired {
    fn apply(&mut self, want: Want) {
        match want {
            Want::On => self.power = Some(PowerWant::On),
            Want::Standby => self.power = Some(PowerWant::Standby),
            Want::Mute(m) => self.mute = Some(m),
        }
    }
}

/// The controller's intervals and limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timing {
    /// Between polls of a settled projector.
    pub poll: Duration,
    /// Between polls while warming up, cooling down or waiting to act; also the first retry
    /// after a failure.
    pub busy_poll: Duration,
    /// Bounds each step of an exchange (connect, each line).
    pub timeout: Duration,
    /// A warm-up longer than this is reported as an error (the wait goes on).
    pub warmup_max: Duration,
    /// A cool-down longer than this is reported as an error (the wait goes on).
    pub cooldown_max: Duration,
    /// The longest wait between retries of a failing projector (the backoff doubles up to it).
    pub retry_max: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            poll: Duration::from_secs(10),
            busy_poll: Duration::from_secs(1),
            timeout: Duration::from_secs(2),
            warmup_max: Duration::from_secs(120),
            cooldown_max: Duration::from_secs(180),
            retry_max: Duration::from_secs(60),
        }
    }
}

impl Timing {
    /// The wait after `failures` consecutive failures: `busy_poll`, doubling, at most
    /// `retry_max`.
    pub fn backoff(&self, failures: u32) -> Duration {
        let doublings = failures.saturating_sub(1).min(16);
        self.busy_poll.saturating_mul(1 << doublings).min(self.retry_max)
    }
}

/// One projector to control.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProjectorSpec {
    pub name: String,
    /// `host` or `host:port`.
    pub address: String,
    pub password: Option<String>,
}

/// The latest known state of one projector, as the event loop and the status page read it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ProjectorStatus {
    /// The configured name.
    pub name: String,
    /// `host:port`.
    pub address: String,
    /// The last exchange worked (a refused command still counts as reachable).
    pub reachable: bool,
    /// What went wrong last: the last exchange's error, a warm-up or cool-down overrun, or
    /// the projector's own error status. None when all is well.
    pub last_error: Option<String>,
    pub power: Option<PowerState>,
    /// Picture muted (AVMT).
    pub muted: Option<bool>,
    /// The most used lamp's hours (None: not polled yet, or no lamps).
    pub lamp_hours: Option<u32>,
    pub lamps: Vec<Lamp>,
    pub errors: Option<ErrorStatus>,
    pub class: Option<Class>,
    /// NAME, INF1, INF2, INFO (and class 2 serial and version), read once.
    pub info: Option<Info>,
    /// Unix ms of the last successful poll (the injected time source's wall clock).
    pub last_poll_unix_ms: Option<i64>,
    pub wanted_power: Option<PowerWant>,
    pub wanted_mute: Option<bool>,
    /// Reachable, powered on, and muted as wanted: the stage may rely on it.
    pub ready: bool,
    /// Consecutive failed exchanges.
    pub failures: u32,
}

impl ProjectorStatus {
    fn new(spec: &ProjectorSpec, address: &str) -> ProjectorStatus {
        ProjectorStatus {
            name: spec.name.clone(),
            address: address.to_string(),
            reachable: false,
            last_error: None,
            power: None,
            muted: None,
            lamp_hours: None,
            lamps: Vec::new(),
            errors: None,
            class: None,
            info: None,
            last_poll_unix_ms: None,
            wanted_power: None,
            wanted_mute: None,
            ready: false,
            failures: 0,
        }
    }

    /// Everything wanted is in place (power and mute as asked, nothing in between).
    pub fn settled(&self) -> bool {
        let power = match self.wanted_power {
            None => true,
            Some(PowerWant::On) => self.power == Some(PowerState::On),
            Some(PowerWant::Standby) => self.power == Some(PowerState::Off),
        };
        let mute = match self.wanted_mute {
            None => true,
            // A projector in standby shows nothing: muted enough.
            Some(true) => self.muted == Some(true) || self.power == Some(PowerState::Off),
            Some(false) => self.muted == Some(false),
        };
        self.reachable && power && mute
    }
}

struct Handle {
    desired: watch::Sender<Desired>,
    status: watch::Receiver<ProjectorStatus>,
    task: JoinHandle<()>,
}

/// The running controller: one task per projector. Dropping it stops them (send
/// `Want::Mute(true)` and await `wait_settled` first where that matters).
pub struct PjlinkControl {
    handles: Vec<Handle>,
}

impl std::fmt::Debug for PjlinkControl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PjlinkControl").field("projectors", &self.handles.len()).finish()
    }
}

impl Drop for PjlinkControl {
    fn drop(&mut self) {
        for h in &self.handles {
            h.task.abort();
        }
    }
}

impl PjlinkControl {
    /// Starts one task per projector on the current tokio runtime.
    pub fn spawn(projectors: &[ProjectorSpec], timing: Timing, time: Arc<dyn TimeSource>) -> PjlinkControl {
        let handles = projectors
            .iter()
            .map(|spec| {
                let projector = Projector::new(&spec.address, spec.password.as_deref(), timing.timeout);
                let initial = ProjectorStatus::new(spec, projector.address());
                let (desired, desired_rx) = watch::channel(Desired::default());
                let (status_tx, status) = watch::channel(initial.clone());
                let worker = Worker {
                    projector,
                    timing,
                    time: time.clone(),
                    status: initial,
                    status_tx,
                    transition: None,
                };
                let task = tokio::spawn(worker.run(desired_rx));
                Handle { desired, status, task }
            })
            .collect();
        PjlinkControl { handles }
    }

    /// Asks every projector; never blocks (the latest wish wins).
    pub fn want(&self, want: Want) {
        for h in &self.handles {
            ask(&h.desired, want);
        }
    }

    /// Asks one projector (index in configuration order); out of range is ignored.
    pub fn want_one(&self, index: usize, want: Want) {
        if let Some(h) = self.handles.get(index) {
            ask(&h.desired, want);
        }
    }

    pub fn len(&self) -> usize {
        self.handles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.handles.is_empty()
    }

    /// The latest status of every projector, in configuration order.
    pub fn statuses(&self) -> Vec<ProjectorStatus> {
        self.handles.iter().map(|h| h.status.borrow().clone()).collect()
    }

    /// Watch receivers for the statuses (in configuration order).
    pub fn subscribe(&self) -> Vec<watch::Receiver<ProjectorStatus>> {
        self.handles.iter().map(|h| h.status.clone()).collect()
    }

    /// Every projector reachable, on, and muted as wanted.
    pub fn all_ready(&self) -> bool {
        self.handles.iter().all(|h| h.status.borrow().ready)
    }

    /// Waits until every projector is ready (warm-up done); false at `limit`.
    pub async fn wait_ready(&self, limit: Duration) -> bool {
        self.wait_for(limit, |s| s.ready).await
    }

    /// Waits until every projector is settled (see `ProjectorStatus::settled`); false at
    /// `limit`.
    pub async fn wait_settled(&self, limit: Duration) -> bool {
        self.wait_for(limit, ProjectorStatus::settled).await
    }

    async fn wait_for(&self, limit: Duration, done: fn(&ProjectorStatus) -> bool) -> bool {
        let mut receivers = self.subscribe();
        let wanted: Vec<Desired> = self.handles.iter().map(|h| *h.desired.borrow()).collect();
        let all = async {
            for (rx, wanted) in receivers.iter_mut().zip(wanted) {
                // Only a status published after the current wish counts.
                let current = |s: &ProjectorStatus| {
                    s.wanted_power == wanted.power && s.wanted_mute == wanted.mute && done(s)
                };
                if rx.wait_for(current).await.is_err() {
                    return false;
                }
            }
            true
        };
        tokio::time::timeout(limit, all).await.unwrap_or(false)
    }
}

/// Records a wish; wakes the projector's task only when it changes something (the event
/// loop may repeat `Mute(true)` on every fault).
fn ask(desired: &watch::Sender<Desired>, want: Want) {
    desired.send_if_modified(|d| {
        let before = *d;
        d.apply(want);
        *d != before
    });
}

struct Worker {
    projector: Projector,
    timing: Timing,
    time: Arc<dyn TimeSource>,
    status: ProjectorStatus,
    status_tx: watch::Sender<ProjectorStatus>,
    /// A warm-up or cool-down seen in progress, and since when.
    transition: Option<(PowerState, Instant)>,
}

/// After a cycle: poll again soon, at the normal interval, or back off.
enum Next {
    Soon,
    Later,
    Backoff,
}

impl Worker {
    async fn run(mut self, mut desired_rx: watch::Receiver<Desired>) {
        loop {
            let desired = *desired_rx.borrow_and_update();
            self.status.wanted_power = desired.power;
            self.status.wanted_mute = desired.mute;
            let next = self.cycle(desired).await;
            self.status.ready = self.status.reachable
                && self.status.power == Some(PowerState::On)
                && desired.mute.is_none_or(|m| self.status.muted == Some(m));
            self.status_tx.send_replace(self.status.clone());
            let delay = match next {
                Next::Soon => self.timing.busy_poll,
                Next::Later => self.timing.poll,
                Next::Backoff => self.timing.backoff(self.status.failures),
            };
            tokio::select! {
                _ = tokio::time::sleep(delay) => {}
                changed = desired_rx.changed() => if changed.is_err() { return },
            }
        }
    }

    /// One exchange: poll, act towards `desired`, record the outcome in `self.status`.
    async fn cycle(&mut self, desired: Desired) -> Next {
        match self.exchange(desired).await {
            Ok(busy) => {
                self.status.reachable = true;
                self.status.failures = 0;
                self.status.last_poll_unix_ms = Some(self.time.wall_ms());
                let overrun = self.overrun();
                let projector_says = self.status.errors.as_ref().and_then(ErrorStatus::describe);
                self.status.last_error = overrun.or(projector_says.map(|e| format!("projector reports {e}")));
                if busy { Next::Soon } else { Next::Later }
            }
            Err(e) => {
                tracing::warn!(projector = %self.status.name, "{e}");
                let projector_says = self.status.errors.as_ref().and_then(ErrorStatus::describe);
                self.status.last_error = Some(match projector_says {
                    Some(says) if !e.is_unreachable() => format!("{e}; projector reports {says}"),
                    _ => e.to_string(),
                });
                match e {
                    // Not now (warming, cooling): reachable, try again soon.
                    PjlinkError::Refused { code: ErrCode::Unavailable, .. } => {
                        self.status.reachable = true;
                        self.status.failures = 0;
                        Next::Soon
                    }
                    PjlinkError::Refused { .. } => {
                        self.status.reachable = true;
                        self.status.failures += 1;
                        Next::Backoff
                    }
                    _ => {
                        self.status.reachable = false;
                        self.status.failures += 1;
                        Next::Backoff
                    }
                }
            }
        }
    }

    /// A warm-up or cool-down beyond its limit, as an error text.
    fn overrun(&self) -> Option<String> {
        let (state, since) = self.transition?;
        let (limit, what) = match state {
            PowerState::Warming => (self.timing.warmup_max, "warm-up"),
            PowerState::Cooling => (self.timing.cooldown_max, "cool-down"),
            _ => return None,
        };
        let took = since.elapsed();
        (took > limit).then(|| {
            format!("{what} has taken {} s (expected at most {} s)", took.as_secs(), limit.as_secs())
        })
    }

    fn observe_power(&mut self, power: PowerState) {
        self.status.power = Some(power);
        match (power, self.transition) {
            (PowerState::Warming | PowerState::Cooling, Some((s, _))) if s == power => {}
            (PowerState::Warming | PowerState::Cooling, _) => self.transition = Some((power, Instant::now())),
            _ => self.transition = None,
        }
    }

    /// Sets the AV mute as wanted if it differs; projectors take it only while on.
    async fn apply_mute(&mut self, session: &mut Session, desired: Desired) -> Result<(), PjlinkError> {
        if let Some(mute) = desired.mute
            && self.status.muted != Some(mute)
            && self.status.power == Some(PowerState::On)
        {
            session.set_av_mute(mute).await?;
            self.status.muted = Some(session.av_mute().await?.video);
        }
        Ok(())
    }

    /// Returns whether something is still in progress (poll again soon).
    async fn exchange(&mut self, desired: Desired) -> Result<bool, PjlinkError> {
        let mut session = self.projector.connect().await?;
        let poll = session.poll().await?;
        self.observe_power(poll.power);
        self.status.muted = Some(poll.mute.video);
        self.status.errors = Some(poll.errors);
        self.status.lamp_hours = poll.lamps.iter().map(|l| l.hours).max();
        self.status.lamps = poll.lamps;
        let mut busy = matches!(poll.power, PowerState::Warming | PowerState::Cooling);
        if self.status.info.is_none() {
            // Read once. A refusing projector (ERR2, ERR4) is still controlled, unnamed.
            let info = match session.info().await {
                Err(PjlinkError::Refused { .. }) => Info::default(),
                other => other?,
            };
            self.status.class = info.class;
            self.status.info = Some(info);
        }

        // The mute first: it is the dark layer. Again after a power change (below).
        self.apply_mute(&mut session, desired).await?;
        match (desired.power, poll.power) {
            // Never power on while cooling down: wait until it is off (busy above).
            (Some(PowerWant::On), PowerState::Off) => {
                session.set_power(true).await?;
                let power = session.power().await?;
                self.observe_power(power);
                busy = true;
            }
            // A warming projector refuses standby (ERR3): switch it off once it is on.
            (Some(PowerWant::Standby), PowerState::On) => {
                session.set_power(false).await?;
                let power = session.power().await?;
                self.observe_power(power);
                busy = true;
            }
            _ => {}
        }
        self.apply_mute(&mut session, desired).await?;
        // Wanted on and now on but the mute not yet applied: come back soon to apply it.
        if desired.mute.is_some_and(|m| self.status.muted != Some(m))
            && matches!(self.status.power, Some(PowerState::On | PowerState::Warming))
        {
            busy = true;
        }
        Ok(busy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> ProjectorStatus {
        let spec = ProjectorSpec { name: "left".into(), address: "p:4352".into(), password: None };
        ProjectorStatus { reachable: true, ..ProjectorStatus::new(&spec, "p:4352") }
    }

    #[test]
    fn settled_means_what_was_asked() {
        let mut s = status();
        assert!(s.settled(), "nothing asked");
        s.wanted_power = Some(PowerWant::On);
        s.power = Some(PowerState::Warming);
        assert!(!s.settled());
        s.power = Some(PowerState::On);
        assert!(s.settled());
        s.wanted_mute = Some(true);
        s.muted = Some(false);
        assert!(!s.settled());
        s.wanted_power = Some(PowerWant::Standby);
        s.power = Some(PowerState::Off);
        assert!(s.settled(), "standby is dark whatever the mute");
        s.reachable = false;
        assert!(!s.settled());
    }

    #[test]
    fn backoff_doubles_up_to_the_limit() {
        let t = Timing {
            busy_poll: Duration::from_millis(500),
            retry_max: Duration::from_secs(5),
            ..Timing::default()
        };
        let ms: Vec<u128> = (1..=7).map(|f| t.backoff(f).as_millis()).collect();
        assert_eq!(ms, [500, 1000, 2000, 4000, 5000, 5000, 5000]);
        assert_eq!(t.backoff(u32::MAX), Duration::from_secs(5));
    }

    #[test]
    fn wants_are_levels_the_latest_wins() {
        let mut d = Desired::default();
        d.apply(Want::On);
        d.apply(Want::Mute(true));
        d.apply(Want::Standby);
        assert_eq!(d, Desired { power: Some(PowerWant::Standby), mute: Some(true) });
        d.apply(Want::Mute(false));
        assert_eq!(d.mute, Some(false));
    }

    #[test]
    fn status_serialises_for_the_status_page() {
        let mut s = status();
        s.power = Some(PowerState::Cooling);
        s.class = Some(Class::Two);
        let json = serde_json::to_value(&s).unwrap();
        assert_eq!(json["power"], "cooling");
        assert_eq!(json["class"], 2);
        assert_eq!(json["address"], "p:4352");
    }
}
