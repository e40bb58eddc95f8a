//! Inverting a projector's measured response: relative light output (above black) to the
//! 8-bit value that produces it, by table look-up (the response is monotonic).

/// Table size. The table is indexed by `sqrt(r)` so that it is fine near black, where a
/// gamma-like response has its smallest steps (level 1 of a gamma-2.6 curve is 6e-7).
const STEPS: usize = 1 << 16;

/// Inverse of one channel's response curve (`response[0] == 0`, `response[255] == 1`).
#[derive(Clone, Debug)]
pub struct InverseResponse {
    /// The forward curve, 256 entries.
    pub forward: [f32; 256],
    nearest: Vec<u8>,
}

impl InverseResponse {
    /// Builds the inverse of a monotonic non-decreasing curve of 256 entries. Non-monotonic
    /// input is made monotonic by a running maximum (a calibrated curve should already be).
    pub fn new(curve: &[f32]) -> Self {
        let mut forward = [0.0f32; 256];
        let mut run = f32::NEG_INFINITY;
        for (f, &c) in forward.iter_mut().zip(curve) {
            run = run.max(if c.is_finite() { c } else { 0.0 });
            *f = run;
        }
        let mut nearest = vec![0u8; STEPS];
        let mut v = 0usize;
        for (q, out) in nearest.iter_mut().enumerate() {
            let r = (q as f32 / (STEPS - 1) as f32).powi(2);
            while v < 255 && forward[v + 1] <= r {
                v += 1;
            }
            // forward[v] <= r < forward[v + 1] (or v == 255): pick the closer level.
            *out = if v < 255 && forward[v + 1] - r < r - forward[v] { v as u8 + 1 } else { v as u8 };
        }
        Self { forward, nearest }
    }

    /// The 8-bit value whose output is closest to `r` (clamped to 0..=1).
    #[inline]
    pub fn nearest(&self, r: f32) -> u8 {
        let q = (r.clamp(0.0, 1.0).sqrt() * (STEPS - 1) as f32 + 0.5) as usize;
        self.nearest[q.min(STEPS - 1)]
    }

    /// The look-up table behind [`Self::nearest`]: entry `q` is the level nearest to
    /// `(q / (len - 1))^2` (the GPU path uploads it).
    pub fn table(&self) -> &[u8] {
        &self.nearest
    }

    /// The largest 8-bit value whose output does not exceed `r` (never rounds light up).
    pub fn floor(&self, r: f32) -> u8 {
        let v = self.forward.partition_point(|&f| f <= r);
        v.saturating_sub(1) as u8
    }

    /// Relative output of value `v`.
    #[inline]
    pub fn output(&self, v: u8) -> f32 {
        self.forward[v as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gamma() -> Vec<f32> {
        (0..256).map(|i| (i as f32 / 255.0).powf(2.2)).collect()
    }

    #[test]
    fn nearest_round_trips_every_level() {
        let inv = InverseResponse::new(&gamma());
        for v in 0..=255u8 {
            assert_eq!(inv.nearest(inv.output(v)), v, "level {v}");
            assert_eq!(inv.floor(inv.output(v)), v);
        }
        assert_eq!(inv.nearest(2.0), 255);
        assert_eq!(inv.nearest(-1.0), 0);
    }

    #[test]
    fn floor_never_exceeds_and_nearest_is_within_half_a_step() {
        let inv = InverseResponse::new(&gamma());
        for i in 0..=1000 {
            let r = i as f32 / 1000.0;
            assert!(inv.output(inv.floor(r)) <= r);
            let v = inv.nearest(r);
            let err = (inv.output(v) - r).abs();
            let lo = inv.output(v.saturating_sub(1));
            let hi = inv.output(v.saturating_add(1));
            assert!(err <= (r - lo).abs() + 1e-4 && err <= (hi - r).abs() + 1e-4, "r {r} -> {v}");
        }
    }
}
