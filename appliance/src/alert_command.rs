//! Runs the operators' alert command (`[alerts] command`) for each alert raised or cleared:
//! on the tokio runtime beside the event loop, killed after a timeout, at most a few at once.

use std::process::{ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt};

use crate::alerts::{self, Alert, AlertState, Changes};
use crate::config::AlertsConfig;

/// Commands running at once; alerts beyond are logged only.
pub const MAX_IN_FLIGHT: usize = 4;
/// Bytes of the command's stdout and of its stderr kept for the log; the rest is read and
/// thrown away (a chatty command neither fills memory nor blocks on its pipe).
pub const OUTPUT_CAP: usize = 4096;

/// How one run ended.
#[derive(Debug)]
pub enum Outcome {
    /// It exited (`status`), having written `output` (stdout then stderr, capped).
    Exited { status: ExitStatus, output: String },
    /// Still running at the timeout: its process group was killed (and reaped).
    TimedOut { pid: Option<u32> },
    /// It could not be started (missing, not executable).
    SpawnFailed(String),
    /// Waiting for it failed.
    WaitFailed(String),
}

/// The configured command.
#[derive(Clone, Debug)]
pub struct AlertCommand {
    argv: Arc<[String]>,
    timeout: Duration,
    max_in_flight: usize,
    in_flight: Arc<AtomicUsize>,
}

impl AlertCommand {
    /// `argv[0]` is the program (no shell); `None` when `argv` is empty.
    pub fn new(argv: Vec<String>, timeout: Duration) -> Option<AlertCommand> {
        (!argv.is_empty()).then(|| AlertCommand {
            argv: argv.into(),
            timeout,
            max_in_flight: MAX_IN_FLIGHT,
            in_flight: Arc::new(AtomicUsize::new(0)),
        })
    }

    /// The command of `[alerts]`, if one is set.
    pub fn from_config(c: &AlertsConfig) -> Option<AlertCommand> {
        Self::new(c.command.clone()?, Duration::from_millis(c.command_timeout_ms))
    }

    /// At most `n` at once (default `MAX_IN_FLIGHT`).
    pub fn with_max_in_flight(mut self, n: usize) -> AlertCommand {
        self.max_in_flight = n;
        self
    }

    /// Commands running now.
    pub fn in_flight(&self) -> usize {
        self.in_flight.load(Ordering::SeqCst)
    }

    /// Starts the command for `alert` on the current tokio runtime and returns at once; the
    /// outcome is logged (and returned through the handle). `None`: too many running, dropped.
    pub fn notify(&self, alert: &Alert, state: AlertState) -> Option<tokio::task::JoinHandle<Outcome>> {
        // Reserve a slot first, so no more than the maximum ever start.
        let taken = self
            .in_flight
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| (n < self.max_in_flight).then_some(n + 1));
        if taken.is_err() {
            tracing::warn!(key = %alert.key, state = state.as_str(), "alert command not run: {} still running", self.max_in_flight);
            return None;
        }
        let slot = Slot(self.in_flight.clone());
        let env = vec![
            ("RESTAGE_ALERT_LEVEL", alert.level.as_str().to_string()),
            ("RESTAGE_ALERT_KIND", alert.kind.as_str().to_string()),
            ("RESTAGE_ALERT_MESSAGE", alert.message.clone()),
            ("RESTAGE_ALERT_STATE", state.as_str().to_string()),
            ("RESTAGE_ALERT_KEY", alert.key.clone()),
        ];
        let (argv, timeout, key) = (self.argv.clone(), self.timeout, alert.key.clone());
        Some(tokio::spawn(async move {
            let _slot = slot;
            let outcome = run(&argv, &env, timeout).await;
            log_outcome(&argv[0], &key, state, &outcome);
            outcome
        }))
    }
}

/// Gives its in-flight slot back when the run ends, however it ends.
struct Slot(Arc<AtomicUsize>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Logs every change (`alerts::log`) and runs `command`, if any, for each.
pub fn dispatch(changes: &Changes, command: Option<&AlertCommand>) {
    for (alert, state) in changes.iter() {
        alerts::log(alert, state);
        if let Some(c) = command {
            c.notify(alert, state);
        }
    }
}

/// Runs `argv` with `env` added, stdin from /dev/null, in its own process group; waits at
/// most `timeout` for it to exit and close its output, then kills the group.
pub async fn run(argv: &[String], env: &[(&str, String)], timeout: Duration) -> Outcome {
    let Some((program, args)) = argv.split_first() else {
        return Outcome::SpawnFailed("no program".into());
    };
    let mut cmd = tokio::process::Command::new(program);
    cmd.args(args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        // Its own group: the timeout kills whatever it started too.
        .process_group(0)
        .kill_on_drop(true);
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => return Outcome::SpawnFailed(format!("{program}: {e}")),
    };
    let pid = child.id();
    let (stdout, stderr) = (child.stdout.take(), child.stderr.take());
    let finished = async {
        let (status, out, err) = tokio::join!(child.wait(), read_capped(stdout), read_capped(stderr));
        (status, [out, err].concat())
    };
    match tokio::time::timeout(timeout, finished).await {
        Ok((Ok(status), output)) => {
            Outcome::Exited { status, output: String::from_utf8_lossy(&output).into() }
        }
        Ok((Err(e), _)) => Outcome::WaitFailed(e.to_string()),
        Err(_) => {
            if let Some(pid) = pid.and_then(|p| i32::try_from(p).ok()) {
                let _ = nix::sys::signal::killpg(nix::unistd::Pid::from_raw(pid), nix::sys::signal::SIGKILL);
            }
            // Kills the child (if the group kill missed it) and reaps it.
            let _ = child.kill().await;
            Outcome::TimedOut { pid }
        }
    }
}

async fn read_capped(pipe: Option<impl AsyncRead + Unpin>) -> Vec<u8> {
    let mut kept = Vec::new();
    let Some(mut pipe) = pipe else { return kept };
    let mut buf = [0u8; 1024];
    while let Ok(n) = pipe.read(&mut buf).await {
        if n == 0 {
            break;
        }
        let room = OUTPUT_CAP.saturating_sub(kept.len());
        kept.extend_from_slice(&buf[..n.min(room)]);
    }
    kept
}

fn log_outcome(program: &str, key: &str, state: AlertState, outcome: &Outcome) {
    let state = state.as_str();
    match outcome {
        Outcome::Exited { status, output } => {
            let output = output.trim();
            if status.success() {
                tracing::info!(program, key, state, %status, output, "alert command done");
            } else {
                tracing::warn!(program, key, state, %status, output, "alert command failed");
            }
        }
        Outcome::TimedOut { .. } => tracing::warn!(program, key, state, "alert command timed out; killed"),
        Outcome::SpawnFailed(e) | Outcome::WaitFailed(e) => {
            tracing::warn!(program, key, state, "alert command could not run: {e}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alerts::{Kind, Level};

    fn alert() -> Alert {
        Alert {
            level: Level::Critical,
            kind: Kind::Projector,
            key: "projector:DP-1".into(),
            message: "projector DP-1: gone".into(),
            since_ms: 5,
        }
    }

    fn sh(script: &str) -> Vec<String> {
        vec!["/bin/sh".into(), "-c".into(), script.into()]
    }

    #[tokio::test]
    async fn the_command_hears_the_alert_in_its_environment() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("heard");
        let script = format!(
            "echo \"$RESTAGE_ALERT_LEVEL $RESTAGE_ALERT_KIND $RESTAGE_ALERT_STATE $RESTAGE_ALERT_MESSAGE\" > '{}'; echo said",
            file.display()
        );
        let cmd = AlertCommand::new(sh(&script), Duration::from_secs(10)).unwrap();
        let outcome = cmd.notify(&alert(), AlertState::Cleared).unwrap().await.unwrap();
        match outcome {
            Outcome::Exited { status, output } => {
                assert!(status.success() && output == "said\n", "{output:?}")
            }
            o => panic!("{o:?}"),
        }
        let heard = std::fs::read_to_string(&file).unwrap();
        assert_eq!(heard, "critical projector cleared projector DP-1: gone\n");
        assert_eq!(cmd.in_flight(), 0);
    }

    #[tokio::test]
    async fn a_hanging_command_is_killed_at_the_timeout() {
        let start = std::time::Instant::now();
        let argv = vec!["sleep".to_string(), "100".to_string()];
        let outcome = run(&argv, &[], Duration::from_millis(300)).await;
        let Outcome::TimedOut { pid: Some(pid) } = outcome else { panic!("{outcome:?}") };
        assert!(start.elapsed() < Duration::from_secs(5), "{:?}", start.elapsed());
        // Killed and reaped: no such process any more.
        assert!(!std::path::Path::new(&format!("/proc/{pid}")).exists(), "sleep {pid} still there");
    }

    #[tokio::test]
    async fn a_command_left_running_by_a_shell_is_killed_with_its_group() {
        let dir = tempfile::tempdir().unwrap();
        let pidfile = dir.path().join("pid");
        let script = format!("sleep 100 & echo $! > '{}'; wait", pidfile.display());
        let outcome = run(&sh(&script), &[], Duration::from_millis(500)).await;
        assert!(matches!(outcome, Outcome::TimedOut { .. }), "{outcome:?}");
        let pid = std::fs::read_to_string(&pidfile).unwrap().trim().to_string();
        // The grandchild got SIGKILL; it is gone or a zombie waiting for init.
        let mut gone = false;
        for _ in 0..50 {
            match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
                Err(_) => gone = true,
                Ok(stat) => gone = stat.rsplit(')').next().is_some_and(|s| s.trim_start().starts_with('Z')),
            }
            if gone {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(gone, "sleep {pid} survived");
    }

    #[tokio::test]
    async fn no_more_than_the_maximum_in_flight() {
        let cmd =
            AlertCommand::new(sh("sleep 100"), Duration::from_millis(400)).unwrap().with_max_in_flight(2);
        let a = cmd.notify(&alert(), AlertState::Raised).unwrap();
        let b = cmd.notify(&alert(), AlertState::Raised).unwrap();
        assert!(cmd.notify(&alert(), AlertState::Raised).is_none(), "a third one started");
        assert_eq!(cmd.in_flight(), 2);
        assert!(matches!(a.await.unwrap(), Outcome::TimedOut { .. }));
        assert!(matches!(b.await.unwrap(), Outcome::TimedOut { .. }));
        assert_eq!(cmd.in_flight(), 0);
        assert!(cmd.notify(&alert(), AlertState::Cleared).is_some());
    }

    #[tokio::test]
    async fn a_missing_program_is_reported_not_fatal() {
        let argv = vec!["/nonexistent/notify".to_string()];
        let outcome = run(&argv, &[], Duration::from_secs(1)).await;
        assert!(
            matches!(outcome, Outcome::SpawnFailed(ref e) if e.contains("/nonexistent/notify")),
            "{outcome:?}"
        );
    }
}
