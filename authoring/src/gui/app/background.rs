//! The window's side of the worker thread (`jobs`): requests go out under a new generation,
//! and each frame takes its messages in (progress, pictures, figures, failures, the log).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use super::App;
use crate::gui::doc::SceneFigures;
use crate::gui::doc::{Scene, Step, Steps};
use crate::gui::jobs::{Msg, Request, Worker};
use crate::gui::views::ViewKind;

/// The request being worked on, as the status line shows it.
pub(super) struct Running {
    pub(super) generation: u64,
    pub(super) done: usize,
    pub(super) total: usize,
    pub(super) step: Option<Step>,
    pub(super) started: Instant,
}

/// Work in the background: what was asked, how far it got, and what came back.
pub(super) struct JobState {
    pub(super) worker: Worker,
    /// The newest request's: messages of older ones are stale.
    pub(super) generation: u64,
    pub(super) running: Option<Running>,
    pub(super) figures: HashMap<Scene, SceneFigures>,
    /// The step that failed (`None`: saving) and why.
    pub(super) failed: Option<(Option<Step>, String)>,
    /// Outputs that could not be read back for showing, and why.
    pub(super) unreadable: Vec<(Step, String)>,
    /// The activity log's last 200 lines (each also goes to tracing).
    log: Vec<String>,
}

impl JobState {
    pub(super) fn new(worker: Worker) -> Self {
        Self {
            worker,
            generation: 0,
            running: None,
            figures: HashMap::new(),
            failed: None,
            unreadable: Vec::new(),
            log: Vec::new(),
        }
    }

    pub(super) fn log(&mut self, line: String) {
        tracing::info!("{line}");
        self.log.push(line);
        if self.log.len() > 200 {
            self.log.remove(0);
        }
    }
}

impl App {
    /// Asks the worker for `steps` on the document as it is now (the `visible` pixels first).
    pub(super) fn submit(&mut self, steps: Steps, visible: Option<[u32; 4]>) {
        if steps.is_empty() {
            return;
        }
        let j = &mut self.jobs;
        j.generation += 1;
        j.failed = None;
        j.worker.submit(Request {
            generation: j.generation,
            steps,
            small: self.doc.small.clone(),
            hints: Arc::new(self.doc.hints.clone()),
            visible,
        });
        j.running = Some(Running {
            generation: j.generation,
            done: 0,
            total: steps.len(),
            step: None,
            started: Instant::now(),
        });
    }

    pub(super) fn poll_worker(&mut self) {
        while let Ok(m) = self.jobs.worker.messages.try_recv() {
            match m {
                Msg::Progress { generation, done, total, step } => {
                    if let Some(r) = self.jobs.running.as_mut().filter(|r| r.generation <= generation) {
                        r.generation = generation;
                        r.done = done;
                        r.total = total;
                        r.step = Some(step);
                    }
                }
                // A visible-region result of a superseded request would draw an old picture.
                Msg::Partial { generation, .. } if generation != self.jobs.generation => {}
                Msg::Partial { rect, image, seconds, .. } => {
                    // (A picture shown downscaled waits for the whole result.)
                    if let Some(t) = self.textures.views.get(&ViewKind::Restored)
                        && t.image.size == t.size
                    {
                        self.textures.gpu.update(&t.image, rect, image.as_raw());
                    }
                    self.jobs.log(format!("visible region restored first in {seconds:.2} s"));
                    if let Some(s) = &mut self.script {
                        s.visible_region_shown(rect);
                    }
                }
                Msg::Image { view, image } => {
                    let size = self.size();
                    self.textures.set_view(view, &image, size);
                    if view == ViewKind::Classes {
                        // The palette may bring new display colours for the hint overlay.
                        self.refresh_colours();
                        self.textures.refresh_overlay(&self.doc.hints, None);
                    }
                }
                Msg::Figures { scene, figures } => {
                    self.jobs.figures.insert(scene, figures);
                }
                Msg::StepDone { generation, step, seconds } => {
                    self.jobs.unreadable.retain(|(s, _)| *s != step);
                    self.jobs.log(format!("{} done in {seconds:.2} s", step.name()));
                    if step == Step::Restore
                        && generation == self.jobs.generation
                        && let Some(s) = &mut self.script
                    {
                        s.restoration_shown();
                    }
                }
                Msg::Done { generation, seconds } => {
                    if self.jobs.running.as_ref().is_some_and(|r| r.generation <= generation)
                        && generation == self.jobs.generation
                    {
                        self.jobs.running = None;
                    }
                    self.jobs.log(format!("up to date ({seconds:.1} s)"));
                }
                Msg::Cancelled { generation } => {
                    if generation == self.jobs.generation {
                        self.jobs.running = None;
                        self.jobs.log("cancelled".into());
                    }
                }
                Msg::Failed { generation, step, message } => {
                    if generation == self.jobs.generation {
                        self.jobs.running = None;
                    }
                    self.jobs.log(format!("failed: {message}"));
                    self.jobs.failed = Some((step, message));
                }
                Msg::Unreadable { step, message } => {
                    self.jobs.log(format!("cannot show {}: {message}", step.name()));
                    self.jobs.unreadable.push((step, message));
                }
            }
        }
    }
}
