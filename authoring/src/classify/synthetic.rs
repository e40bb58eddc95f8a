//! Synthetic painted-pattern photos with known labels, for unit tests and benchmarks (the
//! virtual stage makes the realistic ones): bands with a zig-zag edge, horizontal shading as
//! on a vase, and seeded multiplicative and additive noise.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::{ClassifyError, LabelMap};
use crate::imgio::LinearImage;

/// A photo and the label of every pixel.
#[derive(Clone, Debug)]
pub struct SyntheticScene {
    pub photo: LinearImage,
    pub truth: LabelMap,
}

/// Renders `paints` (linear RGB albedo, one per class) as zig-zag bands over a `width` x
/// `height` image, shaded by a factor 0.55..1 across x, with `noise` relative noise.
pub fn painted_pattern(
    width: u32,
    height: u32,
    paints: &[[f32; 3]],
    noise: f32,
    seed: u64,
) -> Result<SyntheticScene, ClassifyError> {
    let mut photo = LinearImage::new(width, height)?;
    let mut truth = LabelMap::new(width, height, 0)?;
    let k = paints.len().max(1);
    let (w, h) = (width as usize, height as usize);
    let bands = (3 * k) as f32;
    photo.data.par_chunks_mut(w).zip(truth.data.par_chunks_mut(w)).enumerate().for_each(|(y, (row, lab))| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let v = y as f32 / h as f32;
        for x in 0..w {
            let u = x as f32 / w as f32;
            let zig = 0.35 * ((u * 24.0).fract() - 0.5).abs();
            let class = ((v * bands + zig) as usize) % k;
            let shade = 0.55 + 0.45 * ((u - 0.5) * std::f32::consts::PI * 0.9).cos();
            let p = paints[class];
            let m = 1.0 + noise * (rng.r#gen::<f32>() * 2.0 - 1.0);
            row[x] = [0, 1, 2].map(|c| (p[c] * shade * m + noise * 0.1 * rng.r#gen::<f32>()).clamp(0.0, 1.0));
            lab[x] = class as u8;
        }
    });
    Ok(SyntheticScene { photo, truth })
}

/// Paints loosely like Casas Grandes pottery: clay, black, red, white slip, brown.
pub const POTTERY_PAINTS: [[f32; 3]; 5] =
    [[0.55, 0.36, 0.22], [0.035, 0.03, 0.028], [0.42, 0.09, 0.05], [0.75, 0.72, 0.64], [0.22, 0.12, 0.07]];
