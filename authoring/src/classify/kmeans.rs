//! Lloyd's k-means over 3-channel pixel features under the Euclidean distance, fast and
//! deterministic: features are f32 structure-of-arrays, pixels are processed in fixed-size
//! chunks in parallel (rayon) and per-chunk sums (f64) are reduced in chunk order, so the
//! result does not depend on the number of threads.
//!
//! The calibrated distance of Eq. 1 is Euclidean after scaling each channel by `sqrt(a_k)`,
//! so the same engine runs ours and the plain baselines. Ours may also give every cluster
//! its own metric (a symmetric precision matrix, [`Precision`]): the squared Mahalanobis
//! distance `(f - c)^T P (f - c)`, with Euclidean as `P = I`.

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

/// A cluster's metric: the symmetric 3x3 precision matrix `[p00, p11, p22, p01, p02, p12]`.
pub type Precision = [f32; 6];

/// The Euclidean metric.
pub const IDENTITY: Precision = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];

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
///
/// Cluster sums are accumulated in full on the first pass and then updated only by the pixels
/// that change cluster, so later passes cost little more than the distance computations.
pub fn lloyd(features: &Features, init: &[[f32; 3]], labels: &mut [u8], max_iterations: u32) -> KMeansResult {
    lloyd_metric(features, init, None, labels, max_iterations)
}

/// [`lloyd`] with one metric per cluster (`None`: Euclidean for all). The metrics stay fixed;
/// iterations move the centroids to their clusters' means.
pub fn lloyd_metric(
    features: &Features,
    init: &[[f32; 3]],
    metrics: Option<&[Precision]>,
    labels: &mut [u8],
    max_iterations: u32,
) -> KMeansResult {
    if let Some(m) = metrics {
        assert_eq!(m.len(), init.len(), "one metric per cluster");
    }
    assert!(!init.is_empty() && init.len() < MASKED as usize, "1..255 clusters");
    assert_eq!(labels.len(), features.len());
    let k = init.len();
    let mut centroids = init.to_vec();
    let mut sums = vec![[0f64; 4]; k];
    let mut iterations = 0;
    let mut converged = false;
    while iterations < max_iterations {
        iterations += 1;
        let (changed, delta) = match metrics {
            None => assign(features, &centroids, labels, iterations == 1),
            Some(m) => assign_metric(features, &centroids, m, labels, iterations == 1),
        };
        for (s, d) in sums.iter_mut().zip(&delta) {
            for j in 0..4 {
                s[j] += d[j];
            }
        }
        for (c, s) in centroids.iter_mut().zip(&sums) {
            if s[3] > 0.5 {
                *c = [0, 1, 2].map(|j| (s[j] / s[3]) as f32);
            }
        }
        if changed == 0 {
            converged = true;
            break;
        }
    }
    let counts = sums.iter().map(|s| s[3].round() as u64).collect();
    KMeansResult { centroids, counts, iterations, converged }
}

/// Assigns every unmasked pixel to its nearest centroid. Returns how many labels changed and
/// the change of the per-cluster `[sum0, sum1, sum2, count]`: on the `first` pass every pixel
/// counts as newly assigned (its old label is ignored).
fn assign(
    features: &Features,
    centroids: &[[f32; 3]],
    labels: &mut [u8],
    first: bool,
) -> (u64, Vec<[f64; 4]>) {
    match centroids.len() {
        2 => assign_k::<2>(features, centroids, labels, first),
        3 => assign_k::<3>(features, centroids, labels, first),
        4 => assign_k::<4>(features, centroids, labels, first),
        5 => assign_k::<5>(features, centroids, labels, first),
        6 => assign_k::<6>(features, centroids, labels, first),
        7 => assign_k::<7>(features, centroids, labels, first),
        8 => assign_k::<8>(features, centroids, labels, first),
        _ => assign_dyn(features, centroids, labels, first),
    }
}

/// The nearest centroid: argmin |f - c|^2 = argmin (|c|^2 - 2 f.c), three multiply-adds per
/// cluster; ties go to the lower index.
#[inline(always)]
fn nearest(f: [f32; 3], cc: &[f32], c2: &[[f32; 3]]) -> u8 {
    let mut best = 0u8;
    let mut best_d = cc[0] + f[0] * c2[0][0] + f[1] * c2[0][1] + f[2] * c2[0][2];
    for j in 1..cc.len() {
        let d = cc[j] + f[0] * c2[j][0] + f[1] * c2[j][1] + f[2] * c2[j][2];
        if d < best_d {
            best_d = d;
            best = j as u8;
        }
    }
    best
}

/// Squared Mahalanobis distance `(f - c)^T P (f - c)` under a packed precision.
#[inline(always)]
pub fn mahalanobis2(f: [f32; 3], c: [f32; 3], p: &Precision) -> f32 {
    let d = [f[0] - c[0], f[1] - c[1], f[2] - c[2]];
    p[0] * d[0] * d[0]
        + p[1] * d[1] * d[1]
        + p[2] * d[2] * d[2]
        + 2.0 * (p[3] * d[0] * d[1] + p[4] * d[0] * d[2] + p[5] * d[1] * d[2])
}

/// [`assign`] under per-cluster metrics: argmin over clusters of `(f - c)^T P (f - c)`; ties
/// go to the lower index.
fn assign_metric(
    features: &Features,
    centroids: &[[f32; 3]],
    metrics: &[Precision],
    labels: &mut [u8],
    first: bool,
) -> (u64, Vec<[f64; 4]>) {
    let cm: Vec<([f32; 3], Precision)> = centroids.iter().copied().zip(metrics.iter().copied()).collect();
    assign_with(features, labels, first, centroids.len(), |f| {
        let mut best = 0u8;
        let mut best_d = f32::INFINITY;
        for (j, (c, p)) in cm.iter().enumerate() {
            let v = mahalanobis2(f, *c, p);
            if v < best_d {
                best_d = v;
                best = j as u8;
            }
        }
        best
    })
}

/// [`assign`] with the cluster count known at compile time (the loops unroll).
fn assign_k<const K: usize>(
    features: &Features,
    centroids: &[[f32; 3]],
    labels: &mut [u8],
    first: bool,
) -> (u64, Vec<[f64; 4]>) {
    let cc: [f32; K] = std::array::from_fn(|j| centroids[j].iter().map(|v| v * v).sum());
    let c2: [[f32; 3]; K] = std::array::from_fn(|j| centroids[j].map(|v| -2.0 * v));
    assign_with(features, labels, first, K, |f| nearest(f, &cc, &c2))
}

fn assign_dyn(
    features: &Features,
    centroids: &[[f32; 3]],
    labels: &mut [u8],
    first: bool,
) -> (u64, Vec<[f64; 4]>) {
    let cc: Vec<f32> = centroids.iter().map(|c| c.iter().map(|v| v * v).sum()).collect();
    let c2: Vec<[f32; 3]> = centroids.iter().map(|c| c.map(|v| -2.0 * v)).collect();
    assign_with(features, labels, first, centroids.len(), |f| nearest(f, &cc, &c2))
}

#[inline(always)]
fn assign_with(
    features: &Features,
    labels: &mut [u8],
    first: bool,
    k: usize,
    nearest: impl Fn([f32; 3]) -> u8 + Sync,
) -> (u64, Vec<[f64; 4]>) {
    let partials: Vec<(u64, Vec<[f64; 4]>)> = labels
        .par_chunks_mut(CHUNK)
        .zip(features.c[0].par_chunks(CHUNK))
        .zip(features.c[1].par_chunks(CHUNK))
        .zip(features.c[2].par_chunks(CHUNK))
        .map(|(((lab, f0), f1), f2)| {
            let mut delta = vec![[0f64; 4]; k];
            let mut changed = 0u64;
            for i in 0..lab.len() {
                let old = lab[i];
                if old == MASKED {
                    continue;
                }
                let f = [f0[i], f1[i], f2[i]];
                let new = nearest(f);
                if first || new != old {
                    changed += 1;
                    lab[i] = new;
                    let d = &mut delta[new as usize];
                    d[0] += f[0] as f64;
                    d[1] += f[1] as f64;
                    d[2] += f[2] as f64;
                    d[3] += 1.0;
                    if !first {
                        let d = &mut delta[old as usize];
                        d[0] -= f[0] as f64;
                        d[1] -= f[1] as f64;
                        d[2] -= f[2] as f64;
                        d[3] -= 1.0;
                    }
                }
            }
            (changed, delta)
        })
        .collect();
    let mut total = vec![[0f64; 4]; k];
    let mut changed = 0;
    for (c, delta) in partials {
        changed += c;
        for (t, d) in total.iter_mut().zip(&delta) {
            for j in 0..4 {
                t[j] += d[j];
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
            k in 2usize..10,
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
            // Where the two part ways, a near-tie broke otherwise (ours measures `|c|² - 2 f·c`
            // in f32 against f32 centroids, the reference explicit f64 distances) and the runs
            // may settle in different local optima: ours must then still be a Lloyd fixed point,
            // every point at a centroid (its cluster's mean) as near as any other, to f32
            // rounding.
            let fixed_point = || {
                let mut sums = vec![[0f64; 4]; k];
                for (i, &l) in labels.iter().enumerate() {
                    let f = features.get(i);
                    for j in 0..3 { sums[l as usize][j] += f[j] as f64; }
                    sums[l as usize][3] += 1.0;
                }
                let cent: Vec<Option<[f64; 3]>> =
                    sums.iter().map(|s| (s[3] > 0.0).then(|| [s[0] / s[3], s[1] / s[3], s[2] / s[3]])).collect();
                labels.iter().enumerate().all(|(i, &l)| {
                    let f = features.get(i).map(f64::from);
                    let d = |c: &[f64; 3]| (0..3).map(|j| (f[j] - c[j]).powi(2)).sum::<f64>();
                    let own = d(&cent[l as usize].expect("a label's cluster has a member"));
                    let scale = f.iter().map(|v| v * v).sum::<f64>() + 1.0;
                    cent.iter().flatten().all(|c| own <= d(c) + 1e-5 * scale)
                })
            };
            prop_assert!(
                labels == want || (cost(&labels) - cost(&want)).abs() <= 1e-6 * (1.0 + cost(&want)) || fixed_point()
            );
            let mut again = vec![0u8; pts.len()];
            lloyd(&features, &init, &mut again, 100);
            prop_assert_eq!(labels, again);
        }
    }

    #[test]
    fn per_cluster_metrics_follow_each_clusters_spread() {
        // Two clusters at x = 0 and x = 10; the first is wide along x, the second narrow.
        // Euclidean splits at x = 5; the metrics move the boundary towards the narrow one.
        let xs: Vec<f32> = (0..=40).map(|i| i as f32 * 0.25).collect();
        let n = xs.len();
        let features = Features { c: [xs.clone(), vec![0.0; n], vec![0.0; n]] };
        let init = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]];
        let mut eu = vec![0u8; n];
        lloyd(&features, &init, &mut eu, 1);
        let wide = [1.0 / 16.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        let narrow = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        let mut ma = vec![0u8; n];
        let res = lloyd_metric(&features, &init, Some(&[wide, narrow]), &mut ma, 1);
        let first_of = |l: &[u8]| l.iter().position(|&v| v == 1).unwrap();
        // Euclidean: x > 5. Metrics: (x/4)^2 > (10 - x)^2, x > 8 (ties go to the first).
        assert_eq!(xs[first_of(&eu)], 5.25);
        assert_eq!(xs[first_of(&ma)], 8.25);
        assert_eq!(res.counts.iter().sum::<u64>(), n as u64);
        // The identity metric is Euclidean.
        let mut id = vec![0u8; n];
        lloyd_metric(&features, &init, Some(&[IDENTITY, IDENTITY]), &mut id, 1);
        assert_eq!(id, eu);
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
