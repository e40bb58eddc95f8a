//! The light history as CSV (`restage-appliance ledger export --csv`): one line per exposure
//! row of the ledger, for a conservator's records or a loan agreement's light report.
//!
//! Rows are written whole (a row overlapping the range's edge is not cut), with lux·h computed
//! from the row itself; standing reservations (a crash or power cut ended them) are marked and
//! counted in full, as the budget counts them.

use std::io::Write;

use thiserror::Error;

use crate::ledger::ExposureRow;

#[derive(Debug, Error)]
pub enum ExportError {
    #[error("writing CSV: {0}")]
    Csv(#[from] csv::Error),
    #[error("writing CSV: {0}")]
    Io(#[from] std::io::Error),
}

/// The header line, in column order.
pub const HEADER: [&str; 11] = [
    "object",
    "kind",
    "scene",
    "lux",
    "start_utc",
    "end_utc",
    "start_local",
    "end_local",
    "duration_s",
    "lux_hours",
    "status",
];

/// Writes `rows` (object, row) as CSV. `utc` and `local` format a ledger time (Unix ms).
pub fn write_csv<W: Write>(
    rows: &[(String, ExposureRow)],
    utc: impl Fn(i64) -> String,
    local: impl Fn(i64) -> String,
    out: W,
) -> Result<(), ExportError> {
    let mut w = csv::Writer::from_writer(out);
    w.write_record(HEADER)?;
    for (object, r) in rows {
        let ms = (r.end_ms - r.start_ms) as f64;
        w.write_record([
            cell(object),
            cell(&r.kind),
            cell(&r.label),
            format!("{:.3}", r.lux),
            utc(r.start_ms),
            utc(r.end_ms),
            local(r.start_ms),
            local(r.end_ms),
            format!("{:.3}", ms / 1000.0),
            format!("{:.6}", r.lux * ms / 3_600_000.0),
            if r.committed { "committed" } else { "reservation (counted in full)" }.to_string(),
        ])?;
    }
    w.flush()?;
    Ok(())
}

/// A text cell from the bundle (object id, scene id): a spreadsheet must not take it for a
/// formula, so a leading `=`, `+`, `-`, `@` or tab gets a quote mark in front (OWASP's advice
/// for CSV injection); control characters are replaced.
fn cell(s: &str) -> String {
    let clean: String = s.chars().map(|c| if c.is_control() { '\u{fffd}' } else { c }).collect();
    match clean.chars().next() {
        Some('=' | '+' | '-' | '@' | '\t' | '\r') => format!("'{clean}"),
        _ => clean,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(label: &str, lux: f64, start_ms: i64, end_ms: i64, committed: bool) -> ExposureRow {
        ExposureRow { kind: "scene".into(), label: label.into(), lux, start_ms, end_ms, committed }
    }

    fn export(rows: &[(String, ExposureRow)]) -> String {
        let mut out = Vec::new();
        write_csv(rows, |ms| format!("u{ms}"), |ms| format!("l{ms}"), &mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn one_line_per_row_with_lux_hours() {
        let rows = vec![
            ("vase".to_string(), row("restored", 120.0, 0, 30_000, true)),
            ("vase".to_string(), row("restored", 100.0, 60_000, 90_000, false)),
        ];
        let text = export(&rows);
        let mut r = csv::Reader::from_reader(text.as_bytes());
        assert_eq!(r.headers().unwrap().iter().collect::<Vec<_>>(), HEADER);
        let recs: Vec<csv::StringRecord> = r.records().map(|x| x.unwrap()).collect();
        assert_eq!(recs.len(), 2);
        assert_eq!(&recs[0][4], "u0");
        assert_eq!(&recs[0][7], "l30000");
        assert_eq!(&recs[0][8], "30.000");
        // 120 lx for 30 s = 1 lx·h.
        assert_eq!(&recs[0][9], "1.000000");
        assert_eq!(&recs[1][10], "reservation (counted in full)");
        let total: f64 = recs.iter().map(|r| r[9].parse::<f64>().unwrap()).sum();
        assert!((total - (1.0 + 100.0 * 30.0 / 3600.0)).abs() < 1e-6);
    }

    #[test]
    fn names_from_a_bundle_cannot_become_formulas_or_break_lines() {
        let rows = vec![("=HYPERLINK(\"x\")".to_string(), row("a,\"b\"\nc", 1.0, 0, 1, true))];
        let text = export(&rows);
        let mut r = csv::Reader::from_reader(text.as_bytes());
        let rec = r.records().next().unwrap().unwrap();
        assert_eq!(&rec[0], "'=HYPERLINK(\"x\")");
        assert_eq!(&rec[2], "a,\"b\"\u{fffd}c");
        assert_eq!(text.lines().count(), 2, "{text}");
    }
}
