//! Dot-grid light transport (paper §5.2): each projector shows single-pixel dots on a grid of
//! spacing S, shifted over S x S positions; every dot is searched near the camera position the
//! structured-light correspondence predicts and snapped to its blob's weighted centre. The
//! blobs become the projector's sparse [`Transport`], and the snapped centres refine the
//! correspondences.
//!
//! Weights follow the [`Transport`] contract: `weight[q][p]` is the share of camera pixel p's
//! full-white irradiance from this projector that projector pixel q delivers, measured as
//! `(dot - black) / (white - black)` summed over colour channels, so albedo cancels.

use std::collections::HashMap;

use rayon::prelude::*;
use thiserror::Error;

use crate::imgio::{ImageError, LinearImage};
use crate::stage_model::Transport;

/// A camera value at or above this (in any channel) counts as saturated.
pub const SATURATED: f32 = 0.999;

#[derive(Debug, Error)]
pub enum TransportError {
    #[error("projector {projector}: {what} is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    Size { projector: usize, what: String, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("projector {projector}: dot spacing {spacing} is invalid (expected 2..=64)")]
    Spacing { projector: usize, spacing: u32 },
    #[error("projector {projector}: dot image {image} has shift ({dx}, {dy}) outside 0..{spacing}")]
    Shift { projector: usize, image: String, dx: u32, dy: u32, spacing: u32 },
    #[error("projector {projector}: the dot shift ({dx}, {dy}) appears twice ({first} and {second})")]
    DuplicateShift { projector: usize, dx: u32, dy: u32, first: String, second: String },
    #[error(
        "projector {projector}: no valid structured-light correspondence; light transport needs the \
         geometry step first"
    )]
    NoCorrespondence { projector: usize },
    #[error(
        "projector {projector}: the white image {white} is saturated on {percent:.1} % of the lit pixels \
         (expected < 50 %); lower the camera exposure"
    )]
    WhiteSaturated { projector: usize, white: String, percent: f64 },
}

/// Tuning of the blob search; the defaults suit 16-bit captures with a blur of a pixel or two.
#[derive(Clone, Debug)]
pub struct SnapParams {
    /// Detection threshold on the blob peak, in noise standard deviations.
    pub detect_sigmas: f32,
    /// Pixels belong to a blob above this many noise standard deviations.
    pub member_sigmas: f32,
    /// Largest search radius in camera pixels.
    pub max_radius: u32,
    /// Smallest useful `white - black` (channel sum) relative to the noise, below which a pixel's
    /// share of light cannot be measured.
    pub lit_sigmas: f32,
    /// Refined correspondences further than this (projector px) from the decoded ones are
    /// treated as disagreements and not applied. The phase-shift decode is within 0.3-0.4 px
    /// at its 99th percentile inside the object, so a dot fit that moves a pixel further is
    /// more likely wrong (a dot straddling a paint edge is pulled towards the lighter paint):
    /// at 2 px the refined correspondences' 99th percentile error was 1.0-1.5 px (docs/calibrate.md).
    pub max_refine_shift: f32,
}

impl Default for SnapParams {
    fn default() -> Self {
        Self {
            detect_sigmas: 8.0,
            member_sigmas: 3.0,
            max_radius: 24,
            lit_sigmas: 10.0,
            max_refine_shift: 0.5,
        }
    }
}

/// Predicts where a projector pixel lands in the camera from the decoded correspondences:
/// the mean camera position of the camera pixels whose correspondence rounds near it.
#[derive(Clone, Debug)]
pub struct Predictor {
    proj_width: u32,
    proj_height: u32,
    /// Per projector pixel: sum of camera x, sum of camera y, count.
    acc: Vec<[f32; 3]>,
}

impl Predictor {
    pub fn new(correspondence: &[[f32; 2]], cam_width: u32, proj_width: u32, proj_height: u32) -> Self {
        let mut acc = vec![[0.0f32; 3]; proj_width as usize * proj_height as usize];
        for (i, c) in correspondence.iter().enumerate() {
            if !(c[0].is_finite() && c[1].is_finite()) {
                continue;
            }
            let (qx, qy) = (c[0].round(), c[1].round());
            if qx < 0.0 || qy < 0.0 || qx >= proj_width as f32 || qy >= proj_height as f32 {
                continue;
            }
            let a = &mut acc[qy as usize * proj_width as usize + qx as usize];
            a[0] += (i as u32 % cam_width) as f32;
            a[1] += (i as u32 / cam_width) as f32;
            a[2] += 1.0;
        }
        Self { proj_width, proj_height, acc }
    }

    /// Camera position of projector pixel (qx, qy), or `None` when no camera pixel sees it
    /// (the dot falls off the object or into a shadow).
    pub fn predict(&self, qx: u32, qy: u32) -> Option<[f32; 2]> {
        let mut s = [0.0f32; 3];
        let (x0, x1) = (qx.saturating_sub(1), (qx + 1).min(self.proj_width - 1));
        let (y0, y1) = (qy.saturating_sub(1), (qy + 1).min(self.proj_height - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                let a = self.acc[y as usize * self.proj_width as usize + x as usize];
                s[0] += a[0];
                s[1] += a[1];
                s[2] += a[2];
            }
        }
        (s[2] > 0.0).then(|| [s[0] / s[2], s[1] / s[2]])
    }
}

/// One snapped blob.
#[derive(Clone, Debug, PartialEq)]
pub struct Blob {
    /// Weighted centre, camera pixel coordinates (integers at pixel centres).
    pub centre: [f32; 2],
    /// Sum of the weights (camera pixels' worth of full-white light).
    pub energy: f32,
    /// Camera pixel indices and weights.
    pub pixels: Vec<(u32, f32)>,
    /// Some blob pixel reached [`SATURATED`].
    pub saturated: bool,
    /// The blob touches a camera pixel this projector does not light (the object's silhouette,
    /// a cast shadow, a dark gap): part of the dot's light fell where the camera cannot measure
    /// it, so its weighted centre is pulled inwards and is no estimate of where the projector
    /// pixel's centre lands. Its footprint is still the light that does arrive.
    pub clipped: bool,
    /// The blob's light runs on into a neighbouring dot's cell, where it is counted as that
    /// dot's (dots a few camera pixels apart, a projector finer than the camera): its footprint
    /// misses that tail, and its centre leans away from the neighbour.
    pub shared: bool,
}

/// Why a dot with a prediction yielded no blob.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SnapMiss {
    /// Nothing above the detection threshold near the prediction.
    NotFound,
    /// The blob runs past the reach of its neighbours (it is smeared).
    Truncated,
    /// The brightest light near the prediction lies nearer a neighbouring dot's prediction:
    /// the dot itself was too dark to find.
    Elsewhere,
}

/// Per camera pixel data fixed for one projector: black and `white - black`, channel sums.
#[derive(Clone, Debug)]
pub struct SnapContext {
    pub width: u32,
    pub height: u32,
    pub black: Vec<f32>,
    pub lit: Vec<f32>,
    /// Smallest `lit` at which a pixel's share of light is measured.
    pub lit_min: f32,
}

impl SnapContext {
    pub fn new(black: &LinearImage, white: &LinearImage, noise_sigma: f32, params: &SnapParams) -> Self {
        let black_sum: Vec<f32> = black.data.iter().map(|p| p[0] + p[1] + p[2]).collect();
        let lit = white.data.iter().zip(&black_sum).map(|(w, b)| w[0] + w[1] + w[2] - b).collect();
        Self {
            width: black.width,
            height: black.height,
            black: black_sum,
            lit,
            lit_min: (params.lit_sigmas * noise_sigma).max(1e-3),
        }
    }
}

/// A camera image reduced to what snapping reads: per pixel the sum of the three channels and
/// whether any channel is saturated (a third of the memory of a [`LinearImage`]).
#[derive(Clone, Debug)]
pub struct DotSignal {
    pub width: u32,
    pub height: u32,
    pub sum: Vec<f32>,
    pub saturated: Vec<bool>,
}

impl DotSignal {
    pub fn from_linear(img: &LinearImage) -> Self {
        Self {
            width: img.width,
            height: img.height,
            sum: img.data.iter().map(|p| p[0] + p[1] + p[2]).collect(),
            saturated: img.data.iter().map(|p| p.iter().any(|&c| c >= SATURATED)).collect(),
        }
    }

    /// Reads a camera image of `width x height`; 16-bit RGB PNGs (our captures) are reduced
    /// straight from the decoded samples, anything else goes through [`LinearImage::load`].
    pub fn load(path: &std::path::Path, width: u32, height: u32) -> Result<Self, ImageError> {
        let img = crate::imgio::open_sized(path, width, height)?;
        match img {
            image::DynamicImage::ImageRgb16(buf) => {
                let raw = buf.as_raw();
                let sat = (SATURATED * 65535.0).ceil() as u16;
                Ok(Self {
                    width,
                    height,
                    sum: raw
                        .chunks_exact(3)
                        .map(|p| (p[0] as u32 + p[1] as u32 + p[2] as u32) as f32 / 65535.0)
                        .collect(),
                    saturated: raw.chunks_exact(3).map(|p| p[0].max(p[1]).max(p[2]) >= sat).collect(),
                })
            }
            _ => Ok(Self::from_linear(&LinearImage::load_sized(path, width, height)?)),
        }
    }
}

/// Noise standard deviation of a dot image against black, channel sums, from a strided
/// sample. Dots only add light, so where the image is at or below black it is noise alone:
/// its lower half gives the spread however much of the image the dots light (dots a few
/// camera pixels apart light most of it, and the median absolute deviation of the whole
/// sample then read their light as noise, raising every threshold). An image with no
/// values under black (black itself, against zero) falls back to that median absolute
/// deviation.
pub fn noise_sigma(image: &DotSignal, ctx: &SnapContext) -> f32 {
    let mut sample: Vec<f32> = image.sum.iter().zip(&ctx.black).step_by(7).map(|(p, b)| p - b).collect();
    if sample.is_empty() {
        return 0.0;
    }
    let zeros = sample.iter().filter(|&&d| d == 0.0).count();
    let mut below: Vec<f32> = sample.iter().filter(|&&d| d < 0.0).map(|d| -d).collect();
    // Half the exact zeros belong to the lower half (16-bit steps).
    let half = below.len() + zeros / 2;
    if half >= sample.len() / 16 {
        let mid = half / 2;
        if mid < zeros / 2 {
            return 0.0;
        }
        return 1.4826 * *below.select_nth_unstable_by(mid - zeros / 2, f32::total_cmp).1;
    }
    let mid = sample.len() / 2;
    let median = *sample.select_nth_unstable_by(mid, f32::total_cmp).1;
    for s in &mut sample {
        *s = (*s - median).abs();
    }
    1.4826 * *sample.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The neighbouring dots of one dot image around a dot: where they land and how far the
/// dot's own light may be followed.
#[derive(Clone, Debug, Default)]
pub struct Neighbourhood {
    /// Camera positions of the (up to eight) neighbouring dots the correspondences predict.
    pub rivals: Vec<[f32; 2]>,
    /// Half the camera distance to the nearest neighbour (infinite when none is predicted):
    /// a blob centred further than this from the dot's predicted position is nearer a
    /// neighbour's.
    pub halfway: f32,
    /// Radius of the window the peak is sought in: `halfway` rounded down, so that
    /// neighbouring dots' windows do not overlap (half the dot spacing where no neighbour is
    /// predicted), within `2..=max_radius`.
    pub radius: u32,
    /// Camera pixels a blob may reach from the dot's predicted position (Chebyshev): half the
    /// distance to its furthest predicted neighbour, rounded up; beyond that the light is
    /// some other dot's, or a smear.
    pub reach: u32,
}

impl Neighbourhood {
    /// The neighbourhood of a dot predicted at `here` whose neighbours are predicted at
    /// `rivals`, in a dot image of `spacing`.
    pub fn new(here: [f32; 2], rivals: Vec<[f32; 2]>, spacing: u32, max_radius: u32) -> Self {
        let (nearest, furthest) = rivals
            .iter()
            .map(|p| (p[0] - here[0]).hypot(p[1] - here[1]))
            .fold((f32::INFINITY, 0.0f32), |(n, f), d| (n.min(d), f.max(d)));
        let radius = if nearest.is_finite() { (nearest * 0.5).floor() as u32 } else { spacing / 2 }
            .clamp(2, max_radius);
        Neighbourhood {
            halfway: nearest * 0.5,
            radius,
            reach: ((0.5 * furthest).ceil() as u32).min(max_radius),
            rivals,
        }
    }
}

/// Snaps to the blob nearest `guess`. A dot owns the pixels nearer `guess` than any of the
/// neighbouring dots' predicted positions (its cell: where neighbouring blobs touch, each
/// takes the light on its own side). Finds the brightest pixel of its cell within
/// `around.radius`, climbs to the blob's top, grows the connected region above `member` around
/// it over the cell within `around.reach` of `guess`, and returns its weighted centre and
/// footprint. `detect` is the smallest accepted peak (channel sum above black).
pub fn snap_blob(
    image: &DotSignal,
    ctx: &SnapContext,
    guess: [f32; 2],
    around: &Neighbourhood,
    detect: f32,
    member: f32,
) -> Result<Blob, SnapMiss> {
    let (w, h) = (ctx.width as i64, ctx.height as i64);
    let r = around.radius as i64;
    let signal = |x: i64, y: i64| -> f32 {
        let i = (y * w + x) as usize;
        image.sum[i] - ctx.black[i]
    };
    let own = |x: i64, y: i64| {
        let d = |c: [f32; 2]| (x as f32 - c[0]).powi(2) + (y as f32 - c[1]).powi(2);
        let mine = d(guess);
        around.rivals.iter().all(|&c| mine <= d(c))
    };
    let (gx, gy) = (guess[0].round() as i64, guess[1].round() as i64);
    let mut best = (f32::NEG_INFINITY, 0i64, 0i64);
    for y in (gy - r).max(0)..=(gy + r).min(h - 1) {
        for x in (gx - r).max(0)..=(gx + r).min(w - 1) {
            let s = signal(x, y);
            if s > best.0 && own(x, y) {
                best = (s, x, y);
            }
        }
    }
    // Up to the blob's top; a top in a neighbour's cell means the light found is its tail
    // (this dot is too dark to find: dark paint, a shadow).
    loop {
        let (s, x, y) = best;
        for (nx, ny) in [
            (x - 1, y - 1),
            (x, y - 1),
            (x + 1, y - 1),
            (x - 1, y),
            (x + 1, y),
            (x - 1, y + 1),
            (x, y + 1),
            (x + 1, y + 1),
        ] {
            if nx >= 0 && ny >= 0 && nx < w && ny < h && signal(nx, ny) > best.0 {
                best = (signal(nx, ny), nx, ny);
            }
        }
        if best.0 == s {
            break;
        }
        if !own(best.1, best.2) {
            return Err(SnapMiss::Elsewhere);
        }
        if (best.1 - gx).abs().max((best.2 - gy).abs()) > (around.reach as i64).max(r) {
            return Err(SnapMiss::Truncated);
        }
    }
    let (peak, px, py) = best;
    if peak.is_nan() || peak < detect {
        return Err(SnapMiss::NotFound);
    }
    // Region growing (4-connected) inside the window of `reach` around the guess.
    let reach = (around.reach as i64).max(r);
    let side = 2 * reach + 1;
    let mut seen = vec![false; (side * side) as usize];
    let mut stack = vec![(px, py)];
    seen[((py - gy + reach) * side + px - gx + reach) as usize] = true;
    let mut pixels = Vec::new();
    let (mut sx, mut sy, mut sw) = (0.0f64, 0.0f64, 0.0f64);
    let (mut saturated, mut clipped, mut shared) = (false, false, false);
    while let Some((x, y)) = stack.pop() {
        let i = (y * w + x) as usize;
        if image.saturated[i] {
            saturated = true;
        }
        let lit = ctx.lit[i];
        if lit >= ctx.lit_min {
            let wt = signal(x, y) / lit;
            pixels.push((i as u32, wt));
            sx += wt as f64 * x as f64;
            sy += wt as f64 * y as f64;
            sw += wt as f64;
        }
        for (nx, ny) in [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)] {
            let (lx, ly) = (nx - gx + reach, ny - gy + reach);
            if nx < 0 || ny < 0 || nx >= w || ny >= h {
                clipped = true;
                continue;
            }
            if ctx.lit[(ny * w + nx) as usize] < ctx.lit_min {
                clipped = true;
            }
            if signal(nx, ny) <= member {
                continue;
            }
            if !own(nx, ny) {
                shared = true;
                continue;
            }
            if lx < 0 || ly < 0 || lx >= side || ly >= side {
                return Err(SnapMiss::Truncated);
            }
            let k = (ly * side + lx) as usize;
            if !seen[k] {
                seen[k] = true;
                stack.push((nx, ny));
            }
        }
    }
    if sw <= 0.0 {
        return Err(SnapMiss::NotFound);
    }
    pixels.sort_unstable_by_key(|p| p.0);
    Ok(Blob {
        centre: [(sx / sw) as f32, (sy / sw) as f32],
        energy: sw as f32,
        pixels,
        saturated,
        clipped,
        shared,
    })
}

/// The outcome of one dot image.
#[derive(Clone, Debug, Default)]
pub struct DotImageResult {
    pub dx: u32,
    pub dy: u32,
    /// Projector pixel index (`qy * width + qx`) and its blob.
    pub blobs: Vec<(u32, Blob)>,
    /// Dots with no correspondence (off the object or in shadow): not searched.
    pub off_object: usize,
    /// Dots predicted on the object but not found.
    pub not_found: usize,
    /// Dots whose blob ran into the search window's edge.
    pub truncated: usize,
    /// Dots where the blob found lies nearer a neighbouring dot's predicted position than the
    /// dot's own: the dot itself was too dark to find (dark paint, a shadow) and the light
    /// found is its neighbour's, which must not become this pixel's footprint.
    pub elsewhere: usize,
    /// Blobs with a saturated pixel.
    pub saturated: usize,
    /// Blobs cut by the edge of the projector's lit area ([`Blob::clipped`]).
    pub clipped: usize,
    /// Blobs whose light runs on into a neighbouring dot's cell ([`Blob::shared`]).
    pub shared: usize,
    /// Noise standard deviation measured on this image (channel sum).
    pub noise_sigma: f32,
}

impl DotImageResult {
    /// Dots that were searched for (had a prediction).
    pub fn predicted(&self) -> usize {
        self.blobs.len() + self.missed()
    }

    /// Dots predicted on the object that yielded no blob of their own.
    pub fn missed(&self) -> usize {
        self.not_found + self.truncated + self.elsewhere
    }
}

/// The predicted neighbours of dot (qx, qy) at `here`: the eight dots `spacing` away along
/// the axes and diagonals (where the projector's image is sheared in the camera's, a diagonal
/// neighbour can land nearer than the four along the axes).
fn neighbourhood(
    pred: &Predictor,
    qx: u32,
    qy: u32,
    here: [f32; 2],
    spacing: u32,
    max_radius: u32,
) -> Neighbourhood {
    let s = spacing as i64;
    let rivals: Vec<[f32; 2]> = [(s, 0), (-s, 0), (0, s), (0, -s), (s, s), (-s, -s), (s, -s), (-s, s)]
        .iter()
        .filter_map(|&(ox, oy)| {
            let (nx, ny) = (qx as i64 + ox, qy as i64 + oy);
            if nx < 0 || ny < 0 || nx >= pred.proj_width as i64 || ny >= pred.proj_height as i64 {
                return None;
            }
            pred.predict(nx as u32, ny as u32)
        })
        .collect();
    Neighbourhood::new(here, rivals, spacing, max_radius)
}

/// Snaps every dot of one dot image (`spacing`, shift `dx`, `dy`).
pub fn snap_dot_image(
    image: &DotSignal,
    ctx: &SnapContext,
    pred: &Predictor,
    spacing: u32,
    (dx, dy): (u32, u32),
    params: &SnapParams,
) -> DotImageResult {
    let sigma = noise_sigma(image, ctx);
    let quant = 3.0 * 3.0 / 65535.0;
    let detect = (params.detect_sigmas * sigma).max(2.0 * quant);
    let member = (params.member_sigmas * sigma).max(quant);
    let mut out = DotImageResult { dx, dy, noise_sigma: sigma, ..Default::default() };
    for qy in (dy..pred.proj_height).step_by(spacing as usize) {
        for qx in (dx..pred.proj_width).step_by(spacing as usize) {
            let Some(guess) = pred.predict(qx, qy) else {
                out.off_object += 1;
                continue;
            };
            let around = neighbourhood(pred, qx, qy, guess, spacing, params.max_radius);
            match snap_blob(image, ctx, guess, &around, detect, member) {
                // The window reaches halfway to the neighbours (further where the minimum radius
                // applies), so a dark dot's window can hold a neighbour's bright edge.
                Ok(blob) if (blob.centre[0] - guess[0]).hypot(blob.centre[1] - guess[1]) > around.halfway => {
                    out.elsewhere += 1
                }
                Ok(blob) => {
                    out.saturated += blob.saturated as usize;
                    out.clipped += blob.clipped as usize;
                    out.shared += blob.shared as usize;
                    out.blobs.push((qy * pred.proj_width + qx, blob));
                }
                Err(SnapMiss::NotFound) => out.not_found += 1,
                Err(SnapMiss::Truncated) => out.truncated += 1,
                Err(SnapMiss::Elsewhere) => out.elsewhere += 1,
            }
        }
    }
    out
}

/// A snapped dot: projector pixel, camera centre, energy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dot {
    pub projector_px: [u32; 2],
    pub camera: [f32; 2],
    pub energy: f32,
    /// See [`Blob::clipped`] and [`Blob::shared`]: such a dot's centre does not refine
    /// correspondences.
    pub clipped: bool,
}

/// Everything the transport step learns about one projector.
#[derive(Clone, Debug, Default)]
pub struct TransportResult {
    pub transport: Transport,
    pub dots: Vec<Dot>,
    /// Per dot image: name, counts.
    pub images: Vec<(String, DotImageResult)>,
    /// Human-readable warnings naming the projector and the images.
    pub warnings: Vec<String>,
}

impl TransportResult {
    /// Share of predicted dots that were found, 0..=1.
    pub fn found_fraction(&self) -> f64 {
        let predicted: usize = self.images.iter().map(|(_, r)| r.predicted()).sum();
        if predicted == 0 { 0.0 } else { self.dots.len() as f64 / predicted as f64 }
    }
}

/// Builds a projector's transport from its dot images' results (in any order), checking that
/// the shifts are distinct, and writes warnings for images where dots went missing.
pub fn assemble(
    projector: usize,
    proj_width: u32,
    proj_height: u32,
    spacing: u32,
    mut images: Vec<(String, DotImageResult)>,
) -> Result<TransportResult, TransportError> {
    if !(2..=64).contains(&spacing) {
        return Err(TransportError::Spacing { projector, spacing });
    }
    images.sort_by_key(|(_, r)| (r.dy, r.dx));
    let mut seen: HashMap<(u32, u32), String> = HashMap::new();
    let mut warnings = Vec::new();
    let (mut sparse, mut saturated) = (Vec::new(), Vec::new());
    for (name, r) in &images {
        if r.dx >= spacing || r.dy >= spacing {
            return Err(TransportError::Shift {
                projector,
                image: name.clone(),
                dx: r.dx,
                dy: r.dy,
                spacing,
            });
        }
        if let Some(first) = seen.insert((r.dx, r.dy), name.clone()) {
            return Err(TransportError::DuplicateShift {
                projector,
                dx: r.dx,
                dy: r.dy,
                first,
                second: name.clone(),
            });
        }
        let predicted = r.predicted();
        if predicted > 0 && r.missed() * 5 > predicted {
            sparse.push((name, r));
        }
        if r.saturated > 0 {
            saturated.push((name, r.saturated));
        }
    }
    // One warning per kind and projector, however many images (a real capture can have a
    // hundred): the first or worst image is named.
    match sparse.as_slice() {
        [] => {}
        [(name, r)] => warnings.push(format!(
            "projector {projector}: {name}: {} of {} dots predicted on the object were not found ({} not \
             found, {} smeared, {} where only a neighbour's light was found); the correspondences \
             there are kept unrefined",
            r.missed(),
            r.predicted(),
            r.not_found,
            r.truncated,
            r.elsewhere
        )),
        many => {
            let sum = |f: &dyn Fn(&DotImageResult) -> usize| many.iter().map(|(_, r)| f(r)).sum::<usize>();
            let share = |r: &DotImageResult| r.missed() as f64 / r.predicted() as f64;
            let (worst, wr) =
                many.iter().max_by(|a, b| share(a.1).total_cmp(&share(b.1))).copied().unwrap_or(many[0]);
            warnings.push(format!(
                "projector {projector}: in {} of {} dot images more than a fifth of the dots predicted on the \
                 object were not found ({} of {} in all: {} not found, {} smeared, {} where only a \
                 neighbour's light was found; worst {worst}, {:.0} %); the correspondences there are kept \
                 unrefined",
                many.len(),
                images.len(),
                sum(&|r| r.missed()),
                sum(&|r| r.predicted()),
                sum(&|r| r.not_found),
                sum(&|r| r.truncated),
                sum(&|r| r.elsewhere),
                100.0 * share(wr)
            ));
        }
    }
    match saturated.as_slice() {
        [] => {}
        [(name, n)] => warnings.push(format!(
            "projector {projector}: {name}: {n} dots are saturated; their footprint weights are too low"
        )),
        [(name, _), rest @ ..] => warnings.push(format!(
            "projector {projector}: {name} and {} other dot images have saturated dots ({} in all); their \
             footprint weights are too low",
            rest.len(),
            saturated.iter().map(|(_, n)| n).sum::<usize>()
        )),
    }
    let missing = (spacing * spacing) as usize - images.len();
    if missing > 0 {
        warnings.push(format!(
            "projector {projector}: {missing} of {} dot shifts were not captured; their projector pixels \
             have no transport",
            spacing * spacing
        ));
    }
    let n = proj_width as usize * proj_height as usize;
    let mut counts = vec![0u32; n + 1];
    let mut dots = Vec::new();
    for (_, r) in &images {
        for (q, b) in &r.blobs {
            counts[*q as usize + 1] = b.pixels.len() as u32;
            dots.push(Dot {
                projector_px: [q % proj_width, q / proj_width],
                camera: b.centre,
                energy: b.energy,
                // Either way the weighted centre is pulled off the pixel's.
                clipped: b.clipped || b.shared,
            });
        }
    }
    for i in 0..n {
        counts[i + 1] += counts[i];
    }
    let total = counts[n] as usize;
    let mut camera_pixel = vec![0u32; total];
    let mut weight = vec![0f32; total];
    for (_, r) in &images {
        for (q, b) in &r.blobs {
            let start = counts[*q as usize] as usize;
            for (k, (p, w)) in b.pixels.iter().enumerate() {
                camera_pixel[start + k] = *p;
                weight[start + k] = *w;
            }
        }
    }
    dots.sort_by_key(|d| (d.projector_px[1], d.projector_px[0]));
    Ok(TransportResult {
        transport: Transport { row_start: counts, camera_pixel, weight },
        dots,
        images,
        warnings,
    })
}

/// Checks the black/white pair a projector's transport is measured against.
pub fn check_reference(
    projector: usize,
    black: &LinearImage,
    white: &LinearImage,
    white_name: &str,
    cam_width: u32,
    cam_height: u32,
) -> Result<(), TransportError> {
    for (what, img) in [("black image", black), ("white image", white)] {
        if img.width != cam_width || img.height != cam_height {
            return Err(TransportError::Size {
                projector,
                what: what.into(),
                got_w: img.width,
                got_h: img.height,
                want_w: cam_width,
                want_h: cam_height,
            });
        }
    }
    let (mut lit, mut sat) = (0usize, 0usize);
    for (w, b) in white.data.iter().zip(&black.data) {
        if w[0] + w[1] + w[2] - b[0] - b[1] - b[2] > 0.03 {
            lit += 1;
            sat += w.iter().any(|&c| c >= SATURATED) as usize;
        }
    }
    if lit > 0 && sat * 2 >= lit {
        return Err(TransportError::WhiteSaturated {
            projector,
            white: white_name.into(),
            percent: 100.0 * sat as f64 / lit as f64,
        });
    }
    Ok(())
}

/// Statistics of a correspondence refinement.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefineStats {
    /// Camera pixels whose correspondence was replaced.
    pub refined: usize,
    /// Camera pixels with a correspondence but too few dots nearby.
    pub too_few_dots: usize,
    /// Camera pixels where the dots disagreed with the decoded value by more than the limit.
    pub disagreed: usize,
    /// Median change applied, projector pixels.
    pub median_shift: f32,
}

/// Width (camera px, Gaussian sigma) of the taper between refined and unrefined correspondences.
const SEAM_SIGMA_PX: f32 = 2.0;

/// Refines per-camera-pixel correspondences with snapped dots: at each camera pixel, a
/// Gaussian-weighted local affine fit of projector coordinate against camera position over
/// the dots within a few pixels, evaluated at the pixel, and tapered towards the decoded value
/// where the pixels around were not refined.
pub fn refine_correspondences(
    correspondence: &[[f32; 2]],
    cam_width: u32,
    cam_height: u32,
    dots: &[Dot],
    max_shift: f32,
) -> (Vec<[f32; 2]>, RefineStats) {
    let (w, h) = (cam_width as usize, cam_height as usize);
    // Bucket dots by nearest camera pixel (compressed rows over camera pixels).
    let mut start = vec![0u32; w * h + 1];
    let bucket = |d: &Dot| -> Option<usize> {
        let (x, y) = (d.camera[0].round(), d.camera[1].round());
        (x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h).then(|| y as usize * w + x as usize)
    };
    for d in dots {
        if let Some(b) = bucket(d) {
            start[b + 1] += 1;
        }
    }
    for i in 0..w * h {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; start[w * h] as usize];
    for (k, d) in dots.iter().enumerate() {
        if let Some(b) = bucket(d) {
            order[fill[b] as usize] = k as u32;
            fill[b] += 1;
        }
    }
    #[derive(Clone, Copy)]
    enum Outcome {
        Skip,
        Few,
        Disagree,
        Refined(f32),
    }
    let results: Vec<([f32; 2], Outcome)> = correspondence
        .par_iter()
        .enumerate()
        .map(|(i, c)| {
            if !(c[0].is_finite() && c[1].is_finite()) {
                return (*c, Outcome::Skip);
            }
            let (px, py) = ((i % w) as f32, (i / w) as f32);
            for radius in [2i64, 4] {
                if let Some(fit) = local_affine(px, py, radius, w, h, &start, &order, dots) {
                    let shift = ((fit[0] - c[0]).powi(2) + (fit[1] - c[1]).powi(2)).sqrt();
                    if shift > max_shift {
                        return (*c, Outcome::Disagree);
                    }
                    return (fit, Outcome::Refined(shift));
                }
            }
            (*c, Outcome::Few)
        })
        .collect();
    let mut stats = RefineStats::default();
    let mut shifts = Vec::new();
    // Each refined pixel moves from its decoded value towards its dot fit by the share of
    // refined pixels around it (a Gaussian of SEAM_SIGMA_PX over the decoded pixels), so the
    // seams between refined and unrefined pixels taper instead of stepping: a step is a bump
    // in the surface triangulated from them. The fit itself is kept whole inside refined areas
    // (smoothing the shift instead would bring the decode's per-pixel noise back).
    let valid: Vec<bool> = correspondence.iter().map(|c| c[0].is_finite() && c[1].is_finite()).collect();
    let is_refined: Vec<f32> =
        results.iter().map(|(_, o)| if matches!(o, Outcome::Refined(_)) { 1.0 } else { 0.0 }).collect();
    let share = smooth_masked(&is_refined, &valid, w, h, SEAM_SIGMA_PX);
    let mut refined = Vec::with_capacity(results.len());
    for ((r, o), (c, &near)) in results.into_iter().zip(correspondence.iter().zip(&share)) {
        let a = if matches!(o, Outcome::Refined(_)) { near } else { 0.0 };
        refined.push(if c[0].is_finite() && c[1].is_finite() {
            [c[0] + a * (r[0] - c[0]), c[1] + a * (r[1] - c[1])]
        } else {
            *c
        });
        match o {
            Outcome::Skip => {}
            Outcome::Few => stats.too_few_dots += 1,
            Outcome::Disagree => stats.disagreed += 1,
            Outcome::Refined(shift) => {
                stats.refined += 1;
                shifts.push(a * shift);
            }
        }
    }
    if !shifts.is_empty() {
        let mid = shifts.len() / 2;
        stats.median_shift = *shifts.select_nth_unstable_by(mid, f32::total_cmp).1;
    }
    (refined, stats)
}

/// Gaussian smoothing of `field` over the pixels where `valid`, normalised by the weight that
/// falls on valid pixels (the others neither give nor take); 0 where not valid.
fn smooth_masked(field: &[f32], valid: &[bool], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp()).collect();
    // (weighted sum of the field, sum of weights) per pixel, one axis at a time.
    let pass = |src: &[[f32; 2]], horizontal: bool| -> Vec<[f32; 2]> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                let mut acc = [0.0f32; 2];
                for (k, wt) in (-r..=r).zip(&kernel) {
                    let (u, v) = if horizontal { (x + k, y) } else { (x, y + k) };
                    if (0..w as i64).contains(&u) && (0..h as i64).contains(&v) {
                        let s = src[v as usize * w + u as usize];
                        acc = [acc[0] + wt * s[0], acc[1] + wt * s[1]];
                    }
                }
                acc
            })
            .collect()
    };
    let start: Vec<[f32; 2]> =
        field.iter().zip(valid).map(|(&f, &ok)| if ok { [f, 1.0] } else { [0.0; 2] }).collect();
    pass(&pass(&start, true), false)
        .iter()
        .zip(valid)
        .map(|(a, &ok)| if ok && a[1] > 0.0 { a[0] / a[1] } else { 0.0 })
        .collect()
}

/// Weighted least-squares fit `q = a + J (c - p)` over the dots bucketed within `radius` of
/// camera pixel p; returns `a`, or `None` with fewer than 6 dots or a degenerate spread.
#[allow(clippy::too_many_arguments)]
fn local_affine(
    px: f32,
    py: f32,
    radius: i64,
    w: usize,
    h: usize,
    start: &[u32],
    order: &[u32],
    dots: &[Dot],
) -> Option<[f32; 2]> {
    let sigma2 = (radius as f64 * 0.6).powi(2);
    let mut m = [[0.0f64; 3]; 3];
    let mut bx = [0.0f64; 3];
    let mut by = [0.0f64; 3];
    let mut n = 0;
    let (cx, cy) = (px as i64, py as i64);
    for y in (cy - radius).max(0)..=(cy + radius).min(h as i64 - 1) {
        for x in (cx - radius).max(0)..=(cx + radius).min(w as i64 - 1) {
            let b = y as usize * w + x as usize;
            for &k in &order[start[b] as usize..start[b + 1] as usize] {
                let d = &dots[k as usize];
                let (ex, ey) = ((d.camera[0] - px) as f64, (d.camera[1] - py) as f64);
                let wt = (-(ex * ex + ey * ey) / (2.0 * sigma2)).exp();
                let basis = [1.0, ex, ey];
                for r in 0..3 {
                    for c in 0..3 {
                        m[r][c] += wt * basis[r] * basis[c];
                    }
                    bx[r] += wt * basis[r] * d.projector_px[0] as f64;
                    by[r] += wt * basis[r] * d.projector_px[1] as f64;
                }
                n += 1;
            }
        }
    }
    if n < 6 {
        return None;
    }
    let m = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
    // Degenerate when the dots are (nearly) collinear: the smallest singular value is tiny.
    let sv = m.singular_values();
    if sv.min() < 1e-6 * sv.max() {
        return None;
    }
    let inv = m.try_inverse()?;
    let ax = inv * nalgebra::Vector3::from(bx);
    let ay = inv * nalgebra::Vector3::from(by);
    Some([ax[0] as f32, ay[0] as f32])
}

/// Projector pixels around which a missing footprint is filled: its measured neighbours
/// within this many projector pixels (Chebyshev) must surround it.
pub const FILL_REACH: i64 = 3;

/// Fills the footprints of projector pixels whose dots were not measured but whose measured
/// neighbours surround them (within [`FILL_REACH`] on every side): dots on dark clay or dark
/// paint too faint to find, or where the structured light did not decode so no dot was
/// searched. Their light still lands, and a camera pixel there would otherwise be modelled
/// from the few of its projector pixels that were found, as if the missing ones did not
/// spill onto it (the refinement then underrates the halo a chip's bright pixels throw on
/// their neighbours). Each is the nearest whole measured footprint moved by the offset a
/// local affine fit of the surrounding dots' centres gives, on the camera pixels this
/// projector lights. Returns how many were filled.
pub fn fill_missing(
    result: &mut TransportResult,
    ctx: &SnapContext,
    proj_width: u32,
    proj_height: u32,
) -> usize {
    let n = proj_width as usize * proj_height as usize;
    if result.transport.row_start.len() != n + 1 {
        return 0;
    }
    let mut centre: Vec<Option<[f32; 2]>> = vec![None; n];
    for d in result.dots.iter().filter(|d| !d.clipped) {
        let q = d.projector_px[1] as usize * proj_width as usize + d.projector_px[0] as usize;
        if result.transport.row_start[q] < result.transport.row_start[q + 1] {
            centre[q] = Some(d.camera);
        }
    }
    fill_from(&mut result.transport, &centre, ctx, proj_width, proj_height)
}

/// [`fill_missing`] from the measured footprints and their dots' centres, in one pass (filling
/// again from the filled ones, in rounds, closed larger chips but made the view worse:
/// docs/calibrate.md).
fn fill_from(
    t: &mut Transport,
    centre: &[Option<[f32; 2]>],
    ctx: &SnapContext,
    proj_width: u32,
    proj_height: u32,
) -> usize {
    let n = centre.len();
    let (cw, ch) = (ctx.width as i64, ctx.height as i64);
    let filled: Vec<(usize, Vec<(u32, f32)>)> = (0..n)
        .into_par_iter()
        .filter(|&q| t.row_start[q] == t.row_start[q + 1])
        .filter_map(|q| {
            let (qx, qy) = ((q % proj_width as usize) as i64, (q / proj_width as usize) as i64);
            let mut near: Vec<([f64; 2], [f32; 2], usize)> = Vec::new();
            for y in (qy - FILL_REACH).max(0)..=(qy + FILL_REACH).min(proj_height as i64 - 1) {
                for x in (qx - FILL_REACH).max(0)..=(qx + FILL_REACH).min(proj_width as i64 - 1) {
                    let j = y as usize * proj_width as usize + x as usize;
                    if let Some(c) = centre[j] {
                        near.push(([(x - qx) as f64, (y - qy) as f64], c, j));
                    }
                }
            }
            let side = |f: &dyn Fn(&[f64; 2]) -> bool| near.iter().any(|n| f(&n.0));
            if !(side(&|o| o[0] < 0.0)
                && side(&|o| o[0] > 0.0)
                && side(&|o| o[1] < 0.0)
                && side(&|o| o[1] > 0.0))
            {
                return None;
            }
            // Camera position = a + J (q' - q), least squares over the surrounding centres.
            let mut m = [[0.0f64; 3]; 3];
            let mut rhs = [[0.0f64; 3]; 2];
            for (o, c, _) in &near {
                let v = [1.0, o[0], o[1]];
                for a in 0..3 {
                    for b in 0..3 {
                        m[a][b] += v[a] * v[b];
                    }
                    rhs[0][a] += v[a] * c[0] as f64;
                    rhs[1][a] += v[a] * c[1] as f64;
                }
            }
            let m = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
            if m.determinant().abs() < 1e-9 {
                return None;
            }
            let inv = m.try_inverse()?;
            let fit = [inv * nalgebra::Vector3::from(rhs[0]), inv * nalgebra::Vector3::from(rhs[1])];
            let (o, _, j) =
                near.iter().min_by(|a, b| (a.0[0].hypot(a.0[1])).total_cmp(&b.0[0].hypot(b.0[1])))?;
            // The template's offset from this pixel, as the fit has it.
            let shift = [-(fit[0][1] * o[0] + fit[0][2] * o[1]), -(fit[1][1] * o[0] + fit[1][2] * o[1])];
            let (fx, fy) = (shift[0].floor(), shift[1].floor());
            let (ax, ay) = ((shift[0] - fx) as f32, (shift[1] - fy) as f32);
            let mut out: Vec<(u32, f32)> = Vec::new();
            for e in t.row_start[*j] as usize..t.row_start[*j + 1] as usize {
                let p = t.camera_pixel[e] as i64;
                let (x, y) = (p % cw + fx as i64, p / cw + fy as i64);
                for (dx, dy, wt) in [
                    (0, 0, (1.0 - ax) * (1.0 - ay)),
                    (1, 0, ax * (1.0 - ay)),
                    (0, 1, (1.0 - ax) * ay),
                    (1, 1, ax * ay),
                ] {
                    let (x, y) = (x + dx, y + dy);
                    if wt <= 0.0 || x < 0 || y < 0 || x >= cw || y >= ch {
                        continue;
                    }
                    let i = (y * cw + x) as u32;
                    if ctx.lit[i as usize] < ctx.lit_min {
                        continue;
                    }
                    match out.iter_mut().find(|v| v.0 == i) {
                        Some(v) => v.1 += wt * t.weight[e],
                        None => out.push((i, wt * t.weight[e])),
                    }
                }
            }
            out.sort_unstable_by_key(|v| v.0);
            (!out.is_empty()).then_some((q, out))
        })
        .collect();
    if filled.is_empty() {
        return 0;
    }
    let mut extra: Vec<Option<&Vec<(u32, f32)>>> = vec![None; n];
    for (q, e) in &filled {
        extra[*q] = Some(e);
    }
    let mut next = Transport { row_start: Vec::with_capacity(n + 1), ..Default::default() };
    next.row_start.push(0);
    for (q, e) in extra.iter().enumerate() {
        match e {
            Some(e) => e.iter().for_each(|&(p, w)| {
                next.camera_pixel.push(p);
                next.weight.push(w);
            }),
            None => {
                let r = t.row_start[q] as usize..t.row_start[q + 1] as usize;
                next.camera_pixel.extend_from_slice(&t.camera_pixel[r.clone()]);
                next.weight.extend_from_slice(&t.weight[r]);
            }
        }
        next.row_start.push(next.camera_pixel.len() as u32);
    }
    *t = next;
    filled.len()
}

/// Per projector pixel footprint energy (sum of weights, camera pixels' worth of light);
/// NaN where the transport has no row for the pixel.
pub fn footprint_energy(t: &Transport, proj_width: u32, proj_height: u32) -> Vec<f32> {
    let n = proj_width as usize * proj_height as usize;
    if t.row_start.len() != n + 1 {
        return vec![f32::NAN; n];
    }
    (0..n)
        .map(|q| {
            let (a, b) = (t.row_start[q] as usize, t.row_start[q + 1] as usize);
            if a == b { f32::NAN } else { t.weight[a..b].iter().sum() }
        })
        .collect()
}

/// Per camera pixel: whether any projector pixel's footprint of `t` reaches it.
pub fn coverage_mask(t: &Transport, camera_pixels: usize) -> Vec<bool> {
    let mut m = vec![false; camera_pixels];
    for &p in &t.camera_pixel {
        if let Some(v) = m.get_mut(p as usize) {
            *v = true;
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// A synthetic stage: the projector maps to the camera by `cam = origin + scale * q`, every
    /// projector pixel's light is a Gaussian blob of `sigma` camera px, albedo varies per pixel.
    struct Synth {
        cam_w: u32,
        cam_h: u32,
        proj_w: u32,
        proj_h: u32,
        origin: [f32; 2],
        scale: f32,
        sigma: f32,
        noise: f32,
        albedo: Vec<f32>,
    }

    impl Synth {
        fn new(seed: u64) -> Self {
            let (cam_w, cam_h) = (96, 80);
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let albedo = (0..cam_w * cam_h).map(|_| rng.gen_range(0.4f32..0.9)).collect();
            Self {
                cam_w,
                cam_h,
                proj_w: 48,
                proj_h: 40,
                origin: [8.3, 6.7],
                scale: 1.6,
                sigma: 0.9,
                noise: 0.001,
                albedo,
            }
        }

        fn cam_of(&self, q: [f32; 2]) -> [f32; 2] {
            [self.origin[0] + self.scale * q[0], self.origin[1] + self.scale * q[1]]
        }

        /// Irradiance share at camera pixel p from projector pixel q (analytic, normalised so the
        /// shares of all q at a camera pixel sum to one inside the lit area).
        fn share(&self, q: [f32; 2], p: [f32; 2]) -> f32 {
            let c = self.cam_of(q);
            let d2 = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2);
            let s = self.sigma;
            (-d2 / (2.0 * s * s)).exp() * self.scale * self.scale / (2.0 * std::f32::consts::PI * s * s)
        }

        fn render(&self, lit: impl Fn(u32, u32) -> bool, rng: &mut ChaCha8Rng, level: f32) -> LinearImage {
            let mut img = LinearImage::new(self.cam_w, self.cam_h).unwrap();
            for y in 0..self.cam_h {
                for x in 0..self.cam_w {
                    let p = [x as f32, y as f32];
                    // Projector pixels near p (the Gaussian is negligible beyond 4 sigma).
                    let qc = [(p[0] - self.origin[0]) / self.scale, (p[1] - self.origin[1]) / self.scale];
                    let reach = (4.0 * self.sigma / self.scale).ceil() as i32 + 1;
                    let mut e = 0.0;
                    for qy in qc[1].round() as i32 - reach..=qc[1].round() as i32 + reach {
                        for qx in qc[0].round() as i32 - reach..=qc[0].round() as i32 + reach {
                            if qx < 0 || qy < 0 || qx >= self.proj_w as i32 || qy >= self.proj_h as i32 {
                                continue;
                            }
                            if lit(qx as u32, qy as u32) {
                                e += self.share([qx as f32, qy as f32], p);
                            }
                        }
                    }
                    let a = self.albedo[(y * self.cam_w + x) as usize];
                    let v = 0.02 + level * a * e;
                    let px = [0, 1, 2].map(|c| {
                        (v * [1.0, 0.9, 0.8][c] + self.noise * rng.gen_range(-1.7f32..1.7)).clamp(0.0, 1.0)
                    });
                    img.set(x, y, px);
                }
            }
            img
        }

        fn correspondences(&self, rng: &mut ChaCha8Rng, jitter: f32) -> Vec<[f32; 2]> {
            let mut out = vec![[f32::NAN; 2]; (self.cam_w * self.cam_h) as usize];
            for y in 0..self.cam_h {
                for x in 0..self.cam_w {
                    let q =
                        [(x as f32 - self.origin[0]) / self.scale, (y as f32 - self.origin[1]) / self.scale];
                    if q[0] >= -0.5
                        && q[1] >= -0.5
                        && q[0] < self.proj_w as f32 - 0.5
                        && q[1] < self.proj_h as f32 - 0.5
                    {
                        out[(y * self.cam_w + x) as usize] = [
                            q[0] + jitter * rng.gen_range(-1.0f32..1.0),
                            q[1] + jitter * rng.gen_range(-1.0f32..1.0),
                        ];
                    }
                }
            }
            out
        }
    }

    fn run(synth: &Synth, spacing: u32, jitter: f32) -> (TransportResult, Vec<[f32; 2]>) {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let black = synth.render(|_, _| false, &mut rng, 0.5);
        let white = synth.render(|_, _| true, &mut rng, 0.5);
        let corr = synth.correspondences(&mut rng, jitter);
        let params = SnapParams::default();
        let ctx = SnapContext::new(&black, &white, synth.noise, &params);
        let pred = Predictor::new(&corr, synth.cam_w, synth.proj_w, synth.proj_h);
        (snap_all(synth, &ctx, &pred, &params, spacing, &mut rng), corr)
    }

    /// Renders and snaps every dot image of `synth` at `spacing`, and assembles them.
    fn snap_all(
        synth: &Synth,
        ctx: &SnapContext,
        pred: &Predictor,
        params: &SnapParams,
        spacing: u32,
        rng: &mut ChaCha8Rng,
    ) -> TransportResult {
        let mut images = Vec::new();
        for dy in 0..spacing {
            for dx in 0..spacing {
                let img = synth.render(|x, y| x % spacing == dx && y % spacing == dy, rng, 0.5);
                let r = snap_dot_image(&DotSignal::from_linear(&img), ctx, pred, spacing, (dx, dy), params);
                images.push((format!("dots_{dx}_{dy}.png"), r));
            }
        }
        assemble(0, synth.proj_w, synth.proj_h, spacing, images).unwrap()
    }

    /// The black and white references at `level`, exact correspondences and their predictor.
    fn references(
        synth: &Synth,
        rng: &mut ChaCha8Rng,
        level: f32,
    ) -> (LinearImage, SnapContext, Predictor, SnapParams) {
        let black = synth.render(|_, _| false, rng, level);
        let white = synth.render(|_, _| true, rng, level);
        let corr = synth.correspondences(rng, 0.0);
        let params = SnapParams::default();
        let ctx = SnapContext::new(&black, &white, synth.noise, &params);
        let pred = Predictor::new(&corr, synth.cam_w, synth.proj_w, synth.proj_h);
        (black, ctx, pred, params)
    }

    #[test]
    fn blobs_snap_to_known_centres_under_noise() {
        let synth = Synth::new(1);
        let (res, _) = run(&synth, 8, 0.6);
        assert!(res.dots.len() > 800, "found {}", res.dots.len());
        let mut errs: Vec<f32> = res
            .dots
            .iter()
            .map(|d| {
                let t = synth.cam_of([d.projector_px[0] as f32, d.projector_px[1] as f32]);
                ((d.camera[0] - t[0]).powi(2) + (d.camera[1] - t[1]).powi(2)).sqrt()
            })
            .collect();
        errs.sort_by(f32::total_cmp);
        let median = errs[errs.len() / 2];
        assert!(median < 0.05, "median dot error {median} px");
        // Dots on the projector's border spill light past the lit area's edge: clipped, their
        // centres pulled inwards; interior dots are whole.
        let border = |d: &Dot| d.projector_px[0] == 0 || d.projector_px[1] == 0;
        let interior = |d: &Dot| {
            (2..synth.proj_w - 2).contains(&d.projector_px[0])
                && (2..synth.proj_h - 2).contains(&d.projector_px[1])
        };
        assert!(res.dots.iter().filter(|d| interior(d)).all(|d| !d.clipped));
        let edge: Vec<&Dot> = res.dots.iter().filter(|d| border(d)).collect();
        assert!(!edge.is_empty() && edge.iter().all(|d| d.clipped), "{edge:?}");
        // Interior footprints carry one projector pixel's worth of light: scale^2 camera px.
        let energy = footprint_energy(&res.transport, synth.proj_w, synth.proj_h);
        let q = 20 * synth.proj_w as usize + 20;
        let want = synth.scale * synth.scale;
        assert!((energy[q] - want).abs() / want < 0.05, "energy {} vs {want}", energy[q]);
    }

    #[test]
    fn refinement_removes_decoding_jitter() {
        let synth = Synth::new(2);
        let (res, corr) = run(&synth, 8, 0.6);
        let (refined, stats) = refine_correspondences(&corr, synth.cam_w, synth.cam_h, &res.dots, 2.0);
        assert!(stats.refined > 3000, "{stats:?}");
        let err = |c: &[[f32; 2]]| {
            let mut e: Vec<f32> = (0..c.len())
                .filter(|&i| c[i][0].is_finite())
                .filter_map(|i| {
                    let (x, y) = ((i as u32 % synth.cam_w) as f32, (i as u32 / synth.cam_w) as f32);
                    let t = [(x - synth.origin[0]) / synth.scale, (y - synth.origin[1]) / synth.scale];
                    // Interior only: the border has no dots on one side.
                    (t[0] > 2.0
                        && t[1] > 2.0
                        && t[0] < synth.proj_w as f32 - 3.0
                        && t[1] < synth.proj_h as f32 - 3.0)
                        .then(|| ((c[i][0] - t[0]).powi(2) + (c[i][1] - t[1]).powi(2)).sqrt())
                })
                .collect();
            e.sort_by(f32::total_cmp);
            e[e.len() / 2]
        };
        let (before, after) = (err(&corr), err(&refined));
        assert!(after < 0.05 && after < before / 5.0, "median error before {before}, after {after}");
    }

    #[test]
    fn dots_off_the_object_are_counted_not_searched() {
        let synth = Synth::new(3);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let black = synth.render(|_, _| false, &mut rng, 0.5);
        let white = synth.render(|_, _| true, &mut rng, 0.5);
        let mut corr = synth.correspondences(&mut rng, 0.0);
        // The object ends at camera column 50: the correspondences stop there.
        for (i, c) in corr.iter_mut().enumerate() {
            if i as u32 % synth.cam_w >= 50 {
                *c = [f32::NAN; 2];
            }
        }
        let params = SnapParams::default();
        let ctx = SnapContext::new(&black, &white, synth.noise, &params);
        let pred = Predictor::new(&corr, synth.cam_w, synth.proj_w, synth.proj_h);
        let img = synth.render(|x, y| x % 8 == 3 && y % 8 == 3, &mut rng, 0.5);
        let r = snap_dot_image(&DotSignal::from_linear(&img), &ctx, &pred, 8, (3, 3), &params);
        assert!(r.off_object > 0 && !r.blobs.is_empty(), "{r:?}");
        assert_eq!(r.off_object + r.predicted(), (6 * 5) as usize);
    }

    #[test]
    fn saturation_and_missing_dots_are_reported_by_image() {
        let synth = Synth::new(4);
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let (black, ctx, pred, params) = references(&synth, &mut rng, 0.5);
        let bright = synth.render(|x, y| x % 8 == 0 && y % 8 == 0, &mut rng, 8.0);
        let dark = synth.render(|_, _| false, &mut rng, 0.5);
        let images = vec![
            (
                "proj0/dots_0_0.png".to_string(),
                snap_dot_image(&DotSignal::from_linear(&bright), &ctx, &pred, 8, (0, 0), &params),
            ),
            (
                "proj0/dots_1_0.png".to_string(),
                snap_dot_image(&DotSignal::from_linear(&dark), &ctx, &pred, 8, (1, 0), &params),
            ),
        ];
        let res = assemble(0, synth.proj_w, synth.proj_h, 8, images).unwrap();
        let all = res.warnings.join("\n");
        assert!(all.contains("projector 0: proj0/dots_0_0.png") && all.contains("saturated"), "{all}");
        assert!(all.contains("proj0/dots_1_0.png") && all.contains("not found"), "{all}");
        assert!(all.contains("62 of 64 dot shifts were not captured"), "{all}");
        // A saturated white reference is an error naming the image.
        let err = check_reference(0, &black, &bright, "proj0/white.png", synth.cam_w, synth.cam_h);
        assert!(err.is_ok(), "few saturated pixels are tolerated");
        let white_sat = synth.render(|_, _| true, &mut rng, 20.0);
        let err = check_reference(0, &black, &white_sat, "proj0/white.png", synth.cam_w, synth.cam_h)
            .unwrap_err()
            .to_string();
        assert!(err.contains("proj0/white.png") && err.contains("saturated"), "{err}");
    }

    #[test]
    fn a_diagonal_neighbour_nearer_than_the_axis_ones_bounds_the_window() {
        // A sheared view (the bowl's flank at seed 9): projector x runs along camera x, projector
        // y mostly along camera x too, so the dot at (+8, -8) lands 2.9 camera px away while
        // those at (+8, 0) and (0, +8) are 11-12 px away. A window sized by the axis neighbours
        // (5 px) held the diagonal neighbour's whole blob, which became this dot's footprint.
        let (cam_w, proj_w, proj_h) = (200u32, 48u32, 40u32);
        let cam = |q: [f32; 2]| [10.0 + 1.5 * q[0] + 1.4 * q[1], 30.0 + 0.3 * q[0] - 0.05 * q[1]];
        let mut corr = vec![[f32::NAN; 2]; (cam_w * 60) as usize];
        for qy in 0..proj_h {
            for qx in 0..proj_w {
                let c = cam([qx as f32, qy as f32]);
                corr[c[1].round() as usize * cam_w as usize + c[0].round() as usize] = [qx as f32, qy as f32];
            }
        }
        let pred = Predictor::new(&corr, cam_w, proj_w, proj_h);
        let (qx, qy) = (16, 16);
        let here = pred.predict(qx, qy).unwrap();
        let Neighbourhood { radius, halfway, .. } = neighbourhood(&pred, qx, qy, here, 8, 24);
        let diagonal = pred.predict(qx + 8, qy - 8).unwrap();
        let half_diagonal = 0.5 * (diagonal[0] - here[0]).hypot(diagonal[1] - here[1]);
        assert!(half_diagonal < 2.0, "the set-up: the diagonal neighbour is {half_diagonal} px halfway");
        assert_eq!(radius, 2, "the smallest window");
        assert!(halfway <= half_diagonal + 1e-4, "halfway {halfway} vs {half_diagonal}");
    }

    #[test]
    fn a_dot_too_dark_to_find_does_not_take_its_neighbours_light() {
        // Dots 2 projector px apart land 3 camera px apart, so even the smallest window (2 px)
        // reaches past halfway to the neighbours. Only the neighbour (12, 10) is lit: the dot
        // at (10, 10) (dark paint, a shadow) must not be given its blob.
        let synth = Synth { scale: 1.5, sigma: 0.45, ..Synth::new(5) };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (_, ctx, pred, params) = references(&synth, &mut rng, 1.0);
        let img = synth.render(|x, y| (x, y) == (12, 10), &mut rng, 1.0);
        let r = snap_dot_image(&DotSignal::from_linear(&img), &ctx, &pred, 2, (0, 0), &params);
        let found: Vec<u32> = r.blobs.iter().map(|(q, _)| *q).collect();
        assert_eq!(found, vec![10 * synth.proj_w + 12], "{r:?}");
        assert!(r.elsewhere >= 1, "{r:?}");
    }

    /// Every dot image of `synth` at `spacing`, exact correspondences except on the camera
    /// pixels `decoded` refuses, assembled; and the context it was snapped against.
    fn run_decoded(
        synth: &Synth,
        spacing: u32,
        decoded: impl Fn(u32, u32) -> bool,
    ) -> (TransportResult, SnapContext) {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let (_, ctx, _, params) = references(synth, &mut rng, 0.5);
        let mut corr = synth.correspondences(&mut rng, 0.0);
        for (i, c) in corr.iter_mut().enumerate() {
            if !decoded(i as u32 % synth.cam_w, i as u32 / synth.cam_w) {
                *c = [f32::NAN; 2];
            }
        }
        let pred = Predictor::new(&corr, synth.cam_w, synth.proj_w, synth.proj_h);
        let res = snap_all(synth, &ctx, &pred, &params, spacing, &mut rng);
        (res, ctx)
    }

    /// Per camera pixel, the sum of its shares over the projector pixels `t` measured.
    fn share_sums(t: &Transport, camera_pixels: usize) -> Vec<f32> {
        let mut sum = vec![0.0f32; camera_pixels];
        for (&p, &w) in t.camera_pixel.iter().zip(&t.weight) {
            sum[p as usize] += w;
        }
        sum
    }

    #[test]
    fn touching_dots_share_their_light_by_cells_instead_of_being_lost() {
        // Dots 3 projector px apart land 4.8 camera px apart, and with a blur of 0.9 px their
        // blobs touch above the noise: grown without bounds each ran into its neighbours and
        // was dropped as merged (a projector finer than the camera, an oblique one: 40-60 %
        // of two calibrated projectors' dots on the bowl at seed 47). And the dots light most
        // of the image, which the noise estimate must not read as noise.
        let synth = Synth::new(6);
        let (res, _) = run_decoded(&synth, 3, |_, _| true);
        let interior =
            |q: [u32; 2]| (2..synth.proj_w - 2).contains(&q[0]) && (2..synth.proj_h - 2).contains(&q[1]);
        let inner: Vec<&Dot> = res.dots.iter().filter(|d| interior(d.projector_px)).collect();
        let want = ((synth.proj_w - 4) * (synth.proj_h - 4)) as usize;
        assert!(inner.len() * 100 >= want * 98, "{} of {want} interior dots found", inner.len());
        // Each keeps its own light: one projector pixel's worth (scale^2 camera px), less the
        // tail past the cell's edge.
        let energy = footprint_energy(&res.transport, synth.proj_w, synth.proj_h);
        let want = synth.scale * synth.scale;
        for d in &inner {
            let e = energy[(d.projector_px[1] * synth.proj_w + d.projector_px[0]) as usize];
            assert!((0.9 * want..1.05 * want).contains(&e), "{:?}: energy {e} vs {want}", d.projector_px);
        }
        // And every camera pixel inside has all its light accounted for.
        let sums = share_sums(&res.transport, (synth.cam_w * synth.cam_h) as usize);
        for (i, s) in sums.iter().enumerate() {
            let (x, y) = (i as u32 % synth.cam_w, i as u32 / synth.cam_w);
            if (16..80).contains(&x) && (14..64).contains(&y) {
                assert!((0.9..1.1).contains(s), "camera pixel ({x}, {y}): share sum {s}");
            }
        }
    }

    #[test]
    fn footprints_of_dots_not_searched_are_filled_from_the_dots_around() {
        // A patch the structured light did not decode (dark paint): its dots are not searched,
        // yet their light lands there and spills onto the decoded paint around.
        let synth = Synth::new(7);
        let patch = |x: u32, y: u32| (40..50).contains(&x) && (30..40).contains(&y);
        let (mut res, ctx) = run_decoded(&synth, 4, |x, y| !patch(x, y));
        let pixels = (synth.cam_w * synth.cam_h) as usize;
        let inside: Vec<usize> =
            (0..pixels).filter(|&i| patch(i as u32 % synth.cam_w, i as u32 / synth.cam_w)).collect();
        let mean = |sums: &[f32]| inside.iter().map(|&i| sums[i]).sum::<f32>() / inside.len() as f32;
        let before = mean(&share_sums(&res.transport, pixels));
        assert!(before < 0.6, "the set-up: the patch's share sum is {before} before filling");
        let filled = fill_missing(&mut res, &ctx, synth.proj_w, synth.proj_h);
        let after = mean(&share_sums(&res.transport, pixels));
        assert!(filled > 0 && (0.9..1.05).contains(&after), "{filled} filled, share sum {before} -> {after}");
        // A filled footprint is where its pixel's light lands, and as wide.
        let q = [23u32, 16u32];
        let c = synth.cam_of([q[0] as f32, q[1] as f32]);
        assert!(patch(c[0].round() as u32, c[1].round() as u32), "the set-up: {c:?}");
        let row = (q[1] * synth.proj_w + q[0]) as usize;
        let t = &res.transport;
        let (mut miss, mut total) = (0.0f32, 0.0f32);
        for e in t.row_start[row] as usize..t.row_start[row + 1] as usize {
            let p = t.camera_pixel[e];
            let truth =
                synth.share([q[0] as f32, q[1] as f32], [(p % synth.cam_w) as f32, (p / synth.cam_w) as f32]);
            miss += (t.weight[e] - truth).abs();
            total += truth;
        }
        assert!(total > 0.8 * synth.scale * synth.scale && miss < 0.2 * total, "off by {miss} of {total}");
    }

    #[test]
    fn duplicate_shifts_are_refused() {
        let r = DotImageResult { dx: 1, dy: 2, ..Default::default() };
        let err = assemble(2, 16, 16, 4, vec![("a.png".into(), r.clone()), ("b.png".into(), r)]).unwrap_err();
        assert!(err.to_string().contains("a.png") && err.to_string().contains("b.png"), "{err}");
        assert!(matches!(assemble(2, 16, 16, 1, vec![]), Err(TransportError::Spacing { .. })));
    }
}
