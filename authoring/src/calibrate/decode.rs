//! Structured-light decoding: camera images of Gray-code (with inverses) and phase-shift
//! patterns to a per-camera-pixel projector coordinate, with a validity mask and a quality
//! report instead of failure on noisy pixels.
//!
//! Conventions are those documented on [`Pattern`]. Captures from OpenCV's
//! `structured_light.GrayCodePattern` (pattern/inverse pairs, MSB first, columns then rows, then
//! white and black) are mapped onto the same patterns by [`opencv_order`].

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::CalibrateError;
use crate::capture_set::{Axis, Pattern, ProjectorCapture, Shot, gray_bits};

/// Thresholds of the decoder. Values are in image units (0..1 of the camera's full scale).
#[derive(Clone, Debug, PartialEq)]
pub struct DecodeParams {
    /// A pixel is lit (decodable) when white minus black exceeds this ...
    pub min_contrast: f32,
    /// ... or, when set, when white minus black exceeds `min_bit_margin` and this many standard
    /// deviations of the pixel's own noise. The noise is measured at every pixel from its
    /// complementary pairs: in linear light a Gray pattern plus its inverse is white plus black,
    /// whatever the blur, so what is left over is noise. Dark paint returns too little light
    /// for a fixed threshold, and its noise is low too (read noise, little shot noise).
    pub lit_noise_sigmas: Option<f32>,
    /// A Gray bit is weak when |pattern - inverse| is below
    /// `max(min_bit_margin, min_bit_margin_rel * (white - black))`.
    pub min_bit_margin: f32,
    pub min_bit_margin_rel: f32,
    /// Pixels with more weak bits than this on an axis are not decoded. One weak bit is what a
    /// pixel on a stripe boundary has (only one Gray bit changes between neighbouring codes),
    /// and reading it either way gives one of the two neighbouring codes; more weak bits mean
    /// noise. A pixel where a column boundary crosses a row boundary has one on each axis.
    pub max_weak_bits: u32,
    /// A pixel decoded with a weak bit is kept only when each of its coordinates lies within
    /// this (projector px) of the median of the confidently decoded pixels (no weak bit) in
    /// the 5x5 window around it: a weak bit read the wrong way off a stripe boundary lands far
    /// from its neighbours.
    pub max_neighbour_disagreement: f32,
    /// ... and when that window holds at least this many confidently decoded pixels.
    pub min_confident_neighbours: usize,
    /// After phase unwrapping, pixels whose phase coordinate is further than this (projector px)
    /// from the Gray-code cell are rejected as inconsistent.
    pub max_phase_gray_disagreement: f32,
    /// Use phase-shift images when the capture has them.
    pub use_phase: bool,
}

impl Default for DecodeParams {
    fn default() -> Self {
        Self {
            min_contrast: 0.01,
            // A pixel the projector does not light passes four sigma with odds of 1 in 30,000,
            // and then its Gray bits, noise only, still have to clear the bit margin.
            lit_noise_sigmas: Some(4.0),
            min_bit_margin: 0.002,
            min_bit_margin_rel: 0.03,
            max_weak_bits: 1,
            // Measured on the real capture (docs/calibrate.md): 1.5 px and 6 of 24 neighbours
            // keep the weak-bit pixels as consistent as the confident ones.
            max_neighbour_disagreement: 1.5,
            min_confident_neighbours: 6,
            max_phase_gray_disagreement: 1.5,
            use_phase: true,
        }
    }
}

impl DecodeParams {
    /// OpenCV `GrayCodePattern`'s default thresholds (black 40, white 5 on 8-bit images), for
    /// captures stored as 8-bit code values.
    pub fn opencv_defaults() -> Self {
        Self {
            min_contrast: 40.0 / 255.0,
            // OpenCV's fixed thresholds; 8-bit code values of an unknown camera curve are not
            // linear light, so pattern + inverse = white + black would not hold anyway.
            lit_noise_sigmas: None,
            min_bit_margin: 5.0 / 255.0,
            min_bit_margin_rel: 0.0,
            ..Self::default()
        }
    }
}

/// How well one projector decoded.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DecodeQuality {
    pub projector: u32,
    pub pixels: usize,
    /// Pixels with enough white/black contrast.
    pub lit: usize,
    /// ... of which lit by their own noise figure only, below `min_contrast` (dark paint).
    #[serde(default)]
    pub faint: usize,
    /// Pixels with both coordinates decoded.
    pub decoded: usize,
    /// Lit pixels not decoded, each counted once under the first check it failed, in this
    /// order: too many weak Gray bits on an axis (`weak`), a code outside the projector on
    /// either axis (`out_of_range`), phase disagreeing with the Gray code (`phase_rejected`),
    /// a weak bit with neighbours that disagree (`weak_inconsistent`). So
    /// `lit = decoded + weak + out_of_range + weak_inconsistent + phase_rejected`.
    pub weak: usize,
    pub out_of_range: usize,
    #[serde(default)]
    pub weak_inconsistent: usize,
    pub phase_rejected: usize,
    /// Decoded pixels that had a weak bit (stripe boundaries) on either axis, not counting the
    /// bits finer than phase shift needs ...
    pub one_weak_bit: usize,
    /// ... of which on both axes (where a column and a row boundary cross).
    #[serde(default)]
    pub two_weak_bits: usize,
    /// Fraction of decoded pixels further than [`CONSISTENCY_PX`] from the median of their
    /// decoded 5x5 neighbours (see [`inconsistent_fraction`]); 0 in files written before it.
    #[serde(default)]
    pub inconsistent: f32,
    /// The same figure over the decoded pixels read with no weak bit (what OpenCV's decoder
    /// also accepts; the baseline) ...
    #[serde(default)]
    pub inconsistent_confident: f32,
    /// ... and over those kept with a weak bit after the neighbourhood check (the pixels only
    /// restage decodes). Each is measured in the map of all decoded pixels; 0 for an empty set.
    #[serde(default)]
    pub inconsistent_weak: f32,
    /// Phase steps used per axis (0 when Gray code only).
    pub phase_steps: u32,
    pub phase_period: u32,
    /// Whether phase images were linearised with a response measured from gray ramps.
    pub linearised: bool,
    /// Median over decoded pixels of the smallest bit margin relative to white - black.
    #[serde(deserialize_with = "super::nan_if_null_f32")]
    pub median_relative_margin: f32,
    pub warnings: Vec<String>,
}

/// Decoded correspondences of one projector: for every camera pixel (row-major) the projector
/// coordinate seen there (pixel-centre convention), NaN where not decoded.
#[derive(Clone, Debug)]
pub struct ProjectorDecode {
    pub width: u32,
    pub height: u32,
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    /// White minus black per pixel (how strongly this projector lights it).
    pub contrast: Vec<f32>,
    /// Grey response (256 entries, 0 at input 0, 1 at 255) measured from gray ramps, if any.
    pub response: Option<Vec<f32>>,
    pub quality: DecodeQuality,
}

impl ProjectorDecode {
    pub fn is_valid(&self, i: usize) -> bool {
        self.x[i].is_finite() && self.y[i].is_finite()
    }

    /// Correspondences as the stage model stores them.
    pub fn pairs(&self) -> Vec<[f32; 2]> {
        self.x
            .iter()
            .zip(&self.y)
            .map(|(&x, &y)| if x.is_finite() && y.is_finite() { [x, y] } else { [f32::NAN; 2] })
            .collect()
    }
}

/// Where pattern images come from: files of a capture set, or memory in tests.
pub trait PatternImages {
    /// Camera size every image must have.
    fn size(&self) -> (u32, u32);
    /// The grey (single-channel, row-major) camera image of `pattern`, or `None` if not captured.
    fn grey(&self, pattern: &Pattern) -> Result<Option<Vec<f32>>, CalibrateError>;
    /// Patterns present, to discover phase and ramp sequences.
    fn patterns(&self) -> Vec<Pattern>;
}

/// Pattern images of one projector read from a capture directory.
pub struct CaptureImages<'a> {
    pub dir: &'a Path,
    pub projector: &'a ProjectorCapture,
    pub width: u32,
    pub height: u32,
    /// Read 8-bit files as raw code values (foreign captures) instead of decoding sRGB.
    pub raw: bool,
}

impl PatternImages for CaptureImages<'_> {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn grey(&self, pattern: &Pattern) -> Result<Option<Vec<f32>>, CalibrateError> {
        match self.projector.find(pattern) {
            None => Ok(None),
            Some(file) => load_grey(&self.dir.join(file), self.width, self.height, self.raw).map(Some),
        }
    }

    fn patterns(&self) -> Vec<Pattern> {
        self.projector.shots.iter().map(|s| s.pattern.clone()).collect()
    }
}

/// Loads an image as grey: 16-bit files are linear light (mean of channels); 8-bit files are
/// decoded from sRGB, or taken as raw code values / 255 when `raw`.
pub fn load_grey(path: &Path, width: u32, height: u32, raw: bool) -> Result<Vec<f32>, CalibrateError> {
    let img = crate::imgio::open_sized(path, width, height)?;
    let is16 = matches!(
        img.color(),
        image::ColorType::L16 | image::ColorType::La16 | image::ColorType::Rgb16 | image::ColorType::Rgba16
    );
    Ok(if is16 {
        img.to_rgb16()
            .pixels()
            .map(|p| p.0.iter().map(|&c| c as f32).sum::<f32>() / (3.0 * 65535.0))
            .collect()
    } else if raw {
        img.to_rgb8().pixels().map(|p| p.0.iter().map(|&c| c as f32).sum::<f32>() / (3.0 * 255.0)).collect()
    } else {
        img.to_rgb8()
            .pixels()
            .map(|p| p.0.iter().map(|&c| crate::imgio::srgb_to_linear(c as f32 / 255.0)).sum::<f32>() / 3.0)
            .collect()
    })
}

/// Shots of a capture made in OpenCV `GrayCodePattern` order: `2 * ceil(log2 w)` column
/// images, `2 * ceil(log2 h)` row images (each bit: pattern then inverse, most significant bit
/// first), then white and black. `files` must be in that order.
pub fn opencv_order(
    files: &[PathBuf],
    projector_width: u32,
    projector_height: u32,
) -> Result<ProjectorCapture, CalibrateError> {
    let (nx, ny) = (gray_bits(projector_width), gray_bits(projector_height));
    let want = 2 * (nx + ny) as usize + 2;
    if files.len() != want {
        return Err(CalibrateError::BadInput {
            path: files.first().and_then(|f| f.parent()).map(Path::to_path_buf).unwrap_or_default(),
            problem: format!(
                "{} images for a {projector_width}x{projector_height} projector in OpenCV GrayCodePattern \
                 order (expected exactly {want}: 2x{nx} columns, 2x{ny} rows, white, black)",
                files.len()
            ),
        });
    }
    let mut shots = Vec::with_capacity(want);
    let mut it = files.iter();
    for (axis, n) in [(Axis::X, nx), (Axis::Y, ny)] {
        for bit in 0..n {
            for inverted in [false, true] {
                let file = it.next().expect("counted").clone();
                shots.push(Shot { pattern: Pattern::GrayCode { axis, bit, inverted }, file });
            }
        }
    }
    shots.push(Shot { pattern: Pattern::White, file: it.next().expect("counted").clone() });
    shots.push(Shot { pattern: Pattern::Black, file: it.next().expect("counted").clone() });
    Ok(ProjectorCapture { index: 0, width: projector_width, height: projector_height, shots })
}

/// Converts a Gray code to its binary value.
pub fn gray_to_binary(mut g: u32) -> u32 {
    let mut shift = 1;
    while shift < 32 {
        g ^= g >> shift;
        shift <<= 1;
    }
    g
}

/// The 8-bit value projector coordinate `c` has in `pattern` (for rendering patterns in tests
/// and by the virtual stage; follows the conventions on [`Pattern`]).
pub fn pattern_value(pattern: &Pattern, x: u32, y: u32, width: u32, height: u32) -> u8 {
    match *pattern {
        Pattern::White => 255,
        Pattern::Black => 0,
        Pattern::GrayCode { axis, bit, inverted } => {
            let (c, extent) = if axis == Axis::X { (x, width) } else { (y, height) };
            let n = gray_bits(extent);
            let g = c ^ (c >> 1);
            let on = (g >> (n - 1 - bit)) & 1 == 1;
            if on != inverted { 255 } else { 0 }
        }
        Pattern::Phase { axis, period, step, steps } => {
            let c = if axis == Axis::X { x } else { y } as f64;
            let v = 0.5
                + 0.5
                    * (std::f64::consts::TAU * c / period as f64
                        - std::f64::consts::TAU * step as f64 / steps as f64)
                        .cos();
            (v * 255.0).round() as u8
        }
        Pattern::Dots { spacing, dx, dy } => {
            if x % spacing == dx && y % spacing == dy {
                255
            } else {
                0
            }
        }
        Pattern::Ramp { level, .. } => level,
    }
}

/// The phase sequence used for an axis: the finest period with all its steps captured.
fn phase_sequence(patterns: &[Pattern], axis: Axis) -> Option<(u32, u32)> {
    let mut best: Option<(u32, u32)> = None;
    for p in patterns {
        if let Pattern::Phase { axis: a, period, steps, .. } = *p {
            if a != axis || steps < 3 {
                continue;
            }
            let complete =
                (0..steps).all(|s| patterns.contains(&Pattern::Phase { axis, period, step: s, steps }));
            if complete && best.is_none_or(|(bp, _)| period < bp) {
                best = Some((period, steps));
            }
        }
    }
    best
}

/// Measures the projector's grey response (relative light per 8-bit input) from gray-ramp
/// shots, if the capture has any: all-channel ramps, or r, g and b ramps at the same levels
/// (light adds in linear light: all three on = r + g + b - 2 black). Returns 256 entries,
/// monotonic, 0 at input 0 and 1 at 255.
fn measure_response(
    images: &dyn PatternImages,
    white: &[f32],
    black: &[f32],
    lit: &[bool],
) -> Result<Option<Vec<f32>>, CalibrateError> {
    let patterns = images.patterns();
    let mut levels: Vec<u8> = patterns
        .iter()
        .filter_map(|p| match *p {
            Pattern::Ramp { level, .. } => Some(level),
            _ => None,
        })
        .collect();
    levels.sort_unstable();
    levels.dedup();
    // Levels 0 and 255 are 0 and 1 by definition; `fit_response` adds them.
    let mut samples: Vec<(u8, f32)> = Vec::new();
    for &level in &levels {
        if level == 0 || level == 255 {
            continue;
        }
        let img = if let Some(img) = images.grey(&Pattern::Ramp { channel: 3, level })? {
            img
        } else {
            let mut sum: Option<Vec<f32>> = None;
            let mut complete = true;
            for channel in 0..3 {
                match images.grey(&Pattern::Ramp { channel, level })? {
                    Some(img) => {
                        sum = Some(match sum {
                            None => img,
                            Some(s) => s.iter().zip(&img).map(|(a, b)| a + b).collect(),
                        })
                    }
                    None => complete = false,
                }
            }
            match (complete, sum) {
                (true, Some(s)) => s.iter().zip(black).map(|(v, b)| v - 2.0 * b).collect(),
                _ => continue,
            }
        };
        let mut rel: Vec<f32> =
            (0..img.len()).filter(|&i| lit[i]).map(|i| (img[i] - black[i]) / (white[i] - black[i])).collect();
        if rel.len() < 16 {
            continue;
        }
        let mid = rel.len() / 2;
        let (_, m, _) = rel.select_nth_unstable_by(mid, f32::total_cmp);
        samples.push((level, *m));
    }
    if samples.len() < 3 {
        return Ok(None);
    }
    // The same fit as the radiometric step's (log-log, a power law below the first level).
    Ok(Some(super::radiometry::fit_response(&samples)))
}

/// Inverse of a monotonic 256-entry response: relative light to input in 0..=1.
fn invert_response(curve: &[f32], light: f32) -> f32 {
    let k = curve.partition_point(|&c| c < light);
    if k == 0 {
        return 0.0;
    }
    if k >= curve.len() {
        return 1.0;
    }
    let (a, b) = (curve[k - 1], curve[k]);
    let t = if b > a { (light - a) / (b - a) } else { 0.0 };
    ((k - 1) as f32 + t) / 255.0
}

/// One axis's Gray code per pixel, before any pixel is accepted.
struct AxisCodes {
    /// Binary projector coordinate (may lie outside the projector).
    code: Vec<u32>,
    /// Bits finer than the phase shift needs (0 without phase shift): they may be weak.
    fine: u32,
    /// Weak bits per pixel, not counting the fine bits ...
    weak: Vec<u32>,
    /// ... and weak fine bits: with one, the pixel is placed in its coarse cell only.
    weak_fine: Vec<u32>,
    /// Smallest margin of the bits counted in `weak`, relative to white - black.
    min_margin: Vec<f32>,
    /// Sum over the bits of (pattern + inverse - white - black)^2: noise only.
    residual_sq: Vec<f32>,
    /// Bits read.
    bits: u32,
}

impl AxisCodes {
    /// Half the width of the cell the Gray code places pixel `i` in: 0 when every bit was read
    /// clearly, otherwise that of the cell of the bits above the fine ones.
    fn half_cell(&self, i: usize) -> f32 {
        if self.weak_fine[i] == 0 { 0.0 } else { 0.5 * ((1u32 << self.fine) - 1) as f32 }
    }

    /// First projector coordinate of pixel `i`'s cell.
    fn start(&self, i: usize) -> u32 {
        if self.weak_fine[i] == 0 { self.code[i] } else { self.code[i] >> self.fine << self.fine }
    }

    /// The pixel's coordinate as the Gray code alone places it: its cell's centre.
    fn centre(&self, i: usize) -> f32 {
        self.start(i) as f32 + self.half_cell(i)
    }
}

/// Gray bits that phase shift of `period` makes unnecessary: those finer than half a period.
/// Reading the code to cells of at most half a period leaves the phase's period unambiguous
/// (the true coordinate lies within a quarter period of the cell's centre), and the fine
/// stripes are the ones blur and dark paint make unreadable.
fn fine_bits(period: u32, bits: u32) -> u32 {
    let half = (period / 2).max(1);
    (31 - half.leading_zeros()).min(bits.saturating_sub(1))
}

/// Per-pixel references every axis decodes against.
struct Reference<'a> {
    white: &'a [f32],
    black: &'a [f32],
    /// Measured projector response for linearising phase images, if ramps were captured.
    response: Option<&'a [f32]>,
}

fn gray_codes(
    images: &dyn PatternImages,
    projector: u32,
    axis: Axis,
    extent: u32,
    reference: &Reference,
    params: &DecodeParams,
    fine: u32,
) -> Result<AxisCodes, CalibrateError> {
    let Reference { white, black, .. } = *reference;
    let n = gray_bits(extent);
    let pixels = white.len();
    let mut code = vec![0u32; pixels];
    let mut weak = vec![0u32; pixels];
    let mut weak_fine = vec![0u32; pixels];
    let mut min_margin = vec![f32::INFINITY; pixels];
    let mut residual_sq = vec![0.0f32; pixels];
    for bit in 0..n {
        let is_fine = bit >= n - fine;
        let get = |inverted| {
            let pattern = Pattern::GrayCode { axis, bit, inverted };
            images
                .grey(&pattern)?
                .ok_or_else(|| CalibrateError::MissingPattern { projector, pattern: format!("{pattern:?}") })
        };
        let (p, q) = (get(false)?, get(true)?);
        let weak_here = if is_fine { &mut weak_fine } else { &mut weak };
        code.par_iter_mut()
            .zip(weak_here.par_iter_mut())
            .zip(min_margin.par_iter_mut())
            .zip(residual_sq.par_iter_mut())
            .enumerate()
            .for_each(|(i, (((c, w), m), r))| {
                let d = p[i] - q[i];
                *r += (p[i] + q[i] - white[i] - black[i]).powi(2);
                let range = (white[i] - black[i]).max(1e-6);
                *c = (*c << 1) | u32::from(d > 0.0);
                // The epsilon keeps 8-bit thresholds exact after the division by 255.
                if d.abs() < params.min_bit_margin.max(params.min_bit_margin_rel * range) - 1e-6 {
                    *w += 1;
                }
                if !is_fine {
                    *m = m.min(d.abs() / range);
                }
            });
    }
    code.par_iter_mut().for_each(|c| *c = gray_to_binary(*c));
    Ok(AxisCodes { code, fine, weak, weak_fine, min_margin, residual_sq, bits: n })
}

/// Refines one axis's Gray-code coordinates (cell centres of `codes`) with the phase shift
/// `(period, steps)`. Pixels whose phase disagrees with the Gray code are set to NaN and marked
/// in `rejected`.
#[allow(clippy::too_many_arguments)]
fn phase_refine(
    images: &dyn PatternImages,
    axis: Axis,
    extent: u32,
    reference: &Reference,
    params: &DecodeParams,
    (period, steps): (u32, u32),
    codes: &AxisCodes,
    coord: &mut [f32],
    rejected: &mut [bool],
) -> Result<(), CalibrateError> {
    let Reference { white, black, response } = *reference;
    let pixels = white.len();
    let mut s = vec![0.0f32; pixels];
    let mut co = vec![0.0f32; pixels];
    for step in 0..steps {
        let img = images.grey(&Pattern::Phase { axis, period, step, steps })?.expect("checked complete");
        let delta = std::f32::consts::TAU * step as f32 / steps as f32;
        let (sd, cd) = delta.sin_cos();
        s.par_iter_mut().zip(co.par_iter_mut()).enumerate().for_each(|(i, (s, c))| {
            let range = (white[i] - black[i]).max(1e-6);
            let rel = (img[i] - black[i]) / range;
            // Undo the projector's non-linear response so the pattern is a sinusoid again.
            let v = match response {
                Some(curve) => invert_response(curve, rel),
                None => rel,
            };
            *s += v * sd;
            *c += v * cd;
        });
    }
    let p = period as f32;
    for i in 0..pixels {
        let g = coord[i];
        if !g.is_finite() {
            continue;
        }
        let phi = s[i].atan2(co[i]).rem_euclid(std::f32::consts::TAU);
        let cp = p * phi / std::f32::consts::TAU;
        let k = ((g - cp) / p).round();
        let c = k * p + cp;
        // The true coordinate lies within half a cell of the cell's centre.
        if (c - g).abs() > codes.half_cell(i) + params.max_phase_gray_disagreement
            || c < -0.5
            || c > extent as f32 - 0.5
        {
            coord[i] = f32::NAN;
            rejected[i] = true;
        } else {
            coord[i] = c;
        }
    }
    Ok(())
}

/// Side of the window the neighbourhood check and the consistency figure look at.
const WINDOW: usize = 5;

/// A decoded pixel counts as inconsistent with its neighbours when it lies further than this
/// (projector px, on either axis) from the median of the decoded pixels around it.
pub const CONSISTENCY_PX: f32 = 2.0;

/// Median of x and of y over the pixels of the `WINDOW` x `WINDOW` window around pixel `i`
/// (itself excluded) where both are finite, and how many there were. An even count takes the
/// mean of the two middle values (as numpy's median does, so the peer script agrees).
fn window_median(x: &[f32], y: &[f32], width: usize, height: usize, i: usize) -> Option<(f32, f32, usize)> {
    let r = WINDOW / 2;
    let (u, v) = (i % width, i / width);
    let mut xs = [0.0f32; WINDOW * WINDOW];
    let mut ys = [0.0f32; WINDOW * WINDOW];
    let mut n = 0;
    for vv in v.saturating_sub(r)..(v + r + 1).min(height) {
        for uu in u.saturating_sub(r)..(u + r + 1).min(width) {
            let j = vv * width + uu;
            if j != i && x[j].is_finite() && y[j].is_finite() {
                xs[n] = x[j];
                ys[n] = y[j];
                n += 1;
            }
        }
    }
    if n == 0 {
        return None;
    }
    let median = |a: &mut [f32]| {
        a.sort_unstable_by(f32::total_cmp);
        if a.len() % 2 == 1 { a[a.len() / 2] } else { 0.5 * (a[a.len() / 2 - 1] + a[a.len() / 2]) }
    };
    Some((median(&mut xs[..n]), median(&mut ys[..n]), n))
}

/// For every pixel, whether it is decoded (finite x and y) and further than [`CONSISTENCY_PX`]
/// on either axis from the median of the decoded pixels in the 5x5 window around it; a decoded
/// pixel with no decoded neighbour counts as inconsistent (nothing vouches for it).
pub fn inconsistent_pixels(x: &[f32], y: &[f32], width: u32, height: u32) -> Vec<bool> {
    let (w, h) = (width as usize, height as usize);
    (0..x.len())
        .into_par_iter()
        .map(|i| {
            x[i].is_finite()
                && y[i].is_finite()
                && window_median(x, y, w, h, i).is_none_or(|(mx, my, _)| {
                    !((x[i] - mx).abs() <= CONSISTENCY_PX && (y[i] - my).abs() <= CONSISTENCY_PX)
                })
        })
        .collect()
}

/// The share of decoded pixels that [`inconsistent_pixels`] marks; 0 when nothing decoded.
pub fn inconsistent_fraction(x: &[f32], y: &[f32], width: u32, height: u32) -> f32 {
    inconsistent_fractions(x, y, width, height, |_| true)[0]
}

/// [`inconsistent_fraction`] over all decoded pixels, over those `in_set` accepts and over the
/// rest (0 for an empty set). The neighbours are all decoded pixels in every case, so the
/// subsets' figures are those of the whole map, split.
fn inconsistent_fractions(
    x: &[f32],
    y: &[f32],
    width: u32,
    height: u32,
    in_set: impl Fn(usize) -> bool,
) -> [f32; 3] {
    let bad = inconsistent_pixels(x, y, width, height);
    // (decoded, inconsistent) for all, in the set, not in it.
    let mut n = [(0usize, 0usize); 3];
    for i in (0..x.len()).filter(|&i| x[i].is_finite() && y[i].is_finite()) {
        for k in [0, if in_set(i) { 1 } else { 2 }] {
            n[k].0 += 1;
            n[k].1 += usize::from(bad[i]);
        }
    }
    n.map(|(d, b)| if d == 0 { 0.0 } else { b as f32 / d as f32 })
}

/// Why a lit pixel was not decoded. Each pixel has one reason, the first that applies in this
/// order (the order of the checks), so the counts in [`DecodeQuality`] add up.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Status {
    Unlit,
    /// More than `max_weak_bits` weak bits on an axis.
    Weak,
    /// A code outside the projector on either axis.
    OutOfRange,
    PhaseRejected,
    /// Decoded with a weak bit, but its neighbours disagree (or there are too few of them).
    WeakInconsistent,
    Decoded,
}

/// Decodes one projector's structured light.
///
/// Fails only when the input is unusable as a whole (missing or mis-sized images, no contrast
/// at all, a zero projector size); noisy pixels are left undecoded and counted in the quality
/// report.
pub fn decode_projector(
    images: &dyn PatternImages,
    projector: u32,
    projector_width: u32,
    projector_height: u32,
    params: &DecodeParams,
) -> Result<ProjectorDecode, CalibrateError> {
    if projector_width == 0 || projector_height == 0 {
        return Err(CalibrateError::BadInput {
            path: PathBuf::new(),
            problem: format!(
                "projector {projector}: size {projector_width}x{projector_height} has a zero side"
            ),
        });
    }
    let (width, height) = images.size();
    let pixels = width as usize * height as usize;
    let need = |pattern: Pattern| {
        images
            .grey(&pattern)?
            .ok_or_else(|| CalibrateError::MissingPattern { projector, pattern: format!("{pattern:?}") })
    };
    let white = need(Pattern::White)?;
    let black = need(Pattern::Black)?;
    let contrast: Vec<f32> = white.iter().zip(&black).map(|(w, b)| w - b).collect();
    // Bright enough for the fixed threshold: what the response is measured on.
    let bright: Vec<bool> = contrast.iter().map(|&c| c > params.min_contrast + 1e-6).collect();
    let bright_count = bright.iter().filter(|&&l| l).count();
    if bright_count < (pixels / 1000).max(16) {
        return Err(CalibrateError::NoContrast {
            projector,
            lit: bright_count,
            pixels,
            threshold: params.min_contrast,
        });
    }
    let response = measure_response(images, &white, &black, &bright)?;
    let reference = Reference {
        white: &white,
        black: &black,
        response: if params.use_phase { response.as_deref() } else { None },
    };
    let patterns = images.patterns();
    let sequence = |axis| if params.use_phase { phase_sequence(&patterns, axis) } else { None };
    let (seq_x, seq_y) = (sequence(Axis::X), sequence(Axis::Y));
    let fine =
        |seq: Option<(u32, u32)>, extent| seq.map_or(0, |(period, _)| fine_bits(period, gray_bits(extent)));
    let cx = gray_codes(
        images,
        projector,
        Axis::X,
        projector_width,
        &reference,
        params,
        fine(seq_x, projector_width),
    )?;
    let cy = gray_codes(
        images,
        projector,
        Axis::Y,
        projector_height,
        &reference,
        params,
        fine(seq_y, projector_height),
    )?;

    // A pair's residual has four images' noise, white - black two.
    let samples = (cx.bits + cy.bits) as f32;
    let lit: Vec<bool> = (0..pixels)
        .map(|i| {
            bright[i]
                || params.lit_noise_sigmas.is_some_and(|z| {
                    let sigma = ((cx.residual_sq[i] + cy.residual_sq[i]) / (2.0 * samples)).sqrt();
                    contrast[i] > params.min_bit_margin.max(z * sigma)
                })
        })
        .collect();
    let lit_count = lit.iter().filter(|&&l| l).count();

    // Weak before out of range: a code read through too many weak bits is noise, and where it
    // lands says nothing about the projector size.
    let mut status: Vec<Status> = (0..pixels)
        .map(|i| {
            if !lit[i] {
                Status::Unlit
            } else if cx.weak[i] > params.max_weak_bits || cy.weak[i] > params.max_weak_bits {
                Status::Weak
            } else if cx.start(i) >= projector_width || cy.start(i) >= projector_height {
                Status::OutOfRange
            } else {
                Status::Decoded
            }
        })
        .collect();
    let (mut x, mut y): (Vec<f32>, Vec<f32>) =
        (0..pixels)
            .map(|i| {
                if status[i] == Status::Decoded { (cx.centre(i), cy.centre(i)) } else { (f32::NAN, f32::NAN) }
            })
            .unzip();

    if seq_x.is_some() || seq_y.is_some() {
        let mut rejected = vec![false; pixels];
        for (axis, extent, seq, codes, coord) in
            [(Axis::X, projector_width, seq_x, &cx, &mut x), (Axis::Y, projector_height, seq_y, &cy, &mut y)]
        {
            if let Some(seq) = seq {
                phase_refine(images, axis, extent, &reference, params, seq, codes, coord, &mut rejected)?;
            }
        }
        for i in 0..pixels {
            if rejected[i] {
                status[i] = Status::PhaseRejected;
            }
        }
    }

    // A weak bit is read either way; at a stripe boundary both readings are neighbouring codes,
    // elsewhere a wrong reading lands far from its neighbours, and a pixel placed by phase in a
    // coarse cell may be one whose phase is garbage (a pixel that straddles a silhouette).
    // Pixels with no weak bit above the fine ones are the reference; reading only their map
    // makes the result independent of the order (or threads) pixels are visited in.
    let confident = |i: usize| status[i] == Status::Decoded && cx.weak[i] == 0 && cy.weak[i] == 0;
    let any_weak = |i: usize| cx.weak[i] + cy.weak[i] + cx.weak_fine[i] + cy.weak_fine[i] > 0;
    let (conf_x, conf_y): (Vec<f32>, Vec<f32>) =
        (0..pixels).map(|i| if confident(i) { (x[i], y[i]) } else { (f32::NAN, f32::NAN) }).unzip();
    let (w, h) = (width as usize, height as usize);
    let disagreeing: Vec<usize> = (0..pixels)
        .into_par_iter()
        .filter(|&i| status[i] == Status::Decoded && any_weak(i))
        .filter(|&i| {
            window_median(&conf_x, &conf_y, w, h, i).is_none_or(|(mx, my, n)| {
                n < params.min_confident_neighbours
                    || (x[i] - mx).abs() > params.max_neighbour_disagreement
                    || (y[i] - my).abs() > params.max_neighbour_disagreement
            })
        })
        .collect();
    for i in disagreeing {
        status[i] = Status::WeakInconsistent;
    }
    let phase = seq_x.or(seq_y);

    let count = |s: Status| status.iter().filter(|&&t| t == s).count();
    let mut margins = Vec::new();
    let (mut one_weak_bit, mut two_weak_bits) = (0, 0);
    for i in 0..pixels {
        if status[i] == Status::Decoded {
            margins.push(cx.min_margin[i].min(cy.min_margin[i]));
            one_weak_bit += usize::from(cx.weak[i] > 0 || cy.weak[i] > 0);
            two_weak_bits += usize::from(cx.weak[i] > 0 && cy.weak[i] > 0);
        } else {
            x[i] = f32::NAN;
            y[i] = f32::NAN;
        }
    }
    let decoded = margins.len();
    // Decoded pixels read with no weak bit are the baseline: OpenCV's decoder accepts exactly
    // these, so the weak-bit ones must be as consistent with their neighbours.
    let [inconsistent, inconsistent_confident, inconsistent_weak] =
        inconsistent_fractions(&x, &y, width, height, |i| !any_weak(i));
    let median_relative_margin = if margins.is_empty() {
        0.0
    } else {
        let mid = margins.len() / 2;
        *margins.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    let mut quality = DecodeQuality {
        projector,
        pixels,
        lit: lit_count,
        faint: lit_count - lit.iter().zip(&bright).filter(|&(&l, &b)| l && b).count(),
        decoded,
        weak: count(Status::Weak),
        out_of_range: count(Status::OutOfRange),
        weak_inconsistent: count(Status::WeakInconsistent),
        phase_rejected: count(Status::PhaseRejected),
        one_weak_bit,
        two_weak_bits,
        inconsistent,
        inconsistent_confident,
        inconsistent_weak,
        phase_steps: phase.map_or(0, |p| p.1),
        phase_period: phase.map_or(0, |p| p.0),
        linearised: response.is_some() && phase.is_some(),
        median_relative_margin,
        warnings: Vec::new(),
    };
    if let Some(w) = out_of_range_warning(projector, &cx, &cy, &status, projector_width, projector_height) {
        quality.warnings.push(w);
    }
    if decoded < lit_count / 2 {
        quality.warnings.push(format!(
            "projector {projector}: only {decoded} of {lit_count} lit pixels decoded (noise, blur or a wrong pattern order?)"
        ));
    }
    if let Some((_, steps)) = phase {
        if response.is_none() && steps < 6 {
            quality.warnings.push(format!(
                "projector {projector}: {steps}-step phase shift without gray ramps to linearise it; \
                 the projector's non-linear response biases the phase (use >= 6 steps or capture ramps)"
            ));
        }
    } else {
        quality.warnings.push(format!(
            "projector {projector}: no phase-shift images; correspondences are whole projector pixels"
        ));
    }
    if decoded < pixels / 100 {
        quality.warnings.push(format!(
            "projector {projector}: decoded only {decoded} of {pixels} camera pixels; does it see the object?"
        ));
    }
    Ok(ProjectorDecode { width, height, x, y, contrast, response, quality })
}

/// Share of the lit pixels past the weak-bit test that may decode out of range before the
/// projector size is suspect (a few do at the image's edges through blur and noise).
const OUT_OF_RANGE_WARN: f64 = 0.05;

/// Below [`OUT_OF_RANGE_WARN`], out-of-range codes still mean a transposed size when at least
/// this share is out of range and the swapped size puts [`TRANSPOSED_RATIO`] times fewer out:
/// a scene that covers only part of the projector leaves few out of range either way.
const TRANSPOSED_MIN: f64 = 0.01;
const TRANSPOSED_RATIO: usize = 10;

/// A warning when many codes fall outside the projector, or when the transposed size fits the
/// codes much better: the size given is probably wrong, most often transposed.
fn out_of_range_warning(
    projector: u32,
    cx: &AxisCodes,
    cy: &AxisCodes,
    status: &[Status],
    pw: u32,
    ph: u32,
) -> Option<String> {
    let readable: Vec<usize> =
        (0..status.len()).filter(|&i| !matches!(status[i], Status::Unlit | Status::Weak)).collect();
    let n = readable.len() as f64;
    let out = readable.iter().filter(|&&i| status[i] == Status::OutOfRange).count();
    // The codes only mean the same under the swapped size when each axis has as many bits.
    let swapped_out = (gray_bits(pw) == gray_bits(ph))
        .then(|| readable.iter().filter(|&&i| cx.code[i] >= ph || cy.code[i] >= pw).count());
    let transposed = swapped_out.is_some_and(|s| s * TRANSPOSED_RATIO <= out);
    if out == 0 || !(out as f64 > OUT_OF_RANGE_WARN * n || (transposed && out as f64 >= TRANSPOSED_MIN * n)) {
        return None;
    }
    let pct = 100.0 * out as f64 / n;
    let mut msg = format!(
        "projector {projector}: {out} of {} readable pixels ({pct:.1} %) decode outside the {pw}x{ph} projector; \
         is the size right, or transposed ({ph}x{pw})?",
        readable.len()
    );
    if let Some(s) = swapped_out.filter(|_| transposed) {
        msg.push_str(&format!(" With {ph}x{pw} only {s} would be out of range: the size looks transposed."));
    }
    Some(msg)
}

/// Pattern images held in memory (tests, benches, the virtual stage in-process).
#[derive(Default)]
pub struct MemoryImages {
    pub width: u32,
    pub height: u32,
    pub images: Vec<(Pattern, Vec<f32>)>,
}

impl PatternImages for MemoryImages {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn grey(&self, pattern: &Pattern) -> Result<Option<Vec<f32>>, CalibrateError> {
        Ok(self.images.iter().find(|(p, _)| p == pattern).map(|(_, img)| img.clone()))
    }

    fn patterns(&self) -> Vec<Pattern> {
        self.images.iter().map(|(p, _)| p.clone()).collect()
    }
}

/// The full pattern list our own capture uses for a projector: white, black, Gray code with
/// inverses on both axes, and `steps`-step phase shift of `period` on both axes.
pub fn standard_patterns(width: u32, height: u32, period: u32, steps: u32) -> Vec<Pattern> {
    let mut out = vec![Pattern::White, Pattern::Black];
    for (axis, extent) in [(Axis::X, width), (Axis::Y, height)] {
        for bit in 0..gray_bits(extent) {
            for inverted in [false, true] {
                out.push(Pattern::GrayCode { axis, bit, inverted });
            }
        }
        if steps > 0 {
            for step in 0..steps {
                out.push(Pattern::Phase { axis, period, step, steps });
            }
        }
    }
    out
}

/// Scale of the correspondence-map PNGs: value = round(coordinate * 16) + 1, 0 = not decoded.
pub const MAP_SCALE: f32 = 16.0;

/// Writes one projector's correspondence maps into `dir`: `proj<k>_x.png` and `proj<k>_y.png`
/// (16-bit grey, value = round(16 * coordinate) + 1, 0 where not decoded; coordinates up to
/// 4095 px) and `proj<k>_coverage.png` (8-bit colour for people: red = x, green = y, black =
/// not decoded).
pub fn save_maps(
    d: &ProjectorDecode,
    index: u32,
    projector_width: u32,
    projector_height: u32,
    dir: &Path,
) -> Result<(), CalibrateError> {
    use crate::imgio::ImageError;
    let enc =
        |c: f32| if c.is_finite() { ((c * MAP_SCALE).round() + 1.0).clamp(1.0, 65535.0) as u16 } else { 0 };
    for (name, values) in [("x", &d.x), ("y", &d.y)] {
        let path = dir.join(format!("proj{index}_{name}.png"));
        let buf: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
            image::ImageBuffer::from_vec(d.width, d.height, values.iter().map(|&c| enc(c)).collect())
                .expect("sized");
        buf.save(&path).map_err(|source| ImageError::Write { path: path.clone(), source })?;
    }
    let path = dir.join(format!("proj{index}_coverage.png"));
    let img = image::RgbImage::from_fn(d.width, d.height, |x, y| {
        let i = (y * d.width + x) as usize;
        if d.is_valid(i) {
            image::Rgb([
                (40.0 + 215.0 * d.x[i] / projector_width as f32) as u8,
                (40.0 + 215.0 * d.y[i] / projector_height as f32) as u8,
                60,
            ])
        } else {
            image::Rgb([0, 0, 0])
        }
    });
    img.save(&path).map_err(|source| ImageError::Write { path, source })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    fn normal(rng: &mut ChaCha8Rng) -> f64 {
        // Box-Muller: rand 0.8 has no normal distribution without rand_distr.
        let (u1, u2): (f64, f64) = (rng.r#gen::<f64>().max(1e-12), rng.r#gen());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Renders a synthetic capture: camera pixel i sees projector point `map(i)` (or nothing),
    /// through a projector with response `level^gamma`, an albedo of 0.6 and Gaussian noise.
    pub(crate) fn render(
        cam: (u32, u32),
        proj: (u32, u32),
        map: &dyn Fn(u32, u32) -> Option<(f64, f64)>,
        patterns: &[Pattern],
        gamma: f64,
        noise: f64,
        seed: u64,
    ) -> MemoryImages {
        render_painted(cam, proj, map, &|_, _| 1.0, patterns, gamma, noise, seed)
    }

    /// [`render`] with the albedo scaled by `paint(u, v)` at each camera pixel.
    #[allow(clippy::too_many_arguments)]
    fn render_painted(
        cam: (u32, u32),
        proj: (u32, u32),
        map: &dyn Fn(u32, u32) -> Option<(f64, f64)>,
        paint: &dyn Fn(u32, u32) -> f64,
        patterns: &[Pattern],
        gamma: f64,
        noise: f64,
        seed: u64,
    ) -> MemoryImages {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut images = Vec::new();
        for p in patterns {
            let mut img = Vec::with_capacity((cam.0 * cam.1) as usize);
            for v in 0..cam.1 {
                for u in 0..cam.0 {
                    let level = match map(u, v) {
                        Some((px, py))
                            if px >= -0.5
                                && py >= -0.5
                                && px < proj.0 as f64 - 0.5
                                && py < proj.1 as f64 - 0.5 =>
                        {
                            if let Pattern::Phase { axis, period, step, steps } = *p {
                                // The sinusoid at the continuous position, quantised to 8 bits.
                                let c = if axis == Axis::X { px } else { py };
                                let val = 0.5
                                    + 0.5
                                        * (std::f64::consts::TAU * c / period as f64
                                            - std::f64::consts::TAU * step as f64 / steps as f64)
                                            .cos();
                                (val * 255.0).round() / 255.0
                            } else {
                                let (x, y) = (px.round() as u32, py.round() as u32);
                                pattern_value(p, x, y, proj.0, proj.1) as f64 / 255.0
                            }
                        }
                        _ => 0.0,
                    };
                    let light = paint(u, v) * (0.02 + 0.6 * level.powf(gamma)) + normal(&mut rng) * noise;
                    img.push(light as f32);
                }
            }
            images.push((p.clone(), img));
        }
        MemoryImages { width: cam.0, height: cam.1, images }
    }

    fn affine(u: u32, v: u32) -> Option<(f64, f64)> {
        Some((2.3 + 0.37 * u as f64 + 0.02 * v as f64, 1.7 + 0.41 * v as f64 - 0.015 * u as f64))
    }

    fn errors(d: &ProjectorDecode, map: &dyn Fn(u32, u32) -> Option<(f64, f64)>) -> (usize, f64, f64) {
        let (mut n, mut sum2, mut max) = (0, 0.0, 0.0f64);
        for v in 0..d.height {
            for u in 0..d.width {
                let i = (v * d.width + u) as usize;
                if !d.is_valid(i) {
                    continue;
                }
                let (tx, ty) = map(u, v).unwrap();
                let e = (d.x[i] as f64 - tx).hypot(d.y[i] as f64 - ty);
                n += 1;
                sum2 += e * e;
                max = max.max(e);
            }
        }
        (n, (sum2 / n.max(1) as f64).sqrt(), max)
    }

    #[test]
    fn gray_round_trip() {
        for c in 0..5000u32 {
            assert_eq!(gray_to_binary(c ^ (c >> 1)), c);
        }
    }

    #[test]
    fn gray_code_alone_decodes_to_the_nearest_pixel() {
        let pats = standard_patterns(64, 48, 8, 0);
        let imgs = render((120, 100), (64, 48), &affine, &pats, 2.2, 0.003, 1);
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        let (n, rms, max) = errors(&d, &affine);
        assert!(n > 11_000, "decoded {n}");
        assert!(max <= 1.0 + 1e-6, "max error {max}");
        assert!(rms < 0.45, "rms {rms}");
        assert!(d.quality.warnings.iter().any(|w| w.contains("no phase-shift")));
    }

    #[test]
    fn phase_shift_gives_sub_pixel_correspondences() {
        let pats = standard_patterns(64, 48, 8, 8);
        let imgs = render((120, 100), (64, 48), &affine, &pats, 2.2, 0.002, 2);
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        let (n, rms, _) = errors(&d, &affine);
        assert!(n > 11_000, "decoded {n}");
        assert!(rms < 0.05, "rms {rms}");
        assert_eq!(d.quality.phase_steps, 8);
    }

    #[test]
    fn dark_paint_decodes_by_its_own_noise_and_unlit_pixels_stay_unlit() {
        // Left third: a black glaze (1/100 of the albedo: white - black 0.006); right
        // quarter: outside the projector's light. Read noise 0.0008 as on the virtual stage.
        let map = |u: u32, v: u32| if u >= 240 { None } else { affine(u / 2, v / 2) };
        let paint = |u: u32, _v: u32| if u < 100 { 0.01 } else { 1.0 };
        let pats = standard_patterns(192, 96, 16, 8);
        let imgs = render_painted((320, 200), (192, 96), &map, &paint, &pats, 1.0, 0.0008, 11);
        let d = decode_projector(&imgs, 0, 192, 96, &DecodeParams::default()).unwrap();
        lit_adds_up(&d.quality);
        let (mut dark, mut dark_ok, mut unlit_decoded) = (0, 0, 0);
        for v in 0..200u32 {
            for u in 0..320u32 {
                let i = (v * 320 + u) as usize;
                match map(u, v) {
                    None => unlit_decoded += usize::from(d.is_valid(i)),
                    Some((tx, ty)) if u < 100 => {
                        dark += 1;
                        if d.is_valid(i) {
                            let e = (d.x[i] as f64 - tx).hypot(d.y[i] as f64 - ty);
                            assert!(e < 1.5, "dark pixel ({u}, {v}) decoded {e:.2} px off");
                            dark_ok += 1;
                        }
                    }
                    _ => {}
                }
            }
        }
        assert_eq!(unlit_decoded, 0, "{:?}", d.quality);
        // White - black is 5.3 sigma of its noise: about 9 in 10 clear the 4 sigma threshold,
        // the rest fall below it by noise in the difference or in their noise estimate.
        assert!(
            dark_ok as f64 > 0.8 * dark as f64,
            "dark paint: {dark_ok} of {dark} decoded; {:?}",
            d.quality
        );
        assert!(d.quality.faint as f64 > 0.8 * dark as f64, "{:?}", d.quality);
        // The fixed threshold alone (OpenCV's way) loses the glaze but for a few noisy pixels.
        let fixed = DecodeParams { lit_noise_sigmas: None, ..DecodeParams::default() };
        let d = decode_projector(&imgs, 0, 192, 96, &fixed).unwrap();
        let glaze = (0..200u32).flat_map(|v| (0..100u32).map(move |u| (v * 320 + u) as usize));
        let kept = glaze.filter(|&i| d.is_valid(i)).count();
        assert!(kept < dark / 100, "{kept} of {dark}");
    }

    #[test]
    fn gray_ramps_linearise_a_four_step_phase_shift() {
        let mut pats = standard_patterns(64, 48, 8, 4);
        let plain = render((120, 100), (64, 48), &affine, &pats, 2.2, 0.0, 3);
        let d0 = decode_projector(&plain, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert!(!d0.quality.linearised);
        assert!(d0.quality.warnings.iter().any(|w| w.contains("4-step")));
        pats.extend((1..16).map(|k| Pattern::Ramp { channel: 3, level: (k * 17) as u8 }));
        let ramps = render((120, 100), (64, 48), &affine, &pats, 2.2, 0.0, 3);
        let d1 = decode_projector(&ramps, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert!(d1.quality.linearised);
        let (_, rms0, _) = errors(&d0, &affine);
        let (_, rms1, _) = errors(&d1, &affine);
        assert!(rms1 < 0.5 * rms0 && rms1 < 0.05, "linearised {rms1} vs raw {rms0}");
    }

    #[test]
    fn no_contrast_and_missing_images_are_clear_errors() {
        let pats = standard_patterns(64, 48, 8, 0);
        let dark = render((40, 30), (64, 48), &|_, _| None, &pats, 2.2, 0.001, 4);
        let err = decode_projector(&dark, 2, 64, 48, &DecodeParams::default()).unwrap_err();
        assert!(matches!(err, CalibrateError::NoContrast { projector: 2, .. }), "{err}");
        let mut imgs = render((40, 30), (64, 48), &affine, &pats, 2.2, 0.001, 4);
        imgs.images.retain(|(p, _)| *p != Pattern::GrayCode { axis: Axis::Y, bit: 3, inverted: true });
        let err = decode_projector(&imgs, 1, 64, 48, &DecodeParams::default()).unwrap_err();
        assert!(err.to_string().contains("projector 1") && err.to_string().contains("bit: 3"), "{err}");
    }

    #[test]
    fn a_projector_seeing_little_is_a_warning_not_a_failure() {
        let pats = standard_patterns(64, 48, 8, 0);
        let corner = |u: u32, v: u32| if u < 6 && v < 6 { affine(u, v) } else { None };
        let imgs = render((120, 100), (64, 48), &corner, &pats, 2.2, 0.001, 5);
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert_eq!(d.quality.decoded, 36);
        assert!(d.quality.warnings.iter().any(|w| w.contains("does it see the object")));
    }

    #[test]
    fn mis_sized_image_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("white.png");
        image::GrayImage::new(5, 4).save(&path).unwrap();
        let err = load_grey(&path, 6, 4, true).unwrap_err();
        assert!(err.to_string().contains("white.png") && err.to_string().contains("expected 6x4"), "{err}");
        let err = load_grey(&dir.path().join("absent.png"), 6, 4, true).unwrap_err();
        assert!(err.to_string().contains("absent.png"), "{err}");
    }

    #[test]
    fn opencv_order_needs_exact_count() {
        let files: Vec<PathBuf> = (0..42).map(|i| format!("g{i:02}.png").into()).collect();
        let cap = opencv_order(&files, 1024, 768).unwrap();
        assert_eq!(cap.shots[0].pattern, Pattern::GrayCode { axis: Axis::X, bit: 0, inverted: false });
        assert_eq!(cap.shots[1].pattern, Pattern::GrayCode { axis: Axis::X, bit: 0, inverted: true });
        assert_eq!(cap.shots[20].pattern, Pattern::GrayCode { axis: Axis::Y, bit: 0, inverted: false });
        assert_eq!(cap.shots[40].pattern, Pattern::White);
        assert_eq!(cap.shots[41].pattern, Pattern::Black);
        let err = opencv_order(&files[..41], 1024, 768).unwrap_err();
        assert!(err.to_string().contains("expected exactly 42"), "{err}");
    }

    /// Makes bit `bit` of `axis` weak at camera pixel `i` (pattern and inverse nearly equal),
    /// read as `reads_one`.
    fn weaken(imgs: &mut MemoryImages, i: usize, axis: Axis, bit: u32, reads_one: bool) {
        let s = if reads_one { 0.001 } else { -0.001 };
        for (p, img) in &mut imgs.images {
            if let Pattern::GrayCode { axis: a, bit: b, inverted } = *p
                && a == axis
                && b == bit
            {
                img[i] = 0.3 + if inverted { -s } else { s };
            }
        }
    }

    /// Whether Gray bit `bit` (MSB first) of coordinate `c` is one on a `extent`-wide axis.
    fn gray_bit(c: u32, bit: u32, extent: u32) -> bool {
        let g = c ^ (c >> 1);
        (g >> (gray_bits(extent) - 1 - bit)) & 1 == 1
    }

    fn lit_adds_up(q: &DecodeQuality) {
        assert_eq!(
            q.lit,
            q.decoded + q.weak + q.out_of_range + q.weak_inconsistent + q.phase_rejected,
            "{q:?}"
        );
    }

    #[test]
    fn a_weak_bit_is_kept_only_where_the_neighbours_agree() {
        let pats = standard_patterns(64, 48, 8, 0);
        let mut imgs = render((120, 100), (64, 48), &affine, &pats, 1.0, 0.0, 6);
        let clean = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert_eq!((clean.quality.one_weak_bit, clean.quality.weak_inconsistent), (0, 0));
        let at = |u: u32, v: u32| (v * 120 + u) as usize;
        // Pixel A: its most significant x bit read the wrong way, which reflects x about the
        // middle (c -> 63 - c): 12 columns off its neighbours here.
        let a = at(60, 50);
        let ax = clean.x[a] as u32;
        weaken(&mut imgs, a, Axis::X, 0, !gray_bit(ax, 0, 64));
        // Pixel B: a weak least significant x bit read the right way (a stripe boundary) ...
        let b = at(30, 30);
        weaken(&mut imgs, b, Axis::X, 5, gray_bit(clean.x[b] as u32, 5, 64));
        // ... and pixel C: one weak bit on each axis, both read the right way (a corner).
        let c = at(90, 70);
        weaken(&mut imgs, c, Axis::X, 5, gray_bit(clean.x[c] as u32, 5, 64));
        weaken(&mut imgs, c, Axis::Y, 5, gray_bit(clean.y[c] as u32, 5, 48));
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        let q = &d.quality;
        assert!(!d.is_valid(a), "the wrong reading {} was kept (true {ax})", d.x[a]);
        assert_eq!((d.x[b], d.y[b]), (clean.x[b], clean.y[b]));
        assert_eq!((d.x[c], d.y[c]), (clean.x[c], clean.y[c]));
        assert_eq!((q.weak_inconsistent, q.one_weak_bit, q.two_weak_bits), (1, 2, 1), "{q:?}");
        assert_eq!(q.decoded, clean.quality.decoded - 1);
        lit_adds_up(q);
        assert_eq!(q.inconsistent, 0.0, "{q:?}");
        // Without the check, the wrong reading stays and is the one inconsistent pixel.
        let params = DecodeParams { max_neighbour_disagreement: f32::INFINITY, ..DecodeParams::default() };
        let loose = decode_projector(&imgs, 0, 64, 48, &params).unwrap();
        assert!(loose.is_valid(a) && (loose.x[a] - ax as f32).abs() >= 10.0, "{} vs {ax}", loose.x[a]);
        assert!(
            (loose.quality.inconsistent * loose.quality.decoded as f32 - 1.0).abs() < 1e-3,
            "{:?}",
            loose.quality
        );
        // ... and it is one of the three weak-bit pixels, none of the confident ones.
        let lq = &loose.quality;
        assert_eq!((lq.inconsistent_weak, lq.inconsistent_confident), (1.0 / 3.0, 0.0), "{lq:?}");
        assert_eq!((q.inconsistent_weak, q.inconsistent_confident), (0.0, 0.0), "{q:?}");
    }

    #[test]
    fn the_check_does_not_depend_on_the_thread_count() {
        let pats = standard_patterns(64, 48, 8, 0);
        // Noise this strong makes bits weak, and some read the wrong way.
        let imgs = render((120, 100), (64, 48), &affine, &pats, 1.0, 0.2, 7);
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert!(d.quality.one_weak_bit > 0 && d.quality.weak_inconsistent > 0, "{:?}", d.quality);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let d1 = one.install(|| decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap());
        assert_eq!(d1.quality, d.quality);
        let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(p, q)| p.to_bits() == q.to_bits());
        assert!(same(&d.x, &d1.x) && same(&d.y, &d1.y));
    }

    #[test]
    fn a_pixel_rejected_on_both_axes_counts_once() {
        let pats = standard_patterns(64, 48, 8, 0);
        let mut imgs = render((120, 100), (64, 48), &affine, &pats, 1.0, 0.0, 8);
        let clean = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        let i = 50 * 120 + 60;
        // Two weak bits on each axis, read so that y is out of range too (Gray 10.... is 48..63).
        for axis in [Axis::X, Axis::Y] {
            weaken(&mut imgs, i, axis, 0, true);
            weaken(&mut imgs, i, axis, 1, false);
        }
        let d = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        let q = &d.quality;
        assert_eq!((q.weak, q.out_of_range, q.weak_inconsistent), (1, 0, 0), "{q:?}");
        assert_eq!(q.decoded, clean.quality.decoded - 1);
        lit_adds_up(q);
    }

    #[test]
    fn a_transposed_projector_size_is_a_warning_and_zero_an_error() {
        let pats = standard_patterns(64, 48, 8, 0);
        let fill = |u: u32, v: u32| Some((u as f64 * 63.0 / 119.0, v as f64 * 47.0 / 99.0));
        let imgs = render((120, 100), (64, 48), &fill, &pats, 1.0, 0.001, 9);
        let right = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert!(!right.quality.warnings.iter().any(|w| w.contains("outside")), "{:?}", right.quality);
        // 64 and 48 both take 6 bits, so the images are the same for either size.
        let swapped = decode_projector(&imgs, 0, 48, 64, &DecodeParams::default()).unwrap();
        let q = &swapped.quality;
        assert!(q.out_of_range > q.lit / 5, "{q:?}");
        lit_adds_up(q);
        let w = q.warnings.iter().find(|w| w.contains("outside the 48x64 projector")).expect("warned");
        assert!(w.contains("64x48") && w.contains("looks transposed"), "{w}");
        for (pw, ph) in [(0, 0), (64, 0)] {
            let err = decode_projector(&imgs, 3, pw, ph, &DecodeParams::default()).unwrap_err();
            assert!(err.to_string().contains(&format!("{pw}x{ph} has a zero side")), "{err}");
        }
    }

    #[test]
    fn a_transposed_size_is_warned_when_few_codes_fall_outside() {
        // The scene covers projector columns 0..49.4 of 64 only: read as 48x64, 4 % of the
        // pixels land outside (below the 5 % that warns by itself), 64x48 puts none outside.
        let part = |u: u32, v: u32| Some((u as f64 * 49.4 / 119.0, v as f64 * 47.0 / 99.0));
        let pats = standard_patterns(64, 48, 8, 0);
        let imgs = render((120, 100), (64, 48), &part, &pats, 1.0, 0.001, 10);
        let right = decode_projector(&imgs, 0, 64, 48, &DecodeParams::default()).unwrap();
        assert!(!right.quality.warnings.iter().any(|w| w.contains("outside")), "{:?}", right.quality);
        let q = decode_projector(&imgs, 0, 48, 64, &DecodeParams::default()).unwrap().quality;
        let share = q.out_of_range as f64 / (q.lit - q.weak) as f64;
        assert!((0.01..OUT_OF_RANGE_WARN).contains(&share), "{share} {q:?}");
        let w = q.warnings.iter().find(|w| w.contains("outside the 48x64 projector")).expect("warned");
        assert!(
            w.contains("With 64x48 only 0 would be out of range") && w.contains("looks transposed"),
            "{w}"
        );
    }

    #[test]
    fn consistency_counts_outliers_and_loners() {
        // A 6x6 smooth map with one outlier and one decoded pixel whose neighbours are not.
        let (mut x, mut y): (Vec<f32>, Vec<f32>) =
            (0..36).map(|i| ((i % 6) as f32 * 0.8, (i / 6) as f32 * 0.8)).unzip();
        x[14] += 5.0;
        let mask = inconsistent_pixels(&x, &y, 6, 6);
        assert_eq!(mask.iter().filter(|&&b| b).count(), 1);
        assert!(mask[14]);
        // Split: the outlier alone in the set, then the 35 others (none inconsistent).
        assert_eq!(inconsistent_fractions(&x, &y, 6, 6, |i| i == 14), [1.0 / 36.0, 1.0, 0.0]);
        assert_eq!(inconsistent_fractions(&x, &y, 6, 6, |i| i < 18), [1.0 / 36.0, 1.0 / 18.0, 0.0]);
        let mut lone = vec![f32::NAN; 36];
        lone[0] = 1.0;
        assert_eq!(inconsistent_fraction(&lone, &lone, 6, 6), 1.0);
        y.iter_mut().for_each(|v| *v = f32::NAN);
        assert_eq!(inconsistent_fraction(&x, &y, 6, 6), 0.0);
    }

    #[test]
    fn decode_json_from_before_the_consistency_figure_still_loads() {
        let old = r#"{"projector":0,"pixels":10,"lit":9,"decoded":8,"weak":1,"out_of_range":0,
            "phase_rejected":0,"one_weak_bit":2,"phase_steps":0,"phase_period":0,"linearised":false,
            "median_relative_margin":null,"warnings":[]}"#;
        let q: DecodeQuality = serde_json::from_str(old).unwrap();
        assert_eq!((q.decoded, q.weak_inconsistent, q.two_weak_bits, q.inconsistent), (8, 0, 0, 0.0));
        assert_eq!((q.inconsistent_confident, q.inconsistent_weak), (0.0, 0.0));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        /// Encode random projector columns and rows, add camera noise, decode: every pixel
        /// comes back exactly (noise well below the stripe contrast).
        #[test]
        fn encode_noise_decode_random_columns(
            cols in proptest::collection::vec(0u32..1400, 64),
            rows in proptest::collection::vec(0u32..1050, 64),
            noise in 0.0f64..0.04,
            seed in 0u64..1000,
        ) {
            let map = |u: u32, _v: u32| Some((cols[u as usize] as f64, rows[u as usize] as f64));
            let pats = standard_patterns(1400, 1050, 16, 0);
            let imgs = render((64, 1), (1400, 1050), &map, &pats, 1.0, noise, seed);
            let d = decode_projector(&imgs, 0, 1400, 1050, &DecodeParams::default()).unwrap();
            for u in 0..64usize {
                prop_assert_eq!(d.x[u], cols[u] as f32);
                prop_assert_eq!(d.y[u], rows[u] as f32);
            }
        }
    }
}
