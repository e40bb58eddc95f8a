//! A verified bundle as the player holds it: scenes with their peak lux (frames stay in the
//! loader's store), the projector responses (for cross-fades in linear light), the exposure
//! policy, and what the projectors show ([`Look`]). Only `loader` builds one, after every
//! check passed.
//!
//! Dependencies go one way: `player` uses this module; this module does not use `player`.

/// What the projectors show.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Look {
    /// A scene's frames, by index into [`Show::scenes`].
    Scene(usize),
    /// Black frames with the projectors on.
    Black,
    /// Outputs blanked (dark).
    Off,
    /// Projector `k`'s commissioning pattern (`identify`), the others black.
    Identify(usize),
}

/// What a scene is for: the bundle manifest's scene kind. `Original` may be shown while idle
/// when configured; the first press shows the first `Restoration`; `Relit` variants follow.
pub use restage_shared::bundle::SceneKind;

/// One scene: a frame per projector and the peak illuminance it puts on the object.
#[derive(Clone, Debug)]
pub struct Scene {
    pub id: String,
    pub name: String,
    pub kind: SceneKind,
    /// Peak illuminance on the object in lux, recomputed by the appliance from the light
    /// certificate (not taken from the manifest).
    pub peak_lux: f64,
}

/// The exposure policy the player and the ledger enforce.
#[derive(Clone, Debug, PartialEq)]
pub struct Policy {
    /// Longest continuous lit showing, cross-fade included (ms).
    pub max_showing_ms: u64,
    /// Dark (or idle) time after a showing before the next may start (ms).
    pub cooldown_ms: u64,
    /// Lux-hours allowed per local calendar day.
    pub daily_lux_hours: f64,
    /// Lux-hours allowed in any 365 days.
    pub annual_lux_hours: f64,
    /// Fractions of a budget at which operators are warned, ascending (e.g. 0.75, 0.9).
    pub warn_at: Vec<f64>,
}

/// A projector's response: relative light output (0 = black level, 1 = full white) for each
/// 8-bit value of each channel (R, G, B). Non-decreasing in the value.
#[derive(Clone, Debug)]
pub struct Response {
    pub rgb: [[f32; 256]; 3],
}

impl Response {
    /// A power-law response `(v/255)^gamma` on every channel.
    pub fn gamma(gamma: f32) -> Response {
        let mut lut = [0f32; 256];
        for (v, out) in lut.iter_mut().enumerate() {
            *out = (v as f32 / 255.0).powf(gamma);
        }
        Response { rgb: [lut; 3] }
    }

    /// Largest value whose light output is at most `light`: rounding down keeps a mixed frame
    /// at or under the linear mix of its sources, so under the bound.
    fn inverse_floor(lut: &[f32; 256], light: f32) -> u8 {
        let n = lut.partition_point(|&x| x <= light);
        n.saturating_sub(1) as u8
    }
}

/// The loaded, verified content.
#[derive(Clone, Debug)]
pub struct Show {
    pub object_id: String,
    pub version: u64,
    /// Hex hash identifying the bundle file (for status and logs).
    pub bundle_hash: String,
    /// (width, height) per projector.
    pub projectors: Vec<(u32, u32)>,
    pub scenes: Vec<Scene>,
    /// Illuminance of the projectors' black level (all frames 0), in lux.
    pub black_lux: f64,
    /// One per projector.
    pub responses: Vec<Response>,
    pub policy: Policy,
    /// What the projectors show between showings (the policy's, or a darker configured one).
    pub idle: Look,
    /// When the bundle stops being valid (Unix ms), if ever.
    pub expires_unix_ms: Option<i64>,
    /// Each projector's commissioning pattern within the bound (`identify`), if it has one.
    pub identify: Vec<Option<crate::identify::Pattern>>,
}

impl Show {
    /// Index of the original scene, if the bundle has one.
    pub fn original(&self) -> Option<usize> {
        self.scenes.iter().position(|s| s.kind == SceneKind::Original)
    }

    /// The scenes a press cycles through: restorations first, then relit variants.
    pub fn cycle(&self) -> Vec<usize> {
        let of = |k| self.scenes.iter().enumerate().filter(move |(_, s)| s.kind == k).map(|(i, _)| i);
        of(SceneKind::Restoration).chain(of(SceneKind::Relit)).collect()
    }
}

/// Mixes frame `a` towards frame `b` by `t` (0 = a, 1 = b) in linear light through the
/// projector's response, rounding down, so the light of every pixel is at most
/// `(1-t)·light(a) + t·light(b)`: a cross-fade between two bounded scenes stays bounded.
/// `a`, `b` and `out` are XRGB8888 of equal length.
pub fn mix_linear(a: &[u8], b: &[u8], t: f32, response: &Response, out: &mut [u8]) {
    debug_assert!(a.len() == b.len() && a.len() == out.len());
    let t = t.clamp(0.0, 1.0);
    for ((pa, pb), po) in a.chunks_exact(4).zip(b.chunks_exact(4)).zip(out.chunks_exact_mut(4)) {
        // Byte order B, G, R, X; the response is indexed R, G, B.
        for (byte, channel) in [(0usize, 2usize), (1, 1), (2, 0)] {
            let lut = &response.rgb[channel];
            let (va, vb) = (pa[byte], pb[byte]);
            po[byte] = if va == vb {
                va
            } else {
                let light = (1.0 - t) * lut[va as usize] + t * lut[vb as usize];
                Response::inverse_floor(lut, light)
            };
        }
        po[3] = 0;
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    proptest! {
        #[test]
        fn mixed_light_never_exceeds_the_linear_mix(
            a in proptest::collection::vec(any::<u8>(), 64),
            b in proptest::collection::vec(any::<u8>(), 64),
            t in 0f32..=1.0,
            gamma in 1.0f32..3.0,
        ) {
            let r = Response::gamma(gamma);
            let mut out = vec![0u8; 64];
            mix_linear(&a, &b, t, &r, &mut out);
            for i in 0..64 {
                if i % 4 == 3 { continue; }
                let ch = [2, 1, 0][i % 4];
                let lut = &r.rgb[ch];
                let mix = (1.0 - t) * lut[a[i] as usize] + t * lut[b[i] as usize];
                prop_assert!(lut[out[i] as usize] <= mix.max(lut[a[i] as usize].min(lut[b[i] as usize])) + 1e-6);
                // and it is the closest such value: one step up would exceed the mix
                if out[i] < 255 && a[i] != b[i] {
                    prop_assert!(lut[out[i] as usize + 1] > mix);
                }
            }
        }
    }

    #[test]
    fn endpoints_are_the_sources() {
        let r = Response::gamma(2.2);
        let a: Vec<u8> = (0..=255).collect();
        let b: Vec<u8> = (0..=255).rev().collect();
        let mut out = vec![0u8; 256];
        mix_linear(&a, &b, 0.0, &r, &mut out);
        for i in (0..256).filter(|i| i % 4 != 3) {
            assert_eq!(out[i], a[i]);
        }
        mix_linear(&a, &b, 1.0, &r, &mut out);
        for i in (0..256).filter(|i| i % 4 != 3) {
            assert_eq!(out[i], b[i]);
        }
    }
}
