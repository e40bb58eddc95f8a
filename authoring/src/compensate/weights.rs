//! Combining projector lights (paper §5.1.2, Eq. 12): `w_ik = L_ik^m / sum_j L_ij^m`, for any
//! m >= 0 including infinity (the single most efficient projector, Eq. 10).

use std::fmt;
use std::str::FromStr;

/// The smoothness exponent `m` of Eq. 12.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exponent {
    /// A finite `m >= 0`: 0 is uniform, 1 linear, larger values favour head-on projectors.
    Finite(f64),
    /// `m = infinity`: each point is lit by its most efficient projector only (ties split).
    Infinite,
}

impl Exponent {
    /// Checks `m >= 0` and finite (use [`Exponent::Infinite`] for infinity).
    pub fn finite(m: f64) -> Result<Self, String> {
        if m.is_finite() && m >= 0.0 {
            Ok(Self::Finite(m))
        } else {
            Err(format!("smoothness exponent m = {m} is invalid (expected a number >= 0, or \"inf\")"))
        }
    }
}

impl fmt::Display for Exponent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Finite(m) => write!(f, "{m}"),
            Self::Infinite => write!(f, "inf"),
        }
    }
}

impl FromStr for Exponent {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "inf" | "infinity" | "∞" | "max" => Ok(Self::Infinite),
            t => match t.parse::<f64>() {
                Ok(m) if m.is_infinite() && m > 0.0 => Ok(Self::Infinite),
                Ok(m) => Self::finite(m),
                Err(_) => {
                    Err(format!("smoothness exponent {s:?} is not a number (expected >= 0, or \"inf\")"))
                }
            },
        }
    }
}

/// Writes the weights of one point into `w` from its efficiencies `l` (0 where a projector
/// does not see the point). Weights of visible projectors sum to 1; all zero if none sees it.
pub fn point_weights(l: &[f32], m: Exponent, w: &mut [f32]) {
    debug_assert_eq!(l.len(), w.len());
    let lmax = l.iter().copied().fold(0.0f32, f32::max);
    w.iter_mut().for_each(|x| *x = 0.0);
    if lmax <= 0.0 || !lmax.is_finite() {
        return;
    }
    match m {
        Exponent::Infinite => {
            // Ties (within float noise) share the light equally so the result is symmetric.
            let tie = |x: f32| x >= lmax * (1.0 - 1e-6);
            let count = l.iter().filter(|&&x| tie(x)).count() as f32;
            for (wi, &li) in w.iter_mut().zip(l) {
                if tie(li) {
                    *wi = 1.0 / count;
                }
            }
        }
        Exponent::Finite(m) => {
            // Normalising by the largest L keeps L^m finite for any m.
            let mut sum = 0.0f64;
            for (wi, &li) in w.iter_mut().zip(l) {
                if li > 0.0 {
                    let v = (li as f64 / lmax as f64).powf(m);
                    *wi = v as f32;
                    sum += v;
                }
            }
            for wi in w.iter_mut() {
                *wi = (*wi as f64 / sum) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_cases_match_the_paper() {
        let l = [4.0, 1.0, 0.0];
        let mut w = [0.0; 3];
        point_weights(&l, Exponent::Finite(0.0), &mut w);
        assert_eq!(w, [0.5, 0.5, 0.0], "uniform over the projectors that see the point");
        point_weights(&l, Exponent::Finite(1.0), &mut w);
        assert!((w[0] - 0.8).abs() < 1e-6 && (w[1] - 0.2).abs() < 1e-6 && w[2] == 0.0);
        point_weights(&l, Exponent::Infinite, &mut w);
        assert_eq!(w, [1.0, 0.0, 0.0]);
        point_weights(&[2.0, 2.0], Exponent::Infinite, &mut [0.0; 2]);
        point_weights(&[0.0, 0.0], Exponent::Finite(3.0), &mut w[..2]);
        assert_eq!(&w[..2], &[0.0, 0.0]);
    }

    #[test]
    fn large_m_approaches_infinity_without_overflow() {
        let l = [1e6, 0.9e6, 1e-3];
        let mut w = [0.0; 3];
        point_weights(&l, Exponent::Finite(400.0), &mut w);
        assert!(w[0] > 0.999 && w.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn parsing_accepts_infinity_and_refuses_negatives() {
        assert_eq!("inf".parse::<Exponent>().unwrap(), Exponent::Infinite);
        assert_eq!("8".parse::<Exponent>().unwrap(), Exponent::Finite(8.0));
        let err = "-1".parse::<Exponent>().unwrap_err();
        assert!(err.contains(">= 0"), "{err}");
        assert!("NaN".parse::<Exponent>().is_err());
        assert!("abc".parse::<Exponent>().is_err());
    }
}
