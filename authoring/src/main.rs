//! `restage-author`: the command line over the authoring library.

// Arguments' doc comments are clap's help text for a terminal, where `<k>` is a placeholder.
#![allow(rustdoc::invalid_html_tags)]

mod cli;
mod gui;
mod logging;
mod steps;

use anyhow::Result;
use clap::{CommandFactory, Parser, Subcommand};

#[derive(Parser)]
#[command(name = "restage-author", version, about = "Author restoration bundles for a restage appliance")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Acquire a capture set on real hardware: V4L2 camera, projectors as full-screen outputs.
    Capture(steps::capture::CaptureArgs),
    /// Calibrate the stage: capture set in, stage model out, with a PNG report and a PLY model.
    Calibrate(steps::calibrate::CalibrateArgs),
    /// Calibrate the rig once (projector intrinsics and poses) from captures through it: a
    /// non-planar scene or two or more poses of a flat board; `calibrate --rig` then uses it.
    Rig(steps::rig::RigArgs),
    /// Import a capture made with any camera: 8-bit images in a pattern order, per exposure time.
    Import(steps::import::ImportArgs),
    /// Decode structured light to correspondence maps (our captures or OpenCV's order).
    Decode(steps::decode::DecodeArgs),
    /// Compare a step's output with the virtual stage's ground truth (table and JSON).
    Eval(cli::eval::EvalArgs),
    /// Simulate a built-in scene on the virtual stage and write its capture set.
    Simulate(steps::simulate::Args),
    /// Run the whole chain on the virtual stage (the README's first command).
    Demo(steps::demo::Args),
    #[command(flatten)]
    Step(steps::StepCommand),
    /// Evaluate restoration on the virtual stage's built-in scenes against their pristine labels.
    EvalRestore(cli::eval_restore::EvalRestoreArgs),
    /// Make a new Ed25519 signing key (NAME.pem, NAME.pub.pem).
    Keygen(steps::keygen::KeygenArgs),
    /// Sign compensation's frames and light certificate into a bundle.
    Bundle(steps::bundle::BundleArgs),
    /// Summarise a bundle: scenes, projectors, policy, peak lux, hashes.
    Inspect(cli::inspect::InspectArgs),
    /// Verify a bundle exactly as the appliance does.
    Verify(steps::verify::VerifyArgs),
    /// The interactive tool: picks, regions, hints and parameters over a project folder.
    Gui(gui::GuiArgs),
    /// Print a shell completion script, e.g. `restage-author completions bash >
    /// ~/.local/share/bash-completion/completions/restage-author`.
    Completions {
        /// bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
    /// Write man pages (restage-author.1 and one per command) into a folder.
    Man {
        /// Folder for the pages (e.g. ~/.local/share/man/man1).
        #[arg(long, default_value = "man")]
        out: std::path::PathBuf,
        #[command(flatten)]
        overwrite: steps::Overwrite,
    },
}

fn main() -> std::process::ExitCode {
    let command = Cli::parse().command;
    logging::init();
    match run(command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            logging::print_error(&e);
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Capture(args) => cli::capture(&args),
        Command::Calibrate(args) => cli::calibrate(&args),
        Command::Rig(args) => cli::rig(&args),
        Command::Decode(args) => cli::decode(&args),
        Command::Import(args) => cli::import(&args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Simulate(args) => cli::simulate(&args),
        Command::Demo(args) => cli::demo(&args),
        Command::Step(step) => cli::step(&step),
        Command::EvalRestore(a) => cli::eval_restore::run(&a),
        Command::Keygen(a) => cli::keygen(&a),
        Command::Bundle(a) => cli::bundle(&a),
        Command::Inspect(a) => cli::inspect::run(&a),
        Command::Verify(a) => cli::verify(&a),
        Command::Gui(a) => gui::run(a),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut Cli::command(), "restage-author", &mut std::io::stdout());
            Ok(())
        }
        Command::Man { out, overwrite } => cli::man(Cli::command(), &out, overwrite.force),
    }
}
