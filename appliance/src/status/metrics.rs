//! `/metrics`: the snapshot in the Prometheus text exposition format 0.0.4 (HELP and TYPE
//! once per family, then its samples; label values escaped).

use std::fmt::Write;

use super::html::visible_controls;
use super::snapshot::{AlertLevel, BudgetInfo, BundleInfo, Power, Snapshot, StateKind, Window};

/// The `Content-Type` of [`render`]'s text.
pub const CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

/// The metrics for `snap`.
pub fn render(snap: &Snapshot) -> String {
    let mut m = Metrics::default();
    let s = snap;
    m.family("restage_up", "gauge", "1 while the appliance answers (absent when it does not).");
    m.sample("restage_up", &[], 1.0);
    m.family("restage_info", "gauge", "The appliance's version (value always 1).");
    m.sample("restage_info", &[("version", &s.appliance.version)], 1.0);
    m.family("restage_uptime_seconds", "gauge", "Seconds since the appliance process started.");
    m.sample("restage_uptime_seconds", &[], s.appliance.uptime_s as f64);
    m.family(
        "restage_snapshot_timestamp_seconds",
        "gauge",
        "Ledger time of the snapshot served (Unix s); stale when the event loop stalls.",
    );
    m.sample("restage_snapshot_timestamp_seconds", &[], s.clock.unix_ms as f64 / 1000.0);

    m.family("restage_state", "gauge", "1 for the player's current state, 0 for the others.");
    for k in StateKind::ALL {
        m.sample("restage_state", &[("state", k.name())], f64::from(u8::from(k == s.state.kind)));
    }
    m.family("restage_open", "gauge", "1 inside opening hours, else 0.");
    m.sample("restage_open", &[], f64::from(u8::from(s.opening.open)));

    if let BudgetInfo::Known(b) = &s.budget {
        let windows: [(&str, &Window); 2] = [("day", &b.daily), ("year", &b.annual)];
        m.family("restage_budget_used_lux_hours", "gauge", "Light used in the budget window (lux·h).");
        for (w, win) in windows {
            m.sample("restage_budget_used_lux_hours", &[("window", w)], win.used_lux_hours);
        }
        m.family("restage_budget_left_lux_hours", "gauge", "Light left in the budget window (lux·h).");
        for (w, win) in windows {
            if let Some(v) = win.left_lux_hours {
                m.sample("restage_budget_left_lux_hours", &[("window", w)], v);
            }
        }
        m.family("restage_budget_lux_hours", "gauge", "The budget of the window (lux·h).");
        for (w, win) in windows {
            if let Some(v) = win.budget_lux_hours {
                m.sample("restage_budget_lux_hours", &[("window", w)], v);
            }
        }
        m.family("restage_exposure_total_lux_hours", "gauge", "All light the ledger holds for the object.");
        m.sample("restage_exposure_total_lux_hours", &[], b.total_lux_hours);
        m.family("restage_open_reservations", "gauge", "Reservations never committed (counted in full).");
        m.sample("restage_open_reservations", &[], b.open_reservations as f64);
    }
    m.family("restage_budget_warnings", "gauge", "Budget warnings listed on the status page.");
    m.sample("restage_budget_warnings", &[], s.warnings.len() as f64);

    m.family("restage_bundle_loaded", "gauge", "1 while a verified bundle is in force.");
    m.sample("restage_bundle_loaded", &[], f64::from(u8::from(matches!(s.bundle, BundleInfo::Loaded(_)))));
    if let BundleInfo::Loaded(b) = &s.bundle {
        m.family("restage_bundle_info", "gauge", "The bundle in force (value always 1).");
        let version = b.version.to_string();
        m.sample(
            "restage_bundle_info",
            &[("object", &b.object_id), ("version", &version), ("hash", &b.hash_prefix)],
            1.0,
        );
        if let Some(e) = &b.expires {
            m.family(
                "restage_bundle_expiry_seconds",
                "gauge",
                "Seconds from the snapshot until the bundle expires (negative once expired).",
            );
            m.sample("restage_bundle_expiry_seconds", &[], (e.unix_ms - s.clock.unix_ms) as f64 / 1000.0);
            m.family("restage_bundle_expiry_timestamp_seconds", "gauge", "When the bundle expires (Unix s).");
            m.sample("restage_bundle_expiry_timestamp_seconds", &[], e.unix_ms as f64 / 1000.0);
        }
    }

    if !s.projectors.is_empty() {
        m.family("restage_projector_reachable", "gauge", "1 when the projector answered its last poll.");
        for p in &s.projectors {
            m.sample(
                "restage_projector_reachable",
                &[("projector", &p.name)],
                f64::from(u8::from(p.reachable)),
            );
        }
        m.family("restage_projector_power_on", "gauge", "1 when the projector reports power on.");
        for p in &s.projectors {
            let on = f64::from(u8::from(p.power == Power::On));
            m.sample("restage_projector_power_on", &[("projector", &p.name)], on);
        }
        m.family("restage_projector_lamp_hours", "gauge", "Lamp hours the projector reports.");
        for p in &s.projectors {
            if let Some(h) = p.lamp_hours {
                m.sample("restage_projector_lamp_hours", &[("projector", &p.name)], h as f64);
            }
        }
        m.family("restage_projector_errors", "gauge", "Errors the projector reports now.");
        for p in &s.projectors {
            m.sample("restage_projector_errors", &[("projector", &p.name)], p.errors.len() as f64);
        }
    }

    m.family("restage_alerts", "gauge", "Alerts in force, by level.");
    for l in AlertLevel::ALL {
        let n = s.alerts.iter().filter(|a| a.level == l).count();
        m.sample("restage_alerts", &[("level", l.name())], n as f64);
    }
    m.out
}

#[derive(Default)]
struct Metrics {
    out: String,
}

impl Metrics {
    fn family(&mut self, name: &str, kind: &str, help: &str) {
        // HELP text escapes only backslash and newline in 0.0.4; ours are constants without.
        let _ = writeln!(self.out, "# HELP {name} {help}");
        let _ = writeln!(self.out, "# TYPE {name} {kind}");
    }

    fn sample(&mut self, name: &str, labels: &[(&str, &str)], value: f64) {
        self.out.push_str(name);
        if !labels.is_empty() {
            self.out.push('{');
            for (i, (k, v)) in labels.iter().enumerate() {
                if i > 0 {
                    self.out.push(',');
                }
                let _ = write!(self.out, "{k}=\"{}\"", label_value(v));
            }
            self.out.push('}');
        }
        let _ = writeln!(self.out, " {}", number(value));
    }
}

/// A label value as the format wants it: `\`, `"` and newline escaped; other control
/// characters made visible (they are legal, but a terminal escape has no business here).
fn label_value(v: &str) -> String {
    let mut out = String::with_capacity(v.len());
    for c in visible_controls(v).chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '"' => out.push_str("\\\""),
            '\n' => out.push_str("\\n"),
            '\t' => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// A sample value: Go's float syntax, which Rust's `Display` matches except for the infinities.
fn number(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v == f64::INFINITY {
        "+Inf".into()
    } else if v == f64::NEG_INFINITY {
        "-Inf".into()
    } else {
        v.to_string()
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;

    use super::*;
    use crate::status::snapshot::Alert;

    /// Checks one sample line, `name{label="value",...} value`, and returns the name.
    fn parse_sample(line: &str) -> Result<&str, String> {
        let is_name_start = |c: char| c.is_ascii_alphabetic() || c == '_' || c == ':';
        let name_end = line.find(|c: char| !(is_name_start(c) || c.is_ascii_digit())).ok_or("no value")?;
        let name = &line[..name_end];
        if !name.starts_with(is_name_start) {
            return Err(format!("bad metric name in {line:?}"));
        }
        let mut rest = &line[name_end..];
        if let Some(labels) = rest.strip_prefix('{') {
            let mut chars = labels.char_indices().peekable();
            loop {
                // label name
                let start = chars.peek().map(|&(i, _)| i).ok_or("unterminated labels")?;
                while chars.peek().is_some_and(|&(_, c)| c.is_ascii_alphanumeric() || c == '_') {
                    chars.next();
                }
                let end = chars.peek().map(|&(i, _)| i).ok_or("unterminated labels")?;
                if end == start || labels[start..].starts_with(|c: char| c.is_ascii_digit()) {
                    return Err(format!("bad label name in {line:?}"));
                }
                if chars.next().map(|(_, c)| c) != Some('=') || chars.next().map(|(_, c)| c) != Some('"') {
                    return Err(format!("expected =\" in {line:?}"));
                }
                loop {
                    match chars.next().map(|(_, c)| c) {
                        Some('\\') => match chars.next().map(|(_, c)| c) {
                            Some('\\' | '"' | 'n') => {}
                            _ => return Err(format!("bad escape in {line:?}")),
                        },
                        Some('"') => break,
                        Some('\n') | None => return Err(format!("unterminated value in {line:?}")),
                        Some(_) => {}
                    }
                }
                match chars.next() {
                    Some((_, ',')) => continue,
                    Some((i, '}')) => {
                        rest = &labels[i + 1..];
                        break;
                    }
                    _ => return Err(format!("expected , or }} in {line:?}")),
                }
            }
        }
        let value = rest.strip_prefix(' ').ok_or_else(|| format!("no space before the value in {line:?}"))?;
        let ok = matches!(value, "NaN" | "+Inf" | "-Inf") || value.parse::<f64>().is_ok();
        if !ok || value.contains(' ') {
            return Err(format!("bad value {value:?} in {line:?}"));
        }
        Ok(name)
    }

    /// Every line is a HELP, a TYPE or a sample of a family whose TYPE came before it, and
    /// no family is declared twice.
    fn check_exposition(text: &str) -> Result<usize, String> {
        let mut typed = HashSet::new();
        let mut samples = 0;
        for line in text.lines() {
            if let Some(rest) = line.strip_prefix("# TYPE ") {
                let (name, kind) = rest.split_once(' ').ok_or("TYPE without kind")?;
                if !["counter", "gauge", "histogram", "summary", "untyped"].contains(&kind) {
                    return Err(format!("bad type {kind}"));
                }
                if !typed.insert(name.to_string()) {
                    return Err(format!("{name} declared twice"));
                }
            } else if line.starts_with("# HELP ") {
            } else if line.starts_with('#') || line.is_empty() {
                return Err(format!("unexpected line {line:?}"));
            } else {
                let name = parse_sample(line)?;
                if !typed.contains(name) {
                    return Err(format!("{name} has no TYPE before its sample"));
                }
                samples += 1;
            }
        }
        Ok(samples)
    }

    #[test]
    fn the_checker_can_fail() {
        for bad in [
            "x 1 2",
            "x{a=\"b} 1",
            "x{a=\"b\"}1",
            "9x 1",
            "x{a=b} 1",
            "x{a=\"\\q\"} 1",
            "x one",
            "x{=\"v\"} 1",
        ] {
            assert!(parse_sample(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_sample("x{a=\"b\\\"c\",d_1=\"\"} -1.5e3"), Ok("x"));
        assert!(check_exposition("x 1\n").is_err(), "no TYPE");
    }

    #[test]
    fn every_line_parses() {
        let text = render(&Snapshot::example());
        let n = check_exposition(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert!(n > 20, "{n} samples");
        for line in [
            "restage_up 1",
            "restage_state{state=\"showing\"} 1",
            "restage_state{state=\"idle\"} 0",
            "restage_budget_used_lux_hours{window=\"day\"} 412.5",
            "restage_budget_lux_hours{window=\"year\"} 150000",
            "restage_projector_reachable{projector=\"right\"} 0",
            "restage_projector_lamp_hours{projector=\"left\"} 1204",
            "restage_alerts{level=\"warning\"} 1",
            "restage_bundle_expiry_seconds 7689600",
        ] {
            assert!(text.lines().any(|l| l == line), "missing {line}\n{text}");
        }
    }

    #[test]
    fn hostile_label_values_are_escaped() {
        let mut s = Snapshot::example();
        let evil = "a\"b\\c\nd\u{1b}[31m}e{";
        s.projectors[0].name = evil.into();
        s.appliance.version = evil.into();
        s.alerts.push(Alert {
            level: AlertLevel::Critical,
            kind: evil.into(),
            message: evil.into(),
            since: "".into(),
        });
        let text = render(&s);
        check_exposition(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert!(text.contains(r#"restage_projector_reachable{projector="a\"b\\c\nd␛[31m}e{"} 1"#), "{text}");
        assert!(!text.contains('\u{1b}'));
    }

    #[test]
    fn values_use_the_format_s_spelling() {
        assert_eq!(number(f64::INFINITY), "+Inf");
        assert_eq!(number(f64::NEG_INFINITY), "-Inf");
        assert_eq!(number(f64::NAN), "NaN");
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(1e21), "1000000000000000000000");
    }

    #[test]
    fn starting_snapshot_has_no_budget_or_bundle_figures() {
        let s = Snapshot::starting(
            "0.1.0",
            crate::status::snapshot::Clock { local: "x".into(), zone: "UTC".into(), unix_ms: 5_000 },
        );
        let text = render(&s);
        check_exposition(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert!(text.contains("restage_state{state=\"starting\"} 1"));
        assert!(text.contains("restage_bundle_loaded 0"));
        assert!(!text.contains("restage_budget_used_lux_hours{"));
        assert!(text.contains("restage_snapshot_timestamp_seconds 5"));
    }
}
