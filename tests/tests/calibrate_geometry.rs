//! End to end: the virtual stage writes a (small) capture set, calibration recovers the
//! projectors and the surface, and the evaluation against ground truth holds.

use restage_authoring::acquire::AcquireConfig;
use restage_authoring::calibrate::geometry::{self, GeometryOptions};
use restage_authoring::calibrate::selfcal::KnownLength;
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::eval::geometry::evaluate;
use restage_authoring::stage_sim::{SceneConfig, SceneName, VirtualStage};

#[test]
fn virtual_stage_capture_calibrates_close_to_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let cfg =
        SceneConfig { camera: [320, 240], projector: [400, 300], ..SceneConfig::tiny(SceneName::Vase, 3) };
    let stage = VirtualStage::new(&cfg).unwrap();
    // Few dot and ramp images: this test is about geometry.
    let acq = AcquireConfig { dot_spacing: 2, ramp_levels: 3, phase_period: 8, ..AcquireConfig::default() };
    let manifest: CaptureManifest = stage.write_capture_set(dir.path(), &acq, &mut |_, _| {}).unwrap();
    let truth = stage.truth();
    let baseline = {
        let p = &truth.projectors[0];
        let t = nalgebra::Vector3::from(p.translation);
        t.norm()
    };
    let options = GeometryOptions::new(KnownLength::Baseline { projector: 0, mm: baseline });
    let decodes = geometry::decode_capture(dir.path(), &manifest, &options.decode, &mut |_| {}).unwrap();
    let (model, report, _, _) = geometry::solve_geometry(&manifest, &decodes, &options).unwrap();
    let metrics = evaluate(&model, &truth);
    let get = |name: &str| metrics.iter().find(|m| m.name.starts_with(name)).unwrap().value;
    // At this small size (a few thousand object pixels) the figures are looser than the
    // full-size targets the eval command checks.
    assert!(report.dense_rms_px < 0.3, "{report:?}");
    assert!(get("focal error") < 1.0, "{metrics:?}");
    assert!(get("point error mean / object size") < 0.5, "{metrics:?}");
    assert!(get("normal error median") < 5.0, "{metrics:?}");
    assert!(get("object pixels reconstructed") > 80.0, "{metrics:?}");
}
