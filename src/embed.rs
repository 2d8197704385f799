//! The volume pass, embeddable in a host engine's Vulkan frame.
//!
//! [`VolumePass`] records everything it does into a command buffer the caller owns: staged
//! uploads (volume, brick cache, transfer function), the fixup pass, and the ray-cast, which
//! renders with dynamic rendering into the caller's colour view and can stop rays at the caller's
//! depth buffer. It never submits, never waits and never creates an instance or device (wrap the
//! host's objects with [`GpuContext::from_host`]). The offscreen [`crate::renderer::Renderer`] is
//! a small host built on it.
//!
//! # Synchronisation contract
//! For [`VolumePass::record`] into command buffer `cmd` with frame slot `frame`:
//! - **Frame slots.** Slot `frame` (`< frames_in_flight`) owns a parameter buffer, staging
//!   buffers, table copies, descriptor sets and a timestamp pool. The host may record slot
//!   `frame` again only after the command buffer that last used it has completed (wait on its
//!   fence). Use one slot per frame in flight.
//! - **Queue.** All command buffers recorded by one pass go to one queue, in recording order:
//!   the pass's own barriers order its cache updates after earlier frames' reads through queue
//!   submission order.
//! - **Colour target, before.** The image of `target.view` is in `COLOR_ATTACHMENT_OPTIMAL`;
//!   earlier writes to it are available and visible to `COLOR_ATTACHMENT_OUTPUT` (the pass loads
//!   and blends: premultiplied volume *over* the existing content, or clears first with
//!   [`TargetLoad::Clear`]). Its format is [`PassDesc::color_format`].
//! - **Depth, before** (optional). The depth image was created with `SAMPLED` usage, is in the
//!   layout given in [`HostDepth::layout`] (e.g. `DEPTH_STENCIL_READ_ONLY_OPTIMAL`), and the depth
//!   writes are available and visible to `FRAGMENT_SHADER` sampled reads. Rays end where
//!   `clip_from_world` puts the stored depth.
//! - **After.** The pass wrote the colour target at `COLOR_ATTACHMENT_OUTPUT` /
//!   `COLOR_ATTACHMENT_WRITE`, layout unchanged; the host adds the barrier for its next use.
//!   Depth was only read. The pass's own resources need nothing from the host.
//! - **Changing the source** ([`VolumePass::set_volume`], [`VolumePass::set_mixed_volume`]) and
//!   dropping the pass require that no command buffer recorded by it is still executing.
//! - **Residency changes** ([`VolumePass::set_levels`]) and transfer-function changes are staged
//!   on the CPU and recorded by the next [`VolumePass::record`]; they need no wait.

use crate::bricks::{
    fallback_levels, BrickSource, DownsampleFilter, Level, RgbaBrickSource, VolumeBrickSource,
};
use crate::cache::{BrickCache, CacheGeometry};
use crate::error::{Error, Result};
use crate::gpu::{
    image_barrier, Access, Buffer, CacheRegion, CacheTables, GpuBrickCache, GpuContext, Image,
    ImageDesc, PipelineCache, RaycastPipeline, RaycastVariant, TimestampPool, COLOR_LAYERS,
};
use crate::optics::preintegration::PreintegrationTable;
use crate::optics::{ClassificationTable, SamplingModel, TfPreset, TransferFunction, TF_SIZE};
use crate::reference::Transition;
use crate::scene::{Camera, RayFeatures, RaycastParams, RenderSettings};
use crate::volume::{RgbaVolume, ScalarType, Volume};
use ash::vk;
use glam::{Mat4, UVec3};
use gpu_allocator::MemoryLocation;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

/// Timestamp queries per frame slot: frame start, upload end, fixup end, ray-cast start, end.
const QUERIES_PER_FRAME: u32 = 5;

/// How a pass is set up: what it renders into and how many frames may be in flight.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct PassDesc {
    /// Format of the colour targets (must support colour attachment + blending).
    pub color_format: vk::Format,
    /// Frames in flight: independent sets of per-frame resources (at least 1).
    pub frames_in_flight: u32,
}

/// What happens to the colour target before the volume is blended over it.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum TargetLoad {
    /// Keep the content (the host's scene): the volume composites over it.
    Load,
    /// Clear to this premultiplied RGBA first.
    Clear([f32; 4]),
}

/// A host depth buffer the rays stop at.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct HostDepth {
    /// View of the depth image (depth aspect).
    pub view: vk::ImageView,
    /// The layout the depth image is in during the pass (a read-only depth layout).
    pub layout: vk::ImageLayout,
    /// The host's world-to-clip transform (Vulkan clip space, depth in [0, 1]) that produced the
    /// depth buffer, in the crate's world space (see [`crate::scene`]).
    pub clip_from_world: Mat4,
}

/// Where one frame is drawn.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PassTarget {
    /// The colour view (format [`PassDesc::color_format`], layout `COLOR_ATTACHMENT_OPTIMAL`).
    pub view: vk::ImageView,
    /// Its size in pixels; may change from frame to frame (resizing needs nothing else).
    pub extent: vk::Extent2D,
    /// Load or clear.
    pub load: TargetLoad,
    /// Optional depth buffer.
    pub depth: Option<HostDepth>,
}

/// GPU times of one frame's passes, in milliseconds (`None` when the pass did not run in that
/// frame or the queue has no timestamps).
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct PassTimings {
    /// Brick / volume / transfer-function copies.
    pub upload_ms: Option<f64>,
    /// The fixup compute pass.
    pub fixup_ms: Option<f64>,
    /// The ray-cast.
    pub raycast_ms: Option<f64>,
}

/// What one [`VolumePass::record`] drew with.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RecordedFrame {
    /// The parameter block (what the CPU reference needs to reproduce the frame).
    pub params: RaycastParams,
    /// The pipeline variant that drew it.
    pub variant: RaycastVariant,
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
}

impl Default for MixedConfig {
    fn default() -> Self {
        Self {
            brick_size: 32,
            filter: DownsampleFilter::Mean2,
            cache_budget_bytes: 256 << 20,
            transition: Transition::Smooth,
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
    /// [`crate::renderer::Renderer`], which submits and waits; 0 when only staged.
    pub update_ms: f64,
}

struct SingleVolume {
    image: Image,
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
    rgba_model: Option<SamplingModel>,
    value_range: (f32, f32),
}

enum Source {
    None,
    Single(SingleVolume),
    Mixed(Box<MixedState>),
}

struct FrameSlot {
    params: Buffer,
    staging: Option<Buffer>,
    tf_staging: Buffer,
    preint_staging: Option<Buffer>,
    queries: TimestampPool,
}

/// The pre-integration table on the GPU: a TF_SIZE x TF_SIZE RGBA32F image, rebuilt when the
/// transfer function, the sampling model or the step changes.
struct PreintegrationImage {
    image: Image,
    /// (model, step ratio bits) the image (or its pending upload) was built for; `None` after a
    /// transfer-function change.
    key: Option<(SamplingModel, u32)>,
    pending: Option<Vec<u8>>,
    initialized: bool,
}

/// The embeddable volume pass (see the module docs for the contract).
pub struct VolumePass {
    // GPU objects first; the context (which keeps the device alive) last.
    frames: Vec<FrameSlot>,
    source: Source,
    tf_image: Image,
    tf_pending: Option<Vec<u8>>,
    tf_initialized: bool,
    /// The transfer function and the sampling model its table on the GPU was built for.
    tf: TransferFunction,
    tf_model: Option<SamplingModel>,
    preintegration: Option<PreintegrationImage>,
    pipelines: HashMap<RaycastVariant, RaycastPipeline>,
    pipeline_cache: PipelineCache,
    desc: PassDesc,
    ctx: GpuContext,
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

/// Writes `bytes` into `staging` (growing it) and records a whole-image copy into `image`,
/// leaving it ready for fragment sampling.
fn record_image_upload(
    ctx: &GpuContext,
    cmd: vk::CommandBuffer,
    staging: &mut Option<Buffer>,
    image: &Image,
    bytes: &[u8],
    previous: Access,
) -> Result<()> {
    let shared = &ctx.shared;
    if staging.as_ref().is_none_or(|b| b.size < bytes.len() as u64) {
        *staging = Some(Buffer::new(
            shared,
            "staging",
            (bytes.len() as u64).next_power_of_two(),
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )?);
    }
    let buffer = staging.as_mut().expect("created above");
    buffer.mapped_mut()?[..bytes.len()].copy_from_slice(bytes);
    let region = vk::BufferImageCopy::default()
        .image_subresource(COLOR_LAYERS)
        .image_extent(image.desc.extent);
    let device = &shared.device;
    image_barrier(device, cmd, image.raw, previous, Access::TransferWrite);
    // SAFETY: the staging buffer holds the image's texels; the image is in TRANSFER_DST_OPTIMAL
    // after the barrier; `cmd` is recording.
    unsafe {
        device.cmd_copy_buffer_to_image(
            cmd,
            buffer.raw,
            image.raw,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            &[region],
        )
    };
    image_barrier(
        device,
        cmd,
        image.raw,
        Access::TransferWrite,
        Access::FragmentSampled,
    );
    Ok(())
}

impl VolumePass {
    /// Creates the per-frame resources; checks the formats it needs.
    pub fn new(ctx: &GpuContext, desc: PassDesc) -> Result<Self> {
        Self::with_pipeline_cache(ctx, desc, &[])
    }

    /// [`VolumePass::new`] with pipeline variants built through a `VkPipelineCache` seeded with
    /// `cache_data` (from [`VolumePass::pipeline_cache_data`] of an earlier run). Data made for
    /// another device or driver is ignored (see [`VolumePass::pipeline_cache_seeded`]).
    pub fn with_pipeline_cache(
        ctx: &GpuContext,
        desc: PassDesc,
        cache_data: &[u8],
    ) -> Result<Self> {
        if desc.frames_in_flight == 0 {
            return Err(Error::InvalidInput(
                "frames_in_flight must be at least 1".into(),
            ));
        }
        let shared = &ctx.shared;
        shared.require_format(
            desc.color_format,
            vk::FormatFeatureFlags::COLOR_ATTACHMENT
                | vk::FormatFeatureFlags::COLOR_ATTACHMENT_BLEND,
            "volume pass colour target",
        )?;
        let tf_format = vk::Format::R32G32B32A32_SFLOAT;
        shared.require_format(
            tf_format,
            vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
                | vk::FormatFeatureFlags::TRANSFER_DST,
            "transfer function",
        )?;
        let tf_image = Image::new(
            shared,
            "transfer function",
            ImageDesc::new_1d(
                tf_format,
                TF_SIZE as u32,
                vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
            ),
        )?;
        let frames = (0..desc.frames_in_flight)
            .map(|_| {
                Ok(FrameSlot {
                    params: Buffer::new(
                        shared,
                        "raycast params",
                        std::mem::size_of::<RaycastParams>() as u64,
                        vk::BufferUsageFlags::UNIFORM_BUFFER,
                        MemoryLocation::CpuToGpu,
                    )?,
                    staging: None,
                    tf_staging: Buffer::new(
                        shared,
                        "transfer function staging",
                        (TF_SIZE * 16) as u64,
                        vk::BufferUsageFlags::TRANSFER_SRC,
                        MemoryLocation::CpuToGpu,
                    )?,
                    preint_staging: None,
                    queries: TimestampPool::new(shared, QUERIES_PER_FRAME)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            frames,
            source: Source::None,
            tf_image,
            tf_pending: None,
            tf_initialized: false,
            tf: TransferFunction::preset(TfPreset::Grey),
            tf_model: None,
            preintegration: None,
            pipelines: HashMap::new(),
            pipeline_cache: PipelineCache::new(shared, cache_data)?,
            desc,
            ctx: ctx.clone(),
        })
    }

    /// The pass's set-up.
    pub fn desc(&self) -> PassDesc {
        self.desc
    }

    /// The context the pass records for.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Stages a transfer function; the next [`VolumePass::record`] uploads it (as the
    /// classification table of the frame's sampling model, and the pre-integration table when
    /// the frame asks for one).
    pub fn set_transfer_function(&mut self, tf: &TransferFunction) {
        self.tf = tf.clone();
        self.tf_model = None;
        if let Some(pre) = &mut self.preintegration {
            pre.key = None;
        }
    }

    /// The contents of the pass's `VkPipelineCache` (every variant built so far), to save and
    /// pass to [`VolumePass::with_pipeline_cache`] next time.
    pub fn pipeline_cache_data(&self) -> Result<Vec<u8>> {
        self.pipeline_cache.data()
    }

    /// Whether the pipeline cache was seeded with the data given at creation (false when there
    /// was none or it was made for another device or driver).
    pub fn pipeline_cache_seeded(&self) -> bool {
        self.pipeline_cache.seeded
    }

    /// The pipeline variants built so far (each compiled once, then reused).
    pub fn built_variants(&self) -> Vec<RaycastVariant> {
        self.pipelines.keys().copied().collect()
    }

    /// Stages the classification table for `model` and, with `preintegration_ratio`, the 2D
    /// pre-integration table for steps of that many reference lengths, unless already there.
    fn stage_tables(
        &mut self,
        model: SamplingModel,
        preintegration_ratio: Option<f32>,
    ) -> Result<()> {
        if self.tf_model != Some(model) {
            let table = ClassificationTable::new(&self.tf, model);
            self.tf_pending = Some(bytemuck::cast_slice(table.entries()).to_vec());
            self.tf_model = Some(model);
        }
        let Some(ratio) = preintegration_ratio else {
            return Ok(());
        };
        let key = Some((model, ratio.to_bits()));
        if self.preintegration.as_ref().is_some_and(|p| p.key == key) {
            return Ok(());
        }
        let table = PreintegrationTable::build(&ClassificationTable::new(&self.tf, model), ratio)?;
        let bytes = bytemuck::cast_slice(table.entries()).to_vec();
        if self.preintegration.is_none() {
            let image = Image::new(
                &self.ctx.shared,
                "pre-integration table",
                ImageDesc::new_2d(
                    vk::Format::R32G32B32A32_SFLOAT,
                    TF_SIZE as u32,
                    TF_SIZE as u32,
                    vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
                ),
            )?;
            self.preintegration = Some(PreintegrationImage {
                image,
                key: None,
                pending: None,
                initialized: false,
            });
        }
        let pre = self.preintegration.as_mut().expect("created above");
        pre.key = key;
        pre.pending = Some(bytes);
        Ok(())
    }

    /// Renders `volume` as one plain 3D texture from now on (uploaded by the next record).
    /// No command buffer recorded by this pass may still be executing.
    pub fn set_volume(&mut self, volume: &Volume) -> Result<()> {
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

    /// Renders the pre-classified `volume` as one RGBA32F 3D texture from now on (filled by the
    /// next record for the frame's sampling model, and again when the model changes). RGBA
    /// volumes render in DVR mode without shading, gradient opacity, pre-integration or tricubic
    /// reconstruction (those need a scalar field); other settings are an `InvalidInput` error.
    /// No command buffer recorded by this pass may still be executing.
    pub fn set_rgba_volume(&mut self, volume: Arc<RgbaVolume>) -> Result<()> {
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

    /// Renders `volume` through a brick cache from now on: bricks it into `config.brick_size`^3
    /// bricks, sizes the cache image from the budget and the device limit, and makes every brick
    /// absent. Call [`VolumePass::set_levels`] to make bricks resident. No command buffer
    /// recorded by this pass may still be executing.
    pub fn set_mixed_volume(&mut self, volume: Arc<Volume>, config: MixedConfig) -> Result<()> {
        let source = VolumeBrickSource::new(volume, config.brick_size, config.filter)?;
        self.set_brick_source(Arc::new(source), config)
    }

    /// Renders bricks from `source` (an in-memory volume, or a [`crate::store::BrickStreamer`]
    /// streaming a brick store from disk) through the brick cache. `config.brick_size` and
    /// `config.filter` must match the source's. No command buffer recorded by this pass may
    /// still be executing.
    pub fn set_brick_source(
        &mut self,
        source: Arc<dyn BrickSource>,
        config: MixedConfig,
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
        )
        .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let cache =
            BrickCache::new(grid, geometry).map_err(|e| Error::InvalidInput(e.to_string()))?;
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
        )?;
        let range = source.value_range();
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
            rgba_model: None,
        }));
        Ok(())
    }

    /// Renders the pre-classified `volume` through a brick cache from now on, its bricks holding
    /// the weighted channels for `model` (an RGBA32F cache image; the fixup and the smooth
    /// transition blend work on all four channels alike). Frames must ask for the same sampling
    /// model (call again to change it) and DVR without scalar-only effects, as
    /// [`VolumePass::set_rgba_volume`]. Make bricks resident with [`VolumePass::set_levels`].
    pub fn set_rgba_mixed_volume(
        &mut self,
        volume: &RgbaVolume,
        model: SamplingModel,
        config: MixedConfig,
    ) -> Result<()> {
        let source = RgbaBrickSource::new(volume, model, config.brick_size, config.filter)?;
        self.set_brick_source(Arc::new(source), config)?;
        if let Source::Mixed(m) = &mut self.source {
            m.rgba_model = Some(model);
        }
        Ok(())
    }

    /// The brick grid and cache model of the mixed-resolution volume, if one is set.
    pub fn brick_cache(&self) -> Option<&BrickCache> {
        match &self.source {
            Source::Mixed(m) => Some(&m.cache),
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
                "set_levels needs set_mixed_volume first".into(),
            ));
        };
        let pack_start = Instant::now();
        let levels = fallback_levels(wanted, &*state.source);
        let fallback_bricks = levels.iter().zip(wanted).filter(|(a, b)| a != b).count();
        let update = state
            .cache
            .update(&levels)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
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
        let tables = CacheTables {
            layout: &layout,
            neighbours: &neighbours,
            reverse: &reverse,
            fixup_slots: &fixup_slots,
            bricks: grid.bricks_per_axis(),
            brick_size: grid.brick_size(),
            slots_per_axis: state.cache.geometry().slots_per_axis(),
        };
        state.gpu.stage(&regions, &tables)?;
        state.any_transition = !fixup_slots.is_empty();
        let current = state.cache.levels();
        state.any_low_res = current.contains(&Level::Lo);
        state.any_absent = current.contains(&Level::Absent);
        let smooth = state.config.transition == Transition::Smooth;
        Ok(ResidencyReport {
            uploaded_bricks: regions.len(),
            uploaded_bytes: regions.iter().map(|r| r.bytes.len()).sum(),
            hi_bricks: current.iter().filter(|l| **l == Level::Hi).count(),
            lo_bricks: current.iter().filter(|l| **l == Level::Lo).count(),
            fixup_bricks: if smooth { fixup_slots.len() } else { 0 },
            fallback_bricks,
            pack_ms,
            update_ms: 0.0,
        })
    }

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

    /// The parameter block a frame with these arguments uses.
    pub fn params(
        &self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<RaycastParams> {
        match &self.source {
            Source::None => Err(Error::InvalidInput(
                "render called before set_volume / set_mixed_volume".into(),
            )),
            Source::Single(v) => RaycastParams::for_dims(
                v.dims,
                v.spacing,
                v.value_range,
                v.scalar == ScalarType::F32,
                camera,
                settings,
                width,
                height,
            ),
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
        }
    }

    /// Records staged uploads (and the fixup) for frame slot `frame` without drawing. The host
    /// contract of [`VolumePass::record`] applies.
    pub fn record_updates(&mut self, cmd: vk::CommandBuffer, frame: usize) -> Result<()> {
        self.check_frame(frame)?;
        let device = &self.ctx.shared.device;
        let slot = &mut self.frames[frame];
        let pool = slot.queries.raw;
        // SAFETY: `cmd` is recording (caller contract); the slot's queries are not in use.
        unsafe {
            device.cmd_reset_query_pool(cmd, pool, 0, QUERIES_PER_FRAME);
            device.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, 0);
        }
        let mut uploaded = false;
        if let Some(pre) = &mut self.preintegration {
            if let Some(bytes) = pre.pending.take() {
                uploaded = true;
                let previous = if pre.initialized {
                    Access::FragmentSampled
                } else {
                    Access::Nothing
                };
                record_image_upload(
                    &self.ctx,
                    cmd,
                    &mut slot.preint_staging,
                    &pre.image,
                    &bytes,
                    previous,
                )?;
                pre.initialized = true;
            }
        }
        if let Some(bytes) = self.tf_pending.take() {
            uploaded = true;
            let tf_staging = &mut slot.tf_staging;
            tf_staging.mapped_mut()?[..bytes.len()].copy_from_slice(&bytes);
            let region = vk::BufferImageCopy::default()
                .image_subresource(COLOR_LAYERS)
                .image_extent(self.tf_image.desc.extent);
            let previous = if self.tf_initialized {
                Access::FragmentSampled
            } else {
                Access::Nothing
            };
            image_barrier(
                device,
                cmd,
                self.tf_image.raw,
                previous,
                Access::TransferWrite,
            );
            // SAFETY: the staging buffer holds the table; TRANSFER_DST_OPTIMAL after the barrier.
            unsafe {
                device.cmd_copy_buffer_to_image(
                    cmd,
                    tf_staging.raw,
                    self.tf_image.raw,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[region],
                )
            };
            image_barrier(
                device,
                cmd,
                self.tf_image.raw,
                Access::TransferWrite,
                Access::FragmentSampled,
            );
            self.tf_initialized = true;
        }
        let cache_recorded = match &mut self.source {
            Source::Single(v) => {
                if let Some(bytes) = v.pending.take() {
                    uploaded = true;
                    let previous = if v.uploaded {
                        Access::FragmentSampled
                    } else {
                        Access::Nothing
                    };
                    record_image_upload(
                        &self.ctx,
                        cmd,
                        &mut slot.staging,
                        &v.image,
                        &bytes,
                        previous,
                    )?;
                    v.uploaded = true;
                }
                false
            }
            // Writes the upload-end and fixup-end timestamps itself.
            Source::Mixed(m) => m
                .gpu
                .record(cmd, frame, &mut slot.staging, Some((pool, 1)))?,
            Source::None => false,
        };
        if uploaded && !cache_recorded {
            // SAFETY: `cmd` is recording; query 1 was reset above.
            unsafe {
                device.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, 1)
            };
        }
        Ok(())
    }

    fn check_frame(&self, frame: usize) -> Result<()> {
        if frame >= self.frames.len() {
            return Err(Error::InvalidInput(format!(
                "frame slot {frame} out of range (frames in flight: {})",
                self.frames.len()
            )));
        }
        Ok(())
    }

    /// Records one frame into `cmd` (see the module docs for what the host must guarantee):
    /// staged uploads, the fixup, and the ray-cast into `target`.
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: usize,
        target: &PassTarget,
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Result<RecordedFrame> {
        self.check_frame(frame)?;
        let (width, height) = (target.extent.width, target.extent.height);
        let mut params = self.params(camera, settings, width, height)?;
        if let Some(depth) = &target.depth {
            let inverse = depth.clip_from_world.inverse();
            if !inverse.is_finite() {
                return Err(Error::InvalidInput(
                    "host clip_from_world is not invertible".into(),
                ));
            }
            params.world_from_clip = inverse;
        }
        let features = settings.features();
        let rgba_only = RayFeatures {
            sampling_model: features.sampling_model,
            coarse_low_res: features.coarse_low_res,
            clip_planes: features.clip_planes,
            ..RayFeatures::default()
        };
        if let Source::Mixed(m) = &self.source {
            if let Some(model) = m.rgba_model {
                if features != rgba_only || model != features.sampling_model {
                    return Err(Error::InvalidInput(format!(
                        "the RGBA brick cache holds {model:?}-model data and renders in DVR mode \
                         without shading, gradient opacity, pre-integration or tricubic \
                         reconstruction; the settings ask for {features:?}"
                    )));
                }
            }
        }
        if let Source::Single(SingleVolume {
            rgba: Some((volume, model)),
            pending,
            ..
        }) = &mut self.source
        {
            if features != rgba_only {
                return Err(Error::InvalidInput(format!(
                    "pre-classified RGBA volumes render in DVR mode without shading, gradient \
                     opacity, pre-integration or tricubic reconstruction; the settings ask for \
                     {features:?}"
                )));
            }
            if *model != Some(features.sampling_model) {
                *pending =
                    Some(bytemuck::cast_slice(&volume.weighted(features.sampling_model)).to_vec());
                *model = Some(features.sampling_model);
            }
        }
        self.stage_tables(
            features.sampling_model,
            features
                .preintegrated
                .then(|| params.box_min.w / params.box_max.w),
        )?;
        self.record_updates(cmd, frame)?;
        let variant = self.current_variant(target.depth.is_some(), features);
        if !self.pipelines.contains_key(&variant) {
            let pipeline = RaycastPipeline::new(
                &self.ctx.shared,
                self.desc.color_format,
                variant,
                self.desc.frames_in_flight,
                self.pipeline_cache.raw,
            )?;
            self.pipelines.insert(variant, pipeline);
        }
        let slot = &mut self.frames[frame];
        slot.params.mapped_mut()?[..std::mem::size_of::<RaycastParams>()]
            .copy_from_slice(bytemuck::bytes_of(&params));
        let (view, tables) = match &mut self.source {
            Source::Single(v) => (v.image.view, None),
            Source::Mixed(m) => {
                m.gpu.sync_slot(frame)?;
                (m.gpu.image.view, Some(m.gpu.slot_tables(frame)))
            }
            Source::None => unreachable!("params() checked the source"),
        };
        let pipeline = &self.pipelines[&variant];
        pipeline.write_descriptors(
            frame,
            slot.params.raw,
            view,
            self.tf_image.view,
            tables,
            target.depth.map(|d| (d.view, d.layout)),
            self.preintegration.as_ref().map(|p| p.image.view),
        );
        let device = &self.ctx.shared.device;
        let (load_op, clear) = match target.load {
            TargetLoad::Load => (vk::AttachmentLoadOp::LOAD, [0.0; 4]),
            TargetLoad::Clear(c) => (vk::AttachmentLoadOp::CLEAR, c),
        };
        let color = [vk::RenderingAttachmentInfo::default()
            .image_view(target.view)
            .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .load_op(load_op)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                color: vk::ClearColorValue { float32: clear },
            })];
        let area = vk::Rect2D {
            offset: vk::Offset2D { x: 0, y: 0 },
            extent: target.extent,
        };
        let rendering = vk::RenderingInfo::default()
            .render_area(area)
            .layer_count(1)
            .color_attachments(&color);
        let viewport = vk::Viewport {
            x: 0.0,
            y: 0.0,
            width: width as f32,
            height: height as f32,
            min_depth: 0.0,
            max_depth: 1.0,
        };
        let pool = slot.queries.raw;
        // SAFETY: `cmd` is recording (caller contract); every handle is live; the descriptor set
        // of this slot was written above while the slot is not in use (contract).
        unsafe {
            device.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, 3);
            device.cmd_begin_rendering(cmd, &rendering);
            device.cmd_set_viewport(cmd, 0, &[viewport]);
            device.cmd_set_scissor(cmd, 0, &[area]);
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline.pipeline);
            device.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::GRAPHICS,
                pipeline.layout,
                0,
                &[pipeline.descriptors.sets[frame]],
                &[],
            );
            device.cmd_draw(cmd, 3, 1, 0, 0);
            device.cmd_end_rendering(cmd);
            device.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, 4);
        }
        Ok(RecordedFrame { params, variant })
    }

    /// GPU times of the last frame recorded with slot `frame`, read without waiting: call it
    /// after the host's fence for that frame (before recording the slot again).
    pub fn timings(&self, frame: usize) -> Result<PassTimings> {
        self.check_frame(frame)?;
        let info = self.ctx.info();
        if !info.timestamps_supported {
            return Ok(PassTimings::default());
        }
        let ticks = self.frames[frame].queries.read_available()?;
        let period = f64::from(info.timestamp_period_ns) * 1e-6;
        let span = |a: usize, b: usize| match (ticks[a], ticks[b]) {
            (Some(x), Some(y)) => Some(y.wrapping_sub(x) as f64 * period),
            _ => None,
        };
        Ok(PassTimings {
            upload_ms: span(0, 1),
            fixup_ms: span(1, 2),
            raycast_ms: span(3, 4),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{ContextDesc, Severity};
    use crate::volume::SyntheticField;

    /// Two frames in flight, residency changes staged between frames while the other frame may
    /// still run, and a target resize halfway: clean under synchronization validation.
    #[test]
    fn frames_in_flight_with_residency_changes_and_a_resize_are_validation_clean() {
        let ctx = GpuContext::new(&ContextDesc {
            validation: true,
            device_name: None,
        })
        .unwrap();
        let log = ctx.message_log();
        {
            let shared = &ctx.shared;
            let device = &shared.device;
            let frames = 2usize;
            let mut pass = VolumePass::new(
                &ctx,
                PassDesc {
                    color_format: vk::Format::R8G8B8A8_UNORM,
                    frames_in_flight: frames as u32,
                },
            )
            .unwrap();
            let volume = Arc::new(
                SyntheticField::MarschnerLobb
                    .generate(UVec3::splat(32), ScalarType::U8)
                    .unwrap(),
            );
            pass.set_mixed_volume(
                volume,
                MixedConfig {
                    brick_size: 8,
                    ..MixedConfig::default()
                },
            )
            .unwrap();
            let count = pass.brick_cache().unwrap().grid().brick_count();
            // SAFETY: plain object creation on a live device; destroyed below after waiting.
            let (pool, cmds, fences) = unsafe {
                let pool = device
                    .create_command_pool(
                        &vk::CommandPoolCreateInfo::default()
                            .queue_family_index(shared.queue_family)
                            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                        None,
                    )
                    .unwrap();
                let cmds = device
                    .allocate_command_buffers(
                        &vk::CommandBufferAllocateInfo::default()
                            .command_pool(pool)
                            .command_buffer_count(frames as u32),
                    )
                    .unwrap();
                let fences: Vec<_> = (0..frames)
                    .map(|_| {
                        device
                            .create_fence(
                                &vk::FenceCreateInfo::default()
                                    .flags(vk::FenceCreateFlags::SIGNALED),
                                None,
                            )
                            .unwrap()
                    })
                    .collect();
                (pool, cmds, fences)
            };
            let make_targets = |size: u32| -> Vec<Image> {
                (0..frames)
                    .map(|_| {
                        Image::new(
                            shared,
                            "test target",
                            ImageDesc::new_2d(
                                vk::Format::R8G8B8A8_UNORM,
                                size,
                                size,
                                vk::ImageUsageFlags::COLOR_ATTACHMENT,
                            ),
                        )
                        .unwrap()
                    })
                    .collect()
            };
            let mut targets = make_targets(24);
            let mut size = 24;
            for i in 0..12 {
                let slot = i % frames;
                if i % 3 == 0 {
                    let levels: Vec<Level> = (0..count)
                        .map(|b| {
                            if (b + i) % 3 == 0 {
                                Level::Lo
                            } else {
                                Level::Hi
                            }
                        })
                        .collect();
                    pass.set_levels(&levels).unwrap();
                }
                if i == 6 {
                    // Resize: wait for the frames using the old targets, then replace them.
                    // SAFETY: waiting on our own fences.
                    unsafe { device.wait_for_fences(&fences, true, u64::MAX).unwrap() };
                    size = 40;
                    targets = make_targets(size);
                }
                let cmd = cmds[slot];
                // SAFETY: the slot's fence guarantees its previous frame completed.
                unsafe {
                    device
                        .wait_for_fences(&[fences[slot]], true, u64::MAX)
                        .unwrap();
                    device.reset_fences(&[fences[slot]]).unwrap();
                    device
                        .reset_command_buffer(cmd, vk::CommandBufferResetFlags::empty())
                        .unwrap();
                    device
                        .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
                        .unwrap();
                }
                let target = &targets[slot];
                image_barrier(
                    device,
                    cmd,
                    target.raw,
                    Access::Nothing,
                    Access::ColorAttachmentWrite,
                );
                let angle = i as f32 * 0.2;
                let camera = Camera::perspective(
                    glam::Vec3::new(2.0 * angle.cos(), 0.6, 2.0 * angle.sin()),
                    glam::Vec3::ZERO,
                    40.0,
                );
                let recorded = pass
                    .record(
                        cmd,
                        slot,
                        &PassTarget {
                            view: target.view,
                            extent: vk::Extent2D {
                                width: size,
                                height: size,
                            },
                            load: TargetLoad::Clear([0.0; 4]),
                            depth: None,
                        },
                        &camera,
                        &RenderSettings::default(),
                    )
                    .unwrap();
                assert!(recorded.variant.mixed_resolution);
                let cmd_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
                let submits = [vk::SubmitInfo2::default().command_buffer_infos(&cmd_infos)];
                // SAFETY: the command buffer is complete; the fence is unsignalled.
                unsafe {
                    device.end_command_buffer(cmd).unwrap();
                    device
                        .queue_submit2(shared.queue, &submits, fences[slot])
                        .unwrap();
                }
                if i >= frames {
                    // The slot recorded two frames ago has completed: its timings are readable.
                    let other = (i + 1) % frames;
                    // SAFETY: waiting on our own fence.
                    unsafe {
                        device
                            .wait_for_fences(&[fences[other]], true, u64::MAX)
                            .unwrap()
                    };
                    let t = pass.timings(other).unwrap();
                    assert!(t.raycast_ms.is_some_and(|ms| ms >= 0.0), "{t:?}");
                }
            }
            // SAFETY: wait for everything, then destroy our objects.
            unsafe {
                device.device_wait_idle().unwrap();
                for f in fences {
                    device.destroy_fence(f, None);
                }
                device.destroy_command_pool(pool, None);
            }
            drop(targets);
            drop(pass);
        }
        assert_eq!(ctx.live_allocation_count(), 0);
        drop(ctx);
        let problems: Vec<_> = log
            .all()
            .into_iter()
            .filter(|m| m.severity >= Severity::Warning)
            .collect();
        assert!(problems.is_empty(), "{problems:#?}");
    }
}
