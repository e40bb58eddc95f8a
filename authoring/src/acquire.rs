//! The acquisition loop: shows every pattern on every projector through the hardware traits,
//! grabs a camera image for each and writes the capture set (16-bit linear PNGs and
//! `capture.json`). Real hardware and the virtual stage run this same code.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::capture_set::{
    Axis, CAMERA_FILE, CAPTURE_VERSION, CaptureManifest, CaptureSetError, Pattern, ProjectorCapture, Shot,
    gray_bits,
};
use crate::hw::{Camera, Clock, DiffuseLight, HwError, ProjectorOutput, uniform_frame};
use crate::imgio::{ImageError, LinearImage};
use crate::patterns;

#[derive(Debug, Error)]
pub enum AcquireError {
    #[error(transparent)]
    Hw(#[from] HwError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    CaptureSet(#[from] CaptureSetError),
    #[error("cannot create or write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("acquisition setting {name} = {value} is out of range (expected {range})")]
    Setting { name: &'static str, value: u32, range: &'static str },
}

/// What to capture per projector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcquireConfig {
    /// Dot-grid spacing in projector pixels: `spacing^2` shifted grids per projector.
    pub dot_spacing: u32,
    /// Phase-shift period in projector pixels.
    pub phase_period: u32,
    pub phase_steps: u32,
    /// Gray-ramp levels per channel from 0 to 255, dense at the dark end
    /// ([`patterns::ramp_levels`]).
    pub ramp_levels: u32,
    /// Wait after showing a pattern before grabbing (projector latency, camera exposure).
    pub settle: Duration,
}

impl Default for AcquireConfig {
    fn default() -> Self {
        Self {
            dot_spacing: 16,
            phase_period: 16,
            phase_steps: 8,
            ramp_levels: 17,
            settle: Duration::from_millis(150),
        }
    }
}

impl AcquireConfig {
    pub fn validate(&self) -> Result<(), AcquireError> {
        let check = |name, value: u32, ok: bool, range| {
            if ok { Ok(()) } else { Err(AcquireError::Setting { name, value, range }) }
        };
        check("dot spacing", self.dot_spacing, (2..=64).contains(&self.dot_spacing), "2..=64")?;
        check("phase period", self.phase_period, (4..=1024).contains(&self.phase_period), "4..=1024")?;
        check("phase steps", self.phase_steps, (3..=32).contains(&self.phase_steps), "3..=32")?;
        check("ramp levels", self.ramp_levels, (2..=256).contains(&self.ramp_levels), "2..=256")
    }
}

/// The shots for one projector of `width x height`, in capture order, with file names
/// relative to the capture directory.
pub fn plan(projector: usize, width: u32, height: u32, cfg: &AcquireConfig) -> Vec<Shot> {
    let mut patterns = vec![Pattern::White, Pattern::Black];
    for (axis, extent) in [(Axis::X, width), (Axis::Y, height)] {
        for bit in 0..gray_bits(extent) {
            for inverted in [false, true] {
                patterns.push(Pattern::GrayCode { axis, bit, inverted });
            }
        }
    }
    for axis in [Axis::X, Axis::Y] {
        for step in 0..cfg.phase_steps {
            patterns.push(Pattern::Phase { axis, period: cfg.phase_period, step, steps: cfg.phase_steps });
        }
    }
    for dy in 0..cfg.dot_spacing {
        for dx in 0..cfg.dot_spacing {
            patterns.push(Pattern::Dots { spacing: cfg.dot_spacing, dx, dy });
        }
    }
    for channel in 0..3u8 {
        for level in patterns::ramp_levels(cfg.ramp_levels) {
            patterns.push(Pattern::Ramp { channel, level });
        }
    }
    patterns.into_iter().map(|pattern| shot(projector, pattern)).collect()
}

/// The shot of `pattern` for projector `projector`: its file `proj<k>/<name>.png`, the one
/// naming every writer of capture sets uses (acquisition and import).
pub fn shot(projector: usize, pattern: Pattern) -> Shot {
    let axis = |a: Axis| if a == Axis::X { 'x' } else { 'y' };
    let name = match &pattern {
        Pattern::White => "white".to_string(),
        Pattern::Black => "black".to_string(),
        Pattern::GrayCode { axis: a, bit, inverted } => {
            format!("gray_{}{bit:02}{}", axis(*a), if *inverted { "_inv" } else { "" })
        }
        Pattern::Phase { axis: a, step, .. } => format!("phase_{}{step:02}", axis(*a)),
        Pattern::Dots { dx, dy, .. } => format!("dots_{dx:02}_{dy:02}"),
        Pattern::Ramp { channel, level } => {
            format!("ramp_{}{level:03}", ['r', 'g', 'b', 'w'][(*channel as usize).min(3)])
        }
    };
    Shot { pattern, file: format!("proj{projector}/{name}.png").into() }
}

/// File of the diffusely lit photo.
pub const PHOTO_FILE: &str = "photo.png";

/// Runs the acquisition: the diffuse photo (room light on, every projector black), then for
/// each projector in turn every planned pattern (others black, room light off). Images are
/// encoded on a second thread while the next one is captured. `progress(done, total)`.
pub fn acquire<H>(
    hw: &mut H,
    clock: &mut dyn Clock,
    cfg: &AcquireConfig,
    dir: &Path,
    source: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<CaptureManifest, AcquireError>
where
    H: Camera + ProjectorOutput + DiffuseLight + ?Sized,
{
    cfg.validate()?;
    let n = hw.projector_count();
    let mut sizes = Vec::with_capacity(n);
    for k in 0..n {
        sizes.push(hw.resolution(k)?);
    }
    let plans: Vec<Vec<Shot>> = sizes.iter().enumerate().map(|(k, &(w, h))| plan(k, w, h, cfg)).collect();
    for k in 0..n {
        let sub = dir.join(format!("proj{k}"));
        std::fs::create_dir_all(&sub).map_err(|source| AcquireError::Io { path: sub, source })?;
    }
    let camera = hw.intrinsics();
    let camera_path = dir.join(CAMERA_FILE);
    let text = serde_json::to_string_pretty(&camera).expect("intrinsics serialise");
    std::fs::write(&camera_path, text).map_err(|source| AcquireError::Io { path: camera_path, source })?;

    let total = 1 + plans.iter().map(Vec::len).sum::<usize>();
    let (tx, rx) = mpsc::sync_channel::<(PathBuf, LinearImage)>(2);
    std::thread::scope(|scope| -> Result<(), AcquireError> {
        let writer = scope.spawn(move || -> Result<(), AcquireError> {
            for (path, img) in rx {
                img.save_linear16(&path)?;
            }
            Ok(())
        });
        let captured = (|| -> Result<(), AcquireError> {
            let mut done = 0;
            let send = |path: PathBuf, img: LinearImage| tx.send((path, img)).is_ok();
            for (k, &(w, h)) in sizes.iter().enumerate() {
                hw.show(k, &uniform_frame(w, h, [0; 3]))?;
            }
            hw.set_diffuse(true)?;
            clock.sleep(cfg.settle);
            let photo = hw.grab()?;
            hw.set_diffuse(false)?;
            if !send(dir.join(PHOTO_FILE), photo) {
                return Ok(()); // the writer failed; its error is reported below
            }
            done += 1;
            progress(done, total);
            for (k, shots) in plans.iter().enumerate() {
                let (w, h) = sizes[k];
                for shot in shots {
                    hw.show(k, &patterns::render(&shot.pattern, w, h))?;
                    clock.sleep(cfg.settle);
                    let img = hw.grab()?;
                    if !send(dir.join(&shot.file), img) {
                        return Ok(());
                    }
                    done += 1;
                    progress(done, total);
                }
                hw.show(k, &uniform_frame(w, h, [0; 3]))?;
            }
            Ok(())
        })();
        drop(tx);
        let written = writer.join().expect("image writer thread does not panic");
        captured.and(written)
    })?;

    let manifest = CaptureManifest {
        version: CAPTURE_VERSION,
        source: source.into(),
        camera,
        photo: PHOTO_FILE.into(),
        projectors: plans
            .into_iter()
            .enumerate()
            .map(|(k, shots)| ProjectorCapture {
                index: k as u32,
                width: sizes[k].0,
                height: sizes[k].1,
                shots,
            })
            .collect(),
    };
    manifest.save(dir)?;
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_has_every_pattern_once_with_distinct_files() {
        let cfg = AcquireConfig {
            dot_spacing: 4,
            phase_period: 16,
            phase_steps: 8,
            ramp_levels: 5,
            ..Default::default()
        };
        let shots = plan(2, 100, 60, &cfg);
        let gray = 2 * (gray_bits(100) + gray_bits(60)) as usize;
        assert_eq!(shots.len(), 2 + gray + 16 + 16 + 15);
        let mut files: Vec<_> = shots.iter().map(|s| s.file.clone()).collect();
        files.sort();
        files.dedup();
        assert_eq!(files.len(), shots.len());
        assert!(shots.iter().all(|s| s.file.starts_with("proj2")));
        assert!(shots.contains(&Shot {
            pattern: Pattern::Ramp { channel: 2, level: 255 },
            file: "proj2/ramp_b255.png".into()
        }));
    }

    #[test]
    fn bad_settings_are_refused_with_their_range() {
        let cfg = AcquireConfig { dot_spacing: 0, ..Default::default() };
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("dot spacing") && e.contains("2..=64"), "{e}");
    }
}
