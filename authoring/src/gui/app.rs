//! The window of `restage-author gui` (eframe: winit + wgpu + egui). It draws and edits; the
//! worker thread (`jobs`) computes. Pictures are GPU textures drawn through one pan/zoom
//! transform (`views`), so a 10 MP photo pans at the display's frame rate. Widgets edit a
//! working copy of the document, committed to the undo history once a drag or text edit
//! ends, so one slider drag is one undo step and one recomputation.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use eframe::egui::{self, Color32, ColorImage, Pos2, Rect, Sense, Stroke};
use eframe::{egui_wgpu, wgpu};
use image::RgbaImage;
use restage_authoring::classify::PickRect;
use restage_authoring::relight::Light;

use super::GuiArgs;
use super::doc::SceneFigures;
use super::doc::{
    Doc, HintDiff, NO_HINT, RegionSpec, Scene, Small, Step, Steps, directional, light_angles, new_class,
};
use super::gpu::{GpuImage, Pictures, TileMask};
use super::jobs::{Msg, Request, Worker};
use super::project::{Opened, Problem, Project};
use super::views::{ViewKind, ViewTransform};

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
    let script = match (&args.screenshots, &args.bench) {
        (Some(dir), _) => Some(Script::screenshots(dir.clone())),
        (None, Some(json)) => Some(Script::bench(json.clone())),
        _ => None,
    };
    let run_missing = args.run_missing || script.is_some();
    let failure: Arc<Mutex<Option<String>>> = Arc::default();
    let fail = failure.clone();
    let result = eframe::run_native(
        "restage",
        options,
        Box::new(move |cc| {
            cc.egui_ctx.set_visuals(egui::Visuals::dark());
            cc.egui_ctx.all_styles_mut(square_corners);
            let rs = cc.wgpu_render_state.as_ref().context("eframe started without its wgpu renderer")?;
            Ok(Box::new(App::new(&cc.egui_ctx, Pictures::for_window(rs), opened, run_missing, script, fail)))
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Tool {
    Pan,
    Pick,
    RegionRect,
    RegionPolygon,
    Hint,
    Erase,
}

/// Which picture is in the central area.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Shown {
    One(ViewKind),
    /// Photo on the left of the divider, `after` on the right.
    BeforeAfter,
}

/// Tiles of the hint overlay this large are drawn or skipped whole.
const OVERLAY_TILE: u32 = 128;

/// The hint strokes' overlay: a picture mostly transparent, drawn where it holds strokes.
struct Overlay {
    image: GpuImage,
    tiles: TileMask,
}

struct Texture {
    image: GpuImage,
    /// The photo's size (the picture covers it; its texture may be smaller, see `set_texture`).
    size: [u32; 2],
}

/// A scripted session (screenshots for the tests, or the benchmark).
struct Script {
    kind: ScriptKind,
    step: usize,
    frames_in_step: u32,
    started: Instant,
}

enum ScriptKind {
    Screenshots { dir: PathBuf, shot: Arc<Mutex<Option<Arc<ColorImage>>>>, waiting: bool },
    Bench(Bench),
}

/// The benchmark: pan the 1:1 photo, then a hint stroke while still panning, then a second
/// stroke with the view held still, then (with a stage model) a lower E_bound while panning.
#[derive(Default)]
struct Bench {
    out: PathBuf,
    frame_ms: Vec<f64>,
    /// Frame times while the first stroke's steps run in the background (still panning).
    busy_ms: Vec<f64>,
    /// CPU time of each idle panning frame (egui's share of the frame time).
    cpu_ms: Vec<f64>,
    /// Frame times while the three compensations after an E_bound change run (panning).
    compensating_ms: Vec<f64>,
    last: Option<Instant>,
    strokes: Vec<StrokeTiming>,
}

/// From a hint stroke to its visible region's and its whole restoration on screen.
struct StrokeTiming {
    at: Instant,
    panning: bool,
    partial_ms: Option<f64>,
    partial_px: u64,
    full_ms: Option<f64>,
}

impl StrokeTiming {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "while_panning": self.panning,
            "hint_to_visible_region_ms": self.partial_ms,
            "visible_region_px": self.partial_px,
            "hint_to_whole_restoration_ms": self.full_ms,
        })
    }
}

/// The views shown in a screenshot session, in order.
fn screenshot_views() -> Vec<Shown> {
    vec![
        Shown::One(ViewKind::Photo),
        Shown::One(ViewKind::Classes),
        Shown::One(ViewKind::ClassesFalse),
        Shown::One(ViewKind::Restored),
        Shown::One(ViewKind::Relit),
        Shown::One(ViewKind::Visitor(Scene::Restored)),
        Shown::One(ViewKind::Irradiance(Scene::Restored)),
        Shown::BeforeAfter,
    ]
}

impl Script {
    fn screenshots(dir: PathBuf) -> Self {
        Self {
            kind: ScriptKind::Screenshots { dir, shot: Arc::default(), waiting: false },
            step: 0,
            frames_in_step: 0,
            started: Instant::now(),
        }
    }

    fn bench(out: PathBuf) -> Self {
        Self {
            kind: ScriptKind::Bench(Bench { out, ..Default::default() }),
            step: 0,
            frames_in_step: 0,
            started: Instant::now(),
        }
    }
}

struct Running {
    generation: u64,
    done: usize,
    total: usize,
    step: Option<Step>,
    started: Instant,
}

struct App {
    project: Project,
    doc: Doc,
    /// What the widgets edit; committed to `doc` when no drag or text edit is in progress.
    working: Small,
    worker: Worker,
    generation: u64,
    running: Option<Running>,
    pictures: Pictures,
    textures: HashMap<ViewKind, Texture>,
    /// The classes' display colours (palette or picks), cached: reading them touches files.
    colours: Vec<[u8; 3]>,
    hint_tex: Option<Overlay>,
    shown: Shown,
    after: ViewKind,
    split: f32,
    transform: Option<ViewTransform>,
    view_size: [f32; 2],
    tool: Tool,
    class: usize,
    brush: f32,
    show_hints: bool,
    stroke: Option<(HintDiff, [f64; 2])>,
    drag_from: Option<[f32; 2]>,
    polygon: Vec<[f64; 2]>,
    figures: HashMap<Scene, SceneFigures>,
    problems: Vec<Problem>,
    failed: Option<(Option<Step>, String)>,
    unreadable: Vec<(Step, String)>,
    log: Vec<String>,
    offer_missing: Steps,
    export_open: bool,
    export_result: Option<Result<String, String>>,
    frame_times: Vec<f32>,
    frames_drawn: u64,
    last_frame: Option<Instant>,
    /// The previous frame's CPU time in egui (eframe's measure), seconds.
    last_cpu: Option<f32>,
    script: Option<Script>,
    failure: Arc<Mutex<Option<String>>>,
}

impl App {
    fn new(
        ctx: &egui::Context,
        pictures: Pictures,
        opened: Opened,
        run_missing: bool,
        script: Option<Script>,
        failure: Arc<Mutex<Option<String>>>,
    ) -> Self {
        let Opened { project, small, hints, problems } = opened;
        let missing = project.missing_steps(&small);
        let wake_ctx = ctx.clone();
        let worker = Worker::start(project.clone(), move || wake_ctx.request_repaint());
        let mut app = Self {
            project,
            working: small.clone(),
            doc: Doc::new(small, hints),
            worker,
            generation: 0,
            running: None,
            pictures,
            textures: HashMap::new(),
            colours: Vec::new(),
            hint_tex: None,
            shown: Shown::One(ViewKind::Photo),
            after: ViewKind::Restored,
            split: 0.5,
            transform: None,
            view_size: [1.0, 1.0],
            tool: Tool::Pan,
            class: 0,
            brush: 4.0,
            show_hints: true,
            stroke: None,
            drag_from: None,
            polygon: Vec::new(),
            figures: HashMap::new(),
            problems,
            failed: None,
            unreadable: Vec::new(),
            log: Vec::new(),
            offer_missing: Steps::NONE,
            export_open: false,
            export_result: None,
            frame_times: Vec::new(),
            frames_drawn: 0,
            last_frame: None,
            last_cpu: None,
            script,
            failure,
        };
        if !missing.is_empty() {
            if run_missing {
                app.submit(missing.with_dependents(), None);
            } else {
                app.offer_missing = missing;
            }
        }
        app.refresh_colours();
        app.refresh_hint_texture(None);
        app
    }

    fn size(&self) -> [u32; 2] {
        [self.project.photo_size.0, self.project.photo_size.1]
    }

    fn submit(&mut self, steps: Steps, visible: Option<[u32; 4]>) {
        if steps.is_empty() {
            return;
        }
        self.generation += 1;
        self.failed = None;
        self.worker.submit(Request {
            generation: self.generation,
            steps,
            small: self.doc.small.clone(),
            hints: Arc::new(self.doc.hints.clone()),
            visible,
        });
        self.running = Some(Running {
            generation: self.generation,
            done: 0,
            total: steps.len(),
            step: None,
            started: Instant::now(),
        });
    }

    fn visible(&self) -> Option<[u32; 4]> {
        self.transform.and_then(|t| t.visible(self.size(), self.view_size))
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
        self.refresh_hint_texture(None);
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

    fn class_colours(&self) -> Vec<[u8; 3]> {
        self.colours.clone()
    }

    /// Re-reads the classes' display colours (after picks or the palette changed).
    fn refresh_colours(&mut self) {
        self.colours = self.project.class_colours(&self.doc.small.picks);
    }

    /// Re-uploads the hint overlay (all of it, or the pixels `rect`).
    fn refresh_hint_texture(&mut self, rect: Option<[u32; 4]>) {
        let colours = self.class_colours();
        let h = &self.doc.hints;
        let [x, y, w, hh] = rect.unwrap_or([0, 0, h.width, h.height]);
        if w == 0 || hh == 0 {
            return;
        }
        // Premultiplied, so that mip levels average colour and coverage together.
        let mut rgba = Vec::with_capacity((w * hh * 4) as usize);
        for row in y..y + hh {
            for col in x..x + w {
                let l = h.labels[(row * h.width + col) as usize];
                rgba.extend(match colours.get(l as usize) {
                    Some(c) if l != NO_HINT => {
                        Color32::from_rgba_unmultiplied(c[0], c[1], c[2], 170).to_array()
                    }
                    _ => [0; 4],
                });
            }
        }
        let filled = |px: u32, py: u32| h.labels[(py * h.width + px) as usize] != NO_HINT;
        match (&mut self.hint_tex, rect) {
            (Some(o), Some(r)) => {
                self.pictures.update(&o.image, r, &rgba);
                o.tiles.update(r, filled);
            }
            _ if w > self.pictures.max_side || hh > self.pictures.max_side => {
                self.hint_tex = None;
                tracing::warn!(
                    "the hint overlay is not shown: the photo is larger than the adapter's textures"
                );
            }
            _ => {
                let mut tiles = TileMask::new([w, hh], OVERLAY_TILE);
                tiles.update([0, 0, w, hh], filled);
                self.hint_tex = Some(Overlay { image: self.pictures.image([w, hh], &rgba), tiles });
            }
        }
    }

    fn set_texture(&mut self, view: ViewKind, img: &RgbaImage) {
        let max = self.pictures.max_side;
        let scaled;
        let img = if img.width() > max || img.height() > max {
            // Larger than the adapter can hold in one texture: shown downscaled.
            let f = max as f32 / img.width().max(img.height()) as f32;
            scaled = image::imageops::resize(
                img,
                ((img.width() as f32 * f) as u32).max(1),
                ((img.height() as f32 * f) as u32).max(1),
                image::imageops::FilterType::Triangle,
            );
            &scaled
        } else {
            img
        };
        let size = [self.project.photo_size.0, self.project.photo_size.1];
        let dims = [img.width(), img.height()];
        match self.textures.get(&view) {
            Some(t) if t.image.size == dims => {
                self.pictures.update(&t.image, [0, 0, dims[0], dims[1]], img.as_raw())
            }
            _ => {
                let image = self.pictures.image(dims, img.as_raw());
                self.textures.insert(view, Texture { image, size });
            }
        }
    }

    fn poll_worker(&mut self) {
        while let Ok(m) = self.worker.messages.try_recv() {
            match m {
                Msg::Progress { generation, done, total, step } => {
                    if let Some(r) = self.running.as_mut().filter(|r| r.generation <= generation) {
                        r.generation = generation;
                        r.done = done;
                        r.total = total;
                        r.step = Some(step);
                    }
                }
                // A visible-region result of a superseded request would draw an old picture.
                Msg::Partial { generation, .. } if generation != self.generation => {}
                Msg::Partial { rect, image, seconds, .. } => {
                    // (A picture shown downscaled waits for the whole result.)
                    if let Some(t) = self.textures.get(&ViewKind::Restored)
                        && t.image.size == t.size
                    {
                        self.pictures.update(&t.image, rect, image.as_raw());
                    }
                    self.log(format!("visible region restored first in {seconds:.2} s"));
                    if let Some(Script { kind: ScriptKind::Bench(b), .. }) = &mut self.script
                        && let Some(s) = b.strokes.last_mut()
                        && s.partial_ms.is_none()
                    {
                        s.partial_ms = Some(s.at.elapsed().as_secs_f64() * 1e3);
                        s.partial_px = rect[2] as u64 * rect[3] as u64;
                    }
                }
                Msg::Image { view, image } => {
                    self.set_texture(view, &image);
                    if view == ViewKind::Classes {
                        // The palette may bring new display colours for the hint overlay.
                        self.refresh_colours();
                        self.refresh_hint_texture(None);
                    }
                }
                Msg::Figures { scene, figures } => {
                    self.figures.insert(scene, figures);
                }
                Msg::StepDone { generation, step, seconds } => {
                    self.unreadable.retain(|(s, _)| *s != step);
                    self.log(format!("{} done in {seconds:.2} s", step.name()));
                    if step == Step::Restore
                        && generation == self.generation
                        && let Some(Script { kind: ScriptKind::Bench(b), .. }) = &mut self.script
                        && let Some(s) = b.strokes.last_mut()
                        && s.full_ms.is_none()
                    {
                        s.full_ms = Some(s.at.elapsed().as_secs_f64() * 1e3);
                    }
                }
                Msg::Done { generation, seconds } => {
                    if self.running.as_ref().is_some_and(|r| r.generation <= generation)
                        && generation == self.generation
                    {
                        self.running = None;
                    }
                    self.log(format!("up to date ({seconds:.1} s)"));
                }
                Msg::Cancelled { generation } => {
                    if generation == self.generation {
                        self.running = None;
                        self.log("cancelled".into());
                    }
                }
                Msg::Failed { generation, step, message } => {
                    if generation == self.generation {
                        self.running = None;
                    }
                    self.log(format!("failed: {message}"));
                    self.failed = Some((step, message));
                }
                Msg::Unreadable { step, message } => {
                    self.log(format!("cannot show {}: {message}", step.name()));
                    self.unreadable.push((step, message));
                }
            }
        }
    }

    fn log(&mut self, line: String) {
        tracing::info!("{line}");
        self.log.push(line);
        if self.log.len() > 200 {
            self.log.remove(0);
        }
    }

    fn scripted(&self) -> bool {
        self.script.is_some()
    }
}

impl eframe::App for App {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        // The panels' colour: the panels are drawn unfilled (see `panel_frame`).
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.last_cpu = frame.info().cpu_usage;
        let ctx = ui.ctx().clone();
        let now = Instant::now();
        if let Some(last) = self.last_frame {
            self.frame_times.push((now - last).as_secs_f32());
            if self.frame_times.len() > 120 {
                self.frame_times.remove(0);
            }
            self.frames_drawn += 1;
            if self.frames_drawn.is_multiple_of(100) {
                let mut recent = self.frame_times.clone();
                recent.sort_by(f32::total_cmp);
                tracing::debug!(
                    "frame time median {:.1} ms over the last {}, running {:?}, views {}",
                    recent[recent.len() / 2] * 1e3,
                    recent.len(),
                    self.running.as_ref().and_then(|r| r.step),
                    self.textures.len()
                );
            }
        }
        self.last_frame = Some(now);
        self.pictures.begin_frame();
        self.poll_worker();
        self.shortcuts(&ctx);

        egui::Panel::top("top").frame(panel_frame(ui)).show(ui, |ui| self.top_bar(ui));
        egui::Panel::bottom("status").frame(panel_frame(ui)).show(ui, |ui| self.status_bar(ui));
        egui::Panel::left("tools").frame(panel_frame(ui)).resizable(true).default_size(300.0).show(
            ui,
            |ui| {
                egui::ScrollArea::vertical().auto_shrink([false, false]).show(ui, |ui| self.side_panel(ui));
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
        if self.running.is_some() {
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

/// The part of the screen rectangle `rect` inside `clip`, with the matching part of its
/// texture rectangle `uv`; `None` when nothing is left.
fn clip_quad(rect: Rect, uv: Rect, clip: Rect) -> Option<(Rect, Rect)> {
    let vis = rect.intersect(clip);
    (vis.width() > 0.0 && vis.height() > 0.0).then(|| {
        let u = |x: f32| uv.min.x + (x - rect.min.x) / rect.width() * uv.width();
        let v = |y: f32| uv.min.y + (y - rect.min.y) / rect.height() * uv.height();
        (
            vis,
            Rect::from_min_max(Pos2::new(u(vis.min.x), v(vis.min.y)), Pos2::new(u(vis.max.x), v(vis.max.y))),
        )
    })
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

impl App {
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
            self.polygon.clear();
        }
        if ctx.input(|i| i.key_pressed(egui::Key::Enter)) {
            self.close_polygon();
        }
    }

    fn save(&mut self) {
        match self.project.save(&self.doc.small, &self.doc.hints) {
            Ok(()) => self.log(format!("saved {}", self.project.dir.display())),
            Err(e) => self.log(format!("saving failed: {e:#}")),
        }
    }

    fn top_bar(&mut self, ui: &mut egui::Ui) {
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
                self.export_open = true;
            }
            ui.separator();
            let views = [
                ViewKind::Photo,
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
                let on = self.shown == Shown::One(v);
                if ui.selectable_label(on, v.label()).clicked() {
                    self.shown = Shown::One(v);
                }
            }
            if ui.selectable_label(self.shown == Shown::BeforeAfter, "before | after").clicked() {
                self.shown = Shown::BeforeAfter;
            }
            if ui.button("Fit").clicked() {
                self.transform = None;
            }
        });
    }

    fn status_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            if let Some(r) = &self.running {
                let frac = r.done as f32 / r.total.max(1) as f32;
                let what = r.step.map_or("starting".to_string(), |s| s.name().to_string());
                let text = if self.scripted() {
                    format!("{what} ({}/{})", r.done + 1, r.total)
                } else {
                    format!("{what} ({}/{}) {:.0} s", r.done + 1, r.total, r.started.elapsed().as_secs_f32())
                };
                ui.add(egui::ProgressBar::new(frac).desired_width(260.0).text(text));
                if ui.button("Cancel").clicked() {
                    self.worker.cancel();
                }
            } else if let Some((step, msg)) = self.failed.clone() {
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
            if !self.scripted() && !self.frame_times.is_empty() {
                let mean = self.frame_times.iter().sum::<f32>() / self.frame_times.len() as f32;
                ui.weak(format!("frame {:.1} ms", mean * 1e3));
            }
            if let Some(t) = self.transform {
                ui.weak(format!("zoom {:.0} %", t.zoom * 100.0));
            }
        });
    }

    fn side_panel(&mut self, ui: &mut egui::Ui) {
        ui.heading("Tools");
        ui.horizontal_wrapped(|ui| {
            for (t, name, tip) in [
                (Tool::Pan, "pan", "drag to pan, wheel to zoom (any tool: middle drag pans)"),
                (Tool::Pick, "pick", "click: pick a pixel for the class; shift-drag: a rectangle; right-click: remove the nearest pick"),
                (Tool::RegionRect, "rect region", "drag a rectangle to restore"),
                (Tool::RegionPolygon, "polygon region", "click corners; double-click or Enter closes, Esc cancels"),
                (Tool::Hint, "hint brush", "paint the class where the restoration should put it"),
                (Tool::Erase, "eraser", "erase hint strokes"),
            ] {
                ui.selectable_value(&mut self.tool, t, name).on_hover_text(tip);
            }
        });
        if matches!(self.tool, Tool::Hint | Tool::Erase) {
            ui.add(egui::Slider::new(&mut self.brush, 0.5..=64.0).logarithmic(true).text("brush radius px"));
            ui.horizontal(|ui| {
                ui.checkbox(&mut self.show_hints, "show strokes");
                if ui.button("clear strokes").clicked() && !self.doc.hints.is_empty() {
                    let mut diff = HintDiff::default();
                    self.doc.hints.clear(&mut diff);
                    self.refresh_hint_texture(None);
                    self.finish_stroke(diff);
                }
            });
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

    fn classes_ui(&mut self, ui: &mut egui::Ui) {
        ui.heading("Colour classes");
        let colours = self.class_colours();
        let w = &mut self.working;
        let mut remove = None;
        for (i, c) in w.picks.colours.iter_mut().enumerate() {
            ui.horizontal(|ui| {
                let col = colours.get(i).copied().unwrap_or(restage_authoring::color::categorical(i));
                let (rect, _) = ui.allocate_exact_size(egui::vec2(14.0, 14.0), Sense::hover());
                ui.painter().rect_filled(rect, 2.0, Color32::from_rgb(col[0], col[1], col[2]));
                if ui
                    .selectable_label(self.class == i, "")
                    .on_hover_text("select for picks and hints")
                    .clicked()
                {
                    self.class = i;
                }
                ui.add(egui::TextEdit::singleline(&mut c.name).desired_width(90.0));
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
                    .on_hover_text("this class is loss (bare clay): filled from its neighbours")
                    .changed()
                {
                    w.settings.restore.loss.retain(|&l| l != k);
                    if loss {
                        w.settings.restore.loss.push(k);
                        w.settings.restore.loss.sort_unstable();
                    }
                }
                ui.weak(format!("{}", c.pixels.len() + c.rects.len()));
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
            self.class = self.class.min(w.picks.colours.len().saturating_sub(1));
        }
        if ui.button("add class").clicked() {
            let c = new_class(&w.picks);
            w.picks.colours.push(c);
            self.class = w.picks.colours.len() - 1;
            self.tool = Tool::Pick;
        }
        ui.collapsing("classification", |ui| {
            ui.add(
                egui::Slider::new(&mut w.settings.classify.max_iterations, 1..=50).text("k-means iterations"),
            );
            ui.add(egui::Slider::new(&mut w.settings.classify.prior_picks, 0.0..=50.0).text("prior picks"));
        });
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
        );
        ui.add(egui::Slider::new(&mut s.restore.beta, 1.0..=16.0).logarithmic(true).text("beta (spacing)"));
        ui.horizontal(|ui| {
            let mut on = s.restore.gamma.is_some();
            if ui.checkbox(&mut on, "gamma").changed() {
                s.restore.gamma = on.then_some(0.05);
            }
            if let Some(g) = &mut s.restore.gamma {
                ui.add(egui::Slider::new(g, 0.0..=1.0).text("max brightening"));
            }
        });
        ui.add(egui::Slider::new(&mut s.restore.neighbours, 1..=12).text("neighbours"));
        ui.add(egui::Slider::new(&mut s.restore.scale, 1.0..=40.0).text("scale px"));
        ui.horizontal(|ui| {
            let mut auto = s.restore.grid == "auto";
            if ui.checkbox(&mut auto, "grid auto").changed() {
                s.restore.grid = if auto { "auto".into() } else { "4x4".into() };
            }
            if !auto {
                let (mut g, mut h) = s
                    .restore
                    .grid
                    .split_once('x')
                    .map_or((4u32, 4u32), |(a, b)| (a.parse().unwrap_or(4), b.parse().unwrap_or(4)));
                ui.add(egui::DragValue::new(&mut g).range(1..=256));
                ui.label("x");
                ui.add(egui::DragValue::new(&mut h).range(1..=256));
                s.restore.grid = format!("{g}x{h}");
            }
        });
        ui.heading("Compensation");
        ui.add(
            egui::Slider::new(&mut s.compensate.e_bound_lux, 5.0..=1000.0)
                .logarithmic(true)
                .text("E_bound lux"),
        );
        ui.horizontal(|ui| {
            let mut inf = s.compensate.m.is_none();
            if ui.checkbox(&mut inf, "m = ∞").changed() {
                s.compensate.m = if inf { None } else { Some(8.0) };
            }
            if let Some(m) = &mut s.compensate.m {
                ui.add(egui::Slider::new(m, 0.0..=32.0).text("m"));
            }
        });
        ui.add(egui::Slider::new(&mut s.compensate.margin, 0.0..=0.5).text("safety margin"));
        ui.add(egui::Slider::new(&mut s.compensate.clip_fraction, 0.0..=0.1).text("clip fraction"));
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
                let a = ui.add(egui::Slider::new(&mut az, -180.0..=180.0).text("from (° right)"));
                let e = ui.add(egui::Slider::new(&mut el, -89.0..=89.0).text("height (°)"));
                let s = ui.add(egui::Slider::new(&mut strength, 0.0..=3.0).text("strength"));
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
        ui.add(egui::Slider::new(&mut l.ambient, 0.0..=1.0).text("ambient"));
        ui.add(egui::Slider::new(&mut l.specular, 0.0..=1.0).text("specular"));
        ui.add(egui::Slider::new(&mut l.shininess, 1.0..=200.0).logarithmic(true).text("shininess"));
        ui.add(egui::Slider::new(&mut l.exposure, 0.1..=4.0).logarithmic(true).text("exposure"));
        ui.add(egui::Slider::new(&mut w.settings.relight.noise, 0.0..=1.0).text("material noise"));
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
                if let Some(f) = self.figures.get(&s) {
                    ui.label(s.id());
                    ui.label(format!("peak {:.1} lx", f.peak_lux));
                    ui.label(format!("≤ {:.1} lx", f.limit_lux));
                    ui.end_row();
                }
            }
        });
    }

    fn windows(&mut self, ctx: &egui::Context) {
        if !self.offer_missing.is_empty() {
            let names: Vec<&str> = self.offer_missing.iter().map(|s| s.name()).collect();
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
                let steps = self.offer_missing.with_dependents();
                self.submit(steps, None);
            }
            if run || m.should_close() {
                self.offer_missing = Steps::NONE;
            }
        }
        if !self.problems.is_empty() || !self.unreadable.is_empty() {
            let mut open = true;
            egui::Window::new("Problems").open(&mut open).default_width(420.0).show(ctx, |ui| {
                for p in &self.problems {
                    ui.label(format!("{}: {}", p.path.display(), p.message));
                }
                let mut rerun = None;
                for (step, msg) in &self.unreadable {
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
                self.problems.clear();
                self.unreadable.clear();
            }
        }
        if self.export_open {
            let mut open = true;
            egui::Window::new("Export bundle")
                .open(&mut open)
                .default_width(480.0)
                .show(ctx, |ui| self.export_ui(ui));
            self.export_open = open;
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
            ui.add(egui::DragValue::new(&mut e.version).range(1..=u64::MAX));
            ui.end_row();
            ui.label("valid for (days)");
            ui.add(egui::DragValue::new(&mut e.valid_days).range(1..=3650));
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
            opt_drag(ui, &mut e.max_showing_s, 60, 1..=3600);
            ui.end_row();
            ui.label("dark between (s)");
            opt_drag(ui, &mut e.cooldown_s, 30, 0..=3600);
            ui.end_row();
        });
        if ui.button("make a new key").clicked() {
            match super::project::new_key(
                &self.project,
                &format!("key-{}", crate::steps::now_unix_s().unwrap_or(0)),
            ) {
                Ok((k, t)) => {
                    e.key = k;
                    e.trust = t;
                }
                Err(err) => self.export_result = Some(Err(format!("{err:#}"))),
            }
        }
        ui.label("scenes:");
        for s in Scene::ALL {
            let mut on = e.scenes.contains(&s);
            let peak = self.figures.get(&s).map_or("not compensated".to_string(), |f| {
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
        let peak = super::export::peak_of(&e.scenes, &self.figures);
        match super::export::policy_summary(e, peak) {
            Ok(s) => ui.label(s),
            Err(err) => ui.colored_label(Color32::from_rgb(255, 120, 100), format!("{err:#}")),
        };
        let ready = self.running.is_none();
        if ui.add_enabled(ready, egui::Button::new("Write and verify the bundle")).clicked() {
            self.commit_working();
            self.export_result = Some(
                super::export::write_and_verify(&self.project, &self.doc.small.settings)
                    .map_err(|e| format!("{e:#}")),
            );
        }
        match &self.export_result {
            Some(Ok(text)) => {
                ui.monospace(text);
            }
            Some(Err(text)) => {
                ui.colored_label(Color32::from_rgb(255, 120, 100), text);
            }
            None => {}
        }
    }

    fn canvas(&mut self, ui: &mut egui::Ui) {
        let (resp, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
        let area = resp.rect;
        self.view_size = [area.width(), area.height()];
        let size = self.size();
        let t =
            *self.transform.get_or_insert_with(|| ViewTransform::fit(size, [area.width(), area.height()]));
        let local = |p: Pos2| [p.x - area.min.x, p.y - area.min.y];
        let mut t2 = t;
        // Zoom at the cursor; pan with the pan tool, the middle button, or space held.
        if let Some(p) = resp.hover_pos() {
            let (scroll, zoom) = ui.input(|i| (i.smooth_scroll_delta.y, i.zoom_delta()));
            let f = zoom * (scroll * 0.002).exp();
            if (f - 1.0).abs() > 1e-4 {
                t2.zoom_at(f, local(p));
            }
        }
        let panning = self.tool == Tool::Pan || ui.input(|i| i.key_down(egui::Key::Space));
        if resp.dragged_by(egui::PointerButton::Middle)
            || (panning && resp.dragged_by(egui::PointerButton::Primary))
        {
            let d = resp.drag_delta();
            t2.pan([d.x, d.y]);
        }
        self.transform = Some(t2);
        let t = t2;
        let r = t.image_rect(size);
        let img_rect = Rect::from_min_max(
            Pos2::new(area.min.x + r[0], area.min.y + r[1]),
            Pos2::new(area.min.x + r[2], area.min.y + r[3]),
        );
        // Only the visible part of the picture becomes a quad (with the matching texture
        // coordinates): a quad reaching far outside the window costs a software rasteriser
        // (and lavapipe was seen to stall on two such quads at 1:1 on a 10 MP photo).
        let whole = Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0));
        let visible_quad = |clip: Rect| clip_quad(img_rect, whole, clip.intersect(area));
        let pictures = &mut self.pictures;
        let textures = &self.textures;
        let mut draw = |view: ViewKind, clip: Rect| -> bool {
            match textures.get(&view) {
                Some(tex) => {
                    if let Some((rect, uv)) = visible_quad(clip) {
                        pictures.draw(&painter, clip.intersect(area), rect, uv, &tex.image, false);
                    }
                    true
                }
                None => false,
            }
        };
        match self.shown {
            Shown::One(view) => {
                if !draw(view, area) {
                    let why = match view {
                        ViewKind::Visitor(_) if !self.project.has_virtual_stage() => {
                            "the visitor preview needs the virtual stage (a simulated capture); this project has none".to_string()
                        }
                        ViewKind::Visitor(_) | ViewKind::Irradiance(_) if self.project.paths.stage.is_none() => {
                            "no stage model: nothing to compensate".to_string()
                        }
                        _ => format!("no {} yet: run its step", view.label()),
                    };
                    painter.text(
                        area.center(),
                        egui::Align2::CENTER_CENTER,
                        why,
                        egui::FontId::proportional(16.0),
                        Color32::GRAY,
                    );
                }
            }
            Shown::BeforeAfter => {
                let x = area.min.x + self.split * area.width();
                let left = Rect::from_min_max(area.min, Pos2::new(x, area.max.y));
                let right = Rect::from_min_max(Pos2::new(x, area.min.y), area.max);
                draw(ViewKind::Photo, left);
                draw(self.after, right);
                painter.line_segment(
                    [Pos2::new(x, area.min.y), Pos2::new(x, area.max.y)],
                    Stroke::new(2.0, Color32::WHITE),
                );
                painter.text(
                    Pos2::new(left.min.x + 8.0, left.min.y + 8.0),
                    egui::Align2::LEFT_TOP,
                    "before: photo",
                    egui::FontId::proportional(14.0),
                    Color32::WHITE,
                );
                painter.text(
                    Pos2::new(area.max.x - 8.0, area.min.y + 8.0),
                    egui::Align2::RIGHT_TOP,
                    format!("after: {}", self.after.label()),
                    egui::FontId::proportional(14.0),
                    Color32::WHITE,
                );
            }
        }
        if self.show_hints
            && let Some(o) = &self.hint_tex
            && o.tiles.size() == size
            && let Some(vis) = t.visible(size, self.view_size)
        {
            // Only the tiles holding strokes, none without any (uv 0..1 spans the pixel edges).
            let (iw, ih) = (img_rect.width() / size[0] as f32, img_rect.height() / size[1] as f32);
            for [x0, y0, x1, y1] in o.tiles.runs(vis) {
                let rect = Rect::from_min_max(
                    Pos2::new(img_rect.min.x + x0 as f32 * iw, img_rect.min.y + y0 as f32 * ih),
                    Pos2::new(img_rect.min.x + x1 as f32 * iw, img_rect.min.y + y1 as f32 * ih),
                );
                let uv = Rect::from_min_max(
                    Pos2::new(x0 as f32 / size[0] as f32, y0 as f32 / size[1] as f32),
                    Pos2::new(x1 as f32 / size[0] as f32, y1 as f32 / size[1] as f32),
                );
                if let Some((rect, uv)) = clip_quad(rect, uv, area) {
                    self.pictures.draw(&painter, area, rect, uv, &o.image, true);
                }
            }
        }
        self.overlays(&painter, area, t);
        if self.shown == Shown::BeforeAfter {
            self.before_after_controls(ui, area, &resp);
        } else {
            self.tool_input(ui, &resp, area, t);
        }
    }

    fn before_after_controls(&mut self, ui: &mut egui::Ui, area: Rect, resp: &egui::Response) {
        if resp.dragged_by(egui::PointerButton::Primary)
            && self.tool != Tool::Pan
            && let Some(p) = resp.interact_pointer_pos()
        {
            self.split = ((p.x - area.min.x) / area.width()).clamp(0.0, 1.0);
        }
        let mut after = self.after;
        egui::Area::new(egui::Id::unique("after"))
            .fixed_pos(Pos2::new(area.min.x + 8.0, area.max.y - 32.0))
            .show(ui.ctx(), |ui| {
                ui.horizontal(|ui| {
                    for v in [
                        ViewKind::Restored,
                        ViewKind::Visitor(Scene::Restored),
                        ViewKind::Relit,
                        ViewKind::Visitor(Scene::Relit),
                    ] {
                        ui.selectable_value(&mut after, v, v.label());
                    }
                    if ui
                        .button("swap")
                        .on_hover_text("toggle: the whole view shows before, then after")
                        .clicked()
                    {
                        self.split = if self.split > 0.5 { 0.0 } else { 1.0 };
                    }
                });
            });
        self.after = after;
    }

    fn overlays(&self, painter: &egui::Painter, area: Rect, t: ViewTransform) {
        let colours = self.class_colours();
        let at = |p: [f64; 2]| {
            let s = t.to_screen([p[0] as f32, p[1] as f32]);
            Pos2::new(area.min.x + s[0], area.min.y + s[1])
        };
        let p = painter.with_clip_rect(area);
        // Picks where they matter: with the pick tool, and over the photo and classes.
        let picks_shown = self.tool == Tool::Pick
            || matches!(self.shown, Shown::One(ViewKind::Photo | ViewKind::Classes | ViewKind::ClassesFalse));
        if let Shown::One(ViewKind::Irradiance(scene)) = self.shown
            && let Some(f) = self.figures.get(&scene)
        {
            heat_legend(&p, area, f.e_bound_lux);
        }
        for (i, c) in self.working.picks.colours.iter().enumerate().filter(|_| picks_shown) {
            let col = colours.get(i).copied().unwrap_or(restage_authoring::color::categorical(i));
            let fill = Color32::from_rgb(col[0], col[1], col[2]);
            for px in &c.pixels {
                let q = at([px[0] as f64, px[1] as f64]);
                let r = Rect::from_center_size(q, egui::vec2(7.0, 7.0));
                p.rect_filled(r, 0.0, fill);
                p.rect_stroke(r, 0.0, Stroke::new(1.0, Color32::BLACK), egui::StrokeKind::Outside);
            }
            for rc in &c.rects {
                let r = Rect::from_min_max(
                    at([rc.x as f64 - 0.5, rc.y as f64 - 0.5]),
                    at([(rc.x + rc.width as i64) as f64 - 0.5, (rc.y + rc.height as i64) as f64 - 0.5]),
                );
                p.rect_stroke(r, 0.0, Stroke::new(2.0, fill), egui::StrokeKind::Middle);
            }
        }
        let yellow = Stroke::new(2.0, Color32::from_rgb(255, 220, 60));
        for region in &self.working.settings.restore.regions {
            match region {
                RegionSpec::Rect { x, y, width, height, .. } => {
                    let r = Rect::from_min_max(
                        at([*x as f64 - 0.5, *y as f64 - 0.5]),
                        at([(x + width) as f64 - 0.5, (y + height) as f64 - 0.5]),
                    );
                    p.rect_stroke(r, 0.0, yellow, egui::StrokeKind::Middle);
                }
                RegionSpec::Polygon { points, .. } => {
                    let pts: Vec<Pos2> = points.iter().map(|q| at(*q)).collect();
                    p.add(egui::Shape::closed_line(pts, yellow));
                }
            }
        }
        if !self.polygon.is_empty() {
            let pts: Vec<Pos2> = self.polygon.iter().map(|q| at(*q)).collect();
            p.add(egui::Shape::line(pts, Stroke::new(2.0, Color32::from_rgb(255, 160, 40))));
        }
    }

    fn tool_input(&mut self, ui: &mut egui::Ui, resp: &egui::Response, area: Rect, t: ViewTransform) {
        let to_img = |p: Pos2| {
            let q = t.to_image([p.x - area.min.x, p.y - area.min.y]);
            [q[0] as f64, q[1] as f64]
        };
        let (w, h) = self.project.photo_size;
        let inside = |q: [f64; 2]| {
            q[0].round() >= 0.0
                && q[1].round() >= 0.0
                && (q[0].round() as u32) < w
                && (q[1].round() as u32) < h
        };
        if matches!(self.tool, Tool::Hint | Tool::Erase)
            && let Some(p) = resp.hover_pos()
        {
            ui.painter().with_clip_rect(area).circle_stroke(
                p,
                self.brush * t.zoom,
                Stroke::new(1.0, Color32::WHITE),
            );
        }
        match self.tool {
            Tool::Pan => {}
            Tool::Pick => {
                let shift = ui.input(|i| i.modifiers.shift);
                if resp.clicked()
                    && let Some(q) = resp.interact_pointer_pos().map(to_img)
                    && inside(q)
                    && let Some(c) = self.working.picks.colours.get_mut(self.class)
                {
                    c.pixels.push([q[0].round() as i64, q[1].round() as i64]);
                }
                if resp.secondary_clicked()
                    && let Some(p) = resp.interact_pointer_pos()
                {
                    let q = to_img(p);
                    let near = (6.0 / t.zoom) as f64;
                    for c in &mut self.working.picks.colours {
                        if let Some(k) = c
                            .pixels
                            .iter()
                            .position(|px| (px[0] as f64 - q[0]).hypot(px[1] as f64 - q[1]) <= near)
                        {
                            c.pixels.remove(k);
                            break;
                        }
                    }
                }
                if shift {
                    self.rect_drag(resp, &to_img, |app, a, b| {
                        if let Some(c) = app.working.picks.colours.get_mut(app.class) {
                            c.rects.push(PickRect {
                                x: a[0] as i64,
                                y: a[1] as i64,
                                width: b[0] - a[0],
                                height: b[1] - a[1],
                            });
                        }
                    });
                }
            }
            Tool::RegionRect => self.rect_drag(resp, &to_img, |app, a, b| {
                app.working.settings.restore.regions.push(RegionSpec::Rect {
                    x: a[0],
                    y: a[1],
                    width: b[0] - a[0],
                    height: b[1] - a[1],
                    background: None,
                });
            }),
            Tool::RegionPolygon => {
                if resp.double_clicked() {
                    self.close_polygon();
                } else if resp.clicked()
                    && let Some(p) = resp.interact_pointer_pos()
                {
                    let q = to_img(p);
                    self.polygon.push([q[0].clamp(0.0, w as f64 - 1.0), q[1].clamp(0.0, h as f64 - 1.0)]);
                }
            }
            Tool::Hint | Tool::Erase => {
                let value = if self.tool == Tool::Erase { NO_HINT } else { self.class as u8 };
                if value != NO_HINT && (value as usize) >= self.doc.small.picks.colours.len() {
                    return;
                }
                let pos = resp.interact_pointer_pos().map(to_img);
                if (resp.drag_started_by(egui::PointerButton::Primary) || resp.clicked())
                    && let Some(q) = pos
                {
                    self.stroke = Some((HintDiff::default(), q));
                }
                if let Some(q) = pos
                    && let Some((mut diff, last)) = self.stroke.take()
                {
                    self.paint(last, q, value, &mut diff);
                    self.stroke = Some((diff, q));
                }
                if (resp.drag_stopped() || resp.clicked())
                    && let Some((diff, _)) = self.stroke.take()
                {
                    self.finish_stroke(diff);
                }
            }
        }
    }

    /// Paints one segment of a stroke into the document and the overlay texture.
    fn paint(&mut self, a: [f64; 2], b: [f64; 2], value: u8, diff: &mut HintDiff) {
        let r = self.brush as f64;
        self.doc.hints.stroke(a, b, r, value, diff);
        let (w, h) = (self.doc.hints.width as f64, self.doc.hints.height as f64);
        let x0 = (a[0].min(b[0]) - r - 1.0).floor().clamp(0.0, w) as u32;
        let y0 = (a[1].min(b[1]) - r - 1.0).floor().clamp(0.0, h) as u32;
        let x1 = (a[0].max(b[0]) + r + 2.0).ceil().clamp(0.0, w) as u32;
        let y1 = (a[1].max(b[1]) + r + 2.0).ceil().clamp(0.0, h) as u32;
        if x1 > x0 && y1 > y0 {
            self.refresh_hint_texture(Some([x0, y0, x1 - x0, y1 - y0]));
        }
    }

    fn finish_stroke(&mut self, diff: HintDiff) {
        let stale = self.doc.commit_stroke(diff);
        let visible = self.visible();
        self.submit(stale, visible);
    }

    /// A rectangle dragged with the primary button, in whole pixels, handed to `done`.
    fn rect_drag(
        &mut self,
        resp: &egui::Response,
        to_img: &dyn Fn(Pos2) -> [f64; 2],
        done: impl FnOnce(&mut Self, [u32; 2], [u32; 2]),
    ) {
        let (w, h) = self.project.photo_size;
        if resp.drag_started_by(egui::PointerButton::Primary)
            && let Some(p) = resp.interact_pointer_pos()
        {
            let q = to_img(p);
            self.drag_from = Some([q[0] as f32, q[1] as f32]);
        }
        if let (Some(a), Some(p)) = (self.drag_from, resp.interact_pointer_pos()) {
            let b = to_img(p);
            let clamp = |v: f64, m: u32| (v + 0.5).floor().clamp(0.0, m as f64) as u32;
            let (x0, x1) = (clamp((a[0] as f64).min(b[0]), w), clamp((a[0] as f64).max(b[0]) + 1.0, w));
            let (y0, y1) = (clamp((a[1] as f64).min(b[1]), h), clamp((a[1] as f64).max(b[1]) + 1.0, h));
            if resp.drag_stopped() {
                self.drag_from = None;
                if x1 > x0 && y1 > y0 {
                    done(self, [x0, y0], [x1, y1]);
                }
            }
        }
    }

    fn close_polygon(&mut self) {
        if self.polygon.len() >= 3 {
            let points = std::mem::take(&mut self.polygon);
            self.working.settings.restore.regions.push(RegionSpec::Polygon { points, background: None });
        } else {
            self.polygon.clear();
        }
    }

    /// The benchmark's hint stroke across the middle of the visible region, in a class other
    /// than the one already there (a project keeps the last run's strokes: the same stroke
    /// again would change nothing and run nothing).
    fn bench_stroke(&mut self, b: &mut Bench, panning: bool) -> Result<()> {
        let [x, y, w, h] = self.visible().context("the benchmark's view shows no part of the photo")?;
        let (cx, cy) = (x + w / 2, y + h / 2);
        let hints = &self.doc.hints;
        let class = u8::from(hints.labels[(cy * hints.width + cx) as usize] == 0);
        let (cx, cy) = (cx as f64, cy as f64);
        let mut diff = HintDiff::default();
        self.brush = 6.0;
        self.paint([cx - 40.0, cy], [cx + 40.0, cy + 10.0], class, &mut diff);
        if diff.is_empty() {
            bail!("the benchmark's hint stroke changed nothing");
        }
        b.strokes.push(StrokeTiming {
            at: Instant::now(),
            panning,
            partial_ms: None,
            partial_px: 0,
            full_ms: None,
        });
        self.finish_stroke(diff);
        Ok(())
    }

    /// Advances a scripted session by one frame.
    fn drive_script(&mut self, ctx: &egui::Context) {
        let Some(mut script) = self.script.take() else { return };
        // Every frame drawn, except while the benchmark holds the view still.
        if !(matches!(script.kind, ScriptKind::Bench(_)) && script.step == 5) {
            ctx.request_repaint();
        }
        script.frames_in_step += 1;
        let idle = self.running.is_none() && self.offer_missing.is_empty();
        let result = match &mut script.kind {
            ScriptKind::Screenshots { dir, shot, waiting } => {
                let views = screenshot_views();
                if script.step >= views.len() {
                    ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                    Ok(())
                } else if !idle || script.frames_in_step < 3 {
                    if script.started.elapsed() > Duration::from_secs(600) {
                        Err(anyhow!("the project's steps did not finish within 10 minutes"))
                    } else {
                        Ok(())
                    }
                } else {
                    self.shown = views[script.step];
                    self.transform = None;
                    if !*waiting && script.frames_in_step >= 6 {
                        let slot = shot.clone();
                        let c = ctx.clone();
                        ctx.request_screenshot(move |img| {
                            *slot.lock().expect("not poisoned") = Some(img);
                            c.request_repaint();
                        });
                        *waiting = true;
                    }
                    let taken = shot.lock().expect("not poisoned").take();
                    match taken {
                        Some(img) => {
                            *waiting = false;
                            let name = match views[script.step] {
                                Shown::One(v) => v.slug(),
                                Shown::BeforeAfter => "before_after".into(),
                            };
                            let r = save_shot(&img, &dir.join(format!("{:02}-{name}.png", script.step)));
                            script.step += 1;
                            script.frames_in_step = 0;
                            r
                        }
                        None => Ok(()),
                    }
                }
            }
            ScriptKind::Bench(b) => {
                const PAN_FRAMES: usize = 300;
                let now = Instant::now();
                let pending = b.strokes.last().is_some_and(|s| s.full_ms.is_none());
                match script.step {
                    // Wait for the steps, then show the photo at 1:1 in the middle.
                    0 => {
                        if idle && script.frames_in_step > 3 && self.textures.contains_key(&ViewKind::Photo) {
                            self.shown = Shown::One(ViewKind::Photo);
                            let size = self.size();
                            self.transform = Some(ViewTransform {
                                zoom: 1.0,
                                offset: [
                                    size[0] as f32 * 0.5 - self.view_size[0] * 0.5,
                                    size[1] as f32 * 0.5 - self.view_size[1] * 0.5,
                                ],
                            });
                            script.step = 1;
                            b.last = None;
                        }
                        Ok(())
                    }
                    // Pan in a slow circle, timing frames.
                    1 => {
                        if let Some(l) = b.last {
                            b.frame_ms.push((now - l).as_secs_f64() * 1e3);
                            b.cpu_ms.extend(self.last_cpu.map(|c| c as f64 * 1e3));
                        }
                        b.last = Some(now);
                        pan_circle(&mut self.transform, b.frame_ms.len());
                        if b.frame_ms.len() >= PAN_FRAMES {
                            script.step = 2;
                        }
                        Ok(())
                    }
                    // A stroke, then keep panning until its restoration is whole.
                    2 => {
                        self.shown = Shown::One(ViewKind::Restored);
                        script.step = 3;
                        self.bench_stroke(b, true)
                    }
                    3 => {
                        if let Some(l) = b.last {
                            b.busy_ms.push((now - l).as_secs_f64() * 1e3);
                        }
                        b.last = Some(now);
                        pan_circle(&mut self.transform, b.frame_ms.len() + b.busy_ms.len());
                        if !pending && idle {
                            script.step = 4;
                        }
                        Ok(())
                    }
                    // A second stroke with the view still: the window redraws only when
                    // something arrives (the worker's messages wake it).
                    4 => {
                        script.step = 5;
                        self.bench_stroke(b, false)
                    }
                    5 => {
                        if pending && script.started.elapsed() < Duration::from_secs(900) {
                            self.script = Some(script);
                            return;
                        }
                        // With a stage model, go on to a compensation (a lower E_bound).
                        script.step = if self.project.paths.stage.is_some() { 6 } else { 8 };
                        Ok(())
                    }
                    6 => {
                        self.working.settings.compensate.e_bound_lux *= 0.9;
                        self.commit_working();
                        b.last = None;
                        script.step = 7;
                        script.frames_in_step = 0;
                        Ok(())
                    }
                    7 => {
                        if let Some(l) = b.last {
                            b.compensating_ms.push((now - l).as_secs_f64() * 1e3);
                        }
                        b.last = Some(now);
                        pan_circle(&mut self.transform, b.frame_ms.len() + b.compensating_ms.len());
                        if idle && script.frames_in_step > 2 {
                            script.step = 8;
                        }
                        Ok(())
                    }
                    _ => {
                        let r = write_bench(b, self.size());
                        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                        self.script = None;
                        if let Err(e) = r {
                            *self.failure.lock().expect("not poisoned") = Some(format!("{e:#}"));
                        }
                        return;
                    }
                }
            }
        };
        if let Some((step, msg)) = &self.failed {
            *self.failure.lock().expect("not poisoned") =
                Some(format!("{}: {msg}", step.map_or("saving", |s| s.name())));
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        if let Err(e) = result {
            *self.failure.lock().expect("not poisoned") = Some(format!("{e:#}"));
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        self.script = Some(script);
    }
}

fn save_shot(img: &ColorImage, path: &Path) -> Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let rgba: Vec<u8> = img.pixels.iter().flat_map(|p| p.to_srgba_unmultiplied()).collect();
    let out = image::RgbaImage::from_raw(img.size[0] as u32, img.size[1] as u32, rgba)
        .context("screenshot size")?;
    image::DynamicImage::ImageRgba8(out)
        .to_rgb8()
        .save(path)
        .with_context(|| format!("writing {}", path.display()))?;
    tracing::info!("screenshot {}", path.display());
    Ok(())
}

/// Pans along a slow circle, 6 points a frame.
fn pan_circle(t: &mut Option<ViewTransform>, frame: usize) {
    let k = frame as f32 * 0.05;
    if let Some(t) = t {
        t.pan([6.0 * k.cos(), 6.0 * k.sin()]);
    }
}

/// Count, median, p95 and max of frame times (ms).
fn frame_stats(v: &[f64]) -> serde_json::Value {
    let mut sorted = v.to_vec();
    sorted.sort_by(f64::total_cmp);
    let q =
        |f: f64| sorted.get(((sorted.len() as f64 - 1.0) * f).round() as usize).copied().unwrap_or(f64::NAN);
    serde_json::json!({ "frames": sorted.len(), "median_ms": q(0.5), "p95_ms": q(0.95), "max_ms": q(1.0) })
}

fn write_bench(b: &Bench, size: [u32; 2]) -> Result<()> {
    let json = serde_json::json!({
        "photo": [size[0], size[1]],
        "panning_idle": frame_stats(&b.frame_ms),
        "panning_idle_cpu_in_egui": frame_stats(&b.cpu_ms),
        "panning_while_restoring": frame_stats(&b.busy_ms),
        "panning_while_compensating": frame_stats(&b.compensating_ms),
        "strokes": b.strokes.iter().map(StrokeTiming::json).collect::<Vec<_>>(),
    });
    std::fs::write(&b.out, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", b.out.display()))?;
    eprintln!("{json}");
    Ok(())
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

/// An optional number: a checkbox for "preset", a drag value otherwise.
fn opt_drag(ui: &mut egui::Ui, value: &mut Option<u32>, default: u32, range: std::ops::RangeInclusive<u32>) {
    ui.horizontal(|ui| {
        let mut set = value.is_some();
        if ui.checkbox(&mut set, "").changed() {
            *value = set.then_some(default);
        }
        match value {
            Some(v) => {
                ui.add(egui::DragValue::new(v).range(range));
            }
            None => {
                ui.weak("class preset");
            }
        }
    });
}

/// The irradiance map's colour scale: 0 to E_bound lux (compensation's `report::heat`).
fn heat_legend(p: &egui::Painter, area: Rect, e_bound: f64) {
    let (w, h) = (220.0, 14.0);
    let x0 = area.max.x - w - 16.0;
    let y0 = area.max.y - h - 28.0;
    let n = 44;
    for i in 0..n {
        let t = i as f64 / (n - 1) as f64;
        let c = restage_authoring::compensate::report::heat(t);
        let r = Rect::from_min_size(
            Pos2::new(x0 + w * i as f32 / n as f32, y0),
            egui::vec2(w / n as f32 + 0.5, h),
        );
        p.rect_filled(r, 0.0, Color32::from_rgb(c[0], c[1], c[2]));
    }
    let font = egui::FontId::proportional(13.0);
    p.text(Pos2::new(x0, y0 + h + 2.0), egui::Align2::LEFT_TOP, "0 lx", font.clone(), Color32::WHITE);
    p.text(
        Pos2::new(x0 + w, y0 + h + 2.0),
        egui::Align2::RIGHT_TOP,
        format!("E_bound {e_bound:.0} lx"),
        font,
        Color32::WHITE,
    );
}
