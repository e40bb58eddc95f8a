//! Object geometry of the virtual stage: solids of revolution in millimetres, placed in the
//! camera frame, with ray casting by conservative sphere tracing (each solid's implicit
//! function divided by its Lipschitz bound never overestimates the distance to it).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

pub type V3 = Vector3<f64>;

/// Radius as a function of height along the axis (mm), closed forms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[serde(deny_unknown_fields)]
pub enum Profile {
    /// A vase: foot, round belly, narrow neck, flared lip; 300 mm tall.
    Vase,
    /// A wide bowl on a foot; 150 mm tall, 300 mm across the rim.
    Bowl,
    /// A round-shouldered jar; 240 mm tall.
    Jar,
    /// A straight cylinder (with `height` small and the axis towards the camera, a flat disc).
    Cylinder { radius: f64, height: f64 },
}

impl Profile {
    pub fn height(&self) -> f64 {
        match self {
            Profile::Vase => 300.0,
            Profile::Bowl => 150.0,
            Profile::Jar => 240.0,
            Profile::Cylinder { height, .. } => *height,
        }
    }

    /// Radius at height `h` in `0..=height`.
    pub fn radius(&self, h: f64) -> f64 {
        let g = |c: f64, w: f64| (-((h - c) / w).powi(2)).exp();
        match self {
            Profile::Vase => 38.0 + 57.0 * g(115.0, 75.0) - 8.0 * g(235.0, 25.0) + 16.0 * g(300.0, 15.0),
            Profile::Bowl => {
                let x = (h / 150.0).clamp(0.0, 1.0);
                45.0 + 105.0 * (1.0 - (1.0 - x).powf(2.5)) + 4.0 * g(150.0, 6.0)
            }
            Profile::Jar => {
                let x = (h / 240.0).clamp(0.0, 1.0);
                58.0 + 42.0 * (std::f64::consts::PI * x).sin().powf(1.5) + 6.0 * g(240.0, 10.0)
            }
            Profile::Cylinder { radius, .. } => *radius,
        }
    }
}

/// Which part of a solid a point lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    Side,
    Bottom,
    Top,
}

/// A solid of revolution: `profile` swept around `axis` from `base` (mm, camera frame).
#[derive(Clone, Debug)]
pub struct Solid {
    pub profile: Profile,
    pub base: V3,
    /// Unit vector from the base towards the top.
    pub axis: V3,
    /// Unit vectors perpendicular to the axis; azimuth 0 is along `e1`.
    pub e1: V3,
    pub e2: V3,
    height: f64,
    radius: Vec<f64>,
    slope: Vec<f64>,
    lipschitz: f64,
    r_max: f64,
}

const TABLE: usize = 4096;

/// A ray-surface hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f64,
    pub point: V3,
    pub normal: V3,
    pub solid: usize,
    pub part: Part,
}

/// How a built-in object departs from its profile's nominal form: the radius at height `h`
/// is `profile.radius(h) * scale * (1 + taper * (h / height - 1/2))` (the height is kept, so
/// the painted design keeps its bands).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    pub scale: f64,
    pub taper: f64,
}

impl Shape {
    pub const NOMINAL: Shape = Shape { scale: 1.0, taper: 0.0 };

    fn radius(&self, profile: &Profile, h: f64) -> f64 {
        profile.radius(h) * self.scale * (1.0 + self.taper * (h / profile.height() - 0.5))
    }
}

impl Solid {
    /// `facing` is a direction perpendicular-ish to the axis that azimuth 0 points along.
    pub fn new(profile: Profile, base: V3, axis: V3, facing: V3) -> Self {
        Self::shaped(profile, Shape::NOMINAL, base, axis, facing)
    }

    /// [`Solid::new`] with the profile's radius reshaped by `shape`.
    pub fn shaped(profile: Profile, shape: Shape, base: V3, axis: V3, facing: V3) -> Self {
        let axis = axis.normalize();
        let e1 = (facing - axis * facing.dot(&axis)).normalize();
        let e2 = axis.cross(&e1);
        let height = profile.height();
        let dh = height / (TABLE - 1) as f64;
        let r = |h: f64| shape.radius(&profile, h);
        let radius: Vec<f64> = (0..TABLE).map(|i| r(i as f64 * dh)).collect();
        let slope: Vec<f64> = (0..TABLE)
            .map(|i| {
                let h = i as f64 * dh;
                let e = dh * 0.5;
                (r((h + e).min(height)) - r((h - e).max(0.0))) / ((h + e).min(height) - (h - e).max(0.0))
            })
            .collect();
        let max_slope = slope.iter().fold(0.0f64, |m, s| m.max(s.abs()));
        // A little headroom over the sampled slope keeps the bound conservative between samples.
        let lipschitz = (1.0 + (max_slope * 1.05 + 0.01).powi(2)).sqrt();
        let r_max = radius.iter().cloned().fold(0.0, f64::max);
        Self { profile, base, axis, e1, e2, height, radius, slope, lipschitz, r_max }
    }

    pub fn height(&self) -> f64 {
        self.height
    }

    pub fn max_radius(&self) -> f64 {
        self.r_max
    }

    fn table(&self, tab: &[f64], h: f64) -> f64 {
        let x = (h / self.height).clamp(0.0, 1.0) * (TABLE - 1) as f64;
        let i = (x as usize).min(TABLE - 2);
        let f = x - i as f64;
        tab[i] * (1.0 - f) + tab[i + 1] * f
    }

    /// Radius at height `h` (table-interpolated, as the ray caster sees it).
    pub fn radius_at(&self, h: f64) -> f64 {
        self.table(&self.radius, h)
    }

    /// Height along the axis, radial distance and azimuth (radians, -π..π) of `p`.
    pub fn local(&self, p: &V3) -> (f64, f64, f64) {
        let q = p - self.base;
        let h = q.dot(&self.axis);
        let x = q.dot(&self.e1);
        let y = q.dot(&self.e2);
        (h, x.hypot(y), y.atan2(x))
    }

    /// Conservative distance bound: positive outside, and never more than the true distance.
    fn bound(&self, p: &V3) -> (f64, Part) {
        let (h, rho, _) = self.local(p);
        let side = (rho - self.radius_at(h)) / self.lipschitz;
        let bottom = -h;
        let top = h - self.height;
        if side >= bottom && side >= top {
            (side, Part::Side)
        } else if bottom >= top {
            (bottom, Part::Bottom)
        } else {
            (top, Part::Top)
        }
    }

    /// Whether `p` is inside the solid.
    pub fn contains(&self, p: &V3) -> bool {
        self.bound(p).0 < 0.0
    }

    /// Outward unit normal at a surface point on `part`.
    pub fn normal(&self, p: &V3, part: Part) -> V3 {
        match part {
            Part::Bottom => -self.axis,
            Part::Top => self.axis,
            Part::Side => {
                let q = p - self.base;
                let h = q.dot(&self.axis);
                let radial = q - self.axis * h;
                let n = radial.norm();
                let rhat = if n > 1e-12 { radial / n } else { self.e1 };
                (rhat - self.axis * self.table(&self.slope, h)).normalize()
            }
        }
    }
}

/// The object: a union of solids.
#[derive(Clone, Debug)]
pub struct Scene {
    pub solids: Vec<Solid>,
}

const HIT_EPS: f64 = 1e-3;
const MAX_STEPS: usize = 2000;

impl Scene {
    fn bound(&self, p: &V3) -> (f64, usize, Part) {
        let mut best = (f64::INFINITY, 0, Part::Side);
        for (i, s) in self.solids.iter().enumerate() {
            let (d, part) = s.bound(p);
            if d < best.0 {
                best = (d, i, part);
            }
        }
        best
    }

    /// First hit of the ray `origin + t * dir` (unit `dir`) with `t` in `(0, t_max)`.
    pub fn cast(&self, origin: &V3, dir: &V3, t_max: f64) -> Option<Hit> {
        let mut t = 0.0;
        for _ in 0..MAX_STEPS {
            let p = origin + dir * t;
            let (d, solid, part) = self.bound(&p);
            if d < HIT_EPS {
                let normal = self.solids[solid].normal(&p, part);
                return Some(Hit { t, point: p, normal, solid, part });
            }
            t += d.max(HIT_EPS * 0.5);
            if t >= t_max {
                return None;
            }
        }
        None
    }

    /// Whether the straight path from surface point `p` (outward normal `n`) to `target` is
    /// free of the object. The start is lifted off the surface so it does not hit itself.
    pub fn visible(&self, p: &V3, n: &V3, target: &V3) -> bool {
        let start = p + n * 0.05;
        let to = target - start;
        let dist = to.norm();
        let dir = to / dist;
        let mut t = 0.0;
        for _ in 0..MAX_STEPS {
            let q = start + dir * t;
            let (d, _, _) = self.bound(&q);
            if d < HIT_EPS * 0.5 {
                return false;
            }
            t += d.max(HIT_EPS * 0.25);
            if t >= dist {
                return true;
            }
        }
        // A path that grazes the surface for thousands of steps counts as blocked.
        false
    }

    /// Centre and radius of a sphere that bounds the object.
    pub fn bounding_sphere(&self) -> (V3, f64) {
        let centres: Vec<V3> = self.solids.iter().map(|s| s.base + s.axis * (s.height * 0.5)).collect();
        let c = centres.iter().fold(V3::zeros(), |a, b| a + b) / centres.len().max(1) as f64;
        let r = self
            .solids
            .iter()
            .zip(&centres)
            .map(|(s, sc)| (sc - c).norm() + (s.height * 0.5).hypot(s.r_max))
            .fold(0.0, f64::max);
        (c, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cylinder_towards_camera() -> Scene {
        // A disc of radius 100 whose bottom cap faces the camera at z = 500.
        let s = Solid::new(
            Profile::Cylinder { radius: 100.0, height: 5.0 },
            V3::new(0.0, 0.0, 500.0),
            V3::new(0.0, 0.0, 1.0),
            V3::new(1.0, 0.0, 0.0),
        );
        Scene { solids: vec![s] }
    }

    #[test]
    fn rays_hit_a_flat_cap_where_expected() {
        let scene = cylinder_towards_camera();
        let dir = V3::new(0.1, -0.05, 1.0).normalize();
        let hit = scene.cast(&V3::zeros(), &dir, 5000.0).unwrap();
        assert!((hit.point.z - 500.0).abs() < 2e-3, "{:?}", hit.point);
        assert_eq!(hit.part, Part::Bottom);
        assert!((hit.normal - V3::new(0.0, 0.0, -1.0)).norm() < 1e-9);
        assert!(scene.cast(&V3::zeros(), &V3::new(0.5, 0.0, 1.0).normalize(), 5000.0).is_none());
    }

    #[test]
    fn vase_side_hits_lie_on_the_profile_with_outward_normals() {
        let s = Solid::new(
            Profile::Vase,
            V3::new(0.0, 150.0, 800.0),
            V3::new(0.0, -1.0, 0.0),
            V3::new(0.0, 0.0, -1.0),
        );
        let scene = Scene { solids: vec![s] };
        for k in 0..20 {
            let y = -140.0 + k as f64 * 14.0;
            let dir = V3::new(0.0, y, 800.0).normalize();
            let hit = scene.cast(&V3::zeros(), &dir, 5000.0).unwrap();
            let solid = &scene.solids[0];
            let (h, rho, _) = solid.local(&hit.point);
            assert!((rho - solid.radius_at(h)).abs() < 0.01, "h {h} rho {rho}");
            assert!(hit.normal.dot(&dir) < 0.0, "normal faces the camera");
        }
    }
}
