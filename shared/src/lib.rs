//! restage-shared: the code both the authoring tool and the stage appliance must agree on —
//! the bundle format, the light model and the exposure policy. No GPU, no hardware.

pub mod light;
