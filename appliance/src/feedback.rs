//! Visitor feedback: whether pressing the button does anything now (ready, showing, wait,
//! closed, budget exhausted, out of order), derived from the player's state, and the button
//! LED's patterns. The serial box hears it as `LED ...` lines (`input::serial`); a GPIO LED
//! (feature `gpio`) is driven by `run_led`.

use std::time::Duration;

use thiserror::Error;
use tokio::sync::watch;

use crate::player::State;

/// What the visitor's button box shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Availability {
    /// A press starts a showing.
    Ready,
    /// A showing is on (its closing fade included); a press cycles the scene.
    Showing,
    /// Cooldown: presses do nothing until `until_mono_ms` (the player's monotonic clock).
    Wait { until_mono_ms: u64 },
    /// Outside opening hours.
    Closed,
    /// The light budget is used up (a daily budget comes back tomorrow).
    Exhausted,
    /// Dark (no bundle, stopped by an operator, expired) or a fault: needs an operator.
    OutOfOrder,
}

impl Availability {
    /// The word of the serial protocol's `LED` line.
    pub fn led_word(self) -> &'static str {
        match self {
            Availability::Ready => "READY",
            Availability::Showing => "SHOWING",
            Availability::Wait { .. } => "WAIT",
            Availability::Closed => "CLOSED",
            Availability::Exhausted => "EXHAUSTED",
            Availability::OutOfOrder => "FAULT",
        }
    }

    /// The serial line that tells a box this state, terminated.
    pub fn serial_line(self) -> String {
        format!("LED {}\n", self.led_word())
    }
}

/// What the button box shows for `state`; `closed` is true outside opening hours. A showing
/// runs its course whatever the hours (it shows `Showing`); otherwise closed wins over the
/// rest, so visitors outside hours see "closed" rather than a fault they cannot act on.
pub fn availability(state: &State, closed: bool) -> Availability {
    match state {
        State::Showing { .. } | State::Ending { .. } => Availability::Showing,
        _ if closed => Availability::Closed,
        State::Idle => Availability::Ready,
        // The operator's commissioning pattern, then its cooldown: the visitor waits.
        State::Cooldown { until_ms } | State::Identifying { until_ms, .. } => {
            Availability::Wait { until_mono_ms: *until_ms }
        }
        State::Exhausted { .. } => Availability::Exhausted,
        State::Closed { .. } => Availability::Closed,
        State::Dark { .. } | State::Fault { .. } => Availability::OutOfOrder,
    }
}

/// Publishes `now` to the box(es), waking them only when it changed.
pub fn publish(tx: &watch::Sender<Availability>, now: Availability) {
    tx.send_if_modified(|a| {
        let changed = *a != now;
        *a = now;
        changed
    });
}

/// Blink period and lit part (ms) while a showing is on: mostly lit (the button still works:
/// it cycles the scene), with a short dip every two seconds.
pub const SHOWING_BLINK_MS: (u64, u64) = (2_000, 1_500);
/// Blink period and lit part (ms) during the cooldown: an even, slow blink (1 Hz).
pub const WAIT_BLINK_MS: (u64, u64) = (1_000, 500);

/// The LED's level at `t_ms` (any monotonic ms): steady on = ready; slow blinks = showing
/// (mostly on) and wait (half on); off = closed, budget exhausted, out of order.
pub fn led_level(availability: Availability, t_ms: u64) -> bool {
    let blink = |(period, lit): (u64, u64)| t_ms % period < lit;
    match availability {
        Availability::Ready => true,
        Availability::Showing => blink(SHOWING_BLINK_MS),
        Availability::Wait { .. } => blink(WAIT_BLINK_MS),
        Availability::Closed | Availability::Exhausted | Availability::OutOfOrder => false,
    }
}

/// Whether `availability`'s pattern changes over time (the driver then wakes to follow it).
pub fn blinks(availability: Availability) -> bool {
    matches!(availability, Availability::Showing | Availability::Wait { .. })
}

#[derive(Debug, Error)]
pub enum LedError {
    #[error("GPIO LED on BCM pin {pin}: {message}")]
    Gpio { pin: u8, message: String },
}

/// The button's LED: on or off.
pub trait Led {
    fn set(&mut self, on: bool) -> Result<(), LedError>;
}

/// Records every level set (tests).
#[derive(Clone, Debug, Default)]
pub struct RecordingLed {
    pub levels: std::sync::Arc<std::sync::Mutex<Vec<bool>>>,
}

impl RecordingLed {
    /// The levels set so far, in order.
    pub fn levels(&self) -> Vec<bool> {
        self.levels.lock().map(|l| l.clone()).unwrap_or_default()
    }
}

impl Led for RecordingLed {
    fn set(&mut self, on: bool) -> Result<(), LedError> {
        if let Ok(mut l) = self.levels.lock() {
            l.push(on);
        }
        Ok(())
    }
}

/// An LED on a Raspberry Pi GPIO pin (rppal), lit when the pin is high. Dropping it leaves
/// the pin low (rppal resets the pin when the `OutputPin` goes).
#[cfg(feature = "gpio")]
#[derive(Debug)]
pub struct GpioLed {
    pin: rppal::gpio::OutputPin,
}

#[cfg(feature = "gpio")]
impl GpioLed {
    pub fn open(pin: u8) -> Result<GpioLed, LedError> {
        let gpio = rppal::gpio::Gpio::new().map_err(|e| LedError::Gpio { pin, message: e.to_string() })?;
        let pin =
            gpio.get(pin).map_err(|e| LedError::Gpio { pin, message: e.to_string() })?.into_output_low();
        Ok(GpioLed { pin })
    }
}

#[cfg(feature = "gpio")]
impl Led for GpioLed {
    fn set(&mut self, on: bool) -> Result<(), LedError> {
        if on {
            self.pin.set_high();
        } else {
            self.pin.set_low();
        }
        Ok(())
    }
}

/// How often a blinking pattern is looked at (well under its half-periods).
pub const LED_STEP: Duration = Duration::from_millis(50);

/// Sets the LED only when its level changes.
#[derive(Debug, Default)]
pub struct LedDriver {
    last: Option<bool>,
}

impl LedDriver {
    /// Brings `led` to the level of `availability` at `t_ms`.
    pub fn update(&mut self, led: &mut dyn Led, availability: Availability, t_ms: u64) {
        let level = led_level(availability, t_ms);
        if self.last == Some(level) {
            return;
        }
        match led.set(level) {
            Ok(()) => self.last = Some(level),
            // Logged once per failed change; the next change tries again.
            Err(e) => {
                tracing::warn!("{e}");
                self.last = Some(level);
            }
        }
    }
}

/// Drives `led` from the published availability until the sender goes away; the pattern's
/// time runs from this task's start (tokio's clock, so tests can pause it).
pub async fn run_led(mut led: impl Led, mut rx: watch::Receiver<Availability>) {
    let start = tokio::time::Instant::now();
    let mut driver = LedDriver::default();
    loop {
        let now = *rx.borrow_and_update();
        driver.update(&mut led, now, start.elapsed().as_millis() as u64);
        let step = async {
            if blinks(now) { tokio::time::sleep(LED_STEP).await } else { std::future::pending().await }
        };
        tokio::select! {
            changed = rx.changed() => if changed.is_err() { return },
            _ = step => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::player::Now;

    fn states() -> Vec<(State, Availability)> {
        let now = Now { unix_ms: 0, mono_ms: 0 };
        vec![
            (State::Dark { reason: "no bundle".into() }, Availability::OutOfOrder),
            (State::Idle, Availability::Ready),
            (
                State::Showing { scene: 0, started: now, scenes: vec![0], last_change_ms: 0 },
                Availability::Showing,
            ),
            (
                State::Ending { from: 0, to: crate::show::Look::Off, fade_start_ms: 5, step: 1, steps: 3 },
                Availability::Showing,
            ),
            (State::Cooldown { until_ms: 42 }, Availability::Wait { until_mono_ms: 42 }),
            (State::Identifying { projector: 1, until_ms: 43 }, Availability::Wait { until_mono_ms: 43 }),
            (State::Exhausted { reason: "daily".into(), retry_ms: 9 }, Availability::Exhausted),
            (State::Fault { reason: "ledger: locked".into() }, Availability::OutOfOrder),
        ]
    }

    #[test]
    fn availability_of_every_state_open() {
        for (state, want) in states() {
            assert_eq!(availability(&state, false), want, "{state:?}");
        }
    }

    #[test]
    fn closed_wins_except_during_a_showing() {
        for (state, open) in states() {
            let want =
                if open == Availability::Showing { Availability::Showing } else { Availability::Closed };
            assert_eq!(availability(&state, true), want, "{state:?}");
        }
    }

    #[test]
    fn the_closed_state_shows_closed() {
        let closed = State::Closed { reason: "closed: opens Tue 10:00".into() };
        assert_eq!(availability(&closed, true), Availability::Closed);
        assert_eq!(availability(&closed, false), Availability::Closed);
    }

    #[test]
    fn led_words_are_the_documented_ones() {
        let words: Vec<_> = states().into_iter().map(|(s, _)| availability(&s, false).led_word()).collect();
        assert_eq!(words, ["FAULT", "READY", "SHOWING", "SHOWING", "WAIT", "WAIT", "EXHAUSTED", "FAULT"]);
        assert_eq!(Availability::Closed.serial_line(), "LED CLOSED\n");
    }

    #[test]
    fn led_patterns() {
        let over = |a, period: u64| (0..period).step_by(10).filter(|&t| led_level(a, t)).count() as u64 * 10;
        assert_eq!(over(Availability::Ready, 2000), 2000);
        assert_eq!(over(Availability::Showing, 2000), 1500);
        assert_eq!(over(Availability::Wait { until_mono_ms: 7 }, 1000), 500);
        for a in [Availability::Closed, Availability::Exhausted, Availability::OutOfOrder] {
            assert_eq!(over(a, 4000), 0, "{a:?}");
        }
        // Periodic: the same level a period later.
        for t in [0, 499, 500, 999, 1_234_567] {
            let w = Availability::Wait { until_mono_ms: 0 };
            assert_eq!(led_level(w, t), led_level(w, t + WAIT_BLINK_MS.0));
        }
        assert!(led_level(Availability::Wait { until_mono_ms: 0 }, 499));
        assert!(!led_level(Availability::Wait { until_mono_ms: 0 }, 500));
    }

    #[test]
    fn driver_sets_only_changes() {
        let mut led = RecordingLed::default();
        let mut d = LedDriver::default();
        for t in (0..2000).step_by(50) {
            d.update(&mut led, Availability::Wait { until_mono_ms: 0 }, t);
        }
        d.update(&mut led, Availability::Ready, 2000);
        d.update(&mut led, Availability::Ready, 2050);
        d.update(&mut led, Availability::Closed, 2100);
        assert_eq!(led.levels(), [true, false, true, false, true, false]);
    }

    #[test]
    fn publish_wakes_only_on_change() {
        let (tx, mut rx) = watch::channel(Availability::OutOfOrder);
        rx.borrow_and_update();
        publish(&tx, Availability::OutOfOrder);
        assert!(!rx.has_changed().unwrap());
        publish(&tx, Availability::Ready);
        assert!(rx.has_changed().unwrap());
        assert_eq!(*rx.borrow_and_update(), Availability::Ready);
    }

    #[tokio::test(start_paused = true)]
    async fn led_task_follows_changes_and_blinks() {
        let led = RecordingLed::default();
        let (tx, rx) = watch::channel(Availability::Ready);
        let task = tokio::spawn(run_led(led.clone(), rx));
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert_eq!(led.levels(), [true]);
        publish(&tx, Availability::Wait { until_mono_ms: 0 });
        // Two seconds of a 1 Hz blink: it went off and on again at least twice.
        tokio::time::sleep(Duration::from_millis(2_000)).await;
        let n = led.levels().len();
        assert!((4..=7).contains(&n), "{:?}", led.levels());
        publish(&tx, Availability::Closed);
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(led.levels().last(), Some(&false));
        drop(tx);
        tokio::time::timeout(Duration::from_secs(1), task).await.unwrap().unwrap();
    }
}
