//! The `[pjlink]` section of the appliance's configuration: which projectors to control over
//! the network, and how often and how patiently.

use std::time::Duration;

use serde::Deserialize;

use super::client::with_default_port;
use super::control::{ProjectorSpec, Timing};

/// Projector control over PJLink (absent: the projectors are not controlled over the network).
#[derive(Clone, Debug, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields, default)]
pub struct PjlinkConfig {
    /// The projectors, in projector order (1..=8).
    pub projectors: Vec<PjlinkProjectorConfig>,
    /// Seconds between polls of a settled projector (1..=3600). Default 10.
    pub poll_s: u64,
    /// Milliseconds between polls while warming up or cooling down, and the first retry
    /// after a failure (100..=60000). Default 1000.
    pub busy_poll_ms: u64,
    /// Bound on each step of an exchange (connect, each answer), ms (100..=30000). Default 2000.
    pub timeout_ms: u64,
    /// A warm-up longer than this (s, 1..=1800) is reported as an error. Default 120.
    pub warmup_s_max: u64,
    /// A cool-down longer than this (s, 1..=1800) is reported as an error. Default 180.
    pub cooldown_s_max: u64,
    /// Longest wait between retries of an unreachable projector (s, 1..=3600; the wait
    /// doubles from `busy_poll_ms` up to it). Default 60.
    pub retry_max_s: u64,
    /// Power the projectors on this many seconds before opening time, so they have warmed
    /// up when the doors open (0..=3600). Default 120. Outside opening hours (and this lead)
    /// they are put in standby.
    pub power_on_lead_s: u64,
}

impl Default for PjlinkConfig {
    fn default() -> Self {
        PjlinkConfig {
            projectors: Vec::new(),
            poll_s: 10,
            busy_poll_ms: 1000,
            timeout_ms: 2000,
            warmup_s_max: 120,
            cooldown_s_max: 180,
            retry_max_s: 60,
            power_on_lead_s: 120,
        }
    }
}

/// One `[[pjlink.projectors]]` entry.
#[derive(Clone, Debug, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct PjlinkProjectorConfig {
    /// `host` or `host:port` (default port 4352), e.g. "192.168.10.21" or "proj-left:4352".
    pub address: String,
    /// The projector's PJLink password (1..=32 printable ASCII characters), if it asks for one.
    #[serde(default)]
    pub password: Option<String>,
    /// A name for logs and the status page (1..=64 characters). Default: the address.
    #[serde(default)]
    pub name: Option<String>,
}

/// A key out of its accepted range; config.rs adds the file's path.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RangeError {
    pub key: &'static str,
    pub value: String,
    pub expected: &'static str,
}

impl std::fmt::Display for RangeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} = {} (expected {})", self.key, self.value, self.expected)
    }
}

impl PjlinkConfig {
    /// Checks every key against its range; the error names the key.
    pub fn check(&self) -> Result<(), RangeError> {
        let range = |key, value: String, expected| Err(RangeError { key, value, expected });
        if !(1..=8).contains(&self.projectors.len()) {
            return range(
                "pjlink.projectors",
                format!("{} entries", self.projectors.len()),
                "1..=8 projectors",
            );
        }
        let numbers: [(&'static str, u64, u64, u64, &'static str); 7] = [
            ("pjlink.poll_s", self.poll_s, 1, 3600, "1..=3600"),
            ("pjlink.busy_poll_ms", self.busy_poll_ms, 100, 60_000, "100..=60000"),
            ("pjlink.timeout_ms", self.timeout_ms, 100, 30_000, "100..=30000"),
            ("pjlink.warmup_s_max", self.warmup_s_max, 1, 1800, "1..=1800"),
            ("pjlink.cooldown_s_max", self.cooldown_s_max, 1, 1800, "1..=1800"),
            ("pjlink.retry_max_s", self.retry_max_s, 1, 3600, "1..=3600"),
            ("pjlink.power_on_lead_s", self.power_on_lead_s, 0, 3600, "0..=3600"),
        ];
        for (key, value, lo, hi, expected) in numbers {
            if !(lo..=hi).contains(&value) {
                return range(key, value.to_string(), expected);
            }
        }
        let mut seen = std::collections::HashSet::new();
        for (i, p) in self.projectors.iter().enumerate() {
            let Some(address) = with_default_port(&p.address) else {
                return range(
                    "pjlink.projectors.address",
                    format!("{:?} (entry {})", p.address, i + 1),
                    "host or host:port, port 1..=65535",
                );
            };
            if !seen.insert(address) {
                return range(
                    "pjlink.projectors.address",
                    format!("{:?} (entry {})", p.address, i + 1),
                    "a projector listed once",
                );
            }
            if let Some(pw) = &p.password
                && (pw.is_empty() || pw.len() > 32 || !pw.bytes().all(|b| b.is_ascii_graphic() || b == b' '))
            {
                // Never echo a password into a log.
                return range(
                    "pjlink.projectors.password",
                    format!("(hidden, {} bytes; entry {})", pw.len(), i + 1),
                    "1..=32 printable ASCII characters",
                );
            }
            if let Some(n) = &p.name
                && (n.is_empty() || n.chars().count() > 64 || n.chars().any(char::is_control))
            {
                return range(
                    "pjlink.projectors.name",
                    format!("{n:?} (entry {})", i + 1),
                    "1..=64 printable characters",
                );
            }
        }
        Ok(())
    }

    /// The controller's intervals.
    pub fn timing(&self) -> Timing {
        Timing {
            poll: Duration::from_secs(self.poll_s),
            busy_poll: Duration::from_millis(self.busy_poll_ms),
            timeout: Duration::from_millis(self.timeout_ms),
            warmup_max: Duration::from_secs(self.warmup_s_max),
            cooldown_max: Duration::from_secs(self.cooldown_s_max),
            retry_max: Duration::from_secs(self.retry_max_s),
        }
    }

    /// The projectors as the controller takes them (name defaults to the address).
    pub fn specs(&self) -> Vec<ProjectorSpec> {
        self.projectors
            .iter()
            .map(|p| ProjectorSpec {
                name: p.name.clone().unwrap_or_else(|| p.address.clone()),
                address: p.address.clone(),
                password: p.password.clone(),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<PjlinkConfig, String> {
        let c: PjlinkConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        c.check().map_err(|e| e.to_string())?;
        Ok(c)
    }

    #[test]
    fn defaults_and_specs() {
        let c = parse("[[projectors]]\naddress = \"10.0.0.5\"\n[[projectors]]\naddress = \"p2:4353\"\nname = \"right\"\npassword = \"secret\"\n")
            .unwrap();
        assert_eq!(c.poll_s, 10);
        assert_eq!(c.timing(), Timing::default());
        let specs = c.specs();
        assert_eq!(specs[0].name, "10.0.0.5");
        assert_eq!(specs[1].name, "right");
        assert_eq!(specs[1].password.as_deref(), Some("secret"));
    }

    /// The commented-out example in systemd/restage-appliance.toml, uncommented, is valid.
    #[test]
    fn documented_example_parses_when_uncommented() {
        let example = include_str!("../../../systemd/restage-appliance.toml");
        let start = example.find("# [pjlink]").expect("the example documents [pjlink]");
        let text: String = example[start..]
            .lines()
            .take_while(|l| l.starts_with('#'))
            .map(|l| l.trim_start_matches('#').trim_start())
            .map(|l| l.split(" # ").next().unwrap_or(l))
            // Prose lines between the keys stay out.
            .filter(|l| l.starts_with('[') || l.contains(" = "))
            .map(|l| format!("{l}\n"))
            .collect();
        let whole: toml::Value = toml::from_str(&text).unwrap();
        let c: PjlinkConfig = whole["pjlink"].clone().try_into().unwrap();
        c.check().unwrap();
        assert_eq!(c, PjlinkConfig { projectors: c.projectors.clone(), ..PjlinkConfig::default() });
        assert_eq!(c.specs().iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["left", "right"]);
    }

    #[test]
    fn ranges_name_the_key() {
        let one = "[[projectors]]\naddress = \"10.0.0.5\"\n";
        for (text, key) in [
            ("poll_s = 0\n", "pjlink.poll_s"),
            ("timeout_ms = 50\n", "pjlink.timeout_ms"),
            ("warmup_s_max = 0\n", "pjlink.warmup_s_max"),
            ("retry_max_s = 4000\n", "pjlink.retry_max_s"),
        ] {
            let e = parse(&format!("{text}{one}")).unwrap_err();
            assert!(e.contains(key) && e.contains("expected"), "{e}");
        }
        let e = parse("").unwrap_err();
        assert!(e.contains("pjlink.projectors = 0 entries (expected 1..=8 projectors)"), "{e}");
        let e = parse("[[projectors]]\naddress = \"host:0\"\n").unwrap_err();
        assert!(e.contains("pjlink.projectors.address"), "{e}");
        let e = parse("[[projectors]]\naddress = \"a\"\n[[projectors]]\naddress = \"a:4352\"\n").unwrap_err();
        assert!(e.contains("listed once"), "{e}");
        let e = parse("[[projectors]]\naddress = \"a\"\npassword = \"0123456789012345678901234567890123\"\n")
            .unwrap_err();
        assert!(e.contains("pjlink.projectors.password") && !e.contains("0123456789"), "{e}");
        let e = parse("[[projectors]]\naddress = \"a\"\nbogus = 1\n").unwrap_err();
        assert!(e.contains("bogus"), "{e}");
    }
}
