//! Compensation's per-pixel work on the GPU (`gpu/compensate.wgsl`): weights and scale caps
//! per point, then demand, splatting and quantisation. The global scale (a quantile over all
//! points) is taken on the CPU between the two passes with the same function as the CPU path,
//! and the result goes through the same guarantee on the CPU afterwards. Agrees with
//! [`super::draft_cpu`] within one 8-bit level (f32 arithmetic and fixed-point sums here).

use bytemuck::{Pod, Zeroable};
use image::RgbImage;
use rayon::prelude::*;

use super::{CompensateError, Draft, Params, Prepared, ScaleChoice, global_scale, work_points};
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
    m: f32,
    m_inf: u32,
    scale: f32,
    fix: f32,
    total_px: u32,
    k_cur: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuPoint {
    t: [f32; 4],
    g: [f32; 4],
    a: [f32; 4],
    h: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuPk {
    l: f32,
    eta: f32,
    cert_lux: f32,
    _pad: f32,
    coord: [f32; 2],
    half: [f32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuProj {
    w: u32,
    h: u32,
    offset: u32,
    _pad: u32,
}

/// [`super::draft_cpu`] on `gpu`.
pub fn draft(
    gpu: &Gpu,
    stage: &StageModel,
    prep: &Prepared,
    target: &LinearImage,
    params: &Params,
) -> Result<Draft, CompensateError> {
    let t0 = std::time::Instant::now();
    let geom = &prep.geometry;
    let cert = &prep.certificate;
    let kn = geom.projectors;
    let limit = params.limit();
    let room = cert.ambient_lux;
    let idx = work_points(stage, geom, target);
    if idx.is_empty() {
        return Err(CompensateError::NoCoverage);
    }
    let covered = idx.len();
    let v4 = |v: [f32; 3]| [v[0], v[1], v[2], 0.0];
    let points: Vec<GpuPoint> = idx
        .par_iter()
        .map(|&i| {
            let i = i as usize;
            let pt = cert.point_of_pixel[i] as usize;
            GpuPoint {
                t: v4(target.data[i]),
                g: v4(stage.gain[i]),
                a: v4(stage.ambient[i]),
                h: v4(std::array::from_fn(|c| (limit - room - prep.floor[pt][c]).max(0.0) as f32)),
            }
        })
        .collect();
    let pk: Vec<GpuPk> = idx
        .par_iter()
        .flat_map_iter(|&i| {
            let i = i as usize;
            let pt = cert.point_of_pixel[i] as usize;
            (0..kn).map(move |k| {
                let ik = i * kn + k;
                GpuPk {
                    l: geom.l[ik],
                    eta: geom.eta[ik],
                    cert_lux: cert.projectors[k].2[pt].lux_per_unit,
                    _pad: 0.0,
                    coord: geom.coord[ik],
                    half: geom.half[ik],
                }
            })
        })
        .collect();
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
    let (m, m_inf) = match params.m {
        super::Exponent::Finite(m) => (m as f32, 0),
        super::Exponent::Infinite => (0.0, 1),
    };
    let mut prm = GpuParams {
        points: covered as u32,
        kn: kn as u32,
        m,
        m_inf,
        scale: 0.0,
        fix: FIX,
        total_px,
        k_cur: 0,
    };

    let module = gpu.module("compensate", SHADER);
    let p_caps = gpu.pipeline(&module, "weights_caps");
    let p_splat = gpu.pipeline(&module, "splat");
    let p_resolve = gpu.pipeline(&module, "resolve");
    let b_prm = gpu.storage("compensation parameters", std::slice::from_ref(&prm))?;
    let b_pts = gpu.storage("object points", &points)?;
    let b_pk = gpu.storage("point-projector geometry", &pk)?;
    let b_w = gpu.output("weights", (covered * kn * 4) as u64)?;
    let b_caps = gpu.output("scale caps", (covered * 8) as u64)?;
    let b_proj = gpu.storage("projectors", &proj)?;
    let largest = proj.iter().map(|p| p.w as u64 * p.h as u64).max().unwrap_or(1);
    let b_acc = gpu.output("splat sums", largest * 32)?;
    let b_lut = gpu.storage("inverse responses", &lut)?;
    let b_frame = gpu.output("frames", total_px as u64 * 4)?;

    // Pass 1: weights and caps.
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let g = gpu.bind(&p_caps, &[(0, &b_prm), (1, &b_pts), (2, &b_pk), (3, &b_w), (4, &b_caps)]);
    gpu.dispatch(&mut enc, &p_caps, &g, covered as u64);
    gpu.queue.submit([enc.finish()]);
    let caps: Vec<[f32; 2]> = gpu.read(&b_caps, covered)?;
    let caps: Vec<(f64, f64)> =
        caps.iter().map(|c| (c[0] as f64, c[1] as f64)).map(|(b, s)| (unbig(b), unbig(s))).collect();
    let ScaleChoice { scale, by_bound, by_sat, curve } = global_scale(&caps, params.clip_fraction);
    let clip_fraction = params.clip_fraction;
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, scale, "compensate (GPU): caps done");

    // Pass 2 and 3, projector by projector: demand and splat, then average and quantise.
    prm.scale = scale as f32;
    let g_splat =
        gpu.bind(&p_splat, &[(0, &b_prm), (1, &b_pts), (2, &b_pk), (3, &b_w), (5, &b_proj), (6, &b_acc)]);
    let g_res = gpu.bind(&p_resolve, &[(0, &b_prm), (5, &b_proj), (6, &b_acc), (7, &b_lut), (8, &b_frame)]);
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
    let w_cov: Vec<f32> = gpu.read(&b_w, covered * kn)?;
    tracing::debug!(ms = t0.elapsed().as_secs_f64() * 1e3, "compensate (GPU): frames done");

    let frames = proj
        .iter()
        .map(|p| {
            let px = &packed[p.offset as usize..(p.offset + p.w * p.h) as usize];
            let raw: Vec<u8> = px.iter().flat_map(|&v| [v as u8, (v >> 8) as u8, (v >> 16) as u8]).collect();
            RgbImage::from_raw(p.w, p.h, raw).expect("buffer sized to the frame")
        })
        .collect();
    let mut weights = vec![0.0f32; geom.points * kn];
    for (j, &i) in idx.iter().enumerate() {
        let i = i as usize;
        weights[i * kn..(i + 1) * kn].copy_from_slice(&w_cov[j * kn..(j + 1) * kn]);
    }
    // Points that are covered but not worked on (no gain, no finite target) still carry
    // their weights for the reports, as on the CPU path.
    let mut done = vec![false; geom.points];
    idx.iter().for_each(|&i| done[i as usize] = true);
    weights.par_chunks_mut(kn).zip(geom.l.par_chunks(kn)).zip(&done).for_each(|((w, l), &d)| {
        if !d {
            super::weights::point_weights(l, params.m, w);
        }
    });
    Ok(Draft { weights, frames, scale, covered, by_bound, by_sat, curve, clip_fraction })
}

/// The shader's stand-in for infinity back to infinity.
fn unbig(v: f64) -> f64 {
    if v >= 1e38 { f64::INFINITY } else { v }
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
