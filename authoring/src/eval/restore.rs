//! Evaluation of restoration against the virtual stage's pristine labels: pixel error of the
//! label map before and after, and distances from restored contours to pristine contours,
//! for ours and for baselines (a mode filter of the same footprint; OpenCV Telea inpainting
//! given the true deterioration mask, run by `bench/peers/restore_peers.py`).

use std::path::Path;

use anyhow::{Context, Result};

use super::Metric;
use crate::classify::{self, ClassifyOptions, LabelMap, MASKED, picks_from_labels};
use crate::restore::{self, Region, RestoreParams, Shape, io::class_info};
use crate::stage_sim::{RigVariation, SceneConfig, SceneName, VirtualStage};

const STEP: &str = "restore";

/// What [`class_map`] gives a class that the stage's palette does not have.
pub const NO_STAGE_CLASS: u8 = 254;

/// Maps each classified class to the stage class of the same name (the picks are named after
/// the stage's palette); a class with no namesake maps to [`NO_STAGE_CLASS`], which no
/// pristine pixel has, so it always counts as wrong. Matching by name rather than by overlap with the
/// pristine labels keeps the answer out of the mapping: an overlap map would call the clay
/// class (exposed by chips) "slip" or "paint" wherever that flatters the classification,
/// and score a restoration that removes clay as breaking what the classification got right.
pub fn class_map(palette: &classify::Palette, stage_names: &[String]) -> Vec<u8> {
    let mut map = vec![NO_STAGE_CLASS; 256];
    for (k, c) in palette.classes.iter().enumerate() {
        if let Some(s) = stage_names.iter().position(|n| *n == c.name) {
            map[k] = s as u8;
        }
    }
    map
}

/// Pixels (object only) whose mapped class differs from the pristine one, and the count.
pub fn label_error(labels: &LabelMap, pristine: &LabelMap, map: &[u8]) -> (usize, usize) {
    let mut wrong = 0;
    let mut total = 0;
    for (&a, &p) in labels.data.iter().zip(&pristine.data) {
        if p == MASKED || a == MASKED {
            continue;
        }
        total += 1;
        wrong += usize::from(map[a as usize] != p);
    }
    (wrong, total)
}

/// Chip pixels (the worn labels show a loss class where the pristine paint was not loss) that
/// `labels` gives their pristine class, in per cent, and how many there are: whether chips are
/// filled with the colour that surrounds them rather than that of a misread rim.
pub fn chips_restored(labels: &LabelMap, scene: &Scene) -> (f64, usize) {
    let loss: Vec<u8> = scene.loss_classes.iter().map(|&k| scene.map[k as usize]).collect();
    let (mut right, mut chips) = (0usize, 0usize);
    for ((&a, &p), &d) in labels.data.iter().zip(&scene.pristine.data).zip(&scene.deteriorated.data) {
        if a == MASKED || p == MASKED || !loss.contains(&d) || loss.contains(&p) {
            continue;
        }
        chips += 1;
        right += usize::from(scene.map[a as usize] == p);
    }
    (if chips == 0 { 100.0 } else { 100.0 * right as f64 / chips as f64 }, chips)
}

/// Contour pixels: object pixels with a 4-neighbour (on the object) of another class.
fn contour_pixels(data: &[u8], w: usize, h: usize) -> Vec<bool> {
    let mut c = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if data[i] == MASKED {
                continue;
            }
            let differs = |j: usize| data[j] != MASKED && data[j] != data[i];
            c[i] = (x + 1 < w && differs(i + 1))
                || (x > 0 && differs(i - 1))
                || (y + 1 < h && differs(i + w))
                || (y > 0 && differs(i - w));
        }
    }
    c
}

/// Exact Euclidean distance transform (Felzenszwalb-Huttenlocher) to the `true` pixels.
fn distance_to(feature: &[bool], w: usize, h: usize) -> Vec<f64> {
    const INF: f64 = 1e20;
    let mut f: Vec<f64> = feature.iter().map(|&b| if b { 0.0 } else { INF }).collect();
    let edt_1d = |line: &mut [f64]| {
        let n = line.len();
        let (mut v, mut z, mut d) = (vec![0usize; n], vec![0f64; n + 1], vec![0f64; n]);
        let mut k = 0;
        z[0] = -INF;
        z[1] = INF;
        for q in 1..n {
            loop {
                let p = v[k];
                let s =
                    ((line[q] + (q * q) as f64) - (line[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
                if s <= z[k] && k > 0 {
                    k -= 1;
                } else {
                    k += 1;
                    v[k] = q;
                    z[k] = s;
                    z[k + 1] = INF;
                    break;
                }
            }
        }
        k = 0;
        for (q, dq) in d.iter_mut().enumerate() {
            while z[k + 1] < q as f64 {
                k += 1;
            }
            let p = v[k];
            *dq = (q as f64 - p as f64).powi(2) + line[p];
        }
        line.copy_from_slice(&d);
    };
    let mut col = vec![0.0; h];
    for x in 0..w {
        for y in 0..h {
            col[y] = f[y * w + x];
        }
        edt_1d(&mut col);
        for y in 0..h {
            f[y * w + x] = col[y];
        }
    }
    for row in f.chunks_mut(w) {
        edt_1d(row);
    }
    f.iter().map(|d| d.sqrt()).collect()
}

/// Mean and 95th percentile of the distance (px) from `labels`' contour pixels to the
/// nearest pristine contour pixel (classes mapped by `map`).
pub fn contour_distance(labels: &LabelMap, pristine: &LabelMap, map: &[u8]) -> (f64, f64) {
    let (w, h) = (labels.width as usize, labels.height as usize);
    let mapped = mapped(labels, map);
    directed_distance(&contour_pixels(&mapped, w, h), &contour_pixels(&pristine.data, w, h), pristine, w, h)
}

/// The other way round: from each pristine contour pixel to the nearest contour pixel of
/// `labels` — large where a contour is missing (a lost dot), which the forward distance
/// cannot see.
pub fn contour_distance_back(labels: &LabelMap, pristine: &LabelMap, map: &[u8]) -> (f64, f64) {
    let (w, h) = (labels.width as usize, labels.height as usize);
    let mapped = mapped(labels, map);
    directed_distance(&contour_pixels(&pristine.data, w, h), &contour_pixels(&mapped, w, h), pristine, w, h)
}

fn mapped(labels: &LabelMap, map: &[u8]) -> Vec<u8> {
    labels.data.iter().map(|&a| if a == MASKED { MASKED } else { map[a as usize] }).collect()
}

fn directed_distance(from: &[bool], to: &[bool], pristine: &LabelMap, w: usize, h: usize) -> (f64, f64) {
    let dist = distance_to(to, w, h);
    let mut d: Vec<f64> =
        (0..w * h).filter(|&i| from[i] && pristine.data[i] != MASKED).map(|i| dist[i]).collect();
    if d.is_empty() {
        return (0.0, 0.0);
    }
    d.sort_by(f64::total_cmp);
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    (mean, d[((d.len() - 1) as f64 * 0.95).round() as usize])
}

/// Majority (mode) filter over a `(2r+1)^2` window, masked pixels ignored and kept; ties keep
/// the pixel's class, else the smallest index.
pub fn mode_filter(labels: &LabelMap, r: usize, classes: usize) -> LabelMap {
    let (w, h) = (labels.width as usize, labels.height as usize);
    let mut out = labels.clone();
    // Per-class summed-area tables.
    let sat: Vec<Vec<u32>> = (0..classes)
        .map(|k| {
            let mut s = vec![0u32; (w + 1) * (h + 1)];
            for y in 0..h {
                let mut row = 0;
                for x in 0..w {
                    row += u32::from(labels.data[y * w + x] as usize == k);
                    s[(y + 1) * (w + 1) + x + 1] = s[y * (w + 1) + x + 1] + row;
                }
            }
            s
        })
        .collect();
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let i = y * w + x;
            if labels.data[i] == MASKED {
                continue;
            }
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let n = |k: usize| {
                let s = &sat[k];
                s[y1 * (w + 1) + x1] + s[y0 * (w + 1) + x0] - s[y0 * (w + 1) + x1] - s[y1 * (w + 1) + x0]
            };
            let own = labels.data[i] as usize;
            let mut best = own;
            for k in 0..classes {
                if n(k) > n(best) {
                    best = k;
                }
            }
            out.data[i] = best as u8;
        }
    }
    out
}

/// One scene prepared for evaluation: the classification a conservator would get, the truth.
#[derive(Debug)]
pub struct Scene {
    pub name: String,
    pub classified: LabelMap,
    pub palette: classify::Palette,
    pub pristine: LabelMap,
    pub deteriorated: LabelMap,
    /// Stage classes standing for loss (bare clay), as classified class indices.
    pub loss_classes: Vec<u8>,
    /// The stage's background (slip) as a classified class index.
    pub background: u8,
    /// Classified class index -> stage class index ([`class_map`]).
    pub map: Vec<u8>,
}

/// Simulates a built-in scene's diffuse photo and classifies it with picks drawn from the
/// (deteriorated) labels, as a conservator would click them.
pub fn prepare_scene(scene: SceneName, camera: [u32; 2], seed: u64, rig: RigVariation) -> Result<Scene> {
    let cfg = SceneConfig { scene, seed, camera, rig, ..SceneConfig::default() };
    let stage = VirtualStage::new(&cfg).with_context(|| format!("building scene {}", scene.name()))?;
    let photo = stage.capture(&stage.black_frames(), true, 0)?;
    let (w, h) = (camera[0], camera[1]);
    let px = stage.pixels();
    let pristine = LabelMap::from_vec(w, h, px.iter().map(|p| p.label_pristine).collect())?;
    let deteriorated = LabelMap::from_vec(w, h, px.iter().map(|p| p.label).collect())?;
    let pal = stage.palette();
    let names: Vec<String> = pal.classes.iter().map(|c| c.name.clone()).collect();
    let display: Vec<Option<[u8; 3]>> = pal.classes.iter().map(|c| Some(c.srgb)).collect();
    let picks = picks_from_labels(&deteriorated, &names, &display, 40, seed)?;
    let mask: Vec<bool> = px.iter().map(|p| p.is_object()).collect();
    // The picks are in the stage's class order: the bare clay is loss, as a conservator says.
    let opts = ClassifyOptions { loss: vec![pal.clay], ..Default::default() };
    let c = classify::classify(&photo, &picks, Some(&mask), &opts)?;
    let map = class_map(&c.palette, &names);
    let classified_index = |stage_class: u8| {
        map.iter().position(|&m| m == stage_class).map(|k| k as u8).with_context(|| {
            format!("scene {}: no classified class for stage class {stage_class}", scene.name())
        })
    };
    let (clay, background) = (classified_index(pal.clay)?, classified_index(pal.background)?);
    Ok(Scene {
        name: scene.name().to_string(),
        classified: c.labels,
        palette: c.palette,
        pristine,
        deteriorated,
        map,
        loss_classes: vec![clay],
        background,
    })
}

/// Scores one candidate label map of a scene as `method`.
pub fn score(scene: &Scene, method: &str, labels: &LabelMap) -> Vec<Metric> {
    let map = &scene.map;
    let (before, total) = label_error(&scene.classified, &scene.pristine, map);
    let (after, _) = label_error(labels, &scene.pristine, map);
    let fixed = if before == 0 { 1.0 } else { (before as f64 - after as f64) / before as f64 };
    let (mean, p95) = contour_distance(labels, &scene.pristine, map);
    let (back_mean, back_p95) = contour_distance_back(labels, &scene.pristine, map);
    let (chips, _) = chips_restored(labels, scene);
    let n = |what: &str| format!("{} {method}: {what}", scene.name);
    let is_ours = method == "ours";
    vec![
        Metric::info(STEP, &n("wrong pixels"), 100.0 * after as f64 / total.max(1) as f64, "%"),
        if is_ours {
            Metric::at_least(STEP, &n("classification errors fixed"), fixed, "", 0.5)
        } else {
            Metric::info(STEP, &n("classification errors fixed"), fixed, "")
        },
        if is_ours {
            Metric::below(STEP, &n("contour distance mean"), mean, "px", 1.0)
        } else {
            Metric::info(STEP, &n("contour distance mean"), mean, "px")
        },
        Metric::info(STEP, &n("contour distance p95"), p95, "px"),
        Metric::info(STEP, &n("pristine contour distance mean"), back_mean, "px"),
        Metric::info(STEP, &n("pristine contour distance p95"), back_p95, "px"),
        Metric::info(STEP, &n("chip pixels in their pristine colour"), chips, "%"),
    ]
}

/// Restores a prepared scene with `params` (the stage's slip as background, clay as loss).
pub fn restore_scene(scene: &Scene, params: &RestoreParams) -> Result<restore::Restored> {
    let params = RestoreParams { loss_classes: scene.loss_classes.clone(), ..params.clone() };
    let region = Region { shape: Shape::Whole, background: Some(scene.background) };
    Ok(restore::restore(&scene.classified, &class_info(&scene.palette), &[region], None, &params)?)
}

/// The table for one scene: the classification as is, ours, the mode filter of the same
/// footprint (radius = `params.neighbours`), and any peer label maps given.
pub fn evaluate_scene(
    scene: &Scene,
    params: &RestoreParams,
    peers: &[(&str, &LabelMap)],
) -> Result<Vec<Metric>> {
    let ours = restore_scene(scene, params)?;
    let mode = mode_filter(&scene.classified, params.neighbours, scene.palette.classes.len());
    let mut m = score(scene, "classified", &scene.classified);
    m.truncate(1);
    m.extend(score(scene, "ours", &ours.labels));
    m.extend(score(scene, "mode filter", &mode));
    for (name, labels) in peers {
        m.extend(score(scene, name, labels));
    }
    Ok(m)
}

/// The table on every built-in scene at `camera` size (ours and the mode filter; the Telea
/// peer needs files, see `eval-restore`), with the CLI's automatic grid of ~256 px cells.
pub fn evaluate_builtin(
    camera: [u32; 2],
    seed: u64,
    rig: RigVariation,
    params: &RestoreParams,
) -> Result<Vec<Metric>> {
    let params = RestoreParams { grid: (camera[0].div_ceil(256), camera[1].div_ceil(256)), ..params.clone() };
    let mut all = Vec::new();
    for name in SceneName::ALL {
        all.extend(evaluate_scene(&prepare_scene(name, camera, seed, rig)?, &params, &[])?);
    }
    Ok(all)
}

/// Writes what the Telea peer needs: the classified image in class colours, the true
/// deterioration mask (pixels whose label the wear changed) and the classes' colours.
pub fn write_peer_inputs(scene: &Scene, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let colours: Vec<[u8; 3]> =
        (0..scene.palette.classes.len()).map(|i| scene.palette.display_colour(i)).collect();
    restore::render_labels(&scene.classified, &colours)
        .save(dir.join("classified.png"))
        .with_context(|| format!("writing {}", dir.display()))?;
    let mask = image::GrayImage::from_fn(scene.pristine.width, scene.pristine.height, |x, y| {
        let (p, d) = (scene.pristine.get(x, y), scene.deteriorated.get(x, y));
        image::Luma([if p != MASKED && p != d { 255 } else { 0 }])
    });
    mask.save(dir.join("deterioration_mask.png")).with_context(|| format!("writing {}", dir.display()))?;
    let text = serde_json::to_string(&colours)?;
    std::fs::write(dir.join("colours.json"), text).with_context(|| format!("writing {}", dir.display()))?;
    Ok(())
}

/// Reads the peer's output (an RGB image in class colours) back as labels (nearest colour).
pub fn read_peer_labels(scene: &Scene, path: &Path) -> Result<LabelMap> {
    let img = image::open(path).with_context(|| format!("reading {}", path.display()))?.to_rgb8();
    let colours: Vec<[u8; 3]> =
        (0..scene.palette.classes.len()).map(|i| scene.palette.display_colour(i)).collect();
    let data = img
        .pixels()
        .zip(&scene.classified.data)
        .map(|(p, &c)| {
            if c == MASKED {
                return MASKED;
            }
            (0..colours.len())
                .min_by_key(|&k| (0..3).map(|j| (p.0[j] as i32 - colours[k][j] as i32).pow(2)).sum::<i32>())
                .unwrap_or(0) as u8
        })
        .collect();
    Ok(LabelMap::from_vec(img.width(), img.height(), data)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scenes_meet_the_targets_ahead_of_the_mode_filter() {
        // The figure at the eval's default size: at least half of the
        // classification's wrong pixels fixed, mean contour distance under 1 px, fewer wrong
        // pixels than the mode filter, on every built-in scene with default parameters.
        let m = evaluate_builtin([800, 600], 1, RigVariation::Seeded, &RestoreParams::default()).unwrap();
        let get = |scene: &str, what: &str| {
            m.iter().find(|x| x.name == format!("{scene} {what}")).map(|x| x.value).unwrap()
        };
        for scene in SceneName::ALL.map(|s| s.name()) {
            let fixed = get(scene, "ours: classification errors fixed");
            let mean = get(scene, "ours: contour distance mean");
            let (ours, mode) = (get(scene, "ours: wrong pixels"), get(scene, "mode filter: wrong pixels"));
            assert!(fixed >= 0.5 && mean < 1.0, "{scene}: fixed {fixed:.3}, contour distance {mean:.3} px");
            assert!(ours < mode, "{scene}: ours {ours:.3} % wrong vs mode filter {mode:.3} %");
            // Chips take the colour around them, not that of their misread rims, and lines
            // that cross them are bridged (measured 81.9-92.0 %; 78.8 % on the jar without
            // the bridges).
            let chips = get(scene, "ours: chip pixels in their pristine colour");
            assert!(chips > 80.0, "{scene}: {chips:.1} % of chip pixels in their pristine colour");
        }
    }

    #[test]
    fn distances_and_mode_filter_behave() {
        let w = 20;
        let a = LabelMap::from_vec(w, 10, (0..200).map(|i| u8::from(i % 20 >= 10)).collect()).unwrap();
        let b = LabelMap::from_vec(w, 10, (0..200).map(|i| u8::from(i % 20 >= 12)).collect()).unwrap();
        let map: Vec<u8> = (0..=255).collect();
        assert_eq!(contour_distance(&a, &a, &map), (0.0, 0.0));
        let (mean, p95) = contour_distance(&b, &a, &map);
        assert!((mean - 1.5).abs() < 1e-9 && (p95 - 2.0).abs() < 1e-9, "{mean} {p95}");
        assert_eq!(label_error(&b, &a, &map), (20, 200));
        let mut speck = a.clone();
        speck.data[3 * 20 + 3] = 1;
        assert_eq!(mode_filter(&speck, 1, 2), a);
    }
}
