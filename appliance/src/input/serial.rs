//! The serial button box. Protocol, one ASCII command per line (LF or CR ends a line; case is
//! ignored): `PRESS` (button down), `RELEASE` (button up), `PING` (answered `PONG`).
//! Anything else — garbage, non-ASCII, lines over 64 bytes, partial lines cut by a reset — is
//! dropped without effect; a flood is absorbed by the bounded input channel and the player's
//! press-rate limit. The port is reopened after errors (a box unplugged and plugged back).

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use super::{InputEvent, InputSender, send_button};

/// Longest accepted line, in bytes; longer lines are dropped whole.
pub const MAX_LINE: usize = 64;

/// A message from the box.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialMsg {
    Press,
    Release,
    Ping,
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
    } else {
        None
    }
}

/// Serves one open connection until it ends (EOF or error). Returns how many lines were
/// dropped as garbage.
pub async fn serve<S: AsyncRead + AsyncWrite + Unpin>(stream: S, tx: &InputSender) -> std::io::Result<u64> {
    let (mut rd, mut wr) = tokio::io::split(stream);
    let mut lines = LineBuffer::new(MAX_LINE);
    let mut buf = [0u8; 512];
    let mut garbage = 0u64;
    loop {
        let n = rd.read(&mut buf).await?;
        if n == 0 {
            return Ok(garbage);
        }
        let mut pongs = 0;
        lines.feed(&buf[..n], |line| match parse_line(line) {
            Some(SerialMsg::Press) => send_button(tx, InputEvent::Press { source: "serial" }),
            Some(SerialMsg::Release) => send_button(tx, InputEvent::Release { source: "serial" }),
            Some(SerialMsg::Ping) => pongs += 1,
            None => {
                garbage += 1;
                if garbage.is_power_of_two() {
                    tracing::warn!(lines = garbage, "serial: unreadable lines dropped");
                }
            }
        });
        for _ in 0..pongs.min(4) {
            wr.write_all(b"PONG\n").await?;
        }
    }
}

/// Opens the port at `path` and serves it forever, reopening after errors.
pub async fn run(path: PathBuf, baud: u32, tx: InputSender) {
    loop {
        match open(&path, baud) {
            Ok(port) => {
                tracing::info!(path = %path.display(), baud, "serial button box open");
                match serve(port, &tx).await {
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

    proptest! {
        #[test]
        fn any_bytes_never_panic_and_bound_memory(data in proptest::collection::vec(any::<u8>(), 0..4096)) {
            let mut b = LineBuffer::new(MAX_LINE);
            b.feed(&data, |l| { assert!(l.len() <= MAX_LINE); let _ = parse_line(l); });
            prop_assert!(b.line.len() <= MAX_LINE);
        }
    }
}
