//! Value ranges for culling a three-level source (issue 19, item 4): a brick whose range the
//! transfer function maps to zero opacity is left undrawn.
//!
//! A brick's range is the union of the stored ranges, at level 0 and level 1, of the brick and
//! its 26 neighbours. That covers every value a level-0 or level-1 brick reads inside it: its
//! own samples, its border texels (neighbour voxels, or fixed-up neighbour samples), the
//! level-1 field it blends towards, and the skeleton fixup's values (level-1 samples of the
//! brick and its neighbours). So at those levels, culling changes no pixel. A coarser level's
//! samples inside a culled brick are filters over a wider neighbourhood: they can carry a faint
//! spill of data from farther away, which culling leaves out. A brick is culled when the data
//! itself around it is empty, not when every filtered copy of it is; the union over all levels
//! would include the coarsest level, whose blocks span the volume, and cull nothing. Levels 0
//! and 1 are always there (a level store and a pyramid of one level hold level 0 only).

use crate::bricks::{BrickGrid, ValueRange};
use crate::cache::block_origin;
use crate::error::Result;
use glam::{IVec3, UVec3};

/// The culling range of every brick of `grid` (linear index) of a source with `levels`
/// levels (module docs): `stored_range(level, first_brick)` gives the range of the stored brick
/// of `level` (0 or 1) whose block starts at `first_brick`.
pub fn conservative_ranges(
    grid: &BrickGrid,
    levels: u32,
    stored_range: &mut dyn FnMut(u32, UVec3) -> Result<ValueRange>,
) -> Result<Vec<ValueRange>> {
    let count = grid.brick_count();
    let mut own = vec![ValueRange::EMPTY; count];
    for level in 0..levels.min(2) {
        let mut last: Option<(UVec3, ValueRange)> = None;
        for (i, b) in grid.bricks().enumerate() {
            let first = block_origin(b, level);
            let range = match last {
                Some((f, r)) if f == first => r,
                _ => {
                    let r = stored_range(level, first)?;
                    last = Some((first, r));
                    r
                }
            };
            own[i] = union(own[i], range);
        }
    }
    let size = grid.bricks_per_axis().as_ivec3();
    let mut out = own.clone();
    for (i, b) in grid.bricks().enumerate() {
        let b = b.as_ivec3();
        for z in -1..=1 {
            for y in -1..=1 {
                for x in -1..=1 {
                    let n = b + IVec3::new(x, y, z);
                    if n.cmpge(IVec3::ZERO).all() && n.cmplt(size).all() {
                        out[i] = union(out[i], own[grid.linear_index(n.as_uvec3())]);
                    }
                }
            }
        }
    }
    Ok(out)
}

/// The smallest range holding both.
fn union(a: ValueRange, b: ValueRange) -> ValueRange {
    ValueRange {
        min: a.min.min(b.min),
        max: a.max.max(b.max),
    }
}
