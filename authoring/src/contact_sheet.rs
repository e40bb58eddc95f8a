//! Contact sheets: a grid of small sRGB thumbnails of linear camera images, for people to see
//! at a glance what a capture set holds.

use image::{Rgb, RgbImage};

use crate::capture_set::{Axis, CaptureManifest, Pattern};
use crate::imgio::{LinearImage, linear_to_srgb};

/// Box-filtered thumbnail `tile_w` wide (height keeps the aspect), sRGB-encoded after
/// multiplying by `gain`.
pub fn thumbnail(img: &LinearImage, tile_w: u32, gain: f32) -> RgbImage {
    let tile_w = tile_w.clamp(1, img.width);
    let tile_h = ((img.height as u64 * tile_w as u64) / img.width as u64).max(1) as u32;
    RgbImage::from_fn(tile_w, tile_h, |tx, ty| {
        let x0 = tx * img.width / tile_w;
        let x1 = ((tx + 1) * img.width / tile_w).max(x0 + 1);
        let y0 = ty * img.height / tile_h;
        let y1 = ((ty + 1) * img.height / tile_h).max(y0 + 1);
        let mut acc = [0.0f32; 3];
        for y in y0..y1 {
            for x in x0..x1 {
                let p = img.get(x, y);
                for c in 0..3 {
                    acc[c] += p[c];
                }
            }
        }
        let n = ((x1 - x0) * (y1 - y0)) as f32;
        Rgb(acc.map(|v| (linear_to_srgb((v / n * gain).clamp(0.0, 1.0)) * 255.0).round() as u8))
    })
}

/// The dark gap around and between a grid's thumbnails, pixels.
pub const GAP: u32 = 4;

/// Top-left corner of the thumbnail in `row`, `col` of a grid of `tile`-sized thumbnails.
pub fn tile_origin(tile: (u32, u32), row: u32, col: u32) -> (u32, u32) {
    (GAP + col * (tile.0 + GAP), GAP + row * (tile.1 + GAP))
}

/// Lays out rows of thumbnails (all the same size) with a dark gap between them.
pub fn grid(rows: &[Vec<RgbImage>]) -> RgbImage {
    let (tw, th) = rows.iter().flatten().next().map_or((1, 1), |t| t.dimensions());
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0) as u32;
    let w = GAP + cols * (tw + GAP);
    let h = GAP + rows.len() as u32 * (th + GAP);
    let mut sheet = RgbImage::from_pixel(w, h, Rgb([24, 24, 24]));
    for (r, row) in rows.iter().enumerate() {
        for (c, t) in row.iter().enumerate() {
            let (ox, oy) = tile_origin((tw, th), r as u32, c as u32);
            for (x, y, p) in t.enumerate_pixels() {
                if x < tw && y < th {
                    sheet.put_pixel(ox + x, oy + y, *p);
                }
            }
        }
    }
    sheet
}

/// The patterns a contact sheet shows per projector, left to right: white, black, a coarse
/// and a fine Gray code in x and y, the first phase image in x and y, the first dot grid,
/// and mid-level red, green and blue ramps.
pub fn sheet_patterns(manifest: &CaptureManifest, projector: usize) -> Vec<Pattern> {
    let p = &manifest.projectors[projector];
    let mut out = vec![Pattern::White, Pattern::Black];
    for axis in [Axis::X, Axis::Y] {
        for bit in [1, 4] {
            out.push(Pattern::GrayCode { axis, bit, inverted: false });
        }
    }
    let mut phases = p.shots.iter().filter_map(|s| match s.pattern {
        Pattern::Phase { axis, step: 0, .. } => Some((axis, s.pattern.clone())),
        _ => None,
    });
    out.extend(phases.by_ref().map(|(_, pat)| pat));
    out.extend(p.shots.iter().find(|s| matches!(s.pattern, Pattern::Dots { .. })).map(|s| s.pattern.clone()));
    for channel in 0..3u8 {
        let mid = p
            .shots
            .iter()
            .filter_map(|s| match s.pattern {
                Pattern::Ramp { channel: c, level } if c == channel && level >= 128 => Some(level),
                _ => None,
            })
            .min();
        out.extend(mid.map(|level| Pattern::Ramp { channel, level }));
    }
    out.retain(|pat| p.find(pat).is_some());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thumbnails_average_and_encode_srgb() {
        let mut img = LinearImage::new(4, 2).unwrap();
        img.set(0, 0, [1.0; 3]);
        img.set(1, 0, [0.0; 3]);
        let t = thumbnail(&img, 2, 1.0);
        assert_eq!(t.dimensions(), (2, 1));
        // Mean of 1, 0, 0, 0 = 0.25 linear, about 137 in sRGB.
        assert_eq!(t.get_pixel(0, 0).0[0], 137);
        assert_eq!(t.get_pixel(1, 0).0[0], 0);
        let g = grid(&[vec![t.clone(), t.clone()], vec![t]]);
        assert_eq!(g.dimensions(), (4 + 2 * 6, 4 + 2 * 5));
    }
}
