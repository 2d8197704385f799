//! A checked choice of level per brick (issue 19): which level every brick of a grid is drawn
//! at, with the rules the cache's continuity needs (adjacent drawn bricks at most one level
//! apart, blocks of a block level whole and aligned, no more levels than the bricks take) and
//! each brick's coarser-neighbour bits. A plan holds no samples: the level grids
//! ([`super::LevelGrid`]) or a level store supply them.

use super::PyramidError;
use crate::bricks::BrickGrid;
use crate::cache::tables::coarser_neighbour_bits;
use crate::cache::{block_bricks, block_origin, min_brick_size_for_levels};
use crate::lod::check_level_rule_with;
use glam::UVec3;

/// Every brick's level (or `None`: not drawn), checked, with its coarser-neighbour bits.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LevelPlan {
    brick_size: u32,
    bricks: UVec3,
    levels: u32,
    brick_levels: Vec<Option<u32>>,
    coarser_bits: Vec<u32>,
}

impl LevelPlan {
    /// The plan that draws `grid`'s bricks at `brick_levels` (one per brick, linear index; `None`
    /// for a brick that is not drawn), out of `levels` levels (0 up to `levels`, exclusive).
    ///
    /// Errors: no levels, more levels than the brick size allows
    /// ([`min_brick_size_for_levels`]), a brick-level count other than the brick count, a brick
    /// at a level past the last, a block level's block not whole, or adjacent drawn bricks more
    /// than one level apart.
    pub fn new(
        grid: &BrickGrid,
        levels: u32,
        brick_levels: &[Option<u32>],
    ) -> Result<Self, PyramidError> {
        if levels == 0 {
            return Err(PyramidError::NoLevels);
        }
        let n = grid.brick_size();
        let min_brick_size = min_brick_size_for_levels(levels);
        if levels > 31 || n < min_brick_size {
            return Err(PyramidError::TooManyLevels {
                levels: levels as usize,
                min_brick_size,
                brick_size: n,
            });
        }
        if brick_levels.len() != grid.brick_count() {
            return Err(PyramidError::BrickLevelCount {
                given: brick_levels.len(),
                bricks: grid.brick_count(),
            });
        }
        if let Some((brick, level)) = brick_levels
            .iter()
            .enumerate()
            .find_map(|(i, l)| l.filter(|&l| l >= levels).map(|l| (i, l)))
        {
            return Err(PyramidError::UnknownLevel {
                brick,
                level,
                levels: levels as usize,
            });
        }
        if !check_level_rule_with(grid, |i| brick_levels[i]) {
            return Err(PyramidError::LevelRule);
        }
        check_blocks(grid, brick_levels)?;
        let coarser_bits = grid
            .bricks()
            .map(|b| coarser_neighbour_bits(grid, b, |i| brick_levels[i]))
            .collect();
        Ok(Self {
            brick_size: n,
            bricks: grid.bricks_per_axis(),
            levels,
            brick_levels: brick_levels.to_vec(),
            coarser_bits,
        })
    }

    /// Brick size `n` in hi-res voxels.
    pub fn brick_size(&self) -> u32 {
        self.brick_size
    }

    /// Bricks per axis.
    pub fn bricks_per_axis(&self) -> UVec3 {
        self.bricks
    }

    /// Levels the plan chooses from (0 up to this, exclusive).
    pub fn level_count(&self) -> u32 {
        self.levels
    }

    /// The level of linear brick `brick`, `None` when it is not drawn.
    pub fn brick_level(&self, brick: usize) -> Option<u32> {
        self.brick_levels[brick]
    }

    /// Every brick's level, linear index.
    pub fn brick_levels(&self) -> &[Option<u32>] {
        &self.brick_levels
    }

    /// The coarser bits of linear brick `brick` (see [`coarser_neighbour_bits`]).
    pub fn coarser_bits(&self, brick: usize) -> u32 {
        self.coarser_bits[brick]
    }
}

/// Checks that every drawn brick of a block level lies in an aligned block (clipped to the grid)
/// whose bricks are all drawn at that level.
fn check_blocks(grid: &BrickGrid, brick_levels: &[Option<u32>]) -> Result<(), PyramidError> {
    for (brick, b) in grid.bricks().enumerate() {
        let Some(level) = brick_levels[brick] else {
            continue;
        };
        let block = block_bricks(level);
        if block == 1 {
            continue;
        }
        let first = block_origin(b, level);
        let last = (first + UVec3::splat(block)).min(grid.bricks_per_axis());
        for z in first.z..last.z {
            for y in first.y..last.y {
                for x in first.x..last.x {
                    if brick_levels[grid.linear_index(UVec3::new(x, y, z))] != Some(level) {
                        return Err(PyramidError::BrokenBlock {
                            brick,
                            level,
                            block,
                        });
                    }
                }
            }
        }
    }
    Ok(())
}
