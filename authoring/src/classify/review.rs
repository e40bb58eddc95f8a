//! What the classification decided on the weakest evidence, for the conservator to confirm:
//! the regions whose class the soft-border, faded-island and faded-within passes changed from
//! the one their colour gave them. Those passes judge by context (how a border steps, which
//! side is larger, what a shape is surrounded by), and where they are wrong a whole region is
//! wrong (a faded band's end given to the red beside it, a small red patch given to the black
//! band it sits in). One pick of the right class at the suggested pixel settles such a region:
//! a region holding a pick of its class keeps it, or yields only the part beyond its sharpest
//! line (`regions`).

use serde::{Deserialize, Serialize};

use super::{ClassifyError, MASKED, Palette};

/// Fewest pixels for a relabelled region to be listed: smaller ones are mixed edge pixels and
/// specks, which the restoration's own clean-up and the edge pass settle.
pub const MIN_REVIEW_PIXELS: u32 = 20;

/// Version of `review.json`.
pub const REVIEW_VERSION: u32 = 1;

/// One region whose class the context passes changed (8-connected pixels that changed class).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReviewRegion {
    pub pixels: u32,
    /// Bounding box `[x0, y0, x1, y1]`, inclusive, in photo pixels.
    pub bbox: [u32; 4],
    /// The pixel deepest inside the region (farthest from its rim, 4-neighbour steps): where a
    /// pick confirms or corrects it.
    pub pick_at: [u32; 2],
    /// Class index its colour gave the pixel at `pick_at` (the per-pixel rule).
    pub by_colour: u8,
    /// Class index the context passes gave it.
    pub given: u8,
}

/// `review.json`: the regions, largest first, with class names for reading.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Review {
    pub version: u32,
    pub regions: Vec<ReviewEntry>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReviewEntry {
    #[serde(flatten)]
    pub region: ReviewRegion,
    pub by_colour_name: String,
    pub given_name: String,
}

impl Review {
    pub fn new(regions: &[ReviewRegion], palette: &Palette) -> Self {
        let name =
            |c: u8| palette.classes.get(c as usize).map_or_else(|| format!("class {c}"), |p| p.name.clone());
        Self {
            version: REVIEW_VERSION,
            regions: regions
                .iter()
                .map(|r| ReviewEntry {
                    region: r.clone(),
                    by_colour_name: name(r.by_colour),
                    given_name: name(r.given),
                })
                .collect(),
        }
    }

    pub fn save(&self, path: &std::path::Path) -> Result<(), ClassifyError> {
        let json = serde_json::to_string_pretty(self).expect("plain data serialises");
        std::fs::write(path, json + "\n").map_err(|source| ClassifyError::Write { path: path.into(), source })
    }
}

/// Paths of `review.json` and `review.png` inside the classification's output directory.
pub fn output_paths(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    (dir.join("review.json"), dir.join("review.png"))
}

/// The regions of at least [`MIN_REVIEW_PIXELS`] pixels whose label differs between `before`
/// (the per-pixel rule) and `after` (the context passes), largest first (then by position).
pub fn relabelled_regions(before: &[u8], after: &[u8], w: usize, h: usize) -> Vec<ReviewRegion> {
    let changed: Vec<bool> = before.iter().zip(after).map(|(&b, &a)| b != a && a != MASKED).collect();
    let mut comp = vec![u32::MAX; w * h];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in (0..w * h).filter(|&i| changed[i]) {
        if comp[start] != u32::MAX {
            continue;
        }
        let id = out.len() as u32;
        comp[start] = id;
        stack.push(start);
        let mut pix = Vec::new();
        while let Some(i) = stack.pop() {
            pix.push(i);
            for j in neighbours8(i, w, h) {
                if changed[j] && comp[j] == u32::MAX {
                    comp[j] = id;
                    stack.push(j);
                }
            }
        }
        out.push(pix);
    }
    let mut regions: Vec<ReviewRegion> = out
        .iter()
        .enumerate()
        .filter(|(_, pix)| pix.len() as u32 >= MIN_REVIEW_PIXELS)
        .map(|(id, pix)| {
            let deepest = deepest(pix, &comp, id as u32, w, h);
            let (xs, ys) = (pix.iter().map(|&i| (i % w) as u32), pix.iter().map(|&i| (i / w) as u32));
            let bbox = [
                xs.clone().min().unwrap_or(0),
                ys.clone().min().unwrap_or(0),
                xs.max().unwrap_or(0),
                ys.max().unwrap_or(0),
            ];
            ReviewRegion {
                pixels: pix.len() as u32,
                bbox,
                pick_at: [(deepest % w) as u32, (deepest / w) as u32],
                by_colour: before[deepest],
                given: after[deepest],
            }
        })
        .collect();
    regions.sort_by_key(|r| (std::cmp::Reverse(r.pixels), r.pick_at[1], r.pick_at[0]));
    regions
}

fn neighbours8(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    (-1..=1i64)
        .flat_map(move |dy| (-1..=1i64).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(nx, ny)| (nx, ny) != (x, y) && nx >= 0 && ny >= 0 && nx < w as i64 && ny < h as i64)
        .map(move |(nx, ny)| ny as usize * w + nx as usize)
}

/// The pixel of component `id` farthest (in 4-neighbour steps) from any pixel outside it; the
/// lowest index among equals.
fn deepest(pix: &[usize], comp: &[u32], id: u32, w: usize, h: usize) -> usize {
    let inside = |j: usize| comp[j] == id;
    let n4 = |i: usize| {
        let (x, y) = (i % w, i / w);
        [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ]
    };
    let mut depth: std::collections::HashMap<usize, u32> = Default::default();
    let mut queue: std::collections::VecDeque<usize> = Default::default();
    for &i in pix {
        if n4(i).iter().any(|j| j.is_none_or(|j| !inside(j))) {
            depth.insert(i, 0);
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        let d = depth[&i];
        for j in n4(i).into_iter().flatten() {
            if inside(j) && !depth.contains_key(&j) {
                depth.insert(j, d + 1);
                queue.push_back(j);
            }
        }
    }
    // Among the deepest, the nearest to the region's centroid (then the lowest index).
    let n = pix.len() as f64;
    let cx = pix.iter().map(|&i| (i % w) as f64).sum::<f64>() / n;
    let cy = pix.iter().map(|&i| (i / w) as f64).sum::<f64>() / n;
    let off = |i: usize| ((i % w) as f64 - cx).powi(2) + ((i / w) as f64 - cy).powi(2);
    let best = pix.iter().map(|i| depth.get(i).copied().unwrap_or(0)).max().unwrap_or(0);
    pix.iter()
        .copied()
        .filter(|i| depth.get(i).copied().unwrap_or(0) == best)
        .min_by(|&a, &b| off(a).total_cmp(&off(b)).then(a.cmp(&b)))
        .unwrap_or(pix[0])
}

/// The preview with each listed region's rim drawn in magenta and its suggested pick marked by a
/// small white cross: where to look, at a glance.
pub fn review_image(
    preview: &image::RgbImage,
    regions: &[ReviewRegion],
    before: &[u8],
    after: &[u8],
) -> image::RgbImage {
    let (w, h) = (preview.width() as usize, preview.height() as usize);
    let mut out = preview.clone();
    let listed: Vec<bool> = {
        let mut v = vec![false; w * h];
        for r in regions {
            let [x0, y0, x1, y1] = r.bbox.map(|v| v as usize);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let i = y * w + x;
                    v[i] = before[i] != after[i] && after[i] != MASKED;
                }
            }
        }
        v
    };
    for i in (0..w * h).filter(|&i| listed[i]) {
        let (x, y) = (i % w, i / w);
        let rim = x == 0
            || y == 0
            || x + 1 == w
            || y + 1 == h
            || [i - 1, i + 1, i - w, i + w].iter().any(|&j| !listed[j]);
        if rim {
            out.put_pixel(x as u32, y as u32, image::Rgb([255, 0, 255]));
        }
    }
    for r in regions {
        let [x, y] = r.pick_at.map(|v| v as i64);
        for (dx, dy) in [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1), (-2, 0), (2, 0), (0, -2), (0, 2)] {
            let (px, py) = (x + dx, y + dy);
            if px >= 0 && py >= 0 && (px as usize) < w && (py as usize) < h {
                out.put_pixel(px as u32, py as u32, image::Rgb([255, 255, 255]));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relabelled_regions_are_listed_largest_first_with_a_pick_deep_inside() {
        let (w, h) = (40, 20);
        let before = vec![0u8; w * h];
        let mut after = before.clone();
        // A 9x7 block relabelled 0 -> 2, a 5x5 one 0 -> 1, and a 3x3 speck (under the minimum).
        for y in 2..9 {
            for x in 3..12 {
                after[y * w + x] = 2;
            }
        }
        for y in 10..15 {
            for x in 20..25 {
                after[y * w + x] = 1;
            }
        }
        for y in 16..19 {
            for x in 30..33 {
                after[y * w + x] = 1;
            }
        }
        // Off the object: never listed.
        after[0] = MASKED;
        let r = relabelled_regions(&before, &after, w, h);
        assert_eq!(r.len(), 2, "{r:?}");
        assert_eq!(r[0].pixels, 63);
        assert_eq!(r[0].bbox, [3, 2, 11, 8]);
        assert_eq!(r[0].pick_at, [7, 5], "the block's centre");
        assert_eq!((r[0].by_colour, r[0].given), (0, 2));
        assert_eq!(r[1].pixels, 25);
        assert_eq!(r[1].pick_at, [22, 12]);
        assert_eq!((r[1].by_colour, r[1].given), (0, 1));
        // Nothing changed: nothing to review.
        assert!(relabelled_regions(&before, &before, w, h).is_empty());
    }

    #[test]
    fn the_review_image_outlines_the_regions_and_marks_the_pick() {
        let (w, h) = (30usize, 20usize);
        let before = vec![0u8; w * h];
        let mut after = before.clone();
        for y in 5..12 {
            for x in 5..15 {
                after[y * w + x] = 1;
            }
        }
        let r = relabelled_regions(&before, &after, w, h);
        let preview = image::RgbImage::from_pixel(w as u32, h as u32, image::Rgb([10, 20, 30]));
        let img = review_image(&preview, &r, &before, &after);
        assert_eq!(img.get_pixel(5, 5).0, [255, 0, 255], "rim");
        assert_eq!(img.get_pixel(14, 11).0, [255, 0, 255], "rim");
        assert_eq!(img.get_pixel(2, 2).0, [10, 20, 30], "outside untouched");
        let [px, py] = r[0].pick_at;
        assert_eq!(img.get_pixel(px, py).0, [255, 255, 255], "pick marked");
    }
}
