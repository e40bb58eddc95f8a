//! restage-appliance: the unattended stage player (state machine, ledger, outputs, inputs).

pub mod clock;
pub mod config;
pub mod input;
pub mod ledger;
pub mod loader;
pub mod memory;
pub mod notify;
pub mod output;
pub mod pjlink;
pub mod player;
pub mod runtime;
pub mod show;
pub mod verify;
