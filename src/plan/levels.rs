//! The level of every brick from the camera for any number of levels (issue 19, item 4, first
//! part): what the three-level cache with block levels draws for one view under its slots.
//!
//! [`choose_levels`] runs these steps:
//!
//! 0. **A cache too small** for the coarsest plan (every brick at the coarsest level) drops
//!    whole blocks of the coarsest level, the least important first (no active brick in view,
//!    then the farthest), until that plan fits; the dropped bricks are never drawn
//!    ([`LevelChoice::dropped`] counts them). Never an error.
//! 1. **Wanted level** per brick: the coarsest level `k` whose voxel (`2^k` hi-res voxels)
//!    projects to at most `target_pixels` at the brick's nearest point, `floor(log2(target /
//!    p0))` with `p0` the projected size of a hi-res voxel there, clamped to the levels. A
//!    brick outside the frustum, or culled, wants the coarsest level (it draws nothing a ray
//!    sees now, and asks for nothing).
//! 2. **The rule and the blocks**: a brick is refined to at most one level coarser than any of
//!    its 26 neighbours (a Chebyshev distance transform: two raster sweeps), and a brick of a
//!    block level whose aligned block ([`crate::cache::block_bricks`]) holds a finer brick takes
//!    the coarsest level whose block holds none ([`keep_blocks`]: an octree-like split, so that
//!    a culled corner that wants the coarsest level, whose block spans the grid, does not pull
//!    the whole volume to the finest level drawn); both are repeated until neither changes a
//!    level. Levels only ever get finer, so the plan keeps every brick at least as fine as it
//!    wanted.
//! 3. **Culled bricks** are not drawn, unless a drawn block covers them (its stored brick holds
//!    them anyway; drawing them costs nothing).
//! 4. **The budget**: when the plan needs more slots than the cache has
//!    ([`crate::cache::slots_for_plan`]), the target grows by `2^b`, with the smallest `b` in
//!    `[0, top]` that fits found by bisection (slots never grow with `b`; at `top` every brick
//!    wants the coarsest level, however large its hi-res voxels are on screen).
//! 5. **Filling the slots left**: many bricks can cross a level boundary at the same bias (a
//!    distant view of the whole volume moves them all at once), so the plan at `b` may use a
//!    small part of the cache. The bricks that the bias just below `b` would refine are then
//!    refined neediest first (smallest headroom: the largest voxels on screen), as many as fit
//!    (a second bisection, over their count; the rule and the blocks applied as in step 2).
//!    A larger cache still never coarsens a brick: it stops the first bisection at the same or
//!    a smaller bias, and with the same one it refines at least as many.
//!
//! [`choose_levels_near`] adds hysteresis against the last choice. The host calls it per view
//! through `embed::VolumePass::plan_brick_levels`, which moves the cache towards its
//! choice under the per-frame upload budget ([`super::step_towards`]) and, for a streamed
//! source, onto the stored bricks its [`crate::store::LevelStreamer`] holds in RAM.

use crate::cache::{block_bricks, block_origin, slots_for_plan};
use crate::lod::{BrickGeometry, LodView};
use glam::{IVec3, UVec3, Vec3};

/// Why [`choose_levels`] cannot choose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LevelChoiceError {
    /// The culling result does not have one entry per brick.
    #[error("{given} culling flags for a grid of {bricks} bricks")]
    ActiveCount {
        /// Entries given.
        given: usize,
        /// Bricks in the grid.
        bricks: usize,
    },
    /// No level, more than 31, or block levels with bricks below 8 voxels.
    #[error(
        "{levels} levels with bricks of {brick_size} voxels: give 1 to 3 levels, or up to 31 \
         with bricks of at least 8 voxels"
    )]
    Levels {
        /// Levels given.
        levels: u32,
        /// Brick size of the grid.
        brick_size: u32,
    },
    /// The hysteresis margin is not a finite number of levels >= 0.
    #[error("the hysteresis margin must be a finite number of levels >= 0, not {0}")]
    Hysteresis(f32),
    /// The target is not a positive finite number of pixels.
    #[error("the target voxel size on screen must be a positive number of pixels, not {0}")]
    Target(f32),
}

/// What [`choose_levels`] chose.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelChoice {
    /// The level of every brick (linear index), `None` for a brick that is not drawn.
    pub levels: Vec<Option<u32>>,
    /// Slots the plan takes.
    pub slots: u64,
    /// The on-screen voxel size the plan meets (in every brick in view but those at full
    /// resolution already): the target, grown by what the budget forced.
    pub pixels_per_voxel: f32,
    /// Bricks whose chosen level is not drawn yet because its stored brick waits for a later
    /// step's upload budget (`VolumePass::plan_brick_levels`; 0 from [`choose_levels`]).
    pub waiting: usize,
    /// Bricks not drawn because the cache cannot hold even the coarsest plan: the least
    /// important blocks of the coarsest level (out of view first, then the farthest) are
    /// dropped until it fits (module docs, step 0). 0 when the cache holds the coarsest plan.
    pub dropped: usize,
    /// Stored bricks whose read failed while this view was staged
    /// (`VolumePass::plan_brick_levels`; 0 from [`choose_levels`]): each is kept out of every
    /// later step, so its region keeps the level it draws (a coarser one), and the step is
    /// planned again without it.
    pub failed_reads: usize,
}

/// Chooses the level of every brick of `geometry` for `view` among `levels` levels (module
/// docs): `active[i]` false for a culled brick, `slots` the cache's slots, `target_pixels` the
/// largest on-screen size of a drawn voxel wanted.
///
/// Errors: a culling result of another length, 0 levels (or more than 31, or more than 3 with
/// bricks below 8 voxels), or a target that is not a positive number. A cache too small for
/// the coarsest plan is no error: the least important bricks are dropped (module docs, step 0).
pub fn choose_levels(
    geometry: &BrickGeometry,
    view: &LodView,
    active: &[bool],
    levels: u32,
    slots: u64,
    target_pixels: f32,
) -> Result<LevelChoice, LevelChoiceError> {
    choose_levels_near(
        geometry,
        view,
        active,
        levels,
        slots,
        target_pixels,
        &[],
        0.0,
    )
}

/// The hysteresis margin in levels (the log2 scale of the on-screen voxel size) of a relative
/// margin `m` ([`super::PlanOptions::hysteresis`], the two-level planner's): a brick keeps its
/// level while its drawn voxel is within a factor `1 + m` of a level boundary, so
/// `log2(1 + m)` levels (0.1375 for the default 10 %).
pub fn level_margin(relative: f32) -> f32 {
    (1.0 + relative.max(0.0)).log2()
}

/// [`choose_levels`] with hysteresis: a brick whose wanted level (before the rule, the blocks
/// and the budget) lies within `margin` levels of a boundary of its level in `previous` (one
/// entry per brick, the last choice; empty for none) keeps that level, so a camera that hovers
/// at a boundary does not move bricks back and forth: a drawn voxel may project to up to
/// `2^margin` times the target before the brick refines, and a brick coarsens only once its
/// voxels are `2^margin` times below the target ([`level_margin`] of the two-level planner's
/// relative margin). The rule, the blocks and the budget apply as in [`choose_levels`].
///
/// Errors: those of [`choose_levels`], a `previous` of another length than the bricks
/// (reported as [`LevelChoiceError::ActiveCount`]), a margin that is not finite and >= 0.
#[allow(clippy::too_many_arguments)] // reason: the view's inputs; folded into one planner input by the one residency system (issue 36).
pub fn choose_levels_near(
    geometry: &BrickGeometry,
    view: &LodView,
    active: &[bool],
    levels: u32,
    slots: u64,
    target_pixels: f32,
    previous: &[Option<u32>],
    margin: f32,
) -> Result<LevelChoice, LevelChoiceError> {
    let grid = geometry.grid();
    if !previous.is_empty() && previous.len() != grid.brick_count() {
        return Err(LevelChoiceError::ActiveCount {
            given: previous.len(),
            bricks: grid.brick_count(),
        });
    }
    if active.len() != grid.brick_count() {
        return Err(LevelChoiceError::ActiveCount {
            given: active.len(),
            bricks: grid.brick_count(),
        });
    }
    let n = grid.brick_size();
    if levels == 0 || levels > 31 || (levels > 3 && n < 8) {
        return Err(LevelChoiceError::Levels {
            levels,
            brick_size: n,
        });
    }
    if !(target_pixels.is_finite() && target_pixels > 0.0) {
        return Err(LevelChoiceError::Target(target_pixels));
    }
    if !(margin.is_finite() && margin >= 0.0) {
        return Err(LevelChoiceError::Hysteresis(margin));
    }
    let previous = Previous {
        levels: previous,
        margin,
    };
    // Per brick: log2 of the target over the projected hi-res voxel, or None for a brick that
    // wants the coarsest level whatever the target.
    let voxel = geometry.voxel_size().max_element();
    let mut headroom: Vec<Option<f32>> = grid
        .bricks()
        .enumerate()
        .map(|(i, b)| {
            let (min, max) = geometry.brick_box(b);
            if !active[i] || view.box_outside_frustum(min, max) {
                return None;
            }
            let distance = (min - view.eye())
                .max(view.eye() - max)
                .max(Vec3::ZERO)
                .length();
            let pixels = voxel * view.pixels_per_world_unit(distance.max(voxel));
            Some((target_pixels / pixels).log2())
        })
        .collect();
    // The bias at which every brick wants the coarsest level (even the nearest, whose hi-res
    // voxels may be many times the target): the top of the bias search.
    let least = headroom
        .iter()
        .flatten()
        .fold(f32::INFINITY, |a, &h| a.min(h));
    let top = if least.is_finite() {
        (levels as f32 + margin + 1.0 - least).max(levels as f32)
    } else {
        levels as f32
    };
    let mut active = active.to_vec();
    let dropped = drop_to_fit(
        geometry,
        view,
        &mut active,
        &mut headroom,
        previous,
        levels,
        top,
        slots,
    );
    let active = &active[..];
    let plan_each =
        |bias: &dyn Fn(usize) -> f32| plan_for(geometry, active, &headroom, previous, levels, bias);
    let plan = |bias: f32| plan_each(&|_| bias);
    let coarsest = plan(top);
    let finest = plan(0.0);
    let (bias, chosen) = if slots_for_plan(grid.bricks_per_axis(), &finest) <= slots {
        (0.0, finest)
    } else {
        // The smallest bias that fits: `hi` always fits, `lo` never does.
        let (mut lo, mut hi, mut best) = (0.0f32, top, coarsest);
        for _ in 0..16 {
            let mid = 0.5 * (lo + hi);
            let candidate = plan(mid);
            if slots_for_plan(grid.bricks_per_axis(), &candidate) <= slots {
                (hi, best) = (mid, candidate);
            } else {
                lo = mid;
            }
        }
        // Fill the slots left: the bricks `lo` would refine, neediest first, as many as fit.
        let wanted_at = |i: usize, bias: f32| {
            headroom[i].map(|h| wanted_level(h + bias, previous.at(i), levels))
        };
        let mut candidates: Vec<usize> = (0..headroom.len())
            .filter(|&i| wanted_at(i, lo) < wanted_at(i, hi))
            .collect();
        candidates.sort_by(|&a, &b| {
            let (ha, hb) = (
                headroom[a].unwrap_or(f32::MAX),
                headroom[b].unwrap_or(f32::MAX),
            );
            ha.total_cmp(&hb).then(a.cmp(&b))
        });
        let mut rank = vec![usize::MAX; headroom.len()];
        for (r, &i) in candidates.iter().enumerate() {
            rank[i] = r;
        }
        let with_first = |m: usize| plan_each(&|i| if rank[i] < m { lo } else { hi });
        // The largest count that fits (0 always does: it is `best`).
        let (mut fit, mut over) = (0, candidates.len() + 1);
        while over - fit > 1 {
            let mid = (fit + over) / 2;
            let candidate = with_first(mid);
            if slots_for_plan(grid.bricks_per_axis(), &candidate) <= slots {
                (fit, best) = (mid, candidate);
            } else {
                over = mid;
            }
        }
        (hi, best)
    };
    Ok(LevelChoice {
        slots: slots_for_plan(grid.bricks_per_axis(), &chosen),
        levels: chosen,
        pixels_per_voxel: target_pixels * bias.exp2(),
        waiting: 0,
        dropped,
        failed_reads: 0,
    })
}

/// Step 0 of the module docs: when even the coarsest plan needs more slots than the cache has,
/// drops whole blocks of the coarsest level (a block's bricks share one stored brick), the
/// least important first: those with no active brick in view, then the farthest from the eye
/// (the distance of the block's nearest brick), until the coarsest plan fits. A dropped brick
/// is inactive with no headroom: never drawn, at any bias. Returns the active bricks dropped.
#[allow(clippy::too_many_arguments)] // reason: the chooser's state, threaded through one step.
fn drop_to_fit(
    geometry: &BrickGeometry,
    view: &LodView,
    active: &mut [bool],
    headroom: &mut [Option<f32>],
    previous: Previous<'_>,
    levels: u32,
    top: f32,
    slots: u64,
) -> usize {
    let grid = geometry.grid();
    let bricks = grid.bricks_per_axis();
    let coarsest_slots = |active: &[bool], headroom: &[Option<f32>]| {
        let plan = plan_for(geometry, active, headroom, previous, levels, &|_| top);
        slots_for_plan(bricks, &plan)
    };
    if coarsest_slots(active, headroom) <= slots {
        return 0;
    }
    let block = block_bricks(levels - 1);
    let blocks = (bricks + UVec3::splat(block - 1)) / block;
    let bricks_of = |k: UVec3| {
        let first = k * block;
        let end = (first + UVec3::splat(block)).min(bricks);
        (first.z..end.z).flat_map(move |z| {
            (first.y..end.y).flat_map(move |y| (first.x..end.x).map(move |x| UVec3::new(x, y, z)))
        })
    };
    // (in view, distance of the nearest brick, block) per block; least important first.
    let mut order: Vec<(bool, f32, UVec3)> = (0..blocks.z)
        .flat_map(|z| {
            (0..blocks.y).flat_map(move |y| (0..blocks.x).map(move |x| UVec3::new(x, y, z)))
        })
        .map(|k| {
            let mut in_view = false;
            let mut distance = f32::MAX;
            for b in bricks_of(k) {
                in_view |= headroom[grid.linear_index(b)].is_some();
                let (min, max) = geometry.brick_box(b);
                let d = (min - view.eye())
                    .max(view.eye() - max)
                    .max(Vec3::ZERO)
                    .length();
                distance = distance.min(d);
            }
            (in_view, distance, k)
        })
        .collect();
    order.sort_by(|a, b| {
        a.0.cmp(&b.0)
            .then(b.1.total_cmp(&a.1))
            .then((a.2.z, a.2.y, a.2.x).cmp(&(b.2.z, b.2.y, b.2.x)))
    });
    let drop_first = |count: usize, active: &mut [bool], headroom: &mut [Option<f32>]| {
        let mut dropped = 0;
        for &(_, _, k) in &order[..count] {
            for b in bricks_of(k) {
                let i = grid.linear_index(b);
                dropped += usize::from(active[i]);
                active[i] = false;
                headroom[i] = None;
            }
        }
        dropped
    };
    // The fewest blocks whose dropping fits (dropping every block always does: no slot).
    let (mut over, mut fit) = (0, order.len());
    while fit - over > 1 {
        let mid = (over + fit) / 2;
        let (mut a, mut h) = (active.to_vec(), headroom.to_vec());
        drop_first(mid, &mut a, &mut h);
        if coarsest_slots(&a, &h) <= slots {
            fit = mid;
        } else {
            over = mid;
        }
    }
    drop_first(fit, active, headroom)
}

/// The last choice and the hysteresis margin against it ([`choose_levels_near`]).
#[derive(Copy, Clone)]
struct Previous<'a> {
    /// One level per brick, or empty for none.
    levels: &'a [Option<u32>],
    /// Levels past a boundary a brick keeps its last level.
    margin: f32,
}

impl Previous<'_> {
    /// Brick `i`'s last level and the margin, when it had one.
    fn at(&self, i: usize) -> Option<(u32, f32)> {
        self.levels
            .get(i)
            .copied()
            .flatten()
            .map(|level| (level, self.margin))
    }
}

/// The level a brick wants at `raw` (log2 of the target, grown by the bias, over its projected
/// hi-res voxel): `floor(raw)`, or its `previous` level while `raw` lies within the margin of
/// that level's boundaries; clamped to the levels. A non-decreasing function of `raw`.
fn wanted_level(raw: f32, previous: Option<(u32, f32)>, levels: u32) -> u32 {
    let wanted = match previous.map(|(p, m)| (p as f32, m)) {
        Some((p, m)) if raw >= p - m && raw < p + 1.0 + m => p,
        _ => raw.floor(),
    };
    wanted.clamp(0.0, (levels - 1) as f32) as u32
}

/// Steps 1-3 of the module docs with brick `i`'s target grown by `2^bias(i)`, each wanted
/// level kept at `previous` (when given) within its margin of its boundaries. The
/// wanted level stays a non-decreasing function of every brick's bias, so the slots still
/// never grow with it.
fn plan_for(
    geometry: &BrickGeometry,
    active: &[bool],
    headroom: &[Option<f32>],
    previous: Previous<'_>,
    levels: u32,
    bias: &dyn Fn(usize) -> f32,
) -> Vec<Option<u32>> {
    let grid = geometry.grid();
    let coarsest = levels - 1;
    let mut level: Vec<u32> = headroom
        .iter()
        .enumerate()
        .map(|(i, h)| match h {
            Some(h) => wanted_level(h + bias(i), previous.at(i), levels),
            None => coarsest,
        })
        .collect();
    let bricks = grid.bricks_per_axis();
    loop {
        let mut changed = keep_rule(bricks, &mut level);
        changed |= keep_blocks(bricks, &mut level);
        if !changed {
            break;
        }
    }
    // Culled bricks are drawn only where a drawn block covers them.
    let drawn_block = |i: usize| {
        let b = grid.brick_coords(i);
        let block = block_bricks(level[i]);
        if block == 1 {
            return false;
        }
        let first = block_origin(b, level[i]);
        let end = (first + UVec3::splat(block)).min(bricks);
        (first.z..end.z).any(|z| {
            (first.y..end.y)
                .any(|y| (first.x..end.x).any(|x| active[grid.linear_index(UVec3::new(x, y, z))]))
        })
    };
    (0..level.len())
        .map(|i| (active[i] || drawn_block(i)).then_some(level[i]))
        .collect()
}

/// Refines every brick to at most one level coarser than its finest neighbour: the Chebyshev
/// distance transform of the levels, in a forward and a backward raster sweep over the 13
/// neighbours before (after) each brick. Returns whether a level changed.
pub(super) fn keep_rule(bricks: UVec3, level: &mut [u32]) -> bool {
    let size = bricks.as_ivec3();
    let index = |b: IVec3| (b.x + size.x * (b.y + size.y * b.z)) as usize;
    let before: Vec<IVec3> = (-1..=1)
        .flat_map(|z| (-1..=1).flat_map(move |y| (-1..=1).map(move |x| IVec3::new(x, y, z))))
        .filter(|d| (d.z, d.y, d.x) < (0, 0, 0))
        .collect();
    let mut changed = false;
    let mut sweep = |order: &mut dyn Iterator<Item = IVec3>, sign: i32| {
        for b in order {
            let here = index(b);
            for d in &before {
                let nb = b + *d * sign;
                if nb.cmpge(IVec3::ZERO).all() && nb.cmplt(size).all() {
                    let bound = level[index(nb)] + 1;
                    if level[here] > bound {
                        level[here] = bound;
                        changed = true;
                    }
                }
            }
        }
    };
    let forward = (0..size.z)
        .flat_map(|z| (0..size.y).flat_map(move |y| (0..size.x).map(move |x| IVec3::new(x, y, z))));
    sweep(&mut forward.clone(), 1);
    let backward: Vec<IVec3> = forward.collect();
    sweep(&mut backward.into_iter().rev(), -1);
    changed
}

/// Makes every block of a block level uniform, refining as little as it must: a brick at a
/// block level `k` whose aligned block holds a finer brick takes the coarsest level `j < k`
/// whose block around it holds none finer than `j` (level 2 at worst, a single brick), repeated
/// until every block is uniform. Refining a whole block to its finest brick instead would let
/// one culled brick that wants the coarsest level (its block spans the grid) pull every brick
/// of the volume down to the finest level anywhere. Levels only get finer, and finer inputs
/// give finer outputs. Returns whether a level changed.
pub(super) fn keep_blocks(bricks: UVec3, level: &mut [u32]) -> bool {
    let index = |b: UVec3| (b.x + bricks.x * (b.y + bricks.y * b.z)) as usize;
    let mut changed = false;
    loop {
        let deepest = level.iter().copied().max().unwrap_or(0);
        if deepest < 3 {
            return changed;
        }
        let mins = block_minima(bricks, level, deepest);
        let mut pass_changed = false;
        for z in 0..bricks.z {
            for y in 0..bricks.y {
                for x in 0..bricks.x {
                    let b = UVec3::new(x, y, z);
                    let i = index(b);
                    let uniform = |j: u32| {
                        let (counts, values) = &mins[(j - 3) as usize];
                        let c = b / block_bricks(j);
                        values[(c.x + counts.x * (c.y + counts.y * c.z)) as usize] >= j
                    };
                    let kept = (3..=level[i]).rev().find(|&j| uniform(j)).unwrap_or(2);
                    if kept < level[i] {
                        level[i] = kept;
                        pass_changed = true;
                    }
                }
            }
        }
        if !pass_changed {
            return changed;
        }
        changed = true;
    }
}

/// For every block level `3..=deepest`: the blocks per axis and the smallest brick level in
/// each block (x fastest).
fn block_minima(bricks: UVec3, level: &[u32], deepest: u32) -> Vec<(UVec3, Vec<u32>)> {
    let mut out: Vec<(UVec3, Vec<u32>)> = Vec::new();
    // Level 3's blocks (2 bricks per axis) from the bricks, each coarser level from the last.
    let (mut counts, mut values) = (bricks, level.to_vec());
    for _ in 3..=deepest {
        let next = (counts + UVec3::ONE) / 2;
        let mut reduced = vec![u32::MAX; next.element_product() as usize];
        for z in 0..counts.z {
            for y in 0..counts.y {
                for x in 0..counts.x {
                    let v = values[(x + counts.x * (y + counts.y * z)) as usize];
                    let c = UVec3::new(x, y, z) / 2;
                    let slot = &mut reduced[(c.x + next.x * (c.y + next.y * c.z)) as usize];
                    *slot = (*slot).min(v);
                }
            }
        }
        out.push((next, reduced.clone()));
        (counts, values) = (next, reduced);
    }
    out
}
