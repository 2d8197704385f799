//! The fixed level patterns of `--levels` (which bricks are resident at full resolution).

use crate::args::LevelsArg;
use mixvol::bricks::BrickGrid;
use mixvol::{Error, Result};

/// The level of every brick of `grid` under a two-level `pattern` (`Some(0)` full resolution,
/// `Some(1)` the level below), in linear brick order; an error for [`LevelsArg::Staircase`]
/// ([`staircase`]) and [`LevelsArg::Camera`], which are not two-level patterns.
pub fn level_pattern(grid: &BrickGrid, pattern: LevelsArg) -> Result<Vec<Option<u32>>> {
    let half = grid.bricks_per_axis().x / 2;
    (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i);
            let hi = match pattern {
                LevelsArg::AllHi => true,
                LevelsArg::AllLo => false,
                LevelsArg::Checker => (b.x + b.y + b.z).is_multiple_of(2),
                LevelsArg::Half => b.x >= half,
                LevelsArg::Staircase | LevelsArg::Camera => {
                    return Err(Error::InvalidInput(
                        "--levels staircase and --levels camera are not fixed two-level \
                         patterns: `render` draws them (`cargo bench --bench levels` times \
                         them)"
                            .into(),
                    ))
                }
            };
            Ok(Some(if hi { 0 } else { 1 }))
        })
        .collect()
}

/// The `--levels staircase` plan of `grid`: level 0 at the first corner brick, then
/// `floor(log2 d) + 1` for a brick `d` bricks (Chebyshev) away, so each level past 2 comes in the
/// aligned blocks the three-level cache stores whole; capped at level 2 for bricks below 8
/// voxels (they take no block levels).
pub fn staircase(grid: &BrickGrid) -> Vec<Option<u32>> {
    let deepest = if grid.brick_size() < 8 { 2 } else { u32::MAX };
    (0..grid.brick_count())
        .map(|i| {
            let d = grid.brick_coords(i).max_element();
            let level = if d == 0 { 0 } else { 32 - d.leading_zeros() };
            Some(level.min(deepest))
        })
        .collect()
}

/// `levels` with levels 0 and 1 swapped (the partner pattern of `bench --churn`).
pub fn swapped(levels: &[Option<u32>]) -> Vec<Option<u32>> {
    levels
        .iter()
        .map(|l| l.map(|level| u32::from(level == 0)))
        .collect()
}

/// The deepest level of `plan` and how many bricks are drawn at each level up to it.
pub fn per_level_counts(plan: &[Option<u32>]) -> (u32, Vec<usize>) {
    let deepest = plan.iter().flatten().max().copied().unwrap_or(0);
    let counts = (0..=deepest)
        .map(|k| plan.iter().filter(|l| **l == Some(k)).count())
        .collect();
    (deepest, counts)
}
