//! A small host engine that embeds the volume pass in its own Vulkan frame.
//!
//! It creates its own instance (validation on), device, gpu-allocator allocator, colour and depth
//! images, draws an opaque quad with depth, then records [`VolumePass::record`] into the same
//! command buffer: the volume composites over the quad and stops at its depth. The composite is
//! written as a PNG. `tests/embed.rs` runs [`run`] and checks the compositing analytically.
//!
//! A second part renders a brick source twice the size of its cache the way a host drives
//! camera-driven residency: per frame, wait for the slot's fence, [`VolumePass::update`] with the
//! frame's camera (plan, fetch and stage under the cache and upload budgets), record the host's
//! quad and [`VolumePass::record`], submit; two frames in flight. It prints every frame's
//! [`FrameReport`] summary along a short camera path (an orbit and a zoom towards the front
//! view), holds the front view until the residency settles, and checks that image analytically:
//! the transfer function is constant, so whatever the levels the composite is that of
//! [`expected`] (`tests/embed.rs` checks both parts; the example checks them too and fails
//! otherwise).
//!
//! Run: `cargo run --release --example embed_host -- out/embed.png` (writes `out/embed.png` and
//! `out/embed-bricks.png`)

use ash::vk;
use glam::{Mat4, UVec3, Vec3, Vec4};
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};
use gpu_allocator::MemoryLocation;
use mixvol::bricks::DownsampleFilter;
use mixvol::embed::{
    FrameReport, HostDepth, MixedConfig, PassDesc, PassTarget, ResidencyConfig, TargetLoad,
    VolumePass, VolumeSource,
};
use mixvol::gpu::{shaders::compile_source, GpuContext, HostDevice, ShaderStage};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::{Camera, ModelTransform, RenderSettings, Transition};
use mixvol::volume::{ScalarType, SyntheticField, Volume, VoxelData};
use std::ffi::c_void;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// Image size of the example.
pub const SIZE: u32 = 64;
/// Colour of the opaque quad (linear RGB).
pub const QUAD_COLOR: [f32; 3] = [0.9, 0.2, 0.1];
/// Background clear colour.
pub const BACKGROUND: [f32; 3] = [0.0, 0.0, 0.3];

/// Frames in flight of the host (one command buffer, fence and pass slot each).
pub const FRAMES_IN_FLIGHT: usize = 2;
/// Brick edge of the brick-cache part.
pub const BRICK_SIZE: u32 = 8;
/// Cache budget of the brick-cache part: a 32^3 R32F image, 27 slots, for 64 bricks of
/// 10^3 x 4 B = 256 KB in hi-res (twice the cache).
pub const BRICK_CACHE_BUDGET: u64 = 128 << 10;
/// Upload budget of the brick-cache part: four hi-res or 32 low-res bricks per frame, so the
/// residency builds up over several frames.
pub const BRICK_UPLOAD_BUDGET: u64 = 16_000;
/// Frames of the camera path of the brick-cache part.
pub const PATH_FRAMES: usize = 10;
/// Most still frames the brick-cache part waits for the residency to settle.
pub const MAX_SETTLE_FRAMES: usize = 40;

/// Which scene a run draws.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
enum Scene {
    /// A plain 3D texture, one frame.
    Volume,
    /// The brick cache along a camera path, residency planned by the pass.
    Bricks,
}

/// What one run produced.
pub struct HostReport {
    /// RGBA8 pixels, row-major from the top-left.
    pub pixels: Vec<[u8; 4]>,
    /// Validation warnings and errors the host's messenger received.
    pub validation_problems: usize,
    /// The messages themselves.
    pub messages: Vec<String>,
    /// The brick-cache part's per-frame residency reports (empty for the plain volume).
    pub frames: Vec<FrameReport>,
}

static PROBLEMS: AtomicUsize = AtomicUsize::new(0);
static MESSAGES: Mutex<Vec<String>> = Mutex::new(Vec::new());

unsafe extern "system" fn host_messenger(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user: *mut c_void,
) -> vk::Bool32 {
    if severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    ) {
        PROBLEMS.fetch_add(1, Ordering::SeqCst);
        // SAFETY: the layer passes valid callback data for the duration of the call.
        let text = unsafe { (*data).message_as_c_str() }
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        MESSAGES
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(text);
    }
    vk::FALSE
}

type BoxError = Box<dyn std::error::Error>;

fn check(r: Result<(), vk::Result>) -> Result<(), BoxError> {
    r.map_err(|e| format!("vulkan: {e}").into())
}

/// The host's orthographic camera: looks down -z at the unit volume box.
pub fn camera() -> Camera {
    Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.2)
}

/// `clip_from_world` of an orthographic `camera` (e.g. [`camera`]) in Vulkan conventions (y
/// down, depth 0..1), near 0.5, far 4.
pub fn clip_from_world_of(c: &Camera) -> Mat4 {
    let view = Mat4::look_at_rh(c.eye, c.target, c.up);
    let half = match c.projection {
        mixvol::scene::Projection::Orthographic { height } => 0.5 * height,
        mixvol::scene::Projection::Perspective { .. } => unreachable!("the host is orthographic"),
    };
    let proj = Mat4::orthographic_rh(-half, half, -half, half, 0.5, 4.0);
    Mat4::from_scale(Vec3::new(1.0, -1.0, 1.0)) * proj * view
}

/// The brick-cache part's camera path: from 30 degrees to the side and a 1.8-wide view, orbit
/// to the front and zoom to [`camera`]'s 1.2 (the frames after it hold [`camera`]).
pub fn brick_path() -> Vec<Camera> {
    (0..PATH_FRAMES)
        .map(|f| {
            let t = f as f32 / PATH_FRAMES as f32;
            let angle = 0.5 * (1.0 - t);
            let eye = 2.0 * Vec3::new(angle.sin(), 0.0, angle.cos());
            Camera::orthographic(eye, Vec3::ZERO, 1.8 - 0.6 * t)
        })
        .collect()
}

/// The brick-cache part's volume: Marschner-Lobb, 32^3 f32 (with the constant transfer function
/// the image does not depend on the values; the planner's errors do).
pub fn brick_volume() -> Volume {
    SyntheticField::MarschnerLobb
        .generate(UVec3::splat(32), ScalarType::F32)
        .expect("valid volume")
}

/// One line per frame: what the pass uploaded, what is resident, what waits, the worst error.
pub fn summary(frame: usize, r: &FrameReport) -> String {
    format!(
        "frame {frame:2}: uploaded {:3} bricks ({:.3} MB), resident hi {:2} lo {:2} absent {:2} \
         (culled {}), waiting {:2}, deferred {:2}, worst error {:.2} px, slots {}/{}, plan {:.2} \
         ms",
        r.residency.uploaded_bricks,
        r.residency.uploaded_bytes as f64 / 1e6,
        r.residency.hi_bricks,
        r.residency.lo_bricks,
        r.plan.bricks - r.residency.hi_bricks - r.residency.lo_bricks,
        r.plan.culled,
        r.plan.waiting_for_source,
        r.plan.deferred,
        r.plan.max_drawn_error,
        r.plan.slots_used,
        r.plan.slot_budget,
        r.plan_ms,
    )
}

/// Checks a composite of the [`camera`] view of a volume `voxels` deep analytically: where the
/// quad (plane z = 0, left half) is in front of the back half of the volume the rays stop at it
/// (half the path composites over the quad), elsewhere the whole path composites over the
/// background; outside the box the quad shows. Tolerance 2.5 / 255 per channel.
pub fn check_composite(pixels: &[[u8; 4]], voxels: f32) -> Result<(), String> {
    let px = |x: u32, y: u32| pixels[(y * SIZE + x) as usize];
    let close = |a: u8, e: f32| (a as f32 - e * 255.0).abs() <= 2.5;
    // The volume box spans x, y in [-0.5, 0.5]; the image shows [-0.6, 0.6]: pixel 16 is at
    // x = -0.3 (quad, inside the volume), pixel 48 at x = +0.3 (volume only), row 32 at y ~ 0.
    let with_quad = expected(0.5 * voxels, QUAD_COLOR);
    let without = expected(voxels, BACKGROUND);
    let quad = Vec4::new(QUAD_COLOR[0], QUAD_COLOR[1], QUAD_COLOR[2], 1.0);
    for (x, y, e) in [
        (16, 32, with_quad),
        (20, 20, with_quad),
        (48, 32, without),
        (44, 44, without),
        (1, 32, quad),
    ] {
        let p = px(x, y);
        for c in 0..3 {
            if !close(p[c], e[c]) {
                return Err(format!(
                    "pixel ({x},{y}) channel {c}: {} vs expected {:.1}",
                    p[c],
                    e[c] * 255.0
                ));
            }
        }
    }
    Ok(())
}

/// Checks the brick-cache part's reports: every frame within the cache's slots and the upload
/// budget, the budget spreading the first residency over several frames, the last frame settled
/// with every brick resident and both levels drawn.
pub fn check_bricks(frames: &[FrameReport]) -> Result<(), String> {
    for (f, r) in frames.iter().enumerate() {
        if r.plan.upload_bytes > BRICK_UPLOAD_BUDGET || r.plan.slots_used > r.plan.slot_budget {
            return Err(format!("frame {f} over a budget: {}", summary(f, r)));
        }
    }
    let uploading = frames
        .iter()
        .filter(|r| r.residency.uploaded_bricks > 0)
        .count();
    if uploading < 3 || !frames.iter().any(|r| r.plan.deferred > 0) {
        return Err(format!(
            "the upload budget did not spread the residency ({uploading} frames uploaded)"
        ));
    }
    let last = frames.last().ok_or("no frames")?;
    if !last.plan.is_settled()
        || last.residency.hi_bricks == 0
        || last.residency.lo_bricks == 0
        || last.residency.hi_bricks + last.residency.lo_bricks != last.plan.bricks
    {
        return Err(format!(
            "the last frame is not settled and mixed: {}",
            summary(frames.len() - 1, last)
        ));
    }
    Ok(())
}

/// Records the host's part of a frame into `cmd`: the colour and depth targets cleared, the
/// opaque quad drawn with depth, then the barriers the pass contract asks for.
fn record_frame(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    (color, depth): (&HostImage, &HostImage),
    (pipeline, layout): (vk::Pipeline, vk::PipelineLayout),
    clip_from_world: &Mat4,
) {
    use vk::{AccessFlags2 as A, ImageLayout as L, PipelineStageFlags2 as S};
    // Earlier frames (in submission order) may still read both images: wait for all of them.
    barrier(
        device,
        cmd,
        color.image,
        vk::ImageAspectFlags::COLOR,
        (S::ALL_COMMANDS, A::NONE, L::UNDEFINED),
        (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
    );
    barrier(
        device,
        cmd,
        depth.image,
        vk::ImageAspectFlags::DEPTH,
        (S::ALL_COMMANDS, A::NONE, L::UNDEFINED),
        (
            S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
            A::DEPTH_STENCIL_ATTACHMENT_WRITE | A::DEPTH_STENCIL_ATTACHMENT_READ,
            L::DEPTH_ATTACHMENT_OPTIMAL,
        ),
    );
    let area = vk::Rect2D {
        offset: vk::Offset2D { x: 0, y: 0 },
        extent: vk::Extent2D {
            width: SIZE,
            height: SIZE,
        },
    };
    let color_attachment = [vk::RenderingAttachmentInfo::default()
        .image_view(color.view)
        .image_layout(L::COLOR_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .clear_value(vk::ClearValue {
            color: vk::ClearColorValue {
                float32: [BACKGROUND[0], BACKGROUND[1], BACKGROUND[2], 1.0],
            },
        })];
    let depth_attachment = vk::RenderingAttachmentInfo::default()
        .image_view(depth.view)
        .image_layout(L::DEPTH_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .clear_value(vk::ClearValue {
            depth_stencil: vk::ClearDepthStencilValue {
                depth: 1.0,
                stencil: 0,
            },
        });
    let rendering_info = vk::RenderingInfo::default()
        .render_area(area)
        .layer_count(1)
        .color_attachments(&color_attachment)
        .depth_attachment(&depth_attachment);
    // SAFETY: recording the host's own draw with live objects.
    unsafe {
        device.cmd_begin_rendering(cmd, &rendering_info);
        device.cmd_set_viewport(
            cmd,
            0,
            &[vk::Viewport {
                x: 0.0,
                y: 0.0,
                width: SIZE as f32,
                height: SIZE as f32,
                min_depth: 0.0,
                max_depth: 1.0,
            }],
        );
        device.cmd_set_scissor(cmd, 0, &[area]);
        device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline);
        device.cmd_push_constants(
            cmd,
            layout,
            vk::ShaderStageFlags::VERTEX,
            0,
            bytemuck::bytes_of(clip_from_world),
        );
        device.cmd_draw(cmd, 6, 1, 0, 0);
        device.cmd_end_rendering(cmd);
    }
    // The pass contract: colour writes visible to colour-attachment output, depth readable.
    barrier(
        device,
        cmd,
        color.image,
        vk::ImageAspectFlags::COLOR,
        (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
        (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_READ | A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
    );
    barrier(
        device,
        cmd,
        depth.image,
        vk::ImageAspectFlags::DEPTH,
        (
            S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
            A::DEPTH_STENCIL_ATTACHMENT_WRITE,
            L::DEPTH_ATTACHMENT_OPTIMAL,
        ),
        (
            S::FRAGMENT_SHADER,
            A::SHADER_SAMPLED_READ,
            L::DEPTH_READ_ONLY_OPTIMAL,
        ),
    );
}

/// Records the copy of the colour target (after the pass) into `readback`, visible to the host.
fn record_readback(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    image: vk::Image,
    readback: vk::Buffer,
) {
    use vk::{AccessFlags2 as A, ImageLayout as L, PipelineStageFlags2 as S};
    barrier(
        device,
        cmd,
        image,
        vk::ImageAspectFlags::COLOR,
        (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
        (S::COPY, A::TRANSFER_READ, L::TRANSFER_SRC_OPTIMAL),
    );
    let copy = vk::BufferImageCopy::default()
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_extent(vk::Extent3D {
            width: SIZE,
            height: SIZE,
            depth: 1,
        });
    let host_barrier = [vk::MemoryBarrier2::default()
        .src_stage_mask(S::COPY)
        .src_access_mask(A::TRANSFER_WRITE)
        .dst_stage_mask(S::HOST)
        .dst_access_mask(A::HOST_READ)];
    // SAFETY: recording with live objects; layouts as set by the barriers above.
    unsafe {
        device.cmd_copy_image_to_buffer(cmd, image, L::TRANSFER_SRC_OPTIMAL, readback, &[copy]);
        device.cmd_pipeline_barrier2(
            cmd,
            &vk::DependencyInfo::default().memory_barriers(&host_barrier),
        );
    }
}

const QUAD_VS: &str = r#"#version 460
layout(push_constant) uniform Push { mat4 clip_from_world; } pc;
// A quad in the plane z = 0 covering x in [-0.7, 0] and y in [-0.7, 0.7] (the image's left half).
void main() {
    vec2 corners[6] = vec2[6](vec2(-0.7, -0.7), vec2(0.0, -0.7), vec2(0.0, 0.7),
                              vec2(-0.7, -0.7), vec2(0.0, 0.7), vec2(-0.7, 0.7));
    gl_Position = pc.clip_from_world * vec4(corners[gl_VertexIndex], 0.0, 1.0);
}
"#;

const QUAD_FS: &str = r#"#version 460
layout(location = 0) out vec4 color;
void main() { color = vec4(QUAD_R, QUAD_G, QUAD_B, 1.0); }
"#;

struct HostImage {
    image: vk::Image,
    view: vk::ImageView,
    allocation: Option<Allocation>,
}

fn create_image(
    device: &ash::Device,
    allocator: &Mutex<Allocator>,
    format: vk::Format,
    usage: vk::ImageUsageFlags,
    aspect: vk::ImageAspectFlags,
) -> Result<HostImage, BoxError> {
    let info = vk::ImageCreateInfo::default()
        .image_type(vk::ImageType::TYPE_2D)
        .format(format)
        .extent(vk::Extent3D {
            width: SIZE,
            height: SIZE,
            depth: 1,
        })
        .mip_levels(1)
        .array_layers(1)
        .samples(vk::SampleCountFlags::TYPE_1)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(usage);
    // SAFETY: valid create info on the host's live device.
    let image = unsafe { device.create_image(&info, None) }?;
    // SAFETY: `image` was just created.
    let requirements = unsafe { device.get_image_memory_requirements(image) };
    let allocation = allocator.lock().unwrap().allocate(&AllocationCreateDesc {
        name: "host image",
        requirements,
        location: MemoryLocation::GpuOnly,
        linear: false,
        allocation_scheme: AllocationScheme::GpuAllocatorManaged,
    })?;
    // SAFETY: memory from an allocation made for these requirements.
    unsafe { device.bind_image_memory(image, allocation.memory(), allocation.offset()) }?;
    let view_info = vk::ImageViewCreateInfo::default()
        .image(image)
        .view_type(vk::ImageViewType::TYPE_2D)
        .format(format)
        .subresource_range(vk::ImageSubresourceRange {
            aspect_mask: aspect,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        });
    // SAFETY: the image is bound.
    let view = unsafe { device.create_image_view(&view_info, None) }?;
    Ok(HostImage {
        image,
        view,
        allocation: Some(allocation),
    })
}

#[allow(clippy::too_many_arguments)] // reason: a barrier spelled out, as hosts write them.
fn barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    image: vk::Image,
    aspect: vk::ImageAspectFlags,
    (src_stage, src_access, old): (vk::PipelineStageFlags2, vk::AccessFlags2, vk::ImageLayout),
    (dst_stage, dst_access, new): (vk::PipelineStageFlags2, vk::AccessFlags2, vk::ImageLayout),
) {
    let b = [vk::ImageMemoryBarrier2::default()
        .src_stage_mask(src_stage)
        .src_access_mask(src_access)
        .old_layout(old)
        .dst_stage_mask(dst_stage)
        .dst_access_mask(dst_access)
        .new_layout(new)
        .image(image)
        .subresource_range(vk::ImageSubresourceRange {
            aspect_mask: aspect,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        })];
    // SAFETY: `cmd` is recording.
    unsafe {
        device.cmd_pipeline_barrier2(
            cmd,
            &vk::DependencyInfo::default().image_memory_barriers(&b),
        )
    };
}

/// The scene's volume: 32^3 voxels of constant value 0.5 (with the `constant` transfer function:
/// white, opacity 0.1 per voxel).
pub fn volume() -> Volume {
    Volume::new(
        UVec3::splat(32),
        Vec3::ONE,
        VoxelData::F32(vec![0.5; 32 * 32 * 32]),
    )
    .expect("valid volume")
}

/// Creates the host, draws the quad and the volume (a plain 3D texture), reads the image back.
pub fn run() -> Result<HostReport, BoxError> {
    run_scene(Scene::Volume, ModelTransform::default())
}

/// Creates the host and draws the quad and a brick source larger than its cache along
/// [`brick_path`], the pass planning residency every frame, then the [`camera`] view until the
/// residency settles; reads that last image back. [`HostReport::frames`] holds every frame's
/// report.
pub fn run_bricks() -> Result<HostReport, BoxError> {
    run_scene(Scene::Bricks, ModelTransform::default())
}

/// [`run_bricks`] with the volume turned by `model` in the host's world
/// ([`VolumePass::set_model_transform`]): the host's camera, clip-from-world matrix and depth
/// stay in its world; the pass maps them into the volume's frame.
pub fn run_bricks_with_model(model: ModelTransform) -> Result<HostReport, BoxError> {
    run_scene(Scene::Bricks, model)
}

fn run_scene(scene: Scene, model: ModelTransform) -> Result<HostReport, BoxError> {
    PROBLEMS.store(0, Ordering::SeqCst);
    MESSAGES.lock().unwrap_or_else(|e| e.into_inner()).clear();
    // SAFETY: loading the system Vulkan loader.
    let entry = unsafe { ash::Entry::load() }?;
    let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
    let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
    let extensions = [ash::ext::debug_utils::NAME.as_ptr()];
    let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(host_messenger));
    let sync = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&sync);
    let instance_info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions)
        .push_next(&mut messenger_info)
        .push_next(&mut features);
    // SAFETY: pointers outlive the call.
    let instance = unsafe { entry.create_instance(&instance_info, None) }?;
    let debug = ash::ext::debug_utils::Instance::new(&entry, &instance);
    // SAFETY: valid create info.
    let messenger = unsafe { debug.create_debug_utils_messenger(&messenger_info, None) }?;
    // SAFETY: plain enumeration.
    let physical = unsafe { instance.enumerate_physical_devices() }?[0];
    // SAFETY: `physical` belongs to `instance`.
    let family = unsafe { instance.get_physical_device_queue_family_properties(physical) }
        .iter()
        .position(|f| {
            f.queue_flags
                .contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE)
        })
        .ok_or("no graphics queue")? as u32;
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
        .dynamic_rendering(true)
        .synchronization2(true)
        .maintenance4(true);
    let f10 = vk::PhysicalDeviceFeatures::default().shader_storage_image_extended_formats(true);
    let priorities = [1.0];
    let queues = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    let device_info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queues)
        .enabled_features(&f10)
        .push_next(&mut f13);
    // SAFETY: the features were enabled as the volume pass requires.
    let device = unsafe { instance.create_device(physical, &device_info, None) }?;
    // SAFETY: queue 0 of the created family.
    let queue = unsafe { device.get_device_queue(family, 0) };
    let allocator = Arc::new(Mutex::new(Allocator::new(&AllocatorCreateDesc {
        instance: instance.clone(),
        device: device.clone(),
        physical_device: physical,
        debug_settings: Default::default(),
        buffer_device_address: false,
        allocation_sizes: Default::default(),
    })?));

    let color = create_image(
        &device,
        &allocator,
        vk::Format::R8G8B8A8_UNORM,
        vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
        vk::ImageAspectFlags::COLOR,
    )?;
    let depth = create_image(
        &device,
        &allocator,
        vk::Format::D32_SFLOAT,
        vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT | vk::ImageUsageFlags::SAMPLED,
        vk::ImageAspectFlags::DEPTH,
    )?;
    let readback_info = vk::BufferCreateInfo::default()
        .size((SIZE * SIZE * 4) as u64)
        .usage(vk::BufferUsageFlags::TRANSFER_DST);
    // SAFETY: valid create info.
    let readback = unsafe { device.create_buffer(&readback_info, None) }?;
    // SAFETY: `readback` was just created.
    let requirements = unsafe { device.get_buffer_memory_requirements(readback) };
    let mut readback_memory = Some(allocator.lock().unwrap().allocate(&AllocationCreateDesc {
        name: "host readback",
        requirements,
        location: MemoryLocation::GpuToCpu,
        linear: true,
        allocation_scheme: AllocationScheme::GpuAllocatorManaged,
    })?);
    let memory = readback_memory.as_ref().expect("allocated");
    // SAFETY: memory from an allocation made for these requirements.
    unsafe { device.bind_buffer_memory(readback, memory.memory(), memory.offset()) }?;

    // The host's quad pipeline (depth test + write).
    let quad_defines = [
        ("QUAD_R", QUAD_COLOR[0].to_string()),
        ("QUAD_G", QUAD_COLOR[1].to_string()),
        ("QUAD_B", QUAD_COLOR[2].to_string()),
    ];
    let vs = compile_source("quad.vert", QUAD_VS, ShaderStage::Vertex, &[])?;
    let fs = compile_source("quad.frag", QUAD_FS, ShaderStage::Fragment, &quad_defines)?;
    // SAFETY: SPIR-V from shaderc.
    let vs_module = unsafe {
        device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&vs), None)
    }?;
    // SAFETY: as above.
    let fs_module = unsafe {
        device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&fs), None)
    }?;
    let push_range = [vk::PushConstantRange {
        stage_flags: vk::ShaderStageFlags::VERTEX,
        offset: 0,
        size: 64,
    }];
    // SAFETY: valid create info.
    let layout = unsafe {
        device.create_pipeline_layout(
            &vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&push_range),
            None,
        )
    }?;
    let stages = [
        vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::VERTEX)
            .module(vs_module)
            .name(c"main"),
        vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::FRAGMENT)
            .module(fs_module)
            .name(c"main"),
    ];
    let vertex_input = vk::PipelineVertexInputStateCreateInfo::default();
    let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
        .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
    let viewport_state = vk::PipelineViewportStateCreateInfo::default()
        .viewport_count(1)
        .scissor_count(1);
    let raster = vk::PipelineRasterizationStateCreateInfo::default()
        .cull_mode(vk::CullModeFlags::NONE)
        .line_width(1.0);
    let multisample = vk::PipelineMultisampleStateCreateInfo::default()
        .rasterization_samples(vk::SampleCountFlags::TYPE_1);
    let depth_state = vk::PipelineDepthStencilStateCreateInfo::default()
        .depth_test_enable(true)
        .depth_write_enable(true)
        .depth_compare_op(vk::CompareOp::LESS);
    let blend_attachments = [vk::PipelineColorBlendAttachmentState::default()
        .color_write_mask(vk::ColorComponentFlags::RGBA)];
    let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachments);
    let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
    let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
    let color_formats = [vk::Format::R8G8B8A8_UNORM];
    let mut rendering = vk::PipelineRenderingCreateInfo::default()
        .color_attachment_formats(&color_formats)
        .depth_attachment_format(vk::Format::D32_SFLOAT);
    let pipeline_info = vk::GraphicsPipelineCreateInfo::default()
        .stages(&stages)
        .vertex_input_state(&vertex_input)
        .input_assembly_state(&assembly)
        .viewport_state(&viewport_state)
        .rasterization_state(&raster)
        .multisample_state(&multisample)
        .depth_stencil_state(&depth_state)
        .color_blend_state(&blend)
        .dynamic_state(&dynamic)
        .layout(layout)
        .push_next(&mut rendering);
    // SAFETY: every pointer in the create info outlives the call.
    let pipeline = unsafe {
        device.create_graphics_pipelines(vk::PipelineCache::null(), &[pipeline_info], None)
    }
    .map_err(|(_, e)| e)?[0];

    // Embed the volume pass: it borrows the host's objects.
    // SAFETY: the device was created from this instance and physical device with the features
    // the pass needs; everything outlives `ctx` and `pass` (dropped before the host tears down).
    let ctx = unsafe {
        GpuContext::from_host(HostDevice {
            entry: entry.clone(),
            instance: instance.clone(),
            physical_device: physical,
            device: device.clone(),
            queue_family: family,
            queue,
            allocator: Some(allocator.clone()),
        })
    }?;
    let mut pass = VolumePass::new(
        &ctx,
        PassDesc {
            color_format: vk::Format::R8G8B8A8_UNORM,
            frames_in_flight: FRAMES_IN_FLIGHT as u32,
        },
    )?;
    pass.set_transfer_function(&TransferFunction::preset(TfPreset::ConstantWhite));
    pass.set_model_transform(model);
    match scene {
        Scene::Volume => pass.set_source(VolumeSource::Volume(&volume()))?,
        Scene::Bricks => {
            // A brick source twice the size of its cache: the pass plans residency from the
            // camera every frame under the cache and upload budgets.
            pass.set_source(VolumeSource::Mixed {
                volume: Arc::new(brick_volume()),
                config: MixedConfig {
                    brick_size: BRICK_SIZE,
                    filter: DownsampleFilter::Mean2,
                    cache_budget_bytes: BRICK_CACHE_BUDGET,
                    transition: Transition::Smooth,
                    max_levels: 0,
                },
            })?;
            pass.set_residency_config(ResidencyConfig {
                upload_bytes_per_frame: BRICK_UPLOAD_BUDGET,
                ..ResidencyConfig::default()
            });
        }
    }
    let settings = RenderSettings {
        early_termination: 2.0,
        ..RenderSettings::default()
    };

    // SAFETY: plain object creation on the host's device.
    let pool = unsafe {
        device.create_command_pool(
            &vk::CommandPoolCreateInfo::default()
                .queue_family_index(family)
                .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
            None,
        )
    }?;
    // SAFETY: the pool was just created.
    let cmds = unsafe {
        device.allocate_command_buffers(
            &vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .command_buffer_count(FRAMES_IN_FLIGHT as u32),
        )
    }?;
    let mut fences = Vec::with_capacity(FRAMES_IN_FLIGHT);
    for _ in 0..FRAMES_IN_FLIGHT {
        // SAFETY: plain object creation.
        fences.push(unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }?);
    }
    let mut in_flight = [false; FRAMES_IN_FLIGHT];
    let mut frames = Vec::new();
    let path = match scene {
        Scene::Volume => Vec::new(),
        Scene::Bricks => brick_path(),
    };
    let mut frame = 0usize;
    loop {
        let slot = frame % FRAMES_IN_FLIGHT;
        if in_flight[slot] {
            // The slot's last frame is done: its resources may be recorded again.
            // SAFETY: the fence was submitted with the slot's last frame.
            unsafe {
                device.wait_for_fences(&[fences[slot]], true, u64::MAX)?;
                device.reset_fences(&[fences[slot]])?;
            }
            in_flight[slot] = false;
            if frame == 1 || scene == Scene::Bricks && frame.is_multiple_of(8) {
                println!(
                    "volume pass GPU timings (frame {}): {:?}",
                    frame - FRAMES_IN_FLIGHT,
                    pass.timings(slot)?
                );
            }
        }
        // The camera path, then the still view until the residency settles.
        let camera = path.get(frame).copied().unwrap_or_else(camera);
        let clip_from_world = clip_from_world_of(&camera);
        let last = match scene {
            Scene::Volume => true,
            Scene::Bricks => {
                let report = pass.update(&camera, SIZE, SIZE, &settings)?;
                println!("{}", summary(frame, &report));
                // Settled: the frame draws the residency the still view wants, nothing waits.
                let settled = frame >= path.len()
                    && report.plan.is_settled()
                    && report.plan.waiting_for_source == 0
                    && report.plan.drawn_absent == 0;
                frames.push(report);
                if !settled && frame >= path.len() + MAX_SETTLE_FRAMES {
                    return Err(format!(
                        "the residency did not settle within {MAX_SETTLE_FRAMES} still frames"
                    )
                    .into());
                }
                settled
            }
        };
        let cmd = cmds[slot];
        // SAFETY: the command buffer's last submission completed (fence above).
        check(unsafe { device.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()) })?;
        record_frame(
            &device,
            cmd,
            (&color, &depth),
            (pipeline, layout),
            &clip_from_world,
        );
        pass.record(
            cmd,
            slot,
            &PassTarget {
                view: color.view,
                extent: vk::Extent2D {
                    width: SIZE,
                    height: SIZE,
                },
                load: TargetLoad::Load,
                depth: Some(HostDepth {
                    view: depth.view,
                    layout: vk::ImageLayout::DEPTH_READ_ONLY_OPTIMAL,
                    clip_from_world,
                }),
            },
            &camera,
            &settings,
        )?;
        if last {
            record_readback(&device, cmd, color.image, readback);
        }
        check(unsafe { device.end_command_buffer(cmd) })?;
        let infos = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
        let submit = [vk::SubmitInfo2::default().command_buffer_infos(&infos)];
        // SAFETY: the command buffer is complete; the fence is unsignalled.
        unsafe { device.queue_submit2(queue, &submit, fences[slot]) }?;
        in_flight[slot] = true;
        frame += 1;
        if last {
            break;
        }
    }
    // SAFETY: every fence waited on was submitted.
    unsafe {
        for (fence, busy) in fences.iter().zip(in_flight) {
            if busy {
                device.wait_for_fences(&[*fence], true, u64::MAX)?;
            }
        }
    }
    let bytes = readback_memory
        .as_ref()
        .expect("allocated")
        .mapped_slice()
        .ok_or("readback not mapped")?;
    let pixels: Vec<[u8; 4]> = bytes
        .chunks_exact(4)
        .map(|p| [p[0], p[1], p[2], p[3]])
        .collect();

    // Teardown: the pass and context first (the GPU is idle: we waited), then the host.
    drop(pass);
    drop(ctx);
    // SAFETY: the GPU finished all work; objects are destroyed in reverse creation order.
    unsafe {
        for fence in fences {
            device.destroy_fence(fence, None);
        }
        device.destroy_command_pool(pool, None);
        device.destroy_pipeline(pipeline, None);
        device.destroy_pipeline_layout(layout, None);
        device.destroy_shader_module(vs_module, None);
        device.destroy_shader_module(fs_module, None);
        device.destroy_buffer(readback, None);
        for img in [&color, &depth] {
            device.destroy_image_view(img.view, None);
            device.destroy_image(img.image, None);
        }
    }
    let mut alloc = allocator.lock().unwrap();
    alloc.free(readback_memory.take().expect("allocated"))?;
    for mut img in [color, depth] {
        alloc.free(img.allocation.take().expect("allocated"))?;
    }
    drop(alloc);
    drop(allocator);
    // SAFETY: nothing uses the device or instance any more.
    unsafe {
        device.destroy_device(None);
        debug.destroy_debug_utils_messenger(messenger, None);
        instance.destroy_instance(None);
    }
    let messages = MESSAGES.lock().unwrap_or_else(|e| e.into_inner()).clone();
    Ok(HostReport {
        pixels,
        validation_problems: PROBLEMS.load(Ordering::SeqCst),
        messages,
        frames,
    })
}

/// Expected pixel of the composite: premultiplied white volume of `voxels` voxels (opacity 0.1
/// each) over `behind`.
pub fn expected(voxels: f32, behind: [f32; 3]) -> Vec4 {
    let alpha = 1.0 - 0.9f32.powf(voxels);
    Vec4::new(
        alpha + (1.0 - alpha) * behind[0],
        alpha + (1.0 - alpha) * behind[1],
        alpha + (1.0 - alpha) * behind[2],
        1.0,
    )
}

#[allow(dead_code)] // reason: the test includes this file as a module and calls `run` itself.
fn main() -> Result<(), BoxError> {
    let output = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/embed.png".into());
    let output = std::path::Path::new(&output);
    if let Some(parent) = output.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let mut failed = false;
    let parts = [
        ("volume", 32.0, output.to_path_buf()),
        (
            "bricks",
            32.0,
            output.with_file_name(format!(
                "{}-bricks.png",
                output
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .unwrap_or("embed")
            )),
        ),
    ];
    for (name, voxels, path) in parts {
        let report = if name == "volume" {
            run()?
        } else {
            run_bricks()?
        };
        let img = image::RgbaImage::from_fn(SIZE, SIZE, |x, y| {
            image::Rgba(report.pixels[(y * SIZE + x) as usize])
        });
        img.save(&path)?;
        let check = check_composite(&report.pixels, voxels).and_then(|()| {
            if name == "bricks" {
                check_bricks(&report.frames)
            } else {
                Ok(())
            }
        });
        println!(
            "{name}: wrote {}; validation problems: {}; composite {}",
            path.display(),
            report.validation_problems,
            match &check {
                Ok(()) => "matches the analytic expectation, budgets held".to_string(),
                Err(e) => format!("WRONG: {e}"),
            }
        );
        for m in &report.messages {
            eprintln!("  {m}");
        }
        if name == "bricks" {
            let uploading = report
                .frames
                .iter()
                .filter(|r| r.residency.uploaded_bricks > 0)
                .count();
            println!(
                "bricks: {} frames ({} along the path), {uploading} uploaded, settled at the last",
                report.frames.len(),
                PATH_FRAMES
            );
        }
        failed |= check.is_err() || report.validation_problems > 0;
    }
    if failed {
        return Err("the composite or validation failed (see above)".into());
    }
    Ok(())
}
