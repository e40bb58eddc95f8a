//! `restage-author`: the command line over the authoring library.

mod cli;
mod gui;

use anyhow::{Result, anyhow};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "restage-author", version, about = "Author restoration bundles for a restage appliance")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Acquire a capture set on real hardware: V4L2 camera, projectors as full-screen outputs.
    Capture(cli::capture::CaptureArgs),
    /// Calibrate the stage: capture set in, stage model out, with a PNG report and a PLY model.
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Decode structured light to correspondence maps (our captures or OpenCV's order).
    Decode(cli::decode::DecodeArgs),
    /// Compare a step's output with the virtual stage's ground truth (table and JSON).
    Eval(cli::eval::EvalArgs),
    /// Simulate a built-in scene on the virtual stage and write its capture set.
    Simulate(cli::simulate::Args),
    /// Run the whole chain on the virtual stage (the README's first command).
    Demo(cli::demo::Args),
    /// Render what the camera sees when the projectors show given frames (true physics).
    Render(cli::render::Args),
    /// Classify a photo's pixels into the picked paint colours (paper §4.1).
    Classify(cli::classify::ClassifyArgs),
    /// Evaluate restoration on the virtual stage's built-in scenes against their pristine labels.
    EvalRestore(cli::eval_restore::EvalRestoreArgs),
    /// Restore a classified label map by contour energy minimisation (paper §4.2-4.4).
    Restore(cli::restore::RestoreArgs),
    /// One frame per projector for a restored image, under the light bound (paper §5.1).
    Compensate(cli::compensate::Args),
    /// A virtually re-lit variant of a restored image, with optional material noise (§5.3).
    Relight(cli::relight::Args),
    /// Make a new Ed25519 signing key (NAME.pem, NAME.pub.pem).
    Keygen(cli::keygen::KeygenArgs),
    /// Sign compensation's frames and light certificate into a bundle.
    Bundle(cli::bundle::BundleArgs),
    /// Summarise a bundle: scenes, projectors, policy, peak lux, hashes.
    Inspect(cli::inspect::InspectArgs),
    /// Verify a bundle exactly as the appliance does.
    Verify(cli::verify::VerifyArgs),
    /// The interactive tool: picks, regions, hints and parameters over a project folder.
    Gui(gui::GuiArgs),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    dispatch(Cli::parse().command)
}

/// Parses one command line (without the program's name) exactly as the program would.
fn parse_line(args: &[String]) -> Result<Command> {
    let argv = std::iter::once("restage-author".to_string()).chain(args.iter().cloned());
    Cli::try_parse_from(argv).map(|c| c.command).map_err(|e| anyhow!("{}: {e}", args.join(" ")))
}

fn dispatch(command: Command) -> Result<()> {
    match command {
        Command::Capture(args) => cli::capture::run(&args),
        Command::Calibrate(args) => cli::calibrate::run(args),
        Command::Decode(args) => cli::decode::run(args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Simulate(args) => cli::simulate::run(&args),
        Command::Demo(args) => cli::demo::run(&args),
        Command::Render(args) => cli::render::run(&args),
        Command::Classify(args) => cli::classify::run(&args),
        Command::Restore(a) => cli::restore::run(&a),
        Command::EvalRestore(a) => cli::eval_restore::run(&a),
        Command::Compensate(a) => cli::compensate::run(a),
        Command::Relight(a) => cli::relight::run(a),
        Command::Keygen(a) => cli::keygen::run(&a),
        Command::Bundle(a) => cli::bundle::run(&a),
        Command::Inspect(a) => cli::inspect::run(&a),
        Command::Verify(a) => cli::verify::run(&a),
        Command::Gui(a) => gui::run(a),
    }
}
