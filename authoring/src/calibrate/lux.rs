//! Lux calibration: the conservator's lux-meter reading at a reference point with one
//! projector at full white, turned into that projector's `lux_at_1m` through the calibrated
//! geometry (distance, vignetting, meter orientation).
//!
//! Input: `--lux-white 0=420,1=395,2=410` (projector=lux), or a TOML file:
//! ```toml
//! reference_pixel = [812, 604]    # optional: camera pixel of the meter's position
//! meter = "facing-projector"      # or "on-surface" (meter lying on the object's surface)
//! ambient = 2.5                   # optional: reading with every projector black, subtracted
//! [white]                         # projector index = reading at full white, lux
//! 0 = 420
//! 1 = 395
//! ```
//! Without `reference_pixel` the reference is the surface point the projector lights nearest
//! the camera's principal point. A `reference_pixel` that decoded no surface point (dark paint
//! decodes patchily) falls back to the nearest well-decoded pixel the projector lights, within
//! [`FALLBACK_RADIUS`] of the image diagonal; the fit records both pixels and warns. Without `ambient`, the whole reading is taken as the
//! projector's full white including its black level, which errs towards more lux (safe).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use thiserror::Error;

use crate::calibrate::radiometry::vignetting_at;
use crate::stage_model::StageModel;

#[derive(Debug, Error)]
pub enum LuxError {
    #[error("lux readings {text:?}: {problem} (expected e.g. 0=420,1=395,2=410)")]
    Parse { text: String, problem: String },
    #[error("cannot read lux file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("lux file {path}: {source}")]
    Toml { path: PathBuf, source: toml::de::Error },
    #[error(
        "lux reading for projector {projector} is {lux} lx (expected > 0 and above the ambient {ambient} lx)"
    )]
    Value { projector: usize, lux: f64, ambient: f64 },
    #[error("lux reading for projector {projector}, but the stage has {count} projectors (expected 0..={})", count - 1)]
    NoSuchProjector { projector: usize, count: usize },
    #[error("no lux reading for projector(s) {missing:?} (every projector needs one)")]
    Missing { missing: Vec<usize> },
    #[error("projector {projector}: reference pixel {pixel:?} {problem}")]
    Reference { projector: usize, pixel: Option<[u32; 2]>, problem: String },
}

/// How the meter's sensor faced during the reading.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[serde(deny_unknown_fields)]
pub enum Meter {
    /// Sensor pointed at the projector's lens (cos theta = 1): the usual way.
    #[default]
    FacingProjector,
    /// Sensor lying on the object's surface (cos theta from the surface normal).
    OnSurface,
}

/// The conservator's readings.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LuxReadings {
    /// Projector index -> lux at full white.
    pub white: BTreeMap<usize, f64>,
    #[serde(default)]
    pub ambient: Option<f64>,
    #[serde(default)]
    pub reference_pixel: Option<[u32; 2]>,
    #[serde(default)]
    pub meter: Meter,
}

impl LuxReadings {
    /// Parses `0=420,1=395,2=410`.
    pub fn parse(text: &str) -> Result<Self, LuxError> {
        let err = |problem: String| LuxError::Parse { text: text.into(), problem };
        let mut white = BTreeMap::new();
        for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (k, v) = part.split_once('=').ok_or_else(|| err(format!("{part:?} has no '='")))?;
            let k: usize = k.trim().parse().map_err(|_| err(format!("{k:?} is not a projector index")))?;
            let v: f64 = v.trim().parse().map_err(|_| err(format!("{v:?} is not a number of lux")))?;
            if white.insert(k, v).is_some() {
                return Err(err(format!("projector {k} is given twice")));
            }
        }
        if white.is_empty() {
            return Err(err("no readings".into()));
        }
        Ok(Self { white, ..Default::default() })
    }

    /// Reads the TOML file described in the module documentation.
    pub fn load(path: &Path) -> Result<Self, LuxError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| LuxError::Io { path: path.into(), source })?;
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            white: BTreeMap<String, f64>,
            #[serde(default)]
            ambient: Option<f64>,
            #[serde(default)]
            reference_pixel: Option<[u32; 2]>,
            #[serde(default)]
            meter: Meter,
        }
        let f: File = toml::from_str(&text).map_err(|source| LuxError::Toml { path: path.into(), source })?;
        let mut white = BTreeMap::new();
        for (k, v) in f.white {
            let idx = k.parse().map_err(|_| LuxError::Parse {
                text: path.display().to_string(),
                problem: format!("[white] key {k:?} is not a projector index"),
            })?;
            white.insert(idx, v);
        }
        Ok(Self { white, ambient: f.ambient, reference_pixel: f.reference_pixel, meter: f.meter })
    }
}

/// How far from the requested reference pixel a substitute may lie, as a share of the camera
/// image's diagonal: a few centimetres on a typical object, where the meter's reading still
/// holds (the projector's light varies slowly across the surface).
pub const FALLBACK_RADIUS: f64 = 0.03;
/// Of a substitute reference pixel's 3x3 neighbours (inside the image), at least this share must
/// also be surface points the projector lights, so an isolated lucky decode is not chosen.
pub const FALLBACK_NEIGHBOURS: f64 = 0.75;

/// What one projector's lux calibration used, for the report.
#[derive(Clone, Debug, PartialEq)]
pub struct LuxFit {
    pub projector: usize,
    pub reading: f64,
    /// The camera pixel the conservator named (None: chosen near the principal point).
    pub requested_pixel: Option<[u32; 2]>,
    /// The camera pixel the fit used: the requested one, or the nearest well-decoded pixel the
    /// projector lights when the requested one decoded no surface point.
    pub reference_pixel: [u32; 2],
    /// Distance from the requested to the used pixel, camera pixels (0 when used as given).
    pub moved_px: f64,
    pub distance_mm: f64,
    pub cos_theta: f64,
    pub vignetting: f64,
    pub lux_at_1m: f64,
}

/// Sets every projector's `lux_at_1m` in `model` from `readings` (geometry, correspondences
/// and black levels must already be calibrated).
pub fn apply_lux(model: &mut StageModel, readings: &LuxReadings) -> Result<Vec<LuxFit>, LuxError> {
    let count = model.projectors.len();
    if let Some(&projector) = readings.white.keys().find(|&&k| k >= count) {
        return Err(LuxError::NoSuchProjector { projector, count });
    }
    let missing: Vec<usize> = (0..count).filter(|k| !readings.white.contains_key(k)).collect();
    if !missing.is_empty() {
        return Err(LuxError::Missing { missing });
    }
    let ambient = readings.ambient.unwrap_or(0.0);
    let mut fits = Vec::new();
    for (&k, &lux) in &readings.white {
        if !(lux.is_finite() && lux > ambient && ambient >= 0.0) {
            return Err(LuxError::Value { projector: k, lux, ambient });
        }
        let fit = fit_one(model, k, lux - ambient, readings)?;
        if let Some(req) = fit.requested_pixel.filter(|&r| r != fit.reference_pixel) {
            tracing::warn!(
                "projector {k}: lux reference pixel ({}, {}) is not a reconstructed surface point \
                 this projector lights; using the nearest well-decoded one, ({}, {}), {:.1} px away",
                req[0],
                req[1],
                fit.reference_pixel[0],
                fit.reference_pixel[1],
                fit.moved_px
            );
        }
        // Without an ambient reading, the reading also holds this projector's black level.
        let black = if readings.ambient.is_some() {
            0.0
        } else {
            let b = model.projectors[k].black;
            crate::color::luminance(b.map(f64::from))
        };
        let lux_at_1m = fit.lux_at_1m / (1.0 + black);
        model.projectors[k].lux_at_1m = lux_at_1m;
        fits.push(LuxFit { reading: lux, lux_at_1m, ..fit });
    }
    Ok(fits)
}

fn fit_one(model: &StageModel, k: usize, lux: f64, readings: &LuxReadings) -> Result<LuxFit, LuxError> {
    let (w, h) = (model.camera.width, model.camera.height);
    let p = &model.projectors[k];
    let corr = &model.correspondences[k];
    let centre = p.centre();
    // Distance and cosine at camera pixel i, if the projector lights a known surface point there.
    let geometry = |i: usize| -> Option<(f64, f64)> {
        let (x, n) = (model.points[i], model.normals[i]);
        if !(x[0].is_finite() && corr[i][0].is_finite()) {
            return None;
        }
        let to: [f64; 3] = std::array::from_fn(|j| centre[j] - x[j] as f64);
        let d = (to[0] * to[0] + to[1] * to[1] + to[2] * to[2]).sqrt();
        let cos = (n[0] as f64 * to[0] + n[1] as f64 * to[1] + n[2] as f64 * to[2]) / d;
        (cos > 0.05).then_some((d, cos))
    };
    let pixel = match readings.reference_pixel {
        Some(px) => {
            if px[0] >= w || px[1] >= h {
                return Err(LuxError::Reference {
                    projector: k,
                    pixel: Some(px),
                    problem: format!("is outside the {w}x{h} camera image"),
                });
            }
            let i = px[1] as usize * w as usize + px[0] as usize;
            if geometry(i).is_some() {
                px
            } else {
                let radius = FALLBACK_RADIUS * f64::from(w).hypot(f64::from(h));
                nearest_well_decoded(w, h, px, radius, &|i| geometry(i).is_some()).ok_or_else(|| {
                    LuxError::Reference {
                        projector: k,
                        pixel: Some(px),
                        problem: format!(
                            "is not on a reconstructed surface point this projector lights, nor is \
                             any well-decoded pixel within {radius:.0} px ({:.0} % of the image \
                             diagonal); name a pixel on the lit, decoded surface",
                            100.0 * FALLBACK_RADIUS
                        ),
                    }
                })?
            }
        }
        None => {
            let (cx, cy) = (model.camera.cx, model.camera.cy);
            (0..w as usize * h as usize)
                .filter(|&i| geometry(i).is_some())
                .min_by(|&a, &b| {
                    let da = ((a % w as usize) as f64 - cx).powi(2) + ((a / w as usize) as f64 - cy).powi(2);
                    let db = ((b % w as usize) as f64 - cx).powi(2) + ((b / w as usize) as f64 - cy).powi(2);
                    da.total_cmp(&db).then(a.cmp(&b))
                })
                .map(|i| [(i % w as usize) as u32, (i / w as usize) as u32])
                .ok_or(LuxError::Reference {
                    projector: k,
                    pixel: None,
                    problem: "cannot be chosen: the projector lights no reconstructed surface".into(),
                })?
        }
    };
    let i = pixel[1] as usize * w as usize + pixel[0] as usize;
    let (d, cos) = geometry(i).ok_or(LuxError::Reference {
        projector: k,
        pixel: Some(pixel),
        problem: "is not on a reconstructed surface point this projector lights".into(),
    })?;
    let cos_theta = match readings.meter {
        Meter::FacingProjector => 1.0,
        Meter::OnSurface => cos,
    };
    let vignetting = vignetting_at(p.width, p.height, &p.vignetting, corr[i]);
    let lux_at_1m = lux * (d / 1000.0).powi(2) / (vignetting * cos_theta);
    let moved_px = readings.reference_pixel.map_or(0.0, |r| {
        (f64::from(r[0]) - f64::from(pixel[0])).hypot(f64::from(r[1]) - f64::from(pixel[1]))
    });
    Ok(LuxFit {
        projector: k,
        reading: lux,
        requested_pixel: readings.reference_pixel,
        reference_pixel: pixel,
        moved_px,
        distance_mm: d,
        cos_theta,
        vignetting,
        lux_at_1m,
    })
}

/// The pixel nearest `from` (Euclidean, within `radius`, ties to the lower row then column)
/// where `valid` holds and at least [`FALLBACK_NEIGHBOURS`] of its in-image 3x3 neighbours also
/// hold.
fn nearest_well_decoded(
    w: u32,
    h: u32,
    from: [u32; 2],
    radius: f64,
    valid: &dyn Fn(usize) -> bool,
) -> Option<[u32; 2]> {
    let r = radius.floor().max(0.0) as i64;
    let (w, h) = (i64::from(w), i64::from(h));
    let (fx, fy) = (i64::from(from[0]), i64::from(from[1]));
    let well = |x: i64, y: i64| -> bool {
        if !valid((y * w + x) as usize) {
            return false;
        }
        let (mut inside, mut ok) = (0u32, 0u32);
        for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
            let (nx, ny) = (x + dx, y + dy);
            if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w || ny >= h {
                continue;
            }
            inside += 1;
            ok += u32::from(valid((ny * w + nx) as usize));
        }
        f64::from(ok) >= FALLBACK_NEIGHBOURS * f64::from(inside)
    };
    let mut best: Option<(i64, i64, i64)> = None;
    for y in (fy - r).max(0)..=(fy + r).min(h - 1) {
        for x in (fx - r).max(0)..=(fx + r).min(w - 1) {
            let d2 = (x - fx).pow(2) + (y - fy).pow(2);
            if (d2 as f64) > radius * radius || best.is_some_and(|(b, _, _)| b <= d2) {
                continue;
            }
            if well(x, y) {
                best = Some((d2, x, y));
            }
        }
    }
    best.map(|(_, x, y)| [x as u32, y as u32])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture_set::CameraIntrinsics;
    use crate::stage_model::{ProjectorModel, Transport};

    /// A flat wall 1500 mm in front of the camera; one projector 200 mm to the right, looking
    /// along +z.
    fn wall() -> StageModel {
        let (w, h) = (20u32, 10u32);
        let n = (w * h) as usize;
        let camera = CameraIntrinsics {
            width: w,
            height: h,
            fx: 20.0,
            fy: 20.0,
            cx: 9.5,
            cy: 4.5,
            distortion: [0.0; 5],
        };
        let mut points = Vec::new();
        let mut corr = Vec::new();
        for i in 0..n {
            let (x, y) = ((i as u32 % w) as f64, (i as u32 / w) as f64);
            let p = [(x - 9.5) / 20.0 * 1500.0, (y - 4.5) / 20.0 * 1500.0, 1500.0];
            points.push(p.map(|v| v as f32));
            corr.push([((p[0] - 200.0) / 1500.0 * 30.0 + 16.0) as f32, (p[1] / 1500.0 * 30.0 + 12.0) as f32]);
        }
        StageModel {
            camera,
            projectors: vec![ProjectorModel {
                width: 32,
                height: 24,
                f: 30.0,
                cx: 16.0,
                cy: 12.0,
                rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                translation: [-200.0, 0.0, 0.0],
                response: std::array::from_fn(|_| (0..256).map(|v| v as f32 / 255.0).collect()),
                black: [0.02; 3],
                lux_at_1m: 0.0,
                vignetting: vec![],
            }],
            points,
            normals: vec![[0.0, 0.0, -1.0]; n],
            correspondences: vec![corr],
            transport: vec![Transport::default()],
            gain: vec![],
            ambient: vec![],
            provenance: "test".into(),
        }
    }

    #[test]
    fn parses_the_command_line_form() {
        let r = LuxReadings::parse("0=420, 1=395,2=410.5").unwrap();
        assert_eq!(r.white.len(), 3);
        assert_eq!(r.white[&2], 410.5);
        for bad in ["", "0:420", "x=3", "0=abc", "0=1,0=2"] {
            let e = LuxReadings::parse(bad).unwrap_err().to_string();
            assert!(e.contains("expected e.g."), "{bad}: {e}");
        }
    }

    #[test]
    fn reading_gives_the_intensity_by_inverse_square() {
        let mut m = wall();
        // Reference pixel (9, 4) is about 1.5 m from the projector, seen at an angle.
        let readings = LuxReadings {
            white: [(0, 300.0)].into(),
            ambient: Some(10.0),
            reference_pixel: Some([9, 4]),
            meter: Meter::FacingProjector,
        };
        let fits = apply_lux(&mut m, &readings).unwrap();
        let x = m.points[4 * 20 + 9];
        let d = (((x[0] - 200.0) as f64).powi(2) + (x[1] as f64).powi(2) + (x[2] as f64).powi(2)).sqrt();
        let want = 290.0 * (d / 1000.0).powi(2);
        assert!((m.projectors[0].lux_at_1m - want).abs() < 1e-6 * want, "{fits:?}");
        // On the surface the cosine enters, raising the intensity needed for the same reading.
        let on_surface = LuxReadings { meter: Meter::OnSurface, ..readings };
        apply_lux(&mut m, &on_surface).unwrap();
        assert!(m.projectors[0].lux_at_1m > want);
    }

    #[test]
    fn default_reference_and_black_level() {
        let mut m = wall();
        let fits = apply_lux(&mut m, &LuxReadings::parse("0=300").unwrap()).unwrap();
        assert_eq!(fits[0].reference_pixel[1], 4);
        let d = fits[0].distance_mm;
        let want = 300.0 * (d / 1000.0).powi(2) / 1.02;
        assert!((m.projectors[0].lux_at_1m - want).abs() < 1e-6 * want);
    }

    #[test]
    fn bad_readings_are_refused_with_the_projector() {
        let mut m = wall();
        let e = apply_lux(&mut m, &LuxReadings::parse("1=300").unwrap()).unwrap_err().to_string();
        assert!(e.contains("projector 1") && e.contains("0..=0"), "{e}");
        let e = apply_lux(&mut m, &LuxReadings::parse("0=-3").unwrap()).unwrap_err().to_string();
        assert!(e.contains("projector 0") && e.contains("-3"), "{e}");
        let r = LuxReadings { reference_pixel: Some([50, 2]), ..LuxReadings::parse("0=300").unwrap() };
        let e = apply_lux(&mut m, &r).unwrap_err().to_string();
        assert!(e.contains("outside"), "{e}");
    }

    /// A `w`x`h` camera on the same wall, with every surface point inside `holes` (camera
    /// pixels) knocked out, as undecoded dark paint leaves it.
    fn wall_with_holes(w: u32, h: u32, holes: impl Fn(u32, u32) -> bool) -> StageModel {
        let mut m = wall();
        let n = (w * h) as usize;
        let (cx, cy, f) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w as f64);
        m.camera = CameraIntrinsics { width: w, height: h, fx: f, fy: f, cx, cy, distortion: [0.0; 5] };
        m.points.clear();
        m.correspondences[0].clear();
        for i in 0..n as u32 {
            let (x, y) = (i % w, i / w);
            let p = [(x as f64 - cx) / f * 1500.0, (y as f64 - cy) / f * 1500.0, 1500.0];
            let q = [((p[0] - 200.0) / 1500.0 * 30.0 + 16.0) as f32, (p[1] / 1500.0 * 30.0 + 12.0) as f32];
            m.points.push(if holes(x, y) { [f32::NAN; 3] } else { p.map(|v| v as f32) });
            m.correspondences[0].push(q);
        }
        m.normals = vec![[0.0, 0.0, -1.0]; n];
        m
    }

    /// A 7x7 undecoded square around (100, 50) in a 200x100 image (fallback radius 6.7 px).
    fn square_hole(x: u32, y: u32) -> bool {
        (97..=103).contains(&x) && (47..=53).contains(&y)
    }

    #[test]
    fn reference_on_an_undecoded_hole_falls_back_to_the_nearest_well_decoded_pixel() {
        let readings =
            LuxReadings { reference_pixel: Some([100, 50]), ..LuxReadings::parse("0=300").unwrap() };
        let mut m = wall_with_holes(200, 100, square_hole);
        let fit = apply_lux(&mut m, &readings).unwrap()[0].clone();
        assert_eq!(fit.requested_pixel, Some([100, 50]));
        // Pixels on the hole's rim (4 px away) have undecoded neighbours; the nearest with at
        // least 6 of 8 decoded neighbours are 5 px away, and the tie goes to the upper row.
        assert_eq!(fit.reference_pixel, [100, 45], "{fit:?}");
        assert_eq!(fit.moved_px, 5.0);
        // The fit used the substitute's geometry.
        let x = m.points[45 * 200 + 100];
        let d = (((x[0] - 200.0) as f64).powi(2) + (x[1] as f64).powi(2) + (x[2] as f64).powi(2)).sqrt();
        assert!((fit.distance_mm - d).abs() < 1e-6 * d, "{fit:?}");
        // A decoded reference is used as given.
        let mut m = wall_with_holes(200, 100, |_, _| false);
        let fit = apply_lux(&mut m, &readings).unwrap()[0].clone();
        assert_eq!((fit.reference_pixel, fit.moved_px), ([100, 50], 0.0));
    }

    #[test]
    fn an_isolated_lucky_pixel_is_passed_over() {
        // (100, 48) decoded inside the hole, 2 px from the reference, but all its neighbours
        // are undecoded: not trusted.
        let readings =
            LuxReadings { reference_pixel: Some([100, 50]), ..LuxReadings::parse("0=300").unwrap() };
        let mut m = wall_with_holes(200, 100, |x, y| square_hole(x, y) && (x, y) != (100, 48));
        let fit = &apply_lux(&mut m, &readings).unwrap()[0];
        assert_eq!(fit.reference_pixel, [100, 45], "{fit:?}");
    }

    #[test]
    fn reference_far_from_any_decoded_pixel_is_refused() {
        // Nothing decoded within 6.7 px of (100, 50): the left three quarters are undecoded.
        let readings =
            LuxReadings { reference_pixel: Some([100, 50]), ..LuxReadings::parse("0=300").unwrap() };
        let mut m = wall_with_holes(200, 100, |x, _| x < 150);
        let e = apply_lux(&mut m, &readings).unwrap_err().to_string();
        assert!(e.contains("[100, 50]") && e.contains("projector 0"), "{e}");
        assert!(e.contains("not on a reconstructed surface point") && e.contains("within 7 px"), "{e}");
    }

    #[test]
    fn file_form_loads() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lux.toml");
        std::fs::write(&p, "meter = \"on-surface\"\nambient = 3\n[white]\n0 = 420\n2 = 410\n").unwrap();
        let r = LuxReadings::load(&p).unwrap();
        assert_eq!(r.meter, Meter::OnSurface);
        assert_eq!(r.white[&2], 410.0);
        std::fs::write(&p, "[white]\nzero = 1\n").unwrap();
        assert!(LuxReadings::load(&p).unwrap_err().to_string().contains("zero"));
    }
}
