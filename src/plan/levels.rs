//! The level of every brick from the camera for any number of levels (issue 19, item 4; issue
//! 36, item 4): what the cache with block levels draws for one view under its slots.
//!
//! The levels form a tree: a node of a block level `k >= 3` is an aligned block of
//! [`block_bricks`]`(k)` bricks per axis (one stored brick), split into the (up to) 8 blocks of
//! level `k - 1` it holds; a node of level 2, 1 or 0 is one brick, refined in place to the next
//! finer level. A plan is a cut through the tree: every brick at the level of the node that
//! holds it. [`LevelChooser::choose`] builds it greedily:
//!
//! 0. **A cache too small** for the coarsest plan (every brick at the coarsest level) drops
//!    whole blocks of the coarsest level, the least important first (no active brick in view,
//!    then the farthest), until that plan fits; the dropped bricks are never drawn
//!    ([`LevelChoice::dropped`] counts them). Never an error.
//! 1. **Priority** of a node of level `k`: `k - log2(target / p0)`, with `p0` the projected size
//!    of a hi-res voxel at the nearest point of the bounding box of the node's active bricks
//!    (those the transfer function does not cull): by how many levels its voxels are too
//!    large on screen. A node with no active brick, or whose active box lies outside the
//!    frustum, has none: it is refined only when the rule forces it. The priority of a node is
//!    larger than that of every node below it (a child's box is inside its parent's, one level
//!    finer).
//! 2. **Refinement, neediest first**: the node of largest positive priority is split (a block)
//!    or refined (a brick), repeatedly. **The rule** (a brick at most one level coarser than any
//!    of its 26 neighbours) holds throughout: before a node goes to level `k - 1`, every
//!    neighbouring node of level `k + 1` is split or refined first (recursively). Blocks are
//!    whole by construction.
//! 3. **The budget**: the first refinement (with what the rule forced) that takes more slots
//!    than the cache has ([`crate::cache::slots_for_classes`]: 1 level-0, 8 level-1 or 64
//!    coarser stored bricks a slot) is undone and the choice stops there. A larger cache runs
//!    the same sequence further, so it never coarsens a brick; the plan meets the priority of
//!    the refinement it stopped at ([`LevelChoice::pixels_per_voxel`]).
//! 4. **Culled bricks** are not drawn, unless a drawn block covers them (its stored brick holds
//!    them anyway; drawing them costs nothing), and take no slot.
//!
//! The work is the size of the cut, not of the grid: the nodes refined, each with 26 neighbour
//! probes and a queue push (priorities in buckets of 1/64 level), plus one pass writing the plan. The chooser keeps its buffers
//! between calls (no allocation in steady state), and a call with the inputs of the last one
//! (a still camera) returns its plan without choosing again.
//!
//! Hysteresis ([`LevelChooser::choose`]'s `previous` and `margin`): a node that the last plan
//! refined stays refined until its priority falls `margin` levels below zero, and a node the
//! last plan drew whole is refined only once its priority is `margin` above zero, so a camera
//! that hovers at a boundary does not move bricks back and forth.
//!
//! The host calls it per view through `embed::VolumePass::plan_brick_levels`, which moves the
//! cache towards its choice under the per-frame upload budget ([`super::step_towards`]) and, for
//! a streamed source, onto the stored bricks its [`crate::store::LevelStreamer`] holds in RAM.

use crate::cache::{block_bricks, slots_for_classes};
use crate::lod::{BrickGeometry, LodView};
use glam::{UVec3, Vec3};

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
#[derive(Clone, Debug, Default, PartialEq)]
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
/// largest on-screen size of a drawn voxel wanted. A fresh [`LevelChooser`]'s choice; a host
/// that chooses every frame keeps one.
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

/// [`choose_levels`] with hysteresis against `previous` (module docs): a fresh
/// [`LevelChooser`]'s [`LevelChooser::choose`].
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
    LevelChooser::default()
        .choose(
            geometry,
            view,
            active,
            levels,
            slots,
            target_pixels,
            previous,
            margin,
        )
        .cloned()
}

/// The level chooser of the module docs, with the buffers it keeps between calls: a host that
/// chooses every frame keeps one, so that a frame allocates nothing once the buffers have
/// grown to the grid, and a still camera costs a comparison of the inputs.
#[derive(Debug, Default)]
pub struct LevelChooser {
    /// The inputs of the last choice, and whether it succeeded (a still camera reuses it).
    last: Option<LastInputs>,
    /// The activity the boxes below were built from.
    active: Vec<bool>,
    /// The grid (bricks per axis) and level count the boxes were built for.
    boxes_for: Option<(UVec3, u32)>,
    /// Per block level `k >= 3` (index `k - 3`): the blocks per axis and each block's box of
    /// active bricks, in bricks.
    boxes: Vec<(UVec3, Vec<BrickBox>)>,
    /// The `previous` of the last choice (compared for reuse).
    previous: Vec<Option<u32>>,
    /// Per root (block of the coarsest level, x fastest): dropped to fit (step 0).
    dropped: Vec<bool>,
    /// The roots in the order they are dropped (reused buffer).
    drop_order: Vec<(bool, f32, u32)>,
    /// The level of the node holding every brick (the cut being built).
    level: Vec<u8>,
    /// Nodes to refine, neediest first.
    queue: BucketQueue,
    /// The nodes the refinement being tried split, in order (undone when it does not fit).
    undo: Vec<(u32, UVec3)>,
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

/// The active bricks of a block, as an inclusive box of brick coordinates (`min > max` for
/// none).
#[derive(Clone, Copy, Debug, PartialEq)]
struct BrickBox {
    min: UVec3,
    max: UVec3,
}

impl BrickBox {
    const EMPTY: Self = Self {
        min: UVec3::splat(u32::MAX),
        max: UVec3::ZERO,
    };

    fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    fn add(&mut self, other: &BrickBox) {
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }
}

/// A node waiting to be refined.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    priority: f32,
    /// The node's headroom (a brick refined in place keeps it).
    headroom: f32,
    level: u32,
    origin: UVec3,
}

/// Buckets of priority per level: the queue orders nodes to 1/64 of a level (within a bucket,
/// the last queued first), which keeps a push and a pop O(1).
const BUCKETS_PER_LEVEL: f32 = 64.0;

/// The most buckets: priorities past 64 levels share the top one.
const MAX_BUCKETS: usize = 64 * 64;

/// Nodes to refine, in buckets of [`BUCKETS_PER_LEVEL`] per level of priority, the largest
/// first. The buckets keep their capacity between choices.
#[derive(Debug, Default)]
struct BucketQueue {
    buckets: Vec<Vec<Candidate>>,
    /// No bucket above this one holds a node.
    top: usize,
    len: usize,
    /// The largest priority queued since the last clear (the top bucket has no upper edge).
    largest: f32,
}

impl BucketQueue {
    fn clear(&mut self) {
        let used = (self.top + 1).min(self.buckets.len());
        for bucket in &mut self.buckets[..used] {
            bucket.clear();
        }
        self.top = 0;
        self.len = 0;
        self.largest = 0.0;
    }

    /// The bucket of a positive priority.
    fn bucket(priority: f32) -> usize {
        ((priority * BUCKETS_PER_LEVEL) as usize).min(MAX_BUCKETS - 1)
    }

    fn push(&mut self, candidate: Candidate) {
        let b = Self::bucket(candidate.priority);
        if self.buckets.len() <= b {
            self.buckets.resize_with(b + 1, Vec::new);
        }
        self.buckets[b].push(candidate);
        self.top = self.top.max(b);
        self.len += 1;
        self.largest = self.largest.max(candidate.priority);
    }

    fn pop(&mut self) -> Option<Candidate> {
        if self.len == 0 {
            return None;
        }
        loop {
            if let Some(c) = self.buckets[self.top].pop() {
                self.len -= 1;
                return Some(c);
            }
            self.top -= 1;
        }
    }

    /// The largest priority a queued node in the bucket of `priority` may have.
    fn bucket_top(&self, priority: f32) -> f32 {
        match Self::bucket(priority) {
            b if b == MAX_BUCKETS - 1 => self.largest,
            b => (b + 1) as f32 / BUCKETS_PER_LEVEL,
        }
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

impl LevelChooser {
    /// A chooser with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Chooses the level of every brick of `geometry` for `view` among `levels` levels
    /// (module docs): `active[i]` false for a culled brick, `slots` the cache's slots,
    /// `target_pixels` the largest on-screen size of a drawn voxel wanted, `previous` the last
    /// choice (one entry per brick, or empty for none) and `margin` the hysteresis in levels
    /// ([`level_margin`] of the two-level planner's relative margin; 0 for none).
    ///
    /// Errors: a culling result or a `previous` of another length than the bricks (reported as
    /// [`LevelChoiceError::ActiveCount`]), 0 levels (or more than 31, or more than 3 with bricks
    /// below 8 voxels), a target that is not a positive number, a margin that is negative or
    /// not finite. A cache too small for the coarsest plan is no error: the least important
    /// bricks are dropped (module docs, step 0).
    #[allow(clippy::too_many_arguments)] // reason: the view's inputs; folded into one planner input by the one residency system (issue 36).
    pub fn choose(
        &mut self,
        geometry: &BrickGeometry,
        view: &LodView,
        active: &[bool],
        levels: u32,
        slots: u64,
        target_pixels: f32,
        previous: &[Option<u32>],
        margin: f32,
    ) -> Result<&LevelChoice, LevelChoiceError> {
        let grid = geometry.grid();
        let count = grid.brick_count();
        if !previous.is_empty() && previous.len() != count {
            return Err(LevelChoiceError::ActiveCount {
                given: previous.len(),
                bricks: count,
            });
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
        if self.last == Some(inputs) && self.active == active && self.previous == previous {
            return Ok(&self.choice);
        }
        self.last = None;
        if self.boxes_for != Some((bricks, levels)) || self.active != active {
            self.build_boxes(bricks, levels, active);
        }
        self.previous.clear();
        self.previous.extend_from_slice(previous);
        let input = Inputs {
            geometry,
            view,
            active,
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

    /// Rebuilds the boxes of active bricks of every block level for `active`.
    fn build_boxes(&mut self, bricks: UVec3, levels: u32, active: &[bool]) {
        self.active.clear();
        self.active.extend_from_slice(active);
        self.boxes_for = Some((bricks, levels));
        self.boxes.clear();
        for k in 3..levels {
            let blocks = (bricks + UVec3::splat(block_bricks(k) - 1)) / block_bricks(k);
            let mut boxes = vec![BrickBox::EMPTY; blocks.element_product() as usize];
            let at = |c: UVec3| (c.x + blocks.x * (c.y + blocks.y * c.z)) as usize;
            match self.boxes.last() {
                None => {
                    for z in 0..bricks.z {
                        for y in 0..bricks.y {
                            for x in 0..bricks.x {
                                let b = UVec3::new(x, y, z);
                                if active[(x + bricks.x * (y + bricks.y * z)) as usize] {
                                    boxes[at(b / 2)].add(&BrickBox { min: b, max: b });
                                }
                            }
                        }
                    }
                }
                Some((counts, finer)) => {
                    for z in 0..counts.z {
                        for y in 0..counts.y {
                            for x in 0..counts.x {
                                let f = &finer[(x + counts.x * (y + counts.y * z)) as usize];
                                if !f.is_empty() {
                                    boxes[at(UVec3::new(x, y, z) / 2)].add(f);
                                }
                            }
                        }
                    }
                }
            }
            self.boxes.push((blocks, boxes));
        }
    }

    /// The box of active bricks of node `(level, origin)`.
    fn node_box(&self, input: &Inputs<'_>, level: u32, origin: UVec3) -> BrickBox {
        if level <= 2 {
            let i = linear(input.bricks, origin);
            return if input.active[i] {
                BrickBox {
                    min: origin,
                    max: origin,
                }
            } else {
                BrickBox::EMPTY
            };
        }
        let (blocks, boxes) = &self.boxes[(level - 3) as usize];
        boxes[linear(*blocks, origin >> (level - 2))]
    }

    /// Whether node `(level, origin)` is drawn: it holds an active brick, and its root is not
    /// dropped.
    fn drawn(&self, input: &Inputs<'_>, level: u32, origin: UVec3) -> bool {
        !self.dropped[self.root_index(input, origin)]
            && !self.node_box(input, level, origin).is_empty()
    }

    /// The first brick of root `r` (linear index over the roots, x fastest).
    fn root_origin(input: &Inputs<'_>, r: usize) -> UVec3 {
        let (r, roots) = (r as u32, input.roots);
        UVec3::new(
            r % roots.x,
            (r / roots.x) % roots.y,
            r / (roots.x * roots.y),
        ) << input.root_shift
    }

    /// The linear index of the root holding `brick`.
    fn root_index(&self, input: &Inputs<'_>, brick: UVec3) -> usize {
        linear(input.roots, brick >> input.root_shift)
    }

    /// The headroom of node `(level, origin)`: log2 of the target over the projected size of a
    /// hi-res voxel at the nearest point of its active box (module docs, step 1); `None` for a
    /// node with no active brick in view or a dropped root.
    fn headroom(&self, input: &Inputs<'_>, level: u32, origin: UVec3) -> Option<f32> {
        if self.dropped[self.root_index(input, origin)] {
            return None;
        }
        let active = self.node_box(input, level, origin);
        if active.is_empty() {
            return None;
        }
        let (min, _) = input.geometry.brick_box(active.min);
        let (_, max) = input.geometry.brick_box(active.max);
        if input.view.box_outside_frustum(min, max) {
            return None;
        }
        let eye = input.view.eye();
        let distance = (min - eye).max(eye - max).max(Vec3::ZERO).length();
        let pixels = input.voxel * input.view.pixels_per_world_unit(distance.max(input.voxel));
        Some((input.target_pixels / pixels).log2())
    }

    /// Queues node `(level, origin)` of `headroom` when it has a finer level and a positive
    /// priority: its level (moved by the hysteresis margin: refined in the last plan, kept
    /// refined past the boundary; drawn whole, refined only past it) less its headroom.
    fn push(&mut self, input: &Inputs<'_>, level: u32, origin: UVec3, headroom: Option<f32>) {
        let Some(headroom) = headroom.filter(|_| level > 0) else {
            return;
        };
        let k = level as f32;
        let threshold = match input.previous.get(linear(input.bricks, origin)).copied() {
            Some(Some(p)) if p < level => k + input.margin,
            Some(Some(p)) if p == level => k - input.margin,
            _ => k,
        };
        let priority = threshold - headroom;
        if priority > 0.0 {
            self.queue.push(Candidate {
                priority,
                headroom,
                level,
                origin,
            });
        }
    }

    /// Steps 0-4 of the module docs into `self.choice`.
    fn plan(&mut self, input: &Inputs<'_>, slots: u64) {
        let root = input.root;
        let bricks = input.bricks;
        let count = bricks.element_product() as usize;
        self.dropped.clear();
        self.dropped
            .resize(input.roots.element_product() as usize, false);
        self.level.clear();
        self.level.resize(count, root as u8);
        self.queue.clear();
        let mut per_class = [0u64; 3];
        for r in 0..self.dropped.len() {
            let origin = Self::root_origin(input, r);
            per_class[class(root)] += u64::from(self.drawn(input, root, origin));
        }
        let dropped = self.drop_to_fit(input, slots, &mut per_class);
        for r in 0..self.dropped.len() {
            let origin = Self::root_origin(input, r);
            let headroom = self.headroom(input, root, origin);
            self.push(input, root, origin, headroom);
        }
        let mut refused = None;
        while let Some(next) = self.queue.pop() {
            if u32::from(self.level[linear(bricks, next.origin)]) != next.level {
                continue; // refined already, as the rule forced
            }
            self.undo.clear();
            self.refine(
                input,
                next.level,
                next.origin,
                Some(next.headroom),
                &mut per_class,
            );
            if slots_for_classes(per_class) > slots {
                while let Some((level, origin)) = self.undo.pop() {
                    self.unrefine(input, level, origin, &mut per_class);
                }
                // Every node left has a priority in this bucket or below.
                refused = Some(self.queue.bucket_top(next.priority));
                break;
            }
        }
        self.write_choice(input, per_class, dropped, refused);
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
            let first = Self::root_origin(input, r);
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
            let first = Self::root_origin(input, r);
            let end = (first + UVec3::splat(block)).min(bricks);
            dropped += bricks_in(first, end)
                .filter(|&b| input.active[linear(bricks, b)])
                .count();
            self.dropped[r] = true;
            per_class[class(root)] -= 1;
        }
        dropped
    }

    /// Refines node `(level, origin)` (a leaf of the cut) to level `level - 1`, after refining
    /// every neighbouring node of level `level + 1` the rule would otherwise break, and logs
    /// each node refined in `self.undo`. `headroom` is the node's, when known.
    fn refine(
        &mut self,
        input: &Inputs<'_>,
        level: u32,
        origin: UVec3,
        headroom: Option<f32>,
        per_class: &mut [u64; 3],
    ) {
        let bricks = input.bricks;
        let size = block_bricks(level);
        // One probe per neighbouring direction: a node of level `level + 1` next to this one
        // (aligned at twice the size) holds one of them. Below a split block (levels 2 up to
        // the root's), the neighbours inside that block are siblings, never coarser: only the
        // directions out of it are probed (7 of 26).
        let (from, to) = if (2..input.root).contains(&level) {
            let corner = (origin / size) & UVec3::ONE;
            (corner, corner + UVec3::ONE)
        } else {
            (UVec3::ZERO, UVec3::splat(2))
        };
        for dz in from.z..=to.z {
            for dy in from.y..=to.y {
                for dx in from.x..=to.x {
                    if (dx, dy, dz) == (1, 1, 1) {
                        continue;
                    }
                    let Some(q) = probe(origin, size, UVec3::new(dx, dy, dz), bricks) else {
                        continue;
                    };
                    let at = u32::from(self.level[linear(bricks, q)]);
                    if at > level {
                        let block = block_bricks(at);
                        self.refine(input, at, q / block * block, None, per_class);
                    }
                }
            }
        }
        let finer = level - 1;
        if self.drawn(input, level, origin) {
            per_class[class(level)] -= 1;
        }
        self.fill(origin, size, bricks, finer);
        if level >= 3 {
            for child in children(origin, size, bricks) {
                per_class[class(finer)] += u64::from(self.drawn(input, finer, child));
                let headroom = self.headroom(input, finer, child);
                self.push(input, finer, child, headroom);
            }
        } else {
            // A brick refined in place: the same box, so the same headroom.
            per_class[class(finer)] += u64::from(self.drawn(input, finer, origin));
            let headroom = match headroom {
                Some(h) => Some(h),
                None => self.headroom(input, level, origin),
            };
            self.push(input, finer, origin, headroom);
        }
        self.undo.push((level, origin));
    }

    /// Undoes [`LevelChooser::refine`] of node `(level, origin)` (not what it forced).
    fn unrefine(
        &mut self,
        input: &Inputs<'_>,
        level: u32,
        origin: UVec3,
        per_class: &mut [u64; 3],
    ) {
        let bricks = input.bricks;
        let size = block_bricks(level);
        let finer = level - 1;
        if level >= 3 {
            for child in children(origin, size, bricks) {
                per_class[class(finer)] -= u64::from(self.drawn(input, finer, child));
            }
        } else {
            per_class[class(finer)] -= u64::from(self.drawn(input, finer, origin));
        }
        if self.drawn(input, level, origin) {
            per_class[class(level)] += 1;
        }
        self.fill(origin, size, bricks, level);
    }

    /// Sets the level of the bricks of the block at `origin` of `size` bricks per axis.
    fn fill(&mut self, origin: UVec3, size: u32, bricks: UVec3, level: u32) {
        let end = (origin + UVec3::splat(size)).min(bricks);
        for z in origin.z..end.z {
            for y in origin.y..end.y {
                let row = linear(bricks, UVec3::new(origin.x, y, z));
                self.level[row..row + (end.x - origin.x) as usize].fill(level as u8);
            }
        }
    }

    /// Step 4 and the report: the plan from the cut.
    fn write_choice(
        &mut self,
        input: &Inputs<'_>,
        per_class: [u64; 3],
        dropped: usize,
        refused: Option<f32>,
    ) {
        let bricks = input.bricks;
        let mut levels = std::mem::take(&mut self.choice.levels);
        levels.clear();
        for z in 0..bricks.z {
            for y in 0..bricks.y {
                for x in 0..bricks.x {
                    let b = UVec3::new(x, y, z);
                    let i = linear(bricks, b);
                    let level = u32::from(self.level[i]);
                    // A brick is drawn when active, or inside a drawn block (the node of a
                    // block level holds it whole).
                    levels.push(self.drawn(input, level, b).then_some(level));
                }
            }
        }
        self.choice = LevelChoice {
            levels,
            slots: slots_for_classes(per_class),
            pixels_per_voxel: input.target_pixels * refused.unwrap_or(0.0).max(0.0).exp2(),
            waiting: 0,
            dropped,
            failed_reads: 0,
        };
    }
}

/// The brick next to the block at `origin` of `size` bricks per axis in direction `d` (each
/// axis 0: before, 1: along, 2: after), `None` outside the grid.
fn probe(origin: UVec3, size: u32, d: UVec3, bricks: UVec3) -> Option<UVec3> {
    let axis = |o: u32, d: u32, n: u32| match d {
        0 => o.checked_sub(1),
        1 => Some(o),
        _ => Some(o + size).filter(|&v| v < n),
    };
    Some(UVec3::new(
        axis(origin.x, d.x, bricks.x)?,
        axis(origin.y, d.y, bricks.y)?,
        axis(origin.z, d.z, bricks.z)?,
    ))
}

/// The first bricks of the (up to) 8 blocks of half the size in the block at `origin` of
/// `size` bricks per axis, inside a grid of `bricks` per axis.
fn children(origin: UVec3, size: u32, bricks: UVec3) -> impl Iterator<Item = UVec3> {
    (0..8u32)
        .map(move |c| origin + UVec3::new(c & 1, (c >> 1) & 1, c >> 2) * (size / 2))
        .filter(move |child| child.cmplt(bricks).all())
}

/// The linear index of `b` in a grid of `size` per axis (x fastest).
fn linear(size: UVec3, b: UVec3) -> usize {
    (b.x + size.x * (b.y + size.y * b.z)) as usize
}

/// The bricks `first..end` (z, y, x order).
fn bricks_in(first: UVec3, end: UVec3) -> impl Iterator<Item = UVec3> {
    (first.z..end.z).flat_map(move |z| {
        (first.y..end.y).flat_map(move |y| (first.x..end.x).map(move |x| UVec3::new(x, y, z)))
    })
}
