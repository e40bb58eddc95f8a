//! What the remote status page shows: one plain, versioned value that the event loop fills
//! and publishes, and the page, its JSON and its metrics are rendered from (nothing else).

use serde::{Deserialize, Serialize};

/// The snapshot's schema version (`schema` in `/status.json`); bumped on an incompatible change.
pub const SCHEMA: u32 = 1;

/// Everything the status page shows, as of `clock.unix_ms`. Times meant for people are local
/// time strings filled by the event loop; machine-readable instants are Unix ms beside them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// [`SCHEMA`].
    pub schema: u32,
    pub appliance: Appliance,
    pub clock: Clock,
    pub state: StateInfo,
    pub opening: Opening,
    pub budget: BudgetInfo,
    /// Budget warnings, newest first.
    pub warnings: Vec<Warning>,
    /// Last showings, newest first.
    pub showings: Vec<Showing>,
    pub bundle: BundleInfo,
    /// One per controlled projector (empty where the appliance controls none).
    pub projectors: Vec<Projector>,
    /// Alerts in force now.
    pub alerts: Vec<Alert>,
    /// The ledger's recent events, newest first.
    pub events: Vec<Event>,
    /// The bundle inbox, where one is configured (`inbox_dir`).
    #[serde(default)]
    pub inbox: Option<InboxInfo>,
}

/// The program itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Appliance {
    /// The stage's name for people (host name or the object on it), if any.
    pub name: Option<String>,
    /// `restage-appliance` version.
    pub version: String,
    /// Seconds since the process started.
    pub uptime_s: u64,
}

/// When the snapshot was taken.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Clock {
    /// Local time, e.g. "2026-12-01 14:03:12".
    pub local: String,
    /// IANA time zone name, e.g. "Europe/Berlin".
    pub zone: String,
    /// Ledger time in Unix ms.
    pub unix_ms: i64,
}

/// The player's state, as the banner shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StateKind {
    /// The process is up, the event loop has not published its first snapshot yet.
    Starting,
    Idle,
    Showing,
    /// The closing cross-fade.
    Ending,
    Cooldown,
    /// Outside opening hours.
    Closed,
    /// No light: no bundle, an expired one, a projector fault, ...
    Dark,
    BudgetExhausted,
    Fault,
}

impl StateKind {
    /// Every state, in the order `/metrics` lists them.
    pub const ALL: [StateKind; 9] = [
        StateKind::Starting,
        StateKind::Idle,
        StateKind::Showing,
        StateKind::Ending,
        StateKind::Cooldown,
        StateKind::Closed,
        StateKind::Dark,
        StateKind::BudgetExhausted,
        StateKind::Fault,
    ];

    /// The name used in JSON, metrics and the page (as `player::State::name`).
    pub fn name(self) -> &'static str {
        match self {
            StateKind::Starting => "starting",
            StateKind::Idle => "idle",
            StateKind::Showing => "showing",
            StateKind::Ending => "ending",
            StateKind::Cooldown => "cooldown",
            StateKind::Closed => "closed",
            StateKind::Dark => "dark",
            StateKind::BudgetExhausted => "budget-exhausted",
            StateKind::Fault => "fault",
        }
    }
}

/// The state and what explains it, e.g. `Dark` with "no bundle installed", or `Closed` with
/// "closed until 10:00".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StateInfo {
    pub kind: StateKind,
    pub detail: Option<String>,
}

/// An instant, for people and for machines.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Moment {
    /// Local time, e.g. "2026-12-02 10:00".
    pub local: String,
    pub unix_ms: i64,
}

/// Opening hours (both `next_*` absent where none are configured).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Opening {
    pub open: bool,
    pub next_open: Option<Moment>,
    pub next_close: Option<Moment>,
}

/// The light budget, or why it is not known (the ledger could not be read).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "status", rename_all = "lowercase")]
pub enum BudgetInfo {
    Known(Budget),
    Unknown { why: String },
}

/// The ledger's budget figures (`ledger::LedgerStatus`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    /// Local calendar day (YYYY-MM-DD) the daily window is.
    pub day: String,
    pub daily: Window,
    /// The last 365 days.
    pub annual: Window,
    /// Everything the ledger holds for this object.
    pub total_lux_hours: f64,
    /// Reservations never committed (a crash or power cut; counted in full).
    pub open_reservations: u64,
}

/// One budget window; `left` and `budget` are absent while no bundle sets the budget.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Window {
    pub used_lux_hours: f64,
    pub left_lux_hours: Option<f64>,
    pub budget_lux_hours: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Warning {
    /// Local time.
    pub at: String,
    pub text: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Showing {
    /// Local time.
    pub start: String,
    /// Local time.
    pub end: String,
    pub scenes: String,
    pub ended_by: String,
}

/// The bundle in force, or why there is none.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "status", rename_all = "lowercase")]
pub enum BundleInfo {
    Loaded(Bundle),
    #[serde(rename = "none")]
    Absent {
        why: String,
    },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bundle {
    pub object_id: String,
    pub version: u64,
    /// The first hex digits of the bundle's hash (enough to tell bundles apart).
    pub hash_prefix: String,
    /// Absent where the bundle does not expire.
    pub expires: Option<Expiry>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Expiry {
    /// Local time.
    pub local: String,
    pub unix_ms: i64,
    /// Days from the snapshot to the expiry (negative once expired).
    pub days_left: f64,
}

/// A projector's power state as it reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Power {
    On,
    Off,
    WarmingUp,
    CoolingDown,
    Unknown,
}

impl Power {
    pub fn name(self) -> &'static str {
        match self {
            Power::On => "on",
            Power::Off => "off",
            Power::WarmingUp => "warming-up",
            Power::CoolingDown => "cooling-down",
            Power::Unknown => "unknown",
        }
    }
}

/// One projector as last polled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Projector {
    pub name: String,
    /// Its control address (e.g. "192.0.2.10:4352"), where it has one.
    pub address: Option<String>,
    pub reachable: bool,
    pub power: Power,
    pub muted: Option<bool>,
    pub lamp_hours: Option<u64>,
    /// Errors it reports now (empty: none).
    pub errors: Vec<String>,
    /// Local time of the last poll that answered.
    pub last_poll: Option<String>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlertLevel {
    Info,
    Warning,
    Critical,
}

impl AlertLevel {
    /// Every level, in the order `/metrics` lists them.
    pub const ALL: [AlertLevel; 3] = [AlertLevel::Info, AlertLevel::Warning, AlertLevel::Critical];

    pub fn name(self) -> &'static str {
        match self {
            AlertLevel::Info => "info",
            AlertLevel::Warning => "warning",
            AlertLevel::Critical => "critical",
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alert {
    pub level: AlertLevel,
    /// A short machine-friendly kind, e.g. "budget", "projector", "bundle-expiry".
    pub kind: String,
    pub message: String,
    /// Local time it started.
    pub since: String,
}

/// A ledger event (`ledger::EventRecord` with its time in local time).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Event {
    pub at: String,
    pub kind: String,
    pub detail: String,
}

/// The bundle inbox (a USB stick's mount point or a watched folder) and what it did last.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InboxInfo {
    /// The folder watched.
    pub dir: String,
    /// The file being verified and installed now.
    pub installing: Option<String>,
    /// Why the folder cannot be read, where it is there but unreadable.
    pub problem: Option<String>,
    /// The last file taken from it since the appliance started, and what became of it.
    pub last: Option<InboxOutcome>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InboxOutcome {
    /// Local time it finished.
    pub at: String,
    pub file: String,
    pub installed: bool,
    /// What was installed, or why it was refused; and where the file was moved.
    pub detail: String,
}

impl Snapshot {
    /// What to publish before the event loop's first snapshot: state `Starting`, no figures.
    pub fn starting(version: &str, clock: Clock) -> Snapshot {
        Snapshot {
            schema: SCHEMA,
            appliance: Appliance { name: None, version: version.to_string(), uptime_s: 0 },
            clock,
            state: StateInfo { kind: StateKind::Starting, detail: None },
            opening: Opening { open: false, next_open: None, next_close: None },
            budget: BudgetInfo::Unknown { why: "the appliance is starting".into() },
            warnings: Vec::new(),
            showings: Vec::new(),
            bundle: BundleInfo::Absent { why: "the appliance is starting".into() },
            projectors: Vec::new(),
            alerts: Vec::new(),
            events: Vec::new(),
            inbox: None,
        }
    }

    /// A filled-in example (a showing in progress, two projectors, one unreachable): for
    /// tests and for seeing the page without a stage.
    pub fn example() -> Snapshot {
        let now = 1_796_130_192_000; // 2026-12-01 14:03:12 in Berlin
        Snapshot {
            schema: SCHEMA,
            appliance: Appliance {
                name: Some("gallery-3 retable".into()),
                version: "0.1.0".into(),
                uptime_s: 3 * 86_400 + 4 * 3_600 + 12 * 60,
            },
            clock: Clock { local: "2026-12-01 14:03:12".into(), zone: "Europe/Berlin".into(), unix_ms: now },
            state: StateInfo { kind: StateKind::Showing, detail: Some("scene 2 of 3".into()) },
            opening: Opening {
                open: true,
                next_open: Some(Moment { local: "2026-12-02 10:00".into(), unix_ms: now + 71_808_000 }),
                next_close: Some(Moment { local: "2026-12-01 18:00".into(), unix_ms: now + 14_208_000 }),
            },
            budget: BudgetInfo::Known(Budget {
                day: "2026-12-01".into(),
                daily: Window {
                    used_lux_hours: 412.5,
                    left_lux_hours: Some(587.5),
                    budget_lux_hours: Some(1000.0),
                },
                annual: Window {
                    used_lux_hours: 121_034.0,
                    left_lux_hours: Some(28_966.0),
                    budget_lux_hours: Some(150_000.0),
                },
                total_lux_hours: 131_870.25,
                open_reservations: 0,
            }),
            warnings: vec![Warning {
                at: "2026-11-28 16:40".into(),
                text: "annual budget 80 % used (120000 of 150000 lux·h)".into(),
            }],
            showings: vec![
                Showing {
                    start: "2026-12-01 13:58:40".into(),
                    end: "2026-12-01 14:01:40".into(),
                    scenes: "1,2,3".into(),
                    ended_by: "timeout".into(),
                },
                Showing {
                    start: "2026-12-01 13:40:02".into(),
                    end: "2026-12-01 13:41:10".into(),
                    scenes: "1,2".into(),
                    ended_by: "press".into(),
                },
            ],
            bundle: BundleInfo::Loaded(Bundle {
                object_id: "retable-st-anne".into(),
                version: 7,
                hash_prefix: "3f9a1c07be".into(),
                expires: Some(Expiry {
                    local: "2027-03-01 00:00".into(),
                    unix_ms: now + 89 * 86_400_000,
                    days_left: 89.4,
                }),
            }),
            projectors: vec![
                Projector {
                    name: "left".into(),
                    address: Some("192.0.2.10:4352".into()),
                    reachable: true,
                    power: Power::On,
                    muted: Some(false),
                    lamp_hours: Some(1_204),
                    errors: Vec::new(),
                    last_poll: Some("2026-12-01 14:03:05".into()),
                },
                Projector {
                    name: "right".into(),
                    address: Some("192.0.2.11:4352".into()),
                    reachable: false,
                    power: Power::Unknown,
                    muted: None,
                    lamp_hours: None,
                    errors: vec!["no answer for 5 min".into()],
                    last_poll: Some("2026-12-01 13:58:01".into()),
                },
            ],
            alerts: vec![Alert {
                level: AlertLevel::Warning,
                kind: "projector".into(),
                message: "projector \"right\" does not answer".into(),
                since: "2026-12-01 13:58:01".into(),
            }],
            events: vec![
                Event {
                    at: "2026-12-01 09:00:03".into(),
                    kind: "start".into(),
                    detail: "run 41 started".into(),
                },
                Event { at: "2026-11-30 18:00:00".into(), kind: "stop".into(), detail: "SIGTERM".into() },
            ],
            inbox: Some(InboxInfo {
                dir: "/media/stick".into(),
                installing: None,
                problem: None,
                last: Some(InboxOutcome {
                    at: "2026-12-01 09:12:40".into(),
                    file: "/media/stick/retable-v7.bundle".into(),
                    installed: true,
                    detail: "retable-st-anne version 7; moved to /media/stick/installed/retable-v7.bundle"
                        .into(),
                }),
            }),
        }
    }
}
