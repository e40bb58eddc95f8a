//! UTC instants as people write them: [`format_utc`] for everything restage prints (bundle
//! validity, errors, the ledger's export) and [`parse_instant`] for times people type
//! (`--now`). Proleptic Gregorian calendar, UTC only, no leap seconds; local time zones are
//! the appliance's business (`jiff`), not this module's.

use thiserror::Error;

use crate::text::printable;

/// Seconds in a day.
const DAY_S: i64 = 86_400;

/// Why a typed time was refused. The message lists every accepted form.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[error(
    "'{}' is not a time: {problem} (expected 2027-12-31, 2027-12-31T10:00:00Z, 2027-12-31 10:00:00 (UTC) or Unix seconds)",
    printable(text)
)]
pub struct TimeError {
    pub text: String,
    pub problem: String,
}

/// `(year, month 1..=12, day 1..=31)` of a day counted from 1970-01-01 (Howard Hinnant's
/// `civil_from_days`; exact for every `i64` day a Unix second can name).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// Days from 1970-01-01 to `year-month-day` (Hinnant's `days_from_civil`, the inverse of
/// [`civil_from_days`]). `month` 1..=12 and `day` 1..=31; the caller checks the day exists.
pub fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y.rem_euclid(400);
    let mp = i64::from((month + 9) % 12);
    let doy = (153 * mp + 2) / 5 + i64::from(day) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

fn days_in_month(year: i64, month: u32) -> u32 {
    let leap = year % 4 == 0 && (year % 100 != 0 || year % 400 == 0);
    match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// `YYYY-MM-DD HH:MM:SS UTC` for Unix seconds, e.g. `2027-12-02 06:41:11 UTC`.
/// [`parse_instant`] reads it back.
pub fn format_utc(unix_s: i64) -> String {
    let (y, m, d) = civil_from_days(unix_s.div_euclid(DAY_S));
    let secs = unix_s.rem_euclid(DAY_S);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC", secs / 3600, secs / 60 % 60, secs % 60)
}

/// Unix seconds from a time as people type it, always UTC:
/// - `2027-12-31` (midnight UTC at the start of that day),
/// - `2027-12-31T10:00:00Z`,
/// - `2027-12-31 10:00:00` or `2027-12-31 10:00:00 UTC` (what [`format_utc`] prints),
/// - plain Unix seconds, e.g. `1830297600` or `-1`.
///
/// Years are four digits (0000..=9999); no other zone or offset is accepted, so a time is
/// never silently read in the wrong zone.
pub fn parse_instant(text: &str) -> Result<i64, TimeError> {
    let bad = |problem: &str| TimeError { text: text.to_owned(), problem: problem.to_owned() };
    let t = text.trim();
    if t.is_empty() {
        return Err(bad("it is empty"));
    }
    let unsigned = t.strip_prefix('-').unwrap_or(t);
    if !unsigned.is_empty() && unsigned.bytes().all(|b| b.is_ascii_digit()) {
        return t.parse::<i64>().map_err(|_| bad("too large for Unix seconds"));
    }
    // A date, then optionally 'T' + time + 'Z', or ' ' + time (+ " UTC").
    let (date, time) = match (t.get(..10), t.get(10..)) {
        (Some(date), Some("")) => (date, None),
        (Some(date), Some(rest)) => {
            let time = if let Some(r) = rest.strip_prefix('T') {
                r.strip_suffix('Z').ok_or_else(|| bad("a time after 'T' must end in 'Z' (UTC)"))?
            } else if let Some(r) = rest.strip_prefix(' ') {
                r.strip_suffix(" UTC").unwrap_or(r)
            } else {
                return Err(bad("the date must be followed by 'T', a space, or nothing"));
            };
            (date, Some(time))
        }
        _ => return Err(bad("not a date (YYYY-MM-DD) nor a number")),
    };
    let fields =
        |s: &str, sep: u8, widths: &[usize]| -> Option<Vec<u32>> {
            let parts: Vec<&str> = s.split(sep as char).collect();
            if parts.len() != widths.len() {
                return None;
            }
            parts
                .iter()
                .zip(widths)
                .map(|(p, &w)| {
                    if p.len() == w && p.bytes().all(|b| b.is_ascii_digit()) { p.parse().ok() } else { None }
                })
                .collect()
        };
    let ymd = fields(date, b'-', &[4, 2, 2]).ok_or_else(|| bad("the date must be YYYY-MM-DD"))?;
    let (year, month, day) = (i64::from(ymd[0]), ymd[1], ymd[2]);
    if !(1..=12).contains(&month) {
        return Err(bad("the month must be 01..=12"));
    }
    if day == 0 || day > days_in_month(year, month) {
        return Err(bad("that day does not exist in that month"));
    }
    let secs = match time {
        None => 0,
        Some(time) => {
            let hms = fields(time, b':', &[2, 2, 2]).ok_or_else(|| bad("the time must be HH:MM:SS"))?;
            if hms[0] > 23 || hms[1] > 59 || hms[2] > 59 {
                return Err(bad("the time must be 00:00:00..=23:59:59"));
            }
            i64::from(hms[0]) * 3600 + i64::from(hms[1]) * 60 + i64::from(hms[2])
        }
    };
    Ok(days_from_civil(year, month, day) * DAY_S + secs)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    #[test]
    fn known_dates() {
        assert_eq!(format_utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(format_utc(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(format_utc(1_767_225_599), "2025-12-31 23:59:59 UTC");
        assert_eq!(format_utc(-1), "1969-12-31 23:59:59 UTC");
        assert_eq!(format_utc(1_827_701_076), "2027-12-01 22:44:36 UTC");
    }

    #[test]
    fn every_accepted_form() {
        let midnight = 1_830_211_200; // 2027-12-31 00:00:00 UTC
        assert_eq!(parse_instant("2027-12-31"), Ok(midnight));
        assert_eq!(parse_instant("2027-12-31T10:00:00Z"), Ok(midnight + 36_000));
        assert_eq!(parse_instant("2027-12-31 10:00:00"), Ok(midnight + 36_000));
        assert_eq!(parse_instant("2027-12-31 10:00:00 UTC"), Ok(midnight + 36_000));
        assert_eq!(parse_instant(" 1830211200 "), Ok(midnight));
        assert_eq!(parse_instant("-1"), Ok(-1));
        assert_eq!(parse_instant("1969-12-31T23:59:59Z"), Ok(-1));
        assert_eq!(parse_instant("2000-02-29"), Ok(951_782_400));
    }

    #[test]
    fn refusals_say_what_is_accepted() {
        for bad in [
            "",
            "-",
            "tomorrow",
            "2027-13-01",
            "2027-02-29",
            "1900-02-29",
            "2027-12-31T10:00:00",
            "2027-12-31T10:00:00+01:00",
            "2027-12-31 24:00:00",
            "2027-12-31 10:00",
            "2027-12-31 10:00:60",
            "27-12-31",
            "2027-1-31",
            "2027/12/31",
            "2027-12-31X",
            "99999999999999999999",
            "2027-12-3\u{e9}",
        ] {
            let e = parse_instant(bad).unwrap_err();
            assert!(e.to_string().contains("(expected 2027-12-31, 2027-12-31T10:00:00Z"), "{bad:?}: {e}");
        }
        let e = parse_instant("\u{1b}[2K").unwrap_err().to_string();
        assert!(!e.contains('\u{1b}') && e.contains("\\u{1b}[2K"), "{e}");
    }

    /// Years 0000..=9999: what `parse_instant` reads back.
    const FIRST: i64 = -62_167_219_200; // 0000-01-01 00:00:00 UTC
    const LAST: i64 = 253_402_300_799; // 9999-12-31 23:59:59 UTC

    proptest! {
        #[test]
        fn format_then_parse_is_the_identity(t in FIRST..=LAST) {
            let text = format_utc(t);
            prop_assert_eq!(parse_instant(&text), Ok(t), "{}", text);
            let iso = format!("{}T{}Z", &text[..10], &text[11..19]);
            prop_assert_eq!(parse_instant(&iso), Ok(t));
            prop_assert_eq!(parse_instant(&t.to_string()), Ok(t));
        }

        #[test]
        fn days_round_trip(days in -4_000_000i64..4_000_000) {
            let (y, m, d) = civil_from_days(days);
            prop_assert!((1..=12).contains(&m) && d >= 1 && d <= days_in_month(y, m));
            prop_assert_eq!(days_from_civil(y, m, d), days);
        }

        #[test]
        fn parse_never_panics(s in "\\PC{0,30}") {
            let _ = parse_instant(&s);
        }
    }

    #[test]
    fn the_range_ends() {
        assert_eq!(format_utc(FIRST), "0000-01-01 00:00:00 UTC");
        assert_eq!(format_utc(LAST), "9999-12-31 23:59:59 UTC");
        // Far outside the typed range formatting still works (no overflow).
        assert!(format_utc(i64::MAX).ends_with(" UTC"));
        assert!(format_utc(i64::MIN).ends_with(" UTC"));
    }
}
