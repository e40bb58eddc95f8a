//! Faded paint within its ground's region: a stretch of a line or a dot can fade so far
//! towards the ground it was painted on that the per-pixel rule gives it the ground's class.
//! Then no region border marks it (the `regions` and `islands` passes judge regions), yet it
//! still stands out of the ground around it, and with the edge of paint: stains and fading
//! change gradually, brush strokes in steps (the `regions` pass's observation). So each patch
//! of pixels that stand out of their class's local colour (beyond [`OUTLIER`] times the
//! class's median deviation) is judged on three counts:
//! - the ground around it is flat: between 2-3 px beyond the patch (past its mixed rim) and
//!   5-7 px beyond, the ground's colour changes by at most [`FLAT`] of the patch's contrast
//!   with it; a stain's colour runs on past where it stops standing out;
//! - a paint mixed with that local ground (at least half paint, as the `islands` pass mixes)
//!   explains its colour [`EVIDENCE`](super::islands::EVIDENCE) times better than the ground alone does, or than a loss
//!   class's substrate in a cavity's shadow (a crack) mixed with it;
//! - it touches nothing off the object and holds no pick of its class.
//!
//! Such a patch takes the paint; its mixed rim is left to the edge pass that follows.

use super::edges::mix;
use super::islands::{Around, apply, around, better_paint, extents, substrate_residual};
use super::regions::{components, relative};
use crate::imgio::LinearImage;

/// A pixel stands out of its class's local colour beyond this many times the class's median
/// deviation (camera noise and the grain of the surface).
pub const OUTLIER: f64 = 4.0;

/// Side of the blocks the local colour of each class is gathered in (pixels).
const BLOCK: usize = 8;

/// Blocks either side whose class colours give a pixel's local colour (a median, so a patch
/// smaller than about half of the 5 x 5 blocks does not move it).
const REACH: usize = 2;

/// Fewest pixels of a patch, and of ground in the ring beyond it.
const MIN_PIXELS: usize = 6;

/// Least share of paint in the mix (as in `islands`).
const MIN_SHARE: f64 = 0.5;

/// Pixels beyond the patch's rim the local ground is read from.
const RING: [usize; 2] = [2, 3];

/// Pixels beyond the patch the ground further out is read from: where the ground just beyond
/// the rim differs from it by more than [`FLAT`] of the patch's contrast with it, the change
/// runs on past the patch (a stain), and the patch is not paint.
const BEYOND: [usize; 2] = [5, 7];

/// Most share of the patch's contrast the ground may still change by between 2-3 px and
/// 5-7 px beyond the patch.
pub const FLAT: f64 = 0.15;

/// Each pixel's class's local colour (linear RGB; `None` off the object or where too few
/// blocks hold the class): per block and class the mean colour, then per channel the median
/// of the blocks within [`REACH`].
fn local_colours(photo: &LinearImage, labels: &[u8], k: usize) -> Vec<Option<[f64; 3]>> {
    let (w, h) = (photo.width as usize, photo.height as usize);
    let (bw, bh) = (w.div_ceil(BLOCK), h.div_ceil(BLOCK));
    let mut sums = vec![[0f64; 4]; bw * bh * k];
    for (i, &l) in labels.iter().enumerate().filter(|&(_, &l)| (l as usize) < k) {
        let b = ((i / w) / BLOCK * bw + (i % w) / BLOCK) * k + l as usize;
        for (a, v) in sums[b].iter_mut().zip(photo.data[i]) {
            *a += f64::from(v);
        }
        sums[b][3] += 1.0;
    }
    let min_count = (BLOCK * BLOCK / 4) as f64;
    let mut local = vec![None; bw * bh * k];
    let mut vals: [Vec<f64>; 3] = Default::default();
    for by in 0..bh {
        for bx in 0..bw {
            // Only the classes present in the block are asked for there.
            for c in (0..k).filter(|&c| sums[(by * bw + bx) * k + c][3] > 0.0) {
                vals.iter_mut().for_each(Vec::clear);
                for v in by.saturating_sub(REACH)..=(by + REACH).min(bh - 1) {
                    for u in bx.saturating_sub(REACH)..=(bx + REACH).min(bw - 1) {
                        let s = sums[(v * bw + u) * k + c];
                        if s[3] >= min_count {
                            for j in 0..3 {
                                vals[j].push(s[j] / s[3]);
                            }
                        }
                    }
                }
                if vals[0].len() >= 3 {
                    local[(by * bw + bx) * k + c] = Some([0, 1, 2].map(|j| {
                        vals[j].sort_by(f64::total_cmp);
                        vals[j][vals[j].len() / 2]
                    }));
                }
            }
        }
    }
    labels
        .iter()
        .enumerate()
        .map(|(i, &l)| {
            ((l as usize) < k)
                .then(|| local[((i / w) / BLOCK * bw + (i % w) / BLOCK) * k + l as usize])
                .flatten()
        })
        .collect()
}

/// Relabels faded paint within its ground's region (module notes) in place; returns how many
/// pixels changed class. `colours`: each class's colour (linear RGB, the picks' mean);
/// `picks[c]`: the pixels picked for class `c`; `loss`: the loss classes, never taken and never
/// a ground here (a chip's edge is sharp by nature).
pub fn relabel_faded_within(
    photo: &LinearImage,
    labels: &mut [u8],
    k: usize,
    colours: &[[f64; 3]],
    picks: &[Vec<usize>],
    loss: &[u8],
) -> usize {
    let (w, h) = (photo.width as usize, photo.height as usize);
    let rgb = |i: usize| photo.data[i].map(f64::from);
    let local = local_colours(photo, labels, k);
    let deviation: Vec<f64> = (0..w * h).map(|i| local[i].map_or(0.0, |l| relative(rgb(i), l))).collect();
    // Each class's median deviation: its noise and grain.
    let mut by_class: Vec<Vec<f64>> = vec![Vec::new(); k];
    for i in (0..w * h).filter(|&i| local[i].is_some()) {
        by_class[labels[i] as usize].push(deviation[i]);
    }
    let median: Vec<f64> = by_class
        .iter_mut()
        .map(|d| {
            let mid = d.len() / 2;
            if d.is_empty() { f64::INFINITY } else { *d.select_nth_unstable_by(mid, f64::total_cmp).1 }
        })
        .collect();
    let outlier: Vec<bool> = (0..w * h)
        .map(|i| {
            let c = labels[i] as usize;
            c < k && !loss.contains(&labels[i]) && deviation[i] > OUTLIER * median[c]
        })
        .collect();
    let (of_pixel, count) = components(labels, &outlier, w, h, u8::MAX);
    let (open, bbox) = extents(&of_pixel, count, w, h, |j| labels[j] as usize >= k);
    let mut size = vec![0usize; count];
    let mut class = vec![0u8; count];
    for (i, &g) in of_pixel.iter().enumerate().filter(|&(_, &g)| g != u32::MAX) {
        size[g as usize] += 1;
        class[g as usize] = labels[i];
    }
    let mut anchored = vec![false; count];
    for (c, pix) in picks.iter().enumerate() {
        for &i in pix.iter().filter(|&&i| i < w * h && labels[i] as usize == c && of_pixel[i] != u32::MAX) {
            anchored[of_pixel[i] as usize] = true;
        }
    }
    let mean = |a: &[f64; 4]| [a[0] / a[3], a[1] / a[3], a[2] / a[3]];
    let norm = |a: [f64; 3], b: [f64; 3]| (0..3).map(|j| (a[j] - b[j]).powi(2)).sum::<f64>().sqrt();
    let mut relabel: Vec<Option<u8>> = vec![None; count];
    for g in 0..count {
        if open[g] || anchored[g] || size[g] < MIN_PIXELS {
            continue;
        }
        let ground = class[g];
        let Around { bx0, by0, bx1, by1, bw, dist } = around(&of_pixel, g as u32, bbox[g], BEYOND[1], w, h);
        // Inside (all 4-neighbours in the patch), border, and the ground (its class, standing
        // out of nothing) beyond the rim and further out.
        let [mut inner, mut border, mut ring, mut beyond] = [[0f64; 4]; 4];
        for y in by0..=by1 {
            for x in bx0..=bx1 {
                let i = y * w + x;
                let d = dist[(y - by0) * bw + (x - bx0)] as usize;
                let add = |acc: &mut [f64; 4]| {
                    for (a, v) in acc.iter_mut().zip(rgb(i)) {
                        *a += v;
                    }
                    acc[3] += 1.0;
                };
                if d == 0 {
                    let inside = x > 0
                        && x + 1 < w
                        && y > 0
                        && y + 1 < h
                        && [i - 1, i + 1, i - w, i + w].iter().all(|&j| of_pixel[j] == g as u32);
                    add(if inside { &mut inner } else { &mut border });
                } else if labels[i] == ground && of_pixel[i] == u32::MAX {
                    if (RING[0]..=RING[1]).contains(&d) {
                        add(&mut ring);
                    } else if (BEYOND[0]..=BEYOND[1]).contains(&d) {
                        add(&mut beyond);
                    }
                }
            }
        }
        if ring[3] < MIN_PIXELS as f64 || beyond[3] < MIN_PIXELS as f64 {
            continue;
        }
        let local = mean(&ring);
        let own = if inner[3] > 0.0 { mean(&inner) } else { mean(&border) };
        let contrast = norm(own, local);
        let far = mean(&beyond);
        let runs_on = norm(local, far) / norm(own, far);
        if !(contrast > 0.0 && runs_on <= FLAT) {
            continue;
        }
        let light =
            local.iter().sum::<f64>() / colours[ground as usize].iter().sum::<f64>().max(f64::MIN_POSITIVE);
        if !(light.is_finite() && light > 0.0) {
            continue;
        }
        let at_light = |c: usize| colours[c].map(|v| v * light);
        // The ground alone, or a chip or crack: a loss's substrate mixed with the ground.
        let mine = loss
            .iter()
            .filter(|&&c| (c as usize) < k)
            .map(|&c| substrate_residual(own, at_light(c as usize), local))
            .fold(contrast, f64::min);
        let residual = |c: usize| mix(own, at_light(c), local, MIN_SHARE).1;
        relabel[g] = better_paint(k, loss, &[ground as usize], residual, mine);
    }
    apply(labels, &of_pixel, &relabel)
}

#[cfg(test)]
mod tests {
    use super::*;

    const BLACK: [f64; 3] = [0.04, 0.04, 0.04];
    const OCHRE: [f64; 3] = [0.45, 0.28, 0.08];
    const CLAY: [f64; 3] = [0.30, 0.12, 0.06];
    const SLIP: [f64; 3] = [0.60, 0.50, 0.40];
    const COLOURS: [[f64; 3]; 4] = [BLACK, OCHRE, CLAY, SLIP];
    const W: usize = 96;
    const H: usize = 48;

    /// The faded stretch of the stroke (truth black, read as the slip).
    fn faded_stroke(x: usize, y: usize) -> bool {
        (10..14).contains(&x) && (24..40).contains(&y)
    }

    /// The faded ochre dot (read as the slip).
    fn faded_dot(x: usize, y: usize) -> bool {
        (x as f64 - 30.0).hypot(y as f64 - 34.0) < 4.5
    }

    /// `p` faded 45 % of the way to the slip (the most the virtual stage fades).
    fn faded(p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|j| p[j] + 0.45 * (SLIP[j] - p[j]))
    }

    /// Slip under light falling off from left to right, with a black stroke whose lower
    /// stretch has faded, a faded ochre dot, a soft brown stain as dark as the faded ochre at
    /// its centre (the virtual stage's stain tint, 0.8 strong), and a crack (the clay in its
    /// cavity's shadow, one pixel wide). Labels as the per-pixel rule gives them: everything
    /// but the unfaded stroke is slip.
    fn scene() -> (LinearImage, Vec<u8>) {
        let mut photo = LinearImage::new(W as u32, H as u32).unwrap();
        let mut labels = vec![3u8; W * H];
        let tint = [0.70, 0.60, 0.45];
        for y in 0..H {
            for x in 0..W {
                let i = y * W + x;
                let colour = if (10..14).contains(&x) && (4..24).contains(&y) {
                    labels[i] = 0;
                    BLACK
                } else if faded_stroke(x, y) {
                    faded(BLACK)
                } else if faded_dot(x, y) {
                    faded(OCHRE)
                } else if x == 80 && (8..40).contains(&y) {
                    CLAY.map(|c| c * 0.55)
                } else {
                    let d = (x as f64 - 55.0).hypot(y as f64 - 24.0);
                    let s = 0.8 * (-(d / 10.0).powi(2)).exp();
                    [0, 1, 2].map(|j| SLIP[j] * (1.0 + s * (tint[j] - 1.0)))
                };
                let light = 1.0 - 0.3 * x as f64 / W as f64;
                let t = light * (1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0));
                photo.data[i] = colour.map(|c| (c * t) as f32);
            }
        }
        (photo, labels)
    }

    fn picks() -> Vec<Vec<usize>> {
        vec![vec![6 * W + 11], vec![], vec![], vec![2 * W + 40]]
    }

    /// Pixels whose label differs from what `expected` says, as (x, y, label).
    fn wrong(labels: &[u8], expected: impl Fn(usize, usize) -> u8) -> Vec<(usize, usize, u8)> {
        (0..W * H).map(|i| (i % W, i / W, labels[i])).filter(|&(x, y, l)| l != expected(x, y)).collect()
    }

    #[test]
    fn faded_paint_takes_its_class_and_the_stain_and_the_crack_stay_the_ground() {
        let (photo, mut labels) = scene();
        let before = labels.clone();
        let changed = relabel_faded_within(&photo, &mut labels, 4, &COLOURS, &picks(), &[2]);
        let expected = |x, y| {
            if faded_stroke(x, y) {
                0
            } else if faded_dot(x, y) {
                1
            } else {
                before[y * W + x]
            }
        };
        assert_eq!(wrong(&labels, expected), vec![]);
        assert_eq!(
            changed,
            (0..W * H).filter(|&i| faded_stroke(i % W, i / W) || faded_dot(i % W, i / W)).count()
        );
    }

    #[test]
    fn a_picked_patch_is_not_questioned() {
        let (photo, mut labels) = scene();
        let before = labels.clone();
        let mut picks = picks();
        picks[3].extend([30 * W + 12, 34 * W + 30]);
        relabel_faded_within(&photo, &mut labels, 4, &COLOURS, &picks, &[2]);
        assert_eq!(wrong(&labels, |x, y| before[y * W + x]), vec![]);
    }
}
