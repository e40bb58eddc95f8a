//! `restage-author import`: a capture made with any camera (folders of 8-bit PNG/JPEG/TIFF
//! in a documented pattern order, one per exposure time) into a standard capture set,
//! linearised through the camera's recovered or saved response.

use std::path::PathBuf;

use anyhow::{Context, Result};
use restage_authoring::calibrate::response::DebevecParams;
use restage_authoring::capture_set::CameraIntrinsics;
use restage_authoring::import::{self, ImportSpec, ImportSummary, PatternOrder, ResponseSource};

#[derive(clap::Args, Debug)]
pub struct ImportArgs {
    /// The folder of camera images: the sequence itself, or one subfolder per exposure time
    /// (each the whole sequence, in file-name order); exposure times from EXIF ExposureTime,
    /// else each folder's exposure.json ({"exposure_s": 0.01}).
    pub folder: PathBuf,
    /// Capture directory to write (capture.json, camera.json, response.json, 16-bit linear PNGs).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub overwrite: super::Overwrite,
    /// Pattern order of the images: `restage` (white, black, Gray pairs columns then rows, ...)
    /// or `opencv` (GrayCodePattern: Gray pairs columns then rows, then white, black).
    #[arg(long, value_enum)]
    pub order: PatternOrder,
    /// Projector resolution WIDTHxHEIGHT.
    #[arg(long, value_parser = super::decode::parse_size)]
    pub projector_size: (u32, u32),
    /// The first image of each folder is the diffusely lit photo (otherwise the white pattern
    /// stands in for it).
    #[arg(long)]
    pub photo_first: bool,
    /// Camera calibration file (`camera.json` layout); its size must match the images.
    #[arg(long)]
    pub intrinsics: PathBuf,
    /// A saved camera response (`response.json` from an earlier import); without it the
    /// response is recovered from the white pattern's exposures (needs two or more).
    #[arg(long)]
    pub response: Option<PathBuf>,
    /// Smoothness of the recovered response (Debevec-Malik lambda).
    #[arg(long, default_value_t = DebevecParams::default().lambda)]
    pub lambda: f64,
}

/// Runs the step as its arguments say.
pub fn run(args: &ImportArgs, progress: &dyn super::Progress) -> Result<ImportSummary> {
    super::check_out(&args.out, args.overwrite.force)?;
    let camera = CameraIntrinsics::load(&args.intrinsics)?;
    let response = match &args.response {
        Some(path) => ResponseSource::File(path.clone()),
        None => ResponseSource::Recover(DebevecParams { lambda: args.lambda, ..DebevecParams::default() }),
    };
    let spec = ImportSpec {
        order: args.order,
        projector: args.projector_size,
        photo_first: args.photo_first,
        camera,
        response,
    };
    progress.stage("importing");
    let summary = import::import(&args.folder, &args.out, &spec)
        .with_context(|| format!("importing {} into {}", args.folder.display(), args.out.display()))?;
    tracing::info!(
        "imported {} images ({} exposures) into {}; linear 1.0 = saturation at {} s; response: {}",
        summary.images,
        summary.exposures,
        args.out.display(),
        summary.full_scale_exposure_s,
        summary.response_method
    );
    Ok(summary)
}
