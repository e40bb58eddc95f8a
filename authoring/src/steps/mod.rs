//! The pipeline's steps, one typed function per step, called by both the command line
//! (`cli`) and the window (`gui`): files and parameters in, typed outputs and a typed summary
//! out, progress through [`Progress`]. The steps call the library; `cli` parses arguments
//! and prints, `gui` draws, and neither knows the other.
//!
//! A step's parameters derive `clap::Args`: their command-line form belongs to the step, since
//! the window writes its projects' steps as command lines (`steps.sh`) and runs exactly those
//! ([`StepCommand`]).

pub mod bundle;
pub mod calibrate;
pub mod capture;
pub mod classify;
pub mod compensate;
pub mod decode;
pub mod demo;
pub mod demo_chain;
pub mod import;
pub mod keygen;
pub mod mask;
pub mod relight;
pub mod render;
pub mod report;
pub mod restore;
pub mod rig;
pub mod simulate;
pub mod verify;

use anyhow::{Result, anyhow};
use clap::{Parser, Subcommand};

/// Where a step reports what it is doing: a terminal progress bar, the window, or nothing.
/// Shared across the step's worker threads.
pub trait Progress: Sync {
    /// The step starts a stage of its work.
    fn stage(&self, what: &str);
    /// `done` of the current stage's `total` units are finished.
    fn count(&self, done: u64, total: u64);
}

/// Shows nothing (the window's worker thread, tests).
pub struct Quiet;

impl Progress for Quiet {
    fn stage(&self, _: &str) {}
    fn count(&self, _: u64, _: u64) {}
}

/// `--force`, shared by every step that writes: without it a step refuses to write over
/// what is already there ([`check_out`]).
#[derive(clap::Args, Debug, Clone, Copy, Default)]
pub struct Overwrite {
    /// Replace outputs that already exist (otherwise the step refuses to write over them).
    #[arg(long)]
    pub force: bool,
}

/// Refuses to write at `out` when something is already there, unless `force`: a step never
/// replaces files silently. A folder may exist if it is empty. With `force` a step replaces
/// only the files it writes and deletes nothing.
pub fn check_out(out: &std::path::Path, force: bool) -> Result<()> {
    use anyhow::{Context, bail};
    if force {
        return Ok(());
    }
    match std::fs::metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e).with_context(|| format!("cannot look at {}", out.display())),
        Ok(m) if m.is_dir() => {
            let empty = std::fs::read_dir(out)
                .with_context(|| format!("cannot read folder {}", out.display()))?
                .next()
                .is_none();
            if empty {
                Ok(())
            } else {
                bail!(
                    "{} already holds files; choose a new or empty folder, or pass --force to replace \
                     this step's outputs there (nothing else is deleted)",
                    out.display()
                )
            }
        }
        Ok(_) => {
            bail!("{} already exists; choose another name, or pass --force to replace it", out.display())
        }
    }
}

/// The one time taken at the start of a step (Unix seconds).
pub fn now_unix_s() -> Result<i64> {
    use anyhow::Context;
    Ok(std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs() as i64)
}

/// The steps a project runs from command lines (the window, and `steps.sh` by the same lines).
#[derive(Subcommand, Debug)]
pub enum StepCommand {
    /// Render what the camera sees when the projectors show given frames (true physics).
    Render(render::Args),
    /// The object mask: proposed from the stage model's geometry (supports such as a plinth
    /// or a wall removed), or the conservator's outline.
    Mask(mask::MaskArgs),
    /// Classify a photo's pixels into the picked paint colours (paper §4.1).
    Classify(classify::ClassifyArgs),
    /// Restore a classified label map by contour energy minimisation (paper §4.2-4.4).
    Restore(restore::RestoreArgs),
    /// One frame per projector for a restored image, under the light bound (paper §5.1).
    Compensate(compensate::Args),
    /// A virtually re-lit variant of a restored image, with optional material noise (§5.3).
    Relight(relight::Args),
}

/// What one [`StepCommand`] did, for a summary line.
#[derive(Debug)]
pub enum StepSummary {
    Render(render::RenderSummary),
    Mask(mask::MaskStepSummary),
    Classify(classify::ClassifySummary),
    Restore(restore::RestoreSummary),
    Compensate(compensate::CompensateSummary),
    Relight(relight::RelightSummary),
}

impl std::fmt::Display for StepSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StepSummary::Render(s) => s.fmt(f),
            StepSummary::Mask(s) => s.fmt(f),
            StepSummary::Classify(s) => s.fmt(f),
            StepSummary::Restore(s) => s.fmt(f),
            StepSummary::Compensate(s) => s.fmt(f),
            StepSummary::Relight(s) => s.fmt(f),
        }
    }
}

impl StepCommand {
    /// Runs the step.
    pub fn run(&self, progress: &dyn Progress) -> Result<StepSummary> {
        Ok(match self {
            StepCommand::Render(a) => StepSummary::Render(render::run(a, progress)?),
            StepCommand::Mask(a) => StepSummary::Mask(mask::run(a, progress)?),
            StepCommand::Classify(a) => StepSummary::Classify(classify::run(a, progress)?),
            StepCommand::Restore(a) => StepSummary::Restore(restore::run(a, progress)?),
            StepCommand::Compensate(a) => StepSummary::Compensate(compensate::run(a, progress)?),
            StepCommand::Relight(a) => StepSummary::Relight(relight::run(a, progress)?),
        })
    }
}

#[derive(Parser)]
#[command(name = "restage-author")]
struct StepLine {
    #[command(subcommand)]
    step: StepCommand,
}

/// Parses one step's command line (without the program's name), as `restage-author` would.
pub fn parse_line(args: &[String]) -> Result<StepCommand> {
    let argv = std::iter::once("restage-author".to_string()).chain(args.iter().cloned());
    StepLine::try_parse_from(argv).map(|c| c.step).map_err(|e| anyhow!("{}: {e}", args.join(" ")))
}
