//! Object segmentation from the calibrated stage model: which camera pixels are the painted
//! object, as opposed to the plinth it stands on, the wall behind it or a mount. The automatic
//! proposal removes large planar supports (seeded RANSAC), splits the rest at depth
//! discontinuities, keeps the main component(s) and fills small holes; a conservator's outline
//! (polygons in camera pixels) replaces it where given. Classification, restoration and
//! compensation then leave everything outside the mask alone.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::capture_set::CameraIntrinsics;
use crate::stage_model::StageModel;

/// The mask step's outputs inside its folder.
pub const MASK_FILE: &str = "object_mask.png";
pub const SUMMARY_FILE: &str = "mask.json";

#[derive(Debug, Error)]
pub enum SegmentError {
    #[error("the {width}x{height} camera needs {want} points and normals; got {points} and {normals}")]
    Size { width: u32, height: u32, want: usize, points: usize, normals: usize },
    #[error("the stage model reconstructs no camera pixel: there is nothing to segment")]
    Empty,
    #[error("invalid segmentation parameter: {0}")]
    Param(String),
    #[error("outline polygon {index}: {problem}")]
    Polygon { index: usize, problem: String },
    #[error("the outline has no polygon: draw at least one (three corners or more)")]
    NoPolygon,
    #[error("cannot access {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(
        "{path} is not an outline (expected a JSON list of polygons, each a list of [x, y] \
         camera pixel coordinates): {source}"
    )]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("mask {path}: {source}")]
    Image { path: PathBuf, source: image::ImageError },
    #[error("mask {path} is {got_w}x{got_h}, expected {want_w}x{want_h} (the camera's size)")]
    MaskSize { path: PathBuf, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
}

/// How the proposal decides. Lengths are in sampling steps (the size of one camera pixel on
/// the surface, `z / f`), so the same parameters serve any camera resolution.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentParams {
    /// Seed of RANSAC's sampling (same seed, same mask, whatever the thread count).
    pub seed: u64,
    /// Planes examined at most (removed or kept).
    pub max_planes: usize,
    /// RANSAC hypotheses per plane.
    pub iterations: usize,
    /// A point lies on a plane within this many sampling steps.
    pub plane_tolerance_steps: f64,
    /// ... and with its normal within this angle of the plane's, degrees.
    pub normal_tolerance_deg: f64,
    /// A flat region smaller than this fraction of the reconstructed pixels is never a support.
    pub min_plane_fraction: f64,
    /// A support's narrower in-plane extent is at least this fraction of the rest's largest
    /// extent (a plinth top or a wall is broad; a flattish band of a curved vessel is not).
    pub min_support_extent: f64,
    /// A flat region is the object itself (a panel painting) when everything else beside it
    /// is smaller than this fraction of it.
    pub lone_fraction: f64,
    /// Neighbours further apart than this many sampling steps (divided by the cosine of the
    /// viewing angle, floored at 0.2) lie across a depth discontinuity.
    pub jump_steps: f64,
    /// Components beside the main one are kept when at least this fraction of its size and
    /// not behind it.
    pub secondary_fraction: f64,
    /// Holes (enclosed by the object) up to this fraction of the object are filled.
    pub max_hole_fraction: f64,
    /// Pixels taken off the silhouette (0 = none).
    pub erode: u32,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self {
            seed: 1,
            max_planes: 6,
            iterations: 400,
            plane_tolerance_steps: 1.0,
            normal_tolerance_deg: 10.0,
            min_plane_fraction: 0.03,
            min_support_extent: 0.25,
            lone_fraction: 0.05,
            jump_steps: 4.0,
            secondary_fraction: 0.1,
            max_hole_fraction: 0.02,
            erode: 0,
        }
    }
}

impl SegmentParams {
    pub fn validate(&self) -> Result<(), SegmentError> {
        let frac = |v: f64, what: &str| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(SegmentError::Param(format!("{what} {v} is not a fraction 0..=1")))
            }
        };
        frac(self.min_plane_fraction, "min_plane_fraction")?;
        frac(self.min_support_extent, "min_support_extent")?;
        frac(self.lone_fraction, "lone_fraction")?;
        frac(self.secondary_fraction, "secondary_fraction")?;
        frac(self.max_hole_fraction, "max_hole_fraction")?;
        for (v, what) in [
            (self.plane_tolerance_steps, "plane_tolerance_steps"),
            (self.jump_steps, "jump_steps"),
            (self.normal_tolerance_deg, "normal_tolerance_deg"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SegmentError::Param(format!("{what} {v} must be a number > 0")));
            }
        }
        if self.max_planes > 32 || self.iterations > 100_000 || self.erode > 64 {
            return Err(SegmentError::Param(
                "max_planes <= 32, iterations <= 100000 and erode <= 64 px".into(),
            ));
        }
        Ok(())
    }
}

/// One plane RANSAC found and what was decided about it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlaneSummary {
    /// Unit normal in the camera frame, towards the camera.
    pub normal: [f64; 3],
    /// Distance of the plane from the camera's centre, mm (`normal . x + offset_mm = 0`).
    pub offset_mm: f64,
    /// Reconstructed pixels on the plane (anywhere in the image).
    pub inliers: usize,
    /// Pixels of its largest connected flat region, the part decided on.
    pub region_pixels: usize,
    /// Whether the region was taken off the object as a support.
    pub removed: bool,
    /// Why, in words.
    pub reason: String,
}

/// What the mask step found (`mask.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MaskSummary {
    pub width: u32,
    pub height: u32,
    /// `proposal` (automatic) or `outline` (the conservator's polygons).
    pub source: String,
    pub reconstructed_pixels: usize,
    pub object_pixels: usize,
    pub planes: Vec<PlaneSummary>,
    /// Connected pieces after the supports were removed and split at depth discontinuities.
    pub components: usize,
    /// Sizes of the components kept, largest first.
    pub kept_components: Vec<usize>,
    /// How many components were dropped and their pixels in all.
    pub dropped_components: usize,
    pub dropped_pixels: usize,
    /// Pixels of small enclosed holes made object again.
    pub holes_filled: usize,
    /// Pixels taken off the silhouette by erosion.
    pub eroded_pixels: usize,
    /// Present when an outline replaced the proposal.
    pub outline: Option<OutlineSummary>,
    pub params: SegmentParams,
}

/// What an outline did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OutlineSummary {
    pub polygons: usize,
    /// Pixels inside the polygons.
    pub inside_pixels: usize,
    /// Of those, pixels on supports the proposal removed (the plinth's top inside a loose
    /// outline), taken off the object.
    pub trimmed_pixels: usize,
}

/// A mask and how it was made.
#[derive(Clone, Debug)]
pub struct Segmentation {
    pub width: u32,
    pub height: u32,
    /// Per camera pixel, row-major: object.
    pub mask: Vec<bool>,
    /// Per camera pixel: on a support the proposal removed.
    pub support: Vec<bool>,
    pub summary: MaskSummary,
}

/// The conservator's outline: polygons in camera pixel coordinates (integer values at pixel
/// centres); a pixel whose centre lies inside any polygon (even-odd) is object. On disk a
/// JSON list of polygons, each a list of `[x, y]` (docs/formats.md).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Outline {
    pub polygons: Vec<Vec<[f64; 2]>>,
}

impl Outline {
    pub fn load(path: &Path) -> Result<Self, SegmentError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SegmentError::Io { path: path.into(), source })?;
        serde_json::from_str(&text).map_err(|source| SegmentError::Json { path: path.into(), source })
    }

    pub fn save(&self, path: &Path) -> Result<(), SegmentError> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|source| SegmentError::Json { path: path.into(), source })?;
        std::fs::write(path, text + "\n").map_err(|source| SegmentError::Io { path: path.into(), source })
    }

    /// Pixels inside any polygon, for a `w` x `h` camera.
    pub fn rasterise(&self, w: u32, h: u32) -> Result<Vec<bool>, SegmentError> {
        if self.polygons.is_empty() {
            return Err(SegmentError::NoPolygon);
        }
        let mut inside = vec![false; w as usize * h as usize];
        for (index, poly) in self.polygons.iter().enumerate() {
            let region = crate::restore::Region {
                shape: crate::restore::Shape::Polygon(poly.clone()),
                background: None,
            };
            let m = region.mask(w, h).map_err(|problem| SegmentError::Polygon { index, problem })?;
            inside.iter_mut().zip(m).for_each(|(a, b)| *a |= b);
        }
        Ok(inside)
    }
}

/// Writes a mask as an 8-bit PNG, 255 = object.
pub fn save_mask(path: &Path, w: u32, h: u32, mask: &[bool]) -> Result<(), SegmentError> {
    let bytes: Vec<u8> = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    let img = image::GrayImage::from_raw(w, h, bytes).ok_or_else(|| SegmentError::MaskSize {
        path: path.into(),
        got_w: mask.len() as u32,
        got_h: 1,
        want_w: w,
        want_h: h,
    })?;
    img.save(path).map_err(|source| SegmentError::Image { path: path.into(), source })
}

/// Reads a mask PNG (any bit depth; non-zero in any channel = object) of size `w` x `h`.
pub fn load_mask(path: &Path, w: u32, h: u32) -> Result<Vec<bool>, SegmentError> {
    let img = image::open(path).map_err(|source| SegmentError::Image { path: path.into(), source })?;
    if (img.width(), img.height()) != (w, h) {
        return Err(SegmentError::MaskSize {
            path: path.into(),
            got_w: img.width(),
            got_h: img.height(),
            want_w: w,
            want_h: h,
        });
    }
    Ok(img.to_rgba16().pixels().map(|p| p.0[..3].iter().any(|&c| c != 0)).collect())
}

/// The automatic proposal on a stage model.
pub fn propose(stage: &StageModel, params: &SegmentParams) -> Result<Segmentation, SegmentError> {
    propose_from(&stage.camera, &stage.points, &stage.normals, params)
}

/// The automatic proposal from per-pixel points and normals (camera frame, mm; NaN where
/// nothing was reconstructed; normals may be NaN where unknown).
pub fn propose_from(
    camera: &CameraIntrinsics,
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    params: &SegmentParams,
) -> Result<Segmentation, SegmentError> {
    params.validate()?;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let n = w * h;
    if points.len() != n || normals.len() != n {
        return Err(SegmentError::Size {
            width: camera.width,
            height: camera.height,
            want: n,
            points: points.len(),
            normals: normals.len(),
        });
    }
    let g = Grid::new(camera, points, normals, params.jump_steps);
    let reconstructed = g.valid.iter().filter(|&&v| v).count();
    if reconstructed == 0 {
        return Err(SegmentError::Empty);
    }

    // (a) Planar supports.
    let mut support = vec![false; n];
    let mut tried = vec![false; n];
    let mut planes = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let min_region = ((params.min_plane_fraction * reconstructed as f64).ceil() as usize).max(3);
    for _ in 0..params.max_planes {
        let candidates: Vec<usize> = (0..n).filter(|&i| g.valid[i] && !support[i] && !tried[i]).collect();
        let Some(plane) = ransac(&g, &candidates, params, &mut rng) else { break };
        let on_plane: Vec<bool> =
            (0..n).map(|i| g.valid[i] && !support[i] && !tried[i] && g.fits(i, &plane, params)).collect();
        let inliers = on_plane.iter().filter(|&&b| b).count();
        let (labels, sizes) = components(w, h, &on_plane, &g.joined);
        let Some((best, &region_pixels)) =
            sizes.iter().enumerate().max_by_key(|(k, s)| (**s, usize::MAX - k))
        else {
            break;
        };
        if region_pixels < min_region {
            break;
        }
        let region: Vec<bool> = labels.iter().map(|&l| l == best as u32).collect();
        let rest: Vec<bool> = (0..n).map(|i| g.valid[i] && !support[i] && !region[i]).collect();
        let (removed, reason) = judge(&g, &plane, &region, &rest, &support, params);
        let sink = if removed { &mut support } else { &mut tried };
        sink.iter_mut().zip(&region).for_each(|(s, &r)| *s |= r);
        planes.push(PlaneSummary {
            normal: plane.n,
            offset_mm: plane.d,
            inliers,
            region_pixels,
            removed,
            reason,
        });
        if reason_is_lone(&planes) {
            break;
        }
    }

    // (b) Depth discontinuities split the rest into components.
    let rest: Vec<bool> = (0..n).map(|i| g.valid[i] && !support[i]).collect();
    let (labels, sizes) = components(w, h, &rest, &g.joined);

    // (c) The main component (largest; nearer the centre on ties) and those beside it that
    // are big enough and not behind it.
    let mut mask = vec![false; n];
    let mut kept = Vec::new();
    let (mut dropped, mut dropped_pixels) = (0, 0);
    // Components the picture's border cuts are the surroundings (a wall, a floor) unless
    // nothing else of size is there.
    let mut border = vec![false; sizes.len()];
    for (i, &l) in labels.iter().enumerate() {
        if l != u32::MAX && on_border(i, w, h) {
            border[l as usize] = true;
        }
    }
    let rest_pixels: usize = sizes.iter().sum();
    let inner: Vec<usize> = sizes
        .iter()
        .enumerate()
        .map(|(k, &s)| if border[k] || (s as f64) < 0.02 * rest_pixels as f64 { 0 } else { s })
        .collect();
    let pick = if inner.iter().any(|&s| s > 0) { &inner } else { &sizes };
    if let Some(main) = main_component(&labels, pick, w, h) {
        let zs = depth_range(&g, &labels, main as u32);
        for (k, &size) in sizes.iter().enumerate() {
            let keep = k == main
                || (size as f64 >= params.secondary_fraction * sizes[main] as f64
                    && (!border[k] || border[main])
                    && median_depth(&g, &labels, k as u32) <= zs.1);
            if keep {
                kept.push(size);
                labels.iter().zip(mask.iter_mut()).for_each(|(&l, m)| *m |= l == k as u32);
            } else {
                dropped += 1;
                dropped_pixels += size;
            }
        }
    }
    kept.sort_unstable_by(|a, b| b.cmp(a));
    let object = mask.iter().filter(|&&m| m).count();
    let max_hole = (params.max_hole_fraction * object as f64) as usize;
    let holes_filled = fill_holes(w, h, &mut mask, &g.valid, max_hole);
    let eroded_pixels = erode(w, h, &mut mask, params.erode);
    let object_pixels = mask.iter().filter(|&&m| m).count();
    let summary = MaskSummary {
        width: camera.width,
        height: camera.height,
        source: "proposal".into(),
        reconstructed_pixels: reconstructed,
        object_pixels,
        planes,
        components: sizes.len(),
        kept_components: kept,
        dropped_components: dropped,
        dropped_pixels,
        holes_filled,
        eroded_pixels,
        outline: None,
        params: params.clone(),
    };
    Ok(Segmentation { width: camera.width, height: camera.height, mask, support, summary })
}

const LONE: &str = "the object itself:";

fn reason_is_lone(planes: &[PlaneSummary]) -> bool {
    planes.last().is_some_and(|p| p.reason.starts_with(LONE))
}

/// Replaces the proposal by the outline: inside the polygons is object, except pixels on
/// supports the proposal removed when `trim` (a loose outline around a vase does not take
/// in the plinth's top).
pub fn apply_outline(
    proposal: &Segmentation,
    outline: &Outline,
    trim: bool,
) -> Result<Segmentation, SegmentError> {
    let inside = outline.rasterise(proposal.width, proposal.height)?;
    let inside_pixels = inside.iter().filter(|&&b| b).count();
    let mask: Vec<bool> = inside.iter().zip(&proposal.support).map(|(&i, &s)| i && !(trim && s)).collect();
    let object_pixels = mask.iter().filter(|&&m| m).count();
    let mut summary = proposal.summary.clone();
    summary.source = "outline".into();
    summary.object_pixels = object_pixels;
    summary.outline = Some(OutlineSummary {
        polygons: outline.polygons.len(),
        inside_pixels,
        trimmed_pixels: inside_pixels - object_pixels,
    });
    Ok(Segmentation { mask, summary, ..proposal.clone() })
}

/// The outline alone, for a `w` x `h` camera without a stage model (a photo-only project):
/// no proposal to trim it by.
pub fn outline_only(w: u32, h: u32, outline: &Outline) -> Result<Segmentation, SegmentError> {
    let n = w as usize * h as usize;
    let none = Segmentation {
        width: w,
        height: h,
        mask: vec![false; n],
        support: vec![false; n],
        summary: MaskSummary {
            width: w,
            height: h,
            source: "outline".into(),
            reconstructed_pixels: 0,
            object_pixels: 0,
            planes: Vec::new(),
            components: 0,
            kept_components: Vec::new(),
            dropped_components: 0,
            dropped_pixels: 0,
            holes_filled: 0,
            eroded_pixels: 0,
            outline: None,
            params: SegmentParams::default(),
        },
    };
    apply_outline(&none, outline, false)
}

/// Per pixel: finite point, its sampling step and the cosine of its viewing angle, and which
/// neighbours it joins without a depth discontinuity.
struct Grid<'a> {
    w: usize,
    points: &'a [[f32; 3]],
    normals: &'a [[f32; 3]],
    valid: Vec<bool>,
    /// mm per pixel on the surface, facing the camera.
    step: Vec<f32>,
    /// Bit 0: joined to the right neighbour; bit 1: to the one below.
    joined: Vec<u8>,
    /// `SegmentParams::jump_steps`.
    jump: f32,
}

impl<'a> Grid<'a> {
    fn new(camera: &CameraIntrinsics, points: &'a [[f32; 3]], normals: &'a [[f32; 3]], jump: f64) -> Self {
        let w = camera.width as usize;
        let f = 0.5 * (camera.fx + camera.fy);
        let f = if f.is_finite() && f > 0.0 { f as f32 } else { 1.0 };
        let valid: Vec<bool> = points.iter().map(|p| p.iter().all(|c| c.is_finite()) && p[2] > 0.0).collect();
        let step: Vec<f32> = points.iter().map(|p| p[2].abs() / f).collect();
        let mut g =
            Self { w, points, normals, valid, step, joined: vec![0; points.len()], jump: jump as f32 };
        let n = points.len();
        let mut joined = vec![0u8; n];
        for (i, j) in joined.iter_mut().enumerate() {
            if !g.valid[i] {
                continue;
            }
            if (i + 1) % w != 0 && g.valid[i + 1] && g.continuous(i, i + 1) {
                *j |= 1;
            }
            if i + w < n && g.valid[i + w] && g.continuous(i, i + w) {
                *j |= 2;
            }
        }
        g.joined = joined;
        g
    }

    /// No depth discontinuity between neighbours `i` and `j`: their distance is within
    /// `jump` sampling steps, stretched on surfaces seen at a slant.
    fn continuous(&self, i: usize, j: usize) -> bool {
        let (a, b) = (self.points[i], self.points[j]);
        let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        let cos = self.cos_view(i).min(self.cos_view(j)).max(0.2);
        d <= self.jump * self.step[i].max(self.step[j]) / cos
    }

    fn cos_view(&self, i: usize) -> f32 {
        let (p, n) = (self.points[i], self.normals[i]);
        let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let c = (p[0] * n[0] + p[1] * n[1] + p[2] * n[2]).abs() / len;
        if c.is_finite() { c.min(1.0) } else { 1.0 }
    }

    fn point(&self, i: usize) -> [f64; 3] {
        self.points[i].map(f64::from)
    }

    fn normal(&self, i: usize) -> Option<[f64; 3]> {
        let n = self.normals[i].map(f64::from);
        let len = dot(n, n).sqrt();
        (len.is_finite() && len > 0.0).then(|| n.map(|c| c / len))
    }

    /// On `plane` within tolerance, by distance and (where the normal is known) orientation.
    fn fits(&self, i: usize, plane: &Plane, params: &SegmentParams) -> bool {
        let dist = (dot(plane.n, self.point(i)) + plane.d).abs();
        if dist > params.plane_tolerance_steps * self.step[i] as f64 {
            return false;
        }
        self.normal(i).is_none_or(|n| dot(n, plane.n).abs() >= params.normal_tolerance_deg.to_radians().cos())
    }
}

#[derive(Clone, Copy, Debug)]
struct Plane {
    /// Unit normal towards the camera.
    n: [f64; 3],
    d: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The plane through three points, its normal turned towards the camera (at the origin).
fn plane_through(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Option<Plane> {
    let n = cross(sub(b, a), sub(c, a));
    let len = dot(n, n).sqrt();
    if !(len.is_finite() && len > 1e-9) {
        return None;
    }
    let mut n = n.map(|v| v / len);
    let mut d = -dot(n, a);
    if d < 0.0 {
        // The camera (origin) is on the positive side: n . 0 + d > 0.
        n = n.map(|v| -v);
        d = -d;
    }
    Some(Plane { n, d })
}

/// Least-squares plane through the points (the smallest principal axis of their spread).
fn fit_plane(pts: &[[f64; 3]]) -> Option<Plane> {
    if pts.len() < 3 {
        return None;
    }
    let m = pts.len() as f64;
    let c: [f64; 3] = std::array::from_fn(|k| pts.iter().map(|p| p[k]).sum::<f64>() / m);
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for p in pts {
        let v = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        cov += v * v.transpose();
    }
    let eig = nalgebra::SymmetricEigen::new(cov);
    let k = eig.eigenvalues.imin();
    let v = eig.eigenvectors.column(k);
    let mut n = [v[0], v[1], v[2]];
    let len = dot(n, n).sqrt();
    if !(len.is_finite() && len > 0.0) {
        return None;
    }
    n = n.map(|x| x / len);
    let mut d = -dot(n, c);
    if d < 0.0 {
        n = n.map(|x| -x);
        d = -d;
    }
    Some(Plane { n, d })
}

/// The plane with the most inliers among a seeded sample of the candidates, refined by least
/// squares on them.
fn ransac(g: &Grid, candidates: &[usize], params: &SegmentParams, rng: &mut ChaCha8Rng) -> Option<Plane> {
    const SAMPLE: usize = 4000;
    if candidates.len() < 3 {
        return None;
    }
    let sample: Vec<usize> = if candidates.len() <= SAMPLE {
        candidates.to_vec()
    } else {
        (0..SAMPLE).map(|_| candidates[rng.gen_range(0..candidates.len())]).collect()
    };
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..params.iterations {
        let pick: [usize; 3] = std::array::from_fn(|_| sample[rng.gen_range(0..sample.len())]);
        let Some(plane) = plane_through(g.point(pick[0]), g.point(pick[1]), g.point(pick[2])) else {
            continue;
        };
        let count = sample.iter().filter(|&&i| g.fits(i, &plane, params)).count();
        if best.is_none_or(|(c, _)| count > c) {
            best = Some((count, plane));
        }
    }
    let (_, plane) = best?;
    let inliers: Vec<[f64; 3]> =
        sample.iter().filter(|&&i| g.fits(i, &plane, params)).map(|&i| g.point(i)).collect();
    match fit_plane(&inliers) {
        // Keep the refinement only when it keeps at least as many inliers.
        Some(r) if sample.iter().filter(|&&i| g.fits(i, &r, params)).count() >= inliers.len() => Some(r),
        _ => Some(plane),
    }
}

/// Whether a flat region is a support to remove, and why. The rest (everything still
/// reconstructed besides the region) is split into components; those at least
/// `lone_fraction` of the region are "beside" it. A support is broad, touches the image
/// border or the rest, and has something beside it standing in front of its plane (the object
/// before a wall, on a plinth top or floor) or lies under something beside it in the picture
/// (the front of a plinth under its top and the object).
fn judge(
    g: &Grid,
    plane: &Plane,
    region: &[bool],
    rest: &[bool],
    support: &[bool],
    params: &SegmentParams,
) -> (bool, String) {
    let w = g.w;
    let n = region.len();
    let h = n / w;
    let region_pixels = region.iter().filter(|&&b| b).count();
    let (labels, sizes) = components(w, h, rest, &g.joined);
    let beside: Vec<usize> = (0..sizes.len())
        .filter(|&k| sizes[k] as f64 >= params.lone_fraction * region_pixels as f64 && sizes[k] > 0)
        .collect();
    if beside.is_empty() {
        let biggest = sizes.iter().copied().max().unwrap_or(0);
        return (
            false,
            format!(
                "{LONE} a flat surface with nothing beside it bigger than {biggest} px (a panel painting)"
            ),
        );
    }
    // Breadth: the region's narrower in-plane extent against the rest's largest extent; a
    // region the picture's border cuts (the front of a plinth, a floor) may look narrow.
    let border = (0..n).any(|i| region[i] && on_border(i, w, h));
    let pts: Vec<[f64; 3]> = (0..n).filter(|&i| region[i]).map(|i| g.point(i)).collect();
    let rest_pts: Vec<[f64; 3]> = (0..n).filter(|&i| rest[i]).map(|i| g.point(i)).collect();
    let narrow = extents(&pts)[1];
    let object = extents(&rest_pts)[0];
    if !border && narrow < params.min_support_extent * object {
        return (
            false,
            format!(
                "narrow ({narrow:.0} mm across against {object:.0} mm of the rest): part of a curved surface"
            ),
        );
    }
    // Per component beside it: signed distances to the plane (positive: camera side) and
    // contacts with the region within 3 px above (region under it) or below.
    let tol = 2.0 * params.plane_tolerance_steps * median_step(g, region);
    let mut side: Vec<Vec<f64>> = vec![Vec::new(); sizes.len()];
    for (i, &l) in labels.iter().enumerate() {
        if l != u32::MAX {
            side[l as usize].push(dot(plane.n, g.point(i)) + plane.d);
        }
    }
    let mut under = vec![0usize; sizes.len()];
    let mut over = vec![0usize; sizes.len()];
    let (mut under_support, mut over_any) = (0usize, 0usize);
    let mut adjacent = border;
    for i in (0..n).filter(|&i| region[i]) {
        let (x, y) = (i % w, i / w);
        match (1..=3usize).filter(|&d| y >= d).map(|d| i - d * w).find(|&j| rest[j] || support[j]) {
            Some(j) if rest[j] => under[labels[j] as usize] += 1,
            Some(_) => under_support += 1,
            None => {}
        }
        if let Some(j) = (1..=3usize).filter(|&d| y + d < h).map(|d| i + d * w).find(|&j| rest[j]) {
            over[labels[j] as usize] += 1;
            over_any += 1;
        }
        adjacent |= (x > 0 && rest[i - 1]) || (x + 1 < w && rest[i + 1]);
    }
    adjacent |= under_support > 0 || under.iter().chain(&over).any(|&c| c > 0);
    if !adjacent {
        return (false, "it touches neither the rest nor the picture's border".into());
    }
    for &k in &beside {
        let d = &mut side[k];
        let mid = d.len() / 2;
        let (_, m, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
        if *m > tol {
            return (
                true,
                format!(
                    "{} px stand {:.0} mm in front of it (a wall behind, a plinth top or floor below)",
                    sizes[k], *m
                ),
            );
        }
    }
    for &k in &beside {
        if under[k] > 0 && under[k] >= 3 * over[k] {
            return (
                true,
                format!("it lies under {} px of the rest ({} px of contact above it)", sizes[k], under[k]),
            );
        }
    }
    if under_support > 0 && under_support >= 3 * over_any {
        return (true, format!("it lies under a support already removed ({under_support} px of contact)"));
    }
    (false, "nothing beside it stands in front of it or on it: part of the object".into())
}

fn on_border(i: usize, w: usize, h: usize) -> bool {
    let (x, y) = (i % w, i / w);
    x == 0 || y == 0 || x + 1 == w || y + 1 == h
}

/// Full extents (largest, middle) of a point set's spread, mm (uniform-width estimate).
fn extents(pts: &[[f64; 3]]) -> [f64; 2] {
    if pts.len() < 2 {
        return [0.0; 2];
    }
    let m = pts.len() as f64;
    let c: [f64; 3] = std::array::from_fn(|k| pts.iter().map(|p| p[k]).sum::<f64>() / m);
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for p in pts {
        let v = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        cov += v * v.transpose() / m;
    }
    let mut ev: Vec<f64> = nalgebra::SymmetricEigen::new(cov).eigenvalues.iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    [(12.0 * ev[0].max(0.0)).sqrt(), (12.0 * ev[1].max(0.0)).sqrt()]
}

fn median_step(g: &Grid, region: &[bool]) -> f64 {
    let mut s: Vec<f32> = (0..region.len()).filter(|&i| region[i]).map(|i| g.step[i]).collect();
    if s.is_empty() {
        return 0.0;
    }
    let mid = s.len() / 2;
    let (_, m, _) = s.select_nth_unstable_by(mid, f32::total_cmp);
    *m as f64
}

/// Connected components (4-neighbours) of `member` pixels that `joined` links (bit 0 right,
/// bit 1 down). Labels `u32::MAX` outside; sizes per label.
fn components(w: usize, h: usize, member: &[bool], joined: &[u8]) -> (Vec<u32>, Vec<usize>) {
    let n = w * h;
    let mut labels = vec![u32::MAX; n];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..n {
        if !member[start] || labels[start] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        labels[start] = id;
        stack.push(start);
        let mut size = 0;
        while let Some(i) = stack.pop() {
            size += 1;
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize, link: bool| {
                if link && member[j] && labels[j] == u32::MAX {
                    labels[j] = id;
                    stack.push(j);
                }
            };
            if x + 1 < w {
                visit(i + 1, joined[i] & 1 != 0);
            }
            if x > 0 {
                visit(i - 1, joined[i - 1] & 1 != 0);
            }
            if y + 1 < h {
                visit(i + w, joined[i] & 2 != 0);
            }
            if y > 0 {
                visit(i - w, joined[i - w] & 2 != 0);
            }
        }
        sizes.push(size);
    }
    (labels, sizes)
}

/// The largest component; between equals, the one whose centroid is nearer the image centre.
fn main_component(labels: &[u32], sizes: &[usize], w: usize, h: usize) -> Option<usize> {
    let mut sum = vec![[0.0f64; 2]; sizes.len()];
    for (i, &l) in labels.iter().enumerate() {
        if l != u32::MAX {
            sum[l as usize][0] += (i % w) as f64;
            sum[l as usize][1] += (i / w) as f64;
        }
    }
    let centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
    let off = |k: usize| {
        let m = sizes[k] as f64;
        (sum[k][0] / m - centre[0]).hypot(sum[k][1] / m - centre[1])
    };
    (0..sizes.len()).max_by(|&a, &b| sizes[a].cmp(&sizes[b]).then(off(b).total_cmp(&off(a))))
}

fn depth_range(g: &Grid, labels: &[u32], k: u32) -> (f32, f32) {
    labels
        .iter()
        .enumerate()
        .filter(|(_, l)| **l == k)
        .fold((f32::INFINITY, f32::NEG_INFINITY), |r, (i, _)| {
            (r.0.min(g.points[i][2]), r.1.max(g.points[i][2]))
        })
}

fn median_depth(g: &Grid, labels: &[u32], k: u32) -> f32 {
    let mut z: Vec<f32> =
        labels.iter().enumerate().filter(|(_, l)| **l == k).map(|(i, _)| g.points[i][2]).collect();
    let mid = z.len() / 2;
    let (_, m, _) = z.select_nth_unstable_by(mid, f32::total_cmp);
    *m
}

/// Fills the reconstructed pixels of holes (background not reaching the image border) of at
/// most `max_hole` pixels. Returns how many pixels became object.
fn fill_holes(w: usize, h: usize, mask: &mut [bool], valid: &[bool], max_hole: usize) -> usize {
    let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
    let all = vec![3u8; mask.len()];
    let (labels, sizes) = components(w, h, &outside, &all);
    let mut touches = vec![false; sizes.len()];
    for (i, &l) in labels.iter().enumerate() {
        let (x, y) = (i % w, i / w);
        if l != u32::MAX && (x == 0 || y == 0 || x + 1 == w || y + 1 == h) {
            touches[l as usize] = true;
        }
    }
    let mut filled = 0;
    for (i, &l) in labels.iter().enumerate() {
        if l != u32::MAX && !touches[l as usize] && sizes[l as usize] <= max_hole && valid[i] {
            mask[i] = true;
            filled += 1;
        }
    }
    filled
}

/// Takes `px` pixels off the silhouette (4-neighbour erosion, the image border counting as
/// outside). Returns how many pixels it took.
fn erode(w: usize, h: usize, mask: &mut [bool], px: u32) -> usize {
    let mut taken = 0;
    for _ in 0..px {
        let before = mask.to_vec();
        for (i, m) in mask.iter_mut().enumerate() {
            let (x, y) = (i % w, i / w);
            if *m
                && (x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || !before[i - 1]
                    || !before[i + 1]
                    || !before[i - w]
                    || !before[i + w])
            {
                *m = false;
                taken += 1;
            }
        }
    }
    taken
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    // Named, so rand's traits win over the preludes' globs.
    use rand::{Rng, SeedableRng};

    /// A surface of a synthetic scene, in the camera frame (mm).
    enum Surf {
        /// An upright cylinder from `base` along unit `axis`, with a top cap.
        Cylinder { base: [f64; 3], axis: [f64; 3], r: f64, h: f64 },
        /// A rectangle: centre, unit in-plane axes and half sizes.
        Rect { c: [f64; 3], u: [f64; 3], v: [f64; 3], hu: f64, hv: f64 },
    }

    struct Scene {
        cam: CameraIntrinsics,
        points: Vec<[f32; 3]>,
        normals: Vec<[f32; 3]>,
        /// Per pixel: sees the surface marked as the object.
        object: Vec<bool>,
    }

    fn add(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
        [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]]
    }

    /// Nearest hit along ray `d` from the origin: (t, normal).
    fn hit(s: &Surf, d: [f64; 3]) -> Option<(f64, [f64; 3])> {
        match *s {
            Surf::Cylinder { base, axis, r, h } => {
                let mut best: Option<(f64, [f64; 3])> = None;
                let o = base.map(|c| -c);
                let dp = add(d, axis, -dot(d, axis));
                let op = add(o, axis, -dot(o, axis));
                let (a, b, c) = (dot(dp, dp), 2.0 * dot(dp, op), dot(op, op) - r * r);
                let disc = b * b - 4.0 * a * c;
                if disc >= 0.0 {
                    let t = (-b - disc.sqrt()) / (2.0 * a);
                    let q = sub(d.map(|v| v * t), base);
                    let along = dot(q, axis);
                    if t > 0.0 && (0.0..=h).contains(&along) {
                        let radial = add(q, axis, -along).map(|v| v / r);
                        best = Some((t, radial));
                    }
                }
                let top = add(base, axis, h);
                let dn = dot(d, axis);
                if dn.abs() > 1e-12 {
                    let t = dot(top, axis) / dn;
                    let q = sub(d.map(|v| v * t), top);
                    if t > 0.0 && dot(q, q) <= r * r && best.is_none_or(|(bt, _)| t < bt) {
                        best = Some((t, axis));
                    }
                }
                best
            }
            Surf::Rect { c, u, v, hu, hv } => {
                let n = cross(u, v);
                let dn = dot(d, n);
                if dn.abs() < 1e-12 {
                    return None;
                }
                let t = dot(c, n) / dn;
                let q = sub(d.map(|x| x * t), c);
                (t > 0.0 && dot(q, u).abs() <= hu && dot(q, v).abs() <= hv).then_some((t, n))
            }
        }
    }

    /// Ray-casts the surfaces (the first `objects` of them are the object) for a camera
    /// `w` x `h` with focal length `f`.
    fn render(w: u32, h: u32, f: f64, surfs: &[Surf], objects: usize) -> Scene {
        let cam = CameraIntrinsics {
            width: w,
            height: h,
            fx: f,
            fy: f,
            cx: (w as f64 - 1.0) / 2.0,
            cy: (h as f64 - 1.0) / 2.0,
            distortion: [0.0; 5],
        };
        let n = (w * h) as usize;
        let (mut points, mut normals, mut object) =
            (vec![[f32::NAN; 3]; n], vec![[f32::NAN; 3]; n], vec![false; n]);
        for i in 0..n {
            let d = [((i % w as usize) as f64 - cam.cx) / f, ((i / w as usize) as f64 - cam.cy) / f, 1.0];
            let mut best: Option<(f64, [f64; 3], usize)> = None;
            for (k, s) in surfs.iter().enumerate() {
                if let Some((t, nn)) = hit(s, d)
                    && best.is_none_or(|(bt, _, _)| t < bt)
                {
                    best = Some((t, nn, k));
                }
            }
            if let Some((t, nn, k)) = best {
                let p = d.map(|v| v * t);
                let nn = if dot(nn, p) > 0.0 { nn.map(|v| -v) } else { nn };
                points[i] = p.map(|v| v as f32);
                normals[i] = nn.map(|v| v as f32);
                object[i] = k < objects;
            }
        }
        Scene { cam, points, normals, object }
    }

    /// The camera looks down by `deg`: the world's up and horizontal away-from-camera axes.
    fn frame(deg: f64) -> ([f64; 3], [f64; 3]) {
        let a = deg.to_radians();
        ([0.0, -a.cos(), -a.sin()], [0.0, -a.sin(), a.cos()])
    }

    fn accuracy(seg: &Segmentation, truth: &[bool]) -> f64 {
        seg.mask.iter().zip(truth).filter(|(a, b)| a == b).count() as f64 / truth.len() as f64
    }

    /// The virtual stage's vase on its grey plinth (area-integrated pixels, the plinth's top
    /// and front seen), with the stage's own points and normals: the proposal keeps the vase
    /// and drops the plinth. Counted over the pixels that see either. (The stage's seed varies
    /// paint and wear, not geometry: one seed is the whole test. 37 of 15,877 vase pixels
    /// dropped, none of 15,429 plinth pixels kept.)
    #[test]
    fn the_virtual_vase_on_its_plinth_is_segmented() {
        use crate::stage_sim::{SceneConfig, SceneName, Seen, VirtualStage};
        let seed = 1;
        let cfg = SceneConfig {
            plinth: true,
            camera: [320, 240],
            projector: [256, 192],
            ..SceneConfig::tiny(SceneName::Vase, seed)
        };
        let stage = VirtualStage::new(&cfg).unwrap();
        let seg = propose(&stage.truth(), &SegmentParams::default()).unwrap();
        let (mut object, mut dropped, mut plinth, mut kept) = (0, 0, 0, 0);
        for (p, &m) in stage.pixels().iter().zip(&seg.mask) {
            if p.is_object() {
                object += 1;
                dropped += usize::from(!m);
            } else if p.seen == Seen::Plinth {
                plinth += 1;
                kept += usize::from(m);
            }
        }
        eprintln!(
            "FIGURES seed {seed}: vase pixels {object}, dropped {dropped}; plinth pixels {plinth}, kept {kept}"
        );
        assert!(plinth > object / 4, "the plinth is in view: {plinth} of {object}");
        assert!(
            dropped as f64 <= 0.01 * object as f64,
            "seed {seed}: {dropped} of {object} vase pixels dropped"
        );
        assert!(kept as f64 <= 0.01 * plinth as f64, "seed {seed}: {kept} of {plinth} plinth pixels kept");
    }

    fn propose_scene(s: &Scene) -> Segmentation {
        propose_from(&s.cam, &s.points, &s.normals, &SegmentParams::default()).unwrap()
    }

    /// A vase-like cylinder standing on a plinth (top and front face), seen from 10 degrees
    /// above.
    fn cylinder_on_plinth() -> Scene {
        let (up, fwd) = frame(10.0);
        let x = [1.0, 0.0, 0.0];
        let base = add([0.0, 0.0, 900.0], up, -125.0);
        let front_edge = add(base, fwd, -250.0);
        render(
            240,
            180,
            300.0,
            &[
                Surf::Cylinder { base, axis: up, r: 70.0, h: 250.0 },
                Surf::Rect { c: base, u: x, v: fwd, hu: 250.0, hv: 250.0 },
                Surf::Rect { c: add(front_edge, up, -150.0), u: x, v: up, hu: 250.0, hv: 150.0 },
            ],
            1,
        )
    }

    #[test]
    fn a_cylinder_on_a_plinth_keeps_the_cylinder_and_drops_the_plinth() {
        let s = cylinder_on_plinth();
        let seg = propose_scene(&s);
        let acc = accuracy(&seg, &s.object);
        let sum = &seg.summary;
        assert!(acc >= 0.99, "accuracy {acc}: {sum:#?}");
        assert!(sum.planes.iter().filter(|p| p.removed).count() >= 1, "{sum:#?}");
        let object = s.object.iter().filter(|&&o| o).count();
        let kept = seg.mask.iter().zip(&s.object).filter(|(m, o)| **m && **o).count();
        assert!(kept as f64 >= 0.98 * object as f64, "kept {kept} of {object} cylinder pixels");
        // The plinth's pixels are not the object.
        let plinth = seg.mask.iter().zip(&s.object).filter(|(m, o)| **m && !**o).count();
        assert!(plinth as f64 <= 0.02 * object as f64, "{plinth} plinth pixels in the mask");
    }

    #[test]
    fn a_lone_flat_panel_is_kept_whole() {
        let (up, _) = frame(5.0);
        // Turned a little about the vertical, nearly filling the picture, and filling it.
        let a = 0.2f64;
        let u = [a.cos(), 0.0, a.sin()];
        for (hu, hv) in [(300.0, 200.0), (900.0, 700.0)] {
            let s = render(200, 150, 250.0, &[Surf::Rect { c: [0.0, 0.0, 1000.0], u, v: up, hu, hv }], 1);
            let seg = propose_scene(&s);
            assert_eq!(seg.mask, s.object, "panel {hu}x{hv}: {:#?}", seg.summary);
            assert!(seg.summary.planes.iter().all(|p| !p.removed));
        }
    }

    #[test]
    fn a_wall_behind_a_cylinder_is_dropped() {
        let (up, _) = frame(3.0);
        let s = render(
            200,
            150,
            250.0,
            &[
                Surf::Cylinder { base: add([0.0, 0.0, 900.0], up, -150.0), axis: up, r: 90.0, h: 300.0 },
                Surf::Rect {
                    c: [0.0, 0.0, 1400.0],
                    u: [1.0, 0.0, 0.0],
                    v: [0.0, 1.0, 0.0],
                    hu: 3000.0,
                    hv: 3000.0,
                },
            ],
            1,
        );
        let seg = propose_scene(&s);
        let acc = accuracy(&seg, &s.object);
        assert!(acc >= 0.99, "accuracy {acc}: {:#?}", seg.summary);
        // Split at the depth jump alone (no plane removal), the wall is dropped too.
        let no_planes = SegmentParams { max_planes: 0, ..SegmentParams::default() };
        let seg = propose_from(&s.cam, &s.points, &s.normals, &no_planes).unwrap();
        let acc = accuracy(&seg, &s.object);
        assert!(acc >= 0.99, "accuracy without planes {acc}: {:#?}", seg.summary);
        assert!(seg.summary.dropped_pixels > 0);
    }

    #[test]
    fn an_outline_replaces_the_proposal_and_is_trimmed_at_the_plinth() {
        let s = cylinder_on_plinth();
        let seg = propose_scene(&s);
        // A loose box around the cylinder reaching down onto the plinth top.
        let outline =
            Outline { polygons: vec![vec![[80.0, 20.0], [160.0, 20.0], [160.0, 150.0], [80.0, 150.0]]] };
        let out = apply_outline(&seg, &outline, true).unwrap();
        let o = out.summary.outline.as_ref().unwrap();
        // Columns 80..=160, rows 20..150 (a centre on the lower edge is outside).
        assert_eq!(o.inside_pixels, 81 * 130);
        assert!(o.trimmed_pixels > 0);
        assert!(out.mask.iter().zip(&seg.support).all(|(m, s)| !(*m && *s)));
        let untrimmed = apply_outline(&seg, &outline, false).unwrap();
        assert_eq!(untrimmed.summary.object_pixels, 81 * 130);
        assert!(matches!(apply_outline(&seg, &Outline::default(), true), Err(SegmentError::NoPolygon)));
        let bad = Outline { polygons: vec![vec![[0.0, 0.0], [1.0, 1.0]]] };
        assert!(matches!(apply_outline(&seg, &bad, true), Err(SegmentError::Polygon { index: 0, .. })));
    }

    #[test]
    fn outlines_and_masks_round_trip_and_bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("outline.json");
        let o = Outline { polygons: vec![vec![[1.0, 2.0], [5.0, 2.0], [3.0, 6.5]]] };
        o.save(&path).unwrap();
        assert_eq!(Outline::load(&path).unwrap(), o);
        std::fs::write(&path, "{\"polygons\": 3}").unwrap();
        let e = Outline::load(&path).unwrap_err().to_string();
        assert!(e.contains("outline.json") && e.contains("JSON list of polygons"), "{e}");
        let m = dir.path().join("m.png");
        let mask = vec![true, false, false, true, true, false];
        save_mask(&m, 3, 2, &mask).unwrap();
        assert_eq!(load_mask(&m, 3, 2).unwrap(), mask);
        assert!(matches!(load_mask(&m, 2, 3), Err(SegmentError::MaskSize { .. })));
    }

    #[test]
    fn bad_inputs_are_refused() {
        let cam = CameraIntrinsics {
            width: 2,
            height: 2,
            fx: 1.0,
            fy: 1.0,
            cx: 0.5,
            cy: 0.5,
            distortion: [0.0; 5],
        };
        let p = SegmentParams::default();
        assert!(matches!(
            propose_from(&cam, &[[0.0; 3]; 3], &[[0.0; 3]; 4], &p),
            Err(SegmentError::Size { .. })
        ));
        assert!(matches!(
            propose_from(&cam, &[[f32::NAN; 3]; 4], &[[0.0; 3]; 4], &p),
            Err(SegmentError::Empty)
        ));
        let bad = SegmentParams { jump_steps: -1.0, ..p };
        assert!(matches!(
            propose_from(&cam, &[[0.0, 0.0, 1.0]; 4], &[[0.0; 3]; 4], &bad),
            Err(SegmentError::Param(_))
        ));
    }

    /// The proposal on a built-in scene's TRUE stage model against its ground-truth object
    /// mask: (pixel accuracy, object pixels kept, mask pixels that are not object).
    pub(crate) fn scene_figures(scene: crate::stage_sim::SceneName, camera: [u32; 2]) -> (f64, f64, usize) {
        let cfg = crate::stage_sim::SceneConfig {
            camera,
            projector: [128, 96],
            ..crate::stage_sim::SceneConfig::tiny(scene, 1)
        };
        let stage = crate::stage_sim::VirtualStage::new(&cfg).unwrap();
        let truth: Vec<bool> = stage.pixels().iter().map(|p| p.is_object()).collect();
        let seg = propose(&stage.truth(), &SegmentParams::default()).unwrap();
        let acc = seg.mask.iter().zip(&truth).filter(|(a, b)| a == b).count() as f64 / truth.len() as f64;
        let object = truth.iter().filter(|&&t| t).count();
        let kept = seg.mask.iter().zip(&truth).filter(|(m, t)| **m && **t).count();
        let extra = seg.mask.iter().zip(&truth).filter(|(m, t)| **m && !**t).count();
        (acc, kept as f64 / object as f64, extra)
    }

    /// The built-in scenes (an object alone on the virtual stage) keep their whole object.
    #[test]
    fn the_built_in_scenes_are_found_on_their_true_models() {
        for scene in crate::stage_sim::SceneName::ALL {
            let (acc, kept, extra) = scene_figures(scene, [160, 120]);
            assert!(acc >= 0.99, "{}: accuracy {acc}, kept {kept}, {extra} px extra", scene.name());
        }
    }

    /// The figures at 320x240 (`cargo test -p restage-authoring --lib segment -- --ignored
    /// --nocapture`).
    #[test]
    #[ignore]
    fn figures_on_the_built_in_scenes() {
        for camera in [[160, 120], [320, 240]] {
            for scene in crate::stage_sim::SceneName::ALL {
                let (acc, kept, extra) = scene_figures(scene, camera);
                println!(
                    "{} {}x{}: accuracy {:.4} %, object kept {:.4} %, {extra} px not object",
                    scene.name(),
                    camera[0],
                    camera[1],
                    100.0 * acc,
                    100.0 * kept
                );
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
        /// Whatever the depth map (holes, jumps, planes, noise), the proposal only marks
        /// reconstructed pixels, and the same seed gives the same mask.
        #[test]
        fn the_mask_is_a_subset_of_the_reconstructed_pixels(
            w in 4u32..40,
            h in 4u32..30,
            seed in any::<u64>(),
            holes in 0.0f64..0.6,
            erode in 0u32..2,
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let n = (w * h) as usize;
            let f = 50.0;
            let cam = CameraIntrinsics { width: w, height: h, fx: f, fy: f, cx: w as f64 / 2.0, cy: h as f64 / 2.0, distortion: [0.0; 5] };
            // A few depth layers, some tilted, some noisy.
            let layers: Vec<(f64, f64, f64)> = (0..3)
                .map(|_| (rng.gen_range(300.0..1500.0), rng.gen_range(-2.0..2.0), rng.gen_range(-2.0..2.0)))
                .collect();
            let mut points = vec![[f32::NAN; 3]; n];
            let mut normals = vec![[f32::NAN; 3]; n];
            for i in 0..n {
                if rng.gen_bool(holes) {
                    continue;
                }
                let (x, y) = ((i as u32 % w) as f64, (i as u32 / w) as f64);
                let (z0, gx, gy) = layers[((x as usize / 7) + (y as usize / 5)) % 3];
                let z = z0 + gx * x + gy * y + rng.gen_range(-1.0..1.0);
                points[i] = [((x - cam.cx) / f * z) as f32, ((y - cam.cy) / f * z) as f32, z as f32];
                if rng.gen_bool(0.7) {
                    normals[i] = [0.0, 0.0, -1.0];
                }
            }
            let params = SegmentParams { seed, erode, ..SegmentParams::default() };
            match propose_from(&cam, &points, &normals, &params) {
                Ok(seg) => {
                    for (i, (m, p)) in seg.mask.iter().zip(&points).enumerate() {
                        prop_assert!(!m || p[2].is_finite(), "pixel {} not reconstructed", i);
                    }
                    prop_assert_eq!(seg.summary.object_pixels, seg.mask.iter().filter(|&&m| m).count());
                    let again = propose_from(&cam, &points, &normals, &params).unwrap();
                    prop_assert_eq!(again.mask, seg.mask);
                }
                Err(SegmentError::Empty) => prop_assert!(points.iter().all(|p| p[2].is_nan())),
                Err(e) => prop_assert!(false, "{}", e),
            }
        }
    }
}
