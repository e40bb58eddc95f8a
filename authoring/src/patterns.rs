//! Renders every structured-light [`Pattern`] to the 8-bit RGB frame a projector shows,
//! following exactly the conventions documented on [`Pattern`] (calibration decodes by them).

use image::{Rgb, RgbImage};

use crate::capture_set::{Axis, Pattern, gray_bits};

/// The frame for `pattern` on a `width x height` projector.
pub fn render(pattern: &Pattern, width: u32, height: u32) -> RgbImage {
    match *pattern {
        Pattern::White => RgbImage::from_pixel(width, height, Rgb([255; 3])),
        Pattern::Black => RgbImage::new(width, height),
        Pattern::GrayCode { axis, bit, inverted } => {
            let extent = match axis {
                Axis::X => width,
                Axis::Y => height,
            };
            let n = gray_bits(extent);
            RgbImage::from_fn(width, height, |x, y| {
                let c = if axis == Axis::X { x } else { y };
                let on = gray_code_bit(c, bit, n) != inverted;
                Rgb([if on { 255 } else { 0 }; 3])
            })
        }
        Pattern::Phase { axis, period, step, steps } => {
            // One value per coordinate, computed once per column or row.
            let extent = if axis == Axis::X { width } else { height };
            let values: Vec<u8> = (0..extent).map(|c| phase_value(c, period, step, steps)).collect();
            RgbImage::from_fn(width, height, |x, y| {
                let c = if axis == Axis::X { x } else { y };
                Rgb([values[c as usize]; 3])
            })
        }
        Pattern::Dots { spacing, dx, dy } => {
            let s = spacing.max(1);
            RgbImage::from_fn(
                width,
                height,
                |x, y| Rgb([if x % s == dx && y % s == dy { 255 } else { 0 }; 3]),
            )
        }
        Pattern::Ramp { channel, level } => {
            let mut v = [0u8; 3];
            match channel {
                0..=2 => v[channel as usize] = level,
                _ => v = [level; 3],
            }
            RgbImage::from_pixel(width, height, Rgb(v))
        }
    }
}

/// Whether Gray-code bit `bit` (0 = most significant of `n`) is set at coordinate `c`.
pub fn gray_code_bit(c: u32, bit: u32, n: u32) -> bool {
    let g = c ^ (c >> 1);
    (g >> (n - 1 - bit)) & 1 == 1
}

/// The 8-bit value of a phase-shift pattern at coordinate `c`:
/// `round(255 * (0.5 + 0.5 * cos(2π c / period - 2π step / steps)))`.
pub fn phase_value(c: u32, period: u32, step: u32, steps: u32) -> u8 {
    let tau = std::f64::consts::TAU;
    let a = tau * c as f64 / period.max(1) as f64 - tau * step as f64 / steps.max(1) as f64;
    (255.0 * (0.5 + 0.5 * a.cos())).round() as u8
}

/// The gray-ramp levels for `count` levels from 0 to 255 inclusive, spaced as the square of
/// evenly spaced steps (9 levels: 0, 4, 16, 36, 64, 100, 143, 195, 255), and never closer
/// than one level (256 levels: every one). Dense at the dark end, because at a low light bound
/// most frame values lie there, and a projector's curve there (a power law, or one that
/// straightens towards black) is what a fit cannot guess from brighter levels.
pub fn ramp_levels(count: u32) -> Vec<u8> {
    let count = count.clamp(2, 256);
    let last = (count - 1) as f64;
    (0..count).map(|i| ((255.0 * (i as f64 / last).powi(2)).round() as u32).max(i) as u8).collect()
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn decode_gray(bits: &[bool]) -> u32 {
        // Gray to binary: b_i = b_{i-1} xor g_i, most significant first.
        let mut acc = 0u32;
        let mut prev = false;
        for &g in bits {
            prev ^= g;
            acc = (acc << 1) | prev as u32;
        }
        acc
    }

    proptest! {
        #[test]
        fn gray_code_frames_decode_to_their_column(w in 2u32..300, x_frac in 0.0f64..1.0) {
            let x = ((w - 1) as f64 * x_frac) as u32;
            let n = gray_bits(w);
            let bits: Vec<bool> = (0..n)
                .map(|b| {
                    let f = render(&Pattern::GrayCode { axis: Axis::X, bit: b, inverted: false }, w, 1);
                    let g = render(&Pattern::GrayCode { axis: Axis::X, bit: b, inverted: true }, w, 1);
                    // The inverse is the exact complement.
                    prop_assert_eq!(f.get_pixel(x, 0).0[0], 255 - g.get_pixel(x, 0).0[0]);
                    Ok(f.get_pixel(x, 0).0[0] == 255)
                })
                .collect::<Result<_, _>>()?;
            prop_assert_eq!(decode_gray(&bits), x);
        }
    }

    #[test]
    fn phase_dots_and_ramps_follow_the_documented_conventions() {
        let f = render(&Pattern::Phase { axis: Axis::Y, period: 8, step: 0, steps: 4 }, 3, 9);
        assert_eq!(f.get_pixel(1, 0).0, [255; 3]);
        assert_eq!(f.get_pixel(2, 4).0, [0; 3]);
        assert_eq!(f.get_pixel(0, 2).0, [128; 3]); // cos(π/2) = 0 -> 127.5 rounds to 128
        let shifted = render(&Pattern::Phase { axis: Axis::Y, period: 8, step: 1, steps: 4 }, 3, 9);
        assert_eq!(shifted.get_pixel(0, 2).0, [255; 3]);
        let d = render(&Pattern::Dots { spacing: 4, dx: 1, dy: 2 }, 9, 9);
        let lit: Vec<(u32, u32)> =
            d.enumerate_pixels().filter(|(_, _, p)| p.0[0] == 255).map(|(x, y, _)| (x, y)).collect();
        assert_eq!(lit, vec![(1, 2), (5, 2), (1, 6), (5, 6)]);
        let r = render(&Pattern::Ramp { channel: 1, level: 77 }, 2, 2);
        assert_eq!(r.get_pixel(1, 1).0, [0, 77, 0]);
        assert_eq!(ramp_levels(9), [0, 4, 16, 36, 64, 100, 143, 195, 255]);
        assert_eq!(*ramp_levels(17).last().unwrap(), 255);
        assert_eq!(ramp_levels(256), (0..=255).collect::<Vec<u8>>());
        for n in 2..=256 {
            let l = ramp_levels(n);
            assert!(l.len() == n as usize && l[0] == 0 && l.windows(2).all(|w| w[0] < w[1]), "{n}: {l:?}");
        }
    }
}
