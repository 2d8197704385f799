//! The way from the levels drawn now to the levels wanted, one budgeted step at a time (issue 19,
//! item 4): what a three-level source draws while the bricks of a new plan are still to be
//! uploaded.
//!
//! [`step_towards`] mixes two plans that each keep the rules (adjacent drawn bricks at most one
//! level apart, blocks whole): every brick draws its *wanted* level where that level's stored
//! brick may come now (it is in the cache, or the step's upload budget admits it), else its
//! *current* level. A mix can break the rules where the two meet, so the bricks that break them
//! fall back to their current level too (with their blocks, in both plans), until none does:
//! each brick is then next to bricks of its own plan, or to bricks the fall-back left at a level
//! within one of its own. That always ends, at worst at the current plan, which keeps the rules.
//!
//! [`next_target`] is where a step heads: the wanted plan, but at most one level finer than the
//! drawn one (so the move refines coarse to fine, and leaving a coarse block takes only the
//! small bricks of the next level), made to keep the rules. [`admit_by_budget`] picks what a
//! step may upload towards it: every coarsening first (coarser bricks are small, and they free
//! the slots the refinements need), then the refinements that close the largest gap between
//! current and target level, nearest the camera first, up to the budget.

use crate::cache::{block_bricks, block_origin, stored_brick_edge};
use glam::{IVec3, UVec3};
use std::collections::VecDeque;

/// A plan that keeps the rules and lies between `current` and `wanted` (both keep them, one
/// entry per brick of a grid of `bricks` per axis, x fastest): each brick at its wanted level
/// where `ready(first_brick, level)` says that stored brick may be drawn now (the first brick of
/// its block at that level), else at its current level, with the fall-backs the rules need
/// (module docs).
pub fn step_towards(
    bricks: UVec3,
    current: &[Option<u32>],
    wanted: &[Option<u32>],
    ready: &dyn Fn(usize, u32) -> bool,
) -> Vec<Option<u32>> {
    let count = wanted.len();
    let size = bricks.as_ivec3();
    let coords = |i: usize| {
        let i = i as u32;
        UVec3::new(
            i % bricks.x,
            (i / bricks.x) % bricks.y,
            i / (bricks.x * bricks.y),
        )
    };
    let linear = |b: UVec3| (b.x + bricks.x * (b.y + bricks.y * b.z)) as usize;
    let mut back = vec![false; count];
    let mut queue = VecDeque::new();
    for i in 0..count {
        if let Some(level) = wanted[i] {
            if wanted[i] != current[i] && !ready(linear(block_origin(coords(i), level)), level) {
                back[i] = true;
                queue.push_back(i);
            }
        }
    }
    let drawn = |back: &[bool], i: usize| if back[i] { current[i] } else { wanted[i] };
    // Every brick of the block of `level` holding brick `i`.
    let block_of = |i: usize, level: Option<u32>| -> Vec<usize> {
        let Some(level) = level.filter(|&l| block_bricks(l) > 1) else {
            return Vec::new();
        };
        let first = block_origin(coords(i), level);
        let end = (first + UVec3::splat(block_bricks(level))).min(bricks);
        let mut out = Vec::new();
        for z in first.z..end.z {
            for y in first.y..end.y {
                for x in first.x..end.x {
                    out.push(linear(UVec3::new(x, y, z)));
                }
            }
        }
        out
    };
    while let Some(i) = queue.pop_front() {
        let fall_back = |j: usize, back: &mut Vec<bool>, queue: &mut VecDeque<usize>| {
            if !back[j] && wanted[j] != current[j] {
                back[j] = true;
                queue.push_back(j);
            }
        };
        // Both plans' blocks stay whole: the wanted block `i` left, and the current block `i`
        // now draws.
        for j in block_of(i, wanted[i])
            .into_iter()
            .chain(block_of(i, current[i]))
        {
            fall_back(j, &mut back, &mut queue);
        }
        // The rule towards every neighbour still at its wanted level.
        let here = drawn(&back, i);
        let b = coords(i).as_ivec3();
        for z in -1..=1 {
            for y in -1..=1 {
                for x in -1..=1 {
                    let n = b + IVec3::new(x, y, z);
                    if n == b || n.cmplt(IVec3::ZERO).any() || n.cmpge(size).any() {
                        continue;
                    }
                    let j = linear(n.as_uvec3());
                    if let (Some(a), Some(c)) = (here, drawn(&back, j)) {
                        if a.abs_diff(c) > 1 {
                            fall_back(j, &mut back, &mut queue);
                        }
                    }
                }
            }
        }
    }
    (0..count).map(|i| drawn(&back, i)).collect()
}

/// Where a step from `current` towards `wanted` heads (both keep the rules; `levels` levels,
/// one entry per brick of a grid of `bricks` per axis): per brick the wanted level, but at most
/// one level finer than the current one (a brick not drawn now counts as drawn at the coarsest
/// level), refined where the rule or a block needs it (the rule and block passes below), and not
/// drawn where the wanted plan does not draw it and no drawn block covers it. It keeps the
/// rules, and is never finer than the wanted plan but where a block or the rule refines it.
pub fn next_target(
    bricks: UVec3,
    levels: u32,
    current: &[Option<u32>],
    wanted: &[Option<u32>],
) -> Vec<Option<u32>> {
    let coarsest = levels.saturating_sub(1);
    let mut level: Vec<u32> = current
        .iter()
        .zip(wanted)
        .map(|(c, w)| {
            let w = w.unwrap_or(coarsest);
            w.max(c.unwrap_or(coarsest).saturating_sub(1))
        })
        .collect();
    loop {
        let mut changed = keep_rule(bricks, &mut level);
        changed |= keep_blocks(bricks, &mut level);
        if !changed {
            break;
        }
    }
    let linear = |b: UVec3| (b.x + bricks.x * (b.y + bricks.y * b.z)) as usize;
    (0..level.len())
        .map(|i| {
            if wanted[i].is_some() {
                return Some(level[i]);
            }
            // Drawn only inside a drawn block (its stored brick holds the brick anyway).
            let block = block_bricks(level[i]);
            let b = UVec3::new(
                i as u32 % bricks.x,
                (i as u32 / bricks.x) % bricks.y,
                i as u32 / (bricks.x * bricks.y),
            );
            let first = block_origin(b, level[i]);
            let end = (first + UVec3::splat(block)).min(bricks);
            let covered = block > 1
                && (first.z..end.z).any(|z| {
                    (first.y..end.y).any(|y| {
                        (first.x..end.x).any(|x| wanted[linear(UVec3::new(x, y, z))].is_some())
                    })
                });
            covered.then_some(level[i])
        })
        .collect()
}

/// What a budgeted step may upload: the stored bricks (first brick, level) of `wanted` that
/// `resident` says are not in the cache, admitted while their bytes (texels of
/// `bytes_per_texel`, bricks of `brick_size`) stay within `budget` (module docs for the order;
/// `distance[i]` ranks brick `i`, nearer first). The first candidate is always admitted. With
/// `budget = u64::MAX` it lists every missing stored brick in that order; the real cost of a
/// step (re-fixed and moved bricks too) is the pass's to check.
#[allow(clippy::too_many_arguments)]
pub fn admit_by_budget(
    bricks: UVec3,
    brick_size: u32,
    bytes_per_texel: u64,
    current: &[Option<u32>],
    wanted: &[Option<u32>],
    distance: &[f32],
    resident: &dyn Fn(usize, u32) -> bool,
    budget: u64,
) -> Vec<(usize, u32)> {
    let linear = |b: UVec3| (b.x + bricks.x * (b.y + bricks.y * b.z)) as usize;
    // (coarsening first, gap descending, distance ascending) per missing stored brick.
    let mut candidates: Vec<(bool, i64, f32, usize, u32)> = Vec::new();
    for (i, level) in wanted.iter().enumerate() {
        let Some(level) = *level else {
            continue;
        };
        let b = UVec3::new(
            i as u32 % bricks.x,
            (i as u32 / bricks.x) % bricks.y,
            i as u32 / (bricks.x * bricks.y),
        );
        let first = linear(block_origin(b, level));
        if first != i || resident(first, level) {
            continue;
        }
        let now = current[i].map_or(i64::from(u32::MAX), i64::from);
        let gap = now - i64::from(level);
        candidates.push((gap > 0, gap, distance[i], i, level));
    }
    candidates.sort_by(|a, b| {
        a.0.cmp(&b.0)
            .then(b.1.cmp(&a.1))
            .then(a.2.total_cmp(&b.2))
            .then(a.3.cmp(&b.3))
    });
    let mut spent = 0u64;
    let mut admitted = Vec::new();
    for (_, _, _, i, level) in candidates {
        let bytes = u64::from(stored_brick_edge(brick_size, level)).pow(3) * bytes_per_texel;
        if !admitted.is_empty() && spent + bytes > budget {
            break;
        }
        spent += bytes;
        admitted.push((i, level));
    }
    admitted
}

/// Refines every brick to at most one level coarser than its finest neighbour: the Chebyshev
/// distance transform of the levels, in a forward and a backward raster sweep over the 13
/// neighbours before (after) each brick. Returns whether a level changed.
fn keep_rule(bricks: UVec3, level: &mut [u32]) -> bool {
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
fn keep_blocks(bricks: UVec3, level: &mut [u32]) -> bool {
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
