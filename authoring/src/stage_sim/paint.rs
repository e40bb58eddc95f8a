//! Painted albedo of the virtual objects: a few-colour design per scene (bands, zig-zags,
//! spirals, dots) and a seeded deterioration (chips showing the clay, cracks, stains,
//! fading, grain). Everything is a function of surface coordinates (azimuth, height, radius),
//! so it does not depend on the camera.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::imgio::srgb_to_linear;

/// One paint colour (class) of a scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaintClass {
    pub name: String,
    /// The colour as 8-bit sRGB, for people.
    pub srgb: [u8; 3],
    /// True linear albedo (0..1 per channel), what the renderer uses.
    pub albedo: [f32; 3],
}

/// The classes of a scene: index 0 is the background slip; the last is the bare clay that
/// chips and cracks expose (it does not occur on the pristine object).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Palette {
    pub classes: Vec<PaintClass>,
    /// Index of the background (ground) colour the design is painted on.
    pub background: u8,
    /// Index of the exposed clay class.
    pub clay: u8,
}

fn class(name: &str, srgb: [u8; 3]) -> PaintClass {
    PaintClass { name: name.into(), srgb, albedo: srgb.map(|c| srgb_to_linear(c as f32 / 255.0)) }
}

/// The built-in designs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum Design {
    /// Bands, a zig-zag frieze and dots (Casas Grandes style); 4 colours.
    Vase,
    /// A spiral with a rim band and dots (Majiayao style); 3 colours.
    Bowl,
    /// Bands, zig-zag and checker-dots on the shoulder; 5 colours.
    Jar,
    /// A flat painted panel (a rosette of petals, rings, dots and a border), drawn on the
    /// panel's face unrolled as a cylinder of radius [`PANEL_UNROLL_MM`] (see `class_at`);
    /// 4 colours.
    Panel,
    /// One uniform colour, for closed-form tests.
    Uniform,
}

/// Radius of the cylinder a flat panel's face is unrolled onto, so that the designs and the
/// deterioration, written in (azimuth, height) on a solid of revolution, paint a plane too:
/// face point `(x, y)` is azimuth `x / PANEL_UNROLL_MM`, height `y + PANEL_RADIUS_MM`.
pub const PANEL_UNROLL_MM: f64 = 100.0;
/// The panel's radius (a round panel, 12 mm thick).
pub const PANEL_RADIUS_MM: f64 = 160.0;
pub const PANEL_THICKNESS_MM: f64 = 12.0;

impl Design {
    pub fn palette(self) -> Palette {
        let clay = class("clay", [150, 96, 66]);
        let mut classes = match self {
            Design::Vase | Design::Panel => vec![
                class("slip", [226, 206, 170]),
                class("black", [48, 38, 34]),
                class("red", [168, 52, 38]),
                class("ochre", [214, 160, 48]),
            ],
            Design::Bowl => {
                vec![
                    class("slip", [222, 198, 158]),
                    class("black", [40, 32, 30]),
                    class("red", [160, 48, 40]),
                ]
            }
            Design::Jar => vec![
                class("slip", [232, 222, 196]),
                class("black", [44, 36, 34]),
                class("red", [170, 56, 40]),
                class("ochre", [212, 158, 52]),
                class("grey-blue", [86, 104, 120]),
            ],
            Design::Uniform => vec![class("grey", [188, 188, 188])],
        };
        classes.push(clay);
        Palette { clay: (classes.len() - 1) as u8, classes, background: 0 }
    }

    /// Pristine class at azimuth `theta` (radians), height `h` and radius `r` (mm).
    pub fn class_at(self, theta: f64, h: f64, r: f64) -> u8 {
        use std::f64::consts::TAU;
        let s = theta * r; // arc length from azimuth 0
        let tri = |x: f64| 2.0 * (x - (x + 0.5).floor()).abs(); // triangle wave 0..1, period 1
        match self {
            Design::Uniform => 0,
            Design::Vase => {
                let band = |a: f64, b: f64| h >= a && h < b;
                if band(58.0, 64.0) || band(196.0, 202.0) || band(276.0, 281.0) {
                    return 1;
                }
                if band(66.0, 74.0) || band(186.0, 194.0) {
                    return 2;
                }
                if band(80.0, 182.0) {
                    // Zig-zag frieze with eight teeth around.
                    let teeth = 8.0;
                    let c = 131.0 + 38.0 * (2.0 * tri(theta * teeth / TAU) - 1.0);
                    if (h - c).abs() < 5.5 {
                        return 1;
                    }
                    // Dots in the triangles above and below the zig-zag.
                    let cell = TAU / teeth;
                    let k = (theta / cell).round();
                    let ds = (theta - k * cell) * r;
                    for hc in [104.0, 158.0] {
                        if ds.hypot(h - hc) < 7.0 {
                            return if hc < 131.0 { 2 } else { 3 };
                        }
                    }
                    return 0;
                }
                if band(210.0, 268.0) {
                    // Ochre vertical strokes on the neck.
                    let k = (s / 16.0).round();
                    if (s - k * 16.0).abs() < 3.0 {
                        return 3;
                    }
                }
                0
            }
            Design::Bowl => {
                if h > 136.0 {
                    return 2;
                }
                if (128.0..133.0).contains(&h) {
                    return 1;
                }
                if (22.0..124.0).contains(&h) {
                    // Two interleaved spirals rising 60 mm per turn.
                    let u = (h + 60.0 * theta / TAU) / 60.0;
                    let f = u - u.floor();
                    if f < 0.18 {
                        return 1;
                    }
                    if (0.5..0.58).contains(&f) {
                        return 2;
                    }
                    // Dots between the spiral arms.
                    let row = (h / 24.0).round();
                    let col = (s / 24.0).round();
                    if (f > 0.28 && f < 0.42) && (s - col * 24.0).hypot(h - row * 24.0) < 4.5 {
                        return 2;
                    }
                }
                0
            }
            Design::Panel => {
                // Back on the face: x along the unrolled azimuth, y up from the centre.
                let (x, y) = (s, h - PANEL_RADIUS_MM);
                let rho = x.hypot(y);
                let phi = y.atan2(x);
                if (140.0..148.0).contains(&rho) {
                    return 1;
                }
                if (120.0..126.0).contains(&rho) {
                    return 2;
                }
                if rho < 25.0 {
                    return 3;
                }
                if rho < 29.0 {
                    return 1;
                }
                if (40.0..105.0).contains(&rho) {
                    // Eight petals, red and black in turn, widest half-way out.
                    let k = (phi / (TAU / 8.0)).round();
                    let off = rho * (phi - k * TAU / 8.0).sin();
                    if off.abs() < 3.0 + 9.0 * (std::f64::consts::PI * (rho - 40.0) / 65.0).sin() {
                        return if (k as i64).rem_euclid(2) == 0 { 2 } else { 1 };
                    }
                    // A thin black ring through the petals.
                    if (rho - 72.0).abs() < 1.0 {
                        return 1;
                    }
                }
                // Ochre dots every 15 degrees between the red ring and the border.
                let k = (phi / 15f64.to_radians()).round();
                let (dx, dy) =
                    (133.0 * (k * 15f64.to_radians()).cos(), 133.0 * (k * 15f64.to_radians()).sin());
                if (x - dx).hypot(y - dy) < 4.0 {
                    return 3;
                }
                0
            }
            Design::Jar => {
                let band = |a: f64, b: f64| h >= a && h < b;
                if band(24.0, 30.0) || band(150.0, 155.0) || band(226.0, 232.0) {
                    return 1;
                }
                if band(32.0, 40.0) {
                    return 4;
                }
                if band(44.0, 146.0) {
                    // Double zig-zag frieze, red over grey-blue.
                    let teeth = 10.0;
                    let z = 2.0 * tri(theta * teeth / TAU) - 1.0;
                    if (h - (80.0 + 24.0 * z)).abs() < 6.0 {
                        return 2;
                    }
                    if (h - (112.0 + 24.0 * z)).abs() < 4.0 {
                        return 4;
                    }
                    return 0;
                }
                if band(160.0, 220.0) {
                    // Checkerboard of ochre and black dots on the shoulder.
                    let row = ((h - 160.0) / 15.0).floor();
                    let hc = 160.0 + (row + 0.5) * 15.0;
                    let col = (s / 15.0 - 0.5 * (row % 2.0)).round();
                    let sc = (col + 0.5 * (row % 2.0)) * 15.0;
                    if (s - sc).hypot(h - hc) < 5.0 {
                        return if (col as i64 + row as i64).rem_euclid(2) == 0 { 3 } else { 1 };
                    }
                }
                0
            }
        }
    }
}

/// A chip: paint gone, clay shows. Irregular outline from two angular harmonics.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Chip {
    pub theta: f64,
    pub h: f64,
    pub radius: f64,
    pub wobble: [f64; 4],
}

/// A soft stain multiplying the albedo by a brown tint.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stain {
    pub theta: f64,
    pub h: f64,
    pub radius: f64,
    pub strength: f64,
}

/// Seeded deterioration of one object (coordinates on the surface: azimuth, height).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Deterioration {
    pub chips: Vec<Chip>,
    pub stains: Vec<Stain>,
    /// Polylines of (azimuth, height).
    pub cracks: Vec<Vec<(f64, f64)>>,
    pub crack_half_width: f64,
    pub fade_seed: u64,
    pub grain_seed: u64,
    /// Largest fading (fraction of the way from the paint colour to the slip).
    pub fade_max: f64,
    /// Grain amplitude (relative albedo change, ±).
    pub grain: f64,
}

/// What deterioration did at one surface point.
#[derive(Clone, Copy, Debug, Default)]
pub struct Wear {
    pub chipped: bool,
    pub cracked: bool,
    pub stain: f64,
    pub fade: f64,
}

const STAIN_TINT: [f64; 3] = [0.70, 0.60, 0.45];

impl Deterioration {
    /// No deterioration at all.
    pub fn none() -> Self {
        Self {
            chips: vec![],
            stains: vec![],
            cracks: vec![],
            crack_half_width: 0.0,
            fade_seed: 0,
            grain_seed: 0,
            fade_max: 0.0,
            grain: 0.0,
        }
    }

    /// Random deterioration on the part of the object facing azimuth 0 (what the camera
    /// sees), for an object of height `height`.
    pub fn generate(seed: u64, height: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_de7e_0000_0001);
        let az = |rng: &mut ChaCha8Rng| rng.gen_range(-1.5..1.5);
        let chips = (0..rng.gen_range(8..15))
            .map(|_| Chip {
                theta: az(&mut rng),
                h: rng.gen_range(0.05..0.97) * height,
                radius: rng.gen_range(2.5..9.0),
                wobble: [
                    rng.gen_range(0.1..0.3),
                    rng.gen_range(0.0..6.3),
                    rng.gen_range(0.05..0.2),
                    rng.gen_range(0.0..6.3),
                ],
            })
            .collect();
        let stains = (0..rng.gen_range(3..6))
            .map(|_| Stain {
                theta: az(&mut rng),
                h: rng.gen_range(0.1..0.9) * height,
                radius: rng.gen_range(12.0..35.0),
                strength: rng.gen_range(0.25..0.5),
            })
            .collect();
        let cracks = (0..rng.gen_range(2..5))
            .map(|_| {
                let mut th = az(&mut rng);
                let mut h = rng.gen_range(0.1..0.9) * height;
                let mut dir: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                let steps = rng.gen_range(12..30);
                let mut pts = vec![(th, h)];
                for _ in 0..steps {
                    dir += rng.gen_range(-0.6..0.6);
                    // Steps of about 4 mm, in azimuth scaled by a nominal 80 mm radius.
                    th += 4.0 * dir.cos() / 80.0;
                    h = (h + 4.0 * dir.sin()).clamp(1.0, height - 1.0);
                    pts.push((th, h));
                }
                pts
            })
            .collect();
        Self {
            chips,
            stains,
            cracks,
            crack_half_width: 0.45,
            fade_seed: rng.r#gen(),
            grain_seed: rng.r#gen(),
            fade_max: 0.45,
            grain: 0.05,
        }
    }

    /// Deterioration at azimuth `theta`, height `h`, radius `r`.
    pub fn wear_at(&self, theta: f64, h: f64, r: f64) -> Wear {
        let dist = |t2: f64, h2: f64| (wrap(theta - t2) * r).hypot(h - h2);
        let mut w = Wear::default();
        for c in &self.chips {
            let ds = wrap(theta - c.theta) * r;
            let dh = h - c.h;
            let d = ds.hypot(dh);
            if d < c.radius * 1.5 {
                let phi = dh.atan2(ds);
                let edge = c.radius
                    * (1.0
                        + c.wobble[0] * (3.0 * phi + c.wobble[1]).sin()
                        + c.wobble[2] * (5.0 * phi + c.wobble[3]).sin());
                if d < edge {
                    w.chipped = true;
                }
            }
        }
        for crack in &self.cracks {
            for seg in crack.windows(2) {
                let (a, b) = (seg[0], seg[1]);
                // Distance to the segment in local millimetres around this point.
                let ax = wrap(a.0 - theta) * r;
                let bx = wrap(b.0 - theta) * r;
                let (ay, by) = (a.1 - h, b.1 - h);
                let (vx, vy) = (bx - ax, by - ay);
                let len2 = vx * vx + vy * vy;
                let t = if len2 > 0.0 { (-(ax * vx + ay * vy) / len2).clamp(0.0, 1.0) } else { 0.0 };
                if (ax + t * vx).hypot(ay + t * vy) < self.crack_half_width {
                    w.cracked = true;
                }
            }
        }
        for s in &self.stains {
            let d = dist(s.theta, s.h);
            w.stain += s.strength * (-(d / s.radius).powi(2)).exp();
        }
        w.stain = w.stain.min(0.8);
        let n = fbm(self.fade_seed, theta * r / 50.0, h / 50.0);
        w.fade = ((n - 0.5) * 2.5).clamp(0.0, 1.0) * self.fade_max;
        w
    }

    /// Deteriorated albedo and class from the pristine class at a point.
    pub fn apply(&self, palette: &Palette, class: u8, theta: f64, h: f64, r: f64) -> ([f32; 3], u8, Wear) {
        let w = self.wear_at(theta, h, r);
        let slip = palette.classes[palette.background as usize].albedo;
        let clay = palette.classes[palette.clay as usize].albedo;
        let (mut a, label) = if w.cracked {
            (clay.map(|c| c as f64 * 0.55), palette.clay)
        } else if w.chipped {
            (clay.map(|c| c as f64), palette.clay)
        } else {
            let p = palette.classes[class as usize].albedo;
            let a = if class == palette.background {
                p.map(|c| c as f64 * (1.0 - 0.12 * w.fade))
            } else {
                let mut out = [0.0; 3];
                for i in 0..3 {
                    out[i] = p[i] as f64 + w.fade * (slip[i] as f64 - p[i] as f64);
                }
                out
            };
            (a, class)
        };
        for (i, c) in a.iter_mut().enumerate() {
            *c *= 1.0 + w.stain * (STAIN_TINT[i] - 1.0);
        }
        if self.grain > 0.0 {
            let g = value_noise(self.grain_seed, theta * r / 0.7, h / 0.7) * 2.0 - 1.0;
            let g2 = value_noise(self.grain_seed ^ 0xabc, theta * r / 3.0, h / 3.0) * 2.0 - 1.0;
            let m = 1.0 + self.grain * (0.7 * g + 0.3 * g2);
            a.iter_mut().for_each(|c| *c *= m);
        }
        (a.map(|c| c.clamp(0.0, 1.0) as f32), label, w)
    }
}

/// Wraps an angle difference to -π..π.
fn wrap(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    a - TAU * ((a + PI) / TAU).floor()
}

fn hash(seed: u64, x: i64, y: i64) -> f64 {
    // SplitMix64 over the lattice coordinates: portable and fast.
    let mut z = seed
        .wrapping_add((x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add((y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth lattice value noise in 0..1.
pub fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (xf, yf) = (x.floor(), y.floor());
    let (xi, yi) = (xf as i64, yf as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (fx, fy) = (s(x - xf), s(y - yf));
    let a = hash(seed, xi, yi);
    let b = hash(seed, xi + 1, yi);
    let c = hash(seed, xi, yi + 1);
    let d = hash(seed, xi + 1, yi + 1);
    (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
}

fn fbm(seed: u64, x: f64, y: f64) -> f64 {
    0.65 * value_noise(seed, x, y) + 0.35 * value_noise(seed.wrapping_add(1), 2.1 * x, 2.1 * y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn designs_use_their_palettes_and_leave_out_clay() {
        for d in [Design::Vase, Design::Bowl, Design::Jar, Design::Panel] {
            let p = d.palette();
            assert!((3..=5).contains(&(p.classes.len() - 1)), "{d:?}");
            let mut seen = vec![false; p.classes.len()];
            for i in 0..400 {
                for j in 0..300 {
                    let theta = -1.5 + 3.0 * i as f64 / 400.0;
                    let h = j as f64 * 0.8;
                    seen[d.class_at(theta, h, 80.0) as usize] = true;
                }
            }
            assert!(seen[..p.classes.len() - 1].iter().all(|&s| s), "{d:?} uses every paint: {seen:?}");
            assert!(!seen[p.clay as usize], "{d:?}: pristine paint never shows clay");
        }
    }

    #[test]
    fn deterioration_is_seeded_and_chips_show_clay() {
        let a = Deterioration::generate(5, 300.0);
        let b = Deterioration::generate(5, 300.0);
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        let p = Design::Vase.palette();
        let c = &a.chips[0];
        let (albedo, label, wear) = a.apply(&p, 1, c.theta, c.h, 80.0);
        assert!(wear.chipped);
        assert_eq!(label, p.clay);
        let clay = p.classes[p.clay as usize].albedo;
        for i in 0..3 {
            assert!((albedo[i] - clay[i]).abs() < 0.5 * clay[i] + 0.02);
        }
    }
}
