//! talkin: the facade over the workspace crates, one per stage of the pipeline.
pub use talkin_avatar as avatar;
pub use talkin_benches as benches;
pub use talkin_data as data;
pub use talkin_export as export;
pub use talkin_grids as grids;
pub use talkin_human as human;
pub use talkin_import as import;
pub use talkin_nets as nets;
pub use talkin_render as render;
pub use talkin_serve as serve;
pub use talkin_synth as synth;
pub use talkin_train as train;
