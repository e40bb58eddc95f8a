// Compensation's splatting and quantisation on the GPU, the same arithmetic as the CPU
// reference in compensate/mod.rs (f32 here): each point's demand (worked out on the CPU with
// the weights and the global scale, compensate::plan_points) split over the projectors by its
// weight and splatted (tent over its footprint) into 64-bit fixed-point accumulators (two
// 32-bit atomics with carry), one projector at a time; then per projector pixel the average,
// through the inverse response table, to 8 bits. Integer atomics make the sums independent of
// the order the GPU runs threads in; 2^-31 resolution keeps the average right even where a
// pixel gathers only the tiny tail of a tent.

struct Params {
    points: u32,
    kn: u32,
    fix: f32,
    total_px: u32,
    // The projector the splat and resolve passes work on.
    k_cur: u32,
}

// One point seen (or not) by one projector: its correspondence and footprint's half extent
// (projector pixels) and its efficiency (lux per unit of relative output; 0 where unseen).
struct PK {
    coord: vec2<f32>,
    half: vec2<f32>,
    eta: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}

struct Proj {
    w: u32,
    h: u32,
    offset: u32,
    _pad: u32,
}

@group(0) @binding(0) var<storage, read> prm: Params;
@group(0) @binding(1) var<storage, read> pk: array<PK>;
@group(0) @binding(2) var<storage, read> weights: array<f32>;
// Per point, the demand above black (lux per channel, xyz).
@group(0) @binding(3) var<storage, read> dem: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> proj: array<Proj>;
@group(0) @binding(5) var<storage, read_write> acc: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read> lut: array<u32>;
@group(0) @binding(7) var<storage, read_write> frame: array<u32>;

fn index(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 256u;
}

@compute @workgroup_size(256)
fn splat(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let p = index(id, groups);
    if (p >= prm.points) {
        return;
    }
    let kn = prm.kn;
    let d = dem[p].xyz;
    let k = prm.k_cur;
    let e = pk[p * kn + k];
    if (e.eta <= 0.0) {
        return;
    }
    let r = weights[p * kn + k] * d / e.eta;
    let pr = proj[k];
    let rx = e.half.x + 0.5;
    let ry = e.half.y + 0.5;
    let xa = max(i32(ceil(e.coord.x - rx)), 0);
    let xb = min(i32(floor(e.coord.x + rx)), i32(pr.w) - 1);
    let ya = max(i32(ceil(e.coord.y - ry)), 0);
    let yb = min(i32(floor(e.coord.y + ry)), i32(pr.h) - 1);
    for (var y = ya; y <= yb; y++) {
        let wy = 1.0 - abs(f32(y) - e.coord.y) / ry;
        for (var x = xa; x <= xb; x++) {
            let bw = wy * (1.0 - abs(f32(x) - e.coord.x) / rx);
            if (bw <= 0.0) {
                continue;
            }
            let a = (u32(y) * pr.w + u32(x)) * 8u;
            add64(a, bw * r.x);
            add64(a + 2u, bw * r.y);
            add64(a + 4u, bw * r.z);
            add64(a + 6u, bw);
        }
    }
}

// Adds v (0..=1) in units of 2^-31 to the 64-bit sum at acc[i] (low word), acc[i + 1] (high).
fn add64(i: u32, v: f32) {
    let x = u32(clamp(v, 0.0, 1.0) * prm.fix + 0.5);
    let old = atomicAdd(&acc[i], x);
    if (old + x < old) {
        atomicAdd(&acc[i + 1u], 1u);
    }
}

fn sum64(i: u32) -> f32 {
    return f32(atomicLoad(&acc[i + 1u])) * 4294967296.0 + f32(atomicLoad(&acc[i]));
}

fn lut_byte(i: u32) -> u32 {
    return (lut[i >> 2u] >> ((i & 3u) * 8u)) & 255u;
}

@compute @workgroup_size(256)
fn resolve(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let gi = index(id, groups);
    let k = prm.k_cur;
    let pr = proj[k];
    if (gi >= pr.w * pr.h) {
        return;
    }
    let wsum = sum64(gi * 8u + 6u);
    var out = 0u;
    if (wsum > 0.0) {
        for (var c = 0u; c < 3u; c++) {
            let v = clamp(sum64(gi * 8u + 2u * c) / wsum, 0.0, 1.0);
            let q = min(u32(sqrt(v) * 65535.0 + 0.5), 65535u);
            out = out | (lut_byte((k * 3u + c) * 65536u + q) << (8u * c));
        }
    }
    frame[pr.offset + gi] = out;
}
