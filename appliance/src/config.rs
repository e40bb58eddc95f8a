//! The appliance's TOML configuration: every key, its default and its accepted range.
//! `systemd/restage-appliance.toml` is the documented example; unknown keys are refused.

use std::path::{Path, PathBuf};

use restage_shared::light::StageLimits;
use serde::Deserialize;
use thiserror::Error;

use crate::hours::{Hours, HoursConfig, HoursError};
use crate::zone::{LocalZone, ZoneError};

#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("config {path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("config {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("config {path}: {key} = {value} (expected {expected})")]
    Range { path: PathBuf, key: &'static str, value: String, expected: &'static str },
    #[error("config {path}: time_zone: {source}")]
    Zone { path: PathBuf, source: ZoneError },
    #[error("config {path}: {source}")]
    Hours { path: PathBuf, source: HoursError },
}

/// The whole configuration file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Directory of trusted public keys (`*.pub.pem`, SPKI PEM); several keys allow rotation.
    pub trust_dir: PathBuf,
    /// Accept bundles signed with the public demo key (`restage_shared::keys::
    /// demo_signing_key`), whose private half anyone has: only for trying the demo, never for
    /// an object on show. Default false: such a bundle is refused even when the demo key is
    /// in `trust_dir`, because then anyone could sign what this stage shows.
    #[serde(default)]
    pub allow_demo_key: bool,
    /// Directory for the ledger (`ledger.sqlite`) and the active bundle (`active.bundle`);
    /// systemd's `StateDirectory=` (`/var/lib/restage`).
    pub state_dir: PathBuf,
    /// The bundle to play. Default: `STATE_DIR/active.bundle`, where `install` puts it.
    #[serde(default)]
    pub bundle: Option<PathBuf>,
    /// The bundle inbox (`inbox`): a folder watched for signed `*.bundle` files (where a USB
    /// stick is mounted, or one operators copy to). One that stands unchanged for a scan (5 s)
    /// is verified and installed like `restage-appliance install` does, and plays from the
    /// next showing; it is then moved to `installed/` or `refused/` (with why) in the folder.
    /// The service must be able to write there. Default: none.
    #[serde(default)]
    pub inbox_dir: Option<PathBuf>,
    /// The object on this stage (the bundle manifest's object id). Budgets are kept per
    /// object, so a bundle signed for another id is refused: re-signing the same content
    /// under a new id cannot open a fresh budget. Unset: the stage is pinned to the object
    /// of the first bundle it accepts (recorded in the ledger); set it to move to another.
    #[serde(default)]
    pub object_id: Option<String>,
    /// This stage's name for people: the status page's title and the alerts' text, e.g.
    /// "Gallery 3, retable" (1..=64 printable characters). Default: none.
    #[serde(default)]
    pub name: Option<String>,
    /// The stage's IANA time zone, e.g. "Europe/Amsterdam": local days of the daily budget
    /// and the opening hours follow it, daylight saving included. Default "UTC".
    #[serde(default)]
    pub time_zone: Option<String>,
    /// Opening hours (`hours::HoursConfig`); absent: always open.
    #[serde(default)]
    pub hours: Option<HoursConfig>,
    /// `time_zone` (or the deprecated fixed offset) resolved at load.
    #[serde(skip)]
    zone: LocalZone,
    /// `hours` resolved at load.
    #[serde(skip)]
    opening_hours: Hours,
    #[serde(default)]
    pub player: PlayerConfig,
    #[serde(default)]
    pub ledger: LedgerConfig,
    #[serde(default)]
    pub light_check: LightCheckConfig,
    pub output: OutputConfig,
    #[serde(default)]
    pub inputs: InputsConfig,
    #[serde(default)]
    pub feedback: FeedbackConfig,
    #[serde(default)]
    pub alerts: AlertsConfig,
    /// The read-only remote status page (`[status]`; off by default).
    #[serde(default)]
    pub status: crate::status::StatusConfig,
    /// Projector control over the network (PJLink); absent: not controlled.
    #[serde(default)]
    pub pjlink: Option<crate::pjlink::PjlinkConfig>,
}

/// What the visitor sees on the button box (see `feedback`); the serial box needs no key.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FeedbackConfig {
    /// BCM pin (0..=27, not the button's) of the button's LED, lit when high (needs the
    /// `gpio` feature). Steady = ready, slow blinks = showing / wait, off = closed, budget
    /// exhausted, out of order.
    pub gpio_led_pin: Option<u8>,
}

/// Operator alerts (see `alerts`): every alert is logged; `command` also hears it.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlertsConfig {
    /// A program run for every alert raised or cleared, as an argv list (no shell), e.g.
    /// ["/usr/local/bin/notify-museum", "--to", "av"]; it reads RESTAGE_ALERT_LEVEL, _KIND,
    /// _MESSAGE, _STATE (raised|cleared) and _KEY from its environment.
    pub command: Option<Vec<String>>,
    /// Kill the command after this many ms (100..=300000). Default 10000.
    pub command_timeout_ms: u64,
    /// Warn this many days before the bundle expires (0..=365; 0: only when expired).
    /// Default 14.
    pub expiry_warn_days: u32,
    /// Budget fractions used at which to alert, ascending (each 0 < x <= 1, 1..=8 of them);
    /// 1.0 (used up) is critical, the rest warnings. Default [0.8, 1.0].
    pub budget_thresholds: Vec<f64>,
}

impl Default for AlertsConfig {
    fn default() -> Self {
        Self {
            command: None,
            command_timeout_ms: 10_000,
            expiry_warn_days: 14,
            budget_thresholds: vec![0.8, 1.0],
        }
    }
}

/// What the projectors do between showings.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum IdleMode {
    /// Show the bundle's original scene (charged at its peak lux).
    Original,
    /// Show black frames with the projectors on (charged at the black level).
    Black,
    /// Outputs off (charged nothing: use only where a projector without signal emits no light).
    Off,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlayerConfig {
    /// Between showings: "original", "black" or "off". Default: the bundle policy's idle mode.
    /// Only a darker choice than the policy's takes effect (off < black < a scene).
    pub idle: Option<IdleMode>,
    /// Length of the closing cross-fade in ms (0..=10000). Default 1500.
    pub fade_ms: u64,
    /// Frames per second of the cross-fade (1..=120). Default 30.
    pub fade_fps: u32,
    /// Presses closer than this to the last scene change are ignored (ms, 0..=10000): a
    /// bouncing or flooding button cannot strobe the object. Default 400.
    pub min_press_interval_ms: u64,
    /// Optional stricter maximum continuous showing than the bundle's policy (ms). The
    /// bundle's value always applies; this can only shorten it.
    pub max_showing_ms: Option<u64>,
    /// Optional longer cooldown than the bundle's policy (ms); can only lengthen it.
    pub cooldown_ms: Option<u64>,
}

impl Default for PlayerConfig {
    fn default() -> Self {
        Self {
            idle: None,
            fade_ms: 1500,
            fade_fps: 30,
            min_press_interval_ms: 400,
            max_showing_ms: None,
            cooldown_ms: None,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LedgerConfig {
    /// Length of one exposure reservation in ms (2500..=600000). Default 30000. After a
    /// crash or power cut the whole reservation stands (an over-count of at most this).
    pub reserve_ms: u64,
    /// Renew a reservation this many ms before it runs out (2000..=reserve_ms - 500). Default
    /// 15000. This is the slack that covers a stalled process until the watchdog kills it:
    /// systemd's `WatchdogSec` must be at most `renew_ahead_ms - KILL_TO_DARK_MS`
    /// (checked at start).
    pub renew_ahead_ms: u64,
    /// From a blank command to no light at the object, ms (0..=2000): the display pipeline
    /// and the projector's own latency. Commits pay until `now + this`. Default 100.
    pub light_off_latency_ms: u64,
    /// Longest wait for another process's lock on the ledger, ms (10..=1000). Light never
    /// waits longer: a lock held past it is a ledger fault (dark, retried). Default 100.
    pub busy_timeout_ms: u64,
    /// Deprecated: a fixed offset of local time from UTC in minutes (-840..=840), no
    /// daylight saving. Still read from old files (logged); refused together with
    /// `time_zone`, which replaces it.
    pub utc_offset_minutes: Option<i32>,
}

impl Default for LedgerConfig {
    fn default() -> Self {
        Self {
            reserve_ms: 30_000,
            renew_ahead_ms: 15_000,
            light_off_latency_ms: 100,
            busy_timeout_ms: 100,
            utc_offset_minutes: None,
        }
    }
}

/// Allowance from a watchdog kill (or any process death) to dark projectors: signal
/// delivery, the kernel releasing DRM master and restoring its (blank) console, the
/// projector's latency. The watchdog timeout plus this must fit in `renew_ahead_ms`.
pub const KILL_TO_DARK_MS: u64 = 2_000;

impl LedgerConfig {
    /// The longest watchdog timeout (systemd's `WatchdogSec`) this configuration can cover:
    /// a process stopped right after renewing is killed, and its light gone, before its
    /// reservation runs out.
    pub fn max_watchdog_ms(&self) -> u64 {
        self.renew_ahead_ms.saturating_sub(KILL_TO_DARK_MS)
    }
}

/// What the light check assumes about this stage (see `restage_shared::light::check`): a
/// certificate coefficient below `lux_at_1m * min_cos / max_throw_m^2` is refused as
/// under-stating the light. Tighter values (the real throw) make the check stricter.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightCheckConfig {
    /// Farthest distance from a projector to the object, metres (0 < x <= 1000). Default 10.
    pub max_throw_m: f64,
    /// Smallest cos(angle of incidence) x vignetting at which a lit pixel's brightest point
    /// may be lit (0 < x <= 1). Default 0.01.
    pub min_cos: f64,
}

impl Default for LightCheckConfig {
    fn default() -> Self {
        let d = StageLimits::default();
        Self { max_throw_m: d.max_throw_m, min_cos: d.min_cos }
    }
}

impl LightCheckConfig {
    /// The limits the bundle reader takes.
    pub fn limits(&self) -> StageLimits {
        StageLimits { max_throw_m: self.max_throw_m, min_cos: self.min_cos }
    }
}

/// Which display output drives the projectors.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum OutputConfig {
    /// Records every frame and its timestamp into `dir` (tests, demos).
    Headless {
        dir: PathBuf,
        /// Projector count when no bundle is loaded (1..=8). Default 3.
        #[serde(default = "three")]
        projectors: usize,
    },
    /// A development window (needs the `window` feature and a display); space or click = press.
    Window {
        #[serde(default = "three")]
        projectors: usize,
    },
    /// DRM/KMS on the stage machine: `card` (e.g. /dev/dri/card0) and one connector name per
    /// projector in projector order (e.g. ["HDMI-A-1", "HDMI-A-2", "DP-1"]; names as in
    /// /sys/class/drm/card0-NAME). An empty list means every connected connector in the
    /// card's order (fragile: the order changes when a projector is off at boot).
    Kms {
        card: PathBuf,
        #[serde(default)]
        connectors: Vec<String>,
        /// Use atomic modesetting (one commit for all projectors) where the driver offers it;
        /// false forces the legacy modeset + page flip path. Default true.
        #[serde(default = "yes")]
        atomic: bool,
    },
}

fn three() -> usize {
    3
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InputsConfig {
    /// Read `press`/`status`/`stop`/`reload` lines from standard input (development).
    pub stdin: bool,
    /// The operators' control socket (a Unix stream socket), e.g. /run/restage/control.sock.
    pub control_socket: Option<PathBuf>,
    pub serial: Option<SerialConfig>,
    pub evdev: Option<EvdevConfig>,
    pub gpio: Option<GpioConfig>,
}

/// A serial button box speaking the line protocol in `input::serial`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    /// Device path, e.g. /dev/ttyUSB0.
    pub path: PathBuf,
    /// Baud rate (300..=4000000). Default 9600.
    #[serde(default = "baud")]
    pub baud: u32,
}

fn baud() -> u32 {
    9600
}

/// A USB keypad or keyboard read through evdev.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvdevConfig {
    /// Device path, e.g. /dev/input/by-id/usb-...-event-kbd.
    pub path: PathBuf,
    /// Key names that count as the button (evdev names). Default ["KEY_ENTER", "KEY_KPENTER",
    /// "KEY_SPACE"].
    #[serde(default = "default_keys")]
    pub keys: Vec<String>,
}

fn default_keys() -> Vec<String> {
    vec!["KEY_ENTER".into(), "KEY_KPENTER".into(), "KEY_SPACE".into()]
}

/// A push button on a Raspberry Pi GPIO pin (needs the `gpio` feature).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioConfig {
    /// BCM pin number (0..=27).
    pub pin: u8,
    /// The button pulls the pin low when pressed (internal pull-up on). Default true.
    #[serde(default = "yes")]
    pub active_low: bool,
    /// Debounce time in ms (1..=500). Default 30.
    #[serde(default = "debounce")]
    pub debounce_ms: u64,
}

fn yes() -> bool {
    true
}

fn debounce() -> u64 {
    30
}

impl Config {
    /// Reads, parses and checks a configuration file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses and checks configuration text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        let mut config: Config = toml::from_str(text)
            .map_err(|e| ConfigError::Parse { path: path.to_path_buf(), message: e.to_string() })?;
        config.check(path)?;
        config.resolve_time(path)?;
        Ok(config)
    }

    /// The stage's time zone (checked at load).
    pub fn local_zone(&self) -> &LocalZone {
        &self.zone
    }

    /// The opening hours in the stage's time zone (checked at load; always open without an
    /// `[hours]` section).
    pub fn opening_hours(&self) -> &Hours {
        &self.opening_hours
    }

    /// Resolves `time_zone` (or the deprecated `ledger.utc_offset_minutes`) and `[hours]`.
    fn resolve_time(&mut self, path: &Path) -> Result<(), ConfigError> {
        let path = path.to_path_buf();
        self.zone = match (&self.time_zone, self.ledger.utc_offset_minutes) {
            (Some(_), Some(m)) => {
                return Err(ConfigError::Range {
                    path,
                    key: "ledger.utc_offset_minutes",
                    value: m.to_string(),
                    expected: "unset when time_zone is set (time_zone replaces it)",
                });
            }
            (Some(name), None) => {
                LocalZone::named(name).map_err(|source| ConfigError::Zone { path: path.clone(), source })?
            }
            (None, Some(m)) => {
                let zone = LocalZone::fixed_offset_minutes(m).map_err(|_| ConfigError::Range {
                    path: path.clone(),
                    key: "ledger.utc_offset_minutes",
                    value: m.to_string(),
                    expected: "-840..=840",
                })?;
                tracing::warn!(
                    "config {}: ledger.utc_offset_minutes is deprecated (a fixed offset, no daylight saving); \
                     set time_zone = \"Area/City\" instead",
                    path.display()
                );
                zone
            }
            (None, None) => LocalZone::utc(),
        };
        self.opening_hours = match &self.hours {
            Some(h) => h.build(&self.zone).map_err(|source| ConfigError::Hours { path, source })?,
            None => Hours::always_open(self.zone.clone()),
        };
        Ok(())
    }

    /// The bundle path: the configured one, or `STATE_DIR/active.bundle`.
    pub fn bundle_path(&self) -> PathBuf {
        self.bundle.clone().unwrap_or_else(|| self.state_dir.join(ACTIVE_BUNDLE))
    }

    fn check(&self, path: &Path) -> Result<(), ConfigError> {
        let range = |key, value: String, expected| ConfigError::Range {
            path: path.to_path_buf(),
            key,
            value,
            expected,
        };
        let p = &self.player;
        if p.fade_ms > 10_000 {
            return Err(range("player.fade_ms", p.fade_ms.to_string(), "0..=10000"));
        }
        if !(1..=120).contains(&p.fade_fps) {
            return Err(range("player.fade_fps", p.fade_fps.to_string(), "1..=120"));
        }
        if p.min_press_interval_ms > 10_000 {
            return Err(range(
                "player.min_press_interval_ms",
                p.min_press_interval_ms.to_string(),
                "0..=10000",
            ));
        }
        if p.max_showing_ms == Some(0) {
            return Err(range("player.max_showing_ms", "0".into(), "at least 1"));
        }
        let l = &self.ledger;
        if !(2_500..=600_000).contains(&l.reserve_ms) {
            return Err(range("ledger.reserve_ms", l.reserve_ms.to_string(), "2500..=600000"));
        }
        if l.renew_ahead_ms < 2_000 || l.renew_ahead_ms + 500 > l.reserve_ms {
            return Err(range(
                "ledger.renew_ahead_ms",
                l.renew_ahead_ms.to_string(),
                "2000..=ledger.reserve_ms - 500",
            ));
        }
        if l.light_off_latency_ms > 2_000 {
            return Err(range("ledger.light_off_latency_ms", l.light_off_latency_ms.to_string(), "0..=2000"));
        }
        if !(10..=1_000).contains(&l.busy_timeout_ms) {
            return Err(range("ledger.busy_timeout_ms", l.busy_timeout_ms.to_string(), "10..=1000"));
        }
        if let Some(o) = &self.object_id
            && (o.is_empty() || o.len() > 200 || o.chars().any(char::is_control))
        {
            return Err(range("object_id", format!("{o:?}"), "1..=200 printable characters"));
        }
        if let Some(n) = &self.name
            && (n.trim().is_empty() || n.chars().count() > 64 || n.chars().any(char::is_control))
        {
            return Err(range("name", format!("{n:?}"), "1..=64 printable characters"));
        }
        let lc = &self.light_check;
        if !(lc.max_throw_m.is_finite() && lc.max_throw_m > 0.0 && lc.max_throw_m <= 1000.0) {
            return Err(range("light_check.max_throw_m", lc.max_throw_m.to_string(), "0 < metres <= 1000"));
        }
        if !(lc.min_cos > 0.0 && lc.min_cos <= 1.0) {
            return Err(range("light_check.min_cos", lc.min_cos.to_string(), "0 < min_cos <= 1"));
        }
        match &self.output {
            OutputConfig::Headless { projectors, .. } | OutputConfig::Window { projectors } => {
                if !(1..=8).contains(projectors) {
                    return Err(range("output.projectors", projectors.to_string(), "1..=8"));
                }
            }
            OutputConfig::Kms { connectors, .. } => {
                if connectors.len() > 8 {
                    return Err(range(
                        "output.connectors",
                        format!("{connectors:?}"),
                        "0..=8 connector names (none = every connected one, in order)",
                    ));
                }
            }
        }
        if let Some(s) = &self.inputs.serial
            && !(300..=4_000_000).contains(&s.baud)
        {
            return Err(range("inputs.serial.baud", s.baud.to_string(), "300..=4000000"));
        }
        if let Some(g) = &self.inputs.gpio {
            if g.pin > 27 {
                return Err(range("inputs.gpio.pin", g.pin.to_string(), "0..=27 (BCM)"));
            }
            if !(1..=500).contains(&g.debounce_ms) {
                return Err(range("inputs.gpio.debounce_ms", g.debounce_ms.to_string(), "1..=500"));
            }
        }
        if let Some(e) = &self.inputs.evdev
            && e.keys.is_empty()
        {
            return Err(range("inputs.evdev.keys", "[]".into(), "at least one key name"));
        }
        if let Some(led) = self.feedback.gpio_led_pin {
            if led > 27 {
                return Err(range("feedback.gpio_led_pin", led.to_string(), "0..=27 (BCM)"));
            }
            if self.inputs.gpio.as_ref().is_some_and(|g| g.pin == led) {
                return Err(range(
                    "feedback.gpio_led_pin",
                    led.to_string(),
                    "a pin other than inputs.gpio.pin",
                ));
            }
        }
        let a = &self.alerts;
        if let Some(c) = &a.command
            && (c.is_empty() || c[0].is_empty() || c.iter().any(|arg| arg.contains('\0')))
        {
            return Err(range("alerts.command", format!("{c:?}"), "[program, args...] with a program path"));
        }
        if !(100..=300_000).contains(&a.command_timeout_ms) {
            return Err(range("alerts.command_timeout_ms", a.command_timeout_ms.to_string(), "100..=300000"));
        }
        if a.expiry_warn_days > 365 {
            return Err(range("alerts.expiry_warn_days", a.expiry_warn_days.to_string(), "0..=365"));
        }
        let t = &a.budget_thresholds;
        if t.is_empty()
            || t.len() > 8
            || t.iter().any(|x| !(*x > 0.0 && *x <= 1.0))
            || t.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(range(
                "alerts.budget_thresholds",
                format!("{t:?}"),
                "1..=8 ascending fractions, each 0 < x <= 1",
            ));
        }
        self.status.check(path)?;
        if let Some(p) = &self.pjlink {
            p.check().map_err(|e| range(e.key, e.value, e.expected))?;
        }
        Ok(())
    }
}

pub use crate::ledger::{ACTIVE_BUNDLE_FILE as ACTIVE_BUNDLE, LEDGER_FILE};

#[cfg(test)]
mod tests {
    use super::*;

    const EXAMPLE: &str = include_str!("../../systemd/restage-appliance.toml");

    #[test]
    fn documented_example_parses() {
        let c = Config::parse(EXAMPLE, Path::new("example.toml")).unwrap();
        assert_eq!(c.bundle_path(), Path::new("/var/lib/restage/active.bundle"));
        assert!(matches!(c.output, OutputConfig::Kms { .. }));
        assert!(c.inputs.serial.is_some());
        assert_eq!(c.light_check.limits(), StageLimits { max_throw_m: 6.0, min_cos: 0.01 });
        assert_eq!(c.alerts.budget_thresholds, [0.8, 1.0]);
        assert_eq!(c.alerts.expiry_warn_days, 14);
        assert!(!c.allow_demo_key, "the documented example must not accept the demo key");
    }

    #[test]
    fn the_demo_key_is_refused_unless_allowed() {
        let base = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n";
        let c = Config::parse(&format!("{base}{WINDOW}"), Path::new("c.toml")).unwrap();
        assert!(!c.allow_demo_key);
        let c =
            Config::parse(&format!("{base}allow_demo_key = true\n{WINDOW}"), Path::new("c.toml")).unwrap();
        assert!(c.allow_demo_key);
    }

    #[test]
    fn light_check_limits_default_and_range() {
        let base = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[output]\nkind = \"window\"\n";
        let c = Config::parse(base, Path::new("c.toml")).unwrap();
        assert_eq!(c.light_check.limits(), StageLimits::default());
        let e = Config::parse(&format!("{base}[light_check]\nmin_cos = 0.0\n"), Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("light_check.min_cos"), "{e}");
    }

    #[test]
    fn unknown_key_is_refused_with_its_name() {
        let text = "trust_dir = \"/t\"\nstate_dir = \"/s\"\nbogus = 1\n[output]\nkind = \"window\"\n";
        let e = Config::parse(text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("c.toml") && e.contains("bogus"), "{e}");
    }

    #[test]
    fn out_of_range_names_key_and_range() {
        let text =
            "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[player]\nfade_fps = 0\n[output]\nkind = \"window\"\n";
        let e = Config::parse(text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("player.fade_fps") && e.contains("1..=120"), "{e}");
    }

    #[test]
    fn renew_ahead_must_be_below_reserve() {
        let text = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[ledger]\nreserve_ms = 5000\nrenew_ahead_ms = 4800\n\
                    [output]\nkind = \"headless\"\ndir = \"/r\"\n";
        let e = Config::parse(text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("ledger.renew_ahead_ms"), "{e}");
        // Short leases renewed late under load were how light went unpaid: refused.
        let text = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[ledger]\nreserve_ms = 200\nrenew_ahead_ms = 100\n\
                    [output]\nkind = \"headless\"\ndir = \"/r\"\n";
        let e = Config::parse(text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("ledger.reserve_ms"), "{e}");
    }

    const BASE: &str = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n";
    const WINDOW: &str = "[output]\nkind = \"window\"\n";

    #[test]
    fn time_zone_defaults_to_utc_and_names_a_bad_value() {
        let c = Config::parse(&format!("{BASE}{WINDOW}"), Path::new("c.toml")).unwrap();
        assert_eq!(c.local_zone(), &LocalZone::utc());
        assert!(c.opening_hours().at(0).open);
        let c =
            Config::parse(&format!("{BASE}time_zone = \"America/New_York\"\n{WINDOW}"), Path::new("c.toml"))
                .unwrap();
        assert_eq!(c.local_zone().name(), "America/New_York");
        let e = Config::parse(&format!("{BASE}time_zone = \"Mars/Olympus\"\n{WINDOW}"), Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.toml") && e.contains("time_zone") && e.contains("Mars/Olympus"), "{e}");
    }

    #[test]
    fn the_old_fixed_offset_is_read_but_not_with_a_time_zone() {
        let old = format!("{BASE}[ledger]\nutc_offset_minutes = 60\n{WINDOW}");
        let c = Config::parse(&old, Path::new("c.toml")).unwrap();
        assert_eq!(c.local_zone(), &LocalZone::fixed_offset_minutes(60).unwrap());
        let both =
            format!("{BASE}time_zone = \"Europe/Amsterdam\"\n[ledger]\nutc_offset_minutes = 60\n{WINDOW}");
        let e = Config::parse(&both, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("ledger.utc_offset_minutes") && e.contains("time_zone"), "{e}");
        let far = format!("{BASE}[ledger]\nutc_offset_minutes = 900\n{WINDOW}");
        let e = Config::parse(&far, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("ledger.utc_offset_minutes") && e.contains("-840..=840"), "{e}");
    }

    #[test]
    fn opening_hours_are_checked_at_load() {
        let text =
            format!("{BASE}time_zone = \"Europe/Amsterdam\"\n[hours]\nmon = [\"10:00-09:00\"]\n{WINDOW}");
        let e = Config::parse(&text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.starts_with("config c.toml: hours.mon = \"10:00-09:00\""), "{e}");
        let text = format!("{BASE}[hours]\nmonday = [\"10:00-17:00\"]\n{WINDOW}");
        let e = Config::parse(&text, Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("monday"), "{e}");
        let c = Config::parse(EXAMPLE, Path::new("example.toml")).unwrap();
        assert!(c.opening_hours().is_scheduled());
        assert_eq!(c.local_zone().name(), "Europe/Amsterdam");
    }

    #[test]
    fn feedback_and_alerts_keys_default_and_range() {
        let base = "trust_dir = \"/t\"\nstate_dir = \"/s\"\n[output]\nkind = \"window\"\n";
        let c = Config::parse(base, Path::new("c.toml")).unwrap();
        assert_eq!(c.feedback.gpio_led_pin, None);
        assert_eq!((c.alerts.expiry_warn_days, c.alerts.budget_thresholds.clone()), (14, vec![0.8, 1.0]));
        assert!(c.alerts.command.is_none());
        let bad = |extra: &str, key: &str| {
            let e = Config::parse(&format!("{base}{extra}"), Path::new("c.toml")).unwrap_err().to_string();
            assert!(e.contains(key), "{extra}: {e}");
        };
        bad("[feedback]\ngpio_led_pin = 28\n", "feedback.gpio_led_pin");
        bad("[inputs.gpio]\npin = 17\n[feedback]\ngpio_led_pin = 17\n", "feedback.gpio_led_pin");
        bad("[alerts]\ncommand = []\n", "alerts.command");
        bad("[alerts]\nexpiry_warn_days = 400\n", "alerts.expiry_warn_days");
        bad("[alerts]\nbudget_thresholds = [1.0, 0.8]\n", "alerts.budget_thresholds");
        bad("[alerts]\nbudget_thresholds = [0.5, 1.5]\n", "alerts.budget_thresholds");
        bad("[alerts]\ncommand_timeout_ms = 0\n", "alerts.command_timeout_ms");
        bad("[alerts]\nbogus = 1\n", "bogus");
        let ok =
            "[inputs.gpio]\npin = 17\n[feedback]\ngpio_led_pin = 27\n[alerts]\ncommand = [\"/bin/true\"]\n";
        let c = Config::parse(&format!("{base}{ok}"), Path::new("c.toml")).unwrap();
        assert_eq!(c.feedback.gpio_led_pin, Some(27));
    }

    #[test]
    fn the_documented_watchdog_fits_the_default_lease_slack() {
        let c = Config::parse(EXAMPLE, Path::new("example.toml")).unwrap();
        let unit = include_str!("../../systemd/restage-appliance.service");
        let secs: u64 = unit
            .lines()
            .find_map(|l| l.strip_prefix("WatchdogSec="))
            .and_then(|v| v.trim().trim_end_matches('s').parse().ok())
            .expect("the unit sets WatchdogSec in seconds");
        assert!(secs * 1000 <= c.ledger.max_watchdog_ms(), "WatchdogSec={secs}s, {:?}", c.ledger);
    }
}
