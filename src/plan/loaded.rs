//! What the source has loaded, as the planner asks it: brick by brick through a closure
//! ([`super::ResidencyPlanner::plan_frame`]), or from one [`LoadedLevels`] per brick
//! ([`super::ResidencyPlanner::plan_frame_with_loaded`]), which the target pass reads in
//! blocks.

use crate::bricks::{Level, LoadedLevels};

/// The planner's question to the source: is this level of this brick loaded?
pub(super) trait Loaded {
    /// True when `brick` has its `level` bytes loaded.
    fn is_loaded(&self, brick: u32, level: Level) -> bool;

    /// The loaded levels of bricks `0..count` as bytes ([`LoadedLevels::bits`]), when this
    /// query holds them for every one of those bricks.
    fn bits(&self, count: usize) -> Option<&[u8]>;
}

/// A closure asked brick by brick.
pub(super) struct Asked<F>(pub F);

impl<F: Fn(u32, Level) -> bool> Loaded for Asked<F> {
    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        (self.0)(brick, level)
    }

    fn bits(&self, _: usize) -> Option<&[u8]> {
        None
    }
}

/// One entry per brick; bricks past the end have nothing loaded.
pub(super) struct PerBrick<'a>(pub &'a [LoadedLevels]);

impl Loaded for PerBrick<'_> {
    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        self.0
            .get(brick as usize)
            .is_some_and(|l| l.contains(level))
    }

    fn bits(&self, count: usize) -> Option<&[u8]> {
        LoadedLevels::bits(self.0).get(..count)
    }
}
