//! Opening hours: a weekly schedule in local wall time with closed dates and special openings
//! (`[hours]` in the configuration), and the pure question "open at this instant, and until
//! when?" that the runtime turns into the player's `Open`/`Close` events.
//!
//! Daylight saving: an interval's ends are wall times mapped to instants. A wall time the
//! clocks skip (spring forward) maps to the first instant after the jump, so an interval
//! keeps only its existing part (01:30-03:30 on the night 02:00 becomes 03:00 opens 01:30,
//! closes 03:30, one hour; 02:15-02:45 vanishes). A wall time that happens twice (fall back)
//! maps to its first occurrence, and everything between an interval's ends is open: the
//! repeated hour counts once as a wall time, so 01:00-02:30 closes at the first 02:30, while
//! 02:30-03:30 stays open through both passes of 02:30-03:00 (two hours of real time).

use std::collections::{BTreeMap, BTreeSet};

use jiff::civil::{Date, DateTime, Weekday};
use jiff::tz::AmbiguousOffset;
use serde::Deserialize;
use thiserror::Error;

use crate::zone::LocalZone;

/// How far ahead `Hours::at` looks for the next change (a closure for renovation, a year of
/// holidays); no change within it: `next_change_ms` is `None`.
pub const HORIZON_DAYS: u32 = 400;

/// A malformed `[hours]` entry: the key, the offending value and what was expected.
#[derive(Debug, Error, PartialEq, Eq)]
#[error("{key} = {value} (expected {expected})")]
pub struct HoursError {
    pub key: String,
    pub value: String,
    pub expected: String,
}

/// The `[hours]` section as written. Weekdays are lists of "HH:MM-HH:MM" intervals in
/// `time_zone`'s wall time (a missing day is closed; "24:00" ends a day at midnight);
/// `closed_dates` closes whole days ("YYYY-MM-DD"); `open_dates` replaces a date's weekday
/// intervals with its own (special openings, shorter days).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HoursConfig {
    #[serde(default)]
    pub mon: Vec<String>,
    #[serde(default)]
    pub tue: Vec<String>,
    #[serde(default)]
    pub wed: Vec<String>,
    #[serde(default)]
    pub thu: Vec<String>,
    #[serde(default)]
    pub fri: Vec<String>,
    #[serde(default)]
    pub sat: Vec<String>,
    #[serde(default)]
    pub sun: Vec<String>,
    #[serde(default)]
    pub closed_dates: Vec<String>,
    #[serde(default)]
    pub open_dates: BTreeMap<String, Vec<String>>,
}

/// Open from `start` to `end`, minutes after local midnight (`end` up to 1440 = 24:00).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Interval {
    start: u16,
    end: u16,
}

/// Whether the stage is open at an instant, until when, and why (for status and refusals).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Opening {
    pub open: bool,
    /// The next instant (Unix ms) this changes; `None`: not within `HORIZON_DAYS`.
    pub next_change_ms: Option<i64>,
    /// E.g. "closed: opens Tue 10:00", "open: closes 17:00".
    pub reason: String,
}

/// The opening hours, resolved in a time zone. Without an `[hours]` section: always open.
#[derive(Clone, Debug, Default)]
pub struct Hours {
    zone: LocalZone,
    schedule: Option<Schedule>,
}

#[derive(Clone, Debug)]
struct Schedule {
    /// Monday first.
    weekly: [Vec<Interval>; 7],
    closed: BTreeSet<Date>,
    special: BTreeMap<Date, Vec<Interval>>,
}

const WEEKDAYS: [&str; 7] = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"];

impl HoursConfig {
    /// Checks every entry and resolves the schedule in `zone`.
    pub fn build(&self, zone: &LocalZone) -> Result<Hours, HoursError> {
        let days = [&self.mon, &self.tue, &self.wed, &self.thu, &self.fri, &self.sat, &self.sun];
        let mut weekly: [Vec<Interval>; 7] = Default::default();
        for ((name, list), out) in WEEKDAYS.iter().zip(days).zip(weekly.iter_mut()) {
            *out = parse_day(&format!("hours.{name}"), list)?;
        }
        let mut closed = BTreeSet::new();
        for d in &self.closed_dates {
            closed.insert(parse_date("hours.closed_dates", d)?);
        }
        let mut special = BTreeMap::new();
        for (d, list) in &self.open_dates {
            let key = format!("hours.open_dates.{d:?}");
            let date = parse_date("hours.open_dates", d)?;
            if closed.contains(&date) {
                return Err(HoursError {
                    key,
                    value: format!("{list:?}"),
                    expected: "a date not also in hours.closed_dates".into(),
                });
            }
            if list.is_empty() {
                return Err(HoursError {
                    key,
                    value: "[]".into(),
                    expected: "at least one interval (hours.closed_dates closes a day)".into(),
                });
            }
            special.insert(date, parse_day(&key, list)?);
        }
        Ok(Hours { zone: zone.clone(), schedule: Some(Schedule { weekly, closed, special }) })
    }
}

fn parse_day(key: &str, list: &[String]) -> Result<Vec<Interval>, HoursError> {
    let mut out = Vec::with_capacity(list.len());
    for s in list {
        let bad = || HoursError {
            key: key.to_string(),
            value: format!("{s:?}"),
            expected: "\"HH:MM-HH:MM\" with 00:00 <= start < end <= 24:00".into(),
        };
        let (a, b) = s.split_once('-').ok_or_else(bad)?;
        let (start, end) = (parse_hhmm(a.trim()).ok_or_else(bad)?, parse_hhmm(b.trim()).ok_or_else(bad)?);
        if start >= end || start >= 1440 {
            return Err(bad());
        }
        out.push(Interval { start, end });
    }
    out.sort();
    if let Some(w) = out.windows(2).find(|w| w[1].start < w[0].end) {
        return Err(HoursError {
            key: key.to_string(),
            value: format!("\"{}\" and \"{}\"", hhmm(w[0].start, w[0].end), hhmm(w[1].start, w[1].end)),
            expected: "intervals that do not overlap".into(),
        });
    }
    Ok(out)
}

/// "HH:MM" (two digits each) as minutes after midnight; "24:00" is 1440.
fn parse_hhmm(s: &str) -> Option<u16> {
    let b = s.as_bytes();
    if b.len() != 5 || b[2] != b':' || !s[..2].bytes().chain(s[3..].bytes()).all(|c| c.is_ascii_digit()) {
        return None;
    }
    let (h, m): (u16, u16) = (s[..2].parse().ok()?, s[3..].parse().ok()?);
    match (h, m) {
        (24, 0) => Some(1440),
        (0..=23, 0..=59) => Some(h * 60 + m),
        _ => None,
    }
}

fn hhmm(start: u16, end: u16) -> String {
    format!("{:02}:{:02}-{:02}:{:02}", start / 60, start % 60, end / 60, end % 60)
}

fn parse_date(key: &str, s: &str) -> Result<Date, HoursError> {
    let bad = || HoursError {
        key: key.to_string(),
        value: format!("{s:?}"),
        expected: "a date \"YYYY-MM-DD\"".into(),
    };
    // jiff also reads other ISO 8601 spellings; a configuration keeps to one.
    let shape = s.len() == 10
        && s.bytes().enumerate().all(|(i, c)| if i == 4 || i == 7 { c == b'-' } else { c.is_ascii_digit() });
    if !shape {
        return Err(bad());
    }
    s.parse::<Date>().map_err(|_| bad())
}

fn weekday_index(w: Weekday) -> usize {
    usize::from(w.to_monday_zero_offset().unsigned_abs())
}

impl Hours {
    /// Always open (no `[hours]` section): today's behaviour.
    pub fn always_open(zone: LocalZone) -> Hours {
        Hours { zone, schedule: None }
    }

    /// Whether any schedule applies (an `[hours]` section was given).
    pub fn is_scheduled(&self) -> bool {
        self.schedule.is_some()
    }

    pub fn zone(&self) -> &LocalZone {
        &self.zone
    }

    /// Open or closed at `unix_ms`, the next change, and why.
    pub fn at(&self, unix_ms: i64) -> Opening {
        let Some(schedule) = &self.schedule else {
            return Opening { open: true, next_change_ms: None, reason: "open: no opening hours set".into() };
        };
        let Some(today) = self.zone.date_of(unix_ms) else {
            return Opening { open: false, next_change_ms: None, reason: "closed: time out of range".into() };
        };
        // The open stretches from today on, in order, adjacent ones merged (18:00-24:00
        // then 00:00-02:00 is one stretch).
        let mut runs: Vec<(i64, i64)> = Vec::new();
        let mut date = today;
        let mut horizon_reached = true;
        for _ in 0..HORIZON_DAYS {
            for r in self.ranges_on(schedule, date) {
                match runs.last_mut() {
                    Some(last) if r.0 <= last.1 => last.1 = last.1.max(r.1),
                    _ => runs.push(r),
                }
            }
            // Enough once a stretch starts after `unix_ms` and the one holding it has ended.
            if runs.iter().any(|&(s, _)| s > unix_ms) && runs.last().is_some_and(|&(_, e)| e > unix_ms) {
                horizon_reached = false;
                break;
            }
            let Ok(next) = date.tomorrow() else { break };
            date = next;
        }
        let current = runs.iter().find(|&&(s, e)| s <= unix_ms && unix_ms < e);
        let closed_today = schedule.closed.contains(&today) && !schedule.special.contains_key(&today);
        match current {
            Some(&(_, end)) => {
                // A stretch still running at the horizon has no change in sight.
                let ends = !(horizon_reached && runs.last() == current);
                let next = ends.then_some(end);
                let reason = match next {
                    Some(t) => format!("open: closes {}", self.when(unix_ms, t)),
                    None => format!("open: no closing within {HORIZON_DAYS} days"),
                };
                Opening { open: true, next_change_ms: next, reason }
            }
            None => {
                let next = runs.iter().map(|&(s, _)| s).find(|&s| s > unix_ms);
                let why = if closed_today {
                    format!("closed ({} is a closed date)", today)
                } else {
                    "closed".to_string()
                };
                let reason = match next {
                    Some(t) => format!("{why}: opens {}", self.when(unix_ms, t)),
                    None => format!("{why}: no opening within {HORIZON_DAYS} days"),
                };
                Opening { open: false, next_change_ms: next, reason }
            }
        }
    }

    /// The open intervals of local `date` as Unix ms ranges (empty ones, wholly inside a
    /// spring-forward gap, left out).
    fn ranges_on(&self, s: &Schedule, date: Date) -> Vec<(i64, i64)> {
        let intervals = match s.special.get(&date) {
            Some(list) => list.as_slice(),
            None if s.closed.contains(&date) => &[],
            None => s.weekly[weekday_index(date.weekday())].as_slice(),
        };
        intervals
            .iter()
            .filter_map(|i| {
                let start = self.wall_to_ms(date, i.start)?;
                let end = self.wall_to_ms(date, i.end)?;
                (end > start).then_some((start, end))
            })
            .collect()
    }

    /// Wall time `minutes` after the start of local `date` as an instant: a skipped wall time
    /// is the first instant after the jump; a repeated one, its first occurrence.
    fn wall_to_ms(&self, date: Date, minutes: u16) -> Option<i64> {
        let dt: DateTime = if minutes >= 1440 {
            date.tomorrow().ok()?.at(0, 0, 0, 0)
        } else {
            date.at((minutes / 60) as i8, (minutes % 60) as i8, 0, 0)
        };
        let tz = self.zone.time_zone();
        let amb = tz.to_ambiguous_timestamp(dt);
        match amb.offset() {
            AmbiguousOffset::Unambiguous { .. } | AmbiguousOffset::Fold { .. } => {
                amb.earlier().ok().map(|t| t.as_millisecond())
            }
            AmbiguousOffset::Gap { .. } => {
                // `earlier` lies before the jump; the jump itself is the next transition.
                let before = amb.earlier().ok()?;
                tz.following(before).next().map(|t| t.timestamp().as_millisecond())
            }
        }
    }

    /// "Tue 10:00" within the coming week, else "Tue 2026-12-29 10:00".
    fn when(&self, now_ms: i64, t_ms: i64) -> String {
        let Some(z) = self.zone.zoned(t_ms) else { return format!("at {t_ms} Unix ms") };
        if t_ms - now_ms < 6 * 86_400_000 {
            z.strftime("%a %H:%M").to_string()
        } else {
            z.strftime("%a %Y-%m-%d %H:%M").to_string()
        }
    }
}

#[cfg(test)]
mod tests {
    use jiff::Timestamp;

    use super::*;

    fn at(s: &str) -> i64 {
        s.parse::<Timestamp>().unwrap().as_millisecond()
    }

    fn hours(zone: &str, toml_text: &str) -> Hours {
        let c: HoursConfig = toml::from_str(toml_text).unwrap();
        c.build(&LocalZone::named(zone).unwrap()).unwrap()
    }

    fn error(toml_text: &str) -> String {
        let c: HoursConfig = toml::from_str(toml_text).unwrap();
        c.build(&LocalZone::utc()).unwrap_err().to_string()
    }

    const MUSEUM: &str = r#"
        tue = ["10:00-17:00"]
        wed = ["10:00-17:00"]
        thu = ["10:00-12:30", "13:30-21:00"]
        fri = ["10:00-17:00"]
        sat = ["10:00-17:00"]
        sun = ["12:00-17:00"]
        closed_dates = ["2026-12-25", "2027-01-01"]
        [open_dates]
        "2026-12-28" = ["12:00-16:00"]
    "#;

    #[test]
    fn weekly_schedule_opens_and_closes() {
        let h = hours("Europe/Amsterdam", MUSEUM);
        // Monday 2026-06-01 is closed (CEST, UTC+2).
        let o = h.at(at("2026-06-01T10:00:00Z"));
        assert_eq!(
            o,
            Opening {
                open: false,
                next_change_ms: Some(at("2026-06-02T08:00:00Z")),
                reason: "closed: opens Tue 10:00".into()
            }
        );
        let o = h.at(at("2026-06-02T08:00:00Z"));
        assert!(o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-06-02T15:00:00Z")));
        assert_eq!(o.reason, "open: closes Tue 17:00");
        // Thursday's lunch break.
        let o = h.at(at("2026-06-04T10:45:00Z"));
        assert!(!o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-06-04T11:30:00Z")));
        // The end is exclusive.
        assert!(!h.at(at("2026-06-02T15:00:00Z")).open);
        assert!(h.at(at("2026-06-02T15:00:00Z") - 1).open);
    }

    #[test]
    fn closed_and_open_dates_override_the_week() {
        let h = hours("Europe/Amsterdam", MUSEUM);
        // Friday 2026-12-25 is a closed date (CET, UTC+1): next is Saturday 10:00.
        let o = h.at(at("2026-12-25T11:00:00Z"));
        assert!(!o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-12-26T09:00:00Z")));
        assert_eq!(o.reason, "closed (2026-12-25 is a closed date): opens Sat 10:00");
        // Monday 2026-12-28 opens specially, 12:00-16:00.
        let o = h.at(at("2026-12-27T17:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2026-12-28T11:00:00Z")));
        assert!(h.at(at("2026-12-28T12:00:00Z")).open);
        assert_eq!(h.at(at("2026-12-28T12:00:00Z")).next_change_ms, Some(at("2026-12-28T15:00:00Z")));
        // Thursday 2026-12-31 18:00 local: next Saturday (Friday is closed), a week's names.
        let o = h.at(at("2026-12-31T20:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2027-01-02T09:00:00Z")));
    }

    #[test]
    fn far_openings_name_the_date_and_an_empty_schedule_never_opens() {
        let h = hours("UTC", "closed_dates = []\n[open_dates]\n\"2026-08-01\" = [\"10:00-11:00\"]\n");
        let o = h.at(at("2026-06-01T00:00:00Z"));
        assert_eq!(o.reason, "closed: opens Sat 2026-08-01 10:00");
        let o = hours("UTC", "").at(at("2026-06-01T00:00:00Z"));
        assert_eq!((o.open, o.next_change_ms), (false, None));
        assert!(o.reason.contains("no opening"), "{}", o.reason);
    }

    #[test]
    fn no_section_is_always_open() {
        let o = Hours::always_open(LocalZone::utc()).at(at("2026-06-01T03:00:00Z"));
        assert!(o.open && o.next_change_ms.is_none());
        assert!(Hours::default().at(0).open);
    }

    #[test]
    fn stretches_across_midnight_are_one_opening() {
        let h = hours("UTC", "mon = [\"18:00-24:00\"]\ntue = [\"00:00-02:00\", \"02:00-03:00\"]\n");
        // Monday 2026-06-01 20:00: open until Tuesday 03:00, no change at midnight or 02:00.
        let o = h.at(at("2026-06-01T20:00:00Z"));
        assert!(o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-06-02T03:00:00Z")));
        let always =
            hours("UTC", &WEEKDAYS.iter().map(|d| format!("{d} = [\"00:00-24:00\"]\n")).collect::<String>());
        let o = always.at(at("2026-06-01T20:00:00Z"));
        assert!(o.open && o.next_change_ms.is_none(), "{o:?}");
    }

    #[test]
    fn spring_forward_keeps_only_the_existing_part() {
        // Europe/Amsterdam, Sunday 2026-03-29: 02:00 CET (01:00Z) becomes 03:00 CEST.
        let h = hours("Europe/Amsterdam", "sun = [\"01:30-03:30\"]\n");
        let o = h.at(at("2026-03-29T00:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2026-03-29T00:30:00Z")));
        let o = h.at(at("2026-03-29T00:30:00Z"));
        // 01:30 CET to 03:30 CEST: one hour of real time.
        assert_eq!(o.next_change_ms, Some(at("2026-03-29T01:30:00Z")));
        // An interval starting in the gap opens when the clocks land: 03:00 CEST.
        let h = hours("Europe/Amsterdam", "sun = [\"02:30-04:00\"]\n");
        let o = h.at(at("2026-03-29T00:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2026-03-29T01:00:00Z")));
        assert_eq!(o.reason, "closed: opens Sun 03:00");
        // One wholly inside the gap does not happen that day (next: a week later, CEST).
        let h = hours("Europe/Amsterdam", "sun = [\"02:15-02:45\"]\n");
        let o = h.at(at("2026-03-29T00:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2026-04-05T00:15:00Z")));
        // America/New_York, Sunday 2026-03-08: 02:00 EST (07:00Z) becomes 03:00 EDT.
        let h = hours("America/New_York", "sun = [\"02:30-04:00\"]\n");
        let o = h.at(at("2026-03-08T06:00:00Z"));
        assert_eq!(o.next_change_ms, Some(at("2026-03-08T07:00:00Z")));
        assert_eq!(h.at(at("2026-03-08T07:00:00Z")).next_change_ms, Some(at("2026-03-08T08:00:00Z")));
    }

    #[test]
    fn fall_back_counts_the_repeated_hour_once_in_wall_time() {
        // Europe/Amsterdam, Sunday 2026-10-25: 03:00 CEST (01:00Z) becomes 02:00 CET.
        let h = hours("Europe/Amsterdam", "sun = [\"01:00-02:30\"]\n");
        // Opens 01:00 CEST (23:00Z Saturday), closes at the first 02:30 (00:30Z).
        let o = h.at(at("2026-10-24T23:00:00Z"));
        assert!(o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-10-25T00:30:00Z")));
        // The second 02:15 (CET, 01:15Z) is closed.
        assert!(!h.at(at("2026-10-25T01:15:00Z")).open);
        // An interval spanning the repeated hour stays open through both passes: two hours.
        let h = hours("Europe/Amsterdam", "sun = [\"02:30-03:30\"]\n");
        let o = h.at(at("2026-10-25T00:30:00Z"));
        assert!(o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-10-25T02:30:00Z")));
        assert!(h.at(at("2026-10-25T01:15:00Z")).open);
        // America/New_York, Sunday 2026-11-01: 02:00 EDT (06:00Z) becomes 01:00 EST.
        let h = hours("America/New_York", "sun = [\"00:00-01:30\"]\n");
        let o = h.at(at("2026-11-01T04:00:00Z"));
        assert!(o.open);
        assert_eq!(o.next_change_ms, Some(at("2026-11-01T05:30:00Z")));
        assert!(!h.at(at("2026-11-01T06:15:00Z")).open);
    }

    #[test]
    fn a_zone_without_dst_is_the_same_all_year() {
        let daily = WEEKDAYS.iter().map(|d| format!("{d} = [\"09:00-17:00\"]\n")).collect::<String>();
        let h = hours("Asia/Kolkata", &daily);
        for day in ["2026-01-15", "2026-03-29", "2026-07-15", "2026-10-25"] {
            // 09:00 IST is 03:30Z.
            let o = h.at(at(&format!("{day}T03:29:00Z")));
            assert_eq!(o.next_change_ms, Some(at(&format!("{day}T03:30:00Z"))), "{day}");
            let o = h.at(at(&format!("{day}T03:30:00Z")));
            assert_eq!(o.next_change_ms, Some(at(&format!("{day}T11:30:00Z"))), "{day}");
        }
    }

    #[test]
    fn malformed_entries_name_the_key() {
        let e = error("mon = [\"25:00-26:00\"]\n");
        assert!(e.starts_with("hours.mon = \"25:00-26:00\"") && e.contains("HH:MM-HH:MM"), "{e}");
        let e = error("tue = [\"17:00-10:00\"]\n");
        assert!(e.starts_with("hours.tue = \"17:00-10:00\""), "{e}");
        let e = error("wed = [\"10:00-10:00\"]\n");
        assert!(e.starts_with("hours.wed"), "{e}");
        let e = error("thu = [\"9:00-17:00\"]\n");
        assert!(e.starts_with("hours.thu"), "{e}");
        let e = error("fri = [\"10-17\"]\n");
        assert!(e.starts_with("hours.fri"), "{e}");
        let e = error("sat = [\"13:00-17:00\", \"10:00-13:30\"]\n");
        assert!(
            e.starts_with("hours.sat = \"10:00-13:30\" and \"13:00-17:00\"") && e.contains("overlap"),
            "{e}"
        );
        let e = error("closed_dates = [\"2026-13-01\"]\n");
        assert!(e.starts_with("hours.closed_dates = \"2026-13-01\"") && e.contains("YYYY-MM-DD"), "{e}");
        let e = error("closed_dates = [\"20261201\"]\n");
        assert!(e.starts_with("hours.closed_dates"), "{e}");
        let e = error("[open_dates]\n\"2026-02-30\" = [\"10:00-12:00\"]\n");
        assert!(e.starts_with("hours.open_dates = \"2026-02-30\""), "{e}");
        let e = error("[open_dates]\n\"2026-02-03\" = [\"12:00-10:00\"]\n");
        assert!(e.starts_with("hours.open_dates.\"2026-02-03\" = \"12:00-10:00\""), "{e}");
        let e = error("closed_dates = [\"2026-12-25\"]\n[open_dates]\n\"2026-12-25\" = [\"10:00-12:00\"]\n");
        assert!(e.contains("hours.open_dates.\"2026-12-25\"") && e.contains("closed_dates"), "{e}");
        // Adjacent intervals and a 24:00 end are fine.
        let c: HoursConfig = toml::from_str("mon = [\"10:00-12:00\", \"12:00-24:00\"]\n").unwrap();
        assert!(c.build(&LocalZone::utc()).is_ok());
    }
}
