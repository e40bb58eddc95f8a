//! The compensate step (`restage-author compensate STAGE_DIR RESTORED --ebound-lux L --m 8 --margin 0.05 --out DIR`:
//! one frame per projector for a restored image, under the light bound, with a report.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use restage_authoring::compensate::{self, Exponent, Params, Prepared};
use restage_authoring::gpu::Device;
use restage_authoring::imgio::LinearImage;
use restage_authoring::stage_model::StageModel;

use super::Progress;

#[derive(ClapArgs, Debug)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct Args {
    /// Stage model folder (holds stage.bin).
    pub stage_dir: PathBuf,
    /// The restored image in camera space: a PNG, or a folder holding restored.png.
    pub restored: PathBuf,
    /// Maximum irradiance per unit area, lux.
    #[arg(long = "ebound-lux")]
    pub ebound_lux: f64,
    /// Smoothness exponent m of Eq. 12 (>= 0, or "inf").
    #[arg(long, default_value = "8")]
    pub m: Exponent,
    /// Safety margin: frames stay at or below E_bound * (1 - meter accuracy) * (1 - margin).
    #[arg(long, default_value_t = 0.05)]
    pub margin: f64,
    /// Relative accuracy of the lux meter that calibrated the stage (a fraction, 0 <= u < 0.5):
    /// a meter reading low by u leaves every modelled lux low by (1 - u), so the bound is
    /// lowered by that factor. The default is a class-B meter (DIN 5032-7), about 10 %.
    #[arg(long, default_value_t = compensate::DEFAULT_METER_ACCURACY)]
    pub meter_accuracy: f64,
    /// Fraction of object points that may be dimmed locally rather than darkening everything.
    #[arg(long, default_value_t = compensate::DEFAULT_CLIP_FRACTION)]
    pub clip_fraction: f64,
    /// When the stage model may choose a larger clip fraction (1, 2 or 5 %, never below
    /// --clip-fraction), keeping the one whose modelled view is closest to the target: at a low
    /// bound the black level lifts a dim object, and a brighter one with more points dimmed on
    /// their own looks more like the target. `lifted`: only where more than 5 % of the lit
    /// points ask for less light than the black level gives; `always` (also a bare
    /// `--auto-clip`); `off`: the asked fraction whatever the view. A value takes `=`
    /// (`--auto-clip=off`), so that a bare `--auto-clip` never swallows the next argument.
    #[arg(long, value_enum, default_value_t = compensate::AutoClip::Lifted, num_args = 0..=1,
          require_equals = true, default_missing_value = "always")]
    pub auto_clip: compensate::AutoClip,
    /// Camera pixels per light-certificate point along each axis.
    #[arg(long, default_value_t = 2)]
    pub reduction: u32,
    /// Rounds of footprint-aware refinement: the frames are corrected so that the blurred,
    /// overlapping light the transport step measured matches the target (0: the paper's
    /// per-pixel formula alone). Used only when the stage model has measured footprints.
    #[arg(long, default_value_t = compensate::footprint::DEFAULT_ROUNDS)]
    pub footprint_rounds: u32,
    /// Where the per-pixel work runs (auto: a hardware GPU if there is one, else the CPU;
    /// gpu: any adapter, lavapipe included). The light guarantee always runs on the CPU.
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    pub device: Device,
    /// Object mask (the mask step's `object_mask.png`, camera size, non-zero = object):
    /// points outside are not lit (projector pixels that reach only them stay dark).
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Output folder for the frames, the certificate and the report.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
}

/// Resolves RESTORED: a file, or `restored.png` inside a folder.
pub fn restored_path(p: &Path) -> PathBuf {
    if p.is_dir() { p.join("restored.png") } else { p.to_path_buf() }
}

/// What one compensation run did: its figures and where it wrote them.
#[derive(Debug)]
pub struct CompensateSummary {
    pub stats: compensate::Stats,
    pub projectors: usize,
    pub out: PathBuf,
}

impl std::fmt::Display for CompensateSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.stats;
        write!(
            f,
            "{} frames in {}: peak {:.2} lx (limit {:.2} lx: E_bound {} lx less the lux meter's \
             accuracy and the margin), scale {:.4}, \
             limited by bound {:.2} % / saturation {:.2} % of {} points; object {}; report: {}",
            self.projectors,
            self.out.display(),
            s.peak_lux,
            s.limit_lux,
            s.e_bound_lux,
            s.scale,
            100.0 * s.limited_by_bound as f64 / s.covered_points as f64,
            100.0 * s.limited_by_saturation as f64 / s.covered_points as f64,
            s.covered_points,
            s.unlit,
            self.out.join("report/index.html").display()
        )
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &Args, progress: &dyn Progress) -> Result<CompensateSummary> {
    let params = params(args)?;
    if let Some(w) = cie157_warning(params.e_bound_lux) {
        tracing::warn!("{w}");
    }
    super::check_out(&args.out, args.overwrite.force)?;
    progress.stage("loading the stage model");
    let stage = StageModel::load(&args.stage_dir)
        .with_context(|| format!("loading the stage model from {}", args.stage_dir.display()))?;
    progress.stage("preparing geometry and the light certificate");
    let prep = Prepared::new(&stage, params.reduction).context("preparing the stage model")?;
    progress.stage("computing frames and enforcing the light bound");
    run_prepared(args, &stage, &prep)
}

/// A bound above what CIE 157:2004 recommends for any light-sensitive object deserves a word:
/// a typo (100000 for 100) would otherwise pass silently.
pub fn cie157_warning(e_bound_lux: f64) -> Option<String> {
    use restage_shared::policy::Sensitivity;
    let (low, _) = Sensitivity::Low.limits();
    let (medium, _) = Sensitivity::Medium.limits();
    (e_bound_lux > low).then(|| {
        format!(
            "--ebound-lux {e_bound_lux} is above CIE 157:2004's recommended limits ({low} lx for \
             objects of low sensitivity such as oil paint on canvas, {medium} lx for medium and high \
             sensitivity such as watercolour, textiles and paper); make sure the object tolerates it"
        )
    })
}

/// The parameters the arguments ask for, checked.
pub fn params(args: &Args) -> Result<Params> {
    let params = Params {
        e_bound_lux: args.ebound_lux,
        m: args.m,
        margin: args.margin,
        meter_accuracy: args.meter_accuracy,
        clip_fraction: args.clip_fraction,
        auto_clip: args.auto_clip,
        reduction: args.reduction,
        footprint_rounds: args.footprint_rounds,
    };
    params.validate()?;
    Ok(params)
}

/// The command's work on a loaded stage model and its preparation for `args.reduction`
/// (the interactive tool keeps both between runs): frames, certificate and report in `args.out`.
pub fn run_prepared(args: &Args, stage: &StageModel, prep: &Prepared) -> Result<CompensateSummary> {
    let params = params(args)?;
    let restored = restored_path(&args.restored);
    let mut target =
        LinearImage::load(&restored).with_context(|| "loading the restored image".to_string())?;
    if let Some(m) = &args.mask {
        let inside = restage_authoring::segment::load_mask(m, stage.camera.width, stage.camera.height)?;
        target = compensate::mask_target(&target, &inside)?;
    }
    let comp = compensate::compensate_on(stage, prep, &target, &params, args.device)
        .with_context(|| format!("compensating {}", restored.display()))?;
    compensate::io::save(&args.out, &comp, &params, prep)?;
    compensate::report::save(
        &args.out.join("report"),
        &comp,
        &prep.geometry,
        &params,
        stage.camera.width,
        stage.camera.height,
    )?;
    Ok(CompensateSummary { stats: comp.stats, projectors: stage.projectors.len(), out: args.out.clone() })
}

#[cfg(test)]
mod tests {
    use super::super::{StepCommand, parse_line};
    use restage_authoring::compensate::AutoClip;

    fn auto_clip(line: &str) -> anyhow::Result<(AutoClip, String)> {
        let args: Vec<String> = line.split_whitespace().map(String::from).collect();
        match parse_line(&args)? {
            StepCommand::Compensate(a) => Ok((a.auto_clip, a.stage_dir.display().to_string())),
            _ => anyhow::bail!("not a compensate line"),
        }
    }

    #[test]
    fn auto_clip_is_lifted_unless_told_and_a_bare_flag_takes_no_argument() {
        let tail = "--ebound-lux 50 --out f";
        assert_eq!(auto_clip(&format!("compensate st r.png {tail}")).unwrap().0, AutoClip::Lifted);
        // A bare flag before the positionals, as the flag was written when it took no value.
        assert_eq!(
            auto_clip(&format!("compensate --auto-clip st r.png {tail}")).unwrap(),
            (AutoClip::Always, "st".into())
        );
        assert_eq!(
            auto_clip(&format!("compensate st r.png {tail} --auto-clip")).unwrap().0,
            AutoClip::Always
        );
        for (v, want) in [("off", AutoClip::Off), ("lifted", AutoClip::Lifted), ("always", AutoClip::Always)]
        {
            assert_eq!(auto_clip(&format!("compensate st r.png --auto-clip={v} {tail}")).unwrap().0, want);
        }
        let e =
            auto_clip(&format!("compensate st r.png --auto-clip=sometimes {tail}")).unwrap_err().to_string();
        assert!(e.contains("sometimes") && e.contains("lifted"), "{e}");
    }

    /// The help a user reads names the share as a number, not as rustdoc's link to it.
    #[test]
    fn the_lifted_help_names_the_share_it_uses() {
        use clap::ValueEnum;
        let help = AutoClip::Lifted.to_possible_value().unwrap().get_help().unwrap().to_string();
        let share = format!("{} %", 100.0 * restage_authoring::compensate::LIFTED_SHARE);
        assert!(help.contains(&share) && !help.contains("[`"), "{help}");
    }
}
