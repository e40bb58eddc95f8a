// Relighting's per-pixel shading on the GPU, the same model as relight::shade (Lambert
// diffuse plus Blinn-Phong specular seen from the camera at the origin), in f32.

struct Params {
    count: u32,
    lights: u32,
    ambient: f32,
    specular: f32,
    shininess: f32,
    exposure: f32,
    _pad0: u32,
    _pad1: u32,
}

// xyz: the unit direction towards the light (directional) or the position in mm (point);
// w: 0 directional, 1 point. colour.xyz: the light's colour (at 1 m for a point light).
struct Light {
    v: vec4<f32>,
    colour: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> prm: Params;
@group(0) @binding(1) var<storage, read> lights: array<Light>;
// Per camera pixel: surface point (w = 1 where the stage knows the surface), normal, texture.
@group(0) @binding(2) var<storage, read> pts: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> nrm: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> tex: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> outp: array<vec4<f32>>;

fn unit(v: vec3<f32>) -> vec3<f32> {
    let l = length(v);
    if (l > 0.0) {
        return v / l;
    }
    return v;
}

@compute @workgroup_size(256)
fn relight(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = id.x + id.y * groups.x * 256u;
    if (i >= prm.count) {
        return;
    }
    let t = tex[i];
    if (pts[i].w == 0.0) {
        outp[i] = t;
        return;
    }
    let p = pts[i].xyz;
    let n = unit(nrm[i].xyz);
    let view = unit(-p);
    var diffuse = vec3<f32>(prm.ambient);
    var spec = vec3<f32>(0.0);
    for (var j = 0u; j < prm.lights; j++) {
        let l = lights[j];
        var to_light = l.v.xyz;
        var colour = l.colour.xyz;
        if (l.v.w != 0.0) {
            let d = l.v.xyz - p;
            let dist_m = length(d) / 1000.0;
            to_light = unit(d);
            colour = colour / max(dist_m * dist_m, 1e-6);
        }
        let c = dot(n, to_light);
        if (c <= 0.0) {
            continue;
        }
        let h = unit(to_light + view);
        let nh = dot(n, h);
        var s = 0.0;
        if (nh > 0.0) {
            s = prm.specular * pow(nh, prm.shininess);
        }
        diffuse += c * colour;
        spec += s * colour;
    }
    outp[i] = vec4<f32>(prm.exposure * (t.xyz * diffuse + spec), 0.0);
}
