//! The PJLink client: one TCP connection per operation (greeting, authentication, a few
//! commands, close), every step bounded by the configured timeout.
//!
//! Why not a kept connection: many projectors accept a single PJLink connection at a time
//! and close it after ~30 s idle, and authentication is per connection. A connection held
//! by us would lock out the museum's own control system and go stale between polls; a fresh
//! one per operation has no stale state to recover from and costs one loopback-cheap
//! handshake per poll interval.

use std::time::Duration;

use serde::Serialize;
use thiserror::Error;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::time::timeout;

use super::protocol::{
    self, AvMute, Class, Command, ErrCode, ErrorStatus, Greeting, Lamp, MAX_LINE, PowerState, ProtocolError,
};

/// Everything that can go wrong talking to one projector; each variant names it.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum PjlinkError {
    #[error("projector {address}: cannot connect: {message}")]
    Connect { address: String, message: String },
    #[error("projector {address}: no answer within {timeout_ms} ms ({during})")]
    Timeout { address: String, timeout_ms: u64, during: String },
    #[error("projector {address}: connection closed ({during})")]
    Closed { address: String, during: String },
    #[error("projector {address}: {message} ({during})")]
    Io { address: String, during: String, message: String },
    #[error("projector {address}: answer longer than {max} bytes ({during})")]
    Overlong { address: String, during: String, max: usize },
    #[error("projector {address}: password refused (PJLINK ERRA): check its password in [pjlink]")]
    Auth { address: String },
    #[error("projector {address}: asks for a password (PJLINK 1) and none is configured")]
    PasswordRequired { address: String },
    #[error("projector {address}: {command} answered ERR{} ({})", .code.number(), .code.meaning())]
    Refused { address: String, command: String, code: ErrCode },
    #[error("projector {address}: garbage answer to {during}: {why}: {line:?}")]
    Garbage { address: String, during: String, why: &'static str, line: String },
}

impl PjlinkError {
    /// No PJLink exchange happened (connection refused, silence, closed): the projector is
    /// unreachable rather than misbehaving.
    pub fn is_unreachable(&self) -> bool {
        matches!(self, PjlinkError::Connect { .. } | PjlinkError::Timeout { .. } | PjlinkError::Closed { .. })
    }

    fn protocol(address: &str, during: &str, e: ProtocolError) -> PjlinkError {
        let address = address.to_string();
        match e {
            ProtocolError::AuthRefused => PjlinkError::Auth { address },
            ProtocolError::Refused(code) => {
                PjlinkError::Refused { address, command: during.to_string(), code }
            }
            ProtocolError::Garbage { why, line } => {
                PjlinkError::Garbage { address, during: during.to_string(), why, line }
            }
        }
    }
}

/// Normalises `host` or `host:port` (`[v6]:port`, or a bare IPv6 address) to `host:port`
/// with PJLink's port by default. None when it is no address at all.
pub fn with_default_port(address: &str) -> Option<String> {
    let a = address.trim();
    if a.is_empty() || a.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return None;
    }
    if let Some(rest) = a.strip_prefix('[') {
        let (host, tail) = rest.split_once(']')?;
        if host.is_empty() {
            return None;
        }
        return match tail {
            "" => Some(format!("[{host}]:{}", protocol::DEFAULT_PORT)),
            _ => {
                let port: u16 = tail.strip_prefix(':')?.parse().ok()?;
                (port != 0).then(|| format!("[{host}]:{port}"))
            }
        };
    }
    match a.matches(':').count() {
        0 => Some(format!("{a}:{}", protocol::DEFAULT_PORT)),
        1 => {
            let (host, port) = a.split_once(':')?;
            let port: u16 = port.parse().ok()?;
            (!host.is_empty() && port != 0).then(|| a.to_string())
        }
        _ => a.parse::<std::net::Ipv6Addr>().ok().map(|_| format!("[{a}]:{}", protocol::DEFAULT_PORT)),
    }
}

/// What `NAME`, `INF1`, `INF2`, `INFO` and `CLSS` say (and for class 2, `SNUM` and `SVER`).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Info {
    pub name: String,
    pub manufacturer: String,
    pub product: String,
    pub other: String,
    pub class: Option<Class>,
    pub serial_number: Option<String>,
    pub software_version: Option<String>,
}

/// One poll's readings, taken over one connection.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Poll {
    pub power: PowerState,
    pub mute: AvMute,
    pub errors: ErrorStatus,
    /// Empty for a projector without lamps (laser: `LAMP ?` answers ERR1).
    pub lamps: Vec<Lamp>,
}

/// A projector's address and credentials; each operation opens its own connection.
#[derive(Clone, Debug)]
pub struct Projector {
    address: String,
    password: Option<String>,
    timeout: Duration,
}

impl Projector {
    /// `address` is `host` or `host:port` (default port 4352); unparseable addresses are
    /// kept as given and fail at connect with a clear error. `timeout` bounds each step
    /// (connect, each line written or read).
    pub fn new(address: &str, password: Option<&str>, timeout: Duration) -> Projector {
        Projector {
            address: with_default_port(address).unwrap_or_else(|| address.to_string()),
            password: password.map(str::to_string),
            timeout,
        }
    }

    /// `host:port` as connected to.
    pub fn address(&self) -> &str {
        &self.address
    }

    /// Connects and reads the greeting; authentication rides on the first command.
    pub async fn connect(&self) -> Result<Session, PjlinkError> {
        let address = self.address.clone();
        let timeout_ms = self.timeout.as_millis() as u64;
        let stream = match timeout(self.timeout, TcpStream::connect(&address)).await {
            Err(_) => return Err(PjlinkError::Timeout { address, timeout_ms, during: "connect".into() }),
            Ok(Err(e)) => return Err(PjlinkError::Connect { address, message: e.to_string() }),
            Ok(Ok(s)) => s,
        };
        let _ = stream.set_nodelay(true);
        let mut session =
            Session { reader: BufReader::new(stream), address, timeout: self.timeout, digest: None };
        let line = session.read_line("greeting").await?;
        match protocol::parse_greeting(&line)
            .map_err(|e| PjlinkError::protocol(&session.address, "greeting", e))?
        {
            Greeting::Open => {}
            Greeting::Auth { random } => match &self.password {
                Some(p) => session.digest = Some(protocol::auth_digest(&random, p)),
                None => return Err(PjlinkError::PasswordRequired { address: session.address }),
            },
        }
        Ok(session)
    }

    pub async fn power(&self) -> Result<PowerState, PjlinkError> {
        self.connect().await?.power().await
    }

    /// POWR 1 / POWR 0. A projector cooling down or warming up may answer ERR3.
    pub async fn set_power(&self, on: bool) -> Result<(), PjlinkError> {
        self.connect().await?.set_power(on).await
    }

    pub async fn av_mute(&self) -> Result<AvMute, PjlinkError> {
        self.connect().await?.av_mute().await
    }

    /// AVMT 31 / AVMT 30 (picture and sound; class 1 and 2).
    pub async fn set_av_mute(&self, on: bool) -> Result<(), PjlinkError> {
        self.connect().await?.set_av_mute(on).await
    }

    pub async fn lamps(&self) -> Result<Vec<Lamp>, PjlinkError> {
        self.connect().await?.lamps().await
    }

    pub async fn error_status(&self) -> Result<ErrorStatus, PjlinkError> {
        self.connect().await?.error_status().await
    }

    pub async fn class(&self) -> Result<Class, PjlinkError> {
        self.connect().await?.class().await
    }

    pub async fn name(&self) -> Result<String, PjlinkError> {
        self.connect().await?.text(Command::Name).await
    }

    pub async fn info(&self) -> Result<Info, PjlinkError> {
        self.connect().await?.info().await
    }

    pub async fn poll(&self) -> Result<Poll, PjlinkError> {
        self.connect().await?.poll().await
    }
}

/// One open connection, greeting read. Dropping it closes the connection.
#[derive(Debug)]
pub struct Session {
    reader: BufReader<TcpStream>,
    address: String,
    timeout: Duration,
    /// The authentication prefix, until the first command has carried it.
    digest: Option<String>,
}

impl Session {
    fn timed_out(&self, during: &str) -> PjlinkError {
        PjlinkError::Timeout {
            address: self.address.clone(),
            timeout_ms: self.timeout.as_millis() as u64,
            during: during.to_string(),
        }
    }

    fn io(&self, during: &str, e: std::io::Error) -> PjlinkError {
        PjlinkError::Io { address: self.address.clone(), during: during.to_string(), message: e.to_string() }
    }

    /// Reads one CR-terminated line (a stray LF before it is skipped: some firmware sends
    /// CR LF), at most `MAX_LINE` bytes.
    async fn read_line(&mut self, during: &str) -> Result<Vec<u8>, PjlinkError> {
        let mut line = Vec::new();
        let limit = MAX_LINE as u64 + 2;
        let read = async {
            loop {
                let n =
                    (&mut self.reader).take(limit - line.len() as u64).read_until(b'\r', &mut line).await?;
                if n == 0 || line.ends_with(b"\r") || line.len() as u64 >= limit {
                    return Ok::<usize, std::io::Error>(n);
                }
            }
        };
        let n = match timeout(self.timeout, read).await {
            Err(_) => return Err(self.timed_out(during)),
            Ok(Err(e)) => return Err(self.io(during, e)),
            Ok(Ok(n)) => n,
        };
        if line.ends_with(b"\r") {
            line.pop();
        } else if n == 0 && line.len() as u64 <= MAX_LINE as u64 {
            return Err(PjlinkError::Closed { address: self.address.clone(), during: during.to_string() });
        }
        while line.first() == Some(&b'\n') {
            line.remove(0);
        }
        if line.len() > MAX_LINE {
            return Err(PjlinkError::Overlong {
                address: self.address.clone(),
                during: during.to_string(),
                max: MAX_LINE,
            });
        }
        Ok(line)
    }

    /// Sends one command and returns the body of its answer (`%1POWR=1` gives "1").
    pub async fn request(&mut self, command: Command, param: &str) -> Result<String, PjlinkError> {
        let during = format!("{} {param}", command.code());
        let mut out = self.digest.take().map(String::into_bytes).unwrap_or_default();
        out.extend(protocol::encode(command, param));
        match timeout(self.timeout, self.reader.get_mut().write_all(&out)).await {
            Err(_) => return Err(self.timed_out(&during)),
            Ok(Err(e)) => return Err(self.io(&during, e)),
            Ok(Ok(())) => {}
        }
        let line = self.read_line(&during).await?;
        protocol::parse_answer(&line, command).map_err(|e| PjlinkError::protocol(&self.address, &during, e))
    }

    async fn query<T>(
        &mut self,
        command: Command,
        parse: fn(&str) -> Result<T, ProtocolError>,
    ) -> Result<T, PjlinkError> {
        let body = self.request(command, "?").await?;
        parse(&body).map_err(|e| PjlinkError::protocol(&self.address, &format!("{} ?", command.code()), e))
    }

    async fn set(&mut self, command: Command, param: &str) -> Result<(), PjlinkError> {
        let body = self.request(command, param).await?;
        protocol::parse_ok(&body)
            .map_err(|e| PjlinkError::protocol(&self.address, &format!("{} {param}", command.code()), e))
    }

    pub async fn power(&mut self) -> Result<PowerState, PjlinkError> {
        self.query(Command::Powr, protocol::parse_power).await
    }

    pub async fn set_power(&mut self, on: bool) -> Result<(), PjlinkError> {
        self.set(Command::Powr, if on { "1" } else { "0" }).await
    }

    pub async fn av_mute(&mut self) -> Result<AvMute, PjlinkError> {
        self.query(Command::Avmt, protocol::parse_av_mute).await
    }

    pub async fn set_av_mute(&mut self, on: bool) -> Result<(), PjlinkError> {
        self.set(Command::Avmt, if on { "31" } else { "30" }).await
    }

    pub async fn lamps(&mut self) -> Result<Vec<Lamp>, PjlinkError> {
        self.query(Command::Lamp, protocol::parse_lamps).await
    }

    pub async fn error_status(&mut self) -> Result<ErrorStatus, PjlinkError> {
        self.query(Command::Erst, protocol::parse_error_status).await
    }

    pub async fn class(&mut self) -> Result<Class, PjlinkError> {
        self.query(Command::Clss, protocol::parse_class).await
    }

    /// Class 2: filter hours (`%2FILT ?`).
    pub async fn filter_hours(&mut self) -> Result<u32, PjlinkError> {
        self.query(Command::Filt, protocol::parse_count).await
    }

    /// A free-text query: NAME, INF1, INF2, INFO, SNUM, SVER.
    pub async fn text(&mut self, command: Command) -> Result<String, PjlinkError> {
        self.request(command, "?").await
    }

    /// Name, manufacturer, product, other information, class; serial number and software
    /// version when the projector is class 2.
    pub async fn info(&mut self) -> Result<Info, PjlinkError> {
        // Every field is mandatory in class 1, yet some firmware refuses one: a refusal
        // leaves it empty rather than failing the whole projector.
        let class = optional(self.class().await)?;
        let mut info = Info { class, ..Info::default() };
        for (command, field) in [
            (Command::Name, &mut info.name),
            (Command::Inf1, &mut info.manufacturer),
            (Command::Inf2, &mut info.product),
            (Command::Info, &mut info.other),
        ] {
            *field = optional(self.text(command).await)?.unwrap_or_default();
        }
        if class == Some(Class::Two) {
            info.serial_number = optional(self.text(Command::Snum).await)?;
            info.software_version = optional(self.text(Command::Sver).await)?;
        }
        Ok(info)
    }

    /// Power, AV mute, error status and lamps in one connection.
    pub async fn poll(&mut self) -> Result<Poll, PjlinkError> {
        let power = self.power().await?;
        let mute = self.av_mute().await?;
        let errors = self.error_status().await?;
        let lamps = optional(self.lamps().await)?.unwrap_or_default();
        Ok(Poll { power, mute, errors, lamps })
    }
}

/// An optional query: ERR1 (not supported) and ERR3 (not now) mean "no value".
fn optional<T>(r: Result<T, PjlinkError>) -> Result<Option<T>, PjlinkError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(PjlinkError::Refused { code: ErrCode::Undefined | ErrCode::Unavailable, .. }) => Ok(None),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_get_the_default_port() {
        assert_eq!(with_default_port("10.0.0.5").as_deref(), Some("10.0.0.5:4352"));
        assert_eq!(with_default_port("proj-left.local:4353").as_deref(), Some("proj-left.local:4353"));
        assert_eq!(with_default_port("fe80::1").as_deref(), Some("[fe80::1]:4352"));
        assert_eq!(with_default_port("[fe80::1]:99").as_deref(), Some("[fe80::1]:99"));
        assert_eq!(with_default_port("[fe80::1]").as_deref(), Some("[fe80::1]:4352"));
        for bad in ["", " ", "a b", "host:", "host:0", "host:70000", ":4352", "[]:1", "a:b:c", "[::1]x"] {
            assert_eq!(with_default_port(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn errors_name_the_projector_and_the_fix() {
        let e = PjlinkError::Auth { address: "10.0.0.5:4352".into() };
        assert!(e.to_string().contains("10.0.0.5:4352") && e.to_string().contains("password"));
        let e = PjlinkError::Refused {
            address: "p".into(),
            command: "POWR 1".into(),
            code: ErrCode::Unavailable,
        };
        assert_eq!(e.to_string(), "projector p: POWR 1 answered ERR3 (unavailable now)");
        assert!(!e.is_unreachable());
    }
}
