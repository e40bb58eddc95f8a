//! The `restage-author` subcommands: argument parsing, progress, and file I/O around the
//! library's steps. One file per command.

pub mod compensate;
pub mod demo;
pub mod render;
pub mod simulate;
