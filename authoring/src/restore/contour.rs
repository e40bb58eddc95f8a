//! Patches (4-connected components of one class, background excluded) and their contours
//! (outer and holes) traced along pixel sides as closed polylines on the corner lattice.
//!
//! Orientation: walking a contour, the patch lies on the right in image coordinates (y down),
//! so outer contours run clockwise on screen and holes anticlockwise; the outward normal of
//! a step `(dx, dy)` is `(dy, -dx)` for both.

/// A closed polyline of lattice points (unit steps); the last point connects to the first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Contour {
    pub points: Vec<[i32; 2]>,
}

impl Contour {
    /// Signed area on the lattice: positive for outer contours, negative for holes.
    pub fn signed_area(&self) -> i64 {
        let n = self.points.len();
        let mut a = 0i64;
        for i in 0..n {
            let (p, q) = (self.points[i], self.points[(i + 1) % n]);
            a += p[0] as i64 * q[1] as i64 - q[0] as i64 * p[1] as i64;
        }
        a / 2
    }
}

/// One patch: its class, its pixel count and its contours.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Patch {
    pub label: u8,
    pub area: usize,
    pub contours: Vec<Contour>,
}

const NONE: u32 = u32::MAX;

use crate::classify::regions::components;

/// Traces every patch of a `w` x `h` buffer. Deterministic: patches in scan order of their
/// first pixel, contours in order of their first edge.
pub fn trace_patches(labels: &[u8], active: &[bool], w: usize, h: usize, background: u8) -> Vec<Patch> {
    let (comp, n) = components(labels, active, w, h, background);
    let mut patches: Vec<Patch> = vec![Patch { label: 0, area: 0, contours: Vec::new() }; n];
    let lw = w + 1;
    // Directed boundary edges (component, start vertex, direction 0 right 1 down 2 left 3 up).
    let mut edges: Vec<(u32, u32, u8)> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let c = comp[y * w + x];
            if c == NONE {
                continue;
            }
            let p = &mut patches[c as usize];
            p.label = labels[y * w + x];
            p.area += 1;
            let differs = |xx: isize, yy: isize| {
                xx < 0
                    || yy < 0
                    || xx >= w as isize
                    || yy >= h as isize
                    || comp[yy as usize * w + xx as usize] != c
            };
            let (xi, yi) = (x as isize, y as isize);
            let v = |vx: usize, vy: usize| (vy * lw + vx) as u32;
            if differs(xi, yi - 1) {
                edges.push((c, v(x, y), 0));
            }
            if differs(xi + 1, yi) {
                edges.push((c, v(x + 1, y), 1));
            }
            if differs(xi, yi + 1) {
                edges.push((c, v(x + 1, y + 1), 2));
            }
            if differs(xi - 1, yi) {
                edges.push((c, v(x, y + 1), 3));
            }
        }
    }
    edges.sort_unstable();
    let mut used = vec![false; edges.len()];
    let step = |v: u32, d: u8| -> u32 {
        match d {
            0 => v + 1,
            1 => v + lw as u32,
            2 => v - 1,
            _ => v - lw as u32,
        }
    };
    let mut lo = 0;
    while lo < edges.len() {
        let c = edges[lo].0;
        let mut hi = lo;
        while hi < edges.len() && edges[hi].0 == c {
            hi += 1;
        }
        let slice = &edges[lo..hi];
        for first in 0..slice.len() {
            if used[lo + first] {
                continue;
            }
            let mut pts = Vec::new();
            let mut cur = first;
            loop {
                used[lo + cur] = true;
                let (_, s, d) = slice[cur];
                pts.push([(s as usize % lw) as i32, (s as usize / lw) as i32]);
                let t = step(s, d);
                let at = slice.partition_point(|e| e.1 < t);
                // At a pinch two edges leave the vertex: turn right (towards the patch) so
                // pixels touching only at a corner stay separate, as 4-connectivity says.
                let right = (d + 1) % 4;
                let mut next = None;
                for (k, e) in slice.iter().enumerate().skip(at) {
                    if e.1 != t {
                        break;
                    }
                    if next.is_none() || e.2 == right {
                        next = Some(k);
                    }
                }
                let next = next.expect("every boundary edge has a successor");
                if next == first || used[lo + next] {
                    break;
                }
                cur = next;
            }
            patches[c as usize].contours.push(Contour { points: pts });
        }
        lo = hi;
    }
    patches
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_has_outer_and_hole() {
        // 4x4 block of class 1 with a 2x2 hole of background 0 inside.
        let w = 6;
        let mut l = vec![0u8; 36];
        for y in 1..5 {
            for x in 1..5 {
                l[y * w + x] = 1;
            }
        }
        l[2 * w + 2] = 0;
        l[2 * w + 3] = 0;
        l[3 * w + 2] = 0;
        l[3 * w + 3] = 0;
        let p = trace_patches(&l, &[true; 36], 6, 6, 0);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].area, 12);
        let mut areas: Vec<i64> = p[0].contours.iter().map(Contour::signed_area).collect();
        areas.sort();
        assert_eq!(areas, vec![-4, 16]);
        assert_eq!(p[0].contours.iter().map(|c| c.points.len()).sum::<usize>(), 16 + 8);
    }

    #[test]
    fn diagonal_touch_is_two_patches_and_pinch_splits() {
        // Two pixels touching at a corner: two 4-connected patches of 4 steps each.
        let l = vec![1u8, 0, 0, 1];
        let p = trace_patches(&l, &[true; 4], 2, 2, 0);
        assert_eq!(p.len(), 2);
        assert!(p.iter().all(|p| p.contours.len() == 1 && p.contours[0].points.len() == 4));
        // A ring closing on itself through a corner: one patch; the pinch splits the
        // boundary into loops whose signed areas add up to the patch's area.
        #[rustfmt::skip]
        let l = vec![
            1, 1, 1, 0,
            1, 0, 1, 0,
            1, 1, 0, 1,
            0, 0, 1, 1,
        ];
        let p = trace_patches(&l, &[true; 16], 4, 4, 0);
        let sum: i64 = p.iter().flat_map(|p| &p.contours).map(Contour::signed_area).sum();
        let area: usize = p.iter().map(|p| p.area).sum();
        assert_eq!(sum, area as i64);
    }
}
