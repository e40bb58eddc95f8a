//! Evaluation against the virtual stage's ground truth: every step reports figures as rows
//! of one table, printed for people and as JSON for machines. One submodule per step.

pub mod classify;
pub mod compensate;
pub mod geometry;
pub mod restore;

use serde::Serialize;

pub mod transport;

/// One measured figure, with the target it is held to (if any).
#[derive(Clone, Debug, Serialize)]
pub struct Metric {
    /// Which step: "geometry", "classify", ...
    pub step: String,
    /// What was measured, e.g. "reprojection RMS".
    pub name: String,
    pub value: f64,
    pub unit: String,
    /// Human-readable target, e.g. "< 0.3"; `None` when the figure is informative only.
    pub target: Option<String>,
    /// Whether the target holds; `None` when there is no target.
    pub pass: Option<bool>,
}

impl Metric {
    pub fn info(step: &str, name: &str, value: f64, unit: &str) -> Self {
        Self { step: step.into(), name: name.into(), value, unit: unit.into(), target: None, pass: None }
    }

    /// A figure that must stay below `limit`.
    pub fn below(step: &str, name: &str, value: f64, unit: &str, limit: f64) -> Self {
        Self {
            target: Some(format!("< {limit}")),
            pass: Some(value < limit),
            ..Self::info(step, name, value, unit)
        }
    }

    /// A figure that must reach at least `limit`.
    pub fn at_least(step: &str, name: &str, value: f64, unit: &str, limit: f64) -> Self {
        Self {
            target: Some(format!(">= {limit}")),
            pass: Some(value >= limit),
            ..Self::info(step, name, value, unit)
        }
    }
}

/// Renders metrics as an aligned plain-text table.
pub fn table(metrics: &[Metric]) -> String {
    let mut out =
        format!("{:<12} {:<44} {:>14} {:<8} {:<10} {}\n", "step", "figure", "value", "unit", "target", "ok");
    for m in metrics {
        let ok = match m.pass {
            Some(true) => "yes",
            Some(false) => "NO",
            None => "",
        };
        out.push_str(&format!(
            "{:<12} {:<44} {:>14.4} {:<8} {:<10} {}\n",
            m.step,
            m.name,
            m.value,
            m.unit,
            m.target.as_deref().unwrap_or(""),
            ok
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_are_judged() {
        assert_eq!(Metric::below("g", "rms", 0.2, "px", 0.3).pass, Some(true));
        assert_eq!(Metric::at_least("c", "acc", 0.97, "", 0.98).pass, Some(false));
        let t = table(&[Metric::info("g", "points", 10.0, "")]);
        assert!(t.contains("points"));
    }
}
