//! The light certificate: object points at reduced resolution, each with, per projector, the
//! rectangle of projector pixels whose light can reach it and an upper bound of the lux per
//! unit of relative output there. The guarantee is enforced on it, and it travels in the
//! bundle so the appliance can recompute every scene's irradiance by itself
//! (`restage_shared::light::LightCheck`: the same sums, plus the test that every lit pixel
//! lies in a block with a plausible coefficient, which compensation meets by construction —
//! the splat support is inside the blocks — and enforces with `guarantee::darken_unvouched`).
//!
//! A point's rectangle per projector covers, for every camera pixel of its patch that the
//! projector sees, the projector pixels of that camera pixel's footprint (the support
//! compensation splats onto) grown by one pixel for lens blur, and every pixel whose measured
//! footprint (transport) reaches that camera pixel. Its coefficient is the largest bound of
//! `eta_ik` over the patch's stretch of surface (`landing::bound_eta`). So the
//! brightest pixel of the rectangle times the coefficient bounds the light of any point of
//! the patch: the check over-estimates, never under-estimates.

use rayon::prelude::*;
use restage_shared::light::{
    CertificateMap, Coverage, Footprint, LightCertificate, LightError, LightModel, LuxWeighting,
    PeakIrradiance, ProjectorLight, StageLimits, XrgbFrame, max_irradiance, xrgb_from_rgb,
};

use super::geometry::Geometry;
use super::landing::{self, Landing};
use crate::stage_model::StageModel;

/// A point's block of projector pixels and its coefficient: the bundle's own
/// [`Footprint`] (`x0 >= x1` means the projector does not reach the point).
pub type Block = Footprint;

/// Grows `b` to include `[x0, x1) x [y0, y1)`, clipped to a `w` x `h` projector.
fn include(b: &mut Block, x0: i64, y0: i64, x1: i64, y1: i64, w: u32, h: u32) {
    let (x0, y0) = (x0.clamp(0, w as i64) as u16, y0.clamp(0, h as i64) as u16);
    let (x1, y1) = (x1.clamp(0, w as i64) as u16, y1.clamp(0, h as i64) as u16);
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    if b.is_empty() {
        (b.x0, b.y0, b.x1, b.y1) = (x0, y0, x1, y1);
    } else {
        b.x0 = b.x0.min(x0);
        b.y0 = b.y0.min(y0);
        b.x1 = b.x1.max(x1);
        b.y1 = b.y1.max(y1);
    }
}

/// The certificate as compensation builds and enforces it.
#[derive(Clone, Debug)]
pub struct Certificate {
    /// Camera pixels per certificate point along each axis.
    pub reduction: u32,
    /// Per certificate point, its patch's top-left camera pixel.
    pub point_px: Vec<[u16; 2]>,
    /// Per projector: (width, height, one block per point).
    pub projectors: Vec<(u32, u32, Vec<Block>)>,
    /// Room light counted at every point, lux.
    pub ambient_lux: f64,
    /// Per camera pixel, its certificate point (`u32::MAX` where no projector sees it).
    pub point_of_pixel: Vec<u32>,
    /// Points from here on stand for surface the model does not know, beside a projector's
    /// known landing (`add_unseen_ring`); before it, object points.
    pub first_unseen: usize,
}

impl Certificate {
    pub fn points(&self) -> usize {
        self.point_px.len()
    }
}

/// Per camera pixel and projector, the rectangle of pixels that can light it (before
/// grouping into patches).
fn pixel_blocks(stage: &StageModel, geom: &Geometry, k: usize) -> Vec<Block> {
    let p = &stage.projectors[k];
    let kn = geom.projectors;
    let (w, h) = (p.width, p.height);
    let mut blocks: Vec<Block> = (0..geom.points)
        .into_par_iter()
        .map(|i| {
            let mut b = Block::default();
            if geom.eta[i * kn + k] > 0.0 {
                // The camera pixel's footprint (the splat support) grown by one pixel of blur.
                let c = geom.coord[i * kn + k];
                let hf = geom.half[i * kn + k];
                let lo = |v: f32, h: f32| (v - h - 0.5).ceil() as i64 - 1;
                let hi = |v: f32, h: f32| (v + h + 0.5).floor() as i64 + 2;
                include(&mut b, lo(c[0], hf[0]), lo(c[1], hf[1]), hi(c[0], hf[0]), hi(c[1], hf[1]), w, h);
            }
            b
        })
        .collect();
    let t = &stage.transport[k];
    if t.row_start.len() == (w * h) as usize + 1 {
        for px in 0..(w * h) as usize {
            let (x, y) = ((px % w as usize) as i64, (px / w as usize) as i64);
            for e in t.row_start[px] as usize..t.row_start[px + 1] as usize {
                let j = t.camera_pixel[e] as usize;
                if j < geom.points && t.weight[e] > 0.0 && geom.eta[j * kn + k] > 0.0 {
                    include(&mut blocks[j], x, y, x + 1, y + 1, w, h);
                }
            }
        }
    }
    blocks
}

/// Builds the certificate with `reduction x reduction` camera pixels per point and the room
/// light `ambient_lux` counted everywhere: the object points, with coefficients bounded over
/// each pixel's stretch of surface ([`landing::bound_eta`]), then one point per unseen-ring
/// pixel of every projector ([`landing::Landing::ring`]).
pub fn build(
    stage: &StageModel,
    geom: &Geometry,
    landings: &[Landing],
    reduction: u32,
    ambient_lux: f64,
) -> Certificate {
    let r = reduction.max(1) as usize;
    let bound = landing::bound_eta(stage, geom);
    let (cw, ch) = (stage.camera.width as usize, stage.camera.height as usize);
    let (gw, gh) = (cw.div_ceil(r), ch.div_ceil(r));
    let kn = geom.projectors;
    let per_pixel: Vec<Vec<Block>> = (0..kn).map(|k| pixel_blocks(stage, geom, k)).collect();
    // Patches with at least one camera pixel that some projector sees, in raster order.
    let mut point_px = Vec::new();
    let mut patch_point = vec![u32::MAX; gw * gh];
    for gy in 0..gh {
        for gx in 0..gw {
            let seen = (gy * r..((gy + 1) * r).min(ch))
                .any(|y| (gx * r..((gx + 1) * r).min(cw)).any(|x| geom.covered(y * cw + x)));
            if seen {
                patch_point[gy * gw + gx] = point_px.len() as u32;
                point_px.push([(gx * r) as u16, (gy * r) as u16]);
            }
        }
    }
    let projectors = (0..kn)
        .map(|k| {
            let p = &stage.projectors[k];
            let blocks = point_px
                .par_iter()
                .map(|&[x0, y0]| {
                    let mut b = Block::default();
                    let mut l = 0.0f32;
                    for y in y0 as usize..(y0 as usize + r).min(ch) {
                        for x in x0 as usize..(x0 as usize + r).min(cw) {
                            let i = y * cw + x;
                            let pb = per_pixel[k][i];
                            if !pb.is_empty() {
                                include(
                                    &mut b,
                                    pb.x0 as i64,
                                    pb.y0 as i64,
                                    pb.x1 as i64,
                                    pb.y1 as i64,
                                    p.width,
                                    p.height,
                                );
                                l = l.max(bound[i * kn + k]);
                            }
                        }
                    }
                    // A hair above, so that f32 rounding of eta cannot under-count.
                    b.lux_per_unit = l * (1.0 + 1e-6);
                    b
                })
                .collect();
            (p.width, p.height, blocks)
        })
        .collect();
    let point_of_pixel = (0..cw * ch)
        .map(|i| if geom.covered(i) { patch_point[(i / cw / r) * gw + (i % cw) / r] } else { u32::MAX })
        .collect();
    let mut cert = Certificate {
        reduction: r as u32,
        first_unseen: point_px.len(),
        point_px,
        projectors,
        ambient_lux,
        point_of_pixel,
    };
    add_unseen_ring(&mut cert, stage, landings);
    cert
}

/// Appends, per projector, one point for every pixel of its unseen ring: light there lands
/// on surface the model does not know, so the pixel's block (itself and its neighbours, for
/// blur) is charged as if it fell on a surface facing the projector, nearer than the known
/// surface around it ([`Landing::unseen_eta`]). Compensation keeps these pixels black; the
/// points make the appliance's check hold the blur of their lit neighbours to the bound.
fn add_unseen_ring(cert: &mut Certificate, stage: &StageModel, landings: &[Landing]) {
    let (cw, ch) = (stage.camera.width, stage.camera.height);
    for (k, l) in landings.iter().enumerate() {
        let p = &stage.projectors[k];
        for (x, y) in l.ring() {
            let Some(eta) = l.unseen_eta(p, x, y) else { continue };
            let mut b = Block::default();
            include(&mut b, x as i64 - 1, y as i64 - 1, x as i64 + 2, y as i64 + 2, p.width, p.height);
            b.lux_per_unit = eta as f32 * (1.0 + 1e-6);
            // Name it by a camera pixel whose footprint lands next to it.
            let near = (y.saturating_sub(1)..=(y + 1).min(p.height - 1))
                .flat_map(|yy| (x.saturating_sub(1)..=(x + 1).min(p.width - 1)).map(move |xx| (xx, yy)))
                .map(|(xx, yy)| l.near_camera_pixel[(yy * p.width + xx) as usize])
                .find(|&c| c != u32::MAX)
                .map_or([u16::MAX; 2], |c| {
                    [(c % cw).min(u16::MAX as u32) as u16, (c / cw).min(ch - 1).min(u16::MAX as u32) as u16]
                });
            cert.point_px.push(near);
            for (j, (_, _, blocks)) in cert.projectors.iter_mut().enumerate() {
                blocks.push(if j == k { b } else { Block::default() });
            }
        }
    }
}

impl Certificate {
    /// The certificate in the bundle's format (`restage_shared::light`).
    pub fn to_shared(&self) -> LightCertificate {
        self.shared_range(0, self.points())
    }

    /// Points `a..b` of the certificate in the bundle's format.
    fn shared_range(&self, a: usize, b: usize) -> LightCertificate {
        LightCertificate {
            points: (b - a) as u32,
            point_px: self.point_px[a..b].to_vec(),
            projectors: (self.projectors.iter())
                .map(|(w, h, blocks)| CertificateMap {
                    width: *w,
                    height: *h,
                    footprints: blocks[a..b].to_vec(),
                })
                .collect(),
        }
    }
}

/// How many runs of consecutive points [`Certificate::to_shared_parts`] cuts the certificate
/// into (fixed, so nothing depends on the thread count).
pub const PARTS: usize = 16;

impl Certificate {
    /// The certificate in the bundle's format cut into up to [`PARTS`] runs of consecutive
    /// points, each with the index of its first point, so the appliance's single-threaded check
    /// can run on the parts in parallel ([`independent_peak_parts`]).
    pub fn to_shared_parts(&self) -> Vec<(u32, LightCertificate)> {
        let n = self.points();
        let step = n.div_ceil(PARTS).max(1);
        (0..n.max(1))
            .step_by(step)
            .map(|a| {
                let b = (a + step).min(n);
                let part = self.shared_range(a, b);
                (a as u32, part)
            })
            .collect()
    }
}

/// The coverage half of the appliance's light check, over the union of `parts` (the parts of
/// one certificate), with the appliance's default stage limits.
pub fn coverage_of_parts(
    light: &LightModel,
    parts: &[(u32, LightCertificate)],
) -> Result<Coverage, LightError> {
    let refs: Vec<&LightCertificate> = parts.iter().map(|(_, c)| c).collect();
    Coverage::new(light, &refs, &StageLimits::default())
}

/// The appliance's light check of `frames` over the parts of [`Certificate::to_shared_parts`]:
/// every lit pixel vouched for by `coverage` (of the whole certificate), and the peak of the
/// per-point sums, parts in parallel: the peak of the whole is the largest of the parts'
/// peaks (the sums are a maximum over independent points), the first on ties; any error is
/// the result. The bound is the caller's to apply.
pub fn independent_peak_parts(
    light: &LightModel,
    parts: &[(u32, LightCertificate)],
    coverage: &Coverage,
    frames: &[image::RgbImage],
) -> Result<PeakIrradiance, LightError> {
    let xrgb: Vec<Vec<u8>> = frames.par_iter().map(|f| xrgb_from_rgb(f.as_raw())).collect();
    let views: Vec<XrgbFrame<'_>> = frames
        .iter()
        .zip(&xrgb)
        .map(|(f, x)| XrgbFrame { width: f.width(), height: f.height(), xrgb: x })
        .collect();
    for (k, v) in views.iter().enumerate() {
        coverage.check_frame("compensation", k, *v)?;
    }
    let peaks: Vec<Result<PeakIrradiance, LightError>> = parts
        .par_iter()
        .map(|(first, cert)| {
            max_irradiance(light, cert, &views).map(|p| PeakIrradiance { point: p.point + first, ..p })
        })
        .collect();
    let mut best: Option<PeakIrradiance> = None;
    for p in peaks {
        let p = p?;
        if best.as_ref().is_none_or(|b| p.lux > b.lux) {
            best = Some(p);
        }
    }
    best.ok_or_else(|| LightError::Certificate("the certificate has no parts".into()))
}

/// The bundle's light model for this stage and bound: the stage model's responses, black
/// levels and brightness, max-channel lux, and the room light the certificate counts.
pub fn light_model(stage: &StageModel, e_bound_lux: f64, margin: f64, ambient_lux: f64) -> LightModel {
    LightModel {
        projectors: stage
            .projectors
            .iter()
            .map(|p| ProjectorLight { response: p.response.clone(), black: p.black, lux_at_1m: p.lux_at_1m })
            .collect(),
        weighting: LuxWeighting::MaxChannel,
        e_bound_lux,
        safety_margin: margin,
        ambient_lux,
        lux_meter: vec![],
    }
}

/// The appliance's independent check of `frames` against the whole certificate, with its
/// default stage limits: every lit pixel vouched for, then the peak of the per-point sums
/// (the bound is the caller's to apply).
pub fn independent_peak(
    light: &LightModel,
    cert: &LightCertificate,
    frames: &[image::RgbImage],
) -> Result<PeakIrradiance, LightError> {
    let xrgb: Vec<Vec<u8>> = frames.iter().map(|f| xrgb_from_rgb(f.as_raw())).collect();
    let views: Vec<XrgbFrame<'_>> = frames
        .iter()
        .zip(&xrgb)
        .map(|(f, x)| XrgbFrame { width: f.width(), height: f.height(), xrgb: x })
        .collect();
    let coverage = Coverage::new(light, &[cert], &StageLimits::default())?;
    for (k, v) in views.iter().enumerate() {
        coverage.check_frame("compensation", k, *v)?;
    }
    max_irradiance(light, cert, &views)
}
