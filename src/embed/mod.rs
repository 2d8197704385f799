//! The volume pass, embeddable in a host engine's Vulkan frame.
//!
//! The pass is a folder: this file holds the contract below, the pass and its
//! [`VolumePass::record`]; `source` what is drawn ([`VolumeSource`], given to
//! [`VolumePass::set_source`]) and residency changes; `tables` the transfer-function and
//! pre-integration tables; `frames` the frame slots and their timings; `cull_ranges` the value
//! ranges the planner gets from a source that learns them while streaming. Every Vulkan command
//! is recorded through the safe types of [`crate::gpu`].
//!
//! [`VolumePass`] records everything it does into a command buffer the caller owns: staged
//! uploads (volume, brick cache, transfer function), the fixup pass, and the ray-cast, which
//! renders with dynamic rendering into the caller's colour view and can stop rays at the caller's
//! depth buffer. It never submits, never waits and never creates an instance or device (wrap the
//! host's objects with [`GpuContext::from_host`]). The offscreen `renderer::Renderer` is
//! a small host built on it.
//!
//! # World space and the model transform
//! The camera, the clip planes of [`RenderSettings`] and [`HostDepth::clip_from_world`] are in
//! world space ([`crate::scene`]). The pass draws the volume rotated into it by its model
//! transform ([`VolumePass::set_model_transform`]; identity by default, axis-aligned): it maps
//! the camera and clip planes into the volume frame by the inverse rotation before the frame's
//! parameters and the residency planner's view are built, and unprojects the host depth through
//! `(clip_from_world * model)^-1`, so depth-tested rays stop where the host's geometry is in
//! world space whatever the rotation (see [`crate::scene::model`]).
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
//! - **Changing the source** ([`VolumePass::set_source`]) and dropping the pass require that no
//!   command buffer recorded by it is still executing.
//! - **Residency changes** and transfer-function changes are staged on the CPU and recorded by
//!   the next [`VolumePass::record`]; they need no wait. Either the camera drives residency
//!   ([`VolumePass::update`] once per frame before `record`, with the frame's camera, size and
//!   settings: it plans under the budgets of [`ResidencyConfig`], fetches and stages the chosen
//!   bricks and asks the source for what comes next), or the host sets the levels itself
//!   ([`VolumePass::set_levels`]).
//!
//! A frame with camera-driven residency, with `frames_in_flight` slots:
//! ```text
//! wait fence[slot]                       // the slot's last frame is done
//! pass.timings(slot)                     // its GPU times (optional)
//! pass.update(&camera, w, h, &settings)  // CPU: plan, fetch, stage (FrameReport)
//! record host commands into cmd
//! pass.record(cmd, slot, &target, &camera, &settings)
//! submit cmd with fence[slot]; slot = (slot + 1) % frames_in_flight
//! ```

mod cull_ranges;
mod frames;
mod level_source;
mod residency;
mod source;
mod tables;

pub use frames::PassTimings;
pub use residency::{
    largest_step_bytes, FrameReport, LevelCounts, ResidencyConfig, BUDGET_DRIVEN_TARGET_PIXELS,
    MIN_STEP_BRICKS,
};
pub use source::{MixedConfig, ResidencyReport, VolumeSource};

use crate::error::{Error, Result};
use crate::gpu::{DrawTarget, GpuContext, PipelineCache, RaycastPipeline, RaycastVariant};
use crate::optics::TransferFunction;
use crate::scene::{Camera, ModelTransform, RaycastParams, RenderSettings};
use ash::vk;
use frames::{query, FrameSlot};
use glam::Mat4;
use source::Source;
use std::collections::HashMap;
use tables::TransferTables;

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
    /// depth buffer, in the crate's world space (see [`crate::scene`]): the host's projection
    /// times its view. The pass multiplies it by its model matrix
    /// ([`VolumePass::set_model_transform`]) itself.
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

/// What one [`VolumePass::record`] drew with.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RecordedFrame {
    /// The parameter block (what the CPU reference needs to reproduce the frame), in the volume
    /// frame: the camera and clip planes mapped by the inverse model transform.
    pub params: RaycastParams,
    /// The pipeline variant that drew it.
    pub variant: RaycastVariant,
}

/// The embeddable volume pass (see the module docs for the contract).
pub struct VolumePass {
    // GPU objects first; the context (which keeps the device alive) last.
    frames: Vec<FrameSlot>,
    source: Source,
    tables: TransferTables,
    pipelines: HashMap<RaycastVariant, RaycastPipeline>,
    pipeline_cache: PipelineCache,
    desc: PassDesc,
    residency: ResidencyConfig,
    model: ModelTransform,
    ctx: GpuContext,
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
        let tables = TransferTables::new(ctx)?;
        let frames = (0..desc.frames_in_flight)
            .map(|_| FrameSlot::new(ctx))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            frames,
            source: Source::None,
            tables,
            pipelines: HashMap::new(),
            pipeline_cache: PipelineCache::new(shared, cache_data)?,
            desc,
            residency: ResidencyConfig::default(),
            model: ModelTransform::IDENTITY,
            ctx: ctx.clone(),
        })
    }

    /// Places the volume in world space from now on: `model` rotates the volume frame (the
    /// axis-aligned box the ray-caster works in) about its centre into the world the camera,
    /// clip planes and host depth are given in (see [`crate::scene::model`]). Every
    /// [`VolumePass::params`], [`VolumePass::update`] and [`VolumePass::record`] maps its camera
    /// and clip planes by the inverse rotation, and a [`HostDepth::clip_from_world`] is applied
    /// as `clip_from_world * model.matrix()`. Kept across [`VolumePass::set_source`]; the
    /// identity (the default) renders the volume axis-aligned. Needs no wait: the next frame
    /// uses it.
    pub fn set_model_transform(&mut self, model: ModelTransform) {
        self.model = model;
    }

    /// The model transform frames are drawn with (see [`VolumePass::set_model_transform`]).
    pub fn model_transform(&self) -> ModelTransform {
        self.model
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
        self.tables.set(tf);
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

    /// Records staged uploads (and the fixup) for frame slot `frame` without drawing. The host
    /// contract of [`VolumePass::record`] applies.
    pub fn record_updates(&mut self, cmd: vk::CommandBuffer, frame: usize) -> Result<()> {
        self.check_frame(frame)?;
        let slot = &mut self.frames[frame];
        slot.queries.record_reset(cmd);
        slot.queries.write(cmd, query::FRAME_START);
        let tables_uploaded =
            self.tables
                .record(cmd, &mut slot.tf_staging, &mut slot.preint_staging)?;
        // The brick cache writes the upload-end and fixup-end timestamps itself.
        let (source_uploaded, timestamps_written) = self.source.record_upload(
            cmd,
            frame,
            &mut slot.source_staging,
            (&slot.queries, query::UPLOAD_END),
        )?;
        if (tables_uploaded || source_uploaded) && !timestamps_written {
            slot.queries.write(cmd, query::UPLOAD_END);
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
        let camera = &self.model.volume_camera(camera);
        let settings = &self.model.volume_settings(settings);
        let mut params = self.volume_params(camera, settings, width, height)?;
        if let Some(depth) = &target.depth {
            // Rays run in the volume frame: the depth is unprojected into it.
            let inverse = self.model.clip_from_volume(depth.clip_from_world).inverse();
            if !inverse.is_finite() {
                return Err(Error::InvalidInput(
                    "host clip_from_world is not invertible".into(),
                ));
            }
            params.world_from_clip = inverse;
        }
        let features = settings.features();
        self.source.prepare(features)?;
        self.tables.stage(
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
        slot.write_params(&params)?;
        let (view, tables) = match &mut self.source {
            Source::Single(v) => (v.image.view, None),
            Source::Mixed(m) => {
                m.gpu.sync_slot(frame)?;
                (m.gpu.image.view, Some(m.gpu.slot_tables(frame)))
            }
            Source::Levels(l) => {
                l.gpu.sync_slot(frame)?;
                (l.gpu.image.view, Some(l.gpu.slot_tables(frame)))
            }
            Source::None => {
                return Err(Error::InvalidInput(
                    "render called before set_source".into(),
                ))
            }
        };
        let pipeline = &self.pipelines[&variant];
        pipeline.write_descriptors(
            frame,
            slot.params.raw,
            view,
            self.tables.classification_view(),
            tables,
            target.depth.map(|d| (d.view, d.layout)),
            self.tables.preintegration_view(),
        );
        slot.queries.write(cmd, query::RAYCAST_START);
        pipeline.record_draw(
            cmd,
            frame,
            &DrawTarget {
                view: target.view,
                extent: target.extent,
                clear: match target.load {
                    TargetLoad::Load => None,
                    TargetLoad::Clear(c) => Some(c),
                },
            },
        );
        slot.queries.write(cmd, query::RAYCAST_END);
        Ok(RecordedFrame { params, variant })
    }

    /// GPU times of the last frame recorded with slot `frame`, read without waiting: call it
    /// after the host's fence for that frame (before recording the slot again).
    pub fn timings(&self, frame: usize) -> Result<PassTimings> {
        self.check_frame(frame)?;
        self.frames[frame].timings(self.ctx.info())
    }
}
