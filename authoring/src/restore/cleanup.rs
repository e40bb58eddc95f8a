//! Clean-up after the contours are rasterised back: hole filling, speck removal, and the
//! final guarantee of the B term (no pixel brighter than gamma allows).

use super::{ClassInfo, MASKED};

/// Visits the 4-connected components of equal label among `mask` pixels, in scan order of
/// their first pixel, calling `f(label, pixels, neighbour labels)`; `f` may relabel.
/// Neighbour labels are those of 4-neighbours outside the component (one per pixel side),
/// with `None` for a neighbour outside the image or the mask; neither list is in any
/// particular order.
///
/// A scanline flood: each seed grows into its whole run of the row, so a pixel costs a few
/// reads rather than a stack push and four neighbour lookups (this runs four times over the
/// whole image per region, on one core, and was about an eighth of restoration's time).
fn for_components(
    work: &mut [u8],
    w: usize,
    h: usize,
    mask: &[bool],
    mut f: impl FnMut(&mut [u8], u8, &[usize], &[Option<u8>]),
) {
    let mut seen = vec![false; w * h];
    let mut seeds = Vec::new();
    let mut pixels = Vec::new();
    let mut around = Vec::new();
    for start in 0..w * h {
        if seen[start] || !mask[start] || work[start] == MASKED {
            continue;
        }
        let l = work[start];
        let member = |work: &[u8], j: usize| mask[j] && work[j] == l;
        // What a neighbour that is not in the component adds to `around`.
        let outside = |work: &[u8], j: usize| (mask[j] && work[j] != MASKED).then(|| work[j]);
        pixels.clear();
        around.clear();
        seeds.push(start);
        while let Some(s) = seeds.pop() {
            if seen[s] {
                continue;
            }
            let row = s - s % w;
            let (mut x0, mut x1) = (s - row, s - row);
            while x0 > 0 && !seen[row + x0 - 1] && member(work, row + x0 - 1) {
                x0 -= 1;
            }
            while x1 + 1 < w && !seen[row + x1 + 1] && member(work, row + x1 + 1) {
                x1 += 1;
            }
            // A neighbour in the row already seen is in the component (it is a member).
            for (end, x) in [(x0 == 0, x0.wrapping_sub(1)), (x1 + 1 == w, x1 + 1)] {
                if end {
                    around.push(None);
                } else if !member(work, row + x) {
                    around.push(outside(work, row + x));
                }
            }
            seen[row + x0..=row + x1].fill(true);
            pixels.extend(row + x0..=row + x1);
            for (edge, other) in [(row == 0, row.wrapping_sub(w)), (row + w == w * h, row + w)] {
                if edge {
                    around.extend(std::iter::repeat_n(None, x1 - x0 + 1));
                    continue;
                }
                // One seed per run of unseen members: it grows into the run when popped.
                let mut in_run = false;
                for x in x0..=x1 {
                    let j = other + x;
                    if member(work, j) {
                        if !seen[j] && !in_run {
                            seeds.push(j);
                        }
                        in_run = !seen[j];
                    } else {
                        around.push(outside(work, j));
                        in_run = false;
                    }
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
    let (w, h) = (w as usize, h as usize);
    // Merging only grows the class a speck joins, so a component of `min_area` pixels or
    // more stays at least that large: one labelling finds the pixels that can ever be part
    // of a speck, and each pass of the sieve floods from those alone, in scan order, as a
    // scan of the whole image would reach them (a pass over every pixel flooded the whole
    // background seven times over).
    let mut small = vec![false; w * h];
    for_components(work, w, h, mask, |_, _, pixels, _| {
        if pixels.len() < min_area {
            for &p in pixels {
                small[p] = true;
            }
        }
    });
    let candidates: Vec<usize> = (0..w * h).filter(|&i| small[i]).collect();
    // Per pass: `done` marks pixels of components flooded whole, `big` those of a flood cut
    // short because its component is larger than the pass's size.
    let mut mark = vec![0u32; w * h];
    let (mut stack, mut pixels) = (Vec::new(), Vec::new());
    let mut count = [0usize; 256];
    let mut removed = 0;
    for size in 1..min_area {
        let (done, big) = (2 * size as u32 - 1, 2 * size as u32);
        for &start in &candidates {
            if mark[start] == done || mark[start] == big {
                continue;
            }
            let l = work[start];
            pixels.clear();
            stack.clear();
            count.fill(0);
            mark[start] = done;
            stack.push(start);
            let mut too_big = false;
            'flood: while let Some(i) = stack.pop() {
                pixels.push(i);
                if pixels.len() > size {
                    too_big = true;
                    break;
                }
                for j in neighbours4(i, w, h).into_iter().flatten() {
                    if !mask[j] || work[j] == MASKED {
                        continue;
                    }
                    if work[j] != l {
                        count[work[j] as usize] += 1;
                    } else if !small[j] || mark[j] == big {
                        // Joined to a component known to be large: stop early.
                        too_big = true;
                        break 'flood;
                    } else if mark[j] != done {
                        mark[j] = done;
                        stack.push(j);
                    }
                }
            }
            if too_big {
                for &p in pixels.iter().chain(&stack) {
                    mark[p] = big;
                }
                continue;
            }
            let best = (0..255).max_by_key(|&k| (count[k], std::cmp::Reverse(k))).unwrap_or(0);
            if count[best] == 0 {
                continue;
            }
            for &p in &pixels {
                work[p] = best as u8;
            }
            removed += 1;
        }
    }
    removed
}

/// Fills every `loss` pixel of the region (paint gone: bare clay in chips and cracks) with
/// the class of the nearest region pixel that is not loss (Euclidean, by a two-pass vector
/// distance transform; ties to the first found in scan order), or `background` when the
/// region has no such pixel. A chip inside a band becomes band, one on the slip becomes slip,
/// and one across a band's edge is split near where the edge would continue; the contour
/// minimisation then smooths that split. Returns the number of pixels filled.
///
/// A chip's rim is not trusted as a source: a camera pixel there mixes bare clay with the
/// paint around it, and may be classified as a class that is not there at all (a dark mix
/// of clay and light paint reads as a dark paint). Rim pixels whose class is rare in the ring
/// just beyond the rim (`suspect_rims`) are filled with the chip, so the chip takes the
/// colour that surrounds it; a line crossing the chip continues beyond the rim, so its class
/// is in the ring and its rim pixels stay.
pub fn fill_losses(work: &mut [u8], w: u32, h: u32, mask: &[bool], loss: &[u8], background: u8) -> usize {
    let (w, h) = (w as usize, h as usize);
    let is_loss = |l: u8| loss.contains(&l);
    if !work.iter().zip(mask).any(|(&l, &m)| m && is_loss(l)) {
        return 0;
    }
    let suspect = suspect_rims(work, w, h, mask, &is_loss);
    let hole: Vec<bool> = (0..w * h).map(|i| mask[i] && (is_loss(work[i]) || suspect[i])).collect();
    let targets: Vec<usize> = (0..w * h).filter(|&i| hole[i]).collect();
    // Bridges are painted after the nearest-class fill below and are not its sources: a
    // bridge as a source would widen its line across the whole hole.
    let mut bridged = hole.clone();
    bridge_lines(work, w, h, mask, &mut bridged);
    const NONE: (i32, i32) = (i32::MIN, i32::MIN);
    let mut src: Vec<(i32, i32)> = (0..w * h)
        .map(|i| {
            let l = work[i];
            if mask[i] && l != MASKED && !hole[i] { ((i % w) as i32, (i / w) as i32) } else { NONE }
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
    for &i in targets.iter().filter(|&&i| bridged[i]) {
        let s = src[i];
        // Sources are never filled, so reading them after earlier fills is still right.
        work[i] = if s == NONE { background } else { work[s.1 as usize * w + s.0 as usize] };
    }
    targets.len()
}

/// Where a short arc of one class meets a hole: its centroid and the direction (unit) from
/// the class's pixels outside the hole towards it.
struct ArcEnd<'a> {
    class: u8,
    at: [f64; 2],
    inward: [f64; 2],
    pixels: &'a [usize],
}

/// The 4 neighbours of pixel `i` (left, right, up, down), `None` outside a `w` x `h` image.
fn neighbours4(i: usize, w: usize, h: usize) -> [Option<usize>; 4] {
    let (x, y) = (i % w, i / w);
    [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)]
}

/// The 8 neighbours of pixel `i` inside a `w` x `h` image.
fn neighbours8(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    (-1i64..=1)
        .flat_map(move |dy| (-1i64..=1).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(nx, ny)| nx >= 0 && ny >= 0 && nx < w as i64 && ny < h as i64 && (nx, ny) != (x, y))
        .map(move |(nx, ny)| ny as usize * w + nx as usize)
}

/// Thin lines across a hole: where a class enters a hole in two short arcs of its rim that
/// face each other along the direction the class runs outside it (a line or a spiral arm
/// crossing a chip), the hole pixels within the arcs' half-width of the segment joining them
/// take that class and stop being hole. A nearest-class fill alone cuts such a line: inside a
/// round chip the line's share of nearest pixels narrows to nothing at the centre, and the
/// contour minimisation then trims the tips. A class that enters in one arc (a line ending at
/// the chip, a band edge) or in long arcs (the surrounding colour) is left to that fill.
fn bridge_lines(work: &mut [u8], w: usize, h: usize, mask: &[bool], hole: &mut [bool]) {
    /// How far (px) beyond an arc the class's own pixels give its direction.
    const REACH: i64 = 6;
    /// The smallest cosine between the joining segment and each arc's inward direction.
    const FACING: f64 = 0.8;
    // Bridging only paints hole pixels, so which pixels are usable does not change.
    let usable: Vec<bool> = (0..w * h).map(|i| mask[i] && work[i] != MASKED).collect();
    let usable = |i: usize| usable[i];
    let around = |i: usize| neighbours8(i, w, h);
    let at = |i: usize| [(i % w) as f64, (i / w) as f64];
    let mut seen = vec![false; w * h];
    let mut ring_seen = vec![u32::MAX; w * h];
    let mut chips = 0u32;
    for start in 0..w * h {
        if !hole[start] || seen[start] {
            continue;
        }
        // The hole (8-connected) and the usable pixels around it.
        let mut chip = vec![start];
        seen[start] = true;
        let mut k = 0;
        let mut ring = Vec::new();
        while k < chip.len() {
            let i = chip[k];
            k += 1;
            for j in around(i) {
                if hole[j] {
                    if !seen[j] {
                        seen[j] = true;
                        chip.push(j);
                    }
                } else if usable(j) && ring_seen[j] != chips {
                    ring_seen[j] = chips;
                    ring.push(j);
                }
            }
        }
        chips += 1;
        // Arcs: runs of one class along the ring (8-connected among ring pixels).
        let on_ring: std::collections::HashSet<usize> = ring.iter().copied().collect();
        let mut arc_of = std::collections::HashMap::new();
        let mut arcs: Vec<(u8, Vec<usize>)> = Vec::new();
        for &r in &ring {
            if arc_of.contains_key(&r) {
                continue;
            }
            let (l, id) = (work[r], arcs.len());
            let mut members = vec![r];
            arc_of.insert(r, id);
            let mut m = 0;
            while m < members.len() {
                let i = members[m];
                m += 1;
                for j in around(i) {
                    if on_ring.contains(&j) && work[j] == l && !arc_of.contains_key(&j) {
                        arc_of.insert(j, id);
                        members.push(j);
                    }
                }
            }
            arcs.push((l, members));
        }
        // Short arcs with the direction their class comes from.
        let centroid = |px: &[usize]| {
            let mut c = [0.0; 2];
            for &i in px {
                let p = at(i);
                c[0] += p[0];
                c[1] += p[1];
            }
            [c[0] / px.len() as f64, c[1] / px.len() as f64]
        };
        let mut ends: Vec<ArcEnd> = Vec::new();
        for (l, members) in &arcs {
            if members.len() * 4 > ring.len() {
                continue;
            }
            let a = centroid(members);
            let (ax, ay) = (a[0].round() as i64, a[1].round() as i64);
            let mut outside = Vec::new();
            for y in (ay - REACH).max(0)..=(ay + REACH).min(h as i64 - 1) {
                for x in (ax - REACH).max(0)..=(ax + REACH).min(w as i64 - 1) {
                    let j = y as usize * w + x as usize;
                    if usable(j) && !hole[j] && work[j] == *l {
                        outside.push(j);
                    }
                }
            }
            let o = centroid(&outside);
            let inward = [a[0] - o[0], a[1] - o[1]];
            let len = inward[0].hypot(inward[1]);
            if len >= 0.5 {
                ends.push(ArcEnd {
                    class: *l,
                    at: a,
                    inward: [inward[0] / len, inward[1] / len],
                    pixels: members,
                });
            }
        }
        // Pair arcs of one class that face each other, best aligned first.
        let mut pairs = Vec::new();
        for (p, e) in ends.iter().enumerate() {
            for (q, f) in ends.iter().enumerate().skip(p + 1) {
                if e.class != f.class {
                    continue;
                }
                let ab = [f.at[0] - e.at[0], f.at[1] - e.at[1]];
                let len = ab[0].hypot(ab[1]);
                if len < 1.0 {
                    continue;
                }
                let u = [ab[0] / len, ab[1] / len];
                let facing =
                    (u[0] * e.inward[0] + u[1] * e.inward[1]).min(-(u[0] * f.inward[0] + u[1] * f.inward[1]));
                if facing > FACING {
                    pairs.push((facing, p, q));
                }
            }
        }
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.1, a.2).cmp(&(b.1, b.2))));
        let mut used = vec![false; ends.len()];
        for (_, p, q) in pairs {
            if used[p] || used[q] {
                continue;
            }
            used[p] = true;
            used[q] = true;
            let (l, a, b) = (ends[p].class, ends[p].at, ends[q].at);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let len2 = ab[0] * ab[0] + ab[1] * ab[1];
            let normal = [-ab[1] / len2.sqrt(), ab[0] / len2.sqrt()];
            // Half the line's width: the arcs' spread across the joining segment.
            let half = [ends[p].pixels, ends[q].pixels]
                .iter()
                .map(|px| {
                    let across = px.iter().map(|&i| {
                        let v = at(i);
                        (v[0] - a[0]) * normal[0] + (v[1] - a[1]) * normal[1]
                    });
                    let (lo, hi) = across.fold((f64::MAX, f64::MIN), |(lo, hi), t| (lo.min(t), hi.max(t)));
                    (hi - lo) * 0.5 + 0.5
                })
                .fold(0.0, f64::max);
            for &i in &chip {
                let v = at(i);
                let t = (((v[0] - a[0]) * ab[0] + (v[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0);
                let off = [v[0] - a[0] - t * ab[0], v[1] - a[1] - t * ab[1]];
                if hole[i] && off[0].hypot(off[1]) <= half {
                    work[i] = l;
                    hole[i] = false;
                }
            }
        }
    }
}

/// How far out from a chip (pixels, Chebyshev) its rim may be untrustworthy: camera pixels
/// that mix clay and paint, blurred by up to a pixel.
const RIM: u32 = 2;

/// Per pixel, whether it lies on the rim of a loss component (within [`RIM`] pixels of it,
/// inside the mask, not loss) with a class that does not continue outwards: no pixel of the
/// same class just beyond the rim (at distance `RIM + 1`, within `RIM` pixels of it), though
/// such pixels exist there. A paint edge or a line that crosses the chip continues beyond the
/// rim; a misclassified mix does not. Each pixel belongs to its nearest loss component
/// (breadth-first from all losses; ties to the first in scan order), so neighbouring chips do
/// not vouch for each other's rims.
fn suspect_rims(work: &[u8], w: usize, h: usize, mask: &[bool], is_loss: &dyn Fn(u8) -> bool) -> Vec<bool> {
    let n = w * h;
    let usable = |i: usize| mask[i] && work[i] != MASKED;
    // Loss components (8-connected) and breadth-first distance from them.
    let mut comp = vec![u32::MAX; n];
    let mut dist = vec![u32::MAX; n];
    let mut queue = std::collections::VecDeque::new();
    let mut count = 0u32;
    let neighbours = |i: usize| neighbours8(i, w, h);
    for start in 0..n {
        if comp[start] != u32::MAX || !usable(start) || !is_loss(work[start]) {
            continue;
        }
        let mut stack = vec![start];
        comp[start] = count;
        while let Some(i) = stack.pop() {
            dist[i] = 0;
            queue.push_back(i);
            for j in neighbours(i) {
                if comp[j] == u32::MAX && usable(j) && is_loss(work[j]) {
                    comp[j] = count;
                    stack.push(j);
                }
            }
        }
        count += 1;
    }
    queue.make_contiguous().sort_unstable();
    while let Some(i) = queue.pop_front() {
        if dist[i] > RIM {
            continue;
        }
        for j in neighbours(i) {
            if dist[j] == u32::MAX && usable(j) {
                dist[j] = dist[i] + 1;
                comp[j] = comp[i];
                queue.push_back(j);
            }
        }
    }
    (0..n)
        .map(|i| {
            if !(1..=RIM).contains(&dist[i]) || is_loss(work[i]) {
                return false;
            }
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let r = RIM as i64;
            let mut beyond = false;
            for ny in (y - r).max(0)..=(y + r).min(h as i64 - 1) {
                for nx in (x - r).max(0)..=(x + r).min(w as i64 - 1) {
                    let j = ny as usize * w + nx as usize;
                    if dist[j] == RIM + 1 && comp[j] == comp[i] {
                        if work[j] == work[i] {
                            return false;
                        }
                        beyond = true;
                    }
                }
            }
            beyond
        })
        .collect()
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
    use proptest::prelude::*;

    /// The labelling as first written (a pixel stack), against which the scanline flood is
    /// checked.
    fn components_by_pixel_flood(
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
                for j in neighbours4(i, w, h) {
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

    /// The sieve as first written: every pass floods every component of the region.
    fn remove_specks_by_full_scans(work: &mut [u8], w: u32, h: u32, mask: &[bool], min_area: usize) -> usize {
        let mut removed = 0;
        let mut count = [0usize; 256];
        for size in 1..min_area {
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
                removed += 1;
            });
        }
        removed
    }

    /// Each component's label, pixels and neighbour labels, sorted, in visiting order.
    type Components = Vec<(u8, Vec<usize>, Vec<Option<u8>>)>;
    /// What a labelling calls for each component.
    type Visit<'a> = &'a mut dyn FnMut(&mut [u8], u8, &[usize], &[Option<u8>]);

    fn collect(
        labelling: fn(&mut [u8], usize, usize, &[bool], Visit),
        labels: &[u8],
        w: usize,
        h: usize,
        mask: &[bool],
    ) -> Components {
        let mut out = Vec::new();
        let mut work = labels.to_vec();
        labelling(&mut work, w, h, mask, &mut |_, l, pixels, around| {
            let (mut p, mut a) = (pixels.to_vec(), around.to_vec());
            p.sort_unstable();
            a.sort_unstable();
            out.push((l, p, a));
        });
        out
    }

    proptest! {
        /// The scanline flood finds the same components, in the same order, with the same
        /// pixels and neighbours as the pixel flood.
        #[test]
        fn the_scanline_flood_matches_the_pixel_flood(
            w in 1usize..40,
            h in 1usize..40,
            seed in any::<u64>(),
            classes in 1u8..4,
        ) {
            let n = w * h;
            let mut state = seed | 1;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let labels: Vec<u8> = (0..n)
                .map(|_| match next() % 24 {
                    0 => MASKED,
                    r => (r % classes as u64) as u8,
                })
                .collect();
            let mask: Vec<bool> = (0..n).map(|_| next() % 10 != 0).collect();
            let fast = collect(|w_, a, b, m, f| for_components(w_, a, b, m, f), &labels, w, h, &mask);
            let slow = collect(|w_, a, b, m, f| components_by_pixel_flood(w_, a, b, m, f), &labels, w, h, &mask);
            prop_assert_eq!(fast, slow);
        }

        /// Flooding only from the pixels of components that start small gives exactly what
        /// flooding the whole region at every pass gives (speckled labels, a partial mask,
        /// masked pixels).
        #[test]
        fn the_sieve_matches_full_scans(
            w in 1u32..24,
            h in 1u32..24,
            seed in any::<u64>(),
            classes in 2u8..5,
            min_area in 1usize..9,
        ) {
            let n = (w * h) as usize;
            let mut state = seed | 1;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let labels: Vec<u8> = (0..n)
                .map(|_| match next() % 16 {
                    0 => MASKED,
                    r => (r % classes as u64) as u8,
                })
                .collect();
            let mask: Vec<bool> = (0..n).map(|_| next() % 8 != 0).collect();
            let (mut fast, mut slow) = (labels.clone(), labels);
            let a = remove_specks(&mut fast, w, h, &mask, min_area);
            let b = remove_specks_by_full_scans(&mut slow, w, h, &mask, min_area);
            prop_assert_eq!(fast, slow);
            prop_assert_eq!(a, b);
        }
    }

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
    fn a_chip_takes_the_surrounding_colour_not_its_misclassified_rim() {
        // Class 1 paint with a 3x3 chip (9); the chip's rim pixels on its left were
        // classified as class 3 (mixed clay and paint read as a dark paint) that is nowhere
        // else; a class-2 line crosses the chip from top to bottom.
        let (w, h) = (15usize, 11usize);
        let mut l = vec![1u8; w * h];
        for y in 4..7 {
            for x in 6..9 {
                l[y * w + x] = 9;
            }
            l[y * w + 5] = 3;
        }
        for y in 0..h {
            if l[y * w + 7] != 9 {
                l[y * w + 7] = 2;
            }
        }
        let mask = vec![true; w * h];
        let filled = fill_losses(&mut l, w as u32, h as u32, &mask, &[9], 0);
        assert_eq!(filled, 9 + 3, "the chip and its three suspect rim pixels");
        for y in 4..7 {
            assert_eq!(l[y * w + 5], 1, "rim pixel ({}, {y}) takes the surrounding paint", 5);
            assert_eq!(l[y * w + 7], 2, "the line continues through the chip");
            assert_eq!(l[y * w + 6], 1);
        }
        assert!(!l.contains(&3), "the rim's class is gone");
    }

    /// A 40x40 field of class 0 with a chip (loss 9) of radius 8 at (20, 20), crossed by a
    /// line of class 1 drawn by `on_line`; returns the labels after the loss fill.
    fn chip_across(on_line: impl Fn(f64, f64) -> bool) -> Vec<u8> {
        let (w, h) = (40usize, 40usize);
        let mut l: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                if (x - 20.0).hypot(y - 20.0) <= 8.0 {
                    9
                } else if on_line(x, y) {
                    1
                } else {
                    0
                }
            })
            .collect();
        let mask = vec![true; w * h];
        fill_losses(&mut l, w as u32, h as u32, &mask, &[9], 0);
        assert!(!l.contains(&9));
        l
    }

    #[test]
    fn a_line_across_a_chip_stays_whole() {
        // Horizontal, 3 px wide: every column through the chip keeps the line's three rows.
        let l = chip_across(|_, y| (19.0..=21.0).contains(&y));
        for x in 10..31 {
            for y in 19..=21 {
                assert_eq!(l[y * 40 + x], 1, "({x}, {y})");
            }
            assert_eq!(l[16 * 40 + x], 0, "({x}, 16) above the line");
            assert_eq!(l[24 * 40 + x], 0, "({x}, 24) below the line");
        }
        // Diagonal, about 3 px wide: the line runs unbroken along the diagonal.
        let l = chip_across(|x, y| (x - y).abs() <= 1.5);
        for t in 8..33 {
            assert_eq!(l[t * 40 + t], 1, "({t}, {t}) on the diagonal");
        }
        assert_eq!(l[14 * 40 + 26], 0, "off the diagonal inside the chip");
    }

    #[test]
    fn a_line_that_ends_at_a_chip_is_not_extended() {
        let l = chip_across(|x, y| x < 20.0 && (19.0..=21.0).contains(&y));
        // The nearest-class fill carries the line a little way in; it does not cross.
        for x in 24..29 {
            assert_eq!(l[20 * 40 + x], 0, "({x}, 20)");
        }
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
