//! Deterioration is smooth, paint edges are sharp: a region that the per-pixel rule gave one
//! class but whose colour runs on without a step into a neighbouring region of another class
//! is that neighbour's paint, faded or stained (the Retinex observation: reflectance changes
//! in steps, light and slow alteration change gradually). Fading towards the ground, a stain
//! or grime move a paint's colour part of the way to another paint's, far outside the spread
//! of the few pixels a conservator picks, so whole faded patches go to the nearest other
//! colour; chips and cracks, the losses that must keep their class, have sharp edges.
//!
//! Each connected region (4-neighbours, one class) is compared with each neighbouring region of
//! another class across their shared border: the colour step from one pixel inside to one pixel
//! outside (skipping past the border pixels themselves, which may be mixed), less the change
//! the colour goes on making over as many pixels beyond it where it does so on both sides (a
//! stain's gradient runs on past where the line between two close classes cuts it, a brush edge
//! stops), relative to the contrast between the two classes' colours. Where the median step is
//! a small share of the contrast the border is soft, and one region takes the other's class.
//! Mixed pixels do not decide it: the per-pixel rule gives a row of them along a band's edge
//! whatever class lies between the two colours mixed, and the row joins a faded patch of that
//! class it touches. So the median is over the pairs with no pixel beside a third label
//! (another class, or off the object) where there are enough of them, and the sizes compared
//! below leave out pixels one pixel wide in their row or column ([`Region::thick`]):
//! - a region holding a pick of its own class (the conservator named it) yields only in
//!   part: a watershed on colour steps from its picks and its typical pixels on one side and
//!   the soft border on the other splits it along its sharpest line (`flood`); a picked pixel,
//!   and one a split kept because the picks reach it by soft steps, is never given away in a
//!   later round;
//! - a loss class (bare substrate) never spreads over a soft border: a loss has an edge, so a
//!   loss-coloured region that fades into paint is that paint;
//! - otherwise the smaller region takes the class of the larger (a faded or stained patch
//!   lies within the paint it alters).
//!
//! A border that is sharp on the median may still be soft along a stretch: a stain that spreads
//! over a paint edge joins the two paints there, while the rest of the edge stays sharp. A run
//! of at least [`MIN_RUN`] touching soft pairs is such a stretch, and a region holding picks that
//! would yield across it yields the part beyond its sharpest line, as above. A region without
//! picks does not: its sharp border is evidence that it is paint, and which side of the stretch
//! is altered is not known (taking the smaller side turned the bowl's stained slip red).
//!
//! Rounds repeat until nothing changes, so a faded patch beside a fainter one joins the
//! paint through it.

use crate::imgio::LinearImage;

/// A border whose median step is below this share of the classes' contrast is soft.
pub const SOFT_STEP: f32 = 0.25;

/// Fewest border pixel pairs for a border to be judged (a few pairs are noise).
const MIN_PAIRS: usize = 6;

/// Most rounds of merging (each round reads the labels as the previous one left them).
const MAX_ROUNDS: usize = 8;

/// One border between two regions of different classes.
#[derive(Clone, Debug)]
pub struct Border {
    /// The two regions, lower index first.
    pub regions: [u32; 2],
    /// Border pixel pairs measured.
    pub pairs: usize,
    /// Median colour step across the border over the contrast between the two classes: of the
    /// pairs with no pixel beside a third label where at least `MIN_PAIRS` are, else of all.
    pub step: f32,
    /// The pairs whose step is below [`SOFT_STEP`]: (pixel in `regions[0]`, pixel in `regions[1]`).
    pub soft: Vec<[u32; 2]>,
    /// The soft pairs that lie in runs of at least [`MIN_RUN`] (8-connected along the border).
    pub runs: Vec<[u32; 2]>,
}

/// Fewest soft pairs in a run along a border for it to be a soft stretch of a sharp border.
pub const MIN_RUN: usize = 10;

/// The soft pairs that lie in runs of at least [`MIN_RUN`] pairs whose first pixels touch
/// (8-neighbours).
fn runs(soft: &[[u32; 2]], w: usize) -> Vec<[u32; 2]> {
    let at: std::collections::HashMap<u32, usize> = soft.iter().enumerate().map(|(k, p)| (p[0], k)).collect();
    let mut parent: Vec<usize> = (0..soft.len()).collect();
    fn root(parent: &mut [usize], mut k: usize) -> usize {
        while parent[k] != k {
            parent[k] = parent[parent[k]];
            k = parent[k];
        }
        k
    }
    for (k, p) in soft.iter().enumerate() {
        let (x, y) = ((p[0] as usize % w) as i64, (p[0] as usize / w) as i64);
        for (dx, dy) in [(1, 0), (-1, 1), (0, 1), (1, 1)] {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || nx >= w as i64 {
                continue;
            }
            if let Some(&o) = at.get(&((ny as usize * w + nx as usize) as u32)) {
                let (a, b) = (root(&mut parent, k), root(&mut parent, o));
                parent[a] = b;
            }
        }
    }
    let mut size = vec![0usize; soft.len()];
    for k in 0..soft.len() {
        size[root(&mut parent, k)] += 1;
    }
    (0..soft.len()).filter(|&k| size[root(&mut parent, k)] >= MIN_RUN).map(|k| soft[k]).collect()
}

/// One region: a 4-connected run of one class.
#[derive(Clone, Debug)]
pub struct Region {
    pub class: u8,
    pub pixels: u32,
    /// Its pixels outside lines one pixel wide (`thin_pixels`): the size a soft border
    /// compares. A row of mixed pixels along an edge or the silhouette can take the class of a
    /// patch it touches and double the patch's size.
    pub thick: u32,
    /// Holds a pick of its own class.
    pub anchored: bool,
}

/// Regions and the borders between them.
#[derive(Clone, Debug)]
pub struct Regions {
    /// Region index of every pixel (`u32::MAX` off the object).
    pub of_pixel: Vec<u32>,
    pub regions: Vec<Region>,
    pub borders: Vec<Border>,
}

/// Relative difference of two linear RGB colours: the L1 distance over the L1 sum, so that
/// shading (a common factor) cancels.
pub(super) fn relative(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d: f64 = (0..3).map(|j| (a[j] - b[j]).abs()).sum();
    let s: f64 = (0..3).map(|j| a[j].abs() + b[j].abs()).sum();
    if s > 0.0 { d / s } else { 0.0 }
}

/// The 4-neighbours of pixel `i` in a `w` x `h` image.
fn neighbours(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)]
        .into_iter()
        .flatten()
}

/// The pixel `count` pixels from `i` along a row (`d` = 1) or a column (`d` = `w`), back
/// where `count` is negative, if it lies in the `w` x `h` image (never wrapping round a row).
fn along(i: usize, d: usize, count: i64, w: usize, h: usize) -> Option<usize> {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    let (x, y) = if d == 1 { (x + count, y) } else { (x, y + count) };
    (x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h).then(|| y as usize * w + x as usize)
}

/// Pixels one pixel wide in their row or in their column: both neighbours across them have
/// another label or lie off the image. Mixed pixels along an edge or the silhouette, which the
/// per-pixel rule gives whichever class lies between the two colours they mix, form such lines.
fn thin_pixels(labels: &[u8], w: usize, h: usize) -> Vec<bool> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let other = |j: Option<usize>| j.is_none_or(|j| labels[j] != labels[i]);
            (other((x > 0).then(|| i - 1)) && other((x + 1 < w).then(|| i + 1)))
                || (other((y > 0).then(|| i - w)) && other((y + 1 < h).then(|| i + w)))
        })
        .collect()
}

/// Labels 4-connected components (the regions here, the restoration's patches) of equal class among `active` pixels that are not
/// `background`. Returns the component of every pixel (`u32::MAX` for none) and the count.
pub fn components(labels: &[u8], active: &[bool], w: usize, h: usize, background: u8) -> (Vec<u32>, usize) {
    let mut comp = vec![u32::MAX; w * h];
    let mut n = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if comp[start] != u32::MAX || !active[start] || labels[start] == background {
            continue;
        }
        let l = labels[start];
        comp[start] = n;
        stack.push(start);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize| {
                if comp[j] == u32::MAX && active[j] && labels[j] == l {
                    comp[j] = n;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        n += 1;
    }
    (comp, n as usize)
}

/// The regions of `labels` (classes `0..k`; anything else is off the object) without their
/// borders: the region of every pixel (`u32::MAX` off the object) and each region's class,
/// size and whether it holds a pick of its class (`picks[c]`: the pixels picked for `c`).
pub fn regions_only(
    labels: &[u8],
    k: usize,
    w: usize,
    h: usize,
    picks: &[Vec<usize>],
) -> (Vec<u32>, Vec<Region>) {
    let n = labels.len();
    let active: Vec<bool> = labels.iter().map(|&l| (l as usize) < k).collect();
    let (of_pixel, count) = components(labels, &active, w, h, u8::MAX);
    let thin = thin_pixels(labels, w, h);
    let mut regions = vec![Region { class: 0, pixels: 0, thick: 0, anchored: false }; count];
    for (i, &g) in of_pixel.iter().enumerate().filter(|&(_, &g)| g != u32::MAX) {
        let r = &mut regions[g as usize];
        r.class = labels[i];
        r.pixels += 1;
        r.thick += u32::from(!thin[i]);
    }
    for (c, pix) in picks.iter().enumerate() {
        for &i in pix.iter().filter(|&&i| i < n && labels[i] as usize == c) {
            regions[of_pixel[i] as usize].anchored = true;
        }
    }
    (of_pixel, regions)
}

/// Finds the regions of `labels` (classes `0..k`; anything else is off the object) and
/// measures every border. `colours`: each class's colour (linear RGB) the contrast is
/// measured between; `picks[c]`: the pixels picked for class `c`.
pub fn regions(
    photo: &LinearImage,
    labels: &[u8],
    k: usize,
    colours: &[[f64; 3]],
    picks: &[Vec<usize>],
) -> Regions {
    let (w, h) = (photo.width as usize, photo.height as usize);
    let n = labels.len();
    let on = |i: usize| (labels[i] as usize) < k;
    let (of_pixel, regions) = regions_only(labels, k, w, h, picks);

    // Per pair of regions: every pair's step (and whether it is clear of a third label), and
    // the soft pairs.
    type Measured = (Vec<(f32, bool)>, Vec<[u32; 2]>);
    let mut steps: std::collections::BTreeMap<(u32, u32), Measured> = Default::default();
    let px = |i: usize| photo.data[i].map(f64::from);
    for i in (0..n).filter(|&i| on(i)) {
        let (x, y) = (i % w, i / w);
        for (j, d) in [((x + 1 < w).then_some(i + 1), 1), ((y + 1 < h).then_some(i + w), w)] {
            let Some(j) = j.filter(|&j| on(j) && labels[j] != labels[i]) else { continue };
            let contrast = relative(colours[labels[i] as usize], colours[labels[j] as usize]);
            if contrast <= 0.0 {
                continue;
            }
            // One pixel further in on each side where the region goes on, so that mixed
            // border pixels do not halve a sharp edge's step.
            let inner = along(i, d, -1, w, h).filter(|&p| of_pixel[p] == of_pixel[i]).unwrap_or(i);
            let outer = along(j, d, 1, w, h).filter(|&q| of_pixel[q] == of_pixel[j]).unwrap_or(j);
            // Less what the colour goes on changing beyond the border over as many pixels,
            // where it does on both sides: a stain's gradient runs on past where the line
            // between two close classes cuts it, a brush edge stops.
            let beyond = |from: usize, p: usize, count: i64| {
                along(p, d, count, w, h)
                    .filter(|&q| of_pixel[q] == of_pixel[from])
                    .map(|q| relative(px(q), px(p)))
            };
            let run_on = if inner != i && outer != j {
                beyond(i, inner, -3).zip(beyond(j, outer, 3)).map_or(0.0, |(a, b)| a.min(b))
            } else {
                0.0
            };
            let step = ((relative(px(inner), px(outer)) - run_on).max(0.0) / contrast) as f32;
            // A pixel beside a third label (another class, or off the object) may mix that
            // colour in: a row of mixed pixels along a band's edge makes steps to the band
            // that say nothing of how the two regions meet.
            let third =
                |p: usize| neighbours(p, w, h).any(|q| labels[q] != labels[i] && labels[q] != labels[j]);
            let clear = !third(i) && !third(j);
            let (key, pixels) = if of_pixel[i] < of_pixel[j] {
                ((of_pixel[i], of_pixel[j]), [i as u32, j as u32])
            } else {
                ((of_pixel[j], of_pixel[i]), [j as u32, i as u32])
            };
            let entry = steps.entry(key).or_default();
            entry.0.push((step, clear));
            if step < SOFT_STEP {
                entry.1.push(pixels);
            }
        }
    }
    let borders = steps
        .into_iter()
        .map(|((a, b), (all, soft))| {
            // The median over the pairs clear of a third label where there are enough of them.
            let mut v: Vec<f32> = all.iter().filter(|p| p.1).map(|p| p.0).collect();
            if v.len() < MIN_PAIRS {
                v = all.iter().map(|p| p.0).collect();
            }
            let m = v.len() / 2;
            let step = *v.select_nth_unstable_by(m, f32::total_cmp).1;
            let runs = runs(&soft, w);
            Border { regions: [a, b], pairs: all.len(), step, soft, runs }
        })
        .collect();
    Regions { of_pixel, regions, borders }
}

/// Which of two softly bordering regions takes the other's class (module notes), if either;
/// a region holding picks of its class then yields only its part beyond them ([`flood`]).
fn yields(a: &Region, b: &Region, loss: &[u8]) -> Option<usize> {
    let is_loss = |r: &Region| loss.contains(&r.class);
    match (is_loss(a), is_loss(b)) {
        (true, false) => Some(0),
        (false, true) => Some(1),
        _ if a.thick < b.thick => Some(0),
        _ if b.thick < a.thick => Some(1),
        _ => None,
    }
}

/// Splits regions that hold picks but also border softly on a paint they should yield to:
/// the picks and the region's typical pixels keep their class, the soft border's pixels take
/// the other, and every pixel of the region goes to the seed it reaches by the path whose
/// largest colour step is least (a watershed on the colour steps: the split falls on the
/// sharpest line between the picked paint and the altered patch). Typical pixels that only the
/// soft border reaches by soft steps are no seeds (see the body). `seeds`: (pixel, class); the
/// picks are added here. `kept`: pixels an earlier split kept (no seeds), updated.
#[allow(clippy::too_many_arguments)]
fn flood(
    photo: &LinearImage,
    r: &Regions,
    labels: &mut [u8],
    colours: &[[f64; 3]],
    picks: &[Vec<usize>],
    typical: &[bool],
    seeds: Vec<(u32, u8)>,
    kept: &mut [bool],
) {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let (w, h) = (photo.width as usize, photo.height as usize);
    // A pick is the conservator's word on its pixel, and a pixel an earlier round's split kept
    // as one the picks reach by soft steps is settled: neither is a soft-border seed of another
    // class. Otherwise a region in a smooth gradient, which has no sharp line to split along,
    // is eroded round by round (a faded patch with a pick in it went from 593 pixels to 21 in
    // five rounds).
    let own: &[u8] = labels;
    let picked: std::collections::HashSet<usize> = picks
        .iter()
        .enumerate()
        .flat_map(|(c, pix)| pix.iter().copied().filter(move |&i| i < own.len() && own[i] as usize == c))
        .collect();
    let seeds: Vec<(u32, u8)> =
        seeds.into_iter().filter(|&(i, _)| !picked.contains(&(i as usize)) && !kept[i as usize]).collect();
    let split: std::collections::BTreeSet<u32> = seeds.iter().map(|&(i, _)| r.of_pixel[i as usize]).collect();
    let soft: std::collections::HashSet<u32> = seeds.iter().map(|&(i, _)| i).collect();
    let mut heap: BinaryHeap<Reverse<(u32, u32, u8)>> =
        seeds.into_iter().map(|(i, c)| Reverse((0, i, c))).collect();
    let px = |i: usize| photo.data[i].map(f64::from);
    let neighbours = |i: usize| neighbours(i, w, h);
    // The colour step from i to its neighbour j, measured as borders are: from one pixel
    // behind i to one beyond j where the region goes on, since a blurred edge spreads its
    // step over two or three pixels.
    let span_step = |i: usize, j: usize| {
        let (dx, dy) = ((j % w) as i64 - (i % w) as i64, (j / w) as i64 - (i / w) as i64);
        let (d, sign) = if dy == 0 { (1, dx) } else { (w, dy) };
        let at = |count: i64| along(i, d, count, w, h).filter(|&k| r.of_pixel[k] == r.of_pixel[i]);
        let behind = at(-sign).unwrap_or(i);
        let beyond = at(2 * sign).unwrap_or(j);
        relative(px(behind), px(beyond))
    };
    // Per split region, the least contrast between its class and a class it yields to: a step
    // under SOFT_STEP of it is soft.
    let mut soft_below: std::collections::BTreeMap<u32, f64> = Default::default();
    for &Reverse((_, i, c)) in heap.iter() {
        let i = i as usize;
        let contrast = relative(colours[labels[i] as usize], colours[c as usize]);
        let e = soft_below.entry(r.of_pixel[i]).or_insert(f64::INFINITY);
        *e = e.min(SOFT_STEP as f64 * contrast);
    }
    // Whether every step from pixel j to a neighbour in its region is soft. A path may not
    // enter a pixel on an edge: one that runs along an edge at a slant to the rows crosses it
    // by soft steps (the mixed pixels shift from one side's colour to the other's a little a
    // row), which held the vase's stained slip to the ochre stripe beside it at seed 10.
    let flat = |j: usize, below: f64| {
        neighbours(j).filter(|&q| r.of_pixel[q] == r.of_pixel[j]).all(|q| span_step(j, q) < below)
    };
    // Pixels reached by soft steps through flat pixels from `from` within their region.
    let reach = |from: &mut dyn Iterator<Item = usize>| {
        let mut seen = vec![false; labels.len()];
        let mut stack: Vec<usize> = from.filter(|&i| !std::mem::replace(&mut seen[i], true)).collect();
        while let Some(i) = stack.pop() {
            let below = soft_below.get(&r.of_pixel[i]).copied().unwrap_or(0.0);
            for j in neighbours(i) {
                if !seen[j] && r.of_pixel[j] == r.of_pixel[i] && span_step(i, j) < below && flat(j, below) {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        seen
    };
    let mut picked: Vec<usize> = Vec::new();
    for (c, pix) in picks.iter().enumerate() {
        for &i in pix.iter().filter(|&&i| i < labels.len() && labels[i] as usize == c) {
            if split.contains(&r.of_pixel[i]) {
                heap.push(Reverse((0, i as u32, c as u8)));
                picked.push(i);
            }
        }
    }
    // A typical pixel holds its class unless it is another paint altered to look like this
    // one: reached by soft steps from the soft border but not from the picks, that is beyond
    // a sharp edge from the picked paint (red faded to a chip's clay colour beside the chip).
    // A soft border's pixel itself continues the paint beyond it, however typical it looks.
    let held = reach(&mut picked.into_iter());
    let released = reach(&mut soft.iter().map(|&i| i as usize));
    for i in
        (0..labels.len()).filter(|&i| typical[i] && (held[i] || !released[i]) && !soft.contains(&(i as u32)))
    {
        if split.contains(&r.of_pixel[i]) {
            heap.push(Reverse((0, i as u32, labels[i])));
        }
    }
    let mut settled = vec![false; labels.len()];
    let mut out: Vec<(usize, u8)> = Vec::new();
    while let Some(Reverse((cost, i, c))) = heap.pop() {
        let i = i as usize;
        if std::mem::replace(&mut settled[i], true) {
            continue;
        }
        out.push((i, c));
        for j in neighbours(i).filter(|&j| !settled[j] && r.of_pixel[j] == r.of_pixel[i]) {
            // Steps are non-negative, so their bits order as the values do.
            let step = (relative(px(i), px(j)) as f32).to_bits();
            heap.push(Reverse((cost.max(step), j as u32, c)));
        }
    }
    for (i, c) in out {
        kept[i] |= held[i] && labels[i] == c;
        labels[i] = c;
    }
}

/// Relabels regions with soft borders (module notes) until stable; returns how many pixels
/// changed class. `loss`: the loss classes; `picks[c]`: the pixels picked for class `c`.
pub fn merge_soft_regions(
    photo: &LinearImage,
    labels: &mut [u8],
    k: usize,
    colours: &[[f64; 3]],
    picks: &[Vec<usize>],
    typical: &[bool],
    loss: &[u8],
) -> usize {
    let before = labels.to_vec();
    // Pixels a split has kept in their class, reached from its picks by soft steps (`flood`).
    let mut kept = vec![false; labels.len()];
    for _ in 0..MAX_ROUNDS {
        let r = regions(photo, labels, k, colours, picks);
        // Per region: the (size, class) of the largest region it joins.
        let mut join: Vec<Option<(u32, u8)>> = vec![None; r.regions.len()];
        // Seeds of the regions with picks that yield in part.
        let mut seeds: Vec<(u32, u8)> = Vec::new();
        for b in r.borders.iter().filter(|b| b.pairs >= MIN_PAIRS) {
            let pair = b.regions.map(|g| &r.regions[g as usize]);
            let Some(y) = yields(pair[0], pair[1], loss) else { continue };
            let into = pair[1 - y];
            if b.step >= SOFT_STEP {
                // A sharp border with a soft stretch: a region with picks yields the part
                // beyond its sharpest line there (one without picks is paint on the evidence
                // of its sharp border, and which side is altered is not known).
                if pair[y].anchored {
                    seeds.extend(b.runs.iter().map(|p| (p[y], into.class)));
                }
                continue;
            }
            if pair[y].anchored {
                seeds.extend(b.soft.iter().map(|p| (p[y], into.class)));
                continue;
            }
            let slot = &mut join[b.regions[y] as usize];
            if slot.is_none_or(|(size, _)| into.thick > size) {
                *slot = Some((into.thick, into.class));
            }
        }
        let old = labels.to_vec();
        for (l, &g) in labels.iter_mut().zip(&r.of_pixel) {
            if let Some((_, c)) = join.get(g as usize).copied().flatten() {
                *l = c;
            }
        }
        if !seeds.is_empty() {
            flood(photo, &r, labels, colours, picks, typical, seeds, &mut kept);
        }
        if *labels == old[..] {
            break;
        }
    }
    labels.iter().zip(&before).filter(|(a, b)| a != b).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [f64; 3] = [0.50, 0.10, 0.08];
    const CLAY: [f64; 3] = [0.30, 0.20, 0.12];
    const SLIP: [f64; 3] = [0.60, 0.55, 0.45];
    const W: usize = 120;
    const H: usize = 60;

    /// Red paint with a sharp-edged chip (clay) on the left, a patch on the right that fades
    /// smoothly from red to a clay-like colour at its centre, and slip below a straight edge.
    /// Labels as the per-pixel rule gives them: the faded core is nearer the clay.
    fn scene() -> (LinearImage, Vec<u8>) {
        let mut photo = LinearImage::new(W as u32, H as u32).unwrap();
        let mut labels = vec![0u8; W * H];
        for y in 0..H {
            for x in 0..W {
                let i = y * W + x;
                let (colour, label) = if y >= 50 {
                    (SLIP, 2)
                } else if (x as f64 - 15.0).hypot(y as f64 - 15.0) < 6.0 {
                    (CLAY, 1)
                } else {
                    // Fading over tens of pixels: 0 far from (85, 22), up to 0.95 of the way
                    // to the clay colour.
                    let d = (x as f64 - 85.0).hypot(y as f64 - 22.0);
                    let f = 0.95 * (-(d / 15.0).powi(2)).exp();
                    let c = [0, 1, 2].map(|j| RED[j] + f * (CLAY[j] - RED[j]));
                    (c, if f > 0.5 { 1 } else { 0 })
                };
                // A little deterministic texture, as grain and noise give.
                let t = 1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0);
                photo.data[i] = colour.map(|c| (c * t) as f32);
                labels[i] = label;
            }
        }
        (photo, labels)
    }

    fn at(x: usize, y: usize) -> usize {
        y * W + x
    }

    #[test]
    fn a_faded_patch_joins_its_paint_and_a_chip_keeps_its_class() {
        let (photo, mut labels) = scene();
        assert_eq!(labels[at(85, 22)], 1, "the scene's faded core starts as clay");
        let picks = vec![vec![at(35, 5)], vec![at(15, 15)], vec![at(40, 55)]];
        let typical = vec![false; labels.len()];
        let changed = merge_soft_regions(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &typical, &[1]);
        assert_eq!(labels[at(85, 22)], 0, "the faded patch is red paint");
        assert!(changed > 20, "{changed}");
        assert_eq!(labels[at(15, 15)], 1, "the chip keeps its class");
        assert_eq!(labels[at(40, 55)], 2, "the slip is untouched");
        // Only the faded patch changed.
        let (_, before) = scene();
        for i in (0..labels.len()).filter(|&i| labels[i] != before[i]) {
            let (x, y) = (i % W, i / W);
            assert!((x as f64 - 85.0).hypot(y as f64 - 22.0) < 15.0, "({x}, {y}) changed");
        }
    }

    #[test]
    fn a_chip_without_picks_keeps_its_class_too() {
        // No pick in the chip: its edge is sharp, so nothing yields there.
        let (photo, mut labels) = scene();
        let picks = vec![vec![at(35, 5)], vec![], vec![at(40, 55)]];
        let typical = vec![false; labels.len()];
        merge_soft_regions(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &typical, &[1]);
        assert_eq!(labels[at(15, 15)], 1);
        assert_eq!(labels[at(85, 22)], 0);
    }

    #[test]
    fn a_picked_region_yields_only_its_altered_part() {
        // Two more chips that open into the faded core, one of them picked: chips and core are
        // one clay-labelled region holding a pick, so only the part that does not look like
        // the picks (the faded paint) yields, and the split falls on the chips' sharp edges.
        let (mut photo, mut labels) = scene();
        let in_chip = |i: usize| {
            let (x, y) = ((i % W) as f64, (i / W) as f64);
            (x - 72.0).hypot(y - 22.0) < 5.0 || (x - 98.0).hypot(y - 22.0) < 4.0
        };
        for i in (0..labels.len()).filter(|&i| in_chip(i)) {
            photo.data[i] = CLAY.map(|c| c as f32);
            labels[i] = 1;
        }
        let picks = vec![vec![at(35, 5)], vec![at(72, 22)], vec![at(40, 55)]];
        let typical: Vec<bool> = (0..labels.len()).map(in_chip).collect();
        merge_soft_regions(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &typical, &[1]);
        assert!(
            (0..labels.len()).filter(|&i| in_chip(i)).all(|i| labels[i] == 1),
            "the chip keeps its class"
        );
        assert_eq!(labels[at(85, 22)], 0, "the faded core is red");
        assert_eq!(labels[at(15, 15)], 1, "the first chip too");
    }

    #[test]
    fn faded_paint_that_looks_typical_of_a_chip_does_not_hold_beyond_the_chips_edge() {
        // The faded core is typical of the clay (the per-pixel rule gave it the clay's class
        // because the picks' spread covers it) and one region with a picked chip that opens
        // into it. Its typical pixels lie beyond the chip's sharp edge, so they do not hold
        // the clay: the core is red. The classes are in the other order here (clay first), so
        // that the outcome does not rest on which class comes first.
        let (mut photo, mut labels) = scene();
        let in_chip = |i: usize| (((i % W) as f64) - 72.0).hypot((i / W) as f64 - 22.0) < 5.0;
        for i in (0..labels.len()).filter(|&i| in_chip(i)) {
            photo.data[i] = CLAY.map(|c| c as f32);
            labels[i] = 1;
        }
        for l in labels.iter_mut().filter(|l| **l < 2) {
            *l = 1 - *l;
        }
        let typical: Vec<bool> = labels.iter().map(|&l| l == 0).collect();
        let picks = vec![vec![at(72, 22)], vec![at(35, 5)], vec![at(40, 55)]];
        merge_soft_regions(&photo, &mut labels, 3, &[CLAY, RED, SLIP], &picks, &typical, &[0]);
        assert!(
            (0..labels.len()).filter(|&i| in_chip(i)).all(|i| labels[i] == 0),
            "the chip keeps its class"
        );
        assert_eq!(labels[at(85, 22)], 1, "the faded core is red");
        assert_eq!(labels[at(15, 15)], 0, "the first chip keeps its class");
    }

    #[test]
    fn a_stain_over_a_paint_edge_leaves_the_paint_and_the_edge() {
        // A red band above slip with a sharp edge, and a stain on the slip that spreads from
        // the edge: its core is red enough for the per-pixel rule and joins the band's region.
        // The region's border is sharp along the band and soft only around the stain.
        let (w, h) = (W, H);
        let mut photo = LinearImage::new(w as u32, h as u32).unwrap();
        let mut labels = vec![0u8; w * h];
        let mut stain = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let t = 1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0);
                let colour = if y < 20 {
                    RED
                } else {
                    let f = 0.8 * (-((x as f64 - 60.0).hypot(y as f64 - 24.0) / 8.0).powi(2)).exp();
                    if f > 0.5 {
                        stain[i] = true;
                    }
                    labels[i] = if f > 0.5 { 0 } else { 2 };
                    [0, 1, 2].map(|j| SLIP[j] + f * (RED[j] - SLIP[j]))
                };
                photo.data[i] = colour.map(|c| (c * t) as f32);
            }
        }
        assert!(stain.iter().filter(|&&s| s).count() > 50 && (0..w).any(|x| stain[20 * w + x]));
        let typical: Vec<bool> = (0..w * h).map(|i| i < 20 * w).collect();
        let before = labels.clone();
        // Without picks in the band, the sharp border says it is paint: nothing yields.
        let unpicked = vec![vec![], vec![], vec![at(10, 50)]];
        merge_soft_regions(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &unpicked, &typical, &[1]);
        assert_eq!(labels, before);
        // With picks, the stain beyond the band's edge is slip and the band stays red.
        let picks = vec![vec![at(30, 5), at(90, 10)], vec![], vec![at(10, 50)]];
        merge_soft_regions(&photo, &mut labels, 3, &[RED, CLAY, SLIP], &picks, &typical, &[1]);
        for (i, &l) in labels.iter().enumerate() {
            let want = if i < 20 * w { 0 } else { 2 };
            assert_eq!(l, want, "({}, {})", i % w, i / w);
        }
    }

    #[test]
    fn a_faded_patch_that_mixed_rows_tie_to_a_bands_edges_still_joins_its_band() {
        // A black band on slip whose middle fades towards grey-blue (the per-pixel rule gave
        // the faded middle that class), and the band's top and bottom rows, mixed with the
        // slip, given the same class: one region of the patch and two long one-pixel rows.
        // Its steps to the black across those rows are sharp and outnumber the soft steps of
        // the fade, and with the rows it has more pixels than either black piece. The median
        // over the pairs clear of a third label and the size without one-pixel lines see the
        // patch: the whole band is black.
        const BLACK: [f64; 3] = [0.03, 0.03, 0.03];
        const GREY: [f64; 3] = [0.09, 0.14, 0.19];
        let (w, h) = (W, H);
        let mut photo = LinearImage::new(w as u32, h as u32).unwrap();
        let mut labels = vec![2u8; w * h];
        let band = |x: usize, y: usize| (10..110).contains(&x) && (20..30).contains(&y);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let t = 1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0);
                let f = 0.9 * (1.0 - (x as f64 - 60.0).abs() / 20.0).max(0.0);
                let (colour, label) = if !band(x, y) {
                    (SLIP, 2)
                } else if y == 20 || y == 29 {
                    ([0, 1, 2].map(|j| 0.5 * (BLACK[j] + SLIP[j])), 1)
                } else {
                    ([0, 1, 2].map(|j| BLACK[j] + f * (GREY[j] - BLACK[j])), u8::from(f > 0.45))
                };
                photo.data[i] = colour.map(|c| (c * t) as f32);
                labels[i] = label;
            }
        }
        let typical = vec![false; w * h];
        let picks = vec![vec![], vec![], vec![at(5, 5)]];
        merge_soft_regions(&photo, &mut labels, 3, &[BLACK, GREY, SLIP], &picks, &typical, &[]);
        for (i, &l) in labels.iter().enumerate() {
            let want = if band(i % w, i / w) { 0 } else { 2 };
            assert_eq!(l, want, "({}, {})", i % w, i / w);
        }
    }

    /// An ochre stripe whose right edge runs at a slant to the columns (an eighth of a pixel a
    /// row, drawn by area, so each column it crosses shades from stripe to ground over eight
    /// rows), and a stain on the slip beside it that moves the slip 70 % of the way to the
    /// ochre: the per-pixel rule gives the stain's core the ochre's class, it is one region
    /// with the picked stripe, and its pixels are typical of the ochre (as on the vase at
    /// seed 10). Down a crossed column every step is soft, so the stain was held to the pick
    /// and stayed ochre; the stripe's edge is sharp across it, and the stain is slip.
    #[test]
    fn a_stain_beside_a_slanted_stripe_edge_is_not_held_along_the_edge() {
        const OCHRE: [f64; 3] = [0.26, 0.145, 0.03];
        const GROUND: [f64; 3] = [0.29, 0.235, 0.15];
        let (w, h) = (120usize, 90usize);
        let edge = |y: usize| 30.0 + y as f64 / 8.0;
        let (cx, cy) = (edge(45) + 3.0, 45.0);
        let stain = |x: usize, y: usize| 0.7 * (-((x as f64 - cx).hypot(y as f64 - cy) / 30.0).powi(2)).exp();
        let stripe =
            |x: usize, y: usize| if x < 20 { 0.0 } else { (edge(y) - (x as f64 - 0.5)).clamp(0.0, 1.0) };
        let mut photo = LinearImage::new(w as u32, h as u32).unwrap();
        let mut labels = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (c, f) = (stripe(x, y), stain(x, y));
                let ground = [0, 1, 2].map(|j| GROUND[j] + f * (OCHRE[j] - GROUND[j]));
                let colour = [0, 1, 2].map(|j| c * OCHRE[j] + (1.0 - c) * ground[j]);
                let t = 1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0);
                photo.data[i] = colour.map(|v| (v * t) as f32);
                labels[i] = if c + (1.0 - c) * f > 0.5 { 0 } else { 1 };
            }
        }
        let core = |x: usize, y: usize| stripe(x, y) == 0.0 && stain(x, y) > 0.55;
        let cores: Vec<usize> =
            (0..w * h).filter(|&i| core(i % w, i / w) && (i % w) as f64 > edge(i / w) + 2.0).collect();
        assert!(
            cores.len() > 30 && cores.iter().all(|&i| labels[i] == 0),
            "the stain's core starts as ochre"
        );
        let typical: Vec<bool> = labels.iter().map(|&l| l == 0).collect();
        let picks = vec![vec![24 + 5 * w], vec![110 + 85 * w]];
        merge_soft_regions(&photo, &mut labels, 2, &[OCHRE, GROUND], &picks, &typical, &[]);
        let still = cores.iter().filter(|&&i| labels[i] == 0).count();
        assert_eq!(still, 0, "{still} of {} stained pixels beyond the edge stay ochre", cores.len());
        assert!(
            (0..w * h).filter(|&i| stripe(i % w, i / w) == 1.0).all(|i| labels[i] == 0),
            "the stripe keeps its class"
        );
    }

    /// Red paint under a stain whose gradient is steep (as on the bowl's rim at seed 21): the
    /// colour runs from the red towards a brown over 20 px, and the middle of the ramp, nearer
    /// the clay, is a stripe that the per-pixel rule gives the clay (a loss class). Each
    /// three-pixel step across the stripe's edges is over a quarter of the close red-clay
    /// contrast, but the colour goes on changing as fast beyond them on both sides, so the
    /// edges are soft and the stripe is red; a chip's edge, flat on its inside, stays sharp.
    #[test]
    fn a_steep_stain_through_a_close_class_joins_its_paint_and_a_chip_keeps_its_edge() {
        const RED: [f64; 3] = [0.50, 0.10, 0.08];
        const CLAY: [f64; 3] = [0.40, 0.16, 0.10];
        const STAINED: [f64; 3] = [0.30, 0.22, 0.12];
        let (w, h) = (100usize, 40usize);
        let ramp = |x: usize| ((x as f64 - 40.0) / 20.0).clamp(0.0, 1.0);
        let chip = |x: usize, y: usize| (x as f64 - 15.0).hypot(y as f64 - 20.0) < 6.0;
        let mut photo = LinearImage::new(w as u32, h as u32).unwrap();
        let mut labels = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let f = ramp(x);
                let colour =
                    if chip(x, y) { CLAY } else { [0, 1, 2].map(|j| RED[j] + f * (STAINED[j] - RED[j])) };
                let t = 1.0 + 0.01 * (((x * 7 + y * 13) % 5) as f64 - 2.0);
                photo.data[i] = colour.map(|v| (v * t) as f32);
                labels[i] = u8::from(chip(x, y) || (0.35..0.65).contains(&f));
            }
        }
        // The premise: the steps across the stripe's edges are sharp by the median alone.
        let contrast = relative(RED, CLAY);
        let across = relative(photo.data[46 + 20 * w].map(f64::from), photo.data[49 + 20 * w].map(f64::from));
        assert!(across > f64::from(SOFT_STEP) * contrast, "{across} against {contrast}");
        let stripe: Vec<usize> = (0..w * h).filter(|&i| !chip(i % w, i / w) && labels[i] == 1).collect();
        let picks = vec![vec![5 + 5 * w], vec![15 + 20 * w]];
        let typical = vec![false; w * h];
        merge_soft_regions(&photo, &mut labels, 2, &[RED, CLAY], &picks, &typical, &[1]);
        let still = stripe.iter().filter(|&&i| labels[i] == 1).count();
        assert_eq!(still, 0, "{still} of {} stained pixels stay clay", stripe.len());
        assert!(
            (0..w * h).filter(|&i| chip(i % w, i / w)).all(|i| labels[i] == 1),
            "the chip keeps its class"
        );
    }
}
