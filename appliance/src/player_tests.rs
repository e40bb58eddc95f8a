//! Player state-machine tests on an injected clock: every transition, hostile buttons, budgets
//! running out, faults mid-fade, and random event sequences checked against invariants.

use std::collections::BTreeMap;
use std::sync::Arc;

use proptest::prelude::*;

use super::*;
use crate::config::IdleMode;
use crate::show::{Policy, Response, Scene, SceneKind, Show};

const MAX_SHOW: u64 = 30_000;
const COOLDOWN: u64 = 10_000;
const FADE: u64 = 1_000;
const RESERVE: u64 = 5_000;

fn scene(id: &str, kind: SceneKind, lux: f64) -> Scene {
    Scene { id: id.into(), name: id.into(), kind, peak_lux: lux }
}

fn show(idle: IdleMode) -> Arc<Show> {
    Arc::new(Show {
        object_id: "vase".into(),
        version: 1,
        bundle_hash: "h".into(),
        projectors: vec![(1, 1)],
        scenes: vec![
            scene("original", SceneKind::Original, 20.0),
            scene("r1", SceneKind::Restoration, 50.0),
            scene("r2", SceneKind::Restoration, 40.0),
            scene("relit", SceneKind::Relit, 45.0),
        ],
        black_lux: 0.5,
        responses: vec![Response::gamma(2.2)],
        policy: Policy {
            max_showing_ms: MAX_SHOW,
            cooldown_ms: COOLDOWN,
            daily_lux_hours: 1e9,
            annual_lux_hours: 1e9,
            warn_at: vec![0.75, 0.9],
        },
        idle: match idle {
            IdleMode::Off => Look::Off,
            IdleMode::Black => Look::Black,
            IdleMode::Original => Look::Scene(0),
        },
        expires_unix_ms: None,
        identify: vec![Some(crate::identify::Pattern { level: 200, peak_lux: 35.0 })],
    })
}

fn settings() -> PlayerSettings {
    PlayerSettings {
        fade_ms: FADE,
        fade_fps: 10,
        min_press_interval_ms: 300,
        max_showing_ms: None,
        cooldown_ms: None,
        reserve_ms: RESERVE,
        renew_ahead_ms: 1_000,
        light_off_latency_ms: LATENCY,
    }
}

const LATENCY: u64 = 100;

#[derive(Clone, Debug)]
struct Lease {
    kind: LightKind,
    lux: f64,
    start: i64,
    end: i64,
}

/// An in-memory accountant with one total budget (lux·ms) that can be made to fail.
#[derive(Debug, Default)]
struct Books {
    leases: BTreeMap<LeaseId, Lease>,
    next: LeaseId,
    budget_lux_ms: f64,
    fail: bool,
    showings: Vec<(i64, i64, String)>,
}

impl Books {
    fn with_budget(lux_hours: f64) -> Books {
        Books { budget_lux_ms: lux_hours * 3_600_000.0, ..Books::default() }
    }
    fn used(&self) -> f64 {
        self.leases.values().map(|l| l.lux * (l.end - l.start) as f64).sum()
    }
    fn check(&self, extra: f64) -> Result<(), Refusal> {
        if self.fail {
            return Err(Refusal::Failed("disk full".into()));
        }
        if self.used() + extra > self.budget_lux_ms {
            return Err(Refusal::Exhausted("total".into()));
        }
        Ok(())
    }
}

impl Accountant for Books {
    fn reserve(
        &mut self,
        kind: LightKind,
        _: &str,
        lux: f64,
        from: i64,
        until: i64,
    ) -> Result<LeaseId, Refusal> {
        self.check(lux * (until - from) as f64)?;
        self.next += 1;
        self.leases.insert(self.next, Lease { kind, lux, start: from, end: until });
        Ok(self.next)
    }
    fn extend(&mut self, id: LeaseId, until: i64) -> Result<(), Refusal> {
        let l = self.leases[&id].clone();
        self.check(l.lux * (until - l.end).max(0) as f64)?;
        self.leases.get_mut(&id).unwrap().end = l.end.max(until);
        Ok(())
    }
    fn commit(&mut self, id: LeaseId, end: i64) -> Result<(), Refusal> {
        if self.fail {
            return Err(Refusal::Failed("disk full".into()));
        }
        // The actual end, as the ledger does (also past the reservation).
        let l = self.leases.get_mut(&id).unwrap();
        l.end = end.max(l.start);
        Ok(())
    }
    fn record_showing(&mut self, start: i64, end: i64, _: &[String], by: &str) -> Result<(), Refusal> {
        self.showings.push((start, end, by.into()));
        Ok(())
    }
    fn last_showing_end(&self) -> Option<i64> {
        self.leases
            .values()
            .filter(|l| matches!(l.kind, LightKind::Showing | LightKind::Fade))
            .map(|l| l.end)
            .max()
    }
}

/// The player, its books, a fake clock and the light timeline the outputs produced.
struct Sim {
    idle: IdleMode,
    p: Player,
    books: Books,
    now: Now,
    /// (time ms, look lux) whenever the light changes; the last entry holds until now.
    light: Vec<(i64, f64)>,
    commands: Vec<(u64, Command)>,
}

impl Sim {
    fn new(idle: IdleMode, budget_lux_hours: f64) -> Sim {
        let mut sim = Sim {
            idle,
            p: Player::new(settings()),
            books: Books::with_budget(budget_lux_hours),
            now: Now { mono_ms: 1_000, unix_ms: 1_700_000_000_000 },
            light: vec![(1_700_000_000_000, 0.0)],
            commands: Vec::new(),
        };
        sim.event(Event::Load(show(idle)));
        sim
    }

    fn lux(&self, look: Look) -> f64 {
        let s = show(self.idle);
        match look {
            Look::Scene(i) => s.scenes[i].peak_lux,
            Look::Black => s.black_lux,
            Look::Off => 0.0,
            Look::Identify(_) => 35.0,
        }
    }

    fn event(&mut self, e: Event) {
        let cmds = self.p.handle(self.now, e, &mut self.books);
        for c in cmds {
            let lux = match c {
                Command::Show(l) => self.lux(l),
                // A fade frame's light is at most the brighter end's (mix_linear's property).
                Command::Fade { from, to, .. } => self.lux(from).max(self.lux(to)),
            };
            self.light.push((self.now.unix_ms, lux));
            self.commands.push((self.now.mono_ms, c));
        }
        self.p.settle(self.now, &mut self.books);
    }

    /// Advances the clock to `t` (ms from now), ticking at every deadline on the way.
    fn advance(&mut self, ms: u64) {
        let target = self.now.mono_ms + ms;
        while let Some(d) = self.p.next_deadline() {
            if d > target {
                break;
            }
            let d = d.max(self.now.mono_ms);
            self.now = self.now.plus(d - self.now.mono_ms);
            self.event(Event::Tick);
        }
        self.now = self.now.plus(target - self.now.mono_ms);
    }

    fn state(&self) -> &'static str {
        self.p.state().name()
    }

    fn shows(&self) -> Vec<Look> {
        self.commands
            .iter()
            .filter_map(|(_, c)| match c {
                Command::Show(l) => Some(*l),
                _ => None,
            })
            .collect()
    }

    /// Every lit instant up to now is covered by leases paying at least its lux, and the
    /// books hold at least the true exposure.
    fn verify_invariants(&self) {
        let mut points: Vec<i64> = self.light.iter().map(|l| l.0).collect();
        for l in self.books.leases.values() {
            points.extend([l.start, l.end - 1, l.end]);
        }
        points.push(self.now.unix_ms - 1);
        points.sort();
        let mut true_exposure = 0.0;
        for (i, &(t, lux)) in self.light.iter().enumerate() {
            let end = self.light.get(i + 1).map_or(self.now.unix_ms, |n| n.0);
            true_exposure += lux * (end - t) as f64;
            if lux <= 0.0 {
                continue;
            }
            for &p in points.iter().filter(|&&p| p >= t && p < end) {
                let paid: f64 = self
                    .books
                    .leases
                    .values()
                    .filter(|l| l.start <= p && p < l.end)
                    .map(|l| l.lux)
                    .fold(0.0, f64::max);
                assert!(paid >= lux, "at {p}: light {lux} lx, leases pay {paid} lx");
            }
        }
        assert!(
            self.books.used() + 1e-6 >= true_exposure,
            "books {} < true {}",
            self.books.used(),
            true_exposure
        );
    }

    /// Longest continuous lit stretch of restoration light (lux above the idle look's).
    fn longest_showing_ms(&self, idle_lux: f64) -> i64 {
        let (mut longest, mut since) = (0, None);
        for (i, &(t, lux)) in self.light.iter().enumerate() {
            let end = self.light.get(i + 1).map_or(self.now.unix_ms, |n| n.0);
            if lux > idle_lux {
                let s = *since.get_or_insert(t);
                longest = longest.max(end - s);
            } else {
                since = None;
            }
        }
        longest
    }
}

#[test]
fn idle_press_show_timer_fade_cooldown_idle() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    assert_eq!(s.state(), "idle");
    assert_eq!(s.shows(), vec![Look::Scene(0)]);
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    assert_eq!(s.p.look(), Look::Scene(1));
    s.advance(MAX_SHOW - FADE - 1);
    assert_eq!(s.state(), "showing");
    s.advance(1);
    assert_eq!(s.state(), "ending");
    s.advance(FADE / 2);
    assert_eq!(s.state(), "ending");
    let fades: Vec<f32> = s
        .commands
        .iter()
        .filter_map(|(_, c)| match c {
            Command::Fade { from: Look::Scene(1), to: Look::Scene(0), t } => Some(*t),
            _ => None,
        })
        .collect();
    assert!(fades.len() >= 4 && fades.windows(2).all(|w| w[0] < w[1]), "{fades:?}");
    s.advance(FADE / 2);
    assert_eq!(s.state(), "cooldown");
    assert_eq!(s.p.look(), Look::Scene(0));
    s.advance(COOLDOWN);
    assert_eq!(s.state(), "idle");
    s.verify_invariants();
    assert_eq!(s.books.showings.len(), 1);
    assert_eq!(s.books.showings[0].2, "timer");
    assert!(s.longest_showing_ms(20.0) <= MAX_SHOW as i64);
}

#[test]
fn presses_cycle_restorations_then_relit_and_wrap() {
    let mut s = Sim::new(IdleMode::Off, 1e9);
    assert_eq!(s.p.look(), Look::Off);
    for want in [1, 2, 3, 1] {
        s.event(Event::Press);
        assert_eq!(s.p.look(), Look::Scene(want));
        s.advance(500);
    }
    s.verify_invariants();
}

#[test]
fn button_held_for_an_hour_ends_on_time_and_never_restarts() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    // Held: no release, no further edges, for an hour.
    s.advance(3_600_000);
    s.event(Event::Release);
    assert_eq!(s.state(), "idle");
    assert_eq!(s.books.showings.len(), 1);
    assert!(s.longest_showing_ms(20.0) <= MAX_SHOW as i64);
    s.verify_invariants();
}

#[test]
fn a_thousand_presses_a_second_cannot_extend_or_strobe() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    for _ in 0..120_000 {
        s.event(Event::Press);
        s.event(Event::Release);
        s.advance(1);
    }
    // 120 s of flooding: each showing is capped, then a cooldown without light changes.
    assert!(s.longest_showing_ms(20.0) <= MAX_SHOW as i64, "{}", s.longest_showing_ms(20.0));
    assert!(s.books.showings.len() <= 3, "{}", s.books.showings.len());
    let changes: Vec<u64> = s
        .commands
        .iter()
        .filter(|(_, c)| matches!(c, Command::Show(Look::Scene(i)) if *i != 0))
        .map(|(t, _)| *t)
        .collect();
    assert!(changes.windows(2).all(|w| w[1] - w[0] >= 300), "scene changes closer than the press interval");
    s.verify_invariants();
}

#[test]
fn press_during_cooldown_and_fade_is_ignored() {
    let mut s = Sim::new(IdleMode::Black, 1e9);
    s.event(Event::Press);
    s.advance(MAX_SHOW - FADE + 100);
    assert_eq!(s.state(), "ending");
    s.event(Event::Press);
    assert_eq!(s.state(), "ending");
    s.advance(FADE);
    assert_eq!(s.state(), "cooldown");
    let before = s.commands.len();
    s.event(Event::Press);
    s.advance(COOLDOWN - 1_000);
    s.event(Event::Press);
    assert_eq!(s.state(), "cooldown");
    assert_eq!(s.p.look(), Look::Black);
    assert!(
        s.commands[before..]
            .iter()
            .all(|(_, c)| *c == Command::Show(Look::Black) || matches!(c, Command::Show(Look::Black)))
    );
    s.advance(1_000);
    assert_eq!(s.state(), "idle");
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    s.verify_invariants();
}

#[test]
fn budget_running_out_mid_showing_goes_dark() {
    // 50 lx for 20 s is about 0.28 lx·h: the budget allows about 12 s of the restoration.
    let mut s = Sim::new(IdleMode::Off, 50.0 * 12.0 / 3600.0);
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    s.advance(20_000);
    assert_eq!(s.state(), "budget-exhausted");
    assert_eq!(s.p.look(), Look::Off);
    assert_eq!(s.books.showings.last().unwrap().2, "budget");
    assert!(s.books.used() <= s.books.budget_lux_ms + 1e-6);
    // Presses while exhausted find no budget and stay dark.
    s.event(Event::Press);
    assert_eq!(s.p.look(), Look::Off);
    s.verify_invariants();
}

#[test]
fn exhausted_budget_is_retried_and_recovers_when_room_returns() {
    let mut s = Sim::new(IdleMode::Black, 0.0);
    assert_eq!(s.state(), "budget-exhausted");
    assert_eq!(s.p.look(), Look::Off);
    s.books.budget_lux_ms = 1e12;
    s.advance(EXHAUSTED_RETRY_MS);
    assert_eq!(s.state(), "idle");
    assert_eq!(s.p.look(), Look::Black);
    s.verify_invariants();
}

#[test]
fn fault_mid_fade_goes_dark_at_once_and_stays_dark() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.advance(MAX_SHOW - FADE / 2);
    assert_eq!(s.state(), "ending");
    s.event(Event::Fault("output lost".into()));
    assert_eq!(s.state(), "fault");
    assert_eq!(s.commands.last().unwrap().1, Command::Show(Look::Off));
    let n = s.commands.len();
    s.event(Event::Press);
    s.advance(3_600_000);
    assert_eq!(s.commands.len(), n, "no light after a fault");
    assert!(s.p.next_deadline().is_none());
    // A reload brings it back.
    s.event(Event::Load(show(s.idle)));
    assert_eq!(s.state(), "idle");
    s.verify_invariants();
}

#[test]
fn ledger_failure_is_a_fault() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.books.fail = true;
    s.event(Event::Press);
    assert_eq!(s.state(), "fault");
    assert_eq!(s.p.look(), Look::Off);
}

#[test]
fn ledger_failure_on_renewal_is_a_fault() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.advance(1_000);
    s.books.fail = true;
    s.advance(RESERVE);
    assert_eq!(s.state(), "fault");
    assert_eq!(s.p.look(), Look::Off);
}

#[test]
fn stop_goes_dark_and_load_returns_to_idle() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.event(Event::Stop);
    assert_eq!(s.state(), "dark");
    assert_eq!(s.p.look(), Look::Off);
    s.event(Event::Press);
    assert_eq!(s.p.look(), Look::Off);
    assert_eq!(s.books.showings.last().unwrap().2, "stop");
    s.event(Event::Unload("bundle refused".into()));
    assert_eq!(s.state(), "dark");
    // A stopped showing is still followed by its cooldown (from the light's end, latency
    // included), then idle.
    s.event(Event::Load(show(s.idle)));
    assert_eq!(s.state(), "cooldown");
    s.advance(COOLDOWN + LATENCY + 1);
    assert_eq!(s.state(), "idle");
    s.verify_invariants();
}

#[test]
fn idle_light_is_paid_for_continuously() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.advance(24 * 3_600_000);
    s.verify_invariants();
    // 20 lx for a day is 480 lx·h, give or take one reservation.
    let used_lxh = s.books.used() / 3_600_000.0;
    assert!((480.0..480.0 + 20.0 * 5.0 / 3600.0 + 1e-9).contains(&used_lxh), "{used_lxh}");
}

#[test]
fn config_can_shorten_the_showing_and_lengthen_the_cooldown() {
    let mut s = Sim::new(IdleMode::Off, 1e9);
    s.p.settings.max_showing_ms = Some(5_000);
    s.p.settings.cooldown_ms = Some(COOLDOWN * 2);
    s.event(Event::Press);
    s.advance(5_000);
    assert_eq!(s.state(), "cooldown");
    s.advance(COOLDOWN);
    assert_eq!(s.state(), "cooldown");
    s.advance(COOLDOWN);
    assert_eq!(s.state(), "idle");
    // A longer configured maximum than the policy's is ignored.
    s.p.settings.max_showing_ms = Some(MAX_SHOW * 10);
    s.event(Event::Press);
    s.advance(MAX_SHOW);
    assert_eq!(s.state(), "cooldown");
}

#[test]
fn no_bundle_means_dark() {
    let mut p = Player::new(settings());
    let mut b = Books::with_budget(1e9);
    let now = Now { mono_ms: 0, unix_ms: 0 };
    assert!(p.handle(now, Event::Press, &mut b).is_empty());
    assert_eq!(p.state().name(), "dark");
    assert_eq!(p.next_deadline(), None);
}

#[derive(Clone, Debug)]
enum Op {
    Press,
    Release,
    Wait(u64),
    Fault,
    Stop,
    Load,
    Shrink,
    Close,
    Open,
    Identify(u64),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        8 => Just(Op::Press),
        2 => Just(Op::Release),
        10 => (0u64..40_000).prop_map(Op::Wait),
        1 => Just(Op::Fault),
        1 => Just(Op::Stop),
        1 => Just(Op::Load),
        1 => Just(Op::Shrink),
        2 => Just(Op::Close),
        2 => Just(Op::Open),
        1 => (1u64..60_000).prop_map(Op::Identify),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn random_sequences_keep_the_invariants(
        ops in proptest::collection::vec(op(), 1..60),
        idle in prop_oneof![Just(IdleMode::Original), Just(IdleMode::Black), Just(IdleMode::Off)],
    ) {
        let mut s = Sim::new(idle, 1e9);
        for o in ops {
            match o {
                Op::Press => s.event(Event::Press),
                Op::Release => s.event(Event::Release),
                Op::Wait(ms) => s.advance(ms),
                Op::Fault => s.event(Event::Fault("test".into())),
                Op::Stop => s.event(Event::Stop),
                Op::Load => s.event(Event::Load(show(idle))),
                Op::Shrink => s.books.budget_lux_ms = s.books.used() + 50.0 * 3_000.0,
                Op::Close => s.event(Event::Close { reason: "closed: opens Tue 10:00".into() }),
                Op::Open => s.event(Event::Open),
                Op::Identify(ms) => s.event(Event::Identify { projector: 0, ms }),
            }
            if matches!(
                s.p.state(),
                State::Fault { .. } | State::Dark { .. } | State::Exhausted { .. } | State::Closed { .. }
            ) {
                prop_assert_eq!(s.p.look(), Look::Off);
            }
            // Closed: no light and no reservation (only a closing fade still runs, to dark).
            if s.p.is_closed() && !matches!(s.p.state(), State::Ending { .. }) {
                prop_assert_eq!(s.p.look(), Look::Off);
                prop_assert_eq!(s.p.leased_lux(), 0.0);
                let n = s.books.leases.len();
                s.event(Event::Press);
                prop_assert_eq!(s.books.leases.len(), n);
                prop_assert_eq!(s.p.look(), Look::Off);
            }
        }
        s.verify_invariants();
        let idle_lux = match idle { IdleMode::Original => 20.0, IdleMode::Black => 0.5, IdleMode::Off => 0.0 };
        prop_assert!(s.longest_showing_ms(idle_lux) <= MAX_SHOW as i64);
        prop_assert!(s.books.used() <= s.books.budget_lux_ms + 1e-6);
    }
}

#[test]
fn blank_comes_before_any_ledger_write_at_a_fault() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.advance(2_000);
    let showings = s.books.showings.len();
    let open: Vec<i64> = s.books.leases.values().map(|l| l.end).collect();
    // The player's answer to a fault: dark first; the showing record and the commit wait
    // for `settle`, after the outputs went dark.
    let cmds = s.p.handle(s.now, Event::Fault("output lost".into()), &mut s.books);
    assert_eq!(cmds, vec![Command::Show(Look::Off)]);
    assert_eq!(s.books.showings.len(), showings);
    assert_eq!(s.books.leases.values().map(|l| l.end).collect::<Vec<_>>(), open);
    assert!(s.p.has_deferred());
    s.p.settle(s.now, &mut s.books);
    assert_eq!(s.books.showings.len(), showings + 1);
    assert!(!s.p.has_deferred());
}

#[test]
fn a_stall_past_the_lease_is_paid_when_the_process_runs_again() {
    // Stopped (SIGSTOP, starved) while lit for longer than the lease and past the showing's
    // end: nothing ticks, the light stays on. On resume the timer ends the showing and the
    // old lease is committed at the actual end, not its reserved one.
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.now = s.now.plus(MAX_SHOW + 3 * RESERVE);
    s.event(Event::Tick);
    s.verify_invariants();
    assert_ne!(s.state(), "showing");
}

#[test]
fn presses_near_exhaustion_never_strobe() {
    // Room for about 8 s of the restoration: presses at 50 per second for a minute.
    let mut s = Sim::new(IdleMode::Off, 50.0 * 8.0 / 3600.0);
    for _ in 0..3_000 {
        s.event(Event::Press);
        s.advance(20);
    }
    s.verify_invariants();
    let lit_starts = s.light.windows(2).filter(|w| w[0].1 == 0.0 && w[1].1 > 0.0).count();
    assert!(lit_starts <= 2, "{lit_starts} separate flashes of light");
    assert!(s.books.used() <= s.books.budget_lux_ms + 1e-6);
}

#[test]
fn cooldown_holds_across_a_reload() {
    let mut s = Sim::new(IdleMode::Black, 1e9);
    s.event(Event::Press);
    s.advance(MAX_SHOW);
    assert_eq!(s.state(), "cooldown");
    // A reload (or a restart: the books are the ledger) in the middle of the cooldown.
    s.event(Event::Load(show(s.idle)));
    assert_eq!(s.state(), "cooldown");
    s.event(Event::Press);
    assert_ne!(s.state(), "showing");
    // Counted from the light's end (the light-off latency included).
    s.advance(COOLDOWN + LATENCY + 1);
    assert_eq!(s.state(), "idle");
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    s.verify_invariants();
}

const CLOSED: &str = "closed: opens Tue 10:00";

fn close() -> Event {
    Event::Close { reason: CLOSED.into() }
}

#[test]
fn press_while_closed_is_refused_with_the_reason() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(close());
    assert_eq!(s.p.state(), &State::Closed { reason: CLOSED.into() });
    assert!(s.p.is_closed());
    assert_eq!(s.p.closed_reason(), Some(CLOSED));
    assert_eq!(s.p.look(), Look::Off);
    assert_eq!(s.p.leased_lux(), 0.0);
    let (n, leases) = (s.commands.len(), s.books.leases.len());
    s.event(Event::Press);
    s.advance(3_600_000);
    s.event(Event::Press);
    assert_eq!(s.commands.len(), n, "no light while closed");
    assert_eq!(s.books.leases.len(), leases, "no reservation while closed");
    assert!(s.p.next_deadline().is_none());
    // A reload while closed stays closed.
    s.event(Event::Load(show(s.idle)));
    assert_eq!(s.state(), "closed");
    assert_eq!(s.p.look(), Look::Off);
    s.verify_invariants();
}

#[test]
fn a_showing_at_closing_time_fades_out_then_goes_dark() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.advance(5_000);
    s.event(close());
    // The normal fade, towards dark rather than the idle scene: no cut.
    assert_eq!(s.state(), "ending");
    assert_eq!(s.p.look(), Look::Scene(1));
    s.advance(FADE / 2);
    let fades: Vec<f32> = s
        .commands
        .iter()
        .filter_map(|(_, c)| match c {
            Command::Fade { from: Look::Scene(1), to: Look::Off, t } => Some(*t),
            _ => None,
        })
        .collect();
    assert!(fades.len() >= 3 && fades.windows(2).all(|w| w[0] < w[1]), "{fades:?}");
    s.advance(FADE / 2);
    assert_eq!(s.state(), "closed");
    assert_eq!(s.p.look(), Look::Off);
    assert_eq!(s.p.leased_lux(), 0.0);
    assert_eq!(s.books.showings.last().unwrap().2, "closing");
    // The showing was capped by closing, not lengthened.
    assert!(s.longest_showing_ms(20.0) <= 5_000 + FADE as i64);
    s.verify_invariants();
}

#[test]
fn closing_during_idle_or_cooldown_goes_dark_and_reopening_restores_idle() {
    let mut s = Sim::new(IdleMode::Black, 1e9);
    s.event(close());
    assert_eq!(s.state(), "closed");
    assert_eq!(s.p.look(), Look::Off);
    s.event(Event::Open);
    assert!(!s.p.is_closed());
    assert_eq!(s.state(), "idle");
    assert_eq!(s.p.look(), Look::Black);
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    s.advance(MAX_SHOW);
    assert_eq!(s.state(), "cooldown");
    // Closed in the cooldown and open again before it ran out: the cooldown still holds.
    s.event(close());
    assert_eq!(s.state(), "closed");
    s.advance(COOLDOWN / 2);
    s.event(Event::Open);
    assert_eq!(s.state(), "cooldown");
    s.advance(COOLDOWN);
    assert_eq!(s.state(), "idle");
    s.event(Event::Press);
    assert_eq!(s.state(), "showing");
    s.verify_invariants();
}

#[test]
fn opening_during_the_closing_fade_ends_in_the_cooldown() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Press);
    s.event(close());
    assert_eq!(s.state(), "ending");
    s.event(Event::Open);
    s.advance(FADE);
    assert_eq!(s.state(), "cooldown");
    assert_eq!(s.p.look(), Look::Scene(0));
    s.verify_invariants();
}

#[test]
fn a_stop_or_fault_while_closed_keeps_its_reason_and_the_stage_stays_closed() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(close());
    s.event(Event::Stop);
    assert_eq!(s.state(), "dark");
    assert!(s.p.is_closed());
    // The operator's reload brings the bundle back, still closed.
    s.event(Event::Load(show(s.idle)));
    assert_eq!(s.state(), "closed");
    // No commissioning pattern while closed either (identify is from idle only).
    s.event(close());
    s.event(Event::Identify { projector: 0, ms: 10_000 });
    assert_eq!(s.state(), "closed");
    assert_eq!(s.p.look(), Look::Off);
    s.event(Event::Open);
    assert_eq!(s.state(), "idle");
    s.verify_invariants();
}

#[test]
fn identify_from_idle_is_paid_and_ends_by_itself() {
    let mut s = Sim::new(IdleMode::Original, 1e9);
    s.event(Event::Identify { projector: 0, ms: 10_000 });
    assert_eq!(s.state(), "identifying");
    assert_eq!(s.p.look(), Look::Identify(0));
    let lease = s.books.leases.values().last().unwrap().clone();
    assert_eq!((lease.kind, lease.lux), (LightKind::Identify, 35.0));
    // A visitor's press does not cut into it (nor start a showing on top of it).
    s.event(Event::Press);
    assert_eq!(s.state(), "identifying");
    s.advance(10_000);
    assert_eq!(s.state(), "cooldown");
    assert_eq!(s.p.look(), Look::Scene(0));
    s.advance(COOLDOWN + LATENCY + 1);
    assert_eq!(s.state(), "idle");
    // Never longer than the policy's longest showing; stop ends it at once.
    s.event(Event::Identify { projector: 0, ms: 10 * MAX_SHOW });
    s.advance(MAX_SHOW - 1);
    assert_eq!(s.state(), "identifying");
    s.event(Event::Stop);
    assert_eq!(s.p.look(), Look::Off);
    s.verify_invariants();
}

#[test]
fn identify_only_from_idle_and_only_a_projector_with_a_pattern() {
    let mut s = Sim::new(IdleMode::Black, 1e9);
    s.event(Event::Press);
    s.event(Event::Identify { projector: 0, ms: 10_000 });
    assert_eq!(s.state(), "showing");
    s.advance(MAX_SHOW);
    assert_eq!(s.state(), "cooldown");
    s.event(Event::Identify { projector: 0, ms: 10_000 });
    assert_eq!(s.state(), "cooldown", "the object rests after a showing, also from test patterns");
    s.advance(COOLDOWN + LATENCY + 1);
    s.event(Event::Identify { projector: 1, ms: 10_000 });
    assert_eq!(s.state(), "idle", "projector 1 does not exist");
    s.verify_invariants();
}
