//! The status page: one self-contained HTML document (inline CSS, no script, no external
//! asset) rendered from a [`Snapshot`]. maud escapes every interpolated value; control
//! characters (terminal escapes from a hostile bundle name) are made visible afterwards.

use maud::{DOCTYPE, Markup, PreEscaped, html};

use super::snapshot::{AlertLevel, BudgetInfo, BundleInfo, InboxInfo, Power, Snapshot, StateKind, Window};

/// Seconds between the page's own reloads (`<meta http-equiv="refresh">`).
pub const REFRESH_S: u32 = 10;

const CSS: &str = r#"
:root { color-scheme: light; --ink: #1d232a; --muted: #5d6975; --line: #d9dee4; --card: #ffffff; }
* { box-sizing: border-box; }
body { margin: 0; background: #eef1f4; color: var(--ink);
  font: 17px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif; }
main { max-width: 1140px; margin: 0 auto; padding: 20px 24px 32px; }
.banner { border-radius: 14px; padding: 22px 28px; color: #fff; display: flex; gap: 24px;
  justify-content: space-between; align-items: center; flex-wrap: wrap;
  box-shadow: 0 2px 6px rgba(0,0,0,.15); }
.banner .label { font-size: 15px; letter-spacing: .08em; text-transform: uppercase; opacity: .85; }
.banner .state { font-size: 54px; font-weight: 800; line-height: 1.05; letter-spacing: .02em;
  text-transform: uppercase; }
.banner .detail { font-size: 22px; margin-top: 4px; }
.banner .when { text-align: right; font-size: 18px; }
.banner .when .time { font-size: 30px; font-weight: 700; font-variant-numeric: tabular-nums; }
.s-showing { background: #1e7d3a; } .s-idle { background: #1f5f99; } .s-ending, .s-cooldown { background: #2f6f7a; }
.s-starting { background: #55606b; } .s-closed { background: #5b4b8a; } .s-dark { background: #3a3f45; }
.s-budget-exhausted { background: #a85d00; } .s-fault { background: #b3261e; }
.alerts { margin-top: 16px; display: grid; gap: 8px; }
.alert { border-radius: 10px; padding: 10px 16px; border-left: 8px solid; background: #fff; font-size: 18px; }
.alert .kind { font-weight: 700; margin-right: 8px; }
.alert .since { color: var(--muted); font-size: 15px; float: right; }
.a-critical { border-color: #b3261e; background: #fdecea; } .a-warning { border-color: #c77700; background: #fff4e0; }
.a-info { border-color: #1f5f99; background: #e8f1fa; }
.grid { display: grid; grid-template-columns: 1fr 1fr; gap: 16px; margin-top: 16px; }
@media (max-width: 800px) { .grid { grid-template-columns: 1fr; } .banner .when { text-align: left; } }
section { background: var(--card); border-radius: 12px; padding: 16px 20px; box-shadow: 0 1px 3px rgba(0,0,0,.08); }
section.wide { grid-column: 1 / -1; }
h2 { font-size: 15px; text-transform: uppercase; letter-spacing: .08em; color: var(--muted); margin: 0 0 10px; }
table { width: 100%; border-collapse: collapse; font-variant-numeric: tabular-nums; }
th, td { text-align: left; padding: 6px 8px; border-bottom: 1px solid var(--line); vertical-align: top; }
th { font-size: 14px; color: var(--muted); font-weight: 600; }
tr:last-child td, tr:last-child th { border-bottom: none; }
td.t { white-space: nowrap; }
td.num, th.num { text-align: right; }
.kv th { width: 40%; font-size: 16px; color: var(--muted); font-weight: 500; }
.window { margin-bottom: 14px; }
.window .name { font-weight: 600; } .window .fig { font-size: 20px; margin: 2px 0 6px; }
.window .fig b { font-size: 26px; font-variant-numeric: tabular-nums; }
.window .left { color: var(--muted); font-size: 15px; margin-top: 3px; }
.bar { height: 14px; background: #e3e7ec; border-radius: 7px; overflow: hidden; }
.bar > div { height: 100%; background: #2e8b57; }
.bar.warn > div { background: #d98b00; } .bar.over > div { background: #b3261e; }
.ok { color: #1e7d3a; font-weight: 700; } .bad { color: #b3261e; font-weight: 700; }
.dim { color: var(--muted); }
.empty { color: var(--muted); font-style: italic; }
footer { margin-top: 18px; color: var(--muted); font-size: 14px; display: flex; justify-content: space-between; flex-wrap: wrap; gap: 8px; }
footer a { color: inherit; }
"#;

/// The page for `snap`.
pub fn render(snap: &Snapshot) -> String {
    visible_controls(&page(snap).into_string())
}

fn page(s: &Snapshot) -> Markup {
    let title = match &s.appliance.name {
        Some(n) => format!("{} — {}", s.state.kind.name(), n),
        None => format!("{} — restage appliance", s.state.kind.name()),
    };
    html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                meta name="viewport" content="width=device-width, initial-scale=1";
                meta http-equiv="refresh" content=(REFRESH_S);
                title { (title) }
                style { (PreEscaped(CSS)) }
            }
            body {
                main {
                    (banner(s))
                    (alerts(s))
                    div.grid {
                        (budget(s))
                        (bundle(s))
                        (projectors(s))
                        (showings(s))
                        (warnings(s))
                        (events(s))
                    }
                    footer {
                        span {
                            "restage-appliance " (s.appliance.version)
                            " · up " (uptime(s.appliance.uptime_s))
                            " · page as of " (s.clock.local) " · reloads every " (REFRESH_S) " s"
                        }
                        span { a href="/status.json" { "status.json" } " · " a href="/metrics" { "metrics" } }
                    }
                }
            }
        }
    }
}

fn banner(s: &Snapshot) -> Markup {
    let kind = s.state.kind;
    let opening = if s.opening.open { "open" } else { "closed" };
    html! {
        div class={ "banner s-" (kind.name()) } {
            div {
                div.label {
                    @if let Some(n) = &s.appliance.name { (n) } @else { "restage appliance" }
                }
                div.state { (state_word(kind)) }
                @if let Some(d) = &s.state.detail { div.detail { (d) } }
            }
            div.when {
                div.time { (s.clock.local) }
                div { (s.clock.zone) }
                div {
                    (opening)
                    @if s.opening.open {
                        @if let Some(c) = &s.opening.next_close { " · closes " (c.local) }
                    } @else if let Some(o) = &s.opening.next_open {
                        " · opens " (o.local)
                    }
                }
            }
        }
    }
}

fn state_word(k: StateKind) -> &'static str {
    match k {
        StateKind::BudgetExhausted => "budget exhausted",
        k => k.name(),
    }
}

fn alerts(s: &Snapshot) -> Markup {
    html! {
        @if !s.alerts.is_empty() {
            div.alerts {
                @for a in &s.alerts {
                    div class={ "alert a-" (a.level.name()) } {
                        span.since { "since " (a.since) }
                        span.kind { (level_word(a.level)) ": " (a.kind) }
                        (a.message)
                    }
                }
            }
        }
    }
}

fn level_word(l: AlertLevel) -> &'static str {
    match l {
        AlertLevel::Info => "Info",
        AlertLevel::Warning => "Warning",
        AlertLevel::Critical => "Critical",
    }
}

fn budget(s: &Snapshot) -> Markup {
    html! {
        section {
            h2 { "Light budget" }
            @match &s.budget {
                BudgetInfo::Known(b) => {
                    (window(&format!("Today ({})", b.day), &b.daily))
                    (window("Last 365 days", &b.annual))
                    table.kv {
                        tr { th { "total (this object)" } td.num { (lux_h(b.total_lux_hours)) " lux·h" } }
                        @if b.open_reservations > 0 {
                            tr { th { "uncommitted reservations" } td.num.bad { (b.open_reservations) } }
                        }
                    }
                }
                BudgetInfo::Unknown { why } => { p.empty { "Not known: " (why) } }
            }
        }
    }
}

fn window(name: &str, w: &Window) -> Markup {
    let fraction = w.budget_lux_hours.filter(|b| *b > 0.0).map(|b| w.used_lux_hours / b);
    let class = match fraction {
        Some(f) if f >= 1.0 => "bar over",
        Some(f) if f >= 0.8 => "bar warn",
        _ => "bar",
    };
    html! {
        div.window {
            div.name { (name) }
            div.fig {
                b { (lux_h(w.used_lux_hours)) }
                @if let Some(budget) = w.budget_lux_hours { " of " (lux_h(budget)) } " lux·h used"
                @if let Some(f) = fraction { span.dim { " (" (percent(f)) ")" } }
            }
            @if let Some(f) = fraction {
                div class=(class) { div style={ "width:" (percent(f.min(1.0))) } {} }
            }
            @if let Some(left) = w.left_lux_hours { div.left { (lux_h(left)) " lux·h left" } }
        }
    }
}

fn bundle(s: &Snapshot) -> Markup {
    html! {
        section {
            h2 { "Bundle" }
            @match &s.bundle {
                BundleInfo::Loaded(b) => {
                    table.kv {
                        tr { th { "object" } td { (b.object_id) } }
                        tr { th { "version" } td { (b.version) } }
                        tr { th { "hash" } td { code { (b.hash_prefix) } } }
                        tr {
                            th { "expires" }
                            @match &b.expires {
                                Some(e) => {
                                    td class=[(e.days_left < 14.0).then_some("bad")] {
                                        (e.local) " (" (days(e.days_left)) ")"
                                    }
                                }
                                None => { td.dim { "never" } }
                            }
                        }
                    }
                }
                BundleInfo::Absent { why } => { p.bad { "No bundle: " (why) } }
            }
            @if let Some(i) = &s.inbox { (inbox(i)) }
        }
    }
}

/// The inbox under the bundle: where it is, what it is doing, what it did last.
fn inbox(i: &InboxInfo) -> Markup {
    html! {
        table.kv {
            tr { th { "inbox" } td { code { (i.dir) } } }
            @if let Some(p) = &i.problem { tr { th { "inbox problem" } td.bad { (p) } } }
            @if let Some(f) = &i.installing { tr { th { "installing" } td { code { (f) } } } }
            @if let Some(l) = &i.last {
                tr {
                    th { "last from inbox" }
                    td {
                        @if l.installed { span.ok { "installed" } } @else { span.bad { "REFUSED" } }
                        " " code { (l.file) } " " span.dim { (l.at) }
                        div class=[(!l.installed).then_some("bad")] { (l.detail) }
                    }
                }
            }
        }
    }
}

fn projectors(s: &Snapshot) -> Markup {
    html! {
        section.wide {
            h2 { "Projectors" }
            @if s.projectors.is_empty() {
                p.empty { "No projector control configured." }
            } @else {
                table {
                    tr {
                        th { "name" } th { "address" } th { "reachable" } th { "power" } th { "muted" }
                        th.num { "lamp h" } th { "errors" } th { "last poll" }
                    }
                    @for p in &s.projectors {
                        tr {
                            td { b { (p.name) } }
                            td { @if let Some(a) = &p.address { code { (a) } } @else { span.dim { "—" } } }
                            td { @if p.reachable { span.ok { "yes" } } @else { span.bad { "NO" } } }
                            td class=[(p.power != Power::On).then_some("dim")] { (p.power.name()) }
                            td { @match p.muted { Some(true) => "muted", Some(false) => "no", None => "—" } }
                            td.num { @if let Some(h) = p.lamp_hours { (h) } @else { "—" } }
                            td {
                                @if p.errors.is_empty() { span.dim { "none" } }
                                @for e in &p.errors { div.bad { (e) } }
                            }
                            td.t { @if let Some(t) = &p.last_poll { (t) } @else { span.dim { "never" } } }
                        }
                    }
                }
            }
        }
    }
}

fn showings(s: &Snapshot) -> Markup {
    html! {
        section.wide {
            h2 { "Last showings" }
            @if s.showings.is_empty() {
                p.empty { "None yet." }
            } @else {
                table {
                    tr { th { "start" } th { "end" } th { "scenes" } th { "ended by" } }
                    @for w in &s.showings {
                        tr { td.t { (w.start) } td.t { (w.end) } td { (w.scenes) } td { (w.ended_by) } }
                    }
                }
            }
        }
    }
}

fn warnings(s: &Snapshot) -> Markup {
    html! {
        section.wide {
            h2 { "Budget warnings" }
            @if s.warnings.is_empty() {
                p.empty { "None." }
            } @else {
                table {
                    @for w in &s.warnings { tr { td.t.dim { (w.at) } td { (w.text) } } }
                }
            }
        }
    }
}

fn events(s: &Snapshot) -> Markup {
    html! {
        section.wide {
            h2 { "Ledger events" }
            @if s.events.is_empty() {
                p.empty { "None." }
            } @else {
                table {
                    tr { th { "time" } th { "kind" } th { "detail" } }
                    @for e in &s.events { tr { td.t.dim { (e.at) } td { (e.kind) } td { (e.detail) } } }
                }
            }
        }
    }
}

/// Lux·hours for reading: one decimal below 100, else whole, in groups of three digits.
fn lux_h(v: f64) -> String {
    if v.is_nan() || v.abs() < 100.0 {
        return format!("{v:.1}");
    }
    let digits = format!("{:.0}", v.abs());
    let mut out = String::from(if v < 0.0 { "-" } else { "" });
    for (i, d) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i) % 3 == 0 {
            out.push('\u{202f}'); // narrow no-break space
        }
        out.push(d);
    }
    out
}

fn percent(f: f64) -> String {
    format!("{:.0}%", (f * 100.0).clamp(0.0, 1000.0))
}

fn days(d: f64) -> String {
    if d < 0.0 { "expired".to_string() } else { format!("{d:.0} days left") }
}

fn uptime(s: u64) -> String {
    let (d, h, m) = (s / 86_400, s % 86_400 / 3_600, s % 3_600 / 60);
    if d > 0 {
        format!("{d} d {h} h")
    } else if h > 0 {
        format!("{h} h {m} min")
    } else {
        format!("{m} min")
    }
}

/// Replaces control characters other than newline and tab with their visible Unicode
/// pictures (ESC shows as ␛; C1 controls as U+FFFD): text from outside reaches no terminal
/// or parser as a control sequence, and the operator sees that something odd was there.
pub(crate) fn visible_controls(s: &str) -> String {
    s.chars()
        .map(|c| match c {
            '\n' | '\t' => c,
            '\u{0}'..='\u{1f}' => char::from_u32(0x2400 + c as u32).unwrap_or('\u{fffd}'),
            '\u{7f}' => '\u{2421}',
            c if c.is_control() => '\u{fffd}',
            c => c,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::status::snapshot::{Alert, Bundle, Event, Projector};

    fn hostile() -> Snapshot {
        let evil = "<script>alert(1)</script>\u{1b}[2J\u{1b}]0;pwned\u{7}\"'&";
        let mut s = Snapshot::example();
        s.appliance.name = Some(evil.into());
        s.state.detail = Some(evil.into());
        s.bundle = BundleInfo::Loaded(Bundle {
            object_id: evil.into(),
            version: 1,
            hash_prefix: evil.into(),
            expires: None,
        });
        s.projectors.push(Projector {
            name: evil.into(),
            errors: vec![evil.into()],
            ..s.projectors[0].clone()
        });
        s.alerts.push(Alert {
            level: AlertLevel::Critical,
            kind: evil.into(),
            message: evil.into(),
            since: evil.into(),
        });
        s.events.push(Event { at: evil.into(), kind: evil.into(), detail: evil.into() });
        s
    }

    #[test]
    fn hostile_names_are_escaped_and_control_characters_made_visible() {
        let page = render(&hostile());
        assert!(!page.contains("<script"), "a tag from outside reached the page");
        assert!(page.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert!(!page.chars().any(|c| c.is_control() && c != '\n' && c != '\t'), "a control character");
        assert!(page.contains("\u{241b}[2J"), "ESC is shown as ␛");
        assert!(page.contains("&quot;"));
        // The page's own markup is intact: one of each landmark, the stylesheet unescaped.
        assert_eq!(page.matches("<main>").count(), 1);
        assert!(page.contains("<style>") && page.contains(".banner {"));
    }

    #[test]
    fn page_is_self_contained_and_reloads() {
        let page = render(&Snapshot::example());
        assert!(page.starts_with("<!DOCTYPE html>"));
        assert!(page.contains(r#"<meta http-equiv="refresh" content="10">"#), "{page}");
        for external in ["<script", "src=", "<link", "http://", "https://", "@import", "url("] {
            assert!(!page.contains(external), "external asset or script: {external}");
        }
    }

    #[test]
    fn banner_is_coloured_by_state_and_shows_the_detail() {
        for kind in StateKind::ALL {
            let mut s = Snapshot::example();
            s.state.kind = kind;
            let page = render(&s);
            let class = format!("banner s-{}", kind.name());
            assert!(page.contains(&class), "{class}");
            assert!(CSS.contains(&format!(".s-{}", kind.name())), "no colour for {}", kind.name());
        }
        let page = render(&Snapshot::example());
        assert!(page.contains("scene 2 of 3") && page.contains("Europe/Berlin"));
    }

    #[test]
    fn every_section_says_something_when_empty() {
        let s = Snapshot::starting(
            "0.1.0",
            crate::status::snapshot::Clock { local: "x".into(), zone: "UTC".into(), unix_ms: 0 },
        );
        let page = render(&s);
        assert!(page.contains("Not known: the appliance is starting"));
        assert!(page.contains("No bundle: the appliance is starting"));
        assert!(page.contains("No projector control configured."));
    }

    #[test]
    fn the_inbox_says_what_it_took_last_and_why_it_refused() {
        let page = render(&Snapshot::example());
        assert!(page.contains("<code>/media/stick</code>") && page.contains(">installed</span>"), "{page}");
        let mut s = Snapshot::example();
        let i = s.inbox.as_mut().unwrap();
        i.installing = Some("/media/stick/next.bundle".into());
        i.problem = Some("bundle inbox /media/stick cannot be read: Permission denied".into());
        let last = i.last.as_mut().unwrap();
        last.installed = false;
        last.detail =
            "section 3: BLAKE3 hash does not match the manifest; moved to /media/stick/refused/x".into();
        let page = render(&s);
        assert!(page.contains("REFUSED") && page.contains("BLAKE3 hash does not match"), "{page}");
        assert!(page.contains(r#"<td class="bad">bundle inbox /media/stick cannot be read"#), "{page}");
        assert!(page.contains("<code>/media/stick/next.bundle</code>"), "{page}");
        s.inbox = None;
        assert!(!render(&s).contains("inbox"), "no inbox configured, none shown");
    }

    #[test]
    fn budget_bar_turns_amber_then_red() {
        let w = |used| Window { used_lux_hours: used, left_lux_hours: None, budget_lux_hours: Some(100.0) };
        assert!(window("d", &w(10.0)).into_string().contains(r#"class="bar""#));
        assert!(window("d", &w(85.0)).into_string().contains("bar warn"));
        assert!(window("d", &w(130.0)).into_string().contains("bar over"));
        assert!(window("d", &w(130.0)).into_string().contains("width:100%"));
        let none = Window { used_lux_hours: 3.0, left_lux_hours: None, budget_lux_hours: None };
        assert!(!window("d", &none).into_string().contains("bar"), "no budget, no bar");
    }

    #[test]
    fn lux_hours_are_grouped() {
        assert_eq!(lux_h(12.25), "12.2");
        assert_eq!(lux_h(412.5), "412");
        assert_eq!(lux_h(121_034.0), "121\u{202f}034");
        assert_eq!(lux_h(1_000_000.0), "1\u{202f}000\u{202f}000");
        assert_eq!(lux_h(-1500.0), "-1\u{202f}500");
        assert_eq!(lux_h(f64::NAN), "NaN");
    }

    #[test]
    fn uptime_reads_naturally() {
        assert_eq!(uptime(59), "0 min");
        assert_eq!(uptime(3_600 + 120), "1 h 2 min");
        assert_eq!(uptime(3 * 86_400 + 5 * 3_600), "3 d 5 h");
    }
}
