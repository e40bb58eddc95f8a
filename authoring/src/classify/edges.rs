//! Mixed pixels at paint edges and the silhouette: a camera pixel integrates light over its
//! area, so one that straddles two paints (or paint and the room behind the object) has a
//! colour between them, and the nearest-colour rule of §4.1 can give it a third class whose
//! colour happens to lie between (red and white slip make something near the faded red; the
//! silhouette's darkened red looks like the dark paint). Those wrong one-pixel rims then
//! spread through the loss fill. This pass relabels each edge pixel by linear unmixing: its
//! colour is explained as `a·m_j + (1-a)·m_k` of two paints seen next to it (or of a paint
//! and the background beyond the silhouette), in linear light where area integration is a
//! plain mean, and the pixel takes the paint of the larger share.
//!
//! Cracks: a crack is a groove one or two pixels wide that shows the substrate (a loss class,
//! bare clay) in shadow, darker than in the open chips the substrate's colour is learnt from,
//! so the nearest-colour rule calls it dark paint. Where the loss classes are named, each
//! edge pixel is also explained with a loss class darkened (0.9x to 0.4x of its chips'
//! colour) mixed with a paint around; that explanation, which has one more freedom, is taken
//! only where the plain one is worse than the median edge pixel's and the darkened one at
//! least twice as good, and only where every paint around has a pure pixel
//! somewhere to measure its colour (at low resolution a thin paint line has none, its mean
//! is a mixture, and a darkened substrate would explain three-paint mixtures it cannot).

use crate::imgio::LinearImage;

/// The window the neighbours' own colours are taken from (pixels each side of the centre).
const REACH: i64 = 2;

/// How dark bare substrate may look in a crack, as a fraction of its colour in open chips.
pub(super) const CRACK_SHADE: [f64; 5] = [0.9, 0.8, 0.65, 0.5, 0.4];

/// How many times smaller the residual of a darkened-substrate explanation must be.
const CRACK_EVIDENCE: f64 = 2.0;

/// Relabels the edge pixels of `labels` (pixels whose 3x3 neighbourhood holds another class
/// or a pixel off `mask`) in place; returns how many changed. Pure pixels (their whole 3x3
/// neighbourhood of one class) are left alone and supply the colours: each candidate paint's
/// colour is the mean of its pure pixels within 2 px (the shading there), else that paint's
/// mean over the whole photo (a thin line has no pure pixel). The result does not depend on
/// the order pixels are visited in: every decision reads the labels as they were. `loss`:
/// the loss classes (bare substrate) whose cracks are told from dark paint (module notes);
/// empty for none.
pub fn unmix_edges(
    photo: &LinearImage,
    labels: &mut [u8],
    mask: Option<&[bool]>,
    k: usize,
    loss: &[u8],
) -> usize {
    let (w, h) = (photo.width as i64, photo.height as i64);
    let n = labels.len();
    debug_assert_eq!(n, photo.data.len());
    let object = |i: usize| (labels[i] as usize) < k && mask.is_none_or(|m| m[i]);
    let background = |i: usize| mask.is_some_and(|m| !m[i]);
    let at = |x: i64, y: i64| (y * w + x) as usize;
    let neighbours = |x: i64, y: i64, r: i64| {
        (-r..=r)
            .flat_map(move |dy| (-r..=r).map(move |dx| (x + dx, y + dy)))
            .filter(move |&(u, v)| u >= 0 && v >= 0 && u < w && v < h)
    };
    // Pure: every in-image 3x3 neighbour has the same label (background counts as its own).
    let pure: Vec<bool> = (0..n)
        .map(|i| {
            let (x, y) = ((i as i64) % w, (i as i64) / w);
            neighbours(x, y, 1)
                .all(|(u, v)| labels[at(u, v)] == labels[i] && background(at(u, v)) == background(i))
        })
        .collect();
    let mut global = vec![[0f64; 4]; k];
    for i in (0..n).filter(|&i| object(i) && pure[i]) {
        add(&mut global[labels[i] as usize], photo.data[i]);
    }
    // Classes whose colour is measured on pure pixels (before the fallback below).
    let seen_pure: Vec<bool> = global.iter().map(|g| g[3] > 0.0).collect();
    // A class without a pure pixel anywhere (a one-pixel line): the mean of all its pixels.
    for (c, g) in global.iter_mut().enumerate() {
        if g[3] == 0.0 {
            for i in (0..n).filter(|&i| object(i) && labels[i] as usize == c) {
                add(g, photo.data[i]);
            }
        }
    }

    let mut out = labels.to_vec();
    let mut decided: Vec<(usize, [(f64, u8); 2])> = Vec::new();
    for i in (0..n).filter(|&i| object(i) && !pure[i]) {
        let (x, y) = ((i as i64) % w, (i as i64) / w);
        // Candidate paints: the classes next to the pixel and those pure within reach.
        let mut local = vec![[0f64; 4]; k];
        let mut candidate = vec![false; k];
        let mut bg = [0f64; 4];
        let mut bg_any = [0f64; 4];
        for (u, v) in neighbours(x, y, REACH) {
            let j = at(u, v);
            let near = (u - x).abs() <= 1 && (v - y).abs() <= 1;
            if background(j) {
                add(&mut bg_any, photo.data[j]);
                if pure[j] {
                    add(&mut bg, photo.data[j]);
                }
            } else if let Some(c) = labels.get(j).map(|&l| l as usize).filter(|&c| c < k) {
                if pure[j] {
                    add(&mut local[c], photo.data[j]);
                    candidate[c] = true;
                }
                candidate[c] |= near;
            }
        }
        let touches_background = neighbours(x, y, 1).any(|(u, v)| background(at(u, v)));
        // (class, colour, darkened substrate in a crack)
        let mut colours: Vec<(usize, [f64; 3], bool)> = (0..k)
            .filter(|&c| candidate[c])
            .filter_map(|c| mean(&local[c]).or_else(|| mean(&global[c])).map(|m| (c, m, false)))
            .collect();
        // Only where every paint around has its colour measured (a paint seen only in mixed
        // pixels has a mean that explains nothing well, and a darkened substrate would).
        let measured = colours.iter().all(|&(c, _, _)| seen_pure[c]);
        for c in loss.iter().map(|&c| c as usize).filter(|&c| c < k && measured && seen_pure[c]) {
            if mean(&local[c]).is_none()
                && let Some(m) = mean(&global[c])
            {
                colours.extend(CRACK_SHADE.iter().map(|&s| (c, m.map(|v| v * s), true)));
            }
        }
        let behind = touches_background.then(|| mean(&bg).or_else(|| mean(&bg_any))).flatten();
        let px = photo.data[i].map(f64::from);
        // Best explanation with paints as seen around, and with a darkened substrate.
        let mut best = [(f64::INFINITY, labels[i]); 2];
        for (a, &(cj, mj, dj)) in colours.iter().enumerate() {
            for &(ck, mk, dk) in &colours[a..] {
                let (share, r) = mix(px, mj, mk, 0.0);
                let label = if share >= 0.5 { cj } else { ck };
                let b = &mut best[usize::from(dj || dk)];
                if r < b.0 {
                    *b = (r, label as u8);
                }
            }
            // Most of a pixel that counts as object is on it: the paint's share is >= 1/2.
            if let Some(mb) = behind {
                let (_, r) = mix(px, mj, mb, 0.5);
                let b = &mut best[usize::from(dj)];
                if r < b.0 {
                    *b = (r, cj as u8);
                }
            }
        }
        decided.push((i, best));
    }
    // A crack takes the extra freedom of a shade only where the paints around leave the pixel
    // unexplained (worse than the median edge pixel: noise and texture) and the darkened
    // substrate explains it clearly better.
    let mut plain: Vec<f64> = decided.iter().map(|d| d.1[0].0).filter(|r| r.is_finite()).collect();
    let floor = if plain.is_empty() {
        0.0
    } else {
        let m = plain.len() / 2;
        *plain.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let mut changed = 0;
    for (i, [p, d]) in decided {
        let label = if p.0 > floor && d.0 * CRACK_EVIDENCE < p.0 { d.1 } else { p.1 };
        if label != labels[i] {
            out[i] = label;
            changed += 1;
        }
    }
    labels.copy_from_slice(&out);
    changed
}

fn add(acc: &mut [f64; 4], rgb: [f32; 3]) {
    for c in 0..3 {
        acc[c] += rgb[c] as f64;
    }
    acc[3] += 1.0;
}

fn mean(acc: &[f64; 4]) -> Option<[f64; 3]> {
    (acc[3] > 0.0).then(|| [acc[0] / acc[3], acc[1] / acc[3], acc[2] / acc[3]])
}

/// The share `a` in `[min_share, 1]` of `m` in `p ≈ a·m + (1-a)·o` (least squares in linear
/// RGB) and the distance left.
pub(super) fn mix(p: [f64; 3], m: [f64; 3], o: [f64; 3], min_share: f64) -> (f64, f64) {
    let d = [0, 1, 2].map(|c| m[c] - o[c]);
    let dd = d.iter().map(|v| v * v).sum::<f64>();
    let a = if dd > 0.0 { (0..3).map(|c| (p[c] - o[c]) * d[c]).sum::<f64>() / dd } else { 1.0 };
    let a = a.clamp(min_share, 1.0);
    let r = (0..3).map(|c| (p[c] - (a * m[c] + (1.0 - a) * o[c])).powi(2)).sum::<f64>().sqrt();
    (a, r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::MASKED;

    /// A vertical edge between two paints (rows 0-5), each pixel of the edge column covering
    /// `share` of the left paint, and below it (rows 6-9) a third paint, a faded red.
    fn edge_image(share: f32) -> (LinearImage, Vec<u8>) {
        let (w, h) = (8u32, 10u32);
        let red = [0.5f32, 0.05, 0.04];
        let white = [0.8f32, 0.75, 0.7];
        let faded = [0.62f32, 0.3, 0.22];
        let mut img = LinearImage::new(w, h).unwrap();
        let mut truth = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                (img.data[i], truth[i]) = match (x, y) {
                    (_, 6..) => (faded, 2),
                    (0..=3, _) => (red, 0),
                    (4, _) => {
                        ([0, 1, 2].map(|c| share * red[c] + (1.0 - share) * white[c]), u8::from(share < 0.5))
                    }
                    _ => (white, 1),
                };
            }
        }
        (img, truth)
    }

    #[test]
    fn a_mixed_edge_pixel_takes_the_paint_of_its_larger_share() {
        for share in [0.2f32, 0.4, 0.6, 0.8] {
            let (img, truth) = edge_image(share);
            // The nearest-colour rule put the edge column in the faded red.
            let mut labels: Vec<u8> =
                truth.iter().enumerate().map(|(i, &t)| if i % 8 == 4 && i < 48 { 2 } else { t }).collect();
            unmix_edges(&img, &mut labels, None, 3, &[]);
            for y in 0..5 {
                assert_eq!(labels[y * 8..y * 8 + 8], truth[y * 8..y * 8 + 8], "share {share} row {y}");
            }
            assert_eq!(labels[48..], truth[48..], "the faded paint keeps its own pixels");
        }
    }

    #[test]
    fn a_darkened_silhouette_pixel_keeps_its_paint() {
        // Paint on the left, black room on the right (off the mask); the silhouette column
        // covers 60 % of the pixel and looks like the dark paint (class 1).
        let (w, h) = (8u32, 5u32);
        let red = [0.5f32, 0.05, 0.04];
        let dark = [0.06f32, 0.02, 0.02];
        let mut img = LinearImage::new(w, h).unwrap();
        let mut mask = vec![true; (w * h) as usize];
        let mut labels = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                img.data[i] = match x {
                    0..=2 => red,
                    3 => red.map(|v| v * 0.6),
                    _ => [0.002; 3],
                };
                if x >= 4 {
                    mask[i] = false;
                    labels[i] = MASKED;
                } else if x == 3 {
                    labels[i] = 1;
                }
            }
        }
        // A patch of real dark paint elsewhere keeps class 1 in the photo.
        img.data[0] = dark;
        labels[0] = 1;
        unmix_edges(&img, &mut labels, Some(&mask), 2, &[]);
        for y in 0..h as usize {
            assert_eq!(labels[y * 8 + 3], 0, "row {y}");
        }
        assert_eq!(labels[0], 1, "a dark pixel with no mixture to explain it stays dark");
    }

    /// Slip with a black patch and an open chip of clay (both pure), crossed by two thin
    /// lines the per-pixel rule calls black: row 3 a crack (clay in shadow, 0.55x, covering
    /// 70 % of each pixel), row 7 a line of black paint (70 %).
    fn crack_image() -> (LinearImage, Vec<u8>, Vec<u8>) {
        let (w, h) = (20u32, 12u32);
        let slip = [0.3f32, 0.24, 0.16];
        let black = [0.011f32, 0.0075, 0.006];
        let clay = [0.12f32, 0.046, 0.021];
        let mut img = LinearImage::new(w, h).unwrap();
        let (mut labels, mut truth) = (vec![0u8; (w * h) as usize], vec![0u8; (w * h) as usize]);
        let mix = |a: [f32; 3], s: f32| [0, 1, 2].map(|c| s * a[c] + (1.0 - s) * slip[c]);
        for y in 0..h as usize {
            for x in 0..w as usize {
                let i = y * w as usize + x;
                (img.data[i], labels[i], truth[i]) = match (x, y) {
                    (15.., 0..=4) => (black, 1, 1),
                    (15.., 7..) => (clay, 2, 2),
                    (..15, 3) => (mix(clay.map(|v| v * 0.55), 0.7), 1, 2),
                    (..15, 7) => (mix(black, 0.7), 1, 1),
                    _ => (slip, 0, 0),
                };
            }
        }
        (img, labels, truth)
    }

    #[test]
    fn a_crack_is_told_from_a_line_of_dark_paint_when_the_loss_class_is_named() {
        let (img, per_pixel, truth) = crack_image();
        let mut labels = per_pixel.clone();
        unmix_edges(&img, &mut labels, None, 3, &[2]);
        assert_eq!(&labels[3 * 20..3 * 20 + 14], &truth[3 * 20..3 * 20 + 14], "the crack is clay");
        assert_eq!(&labels[7 * 20..7 * 20 + 14], &truth[7 * 20..7 * 20 + 14], "the black line stays black");
        // Without the loss class named, nothing may darken: the crack stays dark paint.
        let mut labels = per_pixel.clone();
        unmix_edges(&img, &mut labels, None, 3, &[]);
        assert!(labels[3 * 20..3 * 20 + 14].iter().all(|&l| l == 1), "{:?}", &labels[3 * 20..3 * 20 + 14]);
    }

    #[test]
    fn pure_pixels_and_uniform_regions_are_untouched() {
        let (img, truth) = edge_image(1.0);
        let mut labels = truth.clone();
        assert_eq!(unmix_edges(&img, &mut labels, None, 3, &[]), 0);
        assert_eq!(labels, truth);
    }
}
