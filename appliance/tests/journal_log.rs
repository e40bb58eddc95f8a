//! Under systemd (`JOURNAL_STREAM` naming stderr) every log line of the real program carries
//! an sd-daemon priority prefix and no escape codes; elsewhere, off a terminal, no escapes.

use std::os::unix::fs::MetadataExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs the appliance (headless, no bundle: it starts dark) until it says it is running,
/// stops it with SIGTERM, and returns its stderr.
fn run_appliance(journal: bool) -> String {
    let dir = tempfile::tempdir().unwrap();
    for d in ["trust", "state", "out"] {
        std::fs::create_dir(dir.path().join(d)).unwrap();
    }
    let p = dir.path().display();
    let config = dir.path().join("c.toml");
    std::fs::write(
        &config,
        format!(
            "trust_dir = \"{p}/trust\"\nstate_dir = \"{p}/state\"\n[output]\nkind = \"headless\"\ndir = \"{p}/out\"\n"
        ),
    )
    .unwrap();
    let log = dir.path().join("stderr");
    let file = std::fs::File::create(&log).unwrap();
    let meta = file.metadata().unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_restage-appliance"));
    cmd.arg("run").arg("--config").arg(&config).stdin(Stdio::null()).stdout(Stdio::null()).stderr(file);
    cmd.env_remove("NOTIFY_SOCKET").env_remove("WATCHDOG_USEC").env("RESTAGE_LOG", "info");
    if journal {
        cmd.env("JOURNAL_STREAM", format!("{}:{}", meta.dev(), meta.ino()));
    } else {
        cmd.env_remove("JOURNAL_STREAM");
    }
    let mut child = cmd.spawn().unwrap();
    let start = Instant::now();
    while !std::fs::read_to_string(&log).unwrap().contains("appliance running") {
        assert!(start.elapsed() < Duration::from_secs(30), "{}", std::fs::read_to_string(&log).unwrap());
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    nix::sys::signal::kill(pid, nix::sys::signal::SIGTERM).unwrap();
    assert!(child.wait().unwrap().success());
    std::fs::read_to_string(&log).unwrap()
}

#[test]
fn journal_lines_have_priorities() {
    let text = run_appliance(true);
    assert!(!text.contains('\x1b'), "{text}");
    for line in text.lines() {
        assert!(["<3>", "<4>", "<6>", "<7>"].iter().any(|p| line.starts_with(p)), "{line:?}\n{text}");
    }
    // Starting without a bundle is a warning; running is information.
    assert!(text.lines().any(|l| l.starts_with("<4>") && l.contains("starting dark")), "{text}");
    assert!(text.lines().any(|l| l.starts_with("<6>") && l.contains("appliance running")), "{text}");
}

#[test]
fn a_file_gets_no_escape_codes() {
    let text = run_appliance(false);
    assert!(text.contains("appliance running") && !text.contains('\x1b'), "{text}");
    assert!(!text.contains("<6>"), "{text}");
}
