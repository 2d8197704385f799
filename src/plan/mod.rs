//! Camera-driven residency planning: per frame, which level of every brick to draw now, which
//! levels the view wants, and what the brick source should load next, under GPU-cache, upload
//! and RAM budgets.
//!
//! [`ResidencyPlanner::plan_frame`] runs these steps, each O(bricks) or O(changes log changes):
//!
//! 1. **Culling** ([`crate::lod::cull_bricks`]) with the [`CullParams`] of the render settings
//!    ([`cull_params`]): culled bricks are [`Level::Absent`] in every output. The planner keeps
//!    the culling result with a copy of its inputs (geometry, criteria, value ranges) and culls
//!    again only when one of them changed; a caller that numbers its ranges
//!    ([`FrameInput::ranges_generation`]) spares the comparison of the ranges.
//! 2. **Dropping.** When even all-low-res does not fit the slot budget (eight `Lo` bricks per
//!    slot), only the `8 x slots` most important active bricks are kept; the rest are dropped
//!    (drawn `Absent`) and counted in [`PlanReport::dropped`]. This is never an error.
//!    Importance: larger [`screen_space_error`] first, then the nearer box, then the lower index.
//! 3. **Wanted levels**, budget-driven as in [`crate::lod::LodSelector`]: every kept brick is at
//!    least `Lo` and the `h` best-ranked candidates are `Hi`, `h` the largest count with
//!    `h + ceil((kept - h) / 8) <= slots` ([`max_hi_bricks`]). With hysteresis margin `m`
//!    ([`PlanOptions::hysteresis`]; the `h` best are found by merging two runs of the order by
//!    error of step 6, the bricks wanted `Hi` last frame and the others, visiting only the
//!    bricks before the boundary (`select.rs`); equal keys ordered as below):
//!    - a brick wanted `Hi` last frame ranks with its error times `1 + m` (and wins exact ties),
//!      so two bricks of nearly equal error do not swap levels back and forth;
//!    - with an error threshold `t > 0` ([`PlanOptions::error_threshold`]) a brick becomes a
//!      candidate for `Hi` only when its error exceeds `t (1 + m)`, and stays one while it
//!      exceeds `t / (1 + m)`; with `t = 0` every kept brick is a candidate.
//! 4. **Fallback**: the *target* of a brick is its wanted level when the source has it loaded,
//!    else `Lo` when that is loaded (as [`crate::bricks::fallback_levels`]), with one addition
//!    for zooming out: a brick wanted `Lo` whose `Lo` level is not loaded but that is drawn `Hi`
//!    with its `Hi` level loaded keeps the target `Hi`, so it stays drawn instead of leaving a
//!    hole until its `Lo` bytes arrive. Such kept `Hi` levels take only the slots the other
//!    targets leave free, the most important first; under that slot pressure the rest are
//!    targeted (and drawn) `Absent`, as is every brick none of whose usable levels is loaded.
//!    The targets therefore always fit the slot budget. [`PlanReport::waiting_for_source`]
//!    counts the bricks whose target differs from their wanted level (a lower fallback, a kept
//!    `Hi`, or `Absent`).
//! 5. **Staging** the change from the previous frame's drawn levels to the targets, under the
//!    upload budget. Uploading a brick costs `(n+2)^3` texels (`Hi`) or `(n/2+1)^3` (`Lo`) times
//!    the bytes per texel ([`upload_bytes`]); a change to `Absent` costs nothing and is always
//!    applied. A brick that is not changed this frame keeps its previous drawn level (it is
//!    resident on the GPU already). In order:
//!    1. while the drawn levels need more slots than the budget (the budget shrank), pending
//!       `Hi -> Lo` changes of the least important bricks are applied (or, when the upload
//!       budget cannot pay even that, the brick is drawn `Absent` for now);
//!    2. holes (drawn `Absent`, target resident), most important first; a hole whose `Hi`
//!       upload does not fit this frame is first filled at `Lo` when that is loaded;
//!    3. refinements (`Lo -> Hi`), most important first;
//!    4. the remaining coarsenings (`Hi -> Lo`), least important first.
//!
//!    A change that needs a slot takes it from pending coarsenings (least important first) when
//!    the budget is full. A change that does not fit the bytes left is skipped and follows in a
//!    later frame. Once every pending coarsening is applied the drawn levels are at most as fine
//!    as the targets, which fit the slot budget, so every refinement eventually fits.
//! 6. **Requests** for the source: [`request_plan`] of the wanted levels (all `Lo` levels first,
//!    then the `Hi` levels, each by descending error), followed by the levels drawn now that are
//!    not wanted (a pending coarsening keeps its `Hi` bytes in RAM for re-uploads), re-ranked so
//!    that the priorities are `len - position`. With a RAM budget
//!    ([`PlanBudget::ram_bytes`]) the list is cut to the longest prefix whose bytes fit. The
//!    order by error comes from one sort of the kept bricks (by the top radix digit of the
//!    key, then bucket by bucket; equal errors in brick order, as `request_plan` keeps them),
//!    the one sort of a moving frame: the `Hi` selection of step 3 reads it too.
//!
//! Errors and box distances are computed from per-axis squared distance components (the same
//! floating-point operations as [`screen_space_error`], so the same values; the distances, only
//! needed to break ties of importance, on demand), and every buffer is kept in the planner
//! between frames (the vectors of the returned [`FramePlan`] are the previous frame's,
//! refilled): once they have grown, a frame allocates nothing. For a still camera (the same
//! view, slot budget and culling inputs as the last frame) the errors, the dropping and the
//! order by error are the last frame's and are reused; when the wanted levels, the RAM cut and
//! the drawn-but-not-wanted `Hi` levels are the last frame's too, so are the requests. When
//! the last frame's wanted levels were those of the frame before it (a settled still camera),
//! the `Hi` selection is skipped as well: its inputs are the last frame's, so
//! the wanted levels are. Given what the source has loaded as one byte per brick
//! ([`ResidencyPlanner::plan_frame_with_loaded`], [`ResidencyPlanner::plan_frame_with_source`]),
//! the per-brick target pass (`targets.rs`) decides every brick without a branch on its state,
//! in blocks the compiler vectorizes; asking a closure ([`ResidencyPlanner::plan_frame`]), it
//! takes a short path for a brick drawn at its wanted level with that level loaded. Both give
//! the same plan. `benches/planner.rs` times a frame of about 10^5 bricks both ways.
//!
//! # Guarantees
//!
//! - The drawn levels never need more than [`PlanBudget::slots`] slots and the staged uploads
//!   never exceed [`PlanBudget::upload_bytes_per_frame`]. The upload bytes counted are the level
//!   changes; the cache's compaction moves and border restores
//!   ([`crate::cache::CacheUpdate`]) come on top and need headroom in the host's staging budget.
//! - The neighbour rule ([`crate::lod::check_level_rule`]) holds for the drawn levels: with two
//!   levels and `Absent` imposing nothing, every assignment satisfies it.
//! - For a still camera and an unchanging source the plan converges (the wanted levels are
//!   stable from the second frame on, and each frame stages at least one pending change while
//!   the upload budget holds one `Hi` and two `Lo` bricks) and then uploads nothing.
//! - With a slot budget that does not bind (so the error threshold alone decides) and a source
//!   that keeps its levels loaded, a frame in which a brick's distance from the eye did not grow
//!   never draws that brick coarser than the frame before: its error did not fall, so a brick
//!   wanted `Hi` stays wanted `Hi`, and nothing but a wanted coarsening or slot pressure coarsens
//!   a drawn brick. The one exception is a coarsening wanted in an earlier frame (when the
//!   distance grew) and still deferred by the upload budget. Along a straight dolly path the
//!   distance to a box is convex in the path parameter, so once it grows it keeps growing and
//!   the exception cannot occur there. Under a binding slot budget nearer bricks compete for
//!   the same slots and no such promise is made.
//!
//! Everything here is CPU-only bookkeeping; wiring it into the pass is the host's job.

use crate::bricks::{BrickSource, Level, LoadedLevels, ValueRange};
use crate::cache::CacheError;
use crate::lod::{
    cull_bricks_into, max_hi_bricks, slots_needed, BrickGeometry, CullParams, LodError, LodView,
};
// Used by the tests.
#[cfg(test)]
use crate::{
    lod::{TfCullTable, ValueCulling},
    optics::TransferFunction,
    scene::{RenderMode, RenderSettings},
};
// Named by the documentation, and compared against by the tests.
#[cfg(any(test, doc))]
use crate::bricks::request_plan;
#[cfg(any(test, doc))]
use crate::lod::screen_space_error;
#[cfg(test)]
use glam::Vec3;
use loaded::{Asked, Loaded, PerBrick};
use order::{more_important, Distances, OrderKeys};
use screen_error::{compute_errors, same_bits, width_factor};
use select::{
    entry_brick, entry_was_hi, order_entry, refresh_was_hi, request_key, select_hi, Ranking,
    SelectScratch,
};
use targets::{targets, Bricks, Changes, Counts};

pub use frame::{
    cull_params, upload_bytes, FrameInput, FramePlan, PlanBudget, PlanOptions, PlanReport,
};
pub use level_choice::{choose_levels, level_margin, LevelChoice, LevelChoiceError, LevelRequest};
pub use level_steps::{admit_by_budget, next_target, step_towards};
pub use levels::LevelChooser;

mod brick_headroom;
mod frame;
mod level_choice;
mod level_rule;
mod level_steps;
mod levels;
mod loaded;
mod order;
mod screen_error;
mod select;
mod targets;
#[cfg(test)]
mod tests;

/// Why a frame cannot be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// Culling or error estimation rejected an input (value window, iso-value, brick counts).
    #[error(transparent)]
    Lod(#[from] LodError),
    /// Converting a cache byte budget to slots failed.
    #[error(transparent)]
    Cache(#[from] CacheError),
    /// A budget or option is unusable.
    #[error("invalid {field}: {reason}")]
    InvalidInput {
        /// Which field (`"bytes_per_texel"`, `"error_threshold"`, `"hysteresis"`, `"geometry"`).
        field: &'static str,
        /// What is wrong.
        reason: &'static str,
    },
}

/// The per-frame residency planner; keeps the previous frame's plan (for hysteresis and for
/// staging) and its buffers between frames.
#[derive(Clone, Debug, Default)]
pub struct ResidencyPlanner {
    options: PlanOptions,
    plan: FramePlan,
    /// Reused per-frame buffers.
    work: Work,
    /// What the source has loaded, per brick ([`ResidencyPlanner::plan_frame_with_source`]).
    loaded: Vec<LoadedLevels>,
}

/// Buffers the planner reuses from frame to frame, so that a frame allocates nothing once they
/// have grown.
#[derive(Clone, Debug, Default)]
struct Work {
    /// What `culled` and `width` were computed from: geometry, culling criteria, value ranges.
    cull_inputs: Option<(BrickGeometry, CullParams)>,
    cull_ranges: Vec<ValueRange>,
    /// The [`FrameInput::ranges_generation`] of `cull_ranges`.
    cull_generation: Option<u64>,
    /// The culling result, and how many bricks it keeps.
    culled: Vec<bool>,
    culled_count: usize,
    /// The culling result, then also cleared for dropped bricks.
    active: Vec<bool>,
    /// Per brick, what the error is the projected pixel size times ([`width_factor`]).
    width: Vec<f32>,
    /// Squared per-axis components of the box distance from the eye, one per brick slab
    /// (the distances are computed from them on demand, [`Distances`]).
    axis_sq: [Vec<f32>; 3],
    error: Vec<f32>,
    /// The view and slot budget `error`, `active` (after dropping) and the sorted `by_error`
    /// were computed for, with the count of dropped bricks: while they and the culling inputs
    /// are unchanged (a still camera), those are reused as they are.
    order_inputs: Option<(LodView, usize, usize)>,
    target: Vec<Level>,
    /// The buffer of the wanted levels before the previous frame's, reused for this frame's.
    spare_wanted: Vec<Level>,
    /// Active bricks (only when dropping).
    order: Vec<u32>,
    /// Scratch of the `Hi` selection.
    select_scratch: SelectScratch,
    /// Bricks drawn `Hi` but not wanted `Hi`, this frame's and the last one's.
    extra: Vec<u32>,
    prev_extra: Vec<u32>,
    /// The `Lo` and `Hi` request counts the last plan's requests were built with (`None`
    /// when the plan was reset or replaced): with them, the last order and the same wanted
    /// levels and `extra`, the requests are the same.
    request_fit: Option<(usize, usize)>,
    /// The count of `Hi` bricks when the last frame's wanted levels were those of the frame
    /// before it (`None` when they were not, or the plan was reset or replaced): with the
    /// same errors they are this frame's as well.
    settled_hi: Option<usize>,
    /// The kept bricks by descending error (NaN last), equal errors in brick order: the
    /// [`order_entry`] of each brick's [`request_key`], with a bit that says whether it was
    /// wanted `Hi` last frame (the `Hi` selection reads the order alone).
    by_error: Vec<u64>,
    sort_scratch: Vec<u64>,
    coarsen: Vec<u32>,
    holes: Vec<u32>,
    refine: Vec<u32>,
    keep_hi: Vec<u32>,
}

/// Running counts of the drawn levels and the upload budget while staging.
struct Stage {
    hi: usize,
    lo: usize,
    slots: usize,
    bytes_left: u64,
    cost_hi: u64,
    cost_lo: u64,
}

impl Stage {
    fn slots_with(&self, hi: isize, lo: isize) -> usize {
        slots_needed(
            (self.hi as isize + hi) as usize,
            (self.lo as isize + lo) as usize,
        )
    }

    fn cost(&self, level: Level) -> u64 {
        match level {
            Level::Hi => self.cost_hi,
            Level::Lo => self.cost_lo,
            Level::Absent => 0,
        }
    }

    fn delta(level: Level) -> (isize, isize) {
        match level {
            Level::Hi => (1, 0),
            Level::Lo => (0, 1),
            Level::Absent => (0, 0),
        }
    }

    /// Counts after changing one brick from `from` to `to`.
    fn change(&self, from: Level, to: Level) -> (isize, isize) {
        let (fh, fl) = Self::delta(from);
        let (th, tl) = Self::delta(to);
        (th - fh, tl - fl)
    }
}

impl ResidencyPlanner {
    /// A planner with `options` and no previous frame.
    pub fn new(options: PlanOptions) -> Self {
        Self {
            options,
            ..Self::default()
        }
    }

    /// The options.
    pub fn options(&self) -> PlanOptions {
        self.options
    }

    /// The last frame's plan (empty before the first frame).
    pub fn last_plan(&self) -> &FramePlan {
        &self.plan
    }

    /// Forgets the previous frame: the next frame plans as if nothing were resident (after the
    /// GPU cache was cleared, or for a new volume).
    pub fn reset(&mut self) {
        self.plan = FramePlan::default();
        self.work.request_fit = None;
        self.work.settled_hi = None;
    }

    /// Replaces the drawn levels the next frame stages from with `drawn` (one per brick): for a
    /// host whose cache ended up other than the last plan said (a brick whose bytes the source
    /// dropped before they were uploaded is drawn at a fallback), or that set the levels itself.
    /// When the last plan has another brick count (or there is none), `drawn` also stands in
    /// for the wanted levels of the previous frame (the hysteresis starts from it).
    pub fn set_drawn(&mut self, drawn: &[Level]) {
        if drawn.len() == self.plan.draw.len() && drawn.len() == self.plan.wanted.len() {
            self.plan.draw.copy_from_slice(drawn);
        } else {
            self.work.request_fit = None;
            self.work.settled_hi = None;
            self.plan = FramePlan {
                draw: drawn.to_vec(),
                wanted: drawn.to_vec(),
                ..FramePlan::default()
            };
        }
    }

    /// [`ResidencyPlanner::plan_frame`] with what `source` has loaded
    /// ([`BrickSource::is_loaded`]).
    pub fn plan_frame_with_source(
        &mut self,
        frame: &FrameInput<'_>,
        source: &dyn BrickSource,
    ) -> Result<&FramePlan, PlanError> {
        // One call for every brick ([`BrickSource::loaded_levels`]) rather than one per brick
        // and level: a streaming source answers it under one lock.
        let mut loaded = std::mem::take(&mut self.loaded);
        source.loaded_levels(&mut loaded);
        let planned = self.plan(frame, &PerBrick(&loaded)).map(|_| ());
        self.loaded = loaded;
        planned.map(|()| &self.plan)
    }

    /// What the source had loaded when [`ResidencyPlanner::plan_frame_with_source`] last asked
    /// it (one entry per brick; empty before the first call).
    pub fn source_loaded(&self) -> &[LoadedLevels] {
        &self.loaded
    }

    /// [`ResidencyPlanner::plan_frame`] with what the source has loaded given as one
    /// [`LoadedLevels`] per brick (bricks past the end of `loaded` have nothing loaded), as
    /// [`BrickSource::loaded_levels`] fills them. The same plan as asking brick by brick, found
    /// faster: the planner reads the levels in blocks.
    pub fn plan_frame_with_loaded(
        &mut self,
        frame: &FrameInput<'_>,
        loaded: &[LoadedLevels],
    ) -> Result<&FramePlan, PlanError> {
        self.plan(frame, &PerBrick(loaded))
    }

    /// Plans one frame (see the module documentation); `is_loaded(brick, level)` says whether the
    /// source has the bytes of `brick` at `level` now. A grid with another brick count than the
    /// previous frame's starts from nothing resident. Errors: unusable options, a zero
    /// `bytes_per_texel`, or what culling rejects (value ranges of the wrong length, a non-finite
    /// iso-value); the previous plan is kept then.
    pub fn plan_frame(
        &mut self,
        frame: &FrameInput<'_>,
        is_loaded: impl Fn(u32, Level) -> bool,
    ) -> Result<&FramePlan, PlanError> {
        self.plan(frame, &Asked(is_loaded))
    }

    /// [`ResidencyPlanner::plan_frame`] with the source's answers as a [`Loaded`].
    fn plan(
        &mut self,
        frame: &FrameInput<'_>,
        loaded: &impl Loaded,
    ) -> Result<&FramePlan, PlanError> {
        let is_loaded = |brick, level| loaded.is_loaded(brick, level);
        let PlanOptions {
            error_threshold,
            hysteresis,
        } = self.options;
        if !(error_threshold.is_finite() && error_threshold >= 0.0) {
            return Err(PlanError::InvalidInput {
                field: "error_threshold",
                reason: "must be finite and >= 0",
            });
        }
        if !(hysteresis.is_finite() && hysteresis >= 0.0) {
            return Err(PlanError::InvalidInput {
                field: "hysteresis",
                reason: "must be finite and >= 0",
            });
        }
        let budget = frame.budget;
        if budget.bytes_per_texel == 0 {
            return Err(PlanError::InvalidInput {
                field: "bytes_per_texel",
                reason: "must be > 0",
            });
        }
        let geometry = frame.geometry;
        let count = geometry.grid().brick_count();
        if count >= 1 << 31 {
            // The order by error keeps a brick index in 31 bits.
            return Err(PlanError::InvalidInput {
                field: "geometry",
                reason: "more than 2^31 - 1 bricks",
            });
        }
        let Self { plan, work, .. } = self;
        // Culling (and the range widths) only when its inputs changed.
        let cull_unchanged = work
            .cull_inputs
            .as_ref()
            .is_some_and(|(g, c)| g == geometry && c == frame.cull)
            && work.cull_ranges.len() == frame.ranges.len()
            && ((frame.ranges_generation.is_some()
                && frame.ranges_generation == work.cull_generation)
                || same_bits(&work.cull_ranges, frame.ranges));
        work.cull_generation = frame.ranges_generation;
        if !cull_unchanged {
            work.cull_inputs = None;
            work.order_inputs = None;
            cull_bricks_into(geometry, frame.ranges, frame.cull, &mut work.culled)?;
            work.cull_inputs = Some((*geometry, frame.cull.clone()));
            work.culled_count = work.culled.iter().filter(|&&a| a).count();
            work.cull_ranges.clear();
            work.cull_ranges.extend_from_slice(frame.ranges);
            work.width.clear();
            work.width.extend(
                frame
                    .ranges
                    .iter()
                    .zip(&work.culled)
                    .map(|(&r, &a)| width_factor(r, a)),
            );
        }
        // A still camera: the errors, dropping and request order of the last frame hold.
        let reuse_order = work
            .order_inputs
            .is_some_and(|(v, s, _)| v == *frame.view && s == budget.slots);
        if plan.draw.len() != count || plan.wanted.len() != count {
            plan.draw = vec![Level::Absent; count];
            plan.wanted = vec![Level::Absent; count];
        }
        let mut report = PlanReport {
            bricks: count,
            slot_budget: budget.slots,
            upload_budget: budget.upload_bytes_per_frame,
            ..PlanReport::default()
        };

        let active_count = work.culled_count;
        report.culled = count - active_count;
        let capacity = budget
            .slots
            .saturating_mul(crate::bricks::SUB_SLOTS_PER_SLOT as usize);
        if let (true, Some((_, _, dropped))) = (reuse_order, work.order_inputs) {
            report.dropped = dropped;
        } else {
            work.order_inputs = None;
            work.active.clone_from(&work.culled);
            // Errors (of every brick; only the active ones are read). A separate loop from the
            // entries of the order by error: this one vectorizes (writing the entries in it made
            // the two together cost 2.7 times the instructions, the frame 27 % more).
            compute_errors(
                geometry,
                frame.view,
                &work.width,
                &mut work.axis_sq,
                &mut work.error,
            );
        }

        // Dropping: keep the 8 x slots most important active bricks.
        let Work {
            active,
            error,
            axis_sq,
            order_inputs,
            target,
            spare_wanted,
            order,
            select_scratch,
            extra,
            prev_extra,
            request_fit,
            settled_hi,
            by_error,
            sort_scratch,
            coarsen,
            holes,
            refine,
            keep_hi,
            ..
        } = work;
        let error = &*error;
        let distance = Distances::new(axis_sq);
        let importance = |a: &u32, b: &u32| more_important(error, distance, *a, *b);
        if !reuse_order && active_count > capacity {
            order.clear();
            order.extend((0..count as u32).filter(|&i| active[i as usize]));
            if capacity > 0 {
                order.select_nth_unstable_by(capacity, importance);
            }
            for &i in &order[capacity..] {
                active[i as usize] = false;
            }
            report.dropped = active_count - capacity;
        }
        let kept = active_count - report.dropped;

        // Wanted levels.
        let prev_wanted = &plan.wanted;
        let boost = 1.0 + hysteresis;
        let refine_above = error_threshold * boost;
        let keep_above = error_threshold / boost;
        let is_candidate = |e: f32, was_hi: bool| {
            (error_threshold == 0.0) | (e > refine_above) | (was_hi & (e > keep_above)) | e.is_nan()
        };
        // A still camera over settled wanted levels (the last frame's were the same as the frame
        // before's, from the same errors): the selection is the last frame's, and so are the
        // wanted levels.
        let reuse_wanted = if reuse_order { *settled_hi } else { None };
        let mut wanted = std::mem::take(spare_wanted);
        wanted.resize(count, Level::Absent);
        let hi = if let Some(hi) = reuse_wanted {
            wanted.copy_from_slice(prev_wanted);
            hi
        } else {
            if !reuse_order {
                // The kept bricks by descending error (NaN last), equal errors in brick order
                // ([`order_entry`]), sorted with the counts of the keys' top digits.
                let mut keys = OrderKeys::new();
                by_error.resize(count, 0);
                let entries = by_error.as_mut_slice();
                let was_hi = prev_wanted.iter().map(|&w| w == Level::Hi);
                for (i, ((&a, &e), was_hi)) in active.iter().zip(error).zip(was_hi).enumerate() {
                    let k = request_key(e);
                    keys.push(entries, k, order_entry(k, i as u32, was_hi), a);
                }
                keys.sort(by_error, sort_scratch);
                *order_inputs = Some((*frame.view, budget.slots, report.dropped));
            } else {
                // The last frame's order, with this frame's previous wanted levels.
                refresh_was_hi(by_error, prev_wanted);
            }
            // Every kept brick is at least `Lo`; the best-ranked candidates become `Hi`.
            for (w, &a) in wanted.iter_mut().zip(active.iter()) {
                *w = if a { Level::Lo } else { Level::Absent };
            }
            let candidate_count = if error_threshold == 0.0 {
                kept
            } else {
                by_error
                    .iter()
                    .filter(|&&k| is_candidate(error[entry_brick(k) as usize], entry_was_hi(k)))
                    .count()
            };
            let hi = max_hi_bricks(kept, candidate_count, budget.slots).unwrap_or(0);
            let ranking = Ranking {
                by_error,
                error,
                distance,
                prev_wanted,
                boost,
            };
            let selected = select_hi(ranking, hi, is_candidate, select_scratch, &mut wanted);
            debug_assert_eq!(selected, hi);
            hi
        };
        report.wanted_hi = hi;
        report.wanted_lo = kept - hi;

        // Targets: the best loaded level at or below the wanted one; a brick wanted `Lo` but
        // drawn `Hi` whose `Lo` level is not loaded keeps `Hi` while that is loaded and the
        // slots allow (decided below).
        let mut draw = std::mem::take(&mut plan.draw);
        target.resize(count, Level::Absent);
        keep_hi.clear();
        coarsen.clear();
        holes.clear();
        refine.clear();
        let counts = targets(
            Bricks {
                prev_wanted,
                wanted: &wanted,
                error,
                draw: &mut draw,
                target,
            },
            Changes {
                keep_hi,
                coarsen,
                holes,
                refine,
            },
            loaded,
        );
        let Counts {
            target_hi,
            target_lo,
            mut drawn_hi,
            drawn_lo,
            deferred,
            waiting,
            max_lo_error,
            wanted_changed,
        } = counts;
        report.waiting_for_source = waiting;
        // The kept Hi levels take the slots the targets leave free, most important first.
        let free = budget
            .slots
            .saturating_sub(slots_needed(target_hi, target_lo));
        if keep_hi.len() > free {
            if free > 0 {
                keep_hi.select_nth_unstable_by(free, importance);
            }
            for &i in &keep_hi[free..] {
                draw[i as usize] = Level::Absent;
                drawn_hi -= 1;
            }
            keep_hi.truncate(free);
        }
        for &i in keep_hi.iter() {
            target[i as usize] = Level::Hi;
        }
        let target = &*target;

        // Staging.
        let n = geometry.grid().brick_size();
        let mut stage = Stage {
            hi: drawn_hi,
            lo: drawn_lo,
            slots: slots_needed(drawn_hi, drawn_lo),
            bytes_left: budget.upload_bytes_per_frame,
            cost_hi: upload_bytes(Level::Hi, n, budget.bytes_per_texel),
            cost_lo: upload_bytes(Level::Lo, n, budget.bytes_per_texel),
        };
        let (cost_hi, cost_lo) = (stage.cost_hi, stage.cost_lo);
        coarsen.sort_unstable_by(|a, b| importance(b, a));
        holes.sort_unstable_by(importance);
        refine.sort_unstable_by(importance);
        let mut uploads = std::mem::take(&mut plan.uploads);
        uploads.clear();
        let mut next_coarsen = 0;
        let mut deferred_change = 0isize;
        let mut apply = |stage: &mut Stage, draw: &mut [Level], i: u32, to: Level| {
            let from = draw[i as usize];
            let t = target[i as usize];
            deferred_change += isize::from(to != t) - isize::from(from != t);
            let (dh, dl) = stage.change(from, to);
            stage.hi = (stage.hi as isize + dh) as usize;
            stage.lo = (stage.lo as isize + dl) as usize;
            stage.slots = slots_needed(stage.hi, stage.lo);
            stage.bytes_left -= stage.cost(to);
            draw[i as usize] = to;
            if to != Level::Absent {
                uploads.push((i, to));
            }
        };
        // 1. Fit a shrunken slot budget.
        while stage.slots > budget.slots && next_coarsen < coarsen.len() {
            let i = coarsen[next_coarsen];
            next_coarsen += 1;
            let to = if stage.bytes_left >= stage.cost_lo {
                Level::Lo
            } else {
                Level::Absent
            };
            apply(&mut stage, &mut draw, i, to);
        }
        let emergency = stage.slots > budget.slots;
        if emergency {
            // Unreachable while the targets fit the budget; kept so the budget holds regardless.
            let mut resident: Vec<u32> = (0..count as u32)
                .filter(|&i| draw[i as usize] != Level::Absent)
                .collect();
            resident.sort_unstable_by(|a, b| importance(b, a));
            for i in resident {
                if stage.slots <= budget.slots {
                    break;
                }
                apply(&mut stage, &mut draw, i, Level::Absent);
            }
        }
        // 2. and 3. Holes, then refinements, making room from pending coarsenings.
        let steps = holes
            .iter()
            .map(|&i| (i, true))
            .chain(refine.iter().map(|&i| (i, false)));
        for (i, is_hole) in steps {
            let to = target[i as usize];
            let from = draw[i as usize];
            // A hole whose Hi upload does not fit is filled low-res when that is loaded.
            let lo_too = is_hole && to == Level::Hi && is_loaded(i, Level::Lo);
            let tries = if lo_too {
                &[Level::Hi, Level::Lo][..]
            } else {
                &[to][..]
            };
            for &to in tries {
                let cost = stage.cost(to);
                if stage.bytes_left < cost {
                    continue;
                }
                let (dh, dl) = stage.change(from, to);
                while stage.slots_with(dh, dl) > budget.slots
                    && next_coarsen < coarsen.len()
                    && stage.bytes_left >= cost.saturating_add(stage.cost_lo)
                {
                    let c = coarsen[next_coarsen];
                    next_coarsen += 1;
                    apply(&mut stage, &mut draw, c, Level::Lo);
                }
                if stage.slots_with(dh, dl) <= budget.slots {
                    apply(&mut stage, &mut draw, i, to);
                    break;
                }
            }
        }
        // 4. The remaining coarsenings.
        while next_coarsen < coarsen.len() && stage.bytes_left >= stage.cost_lo {
            let c = coarsen[next_coarsen];
            next_coarsen += 1;
            apply(&mut stage, &mut draw, c, Level::Lo);
        }

        // Report: staging kept the counts; only bricks it touched can have become drawn `Lo`.
        report.drawn_hi = stage.hi;
        report.drawn_lo = stage.lo;
        // A brick drawn at a resident level is wanted at one.
        report.drawn_absent = kept - stage.hi - stage.lo;
        report.deferred = (deferred as isize + deferred_change) as usize;
        report.max_drawn_error = if emergency {
            draw.iter()
                .zip(error)
                .filter(|(&d, _)| d == Level::Lo)
                .fold(0.0, |m, (_, &e)| m.max(e))
        } else {
            coarsen
                .iter()
                .chain(holes.iter())
                .chain(refine.iter())
                .filter(|&&i| draw[i as usize] == Level::Lo)
                .fold(max_lo_error, |m, &i| m.max(error[i as usize]))
        };
        // The bricks drawn `Hi` but not wanted `Hi` (pending coarsenings of bricks wanted `Lo`,
        // and kept `Hi` levels), in brick order.
        extra.clear();
        extra.extend(
            coarsen
                .iter()
                .chain(keep_hi.iter())
                .copied()
                .filter(|&i| draw[i as usize] == Level::Hi && wanted[i as usize] != Level::Hi),
        );
        extra.sort_unstable();
        report.slots_used = slots_needed(report.drawn_hi, report.drawn_lo);
        report.upload_bytes = budget.upload_bytes_per_frame - stage.bytes_left;

        // Requests: the wanted levels as `request_plan` ranks them (every kept brick's `Lo`
        // level, then the `Hi` levels, each by descending error, equal errors in brick order),
        // then what is drawn `Hi` but not wanted `Hi` (in brick order), cut to the RAM budget.
        debug_assert_eq!(by_error.len(), kept);
        let lo_count = by_error.len();
        let hi_count = report.wanted_hi + extra.len();
        // Every Lo level costs `cost_lo` and comes first, every Hi level `cost_hi`: the longest
        // prefix that fits the RAM budget follows from two divisions.
        let (fit_lo, fit_hi) = match budget.ram_bytes {
            None => (lo_count, hi_count),
            Some(ram) => {
                let fit_lo = (ram / cost_lo.max(1)).min(lo_count as u64) as usize;
                if fit_lo < lo_count {
                    (fit_lo, 0)
                } else {
                    let left = ram - lo_count as u64 * cost_lo;
                    (
                        lo_count,
                        (left / cost_hi.max(1)).min(hi_count as u64) as usize,
                    )
                }
            }
        };
        report.requests_cut = lo_count + hi_count - fit_lo - fit_hi;
        report.request_bytes = (fit_lo as u64)
            .saturating_mul(cost_lo)
            .saturating_add((fit_hi as u64).saturating_mul(cost_hi));
        let total = fit_lo + fit_hi;
        // A still camera over a settled plan asks for the same again.
        let same_requests = reuse_order
            && !wanted_changed
            && *request_fit == Some((fit_lo, fit_hi))
            && extra == prev_extra;
        if !same_requests {
            let mut requests = std::mem::take(&mut plan.requests);
            requests.clear();
            requests.reserve(total);
            requests.extend(
                by_error[..fit_lo]
                    .iter()
                    .enumerate()
                    .map(|(pos, &k)| (entry_brick(k), Level::Lo, (total - pos) as f32)),
            );
            if fit_hi > 0 {
                let hi_levels = by_error
                    .iter()
                    .map(|&k| entry_brick(k))
                    .filter(|&i| wanted[i as usize] == Level::Hi)
                    .take(report.wanted_hi)
                    .chain(extra.iter().copied())
                    .take(fit_hi);
                requests.extend(
                    hi_levels
                        .enumerate()
                        .map(|(pos, i)| (i, Level::Hi, (total - fit_lo - pos) as f32)),
                );
            }
            plan.requests = requests;
        }
        std::mem::swap(extra, prev_extra);
        *request_fit = Some((fit_lo, fit_hi));
        *settled_hi = (!wanted_changed).then_some(report.wanted_hi);
        let prev_wanted = std::mem::replace(&mut plan.wanted, wanted);
        *spare_wanted = prev_wanted;
        plan.draw = draw;
        plan.uploads = uploads;
        plan.report = report;
        Ok(&self.plan)
    }
}

/// Distance from `p` to the nearest point of the box `[min, max]` (0 inside).
#[cfg(test)]
fn box_distance(p: Vec3, min: Vec3, max: Vec3) -> f32 {
    (min - p).max(p - max).max(Vec3::ZERO).length()
}
