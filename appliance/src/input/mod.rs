//! Inputs: every source (GPIO, serial box, USB keypad, control socket, stdin, the development
//! window) sends `InputEvent`s into one channel read by the event loop.

use tokio::sync::{mpsc, oneshot};

pub mod evdev;
#[cfg(feature = "gpio")]
pub mod gpio;
pub mod serial;
pub mod socket;
pub mod stdin;

/// Capacity of the input channel. When it is full, further button events are dropped: a
/// flooding input cannot grow memory, and presses are rate-limited by the player anyway.
pub const CHANNEL_CAPACITY: usize = 64;

/// An operator command (control socket, stdin).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    Press,
    Status,
    Stop,
    Reload,
    /// Projector `projector` (1-based, as installers count) shows its commissioning pattern
    /// for `seconds`.
    Identify {
        projector: u8,
        seconds: u16,
    },
}

/// Longest commissioning pattern, seconds: an operator who walks away leaves no light on.
pub const IDENTIFY_MAX_S: u16 = 120;
/// Default length of `identify K`.
pub const IDENTIFY_DEFAULT_S: u16 = 10;

impl Control {
    /// Parses one command line (`press`, `status`, `stop`, `reload`, `identify K [SECONDS]`;
    /// case and surrounding blanks ignored).
    pub fn parse(line: &str) -> Option<Control> {
        let line = line.trim().to_ascii_lowercase();
        let mut words = line.split_ascii_whitespace();
        let command = match (words.next()?, words.next(), words.next()) {
            ("press", None, _) => Control::Press,
            ("status", None, _) => Control::Status,
            ("stop", None, _) => Control::Stop,
            ("reload", None, _) => Control::Reload,
            ("identify", Some(k), seconds) => {
                let projector = k.parse().ok().filter(|&k| k >= 1)?;
                let seconds = match seconds {
                    Some(s) => s.parse().ok().filter(|s| (1..=IDENTIFY_MAX_S).contains(s))?,
                    None => IDENTIFY_DEFAULT_S,
                };
                Control::Identify { projector, seconds }
            }
            _ => return None,
        };
        words.next().is_none().then_some(command)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_lines() {
        assert_eq!(Control::parse(" PRESS \n"), Some(Control::Press));
        assert_eq!(Control::parse("identify 2"), Some(Control::Identify { projector: 2, seconds: 10 }));
        assert_eq!(Control::parse("identify 3 30"), Some(Control::Identify { projector: 3, seconds: 30 }));
        for bad in [
            "identify",
            "identify 0",
            "identify -1",
            "identify 2 0",
            "identify 2 121",
            "identify 2 5 x",
            "press now",
            "",
            "identify 300",
        ] {
            assert_eq!(Control::parse(bad), None, "{bad:?}");
        }
    }
}

/// Something an input saw.
#[derive(Debug)]
pub enum InputEvent {
    /// The visitor's button went down; `source` names the input for the logs.
    Press { source: &'static str },
    /// The button came up.
    Release { source: &'static str },
    /// An operator command; the answer (one line) goes back on `reply`.
    Control { command: Control, reply: Option<oneshot::Sender<String>> },
    /// The development window was closed: stop the program.
    Quit,
    /// A display was plugged in or out (a DRM HOTPLUG uevent): the output re-probes.
    OutputsChanged,
}

/// The sending side handed to each input.
pub type InputSender = mpsc::Sender<InputEvent>;

/// Sends a button event, dropping it when the loop is saturated (see `CHANNEL_CAPACITY`).
pub fn send_button(tx: &InputSender, event: InputEvent) {
    if let Err(mpsc::error::TrySendError::Full(e)) = tx.try_send(event) {
        tracing::debug!(?e, "input channel full; button event dropped");
    }
}
