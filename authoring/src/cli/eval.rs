//! `restage-author eval <step>`: compare a step's output with the virtual stage's ground truth
//! and print the figures as a table and as JSON.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use restage_authoring::eval::{self, Metric};
use restage_authoring::stage_model::StageModel;

#[derive(Args)]
pub struct EvalArgs {
    #[command(subcommand)]
    pub step: EvalStep,
    /// Also write the figures as JSON here.
    #[arg(long, global = true)]
    pub json: Option<PathBuf>,
}

#[derive(Subcommand)]
pub enum EvalStep {
    /// Calibrated geometry against the capture's ground-truth stage model.
    Geometry {
        /// Capture directory of the virtual stage (its ground-truth/stage/ is the reference).
        #[arg(long)]
        capture: PathBuf,
        /// Stage directory written by `calibrate`.
        #[arg(long)]
        stage: PathBuf,
    },
    /// Light transport, responses, vignetting, black levels, lux and gain (paper §5.2) against
    /// the capture's ground-truth stage model.
    Transport {
        /// Capture directory of the virtual stage (its ground-truth/stage/ is the reference).
        #[arg(long)]
        capture: PathBuf,
        /// Stage directory written by `calibrate` with lux readings.
        #[arg(long)]
        stage: PathBuf,
    },
}

pub fn run(args: EvalArgs) -> Result<()> {
    let metrics: Vec<Metric> = match &args.step {
        EvalStep::Geometry { capture, stage } => {
            let truth_dir = capture.join("ground-truth").join("stage");
            let truth = StageModel::load(&truth_dir)
                .with_context(|| format!("reading the ground truth in {}", truth_dir.display()))?;
            let est = StageModel::load(stage)?;
            eval::geometry::evaluate(&est, &truth)
        }
        EvalStep::Transport { capture, stage } => {
            let truth_dir = capture.join("ground-truth").join("stage");
            let truth = StageModel::load(&truth_dir)
                .with_context(|| format!("reading the ground truth in {}", truth_dir.display()))?;
            let est = StageModel::load(stage)?;
            eval::transport::evaluate(&est, &truth)
        }
    };
    print!("{}", eval::table(&metrics));
    let json = serde_json::to_string_pretty(&metrics)?;
    println!("{json}");
    if let Some(path) = &args.json {
        std::fs::write(path, &json).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
