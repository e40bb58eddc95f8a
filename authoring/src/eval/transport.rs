//! Evaluation of light transport and radiometry (paper §5.2) against the virtual stage's true
//! stage model: dot-centre error, footprint energy error, response error, gain error, plus
//! black level, vignetting, lux and refined-correspondence figures.
//!
//! Truth for a dot: where the true correspondences put projector pixel q (solved by Newton on
//! their bilinear interpolation); truth for its footprint energy: the camera area one projector
//! pixel covers there, `1 / |det d(projector)/d(camera)|`.
//!
//! The dot-centre figure is taken over whole dots: a footprint that touches a camera pixel the
//! projector does not light in the truth (the object's silhouette, a cast shadow) lost part of
//! its light where the camera cannot see it, and its centroid is pulled inwards by up to a
//! pixel whatever the snapping does (noise-free renders of the virtual stage show the same).
//! Those clipped dots are counted and their error reported beside, not mixed in.

use rayon::prelude::*;

use crate::eval::Metric;
use crate::stage_model::StageModel;

const STEP: &str = "transport";

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let i = ((v.len() - 1) as f64 * p).round() as usize;
    *v.select_nth_unstable_by(i, f64::total_cmp).1
}

/// Bilinear value and Jacobian (per camera x and y) of a correspondence map at `c`.
fn corr_at(map: &[[f32; 2]], w: usize, h: usize, c: [f64; 2]) -> Option<([f64; 2], [[f64; 2]; 2])> {
    let (x0, y0) = (c[0].floor(), c[1].floor());
    if x0 < 0.0 || y0 < 0.0 || x0 as usize + 1 >= w || y0 as usize + 1 >= h {
        return None;
    }
    let (x0, y0) = (x0 as usize, y0 as usize);
    let (fx, fy) = (c[0] - x0 as f64, c[1] - y0 as f64);
    let v = |x: usize, y: usize| map[y * w + x];
    let (a, b, cc, d) = (v(x0, y0), v(x0 + 1, y0), v(x0, y0 + 1), v(x0 + 1, y0 + 1));
    if [a, b, cc, d].iter().any(|p| !p[0].is_finite()) {
        return None;
    }
    let mut val = [0.0; 2];
    let mut jac = [[0.0; 2]; 2];
    for k in 0..2 {
        let (a, b, cc, d) = (a[k] as f64, b[k] as f64, cc[k] as f64, d[k] as f64);
        val[k] = (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (cc * (1.0 - fx) + d * fx) * fy;
        jac[k][0] = (b - a) * (1.0 - fy) + (d - cc) * fy;
        jac[k][1] = (cc - a) * (1.0 - fx) + (d - b) * fx;
    }
    Some((val, jac))
}

/// The camera position where `map` equals projector point `q`, starting from `start`.
fn invert(map: &[[f32; 2]], w: usize, h: usize, q: [f64; 2], start: [f64; 2]) -> Option<([f64; 2], f64)> {
    let mut c = start;
    for _ in 0..8 {
        let (v, j) = corr_at(map, w, h, c)?;
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if det.abs() < 1e-9 {
            return None;
        }
        let (rx, ry) = (q[0] - v[0], q[1] - v[1]);
        let dx = (j[1][1] * rx - j[0][1] * ry) / det;
        let dy = (-j[1][0] * rx + j[0][0] * ry) / det;
        c = [c[0] + dx, c[1] + dy];
        if dx.abs() + dy.abs() < 1e-6 {
            let (_, j) = corr_at(map, w, h, c)?;
            return Some((c, 1.0 / (j[0][0] * j[1][1] - j[0][1] * j[1][0]).abs()));
        }
    }
    None
}

/// Figures for a calibrated model against the true one (same camera and projector count).
pub fn evaluate(cal: &StageModel, truth: &StageModel) -> Vec<Metric> {
    let mut out = Vec::new();
    let (w, h) = (cal.camera.width as usize, cal.camera.height as usize);
    if truth.camera.width as usize != w || truth.projectors.len() != cal.projectors.len() {
        out.push(Metric::info(STEP, "models do not match (camera or projector count)", f64::NAN, ""));
        return out;
    }
    // Dots and footprints.
    let mut dot_err = Vec::new();
    let mut clipped_err = Vec::new();
    let mut energy_err = Vec::new();
    for (k, t) in cal.transport.iter().enumerate() {
        let pw = cal.projectors[k].width as usize;
        if t.row_start.len() < 2 {
            continue;
        }
        let rows = t.row_start.len() - 1;
        let truth_map = &truth.correspondences[k];
        let per: Vec<(f64, f64, bool)> = (0..rows)
            .into_par_iter()
            .filter_map(|q| {
                let (a, b) = (t.row_start[q] as usize, t.row_start[q + 1] as usize);
                if a == b {
                    return None;
                }
                let (mut sx, mut sy, mut sw) = (0.0f64, 0.0f64, 0.0f64);
                for i in a..b {
                    let p = t.camera_pixel[i] as usize;
                    let wt = t.weight[i] as f64;
                    sx += wt * (p % w) as f64;
                    sy += wt * (p / w) as f64;
                    sw += wt;
                }
                if sw <= 0.0 {
                    return None;
                }
                let c = [sx / sw, sy / sw];
                let qq = [(q % pw) as f64, (q / pw) as f64];
                let (tc, area) = invert(truth_map, w, h, qq, c)?;
                let e = ((c[0] - tc[0]).powi(2) + (c[1] - tc[1]).powi(2)).sqrt();
                let unlit = |x: i64, y: i64| {
                    x < 0
                        || y < 0
                        || x >= w as i64
                        || y >= h as i64
                        || !truth_map[y as usize * w + x as usize][0].is_finite()
                };
                let clipped = t.camera_pixel[a..b].iter().any(|&p| {
                    let (x, y) = ((p as usize % w) as i64, (p as usize / w) as i64);
                    [(x, y), (x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)].iter().any(|&(x, y)| unlit(x, y))
                });
                Some((e, 100.0 * (sw - area).abs() / area, clipped))
            })
            .collect();
        dot_err.extend(per.iter().filter(|p| !p.2).map(|p| p.0));
        clipped_err.extend(per.iter().filter(|p| p.2).map(|p| p.0));
        energy_err.extend(per.iter().filter(|p| !p.2).map(|p| p.1));
    }
    let n_dots = dot_err.len();
    out.push(Metric::info(STEP, "dots evaluated (whole)", n_dots as f64, ""));
    out.push(Metric::below(STEP, "dot centre error, median", median(dot_err.clone()), "cam px", 0.1));
    out.push(Metric::info(STEP, "dot centre error, 95th percentile", percentile(dot_err, 0.95), "cam px"));
    out.push(Metric::info(STEP, "footprint energy error, median", median(energy_err), "%"));
    out.push(Metric::info(STEP, "clipped dots (silhouette or shadow)", clipped_err.len() as f64, ""));
    out.push(Metric::info(STEP, "clipped dots' centre error, median", median(clipped_err), "cam px"));
    // Refined correspondences.
    let mut corr_err = Vec::new();
    for (c, t) in cal.correspondences.iter().zip(&truth.correspondences) {
        for (a, b) in c.iter().zip(t) {
            if a[0].is_finite() && b[0].is_finite() {
                corr_err.push((((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)) as f64).sqrt());
            }
        }
    }
    // The tail too: a dot fit gone wrong (a dot across a paint edge) moves a pixel by up to
    // the refinement's limit, which a median does not show and the triangulation does.
    out.push(Metric::info(
        STEP,
        "correspondence error after refinement, median",
        median(corr_err.clone()),
        "proj px",
    ));
    out.push(Metric::info(
        STEP,
        "correspondence error after refinement, 99th percentile",
        percentile(corr_err, 0.99),
        "proj px",
    ));
    // Responses and black levels.
    let (mut resp, mut black) = (0.0f64, 0.0f64);
    for (p, t) in cal.projectors.iter().zip(&truth.projectors) {
        for c in 0..3 {
            for (a, b) in p.response[c].iter().zip(&t.response[c]) {
                resp = resp.max((a - b).abs() as f64 * 100.0);
            }
            black = black.max((p.black[c] - t.black[c]).abs() as f64 * 100.0);
        }
    }
    out.push(Metric::below(STEP, "response error, max over levels", resp, "% full", 1.0));
    out.push(Metric::info(STEP, "black level error, max", black, "% full"));
    // Vignetting where the projector lights the object, lux.
    let mut vig = 0.0f64;
    let mut lux = 0.0f64;
    for (k, (p, t)) in cal.projectors.iter().zip(&truth.projectors).enumerate() {
        lux = lux.max(100.0 * (p.lux_at_1m - t.lux_at_1m).abs() / t.lux_at_1m);
        let at =
            |m: &[f32], q: [f32; 2]| crate::calibrate::radiometry::vignetting_at(p.width, p.height, m, q);
        let errs: Vec<f64> = truth.correspondences[k]
            .iter()
            .filter(|q| q[0].is_finite())
            .step_by(7)
            .map(|&q| 100.0 * (at(&p.vignetting, q) - at(&t.vignetting, q)).abs())
            .collect();
        vig = vig.max(median(errs));
    }
    out.push(Metric::info(STEP, "vignetting error on the object, median (worst projector)", vig, "%"));
    out.push(Metric::info(STEP, "lux_at_1m error, max", lux, "%"));
    // Gain, where the object is and calibration gave a value.
    let mut gain_err = Vec::new();
    if cal.gain.len() == truth.gain.len() {
        for (a, b) in cal.gain.iter().zip(&truth.gain) {
            for c in 0..3 {
                if a[c].is_finite() && b[c] > 1e-6 {
                    gain_err.push(100.0 * ((a[c] - b[c]) / b[c]).abs() as f64);
                }
            }
        }
    }
    out.push(Metric::below(STEP, "gain error, median", median(gain_err.clone()), "%", 2.0));
    out.push(Metric::info(STEP, "gain error, 90th percentile", percentile(gain_err, 0.9), "%"));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture_set::CameraIntrinsics;
    use crate::stage_model::{ProjectorModel, Transport};

    fn model(shift: f32) -> StageModel {
        let (w, h) = (12u32, 10u32);
        let n = (w * h) as usize;
        // Projector coordinate = (camera - 1) / 2 (+ shift): each projector pixel covers 4 camera px.
        let corr = (0..n)
            .map(|i| [((i as u32 % w) as f32 - 1.0) / 2.0 + shift, ((i as u32 / w) as f32 - 1.0) / 2.0])
            .collect();
        let ramp: Vec<f32> = (0..256).map(|v| v as f32 / 255.0).collect();
        StageModel {
            camera: CameraIntrinsics {
                width: w,
                height: h,
                fx: 10.0,
                fy: 10.0,
                cx: 6.0,
                cy: 5.0,
                distortion: [0.0; 5],
            },
            projectors: vec![ProjectorModel {
                width: 6,
                height: 5,
                f: 8.0,
                cx: 3.0,
                cy: 2.0,
                rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                translation: [0.0; 3],
                response: [ramp.clone(), ramp.clone(), ramp],
                black: [0.01; 3],
                lux_at_1m: 400.0,
                vignetting: vec![],
            }],
            points: vec![[0.0, 0.0, 500.0]; n],
            normals: vec![[0.0, 0.0, -1.0]; n],
            correspondences: vec![corr],
            transport: vec![Transport::default()],
            gain: vec![[0.001; 3]; n],
            ambient: vec![[0.0; 3]; n],
            provenance: "test".into(),
        }
    }

    #[test]
    fn exact_footprints_score_zero_and_shifted_ones_do_not() {
        let truth = model(0.0);
        let mut cal = model(0.0);
        // Projector pixel (2, 2) lands at camera (5, 5): a 2x2 footprint around it, weights 1.
        let mut t = Transport { row_start: vec![0; 31], camera_pixel: vec![], weight: vec![] };
        let q = 2 * 6 + 2;
        for (x, y) in [(4u32, 4u32), (5, 4), (4, 5), (5, 5), (6, 4), (6, 5), (4, 6), (5, 6), (6, 6)] {
            let wt = if x == 5 && y == 5 {
                1.0
            } else if x == 5 || y == 5 {
                0.5
            } else {
                0.25
            };
            t.camera_pixel.push(y * 12 + x);
            t.weight.push(wt);
        }
        for r in t.row_start.iter_mut().skip(q + 1) {
            *r = 9;
        }
        cal.transport[0] = t;
        let m = evaluate(&cal, &truth);
        let get = |name: &str| m.iter().find(|x| x.name.starts_with(name)).unwrap().value;
        assert_eq!(get("dots evaluated"), 1.0);
        assert!(get("dot centre error, median") < 1e-9);
        assert!(get("footprint energy error") < 1e-6, "{m:?}");
        assert_eq!(get("response error"), 0.0);
        assert_eq!(get("gain error, median"), 0.0);
        // A calibration whose correspondences are off by a quarter projector pixel.
        let mut off = cal.clone();
        off.gain.iter_mut().for_each(|g| g[1] *= 1.05);
        off.projectors[0].response[2][100] += 0.02;
        let truth_shifted = model(0.25);
        let m = evaluate(&off, &truth_shifted);
        let get = |name: &str| m.iter().find(|x| x.name.starts_with(name)).unwrap().value;
        assert!((get("dot centre error, median") - 0.5).abs() < 1e-6, "{m:?}");
        assert!((get("response error") - 2.0).abs() < 1e-3);
        assert!(get("gain error, 90th") > 4.9);
    }
}
