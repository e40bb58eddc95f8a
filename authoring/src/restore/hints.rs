//! User hints (§4.4): strokes painted in class colours over the label map before the
//! minimisation, to reconnect patches across losses too large for smoothing alone.

use super::{MASKED, RestoreError};

/// Hint strokes as class labels per pixel; [`MASKED`] = no stroke.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HintMap {
    pub width: u32,
    pub height: u32,
    pub labels: Vec<u8>,
}

/// Largest per-channel difference at which a stroke colour still names a class (paint tools
/// and 8-bit round trips shift colours slightly).
pub const HINT_COLOUR_TOLERANCE: u8 = 8;

impl HintMap {
    pub(crate) fn check(&self, w: u32, h: u32, classes: usize) -> Result<(), RestoreError> {
        if self.width != w || self.height != h || self.labels.len() != w as usize * h as usize {
            return Err(RestoreError::HintSize {
                got_w: self.width,
                got_h: self.height,
                want_w: w,
                want_h: h,
            });
        }
        if let Some(i) = self.labels.iter().position(|&l| l != MASKED && l as usize >= classes) {
            return Err(RestoreError::HintLabel {
                label: self.labels[i],
                x: (i % w as usize) as u32,
                y: (i / w as usize) as u32,
                classes,
            });
        }
        Ok(())
    }

    /// Paints the strokes over `work` (masked pixels stay masked).
    pub(crate) fn apply(&self, work: &mut [u8]) {
        for (o, &l) in work.iter_mut().zip(&self.labels) {
            if l != MASKED && *o != MASKED {
                *o = l;
            }
        }
    }
}

/// Reads strokes from RGBA pixels: alpha below 128 is no stroke; any other pixel must carry
/// a class's display colour (within `HINT_COLOUR_TOLERANCE`, 8 levels) or the hints are refused.
pub fn hints_from_rgba(
    width: u32,
    height: u32,
    rgba: &[[u8; 4]],
    class_colours: &[[u8; 3]],
) -> Result<HintMap, RestoreError> {
    if rgba.len() != width as usize * height as usize {
        return Err(RestoreError::HintSize {
            got_w: rgba.len() as u32,
            got_h: 1,
            want_w: width,
            want_h: height,
        });
    }
    let mut labels = vec![MASKED; rgba.len()];
    for (i, px) in rgba.iter().enumerate() {
        if px[3] < 128 {
            continue;
        }
        let rgb = [px[0], px[1], px[2]];
        let best = class_colours
            .iter()
            .enumerate()
            .map(|(k, c)| (k, (0..3).map(|j| c[j].abs_diff(rgb[j])).max().unwrap_or(0)))
            .min_by_key(|&(k, d)| (d, k));
        match best {
            Some((k, d)) if d <= HINT_COLOUR_TOLERANCE => labels[i] = k as u8,
            _ => {
                return Err(RestoreError::HintColour {
                    rgb,
                    x: (i % width as usize) as u32,
                    y: (i / width as usize) as u32,
                    classes: class_colours.to_vec(),
                });
            }
        }
    }
    Ok(HintMap { width, height, labels })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strokes_map_to_classes_and_strangers_are_refused() {
        let colours = [[200, 180, 150], [20, 20, 20]];
        let px = [[0, 0, 0, 0], [22, 19, 20, 255], [200, 180, 150, 200]];
        let h = hints_from_rgba(3, 1, &px, &colours).unwrap();
        assert_eq!(h.labels, vec![MASKED, 1, 0]);
        let bad = [[0, 0, 0, 0], [250, 0, 0, 255], [0, 0, 0, 0]];
        let e = hints_from_rgba(3, 1, &bad, &colours).unwrap_err();
        assert!(e.to_string().contains("(1, 0)"), "{e}");
    }
}
