//! Operator alerts, decided without I/O: the event loop hands in what it observes (`Facts`)
//! and the time; `Alerts` answers which alerts were raised and which cleared. The command
//! that tells people is `alert_command`.
//!
//! No flapping: an alert is raised the first time its condition holds and stays raised until
//! the condition has been absent for `CLEAR_AFTER_MS` (a projector that comes and goes every
//! few seconds is one alert, not a stream). Budget and clock alerts also have hysteresis:
//! once raised they hold down to `BUDGET_HYSTERESIS` below their threshold (clock: half of it).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::config::AlertsConfig;
use crate::ledger::LedgerStatus;

/// An alert is cleared only after its condition has been absent this long (ms).
pub const CLEAR_AFTER_MS: i64 = 60_000;
/// A raised budget alert holds until use falls this fraction below its threshold.
pub const BUDGET_HYSTERESIS: f64 = 0.05;
/// The wall clock this far from ledger time (ms) raises a clock alert; it clears below half.
pub const CLOCK_SKEW_ALERT_MS: i64 = 60_000;
const DAY_MS: i64 = 86_400_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    /// Someone should look soon (a budget nearly used, a bundle about to expire).
    Warning,
    /// The stage is not doing its job (dark, a projector gone, a budget used up).
    Critical,
}

impl Level {
    pub fn as_str(self) -> &'static str {
        match self {
            Level::Warning => "warning",
            Level::Critical => "critical",
        }
    }
}

/// What an alert is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kind {
    Budget,
    BundleExpiry,
    Projector,
    Ledger,
    Clock,
    /// An output or other fault: dark until it is dealt with.
    Fault,
    /// Dark without an operator's stop: no bundle, refused, expired.
    Dark,
}

impl Kind {
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::Budget => "budget",
            Kind::BundleExpiry => "bundle-expiry",
            Kind::Projector => "projector",
            Kind::Ledger => "ledger",
            Kind::Clock => "clock",
            Kind::Fault => "fault",
            Kind::Dark => "dark",
        }
    }
}

/// One alert.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Alert {
    pub level: Level,
    pub kind: Kind,
    /// Names the condition (`budget:daily:0.8`, `projector:HDMI-A-1`): one alert per key.
    pub key: String,
    /// For people; kept up to date while the alert is active.
    pub message: String,
    /// Ledger time (Unix ms) it was raised.
    pub since_ms: i64,
}

/// Whether an alert begins or ends (`RESTAGE_ALERT_STATE`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlertState {
    Raised,
    Cleared,
}

impl AlertState {
    pub fn as_str(self) -> &'static str {
        match self {
            AlertState::Raised => "raised",
            AlertState::Cleared => "cleared",
        }
    }
}

/// How much of one light budget is used.
#[derive(Clone, Debug, PartialEq)]
pub struct BudgetUse {
    /// "daily", "annual".
    pub name: String,
    /// Used / budget (1.0 = used up; may exceed 1 after an over-count).
    pub used_fraction: f64,
}

impl BudgetUse {
    /// The daily and annual budgets' use from the ledger's status (those the bundle sets).
    pub fn from_status(s: &LedgerStatus) -> Vec<BudgetUse> {
        let fraction = |used: f64, left: Option<f64>| {
            let total = used + left?;
            (total > 0.0).then(|| used / total)
        };
        [
            ("daily", fraction(s.day_used_lux_hours, s.day_left_lux_hours)),
            ("annual", fraction(s.year_used_lux_hours, s.year_left_lux_hours)),
        ]
        .into_iter()
        .filter_map(|(name, f)| Some(BudgetUse { name: name.into(), used_fraction: f? }))
        .collect()
    }
}

/// A projector that is not as it should be.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectorProblem {
    /// The connector or projector name.
    pub name: String,
    pub problem: String,
}

/// What the event loop saw; every field is "as of now".
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Facts {
    pub budgets: Vec<BudgetUse>,
    /// When the loaded bundle expires (ledger time, Unix ms), if it does.
    pub bundle_expires_ms: Option<i64>,
    pub projectors: Vec<ProjectorProblem>,
    /// The ledger cannot record (the player is dark, retrying).
    pub ledger_fault: Option<String>,
    /// Another fault (an output): dark.
    pub fault: Option<String>,
    /// Dark for a reason other than an operator's stop (no bundle, refused, expired).
    pub dark: Option<String>,
    /// Wall clock minus ledger time (ms).
    pub clock_skew_ms: i64,
}

/// The thresholds (from `[alerts]`).
#[derive(Clone, Debug, PartialEq)]
pub struct AlertSettings {
    pub expiry_warn_days: u32,
    /// Ascending fractions; 1.0 and above are critical.
    pub budget_thresholds: Vec<f64>,
}

impl Default for AlertSettings {
    fn default() -> Self {
        Self::from(&AlertsConfig::default())
    }
}

impl From<&AlertsConfig> for AlertSettings {
    fn from(c: &AlertsConfig) -> Self {
        Self { expiry_warn_days: c.expiry_warn_days, budget_thresholds: c.budget_thresholds.clone() }
    }
}

/// What one `observe` changed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    pub raised: Vec<Alert>,
    pub cleared: Vec<Alert>,
}

impl Changes {
    pub fn is_empty(&self) -> bool {
        self.raised.is_empty() && self.cleared.is_empty()
    }

    /// Every change: cleared ones first (a level change clears nothing, it raises again).
    pub fn iter(&self) -> impl Iterator<Item = (&Alert, AlertState)> {
        let cleared = self.cleared.iter().map(|a| (a, AlertState::Cleared));
        cleared.chain(self.raised.iter().map(|a| (a, AlertState::Raised)))
    }
}

#[derive(Clone, Debug)]
struct Tracked {
    alert: Alert,
    /// When its condition last held.
    seen_ms: i64,
}

/// The active alerts and what it takes to raise and clear them.
#[derive(Clone, Debug)]
pub struct Alerts {
    settings: AlertSettings,
    active: BTreeMap<String, Tracked>,
}

impl Alerts {
    pub fn new(settings: AlertSettings) -> Alerts {
        Alerts { settings, active: BTreeMap::new() }
    }

    /// The alerts now active, most severe first, then by key.
    pub fn active(&self) -> Vec<Alert> {
        let mut v: Vec<Alert> = self.active.values().map(|t| t.alert.clone()).collect();
        v.sort_by(|a, b| b.level.cmp(&a.level).then_with(|| a.key.cmp(&b.key)));
        v
    }

    /// Takes in the facts at `now_ms` (ledger time); returns the alerts raised (new, or at
    /// another level) and cleared (absent for `CLEAR_AFTER_MS`).
    pub fn observe(&mut self, facts: &Facts, now_ms: i64) -> Changes {
        let mut changes = Changes::default();
        let holding = self.conditions(facts, now_ms);
        for (level, kind, key, message) in holding {
            match self.active.get_mut(&key) {
                Some(t) if t.alert.level == level => {
                    t.alert.message = message;
                    t.seen_ms = now_ms;
                }
                _ => {
                    let alert = Alert { level, kind, key: key.clone(), message, since_ms: now_ms };
                    changes.raised.push(alert.clone());
                    self.active.insert(key, Tracked { alert, seen_ms: now_ms });
                }
            }
        }
        let gone: Vec<String> = self
            .active
            .iter()
            .filter(|(_, t)| now_ms.saturating_sub(t.seen_ms) >= CLEAR_AFTER_MS)
            .map(|(k, _)| k.clone())
            .collect();
        for key in gone {
            if let Some(t) = self.active.remove(&key) {
                changes.cleared.push(t.alert);
            }
        }
        changes
    }

    fn is_active(&self, key: &str) -> bool {
        self.active.contains_key(key)
    }

    /// The conditions that hold now: (level, kind, key, message).
    fn conditions(&self, f: &Facts, now_ms: i64) -> Vec<(Level, Kind, String, String)> {
        let mut out = Vec::new();
        for b in &f.budgets {
            for &t in &self.settings.budget_thresholds {
                let key = format!("budget:{}:{t}", b.name);
                let hold = if self.is_active(&key) { t - BUDGET_HYSTERESIS } else { t };
                if b.used_fraction >= hold {
                    let level = if t >= 1.0 { Level::Critical } else { Level::Warning };
                    let message = format!(
                        "{} light budget {:.0} % used (alert at {:.0} %)",
                        b.name,
                        b.used_fraction * 100.0,
                        t * 100.0
                    );
                    out.push((level, Kind::Budget, key, message));
                }
            }
        }
        if let Some(expires) = f.bundle_expires_ms {
            let left = expires.saturating_sub(now_ms);
            let warn = i64::from(self.settings.expiry_warn_days) * DAY_MS;
            if left <= 0 {
                let message = "the bundle has expired: the stage stays dark until a new one is installed";
                out.push((Level::Critical, Kind::BundleExpiry, "bundle-expiry".into(), message.into()));
            } else if left <= warn {
                let message = format!(
                    "the bundle expires in {:.1} days (on {}): install a renewed one",
                    left as f64 / DAY_MS as f64,
                    restage_shared::time::format_utc(expires.div_euclid(1000))
                );
                out.push((Level::Warning, Kind::BundleExpiry, "bundle-expiry".into(), message));
            }
        }
        for p in &f.projectors {
            let message = format!("projector {}: {}", p.name, p.problem);
            out.push((Level::Critical, Kind::Projector, format!("projector:{}", p.name), message));
        }
        if let Some(e) = &f.ledger_fault {
            let message = format!("the ledger cannot record (dark, retried): {e}");
            out.push((Level::Critical, Kind::Ledger, "ledger".into(), message));
        }
        if let Some(e) = &f.fault {
            out.push((Level::Critical, Kind::Fault, "fault".into(), format!("fault (dark): {e}")));
        }
        if let Some(e) = &f.dark {
            out.push((Level::Critical, Kind::Dark, "dark".into(), format!("the stage is dark: {e}")));
        }
        let limit = if self.is_active("clock") { CLOCK_SKEW_ALERT_MS / 2 } else { CLOCK_SKEW_ALERT_MS };
        if f.clock_skew_ms.saturating_abs() > limit {
            let message = format!(
                "the wall clock is {:+.0} s from ledger time (ledger time is kept): check NTP and the RTC",
                f.clock_skew_ms as f64 / 1000.0
            );
            out.push((Level::Warning, Kind::Clock, "clock".into(), message));
        }
        out
    }
}

/// Logs one change: raised warnings as warnings, raised critical alerts as errors, clears as
/// information.
pub fn log(alert: &Alert, state: AlertState) {
    let (kind, key, msg) = (alert.kind.as_str(), alert.key.as_str(), alert.message.as_str());
    match (state, alert.level) {
        (AlertState::Raised, Level::Critical) => tracing::error!(kind, key, "ALERT: {msg}"),
        (AlertState::Raised, Level::Warning) => tracing::warn!(kind, key, "alert: {msg}"),
        (AlertState::Cleared, _) => tracing::info!(kind, key, "alert cleared: {msg}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn budget(name: &str, f: f64) -> Facts {
        Facts { budgets: vec![BudgetUse { name: name.into(), used_fraction: f }], ..Facts::default() }
    }

    fn keys(v: &[Alert]) -> Vec<&str> {
        v.iter().map(|a| a.key.as_str()).collect()
    }

    #[test]
    fn raised_once_then_cleared_after_the_hold() {
        let mut a = Alerts::new(AlertSettings::default());
        let lost = Facts {
            projectors: vec![ProjectorProblem { name: "HDMI-A-1".into(), problem: "disconnected".into() }],
            ..Facts::default()
        };
        let c = a.observe(&lost, 0);
        assert_eq!(keys(&c.raised), ["projector:HDMI-A-1"]);
        assert_eq!(c.raised[0].level, Level::Critical);
        assert!(c.cleared.is_empty());
        // Holding: nothing new, however often it is looked at.
        for t in (1_000..10_000).step_by(1_000) {
            assert!(a.observe(&lost, t).is_empty());
        }
        // Gone, but not for long enough: still active.
        assert!(a.observe(&Facts::default(), 20_000).is_empty());
        assert_eq!(a.active().len(), 1);
        // Back, then gone for good: cleared once, a full hold after it was last seen.
        assert!(a.observe(&lost, 30_000).is_empty());
        assert!(a.observe(&Facts::default(), 30_000 + CLEAR_AFTER_MS - 1).is_empty());
        let c = a.observe(&Facts::default(), 30_000 + CLEAR_AFTER_MS);
        assert_eq!(keys(&c.cleared), ["projector:HDMI-A-1"]);
        assert_eq!(c.cleared[0].since_ms, 0);
        assert!(a.active().is_empty());
        assert!(a.observe(&Facts::default(), 200_000).is_empty());
    }

    #[test]
    fn flapping_projector_is_one_alert() {
        let mut a = Alerts::new(AlertSettings::default());
        let lost = Facts {
            projectors: vec![ProjectorProblem { name: "DP-1".into(), problem: "gone".into() }],
            ..Facts::default()
        };
        let mut raised = 0;
        let mut cleared = 0;
        for k in 0..100 {
            let f = if k % 2 == 0 { lost.clone() } else { Facts::default() };
            let c = a.observe(&f, k * 5_000);
            raised += c.raised.len();
            cleared += c.cleared.len();
        }
        assert_eq!((raised, cleared), (1, 0));
    }

    #[test]
    fn budget_threshold_crossing_with_hysteresis() {
        let mut a = Alerts::new(AlertSettings::default());
        assert!(a.observe(&budget("daily", 0.79), 0).is_empty());
        let c = a.observe(&budget("daily", 0.8), 1);
        assert_eq!(keys(&c.raised), ["budget:daily:0.8"]);
        assert_eq!(c.raised[0].level, Level::Warning);
        assert!(c.raised[0].message.contains("80 %"), "{}", c.raised[0].message);
        // Wobbling just under the threshold does not clear it (hysteresis).
        assert!(a.observe(&budget("daily", 0.78), CLEAR_AFTER_MS * 2).is_empty());
        let c = a.observe(&budget("daily", 1.0), CLEAR_AFTER_MS * 3);
        assert_eq!(keys(&c.raised), ["budget:daily:1"]);
        assert_eq!(c.raised[0].level, Level::Critical);
        assert_eq!(keys(&a.active()), ["budget:daily:1", "budget:daily:0.8"]);
        // A new day: both clear once the hold has passed.
        assert!(a.observe(&budget("daily", 0.0), CLEAR_AFTER_MS * 3 + 1).is_empty());
        let c = a.observe(&budget("daily", 0.0), CLEAR_AFTER_MS * 4);
        assert_eq!(c.cleared.len(), 2);
        // The annual budget is its own alert.
        let c = a.observe(&budget("annual", 0.9), CLEAR_AFTER_MS * 6);
        assert_eq!(keys(&c.raised), ["budget:annual:0.8"]);
    }

    #[test]
    fn expiry_within_the_warning_days_then_expired() {
        let mut a = Alerts::new(AlertSettings { expiry_warn_days: 14, ..AlertSettings::default() });
        let at = |expires| Facts { bundle_expires_ms: Some(expires), ..Facts::default() };
        let now = 1_000 * DAY_MS;
        assert!(a.observe(&at(now + 14 * DAY_MS + 1), now).is_empty());
        let c = a.observe(&at(now + 14 * DAY_MS), now);
        assert_eq!(keys(&c.raised), ["bundle-expiry"]);
        assert_eq!(c.raised[0].level, Level::Warning);
        assert!(c.raised[0].message.contains("14.0 days"), "{}", c.raised[0].message);
        assert!(a.observe(&at(now + 14 * DAY_MS), now + DAY_MS).is_empty());
        // Expired: raised again, critical.
        let c = a.observe(&at(now + 14 * DAY_MS), now + 14 * DAY_MS);
        assert_eq!(c.raised.len(), 1);
        assert_eq!(c.raised[0].level, Level::Critical);
        // A renewed bundle: cleared after the hold.
        let c = a.observe(&at(now + 400 * DAY_MS), now + 14 * DAY_MS + CLEAR_AFTER_MS);
        assert_eq!(keys(&c.cleared), ["bundle-expiry"]);
        // 0 days: only an expired bundle alerts.
        let mut a = Alerts::new(AlertSettings { expiry_warn_days: 0, ..AlertSettings::default() });
        assert!(a.observe(&at(now + 1), now).is_empty());
        assert_eq!(a.observe(&at(now), now).raised.len(), 1);
    }

    #[test]
    fn faults_dark_and_clock() {
        let mut a = Alerts::new(AlertSettings::default());
        let f = Facts {
            ledger_fault: Some("database is locked".into()),
            fault: Some("output: flip timed out".into()),
            dark: Some("no bundle loaded".into()),
            clock_skew_ms: -CLOCK_SKEW_ALERT_MS - 1,
            ..Facts::default()
        };
        let c = a.observe(&f, 0);
        assert_eq!(keys(&c.raised), ["ledger", "fault", "dark", "clock"]);
        assert_eq!(keys(&a.active()), ["dark", "fault", "ledger", "clock"]);
        // The clock holds above half its threshold, then clears.
        let half = Facts { clock_skew_ms: CLOCK_SKEW_ALERT_MS / 2 + 1, ..f.clone() };
        assert!(a.observe(&half, CLEAR_AFTER_MS).is_empty());
        let c = a.observe(&Facts::default(), 2 * CLEAR_AFTER_MS + 1);
        assert_eq!(c.cleared.len(), 4);
    }

    #[test]
    fn budget_use_from_the_ledger_status() {
        let s = LedgerStatus {
            schema_version: 1,
            active: None,
            day: "2026-12-01".into(),
            time_zone: "UTC".into(),
            now_local: "2026-12-01 12:00 UTC".into(),
            day_used_lux_hours: 3.0,
            day_left_lux_hours: Some(1.0),
            year_used_lux_hours: 10.0,
            year_left_lux_hours: None,
            total_lux_hours: 10.0,
            open_reservations: 0,
            warnings: vec![],
            last_showings: vec![],
            last_events: vec![],
        };
        assert_eq!(BudgetUse::from_status(&s), [BudgetUse { name: "daily".into(), used_fraction: 0.75 }]);
    }
}
