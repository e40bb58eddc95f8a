//! The `restage-author` subcommands: argument parsing, progress, and file I/O around the
//! library's steps. One file per command.

pub mod bundle;
pub mod calibrate;
pub mod capture;
pub mod classify;
pub mod compensate;
pub mod decode;
pub mod demo;
pub mod demo_chain;
pub mod eval;
pub mod eval_restore;
pub mod inspect;
pub mod keygen;
pub mod relight;
pub mod render;
pub mod restore;
pub mod simulate;
pub mod verify;

/// The one time taken at the start of a command (Unix seconds).
pub fn now_unix_s() -> anyhow::Result<i64> {
    use anyhow::Context;
    Ok(std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs() as i64)
}

/// A progress bar on stderr for `len` steps of a long command.
pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}
