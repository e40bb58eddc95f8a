//! What the pointer does on the picture with each tool: colour picks, region rectangles and
//! polygons, the object outline's polygons, hint strokes (painted into the document and the overlay as the pointer moves,
//! one undo step and one recomputation when it lifts).

use eframe::egui::{self, Color32, Pos2, Rect, Stroke};
use restage_authoring::classify::PickRect;

use super::App;
use crate::gui::doc::{HintDiff, NO_HINT, RegionSpec};
use crate::gui::views::ViewTransform;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Tool {
    Pan,
    Pick,
    RegionRect,
    RegionPolygon,
    /// Polygons around the object: the mask step's outline.
    Outline,
    Hint,
    Erase,
}

pub(super) struct ToolState {
    pub(super) tool: Tool,
    /// The class picks and hint strokes go to.
    pub(super) class: usize,
    /// The hint brush's radius, photo pixels.
    pub(super) brush: f32,
    /// The hint stroke being painted: what it changed so far, and where it last was.
    pub(super) stroke: Option<(HintDiff, [f64; 2])>,
    /// Where a rectangle drag began, photo pixels.
    pub(super) drag_from: Option<[f32; 2]>,
    /// The corners of the polygon being drawn (a region or the outline), photo pixels.
    pub(super) polygon: Vec<[f64; 2]>,
}

impl Default for ToolState {
    fn default() -> Self {
        Self { tool: Tool::Pan, class: 0, brush: 4.0, stroke: None, drag_from: None, polygon: Vec::new() }
    }
}

impl App {
    pub(super) fn tool_input(
        &mut self,
        ui: &mut egui::Ui,
        resp: &egui::Response,
        area: Rect,
        t: ViewTransform,
    ) {
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
        if matches!(self.tools.tool, Tool::Hint | Tool::Erase)
            && let Some(p) = resp.hover_pos()
        {
            ui.painter().with_clip_rect(area).circle_stroke(
                p,
                self.tools.brush * t.zoom,
                Stroke::new(1.0, Color32::WHITE),
            );
        }
        match self.tools.tool {
            Tool::Pan => {}
            Tool::Pick => {
                let shift = ui.input(|i| i.modifiers.shift);
                if resp.clicked()
                    && let Some(q) = resp.interact_pointer_pos().map(to_img)
                    && inside(q)
                    && let Some(c) = self.working.picks.colours.get_mut(self.tools.class)
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
                        if let Some(c) = app.working.picks.colours.get_mut(app.tools.class) {
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
            Tool::RegionPolygon | Tool::Outline => {
                if resp.double_clicked() {
                    self.close_polygon();
                } else if resp.clicked()
                    && let Some(p) = resp.interact_pointer_pos()
                {
                    let q = to_img(p);
                    // A click on the first corner closes the outline (within 8 points).
                    let first = self.tools.polygon.first().map(|f| {
                        let s = t.to_screen([f[0] as f32, f[1] as f32]);
                        (s[0] + area.min.x - p.x).hypot(s[1] + area.min.y - p.y)
                    });
                    if self.tools.tool == Tool::Outline
                        && self.tools.polygon.len() >= 3
                        && first.is_some_and(|d| d <= 8.0)
                    {
                        self.close_polygon();
                    } else {
                        self.tools
                            .polygon
                            .push([q[0].clamp(0.0, w as f64 - 1.0), q[1].clamp(0.0, h as f64 - 1.0)]);
                    }
                }
            }
            Tool::Hint | Tool::Erase => {
                let value = if self.tools.tool == Tool::Erase { NO_HINT } else { self.tools.class as u8 };
                if value != NO_HINT && (value as usize) >= self.doc.small.picks.colours.len() {
                    return;
                }
                let pos = resp.interact_pointer_pos().map(to_img);
                if (resp.drag_started_by(egui::PointerButton::Primary) || resp.clicked())
                    && let Some(q) = pos
                {
                    self.tools.stroke = Some((HintDiff::default(), q));
                }
                if let Some(q) = pos
                    && let Some((mut diff, last)) = self.tools.stroke.take()
                {
                    self.paint(last, q, value, &mut diff);
                    self.tools.stroke = Some((diff, q));
                }
                if (resp.drag_stopped() || resp.clicked())
                    && let Some((diff, _)) = self.tools.stroke.take()
                {
                    self.finish_stroke(diff);
                }
            }
        }
    }

    /// Paints one segment of a stroke into the document and the overlay texture.
    pub(super) fn paint(&mut self, a: [f64; 2], b: [f64; 2], value: u8, diff: &mut HintDiff) {
        let r = self.tools.brush as f64;
        self.doc.hints.stroke(a, b, r, value, diff);
        let (w, h) = (self.doc.hints.width as f64, self.doc.hints.height as f64);
        let x0 = (a[0].min(b[0]) - r - 1.0).floor().clamp(0.0, w) as u32;
        let y0 = (a[1].min(b[1]) - r - 1.0).floor().clamp(0.0, h) as u32;
        let x1 = (a[0].max(b[0]) + r + 2.0).ceil().clamp(0.0, w) as u32;
        let y1 = (a[1].max(b[1]) + r + 2.0).ceil().clamp(0.0, h) as u32;
        if x1 > x0 && y1 > y0 {
            self.textures.refresh_overlay(&self.doc.hints, Some([x0, y0, x1 - x0, y1 - y0]));
        }
    }

    /// Commits a finished stroke (one undo step) and recomputes what it staled.
    pub(super) fn finish_stroke(&mut self, diff: HintDiff) {
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
            self.tools.drag_from = Some([q[0] as f32, q[1] as f32]);
        }
        if let (Some(a), Some(p)) = (self.tools.drag_from, resp.interact_pointer_pos()) {
            let b = to_img(p);
            let clamp = |v: f64, m: u32| (v + 0.5).floor().clamp(0.0, m as f64) as u32;
            let (x0, x1) = (clamp((a[0] as f64).min(b[0]), w), clamp((a[0] as f64).max(b[0]) + 1.0, w));
            let (y0, y1) = (clamp((a[1] as f64).min(b[1]), h), clamp((a[1] as f64).max(b[1]) + 1.0, h));
            if resp.drag_stopped() {
                self.tools.drag_from = None;
                if x1 > x0 && y1 > y0 {
                    done(self, [x0, y0], [x1, y1]);
                }
            }
        }
    }

    /// Makes the polygon being drawn a region or a polygon of the outline (three corners or
    /// more), else drops it.
    pub(super) fn close_polygon(&mut self) {
        if self.tools.polygon.len() >= 3 {
            let points = std::mem::take(&mut self.tools.polygon);
            if self.tools.tool == Tool::Outline {
                self.working.outline.polygons.push(points);
            } else {
                self.working.settings.restore.regions.push(RegionSpec::Polygon { points, background: None });
            }
        } else {
            self.tools.polygon.clear();
        }
    }
}
