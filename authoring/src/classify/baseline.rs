//! Baselines for comparison (the paper's Figure 6e): plain k-means with k-means++
//! initialisation, in RGB (sRGB-encoded, as one would cluster the photo as displayed) and in
//! CIELAB. They know only the number of colours, not the picks, so their clusters come out in
//! arbitrary order; the evaluation matches clusters to classes.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::calibrated::{MAX_CLASSES, initial_labels};
use super::kmeans::{Features, lloyd};
use super::{ClassifyError, LabelMap, MASKED};
use crate::color::xyz_to_lab;
use crate::imgio::{LinearImage, linear_to_srgb};

/// The colour space a baseline clusters in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaselineSpace {
    /// sRGB-encoded RGB, 0..1.
    Rgb,
    /// CIELAB (D65).
    Lab,
}

impl BaselineSpace {
    pub fn name(self) -> &'static str {
        match self {
            Self::Rgb => "k-means++ RGB",
            Self::Lab => "k-means++ Lab",
        }
    }
}

/// Pixels k-means++ draws its seeds from (a seeded sample of the object, for speed).
const SEED_SAMPLE: usize = 20_000;

/// Plain k-means (k-means++ seeding, seeded RNG) with `k` clusters; returns the cluster map
/// and the iterations run.
pub fn kmeans_baseline(
    photo: &LinearImage,
    k: usize,
    mask: Option<&[bool]>,
    space: BaselineSpace,
    seed: u64,
    max_iterations: u32,
) -> Result<(LabelMap, u32), ClassifyError> {
    if !(2..=MAX_CLASSES).contains(&k) {
        return Err(ClassifyError::ClassCount { count: k, max: MAX_CLASSES });
    }
    let features = match space {
        BaselineSpace::Rgb => {
            Features::from_pixels(&photo.data, |p| p.map(|c| linear_to_srgb(c.clamp(0.0, 1.0))))
        }
        BaselineSpace::Lab => Features::from_pixels(&photo.data, |p| {
            let xyz = crate::color::linear_srgb_to_xyz(p.map(f64::from));
            xyz_to_lab(xyz).map(|v| v as f32)
        }),
    };
    let mut labels = initial_labels(photo.data.len(), mask)?;
    let object: Vec<usize> = (0..labels.len()).filter(|&i| labels[i] != MASKED).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sample: Vec<[f32; 3]> = if object.len() <= SEED_SAMPLE {
        object.iter().map(|&i| features.get(i)).collect()
    } else {
        (0..SEED_SAMPLE).map(|_| features.get(object[rng.gen_range(0..object.len())])).collect()
    };
    let init = kmeans_pp(&sample, k, &mut rng);
    let res = lloyd(&features, &init, &mut labels, max_iterations);
    Ok((LabelMap::from_vec(photo.width, photo.height, labels)?, res.iterations))
}

/// k-means++ seeding (Arthur & Vassilvitskii 2007): each next seed drawn with probability
/// proportional to the squared distance to the nearest seed so far.
fn kmeans_pp(points: &[[f32; 3]], k: usize, rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    let d2 = |a: &[f32; 3], b: &[f32; 3]| (0..3).map(|j| ((a[j] - b[j]) as f64).powi(2)).sum::<f64>();
    let mut seeds = vec![points[rng.gen_range(0..points.len())]];
    let mut dist: Vec<f64> = points.iter().map(|p| d2(p, &seeds[0])).collect();
    while seeds.len() < k {
        let total: f64 = dist.iter().sum();
        let next = if total <= 0.0 {
            points[rng.gen_range(0..points.len())]
        } else {
            let mut r = rng.r#gen::<f64>() * total;
            let mut pick = points.len() - 1;
            for (i, d) in dist.iter().enumerate() {
                if r < *d {
                    pick = i;
                    break;
                }
                r -= d;
            }
            points[pick]
        };
        for (d, p) in dist.iter_mut().zip(points) {
            *d = d.min(d2(p, &next));
        }
        seeds.push(next);
    }
    seeds
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::synthetic::painted_pattern;

    #[test]
    fn baselines_find_well_separated_colours_deterministically() {
        let paints = [[0.8f32, 0.1, 0.1], [0.1, 0.7, 0.1], [0.1, 0.1, 0.8]];
        let scene = painted_pattern(80, 60, &paints, 0.02, 9).unwrap();
        for space in [BaselineSpace::Rgb, BaselineSpace::Lab] {
            let (labels, it) = kmeans_baseline(&scene.photo, 3, None, space, 4, 50).unwrap();
            // Clusters are unordered: each true class must map to exactly one cluster.
            let mut map = [None; 3];
            for (t, l) in scene.truth.data.iter().zip(&labels.data) {
                let m = map[*t as usize].get_or_insert(*l);
                assert_eq!(*m, *l, "{space:?}: class {t} split");
            }
            assert!(it >= 2);
            let (again, _) = kmeans_baseline(&scene.photo, 3, None, space, 4, 50).unwrap();
            assert_eq!(again, labels);
        }
    }
}
