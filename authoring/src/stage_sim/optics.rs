//! Projector and camera models of the virtual stage: pinhole projectors with lens shift,
//! per-channel non-linear response, black level, vignetting and blur; a linear camera with
//! gain and noise, optionally with an 8-bit non-linear output for exposure brackets. Also the projector-space integrator the renderer samples (blurred linear
//! light, then a summed-area table so a camera pixel's footprint costs four lookups).

use image::RgbImage;
use nalgebra::{Matrix3, Rotation3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::geometry::V3;
use crate::calibrate::response::Bracket;
use crate::capture_set::CameraIntrinsics;
use crate::imgio::LinearImage;
use crate::stage_model::ProjectorModel;

/// How one projector is built: placement around the object and its optics and radiometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorSpec {
    /// Degrees around the object's axis from the camera's direction (positive: camera's right).
    pub azimuth_deg: f64,
    /// Degrees above the object's centre, seen from the object.
    pub elevation_deg: f64,
    /// Distance from the object's centre, mm.
    pub distance_mm: f64,
    /// Focal length in pixels as a multiple of the projector's height.
    pub focal_per_height: f64,
    /// Principal point as fractions of width and height (lens shift: `cy` near the bottom).
    pub principal: [f64; 2],
    pub lux_at_1m: f64,
    /// Per channel: `response(x) = x^gamma * (1 + bend * sin(pi x))`, `x = value / 255`.
    pub gamma: [f64; 3],
    pub bend: [f64; 3],
    /// Black level per channel, relative to full white above black.
    pub black: [f32; 3],
    /// Vignetting strength: output falls as `1 - k r^2` with `r` the distance from the
    /// principal point over the half diagonal, normalised to 1 at the image centre.
    pub vignetting: f64,
    /// Gaussian blur (defocus) standard deviation, projector pixels.
    pub blur_px: f64,
}

impl ProjectorSpec {
    /// Projector `k` of `n` around the object, radiometry drawn from `seed`.
    pub fn default_for(k: usize, n: usize, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(31).wrapping_add(k as u64) ^ 0x9e0_1ec7);
        let azimuth_deg = if n == 1 { 10.0 } else { -52.0 + 104.0 * k as f64 / (n - 1) as f64 };
        // The middle projector sits above the camera, so it is not on the camera's axis.
        let elevation_deg = if n > 1 && k * 2 + 1 == n { 24.0 } else { 14.0 + 4.0 * (k % 2) as f64 };
        let g = rng.gen_range(2.0..2.5);
        Self {
            azimuth_deg,
            elevation_deg,
            distance_mm: 1000.0 + 60.0 * (k % 3) as f64,
            focal_per_height: 2.2,
            principal: [0.5 + rng.gen_range(-0.02..0.02), rng.gen_range(0.82..0.95)],
            lux_at_1m: rng.gen_range(400.0..520.0),
            gamma: [0, 1, 2].map(|_| g + rng.gen_range(-0.12..0.12)),
            bend: [0, 1, 2].map(|_| rng.gen_range(-0.06..0.08)),
            black: [0, 1, 2].map(|_| rng.gen_range(0.0025..0.006)),
            vignetting: rng.gen_range(0.12..0.28),
            blur_px: rng.gen_range(0.5..0.9),
        }
    }
}

/// A simulated projector, ready to render.
#[derive(Clone, Debug)]
pub struct SimProjector {
    pub width: u32,
    pub height: u32,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera frame to projector frame: `X_p = rotation * X_c + translation`.
    pub rotation: Matrix3<f64>,
    pub translation: V3,
    /// Centre of projection in the camera frame.
    pub centre: V3,
    pub response: [Vec<f32>; 3],
    pub black: [f32; 3],
    pub lux_at_1m: f64,
    /// `width * height` relative output, 1 at the image centre.
    pub vignetting: Vec<f32>,
    pub blur_px: f64,
}

impl SimProjector {
    /// Builds projector from `spec` around an object centred at `target` with up axis `up`
    /// (unit, camera frame); the object's centre lands at the image centre.
    pub fn from_spec(spec: &ProjectorSpec, width: u32, height: u32, target: &V3, up: &V3) -> Self {
        let (w, h) = (width as f64, height as f64);
        let f = spec.focal_per_height * h;
        let (cx, cy) = (spec.principal[0] * w - 0.5, spec.principal[1] * h - 0.5);
        // Placement: start from the direction towards the camera, turn around the axis, lift.
        let to_cam = -target;
        let b0 = (to_cam - up * to_cam.dot(up)).normalize();
        let b1 = up.cross(&b0);
        let (az, el) = (spec.azimuth_deg.to_radians(), spec.elevation_deg.to_radians());
        // Positive azimuth towards the camera's +x.
        let side = if b1.x >= 0.0 { b1 } else { -b1 };
        let dir = (b0 * az.cos() + side * az.sin()) * el.cos() + up * el.sin();
        let centre = target + dir * spec.distance_mm;
        let rotation = look_at(&centre, target, up, f, cx, cy, w, h);
        let translation = -(rotation * centre);
        let response = [0, 1, 2].map(|c| {
            (0..256)
                .map(|v| {
                    let x = v as f64 / 255.0;
                    (x.powf(spec.gamma[c]) * (1.0 + spec.bend[c] * (std::f64::consts::PI * x).sin())) as f32
                })
                .collect::<Vec<f32>>()
        });
        let half_diag = (w * w + h * h).sqrt() * 0.5;
        let fall = |x: f64, y: f64| {
            1.0 - spec.vignetting * ((x - cx).powi(2) + (y - cy).powi(2)) / half_diag.powi(2)
        };
        let at_centre = fall((w - 1.0) * 0.5, (h - 1.0) * 0.5);
        let vignetting = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| (fall(x as f64, y as f64) / at_centre).max(0.0) as f32)
            .collect();
        Self {
            width,
            height,
            f,
            cx,
            cy,
            rotation,
            translation,
            centre,
            response,
            black: spec.black,
            lux_at_1m: spec.lux_at_1m,
            vignetting,
            blur_px: spec.blur_px,
        }
    }

    /// An ideal projector for closed-form tests: centred principal point, gamma 2.2, no
    /// black level, no vignetting, no blur; aimed from `centre` at `target`.
    pub fn ideal(width: u32, height: u32, f: f64, centre: V3, target: V3, lux_at_1m: f64) -> Self {
        let (w, h) = (width as f64, height as f64);
        let (cx, cy) = ((w - 1.0) * 0.5, (h - 1.0) * 0.5);
        let up = V3::new(0.0, -1.0, 0.0);
        let up =
            if (target - centre).normalize().cross(&up).norm() < 1e-6 { V3::new(0.0, 0.0, 1.0) } else { up };
        let rotation = look_at(&centre, &target, &up, f, cx, cy, w, h);
        let gamma: Vec<f32> = (0..256).map(|v| (v as f32 / 255.0).powf(2.2)).collect();
        Self {
            width,
            height,
            f,
            cx,
            cy,
            rotation,
            translation: -(rotation * centre),
            centre,
            response: [gamma.clone(), gamma.clone(), gamma],
            black: [0.0; 3],
            lux_at_1m,
            vignetting: vec![1.0; (width * height) as usize],
            blur_px: 0.0,
        }
    }

    /// Projector pixel coordinates of a camera-frame point, if it is in front of the lens.
    pub fn project(&self, x: &V3) -> Option<[f64; 2]> {
        let p = self.rotation * x + self.translation;
        if p.z <= 1e-9 {
            return None;
        }
        Some([self.f * p.x / p.z + self.cx, self.f * p.y / p.z + self.cy])
    }

    /// Unit direction (camera frame) of the ray leaving the projector's centre through image
    /// position `(u, v)`: the inverse of [`project`](Self::project).
    pub fn ray(&self, u: f64, v: f64) -> V3 {
        let d = V3::new((u - self.cx) / self.f, (v - self.cy) / self.f, 1.0);
        (self.rotation.transpose() * d).normalize()
    }

    /// Whether projector coordinates fall on the image.
    pub fn on_image(&self, uv: [f64; 2]) -> bool {
        uv[0] >= -0.5 && uv[1] >= -0.5 && uv[0] < self.width as f64 - 0.5 && uv[1] < self.height as f64 - 0.5
    }

    /// The calibration-format description of this projector (the ground truth).
    pub fn model(&self) -> ProjectorModel {
        let r = self.rotation;
        ProjectorModel {
            width: self.width,
            height: self.height,
            f: self.f,
            cx: self.cx,
            cy: self.cy,
            rotation: [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            translation: [self.translation.x, self.translation.y, self.translation.z],
            response: self.response.clone(),
            black: self.black,
            lux_at_1m: self.lux_at_1m,
            vignetting: self.vignetting.clone(),
        }
    }

    /// Relative light leaving each projector pixel for `frame`: vignetting times
    /// (black + response), per channel, then blurred by the lens.
    pub fn light(&self, frame: &RgbImage) -> Vec<[f32; 3]> {
        let (w, h) = (self.width as usize, self.height as usize);
        let raw = frame.as_raw();
        let mut lin: Vec<[f32; 3]> = vec![[0.0; 3]; w * h];
        lin.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let i = y * w + x;
                let v = self.vignetting[i];
                for c in 0..3 {
                    out[c] = v * (self.black[c] + self.response[c][raw[i * 3 + c] as usize]);
                }
            }
        });
        gaussian_blur(&mut lin, w, h, self.blur_px);
        lin
    }
}

/// Bilinear sample of a `w x h` light image (pixel `i` centred at `i`) at `(u, v)`, clamped to
/// the edge pixels: the light at a point between pixel centres, for point irradiance.
pub fn bilinear(img: &[[f32; 3]], w: usize, h: usize, u: f64, v: f64) -> [f64; 3] {
    let axis = |t: f64, n: usize| {
        let t = t.clamp(0.0, (n - 1) as f64);
        let i = (t as usize).min(n.saturating_sub(2));
        (i, (i + 1).min(n - 1), t - i as f64)
    };
    let (x0, x1, fx) = axis(u, w);
    let (y0, y1, fy) = axis(v, h);
    let at = |x: usize, y: usize, c: usize| img[y * w + x][c] as f64;
    [0, 1, 2].map(|c| {
        (at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx) * (1.0 - fy)
            + (at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx) * fy
    })
}

/// Rotation whose optical axis is tilted so that `target`, seen from `centre`, lands at the
/// image centre despite the principal point `(cx, cy)`.
#[allow(clippy::too_many_arguments)]
fn look_at(centre: &V3, target: &V3, up: &V3, f: f64, cx: f64, cy: f64, w: f64, h: f64) -> Matrix3<f64> {
    let z = (target - centre).normalize();
    // +y is down in image coordinates, so x = z x up.
    let x = z.cross(up).normalize();
    let y = z.cross(&x);
    let r0 = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let want = V3::new(((w - 1.0) * 0.5 - cx) / f, ((h - 1.0) * 0.5 - cy) / f, 1.0).normalize();
    let q = Rotation3::rotation_between(&V3::z(), &want).unwrap_or_else(Rotation3::identity);
    q.matrix() * r0
}

/// Separable Gaussian blur in place (zero outside the image).
pub fn gaussian_blur(img: &mut [[f32; 3]], w: usize, h: usize, sigma: f64) {
    if sigma <= 0.05 {
        return;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> =
        (-r..=r).map(|i| (-(i as f64).powi(2) / (2.0 * sigma * sigma)).exp() as f32).collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    let src = img.to_vec();
    let mut tmp = vec![[0.0f32; 3]; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut acc = [0.0f32; 3];
            for (j, kv) in k.iter().enumerate() {
                let xx = x as isize + j as isize - r;
                if xx >= 0 && (xx as usize) < w {
                    let s = src[y * w + xx as usize];
                    for c in 0..3 {
                        acc[c] += kv * s[c];
                    }
                }
            }
            *out = acc;
        }
    });
    img.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut acc = [0.0f32; 3];
            for (j, kv) in k.iter().enumerate() {
                let yy = y as isize + j as isize - r;
                if yy >= 0 && (yy as usize) < h {
                    let s = tmp[yy as usize * w + x];
                    for c in 0..3 {
                        acc[c] += kv * s[c];
                    }
                }
            }
            *out = acc;
        }
    });
}

/// Summed-area table of a projector-space light image, for exact box averages of the
/// piecewise-constant image (pixel `i` covers `[i - 0.5, i + 0.5)`).
#[derive(Debug)]
pub struct Integrator {
    w: usize,
    h: usize,
    sat: Vec<[f64; 3]>,
}

impl Integrator {
    pub fn new(light: &[[f32; 3]], w: usize, h: usize) -> Self {
        let stride = w + 1;
        let mut sat = vec![[0.0f64; 3]; stride * (h + 1)];
        // Row prefix sums in parallel, then accumulate rows.
        sat[stride..].par_chunks_mut(stride).enumerate().for_each(|(y, row)| {
            let mut acc = [0.0f64; 3];
            for x in 0..w {
                let v = light[y * w + x];
                for c in 0..3 {
                    acc[c] += v[c] as f64;
                }
                row[x + 1] = acc;
            }
        });
        for y in 1..h {
            let (prev, cur) = sat.split_at_mut((y + 1) * stride);
            let prev = &prev[y * stride..];
            for x in 0..stride {
                for c in 0..3 {
                    cur[x][c] += prev[x][c];
                }
            }
        }
        Self { w, h, sat }
    }

    /// Integral of the image over `(-inf, x] x (-inf, y]` in pixel coordinates.
    fn corner(&self, x: f64, y: f64) -> [f64; 3] {
        let xi = (x + 0.5).clamp(0.0, self.w as f64);
        let yi = (y + 0.5).clamp(0.0, self.h as f64);
        let i = (xi as usize).min(self.w.saturating_sub(1));
        let j = (yi as usize).min(self.h.saturating_sub(1));
        let (fx, fy) = (xi - i as f64, yi - j as f64);
        let s = self.w + 1;
        let a = self.sat[j * s + i];
        let b = self.sat[j * s + i + 1];
        let c = self.sat[(j + 1) * s + i];
        let d = self.sat[(j + 1) * s + i + 1];
        let mut out = [0.0; 3];
        for k in 0..3 {
            out[k] = (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy;
        }
        out
    }

    /// Mean over the box `[u - hx, u + hx] x [v - hy, v + hy]`; outside the image is dark.
    pub fn box_mean(&self, u: f64, v: f64, hx: f64, hy: f64) -> [f64; 3] {
        let a = self.corner(u + hx, v + hy);
        let b = self.corner(u - hx, v + hy);
        let c = self.corner(u + hx, v - hy);
        let d = self.corner(u - hx, v - hy);
        let area = 4.0 * hx * hy;
        [0, 1, 2].map(|k| (a[k] - b[k] - c[k] + d[k]) / area)
    }
}

/// How the camera is built.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Focal length in pixels as a multiple of the image height.
    pub focal_per_height: f64,
    /// Linear camera value per lux for a white (albedo 1) Lambertian surface.
    pub gain_per_lux: f64,
    /// Noise standard deviation: `sqrt(read^2 + shot * value)`, in 0..1 camera units.
    pub read_noise: f64,
    pub shot_noise: f64,
    /// An 8-bit output through a non-linear response, for exposure brackets
    /// (`VirtualStage::brackets`); captures through the hardware traits stay linear.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub codes: Option<CodeCamera>,
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self {
            focal_per_height: 2.4,
            gain_per_lux: 1.0 / 900.0,
            read_noise: 0.0008,
            shot_noise: 3.0e-5,
            codes: None,
        }
    }
}

/// A camera response that is neither linear nor sRGB: a power law with a filmic shoulder,
/// per channel `v = (1 + s) u / (u + s)`, `u = x^(1/gamma)`, where `x` is the exposure
/// relative to saturation (0..=1) and `v` the code over 255. Closed-form inverse.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToneCurve {
    pub gamma: [f64; 3],
    /// Smaller is a stronger shoulder (more compression near saturation).
    pub shoulder: [f64; 3],
}

impl ToneCurve {
    /// The virtual camera's curve: channels differ a little, as a real camera's do.
    pub fn filmic() -> Self {
        Self { gamma: [2.0, 2.2, 1.8], shoulder: [0.8, 0.7, 1.0] }
    }

    /// Code over 255 (0..=1) for exposure `x` relative to saturation; saturates at `x >= 1`.
    pub fn encode(&self, c: usize, x: f64) -> f64 {
        let s = self.shoulder[c];
        let u = x.clamp(0.0, 1.0).powf(1.0 / self.gamma[c]);
        (1.0 + s) * u / (u + s)
    }

    /// Inverse of [`encode`](Self::encode): relative exposure for code over 255.
    pub fn decode(&self, c: usize, v: f64) -> f64 {
        let (s, v) = (self.shoulder[c], v.clamp(0.0, 1.0));
        (s * v / (1.0 + s - v)).powf(self.gamma[c])
    }

    /// The true inverse response per channel at codes 0..=255, 1 at code 255: what response
    /// recovery should find (up to scale).
    pub fn inverse(&self) -> [Vec<f64>; 3] {
        [0, 1, 2].map(|c| (0..256).map(|z| self.decode(c, z as f64 / 255.0)).collect())
    }
}

/// An 8-bit camera: exposure time, the tone curve, quantisation to codes and saturation, with
/// noise added to the exposure before the curve (as on a sensor, before the camera's
/// processing).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CodeCamera {
    pub curve: ToneCurve,
    /// Exposure time (s) at which the linear camera's full scale (1.0) just saturates: the
    /// relative exposure is `linear * time / saturation_s`.
    pub saturation_s: f64,
    /// Noise standard deviation `sqrt(read^2 + shot * x)`, in units of saturation exposure.
    pub read_noise: f64,
    pub shot_noise: f64,
}

impl Default for CodeCamera {
    fn default() -> Self {
        // A clean sensor (full well about 10^6 electrons): noise about 0.4 code at code 10
        // (green) and 0.1 code near the top, so the 8-bit quantisation and saturation, not the
        // sensor, limit the dynamic range.
        Self { curve: ToneCurve::filmic(), saturation_s: 1.0, read_noise: 5.0e-6, shot_noise: 1.0e-6 }
    }
}

impl CodeCamera {
    /// One exposure of `linear` (unclipped linear camera values) for `exposure_s`, noise from
    /// `seed` (per row, so the result does not depend on the thread count).
    pub fn expose(&self, linear: &LinearImage, exposure_s: f64, seed: u64) -> Bracket {
        let w = linear.width as usize;
        let k = exposure_s / self.saturation_s;
        let mut codes = vec![[0u8; 3]; linear.data.len()];
        codes.par_chunks_mut(w).zip(linear.data.par_chunks(w)).enumerate().for_each(|(y, (out, row))| {
            let mut rng = ChaCha8Rng::seed_from_u64(super::mix(seed, y as u64));
            for (o, px) in out.iter_mut().zip(row) {
                *o = [0, 1, 2].map(|c| {
                    let x = px[c] as f64 * k;
                    let sd = (self.read_noise.powi(2) + self.shot_noise * x.max(0.0)).sqrt();
                    let x = x + sd * super::normal(&mut rng);
                    (255.0 * self.curve.encode(c, x)).round() as u8
                });
            }
        });
        Bracket { width: linear.width, height: linear.height, codes, exposure_s }
    }
}

impl CameraSpec {
    pub fn intrinsics(&self, width: u32, height: u32) -> CameraIntrinsics {
        let f = self.focal_per_height * height as f64;
        CameraIntrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: (width as f64 - 1.0) * 0.5 + 0.011 * width as f64,
            cy: (height as f64 - 1.0) * 0.5 - 0.007 * height as f64,
            distortion: [0.0; 5],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_means_are_exact_for_piecewise_constant_images() {
        let (w, h) = (5, 4);
        let light: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, 1.0, (i % 3) as f32]).collect();
        let it = Integrator::new(&light, w, h);
        // One whole pixel.
        let m = it.box_mean(2.0, 1.0, 0.5, 0.5);
        assert!((m[0] - 7.0).abs() < 1e-9 && (m[1] - 1.0).abs() < 1e-9);
        // Half of pixel (1,1) and half of (2,1).
        let m = it.box_mean(1.5, 1.0, 0.5, 0.5);
        assert!((m[0] - 6.5).abs() < 1e-9);
        // A box half outside the image gets half the light.
        let m = it.box_mean(-0.5, 1.0, 0.5, 0.5);
        assert!((m[1] - 0.5).abs() < 1e-9);
    }

    #[test]
    fn projector_rays_invert_projection_and_bilinear_interpolates() {
        let p =
            SimProjector::ideal(80, 60, 70.0, V3::new(100.0, -50.0, 0.0), V3::new(0.0, 0.0, 1000.0), 450.0);
        for (u, v) in [(0.0, 0.0), (39.5, 29.5), (71.25, 12.75)] {
            let x = p.centre + p.ray(u, v) * 900.0;
            let uv = p.project(&x).unwrap();
            assert!((uv[0] - u).abs() < 1e-9 && (uv[1] - v).abs() < 1e-9, "{uv:?} vs ({u}, {v})");
        }
        let img: Vec<[f32; 3]> = (0..6).map(|i| [i as f32, 1.0, 0.0]).collect(); // 3 x 2
        assert_eq!(bilinear(&img, 3, 2, 1.0, 0.0), [1.0, 1.0, 0.0]);
        assert!((bilinear(&img, 3, 2, 0.5, 0.5)[0] - 2.0).abs() < 1e-12);
        // Clamped at the edges.
        assert_eq!(bilinear(&img, 3, 2, -0.4, 1.3)[0], 3.0);
    }

    #[test]
    fn blur_preserves_light_away_from_the_edges() {
        let (w, h) = (21, 21);
        let mut img = vec![[0.0f32; 3]; w * h];
        img[10 * w + 10] = [1.0; 3];
        gaussian_blur(&mut img, w, h, 0.8);
        let total: f32 = img.iter().map(|p| p[0]).sum();
        assert!((total - 1.0).abs() < 1e-5);
        assert!(img[10 * w + 10][0] < 0.3 && img[10 * w + 11][0] > 0.05);
    }

    #[test]
    fn projectors_aim_at_the_object_despite_lens_shift() {
        let target = V3::new(0.0, 0.0, 900.0);
        let up = V3::new(0.0, -1.0, 0.0);
        for k in 0..3 {
            let spec = ProjectorSpec::default_for(k, 3, 7);
            let p = SimProjector::from_spec(&spec, 140, 105, &target, &up);
            let uv = p.project(&target).unwrap();
            assert!((uv[0] - 69.5).abs() < 1e-6 && (uv[1] - 52.0).abs() < 1e-6, "{uv:?}");
            assert!((p.rotation * p.rotation.transpose() - Matrix3::identity()).norm() < 1e-9);
            assert!(p.cy > 0.8 * 105.0, "lens shift puts the principal point low");
            assert!((p.centre - target).norm() > 900.0);
            // Up in the world is up (-y) in the projector image.
            let above = p.project(&(target + up * 50.0)).unwrap();
            assert!(above[1] < uv[1]);
        }
    }
}
