//! Blob snapping speed (paper §5.2 light transport): one dot image of a 1600x1200 camera with
//! a 16-pixel dot grid from a 1400x1050 projector, the per-image work of the transport step.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use restage_authoring::calibrate::transport::{
    DotSignal, Neighbourhood, Predictor, SnapContext, SnapParams, snap_blob, snap_dot_image,
};
use restage_authoring::imgio::LinearImage;

const CAM: (u32, u32) = (1600, 1200);
const PROJ: (u32, u32) = (1400, 1050);
const SPACING: u32 = 16;
/// Camera pixels per projector pixel, and the blob's standard deviation in camera pixels.
const SCALE: f32 = 1.1;
const SIGMA: f32 = 0.8;

fn cam_of(qx: u32, qy: u32) -> [f32; 2] {
    [10.3 + SCALE * qx as f32, 12.7 + SCALE * qy as f32]
}

fn scene(dx: u32, dy: u32) -> (DotSignal, SnapContext, Predictor) {
    let (w, h) = CAM;
    let mut img = LinearImage::new(w, h).unwrap();
    for qy in (dy..PROJ.1).step_by(SPACING as usize) {
        for qx in (dx..PROJ.0).step_by(SPACING as usize) {
            let c = cam_of(qx, qy);
            for y in (c[1] as i64 - 4).max(0)..(c[1] as i64 + 5).min(h as i64) {
                for x in (c[0] as i64 - 4).max(0)..(c[0] as i64 + 5).min(w as i64) {
                    let d2 = (x as f32 - c[0]).powi(2) + (y as f32 - c[1]).powi(2);
                    let v = 0.2 * (-d2 / (2.0 * SIGMA * SIGMA)).exp();
                    img.set(x as u32, y as u32, [v, v * 0.9, v * 0.8]);
                }
            }
        }
    }
    let black = LinearImage::new(w, h).unwrap();
    let mut white = LinearImage::new(w, h).unwrap();
    white.data.iter_mut().for_each(|p| *p = [0.4, 0.36, 0.32]);
    let ctx = SnapContext::new(&black, &white, 0.001, &SnapParams::default());
    let corr: Vec<[f32; 2]> =
        (0..w * h).map(|i| [((i % w) as f32 - 10.3) / SCALE, ((i / w) as f32 - 12.7) / SCALE]).collect();
    let pred = Predictor::new(&corr, w, PROJ.0, PROJ.1);
    (DotSignal::from_linear(&img), ctx, pred)
}

fn bench(c: &mut Criterion) {
    let (img, ctx, pred) = scene(3, 5);
    let dots = PROJ.0.div_ceil(SPACING) as u64 * PROJ.1.div_ceil(SPACING) as u64;
    let mut g = c.benchmark_group("snap");
    g.throughput(Throughput::Elements(dots));
    g.bench_function("dot image 1600x1200, spacing 16", |b| {
        b.iter(|| snap_dot_image(&img, &ctx, &pred, SPACING, (3, 5), &SnapParams::default()))
    });
    g.throughput(Throughput::Elements(1));
    let (qx, qy) = (3 + SPACING * 40, 5 + SPACING * 30);
    let guess = cam_of(qx, qy);
    let s = SPACING as i64;
    let rivals = [(s, 0), (-s, 0), (0, s), (0, -s), (s, s), (-s, -s), (s, -s), (-s, s)]
        .map(|(ox, oy)| cam_of((qx as i64 + ox) as u32, (qy as i64 + oy) as u32))
        .to_vec();
    let around = Neighbourhood::new(guess, rivals, SPACING, SnapParams::default().max_radius);
    g.bench_function("one blob", |b| b.iter(|| snap_blob(&img, &ctx, guess, &around, 0.01, 0.003)));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
