//! The level of every brick from the camera for any number of levels (issue 19, item 4; issue
//! 36, item 4): what the cache with block levels draws for one view under its slots.
//!
//! The levels form a tree: a node of a block level `k >= 3` is an aligned block of
//! [`block_bricks`]`(k)` bricks per axis (one stored brick), split into the (up to) 8 blocks of
//! level `k - 1` it holds; a node of level 2, 1 or 0 is one brick, refined in place to the next
//! finer level. A plan is a cut through the tree: every brick at the level of the node that
//! holds it. [`LevelChooser::choose`] builds it in a few passes over the bricks:
//!
//! 0. **A cache too small** for the coarsest plan (every brick at the coarsest level) drops
//!    whole blocks of the coarsest level, the least important first (no active brick in view,
//!    then the farthest), until that plan fits; the dropped bricks are never drawn
//!    ([`LevelChoice::dropped`] counts them). Never an error.
//! 1. **Priority** of refining a node of level `k`: `k - headroom`, the headroom being log2 of
//!    the target over the projected size of a hi-res voxel at the nearest point of the node's
//!    nearest active brick in view (times the brick's value-range width when the request
//!    weighs by value, as the two-level planner's screen-space error does): by how many levels
//!    its voxels are too large on screen. A
//!    node with no active brick in view has none: it is refined only when the rule forces it.
//!    A node's priority is capped by its parent's (a node is reached only once its parent is
//!    split), so the refinements wanted at a priority above any threshold form a cut.
//! 2. **The threshold**: the priorities fall in buckets of 1/64 level; each refinement adds its
//!    slot classes' counts to its bucket. Scanning the buckets from the neediest, the first
//!    whose refinements would take more slots than the cache has
//!    ([`crate::cache::slots_for_classes`]: 1 level-0, 8 level-1 or 64 coarser stored bricks a
//!    slot) is the threshold: every refinement in a bucket above it is made, none below it,
//!    and inside it those that fit, neediest first (then the coarser node, then the first in
//!    z, y, x), up to the first that does not (a bucket of equal priorities, as an
//!    orthographic view gives, is split somewhere). A larger cache puts the threshold lower,
//!    so it never coarsens a brick; the plan meets the priority at the threshold's upper edge
//!    ([`LevelChoice::pixels_per_voxel`]).
//! 3. **The rule** (a brick at most one level coarser than any of its 26 neighbours): a node
//!    coarser than that is refined (a block split, recursively, down to the level its finest
//!    neighbour allows), until no brick breaks it; blocks stay whole. When what the rule added
//!    does not fit, fewer of the threshold bucket's refinements are made (leaving room for what
//!    the rule added, a few tries), then none, then the threshold moves up to the next bucket
//!    that holds a refinement and steps 2-3 run again: the coarsest plan breaks no rule, so
//!    this ends.
//! 4. **Culled bricks** are not drawn, unless a drawn block covers them (its stored brick holds
//!    them anyway; drawing them costs nothing), and take no slot.
//!
//! The work is a few passes over the bricks (their headrooms from per-axis terms, the block
//! minima, the buckets, the cut, a 3x3x3 minimum filter per pass of the rule) and over the
//! blocks, with no queue and no allocation once the chooser's buffers have grown to the grid;
//! a call with the inputs of the last one (a still camera) returns its plan without choosing
//! again.
//!
//! Hysteresis ([`LevelRequest::previous`] and [`LevelRequest::margin`]): a node that the last plan
//! refined stays refined until its priority falls `margin` levels below zero, and a node the
//! last plan drew whole is refined only once its priority is `margin` above zero, so a camera
//! that hovers at a boundary does not move bricks back and forth.
//!
//! The host calls it per view through `embed::VolumePass::update`, which moves the
//! cache towards its choice under the per-frame upload budget ([`super::step_towards`]) and, for
//! a streamed source, onto the stored bricks its [`crate::store::LevelStreamer`] holds in RAM.

use super::brick_headroom::{headroom_row, value_headroom, AxisTerms, HeadroomTerms};
use super::level_choice::{LevelChoice, LevelChoiceError, LevelRequest};
use super::level_rule::{bricks_in, linear, RuleKeeper};
use crate::bricks::ValueRange;
use crate::cache::{block_bricks, slots_for_classes};
use crate::lod::{BrickGeometry, LodView};
use glam::{UVec3, Vec3};

/// The level chooser of the module docs, with the buffers it keeps between calls: a host that
/// chooses every frame keeps one, so that a frame allocates nothing once the buffers have
/// grown to the grid, and a still camera costs a comparison of the inputs.
#[derive(Debug, Default)]
pub struct LevelChooser {
    /// The inputs of the last choice, and whether it succeeded (a still camera reuses it).
    last: Option<LastInputs>,
    /// The activity the tree below was built from.
    active: Vec<bool>,
    /// The grid (bricks per axis) and level count the tree was built for.
    tree_for: Option<(UVec3, u32)>,
    /// Per block level `k >= 3` (index `k - 3`): the nodes per axis and, per node, how many of
    /// its children (bricks for level 3) hold an active brick (0: the node is never drawn).
    tree: Vec<(UVec3, Vec<u8>)>,
    /// The `previous` of the last choice (compared for reuse).
    previous: Vec<Option<u32>>,
    /// The `value_ranges` of the last choice (compared for reuse).
    value_ranges: Vec<ValueRange>,
    /// Per root (block of the coarsest level, x fastest): dropped to fit (step 0).
    dropped: Vec<bool>,
    /// The roots in the order they are dropped (reused buffer).
    drop_order: Vec<(bool, f32, u32)>,
    /// Per axis: the brick slabs' terms (step 1).
    axes: [AxisTerms; 3],
    /// Per brick: its headroom (step 1), infinite for a brick not drawn or not in view.
    headroom: Vec<f32>,
    /// Per brick: the bucket of refining it from level 1 and from level 2 (index level - 1),
    /// [`NO_BUCKET`] for none.
    brick_buckets: Vec<[i16; 2]>,
    /// Per block level (index `k - 3`), per node: its priority (capped by its parent's).
    node_priority: Vec<Vec<f32>>,
    /// Per block level, per node: the bucket of splitting it, [`NO_BUCKET`] for none.
    node_bucket: Vec<Vec<i16>>,
    /// Per block level, per node: the level of the leaf of the cut holding it, or [`SPLIT`].
    cover: Vec<Vec<u8>>,
    /// Per bucket: the change of the slot classes' counts its refinements make, and how many
    /// ([`MAX_BUCKETS`] of them once sized).
    buckets: Vec<([i64; 3], u32)>,
    /// No bucket above this one holds a refinement.
    top_bucket: usize,
    /// The largest priority bucketed (the top bucket has no upper edge).
    largest: f32,
    /// The level of the node holding every brick (the cut being built).
    level: Vec<u8>,
    /// The refinements of the threshold bucket: priority, level, index (brick, or node of its
    /// level).
    in_bucket: Vec<(f32, u8, u32)>,
    /// The slot classes' counts after each prefix of `in_bucket` that fits.
    prefix_counts: Vec<[u64; 3]>,
    /// The rule's buffers (step 3).
    rule: RuleKeeper,
    /// The last choice.
    choice: LevelChoice,
}

/// What a choice depends on besides the slices (compared for reuse).
#[derive(Clone, Copy, Debug, PartialEq)]
struct LastInputs {
    view: LodView,
    bricks: UVec3,
    brick_size: u32,
    voxel: Vec3,
    box_min: Vec3,
    levels: u32,
    slots: u64,
    target_pixels: f32,
    margin: f32,
}

/// Buckets of priority per level: the threshold falls on a multiple of 1/64 level.
const BUCKETS_PER_LEVEL: f32 = 64.0;

/// The most buckets: priorities past 64 levels share the top one.
const MAX_BUCKETS: usize = 64 * 64;

/// The bucket of a refinement that is never made by its own priority.
const NO_BUCKET: i16 = -1;

/// A node of the cut that is split: its children carry the level.
const SPLIT: u8 = u8::MAX;

/// The bucket of `priority`, [`NO_BUCKET`] unless it is positive.
fn bucket(priority: f32) -> i16 {
    if priority > 0.0 {
        (priority * BUCKETS_PER_LEVEL).min((MAX_BUCKETS - 1) as f32) as i16
    } else {
        NO_BUCKET
    }
}

/// The threshold of refining a node of `level` that the last plan drew at `last`, with
/// hysteresis `margin` ([`Inputs::threshold`]).
fn threshold(level: u32, last: Option<u32>, margin: f32) -> f32 {
    let k = level as f32;
    match last {
        Some(p) if p < level => k + margin,
        Some(p) if p == level => k - margin,
        _ => k,
    }
}

/// Slot classes: level 0, level 1, level 2 and coarser.
fn class(level: u32) -> usize {
    level.min(2) as usize
}

/// The per-call view of the chooser's inputs.
struct Inputs<'a> {
    geometry: &'a BrickGeometry,
    view: &'a LodView,
    active: &'a [bool],
    value_ranges: &'a [ValueRange],
    previous: &'a [Option<u32>],
    bricks: UVec3,
    root: u32,
    /// Roots per axis, and log2 of a root's bricks per axis.
    roots: UVec3,
    root_shift: u32,
    voxel: f32,
    target_pixels: f32,
    margin: f32,
}

impl Inputs<'_> {
    /// The threshold of refining a node of `level` whose first brick is `origin` (linear): its
    /// level, moved by the hysteresis margin (refined in the last plan: kept refined past the
    /// boundary; drawn whole: refined only past it).
    fn threshold(&self, level: u32, origin: usize) -> f32 {
        threshold(
            level,
            self.previous.get(origin).copied().flatten(),
            self.margin,
        )
    }

    /// The linear index of the root holding `brick`.
    fn root_index(&self, brick: UVec3) -> usize {
        linear(self.roots, brick >> self.root_shift)
    }

    /// The first brick of root `r` (linear index over the roots, x fastest).
    fn root_origin(&self, r: usize) -> UVec3 {
        let (r, roots) = (r as u32, self.roots);
        UVec3::new(
            r % roots.x,
            (r / roots.x) % roots.y,
            r / (roots.x * roots.y),
        ) << self.root_shift
    }
}

impl LevelChooser {
    /// A chooser with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Chooses the level of every brick of `request.geometry` for `request.view` among
    /// `request.levels` levels (module docs; the fields: [`LevelRequest`]).
    ///
    /// Errors: a culling result, value ranges (when given) or a `previous` (when given) of
    /// another length than the bricks (reported as [`LevelChoiceError::ActiveCount`]), 0 levels
    /// (or more than 31, or more than 3 with bricks below 8 voxels), a target that is not a
    /// positive number, a margin that is negative or not finite. A cache too small for the
    /// coarsest plan is no error: the least important bricks are dropped (module docs, step 0).
    pub fn choose(&mut self, request: &LevelRequest<'_>) -> Result<&LevelChoice, LevelChoiceError> {
        let LevelRequest {
            geometry,
            view,
            active,
            value_ranges,
            levels,
            slots,
            target_pixels,
            previous,
            margin,
        } = *request;
        let grid = geometry.grid();
        let count = grid.brick_count();
        for given in [previous.len(), value_ranges.len()] {
            if given != 0 && given != count {
                return Err(LevelChoiceError::ActiveCount {
                    given,
                    bricks: count,
                });
            }
        }
        if active.len() != count {
            return Err(LevelChoiceError::ActiveCount {
                given: active.len(),
                bricks: count,
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
        let bricks = grid.bricks_per_axis();
        let (box_min, _) = geometry.volume_box();
        let inputs = LastInputs {
            view: *view,
            bricks,
            brick_size: n,
            voxel: geometry.voxel_size(),
            box_min,
            levels,
            slots,
            target_pixels,
            margin,
        };
        // A still camera: the same inputs give the same plan.
        if self.last == Some(inputs)
            && self.active == active
            && self.previous == previous
            && self.value_ranges == value_ranges
        {
            return Ok(&self.choice);
        }
        self.last = None;
        if self.tree_for != Some((bricks, levels)) || self.active != active {
            self.build_tree(bricks, levels, active);
        }
        self.previous.clear();
        self.previous.extend_from_slice(previous);
        self.value_ranges.clear();
        self.value_ranges.extend_from_slice(value_ranges);
        let input = Inputs {
            geometry,
            view,
            active,
            value_ranges,
            previous,
            bricks,
            root: levels - 1,
            roots: (bricks + UVec3::splat(block_bricks(levels - 1) - 1)) / block_bricks(levels - 1),
            root_shift: (levels - 1).saturating_sub(2),
            voxel: geometry.voxel_size().max_element(),
            target_pixels,
            margin,
        };
        self.plan(&input, slots);
        self.last = Some(inputs);
        Ok(&self.choice)
    }

    /// Rebuilds the tree's counts of children holding an active brick, and sizes the per-node
    /// buffers, for `active`.
    fn build_tree(&mut self, bricks: UVec3, levels: u32, active: &[bool]) {
        self.active.clear();
        self.active.extend_from_slice(active);
        self.tree_for = Some((bricks, levels));
        let block_levels = levels.saturating_sub(3) as usize;
        self.tree.resize_with(block_levels, Default::default);
        self.node_priority.resize_with(block_levels, Vec::new);
        self.node_bucket.resize_with(block_levels, Vec::new);
        self.cover.resize_with(block_levels, Vec::new);
        for i in 0..block_levels {
            let k = i as u32 + 3;
            let nodes = (bricks + UVec3::splat(block_bricks(k) - 1)) / block_bricks(k);
            let size = nodes.element_product() as usize;
            let (finer, rest) = self.tree.split_at_mut(i);
            let (counts_per_axis, counts) = &mut rest[0];
            *counts_per_axis = nodes;
            counts.clear();
            counts.resize(size, 0);
            match finer.last() {
                None => {
                    for_each_cell(bricks, |b, i| {
                        counts[linear(nodes, b >> 1)] += u8::from(active[i]);
                    });
                }
                Some((finer_nodes, finer_counts)) => {
                    for_each_cell(*finer_nodes, |c, i| {
                        counts[linear(nodes, c >> 1)] += u8::from(finer_counts[i] > 0);
                    });
                }
            }
            self.node_priority[i].resize(size, 0.0);
            self.node_bucket[i].resize(size, NO_BUCKET);
            self.cover[i].resize(size, SPLIT);
        }
    }

    /// Whether node `(level, origin)` holds an active brick (its root not dropped aside).
    fn holds_active(&self, input: &Inputs<'_>, level: u32, origin: UVec3) -> bool {
        if level <= 2 {
            return input.active[linear(input.bricks, origin)];
        }
        let (nodes, counts) = &self.tree[(level - 3) as usize];
        counts[linear(*nodes, origin >> (level - 2))] > 0
    }

    /// Whether node `(level, origin)` is drawn: it holds an active brick, and its root is not
    /// dropped.
    fn drawn(&self, input: &Inputs<'_>, level: u32, origin: UVec3) -> bool {
        !self.dropped[input.root_index(origin)] && self.holds_active(input, level, origin)
    }

    /// Steps 0-4 of the module docs into `self.choice`.
    fn plan(&mut self, input: &Inputs<'_>, slots: u64) {
        let root = input.root;
        let count = input.bricks.element_product() as usize;
        self.dropped.clear();
        self.dropped
            .resize(input.roots.element_product() as usize, false);
        let mut coarsest = [0u64; 3];
        for r in 0..self.dropped.len() {
            let origin = input.root_origin(r);
            coarsest[class(root)] += u64::from(self.drawn(input, root, origin));
        }
        let dropped = self.drop_to_fit(input, slots, &mut coarsest);
        self.buckets.resize(MAX_BUCKETS, ([0; 3], 0));
        for bucket in &mut self.buckets[..=self.top_bucket] {
            *bucket = ([0; 3], 0);
        }
        self.top_bucket = 0;
        self.largest = 0.0;
        self.brick_headrooms(input);
        self.node_priorities(input);
        self.brick_events(input);
        // Step 2: the first bucket, from the neediest, whose refinements do not fit.
        let top = self.top_bucket + 1;
        let mut cut = NO_BUCKET;
        let mut counts = coarsest;
        for b in (0..top).rev() {
            let (delta, made) = self.buckets[b];
            if made == 0 {
                continue;
            }
            let next = add_counts(counts, delta);
            if slots_for_classes(next) > slots {
                cut = b as i16;
                break;
            }
            counts = next;
        }
        self.level.resize(count, 0);
        let mut per_class = None;
        if cut != NO_BUCKET {
            per_class = self.fill_threshold_bucket(input, cut, counts, slots);
        }
        let per_class = match per_class {
            Some(per_class) => per_class,
            None => loop {
                self.write_cut(input, cut);
                self.keep_rule(input);
                let per_class = self.write_levels(input);
                if slots_for_classes(per_class) <= slots {
                    break per_class;
                }
                // Step 3: what the rule added does not fit; the next bucket up that holds a
                // refinement (past the top, the coarsest plan, which breaks no rule).
                match (cut + 1..top as i16).find(|&b| self.buckets[b as usize].1 > 0) {
                    Some(b) => cut = b,
                    None if (cut as usize) < top || cut == NO_BUCKET => cut = top as i16,
                    None => break per_class,
                }
            },
        };
        let refused = (cut != NO_BUCKET).then(|| match cut as usize {
            b if b >= MAX_BUCKETS - 1 => self.largest,
            b => (b + 1) as f32 / BUCKETS_PER_LEVEL,
        });
        self.choice.slots = slots_for_classes(per_class);
        self.choice.pixels_per_voxel = input.target_pixels * refused.unwrap_or(0.0).max(0.0).exp2();
        self.choice.waiting = 0;
        self.choice.dropped = dropped;
        self.choice.failed_reads = 0;
    }

    /// Step 2 inside the threshold bucket `cut`: its refinements, neediest first (then the
    /// coarser node, then the first in z, y, x), are made while they fit with `above` (the
    /// counts with every bucket above made), the first that does not fit ending them, as a
    /// bucket of equal priorities (an orthographic view) must be split somewhere. When what
    /// the rule adds does not fit, fewer are made (the prefix that leaves room for what the
    /// rule added, a few times). Returns the plan's counts, written into `self.level`, or
    /// `None` when no prefix fits with the rule (nothing of the bucket made).
    fn fill_threshold_bucket(
        &mut self,
        input: &Inputs<'_>,
        cut: i16,
        above: [u64; 3],
        slots: u64,
    ) -> Option<[u64; 3]> {
        self.in_bucket.clear();
        for (i, buckets) in self.node_bucket.iter().enumerate() {
            for (j, &b) in buckets.iter().enumerate() {
                if b == cut {
                    let k = i as u32 + 3;
                    self.in_bucket
                        .push((self.node_priority[i][j], k as u8, j as u32));
                }
            }
        }
        let top = input.root.min(2);
        let parents = self.tree.first().map(|(nodes, _)| *nodes);
        let first_priorities = self.node_priority.first();
        let in_bucket = &mut self.in_bucket;
        for_each_cell(input.bricks, |b, i| {
            let buckets = self.brick_buckets[i];
            if !buckets.contains(&cut) {
                return;
            }
            // The priorities as bucketed: capped by the parent's.
            let mut cap = match (parents, first_priorities) {
                (Some(nodes), Some(p)) => p[linear(nodes, b >> 1)],
                _ => f32::INFINITY,
            };
            for level in (1..=top).rev() {
                let p = (input.threshold(level, i) - self.headroom[i]).min(cap);
                if buckets[level as usize - 1] == cut {
                    in_bucket.push((p, level as u8, i as u32));
                }
                cap = p;
            }
        });
        // Neediest first; a parent (capped at least as high, one level coarser) before its
        // children.
        self.in_bucket
            .sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(b.1.cmp(&a.1)).then(a.2.cmp(&b.2)));
        // The counts after each prefix, as long as they fit.
        let mut fits = 0;
        let mut counts = above;
        self.prefix_counts.clear();
        self.prefix_counts.push(counts);
        for &(_, level, index) in &self.in_bucket {
            let level = u32::from(level);
            let children = match level {
                0..=2 => 1,
                k => i64::from(self.tree[(k - 3) as usize].1[index as usize]),
            };
            let mut delta = [0i64; 3];
            delta[class(level)] -= 1;
            delta[class(level - 1)] += children;
            counts = add_counts(counts, delta);
            if slots_for_classes(counts) > slots {
                break;
            }
            self.prefix_counts.push(counts);
            fits += 1;
        }
        let mut made = fits;
        for _ in 0..4 {
            if made == 0 {
                break;
            }
            self.promote(cut, made);
            self.write_cut(input, cut);
            self.keep_rule(input);
            let per_class = self.write_levels(input);
            let used = slots_for_classes(per_class);
            if used <= slots {
                self.promote(cut, 0);
                return Some(per_class);
            }
            // What the rule added at this prefix, left room for.
            let added = used - slots_for_classes(self.prefix_counts[made]);
            let room = slots.saturating_sub(added);
            made = (0..made)
                .rev()
                .find(|&m| slots_for_classes(self.prefix_counts[m]) <= room)
                .unwrap_or(0);
        }
        self.promote(cut, 0);
        None
    }

    /// Moves the first `made` refinements of the threshold bucket `cut` one bucket up (so that
    /// [`LevelChooser::write_cut`] makes them) and the others back into it.
    fn promote(&mut self, cut: i16, made: usize) {
        for (n, &(_, level, index)) in self.in_bucket.iter().enumerate() {
            let b = if n < made { cut + 1 } else { cut };
            match u32::from(level) {
                level @ 1..=2 => self.brick_buckets[index as usize][level as usize - 1] = b,
                k => self.node_bucket[(k - 3) as usize][index as usize] = b,
            }
        }
    }

    /// Step 0 of the module docs: drops the least important roots until the coarsest plan
    /// fits; returns the active bricks dropped.
    fn drop_to_fit(&mut self, input: &Inputs<'_>, slots: u64, per_class: &mut [u64; 3]) -> usize {
        let root = input.root;
        let fits = |per_class: &[u64; 3]| slots_for_classes(*per_class) <= slots;
        if fits(per_class) {
            return 0;
        }
        let block = block_bricks(root);
        let bricks = input.bricks;
        let eye = input.view.eye();
        self.drop_order.clear();
        for r in 0..self.dropped.len() {
            let first = input.root_origin(r);
            let end = (first + UVec3::splat(block)).min(bricks);
            if !self.drawn(input, root, first) {
                continue; // dropping it frees nothing
            }
            let (min, _) = input.geometry.brick_box(first);
            let (_, max) = input.geometry.brick_box(end - UVec3::ONE);
            let distance = (min - eye).max(eye - max).max(Vec3::ZERO).length();
            // In view: an active brick of the block whose box is not outside the frustum.
            let in_view = bricks_in(first, end).any(|b| {
                let (min, max) = input.geometry.brick_box(b);
                input.active[linear(bricks, b)] && !input.view.box_outside_frustum(min, max)
            });
            self.drop_order.push((in_view, distance, r as u32));
        }
        // Least important first: out of view, then the farthest, then the first in z, y, x.
        self.drop_order
            .sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)).then(a.2.cmp(&b.2)));
        let mut dropped = 0;
        for i in 0..self.drop_order.len() {
            if fits(per_class) {
                break;
            }
            let r = self.drop_order[i].2 as usize;
            let first = input.root_origin(r);
            let end = (first + UVec3::splat(block)).min(bricks);
            dropped += bricks_in(first, end)
                .filter(|&b| input.active[linear(bricks, b)])
                .count();
            self.dropped[r] = true;
            per_class[class(root)] -= 1;
        }
        dropped
    }

    /// Step 1 per brick: every brick's headroom into `self.headroom` (plus its value range's,
    /// when given), infinite for one that is culled, in a dropped root or outside the frustum. The box tests and distances are
    /// summed from per-axis terms, in the order [`LodView::box_outside_frustum`] and a box's
    /// distance take them, a row at a time on vector lanes ([`super::brick_headroom`]).
    fn brick_headrooms(&mut self, input: &Inputs<'_>) {
        let view = input.view;
        for (axis, terms) in self.axes.iter_mut().enumerate() {
            terms.fill(input.geometry, view, axis);
        }
        let planes = view.frustum_planes();
        let offsets: [f32; 6] = std::array::from_fn(|p| planes[p].offset);
        let headroom = HeadroomTerms::new(view, input.voxel, input.target_pixels);
        let count = input.bricks.element_product() as usize;
        self.headroom.resize(count, f32::INFINITY);
        let dropped = &self.dropped;
        let any_dropped = dropped.contains(&true);
        let [ax, ay, az] = &self.axes;
        let nx = ax.distance2.len();
        for z in 0..input.bricks.z as usize {
            for y in 0..input.bricks.y as usize {
                let yz = UVec3::new(0, y as u32, z as u32);
                let row = linear(input.bricks, yz);
                let cy: [f32; 6] = std::array::from_fn(|p| ay.corner[p][y]);
                let cz: [f32; 6] = std::array::from_fn(|p| az.corner[p][z]);
                let (dy2, dz2) = (ay.distance2[y], az.distance2[z]);
                let active = &input.active[row..row + nx];
                let headrooms = &mut self.headroom[row..row + nx];
                headroom_row(ax, [cy, cz], offsets, [dy2, dz2], headroom, headrooms);
                for (h, &active) in headrooms.iter_mut().zip(active) {
                    if !active {
                        *h = f32::INFINITY;
                    }
                }
                if let Some(ranges) = input.value_ranges.get(row..row + nx) {
                    for (h, range) in headrooms.iter_mut().zip(ranges) {
                        *h += value_headroom(*range);
                    }
                }
                if any_dropped {
                    for (x, h) in headrooms.iter_mut().enumerate() {
                        if dropped[input.root_index(yz + UVec3::X * x as u32)] {
                            *h = f32::INFINITY;
                        }
                    }
                }
            }
        }
    }

    /// Steps 1-2 for the blocks: each node's headroom, the smallest of its bricks' (bottom up),
    /// then its priority capped by its parent's and its bucket, added to the buckets' counts
    /// (top down).
    fn node_priorities(&mut self, input: &Inputs<'_>) {
        for i in 0..self.tree.len() {
            let (lower, rest) = self.node_priority.split_at_mut(i);
            let minima = &mut rest[0];
            minima.fill(f32::INFINITY);
            let nodes = self.tree[i].0;
            match lower.last() {
                None => {
                    let nx = input.bricks.x as usize;
                    for z in 0..input.bricks.z {
                        for y in 0..input.bricks.y {
                            let row = linear(input.bricks, UVec3::new(0, y, z));
                            let first = linear(nodes, UVec3::new(0, y, z) >> 1);
                            let headrooms = &self.headroom[row..row + nx];
                            for (x, &h) in headrooms.iter().enumerate() {
                                let m = &mut minima[first + (x >> 1)];
                                *m = m.min(h);
                            }
                        }
                    }
                }
                Some(finer) => for_each_cell(self.tree[i - 1].0, |c, j| {
                    let m = &mut minima[linear(nodes, c >> 1)];
                    *m = m.min(finer[j]);
                }),
            }
        }
        for i in (0..self.tree.len()).rev() {
            let k = i as u32 + 3;
            let (finer, coarser) = self.node_priority.split_at_mut(i + 1);
            let priorities = &mut finer[i];
            let parent = coarser.first().map(|p| (self.tree[i + 1].0, p));
            let (nodes, counts) = &self.tree[i];
            let node_buckets = &mut self.node_bucket[i];
            let buckets = &mut self.buckets;
            let mut largest = self.largest;
            let mut top_bucket = self.top_bucket;
            for_each_cell(*nodes, |c, j| {
                let mut p = input.threshold(k, linear(input.bricks, c << (k - 2))) - priorities[j];
                if let Some((parents, parent)) = &parent {
                    p = p.min(parent[linear(*parents, c >> 1)]);
                }
                priorities[j] = p;
                let b = bucket(p);
                node_buckets[j] = b;
                if b != NO_BUCKET {
                    // A node with a bucket holds an active brick in view: it is drawn.
                    let (delta, made) = &mut buckets[b as usize];
                    delta[class(k)] -= 1;
                    delta[class(k - 1)] += i64::from(counts[j]);
                    *made += 1;
                    largest = largest.max(p);
                    top_bucket = top_bucket.max(b as usize);
                }
            });
            self.largest = largest;
            self.top_bucket = top_bucket;
        }
    }

    /// Step 2 for the bricks: each brick's refinements' priorities (capped by its block's)
    /// and buckets, added to the buckets' counts.
    fn brick_events(&mut self, input: &Inputs<'_>) {
        let count = input.bricks.element_product() as usize;
        self.brick_buckets.resize(count, [NO_BUCKET; 2]);
        let top = input.root.min(2);
        let parents = self.tree.first().map(|(nodes, _)| *nodes);
        let parent_priorities = self.node_priority.first();
        let buckets = &mut self.buckets;
        let mut largest = self.largest;
        let mut top_bucket = self.top_bucket;
        let nx = input.bricks.x as usize;
        // Runs of refinements of one level in one bucket (neighbouring bricks share buckets),
        // added to the bucket when the run ends.
        let mut runs = [(NO_BUCKET, 0i64); 2];
        let mut end_run = |run: &mut (i16, i64), level: u32| {
            if run.1 > 0 {
                let (delta, made) = &mut buckets[run.0 as usize];
                delta[class(level)] -= run.1;
                delta[class(level - 1)] += run.1;
                *made += run.1 as u32;
                top_bucket = top_bucket.max(run.0 as usize);
            }
            *run = (NO_BUCKET, 0);
        };
        for z in 0..input.bricks.z as usize {
            for y in 0..input.bricks.y as usize {
                let row = linear(input.bricks, UVec3::new(0, y as u32, z as u32));
                let yz = UVec3::new(0, y as u32, z as u32);
                let headrooms = &self.headroom[row..row + nx];
                let previous = input.previous.get(row..row + nx);
                let caps = parents
                    .zip(parent_priorities)
                    .map(|(nodes, p)| &p[linear(nodes, yz >> 1)..]);
                let brick_buckets = &mut self.brick_buckets[row..row + nx];
                for x in 0..nx {
                    let h = headrooms[x];
                    let last = previous.and_then(|p| p[x]);
                    let mut cap = caps.map_or(f32::INFINITY, |c| c[x >> 1]);
                    let mut brick = [NO_BUCKET; 2];
                    for level in (1..=top).rev() {
                        let p = (threshold(level, last, input.margin) - h).min(cap);
                        let b = bucket(p);
                        brick[level as usize - 1] = b;
                        if b != NO_BUCKET {
                            let run = &mut runs[level as usize - 1];
                            if run.0 != b {
                                end_run(run, level);
                                run.0 = b;
                            }
                            run.1 += 1;
                            largest = largest.max(p);
                        }
                        cap = p;
                    }
                    brick_buckets[x] = brick;
                }
            }
        }
        for (l, run) in runs.iter_mut().enumerate() {
            end_run(run, l as u32 + 1);
        }
        self.largest = largest;
        self.top_bucket = top_bucket;
    }

    /// The cut of step 2 for threshold bucket `cut` (every refinement in a bucket above it
    /// made) into `self.level`.
    fn write_cut(&mut self, input: &Inputs<'_>, cut: i16) {
        for i in (0..self.tree.len()).rev() {
            let k = i as u32 + 3;
            let (finer, coarser) = self.cover.split_at_mut(i + 1);
            let cover = &mut finer[i];
            let parent = coarser.first().map(|p| (self.tree[i + 1].0, p));
            let buckets = &self.node_bucket[i];
            for_each_cell(self.tree[i].0, |c, j| {
                cover[j] = match &parent {
                    Some((parents, parent)) if parent[linear(*parents, c >> 1)] != SPLIT => {
                        parent[linear(*parents, c >> 1)]
                    }
                    _ if buckets[j] > cut => SPLIT,
                    _ => k as u8,
                };
            });
        }
        let top = input.root.min(2);
        let blocks = self.tree.first().map(|(nodes, _)| *nodes);
        let first_cover = self.cover.first();
        let level = &mut self.level;
        let brick_buckets = &self.brick_buckets;
        for_each_cell(input.bricks, |b, i| {
            let covered = match (blocks, first_cover) {
                (Some(nodes), Some(cover)) => cover[linear(nodes, b >> 1)],
                _ => SPLIT,
            };
            level[i] = if covered != SPLIT {
                covered
            } else {
                let mut l = top;
                while l > 0 && brick_buckets[i][l as usize - 1] > cut {
                    l -= 1;
                }
                l as u8
            };
        });
    }

    /// Step 3: refines every node of the cut that breaks the rule ([`RuleKeeper`]).
    fn keep_rule(&mut self, input: &Inputs<'_>) {
        self.rule.keep(input.bricks, &mut self.level);
    }

    /// Step 4: the plan's levels from the cut in `self.level` into `self.choice.levels`, and
    /// the slot classes' counts of its drawn nodes.
    fn write_levels(&mut self, input: &Inputs<'_>) -> [u64; 3] {
        let mut per_class = [0u64; 3];
        let mut levels = std::mem::take(&mut self.choice.levels);
        levels.clear();
        let any_dropped = self.dropped.contains(&true);
        let mut fine = [0u64; 3];
        for_each_cell(input.bricks, |b, i| {
            let level = self.level[i];
            // A brick is drawn when active, or inside a drawn block (the node of a block level
            // holds it whole); a block counts once, at its first brick.
            let drawn = if level <= 2 && !any_dropped {
                let drawn = input.active[i];
                fine[usize::from(level)] += u64::from(drawn);
                drawn
            } else {
                let level = u32::from(level);
                let drawn = self.holds_active(input, level, b)
                    && !(any_dropped && self.dropped[input.root_index(b)]);
                let first =
                    level <= 2 || (b & UVec3::splat(block_bricks(level) - 1)) == UVec3::ZERO;
                per_class[class(level)] += u64::from(drawn && first);
                drawn
            };
            levels.push(drawn.then_some(u32::from(level)));
        });
        for (c, n) in per_class.iter_mut().zip(fine) {
            *c += n;
        }
        self.choice.levels = levels;
        per_class
    }
}

/// The counts after a bucket's change.
fn add_counts(counts: [u64; 3], delta: [i64; 3]) -> [u64; 3] {
    std::array::from_fn(|c| counts[c].saturating_add_signed(delta[c]))
}

/// Calls `f(cell, linear index)` for every cell of a grid of `size` per axis, x fastest.
fn for_each_cell(size: UVec3, mut f: impl FnMut(UVec3, usize)) {
    let mut i = 0;
    for z in 0..size.z {
        for y in 0..size.y {
            for x in 0..size.x {
                f(UVec3::new(x, y, z), i);
                i += 1;
            }
        }
    }
}
