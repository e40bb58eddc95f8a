//! The `restage-author` subcommands: argument parsing, progress, and file I/O around the
//! library's steps. One file per command.

pub mod calibrate;
pub mod compensate;
pub mod decode;
pub mod eval;

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
