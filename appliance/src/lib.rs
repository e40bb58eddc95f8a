//! restage-appliance: the unattended stage player (state machine, ledger, outputs, inputs).

pub mod output;
