//! The panels around the canvas: the top bar (history, saving, export, the views), the
//! status line (progress, failures, frame time, zoom) and the side panel (tools, classes,
//! regions, parameters, lighting, light figures). Widgets edit the working copy.

use eframe::egui::{self, Color32, Sense};
use restage_authoring::relight::Light;

use super::canvas::Shown;
use super::tools::Tool;
use super::{App, REDO, SAVE, UNDO};
use crate::gui::doc::{HintDiff, RegionSpec, Scene, Small, Steps, directional, light_angles, new_class};
use crate::gui::views::ViewKind;

impl App {
    pub(super) fn top_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            let ctx = ui.ctx().clone();
            if ui
                .add_enabled(self.doc.can_undo(), egui::Button::new("Undo"))
                .on_hover_text(ctx.format_shortcut(&UNDO))
                .clicked()
            {
                self.undo();
            }
            if ui
                .add_enabled(self.doc.can_redo(), egui::Button::new("Redo"))
                .on_hover_text(ctx.format_shortcut(&REDO))
                .clicked()
            {
                self.redo();
            }
            if ui.button("Save").on_hover_text(ctx.format_shortcut(&SAVE)).clicked() {
                self.save();
            }
            if ui.button("Export bundle…").clicked() {
                self.dialogs.export_open = true;
            }
            ui.separator();
            let views = [
                ViewKind::Photo,
                ViewKind::Object,
                ViewKind::Classes,
                ViewKind::ClassesFalse,
                ViewKind::Restored,
                ViewKind::Relit,
                ViewKind::Visitor(Scene::Original),
                ViewKind::Visitor(Scene::Restored),
                ViewKind::Visitor(Scene::Relit),
                ViewKind::Irradiance(Scene::Restored),
                ViewKind::Irradiance(Scene::Relit),
            ];
            for v in views {
                let on = self.view.shown == Shown::One(v);
                if ui.selectable_label(on, v.label()).clicked() {
                    self.view.shown = Shown::One(v);
                }
            }
            if ui.selectable_label(self.view.shown == Shown::BeforeAfter, "before | after").clicked() {
                self.view.shown = Shown::BeforeAfter;
            }
            if ui.button("Fit").clicked() {
                self.view.transform = None;
            }
        });
    }

    pub(super) fn status_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            if let Some(r) = &self.jobs.running {
                let frac = r.done as f32 / r.total.max(1) as f32;
                let what = r.step.map_or("starting".to_string(), |s| s.name().to_string());
                let text = if self.scripted() {
                    format!("{what} ({}/{})", r.done + 1, r.total)
                } else {
                    format!("{what} ({}/{}) {:.0} s", r.done + 1, r.total, r.started.elapsed().as_secs_f32())
                };
                ui.add(egui::ProgressBar::new(frac).desired_width(260.0).text(text));
                if ui.button("Cancel").clicked() {
                    self.jobs.worker.cancel();
                }
            } else if let Some((step, msg)) = self.jobs.failed.clone() {
                ui.colored_label(
                    Color32::from_rgb(255, 120, 100),
                    format!("{}: {msg}", step.map_or("saving", |s| s.name())),
                );
                if let Some(step) = step
                    && ui.button("Retry").clicked()
                {
                    self.submit(Steps::from_iter([step]).with_dependents(), None);
                }
            } else {
                ui.label("up to date");
            }
            ui.separator();
            if !self.scripted()
                && let Some(mean) = self.frames.mean()
            {
                ui.weak(format!("frame {:.1} ms", mean * 1e3));
            }
            if let Some(t) = self.view.transform {
                ui.weak(format!("zoom {:.0} %", t.zoom * 100.0));
            }
        });
    }

    pub(super) fn side_panel(&mut self, ui: &mut egui::Ui) {
        self.first_step_ui(ui);
        ui.heading("Tools");
        let before = self.tools.tool;
        ui.horizontal_wrapped(|ui| {
            for (t, name, tip) in [
                (Tool::Pan, "pan", "drag to pan, wheel to zoom (any tool: middle drag pans)"),
                (Tool::Pick, "pick", "click: pick a pixel for the class; shift-drag: a rectangle; right-click: remove the nearest pick"),
                (Tool::RegionRect, "rect region", "drag a rectangle to restore"),
                (Tool::RegionPolygon, "polygon region", "click corners; double-click or Enter closes, Esc cancels"),
                (Tool::Outline, "outline", "the object's outline: click corners; the first corner, double-click or Enter closes, Backspace removes the last corner, Esc cancels"),
                (Tool::Hint, "hint brush", "paint the class where the restoration should put it"),
                (Tool::Erase, "eraser", "erase hint strokes"),
            ] {
                ui.selectable_value(&mut self.tools.tool, t, name).on_hover_text(tip);
            }
        });
        if self.tools.tool != before {
            // A polygon begun with one tool is not finished by another.
            self.tools.polygon.clear();
            if self.tools.tool == Tool::Outline && self.textures.views.contains_key(&ViewKind::Object) {
                self.view.shown = Shown::One(ViewKind::Object);
            }
        }
        if matches!(self.tools.tool, Tool::Hint | Tool::Erase) {
            ui.add(
                egui::Slider::new(&mut self.tools.brush, 0.5..=64.0)
                    .logarithmic(true)
                    .text("brush radius px"),
            )
            .on_hover_text("Radius of the hint brush and the eraser, in photo pixels.");
            ui.horizontal(|ui| {
                ui.checkbox(&mut self.view.show_hints, "show strokes");
                if ui.button("clear strokes").clicked() && !self.doc.hints.is_empty() {
                    let mut diff = HintDiff::default();
                    self.doc.hints.clear(&mut diff);
                    self.textures.refresh_overlay(&self.doc.hints, None);
                    self.finish_stroke(diff);
                }
            });
        }
        if self.tools.tool == Tool::Outline {
            self.outline_ui(ui);
        }
        ui.separator();
        self.classes_ui(ui);
        ui.separator();
        self.regions_ui(ui);
        ui.separator();
        self.parameters_ui(ui);
        ui.separator();
        self.lighting_ui(ui);
        ui.separator();
        self.figures_ui(ui);
    }

    /// One line on what to do first, while the project lacks picks or outputs: a new user
    /// otherwise meets a panel of parameters and no way in.
    fn first_step_ui(&mut self, ui: &mut egui::Ui) {
        // Only when idle and nothing failed: running steps are on their way, a failure has
        // its own Retry in the status line.
        let missing = if self.jobs.running.is_none() && self.jobs.failed.is_none() {
            self.project.missing_steps(&self.doc.small)
        } else {
            Steps::NONE
        };
        let Some(hint) = first_step(&self.doc.small, missing) else { return };
        let text = egui::RichText::new(hint).color(Color32::from_rgb(255, 210, 120));
        ui.add(egui::Label::new(text).wrap());
        if !missing.is_empty()
            && ui
                .button("Run them")
                .on_hover_text(
                    "Compute what is missing; after this, every change recomputes what it affects.",
                )
                .clicked()
        {
            self.submit(missing.with_dependents(), None);
        }
        ui.separator();
    }

    fn classes_ui(&mut self, ui: &mut egui::Ui) {
        ui.heading("Colour classes");
        let colours = self.textures.colours.clone();
        let w = &mut self.working;
        let mut remove = None;
        for (i, c) in w.picks.colours.iter_mut().enumerate() {
            ui.horizontal(|ui| {
                let col = colours.get(i).copied().unwrap_or(restage_authoring::color::categorical(i));
                let (rect, _) = ui.allocate_exact_size(egui::vec2(14.0, 14.0), Sense::hover());
                ui.painter().rect_filled(rect, 2.0, Color32::from_rgb(col[0], col[1], col[2]));
                if ui
                    .selectable_label(self.tools.class == i, "")
                    .on_hover_text("select for picks and hints")
                    .clicked()
                {
                    self.tools.class = i;
                }
                // Narrower than the names need at most, so the row (with "N picks") fits the
                // default panel width.
                ui.add(egui::TextEdit::singleline(&mut c.name).desired_width(72.0));
                let mut restored = c.display_srgb8.is_some();
                if ui
                    .checkbox(&mut restored, "")
                    .on_hover_text("choose the restored display colour")
                    .changed()
                {
                    c.display_srgb8 = restored.then_some(col);
                }
                if let Some(rgb) = &mut c.display_srgb8 {
                    ui.color_edit_button_srgb(rgb);
                }
                let k = i as u8;
                let mut loss = w.settings.restore.loss.contains(&k);
                if ui
                    .checkbox(&mut loss, "loss")
                    .on_hover_text(
                        "this class is loss (bare clay in chips and cracks): its cracks are told from dark paint, \
                         and it is filled from its neighbours",
                    )
                    .changed()
                {
                    w.settings.restore.loss.retain(|&l| l != k);
                    if loss {
                        w.settings.restore.loss.push(k);
                        w.settings.restore.loss.sort_unstable();
                    }
                }
                let (px, rects) = (c.pixels.len(), c.rects.len());
                ui.weak(format!("{} picks", px + rects)).on_hover_text(format!(
                    "What teaches the classifier this colour: {px} picked pixel{} and {rects} \
                     rectangle{}. Add more with the pick tool (click, or shift-drag a rectangle).",
                    plural(px),
                    plural(rects)
                ));
                if ui.small_button("×").on_hover_text("remove this class").clicked() {
                    remove = Some(i);
                }
            });
        }
        if let Some(i) = remove {
            w.picks.colours.remove(i);
            let k = i as u8;
            // Later classes move down one index.
            w.settings.restore.loss = w
                .settings
                .restore
                .loss
                .iter()
                .filter(|&&l| l != k)
                .map(|&l| if l > k { l - 1 } else { l })
                .collect();
            self.tools.class = self.tools.class.min(w.picks.colours.len().saturating_sub(1));
        }
        if ui.button("add class").clicked() {
            let c = new_class(&w.picks);
            w.picks.colours.push(c);
            self.tools.class = w.picks.colours.len() - 1;
            self.tools.tool = Tool::Pick;
        }
        ui.collapsing("classification", |ui| {
            ui.add(
                egui::Slider::new(&mut w.settings.classify.max_iterations, 1..=50).text("k-means iterations"),
            )
            .on_hover_text(
                "Most k-means rounds (--max-iterations). 1: each pixel takes the nearest picked \
                 colour (measured best on the virtual stage); 50: k-means to convergence, as in the paper.",
            );
            ui.add(egui::Slider::new(&mut w.settings.classify.prior_picks, 0.0..=50.0).text("prior picks"))
                .on_hover_text(
                    "How many picks' worth of the plain colour distance each colour's own spread \
                     (from its picks) is pulled towards (--prior-picks). Larger: the picks' spread \
                     counts less.",
                );
        });
    }

    /// The outline tool's state: what the mask is made from, and clearing the outline.
    fn outline_ui(&mut self, ui: &mut egui::Ui) {
        let n = self.working.outline.polygons.len();
        if n == 0 {
            ui.weak(if self.project.paths.stage.is_some() {
                "object: the automatic proposal (tinted outside in the object view); draw to replace it"
            } else {
                "no outline: draw around the object"
            });
        } else {
            ui.label(format!("outline: {n} polygon{}", if n == 1 { "" } else { "s" }));
        }
        if ui
            .add_enabled(n > 0 || !self.tools.polygon.is_empty(), egui::Button::new("clear outline"))
            .clicked()
        {
            self.working.outline.polygons.clear();
            self.tools.polygon.clear();
        }
    }

    fn regions_ui(&mut self, ui: &mut egui::Ui) {
        ui.heading("Regions");
        let names: Vec<String> = self.working.picks.colours.iter().map(|c| c.name.clone()).collect();
        let r = &mut self.working.settings.restore;
        if r.regions.is_empty() {
            ui.weak("whole image (draw a rectangle or polygon to restore only there)");
        }
        let mut remove = None;
        for (i, region) in r.regions.iter_mut().enumerate() {
            ui.horizontal(|ui| {
                ui.label(match region {
                    RegionSpec::Rect { width, height, .. } => format!("rect {width}x{height}"),
                    RegionSpec::Polygon { points, .. } => format!("polygon, {} corners", points.len()),
                });
                class_combo(ui, ("region bg", i), region.background_mut(), &names, "most common");
                if ui.small_button("×").clicked() {
                    remove = Some(i);
                }
            });
        }
        if let Some(i) = remove {
            r.regions.remove(i);
        }
        ui.horizontal(|ui| {
            ui.label("background");
            class_combo(ui, "background", &mut r.background, &names, "most common");
        });
    }

    fn parameters_ui(&mut self, ui: &mut egui::Ui) {
        let s = &mut self.working.settings;
        ui.heading("Restoration");
        ui.add(
            egui::Slider::new(&mut s.restore.alpha, 0.25..=16.0)
                .logarithmic(true)
                .text("alpha (stop energy)"),
        )
        .on_hover_text(
            "Contours are smoothed until no point's bending energy is above alpha (--alpha, > 0; \
             paper 1 to 8). Smaller smooths more: with scale 10 px, alpha 2 smooths bends tighter \
             than a 5 px radius.",
        );
        ui.add(egui::Slider::new(&mut s.restore.beta, 1.0..=16.0).logarithmic(true).text("beta (spacing)"))
            .on_hover_text(
                "How strongly contours keep their spacing to neighbouring contours (--beta, at least 1; \
                 paper 1.5 to 8).",
            );
        ui.horizontal(|ui| {
            let mut on = s.restore.gamma.is_some();
            if ui
                .checkbox(&mut on, "gamma")
                .on_hover_text(
                    "Restore within what the projectors can show (--gamma): no pixel may get brighter \
                     than its original class by more than the set amount.",
                )
                .changed()
            {
                s.restore.gamma = on.then_some(0.05);
            }
            if let Some(g) = &mut s.restore.gamma {
                ui.add(egui::Slider::new(g, 0.0..=1.0).text("max brightening")).on_hover_text(
                    "Largest brightening allowed, in relative luminance (a fraction, 0 to 1).",
                );
            }
        });
        ui.add(egui::Slider::new(&mut s.restore.neighbours, 1..=12).text("neighbours")).on_hover_text(
            "Contour segments on each side whose directions are averaged for the curvature \
             (--neighbours). More: the curvature is measured over a longer stretch.",
        );
        ui.add(egui::Slider::new(&mut s.restore.scale, 1.0..=40.0).text("scale px")).on_hover_text(
            "Length unit of the curvature, in pixels (--scale): a circle of radius r has curvature \
             scale / r.",
        );
        ui.horizontal(|ui| {
            let mut auto = s.restore.grid == "auto";
            if ui
                .checkbox(&mut auto, "grid auto")
                .on_hover_text(
                    "The photo is restored in a grid of cells (--grid): auto makes cells of about \
                     256 px; untick to set the cells across x down.",
                )
                .changed()
            {
                s.restore.grid = if auto { "auto".into() } else { "4x4".into() };
            }
            if !auto {
                let (mut g, mut h) = s
                    .restore
                    .grid
                    .split_once('x')
                    .map_or((4u32, 4u32), |(a, b)| (a.parse().unwrap_or(4), b.parse().unwrap_or(4)));
                ui.add(egui::DragValue::new(&mut g).range(1..=256)).on_hover_text("Grid cells across.");
                ui.label("x");
                ui.add(egui::DragValue::new(&mut h).range(1..=256)).on_hover_text("Grid cells down.");
                s.restore.grid = format!("{g}x{h}");
            }
        });
        ui.heading("Compensation");
        ui.add(
            egui::Slider::new(&mut s.compensate.e_bound_lux, 5.0..=1000.0)
                .logarithmic(true)
                .text("E_bound lux"),
        )
        .on_hover_text(
            "Most light the projectors may put on the object, in lux (--ebound-lux). CIE 157 \
             recommends at most 50 lx for light-sensitive objects.",
        );
        ui.horizontal(|ui| {
            let mut inf = s.compensate.m.is_none();
            if ui
                .checkbox(&mut inf, "m = ∞")
                .on_hover_text("m = ∞: each point is lit by its most efficient projector only (--m inf).")
                .changed()
            {
                s.compensate.m = if inf { None } else { Some(8.0) };
            }
            if let Some(m) = &mut s.compensate.m {
                ui.add(egui::Slider::new(m, 0.0..=32.0).text("m")).on_hover_text(
                    "How the projectors share each point (--m, Eq. 12): 0 shares evenly, 1 in \
                     proportion to their efficiency, larger favours the projector facing the point.",
                );
            }
        });
        ui.add(egui::Slider::new(&mut s.compensate.margin, 0.0..=0.5).text("safety margin")).on_hover_text(
            "A fraction (--margin): the light stays at or below E_bound x (1 - margin); 0.05 keeps \
             5 % under the bound.",
        );
        ui.add(egui::Slider::new(&mut s.compensate.clip_fraction, 0.0..=0.1).text("clip fraction"))
            .on_hover_text(
                "Fraction of the object's points (--clip-fraction) that may be dimmed on their own \
                 rather than darkening everything; 0.01 = 1 %.",
            );
        ui.checkbox(&mut s.compensate.auto_clip, "always let the model choose a larger fraction")
            .on_hover_text(
                "--auto-clip: compensates at 1, 2 and 5 % (never below the clip fraction) and keeps the \
             one whose modelled view is closest to the target. At a low bound the projectors' black \
             level lifts a dim object; a brighter scale with more points dimmed on their own can \
             look more like it. Takes about three times as long. Unticked, the model chooses only \
             where more than 5 % of the lit object asks for less light than the black level gives.",
            );
    }

    fn lighting_ui(&mut self, ui: &mut egui::Ui) {
        let w = &mut self.working;
        ui.heading("Relighting");
        ui.checkbox(&mut w.settings.relight.enabled, "make a relit scene");
        if !w.settings.relight.enabled {
            return;
        }
        let l = &mut w.lighting;
        let mut remove = None;
        for (i, light) in l.lights.iter_mut().enumerate() {
            if let Light::Directional { direction, colour } = light {
                let (mut az, mut el) = light_angles(*direction);
                let mut strength = colour[0];
                ui.horizontal(|ui| {
                    ui.label(format!("light {}", i + 1));
                    if ui.small_button("×").clicked() {
                        remove = Some(i);
                    }
                });
                let a =
                    ui.add(egui::Slider::new(&mut az, -180.0..=180.0).text("from (° right)")).on_hover_text(
                        "Where the light comes from, in degrees: 0 = from the camera, positive = from \
                     the right as the camera sees it.",
                    );
                let e = ui
                    .add(egui::Slider::new(&mut el, -89.0..=89.0).text("height (°)"))
                    .on_hover_text("How high the light is above the camera's horizon, in degrees.");
                let s = ui
                    .add(egui::Slider::new(&mut strength, 0.0..=3.0).text("strength"))
                    .on_hover_text("Strength of this white light (1 = unit strength).");
                if a.changed() || e.changed() || s.changed() {
                    *light = directional(az, el, strength);
                }
            } else {
                ui.label(format!("light {}: a point light (edit relight/lighting.toml)", i + 1));
            }
        }
        if let Some(i) = remove {
            l.lights.remove(i);
        }
        if ui.button("add light").clicked() {
            l.lights.push(directional(30.0, 30.0, 0.5));
        }
        ui.add(egui::Slider::new(&mut l.ambient, 0.0..=1.0).text("ambient")).on_hover_text(
            "Light reaching every point whatever way it faces (keeps shadowed sides visible).",
        );
        ui.add(egui::Slider::new(&mut l.specular, 0.0..=1.0).text("specular"))
            .on_hover_text("Strength of the shiny highlight (0 = matte).");
        ui.add(egui::Slider::new(&mut l.shininess, 1.0..=200.0).logarithmic(true).text("shininess"))
            .on_hover_text(
                "Sharpness of the highlight (Blinn-Phong exponent): larger is smaller and sharper.",
            );
        ui.add(egui::Slider::new(&mut l.exposure, 0.1..=4.0).logarithmic(true).text("exposure"))
            .on_hover_text(
                "Overall gain after lighting (a multiplier), so the brightest lit colours stay near full.",
            );
        ui.add(egui::Slider::new(&mut w.settings.relight.noise, 0.0..=1.0).text("material noise"))
            .on_hover_text(
                "How much of the photo's fine material noise is put back into the relit picture \
                 (--noise, 0 to 1; 0 = none).",
            );
    }

    fn figures_ui(&mut self, ui: &mut egui::Ui) {
        ui.heading("Light");
        if self.project.paths.stage.is_none() {
            ui.weak("no stage model: calibrate the stage to compensate");
            return;
        }
        ui.weak(format!("stage model: {}", self.project.paths.stage_note));
        egui::Grid::new("figures").num_columns(3).show(ui, |ui| {
            for s in Scene::ALL {
                if let Some(f) = self.jobs.figures.get(&s) {
                    let name = ui.label(s.id());
                    if let Some(note) = &f.clip_note {
                        name.on_hover_text(note);
                    }
                    ui.label(format!("peak {:.1} lx", f.peak_lux));
                    ui.label(format!("≤ {:.1} lx", f.limit_lux));
                    ui.end_row();
                }
            }
        });
    }
}

/// What to do first, from what keeps the steps from running (`Project::can_run`): no
/// classes, a class without picks, else steps with no output yet (`missing`). None when
/// nothing is lacking.
pub(super) fn first_step(small: &Small, missing: Steps) -> Option<String> {
    let colours = &small.picks.colours;
    if colours.is_empty() {
        return Some(
            "Start here: press \"add class\" (one per paint colour), then click a few pixels of \
             that colour on the photo. The steps then run by themselves."
                .into(),
        );
    }
    if let Some(c) = colours.iter().find(|c| c.pixels.is_empty() && c.rects.is_empty()) {
        return Some(format!(
            "Next: pick a few pixels of '{}': select it below (the square after its colour), choose \
             the pick tool and click on the photo.",
            c.name
        ));
    }
    if !missing.is_empty() {
        let names: Vec<&str> = missing.iter().map(|s| s.name()).collect();
        return Some(format!("Not computed yet: {}.", names.join(", ")));
    }
    None
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

/// A class chooser with a "none" entry.
fn class_combo(
    ui: &mut egui::Ui,
    id: impl std::hash::Hash + std::fmt::Debug,
    value: &mut Option<u8>,
    names: &[String],
    none: &str,
) {
    let text = value.and_then(|k| names.get(k as usize).cloned()).unwrap_or_else(|| none.to_string());
    egui::ComboBox::from_id_salt(id).selected_text(text).show_ui(ui, |ui| {
        ui.selectable_value(value, None, none);
        for (k, n) in names.iter().enumerate() {
            ui.selectable_value(value, Some(k as u8), n);
        }
    });
}

#[cfg(test)]
mod tests {
    use restage_authoring::relight::Lighting;

    use super::first_step;
    use crate::gui::doc::{Settings, Small, Step, Steps, empty_picks, new_class};

    #[test]
    fn the_first_step_follows_what_the_project_lacks() {
        let mut small = Small {
            settings: Settings::default(),
            picks: empty_picks(),
            lighting: Lighting::default(),
            outline: Default::default(),
        };
        let all = Steps::from_iter(Step::ALL);
        assert!(first_step(&small, all).unwrap().contains("add class"));
        let c = new_class(&small.picks);
        small.picks.colours.push(c);
        let hint = first_step(&small, all).unwrap();
        assert!(hint.contains("'colour 1'") && hint.contains("pick tool"), "{hint}");
        small.picks.colours[0].pixels.push([3, 4]);
        let hint = first_step(&small, Steps::from_iter([Step::Restore, Step::Relight])).unwrap();
        assert!(hint.contains("restore, relight"), "{hint}");
        assert_eq!(first_step(&small, Steps::NONE), None);
    }
}
