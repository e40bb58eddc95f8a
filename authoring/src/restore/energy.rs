//! The energy minimisation of §4.2 on the contours of one cell: Laplacian proposals (Eq. 3),
//! `e = kappa * R * B` (turning-angle curvature, Eq. 5, Eq. 6), a priority queue on e with
//! neighbour updates, stop when every e <= alpha; then the contours are rasterised back.

use std::cmp::Reverse;

use super::contour::{Patch, trace_patches};
use super::raster::fill_even_odd;
use super::{ClassInfo, MASKED, RestoreParams, RestoreStats};

const NONE: u32 = u32::MAX;

/// Candidates whose line of sight is tested, nearest first, before a point is left unpaired.
const MAX_TESTS: usize = 12;

/// Where the spacing agrees with d* within this many px both before and after a move, R is
/// 1 (Eq. 5 with a dead band): distances between pixel contours carry half a pixel of
/// quantisation, and without the band every flat stretch (d = d*) would see any move as
/// "away from d*" and freeze at R = 1/beta.
pub(crate) const SPACING_DEAD_BAND: f64 = 0.5;

/// One cell's pixels, as local row-major buffers of `w` x `h`.
pub(crate) struct Cell<'a> {
    /// Current labels (after hints and earlier cells).
    pub labels: &'a [u8],
    /// The original classification, standing for the physical object (for B).
    pub original: &'a [u8],
    /// Pixels that may change (inside the region and not masked).
    pub active: &'a [bool],
    pub w: usize,
    pub h: usize,
    pub background: u8,
}

struct ContourInfo {
    patch: usize,
    first: usize,
    len: usize,
    alive: usize,
    outer: bool,
}

/// All contour points of a cell with stable ids; removal unlinks a point and leaves `fwd`
/// pointing to its successor so pairings made on the original contours stay valid.
pub(crate) struct Arena {
    pos: Vec<[f64; 2]>,
    /// Where each point started (for the displacement cap).
    origin: Vec<[f64; 2]>,
    prev: Vec<u32>,
    next: Vec<u32>,
    contour: Vec<u32>,
    alive: Vec<bool>,
    anchor: Vec<bool>,
    fwd: Vec<u32>,
    /// Paired point on a neighbouring contour (R), or NONE.
    q: Vec<u32>,
    /// Smoothed spacing d* (px).
    dstar: Vec<f64>,
    /// Reverse pairing, CSR: points whose `q` is this point.
    rev_start: Vec<u32>,
    rev: Vec<u32>,
    contours: Vec<ContourInfo>,
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}
fn norm(a: [f64; 2]) -> f64 {
    // Not hypot: it was a fifth of the run time, and pixel-scale values cannot overflow.
    (a[0] * a[0] + a[1] * a[1]).sqrt()
}
fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    norm(sub(a, b))
}

impl Arena {
    /// Builds the arena from traced patches; a point is an anchor when any pixel touching it
    /// is outside the cell or inactive (cell borders, region borders, masked pixels).
    fn new(patches: &[Patch], active: &[bool], w: usize, h: usize) -> Self {
        let total: usize = patches.iter().flat_map(|p| &p.contours).map(|c| c.points.len()).sum();
        let mut a = Arena {
            pos: Vec::with_capacity(total),
            origin: Vec::new(),
            prev: Vec::with_capacity(total),
            next: Vec::with_capacity(total),
            contour: Vec::with_capacity(total),
            alive: vec![true; total],
            anchor: Vec::with_capacity(total),
            fwd: vec![NONE; total],
            q: vec![NONE; total],
            dstar: vec![0.0; total],
            rev_start: Vec::new(),
            rev: Vec::new(),
            contours: Vec::new(),
        };
        let inside = |x: i64, y: i64| x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h;
        for (pi, p) in patches.iter().enumerate() {
            for c in &p.contours {
                let first = a.pos.len();
                let n = c.points.len();
                let ci = a.contours.len() as u32;
                for (k, pt) in c.points.iter().enumerate() {
                    a.pos.push([pt[0] as f64, pt[1] as f64]);
                    a.prev.push((first + (k + n - 1) % n) as u32);
                    a.next.push((first + (k + 1) % n) as u32);
                    a.contour.push(ci);
                    let (x, y) = (pt[0] as i64, pt[1] as i64);
                    let anchored = [(x - 1, y - 1), (x, y - 1), (x - 1, y), (x, y)]
                        .iter()
                        .any(|&(px, py)| !inside(px, py) || !active[py as usize * w + px as usize]);
                    a.anchor.push(anchored);
                }
                a.contours.push(ContourInfo {
                    patch: pi,
                    first,
                    len: n,
                    alive: n,
                    outer: c.signed_area() > 0,
                });
            }
        }
        // Points move from the lattice corners to the midpoints of the pixel sides: the
        // polygon through the midpoints encloses exactly the same pixel centres (it only cuts
        // and adds corner triangles that hold none), but it lies on a digital straight edge's
        // own line and much closer to a digitised curve, so the minimisation starts from the
        // edge the pixels stand for rather than from the staircase. A midpoint is an anchor
        // when either end of its side is.
        for c in &a.contours {
            let (first, n) = (c.first, c.len);
            let pos: Vec<[f64; 2]> = (0..n)
                .map(|k| {
                    let (p, q) = (a.pos[first + k], a.pos[first + (k + 1) % n]);
                    [(p[0] + q[0]) * 0.5, (p[1] + q[1]) * 0.5]
                })
                .collect();
            let anchor: Vec<bool> =
                (0..n).map(|k| a.anchor[first + k] || a.anchor[first + (k + 1) % n]).collect();
            a.pos[first..first + n].copy_from_slice(&pos);
            a.anchor[first..first + n].copy_from_slice(&anchor);
        }
        a.origin = a.pos.clone();
        a
    }

    /// The live point standing for point `j` (its successor if removed), if any is left.
    fn resolve(&self, mut j: u32) -> Option<usize> {
        while !self.alive[j as usize] {
            j = self.fwd[j as usize];
            if j == NONE {
                return None;
            }
        }
        Some(j as usize)
    }

    /// Pairs every point with the closest point on a neighbouring contour that it sees along
    /// a raster line on the original (lattice) contours, then smooths those distances.
    fn pair(&mut self, w: usize, h: usize, params: &RestoreParams) {
        let n = self.pos.len();
        let lw = w + 1;
        let occ = self.occupancy(lw, h);
        // Buckets of lattice points (4 x 4), searched ring by ring around each point.
        const B: usize = 4;
        let (nbx, nby) = (lw.div_ceil(B), (h + 1).div_ceil(B));
        let mut start = vec![0u32; nbx * nby + 1];
        let bucket_of = |p: [f64; 2]| (p[1] as usize / B) * nbx + p[0] as usize / B;
        for i in 0..n {
            start[bucket_of(self.pos[i]) + 1] += 1;
        }
        for k in 0..nbx * nby {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        // Each member carries its contour and position, so the search reads buckets in order
        // instead of gathering from the point arrays.
        let mut members = vec![(0u32, 0u32, [0.0; 2]); n];
        for i in 0..n {
            let b = bucket_of(self.pos[i]);
            members[fill[b] as usize] = (i as u32, self.contour[i], self.pos[i]);
            fill[b] += 1;
        }
        let reach = params.reach_px.max(0.0);
        let reach2 = reach * reach;
        let rings = (reach / B as f64).ceil() as isize + 1;
        let nb = params.neighbours as f64;
        let mut d = vec![f64::NAN; n];
        // Candidates found so far and not yet examined, unordered: each examination takes
        // the nearest (ties: lower index) by one scan. Most points examine one or two, so
        // keeping the candidates ordered as they arrive (a heap, then a sorted list) was most
        // of the step's time.
        let mut pending: Vec<(u64, u32)> = Vec::new();
        #[allow(clippy::needless_range_loop)] // i names the point in several arrays
        for i in 0..n {
            let p = self.pos[i];
            let (px, py) = (p[0] as i32, p[1] as i32);
            let (bx, by) = ((px as usize / B) as isize, (py as usize / B) as isize);
            let ci = self.contour[i] as usize;
            let mut tests = 0;
            pending.clear();
            'rings: for r in 0..=rings {
                for y in by - r..=by + r {
                    for x in bx - r..=bx + r {
                        let on_ring = (y - by).abs() == r || (x - bx).abs() == r;
                        if !on_ring || x < 0 || y < 0 || x >= nbx as isize || y >= nby as isize {
                            continue;
                        }
                        let k = y as usize * nbx + x as usize;
                        for &(j, cj, pj) in &members[start[k] as usize..start[k + 1] as usize] {
                            if j as usize == i {
                                continue;
                            }
                            // Squared distances until a pair is found: the points sit on
                            // the half-pixel lattice here, so squares are exact and order
                            // (and tie) exactly as the distances do.
                            let e = sub(p, pj);
                            let dd2 = e[0] * e[0] + e[1] * e[1];
                            if dd2 > reach2 {
                                continue;
                            }
                            if cj as usize == ci && self.near_along(i, j as usize, e, dd2, nb) {
                                continue;
                            }
                            // Non-negative, so their bits order like them.
                            pending.push((dd2.to_bits(), j));
                        }
                    }
                }
                // Every point not yet scanned lies beyond a side of the scanned square of
                // buckets that still has buckets behind it; the nearest such side bounds
                // their distance from below (and past `rings`, beyond reach). A point may sit
                // on that bound, so only candidates strictly nearer are examined: an equally
                // near one with a lower index may still be found.
                let bound = if r == rings {
                    f64::INFINITY
                } else {
                    let side = |lo: isize, hi: isize, at: f64, count: usize| {
                        let low = if lo > 0 { at - (lo as usize * B) as f64 } else { f64::INFINITY };
                        let high = if hi + 1 < count as isize {
                            ((hi + 1) as usize * B) as f64 - at
                        } else {
                            f64::INFINITY
                        };
                        low.min(high)
                    };
                    side(bx - r, bx + r, p[0], nbx).min(side(by - r, by + r, p[1], nby))
                };
                while let Some((slot, &(bits, j))) = pending.iter().enumerate().min_by_key(|e| e.1) {
                    let dd2 = f64::from_bits(bits);
                    if dd2 >= bound * bound {
                        break;
                    }
                    pending.swap_remove(slot);
                    let q = self.pos[j as usize];
                    if visible(&occ, lw, (px, py), (q[0] as i32, q[1] as i32)) {
                        self.q[i] = j;
                        d[i] = dd2.sqrt();
                        break 'rings;
                    }
                    tests += 1;
                    if tests >= MAX_TESTS {
                        break 'rings;
                    }
                }
                if bound == f64::INFINITY {
                    break;
                }
            }
        }
        self.smooth_spacing(&d, params);
        self.index_pairs();
    }

    /// Which contour points sit on each lattice point (up to four), for lines of sight.
    fn occupancy(&self, lw: usize, h: usize) -> Vec<[u32; 4]> {
        let mut occ = vec![[NONE; 4]; lw * (h + 1)];
        for (i, p) in self.pos.iter().enumerate() {
            let slot = &mut occ[p[1] as usize * lw + p[0] as usize];
            if let Some(s) = slot.iter_mut().find(|s| **s == NONE) {
                *s = i as u32;
            }
        }
        occ
    }

    /// Whether point `j`, on the same contour as point `i` and `e = pos[i] - pos[j]` away
    /// (`dd2` its square length), lies in `i`'s own neighbourhood along the contour: the same
    /// contour counts only far along it (the other side of a stripe or a dot).
    fn near_along(&self, i: usize, j: usize, e: [f64; 2], dd2: f64, nb: f64) -> bool {
        let info = &self.contours[self.contour[i] as usize];
        let k = (j - info.first).abs_diff(i - info.first);
        let sep = k.min(info.len - k) as f64;
        // The larger coordinate difference bounds the distance from below: most of the
        // point's own neighbourhood is dropped without a square root.
        let near = 2.0 * nb + 2.0;
        sep <= 1.5 * e[0].abs().max(e[1].abs()) + near || sep <= 1.5 * dd2.sqrt() + near
    }

    /// d*: Gaussian-weighted median of the paired distances `d` along each contour, over the
    /// points paired with the same neighbouring contour. A weighted median rather than the
    /// paper's weighted mean, so that a chip or a bump (which pulls a few distances far off)
    /// does not leak into the spacing the others are held to.
    fn smooth_spacing(&mut self, d: &[f64], params: &RestoreParams) {
        let win = params.spacing_window;
        let sigma = (win as f64 / 2.0).max(0.5);
        let weights: Vec<f64> =
            (0..=win).map(|k| (-(k as f64).powi(2) / (2.0 * sigma * sigma)).exp()).collect();
        // The window slides along the contour one point at a time, so its paired distances
        // are kept sorted (distance, then position) and updated by one removal and one
        // insertion per step rather than sorted afresh at every point.
        let mut sorted: Vec<(f64, usize)> = Vec::new();
        // The contour each point is paired with (NONE: unpaired), by position on the contour.
        let mut partner: Vec<u32> = Vec::new();
        for c in &self.contours {
            let (len, first) = (c.len, c.first);
            let half = win.min((len - 1) / 2);
            partner.clear();
            partner.extend(
                self.q[first..first + len]
                    .iter()
                    .map(|&q| if q == NONE { NONE } else { self.contour[q as usize] }),
            );
            let wrap = |j: usize| if j >= len { j - len } else { j };
            let key = |pos: usize| (d[first + pos], pos);
            let before = |a: (f64, usize), b: (f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
            sorted.clear();
            sorted.extend((0..=half).chain(len - half..len).map(key).filter(|e| !e.0.is_nan()));
            sorted.sort_unstable_by(|&a, &b| before(a, b));
            for k in 0..len {
                if k > 0 {
                    for (pos, add) in [((k - 1 + len - half) % len, false), ((k + half) % len, true)] {
                        let e = key(pos);
                        if e.0.is_nan() {
                            continue;
                        }
                        let at = sorted.partition_point(|&x| before(x, e).is_lt());
                        if add {
                            sorted.insert(at, e);
                        } else {
                            sorted.remove(at);
                        }
                    }
                }
                let i = first + k;
                // Only spacings to the same neighbouring contour are combined.
                let p = partner[k];
                if p == NONE {
                    continue;
                }
                let mut total = weights[0];
                for (o, &wo) in weights.iter().enumerate().take(half + 1).skip(1) {
                    for j in [wrap(k + o), wrap(k + len - o)] {
                        if partner[j] == p {
                            total += wo;
                        }
                    }
                }
                let mut acc = 0.0;
                let mut med = d[i];
                for &(dj, pos) in sorted.iter().filter(|e| partner[e.1] == p) {
                    let off = pos.abs_diff(k);
                    acc += weights[off.min(len - off)];
                    med = dj;
                    if acc >= 0.5 * total {
                        break;
                    }
                }
                self.dstar[i] = med;
            }
        }
    }

    /// The reverse pairing (`rev_start`, `rev`): which points are paired with each point.
    fn index_pairs(&mut self) {
        let n = self.pos.len();
        let mut count = vec![0u32; n + 1];
        for &j in &self.q {
            if j != NONE {
                count[j as usize + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        self.rev = vec![0; count[n] as usize];
        let mut fill = count.clone();
        for (i, &j) in self.q.iter().enumerate() {
            if j != NONE {
                self.rev[fill[j as usize] as usize] = i as u32;
                fill[j as usize] += 1;
            }
        }
        self.rev_start = count;
    }

    /// Curvature at point i: turning angle between the chords over `nb` segments before and
    /// after it (the length-weighted mean of their normals), over half their total length,
    /// times `scale`.
    fn kappa(&self, i: usize, nb: usize, scale: f64) -> f64 {
        let c = &self.contours[self.contour[i] as usize];
        let n = nb.min((c.alive - 1) / 2);
        if n == 0 {
            return 0.0;
        }
        let p = self.pos[i];
        let (mut cur, mut lb) = (i, 0.0);
        for _ in 0..n {
            let pr = self.prev[cur] as usize;
            lb += dist(self.pos[cur], self.pos[pr]);
            cur = pr;
        }
        let before = sub(p, self.pos[cur]);
        let (mut cur, mut la) = (i, 0.0);
        for _ in 0..n {
            let nx = self.next[cur] as usize;
            la += dist(self.pos[nx], self.pos[cur]);
            cur = nx;
        }
        let after = sub(self.pos[cur], p);
        let cross = before[0] * after[1] - before[1] * after[0];
        let dot = before[0] * after[0] + before[1] * after[1];
        let len = 0.5 * (lb + la);
        if len <= 0.0 {
            return 0.0;
        }
        scale * cross.abs().atan2(dot) / len
    }

    fn energy(
        &self,
        i: usize,
        cell: &Cell,
        patches: &[Patch],
        classes: &ClassInfo,
        params: &RestoreParams,
    ) -> f64 {
        if !self.alive[i] || self.anchor[i] {
            return 0.0;
        }
        let (a, b) = (self.prev[i] as usize, self.next[i] as usize);
        let p = self.pos[i];
        let ph = [(self.pos[a][0] + self.pos[b][0]) * 0.5, (self.pos[a][1] + self.pos[b][1]) * 0.5];
        // A proposal that barely moves the point cannot lower anything: its neighbours must
        // move first (and recompute this point's energy when they do).
        if dist(p, ph) < 1e-3 {
            return 0.0;
        }
        // No point wanders further than max_shift_px from where it started: Laplacian flow
        // otherwise eats thin stripes from their ends and shrinks small dots to nothing.
        if dist(ph, self.origin[i]) > params.max_shift_px {
            return 0.0;
        }
        let kappa = self.kappa(i, params.neighbours, params.scale_px);
        if kappa <= 0.0 {
            return 0.0;
        }
        let q = if self.q[i] == NONE { None } else { self.resolve(self.q[i]) };
        let r = if let Some(q) = q {
            let qp = self.pos[q];
            let ds = self.dstar[i];
            let dev = (dist(p, qp) - ds).abs();
            let devh = (dist(ph, qp) - ds).abs();
            if dev <= SPACING_DEAD_BAND && devh <= SPACING_DEAD_BAND {
                1.0
            } else if dev < devh {
                1.0 / (params.beta * (1.0 + dev))
            } else {
                params.beta * (1.0 + dev)
            }
        } else {
            1.0
        };
        let b_term = match params.gamma {
            None => 1.0,
            Some(gamma) => {
                let t = sub(self.pos[b], self.pos[a]);
                let tl = norm(t).max(1e-12);
                let nrm = [t[1] / tl, -t[0] / tl];
                let m = sub(ph, p);
                let grow = m[0] * nrm[0] + m[1] * nrm[1] > 0.0;
                let s = if grow { 0.25 } else { -0.25 };
                let at = [(p[0] + ph[0]) * 0.5 + s * nrm[0], (p[1] + ph[1]) * 0.5 + s * nrm[1]];
                let (x, y) = (at[0].floor(), at[1].floor());
                if x < 0.0 || y < 0.0 || x as usize >= cell.w || y as usize >= cell.h {
                    1.0
                } else {
                    let idx = y as usize * cell.w + x as usize;
                    let old = cell.original[idx];
                    let label = patches[self.contours[self.contour[i] as usize].patch].label;
                    let new = if grow { label } else { cell.background };
                    if old == MASKED || !cell.active[idx] {
                        1.0
                    } else if classes.luminance[new as usize] > classes.luminance[old as usize] + gamma {
                        0.0
                    } else {
                        1.0
                    }
                }
            }
        };
        kappa * r * b_term
    }
}

/// Whether the raster (Bresenham) line between two lattice points crosses no contour point
/// other than its ends.
fn visible(occ: &[[u32; 4]], lw: usize, a: (i32, i32), b: (i32, i32)) -> bool {
    let (mut x, mut y) = a;
    let dx = (b.0 - a.0).abs();
    let dy = -(b.1 - a.1).abs();
    let sx = if a.0 < b.0 { 1 } else { -1 };
    let sy = if a.1 < b.1 { 1 } else { -1 };
    let mut err = dx + dy;
    loop {
        if (x, y) == b {
            return true;
        }
        if (x, y) != a && occ[y as usize * lw + x as usize][0] != NONE {
            return false;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}

/// The points whose energy exceeds alpha, highest energy first (ties: lower index first),
/// with each point's energy updated in place when a move changes it: a heap of stale entries
/// grew ten entries per move and its pops were a tenth of the step's time.
struct EnergyQueue {
    heap: Vec<u32>,
    /// Where each point sits in `heap` (`NONE` when absent).
    at: Vec<u32>,
    /// Each point's energy as bits (non-negative, so the bits order like the values).
    key: Vec<u64>,
}

impl EnergyQueue {
    fn new(n: usize) -> Self {
        Self { heap: Vec::with_capacity(n), at: vec![NONE; n], key: vec![0; n] }
    }

    /// Whether point `a` comes out before point `b`.
    fn above(&self, a: u32, b: u32) -> bool {
        (self.key[a as usize], Reverse(a)) > (self.key[b as usize], Reverse(b))
    }

    /// Sets point `i`'s energy: queued while above `alpha`, dropped otherwise.
    fn set(&mut self, i: usize, energy: f64, alpha: f64) {
        let slot = self.at[i];
        if energy.is_nan() || energy <= alpha {
            if slot != NONE {
                self.remove(slot as usize);
            }
            return;
        }
        self.key[i] = energy.to_bits();
        if slot == NONE {
            self.heap.push(i as u32);
            let s = self.heap.len() - 1;
            self.at[i] = s as u32;
            self.up(s);
        } else {
            let s = self.up(slot as usize);
            self.down(s);
        }
    }

    fn pop(&mut self) -> Option<usize> {
        let top = *self.heap.first()?;
        self.remove(0);
        Some(top as usize)
    }

    fn remove(&mut self, s: usize) {
        let gone = self.heap.swap_remove(s);
        self.at[gone as usize] = NONE;
        if s < self.heap.len() {
            self.at[self.heap[s] as usize] = s as u32;
            let s = self.up(s);
            self.down(s);
        }
    }

    fn up(&mut self, mut s: usize) -> usize {
        while s > 0 {
            let parent = (s - 1) / 2;
            if !self.above(self.heap[s], self.heap[parent]) {
                break;
            }
            self.swap(s, parent);
            s = parent;
        }
        s
    }

    fn down(&mut self, mut s: usize) {
        loop {
            let (l, r) = (2 * s + 1, 2 * s + 2);
            let mut best = s;
            if l < self.heap.len() && self.above(self.heap[l], self.heap[best]) {
                best = l;
            }
            if r < self.heap.len() && self.above(self.heap[r], self.heap[best]) {
                best = r;
            }
            if best == s {
                return;
            }
            self.swap(s, best);
            s = best;
        }
    }

    fn swap(&mut self, a: usize, b: usize) {
        self.heap.swap(a, b);
        self.at[self.heap[a] as usize] = a as u32;
        self.at[self.heap[b] as usize] = b as u32;
    }
}

/// What one cell produced: its new labels (local buffer) and counts.
pub(crate) struct CellResult {
    pub labels: Vec<u8>,
    pub stats: RestoreStats,
}

/// Minimises one cell and rasterises its contours back over the background.
pub(crate) fn restore_cell(cell: &Cell, classes: &ClassInfo, params: &RestoreParams) -> CellResult {
    let (ar, patches, stats) = minimise(cell, classes, params);
    let labels = rasterise(cell, &ar, &patches);
    CellResult { labels, stats }
}

/// Traces the cell's patches and runs the priority-queue minimisation on their contours.
fn minimise(cell: &Cell, classes: &ClassInfo, params: &RestoreParams) -> (Arena, Vec<Patch>, RestoreStats) {
    let (w, h) = (cell.w, cell.h);
    let patches = trace_patches(cell.labels, cell.active, w, h, cell.background);
    let mut ar = Arena::new(&patches, cell.active, w, h);
    ar.pair(w, h, params);
    let n = ar.pos.len();
    let mut stats = RestoreStats {
        cells: 1,
        contours: ar.contours.len(),
        points: n,
        anchors: ar.anchor.iter().filter(|&&a| a).count(),
        ..Default::default()
    };
    let energy = |ar: &Arena, i: usize| ar.energy(i, cell, &patches, classes, params);
    let mut heap = EnergyQueue::new(n);
    for i in 0..n {
        heap.set(i, energy(&ar, i), params.alpha);
    }
    let cap = params.max_moves_per_point.saturating_mul(n);
    let mut touched = Vec::new();
    while let Some(i) = heap.pop() {
        if !ar.alive[i] {
            continue;
        }
        if stats.moves >= cap {
            stats.capped_cells = 1;
            break;
        }
        let (a, b) = (ar.prev[i] as usize, ar.next[i] as usize);
        ar.pos[i] = [(ar.pos[a][0] + ar.pos[b][0]) * 0.5, (ar.pos[a][1] + ar.pos[b][1]) * 0.5];
        stats.moves += 1;
        // Points that came too close to a neighbour are dropped (§4.2, 0.2 px).
        let ci = ar.contour[i] as usize;
        if dist(ar.pos[i], ar.pos[a]) < params.min_spacing_px
            || dist(ar.pos[i], ar.pos[b]) < params.min_spacing_px
        {
            ar.alive[i] = false;
            ar.fwd[i] = b as u32;
            ar.next[a] = b as u32;
            ar.prev[b] = a as u32;
            ar.contours[ci].alive -= 1;
            stats.removed_points += 1;
            if ar.contours[ci].alive < 3 {
                // The contour collapsed: the patch part it bounded disappears.
                let mut j = a;
                for _ in 0..ar.contours[ci].alive {
                    let nx = ar.next[j] as usize;
                    ar.alive[j] = false;
                    ar.fwd[j] = NONE;
                    j = nx;
                }
                ar.contours[ci].alive = 0;
            }
        }
        // Recompute the energies that depend on the moved point.
        touched.clear();
        touched.push(i);
        if ar.contours[ci].alive > 0 {
            let reach = params.neighbours + 1;
            let (mut l, mut r) = (a, b);
            for _ in 0..reach {
                touched.push(l);
                touched.push(r);
                l = ar.prev[l] as usize;
                r = ar.next[r] as usize;
            }
        }
        for k in ar.rev_start[i]..ar.rev_start[i + 1] {
            touched.push(ar.rev[k as usize] as usize);
        }
        for &k in &touched {
            heap.set(k, energy(&ar, k), params.alpha);
        }
    }
    (ar, patches, stats)
}

/// The cell's active pixels become background, then patches are drawn largest first so
/// that smaller ones (dots, islands) stay on top; a pixel takes the class of the last patch
/// whose contours hold its centre.
fn rasterise(cell: &Cell, ar: &Arena, patches: &[Patch]) -> Vec<u8> {
    let (w, h) = (cell.w, cell.h);
    let mut by_patch: Vec<Vec<usize>> = vec![Vec::new(); patches.len()];
    for (ci, c) in ar.contours.iter().enumerate() {
        if c.alive >= 3 {
            by_patch[c.patch].push(ci);
        }
    }
    let mut order: Vec<usize> = (0..patches.len()).collect();
    order.sort_by_key(|&p| (Reverse(patches[p].area), p));
    let drawn: Vec<(u8, Vec<Vec<[f64; 2]>>)> = order
        .into_iter()
        .filter(|&p| by_patch[p].iter().any(|&ci| ar.contours[ci].outer))
        .map(|p| {
            let polys = by_patch[p]
                .iter()
                .map(|&ci| {
                    let c = &ar.contours[ci];
                    let start = ar.resolve_any(c.first, c.len);
                    let mut pts = Vec::with_capacity(c.alive);
                    let mut j = start;
                    for _ in 0..c.alive {
                        pts.push(ar.pos[j]);
                        j = ar.next[j] as usize;
                    }
                    pts
                })
                .collect();
            (patches[p].label, polys)
        })
        .collect();
    let mut out = cell.labels.to_vec();
    for (o, &a) in out.iter_mut().zip(cell.active) {
        if a {
            *o = cell.background;
        }
    }
    for (label, polys) in &drawn {
        let refs: Vec<&[[f64; 2]]> = polys.iter().map(|p| p.as_slice()).collect();
        fill_even_odd(&refs, w, h, |x, y| {
            let idx = y * w + x;
            if cell.active[idx] {
                out[idx] = *label;
            }
        });
    }
    out
}

impl Arena {
    /// Some live point of a contour with points `first..first + len`.
    fn resolve_any(&self, first: usize, len: usize) -> usize {
        (first..first + len).find(|&j| self.alive[j]).expect("a live contour has a live point")
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn the_energy_queue_pops_highest_first_with_updates() {
        // Against a plain scan of the live energies, over a seeded mix of sets and pops.
        let n = 50;
        let mut q = EnergyQueue::new(n);
        let mut live: Vec<Option<f64>> = vec![None; n];
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for step in 0..5000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            if step % 3 == 2 {
                let want = (0..n)
                    .filter(|&i| live[i].is_some())
                    .max_by(|&a, &b| live[a].unwrap().total_cmp(&live[b].unwrap()).then(b.cmp(&a)));
                assert_eq!(q.pop(), want);
                if let Some(i) = want {
                    live[i] = None;
                }
            } else {
                let i = (state % n as u64) as usize;
                // Few distinct values, so that ties are common.
                let e = ((state >> 8) % 8) as f64 * 0.5;
                q.set(i, e, 1.0);
                live[i] = (e > 1.0).then_some(e);
            }
        }
    }

    #[test]
    fn anchors_never_move() {
        // A noisy band crossing the cell, with a masked block inside: anchors sit on the cell
        // border and around the masked pixels.
        let (w, h) = (48, 40);
        let mut l = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let top = 12 + (x * 7 % 5) / 2;
                if y >= top && y < 28 - (x * 3 % 4) / 2 {
                    l[y * w + x] = 1;
                }
            }
        }
        let mut active = vec![true; w * h];
        for y in 20..26 {
            for x in 20..26 {
                active[y * w + x] = false;
            }
        }
        let cell = Cell { labels: &l, original: &l, active: &active, w, h, background: 0 };
        let classes = ClassInfo { luminance: vec![0.5; 2] };
        let p = RestoreParams::default();
        let before = Arena::new(&trace_patches(&l, &active, w, h, 0), &active, w, h);
        let (after, _, stats) = minimise(&cell, &classes, &p);
        let anchors: Vec<usize> = (0..before.pos.len()).filter(|&i| before.anchor[i]).collect();
        assert!(anchors.len() > 20 && stats.moves > 0);
        for i in anchors {
            assert!(after.alive[i], "anchor {i} removed");
            assert_eq!(after.pos[i], before.pos[i], "anchor {i} moved");
        }
        let moved =
            (0..before.pos.len()).filter(|&i| !after.alive[i] || after.pos[i] != before.pos[i]).count();
        assert!(moved > 0);
    }

    #[test]
    fn pairing_finds_what_a_search_of_every_point_finds() {
        // The bucketed ring search against the rule itself: every other point within reach
        // (not in the point's own neighbourhood along its contour), nearest first, ties to
        // the lower index; the first of the first MAX_TESTS in sight is the pair.
        let params = RestoreParams::default();
        let nb = params.neighbours as f64;
        let mut paired = 0;
        for seed in 1..=6 {
            let (w, h) = (150 + 7 * seed as u32, 120 - 3 * seed as u32);
            let scene = crate::restore::synthetic::damaged_pattern(w, h, 14.0, seed);
            let (w, h) = (w as usize, h as usize);
            let active = vec![true; w * h];
            let mut ar = Arena::new(&trace_patches(&scene.damaged.data, &active, w, h, 0), &active, w, h);
            ar.pair(w, h, &params);
            let occ = ar.occupancy(w + 1, h);
            let reach2 = params.reach_px * params.reach_px;
            for i in 0..ar.pos.len() {
                let p = ar.pos[i];
                let mut candidates: Vec<(u64, usize)> = (0..ar.pos.len())
                    .filter(|&j| j != i)
                    .filter_map(|j| {
                        let e = sub(p, ar.pos[j]);
                        let dd2 = e[0] * e[0] + e[1] * e[1];
                        let own = ar.contour[j] == ar.contour[i] && ar.near_along(i, j, e, dd2, nb);
                        (dd2 <= reach2 && !own).then_some((dd2.to_bits(), j))
                    })
                    .collect();
                candidates.sort_unstable();
                let want = candidates.iter().take(MAX_TESTS).find(|&&(_, j)| {
                    let q = ar.pos[j];
                    visible(&occ, w + 1, (p[0] as i32, p[1] as i32), (q[0] as i32, q[1] as i32))
                });
                let got = (ar.q[i] != NONE).then_some(ar.q[i] as usize);
                assert_eq!(got, want.map(|&(_, j)| j), "seed {seed}, point {i} at {p:?}");
                paired += usize::from(got.is_some());
            }
        }
        assert!(paired > 1000, "{paired}");
    }

    /// Runs one cell on a whole buffer.
    pub(crate) fn run(labels: &[u8], w: usize, h: usize, bg: u8, params: &RestoreParams) -> CellResult {
        let active = vec![true; w * h];
        let cell = Cell { labels, original: labels, active: &active, w, h, background: bg };
        let classes = ClassInfo { luminance: vec![0.5; 8] };
        restore_cell(&cell, &classes, params)
    }

    #[test]
    fn unmoved_contours_reproduce_the_labels() {
        let (w, h) = (24, 20);
        let mut l = vec![0u8; w * h];
        for y in 3..15 {
            for x in 2..20 {
                l[y * w + x] = if (x + y) % 7 == 0 { 2 } else { 1 };
            }
        }
        let p = RestoreParams { alpha: 1e9, ..Default::default() };
        assert_eq!(run(&l, w, h, 0, &p).labels, l);
    }

    #[test]
    fn kappa_of_a_circle_is_scale_over_radius() {
        let r = 40.0;
        let pts: Vec<[f64; 2]> = (0..400)
            .map(|k| (k as f64) * std::f64::consts::TAU / 400.0)
            .map(|t| [r * t.cos(), r * t.sin()])
            .collect();
        let n = pts.len();
        let ar = Arena {
            origin: pts.clone(),
            pos: pts,
            prev: (0..n).map(|k| ((k + n - 1) % n) as u32).collect(),
            next: (0..n).map(|k| ((k + 1) % n) as u32).collect(),
            contour: vec![0; n],
            alive: vec![true; n],
            anchor: vec![false; n],
            fwd: vec![NONE; n],
            q: vec![NONE; n],
            dstar: vec![0.0; n],
            rev_start: vec![0; n + 1],
            rev: vec![],
            contours: vec![ContourInfo { patch: 0, first: 0, len: n, alive: n, outer: true }],
        };
        let k = ar.kappa(7, 4, 10.0);
        assert!((k - 10.0 / r).abs() < 0.01 * 10.0 / r, "{k}");
    }
}
