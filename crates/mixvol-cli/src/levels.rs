//! The fixed level patterns of `--levels` (which bricks are resident at full resolution).

use crate::args::LevelsArg;
use mixvol::bricks::BrickGrid;
use mixvol::bricks::Level;

/// The level of every brick of `grid` under `pattern`, in linear brick order.
pub fn level_pattern(grid: &BrickGrid, pattern: LevelsArg) -> Vec<Level> {
    let half = grid.bricks_per_axis().x / 2;
    (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i);
            let hi = match pattern {
                LevelsArg::AllHi => true,
                LevelsArg::AllLo => false,
                LevelsArg::Checker => (b.x + b.y + b.z).is_multiple_of(2),
                LevelsArg::Half => b.x >= half,
            };
            if hi {
                Level::Hi
            } else {
                Level::Lo
            }
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
