//! The `restage-author` subcommands: argument parsing, progress, and file I/O around the
//! library's steps. One file per command.

pub mod bundle;
pub mod classify;
pub mod compensate;
pub mod demo;
pub mod eval_restore;
pub mod inspect;
pub mod keygen;
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
