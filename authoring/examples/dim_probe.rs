//! Why the view degrades at a low light bound (README, "Chips and the rings around them; 50 lx"):
//! the object pixels whose target, at the compensation's global scale, asks for less light
//! than the projectors' black level and the room already give (no frame value can take light
//! away), their share and error, at each bound, with the projectors' black level as drawn, at a
//! quarter and at zero.
//!
//! `cargo run --release -p restage-authoring --example dim_probe -- SEED...` (default 2 9).

use restage_authoring::color::{ciede2000, linear_srgb_to_lab};
use restage_authoring::compensate::{self, Exponent, Params, Prepared};
use restage_authoring::eval::compensate::{TruePhysics, eval_scene, pristine_target};
use restage_authoring::stage_sim::{RigVariation, SceneName, VirtualStage};

fn main() -> anyhow::Result<()> {
    let seeds: Vec<u64> = std::env::args().skip(1).map(|s| s.parse()).collect::<Result<_, _>>()?;
    let seeds = if seeds.is_empty() { vec![2, 9] } else { seeds };
    println!(
        "scene, seed | black level | E_bound | dE mean / p95 (eval's) | under the floor: share, dE | above it: dE | black over the scaled white"
    );
    for seed in seeds {
        for scene in SceneName::ALL {
            // The projectors' black level as drawn (0.25-0.6 % of full output each, about
            // 170-400:1), a quarter of it (a deep-black projector) and none.
            for black in [1.0f32, 0.25, 0.0] {
                let mut stage = VirtualStage::new(&eval_scene(scene, seed, RigVariation::Seeded))?;
                if black != 1.0 {
                    let mut setup = stage.setup().clone();
                    setup.projectors.iter_mut().for_each(|p| p.black = p.black.map(|b| b * black));
                    stage = VirtualStage::from_setup(setup);
                }
                let target = pristine_target(&stage);
                let model = stage.truth();
                for bound in [150.0, 50.0] {
                    let params =
                        Params { footprint_rounds: 0, ..Params::new(bound, Exponent::Finite(8.0), 0.05)? };
                    let prep = Prepared::new(&model, params.reduction)?;
                    let comp = compensate::compensate_prepared(&model, &prep, &target, &params)?;
                    let view = stage.view(&comp.frames);
                    let s = comp.stats.scale;
                    let mut under = vec![false; view.len()];
                    for i in compensate::below_black(&model, &target, &comp.weights, s) {
                        under[i] = true;
                    }
                    // (count, dE sum): every object pixel, under the floor, above it.
                    let mut acc = [(0usize, 0.0f64); 3];
                    let mut all = Vec::new();
                    let (mut black_sum, mut white_sum) = (0.0, 0.0);
                    for (i, (v, t)) in view.iter().zip(&target.data).enumerate() {
                        if t.iter().all(|&c| c <= 0.0) {
                            continue;
                        }
                        let de = ciede2000(
                            linear_srgb_to_lab(v.map(|c| c as f64 / s)),
                            linear_srgb_to_lab(t.map(f64::from)),
                        );
                        all.push(de);
                        for k in [0, if under[i] { 1 } else { 2 }] {
                            acc[k].0 += 1;
                            acc[k].1 += de;
                        }
                        black_sum += model.ambient[i].iter().map(|&c| c as f64).sum::<f64>();
                        white_sum += 3.0 * s;
                    }
                    let mean = |k: usize| acc[k].1 / acc[k].0.max(1) as f64;
                    all.sort_by(f64::total_cmp);
                    let p95 = all.get((all.len() as f64 * 0.95) as usize).copied().unwrap_or(f64::NAN);
                    println!(
                        "{}, {seed} | x {black} | {bound} lx | {:.2} / {p95:.1} | {:.1} %, {:.2} | {:.2} | {:.1} %",
                        scene.name(),
                        mean(0),
                        100.0 * acc[1].0 as f64 / acc[0].0.max(1) as f64,
                        mean(1),
                        mean(2),
                        100.0 * black_sum / white_sum.max(f64::MIN_POSITIVE),
                    );
                }
            }
        }
    }
    Ok(())
}
