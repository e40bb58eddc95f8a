//! The exposure policy a bundle carries: how long a showing may last, the cooldown, the
//! daily and annual lux-hour budgets, when to warn operators, and what the stage does when
//! idle. The appliance enforces it; authoring picks it (CIE 157:2004 classes as presets).

use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
#[error("exposure policy: {0}")]
pub struct PolicyError(pub String);

/// What the projectors do between showings.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum IdleMode {
    /// Outputs off (or blank with the lamp off): no light, nothing charged.
    ProjectorsOff,
    /// Projectors on showing black: the black level is light and is charged.
    Black,
    /// Show this scene (normally the "original" one) and charge it like any scene.
    Scene(String),
}

/// CIE 157:2004 sensitivity classes (for presets; the policy stores plain numbers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sensitivity {
    /// 50 lx, 15 000 lx·h a year.
    High,
    /// 50 lx, 150 000 lx·h a year.
    Medium,
    /// 200 lx, 600 000 lx·h a year.
    Low,
}

impl Sensitivity {
    /// `(illuminance limit in lux, annual budget in lux-hours)`.
    pub fn limits(self) -> (f64, f64) {
        match self {
            Sensitivity::High => (50.0, 15_000.0),
            Sensitivity::Medium => (50.0, 150_000.0),
            Sensitivity::Low => (200.0, 600_000.0),
        }
    }
}

/// The exposure policy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExposurePolicy {
    /// Longest a showing may last, seconds, however the button behaves.
    pub max_showing_s: u32,
    /// Dark time after a showing before the next may start, seconds.
    pub cooldown_s: u32,
    /// Lux-hours per local calendar day.
    pub daily_budget_lxh: f64,
    /// Lux-hours per year (the conservation budget).
    pub annual_budget_lxh: f64,
    /// Fractions of a budget at which operators are warned, ascending, each in (0, 1);
    /// normally `[0.75, 0.90]`.
    pub warn_at: Vec<f64>,
    pub idle: IdleMode,
}

impl ExposurePolicy {
    /// A preset from a CIE class: the annual budget, a daily budget of 1/300 of it (about
    /// 300 open days), 60 s showings, 30 s cooldown, warnings at 75 % and 90 %, idle off.
    pub fn cie157(class: Sensitivity) -> Self {
        let (_, annual) = class.limits();
        Self {
            max_showing_s: 60,
            cooldown_s: 30,
            daily_budget_lxh: annual / 300.0,
            annual_budget_lxh: annual,
            warn_at: vec![0.75, 0.90],
            idle: IdleMode::ProjectorsOff,
        }
    }

    /// Checks ranges. `scenes` are the bundle's scene ids (an idle scene must be one).
    pub fn validate(&self, scenes: &[&str]) -> Result<(), PolicyError> {
        let bad = |s: String| Err(PolicyError(s));
        if !(1..=86_400).contains(&self.max_showing_s) {
            return bad(format!("max showing {} s (expected 1..=86400)", self.max_showing_s));
        }
        if self.cooldown_s > 86_400 {
            return bad(format!("cooldown {} s (expected 0..=86400)", self.cooldown_s));
        }
        for (what, v) in [("daily", self.daily_budget_lxh), ("annual", self.annual_budget_lxh)] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{what} budget {v} lx·h (expected finite, > 0)"));
            }
        }
        if self.daily_budget_lxh > self.annual_budget_lxh {
            return bad(format!(
                "daily budget {} lx·h exceeds the annual {} lx·h",
                self.daily_budget_lxh, self.annual_budget_lxh
            ));
        }
        if self.warn_at.len() > 8
            || self.warn_at.iter().any(|w| !(*w > 0.0 && *w < 1.0))
            || self.warn_at.windows(2).any(|p| p[0] >= p[1])
        {
            return bad(format!(
                "warning thresholds {:?} (expected ascending, each in (0, 1))",
                self.warn_at
            ));
        }
        if let IdleMode::Scene(s) = &self.idle
            && !scenes.contains(&s.as_str())
        {
            return bad(format!("idle scene {s:?} is not in the bundle"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_validate_and_bad_values_are_named() {
        for c in [Sensitivity::High, Sensitivity::Medium, Sensitivity::Low] {
            ExposurePolicy::cie157(c).validate(&[]).unwrap();
        }
        let mut p = ExposurePolicy::cie157(Sensitivity::High);
        p.warn_at = vec![0.9, 0.75];
        assert!(p.validate(&[]).unwrap_err().0.contains("ascending"));
        let mut p = ExposurePolicy::cie157(Sensitivity::High);
        p.idle = IdleMode::Scene("original".into());
        assert!(p.validate(&["restored"]).is_err());
        p.validate(&["original"]).unwrap();
        p.daily_budget_lxh = f64::NAN;
        assert!(p.validate(&["original"]).is_err());
    }
}
