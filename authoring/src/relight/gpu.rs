//! Relighting's per-pixel shading on the GPU (`gpu/relight.wgsl`); agrees with the CPU
//! reference [`super::relight`] within one 8-bit sRGB level (f32 here, f64 there).

use bytemuck::{Pod, Zeroable};

use super::{Light, Lighting, RelightError, normalize};
use crate::gpu::Gpu;
use crate::imgio::LinearImage;
use crate::stage_model::StageModel;

const SHADER: &str = include_str!("../gpu/relight.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuParams {
    count: u32,
    lights: u32,
    ambient: f32,
    specular: f32,
    shininess: f32,
    exposure: f32,
    _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuLight {
    v: [f32; 4],
    colour: [f32; 4],
}

/// The shading of [`super::relight`], validated inputs assumed.
pub fn relight(
    gpu: &Gpu,
    stage: &StageModel,
    texture: &LinearImage,
    lighting: &Lighting,
) -> Result<LinearImage, RelightError> {
    let n = texture.data.len();
    let prm = GpuParams {
        count: n as u32,
        lights: lighting.lights.len() as u32,
        ambient: lighting.ambient as f32,
        specular: lighting.specular as f32,
        shininess: lighting.shininess as f32,
        exposure: lighting.exposure as f32,
        _pad: [0; 2],
    };
    let f4 = |v: [f64; 3], w: f32| [v[0] as f32, v[1] as f32, v[2] as f32, w];
    let lights: Vec<GpuLight> = lighting
        .lights
        .iter()
        .map(|l| match l {
            Light::Directional { direction, colour } => {
                GpuLight { v: f4(normalize(direction.map(|v| -v)), 0.0), colour: f4(*colour, 0.0) }
            }
            Light::Point { position, colour } => GpuLight { v: f4(*position, 1.0), colour: f4(*colour, 0.0) },
        })
        .collect();
    // A binding holds at least one element; the shader reads only `prm.lights` of them.
    let lights = if lights.is_empty() { vec![GpuLight::zeroed()] } else { lights };
    let known = |i: usize| stage.points[i].iter().chain(&stage.normals[i]).all(|v| v.is_finite());
    let pts: Vec<[f32; 4]> = (0..n)
        .map(|i| {
            if known(i) {
                [stage.points[i][0], stage.points[i][1], stage.points[i][2], 1.0]
            } else {
                [0.0; 4]
            }
        })
        .collect();
    let nrm: Vec<[f32; 4]> =
        (0..n).map(|i| if known(i) { f4(stage.normals[i].map(f64::from), 0.0) } else { [0.0; 4] }).collect();
    let tex: Vec<[f32; 4]> = texture.data.iter().map(|t| [t[0], t[1], t[2], 0.0]).collect();

    let module = gpu.module("relight", SHADER);
    let pipe = gpu.pipeline(&module, "relight");
    let b_prm = gpu.storage("relight parameters", std::slice::from_ref(&prm))?;
    let b_lights = gpu.storage("lights", &lights)?;
    let b_pts = gpu.storage("points", &pts)?;
    let b_nrm = gpu.storage("normals", &nrm)?;
    let b_tex = gpu.storage("texture", &tex)?;
    let b_out = gpu.output("relit", n as u64 * 16)?;
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let g =
        gpu.bind(&pipe, &[(0, &b_prm), (1, &b_lights), (2, &b_pts), (3, &b_nrm), (4, &b_tex), (5, &b_out)]);
    gpu.dispatch(&mut enc, &pipe, &g, n as u64);
    gpu.queue.submit([enc.finish()]);
    let out: Vec<[f32; 4]> = gpu.read(&b_out, n)?;
    Ok(LinearImage {
        width: texture.width,
        height: texture.height,
        data: out.iter().map(|v| [v[0], v[1], v[2]]).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::synthetic_stage;

    #[test]
    fn gpu_agrees_with_cpu_within_one_level() {
        let Some(gpu) = crate::gpu::for_tests() else { return };
        let s = synthetic_stage(1, 4);
        let cam = &s.model.camera;
        let mut tex = LinearImage::new(cam.width, cam.height).unwrap();
        for (i, v) in tex.data.iter_mut().enumerate() {
            *v = [0.2 + 0.6 * ((i % 7) as f32 / 7.0), 0.4, 0.1 + 0.8 * ((i % 13) as f32 / 13.0)];
        }
        let lighting = Lighting {
            lights: vec![
                Light::Directional { direction: [0.6, 0.5, 1.0], colour: [1.0, 0.97, 0.92] },
                Light::Point { position: [-200.0, -300.0, 100.0], colour: [0.5, 0.5, 0.6] },
            ],
            specular: 0.4,
            ..Lighting::default()
        };
        let c = super::super::relight(&s.model, &tex, &lighting).unwrap();
        let g = relight(gpu, &s.model, &tex, &lighting).unwrap();
        let (c8, g8) = (c.to_srgb8(1.0), g.to_srgb8(1.0));
        let worst = c8.as_raw().iter().zip(g8.as_raw()).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
        assert!(worst <= 1, "relit images differ by {worst} levels");
        let lin = c.data.iter().zip(&g.data).map(|(a, b)| (a[0] - b[0]).abs()).fold(0.0f32, f32::max);
        assert!(lin < 1e-3, "linear difference {lin}");
        assert_ne!(c.data, tex.data, "lighting changed the image");
    }
}
