//! The façade: a volume, a transfer function and a camera in, an image and its timing out.

use crate::bricks::{
    pack_hi_res_brick, pack_low_res_brick, quantize_to, BrickGrid, DownsampleFilter,
};
use crate::cache::{BrickCache, CacheGeometry, Level};
use crate::error::{Error, Result, VkResultExt};
use crate::gpu::{
    image_barrier, memory_barrier, Access, Buffer, CacheRegion, CacheTables, DeviceShared,
    FieldProbe, GpuBrickCache, GpuContext, Image, ImageDesc, RaycastPipeline, RaycastVariant,
    Submitter, TimestampPool, COLOR_LAYERS,
};
use crate::optics::{TransferFunction, TF_SIZE};
use crate::reference::Transition;
use crate::scene::{Camera, RaycastParams, RenderSettings};
use crate::volume::{ScalarType, Volume};
use ash::vk;
use glam::{UVec3, Vec3, Vec4};
use gpu_allocator::MemoryLocation;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Format of the offscreen colour target.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum TargetFormat {
    /// 8-bit UNORM RGBA, linear (not sRGB): what the PNG holds.
    Rgba8Unorm,
    /// 32-bit float RGBA: for comparisons without quantisation.
    Rgba32Float,
}

impl TargetFormat {
    fn vk(self) -> vk::Format {
        match self {
            TargetFormat::Rgba8Unorm => vk::Format::R8G8B8A8_UNORM,
            TargetFormat::Rgba32Float => vk::Format::R32G32B32A32_SFLOAT,
        }
    }

    fn bytes_per_pixel(self) -> usize {
        match self {
            TargetFormat::Rgba8Unorm => 4,
            TargetFormat::Rgba32Float => 16,
        }
    }
}

/// Timing of one frame.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct FrameTiming {
    /// GPU time of the ray-cast pass in milliseconds (timestamps), where the queue supports them.
    pub gpu_raycast_ms: Option<f64>,
    /// CPU wall time from recording to read-back in milliseconds.
    pub cpu_frame_ms: f64,
}

/// A rendered image: premultiplied RGBA per pixel, row-major from the top-left.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Premultiplied colour and opacity per pixel.
    pub pixels: Vec<Vec4>,
    /// How long it took.
    pub timing: FrameTiming,
    /// The pipeline variant that drew it.
    pub variant: RaycastVariant,
}

/// Composites premultiplied pixels over an opaque `background` into 8-bit RGBA.
pub fn pixels_to_rgba8(
    pixels: &[Vec4],
    width: u32,
    height: u32,
    background: Vec3,
) -> image::RgbaImage {
    let to_u8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    image::RgbaImage::from_fn(width, height, |x, y| {
        let p = pixels[(y * width + x) as usize];
        let c = p.truncate() + (1.0 - p.w) * background;
        image::Rgba([to_u8(c.x), to_u8(c.y), to_u8(c.z), 255])
    })
}

/// Writes `img` as PNG to `path`.
pub fn save_png(img: &image::RgbaImage, path: &Path) -> Result<()> {
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| Error::ImageWrite {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

impl Frame {
    /// The frame over an opaque background, as 8-bit RGBA.
    pub fn to_rgba8(&self, background: Vec3) -> image::RgbaImage {
        pixels_to_rgba8(&self.pixels, self.width, self.height, background)
    }

    /// Writes the frame over `background` as a PNG.
    pub fn save_png(&self, path: &Path, background: Vec3) -> Result<()> {
        save_png(&self.to_rgba8(background), path)
    }
}

struct GpuVolume {
    image: Image,
    dims: UVec3,
    spacing: Vec3,
    value_range: (f32, f32),
    scalar: ScalarType,
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
    /// Hi-res bricks whose border the fixup pass rewrote.
    pub fixup_bricks: usize,
    /// CPU time spent packing bricks, in milliseconds.
    pub pack_ms: f64,
    /// Wall time of the upload + fixup submission, in milliseconds.
    pub gpu_update_ms: f64,
}

struct MixedState {
    volume: Arc<Volume>,
    config: MixedConfig,
    cache: BrickCache,
    gpu: GpuBrickCache,
    probe: Option<FieldProbe>,
    any_transition: bool,
    value_range: (f32, f32),
}

enum Source {
    None,
    Single(GpuVolume),
    Mixed(Box<MixedState>),
}

struct Target {
    image: Image,
    readback: Buffer,
    width: u32,
    height: u32,
}

fn volume_format(scalar: ScalarType) -> vk::Format {
    match scalar {
        ScalarType::U8 => vk::Format::R8_UNORM,
        ScalarType::U16 => vk::Format::R16_UNORM,
        ScalarType::F32 => vk::Format::R32_SFLOAT,
    }
}

/// Copies `bytes` into `image` (whole extent) through a staging buffer and leaves it ready for
/// fragment-shader sampling.
fn upload_image(
    shared: &Arc<DeviceShared>,
    submitter: &mut Submitter,
    image: &Image,
    bytes: &[u8],
) -> Result<()> {
    let mut staging = Buffer::new(
        shared,
        "staging",
        bytes.len() as u64,
        vk::BufferUsageFlags::TRANSFER_SRC,
        MemoryLocation::CpuToGpu,
    )?;
    staging.mapped_mut()?[..bytes.len()].copy_from_slice(bytes);
    let region = vk::BufferImageCopy::default()
        .image_subresource(COLOR_LAYERS)
        .image_extent(image.desc.extent);
    submitter.run(|device, cmd| {
        image_barrier(
            device,
            cmd,
            image.raw,
            Access::Nothing,
            Access::TransferWrite,
        );
        // SAFETY: the staging buffer holds exactly the image's texels; the image is in
        // TRANSFER_DST_OPTIMAL after the barrier above.
        unsafe {
            device.cmd_copy_buffer_to_image(
                cmd,
                staging.raw,
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
    })
}

/// Renders volumes offscreen with the GPU ray-caster.
pub struct Renderer {
    // GPU objects first: they are dropped (after the idle wait in Drop) before `ctx`.
    target: Option<Target>,
    source: Source,
    tf_image: Image,
    params: Buffer,
    timestamps: TimestampPool,
    /// Pipeline variants built so far, with the source generation their descriptors point at.
    pipelines: HashMap<RaycastVariant, (RaycastPipeline, u64)>,
    submitter: Submitter,
    format: TargetFormat,
    /// Bumped whenever the resources the descriptor sets point at change.
    generation: u64,
    ctx: GpuContext,
}

impl Renderer {
    /// Creates the pipeline and per-renderer resources; checks the formats it needs.
    pub fn new(ctx: &GpuContext, format: TargetFormat) -> Result<Self> {
        let shared = &ctx.shared;
        shared.require_format(
            format.vk(),
            vk::FormatFeatureFlags::COLOR_ATTACHMENT | vk::FormatFeatureFlags::TRANSFER_SRC,
            "render target",
        )?;
        let tf_format = vk::Format::R32G32B32A32_SFLOAT;
        shared.require_format(
            tf_format,
            vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
                | vk::FormatFeatureFlags::TRANSFER_DST,
            "transfer function",
        )?;
        let mut submitter = Submitter::new(shared)?;
        let tf_image = Image::new(
            shared,
            "transfer function",
            ImageDesc::new_1d(
                tf_format,
                TF_SIZE as u32,
                vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
            ),
        )?;
        let default_tf = TransferFunction::preset(crate::optics::TfPreset::Grey);
        upload_image(
            shared,
            &mut submitter,
            &tf_image,
            bytemuck::cast_slice(default_tf.entries()),
        )?;
        let params = Buffer::new(
            shared,
            "raycast params",
            std::mem::size_of::<RaycastParams>() as u64,
            vk::BufferUsageFlags::UNIFORM_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        let timestamps = TimestampPool::new(shared, 2)?;
        Ok(Self {
            target: None,
            source: Source::None,
            tf_image,
            params,
            timestamps,
            pipelines: HashMap::new(),
            submitter,
            format,
            generation: 1,
            ctx: ctx.clone(),
        })
    }

    /// Uploads `volume` into a 3D image (replacing any previous one).
    pub fn set_volume(&mut self, volume: &Volume) -> Result<()> {
        let shared = &self.ctx.shared;
        let format = volume_format(volume.scalar_type());
        shared.require_format(
            format,
            vk::FormatFeatureFlags::SAMPLED_IMAGE
                | vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
                | vk::FormatFeatureFlags::TRANSFER_DST,
            "volume texture",
        )?;
        let image = Image::new(
            shared,
            "volume",
            ImageDesc::new_3d(
                format,
                volume.dims().to_array(),
                vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
            ),
        )?;
        upload_image(
            shared,
            &mut self.submitter,
            &image,
            volume.data().as_bytes(),
        )?;
        self.source = Source::Single(GpuVolume {
            image,
            dims: volume.dims(),
            spacing: volume.spacing(),
            value_range: volume.value_range(),
            scalar: volume.scalar_type(),
        });
        self.generation += 1;
        Ok(())
    }

    /// Renders `volume` through a brick cache from now on: bricks it into `config.brick_size`^3
    /// bricks, sizes the cache image from the budget and the device limit, and makes every brick
    /// absent. Call [`Renderer::set_levels`] to make bricks resident.
    pub fn set_mixed_volume(&mut self, volume: Arc<Volume>, config: MixedConfig) -> Result<()> {
        let shared = &self.ctx.shared;
        let grid = BrickGrid::new(volume.dims(), config.brick_size)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let scalar = volume.scalar_type();
        let geometry = CacheGeometry::choose(
            config.brick_size,
            scalar.size_bytes() as u32,
            config.cache_budget_bytes,
            shared.info.limits.max_image_dimension3_d,
            u32::try_from(grid.brick_count()).unwrap_or(u32::MAX),
        )
        .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let cache =
            BrickCache::new(grid, geometry).map_err(|e| Error::InvalidInput(e.to_string()))?;
        self.source = Source::None;
        let gpu = GpuBrickCache::new(shared, scalar, cache.geometry().extent())?;
        let value_range = volume.value_range();
        self.source = Source::Mixed(Box::new(MixedState {
            volume,
            config,
            cache,
            gpu,
            probe: None,
            any_transition: false,
            value_range,
        }));
        self.generation += 1;
        Ok(())
    }

    /// The brick grid and cache model of the mixed-resolution volume, if one is set.
    pub fn brick_cache(&self) -> Option<&BrickCache> {
        match &self.source {
            Source::Mixed(m) => Some(&m.cache),
            _ => None,
        }
    }

    /// Moves the cache to `levels` (one per brick): packs and uploads the bricks that changed
    /// (one copy command, one region each), rewrites the tables and runs the fixup pass.
    pub fn set_levels(&mut self, levels: &[Level]) -> Result<ResidencyReport> {
        let Source::Mixed(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "set_levels needs set_mixed_volume first".into(),
            ));
        };
        let update = state
            .cache
            .update(levels)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let pack_start = Instant::now();
        let grid = state.cache.grid();
        let scalar = state.volume.scalar_type();
        let brick_err = |e: crate::bricks::BrickError| Error::InvalidInput(e.to_string());
        let mut packed = Vec::with_capacity(update.uploads.len());
        for upload in &update.uploads {
            let brick = grid.brick_coords(upload.brick as usize);
            let values = match upload.level {
                Level::Hi => pack_hi_res_brick(&state.volume, grid, brick).map_err(brick_err)?,
                _ => pack_low_res_brick(&state.volume, grid, state.config.filter, brick)
                    .map_err(brick_err)?,
            };
            packed.push((upload, quantize_to(&values, scalar)));
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
        let geometry = state.cache.geometry();
        let tables = CacheTables {
            layout: &layout,
            neighbours: &neighbours,
            reverse: &reverse,
            fixup_slots: &fixup_slots,
            bricks: grid.bricks_per_axis(),
            brick_size: grid.brick_size(),
            slots_per_axis: geometry.slots_per_axis(),
        };
        let gpu_start = Instant::now();
        let smooth = state.config.transition == Transition::Smooth;
        state
            .gpu
            .update(&mut self.submitter, &regions, &tables, smooth)?;
        state.any_transition = !fixup_slots.is_empty();
        let current = state.cache.levels();
        self.generation += 1;
        Ok(ResidencyReport {
            uploaded_bricks: regions.len(),
            uploaded_bytes: regions.iter().map(|r| r.bytes.len()).sum(),
            hi_bricks: current.iter().filter(|l| **l == Level::Hi).count(),
            lo_bricks: current.iter().filter(|l| **l == Level::Lo).count(),
            fixup_bricks: if smooth { fixup_slots.len() } else { 0 },
            pack_ms,
            gpu_update_ms: gpu_start.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// Samples the GPU-reconstructed mixed-resolution field at volume points (hi-res voxel units)
    /// with the ray-caster's own functions; `None` where a point lies in an absent brick.
    pub fn probe_field(&mut self, points: &[Vec3]) -> Result<Vec<Option<f32>>> {
        let Source::Mixed(state) = &mut self.source else {
            return Err(Error::InvalidInput(
                "probe_field needs set_mixed_volume first".into(),
            ));
        };
        if state.probe.is_none() {
            let smooth = state.config.transition == Transition::Smooth;
            state.probe = Some(FieldProbe::new(&self.ctx.shared, smooth)?);
        }
        let probe = state.probe.as_ref().expect("created above");
        let grid = state.cache.grid();
        probe.sample(
            &mut self.submitter,
            &state.gpu,
            grid.dims(),
            grid.brick_size(),
            points,
        )
    }

    /// Reads the GPU brick cache back as normalised values (for tests).
    pub fn read_cache(&mut self) -> Result<Vec<f32>> {
        let Source::Mixed(state) = &self.source else {
            return Err(Error::InvalidInput(
                "read_cache needs set_mixed_volume first".into(),
            ));
        };
        let bytes = state.gpu.read_back(&mut self.submitter)?;
        Ok(crate::reference::dequantize(
            &bytes,
            state.volume.scalar_type(),
        ))
    }

    /// The pipeline variant the current source draws with: only the effects it uses.
    pub fn current_variant(&self) -> RaycastVariant {
        match &self.source {
            Source::Mixed(m) => RaycastVariant {
                mixed_resolution: true,
                smooth_transitions: m.config.transition == Transition::Smooth && m.any_transition,
            },
            _ => RaycastVariant::default(),
        }
    }

    /// Uploads a new transfer function.
    pub fn set_transfer_function(&mut self, tf: &TransferFunction) -> Result<()> {
        upload_image(
            &self.ctx.shared,
            &mut self.submitter,
            &self.tf_image,
            bytemuck::cast_slice(tf.entries()),
        )
    }

    /// The parameter block a render with these arguments uses (also what the CPU reference
    /// needs to reproduce the frame).
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
            Source::Single(volume) => RaycastParams::for_dims(
                volume.dims,
                volume.spacing,
                volume.value_range,
                volume.scalar == ScalarType::F32,
                camera,
                settings,
                width,
                height,
            ),
            Source::Mixed(m) => Ok(RaycastParams::for_dims(
                m.volume.dims(),
                m.volume.spacing(),
                m.value_range,
                m.volume.scalar_type() == ScalarType::F32,
                camera,
                settings,
                width,
                height,
            )?
            .with_cache(m.config.brick_size, m.gpu.extent)),
        }
    }

    fn ensure_target(&mut self, width: u32, height: u32) -> Result<()> {
        if let Some(t) = &self.target {
            if t.width == width && t.height == height {
                return Ok(());
            }
        }
        self.target = None;
        let shared = &self.ctx.shared;
        let image = Image::new(
            shared,
            "render target",
            ImageDesc::new_2d(
                self.format.vk(),
                width,
                height,
                vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
            ),
        )?;
        let bytes = (width as u64)
            .checked_mul(height as u64)
            .and_then(|n| n.checked_mul(self.format.bytes_per_pixel() as u64))
            .ok_or_else(|| Error::InvalidInput(format!("viewport {width}x{height} too large")))?;
        let readback = Buffer::new(
            shared,
            "readback",
            bytes,
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        self.target = Some(Target {
            image,
            readback,
            width,
            height,
        });
        Ok(())
    }

    /// Renders one frame at `width` x `height` and reads it back.
    pub fn render(
        &mut self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<Frame> {
        let start = Instant::now();
        let params = self.params(camera, settings, width, height)?;
        self.ensure_target(width, height)?;
        self.params.mapped_mut()?[..std::mem::size_of::<RaycastParams>()]
            .copy_from_slice(bytemuck::bytes_of(&params));
        let variant = self.current_variant();
        if !self.pipelines.contains_key(&variant) {
            let pipeline = RaycastPipeline::new(&self.ctx.shared, self.format.vk(), variant)?;
            self.pipelines.insert(variant, (pipeline, 0));
        }
        let (pipeline, written) = self.pipelines.get_mut(&variant).expect("inserted above");
        if *written != self.generation {
            let (view, layout, tables) = match &self.source {
                Source::Single(v) => (
                    v.image.view,
                    vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                    None,
                ),
                Source::Mixed(m) => {
                    let (Some(l), Some(n)) = (&m.gpu.layout, &m.gpu.neighbours) else {
                        return Err(Error::InvalidInput(
                            "render before the first set_levels".into(),
                        ));
                    };
                    (
                        m.gpu.image.view,
                        vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                        Some((l.raw, n.raw)),
                    )
                }
                Source::None => unreachable!("params() checked the source"),
            };
            pipeline.write_descriptors(self.params.raw, view, layout, self.tf_image.view, tables);
            *written = self.generation;
        }
        let target = self.target.as_ref().expect("created by ensure_target");
        let pipeline = &*pipeline;
        let queries = &self.timestamps;
        self.submitter.run(|device, cmd| {
            let color = [vk::RenderingAttachmentInfo::default()
                .image_view(target.image.view)
                .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)];
            let area = vk::Rect2D {
                offset: vk::Offset2D { x: 0, y: 0 },
                extent: vk::Extent2D { width, height },
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
            let copy = vk::BufferImageCopy::default()
                .image_subresource(COLOR_LAYERS)
                .image_extent(target.image.desc.extent);
            // SAFETY: every handle is live; layouts match the barriers recorded around each use;
            // the descriptor set was written above while no work was pending.
            unsafe {
                device.cmd_reset_query_pool(cmd, queries.raw, 0, queries.count);
                image_barrier(
                    device,
                    cmd,
                    target.image.raw,
                    Access::Nothing,
                    Access::ColorAttachmentWrite,
                );
                device.cmd_write_timestamp2(
                    cmd,
                    vk::PipelineStageFlags2::ALL_COMMANDS,
                    queries.raw,
                    0,
                );
                device.cmd_begin_rendering(cmd, &rendering);
                device.cmd_set_viewport(cmd, 0, &[viewport]);
                device.cmd_set_scissor(cmd, 0, &[area]);
                device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline.pipeline);
                device.cmd_bind_descriptor_sets(
                    cmd,
                    vk::PipelineBindPoint::GRAPHICS,
                    pipeline.layout,
                    0,
                    &[pipeline.descriptors.set],
                    &[],
                );
                device.cmd_draw(cmd, 3, 1, 0, 0);
                device.cmd_end_rendering(cmd);
                device.cmd_write_timestamp2(
                    cmd,
                    vk::PipelineStageFlags2::ALL_COMMANDS,
                    queries.raw,
                    1,
                );
                image_barrier(
                    device,
                    cmd,
                    target.image.raw,
                    Access::ColorAttachmentWrite,
                    Access::TransferRead,
                );
                device.cmd_copy_image_to_buffer(
                    cmd,
                    target.image.raw,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    target.readback.raw,
                    &[copy],
                );
                memory_barrier(device, cmd, Access::TransferWrite, Access::HostRead);
            }
            Ok(())
        })?;
        let info = self.ctx.info();
        let gpu_raycast_ms = if info.timestamps_supported {
            let ticks = self.timestamps.read()?;
            Some(
                ticks[1].wrapping_sub(ticks[0]) as f64 * f64::from(info.timestamp_period_ns) * 1e-6,
            )
        } else {
            None
        };
        let bytes = target.readback.mapped()?;
        let pixels = match self.format {
            TargetFormat::Rgba8Unorm => bytes
                .chunks_exact(4)
                .map(|p| Vec4::new(p[0] as f32, p[1] as f32, p[2] as f32, p[3] as f32) / 255.0)
                .collect(),
            TargetFormat::Rgba32Float => bytemuck::pod_collect_to_vec::<u8, f32>(bytes)
                .chunks_exact(4)
                .map(Vec4::from_slice)
                .collect(),
        };
        Ok(Frame {
            width,
            height,
            pixels,
            timing: FrameTiming {
                gpu_raycast_ms,
                cpu_frame_ms: start.elapsed().as_secs_f64() * 1e3,
            },
            variant,
        })
    }

    /// The context this renderer draws with.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // SAFETY: waiting idle on a live device; afterwards no GPU work uses our objects, which
        // the field drops then destroy.
        let _ = unsafe { self.ctx.shared.device.device_wait_idle() }.vk("vkDeviceWaitIdle");
    }
}
