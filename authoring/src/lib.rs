//! restage-authoring: the conservator's offline tool, one module per step of the data flow
//! (see ARCHITECTURE.md). Each step is a pure function of files in and files out.

pub mod acquire;
pub mod calibrate;
pub mod capture_set;
pub mod classify;
pub mod color;
pub mod compensate;
pub mod contact_sheet;
pub mod devices;
pub mod eval;
pub mod export;
pub mod gpu;
pub mod hw;
pub mod imgio;
pub mod import;
pub mod patterns;
pub mod relight;
pub mod restore;
pub mod segment;
pub mod stage_model;
pub mod stage_sim;
