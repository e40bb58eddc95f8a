//! The page's calibration section: the geometry's and the light's figures, the calibration
//! report's panels with their colour keys, response curves and footprint maps.

use std::fmt::Write as _;

use restage_authoring::calibrate::photometric::footprint_colour;
use restage_authoring::calibrate::report::{
    HIST_BASE, HIST_SIDE, HIST_TOP, PANEL, RESIDUAL_MAX_PX, coverage_colour, depth_grey, normal_colour,
    panel_height,
};
use restage_authoring::calibrate::selfcal::Conditioning;
use restage_authoring::color::categorical;

use super::page::{MISSING, Page, Part, camera_axes, file, num, pct};
use super::svg::{self, ColourBar, Panel, Plot, Scale, Series, esc};

impl Page<'_> {
    pub(super) fn calibrate(&mut self) {
        self.push(
            "<section id=\"calibrate\"><h2>2. Calibration</h2>\n<p><code>restage-author calibrate</code> \
             decodes the structured light into camera–projector correspondences, recovers each \
             projector's lens and pose and the object's surface (one length, the camera-to-projector \
             distance, fixes the scale), then the light: how each projector pixel's light spreads on \
             the object, response curves, vignetting, black levels and, from one lux-meter reading \
             per projector, the lux scale. The result is the stage model ",
        );
        let _ = writeln!(self.html, "{}.</p>", file("stage/stage.bin"));
        self.geometry_table();
        self.calibration_report();
        self.photometric_table();
        self.responses();
        self.footprints();
        let _ = writeln!(
            self.html,
            "<p>Also: {} (a human summary of the model), {} (the surface as points with normals and \
             photo colours; opens in MeshLab).</p>\n</section>",
            file("stage/stage.json"),
            file("stage/model.ply")
        );
    }

    fn geometry_table(&mut self) {
        let Some(g) = &self.inp.geometry else {
            let _ = write!(self.html, r#"<p class="missing"><code>stage/report.json</code> {MISSING}.</p>"#);
            return;
        };
        let _ = writeln!(
            self.html,
            "<h3>Geometry</h3><p>{} surface points triangulated; reprojection error (RMS, projector \
             pixels) {} over all of them and {} over the bundle adjustment's inliers ({} iterations); \
             {} points rejected for their residual and {} for their depth; scale {} mm per solver \
             unit. From {}.</p>",
            g.points,
            num(g.dense_rms_px, 3),
            num(g.adjustment_rms_px, 3),
            g.adjustment_iterations,
            g.rejected_by_residual,
            g.rejected_by_depth,
            num(g.scale_mm, 2),
            file("stage/report.json")
        );
        self.push(
            "<div class=\"tbl\"><table><caption>Per projector: decoding (camera pixels) and how well \
             the lens is determined (± one standard deviation, projector pixels)</caption><thead><tr>\
             <th scope=\"col\">projector</th><th scope=\"col\">camera pixels lit</th><th scope=\"col\">decoded</th>\
             <th scope=\"col\">phase steps</th><th scope=\"col\">f ±</th><th scope=\"col\">cx ±</th><th scope=\"col\">cy ±</th>\
             </tr></thead><tbody>",
        );
        for d in &g.decode {
            let c = g.conditioning.iter().find(|c| c.projector == d.projector);
            let std = |f: fn(&Conditioning) -> f64| c.map_or("–".into(), |c| num(f(c), 2));
            let _ = write!(
                self.html,
                r#"<tr><td>{}</td><td class="n">{} of {}</td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td></tr>"#,
                d.projector,
                d.lit,
                d.pixels,
                d.decoded,
                d.phase_steps,
                std(|c| c.f_std_px),
                std(|c| c.cx_std_px),
                std(|c| c.cy_std_px)
            );
        }
        self.push("</tbody></table></div>\n");
        // The report's warnings include each projector's decoding warnings.
        let warnings = g.warnings.clone();
        self.warnings(&warnings, "geometry", "stage/report.json");
    }

    /// The first few warnings of a step, and how many more its file holds (a capture can give
    /// one per image).
    fn warnings(&mut self, warnings: &[String], what: &str, rel: &str) {
        const SHOWN: usize = 5;
        if warnings.is_empty() {
            let _ = writeln!(self.html, "<p>No {what} warnings.</p>");
            return;
        }
        let _ = write!(self.html, "<p>{} {what} warning(s):</p><ul>", warnings.len());
        for w in warnings.iter().take(SHOWN) {
            let _ = write!(self.html, "<li>{}</li>", esc(w));
        }
        if warnings.len() > SHOWN {
            let _ =
                write!(self.html, "<li>… and {} more, all in {}.</li>", warnings.len() - SHOWN, file(rel));
        }
        self.push("</ul>\n");
    }

    /// `stage/report.png`: coverage per projector on top; normal map, depth map and the
    /// residual histogram below (calibrate::report::render's layout).
    fn calibration_report(&mut self) {
        let rel = "stage/report.png";
        let Some(&(w, _)) = self.inp.pictures.get(rel) else {
            self.figure(rel, &[], &[], "");
            return;
        };
        let cam = self.inp.camera.unwrap_or((PANEL, PANEL * 3 / 4));
        let ph = panel_height(cam.0, cam.1);
        let n = self.inp.geometry.as_ref().map_or(self.inp.projectors.len(), |g| g.decode.len());
        let mut panels = Vec::new();
        for k in 0..n.min((w / PANEL) as usize) {
            let (x, y) = camera_axes(cam, PANEL, ph);
            panels.push(Panel {
                src: [k as u32 * PANEL, 0, PANEL, ph],
                width: PANEL as f64,
                title: format!("Projector {k}: where it was decoded"),
                alt: format!("Camera pixels where projector {k}'s patterns were decoded, coloured by projector coordinate"),
                x,
                y,
            });
        }
        let (x, y) = camera_axes(cam, PANEL, ph);
        panels.push(Panel {
            src: [0, ph, PANEL, ph],
            width: PANEL as f64,
            title: "Surface normals".into(),
            alt: "The object's surface normals as colours".into(),
            x: x.clone(),
            y: y.clone(),
        });
        panels.push(Panel {
            src: [PANEL, ph, PANEL, ph],
            width: PANEL as f64,
            title: "Depth".into(),
            alt: "Distance of the surface from the camera, near bright".into(),
            x,
            y,
        });
        let side = HIST_SIDE as f64;
        panels.push(Panel {
            src: [2 * PANEL, ph, PANEL, ph],
            width: PANEL as f64,
            title: "Reprojection residuals".into(),
            alt: "Histogram of reprojection residuals per projector".into(),
            x: Some(Scale {
                label: "residual (projector px)".into(),
                value: (0.0, RESIDUAL_MAX_PX as f64),
                px: (side, PANEL as f64 - side),
            }),
            y: Some(Scale {
                label: "count / its peak".into(),
                value: (0.0, 1.0),
                px: ((ph - HIST_BASE) as f64, HIST_TOP as f64),
            }),
        });
        let mut extra = Vec::new();
        if let Some(p) = self.inp.projectors.first() {
            let (pw, pht) = (p.width, p.height);
            let id = self.id("key");
            extra.push(svg::colour_key(
                "Coverage colours",
                "Colour key of the coverage maps: red grows with projector x, green with projector y",
                &Scale { label: "projector x (px)".into(), value: (0.0, pw as f64), px: (0.0, 1.0) },
                &Scale { label: "projector y (px)".into(), value: (0.0, pht as f64), px: (0.0, 1.0) },
                &id,
                |u, v| Some(coverage_colour((u * pw as f64) as f32, (v * pht as f64) as f32, pw, pht)),
            ));
        }
        let id = self.id("key");
        extra.push(svg::colour_key(
            "Normal colours",
            "Colour key of the normal map: a sphere facing the camera, coloured by its normal",
            &Scale { label: "normal x".into(), value: (-1.0, 1.0), px: (0.0, 1.0) },
            &Scale { label: "normal y (down)".into(), value: (-1.0, 1.0), px: (0.0, 1.0) },
            &id,
            |u, v| {
                let (nx, ny) = (2.0 * u - 1.0, 2.0 * v - 1.0);
                let r2 = nx * nx + ny * ny;
                // Normals face the camera: negative z in the camera frame.
                (r2 <= 1.0).then(|| normal_colour([nx as f32, ny as f32, -(1.0 - r2).sqrt() as f32]))
            },
        ));
        if let Some((lo, hi)) = self.inp.depth_mm {
            let id = self.id("bar");
            let bar = ColourBar {
                title: "Depth, distance from the camera".into(),
                stops: ColourBar::sampled(1, |t| {
                    let g = depth_grey(lo + t as f32 * (hi - lo), (lo, hi));
                    [g; 3]
                }),
                lo: lo as f64,
                hi: hi as f64,
                unit: "mm".into(),
                marks: vec![],
                swatches: vec![([0, 0, 0], "no surface".into())],
            };
            extra.push(svg::colour_bar(&bar, &id));
        }
        let legend: String = (0..n)
            .map(|k| {
                let c = categorical(k);
                format!(r#"<span style="color:{}">■</span> projector {k}"#, svg::rgb(c))
            })
            .collect::<Vec<_>>()
            .join(", ");
        let caption = format!(
            "The geometric calibration. Top: for each projector, the camera pixels where its \
             patterns were decoded, coloured by the projector pixel seen there (key: red grows \
             with projector x, green with y; black: not decoded); a coloured bar marks each \
             projector. Bottom: the surface normals (key: a sphere facing the camera), the depth \
             (near bright; bar in mm), and the histogram of reprojection residuals from 0 to {} \
             projector pixel, each projector's curve scaled to its own peak ({legend}). Small \
             residuals mean the recovered lenses, poses and surface agree with what was decoded.",
            RESIDUAL_MAX_PX
        );
        self.figure(rel, &panels, &extra, &caption);
    }

    fn photometric_table(&mut self) {
        let Some(ph) = &self.inp.photometric else {
            let _ = write!(
                self.html,
                r#"<p class="missing"><code>stage/photometric.json</code> {MISSING} (calibration without lux readings calibrates only the geometry).</p>"#
            );
            return;
        };
        let _ = writeln!(
            self.html,
            "<h3>Light</h3><p>Per projector, from {}: light transport from the dot grids, the \
             lux-meter reading and the lux scale fitted to it (<code>lux_at_1m</code>: the \
             illuminance the projector's full-white centre pixel gives 1 m away, facing it). Stray \
             room light during the capture: {} lx (red, green, blue).</p>",
            file("stage/photometric.json"),
            ph.stray_lux.iter().map(|v| num(*v, 2)).collect::<Vec<_>>().join(", ")
        );
        self.push(
            "<div class=\"tbl\"><table><thead><tr><th scope=\"col\">projector</th><th scope=\"col\">dots snapped</th>\
             <th scope=\"col\">transport covers (of its lit pixels)</th><th scope=\"col\">pixels filled (no projector decoded them)</th><th scope=\"col\">colour leakage, max</th>\
             <th scope=\"col\">vignetting coefficient</th><th scope=\"col\">lux meter</th><th scope=\"col\">lux_at_1m (lx)</th>\
             <th scope=\"col\">black level (of white)</th></tr></thead><tbody>",
        );
        for p in &ph.projectors {
            let leak = p.leakage.map_or("–".into(), |l| {
                let m = (0..3)
                    .flat_map(|a| (0..3).filter(move |&b| b != a).map(move |b| l[a][b]))
                    .fold(0.0f64, f64::max);
                pct(m)
            });
            let lux = p.lux.as_ref().map_or("–".into(), |l| {
                // A requested pixel that decoded nothing was replaced by the nearest decoded one.
                let moved = match l.requested_pixel {
                    Some(r) if r != l.reference_pixel => format!(
                        " (requested ({}, {}) decoded no surface; used the nearest decoded pixel, {} px away)",
                        r[0],
                        r[1],
                        num(l.moved_px, 1)
                    ),
                    _ => String::new(),
                };
                format!(
                    "{} lx at camera pixel ({}, {}), {} mm away{moved}",
                    num(l.reading, 1),
                    l.reference_pixel[0],
                    l.reference_pixel[1],
                    num(l.distance_mm, 0)
                )
            });
            let black = self.inp.projectors.get(p.projector).map_or("–".into(), |m| {
                m.black.iter().map(|b| pct(*b as f64)).collect::<Vec<_>>().join(", ")
            });
            let _ = write!(
                self.html,
                r#"<tr><td>{}</td><td class="n">{} of {}</td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td><td class="n">{}</td><td>{}</td><td class="n">{}</td><td class="n">{}</td></tr>"#,
                p.projector,
                p.dots_snapped,
                p.dots_predicted,
                pct(p.coverage_of_lit_pixels),
                p.filled_pixels,
                leak,
                p.vignetting_coefficient.map_or("uniform".into(), |v| num(v, 3)),
                lux,
                p.lux.as_ref().map_or("–".into(), |l| num(l.lux_at_1m, 1)),
                black
            );
        }
        self.push("</tbody></table></div>\n");
        let warnings = ph.warnings.clone();
        self.warnings(&warnings, "light calibration", "stage/photometric.json");
    }

    fn responses(&mut self) {
        if self.inp.projectors.iter().all(|p| p.response.iter().all(Vec::is_empty)) {
            return;
        }
        self.push("<figure><div class=\"panels\">");
        const CHANNELS: [(&str, [u8; 3]); 3] =
            [("red", [190, 30, 30]), ("green", [20, 130, 40]), ("blue", [30, 60, 200])];
        for (k, p) in self.inp.projectors.clone().iter().enumerate() {
            let mut series = Vec::new();
            for (c, (name, colour)) in CHANNELS.iter().enumerate() {
                let curve =
                    |r: &[f32]| r.iter().enumerate().map(|(v, &o)| (v as f64, o as f64)).collect::<Vec<_>>();
                series.push(Series {
                    label: format!("{name}, calibrated"),
                    colour: *colour,
                    dashed: false,
                    points: curve(&p.response[c]),
                });
            }
            let id = self.id("plot");
            let plot = Plot {
                title: format!("Projector {k}: response"),
                alt: format!(
                    "Response curves of projector {k}: relative light output against 8-bit input, per colour channel"
                ),
                x: Scale {
                    label: "input value (8-bit, 0–255)".into(), value: (0.0, 255.0), px: (0.0, 1.0)
                },
                y: Scale { label: "relative output".into(), value: (0.0, 1.0), px: (0.0, 1.0) },
                series,
            };
            let s = svg::plot(&plot, &id);
            self.push(&s);
        }
        let pngs: Vec<String> = (0..self.inp.projectors.len())
            .map(|k| format!("stage/response_proj{k}.png"))
            .filter(|r| self.inp.pictures.contains_key(r))
            .map(|r| file(&r))
            .collect();
        let _ = writeln!(
            self.html,
            "</div><figcaption>Each projector's light output for each 8-bit input value, per colour \
             channel, relative to its output at 255 above black (0 = black level, 1 = full). Solid: \
             as calibrated from the gray ramps (<code>stage/stage.bin</code>). The calibration's \
             own plots, with the measured levels as squares and the dark end (levels 0-64) enlarged: {}.</figcaption></figure>",
            if pngs.is_empty() { "none written".to_string() } else { pngs.join(", ") }
        );
    }

    /// The footprint maps, each with its own colour bar (each scale is its map's median).
    fn footprints(&mut self) {
        let mut parts = Vec::new();
        for (k, p) in self.inp.projectors.clone().iter().enumerate() {
            let rel = format!("stage/footprint_proj{k}.png");
            let (Some(&(w, h)), Some(scale)) = (self.inp.pictures.get(&rel), p.footprint_scale) else {
                continue;
            };
            parts.push(Part::Picture(
                rel,
                Panel {
                    src: [0, 0, w, h],
                    width: 300.0,
                    title: format!("Projector {k}: light footprint per pixel"),
                    alt: format!(
                        "How much light each pixel of projector {k} puts on the object, as a false-colour map"
                    ),
                    x: Some(Scale::pixels("projector x (px)", w, w)),
                    y: Some(Scale::pixels("projector y (px)", h, h)),
                },
            ));
            let id = self.id("bar");
            let bar = ColourBar {
                title: format!("Projector {k}: footprint"),
                stops: ColourBar::sampled(2, |t| footprint_colour(t as f32)),
                lo: 0.0,
                hi: scale as f64,
                unit: "camera pixels' worth of light".into(),
                marks: vec![(scale as f64 / 2.0, "median".into())],
                swatches: vec![([0, 0, 0], "not measured".into())],
            };
            parts.push(Part::Svg(svg::colour_bar(&bar, &id)));
        }
        if parts.is_empty() {
            return;
        }
        self.figure_of(
            &parts,
            "Light transport: for each projector pixel, how much light it puts on the object, in \
             camera pixels' worth (a pixel whose light covers one camera pixel fully is 1), with \
             each projector's colour bar beside its map. The colours run to twice that \
             projector's median footprint; a pixel above that shows as the end of the scale. \
             Black: no dot was measured there (off the object, or in shadow).",
        );
    }
}
