//! Regions to restore (whole image, rectangles, polygons, masks), each with its background
//! class, turned into per-pixel masks.

use super::MASKED;

/// The shape of a region, in pixel coordinates (integer values at pixel centres).
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Whole,
    /// Pixels `x..x+width`, `y..y+height`; must lie inside the image.
    Rect {
        x: u32,
        y: u32,
        width: u32,
        height: u32,
    },
    /// Pixels whose centre lies inside the polygon (even-odd rule); at least 3 vertices, at
    /// least one pixel inside the image.
    Polygon(Vec<[f64; 2]>),
    /// One flag per pixel, row-major, same size as the label map.
    Mask {
        width: u32,
        height: u32,
        inside: Vec<bool>,
    },
}

/// A region and its background class (`None`: the region's most common class).
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    pub shape: Shape,
    pub background: Option<u8>,
}

impl Region {
    pub fn whole() -> Self {
        Self { shape: Shape::Whole, background: None }
    }

    /// The region as a per-pixel mask for a `w` x `h` image; an error says what is wrong.
    pub fn mask(&self, w: u32, h: u32) -> Result<Vec<bool>, String> {
        let n = w as usize * h as usize;
        let mask = match &self.shape {
            Shape::Whole => vec![true; n],
            &Shape::Rect { x, y, width, height } => {
                if width == 0 || height == 0 {
                    return Err(format!("rectangle {width}x{height} is empty"));
                }
                if x as u64 + width as u64 > w as u64 || y as u64 + height as u64 > h as u64 {
                    return Err(format!(
                        "rectangle x {x}..{} y {y}..{} lies outside the {w}x{h} image",
                        x as u64 + width as u64,
                        y as u64 + height as u64
                    ));
                }
                let mut m = vec![false; n];
                for yy in y..y + height {
                    let row = yy as usize * w as usize;
                    m[row + x as usize..row + (x + width) as usize].fill(true);
                }
                m
            }
            Shape::Polygon(pts) => {
                if pts.len() < 3 || pts.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
                    return Err(format!("polygon needs at least 3 finite vertices (got {})", pts.len()));
                }
                polygon_mask(pts, w, h)
            }
            Shape::Mask { width, height, inside } => {
                if *width != w || *height != h || inside.len() != n {
                    return Err(format!("mask is {width}x{height}, expected {w}x{h} like the label map"));
                }
                inside.clone()
            }
        };
        if !mask.iter().any(|&b| b) {
            return Err(format!("region has no pixel inside the {w}x{h} image"));
        }
        Ok(mask)
    }
}

/// Pixels whose centre is inside the polygon (even-odd), by scanlines through pixel centres.
fn polygon_mask(pts: &[[f64; 2]], w: u32, h: u32) -> Vec<bool> {
    let mut m = vec![false; w as usize * h as usize];
    let mut xs = Vec::new();
    for y in 0..h {
        let yc = y as f64;
        xs.clear();
        for i in 0..pts.len() {
            let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
            if (a[1] <= yc) != (b[1] <= yc) {
                xs.push(a[0] + (yc - a[1]) / (b[1] - a[1]) * (b[0] - a[0]));
            }
        }
        xs.sort_by(f64::total_cmp);
        for pair in xs.chunks_exact(2) {
            let x0 = pair[0].ceil().max(0.0);
            let x1 = pair[1].min(w as f64 - 1.0);
            if x1 < x0 {
                continue;
            }
            let row = y as usize * w as usize;
            for x in x0 as usize..=x1.floor() as usize {
                m[row + x] = true;
            }
        }
    }
    m
}

/// The most common class inside `mask` (smallest index on ties; 0 if all masked).
pub fn majority(labels: &[u8], mask: &[bool], classes: usize) -> u8 {
    let mut count = vec![0usize; classes.max(1)];
    for (&l, &m) in labels.iter().zip(mask) {
        if m && l != MASKED && (l as usize) < classes {
            count[l as usize] += 1;
        }
    }
    let mut best = 0;
    for (i, &c) in count.iter().enumerate() {
        if c > count[best] {
            best = i;
        }
    }
    best as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rect_and_polygon_masks() {
        let r = Region { shape: Shape::Rect { x: 1, y: 1, width: 2, height: 2 }, background: None };
        let m = r.mask(4, 4).unwrap();
        assert_eq!(m.iter().filter(|&&b| b).count(), 4);
        assert!(m[5] && m[10] && !m[0]);
        // A square polygon through pixel centres 1..=2 holds the same 4 pixels (closed on the
        // left/top edges, open on the right/bottom at exact centres).
        let p = Region {
            shape: Shape::Polygon(vec![[0.5, 0.5], [2.5, 0.5], [2.5, 2.5], [0.5, 2.5]]),
            background: None,
        };
        assert_eq!(p.mask(4, 4).unwrap(), m);
    }

    #[test]
    fn regions_outside_the_image_are_refused() {
        let r = Region { shape: Shape::Rect { x: 3, y: 0, width: 2, height: 1 }, background: None };
        let e = r.mask(4, 4).unwrap_err();
        assert!(e.contains("outside"), "{e}");
        let p = Region {
            shape: Shape::Polygon(vec![[10.0, 10.0], [12.0, 10.0], [11.0, 12.0]]),
            background: None,
        };
        assert!(p.mask(4, 4).unwrap_err().contains("no pixel"));
    }
}
