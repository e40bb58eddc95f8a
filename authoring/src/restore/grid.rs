//! Grid acceleration (§4.3): a region is cut into g x h cells, each expanded to the right and
//! bottom; cells are processed in four groups (the 2x2 parity classes, in raster order), one
//! group after another, the cells of a group in parallel. Cells of a group never overlap and
//! each reads only its own pixels, so the result is the same for any number of threads.

use rayon::prelude::*;

use super::energy::{Cell, CellResult, restore_cell};
use super::{ClassInfo, MASKED, RestoreParams, RestoreStats};

/// A cell's pixel rectangle `x0..x1`, `y0..y1` (already expanded and clipped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CellRect {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

/// The cells of a region's bounding box, grouped A, B, C, D.
pub(crate) fn cells(bbox: CellRect, grid: (u32, u32), expansion: f64) -> [Vec<CellRect>; 4] {
    let (g, h) = (grid.0 as usize, grid.1 as usize);
    let (bw, bh) = (bbox.x1 - bbox.x0, bbox.y1 - bbox.y0);
    let xs: Vec<usize> = (0..=g).map(|i| bbox.x0 + i * bw / g).collect();
    let ys: Vec<usize> = (0..=h).map(|j| bbox.y0 + j * bh / h).collect();
    let mut groups: [Vec<CellRect>; 4] = Default::default();
    for j in 0..h {
        for i in 0..g {
            let (x0, x1, y0, y1) = (xs[i], xs[i + 1], ys[j], ys[j + 1]);
            if x1 == x0 || y1 == y0 {
                continue;
            }
            let ex = (expansion * (x1 - x0) as f64).ceil() as usize;
            let ey = (expansion * (y1 - y0) as f64).ceil() as usize;
            let r = CellRect { x0, y0, x1: (x1 + ex).min(bbox.x1), y1: (y1 + ey).min(bbox.y1) };
            groups[(j % 2) * 2 + i % 2].push(r);
        }
    }
    groups
}

/// Restores one region of `work` in place.
#[allow(clippy::too_many_arguments)]
pub(crate) fn restore_region(
    work: &mut [u8],
    original: &[u8],
    w: u32,
    h: u32,
    mask: &[bool],
    background: u8,
    classes: &ClassInfo,
    params: &RestoreParams,
    stats: &mut RestoreStats,
) {
    let w = w as usize;
    let Some(bbox) = bounding_box(mask, w, h as usize) else { return };
    let groups = cells(bbox, params.grid, params.expansion);
    for group in &groups {
        let snapshot: &[u8] = work;
        let results: Vec<(CellRect, CellResult)> = group
            .par_iter()
            .map(|&r| {
                let (cw, ch) = (r.x1 - r.x0, r.y1 - r.y0);
                let mut labels = Vec::with_capacity(cw * ch);
                let mut orig = Vec::with_capacity(cw * ch);
                let mut active = Vec::with_capacity(cw * ch);
                for y in r.y0..r.y1 {
                    let row = y * w;
                    labels.extend_from_slice(&snapshot[row + r.x0..row + r.x1]);
                    orig.extend_from_slice(&original[row + r.x0..row + r.x1]);
                    for x in r.x0..r.x1 {
                        active.push(mask[row + x] && snapshot[row + x] != MASKED);
                    }
                }
                let cell =
                    Cell { labels: &labels, original: &orig, active: &active, w: cw, h: ch, background };
                (r, restore_cell(&cell, classes, params))
            })
            .collect();
        for (r, res) in results {
            let cw = r.x1 - r.x0;
            for y in r.y0..r.y1 {
                let row = y * w;
                work[row + r.x0..row + r.x1]
                    .copy_from_slice(&res.labels[(y - r.y0) * cw..(y - r.y0 + 1) * cw]);
            }
            let s = res.stats;
            stats.cells += s.cells;
            stats.contours += s.contours;
            stats.points += s.points;
            stats.anchors += s.anchors;
            stats.moves += s.moves;
            stats.removed_points += s.removed_points;
            stats.capped_cells += s.capped_cells;
        }
    }
}

fn bounding_box(mask: &[bool], w: usize, h: usize) -> Option<CellRect> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if mask[y * w + x] {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
        }
    }
    (x0 != usize::MAX).then_some(CellRect { x0, y0, x1, y1 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_do_not_overlap_and_cover_the_box() {
        let bbox = CellRect { x0: 3, y0: 5, x1: 103, y1: 85 };
        let groups = cells(bbox, (5, 4), 0.25);
        let mut covered = vec![false; 100 * 80];
        for g in &groups {
            for (k, a) in g.iter().enumerate() {
                for b in &g[k + 1..] {
                    let overlap = a.x0 < b.x1 && b.x0 < a.x1 && a.y0 < b.y1 && b.y0 < a.y1;
                    assert!(!overlap, "{a:?} {b:?}");
                }
                for y in a.y0..a.y1 {
                    for x in a.x0..a.x1 {
                        covered[(y - 5) * 100 + x - 3] = true;
                    }
                }
            }
        }
        assert!(covered.iter().all(|&c| c));
        assert_eq!(groups.iter().map(Vec::len).sum::<usize>(), 20);
    }
}
