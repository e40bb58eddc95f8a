//! The serial button box. Protocol, one ASCII command per line (LF or CR ends a line; case is
//! ignored): `PRESS` (button down), `RELEASE` (button up), `PING` (answered `PONG`),
//! `STATE?` (answered with the current `LED` line).
//! Anything else — garbage, non-ASCII, lines over 64 bytes, partial lines cut by a reset — is
//! dropped without effect; a flood is absorbed by the bounded input channel and the player's
//! press-rate limit. The port is reopened after errors (a box unplugged and plugged back).
//!
//! The appliance also sends `LED READY`, `LED SHOWING`, `LED WAIT`, `LED CLOSED`,
//! `LED EXHAUSTED` or `LED FAULT` (LF-terminated; see `feedback::Availability`): when the
//! port opens (a box plugged back learns the current state), whenever the state changes,
//! and in answer to `STATE?`. Writes never hold up reading: each line gets at most
//! `WRITE_TIMEOUT`, and answers beyond `MAX_QUEUED_REPLIES` waiting are dropped, so a box
//! that never reads costs nothing but its own lost lines.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};

use super::{InputEvent, InputSender, send_button};
use crate::feedback::Availability;

/// Longest accepted line, in bytes; longer lines are dropped whole.
pub const MAX_LINE: usize = 64;
/// Longest a single line to the box may take to go out; after that it is dropped.
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(500);
/// Answers (`PONG`, `STATE?`) waiting to be written; more are dropped.
pub const MAX_QUEUED_REPLIES: usize = 4;

/// A message from the box.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialMsg {
    Press,
    Release,
    Ping,
    /// `STATE?`: answer with the current `LED` line.
    State,
}

/// Splits a byte stream into bounded lines; survives any input.
#[derive(Debug, Default)]
pub struct LineBuffer {
    line: Vec<u8>,
    /// The current line overflowed: drop bytes until the next terminator.
    skipping: bool,
    max: usize,
}

impl LineBuffer {
    pub fn new(max: usize) -> LineBuffer {
        LineBuffer { line: Vec::with_capacity(max), skipping: false, max }
    }

    /// Feeds bytes; calls `each` with every complete, non-empty line within the limit.
    pub fn feed(&mut self, bytes: &[u8], mut each: impl FnMut(&[u8])) {
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if !self.skipping && !self.line.is_empty() {
                    each(&self.line);
                }
                self.line.clear();
                self.skipping = false;
            } else if self.skipping {
            } else if self.line.len() >= self.max {
                self.line.clear();
                self.skipping = true;
            } else {
                self.line.push(b);
            }
        }
    }
}

/// Parses one line of the protocol.
pub fn parse_line(line: &[u8]) -> Option<SerialMsg> {
    let text = std::str::from_utf8(line).ok()?.trim();
    if text.eq_ignore_ascii_case("PRESS") {
        Some(SerialMsg::Press)
    } else if text.eq_ignore_ascii_case("RELEASE") {
        Some(SerialMsg::Release)
    } else if text.eq_ignore_ascii_case("PING") {
        Some(SerialMsg::Ping)
    } else if text.eq_ignore_ascii_case("STATE?") {
        Some(SerialMsg::State)
    } else {
        None
    }
}

/// An answer waiting for the writer.
#[derive(Clone, Copy, Debug)]
enum Reply {
    Pong,
    State,
}

/// Serves one open connection until it ends (EOF or error): reads the box's lines and, beside
/// that, writes `LED` lines and answers. Returns how many lines were dropped as garbage.
pub async fn serve<S: AsyncRead + AsyncWrite + Unpin>(
    stream: S,
    tx: &InputSender,
    availability: watch::Receiver<Availability>,
) -> std::io::Result<u64> {
    let (rd, wr) = tokio::io::split(stream);
    let (reply_tx, reply_rx) = mpsc::channel(MAX_QUEUED_REPLIES);
    // Both run on this task; the writer only ever waits on itself (bounded by WRITE_TIMEOUT),
    // so reading goes on while a line is stuck.
    tokio::select! {
        read = read_lines(rd, tx, reply_tx) => read,
        written = write_lines(wr, reply_rx, availability) => written.map(|()| 0),
    }
}

async fn read_lines(
    mut rd: impl AsyncRead + Unpin,
    tx: &InputSender,
    replies: mpsc::Sender<Reply>,
) -> std::io::Result<u64> {
    let mut lines = LineBuffer::new(MAX_LINE);
    let mut buf = [0u8; 512];
    let mut garbage = 0u64;
    loop {
        let n = rd.read(&mut buf).await?;
        if n == 0 {
            return Ok(garbage);
        }
        lines.feed(&buf[..n], |line| match parse_line(line) {
            Some(SerialMsg::Press) => send_button(tx, InputEvent::Press { source: "serial" }),
            Some(SerialMsg::Release) => send_button(tx, InputEvent::Release { source: "serial" }),
            // A full queue means the box is not reading its answers: drop.
            Some(SerialMsg::Ping) => {
                let _ = replies.try_send(Reply::Pong);
            }
            Some(SerialMsg::State) => {
                let _ = replies.try_send(Reply::State);
            }
            None => {
                garbage += 1;
                if garbage.is_power_of_two() {
                    tracing::warn!(lines = garbage, "serial: unreadable lines dropped");
                }
            }
        });
    }
}

/// Writes the current `LED` line at once and on every change, and the answers; returns only on
/// a write error.
async fn write_lines(
    wr: impl AsyncWrite + Unpin,
    mut replies: mpsc::Receiver<Reply>,
    mut availability: watch::Receiver<Availability>,
) -> std::io::Result<()> {
    let mut out = LineWriter { wr, dropped: 0, cut: false };
    let mut last_led: Option<&'static str> = None;
    let mut watching = true;
    let mut led_due = true;
    loop {
        if std::mem::take(&mut led_due) {
            let now = *availability.borrow_and_update();
            // A new cooldown is another `Wait` but the same line: sent once.
            if last_led != Some(now.led_word()) {
                last_led = Some(now.led_word());
                out.line(now.serial_line().as_bytes()).await?;
            }
        }
        tokio::select! {
            changed = availability.changed(), if watching => match changed {
                Ok(()) => led_due = true,
                // Nobody publishes any more (tests, shutdown): answers still go out.
                Err(_) => watching = false,
            },
            reply = replies.recv() => match reply {
                Some(Reply::Pong) => out.line(b"PONG\n").await?,
                Some(Reply::State) => {
                    let now = *availability.borrow();
                    out.line(now.serial_line().as_bytes()).await?;
                }
                None => return Ok(()),
            },
        }
    }
}

/// Lines to the box, each within `WRITE_TIMEOUT` or dropped.
struct LineWriter<W> {
    wr: W,
    dropped: u64,
    /// A timed-out line may have gone out in part: the next one starts on a fresh line.
    cut: bool,
}

impl<W: AsyncWrite + Unpin> LineWriter<W> {
    async fn line(&mut self, line: &[u8]) -> std::io::Result<()> {
        let cut = std::mem::take(&mut self.cut);
        let wr = &mut self.wr;
        let write = async {
            if cut {
                wr.write_all(b"\n").await?;
            }
            wr.write_all(line).await?;
            wr.flush().await
        };
        match tokio::time::timeout(WRITE_TIMEOUT, write).await {
            Ok(result) => result,
            Err(_) => {
                self.cut = true;
                self.dropped += 1;
                if self.dropped.is_power_of_two() {
                    tracing::warn!(
                        lines = self.dropped,
                        "serial: the box is not reading; lines to it dropped"
                    );
                }
                Ok(())
            }
        }
    }
}

/// Opens the port at `path` and serves it forever, reopening after errors. `availability` is
/// what the `LED` lines tell the box.
pub async fn run(path: PathBuf, baud: u32, tx: InputSender, availability: watch::Receiver<Availability>) {
    loop {
        match open(&path, baud) {
            Ok(port) => {
                tracing::info!(path = %path.display(), baud, "serial button box open");
                match serve(port, &tx, availability.clone()).await {
                    Ok(_) => tracing::warn!(path = %path.display(), "serial port closed"),
                    Err(e) => tracing::warn!(path = %path.display(), %e, "serial port failed"),
                }
            }
            Err(e) => tracing::warn!(path = %path.display(), %e, "cannot open the serial port; retrying"),
        }
        if tx.is_closed() {
            return;
        }
        tokio::time::sleep(Duration::from_secs(2)).await;
    }
}

/// Opens a serial port (8N1, no flow control), raw.
pub fn open(path: &Path, baud: u32) -> std::io::Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path.to_string_lossy(), baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(std::io::Error::other)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn lines(chunks: &[&[u8]]) -> Vec<Option<SerialMsg>> {
        let mut b = LineBuffer::new(MAX_LINE);
        let mut out = Vec::new();
        for c in chunks {
            b.feed(c, |l| out.push(parse_line(l)));
        }
        out
    }

    #[test]
    fn commands_split_anywhere_and_terminated_any_way() {
        assert_eq!(
            lines(&[b"PRE", b"SS\r\nrelease\n", b"\n\nping\r", b"PRESS"]),
            vec![Some(SerialMsg::Press), Some(SerialMsg::Release), Some(SerialMsg::Ping)]
        );
    }

    #[test]
    fn garbage_and_overlong_lines_are_dropped() {
        let long = [b'P'; 200];
        let out = lines(&[b"\xff\xfePRESS\n", &long, b"PRESS\n", b"PRESSS\nPRESS\n"]);
        assert_eq!(out, vec![None, None, Some(SerialMsg::Press)]);
    }

    #[test]
    fn state_query_parses() {
        assert_eq!(
            lines(&[b"STATE?\n state? \nSTATE\n"]),
            vec![Some(SerialMsg::State), Some(SerialMsg::State), None]
        );
    }

    /// The box's end of a connection served by `serve` (on this test's runtime).
    struct Conn {
        boxed: tokio::io::DuplexStream,
        events: mpsc::Receiver<InputEvent>,
        served: tokio::task::JoinHandle<std::io::Result<u64>>,
    }

    fn connect(availability: &watch::Receiver<Availability>, buffer: usize) -> Conn {
        let (boxed, port) = tokio::io::duplex(buffer);
        let (tx, events) = mpsc::channel(crate::input::CHANNEL_CAPACITY);
        let rx = availability.clone();
        let served = tokio::spawn(async move { serve(port, &tx, rx).await });
        Conn { boxed, events, served }
    }

    impl Conn {
        /// The next line from the appliance (within a second).
        async fn line(&mut self) -> String {
            let mut line = Vec::new();
            let read = async {
                loop {
                    let b = self.boxed.read_u8().await.unwrap();
                    if b == b'\n' {
                        break;
                    }
                    line.push(b);
                }
            };
            tokio::time::timeout(Duration::from_secs(1), read).await.expect("a line from the appliance");
            String::from_utf8(line).unwrap()
        }

        async fn send(&mut self, bytes: &[u8]) {
            self.boxed.write_all(bytes).await.unwrap();
        }
    }

    #[tokio::test(start_paused = true)]
    async fn led_lines_on_open_on_change_and_on_query() {
        let (publish, availability) = watch::channel(Availability::Ready);
        let mut c = connect(&availability, 1024);
        assert_eq!(c.line().await, "LED READY");
        crate::feedback::publish(&publish, Availability::Showing);
        assert_eq!(c.line().await, "LED SHOWING");
        crate::feedback::publish(&publish, Availability::Wait { until_mono_ms: 5 });
        assert_eq!(c.line().await, "LED WAIT");
        // Another cooldown is the same line: not repeated; the next change is what comes.
        crate::feedback::publish(&publish, Availability::Wait { until_mono_ms: 9 });
        crate::feedback::publish(&publish, Availability::Exhausted);
        assert_eq!(c.line().await, "LED EXHAUSTED");
        c.send(b"state?\nPING\n").await;
        assert_eq!(c.line().await, "LED EXHAUSTED");
        assert_eq!(c.line().await, "PONG");
        // Nobody publishes any more: answers still come.
        drop(publish);
        c.send(b"STATE?\n").await;
        assert_eq!(c.line().await, "LED EXHAUSTED");
        drop(c.boxed);
        assert!(tokio::time::timeout(Duration::from_secs(1), c.served).await.is_ok());
    }

    #[tokio::test(start_paused = true)]
    async fn a_reopened_port_learns_the_current_state() {
        let (publish, availability) = watch::channel(Availability::Ready);
        let mut first = connect(&availability, 1024);
        assert_eq!(first.line().await, "LED READY");
        drop(first.boxed);
        let _ = first.served.await;
        // Unplugged: the state changes meanwhile; plugged back: the box hears it first thing.
        crate::feedback::publish(&publish, Availability::OutOfOrder);
        crate::feedback::publish(&publish, Availability::Closed);
        let mut again = connect(&availability, 1024);
        assert_eq!(again.line().await, "LED CLOSED");
        drop(again.events);
    }

    #[tokio::test(start_paused = true)]
    async fn a_box_that_never_reads_does_not_hold_up_presses() {
        let (publish, availability) = watch::channel(Availability::Ready);
        // 16 bytes towards the box, never read: the first LED line already fills it.
        let mut c = connect(&availability, 16);
        let start = tokio::time::Instant::now();
        for k in 0..20u64 {
            let a = if k.is_multiple_of(2) {
                Availability::Showing
            } else {
                Availability::Wait { until_mono_ms: k }
            };
            crate::feedback::publish(&publish, a);
            c.send(b"PING\nSTATE?\nPRESS\n").await;
        }
        for k in 0..20 {
            let ev = tokio::time::timeout(Duration::from_secs(5), c.events.recv()).await;
            assert!(matches!(ev, Ok(Some(InputEvent::Press { .. }))), "press {k}: {ev:?}");
        }
        // Every press came while the first stuck line was still waiting out its timeout.
        assert!(start.elapsed() < WRITE_TIMEOUT, "{:?}", start.elapsed());
        // And the connection is still served.
        assert!(!c.served.is_finished());
    }

    proptest! {
        #[test]
        fn any_bytes_never_panic_and_bound_memory(data in proptest::collection::vec(any::<u8>(), 0..4096)) {
            let mut b = LineBuffer::new(MAX_LINE);
            b.feed(&data, |l| { assert!(l.len() <= MAX_LINE); let _ = parse_line(l); });
            prop_assert!(b.line.len() <= MAX_LINE);
        }
    }
}
