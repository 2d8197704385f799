//! The three-level sources of the pass ([`VolumeSource::Levels`](super::VolumeSource::Levels), [`VolumeSource::LevelStore`](super::VolumeSource::LevelStore)):
//! their state on the GPU ([`LevelState`]), attaching one, and moving it to other levels
//! (`set_brick_levels`, and through `update` in `residency.rs`).

use super::source::{MixedConfig, Source};
use super::VolumePass;
use crate::bricks::dequantize;
use crate::cache::block_origin;
use crate::cache::SlotGeometry;
use crate::error::{Error, Result};
use crate::gpu::GpuBrickCache;
use crate::levels::{
    conservative_ranges, new_three_level_cache, stage_three_level, LevelPlanFacts, LevelResidency,
    LevelUpdateReport,
};
use crate::lod::BrickGeometry;
use crate::pyramid::{LevelPlan, VolumeLevels};
use crate::scene::Transition;
use crate::store::{LevelBackend, LevelStore, LevelStreamer};
use crate::volume::{ScalarType, Volume};
use glam::UVec3;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

/// A volume drawn at host-set levels through the three-level cache ([`VolumeSource::Levels`](super::VolumeSource::Levels)).
pub(crate) struct LevelState {
    pub(crate) gpu: GpuBrickCache,
    /// The brick grid, every level's samples and the cache geometry (a new plan is packed from
    /// them).
    grid: crate::bricks::BrickGrid,
    data: LevelData,
    geometry: SlotGeometry,
    /// The brick grid in world space (for [`VolumePass::update`]).
    pub(super) bricks: BrickGeometry,
    /// The level of every brick drawn now.
    pub(super) current: Vec<Option<u32>>,
    pub(super) dims: UVec3,
    pub(super) spacing: glam::Vec3,
    pub(super) value_range: (f32, f32),
    pub(super) is_float: bool,
    /// The cache's texel type (the source's scalar type).
    pub(super) scalar: ScalarType,
    pub(super) brick_size: u32,
    pub(super) transition: Transition,
    pub(super) facts: LevelPlanFacts,
    /// Which stored bricks the cache holds where (residency changes upload only what changed).
    pub(super) residency: LevelResidency,
    /// The last camera choice ([`VolumePass::update`]): the levels it wanted (drawn once
    /// their bricks are uploaded) and its counts.
    pub(super) last_choice: Option<crate::plan::LevelChoice>,
    /// The camera's level chooser, with its buffers (kept between views).
    pub(super) chooser: crate::plan::LevelChooser,
    /// What the last residency change moved.
    pub(super) last_update: Option<LevelUpdateReport>,
    /// Per brick, the range culling tests (`crate::levels::conservative_ranges`).
    pub(super) cull_ranges: Vec<crate::bricks::ValueRange>,
    /// Per brick, the range that weighs its screen-space error
    /// ([`crate::plan::LevelRequest::value_ranges`]): its culling range as a fraction of the
    /// volume's value range, so that the camera's target means the same for any data range.
    pub(super) error_ranges: Vec<crate::bricks::ValueRange>,
    /// Stored bricks `(level, first brick)` whose read failed: kept out of every later step
    /// (their region keeps the level it draws) for as long as the source is attached.
    pub(super) failed: HashSet<(u32, usize)>,
    /// The stored brick whose read made the last [`LevelState::stage`] fail, if one did.
    pub(super) last_failed_read: Option<(u32, usize)>,
    /// The error of the first stored brick whose read failed on the render thread.
    pub(super) first_failure: Option<String>,
}

/// What a three-level source needs to know of its volume besides the stored bricks.
struct LevelSourceFacts {
    grid: crate::bricks::BrickGrid,
    spacing: glam::Vec3,
    value_range: (f32, f32),
    /// The source's scalar type: the cache's texels.
    scalar: ScalarType,
}

/// Where a three-level source's stored bricks come from.
pub(super) enum LevelData {
    /// A volume in RAM ([`VolumeSource::Levels`](super::VolumeSource::Levels)): level 0 cut
    /// from its voxels when packed, the coarser levels' samples held.
    Volume {
        /// The volume and its coarser levels.
        levels: VolumeLevels,
        /// Brick edge of level 0.
        brick_size: u32,
    },
    /// A level store on disk ([`VolumeSource::LevelStore`](super::VolumeSource::LevelStore)).
    Store(Arc<LevelStore>),
    /// A level store read in the background
    /// ([`VolumeSource::LevelStream`](super::VolumeSource::LevelStream)).
    Streamed(Arc<LevelStreamer>),
}

impl LevelData {
    /// Levels there are (0 up to this, exclusive).
    fn level_count(&self) -> u32 {
        match self {
            LevelData::Volume { levels, .. } => levels.level_count(),
            LevelData::Store(store) => store.level_count(),
            LevelData::Streamed(streamer) => streamer.backend().level_count(),
        }
    }

    /// The normalised texels of the stored brick of `level` that holds `brick` (linear index of
    /// its first brick `first`): cut from the volume in RAM, read from the store, or through the
    /// streamer (from RAM, else on this thread).
    fn read_stored(&self, level: u32, first: usize, brick: UVec3) -> Result<Vec<f32>> {
        match self {
            LevelData::Volume { levels, brick_size } => levels
                .stored_brick(level, block_origin(brick, level), *brick_size)
                .ok_or_else(|| {
                    Error::InvalidInput(format!(
                        "level {level} of a volume of {} levels (brick {first})",
                        levels.level_count()
                    ))
                }),
            LevelData::Store(store) => Ok(store.read_stored(level, brick)?),
            LevelData::Streamed(streamer) => Ok(dequantize(
                &streamer.read_now((level, first))?,
                streamer.backend().scalar(),
            )),
        }
    }

    /// Where the stored bricks are read from, for sources read from a store or a pyramid.
    fn backend(&self) -> Option<&dyn LevelBackend> {
        match self {
            LevelData::Volume { .. } => None,
            LevelData::Store(store) => Some(&**store),
            LevelData::Streamed(streamer) => Some(&**streamer.backend()),
        }
    }
}

impl LevelState {
    /// Stages `levels`: checks the plan (rule, levels, slots) first, so a refused plan leaves
    /// the drawn one as it is; then uploads only what changed ([`LevelResidency`]).
    ///
    /// A stored brick that cannot be read fails the call with its error, changes nothing
    /// (the cache and its residency still hold the drawn plan) and is named in
    /// `last_failed_read`.
    pub(super) fn stage(&mut self, levels: &[Option<u32>]) -> Result<LevelUpdateReport> {
        let start = Instant::now();
        self.last_failed_read = None;
        let plan = LevelPlan::new(&self.grid, self.data.level_count(), levels)?;
        if self.gpu.has_pending() {
            // A change staged but never recorded: the cache does not hold it.
            self.gpu.discard_pending();
            self.residency.invalidate();
        }
        let before = self.residency.clone();
        let update = self.residency.update(&plan, &self.geometry)?;
        let packed = &update.packing;
        let geometry = &self.geometry;
        let scalar = self.scalar;
        let texel_bytes = scalar.size_bytes();
        let mut uploaded_bytes = 0;
        // The texels of each uploaded stored brick: cut from the volume in RAM, or read.
        let (data, grid) = (&self.data, self.grid);
        let mut failed_read = None;
        let staged = stage_three_level(
            &mut self.gpu,
            packed,
            geometry,
            scalar,
            &update.upload,
            &mut |brick| {
                let level = packed.places[brick].map_or(0, |p| p.level);
                let first = grid.linear_index(block_origin(grid.brick_coords(brick), level));
                let texels = data
                    .read_stored(level, first, grid.brick_coords(brick))
                    .inspect_err(|_| failed_read = Some((level, first)))?;
                // What the copy writes: the cache's part of the stored brick (its inner box
                // at level 0 with two slot classes), as `upload_bytes_for` counts it.
                uploaded_bytes += texel_bytes * (geometry.stored_edge(level) as usize).pow(3);
                Ok(texels)
            },
        );
        match staged {
            Ok(facts) => self.facts = facts,
            Err(e) if failed_read.is_some() => {
                // Nothing was staged: the cache and the residency before hold the drawn plan.
                self.residency = before;
                self.last_failed_read = failed_read;
                return Err(e);
            }
            Err(e) => {
                // The cache still holds the drawn plan, but not what the residency now says.
                self.residency.invalidate();
                return Err(e);
            }
        }
        self.current = levels.to_vec();
        let report = LevelUpdateReport {
            stored_bricks: packed.stored.len(),
            uploaded_bricks: update.upload.len(),
            moved_bricks: update.moved,
            uploaded_bytes,
            repacked: update.repacked,
            stage_ms: start.elapsed().as_secs_f64() * 1e3,
        };
        self.last_update = Some(report.clone());
        Ok(report)
    }

    /// Levels the source builds (0 up to this, exclusive).
    pub(super) fn level_count(&self) -> u32 {
        self.data.level_count()
    }

    /// The streamer of a [`VolumeSource::LevelStream`](super::VolumeSource::LevelStream)
    /// source.
    pub(super) fn streamer(&self) -> Option<&LevelStreamer> {
        match &self.data {
            LevelData::Streamed(streamer) => Some(streamer),
            _ => None,
        }
    }

    /// Stored bricks whose read failed since the source was attached, on the render thread or
    /// (a streamed store) in the background: each kept out of every step, its region drawn at
    /// a coarser level or not at all.
    pub(super) fn failed_read_count(&self) -> usize {
        let Some(streamer) = self.streamer() else {
            return self.failed.len();
        };
        let mut keys = streamer.failed_keys();
        if keys.is_empty() {
            return self.failed.len();
        }
        keys.extend(self.failed.iter().copied());
        keys.sort_unstable();
        keys.dedup();
        keys.len()
    }

    /// The error of the first failed read on the render thread, else of one in the background.
    pub(super) fn first_failed_read(&self) -> Option<String> {
        self.first_failure.clone().or_else(|| {
            self.streamer()
                .and_then(LevelStreamer::first_failure)
                .map(|e| e.to_string())
        })
    }

    /// Slots of the cache.
    pub(super) fn slot_count(&self) -> u64 {
        u64::from(self.geometry.slot_count())
    }

    /// Bytes of the cache image.
    pub(super) fn cache_bytes(&self) -> u64 {
        self.geometry.extent().as_u64vec3().element_product() * self.scalar.size_bytes() as u64
    }

    /// Bytes of one stored brick of `level` in the cache.
    pub(super) fn stored_bytes(&self, level: u32) -> u64 {
        u64::from(self.geometry.stored_edge(level)).pow(3) * self.scalar.size_bytes() as u64
    }

    /// Bytes that staging `levels` now would upload, exactly as [`LevelState::stage`] would:
    /// new stored bricks, kept ones whose coarser neighbours change and kept ones moved to make
    /// room (everything when the cache would be packed afresh); `None` when the plan breaks the
    /// rules, does not fit the cache's slots or would upload a stored brick whose read failed.
    pub(super) fn upload_bytes_for(&self, levels: &[Option<u32>]) -> Option<u64> {
        let plan = LevelPlan::new(&self.grid, self.data.level_count(), levels).ok()?;
        let mut residency = self.residency.clone();
        if self.gpu.has_pending() {
            residency.invalidate();
        }
        let update = residency.update(&plan, &self.geometry).ok()?;
        let grid = self.grid;
        let unreadable = update.upload.iter().any(|&i| {
            let level = update.packing.places[i].map_or(0, |p| p.level);
            self.failed.contains(&(
                level,
                grid.linear_index(block_origin(grid.brick_coords(i), level)),
            ))
        });
        if unreadable {
            return None;
        }
        Some(
            update
                .upload
                .iter()
                .map(|&i| self.stored_bytes(update.packing.places[i].map_or(0, |p| p.level)))
                .sum(),
        )
    }
}

/// Each brick's range of `ranges` as a fraction of the volume's `value_range` (`[0, 1]` for the
/// volume's own extremes; a volume of one value gives every brick width 0).
fn error_ranges(
    ranges: &[crate::bricks::ValueRange],
    (min, max): (f32, f32),
) -> Vec<crate::bricks::ValueRange> {
    let scale = if max > min { 1.0 / (max - min) } else { 0.0 };
    ranges
        .iter()
        .map(|r| crate::bricks::ValueRange {
            min: (r.min - min) * scale,
            max: (r.max - min) * scale,
        })
        .collect()
}

impl VolumePass {
    /// Draws `volume` at `levels` through a new three-level cache ([`VolumeSource::Levels`](super::VolumeSource::Levels)).
    pub(super) fn attach_levels(
        &mut self,
        volume: Arc<Volume>,
        levels: &[Option<u32>],
        config: MixedConfig,
    ) -> Result<()> {
        let grid = crate::bricks::BrickGrid::new(volume.dims(), config.brick_size)?;
        let all = crate::cache::pyramid_levels(grid.brick_size(), grid.bricks_per_axis());
        let level_count = match config.max_levels {
            0 => all,
            cap => cap.min(all),
        };
        let data = LevelData::Volume {
            levels: VolumeLevels::new(volume.clone(), level_count, config.filter),
            brick_size: grid.brick_size(),
        };
        let facts = LevelSourceFacts {
            grid,
            spacing: volume.spacing(),
            value_range: volume.value_range(),
            scalar: volume.scalar_type(),
        };
        self.attach_level_data(data, facts, levels, config)
    }

    /// Draws a level store at `levels` through a new three-level cache, read straight from the
    /// file ([`VolumeSource::LevelStore`](super::VolumeSource::LevelStore)) or through a
    /// background streamer ([`VolumeSource::LevelStream`](super::VolumeSource::LevelStream)).
    pub(super) fn attach_level_store(
        &mut self,
        data: LevelData,
        levels: &[Option<u32>],
        config: MixedConfig,
    ) -> Result<()> {
        let Some(backend) = data.backend() else {
            return Err(Error::InvalidInput("not a level store".into()));
        };
        let grid = backend.grid();
        if config.brick_size != grid.brick_size() {
            return Err(Error::InvalidInput(format!(
                "{}: written with bricks of {}, but config.brick_size is {}",
                backend.name(),
                grid.brick_size(),
                config.brick_size
            )));
        }
        let range = backend.value_range();
        let facts = LevelSourceFacts {
            grid,
            spacing: backend.spacing(),
            value_range: (range.min, range.max),
            scalar: backend.scalar(),
        };
        self.attach_level_data(data, facts, levels, config)
    }

    /// Draws `data` at `levels` through a new three-level cache. The cache holds as many slots
    /// as the budget allows, up to every brick at level 0.
    fn attach_level_data(
        &mut self,
        data: LevelData,
        facts: LevelSourceFacts,
        levels: &[Option<u32>],
        config: MixedConfig,
    ) -> Result<()> {
        let grid = facts.grid;
        // Two levels take the two-level cache's slots (its bytes and capacity), more the
        // three-level packing.
        let geometry = SlotGeometry::choose(
            config.brick_size,
            crate::cache::classes_for_levels(data.level_count()),
            facts.scalar.size_bytes() as u32,
            config.cache_budget_bytes,
            self.ctx.shared.info.limits.max_image_dimension3_d,
            u32::try_from(grid.brick_count()).unwrap_or(u32::MAX),
        )?;
        // An empty plan: every brick at the coarsest level (or none drawn, below).
        let planned = levels.is_empty();
        let coarsest = vec![Some(data.level_count() - 1); grid.brick_count()];
        let levels = if planned { &coarsest } else { levels };
        // The plan is checked before the cache is allocated.
        LevelPlan::new(&grid, data.level_count(), levels)?;
        let bricks = BrickGeometry::new(grid, facts.spacing)?;
        let n = grid.brick_size();
        let cull_ranges = match &data {
            LevelData::Volume { levels, .. } => {
                conservative_ranges(&grid, data.level_count(), &mut |level, first| {
                    let texels = levels.stored_brick(level, first, n).unwrap_or_default();
                    Ok(crate::bricks::ValueRange::of(&texels))
                })?
            }
            LevelData::Store(_) | LevelData::Streamed(_) => {
                let backend = data
                    .backend()
                    .ok_or_else(|| Error::InvalidInput("no backend".into()))?;
                let whole = backend.value_range();
                conservative_ranges(&grid, data.level_count(), &mut |level, first| {
                    Ok(backend.stored_range(level, first).unwrap_or(whole))
                })?
            }
        };
        let error_ranges = error_ranges(&cull_ranges, facts.value_range);
        // Free the old source's GPU memory before allocating the new cache.
        self.source = Source::None;
        let gpu = new_three_level_cache(
            &self.ctx.shared,
            &geometry,
            facts.scalar,
            grid.brick_count(),
            config.transition == Transition::Smooth,
            self.desc.frames_in_flight,
        )?;
        let mut state = LevelState {
            gpu,
            grid,
            data,
            geometry,
            bricks,
            current: Vec::new(),
            dims: grid.dims(),
            spacing: facts.spacing,
            value_range: facts.value_range,
            is_float: facts.scalar == ScalarType::F32,
            scalar: facts.scalar,
            brick_size: config.brick_size,
            transition: config.transition,
            facts: LevelPlanFacts {
                any_transition: false,
                any_coarse: false,
                any_absent: true,
            },
            residency: LevelResidency::new(&geometry, grid.brick_count()),
            last_choice: None,
            chooser: crate::plan::LevelChooser::new(),
            last_update: None,
            cull_ranges,
            error_ranges,
            failed: HashSet::new(),
            last_failed_read: None,
            first_failure: None,
        };
        // A source left to the camera whose cache cannot hold the coarsest plan starts with
        // nothing drawn: the first update draws the most important bricks (never an error).
        let nothing = vec![None; grid.brick_count()];
        let levels = if planned && state.upload_bytes_for(levels).is_none() {
            &nothing
        } else {
            levels
        };
        match state.stage(levels) {
            Ok(_) => {}
            // A stored brick of the coarsest plan of a source left to the camera failed to
            // read (a corrupt brick, a failed fetch): it starts with nothing drawn, and the
            // updates step around the failed brick, counting it (never an error here).
            Err(e) if planned => {
                let Some(key) = state.last_failed_read.take() else {
                    return Err(e);
                };
                state.first_failure.get_or_insert_with(|| e.to_string());
                state.failed.insert(key);
                state.stage(&nothing)?;
            }
            Err(e) => return Err(e),
        }
        self.source = Source::Levels(Box::new(state));
        Ok(())
    }

    /// Moves a three-level source ([`VolumeSource::Levels`](super::VolumeSource::Levels), [`VolumeSource::LevelStore`](super::VolumeSource::LevelStore)) to
    /// `levels` (one per brick, the rule kept): the stored bricks that are new, or whose coarser
    /// neighbours changed, are packed (or read from the store) into free sub-slots or their own,
    /// every other one stays where it is (`crate::levels::LevelResidency`); the next
    /// [`VolumePass::record`] uploads them (one copy command, one region each) with the new
    /// tables and runs the fixups of the uploaded bricks. Returns what moved. Errors: another
    /// kind of source, a plan that breaks the one-level rule or names a level the source does
    /// not have, one that needs more slots than the cache has, or a stored brick that cannot be
    /// read; the drawn plan is then unchanged.
    pub fn set_brick_levels(&mut self, levels: &[Option<u32>]) -> Result<LevelUpdateReport> {
        let Source::Levels(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "set_brick_levels needs a three-level source (VolumeSource::Levels)".into(),
            ));
        };
        state.stage(levels)
    }

    /// What the last residency change of a three-level source moved (`None` for other sources,
    /// and before the first change).
    pub fn last_level_update(&self) -> Option<&LevelUpdateReport> {
        match &self.source {
            Source::Levels(state) => state.last_update.as_ref(),
            _ => None,
        }
    }

    /// The last choice of levels from the camera of a level source ([`VolumePass::update`]):
    /// the level each brick wants, the slots, the bricks still waiting, dropped or failed, the
    /// largest voxel on screen (`None` for other sources, and before the first update).
    pub fn last_level_choice(&self) -> Option<&crate::plan::LevelChoice> {
        match &self.source {
            Source::Levels(state) => state.last_choice.as_ref(),
            _ => None,
        }
    }

    /// The level of every brick a three-level source draws (`None` for other sources).
    pub fn brick_levels(&self) -> Option<&[Option<u32>]> {
        match &self.source {
            Source::Levels(state) => Some(&state.current),
            _ => None,
        }
    }

    /// The slots of a level source's cache (`None` for other sources).
    pub fn level_slot_count(&self) -> Option<u64> {
        match &self.source {
            Source::Levels(state) => Some(state.slot_count()),
            _ => None,
        }
    }

    /// Bytes of a level source's cache image (`None` for other sources).
    pub fn level_cache_bytes(&self) -> Option<u64> {
        match &self.source {
            Source::Levels(state) => Some(state.cache_bytes()),
            _ => None,
        }
    }
}
