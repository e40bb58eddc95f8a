//! Rasterising closed polylines on the corner lattice back into pixels: a pixel belongs to a
//! patch when its centre (lattice `(x + 0.5, y + 0.5)`) is inside the patch's contours under
//! the even-odd rule, which keeps holes as holes.

/// Calls `put(x, y)` for every pixel of a `w` x `h` buffer whose centre lies inside `polys`
/// (even-odd). An unmoved traced patch reproduces exactly its pixels.
pub fn fill_even_odd(polys: &[&[[f64; 2]]], w: usize, h: usize, mut put: impl FnMut(usize, usize)) {
    let mut hits: Vec<(i64, f64)> = Vec::new();
    for poly in polys {
        let n = poly.len();
        for i in 0..n {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            if a[1] == b[1] {
                continue;
            }
            let (lo, hi) = if a[1] < b[1] { (a[1], b[1]) } else { (b[1], a[1]) };
            // Rows whose centre y + 0.5 lies in [lo, hi).
            let y0 = ((lo - 0.5).ceil() as i64).max(0);
            let y1 = ((hi - 0.5).ceil() as i64).min(h as i64);
            for y in y0..y1 {
                let yc = y as f64 + 0.5;
                hits.push((y, a[0] + (yc - a[1]) / (b[1] - a[1]) * (b[0] - a[0])));
            }
        }
    }
    hits.sort_unstable_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)));
    for pair in hits.chunks_exact(2) {
        let ((y, xa), (y2, xb)) = (pair[0], pair[1]);
        debug_assert_eq!(y, y2, "even crossings per row");
        let x0 = ((xa - 0.5).ceil() as i64).max(0);
        let x1 = ((xb - 0.5).ceil() as i64).min(w as i64);
        for x in x0..x1 {
            put(x as usize, y as usize);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_with_hole_fills_ring() {
        let outer = [[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]];
        let hole = [[2.0, 2.0], [2.0, 4.0], [4.0, 4.0], [4.0, 2.0]];
        let mut n = 0;
        let mut inside_hole = false;
        fill_even_odd(&[&outer, &hole], 6, 6, |x, y| {
            n += 1;
            inside_hole |= (2..4).contains(&x) && (2..4).contains(&y);
        });
        assert_eq!(n, 12);
        assert!(!inside_hole);
    }

    #[test]
    fn clipped_to_buffer() {
        let big = [[-3.0, -3.0], [9.0, -3.0], [9.0, 9.0], [-3.0, 9.0]];
        let mut n = 0;
        fill_even_odd(&[&big], 4, 3, |_, _| n += 1);
        assert_eq!(n, 12);
    }
}
