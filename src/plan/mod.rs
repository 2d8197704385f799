//! Camera-driven residency planning: per frame, which level of every brick to draw now, which
//! levels the view wants, and what the brick source should load next, under GPU-cache, upload
//! and RAM budgets.
//!
//! [`ResidencyPlanner::plan_frame`] runs these steps, each O(bricks) or O(changes log changes):
//!
//! 1. **Culling** ([`crate::lod::cull_bricks`]) with the [`CullParams`] of the render settings
//!    ([`cull_params`]): culled bricks are [`Level::Absent`] in every output.
//! 2. **Dropping.** When even all-low-res does not fit the slot budget (eight `Lo` bricks per
//!    slot), only the `8 x slots` most important active bricks are kept; the rest are dropped
//!    (drawn `Absent`) and counted in [`PlanReport::dropped`]. This is never an error.
//!    Importance: larger [`screen_space_error`] first, then the nearer box, then the lower index.
//! 3. **Wanted levels**, budget-driven as in [`crate::lod::LodSelector`]: every kept brick is at
//!    least `Lo` and the `h` best-ranked candidates are `Hi`, `h` the largest count with
//!    `h + ceil((kept - h) / 8) <= slots` ([`max_hi_bricks`]). With hysteresis margin `m`
//!    ([`PlanOptions::hysteresis`]):
//!    - a brick wanted `Hi` last frame ranks with its error times `1 + m` (and wins exact ties),
//!      so two bricks of nearly equal error do not swap levels back and forth;
//!    - with an error threshold `t > 0` ([`PlanOptions::error_threshold`]) a brick becomes a
//!      candidate for `Hi` only when its error exceeds `t (1 + m)`, and stays one while it
//!      exceeds `t / (1 + m)`; with `t = 0` every kept brick is a candidate.
//! 4. **Fallback** (as [`crate::bricks::fallback_levels`]): the *target* of a brick is its wanted
//!    level when the source has it loaded, else `Lo` when that is loaded, else `Absent`.
//!    [`PlanReport::waiting_for_source`] counts the bricks whose target is below their wanted
//!    level.
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
//!    ([`PlanBudget::ram_bytes`]) the list is cut to the longest prefix whose bytes fit.
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

use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, request_plan, BrickSource, Level, ValueRange,
};
use crate::cache::{CacheError, CacheGeometry};
use crate::lod::{
    cull_bricks_into, max_hi_bricks, screen_space_error, slots_needed, BrickGeometry, CullParams,
    LodError, LodView, TfCullTable, ValueCulling,
};
use crate::optics::TransferFunction;
use crate::scene::{RenderMode, RenderSettings};
use glam::Vec3;
use std::cmp::Ordering;

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
        /// Which field (`"bytes_per_texel"`, `"error_threshold"`, `"hysteresis"`).
        field: &'static str,
        /// What is wrong.
        reason: &'static str,
    },
}

/// The culling criteria of `settings`: iso-surface mode culls by the iso-value; direct volume
/// rendering by the transfer function `tf` seen through `window` (the value window the frame is
/// classified with: [`RenderSettings::value_window`] or the volume's default); MIP and MIDA keep
/// every non-empty brick (a transparent brick can still hold a ray's maximum, so culling it could
/// change the image). The clip planes are those of `settings`.
pub fn cull_params(
    settings: &RenderSettings,
    tf: &TransferFunction,
    window: (f32, f32),
) -> Result<CullParams, LodError> {
    let value = match settings.mode {
        RenderMode::Iso { value, .. } => ValueCulling::IsoValue(value),
        RenderMode::Dvr => ValueCulling::TransferFunction(TfCullTable::new(tf, window)?),
        RenderMode::Mip | RenderMode::Mida { .. } => ValueCulling::None,
    };
    Ok(CullParams {
        value,
        clip: settings.clip_planes,
    })
}

/// Bytes one upload of `level` costs for bricks of `brick_size` voxels: `(n+2)^3` (`Hi`) or
/// `(n/2+1)^3` (`Lo`) texels times `bytes_per_texel` (saturating); 0 for `Absent`.
pub fn upload_bytes(level: Level, brick_size: u32, bytes_per_texel: u32) -> u64 {
    let extent = match level {
        Level::Hi => hi_res_brick_extent(brick_size),
        Level::Lo => low_res_brick_extent(brick_size),
        Level::Absent => return 0,
    };
    u64::from(extent)
        .saturating_pow(3)
        .saturating_mul(u64::from(bytes_per_texel))
}

/// The budgets of one frame.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct PlanBudget {
    /// GPU cache slots (one `Hi` brick or eight `Lo` bricks each).
    pub slots: usize,
    /// Bytes of brick uploads allowed this frame.
    pub upload_bytes_per_frame: u64,
    /// Bytes per texel of the packed bricks (channels x scalar size; must be > 0).
    pub bytes_per_texel: u32,
    /// Optional RAM budget of the streamer: the request list is cut to what fits.
    pub ram_bytes: Option<u64>,
}

impl PlanBudget {
    /// The budget of a cache of geometry `cache`: all its slots.
    pub fn for_cache(
        cache: &CacheGeometry,
        bytes_per_texel: u32,
        upload_bytes_per_frame: u64,
    ) -> Self {
        Self {
            slots: cache.slot_count() as usize,
            upload_bytes_per_frame,
            bytes_per_texel,
            ram_bytes: None,
        }
    }

    /// Slots of the largest cache image [`CacheGeometry::choose`] fits into `cache_bytes` for
    /// bricks of `brick_size` voxels, `bytes_per_texel` bytes per texel and an image side of at
    /// most `max_dim_3d`.
    pub fn slots_in_bytes(
        brick_size: u32,
        bytes_per_texel: u32,
        cache_bytes: u64,
        max_dim_3d: u32,
    ) -> Result<usize, PlanError> {
        let cache = CacheGeometry::choose(
            brick_size,
            bytes_per_texel,
            cache_bytes,
            max_dim_3d,
            u32::MAX,
        )?;
        Ok(cache.slot_count() as usize)
    }

    /// Bytes per texel of the bricks `source` delivers (channels x scalar size).
    pub fn bytes_per_texel_of(source: &dyn BrickSource) -> u32 {
        source.channels() * source.scalar().size_bytes() as u32
    }
}

/// Tuning of the planner.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PlanOptions {
    /// Screen-space error (pixels x value range, [`screen_space_error`]) below which a brick is
    /// not refined; 0 refines whatever the slot budget allows. Finite, >= 0.
    pub error_threshold: f32,
    /// Relative hysteresis margin `m` (finite, >= 0): see the module documentation.
    pub hysteresis: f32,
}

impl Default for PlanOptions {
    /// Budget-driven (threshold 0) with a 10 % hysteresis margin.
    fn default() -> Self {
        Self {
            error_threshold: 0.0,
            hysteresis: 0.1,
        }
    }
}

/// What one frame is planned from.
#[derive(Copy, Clone, Debug)]
pub struct FrameInput<'a> {
    /// The brick grid in world space.
    pub geometry: &'a BrickGeometry,
    /// The camera and viewport.
    pub view: &'a LodView,
    /// Per-brick value ranges (one per brick, linear index).
    pub ranges: &'a [ValueRange],
    /// Culling criteria ([`cull_params`]).
    pub cull: &'a CullParams,
    /// The frame's budgets.
    pub budget: PlanBudget,
}

/// The counts of one frame's plan.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct PlanReport {
    /// Bricks in the grid.
    pub bricks: usize,
    /// Bricks culled (transfer function, iso-value, clip planes).
    pub culled: usize,
    /// Active bricks dropped because even all-low-res did not fit the slot budget.
    pub dropped: usize,
    /// Bricks wanted `Hi`.
    pub wanted_hi: usize,
    /// Bricks wanted `Lo`.
    pub wanted_lo: usize,
    /// Bricks drawn `Hi`.
    pub drawn_hi: usize,
    /// Bricks drawn `Lo`.
    pub drawn_lo: usize,
    /// Wanted (not culled, not dropped) bricks drawn `Absent` this frame: not loaded yet, or
    /// their upload did not fit this frame.
    pub drawn_absent: usize,
    /// Bricks whose wanted level is not loaded by the source (drawn at a fallback, or absent).
    pub waiting_for_source: usize,
    /// Bricks whose drawn level differs from their target and follows in a later frame.
    pub deferred: usize,
    /// Slots the drawn levels need.
    pub slots_used: usize,
    /// The slot budget.
    pub slot_budget: usize,
    /// Bytes the staged uploads cost.
    pub upload_bytes: u64,
    /// The upload budget.
    pub upload_budget: u64,
    /// Bytes of the levels requested from the source (after the RAM cut).
    pub request_bytes: u64,
    /// Requests left out by the RAM budget.
    pub requests_cut: usize,
    /// Largest screen-space error of a brick drawn `Lo` (0 when none is; `Hi` bricks have none).
    pub max_drawn_error: f32,
}

impl PlanReport {
    /// True when this frame uploads nothing and nothing is deferred: the plan has converged for
    /// what the source has loaded.
    pub fn is_settled(&self) -> bool {
        self.upload_bytes == 0 && self.deferred == 0
    }
}

/// One frame's plan.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FramePlan {
    /// The level to draw every brick at now (what the cache update gets).
    pub draw: Vec<Level>,
    /// The level the view wants for every brick (culled and dropped bricks `Absent`).
    pub wanted: Vec<Level>,
    /// The uploads staged this frame: `(brick, level)` for every brick whose drawn level changed
    /// to a resident level, in staging order.
    pub uploads: Vec<(u32, Level)>,
    /// Requests for the source, `(brick, level, priority)` in priority order (priorities are
    /// ranks, `len - position`, as [`request_plan`] returns them).
    pub requests: Vec<(u32, Level, f32)>,
    /// The counts.
    pub report: PlanReport,
}

/// The per-frame residency planner; keeps the previous frame's plan (for hysteresis and for
/// staging) and its buffers between frames.
#[derive(Clone, Debug, Default)]
pub struct ResidencyPlanner {
    options: PlanOptions,
    plan: FramePlan,
    active: Vec<bool>,
    error: Vec<f32>,
    distance: Vec<f32>,
    target: Vec<Level>,
    order: Vec<u32>,
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
        self.plan_frame(frame, |brick, level| source.is_loaded(brick, level))
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
        cull_bricks_into(geometry, frame.ranges, frame.cull, &mut self.active)?;
        if self.plan.draw.len() != count || self.plan.wanted.len() != count {
            self.plan.draw = vec![Level::Absent; count];
            self.plan.wanted = vec![Level::Absent; count];
        }
        let mut report = PlanReport {
            bricks: count,
            slot_budget: budget.slots,
            upload_budget: budget.upload_bytes_per_frame,
            ..PlanReport::default()
        };

        // Errors and distances of the active bricks.
        let eye = frame.view.eye();
        self.error.clear();
        self.error.resize(count, f32::NEG_INFINITY);
        self.distance.clear();
        self.distance.resize(count, f32::INFINITY);
        self.order.clear();
        {
            let (active, error, distance, order) = (
                &self.active,
                &mut self.error,
                &mut self.distance,
                &mut self.order,
            );
            geometry.for_each_brick_box(|i, min, max| {
                if active[i] {
                    error[i] = screen_space_error(geometry, frame.view, min, max, frame.ranges[i]);
                    distance[i] = box_distance(eye, min, max);
                    order.push(i as u32);
                }
            });
        }
        let active_count = self.order.len();
        report.culled = count - active_count;

        // Dropping: keep the 8 x slots most important active bricks.
        let capacity = budget
            .slots
            .saturating_mul(crate::bricks::SUB_SLOTS_PER_SLOT as usize);
        let (error, distance) = (&self.error, &self.distance);
        let importance = |a: &u32, b: &u32| more_important(error, distance, *a, *b);
        if active_count > capacity {
            if capacity > 0 {
                self.order.select_nth_unstable_by(capacity, importance);
            }
            for &i in &self.order[capacity..] {
                self.active[i as usize] = false;
            }
            report.dropped = active_count - capacity;
            self.order.truncate(capacity);
        }
        let kept = self.order.len();

        // Wanted levels.
        let prev_wanted = &self.plan.wanted;
        let boost = 1.0 + hysteresis;
        let refine_above = error_threshold * boost;
        let keep_above = error_threshold / boost;
        let mut ranked: Vec<(f32, bool, u32)> = Vec::with_capacity(kept);
        for &i in &self.order {
            let e = error[i as usize];
            let was_hi = prev_wanted[i as usize] == Level::Hi;
            let candidate = error_threshold == 0.0
                || e > refine_above
                || (was_hi && e > keep_above)
                || e.is_nan();
            if candidate {
                let key = if was_hi { e * boost } else { e };
                ranked.push((key, was_hi, i));
            }
        }
        let hi = max_hi_bricks(kept, ranked.len(), budget.slots).unwrap_or(0);
        let rank = |a: &(f32, bool, u32), b: &(f32, bool, u32)| {
            b.0.total_cmp(&a.0)
                .then(b.1.cmp(&a.1))
                .then_with(|| more_important(error, distance, a.2, b.2))
        };
        if hi > 0 && hi < ranked.len() {
            ranked.select_nth_unstable_by(hi - 1, rank);
        }
        let mut wanted = vec![Level::Absent; count];
        for &i in &self.order {
            wanted[i as usize] = Level::Lo;
        }
        for &(_, _, i) in &ranked[..hi.min(ranked.len())] {
            wanted[i as usize] = Level::Hi;
        }
        report.wanted_hi = hi.min(ranked.len());
        report.wanted_lo = kept - report.wanted_hi;

        // Targets: the best loaded level at or below the wanted one.
        self.target.clear();
        self.target.extend(wanted.iter().enumerate().map(|(i, &w)| {
            let b = i as u32;
            match w {
                Level::Hi if is_loaded(b, Level::Hi) => Level::Hi,
                Level::Hi | Level::Lo if is_loaded(b, Level::Lo) => Level::Lo,
                _ => Level::Absent,
            }
        }));
        report.waiting_for_source = wanted
            .iter()
            .zip(&self.target)
            .filter(|(w, t)| w != t)
            .count();

        // Staging.
        let n = geometry.grid().brick_size();
        let mut draw = std::mem::take(&mut self.plan.draw);
        let target = &self.target;
        for (d, &t) in draw.iter_mut().zip(target) {
            if t == Level::Absent {
                *d = Level::Absent;
            }
        }
        let mut stage = Stage {
            hi: draw.iter().filter(|&&l| l == Level::Hi).count(),
            lo: draw.iter().filter(|&&l| l == Level::Lo).count(),
            slots: 0,
            bytes_left: budget.upload_bytes_per_frame,
            cost_hi: upload_bytes(Level::Hi, n, budget.bytes_per_texel),
            cost_lo: upload_bytes(Level::Lo, n, budget.bytes_per_texel),
        };
        stage.slots = slots_needed(stage.hi, stage.lo);
        let mut coarsen: Vec<u32> = Vec::new();
        let mut holes: Vec<u32> = Vec::new();
        let mut refine: Vec<u32> = Vec::new();
        for (i, (&d, &t)) in draw.iter().zip(target).enumerate() {
            match (d, t) {
                (Level::Hi, Level::Lo) => coarsen.push(i as u32),
                (Level::Absent, Level::Hi | Level::Lo) => holes.push(i as u32),
                (Level::Lo, Level::Hi) => refine.push(i as u32),
                _ => {}
            }
        }
        coarsen.sort_unstable_by(|a, b| importance(b, a));
        holes.sort_unstable_by(importance);
        refine.sort_unstable_by(importance);
        let mut uploads = Vec::new();
        let mut next_coarsen = 0;
        let mut apply = |stage: &mut Stage, draw: &mut [Level], i: u32, to: Level| {
            let (dh, dl) = stage.change(draw[i as usize], to);
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
        if stage.slots > budget.slots {
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

        // Requests: the wanted levels, then what is drawn but not wanted.
        let mut requests = request_plan(&wanted, error);
        let extra = draw
            .iter()
            .zip(&wanted)
            .enumerate()
            .filter(|(_, (&d, &w))| d == Level::Hi && w != Level::Hi)
            .map(|(i, (&d, _))| (i as u32, d, 0.0));
        requests.extend(extra);
        let mut request_bytes = 0u64;
        if let Some(ram) = budget.ram_bytes {
            let mut fit = requests.len();
            for (pos, &(_, level, _)) in requests.iter().enumerate() {
                let bytes = upload_bytes(level, n, budget.bytes_per_texel);
                if request_bytes.saturating_add(bytes) > ram {
                    fit = pos;
                    break;
                }
                request_bytes += bytes;
            }
            report.requests_cut = requests.len() - fit;
            requests.truncate(fit);
        } else {
            request_bytes = requests
                .iter()
                .map(|&(_, level, _)| upload_bytes(level, n, budget.bytes_per_texel))
                .fold(0u64, u64::saturating_add);
        }
        let total = requests.len();
        for (pos, r) in requests.iter_mut().enumerate() {
            r.2 = (total - pos) as f32;
        }
        report.request_bytes = request_bytes;

        // Report.
        for (i, (&d, &t)) in draw.iter().zip(target).enumerate() {
            match d {
                Level::Hi => report.drawn_hi += 1,
                Level::Lo => {
                    report.drawn_lo += 1;
                    report.max_drawn_error = report.max_drawn_error.max(error[i]);
                }
                Level::Absent if wanted[i].is_resident() => report.drawn_absent += 1,
                Level::Absent => {}
            }
            if d != t {
                report.deferred += 1;
            }
        }
        report.slots_used = slots_needed(report.drawn_hi, report.drawn_lo);
        report.upload_bytes = budget.upload_bytes_per_frame - stage.bytes_left;
        self.plan = FramePlan {
            draw,
            wanted,
            uploads,
            requests,
            report,
        };
        Ok(&self.plan)
    }
}

/// Importance order, most important first: larger error, then smaller distance, then lower index.
fn more_important(error: &[f32], distance: &[f32], a: u32, b: u32) -> Ordering {
    let (a, b) = (a as usize, b as usize);
    error[b]
        .total_cmp(&error[a])
        .then(distance[a].total_cmp(&distance[b]))
        .then(a.cmp(&b))
}

/// Distance from `p` to the nearest point of the box `[min, max]` (0 inside).
fn box_distance(p: Vec3, min: Vec3, max: Vec3) -> f32 {
    (min - p).max(p - max).max(Vec3::ZERO).length()
}
