//! talkin: the facade over the workspace crates.
pub use talkin_engine as engine;
pub use talkin_grids as grids;
pub use talkin_nets as nets;
