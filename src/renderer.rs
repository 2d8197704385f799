//! The façade: a volume, a transfer function and a camera in, an image and its timing out.

use crate::error::{Error, Result, VkResultExt};
use crate::gpu::{
    image_barrier, memory_barrier, Access, Buffer, DeviceShared, GpuContext, Image, ImageDesc,
    RaycastPipeline, RaycastVariant, Submitter, TimestampPool, COLOR_LAYERS,
};
use crate::optics::{TransferFunction, TF_SIZE};
use crate::scene::{Camera, RaycastParams, RenderSettings};
use crate::volume::{ScalarType, Volume};
use ash::vk;
use glam::{UVec3, Vec3, Vec4};
use gpu_allocator::MemoryLocation;
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
    volume: Option<GpuVolume>,
    tf_image: Image,
    params: Buffer,
    timestamps: TimestampPool,
    pipeline: RaycastPipeline,
    submitter: Submitter,
    format: TargetFormat,
    descriptors_dirty: bool,
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
        let pipeline = RaycastPipeline::new(shared, format.vk(), RaycastVariant::default())?;
        Ok(Self {
            target: None,
            volume: None,
            tf_image,
            params,
            timestamps,
            pipeline,
            submitter,
            format,
            descriptors_dirty: true,
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
        self.volume = Some(GpuVolume {
            image,
            dims: volume.dims(),
            spacing: volume.spacing(),
            value_range: volume.value_range(),
            scalar: volume.scalar_type(),
        });
        self.descriptors_dirty = true;
        Ok(())
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
        let volume = self
            .volume
            .as_ref()
            .ok_or_else(|| Error::InvalidInput("render called before set_volume".into()))?;
        RaycastParams::for_dims(
            volume.dims,
            volume.spacing,
            volume.value_range,
            volume.scalar == ScalarType::F32,
            camera,
            settings,
            width,
            height,
        )
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
        let volume = self.volume.as_ref().expect("checked in params()");
        if self.descriptors_dirty {
            self.pipeline
                .write_descriptors(self.params.raw, volume.image.view, self.tf_image.view, None);
            self.descriptors_dirty = false;
        }
        let target = self.target.as_ref().expect("created by ensure_target");
        let pipeline = &self.pipeline;
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
                    &[pipeline.set],
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
