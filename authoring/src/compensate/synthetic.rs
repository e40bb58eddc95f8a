//! Small analytic stages — a painted sphere lit by N projectors — with a known "true" optics
//! that differs from the model the way a calibrated estimate does (projector brightness a
//! little off, a wider blur than the 2x2 neighbourhood). For unit tests, property tests and
//! benches of compensation; the full physically based virtual stage lives in `stage_sim`.

use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::capture_set::CameraIntrinsics;
use crate::stage_model::{ProjectorModel, StageModel, Transport};

/// Sizes of a synthetic stage.
#[derive(Clone, Debug)]
pub struct SyntheticSpec {
    pub seed: u64,
    pub projectors: usize,
    pub camera: (u32, u32),
    pub projector: (u32, u32),
    /// True brightness of each projector relative to the model's `lux_at_1m` is drawn from
    /// `1 +- lux_error`.
    pub lux_error: f64,
    /// Radius (projector pixels) of the true tent-shaped blur of one projector pixel.
    pub blur: f32,
    /// Build the measured transport (footprints) into the model.
    pub with_transport: bool,
    /// Paint bands of a few colours and per-pixel grain (false: one uniform albedo, so a
    /// blurred projector can match a smooth target exactly).
    pub painted: bool,
}

impl SyntheticSpec {
    pub fn small(projectors: usize, seed: u64) -> Self {
        Self {
            seed,
            projectors,
            camera: (48, 36),
            projector: (40, 30),
            lux_error: 0.02,
            blur: 1.5,
            with_transport: true,
            painted: true,
        }
    }
}

/// A synthetic stage: the model compensation reads, and the truth a visitor sees.
#[derive(Clone, Debug)]
pub struct SyntheticStage {
    pub model: StageModel,
    /// True `lux_at_1m` per projector.
    pub true_lux_at_1m: Vec<f64>,
    pub blur: f32,
    /// Room light at every point, lux (not from projectors).
    pub room_lux: f64,
    /// Per camera pixel albedo (NaN off the object).
    pub albedo: Vec<[f32; 3]>,
    /// Camera value per lux on a white surface.
    pub camera_gain: f32,
}

/// A small stage with `projectors` projectors, drawn from `seed`.
pub fn synthetic_stage(projectors: usize, seed: u64) -> SyntheticStage {
    build(&SyntheticSpec::small(projectors, seed))
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Projects camera-frame point `x` into projector `p` (pixel coordinates and depth).
pub fn project(p: &ProjectorModel, x: [f64; 3]) -> ([f64; 2], f64) {
    let r = &p.rotation;
    let q: [f64; 3] = std::array::from_fn(|j| dot(r[j], x) + p.translation[j]);
    ([p.f * q[0] / q[2] + p.cx, p.f * q[1] / q[2] + p.cy], q[2])
}

/// The true tent kernel of one projector pixel's blur, evaluated at offset (dx, dy).
fn tent(dx: f32, dy: f32, b: f32) -> f32 {
    (1.0 - dx.abs() / b).max(0.0) * (1.0 - dy.abs() / b).max(0.0)
}

/// Builds a stage from `spec`.
pub fn build(spec: &SyntheticSpec) -> SyntheticStage {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let (cw, ch) = spec.camera;
    let (pw, ph) = spec.projector;
    let s = [rng.gen_range(-30.0..30.0), rng.gen_range(-30.0..30.0), rng.gen_range(600.0..900.0)];
    let radius: f64 = rng.gen_range(120.0..200.0);
    let ang = (radius / dot(s, s).sqrt()).asin();
    let fx = 0.42 * ch as f64 / ang.tan();
    let camera = CameraIntrinsics {
        width: cw,
        height: ch,
        fx,
        fy: fx,
        cx: (cw as f64 - 1.0) / 2.0,
        cy: (ch as f64 - 1.0) / 2.0,
        distortion: [0.0; 5],
    };
    let kn = spec.projectors;
    let mut projectors = Vec::with_capacity(kn);
    let mut true_lux = Vec::with_capacity(kn);
    for k in 0..kn {
        let spread = if kn == 1 { 0.0 } else { -55.0 + 110.0 * k as f64 / (kn - 1) as f64 };
        let phi = (spread + rng.gen_range(-10.0..10.0f64)).to_radians();
        let elev = rng.gen_range(-15.0..15.0f64).to_radians();
        let dist = rng.gen_range(700.0..1100.0);
        let dir = [phi.sin() * elev.cos(), -elev.sin(), -phi.cos() * elev.cos()];
        let c = [s[0] + dist * dir[0], s[1] + dist * dir[1], s[2] + dist * dir[2]];
        let z = normalize([s[0] - c[0], s[1] - c[1], s[2] - c[2]]);
        let yv = [-z[0] * z[1], 1.0 - z[1] * z[1], -z[2] * z[1]];
        let y = normalize(yv);
        let x = cross(y, z);
        let rotation = [x, y, z];
        let translation: [f64; 3] = std::array::from_fn(|j| -dot(rotation[j], c));
        let f = 0.45 * ph as f64 / (radius / dist).asin().tan();
        let response: [Vec<f32>; 3] = std::array::from_fn(|_| {
            let g: f32 = rng.gen_range(1.8..2.6);
            (0..256).map(|v| (v as f32 / 255.0).powf(g)).collect()
        });
        let black = std::array::from_fn(|_| rng.gen_range(0.001..0.02));
        let lux_at_1m = rng.gen_range(400.0..1500.0);
        let vignetting = (0..pw * ph)
            .map(|i| {
                let (u, v) = ((i % pw) as f32 / pw as f32 - 0.5, (i / pw) as f32 / ph as f32 - 0.5);
                1.0 - 0.5 * (u * u + v * v)
            })
            .collect();
        true_lux.push(lux_at_1m * (1.0 + rng.gen_range(-spec.lux_error..=spec.lux_error)));
        projectors.push(ProjectorModel {
            width: pw,
            height: ph,
            f,
            cx: (pw as f64 - 1.0) / 2.0 + rng.gen_range(-2.0..2.0),
            cy: (ph as f64 - 1.0) / 2.0 + rng.gen_range(-2.0..2.0),
            rotation,
            translation,
            response,
            black,
            lux_at_1m,
            vignetting,
        });
    }
    let n = (cw * ch) as usize;
    let mut points = vec![[f32::NAN; 3]; n];
    let mut normals = vec![[f32::NAN; 3]; n];
    let mut correspondences = vec![vec![[f32::NAN; 2]; n]; kn];
    let palette: Vec<[f32; 3]> =
        (0..4).map(|_| [rng.gen_range(0.1..0.9), rng.gen_range(0.1..0.9), rng.gen_range(0.1..0.9)]).collect();
    let mut albedo = vec![[f32::NAN; 3]; n];
    let bands: f64 = rng.gen_range(3.0..7.0);
    for y in 0..ch {
        for x in 0..cw {
            let i = (y * cw + x) as usize;
            let d = normalize([(x as f64 - camera.cx) / fx, (y as f64 - camera.cy) / fx, 1.0]);
            let b = dot(d, s);
            let disc = b * b - dot(s, s) + radius * radius;
            if disc <= 0.0 {
                continue;
            }
            let t = b - disc.sqrt();
            let p = [d[0] * t, d[1] * t, d[2] * t];
            let nrm = [(p[0] - s[0]) / radius, (p[1] - s[1]) / radius, (p[2] - s[2]) / radius];
            points[i] = p.map(|v| v as f32);
            normals[i] = nrm.map(|v| v as f32);
            let band = (((nrm[1] + 1.0) * bands) as usize + (nrm[0] * 3.0 + 3.0) as usize) % palette.len();
            albedo[i] = if spec.painted {
                palette[band].map(|a| (a * rng.gen_range(0.9..1.1f32)).min(1.0))
            } else {
                palette[0]
            };
            for k in 0..kn {
                let pr = &projectors[k];
                let cc = pr.centre();
                if dot(nrm, [cc[0] - p[0], cc[1] - p[1], cc[2] - p[2]]) <= 0.0 {
                    continue;
                }
                let (uv, depth) = project(pr, p);
                if depth > 0.0
                    && uv[0] >= -0.5
                    && uv[0] < pw as f64 - 0.5
                    && uv[1] >= -0.5
                    && uv[1] < ph as f64 - 0.5
                {
                    correspondences[k][i] = [uv[0] as f32, uv[1] as f32];
                }
            }
        }
    }
    let camera_gain = 1.0 / 2500.0;
    let room_lux = rng.gen_range(0.0..3.0);
    let model = StageModel {
        camera,
        projectors,
        points,
        normals,
        correspondences,
        transport: vec![Transport::default(); kn],
        gain: albedo.iter().map(|a| a.map(|v| if v.is_finite() { v * camera_gain } else { 0.0 })).collect(),
        ambient: vec![[0.0; 3]; n],
        provenance: format!("synthetic sphere, seed {}", spec.seed),
    };
    let stage =
        SyntheticStage { true_lux_at_1m: true_lux, blur: spec.blur, room_lux, albedo, camera_gain, model };
    // Ambient as a camera would measure it with every projector black: room plus black level.
    let black_frames: Vec<RgbImage> = (0..kn).map(|_| RgbImage::new(pw, ph)).collect();
    let lux = stage.true_lux(&black_frames);
    let mut model = stage.model.clone();
    for (i, e) in lux.iter().enumerate() {
        model.ambient[i] =
            std::array::from_fn(|c| if e[c].is_finite() { model.gain[i][c] * e[c] as f32 } else { 0.0 });
    }
    if spec.with_transport {
        model.transport = (0..kn).map(|k| stage.footprints(k)).collect();
    }
    SyntheticStage { model, ..stage }
}

impl SyntheticStage {
    /// The true geometric efficiency (lux per unit relative output) of projector k at point i.
    fn true_eta(&self, k: usize, i: usize) -> Option<f64> {
        let c = self.model.correspondences[k][i];
        if !c[0].is_finite() {
            return None;
        }
        let p = &self.model.projectors[k];
        let x = self.model.points[i].map(f64::from);
        let n = self.model.normals[i].map(f64::from);
        let cc = p.centre();
        let d = [cc[0] - x[0], cc[1] - x[1], cc[2] - x[2]];
        let dist = dot(d, d).sqrt();
        let cos = dot(n, d) / dist;
        Some(self.true_lux_at_1m[k] * super::geometry::vignetting(p, c) * cos * 1e6 / (dist * dist))
    }

    /// The measured footprint of every pixel of projector k: the camera pixels its blurred
    /// light reaches, weighted by the blur kernel (CSR over projector pixels).
    fn footprints(&self, k: usize) -> Transport {
        let p = &self.model.projectors[k];
        let (pw, ph) = (p.width as usize, p.height as usize);
        let b = self.blur;
        let reach = b.ceil() as i64;
        let mut entries: Vec<(u32, u32, f32)> = Vec::new();
        for (i, c) in self.model.correspondences[k].iter().enumerate() {
            if !c[0].is_finite() {
                continue;
            }
            let (px, py) = (c[0].round() as i64, c[1].round() as i64);
            let first = entries.len();
            for y in py - reach..=py + reach {
                for x in px - reach..=px + reach {
                    if x < 0 || y < 0 || x >= pw as i64 || y >= ph as i64 {
                        continue;
                    }
                    let w = tent(x as f32 - c[0], y as f32 - c[1], b);
                    if w > 0.0 {
                        entries.push(((y as usize * pw + x as usize) as u32, i as u32, w));
                    }
                }
            }
            // Shares of this camera pixel's light, as the transport step measures them (and
            // as `true_lux` mixes the pixels): they sum to 1.
            let sum: f32 = entries[first..].iter().map(|e| e.2).sum();
            entries[first..].iter_mut().for_each(|e| e.2 /= sum);
        }
        entries.sort_by_key(|e| (e.0, e.1));
        let mut row_start = vec![0u32; pw * ph + 1];
        for e in &entries {
            row_start[e.0 as usize + 1] += 1;
        }
        for j in 0..pw * ph {
            row_start[j + 1] += row_start[j];
        }
        Transport {
            row_start,
            camera_pixel: entries.iter().map(|e| e.1).collect(),
            weight: entries.iter().map(|e| e.2).collect(),
        }
    }

    /// True irradiance (lux per channel) at every camera pixel when the projectors show
    /// `frames`: room light plus, per projector that sees the point, the true efficiency
    /// times black plus the blur-weighted output of the pixels around the point. NaN off
    /// the object.
    pub fn true_lux(&self, frames: &[RgbImage]) -> Vec<[f64; 3]> {
        let n = self.model.pixel_count();
        let b = self.blur;
        let reach = b.ceil() as i64;
        (0..n)
            .map(|i| {
                if !self.model.points[i][0].is_finite() {
                    return [f64::NAN; 3];
                }
                let mut e = [self.room_lux; 3];
                for (k, frame) in frames.iter().enumerate() {
                    let Some(eta) = self.true_eta(k, i) else { continue };
                    let p = &self.model.projectors[k];
                    let c = self.model.correspondences[k][i];
                    let (px, py) = (c[0].round() as i64, c[1].round() as i64);
                    let mut acc = [0.0f64; 3];
                    let mut wsum = 0.0f64;
                    for y in py - reach..=py + reach {
                        for x in px - reach..=px + reach {
                            if x < 0 || y < 0 || x >= p.width as i64 || y >= p.height as i64 {
                                continue;
                            }
                            let w = tent(x as f32 - c[0], y as f32 - c[1], b) as f64;
                            if w <= 0.0 {
                                continue;
                            }
                            let v = frame.get_pixel(x as u32, y as u32).0;
                            for ch in 0..3 {
                                acc[ch] += w * p.response[ch][v[ch] as usize] as f64;
                            }
                            wsum += w;
                        }
                    }
                    for ch in 0..3 {
                        let out = if wsum > 0.0 { acc[ch] / wsum } else { 0.0 };
                        e[ch] += eta * (p.black[ch] as f64 + out);
                    }
                }
                e
            })
            .collect()
    }

    /// What the camera (a visitor at its place) sees: `gain * E`, linear camera values.
    pub fn view(&self, frames: &[RgbImage]) -> Vec<[f32; 3]> {
        self.true_lux(frames)
            .iter()
            .zip(&self.albedo)
            .map(|(e, a)| std::array::from_fn(|c| (e[c] * (a[c] * self.camera_gain) as f64) as f32))
            .collect()
    }
}
