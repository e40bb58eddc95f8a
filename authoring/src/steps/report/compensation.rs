//! The page's compensation section: per scene, the light certificate in plain words, the
//! figures, the frames, and (where compensation wrote its report) the illuminance and weight
//! maps with their colour bars.

use std::fmt::Write as _;

use restage_authoring::compensate::report::heat;

use super::page::{MISSING, Page, Part, Scene, camera_axes, file, limit_lux, num, pct, verdict};
use super::svg::{self, ColourBar, Panel, Scale, esc, href};

impl Page<'_> {
    pub(super) fn compensate(&mut self) {
        self.push(
            "<section id=\"compensate\"><h2>6. Compensation and the light certificate</h2>\n<p>For \
             each scene, <code>restage-author compensate</code> computes one 8-bit frame per \
             projector so that the lit object looks like the scene's target image, as bright as the \
             light bound allows, blending smoothly where projectors overlap. Then it recomputes, \
             from the final frames, the illuminance on every patch of the object's surface and \
             dims any pixel that would take a patch over the bound: that recomputation is the light \
             certificate, which the bundle carries and the appliance checks again.</p>\n",
        );
        let _ = writeln!(
            self.html,
            "<p>Compensation used the calibrated stage model ({}), as it would on a real stage; \
             the light certificate below is computed with it.</p>",
            file("stage/")
        );
        self.push(
            "<p id=\"assumptions\"><strong>Under which assumptions a certificate holds.</strong> Its \
             figures are as true as the stage model they were computed with: which surface patches \
             each projector pixel reaches (geometry and correspondences), each projector's lux scale \
             (from the lux-meter reading), its response curves and black level, and the room light. \
             Move, refocus or re-lamp a projector, or change the room light, and the stage must be \
             calibrated again. The bound covers the whole surface a projector pixel's light can \
             land on, not only the points the camera saw head-on: each patch's coefficient is the \
             worst over the stretch of surface its pixels span (the nearest distance and the most \
             head-on normal among its neighbours, a surface facing the projector where the camera \
             sees it at more than 75°), and pixels whose light would land on surface the model \
             does not know (unseen, not reconstructed, past a silhouette) stay black, their blur \
             charged as light on a surface facing the projector at 80 % of the distance of the \
             known surface around it. So it assumes no unseen part of the object stands that much \
             nearer to a projector than the surface seen beside it. Exposure over time (lux-hours) is the appliance's \
             ledger's business, under the bundle's policy (see <a href=\"#bundle\">Bundle</a>).</p>\n",
        );
        for s in self.inp.scenes.clone() {
            self.scene(&s);
        }
        if self.inp.scenes.is_empty() {
            let _ = write!(
                self.html,
                r#"<p class="missing">No scene's <code>comp/*/compensation.json</code> {MISSING}.</p>"#
            );
        }
        self.push("</section>\n");
    }

    fn scene(&mut self, s: &Scene) {
        let sm = &s.summary;
        let st = &sm.stats;
        let limit = limit_lux(sm);
        // NaN figures count as over: nothing unproven passes.
        let over = st.peak_lux.partial_cmp(&limit).is_none_or(|o| o.is_gt());
        let _ = write!(
            self.html,
            r#"<h3 id="scene-{}">Scene “{}” (<code>{}</code>)</h3><div class="cert{}"><h4>Light certificate</h4><p>Peak illuminance found: <strong>{} lx</strong>. Allowed: <strong>{} lx</strong> (E_bound {} lx less {} for the lux meter's accuracy and the {} safety margin). {}</p>"#,
            href(&s.id),
            esc(&s.name),
            esc(&s.id),
            if over { " over" } else { "" },
            num(st.peak_lux, 2),
            num(limit, 2),
            num(sm.e_bound_lux, 1),
            pct(sm.meter_accuracy),
            pct(sm.margin),
            verdict(st.peak_lux, limit)
        );
        let _ = write!(
            self.html,
            "<p><strong>What is guaranteed.</strong> Compensation recomputed the illuminance at each \
             of the {} certificate points (patches of {r} × {r} camera pixels of the object's \
             surface) from the final 8-bit frames, conservatively: for every projector that can \
             reach a patch, the brightest pixel that can light it and that projector's black level, \
             the brightest of the three colour channels, plus the room light ({} lx). None is above \
             {} lx. The black levels and room light alone give up to {} lx. Every pixel the frames \
             light is vouched for by the certificate ({} that were not were set black). The \
             appliance repeats this check when it loads the bundle and refuses the scene if it \
             fails. {} projector pixels whose light would have landed on surface the model does \
             not know were kept black; {} certificate points charge their neighbours' blur.</p>",
            st.certificate_points,
            num(st.room_lux, 2),
            num(limit, 2),
            num(st.peak_black_lux, 2),
            st.unvouched_pixels,
            st.unseen_dark_pixels,
            st.unseen_points,
            r = sm.certificate_reduction
        );
        self.push(r##"<p>It holds <a href="#assumptions">under the assumptions above</a>.</p>"##);
        if let Some(line) = &s.check_line {
            let _ = write!(
                self.html,
                "<p>The demo also rendered the scene with the virtual stage's true physics (from \
                 <code>summary.txt</code>):</p><pre>{}</pre>",
                esc(line)
            );
        }
        self.push("</div>\n");
        let covered = st.covered_points.max(1) as f64;
        let _ = writeln!(
            self.html,
            "<div class=\"tbl\"><table><caption>Figures from {}</caption><tbody>\
             <tr><th scope=\"row\">smoothness exponent m</th><td>{}</td></tr>\
             <tr><th scope=\"row\">global scale s (camera value per unit of target)</th><td class=\"n\">{}</td></tr>\
             <tr><th scope=\"row\">object points lit</th><td class=\"n\">{}</td></tr>\
             <tr><th scope=\"row\">limited by the bound</th><td class=\"n\">{} ({})</td></tr>\
             <tr><th scope=\"row\">limited by projector saturation</th><td class=\"n\">{} ({})</td></tr>\
             <tr><th scope=\"row\">darker than the black level and room light give (shown lifted)</th><td class=\"n\">{} ({})</td></tr>\
             <tr><th scope=\"row\">clip fraction allowed</th><td class=\"n\">{}</td></tr>{}\
             <tr><th scope=\"row\">guarantee rounds, pixels dimmed</th><td class=\"n\">{}, {}</td></tr>{}{}\
             </tbody></table></div>",
            file(&format!("{}/compensation.json", s.dir)),
            esc(&sm.m),
            num(st.scale, 5),
            st.covered_points,
            st.limited_by_bound,
            pct(st.limited_by_bound as f64 / covered),
            st.limited_by_saturation,
            pct(st.limited_by_saturation as f64 / covered),
            st.below_black,
            pct(st.below_black as f64 / covered),
            pct(sm.clip_fraction),
            // What another fraction would give (absent from figures written before it was kept).
            if st.scale_by_clip.is_empty() || st.scale <= 0.0 {
                String::new()
            } else {
                format!(
                    "<tr><th scope=\"row\">global scale at other clip fractions (× this one)</th><td>{}{}</td></tr>",
                    esc(&restage_authoring::compensate::clip_curve_text(&st.scale_by_clip, st.scale)),
                    restage_authoring::compensate::clip_tradeoff(
                        &st.scale_by_clip,
                        sm.clip_fraction,
                        st.scale
                    )
                    .map_or(String::new(), |n| format!("<br>{}", esc(&n)))
                )
            } + &if st.clip_judged.is_empty() {
                String::new()
            } else {
                format!(
                    "<tr><th scope=\"row\">{}</th><td>{}</td></tr>",
                    esc(restage_authoring::compensate::CLIP_JUDGED_CAPTION),
                    esc(&restage_authoring::compensate::clip_judged_text(&st.clip_judged, &st.clip_refined))
                )
            },
            st.rounds,
            st.dimmed_pixels,
            // Only where it ran: a model without measured footprints keeps the formula's frames.
            st.refinement.map_or(String::new(), |r| format!(
                "<tr><th scope=\"row\">footprint refinement: rounds, modelled mismatch before → after</th>\
                 <td class=\"n\">{}, {} → {}</td></tr>",
                r.rounds,
                pct(r.mismatch_before),
                pct(r.mismatch_after)
            )),
            // What the object mask asks to light and what stays dark, by why (absent from
            // figures written before it was counted).
            if st.unlit.asked > 0 {
                format!(
                    "<tr><th scope=\"row\">object pixels lit, and why the rest are not</th><td>{}</td></tr>",
                    esc(&st.unlit.to_string())
                )
            } else {
                String::new()
            }
        );
        // The frames: one panel per projector, each in its own pixel coordinates.
        let parts: Vec<Part> = s
            .frames
            .iter()
            .enumerate()
            .filter_map(|(k, rel)| {
                let &(w, h) = self.inp.pictures.get(rel)?;
                Some(Part::Picture(
                    rel.clone(),
                    Panel {
                        src: [0, 0, w, h],
                        width: 300.0,
                        title: format!("Projector {k}"),
                        alt: format!("The frame projector {k} shows for scene {}", s.name),
                        x: Some(Scale::pixels("projector x (px)", w, w)),
                        y: Some(Scale::pixels("projector y (px)", h, h)),
                    },
                ))
            })
            .collect();
        if !parts.is_empty() {
            let caption = format!(
                "The frames, as each projector shows them (8-bit device values; black pixels are \
                 off and light nothing). Dark-looking frames are normal: they add to light from \
                 the other projectors and stay under the bound. The certificate: {}.",
                file(&format!("{}/certificate.bin", s.dir))
            );
            self.figure_of(&parts, &caption);
        }
        if let Some(report) = &s.report {
            self.scene_report(s, report);
        }
    }

    /// The compensation report's pictures: the irradiance heat map with its lux bar and the
    /// weight maps (compensate::report's colour scales).
    fn scene_report(&mut self, s: &Scene, report: &str) {
        let sm = &s.summary;
        let rel = format!("{report}/irradiance.png");
        let id = self.id("bar");
        let bar = ColourBar {
            title: "Illuminance".into(),
            // `heat` is linear between stops at fifths of the scale; 20 samples hit them all.
            stops: ColourBar::sampled(20, heat),
            lo: 0.0,
            hi: sm.e_bound_lux,
            unit: "lux".into(),
            marks: vec![(limit_lux(sm), format!("allowed {} lx", num(limit_lux(sm), 1)))],
            swatches: vec![([20, 24, 32], "no projector reaches".into())],
        };
        let bar = svg::colour_bar(&bar, &id);
        self.camera_picture(
            &rel,
            "Illuminance on the object",
            "False-colour map of the illuminance on the object, in lux",
            480.0,
            &[bar],
            &format!(
                "The illuminance each camera pixel's patch of surface receives from the final \
                 frames, as the certificate counts it (lux; black 0, white E_bound = {} lx; the \
                 triangle marks the allowed {} lx). Dark blue-grey: no projector reaches.",
                num(sm.e_bound_lux, 1),
                num(limit_lux(sm), 1)
            ),
        );
        let cam = self.inp.camera;
        let mut parts: Vec<Part> = (0..s.frames.len().max(1))
            .filter_map(|k| {
                let rel = format!("{report}/weights_proj{k}.png");
                let &(w, h) = self.inp.pictures.get(&rel)?;
                let (x, y) = camera_axes(cam.unwrap_or((w, h)), w, h);
                let title = format!("Projector {k}'s share");
                let alt = format!("Weight map of projector {k}: its share of each point's light");
                Some(Part::Picture(rel, Panel { src: [0, 0, w, h], width: 300.0, title, alt, x, y }))
            })
            .collect();
        if parts.is_empty() {
            return;
        }
        let id = self.id("bar");
        parts.push(Part::Svg(svg::colour_bar(
            &ColourBar {
                title: "Weight w".into(),
                stops: ColourBar::sampled(1, |t| [(t * 255.0).round() as u8; 3]),
                lo: 0.0,
                hi: 1.0,
                unit: "share of the point's light".into(),
                marks: vec![],
                swatches: vec![],
            },
            &id,
        )));
        let caption = format!(
            "Which projector lights what: each point's share of its light from each projector (the \
             paper's weights w, m = {}), 0 black to 1 white, in camera pixels. The full \
             compensation report, with the weights along one row for several m: {}.",
            esc(&sm.m),
            file(&format!("{report}/index.html"))
        );
        self.figure_of(&parts, &caption);
    }
}
