//! `restage-author eval-restore --out DIR`: restoration against the virtual stage's pristine
//! labels on every built-in scene (ours, a mode filter, and the Telea peer when its output
//! is there), printed as a table and written as JSON; peer inputs and before/after sheets
//! are written beside.

use std::path::PathBuf;

use anyhow::{Context, Result};
use restage_authoring::eval::restore::{
    evaluate_scene, prepare_scene, read_peer_labels, restore_scene, write_peer_inputs,
};
use restage_authoring::eval::{Metric, table};
use restage_authoring::restore::{RestoreParams, before_after};
use restage_authoring::stage_sim::SceneName;

#[derive(clap::Args, Debug)]
pub struct EvalRestoreArgs {
    /// Output folder: `<scene>/peer/` inputs for `bench/peers/restore_peers.py`,
    /// `<scene>/before_after.png`, and `restore_eval.json`.
    #[arg(long, default_value = "out/eval-restore")]
    pub out: PathBuf,
    /// Camera size of the simulated scenes, `WxH`.
    #[arg(long, default_value = "800x600")]
    pub camera: String,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// `seeded`: the projectors' placement and lenses, the camera's focal length and the
    /// objects' form vary with the seed; `nominal`: the demo's rig at every seed.
    #[arg(long, value_enum, default_value = "seeded")]
    pub rig: restage_authoring::stage_sim::RigVariation,
    #[arg(long, default_value_t = 2.0)]
    pub alpha: f64,
    #[arg(long, default_value_t = 3.0)]
    pub beta: f64,
}

pub fn run(args: &EvalRestoreArgs) -> Result<()> {
    let (w, h) = args.camera.split_once('x').context("--camera: expected WxH")?;
    let camera: [u32; 2] = [w.parse().context("--camera width")?, h.parse().context("--camera height")?];
    let params = RestoreParams {
        alpha: args.alpha,
        beta: args.beta,
        grid: (camera[0].div_ceil(256), camera[1].div_ceil(256)),
        ..RestoreParams::default()
    };
    let mut all: Vec<Metric> = Vec::new();
    for name in SceneName::ALL {
        let scene = prepare_scene(name, camera, args.seed, args.rig)?;
        let dir = args.out.join(scene.name.as_str());
        write_peer_inputs(&scene, &dir.join("peer"))?;
        let telea_path = dir.join("peer").join("telea.png");
        let telea = if telea_path.exists() { Some(read_peer_labels(&scene, &telea_path)?) } else { None };
        let peers: Vec<(&str, &restage_authoring::classify::LabelMap)> =
            telea.iter().map(|t| ("telea (oracle mask)", t)).collect();
        all.extend(evaluate_scene(&scene, &params, &peers)?);
        let ours = restore_scene(&scene, &params)?;
        let colours: Vec<[u8; 3]> =
            (0..scene.palette.classes.len()).map(|i| scene.palette.display_colour(i)).collect();
        before_after(&scene.classified, &ours.labels, &colours)
            .save(dir.join("before_after.png"))
            .with_context(|| format!("writing {}", dir.display()))?;
        tracing::info!("{}: {:?}", scene.name, ours.stats);
        // Where restoration broke (red) and fixed (green) the classification, against truth.
        let map = &scene.map;
        let diff = image::RgbImage::from_fn(camera[0], camera[1], |x, y| {
            let (c, o, p) = (scene.classified.get(x, y), ours.labels.get(x, y), scene.pristine.get(x, y));
            if p == 255 {
                return image::Rgb([0, 0, 0]);
            }
            let (cw, ow) = (map[c as usize] != p, map[o as usize] != p);
            image::Rgb(match (cw, ow) {
                (false, true) => [255, 0, 0],
                (true, false) => [0, 200, 0],
                (true, true) => [120, 120, 120],
                _ => [255, 255, 255],
            })
        });
        diff.save(dir.join("fixed_broken.png")).with_context(|| format!("writing {}", dir.display()))?;
    }
    print!("{}", table(&all));
    let json = args.out.join("restore_eval.json");
    std::fs::write(&json, serde_json::to_string_pretty(&all)?)
        .with_context(|| format!("writing {}", json.display()))?;
    Ok(())
}
