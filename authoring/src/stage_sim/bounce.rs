//! One bounce of interreflection on the virtual stage: light the grey plinth reflects
//! diffusely (Lambertian) onto the object. The plinth's top is cut into patches (rings x
//! sectors around the object's axis); the transfer from every patch to the object's side is
//! precomputed once on a coarse height x azimuth grid, with visibility; per frame the
//! patches' irradiance is gathered and the grid interpolated wherever the object is lit.
//!
//! The object is a solid of revolution standing on the centre of a round plinth, so the
//! transfer depends only on the receiver's height and the azimuth between receiver and
//! patch: it is computed for one azimuth and applied to all by rotation.

use std::f64::consts::{PI, TAU};

use rayon::prelude::*;

use super::geometry::{Part, Scene, V3};

/// Rings of plinth patches between the object's foot and the plinth's rim.
pub const RINGS: usize = 12;
/// Sectors of plinth patches (and receiver azimuths) around the axis.
pub const SECTORS: usize = 48;
/// Receiver heights along the object's side.
pub const HEIGHTS: usize = 48;
/// Receivers keep this far (mm) from the object's ends, where it meets the plinth.
const END_MM: f64 = 1.0;

/// Bilinear weights into the receiver grid for one object point.
pub type Interp = ([u32; 4], [f32; 4]);

/// The precomputed plinth-to-object transfer.
#[derive(Clone, Debug)]
pub struct Bounce {
    /// The object solid the receivers lie on (the one standing on the plinth).
    pub solid: usize,
    /// Patch centres on the plinth's top (ring-major), mm, camera frame; patch `(r, s)` is
    /// at azimuth `(s + 0.5) * 2 pi / SECTORS` of the solid.
    pub patches: Vec<V3>,
    /// The plinth top's normal (the object's axis).
    pub up: V3,
    /// `transfer[(h * RINGS + r) * SECTORS + ds]`: lux at the receiver at height index `h`,
    /// azimuth 0, per lux on patch `(r, ds)`: `albedo / pi * cos * cos / d^2 * area` where
    /// the patch sees the receiver, else 0.
    transfer: Vec<f32>,
    height: f64,
}

impl Bounce {
    /// The transfer from a plinth of `radius` and `albedo` whose top is the base plane of
    /// `scene.solids[solid]`, centred on its axis.
    pub fn new(scene: &Scene, solid: usize, radius: f64, albedo: f64) -> Self {
        let s = &scene.solids[solid];
        let height = s.height();
        let at =
            |phi: f64, rho: f64, h: f64| s.base + (s.e1 * phi.cos() + s.e2 * phi.sin()) * rho + s.axis * h;
        let r0 = s.radius_at(0.0);
        let dr = (radius - r0).max(0.0) / RINGS as f64;
        let dphi = TAU / SECTORS as f64;
        let mut patches = Vec::with_capacity(RINGS * SECTORS);
        let mut areas = Vec::with_capacity(RINGS);
        for r in 0..RINGS {
            let (a, b) = (r0 + dr * r as f64, r0 + dr * (r + 1) as f64);
            areas.push(dphi * (b * b - a * a) * 0.5);
            patches.extend((0..SECTORS).map(|k| at((k as f64 + 0.5) * dphi, (a + b) * 0.5, 0.0)));
        }
        let up = s.axis;
        let transfer = (0..HEIGHTS)
            .into_par_iter()
            .flat_map_iter(|hi| {
                let h = receiver_height(hi, height);
                let x = at(0.0, s.radius_at(h), h);
                let n = s.normal(&x, Part::Side);
                // Aim just off the surface so the visibility march does not end on it.
                let target = x + n * 0.5;
                let (patches, areas) = (&patches, &areas);
                (0..RINGS * SECTORS).map(move |i| {
                    let q = patches[i];
                    let area = areas[i / SECTORS];
                    let d = q - x;
                    let dist2 = d.norm_squared();
                    let dist = dist2.sqrt();
                    let (cos_x, cos_q) = (n.dot(&d) / dist, -up.dot(&d) / dist);
                    if cos_x <= 0.0 || cos_q <= 0.0 || !scene.visible(&q, &up, &target) {
                        return 0.0;
                    }
                    // A patch closer than its own size counts as if at that distance.
                    (albedo / PI * cos_x * cos_q / dist2.max(area) * area) as f32
                })
            })
            .collect();
        Self { solid, patches, up, transfer, height }
    }

    /// Bounce irradiance on the receiver grid (`h * SECTORS + j`, lux per channel) from the
    /// irradiance on every patch.
    pub fn field(&self, patch_lux: &[[f32; 3]]) -> Vec<[f32; 3]> {
        (0..HEIGHTS * SECTORS)
            .into_par_iter()
            .map(|g| {
                let (h, j) = (g / SECTORS, g % SECTORS);
                let mut e = [0.0f32; 3];
                for r in 0..RINGS {
                    let row = &self.transfer[(h * RINGS + r) * SECTORS..(h * RINGS + r + 1) * SECTORS];
                    for s in 0..SECTORS {
                        let t = row[(s + SECTORS - j) % SECTORS];
                        if t > 0.0 {
                            let l = patch_lux[r * SECTORS + s];
                            for c in 0..3 {
                                e[c] += t * l[c];
                            }
                        }
                    }
                }
                e
            })
            .collect()
    }

    /// Where object point `x` on `solid`'s `part` falls in the receiver grid; None off the
    /// side of the receiving solid (its caps face away from the plinth or lie on it).
    pub fn interp(&self, scene: &Scene, solid: usize, part: Part, x: &V3) -> Option<Interp> {
        if solid != self.solid || part != Part::Side {
            return None;
        }
        let (h, _, theta) = scene.solids[solid].local(x);
        let fh = ((h - END_MM) / (self.height - 2.0 * END_MM)).clamp(0.0, 1.0) * (HEIGHTS - 1) as f64;
        let h0 = (fh as usize).min(HEIGHTS - 2);
        let th = fh - h0 as f64;
        let fj = theta.rem_euclid(TAU) / (TAU / SECTORS as f64);
        let j0 = (fj as usize) % SECTORS;
        let tj = fj - fj.floor();
        let j1 = (j0 + 1) % SECTORS;
        let idx = |h: usize, j: usize| (h * SECTORS + j) as u32;
        Some((
            [idx(h0, j0), idx(h0, j1), idx(h0 + 1, j0), idx(h0 + 1, j1)],
            [(1.0 - th) * (1.0 - tj), (1.0 - th) * tj, th * (1.0 - tj), th * tj].map(|w| w as f32),
        ))
    }
}

/// Interpolated bounce from a [`Bounce::field`].
pub fn sample(field: &[[f32; 3]], at: &Interp) -> [f32; 3] {
    let mut e = [0.0f32; 3];
    for (i, w) in at.0.iter().zip(at.1) {
        for c in 0..3 {
            e[c] += w * field[*i as usize][c];
        }
    }
    e
}

fn receiver_height(i: usize, height: f64) -> f64 {
    END_MM + (height - 2.0 * END_MM) * i as f64 / (HEIGHTS - 1) as f64
}
