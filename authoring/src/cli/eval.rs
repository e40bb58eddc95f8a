//! `restage-author eval <step>`: compare a step's output with the virtual stage's ground truth
//! and print the figures as a table and as JSON.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use restage_authoring::eval::{self, Metric};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::RigVariation;

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
    /// Colour classification, ours vs the k-means++ baselines, against the deteriorated labels.
    Classify {
        /// Capture directories (photo.png + ground-truth/); none = every built-in scene,
        /// simulated in memory.
        #[arg(long)]
        capture: Vec<PathBuf>,
        /// Camera size of the simulated scenes, WIDTHxHEIGHT.
        #[arg(long, default_value = "800x600")]
        camera: String,
        /// Seed of the simulated scenes and of the derived picks.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Write each case's photo, truth, preview, wrong pixels (red) and accuracies into
        /// OUT/<case>/; where another pick seed did worse, its preview and wrong pixels too
        /// (`ours_worst_*.png`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// `seeded`: the projectors' placement and lenses, the camera's focal length and the
        /// objects' form vary with the seed; `nominal`: the demo's rig at every seed.
        #[arg(long, value_enum, default_value = "seeded")]
        rig: RigVariation,
    },
    /// Contour restoration on every built-in scene against the pristine labels: ours and a
    /// mode filter (`eval-restore` adds the Telea peer and writes pictures).
    Restore {
        /// Camera size of the simulated scenes, WIDTHxHEIGHT.
        #[arg(long, default_value = "800x600")]
        camera: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// `seeded`: the projectors' placement and lenses, the camera's focal length and the
        /// objects' form vary with the seed; `nominal`: the demo's rig at every seed.
        #[arg(long, value_enum, default_value = "seeded")]
        rig: RigVariation,
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
    /// Compensation on every built-in scene and the vase on a plinth (true stage model,
    /// pristine paint as the target): CIEDE2000 of the true visitor view, the true peak
    /// irradiance over the whole lit surface against E_bound (the peak at camera pixels as
    /// information), the m trade-off.
    Compensate {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long = "ebound-lux", default_value_t = 150.0)]
        ebound_lux: f64,
        #[arg(long, default_value = "8")]
        m: restage_authoring::compensate::Exponent,
        #[arg(long, default_value_t = 0.05)]
        margin: f64,
        /// Rounds of footprint-aware refinement reported beside the formula (0: the formula
        /// alone).
        #[arg(long, default_value_t = restage_authoring::compensate::footprint::DEFAULT_ROUNDS)]
        footprint_rounds: u32,
        /// Fraction of object points that may be dimmed on their own (as `compensate`'s).
        #[arg(long, default_value_t = restage_authoring::compensate::DEFAULT_CLIP_FRACTION)]
        clip_fraction: f64,
        /// When the model may choose a larger clip fraction (as `compensate --auto-clip`).
        #[arg(long, value_enum, default_value_t = restage_authoring::compensate::AutoClip::Lifted,
              num_args = 0..=1, require_equals = true, default_missing_value = "always")]
        auto_clip: restage_authoring::compensate::AutoClip,
        /// Instead of the built-in scenes: a simulated capture, compensated with its true
        /// model and with `--stage` (what `calibrate` made of it), side by side.
        #[arg(long, requires = "stage")]
        capture: Option<PathBuf>,
        /// The stage `calibrate` wrote for `--capture`.
        #[arg(long, requires = "capture")]
        stage: Option<PathBuf>,
        /// `seeded`: the projectors' placement and lenses, the camera's focal length and the
        /// objects' form vary with the seed; `nominal`: the demo's rig at every seed.
        #[arg(long, value_enum, default_value = "seeded")]
        rig: RigVariation,
    },
}

pub fn run(args: EvalArgs) -> Result<()> {
    let metrics: Vec<Metric> = match &args.step {
        EvalStep::Geometry { capture, stage } => {
            let truth_dir = capture.join("ground-truth").join("stage");
            let truth = StageModel::load(&truth_dir)
                .with_context(|| format!("reading the ground truth in {}", truth_dir.display()))?;
            let est = StageModel::load(stage)?;
            let mut m = eval::geometry::evaluate(&est, &truth);
            let albedo_path = capture.join("ground-truth").join("albedo_deteriorated.png");
            if albedo_path.exists() {
                let albedo = restage_authoring::imgio::LinearImage::load(&albedo_path)
                    .with_context(|| format!("reading {}", albedo_path.display()))?;
                m.extend(eval::geometry::decoded_by_paint(&est, &truth, &albedo.data));
            }
            m
        }
        EvalStep::Classify { capture, camera, seed, out, rig } => {
            eval_classify(capture, camera, *seed, *rig, out.as_deref())?
        }
        EvalStep::Restore { camera, seed, rig } => {
            let (w, h) = camera
                .split_once('x')
                .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
                .with_context(|| format!("--camera {camera}: expected WIDTHxHEIGHT, e.g. 800x600"))?;
            eval::restore::evaluate_builtin(
                [w, h],
                *seed,
                *rig,
                &restage_authoring::restore::RestoreParams::default(),
            )?
        }
        EvalStep::Transport { capture, stage } => {
            let truth_dir = capture.join("ground-truth").join("stage");
            let truth = StageModel::load(&truth_dir)
                .with_context(|| format!("reading the ground truth in {}", truth_dir.display()))?;
            let est = StageModel::load(stage)?;
            eval::transport::evaluate(&est, &truth)
        }
        EvalStep::Compensate {
            seed,
            ebound_lux,
            m,
            margin,
            footprint_rounds,
            clip_fraction,
            auto_clip,
            rig,
            capture,
            stage,
        } => {
            let params = restage_authoring::compensate::Params {
                footprint_rounds: *footprint_rounds,
                clip_fraction: *clip_fraction,
                auto_clip: *auto_clip,
                ..restage_authoring::compensate::Params::new(*ebound_lux, *m, *margin)?
            };
            params.validate()?;
            match (capture, stage) {
                (Some(capture), Some(stage)) => {
                    let model = StageModel::load(stage)?;
                    eval::compensate::evaluate_capture(capture, &model, &params).with_context(|| {
                        format!("evaluating {} against {}", stage.display(), capture.display())
                    })?
                }
                _ => eval::compensate::evaluate_builtin(*seed, *rig, &params)?,
            }
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

fn eval_classify(
    captures: &[PathBuf],
    camera: &str,
    seed: u64,
    rig: RigVariation,
    out: Option<&std::path::Path>,
) -> Result<Vec<Metric>> {
    use restage_authoring::eval::classify as ec;
    use restage_authoring::stage_sim::SceneName;
    let mut cases = Vec::new();
    if captures.is_empty() {
        let (w, h) = camera
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
            .with_context(|| format!("--camera {camera}: expected WIDTHxHEIGHT, e.g. 800x600"))?;
        for scene in SceneName::ALL {
            tracing::info!("simulating the {} photo", scene.name());
            cases.push(ec::scene_case(scene, [w, h], seed, rig)?);
        }
    } else {
        for c in captures {
            cases.push(ec::capture_case(c).with_context(|| format!("reading capture {}", c.display()))?);
        }
    }
    let mut metrics = Vec::new();
    for case in &cases {
        let e = ec::evaluate_photo(
            &case.label,
            &case.photo,
            &case.truth,
            &case.names,
            &case.display,
            &case.loss,
            seed,
        )
        .with_context(|| format!("classifying {}", case.label))?;
        if let Some(dir) = out {
            ec::save_case(&dir.join(&case.label), case, &e)?;
        }
        metrics.extend(ec::metrics(&e));
    }
    Ok(metrics)
}
