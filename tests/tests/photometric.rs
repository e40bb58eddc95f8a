//! End to end on the virtual stage: light transport, responses, vignetting, black levels, lux
//! and gain calibrated from a simulated capture set (the true projectors, the capture's decoded
//! correspondences and points triangulated from them) and scored by `eval::transport`.

use restage_authoring::acquire::AcquireConfig;
use restage_authoring::calibrate::decode::DecodeParams;
use restage_authoring::calibrate::geometry::decode_capture;
use restage_authoring::calibrate::lux::{LuxReadings, Meter};
use restage_authoring::calibrate::photometric::calibrate_photometry;
use restage_authoring::calibrate::radiometry::vignetting_at;
use restage_authoring::calibrate::selfcal::ProjectorGeometry;
use restage_authoring::calibrate::transport::SnapParams;
use restage_authoring::calibrate::triangulate::{TriangulateParams, triangulate};
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::eval::transport::evaluate;
use restage_authoring::stage_model::{StageModel, Transport};
use restage_authoring::stage_sim::{SceneConfig, SceneName, VirtualStage};

/// The model the geometry step would hand over: the true projectors (self-calibration has its
/// own tests), the capture's decoded correspondences and the points triangulated from them,
/// nothing photometric.
fn geometry_only(truth: &StageModel, dir: &std::path::Path, manifest: &CaptureManifest) -> StageModel {
    let mut m = truth.clone();
    let decodes = decode_capture(dir, manifest, &DecodeParams::default(), &mut |_| {}).unwrap();
    m.correspondences = decodes.iter().map(|d| d.pairs()).collect();
    for p in &mut m.projectors {
        p.black = [0.0; 3];
        p.lux_at_1m = 0.0;
        p.vignetting = vec![];
        p.response = std::array::from_fn(|_| vec![0.0; 256]);
    }
    m.transport = vec![Transport::default(); m.projectors.len()];
    m.gain = vec![];
    m.ambient = vec![];
    let geometry: Vec<ProjectorGeometry> = m.projectors.iter().map(ProjectorGeometry::from).collect();
    let maps: Vec<&[[f32; 2]]> = m.correspondences.iter().map(Vec::as_slice).collect();
    let dense = triangulate(&m.camera, &geometry, &maps, &TriangulateParams::default());
    m.points = dense.points;
    m.normals = dense.normals;
    m
}

/// What a lux meter facing each projector reads at camera pixel `px`, ambient subtracted.
fn readings(truth: &StageModel, px: [u32; 2]) -> LuxReadings {
    let i = (px[1] * truth.camera.width + px[0]) as usize;
    let mut r = LuxReadings {
        ambient: Some(0.0),
        reference_pixel: Some(px),
        meter: Meter::FacingProjector,
        ..Default::default()
    };
    for (k, p) in truth.projectors.iter().enumerate() {
        let (rot, t) = (&p.rotation, &p.translation);
        let centre: [f64; 3] =
            std::array::from_fn(|j| -(rot[0][j] * t[0] + rot[1][j] * t[1] + rot[2][j] * t[2]));
        let x = truth.points[i];
        let d = (0..3).map(|j| (centre[j] - x[j] as f64).powi(2)).sum::<f64>().sqrt();
        let vig = vignetting_at(p.width, p.height, &p.vignetting, truth.correspondences[k][i]);
        r.white.insert(k, p.lux_at_1m * vig / (d / 1000.0).powi(2));
    }
    r
}

#[test]
fn photometric_calibration_of_a_tiny_vase_meets_its_figures() {
    let dir = tempfile::tempdir().unwrap();
    let stage = VirtualStage::new(&SceneConfig::tiny(SceneName::Vase, 5)).unwrap();
    let acq = AcquireConfig { dot_spacing: 16, ramp_levels: 9, phase_steps: 4, ..Default::default() };
    stage.write_capture_set(dir.path(), &acq, &mut |_, _| {}).unwrap();
    let truth = stage.truth();
    let manifest = CaptureManifest::load(dir.path()).unwrap();
    let mut model = geometry_only(&truth, dir.path(), &manifest);
    // The meter stands where every projector lights the object, nearest the image centre.
    let w = truth.camera.width as usize;
    let px = (0..truth.points.len())
        .filter(|&i| truth.correspondences.iter().all(|c| c[i][0].is_finite()))
        .min_by_key(|&i| ((i % w) as i64 - 80).pow(2) + ((i / w) as i64 - 60).pow(2))
        .map(|i| [(i % w) as u32, (i / w) as u32])
        .unwrap();
    let (report, dense) = calibrate_photometry(
        dir.path(),
        &manifest,
        &mut model,
        &readings(&truth, px),
        &SnapParams::default(),
        &TriangulateParams::default(),
        &|_, _, _| {},
    )
    .unwrap();
    model.validate().unwrap();
    // One consistent model: the points are triangulated again from the refined
    // correspondences the model keeps, so reprojecting them gives the RMS calibration reports
    // (what `eval geometry` measures), and every point is one the triangulation kept.
    let rms = restage_authoring::eval::geometry::reprojection_rms(&model);
    assert!(
        (rms - dense.rms_px()).abs() <= 0.01 * dense.rms_px(),
        "the model's points reproject at {rms:.4} px, its triangulation reported {:.4} px",
        dense.rms_px()
    );
    assert_eq!(model.points.iter().filter(|p| p[2].is_finite()).count(), dense.valid);
    let metrics = evaluate(&model, &truth);
    let get = |name: &str| metrics.iter().find(|m| m.name.starts_with(name)).unwrap().value;
    let table = restage_authoring::eval::table(&metrics);
    // A 160x120 camera leaves dots few pixels and little light, so centres are noise-limited
    // here; full-size scenes reach the 0.1 px target (see the closing figures). Vignetting, lux
    // and gain rest on the points and normals, here triangulated from a 160x120 decode, whose
    // 7x7 plane fits span a tenth of the vase: this scale measures 3.5 / 2.1 / 3.1 % for them
    // (5.4 / 3.0 / 4.8 % when the points stayed those of the decoded correspondences, before
    // re-triangulation); at 800x600 they are 0.6 / 0.8 / 1.0 % (README, calibration).
    assert!(get("dots evaluated") > 2000.0, "{table}");
    assert!(get("dot centre error, median") < 0.25, "{table}");
    assert!(get("correspondence error after refinement, median") < 0.25, "{table}");
    assert!(get("response error") < 1.0, "{table}");
    assert!(get("black level error") < 0.1, "{table}");
    assert!(get("vignetting error") < 4.5, "{table}");
    assert!(get("lux_at_1m error") < 3.0, "{table}");
    assert!(get("gain error, median") < 4.0, "{table}");
    assert!(report.vignetting.iter().all(|v| v.is_some()));
    assert!(
        report.transport.iter().all(|t| t.coverage > 0.9),
        "{:?}",
        report.transport.iter().map(|t| t.coverage).collect::<Vec<_>>()
    );
    // The report's figures are written.
    let out = dir.path().join("report");
    let sizes: Vec<(u32, u32)> = model.projectors.iter().map(|p| (p.width, p.height)).collect();
    report.save(&out, &sizes).unwrap();
    assert!(out.join("response_proj2.png").exists() && out.join("footprint_proj2.png").exists());
}
