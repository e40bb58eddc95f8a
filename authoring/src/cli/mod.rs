//! The `restage-author` subcommands on a terminal: each runs its step (`crate::steps`) under a
//! progress bar and prints the step's summary. The reporting commands (`eval`, `eval-restore`,
//! `inspect`) have a file each.

pub mod eval;
pub mod eval_restore;
pub mod inspect;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};

use crate::steps::{self, Progress, StepCommand, StepSummary};

/// A step's progress on stderr: a spinner with the stage's name, a bar once it counts.
pub struct Bar {
    bar: ProgressBar,
    counting: std::sync::atomic::AtomicBool,
}

impl Bar {
    pub fn new() -> Bar {
        let bar = ProgressBar::new_spinner().with_style(spinner_style());
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        Bar { bar, counting: false.into() }
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

fn spinner_style() -> ProgressStyle {
    ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
        .unwrap_or_else(|_| ProgressStyle::default_spinner())
}

fn bar_style() -> ProgressStyle {
    ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed}")
        .map(|s| s.progress_chars("=> "))
        .unwrap_or_else(|_| ProgressStyle::default_bar())
}

impl Progress for Bar {
    fn stage(&self, what: &str) {
        if self.counting.swap(false, std::sync::atomic::Ordering::Relaxed) {
            self.bar.set_style(spinner_style());
        }
        self.bar.set_message(what.to_string());
    }

    fn count(&self, done: u64, total: u64) {
        if !self.counting.swap(true, std::sync::atomic::Ordering::Relaxed) {
            self.bar.set_style(bar_style());
        }
        self.bar.set_length(total);
        self.bar.set_position(done);
    }
}

/// Runs `f` under a progress bar, cleared before the caller prints.
fn with_bar<T>(f: impl FnOnce(&dyn Progress) -> Result<T>) -> Result<T> {
    let bar = Bar::new();
    let out = f(&bar);
    drop(bar);
    out
}

pub fn step(step: &StepCommand) -> Result<()> {
    match with_bar(|p| step.run(p))? {
        StepSummary::Mask(s) => println!("{s}"),
        StepSummary::Classify(s) => println!("{s}"),
        StepSummary::Restore(s) => println!("{s}"),
        StepSummary::Compensate(s) => eprintln!("{s}"),
        StepSummary::Relight(s) => eprintln!("{s}"),
        StepSummary::Render(s) => tracing::info!("{s}"),
    }
    Ok(())
}

pub fn capture(args: &steps::capture::CaptureArgs) -> Result<()> {
    let s = with_bar(|p| steps::capture::run(args, p))?;
    tracing::info!("{s}");
    Ok(())
}

pub fn simulate(args: &steps::simulate::Args) -> Result<()> {
    with_bar(|p| steps::simulate::run(args, p)).map(|_| ())
}

pub fn decode(args: &steps::decode::DecodeArgs) -> Result<()> {
    with_bar(|p| steps::decode::run(args, p)).map(|_| ())
}

pub fn import(args: &steps::import::ImportArgs) -> Result<()> {
    with_bar(|p| steps::import::run(args, p)).map(|_| ())
}

pub fn calibrate(args: &steps::calibrate::CalibrateArgs) -> Result<()> {
    with_bar(|p| steps::calibrate::run(args, p)).map(|_| ())
}

pub fn rig(args: &steps::rig::RigArgs) -> Result<()> {
    with_bar(|p| steps::rig::run(args, p)).map(|_| ())
}

/// The demo keeps the terminal to a screen: the steps' summary, a count of the warnings and
/// where to look next; every detail goes to `demo.log` in its folder.
pub fn demo(args: &steps::demo::Args) -> Result<()> {
    let out = steps::demo::prepare_out(args)?;
    let log = out.join("demo.log");
    crate::logging::log_to_file(&log).with_context(|| format!("creating {}", log.display()))?;
    crate::logging::quiet();
    eprintln!(
        "restage demo: the whole chain on the virtual stage, about 2 minutes on 2 cores and 1 GB of disk"
    );
    let s = with_bar(|p| steps::demo::run(args, p))?;
    tracing::info!("the bundle:\n{}{}", s.bundle, s.verified);
    eprint!("{}", s.summary);
    match crate::logging::warnings() {
        0 => eprintln!("details: {}", log.display()),
        n => eprintln!("{n} warning{}: see {}", if n == 1 { "" } else { "s" }, log.display()),
    }
    let report = [out.join("index.html"), out.join("comp/restored/report/index.html")]
        .into_iter()
        .find(|p| p.is_file())
        .unwrap_or_else(|| out.join("before_restored_target.png"));
    eprintln!("open {}; next: restage-author gui {}", report.display(), args.out.display());
    Ok(())
}

pub fn keygen(args: &steps::keygen::KeygenArgs) -> Result<()> {
    let stem = steps::keygen::stem_for(&args.out)?;
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let (id, private, public) = steps::keygen::generate(&stem)?;
    println!("key id      {id}");
    println!("private key {} (keep it secret; mode 0600)", private.display());
    println!("public key  {} (copy into the appliance's trust directory)", public.display());
    Ok(())
}

pub fn bundle(args: &steps::bundle::BundleArgs) -> Result<()> {
    let manifest = steps::bundle::write(args)?;
    print!("{}", restage_shared::bundle::describe(&manifest, None));
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Writes the man pages of `command` and its subcommands into `out`.
pub fn man(command: clap::Command, out: &std::path::Path, force: bool) -> Result<()> {
    steps::check_out(out, force)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    clap_mangen::generate_to(command, out)
        .with_context(|| format!("writing man pages into {}", out.display()))?;
    println!("man pages in {}; read one with `man -l {}/restage-author.1`", out.display(), out.display());
    Ok(())
}

pub fn verify(args: &steps::verify::VerifyArgs) -> Result<()> {
    let (lines, summary) = steps::verify::verify(args)?;
    if args.json {
        println!("{}", summary.to_json()?);
    } else {
        print!("{lines}");
    }
    Ok(())
}
