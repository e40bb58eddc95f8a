//! The calibrated distance of Eq. 1 (with the brief's fix):
//! `D(ci, cj) = a1 (xi - xj)^2 + a2 (yi - yj)^2 + a3 (Yi - Yj)^2`, weights positive and
//! summing to one, fitted by Levenberg-Marquardt to minimise the inverse distances between
//! all pairs of representative colours, so the closest pairs are pushed apart most.
//!
//! The weights are parametrised as `a = floor + (1 - 3 floor) softmax(t1, t2, 0)`: positive and
//! summing to one by construction, so LM runs unconstrained on `(t1, t2)`.

use nalgebra::{Matrix2, Vector2};

/// Smallest weight any channel gets, so every weight stays strictly positive even when the
/// optimum lies on the simplex's edge (e.g. a greyscale photo, where only Y separates).
pub const WEIGHT_FLOOR: f64 = 0.01;

/// The result of the fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightFit {
    /// `[a1, a2, a3]`.
    pub weights: [f64; 3],
    /// Sum over pairs of `1 / D^2` at the solution.
    pub cost: f64,
    pub iterations: u32,
}

/// Weights from the two free parameters.
pub fn weights_from_params(t: [f64; 2]) -> [f64; 3] {
    let m = t[0].max(t[1]).max(0.0);
    let e = [(t[0] - m).exp(), (t[1] - m).exp(), (-m).exp()];
    let s = e[0] + e[1] + e[2];
    e.map(|v| WEIGHT_FLOOR + (1.0 - 3.0 * WEIGHT_FLOOR) * v / s)
}

/// Squared per-channel differences of every pair `i < j` of colours.
pub fn pair_differences(colours: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for (i, a) in colours.iter().enumerate() {
        for b in &colours[i + 1..] {
            out.push([0, 1, 2].map(|c| (a[c] - b[c]).powi(2)));
        }
    }
    out
}

/// The objective `sum 1/D^2` for given weights.
pub fn cost(pairs: &[[f64; 3]], w: [f64; 3]) -> f64 {
    pairs.iter().map(|s| (w[0] * s[0] + w[1] * s[1] + w[2] * s[2]).powi(-2)).sum()
}

/// Fits the weights for representative colours (each `[x, y, Y]`, Y already scaled).
/// Every pair must differ in some channel (the caller checks; a zero distance has no inverse).
pub fn fit_weights(colours: &[[f64; 3]]) -> WeightFit {
    let pairs = pair_differences(colours);
    // From equal weights first; where the optimum lies near an edge of the simplex the
    // softmax saturates on the way and LM can stall short of it, so it also starts near each
    // corner, and a start replaces the first result only when it is clearly better.
    let mut best = lm_from(&pairs, Vector2::zeros());
    for start in [[4.0, 0.0], [0.0, 4.0], [-4.0, -4.0]] {
        let fit = lm_from(&pairs, Vector2::from(start));
        if fit.cost < best.cost * (1.0 - 1e-9) {
            best = WeightFit { iterations: best.iterations + fit.iterations, ..fit };
        } else {
            best.iterations += fit.iterations;
        }
    }
    best
}

/// Levenberg-Marquardt on the two softmax parameters from `t`.
fn lm_from(pairs: &[[f64; 3]], mut t: Vector2<f64>) -> WeightFit {
    let mut w = weights_from_params([t[0], t[1]]);
    let mut c = cost(pairs, w);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..200 {
        iterations += 1;
        // Residuals r_p = 1/D_p; dr/da_k = -s_pk / D^2; da/dt through the softmax.
        let sm = {
            let m = t[0].max(t[1]).max(0.0);
            let e = [(t[0] - m).exp(), (t[1] - m).exp(), (-m).exp()];
            let s = e[0] + e[1] + e[2];
            e.map(|v| v / s)
        };
        let scale = 1.0 - 3.0 * WEIGHT_FLOOR;
        let mut jtj = Matrix2::zeros();
        let mut jtr = Vector2::zeros();
        for s in pairs {
            let d = w[0] * s[0] + w[1] * s[1] + w[2] * s[2];
            let r = 1.0 / d;
            let dr_da = s.map(|v| -v / (d * d));
            let mut row = Vector2::zeros();
            for m in 0..2 {
                for k in 0..3 {
                    let da_dt = scale * sm[k] * (f64::from(u8::from(k == m)) - sm[m]);
                    row[m] += dr_da[k] * da_dt;
                }
            }
            jtj += row * row.transpose();
            jtr += row * r;
        }
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj;
            for i in 0..2 {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = a.lu().solve(&(-jtr)) else {
                lambda *= 10.0;
                continue;
            };
            // Beyond |t| ~ 30 the softmax is saturated; keep the parameters finite.
            let t_new = (t + step).map(|v| v.clamp(-30.0, 30.0));
            let w_new = weights_from_params([t_new[0], t_new[1]]);
            let c_new = cost(pairs, w_new);
            if c_new < c {
                let rel = (c - c_new) / c;
                t = t_new;
                w = w_new;
                c = c_new;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    WeightFit { weights: w, cost: c, iterations }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// Reference minimiser: a dense grid over the (floored) simplex, refined twice.
    fn grid_minimum(colours: &[[f64; 3]]) -> [f64; 3] {
        let pairs = pair_differences(colours);
        let lo = WEIGHT_FLOOR;
        let (mut c1, mut c2, mut half) = (1.0 / 3.0, 1.0 / 3.0, 0.5);
        for _ in 0..4 {
            let mut best = (f64::INFINITY, c1, c2);
            for i in 0..=200 {
                for j in 0..=200 {
                    let a1 = c1 - half + 2.0 * half * i as f64 / 200.0;
                    let a2 = c2 - half + 2.0 * half * j as f64 / 200.0;
                    let a3 = 1.0 - a1 - a2;
                    if a1 < lo || a2 < lo || a3 < lo {
                        continue;
                    }
                    let v = cost(&pairs, [a1, a2, a3]);
                    if v < best.0 {
                        best = (v, a1, a2);
                    }
                }
            }
            (c1, c2, half) = (best.1, best.2, half / 20.0);
        }
        [c1, c2, 1.0 - c1 - c2]
    }

    #[test]
    fn recovers_the_analytic_optimum_of_axis_separated_colours() {
        // Three colours each separated from a base along one channel only, far enough from one
        // another that the cross pairs hardly count: the optimum is a_k ~ s_k^(-2/3).
        let s = [0.04f64, 0.09, 0.16];
        let base = [0.3, 0.3, 0.3];
        let c = [
            base,
            [base[0] + s[0].sqrt(), base[1], base[2]],
            [base[0], base[1] + s[1].sqrt(), base[2]],
            [base[0], base[1], base[2] + s[2].sqrt()],
        ];
        let fit = fit_weights(&c);
        let want = grid_minimum(&c);
        for k in 0..3 {
            assert!((fit.weights[k] - want[k]).abs() < 2e-3, "{:?} vs {want:?}", fit.weights);
        }
        // The near-analytic shape: smaller separations get larger weights.
        assert!(fit.weights[0] > fit.weights[1] && fit.weights[1] > fit.weights[2], "{:?}", fit.weights);
    }

    #[test]
    fn greyscale_colours_put_the_weight_on_luminance() {
        let d65 = crate::color::D65_XY;
        let c = [[d65[0], d65[1], 0.1], [d65[0], d65[1], 0.5], [d65[0], d65[1], 0.9]];
        let fit = fit_weights(&c);
        assert!(fit.weights[2] > 0.97, "{:?}", fit.weights);
    }

    #[test]
    fn an_optimum_at_the_simplex_edge_is_reached() {
        // Found by the property test below: from equal weights alone LM stalled 0.5 % above
        // the grid's minimum, with the luminance weight at its floor.
        let c = [
            [0.19050426560235956, 0.4281330908822376, 0.7893562306969152],
            [0.15, 0.3747078460073581, 0.7807532843868071],
            [0.15, 0.15, 0.7890903478224329],
            [0.425450707698237, 0.4075801277908443, 0.38807470711769715],
        ];
        let fit = fit_weights(&c);
        let pairs = pair_differences(&c);
        let want = cost(&pairs, grid_minimum(&c));
        assert!(fit.cost <= want * (1.0 + 1e-3), "{:?} {} vs {want}", fit.weights, fit.cost);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn weights_are_positive_sum_to_one_and_match_the_grid(
            cols in proptest::collection::vec((0.15f64..0.55, 0.15f64..0.55, 0.0f64..1.0), 2..6)
        ) {
            let c: Vec<[f64; 3]> = cols.iter().map(|&(x, y, l)| [x, y, l]).collect();
            prop_assume!(pair_differences(&c).iter().all(|s| s[0] + s[1] + s[2] > 1e-4));
            let fit = fit_weights(&c);
            prop_assert!(fit.weights.iter().all(|&w| w >= WEIGHT_FLOOR * 0.999));
            prop_assert!((fit.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            let want = grid_minimum(&c);
            let pairs = pair_differences(&c);
            // LM must be at least as good as the grid, up to a small relative tolerance.
            prop_assert!(fit.cost <= cost(&pairs, want) * (1.0 + 1e-3), "{:?} {} vs {want:?} {}",
                fit.weights, fit.cost, cost(&pairs, want));
        }
    }
}
