//! The remote status page: a read-only HTTP view of the appliance (HTML for people,
//! `/status.json`, Prometheus `/metrics`) rendered from a [`Snapshot`] the event loop publishes.

mod fill;
mod html;
mod metrics;
mod server;
mod snapshot;

use std::net::{Ipv4Addr, SocketAddr};
use std::path::Path;

use serde::Deserialize;

pub use self::fill::{Parts, opening, snapshot};
pub use self::html::{REFRESH_S, render as render_html};
pub use self::metrics::{CONTENT_TYPE as METRICS_CONTENT_TYPE, render as render_metrics};
pub use self::server::{Limits, StatusError, bind, respond, serve};
pub use self::snapshot::*;
use crate::config::ConfigError;

/// Default address: loopback only (see systemd/README.md, "Remote status page").
pub const DEFAULT_LISTEN: SocketAddr = SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 8080);

/// The `[status]` section of the configuration.
#[derive(Clone, Debug, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields, default)]
pub struct StatusConfig {
    /// Serve the status page. Default false.
    pub enabled: bool,
    /// Address and port to listen on. Default "127.0.0.1:8080" (this machine only).
    pub listen: SocketAddr,
}

impl Default for StatusConfig {
    fn default() -> Self {
        Self { enabled: false, listen: DEFAULT_LISTEN }
    }
}

impl StatusConfig {
    /// Range checks, with `path` naming the file in the error.
    pub fn check(&self, path: &Path) -> Result<(), ConfigError> {
        let ip = self.listen.ip();
        if self.listen.port() == 0 || ip.is_multicast() {
            return Err(ConfigError::Range {
                path: path.to_path_buf(),
                key: "status.listen",
                value: format!("\"{}\"", self.listen),
                expected: "a unicast address and a port 1..=65535, e.g. \"127.0.0.1:8080\"",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct Doc {
        #[serde(default)]
        status: StatusConfig,
    }

    fn parse(text: &str) -> Result<StatusConfig, String> {
        let doc: Doc = toml::from_str(text).map_err(|e| e.to_string())?;
        doc.status.check(Path::new("c.toml")).map_err(|e| e.to_string())?;
        Ok(doc.status)
    }

    #[test]
    fn defaults_are_off_and_loopback() {
        assert_eq!(
            parse("").unwrap(),
            StatusConfig { enabled: false, listen: "127.0.0.1:8080".parse().unwrap() }
        );
        let c = parse("[status]\nenabled = true\n").unwrap();
        assert!(c.enabled && c.listen.ip().is_loopback());
        let c = parse("[status]\nenabled = true\nlisten = \"[::]:9100\"\n").unwrap();
        assert_eq!(c.listen.port(), 9100);
    }

    #[test]
    fn bad_values_name_the_key() {
        let e = parse("[status]\nlisten = \"0.0.0.0:0\"\n").unwrap_err();
        assert!(e.contains("status.listen") && e.contains("1..=65535") && e.contains("c.toml"), "{e}");
        let e = parse("[status]\nlisten = \"224.0.0.1:80\"\n").unwrap_err();
        assert!(e.contains("status.listen"), "{e}");
        let e = parse("[status]\nlisten = \"localhost\"\n").unwrap_err();
        assert!(e.contains("listen"), "{e}");
        let e = parse("[status]\nport = 80\n").unwrap_err();
        assert!(e.contains("port"), "{e}");
    }
}
