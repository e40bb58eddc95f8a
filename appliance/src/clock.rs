//! Time, injected. The player's timers run on a monotonic clock that counts suspend
//! (CLOCK_BOOTTIME); the ledger's timeline is the wall clock read once at start, raised to the
//! ledger's persisted high-water mark, and advanced by that monotonic clock from then on. So a
//! wall-clock step during a run — back or forward, by an operator, NTP or an attacker — never
//! shrinks a recorded interval, stretches one, or re-opens a budget window; it is only
//! reported (see ARCHITECTURE.md, "Time").

use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};

/// The time, as the player and the ledger see it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Now {
    /// Monotonic milliseconds (any origin; counts suspend on the real clock).
    pub mono_ms: u64,
    /// Ledger time: Unix milliseconds that never go back within a run and advance exactly
    /// as `mono_ms` does.
    pub unix_ms: i64,
}

impl Now {
    pub fn plus(self, ms: u64) -> Now {
        Now { mono_ms: self.mono_ms + ms, unix_ms: self.unix_ms + ms as i64 }
    }
}

/// A source of `Now`.
pub trait Clock: Send {
    fn now(&self) -> Now;
    /// How far the wall clock is from ledger time now (ms; positive: the wall clock is ahead).
    fn wall_skew_ms(&self) -> i64 {
        0
    }
}

/// The raw clocks the machine offers.
pub trait TimeSource: Send + Sync {
    /// Milliseconds of a monotonic clock that counts suspend.
    fn boot_ms(&self) -> u64;
    /// The wall clock, Unix milliseconds (may step either way at any time).
    fn wall_ms(&self) -> i64;
}

/// The machine's clocks: CLOCK_BOOTTIME and the system wall clock.
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemTime;

/// Microseconds of `clock` (0 if unreadable, which Linux never is for these clocks).
fn clock_us(clock: nix::time::ClockId) -> u64 {
    nix::time::clock_gettime(clock)
        .map(|t| t.tv_sec() as u64 * 1_000_000 + t.tv_nsec() as u64 / 1000)
        .unwrap_or(0)
}

/// Microseconds of CLOCK_BOOTTIME.
pub fn boot_us() -> u64 {
    clock_us(nix::time::ClockId::CLOCK_BOOTTIME)
}

/// Microseconds of CLOCK_MONOTONIC: the clock of DRM's flip event timestamps (the KMS output
/// and the logs compare against it).
pub fn monotonic_us() -> u64 {
    clock_us(nix::time::ClockId::CLOCK_MONOTONIC)
}

/// Microseconds of the wall clock (CLOCK_REALTIME), for logs and recordings; 0 before 1970.
/// Ledger time is [`LedgerClock`]'s, never this.
pub fn unix_us() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

impl TimeSource for SystemTime {
    fn boot_ms(&self) -> u64 {
        boot_us() / 1000
    }

    fn wall_ms(&self) -> i64 {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as i64)
            .unwrap_or(0)
    }
}

/// The real clocks with a wall clock that can be stepped (tests: clock steps through the
/// running appliance without touching the machine's clock).
#[derive(Clone, Debug, Default)]
pub struct SteppableTime {
    offset_ms: Arc<AtomicI64>,
}

impl SteppableTime {
    pub fn new() -> SteppableTime {
        SteppableTime::default()
    }

    /// Steps the wall clock by `ms` (negative: back).
    pub fn step(&self, ms: i64) {
        self.offset_ms.fetch_add(ms, Ordering::SeqCst);
    }
}

impl TimeSource for SteppableTime {
    fn boot_ms(&self) -> u64 {
        SystemTime.boot_ms()
    }

    fn wall_ms(&self) -> i64 {
        SystemTime.wall_ms() + self.offset_ms.load(Ordering::SeqCst)
    }
}

/// Ledger time on top of a `TimeSource`: anchored once, then advanced by the monotonic clock.
#[derive(Clone, Debug)]
pub struct LedgerClock<S> {
    source: S,
    anchor_unix_ms: i64,
    anchor_boot_ms: u64,
}

impl<S: TimeSource> LedgerClock<S> {
    /// Anchors ledger time at `max(wall clock, high_water_ms)`: a wall clock behind the
    /// ledger's last recorded time (stepped back, or a dead RTC) cannot move the ledger back.
    pub fn new(source: S, high_water_ms: i64) -> LedgerClock<S> {
        let anchor_boot_ms = source.boot_ms();
        let anchor_unix_ms = source.wall_ms().max(high_water_ms);
        LedgerClock { source, anchor_unix_ms, anchor_boot_ms }
    }

    /// (ledger Unix ms, boot ms) at the anchor: recorded in the ledger so an auditor can map
    /// any boot-clock timestamp of this run onto the ledger's timeline.
    pub fn anchor(&self) -> (i64, u64) {
        (self.anchor_unix_ms, self.anchor_boot_ms)
    }
}

impl<S: TimeSource> Clock for LedgerClock<S> {
    fn now(&self) -> Now {
        let boot = self.source.boot_ms();
        let since = boot.saturating_sub(self.anchor_boot_ms);
        Now { mono_ms: boot, unix_ms: self.anchor_unix_ms + since as i64 }
    }

    fn wall_skew_ms(&self) -> i64 {
        self.source.wall_ms() - self.now().unix_ms
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_steps_do_not_move_ledger_time() {
        let t = SteppableTime::new();
        let c = LedgerClock::new(t.clone(), 0);
        let a = c.now();
        for step in [-3_600_000, 3_600_000, -25 * 3_600_000, 400 * 86_400_000] {
            t.step(step);
            let b = c.now();
            // Only the monotonic clock's progress shows (a few ms at most here).
            assert!(b.unix_ms >= a.unix_ms && b.unix_ms - a.unix_ms < 1_000, "{a:?} {b:?}");
        }
        assert!(c.wall_skew_ms() > 300 * 86_400_000);
    }

    #[test]
    fn anchor_never_below_the_high_water_mark() {
        let t = SteppableTime::new();
        t.step(-10 * 86_400_000);
        let hwm = SystemTime.wall_ms();
        let c = LedgerClock::new(t, hwm);
        assert!(c.now().unix_ms >= hwm);
        assert!(c.wall_skew_ms() < -9 * 86_400_000);
    }
}
