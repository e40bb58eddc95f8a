//! `restage-appliance`: the stage machine's program.

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "restage-appliance", version, about = "Play a signed restage bundle on the stage")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {}

// The allow goes when the first subcommand lands (an empty enum makes main unreachable).
#[allow(unreachable_code)]
fn main() -> Result<()> {
    match Cli::parse().command {}
}
