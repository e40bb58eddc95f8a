//! Lloyd's k-means over 3-channel pixel features under the Euclidean distance, fast and
//! deterministic: features are f32 structure-of-arrays, pixels are processed in fixed-size
//! chunks in parallel (rayon) and per-chunk sums (f64) are reduced in chunk order, so the
//! result does not depend on the number of threads.
//!
//! The calibrated distance of Eq. 1 is Euclidean after scaling each channel by `sqrt(a_k)`,
//! so the same engine runs ours and the plain baselines.

use rayon::prelude::*;

use super::MASKED;

/// Pixels per parallel work item (fixed: it fixes the order of the floating-point sums).
const CHUNK: usize = 1 << 15;

/// Per-pixel features, one slice per channel, row-major.
#[derive(Clone, Debug, Default)]
pub struct Features {
    pub c: [Vec<f32>; 3],
}

impl Features {
    pub fn len(&self) -> usize {
        self.c[0].len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Builds features from linear RGB pixels with a per-pixel map, in parallel.
    pub fn from_pixels(pixels: &[[f32; 3]], f: impl Fn([f32; 3]) -> [f32; 3] + Sync) -> Self {
        let n = pixels.len();
        let mut c = [vec![0f32; n], vec![0f32; n], vec![0f32; n]];
        let [c0, c1, c2] = &mut c;
        c0.par_chunks_mut(CHUNK)
            .zip(c1.par_chunks_mut(CHUNK))
            .zip(c2.par_chunks_mut(CHUNK))
            .zip(pixels.par_chunks(CHUNK))
            .for_each(|(((a, b), d), px)| {
                for i in 0..px.len() {
                    let v = f(px[i]);
                    a[i] = v[0];
                    b[i] = v[1];
                    d[i] = v[2];
                }
            });
        Self { c }
    }

    pub fn get(&self, i: usize) -> [f32; 3] {
        [self.c[0][i], self.c[1][i], self.c[2][i]]
    }
}

/// The outcome of Lloyd's iterations.
#[derive(Clone, Debug)]
pub struct KMeansResult {
    /// Final centroids (cluster means; an emptied cluster keeps its last centroid).
    pub centroids: Vec<[f32; 3]>,
    pub counts: Vec<u64>,
    pub iterations: u32,
    /// True when the last iteration changed no label.
    pub converged: bool,
}

/// Runs Lloyd's algorithm from `init` centroids. `labels` holds one entry per pixel: pixels
/// labelled [`MASKED`] on entry are skipped and stay masked; all others get a cluster index.
pub fn lloyd(features: &Features, init: &[[f32; 3]], labels: &mut [u8], max_iterations: u32) -> KMeansResult {
    assert!(!init.is_empty() && init.len() < MASKED as usize, "1..255 clusters");
    assert_eq!(labels.len(), features.len());
    let k = init.len();
    let mut centroids = init.to_vec();
    let mut counts = vec![0u64; k];
    let mut iterations = 0;
    let mut converged = false;
    while iterations < max_iterations {
        iterations += 1;
        let (changed, sums) = assign(features, &centroids, labels, iterations == 1);
        counts = sums.iter().map(|s| s[3] as u64).collect();
        for (c, s) in centroids.iter_mut().zip(&sums) {
            if s[3] > 0.0 {
                *c = [0, 1, 2].map(|j| (s[j] / s[3]) as f32);
            }
        }
        if changed == 0 {
            converged = true;
            break;
        }
    }
    KMeansResult { centroids, counts, iterations, converged }
}

/// Assigns every unmasked pixel to its nearest centroid; returns how many labels changed
/// (all of them when `first`) and per-cluster `[sum0, sum1, sum2, count]`.
fn assign(
    features: &Features,
    centroids: &[[f32; 3]],
    labels: &mut [u8],
    first: bool,
) -> (u64, Vec<[f64; 4]>) {
    let k = centroids.len();
    // argmin |f - c|^2 = argmin (|c|^2 - 2 f.c): three multiply-adds per cluster.
    let cc: Vec<f32> = centroids.iter().map(|c| c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).collect();
    let c2: Vec<[f32; 3]> = centroids.iter().map(|c| c.map(|v| -2.0 * v)).collect();
    let partials: Vec<(u64, Vec<[f64; 4]>)> = labels
        .par_chunks_mut(CHUNK)
        .zip(features.c[0].par_chunks(CHUNK))
        .zip(features.c[1].par_chunks(CHUNK))
        .zip(features.c[2].par_chunks(CHUNK))
        .map(|(((lab, f0), f1), f2)| {
            // f32 sums inside a chunk would lose precision on 32k pixels; f64 is cheap here.
            let mut sums = vec![[0f64; 4]; k];
            let mut changed = 0u64;
            for i in 0..lab.len() {
                let old = lab[i];
                if old == MASKED {
                    continue;
                }
                let (a, b, d) = (f0[i], f1[i], f2[i]);
                let mut best = 0usize;
                let mut best_d = f32::INFINITY;
                for j in 0..k {
                    let dist = cc[j] + a * c2[j][0] + b * c2[j][1] + d * c2[j][2];
                    if dist < best_d {
                        best_d = dist;
                        best = j;
                    }
                }
                let s = &mut sums[best];
                s[0] += a as f64;
                s[1] += b as f64;
                s[2] += d as f64;
                s[3] += 1.0;
                if first || old != best as u8 {
                    changed += 1;
                }
                lab[i] = best as u8;
            }
            (changed, sums)
        })
        .collect();
    let mut total = vec![[0f64; 4]; k];
    let mut changed = 0;
    for (c, sums) in partials {
        changed += c;
        for (t, s) in total.iter_mut().zip(&sums) {
            for j in 0..4 {
                t[j] += s[j];
            }
        }
    }
    (changed, total)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// Plain reference: nearest centroid by explicit distance, means recomputed naively.
    fn reference(features: &Features, init: &[[f32; 3]], max_it: u32) -> Vec<u8> {
        let mut cent: Vec<[f64; 3]> = init.iter().map(|c| c.map(f64::from)).collect();
        let mut labels = vec![0u8; features.len()];
        for _ in 0..max_it {
            let mut changed = false;
            for (i, l) in labels.iter_mut().enumerate() {
                let f = features.get(i).map(f64::from);
                let d = |c: &[f64; 3]| (0..3).map(|j| (f[j] - c[j]).powi(2)).sum::<f64>();
                let best =
                    (0..cent.len()).min_by(|&a, &b| d(&cent[a]).total_cmp(&d(&cent[b]))).unwrap() as u8;
                changed |= best != *l;
                *l = best;
            }
            for (j, c) in cent.iter_mut().enumerate() {
                let members: Vec<usize> = (0..labels.len()).filter(|&i| labels[i] == j as u8).collect();
                if !members.is_empty() {
                    *c = [0, 1, 2].map(|ch| {
                        members.iter().map(|&i| features.c[ch][i] as f64).sum::<f64>() / members.len() as f64
                    });
                }
            }
            if !changed {
                break;
            }
        }
        labels
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        #[test]
        fn matches_the_plain_reference_and_is_deterministic(
            pts in proptest::collection::vec((0i32..40, 0i32..40, 0i32..40), 20..200),
            k in 2usize..5,
        ) {
            // Integer-valued features keep f32 and f64 distances exact, so ties break alike.
            let features = Features { c: [0, 1, 2].map(|j| pts.iter().map(|p| [p.0, p.1, p.2][j] as f32 * 0.25).collect()) };
            let init: Vec<[f32; 3]> = (0..k).map(|i| features.get(i * pts.len() / k)).collect();
            let mut labels = vec![0u8; pts.len()];
            let res = lloyd(&features, &init, &mut labels, 100);
            let want = reference(&features, &init, 100);
            prop_assert!(res.converged);
            // Distances can tie; compare the cost instead of requiring identical labels.
            let cost = |lab: &[u8]| -> f64 {
                let mut sums = vec![[0f64; 4]; k];
                for (i, &l) in lab.iter().enumerate() {
                    let f = features.get(i);
                    for j in 0..3 { sums[l as usize][j] += f[j] as f64; }
                    sums[l as usize][3] += 1.0;
                }
                lab.iter().enumerate().map(|(i, &l)| {
                    let s = sums[l as usize];
                    (0..3).map(|j| (features.get(i)[j] as f64 - s[j] / s[3]).powi(2)).sum::<f64>()
                }).sum()
            };
            prop_assert!((cost(&labels) - cost(&want)).abs() <= 1e-6 * (1.0 + cost(&want)) || labels == want);
            let mut again = vec![0u8; pts.len()];
            lloyd(&features, &init, &mut again, 100);
            prop_assert_eq!(labels, again);
        }
    }

    #[test]
    fn masked_pixels_stay_masked_and_clusters_separate() {
        let n = 100_000;
        let features = Features {
            c: [
                (0..n).map(|i| if i % 2 == 0 { 0.1 } else { 0.9 } + (i % 7) as f32 * 1e-3).collect(),
                vec![0.5; n],
                vec![0.5; n],
            ],
        };
        let mut labels: Vec<u8> = (0..n).map(|i| if i % 10 == 3 { MASKED } else { 0 }).collect();
        let res = lloyd(&features, &[[0.4, 0.5, 0.5], [0.6, 0.5, 0.5]], &mut labels, 50);
        assert!(res.converged && res.iterations <= 3, "{res:?}");
        for (i, &l) in labels.iter().enumerate() {
            if i % 10 == 3 {
                assert_eq!(l, MASKED);
            } else {
                assert_eq!(l, (i % 2) as u8);
            }
        }
        assert_eq!(res.counts.iter().sum::<u64>(), 90_000);
        // Thread count does not change the result.
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut one: Vec<u8> = (0..n).map(|i| if i % 10 == 3 { MASKED } else { 0 }).collect();
        let r1 = pool.install(|| lloyd(&features, &[[0.4, 0.5, 0.5], [0.6, 0.5, 0.5]], &mut one, 50));
        assert_eq!(one, labels);
        assert_eq!(r1.centroids, res.centroids);
    }
}
