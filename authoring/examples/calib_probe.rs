//! Which part of a calibrated stage model costs the visitor's view (README, "Compensation"):
//! the calibrated model of a simulated capture compensated as it is, then with one part at a
//! time replaced by the virtual stage's truth (room light and black level per pixel, gains,
//! projector responses, black levels, normals, points, correspondences, projector poses, lux;
//! the measured transport dropped, as the truth has none), each judged with the capture's true
//! physics (formula, m = 8; the clip fraction chosen as `compensate` chooses it by default), with
//! the global scale and the share of points the black level lifts. Also prints the calibrated
//! responses against the true ones at the dark end, and the gains' error by how much light a
//! pixel returns.
//!
//! `cargo run --release -p restage-authoring --example calib_probe -- CAPTURE STAGE [E_BOUND
//! [ONLY]]` (default 50 lx; ONLY: run the rows whose name holds it; about 15 s a row at 800x600).

use restage_authoring::calibrate::radiometry::full_irradiance;
use restage_authoring::compensate::{Exponent, Params, Prepared};
use restage_authoring::eval::compensate::{pristine_target, visitor_view};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::{VirtualStage, load_config};
use std::path::PathBuf;

type Swap = Box<dyn Fn(&mut StageModel, &StageModel)>;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [capture, stage_dir] = [0, 1].map(|i| args.get(i).map(PathBuf::from));
    let (Some(capture), Some(stage_dir)) = (capture, stage_dir) else {
        anyhow::bail!("usage: calib_probe CAPTURE STAGE [E_BOUND [ONLY]]");
    };
    let bound: f64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(50.0);
    let stage = VirtualStage::new(&load_config(&capture)?)?;
    let truth = stage.truth();
    let calibrated = StageModel::load(&stage_dir)?;
    let target = pristine_target(&stage);
    let params = Params { footprint_rounds: 0, ..Params::new(bound, Exponent::Finite(8.0), 0.05)? };

    println!("relative output at the dark end, calibrated / true (red channel):");
    for (k, (c, t)) in calibrated.projectors.iter().zip(&truth.projectors).enumerate() {
        let row: Vec<String> = [4, 8, 16, 32, 64]
            .iter()
            .map(|&v| format!("{v}: {:.5} / {:.5}", c.response[0][v], t.response[0][v]))
            .collect();
        println!("  projector {k}: {}", row.join(", "));
    }

    // The gains' error against the truth by how much light the pixel returns (green channel,
    // its full light from every projector, as `white - black` measures it): the camera's noise
    // weighs on the dark paint.
    let mut bins = [(0.0f64, 0.0f64, 0usize); 6];
    for i in 0..calibrated.points.len() {
        let (g, t) = (calibrated.gain[i][1], truth.gain[i][1]);
        if !(calibrated.points[i][0].is_finite() && g.is_finite() && t > 0.0) {
            continue;
        }
        let e: f64 = (0..truth.projectors.len()).filter_map(|k| full_irradiance(&truth, k, i)).sum();
        let light = t as f64 * e;
        let b = ((light / 0.003).log2().floor().max(0.0) as usize).min(bins.len() - 1);
        bins[b].0 += light;
        bins[b].1 += ((g / t - 1.0) as f64).powi(2);
        bins[b].2 += 1;
    }
    println!("gain error (RMS, green) by the pixel's full light, white - black:");
    for (light, sq, n) in bins.iter().filter(|b| b.2 > 0) {
        let n = *n as f64;
        println!("  about {:.4}: {:.1} % over {n} pixels", light / n, 100.0 * (sq / n).sqrt());
    }

    // Per camera pixel the model reconstructed, the truth's value replaces the calibrated one.
    let per_pixel = |m: &mut StageModel, t: &StageModel, gain: bool, ambient: bool| {
        for i in 0..m.points.len() {
            if m.points[i][0].is_finite() {
                if gain {
                    m.gain[i] = t.gain[i];
                }
                if ambient {
                    m.ambient[i] = t.ambient[i];
                }
            }
        }
    };
    let variants: Vec<(&str, Swap)> = vec![
        ("calibrated", Box::new(|_, _| {})),
        ("true room light and black level per pixel", Box::new(move |m, t| per_pixel(m, t, false, true))),
        ("true gains", Box::new(move |m, t| per_pixel(m, t, true, false))),
        (
            "true responses",
            Box::new(|m, t| {
                m.projectors.iter_mut().zip(&t.projectors).for_each(|(p, q)| p.response = q.response.clone())
            }),
        ),
        (
            "true projector black levels",
            Box::new(|m, t| m.projectors.iter_mut().zip(&t.projectors).for_each(|(p, q)| p.black = q.black)),
        ),
        ("true normals", Box::new(|m, t| at_points(m, t, |m, t, i| m.normals[i] = t.normals[i]))),
        (
            "true points and normals",
            Box::new(|m, t| {
                at_points(m, t, |m, t, i| (m.points[i], m.normals[i]) = (t.points[i], t.normals[i]))
            }),
        ),
        (
            "true correspondences",
            Box::new(|m, t| {
                for (c, u) in m.correspondences.iter_mut().zip(&t.correspondences) {
                    for (a, b) in c.iter_mut().zip(u) {
                        if a[0].is_finite() && b[0].is_finite() {
                            *a = *b;
                        }
                    }
                }
            }),
        ),
        (
            "true projector poses and lenses",
            Box::new(|m, t| {
                for (p, q) in m.projectors.iter_mut().zip(&t.projectors) {
                    (p.f, p.cx, p.cy, p.rotation, p.translation) =
                        (q.f, q.cx, q.cy, q.rotation, q.translation);
                }
            }),
        ),
        (
            "all true but which pixels are covered",
            Box::new(|m, t| {
                at_points(m, t, |m, t, i| {
                    (m.points[i], m.normals[i], m.gain[i], m.ambient[i]) =
                        (t.points[i], t.normals[i], t.gain[i], t.ambient[i]);
                    true_correspondences(m, t, i);
                });
                m.projectors = t.projectors.clone();
                m.transport = t.transport.clone();
            }),
        ),
        (
            "no measured transport",
            Box::new(|m, _| m.transport.iter_mut().for_each(|t| *t = Default::default())),
        ),
        ("true correspondences where either has one", Box::new(|m, t| at_points(m, t, true_correspondences))),
        (
            "true lux and vignetting",
            Box::new(|m, t| {
                for (p, q) in m.projectors.iter_mut().zip(&t.projectors) {
                    p.lux_at_1m = q.lux_at_1m;
                    p.vignetting = q.vignetting.clone();
                }
            }),
        ),
    ];
    println!("{bound} lx, formula: CIEDE2000 mean / p95 on covered pixels, in chips, in their rings");
    let only = args.get(3);
    for (name, swap) in variants {
        if only.is_some_and(|o| !name.contains(o.as_str())) {
            continue;
        }
        let mut model = calibrated.clone();
        swap(&mut model, &truth);
        let prep = Prepared::new(&model, params.reduction)?;
        let rows = visitor_view(name, &stage, &model, &prep, &target, &params)?;
        let get = |s: &str| rows.iter().find(|r| r.name.contains(s)).map_or(f64::NAN, |r| r.value);
        println!(
            "  {name}: {:.2} / {:.2}, chips {:.2}, rings {:.2}, scale {:.4}, below black {:.1} %",
            get("CIEDE2000 mean (m"),
            get("CIEDE2000 p95"),
            get("mean in chips"),
            get("ring around"),
            get("global scale"),
            get("less light than the black")
        );
    }
    Ok(())
}

/// Applies `swap` at every camera pixel where both models have a surface point.
fn at_points(m: &mut StageModel, t: &StageModel, swap: impl Fn(&mut StageModel, &StageModel, usize)) {
    for i in 0..m.points.len() {
        if m.points[i][0].is_finite() && t.points[i][0].is_finite() {
            swap(m, t, i);
        }
    }
}

/// Every projector's coordinate at pixel `i` from the truth, including where the model has none.
fn true_correspondences(m: &mut StageModel, t: &StageModel, i: usize) {
    for (c, u) in m.correspondences.iter_mut().zip(&t.correspondences) {
        c[i] = u[i];
    }
}
