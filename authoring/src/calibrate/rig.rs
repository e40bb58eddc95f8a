//! The rig, calibrated once: the camera and every projector's intrinsics and pose, solved from
//! one or more captures made through the fixed rig (a non-planar scene, or two or more poses
//! of a flat board) and saved as `rig.json`. An object capture is then calibrated with the rig
//! by triangulation alone, so a flat painting is just a surface; and the rig is checked first,
//! so a projector knocked since is named instead of silently bending the model.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::board::{Board, BoardCalibration};
use super::decode::ProjectorDecode;
use super::selfcal::{
    self, Conditioning, KnownLength, ProjectorGeometry, ProjectorObservations, SelfCalParams,
};
use super::{CalibrateError, nan_if_null};
use crate::capture_set::CameraIntrinsics;

pub const RIG_FILE: &str = "rig.json";
pub const RIG_VERSION: u32 = 1;

/// A projector's epipolar residual above this (median, projector px) and above
/// [`MOVED_FACTOR`] times its value at calibration means the rig has changed.
pub const MOVED_MIN_PX: f64 = 1.0;
pub const MOVED_FACTOR: f64 = 3.0;

/// What the rig's translations are measured in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RigUnits {
    Millimetres,
    /// No length was measured: projector 0's baseline is 1. Calibrating an object with such a
    /// rig needs `--known-distance-mm`.
    Baseline,
}

/// One projector of the rig: `X_p = rotation * X_c + translation` (camera frame).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigProjector {
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    /// How well the captures determined it (standard deviations).
    pub conditioning: Conditioning,
    /// RMS reprojection error (projector px) of its inlier observations in the adjustment.
    #[serde(deserialize_with = "nan_if_null")]
    pub rms_px: f64,
    /// Median distance (projector px) of its correspondences from the epipolar lines the rig
    /// predicts, over the calibration captures: the yardstick of the moved check.
    #[serde(deserialize_with = "nan_if_null")]
    pub epipolar_median_px: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rig {
    pub version: u32,
    pub camera: CameraIntrinsics,
    pub units: RigUnits,
    pub projectors: Vec<RigProjector>,
    /// RMS reprojection error (projector px) of the adjustment's inliers, all projectors.
    #[serde(deserialize_with = "nan_if_null")]
    pub rms_px: f64,
    /// The captures it was solved from.
    pub captures: Vec<String>,
    pub warnings: Vec<String>,
    pub provenance: String,
    /// How a rig solved from a printed chessboard was fitted (absent for a self-calibrated one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board: Option<BoardFit>,
}

/// A board calibration's figures: the board, the camera's uncertainty (the camera is
/// calibrated too unless it was given) and the corner residuals.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardFit {
    /// Inner corners across and down, and the side of a square (mm).
    pub cols: u32,
    pub rows: u32,
    pub square_mm: f64,
    pub poses: usize,
    /// Standard deviations of the camera's fx, fy, cx, cy (px), k1, k2; zero when given.
    pub camera_std: [f64; 6],
    /// RMS reprojection error of the corners in the camera (px).
    #[serde(deserialize_with = "nan_if_null")]
    pub camera_rms_px: f64,
    /// Per projector: corners it carried over all poses.
    pub projector_corners: Vec<usize>,
}

/// One capture's decoded correspondences, as the rig solver takes them.
pub struct RigCapture<'a> {
    pub name: String,
    pub camera: &'a CameraIntrinsics,
    /// Every projector's `(width, height)`.
    pub projectors: Vec<(u32, u32)>,
    pub decodes: &'a [ProjectorDecode],
}

/// The correspondences of pixels bright enough for the fixed contrast threshold: the rig is
/// solved on these (faint pixels carry several times the noise and are only triangulated).
pub fn bright_maps(decodes: &[ProjectorDecode], min_contrast: f32) -> Vec<Vec<[f32; 2]>> {
    decodes
        .iter()
        .map(|d| {
            d.pairs()
                .iter()
                .zip(&d.contrast)
                .map(|(&c, &k)| if k > min_contrast { c } else { [f32::NAN; 2] })
                .collect()
        })
        .collect()
}

impl RigProjector {
    /// Projector `k` of a solved rig, with its epipolar residual over all the captures'
    /// decoded pixels (the yardstick of the moved check).
    fn new(
        camera: &CameraIntrinsics,
        g: &ProjectorGeometry,
        captures: &[RigCapture],
        k: usize,
        conditioning: Conditioning,
        rms_px: f64,
    ) -> Self {
        let residuals: Vec<f64> =
            captures.iter().flat_map(|c| epipolar_residuals(camera, g, &c.decodes[k].pairs())).collect();
        Self {
            width: g.width,
            height: g.height,
            f: g.f,
            cx: g.cx,
            cy: g.cy,
            rotation: g.rotation_rows(),
            translation: [g.translation.x, g.translation.y, g.translation.z],
            conditioning,
            rms_px,
            epipolar_median_px: median(residuals),
        }
    }

    pub fn geometry(&self) -> ProjectorGeometry {
        ProjectorGeometry {
            width: self.width,
            height: self.height,
            f: self.f,
            cx: self.cx,
            cy: self.cy,
            rotation: Matrix3::from_fn(|r, c| self.rotation[r][c]),
            translation: Vector3::from(self.translation),
        }
    }
}

impl Rig {
    /// Solves the rig from captures made through it (see [`selfcal::self_calibrate_poses`]),
    /// scaled by `known` if a length was measured.
    pub fn calibrate(
        captures: &[RigCapture],
        params: &SelfCalParams,
        min_contrast: f32,
        known: Option<&KnownLength>,
    ) -> Result<Self, CalibrateError> {
        let first = captures.first().ok_or_else(|| CalibrateError::BadInput {
            path: PathBuf::new(),
            problem: "no captures to calibrate the rig from".into(),
        })?;
        for c in &captures[1..] {
            same_rig(first, c)
                .map_err(|problem| CalibrateError::BadInput { path: PathBuf::from(&c.name), problem })?;
        }
        let maps: Vec<Vec<Vec<[f32; 2]>>> =
            captures.iter().map(|c| bright_maps(c.decodes, min_contrast)).collect();
        let obs: Vec<Vec<ProjectorObservations>> = captures
            .iter()
            .zip(&maps)
            .map(|(c, m)| {
                c.projectors
                    .iter()
                    .zip(m)
                    .map(|(&(width, height), m)| ProjectorObservations { width, height, map: m })
                    .collect()
            })
            .collect();
        let poses: Vec<&[ProjectorObservations]> = obs.iter().map(Vec::as_slice).collect();
        let mut cal = selfcal::self_calibrate_poses(first.camera, &poses, params)?;
        let (units, scale) = match known {
            Some(k) => (RigUnits::Millimetres, selfcal::scale_for(&cal.projectors, k)?),
            None => (RigUnits::Baseline, 1.0),
        };
        for g in &mut cal.projectors {
            g.translation *= scale;
        }
        let projectors = cal
            .projectors
            .iter()
            .enumerate()
            .map(|(k, g)| {
                let mut conditioning = cal.conditioning[k].clone();
                conditioning.translation_std *= scale;
                RigProjector::new(first.camera, g, captures, k, conditioning, cal.per_projector_rms_px[k])
            })
            .collect();
        Ok(Self {
            version: RIG_VERSION,
            camera: first.camera.clone(),
            units,
            projectors,
            rms_px: cal.rms_px,
            captures: captures.iter().map(|c| c.name.clone()).collect(),
            warnings: cal.warnings,
            provenance: format!(
                "restage rig {} from {} capture(s)",
                env!("CARGO_PKG_VERSION"),
                captures.len()
            ),
            board: None,
        })
    }

    /// The rig of a board calibration ([`super::board::calibrate`]) of `captures`, with each
    /// projector's epipolar residual over all their decoded pixels (not only the corners).
    pub fn from_board(captures: &[RigCapture], board: &Board, cal: BoardCalibration) -> Self {
        let projectors = cal
            .projectors
            .iter()
            .enumerate()
            .map(|(k, g)| {
                RigProjector::new(
                    &cal.camera,
                    g,
                    captures,
                    k,
                    cal.conditioning[k].clone(),
                    cal.projector_rms_px[k],
                )
            })
            .collect();
        let n: usize = cal.projector_corners.iter().sum();
        let sum2: f64 =
            cal.projector_rms_px.iter().zip(&cal.projector_corners).map(|(r, &c)| r * r * c as f64).sum();
        Self {
            version: RIG_VERSION,
            camera: cal.camera,
            units: RigUnits::Millimetres,
            projectors,
            rms_px: (sum2 / n.max(1) as f64).sqrt(),
            captures: captures.iter().map(|c| c.name.clone()).collect(),
            warnings: Vec::new(),
            provenance: format!(
                "restage rig {} from {} poses of a {}x{} chessboard ({} mm squares)",
                env!("CARGO_PKG_VERSION"),
                captures.len(),
                board.cols,
                board.rows,
                board.square_mm
            ),
            board: Some(BoardFit {
                cols: board.cols,
                rows: board.rows,
                square_mm: board.square_mm,
                poses: cal.poses.len(),
                camera_std: cal.camera_std,
                camera_rms_px: cal.camera_rms_px,
                projector_corners: cal.projector_corners,
            }),
        }
    }

    /// Every projector's geometry, translations in millimetres: the rig's own scale, or
    /// `known`'s when a length is given (it overrides the rig's).
    pub fn geometry(&self, known: Option<&KnownLength>) -> Result<Vec<ProjectorGeometry>, CalibrateError> {
        let mut geo: Vec<ProjectorGeometry> = self.projectors.iter().map(RigProjector::geometry).collect();
        let scale = match (known, self.units) {
            (Some(k), _) => selfcal::scale_for(&geo, k)?,
            (None, RigUnits::Millimetres) => 1.0,
            (None, RigUnits::Baseline) => {
                return Err(CalibrateError::KnownLength(
                    "the rig was calibrated without a measured length (its units are projector 0's baseline); \
                     give the camera-to-projector distance"
                        .into(),
                ));
            }
        };
        for g in &mut geo {
            g.translation *= scale;
        }
        Ok(geo)
    }

    /// Checks a capture against the rig: same camera, same projectors, and every projector's
    /// correspondences on the epipolar lines the rig predicts. Returns the median epipolar
    /// residual per projector; a projector moved since is an error that names it.
    pub fn check(
        &self,
        camera: &CameraIntrinsics,
        sizes: &[(u32, u32)],
        decodes: &[ProjectorDecode],
        path: &Path,
    ) -> Result<Vec<f64>, CalibrateError> {
        let bad = |problem: String| CalibrateError::BadInput { path: path.to_path_buf(), problem };
        if *camera != self.camera {
            return Err(bad(format!(
                "the capture's camera {:?} is not the rig's {:?}: a rig holds for one camera, lens and zoom",
                camera, self.camera
            )));
        }
        if decodes.len() != self.projectors.len() {
            return Err(bad(format!("{} projectors, the rig has {}", decodes.len(), self.projectors.len())));
        }
        let mut medians = Vec::new();
        let mut moved = Vec::new();
        for (k, ((d, p), &(w, h))) in decodes.iter().zip(&self.projectors).zip(sizes).enumerate() {
            if (w, h) != (p.width, p.height) {
                return Err(bad(format!("projector {k} is {w}x{h}, the rig's is {}x{}", p.width, p.height)));
            }
            let m = median(epipolar_residuals(camera, &p.geometry(), &d.pairs()));
            tracing::info!(
                "projector {k}: median epipolar residual {m:.3} px against the rig ({:.3} px when calibrated)",
                p.epipolar_median_px
            );
            // NaN (the projector sees nothing here) has nothing to check.
            if m > MOVED_MIN_PX.max(MOVED_FACTOR * p.epipolar_median_px) {
                moved.push(format!(
                    "projector {k} lies {m:.2} px off the epipolar lines the rig predicts ({:.2} px when calibrated)",
                    p.epipolar_median_px
                ));
            }
            medians.push(m);
        }
        // A turn that moves a projector's light along its epipolar lines (a side projector
        // turned left or right) keeps that check quiet but makes it disagree with the other
        // projectors about depth: each pair's two-view residual, where both see the surface.
        if moved.is_empty() {
            let geo: Vec<ProjectorGeometry> = self.projectors.iter().map(RigProjector::geometry).collect();
            let maps: Vec<Vec<[f32; 2]>> = decodes.iter().map(ProjectorDecode::pairs).collect();
            let pairs = pair_residuals(camera, &geo, &maps);
            let limit = |j: usize, k: usize| {
                MOVED_MIN_PX.max(MOVED_FACTOR * self.projectors[j].rms_px.max(self.projectors[k].rms_px))
            };
            let bad: Vec<(usize, usize, f64)> =
                pairs.iter().copied().filter(|&(j, k, m)| m > limit(j, k)).collect();
            for &(j, k, m) in &pairs {
                tracing::info!("projectors {j} and {k}: median two-view residual {m:.3} px against the rig");
            }
            // Name the projector every disagreeing pair has in common, if there is one.
            let culprit = (0..geo.len()).find(|&p| {
                let with = |&&(j, k, _): &&(usize, usize, f64)| j == p || k == p;
                !bad.is_empty()
                    && bad.iter().all(|b| with(&b))
                    && pairs.iter().filter(with).all(|q| bad.contains(q))
            });
            match (culprit, bad.as_slice()) {
                (_, []) => {}
                (Some(p), _) if geo.len() > 2 => moved.push(format!(
                    "projector {p} (it disagrees about depth with every other projector: {})",
                    bad.iter().map(|(j, k, m)| format!("{j}-{k} {m:.2} px")).collect::<Vec<_>>().join(", ")
                )),
                _ => moved.push(format!(
                    "one of the projectors in {} (their depths disagree)",
                    bad.iter().map(|(j, k, m)| format!("{j}-{k} {m:.2} px")).collect::<Vec<_>>().join(", ")
                )),
            }
        }
        if !moved.is_empty() {
            return Err(CalibrateError::RigMoved { moved: moved.join(", ") });
        }
        Ok(medians)
    }

    pub fn save(&self, dir: &Path) -> Result<PathBuf, CalibrateError> {
        let path = dir.join(RIG_FILE);
        let text = serde_json::to_string_pretty(self).expect("a rig serialises");
        std::fs::write(&path, text).map_err(|source| CalibrateError::Write { path: path.clone(), source })?;
        Ok(path)
    }

    /// Reads `rig.json`, or the `rig.json` inside a folder.
    pub fn load(path: &Path) -> Result<Self, CalibrateError> {
        let path = if path.is_dir() { path.join(RIG_FILE) } else { path.to_path_buf() };
        let bad = |problem: String| CalibrateError::BadInput { path: path.clone(), problem };
        let text = std::fs::read_to_string(&path).map_err(|e| bad(format!("cannot read the rig: {e}")))?;
        let rig: Self = serde_json::from_str(&text).map_err(|e| bad(format!("not a rig file: {e}")))?;
        if rig.version != RIG_VERSION {
            return Err(bad(format!(
                "rig version {} is not supported (expected {RIG_VERSION})",
                rig.version
            )));
        }
        rig.camera.check().map_err(&bad)?;
        if rig.projectors.is_empty() {
            return Err(bad("the rig has no projectors".into()));
        }
        for (k, p) in rig.projectors.iter().enumerate() {
            let finite = [p.f, p.cx, p.cy]
                .iter()
                .chain(p.translation.iter())
                .chain(p.rotation.iter().flatten())
                .all(|v| v.is_finite());
            let r = p.geometry().rotation;
            if !finite || p.f <= 0.0 || (r * r.transpose() - Matrix3::identity()).norm() > 1e-6 {
                return Err(bad(format!("projector {k}'s geometry is not a valid pinhole pose")));
            }
        }
        Ok(rig)
    }
}

/// Whether two captures can have been made through one rig: the same camera and the same
/// projectors (count and sizes).
fn same_rig(a: &RigCapture, b: &RigCapture) -> Result<(), String> {
    if a.camera != b.camera {
        return Err(format!("its camera {:?} differs from the first capture's {:?}", b.camera, a.camera));
    }
    if a.projectors != b.projectors || b.decodes.len() != b.projectors.len() {
        return Err(format!(
            "its projectors {:?} differ from the first capture's {:?}",
            b.projectors, a.projectors
        ));
    }
    Ok(())
}

/// Distance (projector px) of each decoded correspondence from the epipolar line the
/// geometry predicts for its camera pixel (a regular subsample of at most ~20,000).
pub fn epipolar_residuals(cam: &CameraIntrinsics, g: &ProjectorGeometry, map: &[[f32; 2]]) -> Vec<f64> {
    let decoded = map.iter().filter(|m| m[0].is_finite() && m[1].is_finite()).count();
    let stride = (decoded / 20_000).max(1);
    let t = g.translation;
    let tx = Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
    let kp = Matrix3::new(g.f, 0.0, g.cx, 0.0, g.f, g.cy, 0.0, 0.0, 1.0);
    let Some(kinv) = kp.try_inverse() else { return Vec::new() };
    // Lines in projector pixels: l = K_p^-T [t]x R x_c.
    let f = kinv.transpose() * tx * g.rotation;
    let w = cam.width as usize;
    map.iter()
        .enumerate()
        .filter(|(_, m)| m[0].is_finite() && m[1].is_finite())
        .step_by(stride)
        .map(|(i, m)| {
            let ray = selfcal::camera_ray(cam, (i % w) as f64, (i / w) as f64);
            let l = f * ray;
            (l.x * m[0] as f64 + l.y * m[1] as f64 + l.z).abs() / l.x.hypot(l.y).max(1e-30)
        })
        .collect()
}

/// For every pair of projectors that both see some surface: the median over those camera
/// pixels (a regular subsample) of the RMS reprojection residual (projector px) of the depth
/// triangulated from that pair alone. Pairs seeing fewer than 50 common pixels are left out.
pub fn pair_residuals(
    cam: &CameraIntrinsics,
    geo: &[ProjectorGeometry],
    maps: &[Vec<[f32; 2]>],
) -> Vec<(usize, usize, f64)> {
    let w = cam.width as usize;
    let pixels = maps.first().map_or(0, Vec::len);
    let stride = (pixels / 40_000).max(1);
    let mut out = Vec::new();
    for j in 0..geo.len() {
        for k in j + 1..geo.len() {
            let res: Vec<f64> = (0..pixels)
                .step_by(stride)
                .filter_map(|i| {
                    let (a, b) = (maps[j][i], maps[k][i]);
                    if !(a[0].is_finite() && b[0].is_finite()) {
                        return None;
                    }
                    let ray = selfcal::camera_ray(cam, (i % w) as f64, (i / w) as f64);
                    let obs = [(j, [a[0] as f64, a[1] as f64]), (k, [b[0] as f64, b[1] as f64])];
                    let (_, r) = super::triangulate::solve_depth(geo, &ray, &obs)?;
                    Some((r.iter().map(|e| e * e).sum::<f64>() / 2.0).sqrt())
                })
                .collect();
            if res.len() >= 50 {
                out.push((j, k, median(res)));
            }
        }
    }
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::selfcal::tests::{synthetic, test_camera, three_projectors};

    fn decodes(truth: &[ProjectorGeometry], maps: Vec<Vec<[f32; 2]>>) -> Vec<ProjectorDecode> {
        truth
            .iter()
            .zip(maps)
            .map(|(g, m)| ProjectorDecode {
                width: g.width,
                height: g.height,
                x: m.iter().map(|p| p[0]).collect(),
                y: m.iter().map(|p| p[1]).collect(),
                contrast: vec![1.0; m.len()],
                response: None,
                quality: Default::default(),
            })
            .collect()
    }

    #[test]
    fn a_saved_rig_reads_back_and_names_a_moved_projector() {
        let cam = test_camera();
        let truth = three_projectors();
        let d = decodes(&truth, synthetic(&cam, &truth, 0.05, false, 31));
        let cap =
            RigCapture { name: "round".into(), camera: &cam, projectors: vec![(800, 600); 3], decodes: &d };
        let known = KnownLength::Baseline { projector: 0, mm: truth[0].centre().norm() };
        let rig = Rig::calibrate(
            &[cap],
            &SelfCalParams { max_points: 3000, ..Default::default() },
            0.0,
            Some(&known),
        )
        .unwrap();
        assert_eq!(rig.units, RigUnits::Millimetres);
        let dir = tempfile::tempdir().unwrap();
        rig.save(dir.path()).unwrap();
        let back = Rig::load(dir.path()).unwrap();
        assert_eq!((back.units, &back.camera, back.projectors.len()), (rig.units, &rig.camera, 3));
        for (a, b) in back.projectors.iter().zip(&rig.projectors) {
            assert!(
                (a.geometry().centre() - b.geometry().centre()).norm() < 1e-9 && (a.f - b.f).abs() < 1e-9
            );
        }
        for (g, t) in back.geometry(None).unwrap().iter().zip(&truth) {
            assert!((g.centre() - t.centre()).norm() < 2.0, "{} vs {}", g.centre(), t.centre());
        }

        // A new scene through the same rig passes the check ...
        let other = decodes(&truth, synthetic(&cam, &truth, 0.05, true, 32));
        let medians = rig.check(&cam, &[(800, 600); 3], &other, Path::new("flat")).unwrap();
        assert!(medians.iter().all(|&m| m < 0.2), "{medians:?}");
        // ... and the same scene after projector 1 was turned by half a degree does not.
        let mut knocked = truth.clone();
        knocked[1].rotation = nalgebra::Rotation3::from_euler_angles(0.0, 0.5f64.to_radians(), 0.0).matrix()
            * knocked[1].rotation;
        let moved = decodes(&truth, synthetic(&cam, &knocked, 0.05, true, 33));
        let err = rig.check(&cam, &[(800, 600); 3], &moved, Path::new("flat")).unwrap_err().to_string();
        assert!(
            err.contains("projector 1") && !err.contains("projector 0") && !err.contains("projector 2"),
            "{err}"
        );
    }

    #[test]
    fn a_rig_without_a_length_needs_one_and_a_broken_file_is_named() {
        let cam = test_camera();
        let truth = three_projectors();
        let d = decodes(&truth, synthetic(&cam, &truth, 0.05, false, 34));
        let cap =
            RigCapture { name: "round".into(), camera: &cam, projectors: vec![(800, 600); 3], decodes: &d };
        let rig =
            Rig::calibrate(&[cap], &SelfCalParams { max_points: 2000, ..Default::default() }, 0.0, None)
                .unwrap();
        assert_eq!(rig.units, RigUnits::Baseline);
        assert!(rig.geometry(None).unwrap_err().to_string().contains("distance"));
        let mm = rig.geometry(Some(&KnownLength::Baseline { projector: 0, mm: 800.0 })).unwrap();
        assert!((mm[0].translation.norm() - 800.0).abs() < 1e-9);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(RIG_FILE);
        std::fs::write(&path, "{\"version\": 1}").unwrap();
        let err = Rig::load(&path).unwrap_err().to_string();
        assert!(err.contains("rig.json") && err.contains("not a rig file"), "{err}");
        let mut bent = rig.clone();
        bent.projectors[0].rotation[0][0] = 3.0;
        bent.save(dir.path()).unwrap();
        assert!(Rig::load(dir.path()).unwrap_err().to_string().contains("projector 0"));
    }
}
