//! A simulated PJLink projector on 127.0.0.1: power state machine with warm-up and cool-down,
//! AV mute, lamps, error status, class 1 or 2, optional password, and fault modes. It records
//! every command it receives (with the power state it was in) so tests can assert on them.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::protocol::{self, AvMute, Class, ErrorStatus, Level, PowerState};

/// How the simulated projector misbehaves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Fault {
    #[default]
    None,
    /// Accepts connections and never says anything.
    Silent,
    /// Answers every line (the greeting too) with seeded random bytes.
    Garbage,
    /// The lamp has failed: ERST reports lamp error 2, the lamp is off, POWR 1 answers ERR4.
    LampError,
}

/// A simulated projector's settings.
#[derive(Clone, Debug)]
pub struct SimConfig {
    pub class: Class,
    pub password: Option<String>,
    pub warmup: Duration,
    pub cooldown: Duration,
    pub power: PowerState,
    pub lamp_hours: Vec<u32>,
    pub name: String,
    pub fault: Fault,
    /// Seeds the authentication randoms and the garbage.
    pub seed: u64,
    /// The connection is closed after this long without a command (real projectors: ~30 s).
    pub idle_close: Duration,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            class: Class::One,
            password: None,
            warmup: Duration::from_millis(300),
            cooldown: Duration::from_millis(300),
            power: PowerState::Off,
            lamp_hours: vec![1234],
            name: "sim".into(),
            fault: Fault::None,
            seed: 1,
            idle_close: Duration::from_secs(30),
        }
    }
}

/// A command as the simulator received it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Received {
    /// The line without its terminator and authentication prefix: `%1POWR 1`.
    pub line: String,
    /// The power state when it arrived.
    pub power: PowerState,
}

#[derive(Debug)]
struct State {
    config: SimConfig,
    power: PowerState,
    /// When the current warm-up or cool-down ends.
    until: Instant,
    mute: AvMute,
    frozen: bool,
    errors: ErrorStatus,
    received: Vec<Received>,
    connections: usize,
    rng: ChaCha8Rng,
}

impl State {
    /// Finishes a warm-up or cool-down whose time has come.
    fn settle(&mut self, now: Instant) -> PowerState {
        match self.power {
            PowerState::Warming if now >= self.until => self.power = PowerState::On,
            PowerState::Cooling if now >= self.until => self.power = PowerState::Off,
            _ => {}
        }
        self.power
    }

    fn errors(&self) -> ErrorStatus {
        let mut e = self.errors;
        if self.config.fault == Fault::LampError {
            e.lamp = Level::Error;
        }
        e
    }

    /// The answer to one command line (authentication already handled), without CR.
    fn answer(&mut self, line: &str, now: Instant) -> String {
        let power = self.settle(now);
        self.received.push(Received { line: line.to_string(), power });
        let (head, param) = line.split_once(' ').unwrap_or((line, ""));
        let (Some(class), Some(code)) = (head.get(1..2), head.get(2..)) else {
            return "%1ERR1".into();
        };
        if !head.starts_with('%') || code.len() != 4 {
            return format!("%{class}ERR1");
        }
        let reply = |body: &str| format!("%{class}{code}={body}");
        let class2 = self.config.class == Class::Two;
        let body: String = match (class, code, param) {
            ("1", "POWR", "?") => power.digit().to_string(),
            ("1", "POWR", "1") => match power {
                _ if self.config.fault == Fault::LampError => "ERR4".into(),
                PowerState::Cooling => "ERR3".into(),
                PowerState::Off => {
                    self.power = PowerState::Warming;
                    self.until = now + self.config.warmup;
                    self.settle(now);
                    "OK".into()
                }
                PowerState::On | PowerState::Warming => "OK".into(),
            },
            ("1", "POWR", "0") => match power {
                PowerState::Warming => "ERR3".into(),
                PowerState::On => {
                    self.power = PowerState::Cooling;
                    self.until = now + self.config.cooldown;
                    self.settle(now);
                    "OK".into()
                }
                PowerState::Off | PowerState::Cooling => "OK".into(),
            },
            ("1", "POWR", _) => "ERR2".into(),
            ("1", "AVMT", "?") => match self.mute {
                AvMute { video: true, audio: true } => "31".into(),
                AvMute { video: true, audio: false } => "11".into(),
                AvMute { video: false, audio: true } => "21".into(),
                AvMute { video: false, audio: false } => "30".into(),
            },
            ("1", "AVMT", p) => {
                let set: Option<fn(&mut AvMute)> = match p {
                    "10" => Some(|m| m.video = false),
                    "11" => Some(|m| m.video = true),
                    "20" => Some(|m| m.audio = false),
                    "21" => Some(|m| m.audio = true),
                    "30" => Some(|m| *m = AvMute::default()),
                    "31" => Some(|m| *m = AvMute { video: true, audio: true }),
                    _ => None,
                };
                match set {
                    None => "ERR2".into(),
                    Some(_) if power != PowerState::On => "ERR3".into(),
                    Some(f) => {
                        f(&mut self.mute);
                        "OK".into()
                    }
                }
            }
            ("1", "ERST", "?") => {
                self.errors().fields().iter().map(|l| char::from(b'0' + *l as u8)).collect()
            }
            ("1", "LAMP", "?") => {
                let lit = power == PowerState::On && self.config.fault != Fault::LampError;
                let lamps: Vec<String> =
                    self.config.lamp_hours.iter().map(|h| format!("{h} {}", u8::from(lit))).collect();
                if lamps.is_empty() { "ERR1".into() } else { lamps.join(" ") }
            }
            ("1" | "2", "INPT", "?") => "31".into(),
            ("1" | "2", "INPT", _) if power != PowerState::On => "ERR3".into(),
            ("1" | "2", "INPT", "11" | "31" | "32") => "OK".into(),
            ("1" | "2", "INPT", _) => "ERR2".into(),
            ("1" | "2", "INST", "?") => "11 31 32".into(),
            ("1", "NAME", "?") => self.config.name.clone(),
            ("1", "INF1", "?") => "restage".into(),
            ("1", "INF2", "?") => "simulated projector".into(),
            ("1", "INFO", "?") => format!("class {}", u8::from(self.config.class)),
            ("1", "CLSS", "?") => u8::from(self.config.class).to_string(),
            ("2", "SNUM", "?") if class2 => "SIM0001".into(),
            ("2", "SVER", "?") if class2 => "1.0".into(),
            ("2", "FILT", "?") if class2 => "321".into(),
            ("2", "FREZ", "?") if class2 => if self.frozen { "1" } else { "0" }.into(),
            ("2", "FREZ", "0" | "1") if class2 && power != PowerState::On => "ERR3".into(),
            ("2", "FREZ", p @ ("0" | "1")) if class2 => {
                self.frozen = p == "1";
                "OK".into()
            }
            ("2", "SVOL" | "MVOL", "0" | "1") if class2 => "OK".into(),
            ("2", "RLMP" | "RFIL", "?") if class2 => "ERR1".into(),
            (_, _, "?") => "ERR1".into(),
            _ => "ERR1".into(),
        };
        reply(&body)
    }
}

/// A running simulated projector; dropping it stops it and closes its connections.
#[derive(Debug)]
pub struct SimProjector {
    addr: SocketAddr,
    state: Arc<Mutex<State>>,
    task: JoinHandle<()>,
}

impl Drop for SimProjector {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn lock(state: &Mutex<State>) -> MutexGuard<'_, State> {
    // A test that panicked while holding the lock must not hide the state from the others.
    state.lock().unwrap_or_else(|p| p.into_inner())
}

impl SimProjector {
    /// Listens on 127.0.0.1 (a free port) and serves until dropped.
    pub async fn start(config: SimConfig) -> std::io::Result<SimProjector> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let now = Instant::now();
        let state = Arc::new(Mutex::new(State {
            power: config.power,
            until: now,
            mute: AvMute::default(),
            frozen: false,
            errors: ErrorStatus::default(),
            received: Vec::new(),
            connections: 0,
            rng: ChaCha8Rng::seed_from_u64(config.seed),
            config,
        }));
        let shared = state.clone();
        let task = tokio::spawn(async move {
            let mut connections = tokio::task::JoinSet::new();
            loop {
                tokio::select! {
                    accepted = listener.accept() => {
                        let Ok((stream, _)) = accepted else { continue };
                        lock(&shared).connections += 1;
                        connections.spawn(serve(stream, shared.clone()));
                    }
                    Some(_) = connections.join_next(), if !connections.is_empty() => {}
                }
            }
        });
        Ok(SimProjector { addr, state, task })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `127.0.0.1:port`, as configuration takes it.
    pub fn address(&self) -> String {
        self.addr.to_string()
    }

    /// Every command received so far, in order.
    pub fn received(&self) -> Vec<Received> {
        lock(&self.state).received.clone()
    }

    /// The command lines received so far (`%1POWR 1`, ...).
    pub fn commands(&self) -> Vec<String> {
        self.received().into_iter().map(|r| r.line).collect()
    }

    /// Connections accepted so far.
    pub fn connections(&self) -> usize {
        lock(&self.state).connections
    }

    pub fn power(&self) -> PowerState {
        lock(&self.state).settle(Instant::now())
    }

    pub fn mute(&self) -> AvMute {
        lock(&self.state).mute
    }

    pub fn set_fault(&self, fault: Fault) {
        lock(&self.state).config.fault = fault;
    }

    pub fn set_error_status(&self, errors: ErrorStatus) {
        lock(&self.state).errors = errors;
    }

    pub fn set_lamp_hours(&self, hours: Vec<u32>) {
        lock(&self.state).config.lamp_hours = hours;
    }
}

/// An address on 127.0.0.1 where nothing listens (a projector that refuses connections).
pub async fn closed_port() -> std::io::Result<String> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    drop(listener);
    Ok(addr.to_string())
}

fn random_garbage(state: &Mutex<State>) -> Vec<u8> {
    let mut s = lock(state);
    let n = s.rng.gen_range(1..=300);
    let mut bytes: Vec<u8> = (0..n).map(|_| s.rng.r#gen::<u8>()).collect();
    // Terminated, so a client sees garbage rather than waiting for the rest of a line.
    bytes.push(b'\r');
    bytes
}

async fn serve(stream: TcpStream, state: Arc<Mutex<State>>) {
    let (fault, password, idle_close) = {
        let s = lock(&state);
        (s.config.fault, s.config.password.clone(), s.config.idle_close)
    };
    let mut reader = BufReader::new(stream);
    if fault == Fault::Silent {
        // Swallow whatever comes until the client goes away.
        let mut sink = [0u8; 256];
        while matches!(reader.read(&mut sink).await, Ok(n) if n > 0) {}
        return;
    }
    let random = password.as_ref().map(|_| {
        let mut s = lock(&state);
        format!("{:08x}", s.rng.r#gen::<u32>())
    });
    let greeting = match (fault, &random) {
        (Fault::Garbage, _) => random_garbage(&state),
        (_, Some(r)) => format!("PJLINK 1 {r}\r").into_bytes(),
        (_, None) => b"PJLINK 0\r".to_vec(),
    };
    if reader.get_mut().write_all(&greeting).await.is_err() {
        return;
    }
    let mut expect_digest = random.zip(password).map(|(r, p)| protocol::auth_digest(&r, &p));
    let mut line = Vec::new();
    loop {
        line.clear();
        let mut limited = (&mut reader).take(protocol::MAX_LINE as u64);
        match tokio::time::timeout(idle_close, limited.read_until(b'\r', &mut line)).await {
            Ok(Ok(n)) if n > 0 && line.ends_with(b"\r") => {}
            _ => return, // idle, closed, overlong or broken: hang up like a projector does
        }
        line.pop();
        let mut text = String::from_utf8_lossy(&line).into_owned();
        if let Some(digest) = expect_digest.take() {
            match text.strip_prefix(digest.as_str()) {
                Some(rest) => text = rest.to_string(),
                None => {
                    let _ = reader.get_mut().write_all(b"PJLINK ERRA\r").await;
                    return;
                }
            }
        }
        let answer = {
            let mut s = lock(&state);
            (s.config.fault != Fault::Garbage).then(|| s.answer(&text, Instant::now()))
        };
        let bytes = match answer {
            Some(a) => format!("{a}\r").into_bytes(),
            None => random_garbage(&state),
        };
        if reader.get_mut().write_all(&bytes).await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(config: SimConfig) -> State {
        State {
            power: config.power,
            until: Instant::now(),
            mute: AvMute::default(),
            frozen: false,
            errors: ErrorStatus::default(),
            received: Vec::new(),
            connections: 0,
            rng: ChaCha8Rng::seed_from_u64(0),
            config,
        }
    }

    #[tokio::test]
    async fn power_cycle_with_warm_up_and_cool_down() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut s = state(SimConfig { warmup: ms(100), cooldown: ms(200), ..SimConfig::default() });
        assert_eq!(s.answer("%1POWR ?", t0), "%1POWR=0");
        assert_eq!(s.answer("%1AVMT 31", t0), "%1AVMT=ERR3");
        assert_eq!(s.answer("%1POWR 1", t0), "%1POWR=OK");
        assert_eq!(s.answer("%1POWR ?", t0 + ms(50)), "%1POWR=3");
        assert_eq!(s.answer("%1POWR 0", t0 + ms(50)), "%1POWR=ERR3");
        assert_eq!(s.answer("%1POWR ?", t0 + ms(100)), "%1POWR=1");
        assert_eq!(s.answer("%1LAMP ?", t0 + ms(100)), "%1LAMP=1234 1");
        assert_eq!(s.answer("%1AVMT 31", t0 + ms(100)), "%1AVMT=OK");
        assert_eq!(s.answer("%1AVMT ?", t0 + ms(100)), "%1AVMT=31");
        assert_eq!(s.answer("%1POWR 0", t0 + ms(110)), "%1POWR=OK");
        assert_eq!(s.answer("%1POWR 1", t0 + ms(200)), "%1POWR=ERR3");
        assert_eq!(s.answer("%1POWR ?", t0 + ms(310)), "%1POWR=0");
        assert_eq!(s.answer("%1POWR 7", t0 + ms(310)), "%1POWR=ERR2");
        assert_eq!(s.received.len(), 13);
        assert_eq!(s.received[10], Received { line: "%1POWR 1".into(), power: PowerState::Cooling });
    }

    #[tokio::test]
    async fn class_two_commands_need_a_class_two_projector() {
        let now = Instant::now();
        let mut one = state(SimConfig::default());
        assert_eq!(one.answer("%2SNUM ?", now), "%2SNUM=ERR1");
        assert_eq!(one.answer("%1CLSS ?", now), "%1CLSS=1");
        let mut two = state(SimConfig { class: Class::Two, ..SimConfig::default() });
        assert_eq!(two.answer("%2SNUM ?", now), "%2SNUM=SIM0001");
        assert_eq!(two.answer("%1CLSS ?", now), "%1CLSS=2");
        assert_eq!(two.answer("garbage", now), "%aERR1");
        assert_eq!(two.answer("", now), "%1ERR1");
    }

    #[tokio::test]
    async fn lamp_error_reports_and_refuses_power() {
        let now = Instant::now();
        let mut s = state(SimConfig { fault: Fault::LampError, ..SimConfig::default() });
        assert_eq!(s.answer("%1ERST ?", now), "%1ERST=020000");
        assert_eq!(s.answer("%1POWR 1", now), "%1POWR=ERR4");
        assert_eq!(s.answer("%1LAMP ?", now), "%1LAMP=1234 0");
    }
}
