//! Calibration (paper §3 and §5.2): from a capture set to a stage model — geometry, light
//! transport, projector responses, per-pixel gain and ambient, lux scale.

pub mod lux;
pub mod photometric;
pub mod radiometry;
pub mod transport;
