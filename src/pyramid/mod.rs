//! The levels themselves, in production code: each level's samples on the global grid
//! ([`LevelGrid`], built level by level with one downsampling sum), a checked level per brick
//! ([`LevelPlan`]: the one-level rule, whole blocks, coarser bits) and where a plan's drawn
//! bricks go in the cache ([`LevelPacking`]); a volume's levels with level 0 read on demand
//! ([`VolumeLevels`]). The stores, the streamers and the GPU staging
//! build on these; the CPU reference (`reference`) consumes them and is never imported here.

mod grid;
mod packing;
mod plan;
mod volume_levels;

pub use grid::{
    box_values, downsample_sum, downsample_taps, level_one_taps, LevelGrid, PyramidError,
    SamplePlacement,
};
pub use packing::{LevelPacking, PackingError};
pub use plan::LevelPlan;
pub use volume_levels::VolumeLevels;
