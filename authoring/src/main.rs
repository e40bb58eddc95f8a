//! `restage-author`: the command line over the authoring library.

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "restage-author", version, about = "Author restoration bundles for a restage appliance")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrate the stage: capture set in, stage model out, with a PNG report and a PLY model.
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Decode structured light to correspondence maps (our captures or OpenCV's order).
    Decode(cli::decode::DecodeArgs),
    /// Compare a step's output with the virtual stage's ground truth (table and JSON).
    Eval(cli::eval::EvalArgs),
    /// One frame per projector for a restored image, under the light bound (paper §5.1).
    Compensate(cli::compensate::Args),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Calibrate(args) => cli::calibrate::run(args),
        Command::Decode(args) => cli::decode::run(args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Compensate(a) => cli::compensate::run(a),
    }
}
