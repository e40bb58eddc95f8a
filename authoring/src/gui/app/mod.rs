//! The window of `restage-author gui` (eframe: winit + wgpu + egui). It draws and edits; the
//! worker thread (`jobs`) computes. Pictures are GPU textures drawn through one pan/zoom
//! transform (`views`), so a 10 MP photo pans at the display's frame rate. Widgets edit a
//! working copy of the document, committed to the undo history once a drag or text edit
//! ends, so one slider drag is one undo step and one recomputation.
//!
//! Here: opening the window, `App` and its frame loop, undo/redo and saving. The rest by
//! concern: `panels` (top bar, status line, side panel), `windows` (the dialogs), `canvas`
//! (the picture and its view), `tools` (what the pointer does on it), `textures` (pictures
//! on the GPU), `background` (requests to the worker and its messages), `script` (the
//! scripted screenshot and benchmark sessions).

mod background;
mod canvas;
mod panels;
mod script;
mod textures;
mod tools;
mod windows;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use eframe::egui::{self, Color32};
use eframe::{egui_wgpu, wgpu};

use super::GuiArgs;
use super::doc::{Doc, Small, Steps};
use super::gpu::Pictures;
use super::jobs::Worker;
use super::project::{Opened, Project};
use background::JobState;
use canvas::ViewState;
use script::Script;
use textures::Textures;
use tools::ToolState;
use windows::Dialogs;

/// Opens the window on a project; returns when it is closed.
pub fn run_window(opened: Opened, args: &GuiArgs) -> Result<()> {
    let title = format!("restage — {}", opened.project.dir.display());
    let mut options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(title)
            .with_inner_size([args.window.0[0] as f32, args.window.0[1] as f32])
            .with_min_inner_size([640.0, 400.0]),
        ..Default::default()
    };
    let mut setup = egui_wgpu::WgpuSetupCreateNew::without_display_handle();
    setup.instance_descriptor.backends =
        wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
    // Use the adapter's own texture limit (egui asks for 8192 by default): large photos stay one texture.
    setup.device_descriptor = Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("restage gui"),
        required_limits: wgpu::Limits {
            max_texture_dimension_2d: adapter.limits().max_texture_dimension_2d,
            ..wgpu::Limits::default()
        },
        ..Default::default()
    });
    options.wgpu_options.wgpu_setup = setup.into();
    // Where a scripted session leaves what went wrong: the window closes, then this returns it.
    let failure: Arc<Mutex<Option<String>>> = Arc::default();
    let script = match (&args.screenshots, &args.bench) {
        (Some(dir), _) => Some(Script::screenshots(dir.clone(), failure.clone())),
        (None, Some(json)) => Some(Script::bench(json.clone(), failure.clone())),
        _ => None,
    };
    let run_missing = args.run_missing || script.is_some();
    let result = eframe::run_native(
        "restage",
        options,
        Box::new(move |cc| {
            cc.egui_ctx.set_visuals(egui::Visuals::dark());
            cc.egui_ctx.all_styles_mut(square_corners);
            let rs = cc.wgpu_render_state.as_ref().context("eframe started without its wgpu renderer")?;
            Ok(Box::new(App::new(&cc.egui_ctx, Pictures::for_window(rs), opened, run_missing, script)))
        }),
    );
    if let Some(f) = failure.lock().expect("not poisoned").take() {
        return Err(anyhow!(f));
    }
    result.map_err(|e| match e {
        eframe::Error::Wgpu(w) => anyhow!(
            "no graphics adapter for the window ({w}). Install a Vulkan driver (with no GPU, Mesa's \
             software lavapipe: apt-get install mesa-vulkan-drivers); the steps also run without a \
             window: restage-author gui DIR --no-window --run-missing"
        ),
        other => {
            anyhow!("cannot open the window ({other}); is there a display (DISPLAY or WAYLAND_DISPLAY)?")
        }
    })
}

struct App {
    project: Project,
    doc: Doc,
    /// What the widgets edit; committed to `doc` when no drag or text edit is in progress.
    working: Small,
    textures: Textures,
    view: ViewState,
    tools: ToolState,
    jobs: JobState,
    dialogs: Dialogs,
    frames: FrameStats,
    script: Option<Script>,
}

/// Recent frame times, for the status line and the debug log.
#[derive(Default)]
struct FrameStats {
    /// The last 120 frames' times, seconds.
    times: Vec<f32>,
    drawn: u64,
    last: Option<Instant>,
    /// The previous frame's CPU time in egui (eframe's measure), seconds.
    last_cpu: Option<f32>,
}

impl FrameStats {
    /// Counts a frame begun at `now`. Every 100th frame: the recent frames' median time
    /// (seconds) and how many they are.
    fn record(&mut self, now: Instant) -> Option<(f32, usize)> {
        let mut due = None;
        if let Some(last) = self.last {
            self.times.push((now - last).as_secs_f32());
            if self.times.len() > 120 {
                self.times.remove(0);
            }
            self.drawn += 1;
            if self.drawn.is_multiple_of(100) {
                let mut recent = self.times.clone();
                recent.sort_by(f32::total_cmp);
                due = Some((recent[recent.len() / 2], recent.len()));
            }
        }
        self.last = Some(now);
        due
    }

    /// The recent frames' mean time, seconds.
    fn mean(&self) -> Option<f32> {
        (!self.times.is_empty()).then(|| self.times.iter().sum::<f32>() / self.times.len() as f32)
    }
}

impl App {
    fn new(
        ctx: &egui::Context,
        pictures: Pictures,
        opened: Opened,
        run_missing: bool,
        script: Option<Script>,
    ) -> Self {
        let Opened { project, small, hints, problems } = opened;
        let missing = project.missing_steps(&small);
        let wake_ctx = ctx.clone();
        let worker = Worker::start(project.clone(), move || wake_ctx.request_repaint());
        let mut app = Self {
            project,
            working: small.clone(),
            doc: Doc::new(small, hints),
            textures: Textures::new(pictures),
            view: ViewState::default(),
            tools: ToolState::default(),
            jobs: JobState::new(worker),
            dialogs: Dialogs::new(problems),
            frames: FrameStats::default(),
            script,
        };
        if !missing.is_empty() {
            if run_missing {
                app.submit(missing.with_dependents(), None);
            } else {
                app.dialogs.offer_missing = missing;
            }
        }
        app.refresh_colours();
        app.textures.refresh_overlay(&app.doc.hints, None);
        app
    }

    fn size(&self) -> [u32; 2] {
        [self.project.photo_size.0, self.project.photo_size.1]
    }

    /// The photo's pixels on screen (for a restoration to do first).
    fn visible(&self) -> Option<[u32; 4]> {
        self.view.transform.and_then(|t| t.visible(self.size(), self.view.view_size))
    }

    /// Puts the working copy into the document (one undo step) and recomputes what it staled.
    fn commit_working(&mut self) {
        if self.working == self.doc.small {
            return;
        }
        let w = self.working.clone();
        let stale = self.doc.edit(|s| *s = w);
        self.refresh_colours();
        let visible = self.visible();
        self.submit(stale, visible);
    }

    fn after_history(&mut self, stale: Steps) {
        self.working = self.doc.small.clone();
        self.refresh_colours();
        self.textures.refresh_overlay(&self.doc.hints, None);
        let visible = self.visible();
        self.submit(stale, visible);
    }

    fn undo(&mut self) {
        let stale = self.doc.undo();
        self.after_history(stale);
    }

    fn redo(&mut self) {
        let stale = self.doc.redo();
        self.after_history(stale);
    }

    /// Re-reads the classes' display colours (after picks or the palette changed).
    fn refresh_colours(&mut self) {
        self.textures.colours = self.project.class_colours(&self.doc.small.picks);
    }

    fn save(&mut self) {
        match self.project.save(&self.doc.small, &self.doc.hints) {
            Ok(()) => self.jobs.log(format!("saved {}", self.project.dir.display())),
            Err(e) => self.jobs.log(format!("saving failed: {e:#}")),
        }
    }

    fn scripted(&self) -> bool {
        self.script.is_some()
    }

    fn shortcuts(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        if ctx.input_mut(|i| i.consume_shortcut(&REDO) || i.consume_shortcut(&REDO_Y)) {
            self.redo();
        } else if ctx.input_mut(|i| i.consume_shortcut(&UNDO)) {
            self.undo();
        }
        if ctx.input_mut(|i| i.consume_shortcut(&SAVE)) {
            self.save();
        }
        if ctx.input(|i| i.key_pressed(egui::Key::Escape)) {
            self.tools.polygon.clear();
        }
        if ctx.input(|i| i.key_pressed(egui::Key::Enter)) {
            self.close_polygon();
        }
        if ctx.input(|i| i.key_pressed(egui::Key::Backspace)) {
            self.tools.polygon.pop();
        }
    }
}

impl eframe::App for App {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        // The panels' colour: the panels are drawn unfilled (see `panel_frame`).
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.frames.last_cpu = frame.info().cpu_usage;
        let ctx = ui.ctx().clone();
        if let Some((median, n)) = self.frames.record(Instant::now()) {
            tracing::debug!(
                "frame time median {:.1} ms over the last {n}, running {:?}, views {}",
                median * 1e3,
                self.jobs.running.as_ref().and_then(|r| r.step),
                self.textures.views.len()
            );
        }
        self.textures.gpu.begin_frame();
        self.poll_worker();
        self.shortcuts(&ctx);

        egui::Panel::top("top").frame(panel_frame(ui)).show(ui, |ui| self.top_bar(ui));
        egui::Panel::bottom("status").frame(panel_frame(ui)).show(ui, |ui| self.status_bar(ui));
        egui::Panel::left("tools").frame(panel_frame(ui)).resizable(true).default_size(300.0).show(
            ui,
            |ui| {
                // A solid, always shown scroll bar: egui's floating one appears only on hover, so
                // a panel taller than the window looked cut off rather than scrollable.
                ui.style_mut().spacing.scroll = egui::style::ScrollStyle::solid();
                egui::ScrollArea::vertical()
                    .auto_shrink([false, false])
                    .scroll_bar_visibility(egui::scroll_area::ScrollBarVisibility::AlwaysVisible)
                    .show(ui, |ui| self.side_panel(ui));
            },
        );
        egui::CentralPanel::default()
            // No fill: the clear colour is the background.
            .frame(egui::Frame::NONE)
            .show(ui, |ui| self.canvas(ui));
        self.windows(&ctx);

        // Commit the working copy once nothing is being dragged or typed.
        let busy = ctx.dragged_id().is_some()
            || ctx.egui_wants_keyboard_input()
            || ctx.input(|i| i.pointer.any_down());
        if !busy {
            self.commit_working();
        }
        if self.jobs.running.is_some() {
            // The elapsed time on the progress line; progress itself wakes the window. No
            // faster: on a software rasteriser every idle frame is time taken from the step.
            ctx.request_repaint_after(Duration::from_millis(250));
        }
        self.drive_script(&ctx);
    }
}

/// Square widgets and windows: every rounded corner is a fan of small triangles, and a software
/// rasteriser sets each up on its own (the side panel's corners were a fifth of a frame).
fn square_corners(style: &mut egui::Style) {
    let v = &mut style.visuals;
    for w in [
        &mut v.widgets.noninteractive,
        &mut v.widgets.inactive,
        &mut v.widgets.hovered,
        &mut v.widgets.active,
        &mut v.widgets.open,
    ] {
        w.corner_radius = egui::CornerRadius::ZERO;
    }
    v.window_corner_radius = egui::CornerRadius::ZERO;
    v.menu_corner_radius = egui::CornerRadius::ZERO;
}

/// A side or top panel's frame without its fill: the clear colour is the panel colour. Each
/// pixel egui fills goes through its general shader, which a software rasteriser (lavapipe)
/// pays for: the three panels' fills were about a quarter of a 1280x800 frame.
fn panel_frame(ui: &egui::Ui) -> egui::Frame {
    egui::Frame::side_top_panel(ui.style()).fill(Color32::TRANSPARENT)
}

const UNDO: egui::KeyboardShortcut = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::Z);
const REDO: egui::KeyboardShortcut =
    egui::KeyboardShortcut::new(egui::Modifiers::COMMAND.plus(egui::Modifiers::SHIFT), egui::Key::Z);
const REDO_Y: egui::KeyboardShortcut = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::Y);
const SAVE: egui::KeyboardShortcut = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::S);
