//! Clean-up after the contours are rasterised back: hole filling, speck removal, and the
//! final guarantee of the B term (no pixel brighter than gamma allows).

use super::{ClassInfo, MASKED};

/// Visits the 4-connected components of equal label among `mask` pixels, in scan order of
/// their first pixel, calling `f(label, pixels, neighbour labels)`; `f` may relabel.
/// Neighbour labels are those of 4-neighbours outside the component, with `None` for a
/// neighbour outside the image or the mask.
fn for_components(
    work: &mut [u8],
    w: usize,
    h: usize,
    mask: &[bool],
    mut f: impl FnMut(&mut [u8], u8, &[usize], &[Option<u8>]),
) {
    let mut seen = vec![false; w * h];
    let mut stack = Vec::new();
    let mut pixels = Vec::new();
    let mut around = Vec::new();
    for start in 0..w * h {
        if seen[start] || !mask[start] || work[start] == MASKED {
            continue;
        }
        let l = work[start];
        pixels.clear();
        around.clear();
        seen[start] = true;
        stack.push(start);
        while let Some(i) = stack.pop() {
            pixels.push(i);
            let (x, y) = (i % w, i / w);
            let nbrs = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            for j in nbrs {
                match j {
                    Some(j) if mask[j] && work[j] == l => {
                        if !seen[j] {
                            seen[j] = true;
                            stack.push(j);
                        }
                    }
                    Some(j) if mask[j] && work[j] != MASKED => around.push(Some(work[j])),
                    _ => around.push(None),
                }
            }
        }
        f(work, l, &pixels, &around);
    }
}

/// Fills background components of at most `max_area` pixels that are enclosed by a single
/// class (not touching the region's border). Returns how many were filled.
pub fn fill_holes(work: &mut [u8], w: u32, h: u32, mask: &[bool], background: u8, max_area: usize) -> usize {
    let mut filled = 0;
    for_components(work, w as usize, h as usize, mask, |work, l, pixels, around| {
        if l != background || pixels.len() > max_area || around.is_empty() {
            return;
        }
        let Some(first) = around[0] else { return };
        if around.iter().all(|&a| a == Some(first)) {
            for &p in pixels {
                work[p] = first;
            }
            filled += 1;
        }
    });
    filled
}

/// Merges components smaller than `min_area` pixels into the class most of their
/// neighbours have (smallest class index on ties), smallest first: a sieve that removes the
/// one-pixel components, then those of two, and so on. Smallest first matters where the
/// classification is speckled (faded or stained paint): the tiny background specks inside
/// a dot go first, which joins the dot's fragments into one patch, instead of the fragments
/// being merged into the background one by one. Returns how many components were merged.
pub fn remove_specks(work: &mut [u8], w: u32, h: u32, mask: &[bool], min_area: usize) -> usize {
    let mut removed = 0;
    let mut count = [0usize; 256];
    for size in 1..min_area {
        let mut merged_now = 0;
        for_components(work, w as usize, h as usize, mask, |work, _, pixels, around| {
            if pixels.len() > size {
                return;
            }
            count.fill(0);
            for a in around.iter().flatten() {
                count[*a as usize] += 1;
            }
            let best = (0..255).max_by_key(|&k| (count[k], std::cmp::Reverse(k))).unwrap_or(0);
            if count[best] == 0 {
                return;
            }
            for &p in pixels {
                work[p] = best as u8;
            }
            merged_now += 1;
        });
        removed += merged_now;
    }
    removed
}

/// Fills every `loss` pixel of the region (paint gone: bare clay in chips and cracks) with
/// the class of the nearest region pixel that is not loss (Euclidean, by a two-pass vector
/// distance transform; ties to the first found in scan order), or `background` when the
/// region has no such pixel. A chip inside a band becomes band, one on the slip becomes slip,
/// and one across a band's edge is split near where the edge would continue; the contour
/// minimisation then smooths that split. Returns the number of pixels filled.
pub fn fill_losses(work: &mut [u8], w: u32, h: u32, mask: &[bool], loss: &[u8], background: u8) -> usize {
    let (w, h) = (w as usize, h as usize);
    let is_loss = |l: u8| loss.contains(&l);
    if !work.iter().zip(mask).any(|(&l, &m)| m && is_loss(l)) {
        return 0;
    }
    const NONE: (i32, i32) = (i32::MIN, i32::MIN);
    let mut src: Vec<(i32, i32)> = (0..w * h)
        .map(|i| {
            let l = work[i];
            if mask[i] && l != MASKED && !is_loss(l) { ((i % w) as i32, (i / w) as i32) } else { NONE }
        })
        .collect();
    let d2 = |s: (i32, i32), x: i32, y: i32| {
        if s == NONE { i64::MAX } else { ((s.0 - x) as i64).pow(2) + ((s.1 - y) as i64).pow(2) }
    };
    let relax = |src: &mut Vec<(i32, i32)>, x: usize, y: usize, dx: isize, dy: isize| {
        let (nx, ny) = (x as isize + dx, y as isize + dy);
        if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
            return;
        }
        let cand = src[ny as usize * w + nx as usize];
        let (xi, yi) = (x as i32, y as i32);
        if d2(cand, xi, yi) < d2(src[y * w + x], xi, yi) {
            src[y * w + x] = cand;
        }
    };
    for y in 0..h {
        for x in 0..w {
            for (dx, dy) in [(-1, 0), (-1, -1), (0, -1), (1, -1)] {
                relax(&mut src, x, y, dx, dy);
            }
        }
        for x in (0..w).rev() {
            relax(&mut src, x, y, 1, 0);
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            for (dx, dy) in [(1, 0), (1, 1), (0, 1), (-1, 1)] {
                relax(&mut src, x, y, dx, dy);
            }
        }
        for x in 0..w {
            relax(&mut src, x, y, -1, 0);
        }
    }
    let mut n = 0;
    for i in 0..w * h {
        if mask[i] && is_loss(work[i]) {
            let s = src[i];
            // Sources are never loss, so reading them after earlier fills is still right.
            work[i] = if s == NONE { background } else { work[s.1 as usize * w + s.0 as usize] };
            n += 1;
        }
    }
    n
}

/// Puts back the original class wherever the restored one is brighter than the original
/// by more than `gamma` (relative luminance). Returns the number of pixels put back.
pub(crate) fn clamp_brightening(
    work: &mut [u8],
    original: &[u8],
    mask: &[bool],
    classes: &ClassInfo,
    gamma: f64,
) -> usize {
    let mut n = 0;
    for ((o, &orig), &m) in work.iter_mut().zip(original).zip(mask) {
        if !m || *o == MASKED || orig == MASKED || *o == orig {
            continue;
        }
        if classes.luminance[*o as usize] > classes.luminance[orig as usize] + gamma {
            *o = orig;
            n += 1;
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enclosed_hole_filled_open_bay_kept() {
        #[rustfmt::skip]
        let mut l = vec![
            1, 1, 1, 1, 0,
            1, 0, 1, 1, 0,
            1, 1, 1, 0, 0,
        ];
        let mask = vec![true; 15];
        assert_eq!(fill_holes(&mut l, 5, 3, &mask, 0, 4), 1);
        assert_eq!(l[6], 1);
        assert_eq!(l[4], 0, "background touching the border stays");
    }

    #[test]
    fn losses_take_the_nearest_class() {
        // A loss (9) across the edge between class 1 (left) and 2 (right): each side grows
        // into it up to the middle; a loss pixel outside the region stays.
        #[rustfmt::skip]
        let mut l = vec![
            1, 1, 9, 9, 2, 2,
            1, 9, 9, 9, 9, 2,
            1, 1, 9, 9, 2, 9,
        ];
        let mut mask = vec![true; 18];
        mask[17] = false;
        assert_eq!(fill_losses(&mut l, 6, 3, &mask, &[9], 0), 8);
        assert_eq!(l, vec![1, 1, 1, 2, 2, 2, 1, 1, 1, 2, 2, 2, 1, 1, 1, 2, 2, 9]);
    }

    #[test]
    fn specks_take_the_majority_class() {
        #[rustfmt::skip]
        let mut l = vec![
            2, 2, 2, 1,
            2, 3, 2, 1,
            2, 2, 1, 1,
        ];
        let mask = vec![true; 12];
        assert_eq!(remove_specks(&mut l, 4, 3, &mask, 2), 1);
        assert_eq!(l[5], 2);
    }
}
