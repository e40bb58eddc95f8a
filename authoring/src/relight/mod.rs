//! Virtual illumination (paper §5.3): the restored image used as a texture on the
//! reconstructed surface, re-lit by virtual directional and point lights (Lambert diffuse
//! plus Blinn-Phong specular, seen from the camera), optionally with some of the photo's
//! high-frequency material noise infused back. Per camera pixel, using the stage model's
//! points and normals; no rasteriser needed since the view is the camera's.

pub mod gpu;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::imgio::LinearImage;
use crate::stage_model::StageModel;

#[derive(Debug, Error)]
pub enum RelightError {
    #[error("{what} is {got_w}x{got_h} but the stage model's camera is {want_w}x{want_h}")]
    SizeMismatch { what: &'static str, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("light {index}: {problem}")]
    BadLight { index: usize, problem: String },
    #[error("{name} = {value} is invalid (expected {range})")]
    BadParam { name: &'static str, value: f64, range: &'static str },
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

/// A virtual light. Colours are linear RGB multipliers (1 = white of unit strength).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum Light {
    /// Light travelling along `direction` (camera frame: +x right, +y down, +z away from
    /// the camera), e.g. `[0.5, 0.5, 1.0]` comes from the upper left behind the camera.
    Directional { direction: [f64; 3], colour: [f64; 3] },
    /// A point light at `position` (mm, camera frame) with `colour` at 1 m (inverse square).
    Point { position: [f64; 3], colour: [f64; 3] },
}

/// The virtual lighting of one relit variant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lighting {
    pub lights: Vec<Light>,
    /// Light reaching every point regardless of orientation (keeps shadowed sides visible).
    pub ambient: f64,
    /// Strength of the specular highlight (0 = matte).
    pub specular: f64,
    /// Blinn-Phong exponent (sharper highlight when larger).
    pub shininess: f64,
    /// Overall gain applied after lighting, so the brightest lit texture stays near 1.
    pub exposure: f64,
}

impl Default for Lighting {
    /// A soft key light from the upper left and a little ambient: a mild "gallery" look.
    fn default() -> Self {
        Self {
            lights: vec![Light::Directional { direction: [0.6, 0.5, 1.0], colour: [1.0, 0.97, 0.92] }],
            ambient: 0.35,
            specular: 0.15,
            shininess: 24.0,
            exposure: 1.0,
        }
    }
}

impl Lighting {
    pub fn validate(&self) -> Result<(), RelightError> {
        let bad = |name, value: f64, range| Err(RelightError::BadParam { name, value, range });
        if !(self.ambient.is_finite() && self.ambient >= 0.0) {
            return bad("ambient", self.ambient, ">= 0");
        }
        if !(self.specular.is_finite() && self.specular >= 0.0) {
            return bad("specular", self.specular, ">= 0");
        }
        if !(self.shininess.is_finite() && (1.0..=1000.0).contains(&self.shininess)) {
            return bad("shininess", self.shininess, "1..=1000");
        }
        if !(self.exposure.is_finite() && self.exposure > 0.0) {
            return bad("exposure", self.exposure, "> 0");
        }
        for (index, l) in self.lights.iter().enumerate() {
            let (v, c) = match l {
                Light::Directional { direction, colour } => (direction, colour),
                Light::Point { position, colour } => (position, colour),
            };
            if !v.iter().chain(c).all(|x| x.is_finite()) || c.iter().any(|&x| x < 0.0) {
                return Err(RelightError::BadLight {
                    index,
                    problem: "values must be finite, colours >= 0".into(),
                });
            }
            if let Light::Directional { direction, .. } = l
                && direction.iter().all(|&x| x == 0.0)
            {
                return Err(RelightError::BadLight { index, problem: "direction is the zero vector".into() });
            }
        }
        Ok(())
    }
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 { [v[0] / n, v[1] / n, v[2] / n] } else { v }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Shading of one surface point: (diffuse multiplier per channel, specular per channel).
pub fn shade(point: [f64; 3], normal: [f64; 3], lighting: &Lighting) -> ([f64; 3], [f64; 3]) {
    let n = normalize(normal);
    let view = normalize([-point[0], -point[1], -point[2]]);
    let mut diffuse = [lighting.ambient; 3];
    let mut spec = [0.0; 3];
    for l in &lighting.lights {
        let (to_light, colour) = match l {
            Light::Directional { direction, colour } => (normalize(direction.map(|v| -v)), *colour),
            Light::Point { position, colour } => {
                let d = [position[0] - point[0], position[1] - point[1], position[2] - point[2]];
                let dist_m = dot(d, d).sqrt() / 1000.0;
                (normalize(d), colour.map(|c| c / (dist_m * dist_m).max(1e-6)))
            }
        };
        let cos = dot(n, to_light);
        if cos <= 0.0 {
            continue;
        }
        let h = normalize([to_light[0] + view[0], to_light[1] + view[1], to_light[2] + view[2]]);
        let s = lighting.specular * dot(n, h).max(0.0).powf(lighting.shininess);
        for c in 0..3 {
            diffuse[c] += cos * colour[c];
            spec[c] += s * colour[c];
        }
    }
    (diffuse, spec)
}

/// Relights `texture` (linear, camera space): `exposure * (texture * diffuse + specular)`
/// where the stage knows the surface; unchanged elsewhere. The CPU reference path.
pub fn relight(
    stage: &StageModel,
    texture: &LinearImage,
    lighting: &Lighting,
) -> Result<LinearImage, RelightError> {
    relight_on(stage, texture, lighting, crate::gpu::Device::Cpu)
}

/// [`relight`] with the per-pixel shading on `device`.
pub fn relight_on(
    stage: &StageModel,
    texture: &LinearImage,
    lighting: &Lighting,
    device: crate::gpu::Device,
) -> Result<LinearImage, RelightError> {
    lighting.validate()?;
    check_size(stage, texture, "restored image")?;
    if let Some(g) = crate::gpu::select(device)? {
        return gpu::relight(g, stage, texture, lighting);
    }
    let data = texture
        .data
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let p = stage.points[i].map(f64::from);
            let n = stage.normals[i].map(f64::from);
            if !p.iter().chain(&n).all(|v| v.is_finite()) {
                return *t;
            }
            let (d, s) = shade(p, n, lighting);
            std::array::from_fn(|c| (lighting.exposure * (t[c] as f64 * d[c] + s[c])) as f32)
        })
        .collect();
    Ok(LinearImage { width: texture.width, height: texture.height, data })
}

fn check_size(stage: &StageModel, img: &LinearImage, what: &'static str) -> Result<(), RelightError> {
    let (w, h) = (stage.camera.width, stage.camera.height);
    if (img.width, img.height) != (w, h) {
        return Err(RelightError::SizeMismatch {
            what,
            got_w: img.width,
            got_h: img.height,
            want_w: w,
            want_h: h,
        });
    }
    Ok(())
}

/// Separable box blur of radius `r` (edge pixels repeated), deterministic.
fn box_blur(img: &LinearImage, r: usize) -> Vec<[f32; 3]> {
    let (w, h) = (img.width as usize, img.height as usize);
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        let (outer, inner) = if horizontal { (h, w) } else { (w, h) };
        let at = |o: usize, i: usize| if horizontal { o * w + i } else { i * w + o };
        let mut out = vec![[0.0f32; 3]; w * h];
        let cols: Vec<Vec<(usize, [f32; 3])>> = (0..outer)
            .into_par_iter()
            .map(|o| {
                (0..inner)
                    .map(|i| {
                        let mut acc = [0.0f64; 3];
                        for d in -(r as i64)..=r as i64 {
                            let j = (i as i64 + d).clamp(0, inner as i64 - 1) as usize;
                            let v = src[at(o, j)];
                            for c in 0..3 {
                                acc[c] += v[c] as f64;
                            }
                        }
                        (at(o, i), acc.map(|a| (a / (2 * r + 1) as f64) as f32))
                    })
                    .collect()
            })
            .collect();
        for col in cols {
            for (idx, v) in col {
                out[idx] = v;
            }
        }
        out
    };
    let tmp = pass(&img.data, true);
    pass(&tmp, false)
}

/// Infuses `amount` (0 = none, 1 = all) of the photo's high-frequency material noise: the
/// photo's ratio to its own blur (radius `radius` px) multiplies the image, so the mean
/// brightness is kept and only fine irregularities come back.
pub fn infuse_noise(
    stage: &StageModel,
    image: &LinearImage,
    photo: &LinearImage,
    amount: f64,
    radius: usize,
) -> Result<LinearImage, RelightError> {
    if !(amount.is_finite() && (0.0..=1.0).contains(&amount)) {
        return Err(RelightError::BadParam { name: "noise amount", value: amount, range: "0..=1" });
    }
    if !(1..=32).contains(&radius) {
        return Err(RelightError::BadParam {
            name: "noise radius",
            value: radius as f64,
            range: "1..=32 px",
        });
    }
    check_size(stage, image, "image")?;
    check_size(stage, photo, "photo")?;
    let smooth = box_blur(photo, radius);
    let data = image
        .data
        .par_iter()
        .zip(&photo.data)
        .zip(&smooth)
        .map(|((v, p), s)| {
            std::array::from_fn(|c| {
                let ratio = if s[c] > 1e-4 { (p[c] / s[c]).clamp(0.25, 4.0) } else { 1.0 };
                (v[c] as f64 * (1.0 + amount * (ratio as f64 - 1.0))) as f32
            })
        })
        .collect();
    Ok(LinearImage { width: image.width, height: image.height, data })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::synthetic_stage;

    #[test]
    fn lambert_follows_cosine_and_back_faces_get_only_ambient() {
        let l = Lighting {
            lights: vec![Light::Directional { direction: [0.0, 0.0, 1.0], colour: [1.0; 3] }],
            ambient: 0.1,
            specular: 0.0,
            shininess: 10.0,
            exposure: 1.0,
        };
        // Facing the camera (normal -z): the light travels +z, so it comes from behind the
        // camera and hits head on.
        let (d, s) = shade([0.0, 0.0, 500.0], [0.0, 0.0, -1.0], &l);
        assert!((d[0] - 1.1).abs() < 1e-12 && s == [0.0; 3]);
        let n60 = [60f64.to_radians().sin(), 0.0, -60f64.to_radians().cos()];
        let (d, _) = shade([0.0, 0.0, 500.0], n60, &l);
        assert!((d[1] - (0.1 + 0.5)).abs() < 1e-9);
        let (d, _) = shade([0.0, 0.0, 500.0], [0.0, 0.0, 1.0], &l);
        assert_eq!(d, [0.1; 3]);
    }

    #[test]
    fn point_light_falls_off_with_inverse_square_and_highlight_peaks_at_mirror() {
        let mk = |spec| Lighting {
            lights: vec![Light::Point { position: [0.0, 0.0, 0.0], colour: [1.0; 3] }],
            ambient: 0.0,
            specular: spec,
            shininess: 50.0,
            exposure: 1.0,
        };
        let (d1, _) = shade([0.0, 0.0, 1000.0], [0.0, 0.0, -1.0], &mk(0.0));
        let (d2, _) = shade([0.0, 0.0, 2000.0], [0.0, 0.0, -1.0], &mk(0.0));
        assert!((d1[0] / d2[0] - 4.0).abs() < 1e-9);
        // Light at the camera: the highlight is strongest where the normal faces the camera.
        let (_, s_head) = shade([0.0, 0.0, 1000.0], [0.0, 0.0, -1.0], &mk(1.0));
        let (_, s_tilt) = shade([0.0, 0.0, 1000.0], normalize([0.3, 0.0, -1.0]), &mk(1.0));
        assert!(s_head[0] > s_tilt[0] * 2.0);
    }

    #[test]
    fn relight_keeps_background_and_noise_keeps_mean() {
        let s = synthetic_stage(1, 4);
        let cam = &s.model.camera;
        let mut tex = LinearImage::new(cam.width, cam.height).unwrap();
        tex.data.iter_mut().for_each(|v| *v = [0.5, 0.4, 0.3]);
        let out = relight(&s.model, &tex, &Lighting::default()).unwrap();
        let bg = s.model.points.iter().position(|p| p[0].is_nan()).unwrap();
        assert_eq!(out.data[bg], tex.data[bg]);
        let obj = s.model.points.iter().position(|p| p[0].is_finite()).unwrap();
        assert_ne!(out.data[obj], tex.data[obj]);
        // A photo with fine grain: the infused image keeps its mean, gains variance.
        let mut photo = tex.clone();
        for (i, v) in photo.data.iter_mut().enumerate() {
            let g = if (i * 7919) % 3 == 0 { 1.2 } else { 0.9 };
            v.iter_mut().for_each(|c| *c *= g);
        }
        let noisy = infuse_noise(&s.model, &tex, &photo, 0.5, 3).unwrap();
        let mean =
            |img: &LinearImage| img.data.iter().map(|v| v[0] as f64).sum::<f64>() / img.data.len() as f64;
        assert!((mean(&noisy) / mean(&tex) - 1.0).abs() < 0.02);
        assert!(noisy.data.iter().any(|v| (v[0] - 0.5).abs() > 0.02));
        let none = infuse_noise(&s.model, &tex, &photo, 0.0, 3).unwrap();
        assert_eq!(none, tex);
    }

    #[test]
    fn bad_input_is_refused() {
        let s = synthetic_stage(1, 4);
        let small = LinearImage::new(3, 3).unwrap();
        assert!(matches!(
            relight(&s.model, &small, &Lighting::default()),
            Err(RelightError::SizeMismatch { .. })
        ));
        let bad = Lighting { shininess: 0.0, ..Lighting::default() };
        let tex = LinearImage::new(s.model.camera.width, s.model.camera.height).unwrap();
        assert!(relight(&s.model, &tex, &bad).unwrap_err().to_string().contains("shininess"));
        assert!(infuse_noise(&s.model, &tex, &tex, 1.5, 3).is_err());
    }
}
