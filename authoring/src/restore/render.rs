//! Pictures of label maps for people: the restored image in class colours, and a
//! before/after sheet with the patch contours drawn over each.

use image::{Rgb, RgbImage};

use super::{LabelMap, MASKED};

/// Renders labels with one 8-bit sRGB colour per class; masked pixels are black.
pub fn render_labels(labels: &LabelMap, colours: &[[u8; 3]]) -> RgbImage {
    RgbImage::from_fn(labels.width, labels.height, |x, y| {
        let l = labels.get(x, y);
        Rgb(if l == MASKED { [0, 0, 0] } else { colours.get(l as usize).copied().unwrap_or([255, 0, 255]) })
    })
}

/// Pixels on a contour: those whose right or lower neighbour has another class.
pub fn boundary_mask(labels: &LabelMap) -> Vec<bool> {
    let (w, h) = (labels.width as usize, labels.height as usize);
    let d = &labels.data;
    let mut m = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            m[i] = (x + 1 < w && d[i + 1] != d[i]) || (y + 1 < h && d[i + w] != d[i]);
        }
    }
    m
}

/// The white gap between the two panels of [`before_after`], pixels.
pub const BEFORE_AFTER_GAP: u32 = 8;

/// Before (left) and after (right), [`BEFORE_AFTER_GAP`] apart; contours before in magenta on
/// both panels, contours after in cyan on the right, so what moved stands out.
pub fn before_after(before: &LabelMap, after: &LabelMap, colours: &[[u8; 3]]) -> RgbImage {
    let (w, h) = (before.width, before.height);
    let gap = BEFORE_AFTER_GAP;
    let mut out = RgbImage::from_pixel(2 * w + gap, h, Rgb([255, 255, 255]));
    let (b_img, a_img) = (render_labels(before, colours), render_labels(after, colours));
    let (b_edge, a_edge) = (boundary_mask(before), boundary_mask(after));
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let magenta = Rgb([255, 0, 255]);
            out.put_pixel(x, y, if b_edge[i] { magenta } else { *b_img.get_pixel(x, y) });
            let right = if a_edge[i] {
                Rgb([0, 255, 255])
            } else if b_edge[i] {
                magenta
            } else {
                *a_img.get_pixel(x, y)
            };
            out.put_pixel(x + w + gap, y, right);
        }
    }
    out
}
