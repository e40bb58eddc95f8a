//! restage-shared: the code both the authoring tool and the stage appliance must agree on —
//! the bundle format, keys, the light model and the exposure policy. No GPU, no hardware.

pub mod bundle;
pub mod keys;
pub mod light;
pub mod policy;
