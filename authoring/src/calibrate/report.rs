//! The calibration report image: per projector a coverage map (decoded camera pixels,
//! coloured by projector coordinate), the normal map, a depth map, and the reprojection
//! residual histogram (one colour per projector, 0 to 1 px). Figures go to `report.json`.

use image::{Rgb, RgbImage, imageops};

use super::decode::ProjectorDecode;
use super::triangulate::DenseGeometry;

/// Width of each panel of the report image, pixels; panels keep the camera's aspect.
pub const PANEL: u32 = 320;
/// The residual histogram's x axis ends here, projector pixels.
pub const RESIDUAL_MAX_PX: f32 = 1.0;
/// The histogram's plot area: 10 px in from the left and right, its zero line 13 px above the
/// bottom, a count at the curve's peak 7 px below the top.
pub const HIST_SIDE: u32 = 10;
pub const HIST_BASE: u32 = 13;
pub const HIST_TOP: u32 = 7;

/// Height of a panel showing a `width x height` camera image.
pub fn panel_height(width: u32, height: u32) -> u32 {
    (PANEL as f64 * height as f64 / width as f64).round().max(1.0) as u32
}

fn panel(img: &RgbImage) -> RgbImage {
    imageops::resize(img, PANEL, panel_height(img.width(), img.height()), imageops::FilterType::Triangle)
}

/// Residual histogram: `bins` bins over 0..`max_px`, one curve per projector, normalised to its
/// peak. Axis ticks every 0.1 px.
pub fn histogram(residuals: &[Vec<f32>], max_px: f32, width: u32, height: u32) -> RgbImage {
    let mut img = RgbImage::from_pixel(width, height, Rgb([250, 250, 250]));
    let bins = (width - 2 * HIST_SIDE) as usize;
    for tick in 0..=10 {
        let x = HIST_SIDE + (tick as f32 / 10.0 * bins as f32) as u32;
        for y in height - HIST_BASE + 1..height - 2 {
            img.put_pixel(x.min(width - 1), y, Rgb([0, 0, 0]));
        }
    }
    for x in HIST_SIDE..width - HIST_SIDE {
        img.put_pixel(x, height - HIST_BASE + 1, Rgb([0, 0, 0]));
    }
    for (k, res) in residuals.iter().enumerate() {
        let mut counts = vec![0u32; bins];
        for &r in res.iter().filter(|r| r.is_finite()) {
            let b = ((r / max_px) * bins as f32) as usize;
            if b < bins {
                counts[b] += 1;
            }
        }
        let peak = counts.iter().copied().max().unwrap_or(0).max(1) as f32;
        let colour = Rgb(crate::color::categorical(k));
        let plot_h = (height - HIST_BASE - HIST_TOP) as f32;
        let mut prev: Option<u32> = None;
        for (b, &c) in counts.iter().enumerate() {
            let y = height - HIST_BASE - (c as f32 / peak * plot_h) as u32;
            let x = HIST_SIDE + b as u32;
            let (lo, hi) = match prev {
                Some(p) => (p.min(y), p.max(y)),
                None => (y, y),
            };
            for yy in lo..=hi {
                img.put_pixel(x, yy, colour);
            }
            prev = Some(y);
        }
    }
    img
}

/// A unit normal's colour: `(n + 1) / 2` with +y and +z flipped, so up-facing surfaces look
/// green and surfaces facing the camera blue.
pub fn normal_colour(n: [f32; 3]) -> [u8; 3] {
    [
        ((n[0] * 0.5 + 0.5) * 255.0) as u8,
        ((-n[1] * 0.5 + 0.5) * 255.0) as u8,
        ((-n[2] * 0.5 + 0.5) * 255.0) as u8,
    ]
}

/// Normal map as colours ([`normal_colour`]), black where unknown.
pub fn normal_map(width: u32, height: u32, normals: &[[f32; 3]]) -> RgbImage {
    RgbImage::from_fn(width, height, |x, y| {
        let n = normals[(y * width + x) as usize];
        if n[0].is_finite() { Rgb(normal_colour(n)) } else { Rgb([0, 0, 0]) }
    })
}

/// The depth map's range: nearest and farthest finite z, mm (None without two depths).
pub fn depth_range(points: &[[f32; 3]]) -> Option<(f32, f32)> {
    let (lo, hi) = points
        .iter()
        .map(|p| p[2])
        .filter(|z| z.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |a, z| (a.0.min(z), a.1.max(z)));
    (hi > lo).then_some((lo, hi))
}

/// The depth map's grey for depth `z` mm in `range`: 255 nearest, 40 farthest.
pub fn depth_grey(z: f32, (lo, hi): (f32, f32)) -> u8 {
    (40.0 + 215.0 * (hi - z) / (hi - lo)) as u8
}

/// Depth map, near = bright ([`depth_grey`]), black where unknown.
pub fn depth_map(width: u32, height: u32, points: &[[f32; 3]]) -> RgbImage {
    let range = depth_range(points);
    RgbImage::from_fn(width, height, |x, y| {
        let z = points[(y * width + x) as usize][2];
        match range {
            Some(r) if z.is_finite() => {
                let v = depth_grey(z, r);
                Rgb([v, v, v])
            }
            _ => Rgb([0, 0, 0]),
        }
    })
}

/// A coverage map's colour for projector coordinate (`x`, `y`) of a `width x height`
/// projector: red grows with x, green with y.
pub fn coverage_colour(x: f32, y: f32, width: u32, height: u32) -> [u8; 3] {
    [(40.0 + 215.0 * x / width as f32) as u8, (40.0 + 215.0 * y / height as f32) as u8, 60]
}

/// The whole report: a row of coverage maps, then normal map, depth map and histogram.
pub fn render(decodes: &[ProjectorDecode], dense: &DenseGeometry, pw: &[(u32, u32)]) -> RgbImage {
    let Some(first) = decodes.first() else {
        return RgbImage::new(1, 1);
    };
    let (w, h) = (first.width, first.height);
    let mut top: Vec<RgbImage> = decodes
        .iter()
        .zip(pw)
        .map(|(d, &(px, py))| {
            RgbImage::from_fn(w, h, |x, y| {
                let i = (y * w + x) as usize;
                if d.is_valid(i) { Rgb(coverage_colour(d.x[i], d.y[i], px, py)) } else { Rgb([0, 0, 0]) }
            })
        })
        .map(|i| panel(&i))
        .collect();
    for (k, p) in top.iter_mut().enumerate() {
        let c = Rgb(crate::color::categorical(k));
        let (pw, ph) = p.dimensions();
        for x in 0..pw {
            for t in 0..3 {
                p.put_pixel(x, t, c);
                p.put_pixel(x, ph - 1 - t, c);
            }
        }
    }
    let ph = top[0].height();
    let bottom = [
        panel(&normal_map(w, h, &dense.normals)),
        panel(&depth_map(w, h, &dense.points)),
        histogram(&dense.residuals, RESIDUAL_MAX_PX, PANEL, ph),
    ];
    let cols = top.len().max(3) as u32;
    let mut out = RgbImage::from_pixel(cols * PANEL, ph * 2, Rgb([255, 255, 255]));
    for (k, p) in top.iter().enumerate() {
        imageops::overlay(&mut out, p, (k as u32 * PANEL) as i64, 0);
    }
    for (k, p) in bottom.iter().enumerate() {
        imageops::overlay(&mut out, p, (k as u32 * PANEL) as i64, ph as i64);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_peaks_where_the_residuals_are() {
        let res = vec![vec![0.5f32; 100], vec![f32::NAN; 10]];
        let img = histogram(&res, 1.0, 220, 100);
        // The curve of projector 0 reaches the top only near 0.5 px (x = 10 + 100).
        let top_row: Vec<u32> = (0..220)
            .filter(|&x| img.get_pixel(x, 100 - 13 - 80) == &Rgb(crate::color::categorical(0)))
            .collect();
        assert!(!top_row.is_empty() && top_row.iter().all(|&x| (105..=115).contains(&x)), "{top_row:?}");
    }
}
