//! What the appliance's end-to-end tests share: the operators' control socket and the
//! running program.

#![allow(dead_code)] // each test file uses its own part

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// Sends one command to the control socket and returns the answer line, retrying until the
/// appliance answers or `timeout` passes.
pub fn ask(socket: &Path, command: &str, timeout: Duration) -> Option<String> {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Ok(mut s) = std::os::unix::net::UnixStream::connect(socket) {
            s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
            if s.write_all(format!("{command}\n").as_bytes()).is_ok() {
                let mut line = String::new();
                if BufReader::new(s).read_line(&mut line).is_ok() && !line.is_empty() {
                    return Some(line.trim_end().to_string());
                }
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

/// `restage-appliance run --config CONFIG`; SIGTERM and wait when stopped or dropped.
pub struct Running(Child);

impl Running {
    pub fn start(config: &Path) -> Running {
        Running(
            Command::new(env!("CARGO_BIN_EXE_restage-appliance"))
                .args(["run", "--config"])
                .arg(config)
                .env("RESTAGE_LOG", "warn")
                .spawn()
                .expect("the appliance starts"),
        )
    }

    pub fn stop(&mut self) {
        let _ = Command::new("kill").arg("-TERM").arg(self.0.id().to_string()).status();
        let _ = self.0.wait();
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.stop();
    }
}
