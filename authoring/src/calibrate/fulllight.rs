//! Each projector's full light at each camera pixel (`lit`: full level minus black), measured
//! again from the Gray-code images so that per-pixel gains are not one image's noise.
//!
//! Where a pixel's projector coordinate lies well inside a stripe of a Gray-code bit, that image
//! shows the pixel either fully lit or black: up to 18 lit and 18 black samples per projector
//! at 1400x1050 instead of one of each (the camera's read noise made dark paint's gains 12-28 %
//! wrong). The stripes' difference is the direct light only (light reflected from elsewhere on
//! the object falls half on the black stripes), so the result keeps the full-white
//! measurement's local ratio to it, smoothed over a window:
//! `lit = direct * box(lit_white * direct) / box(direct^2)`. Global light varies slowly against
//! the direct light, and the camera noise averages out in the box.

use std::path::Path;

use rayon::prelude::*;

use crate::capture_set::{Axis, CaptureManifest, Pattern, gray_bits};
use crate::imgio::{ImageError, LinearImage};
use crate::patterns::gray_code_bit;

/// Projector pixels between a sample's projector coordinate and the nearest stripe edge: the
/// lens blur, the camera pixel's footprint and the correspondence error together stay inside.
pub const STRIPE_MARGIN: f32 = 3.0;
/// Half-width, in camera pixels, of the window over which the full-white measurement's ratio
/// to the stripes' direct light is taken.
pub const RATIO_RADIUS: usize = 7;

/// Samples at one pixel: their sum per channel, the sum of squares of their channel sums, and
/// their count.
#[derive(Clone, Copy, Debug, Default)]
struct Acc {
    sum: [f32; 3],
    sq: f32,
    n: u16,
    /// Which Gray-code axes gave samples (bit 0: x, bit 1: y).
    axes: u8,
}

impl Acc {
    fn add(&mut self, v: &[f32; 3]) {
        for (s, x) in self.sum.iter_mut().zip(v) {
            *s += x;
        }
        self.sq += (v[0] + v[1] + v[2]).powi(2);
        self.n = self.n.saturating_add(1);
    }

    fn mean(&self) -> [f32; 3] {
        self.sum.map(|s| s / self.n as f32)
    }

    /// Mean and sample variance of the channel sums.
    fn total(&self) -> (f64, f64) {
        let n = self.n as f64;
        let m = (self.sum[0] + self.sum[1] + self.sum[2]) as f64 / n;
        (m, ((self.sq as f64 / n - m * m) * n / (n - 1.0)).max(0.0))
    }
}

/// Sums of the lit and black samples per camera pixel.
#[derive(Clone, Debug)]
pub struct StripeSums {
    width: usize,
    height: usize,
    /// Per projector, per pixel: the samples inside a lit stripe.
    lit: Vec<Vec<Acc>>,
    /// Per pixel: the samples where no projector lit it (black images included).
    dark: Vec<Acc>,
}

impl StripeSums {
    pub fn new(width: u32, height: u32, projectors: usize) -> Self {
        let n = width as usize * height as usize;
        Self {
            width: width as usize,
            height: height as usize,
            lit: vec![vec![Acc::default(); n]; projectors],
            dark: vec![Acc::default(); n],
        }
    }

    /// Adds an image taken with every projector black.
    pub fn add_black(&mut self, img: &LinearImage) {
        for (d, v) in self.dark.iter_mut().zip(&img.data) {
            d.add(v);
        }
    }

    /// Adds projector `k`'s image of a Gray-code bit: a pixel whose projector coordinate
    /// (`corr`, pixel centres at integers) is at least [`STRIPE_MARGIN`] from the bit's stripe
    /// edges counts as lit or black; the others are skipped.
    pub fn add_gray(
        &mut self,
        k: usize,
        (axis, bit, inverted): (Axis, u32, bool),
        (proj_w, proj_h): (u32, u32),
        corr: &[[f32; 2]],
        img: &LinearImage,
    ) {
        let (extent, a) = match axis {
            Axis::X => (proj_w, 0),
            Axis::Y => (proj_h, 1),
        };
        let n = gray_bits(extent);
        for (i, (c, v)) in corr.iter().zip(&img.data).enumerate() {
            let u = c[a];
            if !u.is_finite() {
                continue;
            }
            let lo = (u - STRIPE_MARGIN + 0.5).floor();
            let hi = (u + STRIPE_MARGIN + 0.5).floor();
            if lo < 0.0 || hi >= extent as f32 {
                continue;
            }
            let (lo, hi) = (lo as u32, hi as u32);
            // A stripe of this bit spans 2^(n - bit) columns (the first and last may be cut);
            // narrower than the window, the same value at both ends does not mean one stripe.
            let stripe = 1u64 << (n - bit).min(40);
            let on = gray_code_bit(lo, bit, n);
            if stripe <= (hi - lo) as u64 + 1 || gray_code_bit(hi, bit, n) != on {
                continue;
            }
            if on != inverted {
                self.lit[k][i].add(v);
                self.lit[k][i].axes |= 1 << a;
            } else {
                self.dark[i].add(v);
            }
        }
    }

    /// Whether projector `k`'s images agree that it lights pixel `i` where the coordinate given
    /// to [`add_gray`](Self::add_gray) says: the lit samples' mean stands above the black
    /// samples' by more than `min_z` standard errors, and the lit samples agree with each other
    /// (spread within three times the black samples' noise plus 15 % of their light, which
    /// leaves room for shot noise and light from elsewhere on the object). A coordinate off by
    /// more than the stripe margin mixes black samples into the lit ones on the bits whose
    /// stripe edges it crosses, which widens their spread; no light at all gives no contrast.
    /// Both axes' stripes must speak. This checks light and rough position; the precision of a
    /// filled coordinate comes from [`crate::calibrate::fill`]'s fit.
    pub fn confirms(&self, k: usize, i: usize, min_z: f64) -> bool {
        let (b, d) = (&self.lit[k][i], &self.dark[i]);
        if b.n < 4 || d.n < 4 || b.axes != 3 {
            return false;
        }
        let ((mb, vb), (md, vd)) = (b.total(), d.total());
        let stderr = (vb / b.n as f64 + vd / d.n as f64).sqrt().max(1e-9);
        mb - md > min_z * stderr && vb.sqrt() <= 3.0 * vd.sqrt() + 0.15 * (mb - md)
    }

    /// Replaces `lits[k]` (full-white measurement minus black) by the stripes' direct light
    /// times the full-white measurement's local ratio to it, where the pixel has at least
    /// `min_samples` lit and black samples; elsewhere `lits[k]` is kept. Returns per projector
    /// how many pixels were replaced.
    pub fn refine(&self, lits: &mut [Vec<[f32; 3]>], min_samples: u16) -> Vec<usize> {
        let (w, h) = (self.width, self.height);
        lits.iter_mut()
            .zip(&self.lit)
            .map(|(lit, sums)| {
                let direct: Vec<Option<[f32; 3]>> = sums
                    .par_iter()
                    .zip(&self.dark)
                    .map(|(b, d)| {
                        (b.n >= min_samples && d.n >= min_samples).then(|| {
                            let (b, d) = (b.mean(), d.mean());
                            std::array::from_fn(|c| b[c] - d[c])
                        })
                    })
                    .collect();
                // Per channel, the window sums of lit_white * direct and direct^2.
                let mut num = vec![[0.0f64; 3]; w * h];
                let mut den = vec![[0.0f64; 3]; w * h];
                for (i, d) in direct.iter().enumerate() {
                    if let (Some(d), l) = (d, lit[i]) {
                        num[i] = std::array::from_fn(|c| l[c] as f64 * d[c] as f64);
                        den[i] = std::array::from_fn(|c| d[c] as f64 * d[c] as f64);
                    }
                }
                let num = box_sum(&num, w, h, RATIO_RADIUS);
                let den = box_sum(&den, w, h, RATIO_RADIUS);
                let mut replaced = 0;
                for (i, d) in direct.iter().enumerate() {
                    let Some(d) = d else { continue };
                    if (0..3).all(|c| den[i][c] > 0.0 && num[i][c].is_finite()) {
                        lit[i] = std::array::from_fn(|c| d[c] * (num[i][c] / den[i][c]) as f32);
                        replaced += 1;
                    }
                }
                replaced
            })
            .collect()
    }
}

/// Sum over the `(2r + 1)^2` window around each pixel (clipped at the image's edges), from a
/// summed-area table.
fn box_sum(v: &[[f64; 3]], w: usize, h: usize, r: usize) -> Vec<[f64; 3]> {
    let mut sat = vec![[0.0f64; 3]; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = [0.0f64; 3];
        for x in 0..w {
            for c in 0..3 {
                row[c] += v[y * w + x][c];
                sat[(y + 1) * (w + 1) + x + 1][c] = sat[y * (w + 1) + x + 1][c] + row[c];
            }
        }
    }
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (x0, y0, x1, y1) =
                (x.saturating_sub(r), y.saturating_sub(r), (x + r + 1).min(w), (y + r + 1).min(h));
            std::array::from_fn(|c| {
                sat[y1 * (w + 1) + x1][c] - sat[y0 * (w + 1) + x1][c] - sat[y1 * (w + 1) + x0][c]
                    + sat[y0 * (w + 1) + x0][c]
            })
        })
        .collect()
}

/// Loads every projector's black and Gray-code images of `manifest` (a few at a time, summed in
/// the manifest's order, so the result does not depend on the number of threads) and sorts
/// their pixels into lit and black samples by `correspondences`.
pub fn stripe_sums(
    dir: &Path,
    manifest: &CaptureManifest,
    (cam_w, cam_h): (u32, u32),
    correspondences: &[Vec<[f32; 2]>],
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<StripeSums, ImageError> {
    let mut sums = StripeSums::new(cam_w, cam_h, manifest.projectors.len());
    let jobs: Vec<(usize, &Pattern, &Path)> = manifest
        .projectors
        .iter()
        .enumerate()
        .flat_map(|(k, p)| p.shots.iter().map(move |s| (k, &s.pattern, s.file.as_path())))
        .filter(|(_, p, _)| matches!(p, Pattern::Black | Pattern::GrayCode { .. }))
        .collect();
    for (done, chunk) in jobs.chunks(8).enumerate() {
        let images = chunk
            .par_iter()
            .map(|(_, _, f)| LinearImage::load_sized(&dir.join(f), cam_w, cam_h))
            .collect::<Result<Vec<_>, _>>()?;
        for ((k, pattern, _), img) in chunk.iter().zip(&images) {
            let p = &manifest.projectors[*k];
            match **pattern {
                Pattern::Black => sums.add_black(img),
                Pattern::GrayCode { axis, bit, inverted } => {
                    sums.add_gray(*k, (axis, bit, inverted), (p.width, p.height), &correspondences[*k], img)
                }
                _ => {}
            }
        }
        progress("full light from the Gray codes", ((done + 1) * 8).min(jobs.len()), jobs.len());
    }
    Ok(sums)
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::patterns::render;

    /// One projector of 256x192 seen one to one by a 256x192 camera: albedo per pixel (dark
    /// bands), black level plus room light, optional global light proportional to the frame's
    /// mean, and read noise. Returns the sums, the full-white lit measured from one image pair,
    /// and the true lit.
    fn scene(global: f32, noise: f32, shift: f32) -> (StripeSums, Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let (w, h) = (256u32, 192u32);
        let n = (w * h) as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let albedo: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let band = (i / w as usize / 12) % 3;
                // The first 8 columns are beyond the object: nothing there reflects light.
                let a = if i % (w as usize) < 8 {
                    0.0
                } else {
                    [0.6, 0.02, 0.15][band] * rng.gen_range(0.9f32..1.1)
                };
                [a, a * 0.5, a * 0.8]
            })
            .collect();
        // Columns from 128 on are given coordinates `shift` projector px off.
        let corr: Vec<[f32; 2]> = (0..n)
            .map(|i| {
                let x = (i % w as usize) as f32;
                [if x >= 128.0 { x + shift } else { x }, (i / w as usize) as f32]
            })
            .collect();
        let shoot = |frame: &[f32], rng: &mut ChaCha8Rng| {
            let mean = frame.iter().sum::<f32>() / n as f32;
            LinearImage {
                width: w,
                height: h,
                data: (0..n)
                    .map(|i| {
                        std::array::from_fn(|c| {
                            albedo[i][c] * (frame[i] + global * mean)
                                + 0.004
                                + noise * rng.gen_range(-1.7f32..1.7)
                        })
                    })
                    .collect(),
            }
        };
        let mut sums = StripeSums::new(w, h, 1);
        let black = shoot(&vec![0.0; n], &mut rng);
        let white = shoot(&vec![1.0; n], &mut rng);
        sums.add_black(&black);
        for (axis, extent) in [(Axis::X, w), (Axis::Y, h)] {
            for bit in 0..gray_bits(extent) {
                for inverted in [false, true] {
                    let frame: Vec<f32> = render(&Pattern::GrayCode { axis, bit, inverted }, w, h)
                        .pixels()
                        .map(|p| p.0[0] as f32 / 255.0)
                        .collect();
                    let img = shoot(&frame, &mut rng);
                    sums.add_gray(0, (axis, bit, inverted), (w, h), &corr, &img);
                }
            }
        }
        let measured: Vec<[f32; 3]> =
            white.data.iter().zip(&black.data).map(|(a, b)| std::array::from_fn(|c| a[c] - b[c])).collect();
        let truth = albedo.iter().map(|a| a.map(|v| v * (1.0 + global))).collect();
        (sums, measured, truth)
    }

    /// Relative RMS error of `lit` against `truth` over the pixels of the dark band, channel 0.
    fn dark_band_error(lit: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
        let (s, n) = lit
            .iter()
            .zip(truth)
            .filter(|(_, t)| t[0] > 0.0 && t[0] < 0.05)
            .fold((0.0, 0), |(s, n), (l, t)| (s + ((l[0] / t[0] - 1.0) as f64).powi(2), n + 1));
        (s / n as f64).sqrt()
    }

    #[test]
    fn the_stripes_average_the_noise_of_dark_paint_away() {
        let (sums, measured, truth) = scene(0.0, 0.0008, 0.0);
        let before = dark_band_error(&measured, &truth);
        let mut lits = vec![measured];
        let replaced = sums.refine(&mut lits, 4);
        let after = dark_band_error(&lits[0], &truth);
        assert!(replaced[0] > 30_000, "{replaced:?}");
        assert!(before > 0.05 && after < 0.4 * before, "dark band: {before:.3} -> {after:.3}");
    }

    #[test]
    fn light_from_elsewhere_on_the_object_is_kept() {
        // A fifth of the light arrives by interreflection: the stripes see half of it on both
        // lit and black pixels, the full-white image all of it; the result must keep it.
        let (sums, measured, truth) = scene(0.2, 0.0, 0.0);
        let mut lits = vec![measured];
        sums.refine(&mut lits, 4);
        let errors: Vec<f32> = lits[0]
            .iter()
            .zip(&truth)
            .filter(|(_, t)| t[0] > 0.0)
            .map(|(l, t)| (l[0] / t[0] - 1.0).abs())
            .collect();
        let mean = errors.iter().sum::<f32>() / errors.len() as f32;
        let worst = errors.iter().fold(0.0f32, |a, &b| a.max(b));
        // The stripes alone would be 17 % low; which bits a pixel uses moves it a little.
        assert!(mean < 0.01 && worst < 0.03, "relative error mean {mean}, worst {worst}");
    }

    #[test]
    fn the_stripes_confirm_a_right_coordinate_and_refuse_a_wrong_one() {
        // Dark paint (rows 12-23 of every 36) at the camera's noise, as `fill` meets it; from
        // column 128 on the coordinates are `shift` projector px off in x.
        let w = 256;
        let share = |shift: f32, pick: &dyn Fn(usize) -> bool| {
            let (sums, _, _) = scene(0.0, 0.0008, shift);
            let idx: Vec<usize> = (0..w * 192).filter(|&i| (i / w / 12) % 3 == 1 && pick(i)).collect();
            idx.iter().filter(|&&i| sums.confirms(0, i, crate::calibrate::fill::MIN_Z)).count() as f64
                / idx.len() as f64
        };
        let right = share(13.0, &|i| (8..128).contains(&(i % w)));
        let unlit = share(13.0, &|i| i % w < 8);
        let off = share(13.0, &|i| i % w >= 128);
        // Past the projector's edge in x only the y stripes would speak for it.
        let beyond = share(150.0, &|i| i % w >= 128);
        assert!(right > 0.99, "right coordinates confirmed at {right}");
        assert!(unlit == 0.0, "pixels no light reaches confirmed at {unlit}");
        assert!(off < 0.2, "coordinates 13 px off confirmed at {off}");
        assert!(beyond == 0.0, "coordinates beyond the projector confirmed at {beyond}");
    }
}
