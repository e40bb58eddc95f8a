//! Scripted sessions, advanced one frame at a time: `--screenshots DIR` shows each view and
//! saves its screenshot (the window tests' golden images), `--bench JSON` times panning and
//! hint strokes. Each is a list of named steps; a step's frame does its work and says which
//! step comes next.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use eframe::egui::{self, ColorImage};

use super::App;
use super::canvas::Shown;
use crate::gui::doc::{HintDiff, Scene};
use crate::gui::views::{ViewKind, ViewTransform};

/// A scripted session (screenshots for the tests, or the benchmark).
pub(super) struct Script {
    kind: Kind,
    /// Frames in the current step, this one included.
    frames_in_step: u32,
    started: Instant,
    /// What went wrong, for `run_window` to return once the window has closed.
    failure: Arc<Mutex<Option<String>>>,
}

enum Kind {
    Screenshots(Screenshots),
    Bench(Bench),
}

struct Screenshots {
    dir: PathBuf,
    step: ShotStep,
    /// Where egui's screenshot arrives (a frame or more after it is asked for).
    shot: Arc<Mutex<Option<Arc<ColorImage>>>>,
    /// A screenshot was asked for and has not arrived yet.
    waiting: bool,
}

/// The steps of the screenshot session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ShotStep {
    /// Once the project's steps are done, show the `n`th of `screenshot_views()` and save its
    /// screenshot as `NN-name.png`.
    View(usize),
    /// Every view saved: close the window.
    Close,
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

/// The benchmark: pan the 1:1 photo, then a hint stroke while still panning, then a second
/// stroke with the view held still, then (with a stage model) a lower E_bound while panning.
#[derive(Default)]
struct Bench {
    out: PathBuf,
    step: BenchStep,
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

/// The steps of the benchmark, in order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum BenchStep {
    /// Wait for the project's steps, then show the photo at 1:1 in the middle.
    #[default]
    Start,
    /// Pan in a slow circle for `PAN_FRAMES` frames, timing them.
    Pan,
    /// A hint stroke in the restored view.
    StrokePanning,
    /// Keep panning until the stroke's restoration is whole and nothing runs.
    PanWhileRestoring,
    /// A second stroke with the view still.
    StrokeStill,
    /// Wait for its restoration: the window redraws only when something arrives (the
    /// worker's messages wake it).
    WaitStill,
    /// With a stage model: lower E_bound by 10 %.
    LowerEBound,
    /// Pan while the compensations run, until nothing runs.
    PanWhileCompensating,
    /// Write the figures and close the window.
    Write,
}

/// Frames of the benchmark's idle panning.
const PAN_FRAMES: usize = 300;
/// How long the screenshots wait for the project's steps.
const SCREENSHOTS_WAIT: Duration = Duration::from_secs(600);
/// How long (from the start) the benchmark waits for the still stroke's restoration.
const BENCH_WAIT: Duration = Duration::from_secs(900);

/// What a step's frame decided.
enum Then<S> {
    /// Another frame in this step.
    Stay,
    /// The next frame is the first of this step.
    Go(S),
    /// Another frame in this step, without looking at failed steps this frame (the benchmark
    /// waiting for its still stroke).
    Hold,
    /// The session is over: the window is closing.
    End,
}

impl<S> Then<S> {
    /// Moves `step` on; the rest is for the session.
    fn apply(self, step: &mut S) -> Then<()> {
        match self {
            Then::Stay => Then::Stay,
            Then::Go(next) => {
                *step = next;
                Then::Go(())
            }
            Then::Hold => Then::Hold,
            Then::End => Then::End,
        }
    }
}

/// A step's frame: what comes next, and what went wrong (the step moves on even so).
type Frame<S> = (Then<S>, Result<()>);

/// What a step's frame sees of the session.
struct Clock {
    frames_in_step: u32,
    started: Instant,
    /// Nothing runs and no dialog waits for an answer.
    idle: bool,
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

impl Script {
    pub(super) fn screenshots(dir: PathBuf, failure: Arc<Mutex<Option<String>>>) -> Self {
        let s = Screenshots { dir, step: ShotStep::View(0), shot: Arc::default(), waiting: false };
        Self::new(Kind::Screenshots(s), failure)
    }

    pub(super) fn bench(out: PathBuf, failure: Arc<Mutex<Option<String>>>) -> Self {
        Self::new(Kind::Bench(Bench { out, ..Default::default() }), failure)
    }

    fn new(kind: Kind, failure: Arc<Mutex<Option<String>>>) -> Self {
        Self { kind, frames_in_step: 0, started: Instant::now(), failure }
    }

    /// The benchmark holds the view still: frames are drawn only when something arrives.
    fn holds_still(&self) -> bool {
        matches!(&self.kind, Kind::Bench(b) if b.step == BenchStep::WaitStill)
    }

    fn fail(&self, message: String) {
        *self.failure.lock().expect("not poisoned") = Some(message);
    }

    /// The newest request's visible region (`rect`) is on screen: the benchmark's last stroke
    /// takes its time.
    pub(super) fn visible_region_shown(&mut self, rect: [u32; 4]) {
        if let Kind::Bench(b) = &mut self.kind
            && let Some(s) = b.strokes.last_mut()
            && s.partial_ms.is_none()
        {
            s.partial_ms = Some(s.at.elapsed().as_secs_f64() * 1e3);
            s.partial_px = rect[2] as u64 * rect[3] as u64;
        }
    }

    /// The newest request's whole restoration is done: the benchmark's last stroke takes its time.
    pub(super) fn restoration_shown(&mut self) {
        if let Kind::Bench(b) = &mut self.kind
            && let Some(s) = b.strokes.last_mut()
            && s.full_ms.is_none()
        {
            s.full_ms = Some(s.at.elapsed().as_secs_f64() * 1e3);
        }
    }
}

impl App {
    /// Advances a scripted session by one frame.
    pub(super) fn drive_script(&mut self, ctx: &egui::Context) {
        let Some(mut script) = self.script.take() else { return };
        // Every frame drawn, except while the benchmark holds the view still.
        if !script.holds_still() {
            ctx.request_repaint();
        }
        script.frames_in_step += 1;
        let clock = Clock {
            frames_in_step: script.frames_in_step,
            started: script.started,
            idle: self.jobs.running.is_none() && self.dialogs.offer_missing.is_empty(),
        };
        let (then, result) = match &mut script.kind {
            Kind::Screenshots(s) => {
                let (then, result) = self.screenshot_frame(ctx, s, &clock);
                (then.apply(&mut s.step), result)
            }
            Kind::Bench(b) => {
                let (then, result) = self.bench_frame(ctx, b, &clock);
                (then.apply(&mut b.step), result)
            }
        };
        match then {
            Then::Stay => {}
            Then::Go(()) => script.frames_in_step = 0,
            Then::Hold => {
                self.script = Some(script);
                return;
            }
            Then::End => {
                if let Err(e) = result {
                    script.fail(format!("{e:#}"));
                }
                return;
            }
        }
        if let Some((step, msg)) = &self.jobs.failed {
            script.fail(format!("{}: {msg}", step.map_or("saving", |s| s.name())));
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        if let Err(e) = result {
            script.fail(format!("{e:#}"));
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        self.script = Some(script);
    }

    fn screenshot_frame(
        &mut self,
        ctx: &egui::Context,
        s: &mut Screenshots,
        clock: &Clock,
    ) -> Frame<ShotStep> {
        let n = match s.step {
            ShotStep::Close => {
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                return (Then::Stay, Ok(()));
            }
            ShotStep::View(n) => n,
        };
        // Wait for the project's steps, and a few frames for the view to settle.
        if !clock.idle || clock.frames_in_step < 3 {
            if clock.started.elapsed() > SCREENSHOTS_WAIT {
                return (Then::Stay, Err(anyhow!("the project's steps did not finish within 10 minutes")));
            }
            return (Then::Stay, Ok(()));
        }
        let views = screenshot_views();
        self.view.shown = views[n];
        self.view.transform = None;
        if !s.waiting && clock.frames_in_step >= 6 {
            let slot = s.shot.clone();
            let c = ctx.clone();
            ctx.request_screenshot(move |img| {
                *slot.lock().expect("not poisoned") = Some(img);
                c.request_repaint();
            });
            s.waiting = true;
        }
        let taken = s.shot.lock().expect("not poisoned").take();
        let Some(img) = taken else { return (Then::Stay, Ok(())) };
        s.waiting = false;
        let name = match views[n] {
            Shown::One(v) => v.slug(),
            Shown::BeforeAfter => "before_after".into(),
        };
        let saved = save_shot(&img, &s.dir.join(format!("{n:02}-{name}.png")));
        let next = if n + 1 < views.len() { ShotStep::View(n + 1) } else { ShotStep::Close };
        (Then::Go(next), saved)
    }

    fn bench_frame(&mut self, ctx: &egui::Context, b: &mut Bench, clock: &Clock) -> Frame<BenchStep> {
        let now = Instant::now();
        let pending = b.strokes.last().is_some_and(|s| s.full_ms.is_none());
        match b.step {
            BenchStep::Start => {
                if !(clock.idle
                    && clock.frames_in_step > 3
                    && self.textures.views.contains_key(&ViewKind::Photo))
                {
                    return (Then::Stay, Ok(()));
                }
                self.view.shown = Shown::One(ViewKind::Photo);
                let size = self.size();
                self.view.transform = Some(ViewTransform {
                    zoom: 1.0,
                    offset: [
                        size[0] as f32 * 0.5 - self.view.view_size[0] * 0.5,
                        size[1] as f32 * 0.5 - self.view.view_size[1] * 0.5,
                    ],
                });
                b.last = None;
                (Then::Go(BenchStep::Pan), Ok(()))
            }
            BenchStep::Pan => {
                if let Some(l) = b.last {
                    b.frame_ms.push((now - l).as_secs_f64() * 1e3);
                    b.cpu_ms.extend(self.frames.last_cpu.map(|c| c as f64 * 1e3));
                }
                b.last = Some(now);
                pan_circle(&mut self.view.transform, b.frame_ms.len());
                let done = b.frame_ms.len() >= PAN_FRAMES;
                (if done { Then::Go(BenchStep::StrokePanning) } else { Then::Stay }, Ok(()))
            }
            BenchStep::StrokePanning => {
                self.view.shown = Shown::One(ViewKind::Restored);
                (Then::Go(BenchStep::PanWhileRestoring), self.bench_stroke(b, true))
            }
            BenchStep::PanWhileRestoring => {
                if let Some(l) = b.last {
                    b.busy_ms.push((now - l).as_secs_f64() * 1e3);
                }
                b.last = Some(now);
                pan_circle(&mut self.view.transform, b.frame_ms.len() + b.busy_ms.len());
                let done = !pending && clock.idle;
                (if done { Then::Go(BenchStep::StrokeStill) } else { Then::Stay }, Ok(()))
            }
            BenchStep::StrokeStill => (Then::Go(BenchStep::WaitStill), self.bench_stroke(b, false)),
            BenchStep::WaitStill => {
                if pending && clock.started.elapsed() < BENCH_WAIT {
                    return (Then::Hold, Ok(()));
                }
                // With a stage model, go on to a compensation (a lower E_bound).
                let stage = self.project.paths.stage.is_some();
                (Then::Go(if stage { BenchStep::LowerEBound } else { BenchStep::Write }), Ok(()))
            }
            BenchStep::LowerEBound => {
                self.working.settings.compensate.e_bound_lux *= 0.9;
                self.commit_working();
                b.last = None;
                (Then::Go(BenchStep::PanWhileCompensating), Ok(()))
            }
            BenchStep::PanWhileCompensating => {
                if let Some(l) = b.last {
                    b.compensating_ms.push((now - l).as_secs_f64() * 1e3);
                }
                b.last = Some(now);
                pan_circle(&mut self.view.transform, b.frame_ms.len() + b.compensating_ms.len());
                let done = clock.idle && clock.frames_in_step > 2;
                (if done { Then::Go(BenchStep::Write) } else { Then::Stay }, Ok(()))
            }
            BenchStep::Write => {
                let written = write_bench(b, self.size());
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                (Then::End, written)
            }
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
        self.tools.brush = 6.0;
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
