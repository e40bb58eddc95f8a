//! The windows over the canvas: the offer to run the steps with no output yet, the problems
//! found reading the project, and the bundle export.

use eframe::egui::{self, Color32};

use super::App;
use crate::gui::doc::{Scene, Steps};
use crate::gui::export;
use crate::gui::project::Problem;

pub(super) struct Dialogs {
    /// Steps with no output yet, offered to run until answered.
    pub(super) offer_missing: Steps,
    /// Files that could not be read when the project was opened.
    pub(super) problems: Vec<Problem>,
    pub(super) export_open: bool,
    /// The last export's report, or why it failed.
    pub(super) export_result: Option<Result<String, String>>,
}

impl Dialogs {
    pub(super) fn new(problems: Vec<Problem>) -> Self {
        Self { offer_missing: Steps::NONE, problems, export_open: false, export_result: None }
    }
}

impl App {
    pub(super) fn windows(&mut self, ctx: &egui::Context) {
        if !self.dialogs.offer_missing.is_empty() {
            let names: Vec<&str> = self.dialogs.offer_missing.iter().map(|s| s.name()).collect();
            let mut run = false;
            let m = egui::Modal::new(egui::Id::unique("missing")).show(ctx, |ui| {
                ui.heading("Steps to run");
                ui.label(format!("This project has no output yet for: {}.", names.join(", ")));
                ui.horizontal(|ui| {
                    if ui.button("Run them").clicked() {
                        run = true;
                        ui.close();
                    }
                    if ui.button("Not now").clicked() {
                        ui.close();
                    }
                });
            });
            if run {
                let steps = self.dialogs.offer_missing.with_dependents();
                self.submit(steps, None);
            }
            if run || m.should_close() {
                self.dialogs.offer_missing = Steps::NONE;
            }
        }
        if !self.dialogs.problems.is_empty() || !self.jobs.unreadable.is_empty() {
            let mut open = true;
            egui::Window::new("Problems").open(&mut open).default_width(420.0).show(ctx, |ui| {
                for p in &self.dialogs.problems {
                    ui.label(format!("{}: {}", p.path.display(), p.message));
                }
                let mut rerun = None;
                for (step, msg) in &self.jobs.unreadable {
                    ui.horizontal_wrapped(|ui| {
                        ui.label(msg);
                        if ui.button(format!("re-run {}", step.name())).clicked() {
                            rerun = Some(*step);
                        }
                    });
                }
                if let Some(s) = rerun {
                    self.submit(Steps::from_iter([s]).with_dependents(), None);
                }
            });
            if !open {
                self.dialogs.problems.clear();
                self.jobs.unreadable.clear();
            }
        }
        if self.dialogs.export_open {
            let mut open = true;
            egui::Window::new("Export bundle")
                .open(&mut open)
                .default_width(480.0)
                .show(ctx, |ui| self.export_ui(ui));
            self.dialogs.export_open = open;
        }
    }

    fn export_ui(&mut self, ui: &mut egui::Ui) {
        let e = &mut self.working.settings.export;
        egui::Grid::new("export").num_columns(2).show(ui, |ui| {
            ui.label("object id");
            ui.text_edit_singleline(&mut e.object_id);
            ui.end_row();
            ui.label("object name");
            ui.text_edit_singleline(&mut e.object_name);
            ui.end_row();
            ui.label("bundle version");
            ui.add(egui::DragValue::new(&mut e.version).range(1..=u64::MAX)).on_hover_text(
                "The bundle's version number; each new bundle of an object needs a higher one.",
            );
            ui.end_row();
            ui.label("valid for (days)");
            ui.add(egui::DragValue::new(&mut e.valid_days).range(1..=3650))
                .on_hover_text("Days from today until the bundle expires.");
            ui.end_row();
            ui.label("signing key");
            ui.text_edit_singleline(&mut e.key);
            ui.end_row();
            ui.label("trusted keys");
            ui.text_edit_singleline(&mut e.trust);
            ui.end_row();
            ui.label("bundle file");
            ui.text_edit_singleline(&mut e.out);
            ui.end_row();
            ui.label("sensitivity (CIE 157)");
            egui::ComboBox::from_id_salt("class").selected_text(e.policy_class.clone()).show_ui(ui, |ui| {
                for c in ["high", "medium", "low"] {
                    ui.selectable_value(&mut e.policy_class, c.to_string(), c);
                }
            });
            ui.end_row();
            ui.label("longest showing (s)");
            opt_drag(
                ui,
                &mut e.max_showing_s,
                60,
                1..=3600,
                "Longest a scene may be shown at a time, in seconds.",
            );
            ui.end_row();
            ui.label("dark between (s)");
            opt_drag(
                ui,
                &mut e.cooldown_s,
                30,
                0..=3600,
                "How long the object rests dark between showings, in seconds.",
            );
            ui.end_row();
        });
        if ui.button("make a new key").clicked() {
            match crate::gui::project::new_key(
                &self.project,
                &format!("key-{}", crate::steps::now_unix_s().unwrap_or(0)),
            ) {
                Ok((k, t)) => {
                    e.key = k;
                    e.trust = t;
                }
                Err(err) => self.dialogs.export_result = Some(Err(format!("{err:#}"))),
            }
        }
        ui.label("scenes:");
        for s in Scene::ALL {
            let mut on = e.scenes.contains(&s);
            let peak = self.jobs.figures.get(&s).map_or("not compensated".to_string(), |f| {
                format!("peak {:.1} lx of {:.1} lx allowed", f.peak_lux, f.limit_lux)
            });
            if ui.checkbox(&mut on, format!("{} — {peak}", s.title())).changed() {
                e.scenes.retain(|x| *x != s);
                if on {
                    e.scenes.push(s);
                    e.scenes.sort_by_key(|x| Scene::ALL.iter().position(|y| y == x));
                }
            }
        }
        let peak = export::peak_of(&e.scenes, &self.jobs.figures);
        match export::policy_summary(e, peak) {
            Ok(s) => ui.label(s),
            Err(err) => ui.colored_label(Color32::from_rgb(255, 120, 100), format!("{err:#}")),
        };
        let ready = self.jobs.running.is_none();
        if ui.add_enabled(ready, egui::Button::new("Write and verify the bundle")).clicked() {
            self.commit_working();
            self.dialogs.export_result = Some(
                export::write_and_verify(&self.project, &self.doc.small.settings)
                    .map_err(|e| format!("{e:#}")),
            );
        }
        match &self.dialogs.export_result {
            Some(Ok(text)) => {
                ui.monospace(text);
            }
            Some(Err(text)) => {
                ui.colored_label(Color32::from_rgb(255, 120, 100), text);
            }
            None => {}
        }
    }
}

/// An optional number: a checkbox for "preset", a drag value otherwise.
fn opt_drag(
    ui: &mut egui::Ui,
    value: &mut Option<u32>,
    default: u32,
    range: std::ops::RangeInclusive<u32>,
    tip: &str,
) {
    ui.horizontal(|ui| {
        let mut set = value.is_some();
        if ui.checkbox(&mut set, "").on_hover_text("Untick to use the sensitivity class's preset.").changed()
        {
            *value = set.then_some(default);
        }
        match value {
            Some(v) => {
                ui.add(egui::DragValue::new(v).range(range)).on_hover_text(tip);
            }
            None => {
                ui.weak("class preset");
            }
        }
    });
}
