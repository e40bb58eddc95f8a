//! Faded islands: a dot or small shape of paint that has faded evenly towards the ground it
//! sits on keeps its sharp edge, so the soft-border pass (`regions`) cannot see it, and its
//! colour, part of the way from its paint to the ground, can lie nearer a third class (a red
//! dot faded towards the slip reads as bare clay; a black one as the grey-blue). Fading is a
//! mix in linear light of the paint and the ground, so a region that holds no pick of its
//! own class, touches nothing off the object, and is surrounded beyond its rim (which may be
//! mixed) by one class, the ground (losses aside: a chip beside it hides what was there), is
//! explained at the ground's local light as each paint
//! mixed with that ground: the region takes the paint that explains it at least [`EVIDENCE`]
//! times better than its own class does under the same mix. A real chip (bare clay on the slip) is explained by its own
//! class and keeps it: the clay does not lie on the line from any paint to the slip, and
//! where a loss class is named its island may also be the substrate in its cavity's shadow
//! (darkened as the edge pass darkens it in cracks), which no fading explains.

use super::edges::{CRACK_SHADE, mix};
use super::regions::regions_only;
use crate::imgio::LinearImage;

/// How many times smaller the residual of another paint's mix with the ground must be than
/// the region's own class's (as the edge pass asks of its darkened-substrate explanation).
pub const EVIDENCE: f64 = 2.0;

/// Least share of the paint in a faded island's mix: a region more ground than paint is not
/// told from a stain on the ground.
const MIN_SHARE: f64 = 0.5;

/// Pixels beyond the island's rim (which may be mixed) the ground's local colour is read from.
const RING: [usize; 2] = [2, 3];

/// Least share of the ring beyond the rim that must be of one class (the ground): a shape
/// between two paints is not an island.
const GROUND_SHARE: f64 = 0.9;

/// Fewest ground pixels in the ring for the local light to be read.
const MIN_RING: usize = 4;

/// Relabels faded islands (module notes) in place; returns how many pixels changed class.
/// `colours`: each class's colour (linear RGB, the picks' mean); `picks[c]`: the pixels picked
/// for class `c` (an island holding a pick of its own class is the conservator's word and
/// stays); `loss`: the loss classes, which do not fade (never taken; an island of one may be
/// its substrate in shadow).
pub fn relabel_faded_islands(
    photo: &LinearImage,
    labels: &mut [u8],
    k: usize,
    colours: &[[f64; 3]],
    picks: &[Vec<usize>],
    loss: &[u8],
) -> usize {
    let (w, h) = (photo.width as usize, photo.height as usize);
    // Only the regions: their borders' steps are the regions pass's business.
    let (of_pixel, regions) = regions_only(labels, k, w, h, picks);
    let count = regions.len();
    let (open, bbox) = extents(&of_pixel, count, w, h, |j| of_pixel[j] == u32::MAX);
    let mut relabel: Vec<Option<u8>> = vec![None; count];
    for (g, region) in regions.iter().enumerate() {
        if open[g] || region.anchored {
            continue;
        }
        let Around { bx0, by0, bx1, by1, bw, dist } = around(&of_pixel, g as u32, bbox[g], RING[1], w, h);
        // The island's own colour (its pixels that do not touch another region, or all of
        // them where none is inside); the ring's classes and colours beyond the rim, which
        // may be mixed.
        let mut inner = [0f64; 4];
        let mut all = [0f64; 4];
        let mut ring = vec![[0f64; 4]; k];
        for y in by0..=by1 {
            for x in bx0..=bx1 {
                let i = y * w + x;
                let d = dist[(y - by0) * bw + (x - bx0)] as usize;
                let add = |acc: &mut [f64; 4]| {
                    for (a, v) in acc.iter_mut().zip(photo.data[i]) {
                        *a += f64::from(v);
                    }
                    acc[3] += 1.0;
                };
                if d == 0 {
                    add(&mut all);
                    let inside = x > 0
                        && x + 1 < w
                        && y > 0
                        && y + 1 < h
                        && [i - 1, i + 1, i - w, i + w].iter().all(|&j| of_pixel[j] == g as u32);
                    if inside {
                        add(&mut inner);
                    }
                } else if (RING[0]..=RING[1]).contains(&d) && (labels[i] as usize) < k {
                    add(&mut ring[labels[i] as usize]);
                }
            }
        }
        // The ground: the class of nearly all of the ring, losses aside (a chip beside the
        // island hides what was there).
        let kept = |c: &usize| !loss.contains(&(*c as u8));
        let total: f64 = (0..k).filter(kept).map(|c| ring[c][3]).sum();
        let Some(ground) = (0..k).filter(kept).max_by(|&a, &b| ring[a][3].total_cmp(&ring[b][3])) else {
            continue;
        };
        if ground == region.class as usize
            || ring[ground][3] < MIN_RING as f64
            || ring[ground][3] < GROUND_SHARE * total
        {
            continue;
        }
        let mean = |a: &[f64; 4]| [a[0] / a[3], a[1] / a[3], a[2] / a[3]];
        let own = if inner[3] > 0.0 { mean(&inner) } else { mean(&all) };
        let local = mean(&ring[ground]);
        let gc = colours[ground];
        let light = local.iter().sum::<f64>() / gc.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        if !(light.is_finite() && light > 0.0) {
            continue;
        }
        let at_light = |c: usize| colours[c].map(|v| v * light);
        let residual = |c: usize| mix(own, at_light(c), at_light(ground), MIN_SHARE).1;
        // A loss (bare substrate in a chip) may lie in its cavity's shadow, as in a crack.
        let mine = if loss.contains(&region.class) {
            substrate_residual(own, at_light(region.class as usize), at_light(ground))
        } else {
            residual(region.class as usize)
        };
        relabel[g] = better_paint(k, loss, &[ground, region.class as usize], residual, mine);
    }
    apply(labels, &of_pixel, &relabel)
}

/// How well a loss's bare substrate, in its cavity's shadow or not (as the edge pass darkens it
/// in cracks), mixed with `ground` explains `own` (the distance left).
pub(super) fn substrate_residual(own: [f64; 3], bare: [f64; 3], ground: [f64; 3]) -> f64 {
    std::iter::once(1.0)
        .chain(CRACK_SHADE)
        .map(|s| mix(own, bare.map(|v| v * s), ground, MIN_SHARE).1)
        .fold(f64::INFINITY, f64::min)
}

/// The paint (not a loss, not in `not`) whose `residual` is least, where it is at least
/// [`EVIDENCE`] times smaller than `mine`, the shape's own explanation.
pub(super) fn better_paint(
    k: usize,
    loss: &[u8],
    not: &[usize],
    residual: impl Fn(usize) -> f64,
    mine: f64,
) -> Option<u8> {
    (0..k)
        .filter(|c| !not.contains(c) && !loss.contains(&(*c as u8)))
        .map(|c| (c, residual(c)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|&(_, res)| res * EVIDENCE < mine)
        .map(|(c, _)| c as u8)
}

/// Gives every pixel of a component (`of_pixel`) the class `relabel` names for it, if any;
/// returns how many pixels changed.
pub(super) fn apply(labels: &mut [u8], of_pixel: &[u32], relabel: &[Option<u8>]) -> usize {
    let mut changed = 0;
    for (l, &g) in labels.iter_mut().zip(of_pixel) {
        if let Some(c) = relabel.get(g as usize).copied().flatten() {
            *l = c;
            changed += 1;
        }
    }
    changed
}

/// Per component of `of_pixel` (`count` of them, `u32::MAX` for none): whether it touches the
/// image's edge or a pixel `off` names (what is not object), and its bounding box
/// `[x0, y0, x1, y1]`.
pub(super) fn extents(
    of_pixel: &[u32],
    count: usize,
    w: usize,
    h: usize,
    off: impl Fn(usize) -> bool,
) -> (Vec<bool>, Vec<[usize; 4]>) {
    let mut open = vec![false; count];
    let mut bbox = vec![[usize::MAX, usize::MAX, 0, 0]; count];
    for (i, &g) in of_pixel.iter().enumerate().filter(|&(_, &g)| g != u32::MAX) {
        let (x, y) = (i % w, i / w);
        let b = &mut bbox[g as usize];
        *b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
        let n4 = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ];
        if n4.iter().any(|j| j.is_none_or(&off)) {
            open[g as usize] = true;
        }
    }
    (open, bbox)
}

/// Chebyshev distance (up to `reach`) from component `g` of `of_pixel` within its bounding box
/// `[x0, y0, x1, y1]` grown by `reach`: the rings around a shape that this pass and the
/// `within` pass read the ground from.
pub(super) struct Around {
    pub bx0: usize,
    pub by0: usize,
    pub bx1: usize,
    pub by1: usize,
    pub bw: usize,
    /// Row-major over the grown box; `u8::MAX` beyond `reach`.
    pub dist: Vec<u8>,
}

pub(super) fn around(of_pixel: &[u32], g: u32, bbox: [usize; 4], reach: usize, w: usize, h: usize) -> Around {
    let [x0, y0, x1, y1] = bbox;
    let (bx0, by0) = (x0.saturating_sub(reach), y0.saturating_sub(reach));
    let (bx1, by1) = ((x1 + reach).min(w - 1), (y1 + reach).min(h - 1));
    let (bw, bh) = (bx1 - bx0 + 1, by1 - by0 + 1);
    // Breadth first over 8-neighbours: each pixel once, at its chessboard distance.
    let mut dist = vec![u8::MAX; bw * bh];
    let mut queue = std::collections::VecDeque::new();
    for y in by0..=by1 {
        for x in bx0..=bx1 {
            if of_pixel[y * w + x] == g {
                dist[(y - by0) * bw + (x - bx0)] = 0;
                queue.push_back((x - bx0, y - by0));
            }
        }
    }
    while let Some((x, y)) = queue.pop_front() {
        let d = dist[y * bw + x];
        if d as usize >= reach {
            continue;
        }
        for v in y.saturating_sub(1)..=(y + 1).min(bh - 1) {
            for u in x.saturating_sub(1)..=(x + 1).min(bw - 1) {
                if dist[v * bw + u] == u8::MAX {
                    dist[v * bw + u] = d + 1;
                    queue.push_back((u, v));
                }
            }
        }
    }
    Around { bx0, by0, bx1, by1, bw, dist }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [f64; 3] = [0.50, 0.05, 0.03];
    const CLAY: [f64; 3] = [0.30, 0.12, 0.06];
    const SLIP: [f64; 3] = [0.60, 0.50, 0.40];
    const W: usize = 80;
    const H: usize = 40;

    /// Slip with a red dot, a faded red dot (a quarter of the way to the slip) and a clay chip,
    /// all with sharp edges, under light that falls off from left to right. Labels as the
    /// per-pixel rule might give them: the faded dot as clay.
    fn scene() -> (LinearImage, Vec<u8>) {
        let mut photo = LinearImage::new(W as u32, H as u32).unwrap();
        let mut labels = vec![2u8; W * H];
        let faded = [0, 1, 2].map(|j| RED[j] + 0.25 * (SLIP[j] - RED[j]));
        for y in 0..H {
            for x in 0..W {
                let i = y * W + x;
                let d = |cx: f64| (x as f64 - cx).hypot(y as f64 - 20.0) < 6.0;
                let (colour, label) = if d(15.0) {
                    (RED, 0)
                } else if d(40.0) {
                    (faded, 1)
                } else if d(65.0) {
                    (CLAY, 1)
                } else {
                    (SLIP, 2)
                };
                let light = 1.0 - 0.5 * x as f64 / W as f64;
                let t = light * (1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0));
                photo.data[i] = colour.map(|c| (c * t) as f32);
                labels[i] = label;
            }
        }
        (photo, labels)
    }

    #[test]
    fn a_faded_dot_takes_its_paint_and_a_chip_keeps_its_class() {
        let (photo, mut labels) = scene();
        let before = labels.clone();
        let picks = vec![vec![20 * W + 15], vec![20 * W + 65], vec![2 * W + 2]];
        let changed = relabel_faded_islands(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &[1]);
        assert_eq!(labels[20 * W + 40], 0, "the faded dot is red paint");
        assert_eq!(labels[20 * W + 65], 1, "the chip is clay");
        assert_eq!(labels[20 * W + 15], 0);
        assert!(changed > 80, "{changed}");
        for i in (0..labels.len()).filter(|&i| labels[i] != before[i]) {
            assert!(((i % W) as f64 - 40.0).hypot((i / W) as f64 - 20.0) < 6.0, "{i} changed");
        }
    }

    #[test]
    fn an_unpicked_chip_keeps_its_class_and_a_picked_island_is_not_questioned() {
        // No pick in the chip: it is still explained by the clay alone.
        let (photo, mut labels) = scene();
        let picks = vec![vec![20 * W + 15], vec![], vec![2 * W + 2]];
        relabel_faded_islands(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &[1]);
        assert_eq!(labels[20 * W + 65], 1);
        // A pick in the faded dot: the conservator called it clay, and it stays so.
        let (photo, mut labels) = scene();
        let picks = vec![vec![20 * W + 15], vec![20 * W + 40], vec![2 * W + 2]];
        relabel_faded_islands(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &[1]);
        assert_eq!(labels[20 * W + 40], 1);
    }

    #[test]
    fn a_rim_of_mixed_pixels_does_not_hide_the_island() {
        // The faded dot's rim (mixed with the slip) read as the red: the ring beyond the rim
        // is still all slip, so the dot is an island and takes the red.
        let (photo, mut labels) = scene();
        for (i, l) in labels.iter_mut().enumerate() {
            let d = ((i % W) as f64 - 40.0).hypot((i / W) as f64 - 20.0);
            if (4.5..6.0).contains(&d) {
                *l = 0;
            }
        }
        let picks = vec![vec![20 * W + 15], vec![20 * W + 65], vec![2 * W + 2]];
        relabel_faded_islands(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &[1]);
        assert_eq!(labels[20 * W + 40], 0);
    }

    #[test]
    fn chips_beside_the_island_do_not_hide_its_ground() {
        // A band of black faded towards the slip, read as red, with a clay chip biting into
        // each end (together a third of the ring around it): a loss hides what was there, so
        // the rest of the ring, all slip, is the ground, and the band takes the black.
        const BLACK: [f64; 3] = [0.04, 0.04, 0.04];
        let mut photo = LinearImage::new(W as u32, H as u32).unwrap();
        let mut labels = vec![3u8; W * H];
        for (i, (px, l)) in photo.data.iter_mut().zip(labels.iter_mut()).enumerate() {
            let (x, y) = ((i % W) as f64, (i / W) as f64);
            let (colour, label) = if (x - 20.0).hypot(y - 20.0) < 6.0 || (x - 60.0).hypot(y - 20.0) < 6.0 {
                (CLAY, 2)
            } else if (20.0..60.0).contains(&x) && (17.0..23.0).contains(&y) {
                ([0, 1, 2].map(|j| BLACK[j] + 0.45 * (SLIP[j] - BLACK[j])), 1)
            } else {
                (SLIP, 3)
            };
            let t = 1.0 - 0.5 * x / W as f64;
            *px = colour.map(|c| (c * t) as f32);
            *l = label;
        }
        let picks = vec![vec![2 * W + 2], vec![2 * W + 70], vec![20 * W + 20], vec![38 * W + 2]];
        let colours = [BLACK, RED, CLAY, SLIP];
        relabel_faded_islands(&photo, &mut labels, 4, &colours, &picks, &[2]);
        assert_eq!(labels[20 * W + 40], 0, "the faded band is black paint");
        assert_eq!(labels[20 * W + 60], 2, "the chip is clay");
    }

    #[test]
    fn a_shape_between_two_paints_is_not_an_island() {
        // A red band over the top of the scene down to the faded dot's centre: half of the
        // ring around the dot is red, so there is no one ground to have faded towards.
        let (mut photo, mut labels) = scene();
        for (i, (px, l)) in photo.data.iter_mut().zip(labels.iter_mut()).enumerate().take(W * 20) {
            if ((i % W) as f64 - 40.0).hypot((i / W) as f64 - 20.0) >= 6.0 {
                *px = RED.map(|c| c as f32);
                *l = 0;
            }
        }
        let picks = vec![vec![2 * W + 2], vec![20 * W + 65], vec![38 * W + 2]];
        let before = labels.clone();
        relabel_faded_islands(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &[1]);
        assert_eq!(labels[22 * W + 40], 1);
        assert_eq!(labels, before);
    }
}
