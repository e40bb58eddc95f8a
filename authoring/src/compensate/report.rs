//! Pictures of a compensation for people: the irradiance heat map (lux), per-projector weight
//! maps, and the weights along one image row for several m (the paper's Figure 9), gathered
//! in an HTML page. Pure image/string builders plus one explicit `save` function.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use image::{GrayImage, Luma, Rgb, RgbImage};

use super::footprint::Refinement;
use super::weights::{Exponent, point_weights};
use super::{Compensation, Geometry, Params};

/// A perceptually ordered dark-to-bright colour ramp (black, purple, red, orange, yellow,
/// white), `t` in 0..=1.
pub fn heat(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 6] = [
        [0.0, 0.0, 0.0],
        [80.0, 18.0, 123.0],
        [182.0, 54.0, 121.0],
        [251.0, 136.0, 97.0],
        [252.0, 230.0, 120.0],
        [255.0, 255.0, 255.0],
    ];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    std::array::from_fn(|c| (STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f).round() as u8)
}

/// Heat map of irradiance per camera pixel, 0 lux black to `e_bound` white; pixels that no
/// projector reaches are dark blue-grey so they read as "not object".
pub fn irradiance_map(lux: &[f64], width: u32, height: u32, e_bound: f64) -> RgbImage {
    RgbImage::from_fn(width, height, |x, y| {
        let e = lux[(y * width + x) as usize];
        if e <= 0.0 { Rgb([20, 24, 32]) } else { Rgb(heat(e / e_bound)) }
    })
}

/// Weight map of projector `k` (grey: 0 black, 1 white).
pub fn weight_map(weights: &[f32], projectors: usize, k: usize, width: u32, height: u32) -> GrayImage {
    GrayImage::from_fn(width, height, |x, y| {
        let i = (y * width + x) as usize;
        Luma([(weights[i * projectors + k].clamp(0.0, 1.0) * 255.0).round() as u8])
    })
}

/// The camera row through the middle of the object: the one with the most covered pixels
/// among the rows near the centre of the covered rows.
pub fn middle_row(geom: &Geometry, width: u32) -> u32 {
    let height = geom.points as u32 / width;
    let counts: Vec<usize> =
        (0..height).map(|y| (0..width).filter(|&x| geom.covered((y * width + x) as usize)).count()).collect();
    let rows: Vec<u32> = (0..height).filter(|&y| counts[y as usize] > 0).collect();
    if rows.is_empty() {
        return height / 2;
    }
    let mid = rows[rows.len() / 2];
    let span = (rows.len() / 10) as u32;
    (mid.saturating_sub(span)..=(mid + span).min(height - 1))
        .max_by_key(|&y| (counts[y as usize], u32::MAX - y))
        .unwrap()
}

/// An SVG line chart of the weights along camera row `row` for each m in `ms`, one panel per
/// m, one line per projector (paper's Figure 9).
pub fn weights_along_row_svg(geom: &Geometry, width: u32, row: u32, ms: &[Exponent]) -> String {
    const COLOURS: [&str; 8] =
        ["#d62728", "#2ca02c", "#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
    let kn = geom.projectors;
    let (pw, ph, pad) = (560.0, 150.0, 36.0);
    let mut svg = String::new();
    let total_h = (ph + pad) * ms.len() as f64 + pad;
    let _ = write!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{}" height="{total_h}" font-family="sans-serif" font-size="12">"#,
        pw + 2.0 * pad
    );
    let xs: Vec<u32> = (0..width).filter(|&x| geom.covered((row * width + x) as usize)).collect();
    let (x_lo, x_hi) = (xs.first().copied().unwrap_or(0) as f64, xs.last().copied().unwrap_or(1) as f64);
    let span = (x_hi - x_lo).max(1.0);
    for (panel, &m) in ms.iter().enumerate() {
        let top = pad + panel as f64 * (ph + pad);
        let _ = write!(
            svg,
            r##"<rect x="{pad}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#999"/><text x="{pad}" y="{}">m = {m}: w_ik along camera row {row} (x {x_lo}..{x_hi})</text><text x="4" y="{}">1</text><text x="4" y="{}">0</text>"##,
            top - 6.0,
            top + 10.0,
            top + ph
        );
        let mut w = vec![0.0f32; kn];
        let mut lines = vec![String::new(); kn];
        for &x in &xs {
            let i = (row * width + x) as usize;
            point_weights(&geom.l[i * kn..(i + 1) * kn], m, &mut w);
            let px = pad + (x as f64 - x_lo) / span * pw;
            for k in 0..kn {
                let py = top + ph - w[k] as f64 * ph;
                let _ = write!(lines[k], "{px:.1},{py:.1} ");
            }
        }
        for (k, pts) in lines.iter().enumerate() {
            let _ = write!(
                svg,
                r#"<polyline fill="none" stroke="{}" stroke-width="1.5" points="{pts}"/><text x="{}" y="{}" fill="{}">projector {k}</text>"#,
                COLOURS[k % 8],
                pad + pw - 80.0,
                top + 14.0 + 14.0 * k as f64,
                COLOURS[k % 8]
            );
        }
    }
    svg.push_str("</svg>");
    svg
}

/// What the report says of the footprint-aware refinement: its rounds and modelled mismatch
/// where it ran, otherwise why the per-pixel formula's frames stand.
fn refinement_text(refinement: Option<&Refinement>, rounds: u32) -> String {
    match refinement {
        Some(r) => format!(
            "{} rounds; modelled mismatch {:.1} % → {:.1} %",
            r.rounds,
            100.0 * r.mismatch_before,
            100.0 * r.mismatch_after
        ),
        None if rounds == 0 => "off (--footprint-rounds 0): the per-pixel formula's frames".into(),
        None => "not run: the stage model has no measured footprints (the per-pixel formula's frames)".into(),
    }
}

/// Writes the report into `dir`: `irradiance.png`, `weights_proj<k>.png`, `index.html`.
pub fn save(
    dir: &Path,
    comp: &Compensation,
    geom: &Geometry,
    params: &Params,
    width: u32,
    height: u32,
) -> Result<Vec<PathBuf>, crate::imgio::ImageError> {
    use crate::imgio::ImageError;
    let write_err =
        |path: &Path, e: std::io::Error| ImageError::Write { path: path.into(), source: e.into() };
    std::fs::create_dir_all(dir).map_err(|e| write_err(dir, e))?;
    let mut written = Vec::new();
    let heat_path = dir.join("irradiance.png");
    irradiance_map(&comp.lux, width, height, params.e_bound_lux)
        .save(&heat_path)
        .map_err(|source| ImageError::Write { path: heat_path.clone(), source })?;
    written.push(heat_path);
    for k in 0..geom.projectors {
        let p = dir.join(format!("weights_proj{k}.png"));
        weight_map(&comp.weights, geom.projectors, k, width, height)
            .save(&p)
            .map_err(|source| ImageError::Write { path: p.clone(), source })?;
        written.push(p);
    }
    let row = middle_row(geom, width);
    let mut ms = vec![Exponent::Finite(0.0), Exponent::Finite(1.0)];
    if !ms.contains(&params.m) && params.m != Exponent::Infinite {
        ms.push(params.m);
    }
    ms.push(Exponent::Infinite);
    let svg = weights_along_row_svg(geom, width, row, &ms);
    let s = &comp.stats;
    let gradient: Vec<String> = (0..=10)
        .map(|i| {
            let c = heat(i as f64 / 10.0);
            format!("rgb({},{},{}) {}%", c[0], c[1], c[2], i * 10)
        })
        .collect();
    let mut html = String::new();
    let _ = write!(
        html,
        r#"<!doctype html><meta charset="utf-8"><title>restage compensation report</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:1em auto}} img{{max-width:560px;image-rendering:pixelated;border:1px solid #ccc}} td{{padding:2px 10px}}</style>
<h1>Compensation report</h1>
<table>
<tr><td>E_bound</td><td>{eb} lx (limit {lim:.2} lx = E_bound × (1 − {u} lux-meter accuracy) × (1 − {margin} margin))</td></tr>
<tr><td>m</td><td>{m}</td></tr>
<tr><td>peak recomputed irradiance (final 8-bit frames, certificate)</td><td>{peak:.2} lx</td></tr>
<tr><td>black level + room light alone, peak</td><td>{black:.2} lx (room {room:.2} lx)</td></tr>
<tr><td>global scale s</td><td>{scale:.5} at clip fraction {cf:.2} %{curve}{judged}</td></tr>
<tr><td>covered object points</td><td>{cov}</td></tr>
<tr><td>limited by the bound / by projector saturation</td><td>{bb} ({bbp:.2} %) / {bs} ({bsp:.2} %)</td></tr>
<tr><td>darker than the black level and room light give (shown lifted)</td><td>{bbl} ({bblp:.2} %)</td></tr>
<tr><td>guarantee rounds, pixels dimmed</td><td>{rounds}, {dimmed}</td></tr>
<tr><td>certificate points (of them beside unknown surface)</td><td>{cp} ({up})</td></tr>
<tr><td>pixels kept black: light would land on unknown surface</td><td>{ud}</td></tr>
<tr><td>footprint refinement</td><td>{refined}</td></tr>
<tr><td>object pixels the target asks to light</td><td>{unlit}</td></tr>
</table>
<h2>Irradiance per unit area (lux)</h2>
<img src="irradiance.png"><div style="width:560px;height:14px;background:linear-gradient(to right,{grad})"></div>
<div style="width:560px;display:flex;justify-content:space-between"><span>0 lx</span><span>{half:.0} lx</span><span>E_bound {eb} lx</span></div>
<h2>Projector weights w_ik</h2>
"#,
        eb = params.e_bound_lux,
        margin = params.margin,
        u = params.meter_accuracy,
        lim = params.limit(),
        m = params.m,
        peak = s.peak_lux,
        black = s.peak_black_lux,
        room = s.room_lux,
        scale = s.scale,
        cf = 100.0 * s.clip_fraction,
        // What other fractions would give, and a sentence where that is much (the scale
        // moves steeply there).
        curve = {
            let text = super::clip_curve_text(&s.scale_by_clip, s.scale);
            let note = super::clip_tradeoff(&s.scale_by_clip, s.clip_fraction, s.scale);
            match (text.is_empty(), note) {
                (true, _) => String::new(),
                (false, None) => format!("; at other fractions, times this: {text}"),
                (false, Some(n)) => format!("; at other fractions, times this: {text}<br>{n}"),
            }
        },
        judged = if s.clip_judged.is_empty() {
            String::new()
        } else {
            format!(
                "<br>{}: {}",
                super::CLIP_JUDGED_CAPTION,
                super::clip_judged_text(&s.clip_judged, &s.clip_refined)
            )
        },
        cov = s.covered_points,
        bb = s.limited_by_bound,
        bbp = 100.0 * s.limited_by_bound as f64 / s.covered_points.max(1) as f64,
        bs = s.limited_by_saturation,
        bbl = s.below_black,
        bblp = 100.0 * s.below_black as f64 / s.covered_points.max(1) as f64,
        bsp = 100.0 * s.limited_by_saturation as f64 / s.covered_points.max(1) as f64,
        rounds = s.rounds,
        dimmed = s.dimmed_pixels,
        cp = s.certificate_points,
        up = s.unseen_points,
        ud = s.unseen_dark_pixels,
        grad = gradient.join(","),
        half = params.e_bound_lux / 2.0,
        refined = refinement_text(s.refinement.as_ref(), params.footprint_rounds),
        unlit = s.unlit,
    );
    for k in 0..geom.projectors {
        let _ = write!(
            html,
            r#"<figure style="display:inline-block"><img src="weights_proj{k}.png" style="max-width:380px"><figcaption>projector {k}</figcaption></figure>"#
        );
    }
    let _ = write!(html, "<h2>Weights along camera row {row} (paper's Figure 9)</h2>\n{svg}\n");
    let index = dir.join("index.html");
    std::fs::write(&index, html).map_err(|e| write_err(&index, e))?;
    written.push(index);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::synthetic::synthetic_stage;
    use crate::compensate::{Exponent, Params, compensate};
    use crate::imgio::LinearImage;

    #[test]
    fn heat_ramp_is_monotonic_in_brightness() {
        let lum = |c: [u8; 3]| crate::color::luminance(c.map(f64::from));
        let mut last = -1.0;
        for i in 0..=100 {
            let l = lum(heat(i as f64 / 100.0));
            assert!(l >= last - 1e-9, "step {i}");
            last = l;
        }
    }

    #[test]
    fn report_files_are_written_and_the_row_plot_has_every_m() {
        let s = synthetic_stage(3, 2);
        let cam = &s.model.camera;
        let mut t = LinearImage::new(cam.width, cam.height).unwrap();
        t.data.iter_mut().for_each(|v| *v = [0.4, 0.3, 0.2]);
        let p = Params::new(150.0, Exponent::Finite(8.0), 0.05).unwrap();
        let c = compensate(&s.model, &t, &p).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let geom = Geometry::new(&s.model);
        let files = save(dir.path(), &c, &geom, &p, cam.width, cam.height).unwrap();
        assert_eq!(files.len(), 5);
        let html = std::fs::read_to_string(dir.path().join("index.html")).unwrap();
        for m in ["m = 0:", "m = 1:", "m = 8:", "m = inf:"] {
            assert!(html.contains(m), "{m} missing");
        }
        // The bound names the meter's accuracy: 150 x 0.9 x 0.95 = 128.25.
        assert!(
            html.contains("limit 128.25 lx = E_bound × (1 − 0.1 lux-meter accuracy) × (1 − 0.05 margin)"),
            "{html}"
        );
        let heat = image::open(dir.path().join("irradiance.png")).unwrap().to_rgb8();
        assert_eq!(heat.dimensions(), (cam.width, cam.height));
        // The synthetic stage has measured footprints: the refinement ran and says so.
        let r = c.stats.refinement.as_ref().expect("the stage has footprints");
        assert!(
            html.contains(&format!(
                "<tr><td>footprint refinement</td><td>{} rounds; modelled mismatch",
                r.rounds
            )),
            "{html}"
        );
    }

    #[test]
    fn the_report_says_why_the_formula_frames_stand() {
        let r = Refinement { rounds: 8, mismatch_before: 0.0812, mismatch_after: 0.0604 };
        assert_eq!(refinement_text(Some(&r), 8), "8 rounds; modelled mismatch 8.1 % → 6.0 %");
        assert!(refinement_text(None, 0).starts_with("off (--footprint-rounds 0)"));
        assert!(refinement_text(None, 8).starts_with("not run: the stage model has no measured footprints"));
    }
}
