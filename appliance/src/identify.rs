//! The commissioning pattern (`restage-appliance identify --projector K`): projector K shows
//! a grid, a frame and its number (1-based, as a seven-segment digit) so an installer sees
//! which projector is which and how it lands; the others stay black.
//!
//! The pattern lights only pixels the bundle's certificate vouches for, at the brightest grey
//! level whose peak irradiance (the same per-point sums as every scene's light check, black
//! level of the other projectors included) stays under the bound; the final frames then pass
//! the whole light check like a scene. The player pays for it at that peak, like any light.

use restage_shared::light::{LightCertificate, LightCheck, LightError, LightModel, StageLimits, XrgbFrame};

/// One projector's pattern: its grey level and the peak lux it puts on the object.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pattern {
    pub level: u8,
    pub peak_lux: f64,
}

/// Whether pixel `(x, y)` of a `w` x `h` frame is part of projector `k`'s pattern: a border,
/// an 8 x 8 grid and the digit `k + 1` in the middle.
pub fn in_pattern(w: u32, h: u32, k: usize, x: u32, y: u32) -> bool {
    let line = (w.min(h) / 200).max(1);
    let (cw, ch) = (w.div_ceil(8).max(1), h.div_ceil(8).max(1));
    if x % cw < line || y % ch < line || x + line >= w || y + line >= h {
        return true;
    }
    // Seven segments in a box a third of the height tall, centred.
    let dh = (h / 3).max(7);
    let dw = (dh / 2).max(4);
    let t = (dh / 8).max(1);
    let (x0, y0) = ((w.saturating_sub(dw)) / 2, (h.saturating_sub(dh)) / 2);
    if x < x0 || y < y0 || x >= x0 + dw || y >= y0 + dh {
        return false;
    }
    let (u, v) = (x - x0, y - y0);
    let mid = dh / 2;
    let seg = |s: u8| match s {
        b'a' => v < t,
        b'd' => v >= dh - t,
        b'g' => v + t / 2 >= mid && v < mid + t.div_ceil(2),
        b'f' => u < t && v < mid,
        b'b' => u >= dw - t && v < mid,
        b'e' => u < t && v >= mid,
        b'c' => u >= dw - t && v >= mid,
        _ => false,
    };
    let segments: &[u8] = match (k + 1) % 10 {
        0 => b"abcdef",
        1 => b"bc",
        2 => b"abdeg",
        3 => b"abcdg",
        4 => b"bcfg",
        5 => b"acdfg",
        6 => b"acdefg",
        7 => b"abc",
        8 => b"abcdefg",
        _ => b"abcdfg",
    };
    segments.iter().any(|&s| seg(s))
}

/// Projector `k`'s frames at grey `level`: pattern pixels the coverage vouches for at
/// `level`, everything else (and every other projector) black. XRGB8888.
pub fn frames(check: &LightCheck<'_>, sizes: &[(u32, u32)], k: usize, level: u8) -> Vec<Vec<u8>> {
    sizes
        .iter()
        .enumerate()
        .map(|(j, &(w, h))| {
            let mut f = vec![0u8; w as usize * h as usize * 4];
            if j == k {
                draw(check, w, h, k, level, &mut f);
            }
            f
        })
        .collect()
}

/// Writes projector `k`'s pattern at `level` into `f` (a `w` x `h` XRGB8888 frame).
fn draw(check: &LightCheck<'_>, w: u32, h: u32, k: usize, level: u8, f: &mut [u8]) {
    f.fill(0);
    if level == 0 {
        return;
    }
    for y in 0..h {
        for x in 0..w {
            if in_pattern(w, h, k, x, y) && check.coverage().is_vouched(k, x, y) {
                let i = (y as usize * w as usize + x as usize) * 4;
                f[i..i + 3].fill(level);
            }
        }
    }
}

/// Every projector's brightest pattern within the bound: a bisection on the grey level over
/// the light check (the peak grows with the level: responses are read as running maxima).
/// `None` for a projector whose dimmest level is over the bound. Memory: one coverage map,
/// the pattern's frame and one shared frame of zeros for the other projectors.
pub fn patterns(
    light: &LightModel,
    cert: &LightCertificate,
    stage: &StageLimits,
    sizes: &[(u32, u32)],
) -> Result<Vec<Option<Pattern>>, LightError> {
    let check = LightCheck::new(light, cert, stage)?;
    let largest = sizes.iter().map(|&(w, h)| w as usize * h as usize * 4).max().unwrap_or(0);
    let zeros = vec![0u8; largest];
    let mut lit = vec![0u8; largest];
    let mut out = Vec::with_capacity(sizes.len());
    for (k, &(w, h)) in sizes.iter().enumerate() {
        let len = w as usize * h as usize * 4;
        let mut peak_at = |level: u8| -> Result<Option<f64>, LightError> {
            draw(&check, w, h, k, level, &mut lit[..len]);
            let fs: Vec<XrgbFrame<'_>> = sizes
                .iter()
                .enumerate()
                .map(|(j, &(width, height))| {
                    let n = width as usize * height as usize * 4;
                    XrgbFrame { width, height, xrgb: if j == k { &lit[..n] } else { &zeros[..n] } }
                })
                .collect();
            match check.check_scene("identify", &fs) {
                Ok(p) => Ok(Some(p.lux)),
                Err(LightError::OverBound { .. }) => Ok(None),
                Err(e) => Err(e),
            }
        };
        let mut best = None;
        if let Some(p) = peak_at(255)? {
            best = Some(Pattern { level: 255, peak_lux: p });
        } else {
            // Invariant: `lo` passes (or is 0), `hi` fails.
            let (mut lo, mut hi) = (0u8, 255u8);
            while hi - lo > 1 {
                let mid = lo + (hi - lo) / 2;
                match peak_at(mid)? {
                    Some(p) => {
                        lo = mid;
                        best = Some(Pattern { level: mid, peak_lux: p });
                    }
                    None => hi = mid,
                }
            }
        }
        out.push(best);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use restage_shared::bundle::example::{ExampleSpec, example_certificate};
    use restage_shared::light::{example_light_model, max_irradiance};

    #[test]
    fn the_digit_is_the_projector_number() {
        // Projector 0 shows "1": segments b and c only, so the digit box's left column is
        // dark at mid-height of the upper half while its right column is lit.
        let (w, h) = (800u32, 600u32);
        let dh = h / 3;
        let dw = dh / 2;
        let (x0, y0) = ((w - dw) / 2, (h - dh) / 2);
        let upper = y0 + dh / 4;
        assert!(!in_pattern(w, h, 0, x0 + 1, upper));
        assert!(in_pattern(w, h, 0, x0 + dw - 1, upper));
        // Projector 7 shows "8": the left column is lit too.
        assert!(in_pattern(w, h, 7, x0 + 1, upper));
        // The grid and border.
        assert!(in_pattern(w, h, 3, 0, 123) && in_pattern(w, h, 3, w - 1, 123));
    }

    #[test]
    fn the_pattern_stays_under_the_bound_and_pays_its_true_peak() {
        // 40 lux per unit of response: full white on one projector alone is over the 47.5 lx
        // the example model allows, so the bisection must dim the pattern.
        for lux_per_unit in [15.0f32, 40.0, 120.0] {
            let spec = ExampleSpec { lux_per_unit, ..ExampleSpec::small() };
            let light = example_light_model(spec.projectors, 50.0);
            let cert = example_certificate(&spec);
            let sizes = vec![(spec.width, spec.height); spec.projectors];
            let stage = StageLimits::default();
            let all = patterns(&light, &cert, &stage, &sizes).unwrap();
            for (k, p) in all.iter().enumerate() {
                let p = p.expect("a pattern");
                assert!(p.peak_lux <= light.allowed_lux(), "{p:?}");
                let check = LightCheck::new(&light, &cert, &stage).unwrap();
                let owned = frames(&check, &sizes, k, p.level);
                let fs: Vec<XrgbFrame<'_>> = owned
                    .iter()
                    .map(|x| XrgbFrame { width: spec.width, height: spec.height, xrgb: x })
                    .collect();
                let true_peak = max_irradiance(&light, &cert, &fs).unwrap().lux;
                assert!((true_peak - p.peak_lux).abs() < 1e-9, "{true_peak} vs {p:?}");
                if p.level < 255 {
                    // One level brighter would be over the bound: the bisection found the top.
                    let brighter = frames(&check, &sizes, k, p.level + 1);
                    let fs: Vec<XrgbFrame<'_>> = brighter
                        .iter()
                        .map(|x| XrgbFrame { width: spec.width, height: spec.height, xrgb: x })
                        .collect();
                    assert!(max_irradiance(&light, &cert, &fs).unwrap().lux > light.allowed_lux());
                }
                // Only projector k lights anything.
                for (j, f) in owned.iter().enumerate() {
                    assert_eq!(f.iter().any(|&b| b > 0), j == k, "projector {j} for pattern {k}");
                }
            }
        }
    }
}
