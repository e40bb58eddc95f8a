//! The tool's background work: a worker thread runs the stale steps of the newest request,
//! each as the command line `steps.sh` records (parsed by the CLI's own parser and run in this
//! process, with the stage model, its preparation and the virtual stage kept between runs),
//! sends progress, pictures and figures, and stops between steps when cancelled or superseded.
//! A hint stroke's restoration is first computed for the visible part only, so the picture
//! under the brush updates before the whole image is done.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::time::Instant;

use anyhow::{Context, Result};
use image::RgbaImage;
use restage_authoring::compensate::Prepared;
use restage_authoring::imgio::LinearImage;
use restage_authoring::restore::{self, HintMap, Region, Shape};
use restage_authoring::stage_model::StageModel;
use restage_authoring::stage_sim::{self, VirtualStage};

use super::doc::{HintLayer, Scene, SceneFigures, Small, Step, Steps};
use super::project::{CLASSIFY_DIR, Project, RELIT_FILE, RESTORE_DIR};
use super::views::ViewKind;
use crate::steps::{self, StepCommand};

/// What the window asks for.
#[derive(Clone, Debug)]
pub struct Request {
    pub generation: u64,
    pub steps: Steps,
    pub small: Small,
    pub hints: Arc<HintLayer>,
    /// The image pixels on screen `[x, y, w, h]`: a restoration runs there first.
    pub visible: Option<[u32; 4]>,
}

/// What the worker reports.
#[derive(Debug)]
pub enum Msg {
    /// Step `done + 1` of `total` is starting (`step`).
    Progress {
        generation: u64,
        done: usize,
        total: usize,
        step: Step,
    },
    /// The visible region's restoration, ahead of the whole: pixels `rect` of the restored view.
    Partial {
        generation: u64,
        rect: [u32; 4],
        image: RgbaImage,
        seconds: f64,
    },
    /// A picture for a view, fresh from its step's output files.
    Image {
        view: ViewKind,
        image: Arc<RgbaImage>,
    },
    Figures {
        scene: Scene,
        figures: SceneFigures,
    },
    StepDone {
        generation: u64,
        step: Step,
        seconds: f64,
    },
    Done {
        generation: u64,
        seconds: f64,
    },
    Cancelled {
        generation: u64,
    },
    /// A step failed; the steps after it did not run.
    Failed {
        generation: u64,
        step: Option<Step>,
        message: String,
    },
    /// A file could not be shown (named in the message); the step that makes it can be re-run.
    Unreadable {
        step: Step,
        message: String,
    },
}

/// The worker thread's handle.
pub struct Worker {
    requests: Sender<Request>,
    pub messages: Receiver<Msg>,
    cancel: Arc<AtomicBool>,
}

/// Lowers the calling thread's priority (its niceness, on Linux) below the window's threads.
fn background_priority() {
    if let Err(e) = thread_priority::set_current_thread_priority(thread_priority::ThreadPriority::Min) {
        tracing::debug!("worker thread keeps its priority: {e:?}");
    }
}

impl Worker {
    /// Starts the worker on `project`; it first loads the pictures of every step on disk.
    /// `wake` is called after each message (the window repaints).
    pub fn start(project: Project, wake: impl Fn() + Send + 'static) -> Self {
        let (requests, rx) = channel::<Request>();
        let (tx, messages) = channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let flag = cancel.clone();
        std::thread::Builder::new()
            .name("restage-gui-worker".into())
            .spawn(move || {
                // One core fewer than the machine has, and every worker thread at the lowest
                // priority, so the window keeps drawing while a step runs (results do not
                // depend on the thread count).
                background_priority();
                let threads =
                    std::thread::available_parallelism().map_or(1, |n| n.get().saturating_sub(1).max(1));
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .start_handler(|_| background_priority());
                match pool.build() {
                    Ok(pool) => pool.install(move || serve(Runner::new(project), &rx, &tx, &flag, &wake)),
                    Err(e) => tracing::error!("cannot start the worker's threads: {e}"),
                }
            })
            .expect("spawning the worker thread");
        Self { requests, messages, cancel }
    }

    pub fn submit(&self, req: Request) {
        let _ = self.requests.send(req);
    }

    /// Asks the running request to stop after its current step.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::SeqCst);
    }
}

/// The worker's loop: first the pictures already on disk, then requests until the window
/// goes away; a newer request supersedes the running one between steps.
fn serve(mut runner: Runner, rx: &Receiver<Request>, tx: &Sender<Msg>, flag: &AtomicBool, wake: &dyn Fn()) {
    let mut send = |m: Msg| {
        let _ = tx.send(m);
        wake();
    };
    runner.load_all_views(&mut send);
    let mut next: Option<Request> = None;
    loop {
        let req = match next.take() {
            Some(r) => r,
            None => match rx.recv() {
                Ok(r) => r,
                Err(_) => return,
            },
        };
        flag.store(false, Ordering::SeqCst);
        let mut newer = None;
        let stop = || {
            flag.load(Ordering::SeqCst) || {
                match rx.try_recv() {
                    Ok(r) => {
                        newer = Some(r);
                        true
                    }
                    Err(TryRecvError::Empty) => false,
                    Err(TryRecvError::Disconnected) => true,
                }
            }
        };
        let left = runner.run(&req, stop, &mut send);
        if let Some(mut n) = newer {
            // What this run did not get to is still stale under the newer document.
            n.steps = n.steps.union(left);
            next = Some(n);
        }
    }
}

/// Runs requests; owns what is kept between runs.
pub struct Runner {
    pub project: Project,
    stage: Option<(PathBuf, u32, Arc<StageModel>, Arc<Prepared>)>,
    virtual_stage: Option<Arc<VirtualStage>>,
}

impl Runner {
    pub fn new(project: Project) -> Self {
        Self { project, stage: None, virtual_stage: None }
    }

    /// Runs `req`'s steps in order, checking `stop` between steps (and within a restoration,
    /// between its visible region and the whole). Returns the steps it did not finish (empty
    /// when everything ran).
    pub fn run(&mut self, req: &Request, mut stop: impl FnMut() -> bool, send: &mut dyn FnMut(Msg)) -> Steps {
        let t0 = Instant::now();
        let g = req.generation;
        let steps: Steps =
            req.steps.iter().filter(|s| self.project.can_run(*s, &req.small).is_ok()).collect();
        let total = steps.len();
        let mut left = steps;
        if let Err(e) = self.project.save(&req.small, &req.hints) {
            send(Msg::Failed { generation: g, step: None, message: format!("saving the project: {e:#}") });
            return left;
        }
        for (done, step) in steps.iter().enumerate() {
            if stop() {
                send(Msg::Cancelled { generation: g });
                return left;
            }
            send(Msg::Progress { generation: g, done, total, step });
            let ts = Instant::now();
            match self.run_step(step, req, &mut stop, send) {
                Ok(true) => {}
                Ok(false) => {
                    send(Msg::Cancelled { generation: g });
                    return left;
                }
                Err(e) => {
                    send(Msg::Failed { generation: g, step: Some(step), message: format!("{e:#}") });
                    return left;
                }
            }
            left.remove(step);
            send(Msg::StepDone { generation: g, step, seconds: ts.elapsed().as_secs_f64() });
            self.load_views(step, send);
        }
        send(Msg::Done { generation: g, seconds: t0.elapsed().as_secs_f64() });
        Steps::NONE
    }

    /// Runs one step's command lines; `Ok(false)` when `stop` said so part way.
    fn run_step(
        &mut self,
        step: Step,
        req: &Request,
        stop: &mut dyn FnMut() -> bool,
        send: &mut dyn FnMut(Msg),
    ) -> Result<bool> {
        let dir = self.project.dir.clone();
        if step == Step::Restore && req.steps.contains(Step::Classify) {
            // The classification just ran: its palette may give the classes new colours.
            self.project.write_hints(&req.small, &req.hints)?;
        }
        let lines = self.project.commands(step, &req.small, &req.hints, &dir);
        for (i, line) in lines.iter().enumerate() {
            let command = steps::parse_line(line)?;
            if step == Step::Restore
                && let StepCommand::Restore(args) = &command
                && let Some(rect) = req.visible
                && req.small.settings.restore.regions.is_empty()
            {
                self.restore_visible_first(args, rect, req.generation, send)?;
                // The visible part is on screen: a newer stroke (or Cancel) need not wait
                // for the whole image.
                if stop() {
                    return Ok(false);
                }
            }
            match command {
                StepCommand::Compensate(args) => {
                    let (model, prep) = self.prepared(&args.stage_dir, args.reduction)?;
                    steps::compensate::run_prepared(&args, &model, &prep)?;
                }
                StepCommand::Render(args) => {
                    let stage = self.virtual_stage(&args.capture)?;
                    if let Some(parent) = args.out.parent() {
                        std::fs::create_dir_all(parent)?;
                    }
                    steps::render::run_with(&args, &stage)?;
                }
                other => {
                    other.run(&steps::Quiet)?;
                }
            }
            tracing::debug!("{} line {} done", step.name(), i + 1);
        }
        Ok(true)
    }

    /// Restores only `rect` (the visible pixels) and sends that part of the picture. The
    /// label map is cut to the rectangle plus a margin, so the work is the visible part's,
    /// and the rectangle is the region (its border anchors contours as in the whole image).
    fn restore_visible_first(
        &self,
        args: &steps::restore::RestoreArgs,
        rect: [u32; 4],
        generation: u64,
        send: &mut dyn FnMut(Msg),
    ) -> Result<()> {
        const MARGIN: u32 = 16;
        let t0 = Instant::now();
        let inputs = steps::restore::load_inputs(args)?;
        let [x, y, width, height] = rect;
        let (w, h) = (inputs.labels.width, inputs.labels.height);
        let (x0, y0) = (x.saturating_sub(MARGIN), y.saturating_sub(MARGIN));
        let (x1, y1) = ((x + width + MARGIN).min(w), (y + height + MARGIN).min(h));
        let (cw, ch) = (x1 - x0, y1 - y0);
        let cut = |data: &[u8]| -> Vec<u8> {
            (y0..y1)
                .flat_map(|row| &data[(row * w + x0) as usize..(row * w + x1) as usize])
                .copied()
                .collect()
        };
        let labels = restore::LabelMap { width: cw, height: ch, data: cut(&inputs.labels.data) };
        let hints = inputs.hints.as_ref().map(|m| HintMap { width: cw, height: ch, labels: cut(&m.labels) });
        let region = Region {
            shape: Shape::Rect { x: x - x0, y: y - y0, width, height },
            background: args.background,
        };
        let params = restore::RestoreParams { grid: (cw.div_ceil(256), ch.div_ceil(256)), ..inputs.params };
        let restored = restore::restore(&labels, &inputs.info, &[region], hints.as_ref(), &params)?;
        let full = restore::render_labels(&restored.labels, &inputs.colours);
        let part = image::imageops::crop_imm(&full, x - x0, y - y0, width, height).to_image();
        let image = image::DynamicImage::ImageRgb8(part).to_rgba8();
        send(Msg::Partial { generation, rect, image, seconds: t0.elapsed().as_secs_f64() });
        Ok(())
    }

    fn prepared(&mut self, dir: &Path, reduction: u32) -> Result<(Arc<StageModel>, Arc<Prepared>)> {
        if let Some((d, r, m, p)) = &self.stage
            && d == dir
            && *r == reduction
        {
            return Ok((m.clone(), p.clone()));
        }
        let model = Arc::new(
            StageModel::load(dir)
                .with_context(|| format!("loading the stage model from {}", dir.display()))?,
        );
        let prep = Arc::new(Prepared::new(&model, reduction).context("preparing the stage model")?);
        self.stage = Some((dir.to_path_buf(), reduction, model.clone(), prep.clone()));
        Ok((model, prep))
    }

    fn virtual_stage(&mut self, capture: &Path) -> Result<Arc<VirtualStage>> {
        if let Some(s) = &self.virtual_stage {
            return Ok(s.clone());
        }
        let config = stage_sim::load_config(capture)?;
        let s = Arc::new(VirtualStage::new(&config)?);
        self.virtual_stage = Some(s.clone());
        Ok(s)
    }

    /// Sends the pictures of every step whose outputs exist, and the photo.
    pub fn load_all_views(&self, send: &mut dyn FnMut(Msg)) {
        match LinearImage::load(&self.project.path(&self.project.paths.photo)) {
            Ok(p) => send(Msg::Image { view: ViewKind::Photo, image: Arc::new(rgba(p.to_srgb8(1.0))) }),
            Err(e) => send(Msg::Unreadable { step: Step::Classify, message: format!("{e:#}") }),
        }
        for step in Step::ALL {
            if self.project.outputs(step).iter().all(|p| p.is_file()) {
                self.load_views(step, send);
            }
        }
    }

    /// Reads a step's output files into pictures (and figures) for the window.
    pub fn load_views(&self, step: Step, send: &mut dyn FnMut(Msg)) {
        let p = &self.project;
        let result = (|| -> Result<()> {
            match step {
                Step::Classify => {
                    let (labels_path, _, preview_path) =
                        restage_authoring::classify::output_paths(&p.path(CLASSIFY_DIR));
                    send(Msg::Image { view: ViewKind::Classes, image: Arc::new(load_rgba(&preview_path)?) });
                    let labels = restage_authoring::classify::LabelMap::load(&labels_path)?;
                    let mut img = RgbaImage::new(labels.width, labels.height);
                    for (px, &l) in img.pixels_mut().zip(&labels.data) {
                        let c = if l == restage_authoring::classify::MASKED {
                            [0; 3]
                        } else {
                            restage_authoring::color::categorical(l as usize)
                        };
                        px.0 = [c[0], c[1], c[2], 255];
                    }
                    send(Msg::Image { view: ViewKind::ClassesFalse, image: Arc::new(img) });
                    if let Some(mask_path) = p.shown_mask().filter(|m| m.is_file()) {
                        let photo = LinearImage::load(&p.path(&p.paths.photo))?;
                        let mask =
                            restage_authoring::segment::load_mask(&mask_path, photo.width, photo.height)?;
                        send(Msg::Image {
                            view: ViewKind::Object,
                            image: Arc::new(tinted(photo.to_srgb8(1.0), &mask)),
                        });
                    }
                }
                Step::Restore => {
                    let path = p.path(RESTORE_DIR).join(restore::io::RESTORED_FILE);
                    send(Msg::Image { view: ViewKind::Restored, image: Arc::new(load_rgba(&path)?) });
                }
                Step::Relight => {
                    send(Msg::Image {
                        view: ViewKind::Relit,
                        image: Arc::new(load_rgba(&p.path(RELIT_FILE))?),
                    });
                }
                s => {
                    let scene = s.scene().expect("a compensation step");
                    let dir = p.comp_dir(scene);
                    let figures = SceneFigures::of(&restage_authoring::compensate::io::Summary::load(&dir)?);
                    let scale = figures.scale;
                    send(Msg::Figures { scene, figures });
                    let heat = dir.join("report").join("irradiance.png");
                    send(Msg::Image {
                        view: ViewKind::Irradiance(scene),
                        image: Arc::new(load_rgba(&heat)?),
                    });
                    if p.has_virtual_stage() {
                        let linear = p.preview_file(scene).1;
                        let view = LinearImage::load(&linear)?;
                        // Exposure normalised by the global scale, as the demo's contact sheet.
                        let gain = (1.0 / scale.max(1e-9)) as f32;
                        send(Msg::Image {
                            view: ViewKind::Visitor(scene),
                            image: Arc::new(rgba(view.to_srgb8(gain))),
                        });
                    }
                }
            }
            Ok(())
        })();
        if let Err(e) = result {
            send(Msg::Unreadable { step, message: format!("{e:#}") });
        }
    }
}

fn load_rgba(path: &Path) -> Result<RgbaImage> {
    Ok(image::open(path).with_context(|| format!("cannot read {}", path.display()))?.to_rgba8())
}

/// The photo with what is outside the object mask tinted blue and dimmed.
fn tinted(photo: image::RgbImage, mask: &[bool]) -> RgbaImage {
    let mut img = rgba(photo);
    for (px, &inside) in img.pixels_mut().zip(mask) {
        if !inside {
            let tint = [40.0, 90.0, 200.0];
            px.0 = [0, 1, 2, 3]
                .map(|c| if c == 3 { 255 } else { (0.35 * px.0[c] as f32 + 0.65 * tint[c]) as u8 });
        }
    }
    img
}

fn rgba(img: image::RgbImage) -> RgbaImage {
    image::DynamicImage::ImageRgb8(img).to_rgba8()
}
