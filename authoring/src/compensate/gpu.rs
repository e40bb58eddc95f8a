//! Compensation's splatting and quantisation on the GPU (`gpu/compensate.wgsl`). The
//! per-point part — weights, the global scale and each point's demand — is
//! [`super::plan_points`] on the CPU, as on the CPU path, and the result goes through the same
//! guarantee on the CPU afterwards. Agrees with [`super::draft_cpu`] within one 8-bit level
//! (f32 arithmetic and fixed-point sums here).

use bytemuck::{Pod, Zeroable};
use image::RgbImage;
use rayon::prelude::*;

use super::{CompensateError, Draft, Params, PointPlan, Prepared, ScaleChoice, plan_points};
use crate::gpu::Gpu;
use crate::imgio::LinearImage;
use crate::stage_model::StageModel;

const SHADER: &str = include_str!("../gpu/compensate.wgsl");

/// Fixed-point unit of the splat sums: 2^31 per unit of relative output (each contribution is
/// at most 1, so it fits a 32-bit word; the sums are 64-bit).
const FIX: f32 = 2147483648.0;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuParams {
    points: u32,
    kn: u32,
    fix: f32,
    total_px: u32,
    k_cur: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuPk {
    coord: [f32; 2],
    half: [f32; 2],
    eta: f32,
    _pad: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuProj {
    w: u32,
    h: u32,
    offset: u32,
    _pad: u32,
}

/// [`super::draft_cpu`] with the splatting and quantisation on `gpu`.
pub fn draft(
    gpu: &Gpu,
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Draft, CompensateError> {
    let t0 = std::time::Instant::now();
    let geom = &prep.geometry;
    let kn = geom.projectors;
    let PointPlan { weights, idx, scale, demand } = plan_points(stage, prep, target, params)?;
    let ScaleChoice { scale, by_bound, by_sat, curve } = scale;
    let covered = idx.len();
    let pk: Vec<GpuPk> = idx
        .par_iter()
        .flat_map_iter(|&i| {
            let i = i as usize;
            (0..kn).map(move |k| {
                let ik = i * kn + k;
                GpuPk { coord: geom.coord[ik], half: geom.half[ik], eta: geom.eta[ik], _pad: [0.0; 3] }
            })
        })
        .collect();
    let w_cov: Vec<f32> = idx
        .par_iter()
        .flat_map_iter(|&i| weights[i as usize * kn..(i as usize + 1) * kn].iter().copied())
        .collect();
    let dem: Vec<[f32; 4]> = demand.iter().map(|d| [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]).collect();
    let mut offset = 0u32;
    let proj: Vec<GpuProj> = stage
        .projectors
        .iter()
        .map(|p| {
            let r = GpuProj { w: p.width, h: p.height, offset, _pad: 0 };
            offset += p.width * p.height;
            r
        })
        .collect();
    let total_px = offset;
    // Inverse-response tables, projector-major then channel, bytes packed into words.
    let lut: Vec<u8> =
        prep.inverse.iter().flat_map(|inv| inv.iter().flat_map(|c| c.table().iter().copied())).collect();
    let lut: Vec<u32> =
        lut.chunks(4).map(|b| u32::from_le_bytes(std::array::from_fn(|j| *b.get(j).unwrap_or(&0)))).collect();
    let mut prm = GpuParams { points: covered as u32, kn: kn as u32, fix: FIX, total_px, k_cur: 0 };

    let module = gpu.module("compensate", SHADER);
    let p_splat = gpu.pipeline(&module, "splat");
    let p_resolve = gpu.pipeline(&module, "resolve");
    let b_prm = gpu.storage("compensation parameters", std::slice::from_ref(&prm))?;
    let b_pk = gpu.storage("point-projector geometry", &pk)?;
    let b_w = gpu.storage("weights", &w_cov)?;
    let b_dem = gpu.storage("demands", &dem)?;
    let b_proj = gpu.storage("projectors", &proj)?;
    let largest = proj.iter().map(|p| p.w as u64 * p.h as u64).max().unwrap_or(1);
    let b_acc = gpu.output("splat sums", largest * 32)?;
    let b_lut = gpu.storage("inverse responses", &lut)?;
    let b_frame = gpu.output("frames", total_px as u64 * 4)?;
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate (GPU): uploaded");

    // Projector by projector: splat, then average and quantise.
    let g_splat =
        gpu.bind(&p_splat, &[(0, &b_prm), (1, &b_pk), (2, &b_w), (3, &b_dem), (4, &b_proj), (5, &b_acc)]);
    let g_res = gpu.bind(&p_resolve, &[(0, &b_prm), (4, &b_proj), (5, &b_acc), (6, &b_lut), (7, &b_frame)]);
    for (k, p) in proj.iter().enumerate() {
        prm.k_cur = k as u32;
        // Applied before the next submission, so each projector's passes see their own k.
        gpu.queue.write_buffer(&b_prm, 0, bytemuck::bytes_of(&prm));
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&b_acc, 0, None);
        gpu.dispatch(&mut enc, &p_splat, &g_splat, covered as u64);
        gpu.dispatch(&mut enc, &p_resolve, &g_res, p.w as u64 * p.h as u64);
        gpu.queue.submit([enc.finish()]);
    }
    let packed: Vec<u32> = gpu.read(&b_frame, total_px as usize)?;
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate (GPU): frames done");

    let frames = proj
        .iter()
        .map(|p| {
            let px = &packed[p.offset as usize..(p.offset + p.w * p.h) as usize];
            let raw: Vec<u8> = px.iter().flat_map(|&v| [v as u8, (v >> 8) as u8, (v >> 16) as u8]).collect();
            RgbImage::from_raw(p.w, p.h, raw).expect("buffer sized to the frame")
        })
        .collect();
    Ok(Draft {
        weights,
        frames,
        scale,
        covered,
        by_bound,
        by_sat,
        curve,
        clip_fraction: params.clip_fraction,
        idx,
        demand,
    })
}

#[cfg(test)]
mod tests {
    use super::super::synthetic::{SyntheticSpec, build};
    use super::super::{Exponent, compensate_on, draft_cpu};
    use super::*;
    use crate::gpu::Device;

    /// GPU and CPU drafts agree within one 8-bit level everywhere, for every kind of m, and
    /// the GPU result passes the (CPU) guarantee.
    #[test]
    fn gpu_agrees_with_cpu_within_one_level() {
        let Some(gpu) = crate::gpu::for_tests() else { return };
        let s = build(&SyntheticSpec { camera: (96, 72), projector: (80, 60), ..SyntheticSpec::small(3, 5) });
        let cam = &s.model.camera;
        let mut t = LinearImage::new(cam.width, cam.height).unwrap();
        for (v, a) in t.data.iter_mut().zip(&s.albedo) {
            *v = if a[0].is_finite() { a.map(|c| 0.8 * c) } else { [0.0; 3] };
        }
        for (m, e_bound) in [
            (Exponent::Finite(0.0), 150.0),
            (Exponent::Finite(1.0), 2000.0),
            (Exponent::Finite(8.0), 150.0),
            (Exponent::Finite(2.5), 400.0),
            (Exponent::Infinite, 150.0),
        ] {
            let p = Params::new(e_bound, m, 0.05).unwrap();
            let prep = Prepared::new(&s.model, p.reduction).unwrap();
            let c = draft_cpu(&s.model, &prep, &t, &p).unwrap();
            let g = draft(gpu, &s.model, &prep, &t, &p).unwrap();
            assert!((g.scale / c.scale - 1.0).abs() < 1e-4, "m {m}: scale {} vs {}", g.scale, c.scale);
            assert_eq!(g.covered, c.covered);
            let wd = g.weights.iter().zip(&c.weights).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(wd < 1e-4, "m {m}: weights differ by {wd}");
            let mut lit = 0;
            for (fg, fc) in g.frames.iter().zip(&c.frames) {
                for (a, b) in fg.as_raw().iter().zip(fc.as_raw()) {
                    assert!(a.abs_diff(*b) <= 1, "m {m}: GPU {a} vs CPU {b}");
                    lit += (*b > 0) as usize;
                }
            }
            assert!(lit > 1000, "m {m}: the comparison must cover lit pixels ({lit})");
            let full = compensate_on(&s.model, &prep, &t, &p, Device::Gpu).unwrap();
            assert!(full.stats.peak_lux <= p.limit());
        }
    }
}
