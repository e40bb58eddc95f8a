//! Projector control over the network with PJLink (JBMIA, class 1 and 2, TCP 4352): a client,
//! a simulated projector for tests, and the controller the appliance runs (power with warm-up
//! and cool-down, AV mute as a second dark layer, status polling).
//!
//! Layers, each usable alone: `protocol` (pure wire format) <- `client` (one connection per
//! operation) <- `control` (one task per projector, watch channels in and out); `sim` serves
//! the protocol on loopback; `config` is the `[pjlink]` section.

pub mod client;
pub mod config;
pub mod control;
pub mod protocol;
pub mod sim;

pub use client::{Info, PjlinkError, Poll, Projector, Session};
pub use config::{PjlinkConfig, PjlinkProjectorConfig};
pub use control::{Desired, PjlinkControl, PowerWant, ProjectorSpec, ProjectorStatus, Timing, Want};
pub use protocol::{AvMute, Class, ErrCode, ErrorStatus, Lamp, Level, PowerState};
