//! What the pass draws: [`VolumeSource`] in, one of two kinds of source on the GPU out (one
//! plain 3D texture, or a brick cache), and everything that depends on which: residency changes,
//! the pipeline variant and the parameter block.

use super::level_source::{LevelData, LevelState};
use super::VolumePass;
use crate::bricks::{
    fallback_levels, BrickSource, DownsampleFilter, Level, RgbaBrickSource, VolumeBrickSource,
};
use crate::cache::{BrickCache, CacheGeometry};
use crate::error::{Error, Result};
use crate::gpu::{Access, TimestampPool};
use crate::gpu::{
    CacheRegion, CacheTables, GpuBrickCache, GpuContext, Image, ImageDesc, SlotPacking,
};
use crate::gpu::{RaycastVariant, StagingUpload};
use crate::lod::BrickGeometry;
use crate::optics::SamplingModel;
use crate::plan::ResidencyPlanner;
use crate::scene::Transition;
use crate::scene::{Camera, RayFeatures, RaycastParams, RenderSettings};
use crate::store::{LevelStore, LevelStreamer};
use crate::volume::{RgbaVolume, ScalarType, Volume};
use ash::vk;
use glam::UVec3;
use std::sync::Arc;
use std::time::Instant;

/// What a [`VolumePass`] (or `renderer::Renderer`) draws, given to
/// [`VolumePass::set_source`].
pub enum VolumeSource<'a> {
    /// `volume` as one plain 3D texture (its texels are copied now and uploaded by the next
    /// record).
    Volume(&'a Volume),
    /// A pre-classified volume as one RGBA32F 3D texture, filled by the next record for the
    /// frame's sampling model (and again when the model changes). RGBA volumes render in DVR
    /// mode without shading, gradient opacity, pre-integration or tricubic reconstruction (those
    /// need a scalar field); other settings are an `InvalidInput` error.
    Rgba(Arc<RgbaVolume>),
    /// A volume through the brick cache: bricked into `config.brick_size`^3 bricks, the cache
    /// image sized from the budget and the device limit, every brick absent until
    /// [`VolumePass::set_levels`] makes bricks resident.
    Mixed {
        /// The volume.
        volume: Arc<Volume>,
        /// Brick size, filter, cache budget and transition.
        config: MixedConfig,
    },
    /// Bricks from any source (an in-memory volume, or a [`crate::store::BrickStreamer`]
    /// streaming a brick store from disk) through the brick cache, as [`VolumeSource::Mixed`].
    Bricks {
        /// The brick source.
        source: Arc<dyn BrickSource>,
        /// `brick_size` and `filter` must match the source's.
        config: MixedConfig,
    },
    /// A volume drawn through the paper's three-level brick cache (`(n+4)^3` slots holding one
    /// level-0, eight level-1 or sixty-four level-2 bricks; `crate::cache::SlotGeometry`)
    /// at the levels the host gives, one per brick: `Some(0)` full resolution, `Some(k)` the
    /// vertex level `k` of [`crate::pyramid::LevelGrid::vertex_pyramid`], `None` not drawn (an
    /// empty slice: every brick at the coarsest level, a start for `VolumePass::update`, or
    /// none drawn when the cache cannot hold that: the first update draws the most important
    /// bricks). Face-, edge- and corner-adjacent drawn bricks must
    /// differ by at most one level; past
    /// level 2 (bricks of at least 8 voxels) the bricks of a level come in aligned blocks of
    /// [`crate::cache::block_bricks`]`(k)` per axis, each stored as one level-2-sized brick, up to
    /// the level whose block covers the grid's longest axis.
    /// The cache holds texels of the volume's scalar type (u8 / u16 UNORM: transitions between
    /// vertex levels then jump by at most half a step, `docs/cache-layout.md`; f32: C0
    /// everywhere); `config.filter` builds level 1 from level 0 (the two-level cache's low-res
    /// samples of that filter), every coarser level is the pyramid's tent or mean.
    /// `VolumePass::update` chooses levels from the camera (the levels given are where it
    /// starts); `VolumePass::set_brick_levels` sets them explicitly.
    Levels {
        /// The volume (shared: level 0's stored bricks are cut from it whenever they are
        /// uploaded, so no f32 copy of it is held; level 1 and coarser are, about 0.57 bytes
        /// per voxel, `crate::pyramid::VolumeLevels`).
        volume: Arc<Volume>,
        /// The level of each brick (linear brick index).
        levels: &'a [Option<u32>],
        /// Brick size, cache budget and transition.
        config: MixedConfig,
    },
    /// A level store drawn through the three-level brick cache, as [`VolumeSource::Levels`]
    /// draws a volume: every drawn brick is read from the file (one positioned read, CRC-checked)
    /// and packed straight into its slot, so the volume never sits in RAM. `levels` as for
    /// [`VolumeSource::Levels`], out of the store's levels (empty: every brick at the coarsest);
    /// `config.brick_size` must be the store's, `config.filter` is not used (the store's level 1
    /// was built by its own, [`LevelStore::filter`]).
    LevelStore {
        /// The open store.
        store: Arc<LevelStore>,
        /// The level of each brick (linear brick index).
        levels: &'a [Option<u32>],
        /// Brick size (the store's), cache budget and transition.
        config: MixedConfig,
    },
    /// A level store drawn as [`VolumeSource::LevelStore`] draws it, its stored bricks read on
    /// the streamer's background thread: [`VolumePass::update`](super::VolumePass::update)
    /// steps only onto bricks already in RAM (never waiting on the disk) and tells the streamer
    /// what to read next (`crate::store::LevelStreamer`'s module docs). Attaching the source and
    /// [`VolumePass::set_brick_levels`](super::VolumePass::set_brick_levels) read what is not in
    /// RAM on the caller's thread.
    LevelStream {
        /// The streamer over the store (shared with the host, which may read its counters).
        streamer: Arc<LevelStreamer>,
        /// The level of each brick (linear brick index; empty: every brick at the coarsest).
        levels: &'a [Option<u32>],
        /// Brick size (the store's), cache budget and transition.
        config: MixedConfig,
    },
    /// A pre-classified volume through the brick cache, its bricks holding the weighted channels
    /// for `model` (an RGBA32F cache image; the fixup and the smooth transition blend work on all
    /// four channels alike). Frames must ask for the same sampling model (set the source again
    /// to change it) and DVR without scalar-only effects, as [`VolumeSource::Rgba`].
    RgbaMixed {
        /// The volume.
        volume: &'a RgbaVolume,
        /// The sampling model the bricks are weighted for.
        model: SamplingModel,
        /// Brick size, filter, cache budget and transition.
        config: MixedConfig,
    },
}

/// Names the kind of source and its size (not the voxels).
impl std::fmt::Debug for VolumeSource<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VolumeSource::Volume(v) => f.debug_struct("Volume").field("dims", &v.dims()).finish(),
            VolumeSource::Rgba(v) => f.debug_struct("Rgba").field("dims", &v.dims()).finish(),
            VolumeSource::Mixed { volume, config } => f
                .debug_struct("Mixed")
                .field("dims", &volume.dims())
                .field("config", config)
                .finish(),
            VolumeSource::Bricks { source, config } => f
                .debug_struct("Bricks")
                .field("dims", &source.grid().dims())
                .field("config", config)
                .finish(),
            VolumeSource::Levels {
                volume,
                levels,
                config,
            } => f
                .debug_struct("Levels")
                .field("dims", &volume.dims())
                .field("bricks", &levels.len())
                .field("config", config)
                .finish(),
            VolumeSource::LevelStore {
                store,
                levels,
                config,
            } => f
                .debug_struct("LevelStore")
                .field("path", &store.path())
                .field("dims", &store.header().dims)
                .field("bricks", &levels.len())
                .field("config", config)
                .finish(),
            VolumeSource::LevelStream {
                streamer,
                levels,
                config,
            } => f
                .debug_struct("LevelStream")
                .field("from", &streamer.backend().name())
                .field("dims", &streamer.backend().grid().dims())
                .field("bricks", &levels.len())
                .field("config", config)
                .finish(),
            VolumeSource::RgbaMixed {
                volume,
                model,
                config,
            } => f
                .debug_struct("RgbaMixed")
                .field("dims", &volume.dims())
                .field("model", model)
                .field("config", config)
                .finish(),
        }
    }
}

/// How a volume is rendered through the brick cache.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct MixedConfig {
    /// Brick edge `n` in voxels (power of two).
    pub brick_size: u32,
    /// Filter that builds the low-res level.
    pub filter: DownsampleFilter,
    /// Upper bound on the cache image's size in bytes.
    pub cache_budget_bytes: u64,
    /// Smooth (C0) or discontinuous transitions.
    pub transition: Transition,
    /// The most levels an in-memory volume drawn as a level source
    /// ([`VolumeSource::Levels`]) gets: 0 for as many as its grid takes
    /// ([`crate::cache::pyramid_levels`]); 2 draws levels 0 and 1 through two slot classes,
    /// the two-level cache's bytes and capacity. A store has its own levels (ignored there).
    pub max_levels: u32,
}

impl Default for MixedConfig {
    /// Bricks of 32, the mean-of-2 filter, a 256 MiB cache, smooth transitions, every level.
    fn default() -> Self {
        Self {
            brick_size: 32,
            filter: DownsampleFilter::Mean2,
            cache_budget_bytes: 256 << 20,
            transition: Transition::Smooth,
            max_levels: 0,
        }
    }
}

/// What one residency change moved.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ResidencyReport {
    /// Bricks written into the cache (one copy region each).
    pub uploaded_bricks: usize,
    /// Bytes copied into the cache.
    pub uploaded_bytes: usize,
    /// Hi-res bricks resident after the change.
    pub hi_bricks: usize,
    /// Low-res bricks resident after the change.
    pub lo_bricks: usize,
    /// Hi-res bricks whose border the fixup pass rewrites.
    pub fixup_bricks: usize,
    /// Bricks drawn at a lower level than asked for because their bytes were not loaded yet
    /// (streaming sources); 0 for in-memory volumes.
    pub fallback_bricks: usize,
    /// CPU time spent packing (or fetching) bricks, in milliseconds.
    pub pack_ms: f64,
    /// Wall time of the update's submission in milliseconds: filled by the offscreen
    /// `renderer::Renderer`, which submits and waits; 0 when only staged.
    pub update_ms: f64,
}

/// One plain 3D texture.
pub(super) struct SingleVolume {
    pub(super) image: Image,
    dims: UVec3,
    spacing: glam::Vec3,
    value_range: (f32, f32),
    scalar: ScalarType,
    pending: Option<Vec<u8>>,
    /// Whether the image holds data (a later upload waits for earlier fragment reads).
    uploaded: bool,
    /// A pre-classified RGBA volume, and the sampling model its texture was filled for.
    rgba: Option<(Arc<RgbaVolume>, Option<SamplingModel>)>,
}

/// A source rendered through the brick cache.
pub(crate) struct MixedState {
    pub(crate) source: Arc<dyn BrickSource>,
    pub(crate) config: MixedConfig,
    pub(crate) cache: BrickCache,
    pub(crate) gpu: GpuBrickCache,
    any_transition: bool,
    /// Some resident brick is low-res (tricubic reconstruction then stays off).
    any_low_res: bool,
    /// Some brick is absent (culled or not resident): rays jump over it. A cache with every brick
    /// resident draws with a variant without that code.
    any_absent: bool,
    /// The sampling model of a pre-classified RGBA source (`None`: scalar data).
    pub(super) rgba_model: Option<SamplingModel>,
    pub(super) value_range: (f32, f32),
    /// The brick grid in world space (for the planner).
    pub(super) geometry: BrickGeometry,
    /// The camera-driven residency planner ([`VolumePass::update`]); remembers what it drew.
    pub(super) planner: ResidencyPlanner,
    /// The ranges the planner gets when the source learns ranges while streaming.
    pub(super) cull_ranges: super::cull_ranges::CullRanges,
    /// Whether tables were ever staged for the GPU cache (until then even an unchanged
    /// residency must be staged: the GPU tables hold nothing yet).
    tables_staged: bool,
    /// Per brick: its fixed-up border is stale and the next fixup must rewrite it
    /// ([`BrickCache::mark_stale_borders`]); cleared once a staged update was recorded.
    stale_borders: Vec<bool>,
}

/// The source on the GPU.
pub(super) enum Source {
    None,
    Single(SingleVolume),
    Mixed(Box<MixedState>),
    Levels(Box<LevelState>),
}

fn volume_format(scalar: ScalarType) -> vk::Format {
    match scalar {
        ScalarType::U8 => vk::Format::R8_UNORM,
        ScalarType::U16 => vk::Format::R16_UNORM,
        ScalarType::F32 => vk::Format::R32_SFLOAT,
    }
}

/// A sampled, linearly filtered 3D texture of `dims` texels in `format` for a single-resolution
/// volume (checks the format's features first).
fn volume_texture(ctx: &GpuContext, format: vk::Format, dims: UVec3, what: &str) -> Result<Image> {
    let shared = &ctx.shared;
    shared.require_format(
        format,
        vk::FormatFeatureFlags::SAMPLED_IMAGE
            | vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
            | vk::FormatFeatureFlags::TRANSFER_DST,
        what,
    )?;
    Image::new(
        shared,
        what,
        ImageDesc::new_3d(
            format,
            dims.to_array(),
            vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
        ),
    )
}

impl Source {
    /// Checks that frames with `features` can draw this source, and refills an RGBA texture
    /// whose sampling model changed.
    pub(super) fn prepare(&mut self, features: RayFeatures) -> Result<()> {
        let rgba_only = RayFeatures {
            sampling_model: features.sampling_model,
            coarse_low_res: features.coarse_low_res,
            clip_planes: features.clip_planes,
            ..RayFeatures::default()
        };
        match self {
            Source::Mixed(m) => {
                if let Some(model) = m.rgba_model {
                    if features != rgba_only || model != features.sampling_model {
                        return Err(Error::InvalidInput(format!(
                            "the RGBA brick cache holds {model:?}-model data and renders in DVR \
                             mode without shading, gradient opacity, pre-integration or \
                             tricubic reconstruction; the settings ask for {features:?}"
                        )));
                    }
                }
            }
            Source::Single(SingleVolume {
                rgba: Some((volume, model)),
                pending,
                ..
            }) => {
                if features != rgba_only {
                    return Err(Error::InvalidInput(format!(
                        "pre-classified RGBA volumes render in DVR mode without shading, \
                         gradient opacity, pre-integration or tricubic reconstruction; the \
                         settings ask for {features:?}"
                    )));
                }
                if *model != Some(features.sampling_model) {
                    *pending = Some(
                        bytemuck::cast_slice(&volume.weighted(features.sampling_model)).to_vec(),
                    );
                    *model = Some(features.sampling_model);
                }
            }
            Source::Single(_) | Source::Levels(_) | Source::None => {}
        }
        Ok(())
    }

    /// Records the source's staged upload for frame slot `frame` through `staging`: the plain
    /// texture's texels, or the brick cache's bricks and fixup (which write the upload-end and
    /// fixup-end timestamps at `queries` themselves). Returns (uploaded, timestamps written).
    pub(super) fn record_upload(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: usize,
        staging: &mut StagingUpload,
        queries: (&TimestampPool, u32),
    ) -> Result<(bool, bool)> {
        match self {
            Source::Single(v) => {
                let Some(bytes) = v.pending.take() else {
                    return Ok((false, false));
                };
                let previous = if v.uploaded {
                    Access::FragmentSampled
                } else {
                    Access::Nothing
                };
                staging.record_whole_image(cmd, &v.image, &bytes, previous)?;
                v.uploaded = true;
                Ok((true, false))
            }
            Source::Mixed(m) => {
                let recorded = m.gpu.record(cmd, frame, staging, Some(queries))?;
                Ok((recorded, recorded))
            }
            Source::Levels(l) => {
                let recorded = l.gpu.record(cmd, frame, staging, Some(queries))?;
                Ok((recorded, recorded))
            }
            Source::None => Ok((false, false)),
        }
    }
}

impl VolumePass {
    /// Draws `source` from now on (replacing any previous source); see [`VolumeSource`] for
    /// what each kind does. No command buffer recorded by this pass may still be executing.
    pub fn set_source(&mut self, source: VolumeSource<'_>) -> Result<()> {
        match source {
            VolumeSource::Volume(volume) => {
                let image = volume_texture(
                    &self.ctx,
                    volume_format(volume.scalar_type()),
                    volume.dims(),
                    "volume",
                )?;
                self.source = Source::Single(SingleVolume {
                    image,
                    dims: volume.dims(),
                    spacing: volume.spacing(),
                    value_range: volume.value_range(),
                    scalar: volume.scalar_type(),
                    pending: Some(volume.data().as_bytes().to_vec()),
                    uploaded: false,
                    rgba: None,
                });
                Ok(())
            }
            VolumeSource::Rgba(volume) => {
                let image = volume_texture(
                    &self.ctx,
                    vk::Format::R32G32B32A32_SFLOAT,
                    volume.dims(),
                    "RGBA volume",
                )?;
                self.source = Source::Single(SingleVolume {
                    image,
                    dims: volume.dims(),
                    spacing: volume.spacing(),
                    value_range: (0.0, 1.0),
                    scalar: ScalarType::F32,
                    pending: None,
                    uploaded: false,
                    rgba: Some((volume, None)),
                });
                Ok(())
            }
            VolumeSource::Mixed { volume, config } => {
                // The cache geometry is checked before the bricking work it would waste.
                self.check_cache_geometry(
                    &config,
                    volume.scalar_type().size_bytes() as u32,
                    volume.dims(),
                )?;
                let source = VolumeBrickSource::new(volume, config.brick_size, config.filter)?;
                self.attach_brick_source(Arc::new(source), config, None)
            }
            VolumeSource::Bricks { source, config } => {
                self.attach_brick_source(source, config, None)
            }
            VolumeSource::Levels {
                volume,
                levels,
                config,
            } => self.attach_levels(volume, levels, config),
            VolumeSource::LevelStore {
                store,
                levels,
                config,
            } => self.attach_level_store(LevelData::Store(store), levels, config),
            VolumeSource::LevelStream {
                streamer,
                levels,
                config,
            } => self.attach_level_store(LevelData::Streamed(streamer), levels, config),
            VolumeSource::RgbaMixed {
                volume,
                model,
                config,
            } => {
                self.check_cache_geometry(&config, 4 * 4, volume.dims())?;
                let source = RgbaBrickSource::new(volume, model, config.brick_size, config.filter)?;
                self.attach_brick_source(Arc::new(source), config, Some(model))
            }
        }
    }

    /// Refuses a `config` whose cache geometry cannot exist (a slot beyond the device's 3D image
    /// limit, a budget below one slot) for a volume of `dims` with `bytes_per_texel`, before the
    /// bricking that would come first.
    fn check_cache_geometry(
        &self,
        config: &MixedConfig,
        bytes_per_texel: u32,
        dims: glam::UVec3,
    ) -> Result<()> {
        // An invalid brick size or volume is left to the source's own (named) error.
        let Ok(grid) = crate::bricks::BrickGrid::new(dims, config.brick_size) else {
            return Ok(());
        };
        CacheGeometry::choose(
            config.brick_size,
            bytes_per_texel,
            config.cache_budget_bytes,
            self.ctx.shared.info.limits.max_image_dimension3_d,
            u32::try_from(grid.brick_count()).unwrap_or(u32::MAX),
        )?;
        Ok(())
    }

    /// Renders bricks from `source` through a new brick cache (`rgba_model`: the sampling model
    /// of pre-classified RGBA bricks).
    fn attach_brick_source(
        &mut self,
        source: Arc<dyn BrickSource>,
        config: MixedConfig,
        rgba_model: Option<SamplingModel>,
    ) -> Result<()> {
        let shared = &self.ctx.shared;
        let grid = source.grid();
        if grid.brick_size() != config.brick_size || source.filter() != config.filter {
            return Err(Error::InvalidInput(format!(
                "brick source has bricks of {} with filter {:?}; the config asks for {} with {:?}",
                grid.brick_size(),
                source.filter(),
                config.brick_size,
                config.filter
            )));
        }
        let scalar = source.scalar();
        let channels = source.channels();
        let geometry = CacheGeometry::choose(
            config.brick_size,
            scalar.size_bytes() as u32 * channels,
            config.cache_budget_bytes,
            shared.info.limits.max_image_dimension3_d,
            u32::try_from(grid.brick_count()).unwrap_or(u32::MAX),
        )?;
        let cache = BrickCache::new(grid, geometry)?;
        // Free the old source's GPU memory before allocating the new cache.
        self.source = Source::None;
        let gpu = GpuBrickCache::new(
            shared,
            scalar,
            channels,
            cache.geometry().extent(),
            cache.grid().brick_count(),
            cache.geometry().slot_count() as usize,
            self.desc.frames_in_flight,
            config.transition == Transition::Smooth,
            SlotPacking::TwoLevel,
        )?;
        let range = source.value_range();
        let geometry = BrickGeometry::new(grid, source.spacing())?;
        self.source = Source::Mixed(Box::new(MixedState {
            source,
            config,
            cache,
            gpu,
            any_transition: false,
            any_low_res: false,
            // Nothing is resident before the first plan.
            any_absent: true,
            value_range: (range.min, range.max),
            rgba_model,
            geometry,
            planner: ResidencyPlanner::new(self.residency.options),
            cull_ranges: Default::default(),
            tables_staged: false,
            stale_borders: vec![false; grid.brick_count()],
        }));
        Ok(())
    }

    /// The brick grid and cache model of the brick-cache source, if one is set.
    pub fn brick_cache(&self) -> Option<&BrickCache> {
        match &self.source {
            Source::Mixed(m) => Some(&m.cache),
            _ => None,
        }
    }

    /// The brick cache of a brick-cache source (two-level or level) with what a field probe
    /// needs: the volume's dimensions, the brick size and whether transitions are smooth.
    pub(crate) fn probe_target(&mut self) -> Option<(&mut GpuBrickCache, UVec3, u32, bool)> {
        match &mut self.source {
            Source::Mixed(m) => Some((
                &mut m.gpu,
                m.source.grid().dims(),
                m.config.brick_size,
                m.config.transition == Transition::Smooth,
            )),
            Source::Levels(l) => {
                let (dims, n, smooth) = (l.dims, l.brick_size, l.transition == Transition::Smooth);
                Some((&mut l.gpu, dims, n, smooth))
            }
            _ => None,
        }
    }

    pub(crate) fn mixed_state_mut(&mut self) -> Option<&mut MixedState> {
        match &mut self.source {
            Source::Mixed(m) => Some(m),
            _ => None,
        }
    }

    /// Moves the cache to `wanted` (one level per brick): bricks whose bytes the source has not
    /// loaded yet fall back to their low-res level (or stay absent) so this never blocks on disk;
    /// packs or fetches the bricks that changed and stages them with the new tables; the next
    /// [`VolumePass::record`] copies them (one copy command, one region each) and runs the fixup.
    pub fn set_levels(&mut self, wanted: &[Level]) -> Result<ResidencyReport> {
        let Source::Mixed(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "set_levels needs a brick-cache source (set_source) first".into(),
            ));
        };
        let (report, levels) = state.stage_levels(wanted)?;
        // The planner (if the host switches to `update` later) starts from what is drawn now.
        state.planner.set_drawn(&levels);
        Ok(report)
    }
}

impl MixedState {
    /// [`VolumePass::set_levels`] on this source: returns the report and the levels drawn (the
    /// fallbacks of `wanted`).
    pub(super) fn stage_levels(
        &mut self,
        wanted: &[Level],
    ) -> Result<(ResidencyReport, Vec<Level>)> {
        let state = self;
        let pack_start = Instant::now();
        let levels = fallback_levels(wanted, &*state.source);
        let fallback_bricks = levels.iter().zip(wanted).filter(|(a, b)| a != b).count();
        let before = state.cache.residencies().to_vec();
        let before_levels: Vec<Level> = before.iter().map(|r| r.level()).collect();
        let update = state.cache.update(&levels)?;
        if !state.gpu.has_pending() {
            // The last staged update was recorded with its fixup: every border is current.
            state.stale_borders.fill(false);
        }
        state
            .cache
            .mark_stale_borders(&update, &before_levels, &mut state.stale_borders);
        // Nothing moved (a still camera once converged): the GPU cache and its tables are
        // current, so nothing is staged and the next record copies nothing and skips the fixup.
        let unchanged =
            state.tables_staged && update.uploads.is_empty() && state.cache.residencies() == before;
        let grid = state.cache.grid();
        let mut packed = Vec::with_capacity(update.uploads.len());
        for upload in &update.uploads {
            let bytes = state
                .source
                .brick_bytes(upload.brick, upload.level)?
                .ok_or_else(|| {
                    Error::InvalidInput(format!(
                        "brick {} ({:?}) vanished from the source between fallback and upload",
                        upload.brick, upload.level
                    ))
                })?;
            packed.push((upload, bytes));
        }
        let regions: Vec<CacheRegion> = packed
            .iter()
            .map(|(u, bytes)| CacheRegion {
                origin: UVec3::from_array(u.dst_origin),
                extent: UVec3::from_array(u.extent),
                bytes,
            })
            .collect();
        let pack_ms = pack_start.elapsed().as_secs_f64() * 1e3;
        let layout = state.cache.layout_table();
        let neighbours = state.cache.neighbour_bits();
        let reverse = state.cache.reverse_table();
        let fixup_slots = state.cache.fixup_slots();
        // The fixup runs only over the hi-res bricks whose border this update (and any staged
        // before it, not yet recorded) made stale: a still or slowly moving camera re-fixes a
        // handful of bricks instead of every brick next to a low-res one.
        let stale_slots = state.cache.stale_fixup_slots(&state.stale_borders);
        let tables = CacheTables {
            layout: &layout,
            neighbours: &neighbours,
            reverse: &reverse,
            fixup_slots: &stale_slots,
            skeleton_bricks: &[],
            bricks: grid.bricks_per_axis(),
            brick_size: grid.brick_size(),
            slots_per_axis: state.cache.geometry().slots_per_axis(),
        };
        if !unchanged {
            state.gpu.stage(&regions, &tables)?;
            state.tables_staged = true;
        }
        state.any_transition = !fixup_slots.is_empty();
        let current = state.cache.levels();
        state.any_low_res = current.contains(&Level::Lo);
        state.any_absent = current.contains(&Level::Absent);
        let smooth = state.config.transition == Transition::Smooth;
        let report = ResidencyReport {
            uploaded_bricks: regions.len(),
            uploaded_bytes: regions.iter().map(|r| r.bytes.len()).sum(),
            hi_bricks: current.iter().filter(|l| **l == Level::Hi).count(),
            lo_bricks: current.iter().filter(|l| **l == Level::Lo).count(),
            fixup_bricks: if smooth { stale_slots.len() } else { 0 },
            fallback_bricks,
            pack_ms,
            update_ms: 0.0,
        };
        Ok((report, levels))
    }
}

impl VolumePass {
    /// The pipeline variant the current source draws with, with or without a host depth buffer:
    /// only the effects the scene uses.
    pub fn current_variant(&self, host_depth: bool, features: RayFeatures) -> RaycastVariant {
        match &self.source {
            Source::Mixed(m) => RaycastVariant {
                mixed_resolution: true,
                smooth_transitions: m.config.transition == Transition::Smooth && m.any_transition,
                absent_bricks: m.any_absent,
                host_depth,
                rgba_volume: m.rgba_model.is_some(),
                features: RayFeatures {
                    // The 8-fetch B-spline assumes a field trilinear on one grid.
                    tricubic: features.tricubic && !m.any_low_res,
                    ..features
                },
            },
            Source::Levels(l) => RaycastVariant {
                mixed_resolution: true,
                smooth_transitions: l.transition == Transition::Smooth && l.facts.any_transition,
                absent_bricks: l.facts.any_absent,
                host_depth,
                rgba_volume: false,
                features: RayFeatures {
                    tricubic: features.tricubic && !l.facts.any_coarse,
                    ..features
                },
            },
            Source::Single(v) => RaycastVariant {
                host_depth,
                features: RayFeatures {
                    coarse_low_res: false,
                    ..features
                },
                rgba_volume: v.rgba.is_some(),
                ..RaycastVariant::default()
            },
            Source::None => RaycastVariant {
                host_depth,
                features,
                ..RaycastVariant::default()
            },
        }
    }

    /// The parameter block a frame with these arguments uses: `camera` and `settings` are in
    /// world space, the block in the volume frame (both mapped by the inverse of the pass's
    /// [`VolumePass::model_transform`]).
    pub fn params(
        &self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<RaycastParams> {
        let model = self.model_transform();
        self.volume_params(
            &model.volume_camera(camera),
            &model.volume_settings(settings),
            width,
            height,
        )
    }

    /// [`VolumePass::params`] of a camera and settings already in the volume frame.
    pub(super) fn volume_params(
        &self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<RaycastParams> {
        match &self.source {
            Source::None => Err(Error::InvalidInput(
                "render called before set_source".into(),
            )),
            Source::Single(v) => Ok(RaycastParams::for_dims(
                v.dims,
                v.spacing,
                v.value_range,
                v.scalar == ScalarType::F32,
                camera,
                settings,
                width,
                height,
            )?),
            Source::Mixed(m) => Ok(RaycastParams::for_dims(
                m.source.grid().dims(),
                m.source.spacing(),
                m.value_range,
                m.source.scalar() == ScalarType::F32,
                camera,
                settings,
                width,
                height,
            )?
            .with_cache(m.config.brick_size, m.gpu.extent)),
            Source::Levels(l) => Ok(RaycastParams::for_dims(
                l.dims,
                l.spacing,
                l.value_range,
                l.is_float,
                camera,
                settings,
                width,
                height,
            )?
            .with_cache(l.brick_size, l.gpu.extent)),
        }
    }
}
