//! Display outputs: one frame per projector, shown together. Implementations: DRM/KMS on the
//! stage machine, a development window, and a headless recorder for tests.

use thiserror::Error;

pub mod headless;
#[cfg(target_os = "linux")]
pub mod kms;
#[cfg(feature = "window")]
pub mod window;

/// A frame in scan-out layout: XRGB8888, little-endian (byte order B, G, R, X), row-major,
/// `stride == width * 4`.
#[derive(Clone, Copy, Debug)]
pub struct FrameRef<'a> {
    pub width: u32,
    pub height: u32,
    pub xrgb: &'a [u8],
}

#[derive(Debug, Error)]
pub enum OutputError {
    #[error("output {output}: {problem}")]
    Device { output: String, problem: String },
    #[error("expected {expected} frames (one per projector), got {got}")]
    FrameCount { expected: usize, got: usize },
    #[error("projector {index}: frame is {got_w}x{got_h}, the output shows {want_w}x{want_h}")]
    FrameSize { index: usize, got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
}

/// Something that shows one frame per projector. Dropping an output must leave the
/// projectors dark.
pub trait Output {
    /// Number of projectors this output drives.
    fn projector_count(&self) -> usize;
    /// Prepares every projector for frames of these sizes (one per projector, in order), e.g.
    /// sets the display mode; called when a bundle is loaded, before its first `show`. An
    /// output that cannot show them refuses clearly.
    fn set_modes(&mut self, sizes: &[(u32, u32)]) -> Result<(), OutputError> {
        if sizes.len() != self.projector_count() {
            return Err(OutputError::FrameCount { expected: self.projector_count(), got: sizes.len() });
        }
        Ok(())
    }
    /// Shows one frame per projector, all on the same refresh where the hardware allows.
    fn show(&mut self, frames: &[FrameRef<'_>]) -> Result<(), OutputError>;
    /// Makes every projector dark (all-black frames, or the outputs off).
    fn blank(&mut self) -> Result<(), OutputError>;
    /// Looks at the displays again after a hot-plug event (`InputEvent::OutputsChanged`):
    /// a projector that came back is set up again with what it should show. Outputs without
    /// hot-plug have nothing to do.
    fn reprobe(&mut self) -> Result<(), OutputError> {
        Ok(())
    }
}

/// Checks a frame set against the projector count and the sizes set by `set_modes`.
pub fn check_frames(
    projectors: usize,
    sizes: Option<&[(u32, u32)]>,
    frames: &[FrameRef<'_>],
) -> Result<(), OutputError> {
    if frames.len() != projectors {
        return Err(OutputError::FrameCount { expected: projectors, got: frames.len() });
    }
    for (index, f) in frames.iter().enumerate() {
        let (want_w, want_h) = sizes.and_then(|s| s.get(index).copied()).unwrap_or((f.width, f.height));
        if (f.width, f.height) != (want_w, want_h)
            || f.xrgb.len() != (f.width as usize) * (f.height as usize) * 4
        {
            return Err(OutputError::FrameSize { index, got_w: f.width, got_h: f.height, want_w, want_h });
        }
    }
    Ok(())
}
