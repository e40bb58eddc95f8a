//! End to end: the virtual stage writes a (small) capture set, calibration recovers the
//! projectors and the surface, and the evaluation against ground truth holds.

use std::path::Path;

use restage_authoring::acquire::AcquireConfig;
use restage_authoring::calibrate::decode::DecodeParams;
use restage_authoring::calibrate::geometry::{self, GeometryOptions};
use restage_authoring::calibrate::rig::{Rig, RigCapture};
use restage_authoring::calibrate::selfcal::{KnownLength, SelfCalParams};
use restage_authoring::capture_set::CaptureManifest;
use restage_authoring::eval::geometry::evaluate;
use restage_authoring::stage_sim::{RigVariation, SceneConfig, SceneName, VirtualStage};

#[test]
fn virtual_stage_capture_calibrates_close_to_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    // A rig drawn from the seed: projector placement and lenses, the camera's focal length
    // and the vase's form differ from the demo's.
    let cfg = SceneConfig {
        camera: [320, 240],
        projector: [400, 300],
        rig: RigVariation::Seeded,
        ..SceneConfig::tiny(SceneName::Vase, 3)
    };
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

/// A flat painted panel cannot calibrate the rig by itself; through the rig calibrated once
/// from a round object (same seed: the same projectors) it calibrates as well as the round
/// object does, and a projector knocked since is named.
#[test]
fn a_flat_panel_calibrates_through_a_saved_rig() {
    let acq = AcquireConfig { dot_spacing: 2, ramp_levels: 3, phase_period: 8, ..AcquireConfig::default() };
    let sized = |scene| SceneConfig {
        camera: [320, 240],
        projector: [400, 300],
        rig: RigVariation::Seeded,
        ..SceneConfig::tiny(scene, 3)
    };
    let capture = |scene| {
        let dir = tempfile::tempdir().unwrap();
        let stage = VirtualStage::new(&sized(scene)).unwrap();
        let manifest = stage.write_capture_set(dir.path(), &acq, &mut |_, _| {}).unwrap();
        let options = GeometryOptions::new(KnownLength::Baseline { projector: 0, mm: 1.0 });
        let decodes = geometry::decode_capture(dir.path(), &manifest, &options.decode, &mut |_| {}).unwrap();
        (dir, stage, manifest, decodes, options)
    };
    let (_vase_dir, vase, vase_manifest, vase_decodes, _) = capture(SceneName::Vase);
    let truth = vase.truth();
    let known = KnownLength::Baseline {
        projector: 0,
        mm: nalgebra::Vector3::from(truth.projectors[0].translation).norm(),
    };
    let rig = Rig::calibrate(
        &[RigCapture {
            name: "vase".into(),
            camera: &vase_manifest.camera,
            projectors: vase_manifest.projectors.iter().map(|p| (p.width, p.height)).collect(),
            decodes: &vase_decodes,
        }],
        &SelfCalParams::default(),
        DecodeParams::default().min_contrast,
        Some(&known),
    )
    .unwrap();

    let (_panel_dir, panel, manifest, decodes, mut options) = capture(SceneName::Panel);
    options.known = known;
    let err = geometry::solve_geometry(&manifest, &decodes, &options).unwrap_err();
    assert!(err.to_string().contains("planar"), "{err}");

    let (model, report, _) = geometry::solve_with_rig(
        &manifest,
        &decodes,
        &rig,
        Path::new("rig.json"),
        None,
        &options.triangulate,
    )
    .unwrap();
    let metrics = evaluate(&model, &panel.truth());
    let get = |name: &str| metrics.iter().find(|m| m.name.starts_with(name)).unwrap().value;
    assert!(report.rig_epipolar_median_px.iter().all(|&m| m < 0.5), "{report:?}");
    assert!(report.dense_rms_px < 0.3, "{report:?}");
    assert!(get("point error mean / object size") < 0.5, "{metrics:?}");
    assert!(get("normal error median") < 5.0, "{metrics:?}");
    assert!(get("object pixels reconstructed") > 80.0, "{metrics:?}");

    // Projector 2 turned by half a degree (about its vertical axis) since the rig was calibrated.
    let mut knocked = rig.clone();
    let r = &mut knocked.projectors[2].rotation;
    let turned = nalgebra::Rotation3::from_euler_angles(0.0, 0.5f64.to_radians(), 0.0).matrix()
        * nalgebra::Matrix3::from_fn(|i, j| r[i][j]);
    *r = std::array::from_fn(|i| std::array::from_fn(|j| turned[(i, j)]));
    match geometry::solve_with_rig(
        &manifest,
        &decodes,
        &knocked,
        Path::new("rig.json"),
        None,
        &options.triangulate,
    ) {
        Ok((_, report, _)) => panic!("a knocked projector passed: {:?}", report.rig_epipolar_median_px),
        Err(e) => {
            // Turned left or right it moves along its epipolar lines: the pair that disagrees is named.
            assert!(e.to_string().contains("moved") && e.to_string().contains("0-2"), "{e}")
        }
    }
}
