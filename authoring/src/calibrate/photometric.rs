//! The photometric half of calibration (paper §5.2), run after the geometry step: light
//! transport from the dot grids, responses from the ramps, dark-paint pixels filled and each
//! projector's full light measured again from the Gray-code stripes, then vignetting, black
//! levels, lux scale, per-pixel gain and ambient — all written into the [`StageModel`].
//!
//! Loads the capture's images (the only I/O here), one at a time per worker so memory stays at
//! a few images whatever the number of dots or levels.
//!
//! Two things a camera cannot see directly are modelled: (1) vignetting, taken as a radial
//! falloff `1 - a r^2` about each projector's principal point (normalised at the image centre)
//! with `a` fitted from where projectors overlap (albedo cancels in their ratio); with one
//! projector it stays uniform; (2) black levels and stray room light, fitted together from the
//! all-black image as `black(p) = sum_k b_k lit_k(p) + s gain(p)` (acquisition keeps every
//! other projector black and the room light off).

use std::path::Path;

use rayon::prelude::*;
use thiserror::Error;
use tracing::{info, warn};

use crate::calibrate::fill::{self, FillParams};
use crate::calibrate::fulllight;
use crate::calibrate::lux::{LuxError, LuxFit, LuxReadings, apply_lux};
use crate::calibrate::radiometry::{
    ProjectorRadiometry, RadiometryError, ResponseBuilder, full_irradiance, gain_map,
};
use crate::calibrate::selfcal::ProjectorGeometry;
use crate::calibrate::transport::{
    self, DotSignal, Predictor, RefineStats, SnapContext, SnapParams, TransportError, TransportResult,
    noise_sigma,
};
use crate::calibrate::triangulate::{self, DenseGeometry, TriangulateParams};
use crate::capture_set::{CaptureManifest, Pattern, ProjectorCapture};
use crate::imgio::{ImageError, LinearImage};
use crate::stage_model::StageModel;

#[derive(Debug, Error)]
pub enum PhotometricError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Radiometry(#[from] RadiometryError),
    #[error(transparent)]
    Lux(#[from] LuxError),
    #[error("projector {projector}: the capture has no {what} image")]
    Missing { projector: usize, what: String },
    #[error("projector {projector}: dot images use spacings {spacings:?} (expected one spacing)")]
    MixedSpacing { projector: usize, spacings: Vec<u32> },
    #[error("the stage model has {model} projectors but the capture has {capture}")]
    ProjectorCount { model: usize, capture: usize },
}

/// What the photometric steps report (warnings name projectors and images).
#[derive(Clone, Debug, Default)]
pub struct PhotometricReport {
    pub transport: Vec<TransportSummary>,
    pub radiometry: Vec<ProjectorRadiometry>,
    /// Fitted vignetting coefficient `a` per projector (None: not observable, left uniform).
    pub vignetting: Vec<Option<f64>>,
    /// Stray room light per channel, in lux.
    pub stray_lux: [f32; 3],
    pub lux: Vec<LuxFit>,
    /// Per projector: camera pixels it did not decode that [`fill`] gave its coordinates.
    pub filled: Vec<usize>,
    pub warnings: Vec<String>,
}

/// Per projector: what transport found.
#[derive(Clone, Debug, Default)]
pub struct TransportSummary {
    pub spacing: u32,
    pub dots: usize,
    pub predicted: usize,
    pub off_object: usize,
    pub refine: RefineStats,
    /// Per projector pixel footprint energy (camera pixels' worth), NaN where unmeasured.
    pub footprint: Vec<f32>,
    /// Share of the projector's lit camera pixels that its transport covers.
    pub coverage: f64,
}

/// Hooks for progress: `(stage name, done, total)`.
pub type Progress<'a> = &'a (dyn Fn(&str, usize, usize) + Sync);

fn load(dir: &Path, file: &Path, w: u32, h: u32) -> Result<LinearImage, ImageError> {
    LinearImage::load_sized(&dir.join(file), w, h)
}

fn need<'a>(
    p: &'a ProjectorCapture,
    k: usize,
    pattern: &Pattern,
    what: &str,
) -> Result<&'a Path, PhotometricError> {
    p.find(pattern).ok_or(PhotometricError::Missing { projector: k, what: what.into() })
}

/// Measures one projector's transport from its dot images and refines `correspondence`.
pub fn measure_transport(
    dir: &Path,
    k: usize,
    capture: &ProjectorCapture,
    (cam_w, cam_h): (u32, u32),
    correspondence: &[[f32; 2]],
    params: &SnapParams,
    progress: Progress,
) -> Result<(TransportResult, Vec<[f32; 2]>, RefineStats), PhotometricError> {
    let white_file = need(capture, k, &Pattern::White, "white")?;
    let black = load(dir, need(capture, k, &Pattern::Black, "black")?, cam_w, cam_h)?;
    let white = load(dir, white_file, cam_w, cam_h)?;
    transport::check_reference(k, &black, &white, &white_file.display().to_string(), cam_w, cam_h)?;
    if !correspondence.iter().any(|c| c[0].is_finite()) {
        return Err(TransportError::NoCorrespondence { projector: k }.into());
    }
    let dots: Vec<(u32, u32, u32, &Path)> = capture
        .shots
        .iter()
        .filter_map(|s| match s.pattern {
            Pattern::Dots { spacing, dx, dy } => Some((spacing, dx, dy, s.file.as_path())),
            _ => None,
        })
        .collect();
    let mut spacings: Vec<u32> = dots.iter().map(|d| d.0).collect();
    spacings.sort_unstable();
    spacings.dedup();
    let spacing = match spacings.as_slice() {
        [s] => *s,
        [] => return Err(PhotometricError::Missing { projector: k, what: "dot-grid".into() }),
        _ => return Err(PhotometricError::MixedSpacing { projector: k, spacings }),
    };
    // The black image's spread (channel sums) is the camera noise: the scene is dark.
    let zero = SnapContext {
        width: cam_w,
        height: cam_h,
        black: vec![0.0; black.data.len()],
        lit: vec![],
        lit_min: 0.0,
    };
    let sigma = noise_sigma(&DotSignal::from_linear(&black), &zero);
    let ctx = SnapContext::new(&black, &white, sigma, params);
    drop((black, white));
    let pred = Predictor::new(correspondence, cam_w, capture.width, capture.height);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let images = dots
        .par_iter()
        .map(|&(_, dx, dy, file)| {
            let img = DotSignal::load(&dir.join(file), cam_w, cam_h)?;
            let r = transport::snap_dot_image(&img, &ctx, &pred, spacing, (dx, dy), params);
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(&format!("projector {k}: dots"), n, dots.len());
            Ok((file.display().to_string(), r))
        })
        .collect::<Result<Vec<_>, ImageError>>()?;
    let mut result = transport::assemble(k, capture.width, capture.height, spacing, images)?;
    let filled = transport::fill_missing(&mut result, &ctx, capture.width, capture.height);
    if filled > 0 {
        info!("projector {k}: {filled} footprints of dots not found filled from the dots around them");
    }
    // Dots cut by the silhouette, a shadow or a neighbour's cell have centres pulled off the
    // pixel's: not used to refine.
    let whole: Vec<transport::Dot> = result.dots.iter().filter(|d| !d.clipped).copied().collect();
    let (refined, stats) =
        transport::refine_correspondences(correspondence, cam_w, cam_h, &whole, params.max_refine_shift);
    Ok((result, refined, stats))
}

/// Measures one projector's responses from its ramps; also returns its black image.
pub fn measure_radiometry(
    dir: &Path,
    k: usize,
    capture: &ProjectorCapture,
    (cam_w, cam_h): (u32, u32),
    progress: Progress,
) -> Result<(ProjectorRadiometry, LinearImage), PhotometricError> {
    let black = load(dir, need(capture, k, &Pattern::Black, "black")?, cam_w, cam_h)?;
    let white_file = need(capture, k, &Pattern::White, "white")?;
    // Each channel's full level: its 255 ramp, else the white image.
    let full_files: Vec<&Path> = (0..3u8)
        .map(|channel| capture.find(&Pattern::Ramp { channel, level: 255 }).unwrap_or(white_file))
        .collect();
    let fulls: Vec<LinearImage> =
        full_files.iter().map(|f| load(dir, f, cam_w, cam_h)).collect::<Result<_, _>>()?;
    let names: Vec<String> = full_files.iter().map(|f| f.display().to_string()).collect();
    let zero = SnapContext {
        width: cam_w,
        height: cam_h,
        black: vec![0.0; black.data.len()],
        lit: vec![],
        lit_min: 0.0,
    };
    let min_lit = (10.0 * noise_sigma(&DotSignal::from_linear(&black), &zero) / 3.0f32.sqrt()).max(0.01);
    let mut builder = ResponseBuilder::new(
        k,
        &black,
        [(&fulls[0], names[0].as_str()), (&fulls[1], names[1].as_str()), (&fulls[2], names[2].as_str())],
        min_lit,
    )?;
    drop(fulls);
    let ramps: Vec<(u8, u8, &Path)> = capture
        .shots
        .iter()
        .filter_map(|s| match s.pattern {
            Pattern::Ramp { channel, level } if channel < 3 && level != 0 => {
                Some((channel, level, s.file.as_path()))
            }
            _ => None,
        })
        .collect();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let samples = ramps
        .par_iter()
        .map(|&(channel, level, file)| {
            let img = load(dir, file, cam_w, cam_h)?;
            let s = builder.measure(channel, level, &img, &file.display().to_string())?;
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(&format!("projector {k}: ramps"), n, ramps.len());
            Ok(s)
        })
        .collect::<Result<Vec<_>, PhotometricError>>()?;
    for s in samples {
        builder.insert(s)?;
    }
    Ok((builder.finish()?, black))
}

/// Runs every photometric step on `model` (whose geometry and correspondences are calibrated):
/// transport (refining the correspondences), the points and normals triangulated again from
/// the refined correspondences (returned, for the report), responses, vignetting, black levels
/// and stray light, lux, gain, ambient.
pub fn calibrate_photometry(
    dir: &Path,
    manifest: &CaptureManifest,
    model: &mut StageModel,
    lux: &LuxReadings,
    params: &SnapParams,
    triangulate: &TriangulateParams,
    progress: Progress,
) -> Result<(PhotometricReport, DenseGeometry), PhotometricError> {
    let n = model.projectors.len();
    if manifest.projectors.len() != n {
        return Err(PhotometricError::ProjectorCount { model: n, capture: manifest.projectors.len() });
    }
    let size = (model.camera.width, model.camera.height);
    let mut report = PhotometricReport::default();
    let mut blacks = Vec::new();
    let mut lits = Vec::new();
    for (k, cap) in manifest.projectors.iter().enumerate() {
        let (res, refined, stats) =
            measure_transport(dir, k, cap, size, &model.correspondences[k], params, progress)?;
        info!(
            "projector {k}: {} dots snapped of {} predicted ({} off the object, {} sharing light with a \
             neighbour); {} camera pixels refined, median shift {:.3} px",
            res.dots.len(),
            res.images.iter().map(|(_, r)| r.predicted()).sum::<usize>(),
            res.images.iter().map(|(_, r)| r.off_object).sum::<usize>(),
            res.images.iter().map(|(_, r)| r.shared).sum::<usize>(),
            stats.refined,
            stats.median_shift
        );
        report.warnings.extend(res.warnings.iter().cloned());
        model.correspondences[k] = refined;
        let (rad, black) = measure_radiometry(dir, k, cap, size, progress)?;
        report.warnings.extend(rad.warnings.iter().cloned());
        if rad.max_leakage() > 0.02 {
            report.warnings.push(format!(
                "projector {k}: colour leakage up to {:.1} % between channels (the model assumes none)",
                100.0 * rad.max_leakage()
            ));
        }
        model.projectors[k].response = rad.response.clone();
        let lit: Vec<bool> = rad.lit.iter().map(|l| l[0] + l[1] + l[2] > 0.03).collect();
        let covered = transport::coverage_mask(&res.transport, lit.len());
        let lit_count = lit.iter().filter(|&&l| l).count().max(1);
        let coverage = lit.iter().zip(&covered).filter(|(l, c)| **l && **c).count() as f64 / lit_count as f64;
        report.transport.push(TransportSummary {
            spacing: res.images.first().map_or(0, |_| {
                cap.shots
                    .iter()
                    .find_map(|s| {
                        if let Pattern::Dots { spacing, .. } = s.pattern { Some(spacing) } else { None }
                    })
                    .unwrap_or(0)
            }),
            dots: res.dots.len(),
            predicted: res.images.iter().map(|(_, r)| r.predicted()).sum(),
            off_object: res.images.iter().map(|(_, r)| r.off_object).sum(),
            refine: stats,
            footprint: transport::footprint_energy(&res.transport, cap.width, cap.height),
            coverage,
        });
        model.transport[k] = res.transport;
        lits.push(rad.lit.clone());
        report.radiometry.push(rad);
        blacks.push(black);
    }
    // Pixels a projector did not decode between pixels it did (dark paint, surface turned
    // away from the camera, the silhouette's rim): coordinates fitted to the neighbours, kept
    // where that projector's Gray-code images confirm them, in rounds; the last round's
    // stripes then measure each projector's full light again.
    let (w, h) = (size.0 as usize, size.1 as usize);
    let (filled, sums) = fill::in_rounds(
        w,
        h,
        &mut model.correspondences,
        &FillParams::default(),
        |tentative| fulllight::stripe_sums(dir, manifest, size, tentative, progress),
        |sums, k, i| sums.confirms(k, i, fill::MIN_Z),
    )?;
    for (k, counts) in filled.iter().enumerate() {
        info!(
            "projector {k}: {} coordinates fitted at pixels it did not decode confirmed by its \
             Gray-code images (per round {counts:?})",
            counts.iter().sum::<usize>()
        );
    }
    report.filled = filled.iter().map(|c| c.iter().sum()).collect();
    let refined = sums.refine(&mut lits, 4);
    info!("full light per projector averaged over the Gray-code stripes at {refined:?} camera pixels");
    // The dots moved the correspondences: triangulate again with the same projectors, so that
    // the saved points are the ones the saved correspondences give (one consistent model) and
    // the fits below use them.
    let geometry: Vec<ProjectorGeometry> = model.projectors.iter().map(ProjectorGeometry::from).collect();
    let maps: Vec<&[[f32; 2]]> = model.correspondences.iter().map(Vec::as_slice).collect();
    let dense = triangulate::triangulate(&model.camera, &geometry, &maps, triangulate);
    info!(
        "triangulated again from the refined correspondences: {} points, reprojection RMS {:.3} px",
        dense.valid,
        dense.rms_px()
    );
    model.points = dense.points.clone();
    model.normals = dense.normals.clone();
    // Vignetting from overlaps, then the black levels and stray light, then lux and gain.
    report.vignetting = fit_vignetting(model, &lits, &mut report.warnings);
    let lit_refs: Vec<&[[f32; 3]]> = lits.iter().map(|l| l.as_slice()).collect();
    // `fit_vignetting` left relative intensities (projector 0 = 1) in `lux_at_1m`, so this gain
    // shape is the true gain times projector 0's intensity.
    let shape = gain_map(model, &lit_refs)?;
    let mean_black = crate::calibrate::radiometry::ambient_map(&blacks.iter().collect::<Vec<_>>());
    let (levels, stray) = fit_black(&mean_black, &lit_refs, &shape);
    for (p, b) in model.projectors.iter_mut().zip(&levels) {
        p.black = *b;
    }
    report.lux = apply_lux(model, lux)?;
    for f in &report.lux {
        if let Some(req) = f.requested_pixel.filter(|&r| r != f.reference_pixel) {
            report.warnings.push(format!(
                "projector {}: the lux reference pixel ({}, {}) decoded no surface point this \
                 projector lights; the nearest well-decoded pixel, ({}, {}), {:.1} px away, was used",
                f.projector, req[0], req[1], f.reference_pixel[0], f.reference_pixel[1], f.moved_px
            ));
        }
    }
    model.gain = gain_map(model, &lit_refs)?;
    let lux0 = model.projectors[0].lux_at_1m as f32;
    report.stray_lux = stray.map(|s| s * lux0);
    model.ambient = mean_black
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let g = shape[i];
            if !g[0].is_finite() {
                return *m;
            }
            std::array::from_fn(|c| {
                let mut v = stray[c] * g[c];
                for (k, l) in lit_refs.iter().enumerate() {
                    v += levels[k][c] * l[i][c];
                }
                v
            })
        })
        .collect();
    for w in &report.warnings {
        warn!("{w}");
    }
    Ok((report, dense))
}

/// Least-squares black levels per projector and channel plus a stray-light term, from the
/// all-black image `black(p) = sum_k b_k lit_k(p) + s shape(p)` over pixels some projector lights.
pub fn fit_black(black: &[[f32; 3]], lit: &[&[[f32; 3]]], shape: &[[f32; 3]]) -> (Vec<[f32; 3]>, [f32; 3]) {
    let n = lit.len();
    let m = n + 1;
    let mut levels = vec![[0.0f32; 3]; n];
    let mut stray = [0.0f32; 3];
    for c in 0..3 {
        let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut b = nalgebra::DVector::<f64>::zeros(m);
        let mut row = vec![0.0f64; m];
        for i in 0..black.len() {
            if !shape[i][c].is_finite() {
                continue;
            }
            for k in 0..n {
                row[k] = lit[k][i][c] as f64;
            }
            row[n] = shape[i][c] as f64;
            for r in 0..m {
                for q in 0..m {
                    a[(r, q)] += row[r] * row[q];
                }
                b[r] += row[r] * black[i][c] as f64;
            }
        }
        // A tiny ridge keeps the solve defined when a column is empty.
        let scale = (0..m).map(|r| a[(r, r)]).fold(0.0, f64::max).max(1e-30);
        for r in 0..m {
            a[(r, r)] += 1e-9 * scale;
        }
        if let Some(x) = a.lu().solve(&b) {
            for k in 0..n {
                levels[k][c] = x[k].max(0.0) as f32;
            }
            stray[c] = x[n].max(0.0) as f32;
        }
    }
    (levels, stray)
}

/// Fits each projector's radial vignetting coefficient from the ratios of `lit` where two
/// projectors light the same pixel, and writes the maps into `model`, with the intensities
/// relative to projector 0 in `lux_at_1m`. Returns the coefficients.
pub fn fit_vignetting(
    model: &mut StageModel,
    lits: &[Vec<[f32; 3]>],
    warnings: &mut Vec<String>,
) -> Vec<Option<f64>> {
    let n = model.projectors.len();
    for p in &mut model.projectors {
        p.vignetting = vec![];
        p.lux_at_1m = 1.0;
    }
    if n < 2 {
        warnings.push(
            "one projector: vignetting cannot be separated from albedo and is taken as uniform (the gain \
             absorbs it)"
                .into(),
        );
        return vec![None];
    }
    // rho(u) = |u - principal|^2 / half_diag^2 per projector, and its value at the image centre.
    let rho = |k: usize, u: [f32; 2]| -> f64 {
        let p = &model.projectors[k];
        let hd2 = (p.width as f64).powi(2) / 4.0 + (p.height as f64).powi(2) / 4.0;
        ((u[0] as f64 - p.cx).powi(2) + (u[1] as f64 - p.cy).powi(2)) / hd2
    };
    let rho_c: Vec<f64> = (0..n)
        .map(|k| {
            let p = &model.projectors[k];
            rho(k, [(p.width as f32 - 1.0) / 2.0, (p.height as f32 - 1.0) / 2.0])
        })
        .collect();
    // Observations: (j, k, y = ln(lit_j / lit_k) - ln(E_j / E_k), rho_j, rho_k).
    let pixels = model.pixel_count();
    let stride = (pixels / 400_000).max(1);
    let mut obs = Vec::new();
    for i in (0..pixels).step_by(stride) {
        let e: Vec<Option<f64>> = (0..n).map(|k| full_irradiance(model, k, i)).collect();
        for j in 0..n {
            for k in j + 1..n {
                let (Some(ej), Some(ek)) = (e[j], e[k]) else { continue };
                let (lj, lk) = (lits[j][i], lits[k][i]);
                let (sj, sk) = ((lj[0] + lj[1] + lj[2]) as f64, (lk[0] + lk[1] + lk[2]) as f64);
                if sj < 0.05 || sk < 0.05 {
                    continue;
                }
                let (uj, uk) = (model.correspondences[j][i], model.correspondences[k][i]);
                obs.push((j, k, (sj / sk).ln() - (ej / ek).ln(), rho(j, uj), rho(k, uk)));
            }
        }
    }
    if obs.len() < 1000 {
        warnings.push(format!(
            "only {} camera pixels are lit by two projectors: vignetting is taken as uniform (the gain \
             absorbs it)",
            obs.len()
        ));
        return vec![None; n];
    }
    // Parameters: log intensity of projectors 1..n (projector 0 is the gauge), then a_0..a_{n-1}.
    let np = (n - 1) + n;
    let mut theta = vec![0.0f64; np];
    let lv = |a: f64, r: f64, rc: f64| (1.0 - a * r).max(1e-3).ln() - (1.0 - a * rc).max(1e-3).ln();
    let dlv = |a: f64, r: f64, rc: f64| -r / (1.0 - a * r).max(1e-3) + rc / (1.0 - a * rc).max(1e-3);
    let mut keep = vec![true; obs.len()];
    for iter in 0..12 {
        let mut h = nalgebra::DMatrix::<f64>::zeros(np, np);
        let mut g = nalgebra::DVector::<f64>::zeros(np);
        let mut resid = Vec::with_capacity(obs.len());
        for (o, &(j, k, y, rj, rk)) in obs.iter().enumerate() {
            let (aj, ak) = (theta[n - 1 + j], theta[n - 1 + k]);
            let lj = if j == 0 { 0.0 } else { theta[j - 1] };
            let lk = if k == 0 { 0.0 } else { theta[k - 1] };
            let r = y - (lj - lk + lv(aj, rj, rho_c[j]) - lv(ak, rk, rho_c[k]));
            resid.push(r.abs());
            if !keep[o] {
                continue;
            }
            let mut jac = [(0usize, 0.0f64); 4];
            let mut nj = 0;
            if j > 0 {
                jac[nj] = (j - 1, 1.0);
                nj += 1;
            }
            if k > 0 {
                jac[nj] = (k - 1, -1.0);
                nj += 1;
            }
            jac[nj] = (n - 1 + j, dlv(aj, rj, rho_c[j]));
            jac[nj + 1] = (n - 1 + k, -dlv(ak, rk, rho_c[k]));
            nj += 2;
            for &(a, va) in &jac[..nj] {
                g[a] += va * r;
                for &(b, vb) in &jac[..nj] {
                    h[(a, b)] += va * vb;
                }
            }
        }
        // Reject outliers (shadow edges, grazing normals) after the first solves.
        if iter >= 2 {
            let mut sorted = resid.clone();
            let mid = sorted.len() / 2;
            let mad = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
            for (kp, r) in keep.iter_mut().zip(&resid) {
                *kp = *r <= 4.0 * 1.4826 * mad.max(1e-6);
            }
        }
        for d in 0..np {
            h[(d, d)] += 1e-6;
        }
        let Some(step) = h.lu().solve(&g) else { break };
        for d in 0..np {
            theta[d] += step[d];
        }
        for a in &mut theta[n - 1..] {
            *a = a.clamp(-0.5, 0.6);
        }
        if step.amax() < 1e-7 {
            break;
        }
    }
    let coeffs: Vec<f64> = theta[n - 1..].to_vec();
    for (k, &a) in coeffs.iter().enumerate() {
        let p = &mut model.projectors[k];
        p.lux_at_1m = if k == 0 { 1.0 } else { theta[k - 1].exp() };
        let (w, h) = (p.width, p.height);
        let hd2 = (w as f64).powi(2) / 4.0 + (h as f64).powi(2) / 4.0;
        let (cx, cy) = (p.cx, p.cy);
        let at_c = 1.0 - a * rho_c[k];
        p.vignetting = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let r = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)) / hd2;
                ((1.0 - a * r) / at_c).max(0.0) as f32
            })
            .collect();
    }
    coeffs.into_iter().map(Some).collect()
}

/// Draws a line into `img` (clipped), for the plots below.
fn line(img: &mut image::RgbImage, a: (f64, f64), b: (f64, f64), colour: [u8; 3]) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        let (x, y) = ((a.0 + (b.0 - a.0) * t).round(), (a.1 + (b.1 - a.1) * t).round());
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, image::Rgb(colour));
        }
    }
}

/// A projector's response curves (red, green, blue) over input level (x) against relative
/// output (y), measured levels as squares, in two panels: on the left the whole curve (0..255
/// against 0..1, gridlines every 32 levels and 0.1), on the right the dark end enlarged (0..64,
/// gridlines every 16, against 0 to a tenth above the highest curve's output at 64), where a
/// low light bound puts most frame values and the full curve lies on the axis.
pub fn response_plot(rad: &ProjectorRadiometry) -> image::RgbImage {
    let (w, h) = (560u32, 420u32);
    let mut img = image::RgbImage::from_pixel(w + w / 2, h, image::Rgb([255; 3]));
    let top = rad.response.iter().map(|r| r[DARK_END]).fold(0.0f32, f32::max).max(1e-6) as f64 * 1.1;
    response_panel(&mut img, rad, (0.0, w as f64), (255, 32), (1.0, 0.1));
    response_panel(&mut img, rad, (w as f64, (w / 2) as f64), (DARK_END, 16), (top, top));
    img
}

/// The last level [`response_plot`]'s enlarged dark end shows.
const DARK_END: usize = 64;

/// One panel of [`response_plot`], `left` and `width` in pixels: levels `0..=levels.0` with
/// gridlines every `levels.1`, outputs `0..=outputs.0` with gridlines every `outputs.1`.
fn response_panel(
    img: &mut image::RgbImage,
    rad: &ProjectorRadiometry,
    (left, width): (f64, f64),
    levels: (usize, usize),
    outputs: (f64, f64),
) {
    let m = 30.0;
    let (pw, ph) = (width - 2.0 * m, img.height() as f64 - 2.0 * m);
    let (max_level, max_out) = (levels.0 as f64, outputs.0);
    let at = |level: f64, out: f64| (left + m + pw * level / max_level, m + ph * (1.0 - out / max_out));
    for l in (0..=levels.0).step_by(levels.1).chain([levels.0]) {
        line(img, at(l as f64, 0.0), at(l as f64, max_out), [225; 3]);
    }
    let steps = (max_out / outputs.1).round() as usize;
    for i in 0..=steps {
        let out = max_out * i as f64 / steps.max(1) as f64;
        line(img, at(0.0, out), at(max_level, out), [225; 3]);
    }
    line(img, at(0.0, 0.0), at(max_level, 0.0), [0; 3]);
    line(img, at(0.0, 0.0), at(0.0, max_out), [0; 3]);
    let colours = [[200, 30, 30], [20, 150, 40], [30, 60, 210]];
    for (c, &colour) in colours.iter().enumerate() {
        let r = &rad.response[c];
        for v in 1..=levels.0 {
            let (a, b) = (r[v - 1] as f64, r[v] as f64);
            if a <= max_out {
                line(img, at(v as f64 - 1.0, a), at(v as f64, b.min(max_out)), colour);
            }
        }
        // A level measured a little above the panel's top (noise, or full output) is drawn on it.
        let shown = |&&(l, o): &&(u8, f32)| l as usize <= levels.0 && o as f64 <= max_out * 1.05;
        for &(l, o) in rad.measured[c].iter().filter(shown) {
            square(img, at(l as f64, (o as f64).clamp(0.0, max_out)), colour);
        }
    }
}

/// A 7-pixel open square centred on `(x, y)`: a measured point.
fn square(img: &mut image::RgbImage, (x, y): (f64, f64), colour: [u8; 3]) {
    let corners = [(x - 3.0, y - 3.0), (x + 3.0, y - 3.0), (x + 3.0, y + 3.0), (x - 3.0, y + 3.0)];
    for e in 0..4 {
        line(img, corners[e], corners[(e + 1) % 4], colour);
    }
}

/// The footprint that [`footprint_map`] shows at full scale (yellow): twice the median of the
/// measured footprints, camera pixels' worth of light.
pub fn footprint_scale(footprint: &[f32]) -> f32 {
    let mut vals: Vec<f32> = footprint.iter().copied().filter(|v| v.is_finite()).collect();
    if vals.is_empty() {
        return 1.0;
    }
    let mid = vals.len() / 2;
    2.0 * *vals.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The footprint map's colour at `t` (0..=1 of [`footprint_scale`]): blue, teal, yellow.
pub fn footprint_colour(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let (r, g, b) = if t < 0.5 {
        let s = t * 2.0;
        (30.0 + 10.0 * s, 40.0 + 140.0 * s, 140.0 + 10.0 * s)
    } else {
        let s = (t - 0.5) * 2.0;
        (40.0 + 210.0 * s, 180.0 + 50.0 * s, 150.0 - 120.0 * s)
    };
    [r as u8, g as u8, b as u8]
}

/// Footprint size per projector pixel as a false-colour image ([`footprint_colour`] up to
/// [`footprint_scale`]), black where no dot was measured.
pub fn footprint_map(footprint: &[f32], width: u32, height: u32) -> image::RgbImage {
    let scale = footprint_scale(footprint);
    image::RgbImage::from_fn(width, height, |x, y| {
        let v = footprint[(y * width + x) as usize];
        if !v.is_finite() {
            return image::Rgb([0; 3]);
        }
        image::Rgb(footprint_colour(v / scale.max(1e-6)))
    })
}

impl PhotometricReport {
    /// Writes the figures people look at into `dir`: `response_proj<k>.png`,
    /// `footprint_proj<k>.png` and `photometric.json` (counts, coverage, leakage, vignetting,
    /// lux, warnings).
    pub fn save(&self, dir: &Path, projector_sizes: &[(u32, u32)]) -> Result<(), ImageError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| ImageError::Write { path: dir.into(), source: image::ImageError::IoError(e) })?;
        for (k, rad) in self.radiometry.iter().enumerate() {
            let path = dir.join(format!("response_proj{k}.png"));
            response_plot(rad).save(&path).map_err(|source| ImageError::Write { path, source })?;
        }
        for (k, (t, &(w, h))) in self.transport.iter().zip(projector_sizes).enumerate() {
            if t.footprint.len() == (w * h) as usize {
                let path = dir.join(format!("footprint_proj{k}.png"));
                footprint_map(&t.footprint, w, h)
                    .save(&path)
                    .map_err(|source| ImageError::Write { path, source })?;
            }
        }
        let path = dir.join(PHOTOMETRIC_FILE);
        let json = serde_json::to_string_pretty(&self.summary()).map_err(|e| ImageError::Write {
            path: path.clone(),
            source: image::ImageError::IoError(e.into()),
        })?;
        std::fs::write(&path, json)
            .map_err(|e| ImageError::Write { path, source: image::ImageError::IoError(e) })
    }

    /// The figures `photometric.json` holds.
    pub fn summary(&self) -> PhotometricSummary {
        let wide = |v: [f32; 3]| v.map(f64::from);
        PhotometricSummary {
            projectors: (self.transport.iter().enumerate())
                .map(|(k, t)| ProjectorPhotometry {
                    correspondences_disagreeing: t.refine.disagreed,
                    correspondences_refined: t.refine.refined,
                    coverage_of_lit_pixels: t.coverage,
                    dot_spacing: t.spacing,
                    dots_off_object: t.off_object,
                    dots_predicted: t.predicted,
                    dots_snapped: t.dots,
                    filled_pixels: self.filled.get(k).copied().unwrap_or(0),
                    leakage: self.radiometry.get(k).map(|r| r.leakage.map(wide)),
                    lux: self.lux.iter().find(|l| l.projector == k).map(|l| LuxFigures {
                        distance_mm: l.distance_mm,
                        lux_at_1m: l.lux_at_1m,
                        moved_px: l.moved_px,
                        reading: l.reading,
                        reference_pixel: l.reference_pixel,
                        requested_pixel: l.requested_pixel,
                    }),
                    projector: k,
                    refine_median_shift_px: f64::from(t.refine.median_shift),
                    vignetting_coefficient: self.vignetting.get(k).copied().flatten(),
                })
                .collect(),
            stray_lux: wide(self.stray_lux),
            version: PHOTOMETRIC_VERSION,
            warnings: self.warnings.clone(),
        }
    }
}

/// The photometric summary's file name, in the stage folder.
pub const PHOTOMETRIC_FILE: &str = "photometric.json";
/// Version of [`PhotometricSummary`]; a reader refuses a newer one. 2: the lux figures say
/// which reference pixel was requested and how far the used one lies from it; 3: each
/// projector's filled pixels (older files, without them, still load).
pub const PHOTOMETRIC_VERSION: u32 = 3;

/// `photometric.json`: the photometric calibration's figures per projector. Fields are in
/// alphabetical order, as the file has always had them; values that are `f32` in the
/// calibration are widened to `f64`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhotometricSummary {
    pub projectors: Vec<ProjectorPhotometry>,
    /// Stray room light per channel, lux.
    pub stray_lux: [f64; 3],
    pub version: u32,
    pub warnings: Vec<String>,
}

/// One projector's figures in [`PhotometricSummary`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorPhotometry {
    pub correspondences_disagreeing: usize,
    pub correspondences_refined: usize,
    pub coverage_of_lit_pixels: f64,
    pub dot_spacing: u32,
    pub dots_off_object: usize,
    pub dots_predicted: usize,
    pub dots_snapped: usize,
    /// Camera pixels this projector did not decode that were given its coordinates by
    /// interpolation, confirmed by its Gray-code images (dark paint; `calibrate::fill`).
    #[serde(default)]
    pub filled_pixels: usize,
    /// Camera channel response to each projector channel, relative (`[projector][camera]`).
    pub leakage: Option<[[f64; 3]; 3]>,
    pub lux: Option<LuxFigures>,
    pub projector: usize,
    pub refine_median_shift_px: f64,
    pub vignetting_coefficient: Option<f64>,
}

/// A projector's lux-meter reading and the scale fitted to it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LuxFigures {
    pub distance_mm: f64,
    pub lux_at_1m: f64,
    /// Camera pixels between the requested and the used reference pixel (0: used as given).
    #[serde(default)]
    pub moved_px: f64,
    pub reading: f64,
    /// The pixel the fit used.
    pub reference_pixel: [u32; 2],
    /// The pixel the conservator named (None: chosen near the principal point).
    #[serde(default)]
    pub requested_pixel: Option<[u32; 2]>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    use crate::capture_set::{CAPTURE_VERSION, CameraIntrinsics, Shot};

    /// A flat, evenly lit scene: projector pixel q lands at camera `2 q + 3` with a small
    /// Gaussian blob; gamma-2 response; white albedo 0.5, black 0.01, no noise.
    fn write_capture(
        dir: &Path,
        spacing: u32,
        levels: &[u8],
        skip: &[&str],
    ) -> (CaptureManifest, Vec<[f32; 2]>) {
        let (cw, ch, pw, ph) = (72u32, 56u32, 34u32, 26u32);
        let share = |q: [u32; 2], x: u32, y: u32| {
            let (cx, cy) = (2.0 * q[0] as f32 + 3.0, 2.0 * q[1] as f32 + 3.0);
            let d2 = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2);
            (-d2 / (2.0 * 0.8f32.powi(2))).exp() * 4.0 / (2.0 * std::f32::consts::PI * 0.64)
        };
        let render = |on: &dyn Fn(u32, u32) -> Option<[f32; 3]>| {
            let mut img = LinearImage::new(cw, ch).unwrap();
            for y in 0..ch {
                for x in 0..cw {
                    let mut e = [0.0f32; 3];
                    // The blob is negligible beyond 3 projector pixels.
                    let (qx0, qy0) = ((x / 2).saturating_sub(4), (y / 2).saturating_sub(4));
                    for qy in qy0..(qy0 + 8).min(ph) {
                        for qx in qx0..(qx0 + 8).min(pw) {
                            if let Some(out) = on(qx, qy) {
                                let s = share([qx, qy], x, y);
                                for c in 0..3 {
                                    e[c] += s * out[c];
                                }
                            }
                        }
                    }
                    img.set(x, y, e.map(|v| 0.01 + 0.5 * v));
                }
            }
            img
        };
        std::fs::create_dir_all(dir.join("proj0")).unwrap();
        let mut shots = Vec::new();
        let mut add = |pattern: Pattern, name: String, img: LinearImage| {
            if skip.contains(&name.as_str()) {
                return;
            }
            let file = PathBuf::from(format!("proj0/{name}.png"));
            img.save_linear16(&dir.join(&file)).unwrap();
            shots.push(Shot { pattern, file });
        };
        add(Pattern::White, "white".into(), render(&|_, _| Some([1.0; 3])));
        add(Pattern::Black, "black".into(), render(&|_, _| None));
        for dy in 0..spacing {
            for dx in 0..spacing {
                let img = render(&|x, y| (x % spacing == dx && y % spacing == dy).then_some([1.0; 3]));
                add(Pattern::Dots { spacing, dx, dy }, format!("dots_{dx:02}_{dy:02}"), img);
            }
        }
        for channel in 0..3u8 {
            for &level in levels {
                let r = (level as f32 / 255.0).powi(2);
                let mut out = [0.0; 3];
                out[channel as usize] = r;
                add(
                    Pattern::Ramp { channel, level },
                    format!("ramp_{channel}_{level:03}"),
                    render(&|_, _| Some(out)),
                );
            }
        }
        let manifest = CaptureManifest {
            version: CAPTURE_VERSION,
            source: "test".into(),
            camera: CameraIntrinsics {
                width: cw,
                height: ch,
                fx: 50.0,
                fy: 50.0,
                cx: 36.0,
                cy: 28.0,
                distortion: [0.0; 5],
            },
            photo: "photo.png".into(),
            projectors: vec![ProjectorCapture { index: 0, width: pw, height: ph, shots }],
        };
        let corr = (0..cw * ch)
            .map(|i| {
                let q = [((i % cw) as f32 - 3.0) / 2.0, ((i / cw) as f32 - 3.0) / 2.0];
                if q[0] < -0.5 || q[1] < -0.5 || q[0] > pw as f32 - 0.5 || q[1] > ph as f32 - 0.5 {
                    [f32::NAN; 2]
                } else {
                    // Decoding error of a quarter pixel that the dots should remove.
                    [q[0] + 0.25, q[1] - 0.25]
                }
            })
            .collect();
        (manifest, corr)
    }

    #[test]
    fn capture_files_give_transport_and_responses() {
        let dir = tempfile::tempdir().unwrap();
        let (m, corr) = write_capture(dir.path(), 6, &[64, 128, 192, 255], &[]);
        let none = |_: &str, _: usize, _: usize| {};
        let (res, refined, stats) = measure_transport(
            dir.path(),
            0,
            &m.projectors[0],
            (72, 56),
            &corr,
            &SnapParams::default(),
            &none,
        )
        .unwrap();
        assert!(res.dots.len() > 600, "{} dots", res.dots.len());
        assert!(stats.refined > 2000, "{stats:?}");
        let i = 30 * 72 + 31;
        let want = [(31.0 - 3.0) / 2.0, (30.0 - 3.0) / 2.0];
        assert!(
            (refined[i][0] - want[0]).abs() < 0.03 && (refined[i][1] - want[1]).abs() < 0.03,
            "{:?}",
            refined[i]
        );
        let (rad, _) = measure_radiometry(dir.path(), 0, &m.projectors[0], (72, 56), &none).unwrap();
        for c in 0..3 {
            for v in [64usize, 100, 128, 192] {
                let want = (v as f32 / 255.0).powi(2);
                assert!(
                    (rad.response[c][v] - want).abs() < 0.01,
                    "channel {c} level {v}: {}",
                    rad.response[c][v]
                );
            }
        }
        // The figures people look at.
        let report = PhotometricReport {
            transport: vec![TransportSummary {
                footprint: transport::footprint_energy(&res.transport, 34, 26),
                ..Default::default()
            }],
            radiometry: vec![rad],
            ..Default::default()
        };
        report.save(&dir.path().join("report"), &[(34, 26)]).unwrap();
        for f in ["response_proj0.png", "footprint_proj0.png", "photometric.json"] {
            assert!(dir.path().join("report").join(f).exists(), "{f}");
        }
        // The summary reads back as written, typed.
        let text = std::fs::read_to_string(dir.path().join("report").join(PHOTOMETRIC_FILE)).unwrap();
        let back: PhotometricSummary = serde_json::from_str(&text).unwrap();
        assert_eq!(back, report.summary());
        assert_eq!(back.version, PHOTOMETRIC_VERSION);
    }

    #[test]
    fn a_version_1_lux_figure_still_loads() {
        // Written before the fallback reference pixel: no requested pixel, nothing moved.
        let text =
            r#"{"distance_mm": 1000.0, "lux_at_1m": 400.0, "reading": 400.0, "reference_pixel": [3, 4]}"#;
        let l: LuxFigures = serde_json::from_str(text).unwrap();
        assert_eq!((l.requested_pixel, l.moved_px, l.reference_pixel), (None, 0.0, [3, 4]));
    }

    #[test]
    fn missing_images_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let none = |_: &str, _: usize, _: usize| {};
        let (m, corr) = write_capture(dir.path(), 4, &[128, 255], &["white"]);
        let e = measure_transport(
            dir.path(),
            0,
            &m.projectors[0],
            (72, 56),
            &corr,
            &SnapParams::default(),
            &none,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("projector 0") && e.contains("white"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let (m, _) = write_capture(dir.path(), 4, &[128, 255], &[]);
        let e = measure_radiometry(dir.path(), 0, &m.projectors[0], (72, 56), &none).unwrap_err().to_string();
        assert!(e.contains("projector 0, channel 0") && e.contains("ramp levels"), "{e}");
        // No correspondences at all: the geometry step has not run.
        let e = measure_transport(
            dir.path(),
            0,
            &m.projectors[0],
            (72, 56),
            &vec![[f32::NAN; 2]; 72 * 56],
            &SnapParams::default(),
            &none,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("geometry step"), "{e}");
    }

    #[test]
    fn black_levels_and_stray_light_separate() {
        // Two projectors lighting overlapping halves, a gain that varies per pixel.
        let n = 400;
        let gain: Vec<[f32; 3]> = (0..n).map(|i| [0.5 + 0.4 * ((i * 7 % 13) as f32 / 13.0); 3]).collect();
        let l0: Vec<[f32; 3]> =
            (0..n).map(|i| if i < 250 { gain[i].map(|g| g * 0.6) } else { [0.0; 3] }).collect();
        let l1: Vec<[f32; 3]> = (0..n)
            .map(|i| if i > 150 { gain[i].map(|g| g * (0.3 + i as f32 / 1000.0)) } else { [0.0; 3] })
            .collect();
        let black: Vec<[f32; 3]> = (0..n)
            .map(|i| std::array::from_fn(|c| 0.004 * l0[i][c] + 0.006 * l1[i][c] + 0.002 * gain[i][c]))
            .collect();
        let (levels, stray) = fit_black(&black, &[&l0, &l1], &gain);
        assert!((levels[0][0] - 0.004).abs() < 1e-5 && (levels[1][2] - 0.006).abs() < 1e-5, "{levels:?}");
        assert!((stray[1] - 0.002).abs() < 1e-5, "{stray:?}");
    }
}
