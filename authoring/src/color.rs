//! The project's one colour module: linear sRGB <-> CIE XYZ (D65) <-> xyY, CIELAB (D65 white)
//! and the CIEDE2000 colour difference (Sharma, Wu & Dalal 2005), checked against their 34
//! published test pairs.
//!
//! Conventions: linear sRGB values are relative to the camera's (or display's) full scale,
//! 0..=1; XYZ is scaled so that Y = 1 is that full scale (the D65 white of linear sRGB
//! `[1, 1, 1]` has XYZ = [`D65_WHITE`]); CIELAB uses that same white, so L* = 100 at Y = 1.

use crate::imgio::{linear_to_srgb, srgb_to_linear};

/// XYZ of the D65 white point with Y = 1 (IEC 61966-2-1's sRGB white).
pub const D65_WHITE: [f64; 3] = [0.950_47, 1.0, 1.088_83];

/// Chromaticity (x, y) of D65, used for black, which has no chromaticity of its own.
pub const D65_XY: [f64; 2] = [0.312_727, 0.329_023];

/// Linear sRGB to XYZ (IEC 61966-2-1, D65).
pub const SRGB_TO_XYZ: [[f64; 3]; 3] = [
    [0.412_456_4, 0.357_576_1, 0.180_437_5],
    [0.212_672_9, 0.715_152_2, 0.072_175_0],
    [0.019_333_9, 0.119_192_0, 0.950_304_1],
];

/// XYZ to linear sRGB, the inverse of [`SRGB_TO_XYZ`].
pub const XYZ_TO_SRGB: [[f64; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266_0, 1.876_010_8, 0.041_556_0],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

/// Rec. 709 luma weights of linear R, G, B: relative luminance is their weighted sum.
pub const REC709_LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// Relative luminance of a linear RGB triple (Rec. 709 weights).
pub fn luminance(rgb: [f64; 3]) -> f64 {
    REC709_LUMA[0] * rgb[0] + REC709_LUMA[1] * rgb[1] + REC709_LUMA[2] * rgb[2]
}

/// Linear sRGB (0..=1) to CIE XYZ (Y = 1 at full scale white).
pub fn linear_srgb_to_xyz(rgb: [f64; 3]) -> [f64; 3] {
    mat_vec(&SRGB_TO_XYZ, rgb)
}

/// CIE XYZ to linear sRGB (may leave 0..=1 for out-of-gamut colours).
pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    mat_vec(&XYZ_TO_SRGB, xyz)
}

/// XYZ to xyY. Black (X + Y + Z = 0) gets the D65 chromaticity, so xyY stays continuous
/// along the grey axis.
pub fn xyz_to_xyy(xyz: [f64; 3]) -> [f64; 3] {
    let s = xyz[0] + xyz[1] + xyz[2];
    if s <= 1e-12 { [D65_XY[0], D65_XY[1], xyz[1]] } else { [xyz[0] / s, xyz[1] / s, xyz[1]] }
}

/// xyY to XYZ. A chromaticity with y = 0 has no finite XYZ; it maps to black.
pub fn xyy_to_xyz(xyy: [f64; 3]) -> [f64; 3] {
    let [x, y, big_y] = xyy;
    if y <= 1e-12 { [0.0, 0.0, 0.0] } else { [x * big_y / y, big_y, (1.0 - x - y) * big_y / y] }
}

/// Linear sRGB to xyY.
pub fn linear_srgb_to_xyy(rgb: [f64; 3]) -> [f64; 3] {
    xyz_to_xyy(linear_srgb_to_xyz(rgb))
}

/// xyY to linear sRGB.
pub fn xyy_to_linear_srgb(xyy: [f64; 3]) -> [f64; 3] {
    xyz_to_linear_srgb(xyy_to_xyz(xyy))
}

const LAB_EPS: f64 = 216.0 / 24389.0;
const LAB_KAPPA: f64 = 24389.0 / 27.0;

fn lab_f(t: f64) -> f64 {
    if t > LAB_EPS { t.cbrt() } else { (LAB_KAPPA * t + 16.0) / 116.0 }
}

fn lab_f_inv(f: f64) -> f64 {
    let t = f * f * f;
    if t > LAB_EPS { t } else { (116.0 * f - 16.0) / LAB_KAPPA }
}

/// XYZ to CIELAB relative to [`D65_WHITE`] (CIE 15, with the exact CIE constants).
pub fn xyz_to_lab(xyz: [f64; 3]) -> [f64; 3] {
    let fx = lab_f(xyz[0] / D65_WHITE[0]);
    let fy = lab_f(xyz[1] / D65_WHITE[1]);
    let fz = lab_f(xyz[2] / D65_WHITE[2]);
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIELAB (D65 white) to XYZ.
pub fn lab_to_xyz(lab: [f64; 3]) -> [f64; 3] {
    let fy = (lab[0] + 16.0) / 116.0;
    let fx = fy + lab[1] / 500.0;
    let fz = fy - lab[2] / 200.0;
    [lab_f_inv(fx) * D65_WHITE[0], lab_f_inv(fy) * D65_WHITE[1], lab_f_inv(fz) * D65_WHITE[2]]
}

/// Linear sRGB to CIELAB.
pub fn linear_srgb_to_lab(rgb: [f64; 3]) -> [f64; 3] {
    xyz_to_lab(linear_srgb_to_xyz(rgb))
}

/// CIELAB to linear sRGB.
pub fn lab_to_linear_srgb(lab: [f64; 3]) -> [f64; 3] {
    xyz_to_linear_srgb(lab_to_xyz(lab))
}

/// 8-bit sRGB (display values) to linear sRGB.
pub fn srgb8_to_linear(c: [u8; 3]) -> [f64; 3] {
    c.map(|v| srgb_to_linear(v as f32 / 255.0) as f64)
}

/// Linear sRGB to 8-bit sRGB, clamping to the gamut.
pub fn linear_to_srgb8(rgb: [f64; 3]) -> [u8; 3] {
    rgb.map(|v| (linear_to_srgb(v.clamp(0.0, 1.0) as f32) * 255.0).round() as u8)
}

/// Sine and cosine of the phase shifts in CIEDE2000's T (30, 6 and 63 degrees).
const T_SHIFTS: [(f64, f64); 3] = [
    (0.5, 0.866_025_403_784_438_6),
    (0.104_528_463_267_653_47, 0.994_521_895_368_273_3),
    (0.891_006_524_188_367_9, 0.453_990_499_739_546_75),
];

/// CIEDE2000 colour difference between two CIELAB colours, with kL = kC = kH = 1.
///
/// Follows Sharma, Wu & Dalal, "The CIEDE2000 color-difference formula: implementation
/// notes, supplementary test data, and mathematical observations" (2005), including their
/// conventions for the hue of achromatic colours and the mean hue across the 0/360 seam.
pub fn ciede2000(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    use std::f64::consts::PI;
    let [l1, a1, b1] = lab1;
    let [l2, a2, b2] = lab2;
    let c1 = (a1 * a1 + b1 * b1).sqrt();
    let c2 = (a2 * a2 + b2 * b2).sqrt();
    let c_bar = 0.5 * (c1 + c2);
    let c_bar7 = c_bar.powi(7);
    let g = 0.5 * (1.0 - (c_bar7 / (c_bar7 + 25f64.powi(7))).sqrt());
    let a1p = (1.0 + g) * a1;
    let a2p = (1.0 + g) * a2;
    let c1p = (a1p * a1p + b1 * b1).sqrt();
    let c2p = (a2p * a2p + b2 * b2).sqrt();
    // Hue in degrees, 0..360; achromatic colours get 0 (Sharma's eq. 4).
    let hue = |b: f64, ap: f64| {
        if b == 0.0 && ap == 0.0 {
            0.0
        } else {
            let h = b.atan2(ap).to_degrees();
            if h < 0.0 { h + 360.0 } else { h }
        }
    };
    let h1p = hue(b1, a1p);
    let h2p = hue(b2, a2p);

    let dlp = l2 - l1;
    let dcp = c2p - c1p;
    let cprod = c1p * c2p;
    let dhp = if cprod == 0.0 {
        0.0
    } else {
        let d = h2p - h1p;
        if d > 180.0 {
            d - 360.0
        } else if d < -180.0 {
            d + 360.0
        } else {
            d
        }
    };
    let d_big_hp = 2.0 * cprod.sqrt() * (dhp.to_radians() / 2.0).sin();

    let l_bar_p = 0.5 * (l1 + l2);
    let c_bar_p = 0.5 * (c1p + c2p);
    let h_bar_p = if cprod == 0.0 {
        h1p + h2p
    } else if (h1p - h2p).abs() <= 180.0 {
        0.5 * (h1p + h2p)
    } else if h1p + h2p < 360.0 {
        0.5 * (h1p + h2p + 360.0)
    } else {
        0.5 * (h1p + h2p - 360.0)
    };
    // T's four cosines from one sine and cosine of the mean hue (multiple-angle formulas):
    // the colour difference sits in every search of the nearest view, and these were a
    // tenth of a compensation.
    let (sin1, cos1) = h_bar_p.to_radians().sin_cos();
    let (sin2, cos2) = (2.0 * sin1 * cos1, 2.0 * cos1 * cos1 - 1.0);
    let (sin3, cos3) = (sin1 * (3.0 - 4.0 * sin1 * sin1), cos1 * (4.0 * cos1 * cos1 - 3.0));
    let (sin4, cos4) = (2.0 * sin2 * cos2, 2.0 * cos2 * cos2 - 1.0);
    let [(sin30, cos30), (sin6, cos6), (sin63, cos63)] = T_SHIFTS;
    let t = 1.0 - 0.17 * (cos1 * cos30 + sin1 * sin30) + 0.24 * cos2 + 0.32 * (cos3 * cos6 - sin3 * sin6)
        - 0.20 * (cos4 * cos63 + sin4 * sin63);
    let d_theta = 30.0 * (-((h_bar_p - 275.0) / 25.0).powi(2)).exp();
    let c_bar_p7 = c_bar_p.powi(7);
    let r_c = 2.0 * (c_bar_p7 / (c_bar_p7 + 25f64.powi(7))).sqrt();
    let l50 = (l_bar_p - 50.0).powi(2);
    let s_l = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let s_c = 1.0 + 0.045 * c_bar_p;
    let s_h = 1.0 + 0.015 * c_bar_p * t;
    let r_t = -(2.0 * d_theta * PI / 180.0).sin() * r_c;
    let tl = dlp / s_l;
    let tc = dcp / s_c;
    let th = d_big_hp / s_h;
    (tl * tl + tc * tc + th * th + r_t * tc * th).max(0.0).sqrt()
}

/// Distinct 8-bit sRGB colours for things that are told apart by colour alone (projectors in
/// reports, classes in false colour), cycling after eight.
pub fn categorical(i: usize) -> [u8; 3] {
    const COLOURS: [[u8; 3]; 8] = [
        [230, 80, 60],
        [70, 170, 80],
        [60, 110, 230],
        [220, 180, 40],
        [170, 70, 200],
        [40, 190, 200],
        [240, 130, 180],
        [150, 150, 150],
    ];
    COLOURS[i % COLOURS.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Table 1 of Sharma, Wu & Dalal (2005): L1 a1 b1, L2 a2 b2, dE00.
    const SHARMA: [([f64; 3], [f64; 3], f64); 34] = [
        ([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485], 2.0425),
        ([50.0, 3.1571, -77.2803], [50.0, 0.0, -82.7485], 2.8615),
        ([50.0, 2.8361, -74.0200], [50.0, 0.0, -82.7485], 3.4412),
        ([50.0, -1.3802, -84.2814], [50.0, 0.0, -82.7485], 1.0000),
        ([50.0, -1.1848, -84.8006], [50.0, 0.0, -82.7485], 1.0000),
        ([50.0, -0.9009, -85.5211], [50.0, 0.0, -82.7485], 1.0000),
        ([50.0, 0.0, 0.0], [50.0, -1.0, 2.0], 2.3669),
        ([50.0, -1.0, 2.0], [50.0, 0.0, 0.0], 2.3669),
        ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0009], 7.1792),
        ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0010], 7.1792),
        ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0011], 7.2195),
        ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0012], 7.2195),
        ([50.0, -0.001, 2.49], [50.0, 0.0009, -2.49], 4.8045),
        ([50.0, -0.001, 2.49], [50.0, 0.0010, -2.49], 4.8045),
        ([50.0, -0.001, 2.49], [50.0, 0.0011, -2.49], 4.7461),
        ([50.0, -0.001, 2.49], [50.0, 0.0012, -2.49], 4.7461),
        ([50.0, 2.5, 0.0], [50.0, 0.0, -2.5], 4.3065),
        ([50.0, 2.5, 0.0], [73.0, 25.0, -18.0], 27.1492),
        ([50.0, 2.5, 0.0], [61.0, -5.0, 29.0], 22.8977),
        ([50.0, 2.5, 0.0], [56.0, -27.0, -3.0], 31.9030),
        ([50.0, 2.5, 0.0], [58.0, 24.0, 15.0], 19.4535),
        ([50.0, 2.5, 0.0], [50.0, 3.1736, 0.5854], 1.0000),
        ([50.0, 2.5, 0.0], [50.0, 3.2972, 0.0], 1.0000),
        ([50.0, 2.5, 0.0], [50.0, 1.8634, 0.5757], 1.0000),
        ([50.0, 2.5, 0.0], [50.0, 3.2592, 0.3350], 1.0000),
        ([60.2574, -34.0099, 36.2677], [60.4626, -34.1751, 39.4387], 1.2644),
        ([63.0109, -31.0961, -5.8663], [62.8187, -29.7946, -4.0864], 1.2630),
        ([61.2901, 3.7196, -5.3901], [61.4292, 2.2480, -4.9620], 1.8731),
        ([35.0831, -44.1164, 3.7933], [35.0232, -40.0716, 1.5901], 1.8645),
        ([22.7233, 20.0904, -46.6940], [23.0331, 14.9730, -42.5619], 2.0373),
        ([36.4612, 47.8580, 18.3852], [36.2715, 50.5065, 21.2231], 1.4146),
        ([90.8027, -2.0831, 1.4410], [91.1528, -1.6435, 0.0447], 1.4441),
        ([90.9257, -0.5406, -0.9208], [88.6381, -0.8985, -0.7239], 1.5381),
        ([6.7747, -0.2908, -2.4247], [5.8714, -0.0985, -2.2286], 0.6377),
    ];

    #[test]
    fn t_shifts_are_the_sines_and_cosines_of_their_angles() {
        for ((s, c), d) in T_SHIFTS.iter().zip([30f64, 6.0, 63.0]) {
            let (ws, wc) = d.to_radians().sin_cos();
            assert!((s - ws).abs() < 1e-15 && (c - wc).abs() < 1e-15, "{d} degrees: {s} {c}");
        }
    }

    #[test]
    fn ciede2000_matches_all_34_sharma_pairs() {
        for (i, (p, q, want)) in SHARMA.iter().enumerate() {
            let got = ciede2000(*p, *q);
            assert!((got - want).abs() < 5e-5, "pair {}: got {got:.5}, want {want}", i + 1);
            let back = ciede2000(*q, *p);
            assert!((got - back).abs() < 1e-9, "pair {} is not symmetric", i + 1);
        }
        assert_eq!(ciede2000([40.0, 10.0, -5.0], [40.0, 10.0, -5.0]), 0.0);
    }

    #[test]
    fn srgb_primaries_have_their_published_lab() {
        // Lab of the sRGB primaries and white (D65), as tabulated by Lindbloom.
        let cases = [
            ([1.0, 1.0, 1.0], [100.0, 0.0, 0.0]),
            ([1.0, 0.0, 0.0], [53.2408, 80.0925, 67.2032]),
            ([0.0, 1.0, 0.0], [87.7347, -86.1827, 83.1793]),
            ([0.0, 0.0, 1.0], [32.2970, 79.1875, -107.8602]),
        ];
        for (rgb, want) in cases {
            let lab = linear_srgb_to_lab(rgb);
            for c in 0..3 {
                assert!((lab[c] - want[c]).abs() < 0.01, "{rgb:?} -> {lab:?}, want {want:?}");
            }
        }
        // A grey is achromatic and sits at the white's chromaticity.
        let grey = linear_srgb_to_xyy([0.3, 0.3, 0.3]);
        assert!((grey[0] - D65_XY[0]).abs() < 1e-4 && (grey[1] - D65_XY[1]).abs() < 1e-4);
        assert!((grey[2] - 0.3).abs() < 1e-6);
    }

    #[test]
    fn conversions_round_trip() {
        for rgb in [[0.2, 0.5, 0.9], [1.0, 0.0, 0.3], [0.01, 0.02, 0.005], [0.0, 0.0, 0.0]] {
            let via_lab = lab_to_linear_srgb(linear_srgb_to_lab(rgb));
            let via_xyy = xyy_to_linear_srgb(linear_srgb_to_xyy(rgb));
            for c in 0..3 {
                assert!((via_lab[c] - rgb[c]).abs() < 1e-6, "{rgb:?} via Lab -> {via_lab:?}");
                assert!((via_xyy[c] - rgb[c]).abs() < 1e-6, "{rgb:?} via xyY -> {via_xyy:?}");
            }
        }
        for v in [0u8, 1, 77, 128, 254, 255] {
            assert_eq!(linear_to_srgb8(srgb8_to_linear([v, v, v])), [v, v, v]);
        }
    }
}
