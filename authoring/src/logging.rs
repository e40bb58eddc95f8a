//! What `restage-author` writes to the terminal besides results: log lines (plain, no
//! timestamps, colour only on a terminal), an optional full log file, and errors as one
//! `error:` line with each cause once.
//!
//! `RUST_LOG` set: the terminal shows what it asks for, as a developer expects. Otherwise the
//! terminal shows info and above, or in quiet mode (the demo) errors only, with warnings
//! counted for one summary line; the log file, once opened, gets everything at info and above
//! with timestamps and module paths.

use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use tracing::Level;
use tracing_subscriber::Layer;
use tracing_subscriber::filter::{EnvFilter, filter_fn};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

static QUIET: AtomicBool = AtomicBool::new(false);
static WARNINGS: AtomicUsize = AtomicUsize::new(0);
static FILE: Mutex<Option<std::fs::File>> = Mutex::new(None);

/// Writes to the log file when one is open, else nowhere.
struct FileSink;

impl Write for FileSink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match FILE.lock() {
            Ok(mut f) => match f.as_mut() {
                Some(f) => f.write(buf),
                None => Ok(buf.len()),
            },
            Err(_) => Ok(buf.len()),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match FILE.lock() {
            Ok(mut f) => f.as_mut().map_or(Ok(()), |f| f.flush()),
            Err(_) => Ok(()),
        }
    }
}

/// Whether the terminal may get colour: stderr is a terminal and `NO_COLOR` is not set.
fn colour() -> bool {
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none()
}

/// Installs the logger; call once, after parsing the arguments.
pub fn init() {
    let env = std::env::var("RUST_LOG").ok().filter(|v| !v.is_empty());
    let terminal = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(colour())
        .without_time()
        .with_target(env.is_some());
    let terminal = match env {
        Some(filter) => terminal.with_filter(EnvFilter::new(filter)).boxed(),
        None => terminal
            .with_filter(filter_fn(|m| {
                let level = *m.level();
                if level == Level::WARN {
                    WARNINGS.fetch_add(1, Ordering::Relaxed);
                }
                if QUIET.load(Ordering::Relaxed) { level == Level::ERROR } else { level <= Level::INFO }
            }))
            .boxed(),
    };
    let file = tracing_subscriber::fmt::layer()
        .with_writer(|| FileSink)
        .with_ansi(false)
        .with_filter(filter_fn(|m| *m.level() <= Level::INFO));
    let _ = tracing_subscriber::registry().with(terminal).with(file).try_init();
}

/// From now on the terminal shows errors only and counts warnings ([`warnings`]); detail goes
/// to the log file.
pub fn quiet() {
    QUIET.store(true, Ordering::Relaxed);
}

/// Warnings logged since the start (counted when `RUST_LOG` is not set).
pub fn warnings() -> usize {
    WARNINGS.load(Ordering::Relaxed)
}

/// Sends every log line from now on also to `path` (created or replaced).
pub fn log_to_file(path: &Path) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    if let Ok(mut f) = FILE.lock() {
        *f = Some(file);
    }
    Ok(())
}

/// Prints an error as one `error:` line and each cause once: a cause whose text an earlier
/// line already holds (a context that quoted its source) is left out. No backtrace: errors
/// here are the user's to fix; a bug panics, and a panic keeps its backtrace.
pub fn print_error(e: &anyhow::Error) {
    let lines = error_lines(e);
    let mut err = std::io::stderr().lock();
    let label = if colour() { "\x1b[1;31merror:\x1b[0m" } else { "error:" };
    let _ = writeln!(err, "{label} {}", lines.first().map_or("", String::as_str));
    for l in lines.iter().skip(1) {
        let _ = writeln!(err, "  because: {l}");
    }
}

/// The error's own text and each cause not already quoted by an earlier one.
fn error_lines(e: &anyhow::Error) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !lines.iter().any(|l| l.contains(&text)) {
            lines.push(text);
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    #[test]
    fn causes_are_printed_once() {
        let inner = std::io::Error::other("disk full");
        let e =
            anyhow::Error::new(inner).context("writing out/x.png: disk full").context("saving the frames");
        assert_eq!(super::error_lines(&e), ["saving the frames", "writing out/x.png: disk full"]);
    }
}
