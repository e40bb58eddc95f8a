//! Geometry evaluation: a calibrated stage model against the virtual stage's true one —
//! reprojection, points, normals, projector intrinsics and poses.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::Metric;
use crate::calibrate::geometry::extent_mm;
use crate::stage_model::{ProjectorModel, StageModel};

const STEP: &str = "geometry";

fn rotation(p: &ProjectorModel) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| p.rotation[r][c])
}

fn centre(p: &ProjectorModel) -> Vector3<f64> {
    Vector3::from(p.centre())
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Reprojection RMS (projector px) of a model's own points against its correspondences.
pub fn reprojection_rms(m: &StageModel) -> f64 {
    let (mut n, mut s) = (0usize, 0.0f64);
    for (p, corr) in m.projectors.iter().zip(&m.correspondences) {
        let r = rotation(p);
        let t = Vector3::from(p.translation);
        for (x, c) in m.points.iter().zip(corr) {
            if !(x[2].is_finite() && c[0].is_finite()) {
                continue;
            }
            let y = r * Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) + t;
            if y.z <= 0.0 {
                continue;
            }
            let (u, v) = (p.f * y.x / y.z + p.cx, p.f * y.y / y.z + p.cy);
            let e2 = (u - c[0] as f64).powi(2) + (v - c[1] as f64).powi(2);
            // Observations the triangulation rejected are not part of the model's fit.
            if e2 < 4.0 {
                n += 1;
                s += e2;
            }
        }
    }
    (s / n.max(1) as f64).sqrt()
}

/// Compares `est` with `truth` (same camera). Targets from the brief: reprojection RMS < 0.3
/// px, mean point error < 0.1 % of the object's size, median normal error < 2 degrees, focal
/// error < 0.5 %.
pub fn evaluate(est: &StageModel, truth: &StageModel) -> Vec<Metric> {
    let mut out = vec![Metric::below(STEP, "reprojection RMS", reprojection_rms(est), "px", 0.3)];
    let size = extent_mm(&truth.points);
    let (mut errs, mut angles) = (Vec::new(), Vec::new());
    let (mut truth_px, mut both) = (0usize, 0usize);
    for i in 0..truth.points.len().min(est.points.len()) {
        let (a, b) = (est.points[i], truth.points[i]);
        if !b[2].is_finite() {
            continue;
        }
        truth_px += 1;
        if !a[2].is_finite() {
            continue;
        }
        both += 1;
        let d = Vector3::new((a[0] - b[0]) as f64, (a[1] - b[1]) as f64, (a[2] - b[2]) as f64);
        errs.push(d.norm());
        let (na, nb) = (est.normals[i], truth.normals[i]);
        if na[0].is_finite() && nb[0].is_finite() {
            let c = (na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]) as f64;
            angles.push(c.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    let mean = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
    out.push(Metric::info(STEP, "object size (bounding-box diagonal)", size, "mm"));
    out.push(Metric::info(
        STEP,
        "object pixels reconstructed",
        100.0 * both as f64 / truth_px.max(1) as f64,
        "%",
    ));
    out.push(Metric::info(
        STEP,
        "of the object pixels not reconstructed: on the silhouette (within 2 px)",
        100.0 * missing_on_silhouette(est, truth),
        "%",
    ));
    out.push(Metric::info(STEP, "point error mean", mean, "mm"));
    out.push(Metric::info(STEP, "point error p95", percentile(&mut errs, 0.95), "mm"));
    out.push(Metric::below(STEP, "point error mean / object size", 100.0 * mean / size.max(1e-9), "%", 0.1));
    out.push(Metric::below(STEP, "normal error median", percentile(&mut angles, 0.5), "deg", 2.0));
    out.push(Metric::info(STEP, "normal error p95", percentile(&mut angles, 0.95), "deg"));
    let (mut f_err, mut cx_err, mut cy_err, mut rot_err, mut pos_err) =
        (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (e, t) in est.projectors.iter().zip(&truth.projectors) {
        f_err = f_err.max(100.0 * (e.f - t.f).abs() / t.f);
        cx_err = cx_err.max(100.0 * (e.cx - t.cx).abs() / t.width as f64);
        cy_err = cy_err.max(100.0 * (e.cy - t.cy).abs() / t.height as f64);
        let dr = Rotation3::from_matrix(&(rotation(e) * rotation(t).transpose())).angle().to_degrees();
        rot_err = rot_err.max(dr);
        pos_err = pos_err.max((centre(e) - centre(t)).norm());
    }
    out.push(Metric::below(STEP, "focal error (worst projector)", f_err, "%", 0.5));
    out.push(Metric::info(STEP, "principal point x error (worst, % of width)", cx_err, "%"));
    out.push(Metric::info(STEP, "principal point y error (worst, % of height)", cy_err, "%"));
    out.push(Metric::info(STEP, "rotation error (worst projector)", rot_err, "deg"));
    out.push(Metric::info(STEP, "projector position error (worst)", pos_err, "mm"));
    out
}

/// The share of the object pixels `est` did not reconstruct that lie within 2 px of the
/// object's silhouette (a truth pixel with no surface), where a pixel's footprint straddles
/// the edge: what a fill at the rim would reach, against holes inside the object.
fn missing_on_silhouette(est: &StageModel, truth: &StageModel) -> f64 {
    let (w, h) = (truth.camera.width as i64, truth.camera.height as i64);
    let surface = |x: i64, y: i64| {
        (0..w).contains(&x) && (0..h).contains(&y) && truth.points[(y * w + x) as usize][2].is_finite()
    };
    let (mut missing, mut rim) = (0usize, 0usize);
    for i in 0..truth.points.len().min(est.points.len()) {
        let (x, y) = (i as i64 % w, i as i64 / w);
        if !surface(x, y) || est.points[i][2].is_finite() {
            continue;
        }
        missing += 1;
        if (-2..=2).any(|dy| (-2..=2).any(|dx| !surface(x + dx, y + dy))) {
            rim += 1;
        }
    }
    rim as f64 / missing.max(1) as f64
}

/// Linear albedo luminance below which paint counts as dark (a black glaze: about sRGB 60).
pub const DARK_ALBEDO: f32 = 0.05;

/// How much of the surface each projector lights was decoded, on dark paint and on the rest
/// (`albedo`: the truth's linear albedo per camera pixel): dark paint returns little of the
/// patterns' light, so its codes are the first to drown in noise. Per paint group, the worst
/// projector's share of the truth's lit object pixels that `est` has a correspondence for.
pub fn decoded_by_paint(est: &StageModel, truth: &StageModel, albedo: &[[f32; 3]]) -> Vec<Metric> {
    let dark = |i: usize| crate::color::luminance(albedo[i].map(f64::from)) < f64::from(DARK_ALBEDO);
    let mut worst = [f64::INFINITY; 2];
    for (te, ee) in truth.correspondences.iter().zip(&est.correspondences) {
        let mut n = [[0usize; 2]; 2];
        for i in 0..te.len().min(ee.len()).min(albedo.len()) {
            if !te[i][0].is_finite() || !truth.points[i][2].is_finite() {
                continue;
            }
            let g = usize::from(dark(i));
            n[g][0] += 1;
            n[g][1] += usize::from(ee[i][0].is_finite());
        }
        for g in 0..2 {
            if n[g][0] > 0 {
                worst[g] = worst[g].min(100.0 * n[g][1] as f64 / n[g][0] as f64);
            }
        }
    }
    let name = ["decoded, light paint (worst projector)", "decoded, dark paint (worst projector)"];
    (0..2).filter(|&g| worst[g].is_finite()).map(|g| Metric::info(STEP, name[g], worst[g], "%")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture_set::CameraIntrinsics;

    fn model() -> StageModel {
        let cam = CameraIntrinsics {
            width: 3,
            height: 1,
            fx: 100.0,
            fy: 100.0,
            cx: 1.0,
            cy: 0.0,
            distortion: [0.0; 5],
        };
        let p = ProjectorModel {
            width: 100,
            height: 80,
            f: 200.0,
            cx: 49.5,
            cy: 60.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [-100.0, 0.0, 0.0],
            response: [vec![0.0; 256], vec![0.0; 256], vec![0.0; 256]],
            black: [0.0; 3],
            lux_at_1m: 0.0,
            vignetting: vec![],
        };
        let points = vec![[0.0, 0.0, 1000.0], [10.0, 0.0, 1000.0], [f32::NAN; 3]];
        let corr = points
            .iter()
            .map(|x: &[f32; 3]| {
                let y = [x[0] - 100.0, x[1], x[2]];
                [200.0 * y[0] / y[2] + 49.5, 200.0 * y[1] / y[2] + 60.0]
            })
            .collect();
        StageModel {
            camera: cam,
            projectors: vec![p],
            points,
            normals: vec![[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [f32::NAN; 3]],
            correspondences: vec![corr],
            transport: vec![Default::default()],
            gain: vec![],
            ambient: vec![],
            provenance: "test".into(),
        }
    }

    #[test]
    fn truth_against_itself_is_perfect_and_errors_are_seen() {
        let t = model();
        let m = evaluate(&t, &t);
        assert!(m.iter().all(|m| m.pass != Some(false)), "{m:?}");
        let mut e = t.clone();
        e.projectors[0].f *= 1.01;
        e.normals[0] = [0.0, 0.6, -0.8];
        e.normals[1] = [0.0, 0.6, -0.8];
        let m = evaluate(&e, &t);
        let get = |name: &str| m.iter().find(|x| x.name.starts_with(name)).unwrap();
        assert_eq!(get("focal error").pass, Some(false));
        assert!((get("focal error").value - 1.0).abs() < 1e-9);
        assert!(get("reprojection RMS").value > 0.05);
        assert!((get("normal error median").value - 36.87).abs() < 0.01);
    }

    #[test]
    fn decoding_is_counted_per_paint_over_the_pixels_the_truth_lights() {
        let t = model();
        let mut e = t.clone();
        // Pixel 0 light paint, pixel 1 black paint; pixel 2 sees nothing and never counts.
        let albedo = [[0.5f32; 3], [0.01; 3], [0.01; 3]];
        let get = |m: &[Metric], name: &str| m.iter().find(|x| x.name.contains(name)).map(|x| x.value);
        let m = decoded_by_paint(&e, &t, &albedo);
        assert_eq!((get(&m, "light"), get(&m, "dark")), (Some(100.0), Some(100.0)));
        e.correspondences[0][1] = [f32::NAN; 2];
        let m = decoded_by_paint(&e, &t, &albedo);
        assert_eq!((get(&m, "light"), get(&m, "dark")), (Some(100.0), Some(0.0)));
    }
}
