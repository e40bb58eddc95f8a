//! The stage's local time zone (an IANA name through `jiff`): where local days begin for the
//! daily light budget and the opening hours, and how times are shown to people.

use jiff::civil::Date;
use jiff::tz::{Offset, TimeZone, TimeZoneDatabase};
use jiff::{Timestamp, ZonedDateTime};
use thiserror::Error;

const MS_PER_DAY: i64 = 86_400_000;

#[derive(Debug, Error)]
pub enum ZoneError {
    #[error(
        "{name:?} is not a time zone in the system database (/usr/share/zoneinfo) nor in the copy built \
         into this program (expected an IANA name such as \"Europe/Amsterdam\" or \"UTC\")"
    )]
    Unknown { name: String },
    #[error("UTC offset {minutes} minutes is out of range (expected -840..=840)")]
    Offset { minutes: i32 },
}

/// The stage's time zone. Cheap to clone (jiff shares the zone's rules).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LocalZone {
    tz: TimeZone,
}

impl Default for LocalZone {
    fn default() -> Self {
        LocalZone::utc()
    }
}

impl LocalZone {
    pub fn utc() -> LocalZone {
        LocalZone { tz: TimeZone::UTC }
    }

    /// The zone named `name` (IANA, case-insensitive): from the system database when it has
    /// it (updated with the OS), else from the copy built into the program, so a minimal stage
    /// machine without /usr/share/zoneinfo still knows every zone.
    pub fn named(name: &str) -> Result<LocalZone, ZoneError> {
        Self::named_in(jiff::tz::db(), name)
    }

    /// As [`LocalZone::named`] with `system` standing for the system database (tests pass
    /// `TimeZoneDatabase::none()` to play a machine without one).
    pub fn named_in(system: &TimeZoneDatabase, name: &str) -> Result<LocalZone, ZoneError> {
        let unknown = || ZoneError::Unknown { name: name.to_string() };
        // jiff accepts "" as nothing useful and "Etc/Unknown" as a placeholder: neither is a
        // stage's zone.
        if name.trim().is_empty() || name.eq_ignore_ascii_case("Etc/Unknown") {
            return Err(unknown());
        }
        let tz =
            system.get(name).or_else(|_| TimeZoneDatabase::bundled().get(name)).map_err(|_| unknown())?;
        Ok(LocalZone { tz })
    }

    /// A fixed offset from UTC (the deprecated `ledger.utc_offset_minutes`; no daylight saving).
    pub fn fixed_offset_minutes(minutes: i32) -> Result<LocalZone, ZoneError> {
        if !(-840..=840).contains(&minutes) {
            return Err(ZoneError::Offset { minutes });
        }
        let offset = Offset::from_seconds(minutes * 60).map_err(|_| ZoneError::Offset { minutes })?;
        Ok(LocalZone { tz: TimeZone::fixed(offset) })
    }

    /// The zone's IANA name, or its offset for a fixed one ("UTC+01:00").
    pub fn name(&self) -> String {
        match self.tz.iana_name() {
            Some(n) => n.to_string(),
            None => {
                let offset = self.tz.to_offset(Timestamp::UNIX_EPOCH);
                if offset == Offset::UTC { "UTC".to_string() } else { format!("UTC{offset}") }
            }
        }
    }

    /// The jiff zone (for code that needs more than this type offers).
    pub fn time_zone(&self) -> &TimeZone {
        &self.tz
    }

    /// `unix_ms` in this zone; `None` out of jiff's range (years -9999..=9999).
    pub(crate) fn zoned(&self, unix_ms: i64) -> Option<ZonedDateTime> {
        Timestamp::from_millisecond(unix_ms).ok().map(|t| t.to_zoned_datetime(self.tz.clone()))
    }

    /// The local day containing `unix_ms`: `[local midnight, next local midnight)` in Unix ms,
    /// 23 or 25 hours long on a daylight-saving change day. Where local midnight does not
    /// exist (a zone changing at midnight) the day starts at the first instant it does. Out of
    /// jiff's range (never on a real stage) days are UTC days.
    pub fn day_bounds(&self, unix_ms: i64) -> (i64, i64) {
        let local = self.zoned(unix_ms).and_then(|z| {
            let start = z.start_of_day().ok()?;
            let next = z.date().tomorrow().ok()?.to_zoned_datetime(self.tz.clone()).ok()?;
            Some((start.timestamp().as_millisecond(), next.timestamp().as_millisecond()))
        });
        local.unwrap_or_else(|| {
            let start = unix_ms.div_euclid(MS_PER_DAY) * MS_PER_DAY;
            (start, start + MS_PER_DAY)
        })
    }

    /// Start (Unix ms) of the local day containing `unix_ms`.
    pub fn day_start(&self, unix_ms: i64) -> i64 {
        self.day_bounds(unix_ms).0
    }

    /// The local calendar date of `unix_ms`, e.g. "2026-03-29".
    pub fn local_date(&self, unix_ms: i64) -> String {
        match self.zoned(unix_ms) {
            Some(z) => z.date().to_string(),
            None => format!("(out of range: {unix_ms} Unix ms)"),
        }
    }

    /// The local calendar date of `unix_ms` as a value (`None` out of jiff's range).
    pub fn date_of(&self, unix_ms: i64) -> Option<Date> {
        self.zoned(unix_ms).map(|z| z.date())
    }

    /// Local date and time of `unix_ms` with the zone's abbreviation, e.g. "2026-03-29 10:15
    /// CEST"; zones without abbreviations show their offset ("-03").
    pub fn local_time(&self, unix_ms: i64) -> String {
        match self.zoned(unix_ms) {
            Some(z) => z.strftime("%Y-%m-%d %H:%M %Z").to_string(),
            None => format!("(out of range: {unix_ms} Unix ms)"),
        }
    }

    /// As [`LocalZone::local_time`] to the second, e.g. "2026-03-29 10:15:02 CEST" (records).
    pub fn local_time_s(&self, unix_ms: i64) -> String {
        match self.zoned(unix_ms) {
            Some(z) => z.strftime("%Y-%m-%d %H:%M:%S %Z").to_string(),
            None => format!("(out of range: {unix_ms} Unix ms)"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: i64 = 3_600_000;

    /// Unix ms of an RFC 3339 instant.
    fn at(s: &str) -> i64 {
        s.parse::<Timestamp>().unwrap().as_millisecond()
    }

    #[test]
    fn zones_resolve_without_a_system_database() {
        let none = TimeZoneDatabase::none();
        for name in ["Europe/Amsterdam", "america/new_york", "Asia/Kolkata", "UTC"] {
            let z = LocalZone::named_in(&none, name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(z.time_zone().iana_name().is_some(), "{name}");
        }
        let e = LocalZone::named_in(&none, "Europe/Amsterdm").unwrap_err().to_string();
        assert!(e.contains("Europe/Amsterdm") && e.contains("IANA"), "{e}");
        assert!(LocalZone::named_in(&none, "").is_err());
    }

    #[test]
    fn days_are_23_and_25_hours_on_change_days() {
        let ams = LocalZone::named("Europe/Amsterdam").unwrap();
        // 2026-03-29: clocks go 02:00 CET -> 03:00 CEST.
        let (s, e) = ams.day_bounds(at("2026-03-29T10:00:00Z"));
        assert_eq!((s, e), (at("2026-03-28T23:00:00Z"), at("2026-03-29T22:00:00Z")));
        assert_eq!(e - s, 23 * H);
        // 2026-10-25: 03:00 CEST -> 02:00 CET.
        let (s, e) = ams.day_bounds(at("2026-10-25T10:00:00Z"));
        assert_eq!((s, e), (at("2026-10-24T22:00:00Z"), at("2026-10-25T23:00:00Z")));
        assert_eq!(e - s, 25 * H);
        let ny = LocalZone::named("America/New_York").unwrap();
        let (s, e) = ny.day_bounds(at("2026-03-08T12:00:00Z"));
        assert_eq!((s, e - s), (at("2026-03-08T05:00:00Z"), 23 * H));
        let (s, e) = ny.day_bounds(at("2026-11-01T12:00:00Z"));
        assert_eq!((s, e - s), (at("2026-11-01T04:00:00Z"), 25 * H));
    }

    #[test]
    fn a_zone_without_dst_has_24_hour_days() {
        let kolkata = LocalZone::named("Asia/Kolkata").unwrap();
        for day in ["2026-03-29T10:00:00Z", "2026-10-25T10:00:00Z"] {
            let (s, e) = kolkata.day_bounds(at(day));
            assert_eq!(e - s, 24 * H);
            assert_eq!(kolkata.local_time(s), format!("{} 00:00 IST", &day[..10]));
        }
    }

    #[test]
    fn local_time_shows_the_abbreviation() {
        let ams = LocalZone::named("Europe/Amsterdam").unwrap();
        assert_eq!(ams.local_time(at("2026-03-29T08:15:00Z")), "2026-03-29 10:15 CEST");
        assert_eq!(ams.local_time(at("2026-01-10T08:15:00Z")), "2026-01-10 09:15 CET");
        assert_eq!(ams.local_time_s(at("2026-01-10T08:15:02.5Z")), "2026-01-10 09:15:02 CET");
        assert_eq!(ams.local_date(at("2026-03-28T23:30:00Z")), "2026-03-29");
        assert_eq!(LocalZone::utc().local_time(0), "1970-01-01 00:00 UTC");
        assert_eq!(LocalZone::utc().name(), "UTC");
        assert_eq!(ams.name(), "Europe/Amsterdam");
    }

    #[test]
    fn fixed_offsets_and_out_of_range_times() {
        let z = LocalZone::fixed_offset_minutes(120).unwrap();
        // 23:00 UTC is 01:00 the next day at UTC+2.
        assert_eq!(z.day_start(23 * H), 22 * H);
        assert_eq!(z.local_date(23 * H), "1970-01-02");
        assert_eq!(z.name(), "UTC+02");
        assert!(LocalZone::fixed_offset_minutes(900).is_err());
        // Far outside jiff's range: UTC days, no panic.
        let far = i64::MAX / 4;
        let (s, e) = z.day_bounds(far);
        assert!(s <= far && far < e && e - s == 24 * H);
        assert!(z.local_time(far).contains("out of range"));
    }
}
