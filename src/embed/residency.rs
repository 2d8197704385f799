//! Camera-driven residency in the pass: [`VolumePass::update`] runs the
//! [`crate::plan::ResidencyPlanner`] for the frame's camera, viewport and settings, fetches and
//! stages the bricks it chose within the upload budget, and tells the source what to load next.
//!
//! One frame, for a brick-cache source:
//!
//! 1. culling criteria from the settings and the pass's transfer function
//!    ([`crate::plan::cull_params`]; pre-classified RGBA sources cull by clip planes only);
//! 2. the plan ([`crate::plan::ResidencyPlanner::plan_frame_with_source`]) under the budgets:
//!    the cache's slots, [`ResidencyConfig::upload_bytes_per_frame`] and
//!    [`ResidencyConfig::ram_bytes`];
//! 3. the drawn levels are fetched from the source and staged (as [`VolumePass::set_levels`]
//!    does); a level whose bytes the source dropped since the plan falls back (counted in
//!    [`FrameReport::fell_back`]) and the planner is told what is drawn instead;
//! 4. the planner's requests go to the source ([`crate::bricks::BrickSource::request_levels`]),
//!    after the fetch, so a streamer keeps the drawn levels pinned until then.
//!
//! The next [`VolumePass::record`] records the staged uploads and the fixup with the frame.
//! `update` records nothing and waits for nothing: it is CPU work plus the source's
//! non-blocking calls.

use super::level_source::LevelState;
use super::source::{ResidencyReport, Source};
use super::VolumePass;
use crate::bricks::Level;
use crate::cache::block_origin;
use crate::error::{Error, Result};
use crate::levels::LevelUpdateReport;
use crate::lod::{cull_bricks, CullParams, LodView, ValueCulling};
use crate::plan::{
    admit_by_budget, cull_params, level_margin, next_target, step_towards, FrameInput, FramePlan,
    LevelRequest, PlanBudget, PlanOptions, PlanReport, ResidencyPlanner,
};
use crate::scene::{Camera, RenderSettings};
use crate::volume::ScalarType;
use glam::Vec3;
use std::collections::HashSet;
use std::time::Instant;

/// Budgets and tuning of camera-driven residency ([`VolumePass::set_residency_config`]). The
/// GPU cache budget is the brick cache's own ([`super::MixedConfig::cache_budget_bytes`]).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ResidencyConfig {
    /// Bytes of brick level changes uploaded per frame at most. Two-level sources: the
    /// planner's budget (the cache's compaction moves and border restores come on top, see
    /// [`crate::plan`]); it should hold one hi-res and two low-res bricks, or a still camera may
    /// not converge. Level sources ([`VolumePass::update`]): a hard cap on every
    /// stored brick a step uploads, moves and re-fixed neighbours included; at least
    /// [`MIN_STEP_BRICKS`] level-0 stored bricks.
    pub upload_bytes_per_frame: u64,
    /// RAM budget of a streaming source: the request list is cut to what fits (`None`: all);
    /// for a level source, the longest prefix of its request (next steps, drawn bricks, the
    /// rest of the wanted plan) whose stored bricks fit.
    pub ram_bytes: Option<u64>,
    /// Planner tuning (error threshold, hysteresis).
    pub options: PlanOptions,
    /// Level sources ([`VolumePass::update`]): weigh each brick's on-screen voxel
    /// size by its value-range width as a fraction of the volume's (the two-level planner's
    /// screen-space error, which it always uses): a brick of narrow range is drawn
    /// `log2(1 / width)` levels coarser for the same target, one of a single value only as
    /// fine as the rule forces. Off: the voxel size alone.
    pub weigh_by_value: bool,
}

impl Default for ResidencyConfig {
    /// 64 MiB of uploads per frame, no RAM cut, the planner's default options, level sources
    /// by voxel size alone.
    fn default() -> Self {
        Self {
            upload_bytes_per_frame: 64 << 20,
            ram_bytes: None,
            options: PlanOptions::default(),
            weigh_by_value: false,
        }
    }
}

/// Bricks at one level in one frame ([`FrameReport::per_level`]).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct LevelCounts {
    /// Bricks the view wants at this level.
    pub wanted: usize,
    /// Bricks drawn at this level.
    pub drawn: usize,
}

/// The target of a level source's choice when [`PlanOptions::error_threshold`] is 0 (refine
/// whatever the slots allow): a drawn voxel of 1/64 pixel, below which no voxel in view is
/// refined, so that the slot budget decides.
pub const BUDGET_DRIVEN_TARGET_PIXELS: f32 = 1.0 / 64.0;

/// What one [`VolumePass::update`] planned and staged: the per-frame residency report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameReport {
    /// The planner's counts: culled and dropped bricks, wanted and drawn per level, bricks
    /// waiting for the source, deferred changes, slots against the slot budget, upload bytes
    /// against the upload budget, request bytes (after the RAM cut) and the worst screen-space
    /// error of a brick drawn low-res.
    pub plan: PlanReport,
    /// What was fetched and staged: bricks and bytes (compaction moves and border restores
    /// included), resident hi/lo after the change, bricks the fixup rewrites, pack time.
    pub residency: ResidencyReport,
    /// Bricks drawn below the plan because their bytes left the source between planning and
    /// fetching (the planner draws them from their fallback next frame).
    pub fell_back: usize,
    /// Bricks whose wanted level failed to load in the source (drawn at a fallback level, or
    /// absent when none is loaded). A level source: the stored bricks whose read failed since
    /// it was attached, on the render thread or in a streamer's background (each kept out of
    /// every step, its region drawn at a coarser level or not at all). A host that must not
    /// show a fallback (a batch render) treats a non-zero count as an error.
    pub source_errors: usize,
    /// The first of those errors, for the host's log.
    pub first_source_error: Option<String>,
    /// Bytes of the GPU cache image.
    pub cache_bytes: u64,
    /// Per level from the finest, for every brick-cache source (two-level sources: 0 the
    /// hi-res level, 1 the low-res one): the bricks the view wants at that level and the bricks
    /// drawn there after this update.
    pub per_level: Vec<LevelCounts>,
    /// Bricks whose drawn level is not the one the view wants (not loaded yet, or waiting for
    /// the upload budget of a later frame); culled and dropped bricks are not counted.
    pub waiting: usize,
    /// CPU time of the plan (culling, level choice, staging decisions), in milliseconds.
    pub plan_ms: f64,
    /// CPU time of the whole update (plan, fetch, staging, requests), in milliseconds.
    pub update_ms: f64,
}

impl VolumePass {
    /// Sets the budgets and tuning of [`VolumePass::update`] (kept across sources; the planner
    /// of the current source restarts with the new options and plans from what is drawn).
    pub fn set_residency_config(&mut self, config: ResidencyConfig) {
        self.residency = config;
        if let Source::Mixed(state) = &mut self.source {
            state.planner = ResidencyPlanner::new(config.options);
            // Keep what is resident: the next frame plans from the cache's levels.
            state.planner.set_drawn(&state.cache.levels());
        }
    }

    /// The budgets and tuning of [`VolumePass::update`].
    pub fn residency_config(&self) -> ResidencyConfig {
        self.residency
    }

    /// The last frame's plan of the brick-cache source (`None` for other sources; empty before
    /// the first [`VolumePass::update`]).
    pub fn last_plan(&self) -> Option<&FramePlan> {
        match &self.source {
            Source::Mixed(state) => Some(state.planner.last_plan()),
            _ => None,
        }
    }

    /// Plans residency for a frame of `camera` at `width` x `height` pixels with `settings`:
    /// culling criteria from the settings and the pass's transfer function, the plan
    /// ([`crate::plan::ResidencyPlanner`]) under the cache's slots and the budgets of
    /// [`ResidencyConfig`], the drawn levels fetched and staged for the next
    /// [`VolumePass::record`] (a level the source dropped meanwhile falls back), and the
    /// planner's requests given to the source ([`crate::bricks::BrickSource::request_levels`]). Call it once per frame before
    /// `record`, with the same camera, size and settings (in world space: the pass maps them into
    /// the volume frame by its [`VolumePass::model_transform`]). Needs a brick-cache source. Records
    /// nothing and needs no wait (the staged bytes go to the frame slot `record` is given).
    ///
    /// A level source ([`VolumeSource::Levels`], [`VolumeSource::LevelStore`],
    /// [`VolumeSource::LevelStream`]) is planned by levels chosen from the camera for the
    /// target [`PlanOptions::error_threshold`] (0, the default: [`BUDGET_DRIVEN_TARGET_PIXELS`],
    /// the slots decide, as for two levels) and reported alike: [`FrameReport::per_level`],
    /// [`FrameReport::waiting`], the plan's culled and dropped bricks, slots and upload bytes
    /// against their budgets (its `wanted_hi` ... `drawn_lo` stay 0), the choice's largest voxel
    /// on screen in pixels as the worst screen-space error ([`PlanReport::max_drawn_error`];
    /// weighted by value range with [`ResidencyConfig::weigh_by_value`]), the step's uploads,
    /// and the stored bricks whose read failed since the source was attached as source errors. Each update takes one step towards the choice
    /// ([`VolumePass::last_level_choice`]): at most one level finer per brick, within the upload
    /// budget as a hard cap (re-fixed neighbours and moved bricks counted; a budget below
    /// [`MIN_STEP_BRICKS`] level-0 stored bricks is an error), a streamed store only onto
    /// stored bricks its reader holds in RAM (never reading the disk on this thread but for a
    /// drawn brick evicted under a tight RAM budget); a failed read keeps its region at the
    /// level it draws and is counted, and a cache too small for the coarsest plan draws the
    /// most important bricks only ([`PlanReport::dropped`]).
    ///
    /// [`VolumeSource::Levels`]: super::VolumeSource::Levels
    /// [`VolumeSource::LevelStore`]: super::VolumeSource::LevelStore
    /// [`VolumeSource::LevelStream`]: super::VolumeSource::LevelStream
    pub fn update(
        &mut self,
        camera: &Camera,
        width: u32,
        height: u32,
        settings: &RenderSettings,
    ) -> Result<FrameReport> {
        let start = Instant::now();
        let (world_camera, world_settings) = (camera, settings);
        // The planner works in the volume frame, as the ray-caster does.
        let model = self.model_transform();
        let camera = &model.volume_camera(camera);
        let settings = &model.volume_settings(settings);
        // Validates camera, size and settings as the frame will.
        self.volume_params(camera, settings, width, height)?;
        let config = self.residency;
        if let Source::Levels(_) = &self.source {
            return self.update_levels(world_camera, width, height, world_settings, start);
        }
        let tf = self.tables.transfer_function();
        let Source::Mixed(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "update needs a brick-cache source (set_source with Mixed, Bricks, RgbaMixed, \
                 Levels, LevelStore or LevelStream)"
                    .into(),
            ));
        };
        let cull = if state.rgba_model.is_some() {
            // Pre-classified bricks: the transfer function does not apply.
            CullParams {
                value: ValueCulling::None,
                clip: settings.clip_planes,
            }
        } else {
            let is_float = state.source.scalar() == ScalarType::F32;
            let window = settings.classification_window(is_float, state.value_range);
            cull_params(settings, tf, window)?
        };
        let view = LodView::new(camera, width, height)?;
        let budget = PlanBudget {
            slots: state.cache.geometry().slot_count() as usize,
            upload_bytes_per_frame: config.upload_bytes_per_frame,
            bytes_per_texel: PlanBudget::bytes_per_texel_of(&*state.source),
            ram_bytes: config.ram_bytes,
        };
        let plan_start = Instant::now();
        // A streaming source's ranges tighten as its voxels arrive: bricks found empty are
        // culled (see cull_ranges.rs).
        let (ranges, ranges_generation) =
            state
                .cull_ranges
                .ranges(&*state.source, &state.geometry, &cull)?;
        let frame = FrameInput {
            geometry: &state.geometry,
            view: &view,
            ranges,
            ranges_generation: Some(ranges_generation),
            cull: &cull,
            budget,
        };
        state
            .planner
            .plan_frame_with_source(&frame, &*state.source)?;
        let plan = state.planner.last_plan();
        let plan_ms = plan_start.elapsed().as_secs_f64() * 1e3;
        let report = plan.report;
        let draw = plan.draw.clone();
        let requests = plan.requests.clone();
        let (mut source_errors, mut first_source_error) = (0, None);
        // What the source said it had loaded when it was planned for (one query, not one per
        // brick).
        let loaded = state.planner.source_loaded();
        for (brick, (&wanted, &drawn)) in plan.wanted.iter().zip(&plan.draw).enumerate() {
            // A loaded level has no error to report (and fetching it would pack a deferred brick
            // of an in-memory source for nothing): only a level the source lacks is asked about.
            if wanted == drawn
                || wanted == Level::Absent
                || loaded.get(brick).is_some_and(|l| l.contains(wanted))
            {
                continue;
            }
            if let Err(e) = state.source.brick_bytes(brick as u32, wanted) {
                source_errors += 1;
                first_source_error.get_or_insert_with(|| e.to_string());
            }
        }
        let (residency, levels) = state.stage_levels(&draw)?;
        let fell_back = levels.iter().zip(&draw).filter(|(a, b)| a != b).count();
        let mut per_level = vec![LevelCounts::default(); 2];
        let mut waiting = 0;
        // The plan's wanted levels, read again after staging (staging does not touch the
        // planner) rather than copied per frame.
        let wanted_levels = &state.planner.last_plan().wanted;
        for (&wanted, &drawn) in wanted_levels.iter().zip(&levels) {
            if let Some(l) = wanted.number() {
                let l = l as usize;
                per_level[l].wanted += 1;
                waiting += usize::from(wanted != drawn);
            }
            if let Some(l) = drawn.number() {
                let l = l as usize;
                per_level[l].drawn += 1;
            }
        }
        if fell_back > 0 {
            state.planner.set_drawn(&levels);
        }
        state
            .source
            .request_levels(&requests)
            .map_err(Error::Source)?;
        let extent = state.cache.geometry().extent();
        let cache_bytes = u64::from(extent.x)
            * u64::from(extent.y)
            * u64::from(extent.z)
            * u64::from(budget.bytes_per_texel);
        Ok(FrameReport {
            plan: report,
            residency,
            fell_back,
            source_errors,
            first_source_error,
            cache_bytes,
            per_level,
            waiting,
            plan_ms,
            update_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }
}

impl VolumePass {
    /// [`VolumePass::update`] of a level source ([`VolumeSource::Levels`],
    /// [`VolumeSource::LevelStore`], [`VolumeSource::LevelStream`]): chooses the level of
    /// every brick for a frame of `camera` (world space) with `settings` at `width` x `height`
    /// pixels, with drawn voxels at most [`PlanOptions::error_threshold`] pixels on screen
    /// ([`BUDGET_DRIVEN_TARGET_PIXELS`] for 0) where the cache allows (each voxel's size
    /// weighted by its brick's value range with [`ResidencyConfig::weigh_by_value`])
    /// ([`crate::plan::LevelChooser`], with hysteresis against the last choice), and stages a
    /// step towards it (the next [`VolumePass::record`] uploads what changed): the step refines
    /// at most one level per brick and uploads at most
    /// [`ResidencyConfig::upload_bytes_per_frame`] bytes, counting every stored brick it
    /// uploads (new ones, kept ones whose coarser neighbours changed, ones moved to make room);
    /// a step that does not fit waits ([`crate::plan::next_target`],
    /// [`crate::plan::admit_by_budget`], [`crate::plan::step_towards`]). The choice
    /// ([`VolumePass::last_level_choice`]) counts the bricks still waiting, and the next update
    /// goes on. Bricks the pass's transfer function (or iso-value, or clip planes) leaves
    /// empty are culled by their conservative ranges (`crate::levels::conservative_ranges`):
    /// not drawn, taking no slot, unless a drawn block covers them. A streamed store
    /// ([`VolumeSource::LevelStream`]) steps only onto stored bricks its streamer holds in RAM
    /// (it waits, drawing what it has, while they are read) and then requests the next step's
    /// bricks, the drawn ones and the rest of the wanted plan, in that order, cut to
    /// [`ResidencyConfig::ram_bytes`]: the call never reads the disk, except for a drawn brick
    /// whose coarser neighbour changed and that the streamer evicted under a tight RAM budget.
    /// Errors: a bad view, settings or target, an upload budget below [`MIN_STEP_BRICKS`]
    /// level-0 stored bricks. A cache too small for the coarsest plan is no error: the least
    /// important bricks are not drawn ([`crate::plan::LevelChoice::dropped`]).
    ///
    /// [`VolumeSource::Levels`]: super::VolumeSource::Levels
    /// [`VolumeSource::LevelStore`]: super::VolumeSource::LevelStore
    /// [`VolumeSource::LevelStream`]: super::VolumeSource::LevelStream
    fn update_levels(
        &mut self,
        camera: &Camera,
        width: u32,
        height: u32,
        settings: &RenderSettings,
        start: Instant,
    ) -> Result<FrameReport> {
        let threshold = self.residency.options.error_threshold;
        let target = if threshold > 0.0 {
            threshold
        } else {
            BUDGET_DRIVEN_TARGET_PIXELS
        };
        let step = self.step_levels(camera, settings, width, height, target)?;
        let Source::Levels(state) = &self.source else {
            return Err(Error::InvalidInput("the level source went away".into()));
        };
        let Some(choice) = &state.last_choice else {
            return Err(Error::InvalidInput("the level step chose nothing".into()));
        };
        let mut per_level = vec![LevelCounts::default(); state.level_count() as usize];
        for (&wanted, &drawn) in choice.levels.iter().zip(&state.current) {
            if let Some(l) = wanted {
                per_level[l as usize].wanted += 1;
            }
            if let Some(l) = drawn {
                per_level[l as usize].drawn += 1;
            }
        }
        let staged = step.staged.unwrap_or_default();
        let count = choice.levels.len();
        let plan = PlanReport {
            bricks: count,
            culled: step.culled,
            dropped: choice.dropped,
            deferred: choice.waiting,
            slots_used: usize::try_from(choice.slots).unwrap_or(usize::MAX),
            slot_budget: usize::try_from(state.slot_count()).unwrap_or(usize::MAX),
            upload_bytes: staged.uploaded_bytes as u64,
            upload_budget: self.residency.upload_bytes_per_frame,
            max_drawn_error: choice.pixels_per_voxel,
            ..PlanReport::default()
        };
        let residency = ResidencyReport {
            uploaded_bricks: staged.uploaded_bricks,
            uploaded_bytes: staged.uploaded_bytes,
            fixup_bricks: staged.uploaded_bricks,
            pack_ms: staged.stage_ms,
            update_ms: staged.stage_ms,
            ..ResidencyReport::default()
        };
        Ok(FrameReport {
            plan,
            residency,
            fell_back: 0,
            source_errors: state.failed_read_count(),
            first_source_error: state.first_failed_read(),
            cache_bytes: state.cache_bytes(),
            per_level,
            waiting: choice.waiting,
            plan_ms: step.plan_ms,
            update_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// One step of [`VolumePass::update`] for a level source towards `target_pixels` (its
    /// choice kept as the source's last), with what the step staged.
    fn step_levels(
        &mut self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
        target_pixels: f32,
    ) -> Result<LevelStep> {
        let model = self.model_transform();
        let camera = model.volume_camera(camera);
        let settings = model.volume_settings(settings);
        // Validates camera, size and settings as the frame will.
        self.volume_params(&camera, &settings, width, height)?;
        let tf = self.tables.transfer_function();
        let Source::Levels(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "a level step needs a level source (VolumeSource::Levels, LevelStore or \
                 LevelStream)"
                    .into(),
            ));
        };
        let budget = self.residency.upload_bytes_per_frame;
        let bricks = state.bricks.grid().brick_count();
        let step_bricks = MIN_STEP_BRICKS.min(bricks as u64);
        let least = largest_step_bytes(state.stored_bytes(0), bricks);
        if budget < least {
            return Err(Error::InvalidInput(format!(
                "upload budget of {budget} bytes per frame is below the largest single step, \
                 {least} bytes ({step_bricks} level-0 stored bricks of {} bytes: a brick and \
                 the neighbours it makes stale); a smaller budget could stop the cache short of \
                 the camera's levels: raise upload_bytes_per_frame",
                state.stored_bytes(0)
            )));
        }
        let window = settings.classification_window(state.is_float, state.value_range);
        let cull = cull_params(&settings, tf, window)?;
        let plan_start = Instant::now();
        let active = cull_bricks(&state.bricks, &state.cull_ranges, &cull)?;
        let culled = active.iter().filter(|a| !**a).count();
        let view = LodView::new(&camera, width, height)?;
        // Hysteresis against the last choice, so that a hovering camera does not churn.
        let (levels, slots) = (state.level_count(), state.slot_count());
        let mut choice = state
            .chooser
            .choose(&LevelRequest {
                geometry: &state.bricks,
                view: &view,
                active: &active,
                value_ranges: if self.residency.weigh_by_value {
                    &state.error_ranges
                } else {
                    &[]
                },
                levels,
                slots,
                target_pixels,
                previous: state.last_choice.as_ref().map_or(&[], |c| &c.levels),
                margin: level_margin(self.residency.options.hysteresis),
            })?
            .clone();
        // A stored brick whose read fails is kept out and the step planned again without it
        // (its region keeps the level it draws), at most a few times a call.
        let mut drawn = budgeted_step(state, &view, &choice.levels, budget);
        let plan_ms = plan_start.elapsed().as_secs_f64() * 1e3;
        let mut staged = None;
        for _ in 0..MAX_FAILED_READS_PER_CALL {
            if drawn == state.current {
                break;
            }
            match state.stage(&drawn) {
                Ok(report) => {
                    staged = Some(report);
                    break;
                }
                Err(e) => {
                    let Some(key) = state.last_failed_read.take() else {
                        return Err(e);
                    };
                    log::warn!("level {}, stored brick of brick {}: {e}", key.0, key.1);
                    state.first_failure.get_or_insert_with(|| e.to_string());
                    state.failed.insert(key);
                    choice.failed_reads += 1;
                    drawn = budgeted_step(state, &view, &choice.levels, budget);
                }
            }
        }
        // What the cache draws now: the last step when it staged; when every retry failed, the
        // levels drawn before (the next call goes on).
        let drawn = state.current.clone();
        choice.waiting = drawn
            .iter()
            .zip(&choice.levels)
            .filter(|(d, w)| d != w)
            .count();
        if let Some(streamer) = state.streamer() {
            let mut keys = stream_request(state, &view, &choice.levels);
            if let Some(ram) = self.residency.ram_bytes {
                cut_to_ram(&mut keys, ram, &|level| state.stored_bytes(level));
            }
            streamer.request(&keys);
        }
        state.last_choice = Some(choice);
        Ok(LevelStep {
            staged,
            culled,
            plan_ms,
        })
    }
}

/// What one step of a level source staged ([`VolumePass::update`]; its choice is the
/// source's last).
struct LevelStep {
    /// What the step staged (`None`: nothing changed).
    staged: Option<LevelUpdateReport>,
    /// Bricks culled.
    culled: usize,
    /// CPU time of culling, the choice and the step's planning, in milliseconds.
    plan_ms: f64,
}

/// The stored bricks of the largest single step of a level source, in level-0 stored bricks: a
/// brick refined to level 0 (or coarsened from it) and its 26 level-0 neighbours, whose
/// fixed-up borders go stale and are uploaded again (a grid of fewer bricks: all of them). An upload budget of this many level-0
/// stored bricks always lets some step move ([`VolumePass::update`] refuses less).
pub const MIN_STEP_BRICKS: u64 = 27;

/// The bytes of the largest single step of a level source of `bricks` bricks whose level-0
/// stored brick takes `level0_bytes` (as the cache copies it): [`MIN_STEP_BRICKS`] of them, or
/// every brick of a smaller grid. [`VolumePass::update`] refuses an upload budget below it.
pub fn largest_step_bytes(level0_bytes: u64, bricks: usize) -> u64 {
    MIN_STEP_BRICKS.min(bricks as u64) * level0_bytes
}

/// Failed stored-brick reads [`VolumePass::update`] plans around within one call
/// (each read once); past them the call keeps the drawn levels and goes on at the next.
const MAX_FAILED_READS_PER_CALL: usize = 8;

/// [`admit_by_budget`] for a move from `current` towards `towards`.
fn admit_towards(
    state: &LevelState,
    current: &[Option<u32>],
    distance: &[f32],
    towards: &[Option<u32>],
    skip: &dyn Fn(usize, u32) -> bool,
    budget: u64,
) -> Vec<(usize, u32)> {
    admit_by_budget(
        state.bricks.grid().bricks_per_axis(),
        state.brick_size,
        state.scalar.size_bytes() as u64,
        current,
        towards,
        distance,
        skip,
        budget,
    )
}

/// Distance from the eye to every brick's box (0 inside), by linear brick index.
fn brick_distances(state: &LevelState, view: &LodView) -> Vec<f32> {
    let grid = state.bricks.grid();
    grid.bricks()
        .map(|b| {
            let (min, max) = state.bricks.brick_box(b);
            (min - view.eye())
                .max(view.eye() - max)
                .max(Vec3::ZERO)
                .length()
        })
        .collect()
}

/// Cuts the request `keys` (stored bricks `(level, first brick)`, highest priority first) to
/// its longest prefix whose distinct stored bricks take at most `ram` bytes (`bytes(level)` a
/// stored brick of `level`): [`ResidencyConfig::ram_bytes`] for a level source.
fn cut_to_ram(keys: &mut Vec<(u32, usize)>, ram: u64, bytes: &dyn Fn(u32) -> u64) {
    let mut seen = HashSet::new();
    let mut total = 0u64;
    let keep = keys
        .iter()
        .position(|&key| {
            if seen.insert(key) {
                total += bytes(key.0);
            }
            total > ram
        })
        .unwrap_or(keys.len());
    keys.truncate(keep);
}

/// The stored bricks a streamed source asks its streamer for, highest priority first: the
/// uploads of the next steps towards `wanted` (each [`next_target`] in turn, each in
/// [`admit_by_budget`]'s order), the stored bricks drawn now (a change of their coarser neighbours uploads them again, from RAM), then
/// the rest of the wanted plan's uploads.
fn stream_request(state: &LevelState, view: &LodView, wanted: &[Option<u32>]) -> Vec<(u32, usize)> {
    let grid = state.bricks.grid();
    let bricks = grid.bricks_per_axis();
    let distance = brick_distances(state, view);
    let resident = |first: usize, level: u32| state.residency.holds(first, level);
    let uploads = |towards: &[Option<u32>]| {
        admit_towards(
            state,
            &state.current,
            &distance,
            towards,
            &resident,
            u64::MAX,
        )
    };
    // The uploads of the next steps, level by level (a streamed source steps on through those
    // in RAM within one call).
    let mut keys: Vec<(u32, usize)> = Vec::new();
    let mut from = state.current.clone();
    for _ in 0..state.level_count() {
        let target = next_target(bricks, state.level_count(), &from, wanted);
        if target == from {
            break;
        }
        keys.extend(
            uploads(&target)
                .into_iter()
                .map(|(first, level)| (level, first)),
        );
        from = target;
    }
    for (i, level) in state.current.iter().enumerate() {
        if let Some(level) = *level {
            let first = grid.linear_index(block_origin(grid.brick_coords(i), level));
            if first == i {
                keys.push((level, first));
            }
        }
    }
    keys.extend(
        uploads(wanted)
            .into_iter()
            .map(|(first, level)| (level, first)),
    );
    keys
}

/// The levels a three-level source draws this step on its way to `wanted`, under a hard cap of
/// `budget` bytes on everything the step uploads ([`LevelState::upload_bytes_for`]: new stored
/// bricks, kept ones whose coarser neighbours change, ones moved to make room):
/// - `wanted` itself when its uploads fit;
/// - else a step towards [`next_target`] (at most one level finer than drawn now): the target's
///   missing stored bricks in [`admit_by_budget`]'s order (coarsenings first, then the largest
///   gaps, nearest first), the longest prefix whose step ([`step_towards`]) fits the budget and
///   the cache's slots; when no prefix does, the first such brick alone that does (a brick
///   with fewer finer neighbours to fix up again costs less);
/// - else the drawn levels: the step waits (a budget below one stored brick and the
///   neighbours it makes stale never moves; `update` refuses a budget below
///   [`MIN_STEP_BRICKS`] level-0 stored bricks).
///
/// A streamed source admits only stored bricks in its streamer's RAM, and a step that moves
/// goes on towards the next levels while their bricks are in RAM and the whole move's uploads
/// still fit the budget.
fn budgeted_step(
    state: &LevelState,
    view: &LodView,
    wanted: &[Option<u32>],
    budget: u64,
) -> Vec<Option<u32>> {
    let grid = state.bricks.grid();
    let bricks = grid.bricks_per_axis();
    // Nothing staged yet counts as nothing drawn.
    let current = if state.current.is_empty() {
        vec![None; grid.brick_count()]
    } else {
        state.current.clone()
    };
    let distance = brick_distances(state, view);
    let resident = |first: usize, level: u32| state.residency.holds(first, level);
    let streamer = state.streamer();
    // A streamed source draws only stored bricks already in RAM; none draws one that failed.
    let in_ram = |first: usize, level: u32| {
        !state.failed.contains(&(level, first))
            && streamer.is_none_or(|s| s.is_ready((level, first)))
    };
    let not_drawable = |first: usize, level: u32| resident(first, level) || !in_ram(first, level);
    let affordable = |plan: &[Option<u32>]| {
        state
            .upload_bytes_for(plan)
            .is_some_and(|bytes| bytes <= budget)
    };
    // The whole way in one step when its uploads fit the budget (and are in RAM).
    let needed = admit_towards(state, &current, &distance, wanted, &resident, u64::MAX);
    if needed.iter().all(|&(f, l)| in_ram(f, l)) && affordable(wanted) {
        return wanted.to_vec();
    }
    let target = next_target(bricks, state.level_count(), &current, wanted);
    let order = admit_towards(state, &current, &distance, &target, &not_drawable, u64::MAX);
    let step_with = |taken: &[(usize, u32)]| {
        let taken: HashSet<(usize, u32)> = taken.iter().copied().collect();
        let ready =
            |first: usize, level: u32| resident(first, level) || taken.contains(&(first, level));
        step_towards(bricks, &current, &target, &ready)
    };
    // The longest affordable prefix (a prefix's bytes grow with its length but for the odd
    // compaction, so a bisection; only an affordable step is ever taken).
    let mut chosen = current.clone();
    let (mut fit, mut over) = (0, order.len() + 1);
    while over - fit > 1 {
        let mid = (fit + over) / 2;
        let step = step_with(&order[..mid]);
        if affordable(&step) {
            (fit, chosen) = (mid, step);
        } else {
            over = mid;
        }
    }
    if fit == 0 {
        // No prefix fits: the first single brick whose step does.
        if let Some(step) = order
            .iter()
            .take(64)
            .map(|&one| step_with(&[one]))
            .find(|step| *step != current && affordable(step))
        {
            chosen = step;
        }
    }
    if streamer.is_some() && chosen != current {
        // A streamed source steps on, a level at a time, while the next level's bricks are in
        // RAM and the uploads of the whole move still fit the budget.
        let ready = |first: usize, level: u32| resident(first, level) || in_ram(first, level);
        for _ in 0..state.level_count() {
            let next_goal = next_target(bricks, state.level_count(), &chosen, wanted);
            let next = step_towards(bricks, &chosen, &next_goal, &ready);
            if next == chosen || !affordable(&next) {
                break;
            }
            chosen = next;
        }
    }
    chosen
}
