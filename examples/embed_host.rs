//! A small host engine that embeds the volume pass in its own Vulkan frame.
//!
//! It creates its own instance (validation on), device, gpu-allocator allocator, colour and depth
//! images, draws an opaque quad with depth, then records [`VolumePass::record`] into the same
//! command buffer: the volume composites over the quad and stops at its depth. The composite is
//! written as a PNG. `tests/embed.rs` runs [`run`] and checks the compositing analytically.
//!
//! Run: `cargo run --release --example embed_host -- out/embed.png`

use ash::vk;
use glam::{Mat4, UVec3, Vec3, Vec4};
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};
use gpu_allocator::MemoryLocation;
use mixvol::embed::{HostDepth, PassDesc, PassTarget, TargetLoad, VolumePass, VolumeSource};
use mixvol::gpu::{shaders::compile_source, GpuContext, HostDevice, ShaderStage};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{Volume, VoxelData};
use std::ffi::c_void;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// Image size of the example.
pub const SIZE: u32 = 64;
/// Colour of the opaque quad (linear RGB).
pub const QUAD_COLOR: [f32; 3] = [0.9, 0.2, 0.1];
/// Background clear colour.
pub const BACKGROUND: [f32; 3] = [0.0, 0.0, 0.3];

/// What one run produced.
pub struct HostReport {
    /// RGBA8 pixels, row-major from the top-left.
    pub pixels: Vec<[u8; 4]>,
    /// Validation warnings and errors the host's messenger received.
    pub validation_problems: usize,
    /// The messages themselves.
    pub messages: Vec<String>,
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

/// `clip_from_world` of [`camera`] in Vulkan conventions (y down, depth 0..1), near 0.5, far 4.
pub fn clip_from_world() -> Mat4 {
    let c = camera();
    let view = Mat4::look_at_rh(c.eye, c.target, c.up);
    let half = 0.6;
    let proj = Mat4::orthographic_rh(-half, half, -half, half, 0.5, 4.0);
    Mat4::from_scale(Vec3::new(1.0, -1.0, 1.0)) * proj * view
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

/// Creates the host, draws the quad and the volume, reads the image back.
pub fn run() -> Result<HostReport, BoxError> {
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
            frames_in_flight: 2,
        },
    )?;
    pass.set_source(VolumeSource::Volume(&volume()))?;
    pass.set_transfer_function(&TransferFunction::preset(TfPreset::ConstantWhite));
    let settings = RenderSettings {
        early_termination: 2.0,
        ..RenderSettings::default()
    };

    // SAFETY: plain object creation on the host's device.
    let pool = unsafe {
        device.create_command_pool(
            &vk::CommandPoolCreateInfo::default().queue_family_index(family),
            None,
        )
    }?;
    // SAFETY: the pool was just created.
    let cmd = unsafe {
        device.allocate_command_buffers(
            &vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .command_buffer_count(1),
        )
    }?[0];
    // SAFETY: plain object creation.
    let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }?;
    // SAFETY: the command buffer is new.
    check(unsafe { device.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()) })?;
    use vk::{AccessFlags2 as A, ImageLayout as L, PipelineStageFlags2 as S};
    barrier(
        &device,
        cmd,
        color.image,
        vk::ImageAspectFlags::COLOR,
        (S::NONE, A::NONE, L::UNDEFINED),
        (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
    );
    barrier(
        &device,
        cmd,
        depth.image,
        vk::ImageAspectFlags::DEPTH,
        (S::NONE, A::NONE, L::UNDEFINED),
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
    let clip_from_world = clip_from_world();
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
            bytemuck::bytes_of(&clip_from_world),
        );
        device.cmd_draw(cmd, 6, 1, 0, 0);
        device.cmd_end_rendering(cmd);
    }
    // The pass contract: colour writes visible to colour-attachment output, depth readable.
    barrier(
        &device,
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
        &device,
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
    pass.record(
        cmd,
        0,
        &PassTarget {
            view: color.view,
            extent: area.extent,
            load: TargetLoad::Load,
            depth: Some(HostDepth {
                view: depth.view,
                layout: L::DEPTH_READ_ONLY_OPTIMAL,
                clip_from_world,
            }),
        },
        &camera(),
        &settings,
    )?;
    barrier(
        &device,
        cmd,
        color.image,
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
        device.cmd_copy_image_to_buffer(
            cmd,
            color.image,
            L::TRANSFER_SRC_OPTIMAL,
            readback,
            &[copy],
        );
        device.cmd_pipeline_barrier2(
            cmd,
            &vk::DependencyInfo::default().memory_barriers(&host_barrier),
        );
    }
    check(unsafe { device.end_command_buffer(cmd) })?;
    let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
    let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmds)];
    // SAFETY: the command buffer is complete; the host submits and waits, as hosts do.
    unsafe {
        device.queue_submit2(queue, &submit, fence)?;
        device.wait_for_fences(&[fence], true, u64::MAX)?;
    }
    let timings = pass.timings(0)?;
    println!("volume pass GPU timings: {timings:?}");
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
        device.destroy_fence(fence, None);
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
    let report = run()?;
    if let Some(parent) = std::path::Path::new(&output).parent() {
        std::fs::create_dir_all(parent)?;
    }
    let img = image::RgbaImage::from_fn(SIZE, SIZE, |x, y| {
        image::Rgba(report.pixels[(y * SIZE + x) as usize])
    });
    img.save(&output)?;
    println!(
        "wrote {output}; validation problems: {}",
        report.validation_problems
    );
    for m in &report.messages {
        eprintln!("  {m}");
    }
    Ok(())
}
