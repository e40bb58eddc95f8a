//! Projectors whose response straightens towards black (README, "Compensation"): the virtual
//! stage's projectors are power laws near black, so they cannot show what a fit of the
//! responses gets wrong on a projector in sRGB mode. This probe gives every projector of a
//! virtual stage the sRGB curve (a linear toe below 4 % input), writes its capture with the
//! acquisition's 9 ramp levels, and, once `restage-author calibrate` has made a model of it, judges
//! compensation with that model against the modified stage's true physics (formula, m = 8).
//!
//! ```text
//! cargo run --release -p restage-authoring --example toe_probe -- write C SEED
//! restage-author calibrate C --out S --known-distance-mm D --lux-file C/ground-truth/lux_meter.toml
//! cargo run --release -p restage-authoring --example toe_probe -- eval S SEED E_BOUND...
//! ```
//! (800x600 camera, 1400x1050 projectors, dot spacing 8; D is printed by `write`.)

use std::path::Path;

use anyhow::{Context, bail};
use restage_authoring::acquire::AcquireConfig;
use restage_authoring::compensate::{Exponent, Params, Prepared};
use restage_authoring::eval::compensate::{pristine_target, visitor_view};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, VirtualStage};

/// The sRGB decoding curve: linear below 0.04045, a 2.4 power above.
fn srgb(x: f64) -> f64 {
    if x <= 0.04045 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) }
}

fn stage(seed: u64) -> anyhow::Result<VirtualStage> {
    let config =
        SceneConfig { seed, camera: [800, 600], rig: RigVariation::Seeded, ..SceneConfig::default() };
    let mut setup = VirtualStage::new(&config)?.setup().clone();
    let curve: Vec<f32> = (0..256).map(|v| srgb(v as f64 / 255.0) as f32).collect();
    for p in &mut setup.projectors {
        p.response = [curve.clone(), curve.clone(), curve.clone()];
    }
    Ok(VirtualStage::from_setup(setup))
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize| args.get(i).map(String::as_str).context("missing argument (see the module's doc)");
    match arg(0)? {
        "write" => {
            let (dir, seed) = (Path::new(arg(1)?), arg(2)?.parse()?);
            let stage = stage(seed)?;
            let acq = AcquireConfig { dot_spacing: 8, ramp_levels: 9, ..AcquireConfig::default() };
            stage.write_capture_set(dir, &acq, &mut |_, _| {})?;
            let c = stage.truth().projectors[0].centre();
            println!("known distance: {:.3} mm", (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt());
        }
        "eval" => {
            let (st, seed) = (Path::new(arg(1)?), arg(2)?.parse()?);
            let stage = stage(seed)?;
            let model = StageModel::load(st)?;
            let target = pristine_target(&stage);
            for bound in args[3..].iter().map(|b| b.parse::<f64>()) {
                let bound = bound?;
                let params =
                    Params { footprint_rounds: 0, ..Params::new(bound, Exponent::Finite(8.0), 0.05)? };
                let prep = Prepared::new(&model, params.reduction)?;
                let rows = visitor_view("calibrated", &stage, &model, &prep, &target, &params)?;
                let get = |s: &str| rows.iter().find(|r| r.name.contains(s)).map_or(f64::NAN, |r| r.value);
                println!(
                    "{bound} lx: CIEDE2000 mean {:.2}, p95 {:.2}; true peak {:.1} lx",
                    get("CIEDE2000 mean (m"),
                    get("CIEDE2000 p95"),
                    get("true peak over the whole")
                );
            }
        }
        other => bail!("{other:?}: expected write or eval"),
    }
    Ok(())
}
