//! PJLink's wire format, pure: commands out, greetings and answers in, every parser total
//! (any byte string gives a value or a `ProtocolError`, never a panic).

use md5::{Digest, Md5};
use serde::Serialize;
use thiserror::Error;

/// PJLink's TCP port.
pub const DEFAULT_PORT: u16 = 4352;
/// Longest line accepted from a projector, terminator excluded. The specification's longest
/// answer is 136 bytes (class 2 names and input names fit); anything longer is not PJLink.
pub const MAX_LINE: usize = 256;

/// The PJLink class a projector implements (`CLSS ?`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(into = "u8")]
pub enum Class {
    One,
    Two,
}

impl From<Class> for u8 {
    fn from(c: Class) -> u8 {
        match c {
            Class::One => 1,
            Class::Two => 2,
        }
    }
}

/// `POWR ?`: 0 standby, 1 on, 2 cooling down, 3 warming up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PowerState {
    Off,
    On,
    Cooling,
    Warming,
}

impl PowerState {
    pub fn digit(self) -> char {
        match self {
            PowerState::Off => '0',
            PowerState::On => '1',
            PowerState::Cooling => '2',
            PowerState::Warming => '3',
        }
    }
}

/// `AVMT ?`: which of picture and sound are muted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct AvMute {
    pub video: bool,
    pub audio: bool,
}

/// One field of `ERST ?`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    #[default]
    Ok,
    Warning,
    Error,
}

/// `ERST ?`: six digits, fan, lamp, temperature, cover, filter, other (0 ok, 1 warning,
/// 2 error).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ErrorStatus {
    pub fan: Level,
    pub lamp: Level,
    pub temperature: Level,
    pub cover: Level,
    pub filter: Level,
    pub other: Level,
}

impl ErrorStatus {
    pub const NAMES: [&'static str; 6] = ["fan", "lamp", "temperature", "cover", "filter", "other"];

    pub fn fields(&self) -> [Level; 6] {
        [self.fan, self.lamp, self.temperature, self.cover, self.filter, self.other]
    }

    /// The worst level reported.
    pub fn worst(&self) -> Level {
        self.fields().into_iter().max().unwrap_or_default()
    }

    /// "lamp error, filter warning", or None when all is well.
    pub fn describe(&self) -> Option<String> {
        let parts: Vec<String> = Self::NAMES
            .iter()
            .zip(self.fields())
            .filter(|(_, l)| *l != Level::Ok)
            .map(|(n, l)| format!("{n} {}", if l == Level::Error { "error" } else { "warning" }))
            .collect();
        (!parts.is_empty()).then(|| parts.join(", "))
    }
}

/// One lamp of `LAMP ?`: cumulative hours and whether it is lit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Lamp {
    pub hours: u32,
    pub on: bool,
}

/// The error answers `ERR1`..`ERR4`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrCode {
    /// ERR1: the projector does not know the command.
    Undefined,
    /// ERR2: parameter out of range.
    OutOfParameter,
    /// ERR3: not now (warming up, cooling down, in standby).
    Unavailable,
    /// ERR4: projector failure.
    Failure,
}

impl ErrCode {
    pub fn number(self) -> u8 {
        match self {
            ErrCode::Undefined => 1,
            ErrCode::OutOfParameter => 2,
            ErrCode::Unavailable => 3,
            ErrCode::Failure => 4,
        }
    }

    pub fn meaning(self) -> &'static str {
        match self {
            ErrCode::Undefined => "undefined command",
            ErrCode::OutOfParameter => "parameter out of range",
            ErrCode::Unavailable => "unavailable now",
            ErrCode::Failure => "projector failure",
        }
    }
}

/// A PJLink command: its four letters and the class prefix it is sent with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    Powr,
    Inpt,
    Avmt,
    Erst,
    Lamp,
    Inst,
    Name,
    Inf1,
    Inf2,
    Info,
    Clss,
    /// Class 2: serial number.
    Snum,
    /// Class 2: software version.
    Sver,
    /// Class 2: filter hours.
    Filt,
    /// Class 2: freeze.
    Frez,
}

impl Command {
    pub fn code(self) -> &'static str {
        match self {
            Command::Powr => "POWR",
            Command::Inpt => "INPT",
            Command::Avmt => "AVMT",
            Command::Erst => "ERST",
            Command::Lamp => "LAMP",
            Command::Inst => "INST",
            Command::Name => "NAME",
            Command::Inf1 => "INF1",
            Command::Inf2 => "INF2",
            Command::Info => "INFO",
            Command::Clss => "CLSS",
            Command::Snum => "SNUM",
            Command::Sver => "SVER",
            Command::Filt => "FILT",
            Command::Frez => "FREZ",
        }
    }

    /// The class digit of the prefix (`%1`, `%2`). Class 1 commands are sent as `%1` to
    /// every projector, class 2 ones as `%2`.
    pub fn class(self) -> u8 {
        match self {
            Command::Snum | Command::Sver | Command::Filt | Command::Frez => 2,
            _ => 1,
        }
    }
}

/// A request line: `%1POWR 1\r`. `param` must not contain CR (the callers pass constants or
/// `?`); a CR in it is dropped so that one request can never become two.
pub fn encode(command: Command, param: &str) -> Vec<u8> {
    let mut line = format!("%{}{} ", command.class(), command.code()).into_bytes();
    line.extend(param.bytes().filter(|b| *b != b'\r' && *b != b'\n'));
    line.push(b'\r');
    line
}

/// What a projector says on connecting.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Greeting {
    /// `PJLINK 0`: no authentication.
    Open,
    /// `PJLINK 1 <random>`: prefix the first command with MD5(random + password).
    Auth { random: String },
}

/// What is wrong with a line, before the client adds which projector and command.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum ProtocolError {
    #[error("not PJLink ({why}): {line:?}")]
    Garbage { why: &'static str, line: String },
    #[error("ERR{} ({})", .0.number(), .0.meaning())]
    Refused(ErrCode),
    #[error("password refused (ERRA)")]
    AuthRefused,
}

fn garbage(why: &'static str, line: &[u8]) -> ProtocolError {
    // Shown to operators: printable, bounded.
    let mut text: String = String::from_utf8_lossy(line).chars().take(64).collect();
    if line.len() > 64 {
        text.push('…');
    }
    ProtocolError::Garbage { why, line: text }
}

/// Parses the greeting line (terminator removed).
pub fn parse_greeting(line: &[u8]) -> Result<Greeting, ProtocolError> {
    match line {
        b"PJLINK 0" => Ok(Greeting::Open),
        b"PJLINK ERRA" => Err(ProtocolError::AuthRefused),
        _ => match line.strip_prefix(b"PJLINK 1 ") {
            Some(random) if random.len() == 8 && random.iter().all(|b| b.is_ascii_graphic()) => {
                Ok(Greeting::Auth { random: String::from_utf8_lossy(random).into_owned() })
            }
            _ => Err(garbage("bad greeting", line)),
        },
    }
}

/// MD5(random + password) as 32 lowercase hex digits: the prefix of the first command.
pub fn auth_digest(random: &str, password: &str) -> String {
    let mut h = Md5::new();
    h.update(random.as_bytes());
    h.update(password.as_bytes());
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Parses the answer to `command` (terminator removed) and returns its body: `%1POWR=1`
/// gives "1". `ERR1`..`ERR4` and `ERRA` bodies, and `PJLINK ERRA`, are errors.
pub fn parse_answer(line: &[u8], command: Command) -> Result<String, ProtocolError> {
    if line == b"PJLINK ERRA" {
        return Err(ProtocolError::AuthRefused);
    }
    let Some(rest) = line.strip_prefix(b"%") else {
        return Err(garbage("no % prefix", line));
    };
    let [class, c0, c1, c2, c3, b'=', body @ ..] = rest else {
        return Err(garbage("no %<class><CMD>= header", line));
    };
    if *class != b'0' + command.class() {
        return Err(garbage("wrong class digit", line));
    }
    if !([*c0, *c1, *c2, *c3].eq_ignore_ascii_case(command.code().as_bytes())) {
        return Err(garbage("answer to another command", line));
    }
    let Ok(body) = std::str::from_utf8(body) else {
        return Err(garbage("not UTF-8", line));
    };
    if body.chars().any(char::is_control) {
        return Err(garbage("control character", line));
    }
    match body {
        "ERR1" => Err(ProtocolError::Refused(ErrCode::Undefined)),
        "ERR2" => Err(ProtocolError::Refused(ErrCode::OutOfParameter)),
        "ERR3" => Err(ProtocolError::Refused(ErrCode::Unavailable)),
        "ERR4" => Err(ProtocolError::Refused(ErrCode::Failure)),
        "ERRA" => Err(ProtocolError::AuthRefused),
        _ => Ok(body.to_string()),
    }
}

/// The body of a set command's answer: `OK`.
pub fn parse_ok(body: &str) -> Result<(), ProtocolError> {
    if body == "OK" { Ok(()) } else { Err(garbage("expected OK", body.as_bytes())) }
}

pub fn parse_power(body: &str) -> Result<PowerState, ProtocolError> {
    match body {
        "0" => Ok(PowerState::Off),
        "1" => Ok(PowerState::On),
        "2" => Ok(PowerState::Cooling),
        "3" => Ok(PowerState::Warming),
        _ => Err(garbage("power state not 0..3", body.as_bytes())),
    }
}

/// `AVMT ?`: 11/10 picture mute on/off, 21/20 sound, 31/30 both. A one-sided answer says
/// the other side is not muted.
pub fn parse_av_mute(body: &str) -> Result<AvMute, ProtocolError> {
    let (video, audio) = match body {
        "10" | "20" | "30" => (false, false),
        "11" => (true, false),
        "21" => (false, true),
        "31" => (true, true),
        _ => return Err(garbage("AV mute not 10/11/20/21/30/31", body.as_bytes())),
    };
    Ok(AvMute { video, audio })
}

pub fn parse_error_status(body: &str) -> Result<ErrorStatus, ProtocolError> {
    let level = |b: u8| match b {
        b'0' => Some(Level::Ok),
        b'1' => Some(Level::Warning),
        b'2' => Some(Level::Error),
        _ => None,
    };
    let levels: Option<Vec<Level>> = body.bytes().map(level).collect();
    match levels.as_deref() {
        Some(&[fan, lamp, temperature, cover, filter, other]) => {
            Ok(ErrorStatus { fan, lamp, temperature, cover, filter, other })
        }
        _ => Err(garbage("error status not six digits 0..2", body.as_bytes())),
    }
}

/// `LAMP ?`: pairs `hours on` for 1..=8 lamps (`1234 1 567 0`).
pub fn parse_lamps(body: &str) -> Result<Vec<Lamp>, ProtocolError> {
    let words: Vec<&str> = body.split(' ').collect();
    if !words.len().is_multiple_of(2) || words.is_empty() || words.len() > 16 {
        return Err(garbage("lamp answer not 1..8 pairs", body.as_bytes()));
    }
    words
        .chunks_exact(2)
        .map(|pair| {
            let &[hours, on] = pair else { return Err(garbage("lamp answer not pairs", body.as_bytes())) };
            if hours.is_empty() || hours.len() > 9 || !hours.bytes().all(|b| b.is_ascii_digit()) {
                return Err(garbage("lamp hours not a number", body.as_bytes()));
            }
            let hours = hours.parse().map_err(|_| garbage("lamp hours not a number", body.as_bytes()))?;
            let on = match on {
                "0" => false,
                "1" => true,
                _ => return Err(garbage("lamp on/off not 0/1", body.as_bytes())),
            };
            Ok(Lamp { hours, on })
        })
        .collect()
}

pub fn parse_class(body: &str) -> Result<Class, ProtocolError> {
    match body {
        "1" => Ok(Class::One),
        "2" => Ok(Class::Two),
        _ => Err(garbage("class not 1 or 2", body.as_bytes())),
    }
}

/// A count answer such as `FILT ?` (hours).
pub fn parse_count(body: &str) -> Result<u32, ProtocolError> {
    if body.is_empty() || body.len() > 9 || !body.bytes().all(|b| b.is_ascii_digit()) {
        return Err(garbage("not a number", body.as_bytes()));
    }
    body.parse().map_err(|_| garbage("not a number", body.as_bytes()))
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    #[test]
    fn requests_are_one_line_with_the_class_prefix() {
        assert_eq!(encode(Command::Powr, "1"), b"%1POWR 1\r");
        assert_eq!(encode(Command::Snum, "?"), b"%2SNUM ?\r");
        assert_eq!(encode(Command::Avmt, "31\r%1POWR 0"), b"%1AVMT 31%1POWR 0\r");
    }

    #[test]
    fn greetings() {
        assert_eq!(parse_greeting(b"PJLINK 0"), Ok(Greeting::Open));
        assert_eq!(parse_greeting(b"PJLINK 1 498e4a67"), Ok(Greeting::Auth { random: "498e4a67".into() }));
        assert_eq!(parse_greeting(b"PJLINK ERRA"), Err(ProtocolError::AuthRefused));
        assert!(matches!(parse_greeting(b"PJLINK 1 short"), Err(ProtocolError::Garbage { .. })));
        assert!(matches!(parse_greeting(b"HTTP/1.1 400"), Err(ProtocolError::Garbage { .. })));
    }

    #[test]
    fn digest_is_the_specifications_example() {
        // PJLink class 1 specification, section 5.1: random 498e4a67, password JBMIAProjectorLink.
        assert_eq!(auth_digest("498e4a67", "JBMIAProjectorLink"), "5d8409bc1c3fa39749434aa3a5c38682");
    }

    #[test]
    fn answers_and_errors() {
        assert_eq!(parse_answer(b"%1POWR=OK", Command::Powr), Ok("OK".into()));
        assert_eq!(parse_answer(b"%1powr=1", Command::Powr), Ok("1".into()));
        assert_eq!(
            parse_answer(b"%1POWR=ERR3", Command::Powr),
            Err(ProtocolError::Refused(ErrCode::Unavailable))
        );
        assert_eq!(
            parse_answer(b"%1POWR=ERR4", Command::Powr),
            Err(ProtocolError::Refused(ErrCode::Failure))
        );
        assert_eq!(parse_answer(b"%1POWR=ERRA", Command::Powr), Err(ProtocolError::AuthRefused));
        assert_eq!(parse_answer(b"PJLINK ERRA", Command::Powr), Err(ProtocolError::AuthRefused));
        assert!(matches!(parse_answer(b"%2POWR=1", Command::Powr), Err(ProtocolError::Garbage { .. })));
        assert!(matches!(parse_answer(b"%1LAMP=1", Command::Powr), Err(ProtocolError::Garbage { .. })));
        assert!(matches!(parse_answer(b"%1POW", Command::Powr), Err(ProtocolError::Garbage { .. })));
        assert!(matches!(parse_answer(b"#1POWR=1", Command::Powr), Err(ProtocolError::Garbage { .. })));
        assert_eq!(parse_answer(b"%2SNUM=AB123", Command::Snum), Ok("AB123".into()));
        assert_eq!(parse_answer(b"%1NAME=", Command::Name), Ok(String::new()));
    }

    #[test]
    fn bodies() {
        assert_eq!(parse_power("3"), Ok(PowerState::Warming));
        assert!(parse_power("4").is_err());
        assert_eq!(parse_av_mute("31"), Ok(AvMute { video: true, audio: true }));
        assert_eq!(parse_av_mute("11"), Ok(AvMute { video: true, audio: false }));
        assert_eq!(parse_av_mute("30"), Ok(AvMute::default()));
        assert!(parse_av_mute("32").is_err());
        let e = parse_error_status("020001").unwrap();
        assert_eq!(e.lamp, Level::Error);
        assert_eq!(e.other, Level::Warning);
        assert_eq!(e.worst(), Level::Error);
        assert_eq!(e.describe().as_deref(), Some("lamp error, other warning"));
        assert_eq!(parse_error_status("000000").unwrap().describe(), None);
        assert!(parse_error_status("00000").is_err());
        assert!(parse_error_status("000003").is_err());
        assert_eq!(parse_lamps("1234 1"), Ok(vec![Lamp { hours: 1234, on: true }]));
        assert_eq!(
            parse_lamps("1234 1 99999 0"),
            Ok(vec![Lamp { hours: 1234, on: true }, Lamp { hours: 99999, on: false }])
        );
        assert!(parse_lamps("1234").is_err());
        assert!(parse_lamps("1234 2").is_err());
        assert!(parse_lamps("-1 1").is_err());
        assert!(parse_lamps("99999999999 1").is_err());
        assert!(parse_lamps("").is_err());
        assert_eq!(parse_class("2"), Ok(Class::Two));
        assert!(parse_class("3").is_err());
        assert_eq!(parse_count("0123"), Ok(123));
        assert!(parse_count("+1").is_err());
    }

    proptest! {
        #[test]
        fn parsers_are_total(line in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = parse_greeting(&line);
            for c in [Command::Powr, Command::Lamp, Command::Snum] {
                if let Ok(body) = parse_answer(&line, c) {
                    let _ = parse_ok(&body);
                    let _ = parse_power(&body);
                    let _ = parse_av_mute(&body);
                    let _ = parse_error_status(&body);
                    let _ = parse_lamps(&body);
                    let _ = parse_class(&body);
                    let _ = parse_count(&body);
                }
            }
        }

        #[test]
        fn framed_bodies_never_panic(body in "[ -~]{0,40}") {
            let line = format!("%1LAMP={body}");
            if let Ok(b) = parse_answer(line.as_bytes(), Command::Lamp) {
                let _ = parse_lamps(&b);
                let _ = parse_error_status(&b);
            }
        }
    }
}
