//! Synthetic painted label maps with known damage, for benchmarks and tests: wavy bands and
//! dots over a background class, then seeded chips (background showing through paint),
//! stains (paint specks on the background) and edge wobble.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::LabelMap;

/// A damaged label map and the pristine one it was made from.
#[derive(Clone, Debug)]
pub struct DamagedPattern {
    pub damaged: LabelMap,
    pub pristine: LabelMap,
}

/// Bands of classes 1 and 2 with a gentle wave, and dots of class 2, over background 0, at
/// `w` x `h`; features scale with `feature_px` (band period). Damage: about one chip per
/// 2000 px, one stain per 4000 px, and up to 1 px of edge wobble.
pub fn damaged_pattern(w: u32, h: u32, feature_px: f64, seed: u64) -> DamagedPattern {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let area = w as f64 * h as f64;
    let dots: Vec<(f64, f64, f64)> = (0..(area / (feature_px * feature_px * 8.0)) as usize)
        .map(|_| {
            (
                rng.gen_range(0.0..w as f64),
                rng.gen_range(0.0..h as f64),
                rng.gen_range(0.12..0.25) * feature_px,
            )
        })
        .collect();
    let chips: Vec<(f64, f64, f64)> = (0..(area / 2000.0) as usize)
        .map(|_| (rng.gen_range(0.0..w as f64), rng.gen_range(0.0..h as f64), rng.gen_range(0.8..2.5)))
        .collect();
    let stains: Vec<(f64, f64, f64)> = (0..(area / 4000.0) as usize)
        .map(|_| (rng.gen_range(0.0..w as f64), rng.gen_range(0.0..h as f64), rng.gen_range(0.6..1.8)))
        .collect();
    let phase: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
    // Spatial buckets so each pixel only looks at nearby dots, chips and stains.
    let cell = 64.0;
    let (bw, bh) = ((w as f64 / cell).ceil() as usize + 1, (h as f64 / cell).ceil() as usize + 1);
    let bucket = |items: &[(f64, f64, f64)]| {
        let mut b: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); bw * bh];
        for &(x, y, r) in items {
            let (x0, x1) = (((x - r) / cell).floor().max(0.0) as usize, ((x + r) / cell) as usize);
            let (y0, y1) = (((y - r) / cell).floor().max(0.0) as usize, ((y + r) / cell) as usize);
            for by in y0..=y1.min(bh - 1) {
                for bx in x0..=x1.min(bw - 1) {
                    b[by * bw + bx].push((x, y, r));
                }
            }
        }
        b
    };
    let (dots, chips, stains) = (bucket(&dots), bucket(&chips), bucket(&stains));
    let inside = |b: &[Vec<(f64, f64, f64)>], x: f64, y: f64| {
        b[(y / cell) as usize * bw + (x / cell) as usize]
            .iter()
            .any(|&(cx, cy, r)| (x - cx).hypot(y - cy) < r)
    };
    let pristine_at = |x: f64, y: f64| -> u8 {
        if inside(&dots, x, y) {
            return 2;
        }
        let v = (y + 0.08 * feature_px * (x / feature_px * 1.3 + phase).sin()) / feature_px;
        match (v.rem_euclid(1.0) * 5.0) as u32 {
            0 | 1 => 1,
            3 => 2,
            _ => 0,
        }
    };
    let (wu, hu) = (w as usize, h as usize);
    let mut pristine = vec![0u8; wu * hu];
    let mut damaged = vec![0u8; wu * hu];
    pristine.par_chunks_mut(wu).zip(damaged.par_chunks_mut(wu)).enumerate().for_each(|(y, (p, d))| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (y as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for x in 0..wu {
            let (xf, yf) = (x as f64, y as f64);
            p[x] = pristine_at(xf, yf);
            let jitter = rng.gen_range(-0.7..0.7);
            let mut l = pristine_at(xf, yf + jitter);
            if l != 0 && inside(&chips, xf, yf) {
                l = 0;
            } else if l == 0 && inside(&stains, xf, yf) {
                l = 1;
            }
            d[x] = l;
        }
    });
    DamagedPattern {
        damaged: LabelMap { width: w, height: h, data: damaged },
        pristine: LabelMap { width: w, height: h, data: pristine },
    }
}
