//! The fixed level patterns of `--levels` (which bricks are resident at full resolution).

use crate::args::LevelsArg;
use mixvol::bricks::BrickGrid;
use mixvol::bricks::Level;
use mixvol::{Error, Result};

/// The level of every brick of `grid` under a two-level `pattern`, in linear brick order; an
/// error for [`LevelsArg::Staircase`] ([`staircase`]) and [`LevelsArg::Camera`], which draw
/// through the three-level cache.
pub fn level_pattern(grid: &BrickGrid, pattern: LevelsArg) -> Result<Vec<Level>> {
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
                        "--levels staircase and --levels camera draw through the three-level \
                         cache, which only `render` sets up (`cargo bench --bench levels` times \
                         it)"
                        .into(),
                    ))
                }
            };
            Ok(if hi { Level::Hi } else { Level::Lo })
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

/// `levels` with hi and lo swapped (the partner pattern of `bench --churn`).
pub fn swapped(levels: &[Level]) -> Vec<Level> {
    levels
        .iter()
        .map(|l| {
            if *l == Level::Hi {
                Level::Lo
            } else {
                Level::Hi
            }
        })
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
