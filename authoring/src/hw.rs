//! The stage hardware behind small traits: a camera that grabs linear images, projector
//! outputs that show 8-bit RGB frames, the room's diffuse light, and an injected clock.
//! Real devices and the virtual stage implement the same traits, so one acquisition loop
//! (`acquire`) drives both.

use std::time::Duration;

use image::RgbImage;
use thiserror::Error;

use crate::capture_set::CameraIntrinsics;
use crate::imgio::LinearImage;

/// Errors from a hardware device (real or simulated).
#[derive(Debug, Error)]
pub enum HwError {
    #[error("projector {projector} does not exist (the stage has {count})")]
    NoSuchProjector { projector: usize, count: usize },
    #[error("frame for projector {projector} is {got_w}x{got_h}, expected {want_w}x{want_h}")]
    FrameSize { projector: usize, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    #[error("{device}: {problem}")]
    Device { device: String, problem: String },
}

/// A camera with known intrinsics that returns linear-light images (0..1 of full scale).
pub trait Camera {
    fn intrinsics(&self) -> CameraIntrinsics;
    /// Takes one exposure of whatever the stage shows now.
    fn grab(&mut self) -> Result<LinearImage, HwError>;
}

/// A set of projectors, each showing one 8-bit RGB frame (device values) at its resolution.
pub trait ProjectorOutput {
    fn projector_count(&self) -> usize;
    /// `(width, height)` of projector `projector`.
    fn resolution(&self, projector: usize) -> Result<(u32, u32), HwError>;
    /// Shows `frame` on projector `projector` until the next call for that projector.
    fn show(&mut self, projector: usize, frame: &RgbImage) -> Result<(), HwError>;
}

/// The room's diffuse light, on for the diffusely lit photo and off for structured light.
pub trait DiffuseLight {
    fn set_diffuse(&mut self, on: bool) -> Result<(), HwError>;
}

/// Injected time: acquisition waits for projectors and camera to settle through this, so
/// simulations and tests do not sleep.
pub trait Clock {
    fn now(&self) -> Duration;
    fn sleep(&mut self, duration: Duration);
}

/// The wall clock, for real hardware.
#[derive(Debug)]
pub struct SystemClock {
    start: std::time::Instant,
}

impl Default for SystemClock {
    fn default() -> Self {
        Self { start: std::time::Instant::now() }
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.start.elapsed()
    }
    fn sleep(&mut self, duration: Duration) {
        std::thread::sleep(duration);
    }
}

/// A clock that only advances when asked to sleep: for simulations and tests.
#[derive(Debug, Default)]
pub struct FakeClock {
    now: Duration,
}

impl Clock for FakeClock {
    fn now(&self) -> Duration {
        self.now
    }
    fn sleep(&mut self, duration: Duration) {
        self.now += duration;
    }
}

/// A stage assembled from separate devices: a camera, the projector outputs and the room
/// light. The acquisition loop needs all three behind one value.
#[derive(Debug)]
pub struct Rig<C, P, L> {
    pub camera: C,
    pub projectors: P,
    pub light: L,
}

impl<C: Camera, P, L> Camera for Rig<C, P, L> {
    fn intrinsics(&self) -> CameraIntrinsics {
        self.camera.intrinsics()
    }
    fn grab(&mut self) -> Result<LinearImage, HwError> {
        self.camera.grab()
    }
}

impl<C, P: ProjectorOutput, L> ProjectorOutput for Rig<C, P, L> {
    fn projector_count(&self) -> usize {
        self.projectors.projector_count()
    }
    fn resolution(&self, projector: usize) -> Result<(u32, u32), HwError> {
        self.projectors.resolution(projector)
    }
    fn show(&mut self, projector: usize, frame: &RgbImage) -> Result<(), HwError> {
        self.projectors.show(projector, frame)
    }
}

impl<C, P, L: DiffuseLight> DiffuseLight for Rig<C, P, L> {
    fn set_diffuse(&mut self, on: bool) -> Result<(), HwError> {
        self.light.set_diffuse(on)
    }
}

/// A frame of one colour, e.g. all black.
pub fn uniform_frame(width: u32, height: u32, rgb: [u8; 3]) -> RgbImage {
    RgbImage::from_pixel(width, height, image::Rgb(rgb))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fake_clock_advances_only_when_sleeping() {
        let mut c = FakeClock::default();
        assert_eq!(c.now(), Duration::ZERO);
        c.sleep(Duration::from_millis(40));
        c.sleep(Duration::from_millis(2));
        assert_eq!(c.now(), Duration::from_millis(42));
    }
}
