//! restage-shared: the code both the authoring tool and the stage appliance must agree on —
//! the bundle format, keys, the light model and the exposure policy, and how both print
//! what a bundle says (UTC times, terminal-safe text). No GPU, no hardware.

// Non-test code never unwraps, expects or panics: bad input or a fault is an error value the
// caller handles (the appliance goes dark on it), never an abort. Tests may.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod bundle;
pub mod keys;
pub mod light;
pub mod policy;
pub mod text;
pub mod time;
