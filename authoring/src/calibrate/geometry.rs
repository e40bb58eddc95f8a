//! The geometry half of calibration as one call: decode every projector, self-calibrate them
//! jointly, fix the scale, triangulate, and fill the stage model's geometric fields
//! (camera, projector intrinsics and poses, points, normals, correspondences).
//!
//! The photometric fields (responses, black level, lux, vignetting, transport, gain, ambient)
//! are the later steps' (`transport`, `radiometry`). Until they run, a projector's response is
//! the grey response measured from the capture's gray ramps when there are any (else the
//! identity), its black level 0 and `lux_at_1m` 0 ("not measured").

use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::decode::{self, CaptureImages, DecodeParams, DecodeQuality, ProjectorDecode};
use super::rig::{self, Rig, RigUnits};
use super::selfcal::{
    self, Conditioning, KnownLength, ProjectorGeometry, ProjectorObservations, SelfCalParams, SelfCalResult,
};
use super::triangulate::{self, DenseGeometry, TriangulateParams};
use super::{CalibrateError, SolverError};
use crate::capture_set::CaptureManifest;
use crate::stage_model::{ProjectorModel, StageModel, Transport};

#[derive(Clone, Debug)]
pub struct GeometryOptions {
    pub decode: DecodeParams,
    pub selfcal: SelfCalParams,
    pub triangulate: TriangulateParams,
    pub known: KnownLength,
}

impl GeometryOptions {
    pub fn new(known: KnownLength) -> Self {
        Self {
            decode: DecodeParams::default(),
            selfcal: SelfCalParams::default(),
            triangulate: TriangulateParams::default(),
            known,
        }
    }
}

/// Figures of the geometric calibration, for people and the report (`STAGE/report.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GeometryReport {
    pub decode: Vec<DecodeQuality>,
    /// RMS reprojection error (projector px) of the bundle adjustment's inliers.
    #[serde(deserialize_with = "super::nan_if_null")]
    pub adjustment_rms_px: f64,
    pub adjustment_iterations: usize,
    /// RMS reprojection error (projector px) over every triangulated observation.
    #[serde(deserialize_with = "super::nan_if_null")]
    pub dense_rms_px: f64,
    pub points: usize,
    pub rejected_by_residual: usize,
    pub rejected_by_depth: usize,
    /// Millimetres per solver unit, from the known length.
    #[serde(deserialize_with = "super::nan_if_null")]
    pub scale_mm: f64,
    pub conditioning: Vec<Conditioning>,
    /// With a saved rig: per projector, the median distance (projector px) of this capture's
    /// correspondences from the rig's epipolar lines (empty when self-calibrated).
    #[serde(default)]
    pub rig_epipolar_median_px: Vec<f64>,
    pub warnings: Vec<String>,
}

/// Decodes every projector of a capture set (`progress` is called after each projector).
pub fn decode_capture(
    dir: &Path,
    manifest: &CaptureManifest,
    params: &DecodeParams,
    progress: &mut dyn FnMut(usize),
) -> Result<Vec<ProjectorDecode>, CalibrateError> {
    let mut out = Vec::new();
    for (k, p) in manifest.projectors.iter().enumerate() {
        let images = CaptureImages {
            dir,
            projector: p,
            width: manifest.camera.width,
            height: manifest.camera.height,
            raw: false,
        };
        out.push(decode::decode_projector(&images, p.index, p.width, p.height, params)?);
        progress(k + 1);
    }
    Ok(out)
}

/// Self-calibration, scale and dense geometry from decoded correspondences.
pub fn solve_geometry(
    manifest: &CaptureManifest,
    decodes: &[ProjectorDecode],
    options: &GeometryOptions,
) -> Result<(StageModel, GeometryReport, DenseGeometry, SelfCalResult), CalibrateError> {
    let cam = &manifest.camera;
    let bright = rig::bright_maps(decodes, options.decode.min_contrast);
    let obs: Vec<ProjectorObservations> = manifest
        .projectors
        .iter()
        .zip(&bright)
        .map(|(p, m)| ProjectorObservations { width: p.width, height: p.height, map: m })
        .collect();
    let mut cal = selfcal::self_calibrate(cam, &obs, &options.selfcal)?;
    let scale = selfcal::scale_for(&cal.projectors, &options.known)?;
    for g in &mut cal.projectors {
        g.translation *= scale;
    }
    let solved = Solved {
        geometry: &cal.projectors,
        adjustment_rms_px: cal.rms_px,
        adjustment_iterations: cal.iterations,
        scale_mm: scale,
        conditioning: cal.conditioning.clone(),
        warnings: cal.warnings.clone(),
        rig_epipolar_median_px: Vec::new(),
        how: "geometry",
    };
    let (model, report, dense) = build_model(manifest, decodes, solved, &options.triangulate)?;
    Ok((model, report, dense, cal))
}

/// The geometry of an object capture through a saved rig: the rig is checked against the
/// capture (a projector moved since is named), then every pixel is triangulated with it. No
/// self-calibration, so a flat object is as good as a round one. `known`, when given, rescales
/// the rig (and is needed when the rig was calibrated without a length).
pub fn solve_with_rig(
    manifest: &CaptureManifest,
    decodes: &[ProjectorDecode],
    rig: &Rig,
    rig_path: &Path,
    known: Option<&KnownLength>,
    triangulate: &TriangulateParams,
) -> Result<(StageModel, GeometryReport, DenseGeometry), CalibrateError> {
    let sizes: Vec<(u32, u32)> = manifest.projectors.iter().map(|p| (p.width, p.height)).collect();
    let medians = rig.check(&manifest.camera, &sizes, decodes, rig_path)?;
    let geometry = rig.geometry(known)?;
    let scale = match rig.units {
        RigUnits::Millimetres => {
            geometry[0].translation.norm() / rig.projectors[0].geometry().translation.norm()
        }
        RigUnits::Baseline => geometry[0].translation.norm(),
    };
    let solved = Solved {
        geometry: &geometry,
        adjustment_rms_px: rig.rms_px,
        adjustment_iterations: 0,
        scale_mm: scale,
        conditioning: rig.projectors.iter().map(|p| p.conditioning.clone()).collect(),
        warnings: rig.warnings.clone(),
        rig_epipolar_median_px: medians,
        how: "geometry from the saved rig",
    };
    build_model(manifest, decodes, solved, triangulate)
}

/// Projector geometry (millimetres) and the figures of how it was found.
struct Solved<'a> {
    geometry: &'a [ProjectorGeometry],
    adjustment_rms_px: f64,
    adjustment_iterations: usize,
    scale_mm: f64,
    conditioning: Vec<Conditioning>,
    warnings: Vec<String>,
    rig_epipolar_median_px: Vec<f64>,
    how: &'static str,
}

/// Triangulates every decoded pixel with the solved projectors and fills the stage model's
/// geometric fields.
fn build_model(
    manifest: &CaptureManifest,
    decodes: &[ProjectorDecode],
    solved: Solved,
    triangulate: &TriangulateParams,
) -> Result<(StageModel, GeometryReport, DenseGeometry), CalibrateError> {
    let cam = &manifest.camera;
    let maps: Vec<Vec<[f32; 2]>> = decodes.iter().map(ProjectorDecode::pairs).collect();
    let refs: Vec<&[[f32; 2]]> = maps.iter().map(Vec::as_slice).collect();
    let dense = triangulate::triangulate(cam, solved.geometry, &refs, triangulate);
    let mut warnings: Vec<String> = decodes.iter().flat_map(|d| d.quality.warnings.clone()).collect();
    warnings.extend(solved.warnings);
    let projectors = solved
        .geometry
        .iter()
        .zip(decodes)
        .map(|(g, d)| {
            let curve = d.response.clone().unwrap_or_else(|| (0..256).map(|v| v as f32 / 255.0).collect());
            ProjectorModel {
                width: g.width,
                height: g.height,
                f: g.f,
                cx: g.cx,
                cy: g.cy,
                rotation: g.rotation_rows(),
                translation: [g.translation.x, g.translation.y, g.translation.z],
                response: [curve.clone(), curve.clone(), curve],
                black: [0.0; 3],
                lux_at_1m: 0.0,
                vignetting: Vec::new(),
            }
        })
        .collect();
    let model = StageModel {
        camera: cam.clone(),
        projectors,
        points: dense.points.clone(),
        normals: dense.normals.clone(),
        correspondences: maps,
        transport: vec![Transport::default(); decodes.len()],
        gain: Vec::new(),
        ambient: Vec::new(),
        provenance: format!(
            "restage calibrate {} ({}; responses from ramps or identity until radiometry) from: {}",
            env!("CARGO_PKG_VERSION"),
            solved.how,
            manifest.source
        ),
    };
    model.validate().map_err(SolverError::Model)?;
    let report = GeometryReport {
        decode: decodes.iter().map(|d| d.quality.clone()).collect(),
        adjustment_rms_px: solved.adjustment_rms_px,
        adjustment_iterations: solved.adjustment_iterations,
        dense_rms_px: dense.rms_px(),
        points: dense.valid,
        rejected_by_residual: dense.rejected_residual,
        rejected_by_depth: dense.rejected_depth,
        scale_mm: solved.scale_mm,
        conditioning: solved.conditioning,
        rig_epipolar_median_px: solved.rig_epipolar_median_px,
        warnings,
    };
    Ok((model, report, dense))
}

/// Largest extent of the reconstructed points (bounding-box diagonal, mm).
pub fn extent_mm(points: &[[f32; 3]]) -> f64 {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points.iter().filter(|p| p[2].is_finite()) {
        let v = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    if lo.x.is_finite() { (hi - lo).norm() } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `report.json` is read back by the demo's page; figures the data cannot determine
    /// (infinite, NaN) are written as `null` and must still read, as NaN.
    #[test]
    fn a_report_with_undetermined_figures_reads_back() {
        let report = GeometryReport {
            decode: vec![DecodeQuality {
                projector: 0,
                decoded: 7,
                median_relative_margin: f32::NAN,
                ..Default::default()
            }],
            adjustment_rms_px: 0.25,
            adjustment_iterations: 4,
            dense_rms_px: 0.5,
            points: 7,
            rejected_by_residual: 1,
            rejected_by_depth: 0,
            scale_mm: 600.0,
            rig_epipolar_median_px: Vec::new(),
            conditioning: vec![Conditioning {
                projector: 0,
                f_std_px: 1.0,
                cx_std_px: 0.5,
                cy_std_px: 2.0,
                cx_std_data_only_px: f64::INFINITY,
                homography_fraction: 0.1,
                rotation_std_deg: 0.01,
                translation_std: 0.2,
            }],
            warnings: vec!["w".into()],
        };
        let json = serde_json::to_string(&report).unwrap();
        assert!(json.contains("\"cx_std_data_only_px\":null"), "{json}");
        let back: GeometryReport = serde_json::from_str(&json).unwrap();
        assert!(
            back.conditioning[0].cx_std_data_only_px.is_nan()
                && back.decode[0].median_relative_margin.is_nan()
        );
        assert_eq!((back.points, back.scale_mm, back.conditioning[0].cy_std_px), (7, 600.0, 2.0));
        assert_eq!(back.warnings, ["w"]);
    }
}
