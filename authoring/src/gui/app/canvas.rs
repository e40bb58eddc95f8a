//! The central area: which picture it shows and through which pan/zoom (`ViewState`), the
//! visible part of the textures, and what is drawn over them (picks, regions, the polygon
//! being drawn, hint strokes, the irradiance scale, the before/after divider).

use eframe::egui::{self, Color32, Pos2, Rect, Sense, Stroke};

use super::App;
use super::tools::Tool;
use crate::gui::doc::{RegionSpec, Scene};
use crate::gui::views::{ViewKind, ViewTransform};

/// Which picture is in the central area.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Shown {
    One(ViewKind),
    /// Photo on the left of the divider, `after` on the right.
    BeforeAfter,
}

pub(super) struct ViewState {
    pub(super) shown: Shown,
    /// The right-hand picture of the before/after split.
    pub(super) after: ViewKind,
    /// The before/after divider, a fraction of the width from the left.
    pub(super) split: f32,
    /// `None` fits the photo into the area on the next frame.
    pub(super) transform: Option<ViewTransform>,
    /// The central area's size in points, as last drawn.
    pub(super) view_size: [f32; 2],
    /// Whether the hint strokes are drawn.
    pub(super) show_hints: bool,
}

impl Default for ViewState {
    fn default() -> Self {
        Self {
            shown: Shown::One(ViewKind::Photo),
            after: ViewKind::Restored,
            split: 0.5,
            transform: None,
            view_size: [1.0, 1.0],
            show_hints: true,
        }
    }
}

impl App {
    pub(super) fn canvas(&mut self, ui: &mut egui::Ui) {
        let (resp, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
        let area = resp.rect;
        self.view.view_size = [area.width(), area.height()];
        let size = self.size();
        let t = *self
            .view
            .transform
            .get_or_insert_with(|| ViewTransform::fit(size, [area.width(), area.height()]));
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
        let panning = self.tools.tool == Tool::Pan || ui.input(|i| i.key_down(egui::Key::Space));
        if resp.dragged_by(egui::PointerButton::Middle)
            || (panning && resp.dragged_by(egui::PointerButton::Primary))
        {
            let d = resp.drag_delta();
            t2.pan([d.x, d.y]);
        }
        self.view.transform = Some(t2);
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
        let pictures = &mut self.textures.gpu;
        let textures = &self.textures.views;
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
        match self.view.shown {
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
                let x = area.min.x + self.view.split * area.width();
                let left = Rect::from_min_max(area.min, Pos2::new(x, area.max.y));
                let right = Rect::from_min_max(Pos2::new(x, area.min.y), area.max);
                draw(ViewKind::Photo, left);
                draw(self.view.after, right);
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
                    format!("after: {}", self.view.after.label()),
                    egui::FontId::proportional(14.0),
                    Color32::WHITE,
                );
            }
        }
        if self.view.show_hints
            && let Some(o) = &self.textures.overlay
            && o.tiles.size() == size
            && let Some(vis) = t.visible(size, self.view.view_size)
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
                    self.textures.gpu.draw(&painter, area, rect, uv, &o.image, true);
                }
            }
        }
        self.overlays(&painter, area, t);
        if self.view.shown == Shown::BeforeAfter {
            self.before_after_controls(ui, area, &resp);
        } else {
            self.tool_input(ui, &resp, area, t);
        }
    }

    /// Dragging the divider (any tool but pan), and the choice of the right-hand picture.
    fn before_after_controls(&mut self, ui: &mut egui::Ui, area: Rect, resp: &egui::Response) {
        if resp.dragged_by(egui::PointerButton::Primary)
            && self.tools.tool != Tool::Pan
            && let Some(p) = resp.interact_pointer_pos()
        {
            self.view.split = ((p.x - area.min.x) / area.width()).clamp(0.0, 1.0);
        }
        let mut after = self.view.after;
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
                        self.view.split = if self.view.split > 0.5 { 0.0 } else { 1.0 };
                    }
                });
            });
        self.view.after = after;
    }

    /// Picks, regions, the polygon being drawn and the irradiance scale, over the picture.
    fn overlays(&self, painter: &egui::Painter, area: Rect, t: ViewTransform) {
        let colours = &self.textures.colours;
        let at = |p: [f64; 2]| {
            let s = t.to_screen([p[0] as f32, p[1] as f32]);
            Pos2::new(area.min.x + s[0], area.min.y + s[1])
        };
        let p = painter.with_clip_rect(area);
        // Picks where they matter: with the pick tool, and over the photo and classes.
        let picks_shown = self.tools.tool == Tool::Pick
            || matches!(
                self.view.shown,
                Shown::One(ViewKind::Photo | ViewKind::Classes | ViewKind::ClassesFalse)
            );
        if let Shown::One(ViewKind::Irradiance(scene)) = self.view.shown
            && let Some(f) = self.jobs.figures.get(&scene)
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
        // The outline with its tool or over the object view.
        if self.tools.tool == Tool::Outline || self.view.shown == Shown::One(ViewKind::Object) {
            let cyan = Stroke::new(2.0, Color32::from_rgb(60, 220, 255));
            for poly in &self.working.outline.polygons {
                p.add(egui::Shape::closed_line(poly.iter().map(|q| at(*q)).collect(), cyan));
            }
        }
        if !self.tools.polygon.is_empty() {
            let pts: Vec<Pos2> = self.tools.polygon.iter().map(|q| at(*q)).collect();
            if self.tools.tool == Tool::Outline {
                // The first corner, where a click closes the outline.
                p.circle_stroke(pts[0], 6.0, Stroke::new(1.5, Color32::WHITE));
            }
            p.add(egui::Shape::line(pts, Stroke::new(2.0, Color32::from_rgb(255, 160, 40))));
        }
    }
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
