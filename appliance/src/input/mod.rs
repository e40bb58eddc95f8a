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
}

impl Control {
    /// Parses one command line (`press`, `status`, `stop`, `reload`; case and surrounding
    /// blanks ignored).
    pub fn parse(line: &str) -> Option<Control> {
        match line.trim().to_ascii_lowercase().as_str() {
            "press" => Some(Control::Press),
            "status" => Some(Control::Status),
            "stop" => Some(Control::Stop),
            "reload" => Some(Control::Reload),
            _ => None,
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
