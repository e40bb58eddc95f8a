//! From the event loop's parts to a [`Snapshot`]: the one place that decides what the status
//! page, `/status.json` and `/metrics` say about the player, the ledger, the bundle, the
//! projectors and the alerts. Pure: the loop gathers, this arranges.

use crate::alerts;
use crate::ledger::LedgerStatus;
use crate::pjlink::{Level, PowerState, ProjectorStatus};
use crate::player::State;
use crate::show::Show;

use super::snapshot::*;

/// Everything a snapshot is made of, as the event loop has it.
pub struct Parts<'a> {
    /// The stage's configured name.
    pub name: Option<&'a str>,
    pub version: &'a str,
    pub uptime_s: u64,
    /// Ledger time, Unix ms.
    pub now_ms: i64,
    /// IANA name of the stage's time zone.
    pub zone: &'a str,
    /// Formats a ledger time in the stage's local time.
    pub local: &'a dyn Fn(i64) -> String,
    pub state: &'a State,
    pub opening: Opening,
    /// The ledger's report, or why it could not be read.
    pub ledger: Result<&'a LedgerStatus, String>,
    pub show: Option<&'a Show>,
    pub projectors: &'a [ProjectorStatus],
    pub alerts: &'a [alerts::Alert],
    /// The bundle inbox, as the runtime reports it (also in the control socket's `status`).
    pub inbox: Option<InboxInfo>,
}

/// The opening hours' answer (`hours::Hours::at`) as the snapshot shows it; always open (no
/// `[hours]`): neither `next_open` nor `next_close`.
pub fn opening(o: &crate::hours::Opening, local: &dyn Fn(i64) -> String) -> Opening {
    let next = o.next_change_ms.map(|t| Moment { local: local(t), unix_ms: t });
    match o.open {
        true => Opening { open: true, next_open: None, next_close: next },
        false => Opening { open: false, next_open: next, next_close: None },
    }
}

/// Arranges `p` into a snapshot.
pub fn snapshot(p: &Parts<'_>) -> Snapshot {
    let local = p.local;
    let (kind, detail) = match p.state {
        State::Idle => (StateKind::Idle, None),
        State::Showing { .. } => (StateKind::Showing, None),
        State::Ending { .. } => (StateKind::Ending, Some("fading out".to_string())),
        State::Cooldown { .. } => (StateKind::Cooldown, Some("the object rests after a showing".into())),
        State::Identifying { projector, .. } => {
            (StateKind::Cooldown, Some(format!("commissioning pattern on projector {}", projector + 1)))
        }
        State::Exhausted { reason, .. } => (StateKind::BudgetExhausted, Some(reason.clone())),
        State::Fault { reason } => (StateKind::Fault, Some(reason.clone())),
        State::Dark { reason } => (StateKind::Dark, Some(reason.clone())),
        State::Closed { reason } => (StateKind::Closed, Some(reason.clone())),
    };
    // Outside opening hours a dark stage is closed, not out of order.
    let (kind, detail) = match (kind, p.opening.open) {
        (StateKind::Dark | StateKind::Idle, false) => {
            (StateKind::Closed, p.opening.next_open.as_ref().map(|m| format!("opens {}", m.local)))
        }
        _ => (kind, detail),
    };
    let (budget, warnings, showings, events) = match &p.ledger {
        Ok(l) => {
            let budgets = l.active.as_ref().map(|a| a.budgets.clone());
            let budget = BudgetInfo::Known(Budget {
                day: l.day.clone(),
                daily: Window {
                    used_lux_hours: l.day_used_lux_hours,
                    left_lux_hours: l.day_left_lux_hours,
                    budget_lux_hours: budgets.as_ref().map(|b| b.daily_lux_hours),
                },
                annual: Window {
                    used_lux_hours: l.year_used_lux_hours,
                    left_lux_hours: l.year_left_lux_hours,
                    budget_lux_hours: budgets.as_ref().map(|b| b.annual_lux_hours),
                },
                total_lux_hours: l.total_lux_hours,
                open_reservations: l.open_reservations,
            });
            let warnings = l
                .warnings
                .iter()
                .map(|w| Warning {
                    at: local(w.at_ms),
                    text: format!(
                        "{} budget at {:.0} % ({:.3} of {:.3} lx·h)",
                        w.budget,
                        w.threshold * 100.0,
                        w.used,
                        w.budget_lux_hours
                    ),
                })
                .collect();
            let showings = l
                .last_showings
                .iter()
                .map(|s| Showing {
                    start: local(s.started_ms),
                    end: local(s.ended_ms),
                    scenes: s.scenes.clone(),
                    ended_by: s.ended_by.clone(),
                })
                .collect();
            let events = l
                .last_events
                .iter()
                .map(|e| Event { at: local(e.at_ms), kind: e.kind.clone(), detail: e.detail.clone() })
                .collect();
            (budget, warnings, showings, events)
        }
        Err(why) => (BudgetInfo::Unknown { why: why.clone() }, Vec::new(), Vec::new(), Vec::new()),
    };
    let bundle = match p.show {
        Some(s) => BundleInfo::Loaded(Bundle {
            object_id: s.object_id.clone(),
            version: s.version,
            hash_prefix: s.bundle_hash.chars().take(16).collect(),
            expires: s.expires_unix_ms.map(|e| Expiry {
                local: local(e),
                unix_ms: e,
                days_left: (e - p.now_ms) as f64 / 86_400_000.0,
            }),
        }),
        None => BundleInfo::Absent { why: detail.clone().unwrap_or_else(|| "no bundle loaded".into()) },
    };
    Snapshot {
        schema: SCHEMA,
        appliance: Appliance {
            name: p.name.map(str::to_string),
            version: p.version.to_string(),
            uptime_s: p.uptime_s,
        },
        clock: Clock { local: local(p.now_ms), zone: p.zone.to_string(), unix_ms: p.now_ms },
        state: StateInfo { kind, detail },
        opening: p.opening.clone(),
        budget,
        warnings,
        showings,
        bundle,
        projectors: p.projectors.iter().map(|s| projector(s, local)).collect(),
        alerts: p
            .alerts
            .iter()
            .map(|a| Alert {
                level: match a.level {
                    alerts::Level::Warning => AlertLevel::Warning,
                    alerts::Level::Critical => AlertLevel::Critical,
                },
                kind: a.kind.as_str().to_string(),
                message: a.message.clone(),
                since: local(a.since_ms),
            })
            .collect(),
        events,
        inbox: p.inbox.clone(),
    }
}

fn projector(s: &ProjectorStatus, local: &dyn Fn(i64) -> String) -> Projector {
    let mut errors: Vec<String> = s
        .errors
        .map(|e| {
            e.fields()
                .iter()
                .zip(crate::pjlink::ErrorStatus::NAMES)
                .filter(|(l, _)| **l != Level::Ok)
                .map(|(l, name)| format!("{name}: {}", if *l == Level::Error { "error" } else { "warning" }))
                .collect()
        })
        .unwrap_or_default();
    if let Some(e) = &s.last_error
        && !errors.iter().any(|x| e.contains(x.as_str()))
    {
        errors.push(e.clone());
    }
    Projector {
        name: s.name.clone(),
        address: Some(s.address.clone()),
        reachable: s.reachable,
        power: match s.power {
            Some(PowerState::On) => Power::On,
            Some(PowerState::Off) => Power::Off,
            Some(PowerState::Warming) => Power::WarmingUp,
            Some(PowerState::Cooling) => Power::CoolingDown,
            None => Power::Unknown,
        },
        muted: s.muted,
        lamp_hours: s.lamp_hours.map(u64::from),
        errors,
        last_poll: s.last_poll_unix_ms.map(local),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_puts_the_next_change_where_it_belongs() {
        let local = |t: i64| format!("t{t}");
        let hours = |open, next| crate::hours::Opening { open, next_change_ms: next, reason: String::new() };
        let moment = Some(Moment { local: "t5".into(), unix_ms: 5 });
        assert_eq!(
            opening(&hours(false, Some(5)), &local),
            Opening { open: false, next_open: moment.clone(), next_close: None }
        );
        assert_eq!(
            opening(&hours(true, Some(5)), &local),
            Opening { open: true, next_open: None, next_close: moment }
        );
        assert_eq!(
            opening(&hours(true, None), &local),
            Opening { open: true, next_open: None, next_close: None }
        );
    }
}
