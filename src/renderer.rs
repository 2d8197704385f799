//! The façade: a volume, a transfer function and a camera in, an image and its timing out.

use crate::bricks::Level;
use crate::cache::BrickCache;
pub use crate::embed::{FrameReport, MixedConfig, ResidencyConfig, ResidencyReport, VolumeSource};
use crate::embed::{PassDesc, PassTarget, TargetLoad, VolumePass};
use crate::error::{Error, Result};
use crate::gpu::{
    image_barrier, record_image_readback, Access, Buffer, FieldProbe, GpuContext, Image, ImageDesc,
    RaycastVariant, Submitter,
};
use crate::optics::TransferFunction;
use crate::plan::FramePlan;
use crate::scene::{Camera, ModelTransform, RaycastParams, RenderSettings};
use ash::vk;
use glam::{Vec3, Vec4};
use gpu_allocator::MemoryLocation;
use std::path::Path;
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
    /// The Vulkan format.
    pub fn vk(self) -> vk::Format {
        match self {
            TargetFormat::Rgba8Unorm => vk::Format::R8G8B8A8_UNORM,
            TargetFormat::Rgba32Float => vk::Format::R32G32B32A32_SFLOAT,
        }
    }

    /// Bytes per pixel of the format.
    pub fn bytes_per_pixel(self) -> usize {
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
    /// GPU time of uploads recorded with this frame, if any.
    pub gpu_upload_ms: Option<f64>,
    /// GPU time of the fixup pass recorded with this frame, if any.
    pub gpu_fixup_ms: Option<f64>,
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
    /// The camera-driven residency of this frame ([`VolumePass::update`]): `Some` when the
    /// renderer planned it (a brick-cache source whose levels the caller did not set).
    pub residency: Option<FrameReport>,
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

/// Writes `img` as PNG to `path`, atomically ([`crate::output`]): encoded in memory first, and
/// a failed write leaves any previous file intact.
pub fn save_png<P>(img: &image::ImageBuffer<P, Vec<u8>>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType<Subpixel = u8>,
{
    let fail = |message: String| Error::ImageWrite {
        path: path.to_path_buf(),
        message,
    };
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| fail(e.to_string()))?;
    crate::output::write_file_atomically(path, png.get_ref()).map_err(|e| fail(e.to_string()))
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

struct Target {
    image: Image,
    readback: Buffer,
    width: u32,
    height: u32,
}

/// Renders volumes offscreen: a small host of [`VolumePass`] that owns its target, submits each
/// frame, waits for it and reads the image back.
pub struct Renderer {
    // GPU objects first: they are dropped (after the idle wait in Drop) before `ctx`.
    target: Option<Target>,
    probe: Option<FieldProbe>,
    pass: VolumePass,
    submitter: Submitter,
    format: TargetFormat,
    /// Whether [`Renderer::render`] plans residency from the camera (brick-cache sources until
    /// the caller sets levels itself).
    planned: bool,
    ctx: GpuContext,
}

impl Renderer {
    /// Creates the pass and per-renderer resources; checks the formats it needs.
    pub fn new(ctx: &GpuContext, format: TargetFormat) -> Result<Self> {
        Self::with_pipeline_cache(ctx, format, &[])
    }

    /// [`Renderer::new`] with pipeline variants built through a `VkPipelineCache` seeded with
    /// `cache_data` from [`Renderer::pipeline_cache_data`] of an earlier run (see
    /// [`VolumePass::with_pipeline_cache`]).
    pub fn with_pipeline_cache(
        ctx: &GpuContext,
        format: TargetFormat,
        cache_data: &[u8],
    ) -> Result<Self> {
        ctx.shared.require_format(
            format.vk(),
            vk::FormatFeatureFlags::COLOR_ATTACHMENT | vk::FormatFeatureFlags::TRANSFER_SRC,
            "render target",
        )?;
        let pass = VolumePass::with_pipeline_cache(
            ctx,
            PassDesc {
                color_format: format.vk(),
                frames_in_flight: 1,
            },
            cache_data,
        )?;
        let submitter = Submitter::new(&ctx.shared)?;
        Ok(Self {
            target: None,
            probe: None,
            pass,
            submitter,
            format,
            planned: true,
            ctx: ctx.clone(),
        })
    }

    /// Submits the staged uploads now and waits (so errors and costs show where they arise).
    fn flush(&mut self) -> Result<()> {
        let pass = &mut self.pass;
        self.submitter.run(|_, cmd| pass.record_updates(cmd, 0))
    }

    /// Draws `source` from now on, replacing any previous source (see
    /// [`VolumePass::set_source`]). A plain volume is uploaded at once (and waited for). A
    /// brick-cache source starts with nothing resident; from then on every
    /// [`Renderer::render`] plans its residency from the camera ([`VolumePass::update`], under
    /// [`Renderer::set_residency_config`]) until [`Renderer::set_levels`] or
    /// [`Renderer::stage_levels`] takes over (for tests and fixed patterns). A level source
    /// given no levels (an empty slice) is planned alike, inside each render's submission (its
    /// uploads and fixups in the frame's timing), until [`Renderer::set_brick_levels`] takes
    /// over; one given its levels draws them (and [`Renderer::update`] plans it explicitly).
    pub fn set_source(&mut self, source: VolumeSource<'_>) -> Result<()> {
        self.probe = None;
        // A level source given its levels draws them; one given none is planned.
        self.planned = match &source {
            VolumeSource::Levels { levels, .. }
            | VolumeSource::LevelStore { levels, .. }
            | VolumeSource::LevelStream { levels, .. } => levels.is_empty(),
            _ => true,
        };
        let upload_now = matches!(source, VolumeSource::Volume(_));
        self.pass.set_source(source)?;
        if upload_now {
            self.flush()?;
        }
        Ok(())
    }

    /// The brick grid and cache model of the brick-cache source, if one is set.
    pub fn brick_cache(&self) -> Option<&BrickCache> {
        self.pass.brick_cache()
    }

    /// Moves the cache to `levels` (one per brick), uploads the changed bricks (one copy
    /// command, one region each), rewrites the tables and runs the fixup, and waits.
    /// Renders no longer plan residency from the camera (until the next
    /// [`Renderer::set_source`] or [`Renderer::set_planned`]).
    pub fn set_levels(&mut self, levels: &[Level]) -> Result<ResidencyReport> {
        self.planned = false;
        let mut report = self.pass.set_levels(levels)?;
        let start = Instant::now();
        self.flush()?;
        report.update_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(report)
    }

    /// Moves a three-level source ([`VolumeSource::Levels`], [`VolumeSource::LevelStore`],
    /// [`VolumeSource::LevelStream`]) to `levels` (see [`VolumePass::set_brick_levels`]):
    /// uploads the stored bricks that changed (a streamed source reads those not in RAM on this
    /// thread), rewrites the tables, runs the fixups of the uploaded bricks and waits. Renders
    /// no longer plan residency from the camera (until the next [`Renderer::set_source`] or
    /// [`Renderer::set_planned`]).
    pub fn set_brick_levels(
        &mut self,
        levels: &[Option<u32>],
    ) -> Result<crate::levels::LevelUpdateReport> {
        self.planned = false;
        let report = self.pass.set_brick_levels(levels)?;
        self.flush()?;
        Ok(report)
    }

    /// Stages a level source's move to `levels` without submitting it (see
    /// [`VolumePass::set_brick_levels`]): the next [`Renderer::render`] records the uploads and
    /// the fixups in its own command buffer (so the frame's timings include them). Renders no
    /// longer plan residency from the camera, as with [`Renderer::set_brick_levels`].
    pub fn stage_brick_levels(
        &mut self,
        levels: &[Option<u32>],
    ) -> Result<crate::levels::LevelUpdateReport> {
        self.planned = false;
        self.pass.set_brick_levels(levels)
    }

    /// What the last residency change of a three-level source moved (see
    /// [`VolumePass::last_level_update`]).
    pub fn last_level_update(&self) -> Option<&crate::levels::LevelUpdateReport> {
        self.pass.last_level_update()
    }

    /// The last choice of levels from the camera of a level source (see
    /// [`VolumePass::last_level_choice`]).
    pub fn last_level_choice(&self) -> Option<&crate::plan::LevelChoice> {
        self.pass.last_level_choice()
    }

    /// Plans the residency of a brick-cache source from `camera` as the next
    /// [`Renderer::render`] would ([`VolumePass::update`], under
    /// [`Renderer::set_residency_config`]), submits what it staged (uploads, fixups) and waits,
    /// without drawing: a host converging residency before a timed frame or a batch render calls
    /// it until the report says nothing uploads or waits. Whether renders plan is unchanged
    /// ([`Renderer::is_planned`]). Errors: not a brick-cache source, a bad view or settings.
    pub fn update(
        &mut self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<FrameReport> {
        let report = self.pass.update(camera, width, height, settings)?;
        self.flush()?;
        Ok(report)
    }

    /// The level of every brick a three-level source draws (`None` for other sources).
    pub fn brick_levels(&self) -> Option<&[Option<u32>]> {
        self.pass.brick_levels()
    }

    /// The slots of a level source's cache (`None` for other sources).
    pub fn level_slot_count(&self) -> Option<u64> {
        self.pass.level_slot_count()
    }

    /// Bytes of a level source's cache image (`None` for other sources).
    pub fn level_cache_bytes(&self) -> Option<u64> {
        self.pass.level_cache_bytes()
    }

    /// Stages a residency change without submitting it: the next [`Renderer::render`] records
    /// the uploads and the fixup in its own command buffer (so the frame's timings include them).
    /// Renders no longer plan residency from the camera, as with [`Renderer::set_levels`].
    pub fn stage_levels(&mut self, levels: &[Level]) -> Result<ResidencyReport> {
        self.planned = false;
        self.pass.set_levels(levels)
    }

    /// Whether renders of a brick-cache source plan residency from the camera: on after
    /// [`Renderer::set_source`], off after [`Renderer::set_levels`]; switching it on plans
    /// from what is resident.
    pub fn set_planned(&mut self, planned: bool) {
        self.planned = planned;
    }

    /// Whether renders plan residency from the camera (see [`Renderer::set_planned`]).
    pub fn is_planned(&self) -> bool {
        self.planned && (self.pass.brick_cache().is_some() || self.pass.brick_levels().is_some())
    }

    /// Budgets and tuning of camera-driven residency (see [`VolumePass::set_residency_config`]).
    pub fn set_residency_config(&mut self, config: ResidencyConfig) {
        self.pass.set_residency_config(config);
    }

    /// The budgets and tuning of camera-driven residency.
    pub fn residency_config(&self) -> ResidencyConfig {
        self.pass.residency_config()
    }

    /// The last planned frame's plan (see [`VolumePass::last_plan`]).
    pub fn last_plan(&self) -> Option<&FramePlan> {
        self.pass.last_plan()
    }

    /// Places the volume in world space: a rotation about the volume's centre, applied to every
    /// later frame (see [`VolumePass::set_model_transform`] and [`crate::scene::model`]; e.g.
    /// [`ModelTransform::of_volume`] for an oblique NIfTI or DICOM volume). The
    /// camera and clip planes stay in world space; [`Renderer::params`] is in the volume frame.
    pub fn set_model_transform(&mut self, model: ModelTransform) {
        self.pass.set_model_transform(model);
    }

    /// The model transform frames are drawn with (identity unless set).
    pub fn model_transform(&self) -> ModelTransform {
        self.pass.model_transform()
    }

    /// Uploads a new transfer function.
    pub fn set_transfer_function(&mut self, tf: &TransferFunction) -> Result<()> {
        self.pass.set_transfer_function(tf);
        self.flush()
    }

    /// Samples the GPU-reconstructed mixed-resolution field at volume points (hi-res voxel units)
    /// with the ray-caster's own functions; `None` where a point lies in an absent brick.
    pub fn probe_field(&mut self, points: &[Vec3]) -> Result<Vec<Option<f32>>> {
        let Some((gpu, dims, brick_size, smooth)) = self.pass.probe_target() else {
            return Err(Error::InvalidInput(
                "probe_field needs a brick-cache source (set_source) first".into(),
            ));
        };
        if self.probe.is_none() {
            self.probe = Some(FieldProbe::new(&self.ctx.shared, smooth)?);
        }
        let probe = self.probe.as_ref().expect("created above");
        probe.sample(&mut self.submitter, gpu, 0, dims, brick_size, points)
    }

    /// Reads the GPU brick cache back as normalised values (for tests).
    pub fn read_cache(&mut self) -> Result<Vec<f32>> {
        let Some(state) = self.pass.mixed_state_mut() else {
            return Err(Error::InvalidInput(
                "read_cache needs a brick-cache source (set_source) first".into(),
            ));
        };
        let bytes = state.gpu.read_back(&mut self.submitter)?;
        Ok(crate::bricks::dequantize(&bytes, state.source.scalar()))
    }

    /// The pipeline variants built so far (each compiled once, then reused).
    pub fn built_variants(&self) -> Vec<RaycastVariant> {
        self.pass.built_variants()
    }

    /// The contents of the pipeline cache (every variant built so far), to save for the next
    /// run.
    pub fn pipeline_cache_data(&self) -> Result<Vec<u8>> {
        self.pass.pipeline_cache_data()
    }

    /// Whether the pipeline cache was seeded with the data given at creation.
    pub fn pipeline_cache_seeded(&self) -> bool {
        self.pass.pipeline_cache_seeded()
    }

    /// The pipeline variant the current source draws with under `settings`: only the effects
    /// they use.
    pub fn current_variant(&self, settings: &RenderSettings) -> RaycastVariant {
        self.pass.current_variant(false, settings.features())
    }

    /// The parameter block a render with these arguments uses (also what the CPU reference
    /// needs to reproduce the frame), in the volume frame (see [`Renderer::set_model_transform`]).
    pub fn params(
        &self,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<RaycastParams> {
        self.pass.params(camera, settings, width, height)
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
        // Validate the arguments before creating a target of that size.
        self.pass.params(camera, settings, width, height)?;
        let residency = if self.is_planned() {
            Some(self.pass.update(camera, width, height, settings)?)
        } else {
            None
        };
        self.ensure_target(width, height)?;
        let target = self.target.as_ref().expect("created by ensure_target");
        let pass = &mut self.pass;
        let mut recorded = None;
        self.submitter.run(|device, cmd| {
            image_barrier(
                device,
                cmd,
                target.image.raw,
                Access::Nothing,
                Access::ColorAttachmentWrite,
            );
            recorded = Some(pass.record(
                cmd,
                0,
                &PassTarget {
                    view: target.image.view,
                    extent: vk::Extent2D { width, height },
                    load: TargetLoad::Clear([0.0; 4]),
                    depth: None,
                },
                camera,
                settings,
            )?);
            record_image_readback(
                device,
                cmd,
                &target.image,
                &target.readback,
                Access::ColorAttachmentWrite,
                None,
            )
        })?;
        let recorded = recorded.expect("recorded in the submission");
        let timings = self.pass.timings(0)?;
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
                gpu_raycast_ms: timings.raycast_ms,
                gpu_upload_ms: timings.upload_ms,
                gpu_fixup_ms: timings.fixup_ms,
                cpu_frame_ms: start.elapsed().as_secs_f64() * 1e3,
            },
            variant: recorded.variant,
            residency,
        })
    }

    /// The context this renderer draws with.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // Afterwards no GPU work uses our objects, which the field drops then destroy.
        if let Err(e) = self.ctx.shared.wait_idle() {
            log::error!("dropping the renderer: {e}");
        }
    }
}

#[cfg(test)]
mod device_loss_tests {
    use super::*;
    use crate::gpu::{ContextDesc, INJECT_WAIT_RESULT};
    use crate::optics::TfPreset;
    use crate::volume::{marschner_lobb, ScalarType};
    use glam::{UVec3, Vec3};

    fn renderer(ctx: &GpuContext, volume: &crate::volume::Volume) -> Renderer {
        let mut r = Renderer::new(ctx, TargetFormat::Rgba8Unorm).unwrap();
        r.set_transfer_function(&TransferFunction::preset(TfPreset::Fire))
            .unwrap();
        r.set_source(VolumeSource::Volume(volume)).unwrap();
        r
    }

    /// Device loss and a timed-out wait (injected after the real fence wait, which a healthy
    /// device cannot be made to fail) come back as typed errors, never a panic; the renderer is
    /// dropped without a leak and a new one renders on.
    #[test]
    fn a_lost_device_and_a_timeout_are_typed_errors_and_a_new_renderer_works() {
        let ctx = GpuContext::new(&ContextDesc {
            validation: true,
            device_name: None,
        })
        .unwrap();
        let log = ctx.message_log();
        let volume = marschner_lobb(UVec3::splat(16), ScalarType::U8).unwrap();
        let camera = Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0);
        let settings = RenderSettings::default();

        let mut r = renderer(&ctx, &volume);
        let good = r.render(&camera, &settings, 32, 32).unwrap();
        assert!(good.pixels.iter().any(|p| p.w > 0.05), "the ball is drawn");
        INJECT_WAIT_RESULT.with(|c| c.set(Some(vk::Result::ERROR_DEVICE_LOST)));
        match r.render(&camera, &settings, 32, 32) {
            Err(Error::DeviceLost { call }) => assert_eq!(call, "vkWaitForFences"),
            other => panic!("expected DeviceLost, got {:?}", other.map(|_| ())),
        }
        // A timeout: the submission is left pending, and the next frame waits for it first.
        INJECT_WAIT_RESULT.with(|c| c.set(Some(vk::Result::TIMEOUT)));
        match r.render(&camera, &settings, 32, 32) {
            Err(Error::GpuTimeout { timeout_ms, .. }) => assert!(timeout_ms > 0),
            other => panic!("expected GpuTimeout, got {:?}", other.map(|_| ())),
        }
        let again = r.render(&camera, &settings, 32, 32).unwrap();
        assert_eq!(again.pixels, good.pixels);
        drop(r);
        assert_eq!(
            ctx.live_allocation_count(),
            0,
            "the dropped renderer leaked"
        );

        // A new renderer on the context renders the same image.
        let mut r = renderer(&ctx, &volume);
        let fresh = r.render(&camera, &settings, 32, 32).unwrap();
        assert_eq!(fresh.pixels, good.pixels);
        drop(r);
        assert_eq!(ctx.live_allocation_count(), 0);
        drop(ctx);
        let problems = log.warnings_and_errors();
        assert!(problems.is_empty(), "{problems:?}");
    }

    #[test]
    fn device_lost_results_map_to_the_typed_error() {
        use crate::error::VkResultExt;
        let lost: std::result::Result<(), vk::Result> = Err(vk::Result::ERROR_DEVICE_LOST);
        assert!(matches!(
            lost.vk("vkQueueSubmit2"),
            Err(Error::DeviceLost {
                call: "vkQueueSubmit2"
            })
        ));
        let other: std::result::Result<(), vk::Result> = Err(vk::Result::ERROR_OUT_OF_HOST_MEMORY);
        assert!(matches!(other.vk("x"), Err(Error::Vulkan { .. })));
    }
}
