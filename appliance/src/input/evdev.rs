//! A USB keypad (or any keyboard) through evdev: any configured key is the button. The device
//! is reopened after errors (unplugged and plugged back).

use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

use evdev::{Device, EventSummary, KeyCode};

use super::{InputEvent, InputSender, send_button};

/// Parses evdev key names (e.g. `KEY_ENTER`).
pub fn parse_keys(names: &[String]) -> Result<Vec<KeyCode>, String> {
    names.iter().map(|n| KeyCode::from_str(n).map_err(|_| format!("unknown evdev key name {n:?}"))).collect()
}

/// Reads key events forever.
pub async fn run(path: PathBuf, keys: Vec<KeyCode>, tx: InputSender) {
    loop {
        match Device::open(&path).and_then(|d| d.into_event_stream()) {
            Ok(mut stream) => {
                tracing::info!(path = %path.display(), "keypad open");
                loop {
                    match stream.next_event().await {
                        Ok(ev) => {
                            if let EventSummary::Key(_, code, value) = ev.destructure()
                                && keys.contains(&code)
                            {
                                // 1 = down, 0 = up, 2 = auto-repeat (ignored: a held key is one press).
                                match value {
                                    1 => send_button(&tx, InputEvent::Press { source: "keypad" }),
                                    0 => send_button(&tx, InputEvent::Release { source: "keypad" }),
                                    _ => {}
                                }
                            }
                        }
                        Err(e) => {
                            tracing::warn!(path = %path.display(), %e, "keypad read failed");
                            break;
                        }
                    }
                }
            }
            Err(e) => tracing::warn!(path = %path.display(), %e, "cannot open the keypad; retrying"),
        }
        if tx.is_closed() {
            return;
        }
        tokio::time::sleep(Duration::from_secs(2)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_names() {
        assert_eq!(parse_keys(&["KEY_ENTER".into()]).unwrap(), vec![KeyCode::KEY_ENTER]);
        assert!(parse_keys(&["KEY_NOPE".into()]).unwrap_err().contains("KEY_NOPE"));
    }
}
