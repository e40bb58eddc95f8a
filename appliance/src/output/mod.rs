//! Display outputs: one frame per projector, shown together. Implementations: DRM/KMS on the
//! stage machine, a development window, and a headless recorder for tests.

use thiserror::Error;

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
    /// Shows one frame per projector, all on the same refresh where the hardware allows.
    fn show(&mut self, frames: &[FrameRef<'_>]) -> Result<(), OutputError>;
    /// Makes every projector dark (all-black frames, or the outputs off).
    fn blank(&mut self) -> Result<(), OutputError>;
}
