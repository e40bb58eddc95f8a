//! Where the error in the ring around chips comes from (README, "Chips and the rings around
//! them"): the eval's 2 px ring split into the pixels touching a chip (1 px) and the rest, with
//! the share of the touching ones that straddle the chip's edge (mixed camera pixels), for the
//! formula and the footprint refinement, with the projectors' lens blur as drawn and removed.
//!
//! `cargo run --release -p restage-authoring --example ring_probe -- SEED...` (default 2 9).

use restage_authoring::color::{ciede2000, linear_srgb_to_lab};
use restage_authoring::compensate::{self, Exponent, Params, Prepared};
use restage_authoring::eval::compensate::{CHIP_RING_PX, TruePhysics, eval_scene, pristine_target};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::{RigVariation, SceneName, VirtualStage};

/// Squared distance (pixel centres) from pixel `i` to the nearest chipped pixel within the ring.
fn chip_distance2(chipped: &[bool], width: usize, i: usize) -> Option<i64> {
    let height = chipped.len() / width;
    let (x, y) = ((i % width) as i64, (i / width) as i64);
    let r = CHIP_RING_PX;
    (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| {
            let (u, v) = (x + dx, y + dy);
            (1..=r * r).contains(&(dx * dx + dy * dy))
                && (0..width as i64).contains(&u)
                && (0..height as i64).contains(&v)
                && chipped[v as usize * width + u as usize]
        })
        .map(|(dx, dy)| dx * dx + dy * dy)
        .min()
}

fn main() -> anyhow::Result<()> {
    let seeds: Vec<u64> = std::env::args().skip(1).map(|s| s.parse()).collect::<Result<_, _>>()?;
    let seeds = if seeds.is_empty() { vec![2, 9] } else { seeds };
    println!(
        "scene, seed | blur | rounds | ring dE (eval's) | touching: dE, mixed share, mixed dE | 1-2 px beyond: dE"
    );
    for seed in seeds {
        for scene in SceneName::ALL {
            for blur in [true, false] {
                let mut stage = VirtualStage::new(&eval_scene(scene, seed, RigVariation::Seeded))?;
                if !blur {
                    let mut setup = stage.setup().clone();
                    setup.projectors.iter_mut().for_each(|p| p.blur_px = 0.0);
                    stage = VirtualStage::from_setup(setup);
                }
                let target = pristine_target(&stage);
                let width = target.width as usize;
                let chipped = stage.chipped().expect("the virtual stage knows its chips");
                for rounds in [0, 8] {
                    let model = stage.truth();
                    let model = if rounds > 0 {
                        StageModel { transport: stage.true_transport(), ..model }
                    } else {
                        model
                    };
                    let params = Params {
                        footprint_rounds: rounds,
                        ..Params::new(150.0, Exponent::Finite(8.0), 0.05)?
                    };
                    let prep = Prepared::new(&model, params.reduction)?;
                    let comp = compensate::compensate_prepared(&model, &prep, &target, &params)?;
                    let view = stage.view(&comp.frames);
                    let s = comp.stats.scale;
                    // (count, dE sum) for: the whole ring, touching, touching and mixed, beyond.
                    let mut acc = [(0usize, 0.0f64); 4];
                    for (i, (v, t)) in view.iter().zip(&target.data).enumerate() {
                        if chipped[i] || t.iter().all(|&c| c <= 0.0) {
                            continue;
                        }
                        let Some(d2) = chip_distance2(&chipped, width, i) else { continue };
                        let de = ciede2000(
                            linear_srgb_to_lab(v.map(|c| c as f64 / s)),
                            linear_srgb_to_lab(t.map(f64::from)),
                        );
                        let mut add = |k: usize| {
                            acc[k].0 += 1;
                            acc[k].1 += de;
                        };
                        add(0);
                        if d2 == 1 {
                            add(1);
                            if stage.pixels()[i].mixed {
                                add(2);
                            }
                        } else {
                            add(3);
                        }
                    }
                    let mean = |k: usize| acc[k].1 / acc[k].0.max(1) as f64;
                    println!(
                        "{}, {seed} | {} | {rounds} | {:.2} | {:.2}, {:.0} %, {:.2} | {:.2}",
                        scene.name(),
                        if blur { "as drawn" } else { "none" },
                        mean(0),
                        mean(1),
                        100.0 * acc[2].0 as f64 / acc[1].0.max(1) as f64,
                        mean(2),
                        mean(3),
                    );
                }
            }
        }
    }
    Ok(())
}
