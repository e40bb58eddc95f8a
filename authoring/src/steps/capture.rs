//! `restage-author capture`: acquisition on real hardware. Patterns go full screen on each
//! projector's display output, a V4L2 camera grabs each one, and the capture set is written
//! exactly as `simulate` writes it (the same acquisition loop). Needs the `hardware` feature.

use std::path::PathBuf;

use anyhow::Result;

use super::simulate::PatternArgs;

#[derive(clap::Args, Debug)]
pub struct CaptureArgs {
    /// The camera's V4L2 device.
    #[arg(long, value_name = "/dev/videoN")]
    pub camera: PathBuf,
    /// Camera calibration file (`camera.json` layout: width, height, fx, fy, cx, cy in pixels);
    /// the camera is set to this size.
    #[arg(long)]
    pub intrinsics: PathBuf,
    /// Capture directory to write.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// The projectors' display outputs in projector order: monitor indices or names
    /// (e.g. `HDMI-1,DP-2,DP-3`). Run with a wrong name to see the list.
    #[arg(long, value_delimiter = ',', required = true)]
    pub screens: Vec<String>,
    /// Wait after showing a pattern before grabbing (projector and camera latency), ms.
    #[arg(long, default_value_t = 150)]
    pub settle_ms: u64,
    /// Fresh camera frames averaged per image (less noise, slower).
    #[arg(long, default_value_t = 1)]
    pub average: u32,
    /// Manual exposure in the driver's units (usually 100 µs); automatic exposure, gain and
    /// white balance are switched off either way.
    #[arg(long)]
    pub exposure: Option<i64>,
    /// How the camera's 8-bit values relate to light: `srgb` (webcams) or `linear`.
    #[arg(long, default_value = "srgb")]
    pub camera_response: restage_authoring::devices::stream::CameraResponse,
    /// Pixel formats to ask the camera for, best first.
    #[arg(long, value_delimiter = ',', default_value = "YUYV,RGB3,GREY,MJPG")]
    pub formats: Vec<String>,
    #[command(flatten)]
    pub patterns: PatternArgs,
}

/// What one capture wrote.
#[derive(Debug)]
pub struct CaptureSummary {
    pub images: usize,
    pub out: PathBuf,
}

impl std::fmt::Display for CaptureSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "wrote {} camera images to {}", self.images, self.out.display())
    }
}

/// Runs the step as its arguments say, on the camera and screens they name.
#[cfg(feature = "hardware")]
pub fn run(args: &CaptureArgs, progress: &dyn super::Progress) -> Result<CaptureSummary> {
    use anyhow::{Context, bail};
    use restage_authoring::acquire::acquire;
    use restage_authoring::capture_set::CameraIntrinsics;
    use restage_authoring::devices::AskedLight;
    use restage_authoring::devices::screens::ScreenOutput;
    use restage_authoring::devices::stream::{GrabConfig, PixelFormat, StreamCamera};
    use restage_authoring::devices::v4l_camera::{V4lSettings, V4lSource};
    use restage_authoring::hw::{Rig, SystemClock};

    let acq = args.patterns.config(std::time::Duration::from_millis(args.settle_ms))?;
    super::check_out(&args.out, args.overwrite.force)?;
    let intrinsics = CameraIntrinsics::load(&args.intrinsics)?;
    let mut formats = Vec::new();
    for f in &args.formats {
        let code: [u8; 4] = f.as_bytes().try_into().unwrap_or([0; 4]);
        match PixelFormat::from_fourcc(code) {
            Some(p) => formats.push(p),
            None => bail!("--formats: {f:?} is not one of YUYV, RGB3, GREY, MJPG"),
        }
    }
    let settings =
        V4lSettings { width: intrinsics.width, height: intrinsics.height, formats, exposure: args.exposure };
    let source = V4lSource::open(&args.camera, &settings)?;
    let grab = GrabConfig { average: args.average, response: args.camera_response };
    let camera = StreamCamera::new(source, intrinsics, grab)?;
    let projectors = ScreenOutput::open(args.screens.clone())?;
    let light = AskedLight::new(std::io::stdin().lock(), std::io::stderr());
    let mut rig = Rig { camera, projectors, light };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
    progress.stage("capturing");
    let source = format!("capture from {}", args.camera.display());
    let manifest =
        acquire(&mut rig, &mut SystemClock::default(), &acq, &args.out, &source, &mut |done, total| {
            progress.count(done as u64, total as u64)
        })
        .with_context(|| format!("capturing into {}", args.out.display()))?;
    let images = 1 + manifest.projectors.iter().map(|p| p.shots.len()).sum::<usize>();
    Ok(CaptureSummary { images, out: args.out.clone() })
}

#[cfg(not(feature = "hardware"))]
pub fn run(_: &CaptureArgs, _: &dyn super::Progress) -> Result<CaptureSummary> {
    anyhow::bail!(
        "this restage-author was built without camera and projector support; rebuild with \
         `cargo build --release --features restage-authoring/hardware` (needs libclang-dev for v4l)"
    )
}
