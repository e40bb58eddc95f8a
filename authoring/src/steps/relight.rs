//! The relight step (`restage-author relight STAGE_DIR RESTORED [--lighting L.toml] [--photo P --noise 0.3]
//! --out RELIT.png`): a virtually re-lit variant of a restored image (paper §5.3), ready to be
//! compensated as a scene of its own.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use restage_authoring::gpu::Device;
use restage_authoring::imgio::LinearImage;
use restage_authoring::relight::{self, Lighting};
use restage_authoring::stage_model::StageModel;

use super::Progress;

#[derive(ClapArgs, Debug)]
// Negative numbers are values, to be refused with a clear message rather than taken for flags.
#[command(allow_negative_numbers = true)]
pub struct Args {
    /// Stage model folder (points and normals per camera pixel).
    pub stage_dir: PathBuf,
    /// The restored image (a PNG, or a folder holding restored.png).
    pub restored: PathBuf,
    /// Lighting as TOML (`ambient`, `specular`, `shininess`, `exposure`, `[[lights]]` with
    /// `kind = "directional"`/`"point"`); a soft key light from the upper left if omitted.
    #[arg(long)]
    pub lighting: Option<PathBuf>,
    /// The diffusely lit photo whose fine material noise is infused back.
    #[arg(long)]
    pub photo: Option<PathBuf>,
    /// How much of the photo's noise to infuse (0..=1).
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Scale (px) below which the photo's variation counts as material noise.
    #[arg(long, default_value_t = 3)]
    pub noise_radius: usize,
    /// Where the per-pixel shading runs (auto, cpu or gpu; see `compensate --help`).
    #[arg(long, value_enum, default_value_t = Device::Auto)]
    pub device: Device,
    /// Output PNG (8-bit sRGB); a side-by-side `<name>_compare.png` is written beside it.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
}

/// Where one relighting run wrote its image and its before/after comparison.
#[derive(Debug)]
pub struct RelightSummary {
    pub out: PathBuf,
    pub compare: PathBuf,
}

impl std::fmt::Display for RelightSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "relit image: {} (before/after: {})", self.out.display(), self.compare.display())
    }
}

/// Runs the step as its arguments say.
pub fn run(args: &Args, progress: &dyn Progress) -> Result<RelightSummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    progress.stage("relighting");
    let stage = StageModel::load(&args.stage_dir)
        .with_context(|| format!("loading the stage model from {}", args.stage_dir.display()))?;
    let restored = super::compensate::restored_path(&args.restored);
    let texture = LinearImage::load(&restored).context("loading the restored image")?;
    let lighting = match &args.lighting {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str::<Lighting>(&text)
                .with_context(|| format!("{} is not a valid lighting file", p.display()))?
        }
        None => Lighting::default(),
    };
    let mut out = relight::relight_on(&stage, &texture, &lighting, args.device)?;
    if let Some(photo) = &args.photo {
        let photo = LinearImage::load(photo).context("loading the photo")?;
        out = relight::infuse_noise(&stage, &out, &photo, args.noise, args.noise_radius)?;
    } else if args.noise > 0.0 {
        anyhow::bail!("--noise {} needs --photo (the photo whose material noise is infused)", args.noise);
    }
    out.save_srgb8(&args.out, 1.0)?;
    let (w, h) = (out.width, out.height);
    let mut cmp = image::RgbImage::new(2 * w, h);
    image::imageops::replace(&mut cmp, &texture.to_srgb8(1.0), 0, 0);
    image::imageops::replace(&mut cmp, &out.to_srgb8(1.0), w as i64, 0);
    let stem = args.out.file_stem().and_then(|s| s.to_str()).unwrap_or("relit");
    let cmp_path = args.out.with_file_name(format!("{stem}_compare.png"));
    cmp.save(&cmp_path).with_context(|| format!("writing {}", cmp_path.display()))?;
    Ok(RelightSummary { out: args.out.clone(), compare: cmp_path })
}
