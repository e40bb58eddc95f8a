//! restage-appliance: the unattended stage player (state machine, ledger, outputs, inputs).

// Non-test code never unwraps, expects or panics: bad input or a fault is an error value and
// the outputs go dark on it, never an abort. Tests may.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod alert_command;
pub mod alerts;
pub mod clock;
pub mod config;
pub mod export;
pub mod feedback;
pub mod hours;
pub mod identify;
pub mod inbox;
pub mod input;
pub mod install;
pub mod ledger;
pub mod loader;
pub mod logging;
pub mod memory;
pub mod notify;
pub mod output;
pub mod pjlink;
pub mod player;
pub mod runtime;
pub mod show;
pub mod status;
pub mod sysupdate;
pub mod verify;
pub mod zone;
