//! The ray-cast graphics pipeline: a full-screen triangle whose fragment shader casts one ray per
//! pixel (dynamic rendering, no render pass objects).

use super::context::DeviceShared;
use super::descriptors::{DescriptorBundle, Sampler};
use super::shaders::{compile, ShaderStage};
use super::shared_defs::{
    BINDING_HOST_DEPTH, BINDING_LAYOUT_TABLE, BINDING_NEIGHBOUR_TABLE, BINDING_PARAMS,
    BINDING_PREINTEGRATION, BINDING_TF, BINDING_VOLUME,
};
use crate::error::{Result, VkResultExt};
use crate::optics::SamplingModel;
use crate::scene::{ModeKind, RayFeatures};
use ash::vk;
use std::sync::Arc;

/// Which ray-cast shader variant a pipeline contains: a scene compiles only what it uses.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, Default)]
pub struct RaycastVariant {
    /// Read a brick cache through the layout table (otherwise one plain 3D volume texture).
    pub mixed_resolution: bool,
    /// Add the C0 transition blend (mixed resolution only).
    pub smooth_transitions: bool,
    /// Some bricks are absent and rays jump over them (mixed resolution only); without it every
    /// brick must be resident.
    pub absent_bricks: bool,
    /// Stop rays at a host depth buffer (embedding).
    pub host_depth: bool,
    /// What each sample does: mode, shading, gradient opacity, sampling model, pre-integration.
    pub features: RayFeatures,
    /// The volume is pre-classified RGBA (single resolution, DVR).
    pub rgba_volume: bool,
}

impl RaycastVariant {
    /// The feature switches the variant is compiled with (the shared constants come from
    /// [`super::shared_defs`], which every compile adds).
    pub(crate) fn defines(self) -> Vec<(&'static str, String)> {
        let mut defines = Vec::new();
        if self.mixed_resolution {
            defines.push(("MIXED_RESOLUTION", "1".into()));
            if self.smooth_transitions {
                defines.push(("SMOOTH_TRANSITIONS", "1".into()));
            }
            if self.absent_bricks {
                defines.push(("ABSENT_BRICKS", "1".into()));
            }
        }
        if self.host_depth {
            defines.push(("HOST_DEPTH", "1".into()));
        }
        if self.rgba_volume {
            defines.push(("RGBA_VOLUME", "1".into()));
        }
        let f = self.features;
        let mode = match f.mode {
            ModeKind::Dvr => "MODE_DVR",
            ModeKind::Iso => "MODE_ISO",
            ModeKind::Mip => "MODE_MIP",
            ModeKind::Mida => "MODE_MIDA",
        };
        defines.push((mode, "1".into()));
        for (on, name) in [
            (f.shading, "SHADING"),
            (f.gradient_opacity, "GRADIENT_OPACITY"),
            (
                f.sampling_model == SamplingModel::Extinction,
                "EXTINCTION_MODEL",
            ),
            (f.preintegrated, "PREINTEGRATED"),
            (f.tricubic && !self.smooth_transitions, "TRICUBIC"),
            (f.coarse_low_res && self.mixed_resolution, "COARSE_LOW_RES"),
            (f.clip_planes, "CLIP_PLANES"),
        ] {
            if on {
                defines.push((name, "1".into()));
            }
        }
        defines
    }
}

/// Where one ray-cast draw renders: a colour view in `COLOR_ATTACHMENT_OPTIMAL`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub(crate) struct DrawTarget {
    /// The colour view.
    pub(crate) view: vk::ImageView,
    /// Its size in pixels (render area, viewport and scissor).
    pub(crate) extent: vk::Extent2D,
    /// `None`: keep (load) the content; `Some(c)`: clear to premultiplied `c` first.
    pub(crate) clear: Option<[f32; 4]>,
}

/// Pipeline, layouts, sampler and the one descriptor set the ray-caster binds.
pub(crate) struct RaycastPipeline {
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    descriptors: DescriptorBundle,
    sampler: Sampler,
    depth_sampler: Sampler,
    pub(crate) variant: RaycastVariant,
    shared: Arc<DeviceShared>,
}

impl RaycastPipeline {
    /// Builds the variant for `color_format` targets with `sets` descriptor sets (one per frame
    /// slot) through `cache`. The pipeline blends premultiplied colour *over* what the target
    /// holds.
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        color_format: vk::Format,
        variant: RaycastVariant,
        sets: u32,
        cache: vk::PipelineCache,
    ) -> Result<Self> {
        let defines = variant.defines();
        let vert = compile("raycast.vert", ShaderStage::Vertex, &defines)?;
        let frag = compile("raycast.frag", ShaderStage::Fragment, &defines)?;
        let device = &shared.device;
        let mut bindings = vec![
            (BINDING_PARAMS, vk::DescriptorType::UNIFORM_BUFFER),
            (BINDING_VOLUME, vk::DescriptorType::COMBINED_IMAGE_SAMPLER),
            (BINDING_TF, vk::DescriptorType::COMBINED_IMAGE_SAMPLER),
        ];
        if variant.mixed_resolution {
            bindings.push((BINDING_LAYOUT_TABLE, vk::DescriptorType::STORAGE_BUFFER));
            bindings.push((BINDING_NEIGHBOUR_TABLE, vk::DescriptorType::STORAGE_BUFFER));
        }
        if variant.host_depth {
            bindings.push((
                BINDING_HOST_DEPTH,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ));
        }
        if variant.features.preintegrated {
            bindings.push((
                BINDING_PREINTEGRATION,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ));
        }
        let descriptors =
            DescriptorBundle::new(shared, &bindings, vk::ShaderStageFlags::FRAGMENT, sets)?;
        let sampler = Sampler::linear_clamp(shared)?;
        let depth_sampler = Sampler::nearest_clamp(shared)?;
        let set_layouts = [descriptors.set_layout];
        // SAFETY: valid create info on a live device.
        let layout = unsafe {
            device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts),
                None,
            )
        }
        .vk("vkCreatePipelineLayout")?;
        let mut this = Self {
            pipeline: vk::Pipeline::null(),
            layout,
            descriptors,
            sampler,
            depth_sampler,
            variant,
            shared: shared.clone(),
        };
        // SAFETY: `this.layout` is a live pipeline layout of `device`; `cache` is null or a live
        // pipeline cache of `device`.
        this.pipeline = unsafe {
            Self::create_pipeline(device, this.layout, color_format, &vert, &frag, cache)
        }?;
        Ok(this)
    }

    /// # Safety
    /// `layout` must be a live pipeline layout of `device`, `cache` null or a live pipeline
    /// cache of `device` not used by another thread meanwhile.
    unsafe fn create_pipeline(
        device: &ash::Device,
        layout: vk::PipelineLayout,
        color_format: vk::Format,
        vert: &[u32],
        frag: &[u32],
        cache: vk::PipelineCache,
    ) -> Result<vk::Pipeline> {
        // SAFETY: SPIR-V words from shaderc; modules are destroyed before returning.
        unsafe {
            let vert_module = device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(vert), None)
                .vk("vkCreateShaderModule")?;
            let frag_module = match device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(frag), None)
            {
                Ok(m) => m,
                Err(result) => {
                    device.destroy_shader_module(vert_module, None);
                    return Err(crate::Error::Vulkan {
                        call: "vkCreateShaderModule",
                        result,
                    });
                }
            };
            let stages = [
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::VERTEX)
                    .module(vert_module)
                    .name(c"main"),
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::FRAGMENT)
                    .module(frag_module)
                    .name(c"main"),
            ];
            let vertex_input = vk::PipelineVertexInputStateCreateInfo::default();
            let input_assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
                .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
            let viewport = vk::PipelineViewportStateCreateInfo::default()
                .viewport_count(1)
                .scissor_count(1);
            let raster = vk::PipelineRasterizationStateCreateInfo::default()
                .polygon_mode(vk::PolygonMode::FILL)
                .cull_mode(vk::CullModeFlags::NONE)
                .line_width(1.0);
            let multisample = vk::PipelineMultisampleStateCreateInfo::default()
                .rasterization_samples(vk::SampleCountFlags::TYPE_1);
            // Premultiplied "over": result = volume + (1 - volume alpha) * target.
            let attachments = [vk::PipelineColorBlendAttachmentState::default()
                .blend_enable(true)
                .src_color_blend_factor(vk::BlendFactor::ONE)
                .dst_color_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                .color_blend_op(vk::BlendOp::ADD)
                .src_alpha_blend_factor(vk::BlendFactor::ONE)
                .dst_alpha_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                .alpha_blend_op(vk::BlendOp::ADD)
                .color_write_mask(vk::ColorComponentFlags::RGBA)];
            let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&attachments);
            let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
            let dynamic =
                vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
            let formats = [color_format];
            let mut rendering =
                vk::PipelineRenderingCreateInfo::default().color_attachment_formats(&formats);
            let info = vk::GraphicsPipelineCreateInfo::default()
                .stages(&stages)
                .vertex_input_state(&vertex_input)
                .input_assembly_state(&input_assembly)
                .viewport_state(&viewport)
                .rasterization_state(&raster)
                .multisample_state(&multisample)
                .color_blend_state(&blend)
                .dynamic_state(&dynamic)
                .layout(layout)
                .push_next(&mut rendering);
            let result = device.create_graphics_pipelines(cache, &[info], None);
            device.destroy_shader_module(vert_module, None);
            device.destroy_shader_module(frag_module, None);
            result
                .map(|p| p[0])
                .map_err(|(_, result)| crate::Error::Vulkan {
                    call: "vkCreateGraphicsPipelines",
                    result,
                })
        }
    }

    /// Points descriptor set `set` at the parameter buffer, the volume (or brick cache), the
    /// transfer function, for mixed resolution the layout and neighbour tables, for host depth
    /// the depth view (in `depth_layout`) and for pre-integration the 2D table. The set must not
    /// be in use by pending GPU work.
    #[allow(clippy::too_many_arguments)] // reason: one argument per binding.
    pub(crate) fn write_descriptors(
        &self,
        set: usize,
        params: vk::Buffer,
        volume_view: vk::ImageView,
        tf_view: vk::ImageView,
        tables: Option<(vk::Buffer, vk::Buffer)>,
        depth: Option<(vk::ImageView, vk::ImageLayout)>,
        preintegration: Option<vk::ImageView>,
    ) {
        let buffer_info = [vk::DescriptorBufferInfo {
            buffer: params,
            offset: 0,
            range: vk::WHOLE_SIZE,
        }];
        let image_info = |view, image_layout| {
            [vk::DescriptorImageInfo {
                sampler: self.sampler.raw,
                image_view: view,
                image_layout,
            }]
        };
        let volume_info = image_info(volume_view, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL);
        let tf_info = image_info(tf_view, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL);
        let preint_info =
            preintegration.map(|view| image_info(view, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL));
        let depth_info = depth.map(|(view, image_layout)| {
            [vk::DescriptorImageInfo {
                sampler: self.depth_sampler.raw,
                image_view: view,
                image_layout,
            }]
        });
        let table_info = |buffer| {
            [vk::DescriptorBufferInfo {
                buffer,
                offset: 0,
                range: vk::WHOLE_SIZE,
            }]
        };
        let (layout_info, neighbour_info) = match tables {
            Some((layout, neighbours)) => (table_info(layout), table_info(neighbours)),
            None => (
                table_info(vk::Buffer::null()),
                table_info(vk::Buffer::null()),
            ),
        };
        let mut writes = vec![
            vk::WriteDescriptorSet::default()
                .dst_set(self.descriptors.sets[set])
                .dst_binding(BINDING_PARAMS)
                .descriptor_type(vk::DescriptorType::UNIFORM_BUFFER)
                .buffer_info(&buffer_info),
            vk::WriteDescriptorSet::default()
                .dst_set(self.descriptors.sets[set])
                .dst_binding(BINDING_VOLUME)
                .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
                .image_info(&volume_info),
            vk::WriteDescriptorSet::default()
                .dst_set(self.descriptors.sets[set])
                .dst_binding(BINDING_TF)
                .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
                .image_info(&tf_info),
        ];
        if self.variant.mixed_resolution && tables.is_some() {
            for (binding, info) in [
                (BINDING_LAYOUT_TABLE, &layout_info),
                (BINDING_NEIGHBOUR_TABLE, &neighbour_info),
            ] {
                writes.push(
                    vk::WriteDescriptorSet::default()
                        .dst_set(self.descriptors.sets[set])
                        .dst_binding(binding)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(info),
                );
            }
        }
        if let (true, Some(info)) = (self.variant.host_depth, &depth_info) {
            writes.push(
                vk::WriteDescriptorSet::default()
                    .dst_set(self.descriptors.sets[set])
                    .dst_binding(BINDING_HOST_DEPTH)
                    .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
                    .image_info(info),
            );
        }
        if let (true, Some(info)) = (self.variant.features.preintegrated, &preint_info) {
            writes.push(
                vk::WriteDescriptorSet::default()
                    .dst_set(self.descriptors.sets[set])
                    .dst_binding(BINDING_PREINTEGRATION)
                    .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
                    .image_info(info),
            );
        }
        // SAFETY: all handles are live; the caller guarantees no pending GPU use of the set.
        unsafe { self.shared.device.update_descriptor_sets(&writes, &[]) };
    }

    /// Records the draw into `cmd` (recording, outside rendering): begins dynamic rendering into
    /// `target`, sets viewport and scissor to its extent, binds the pipeline and descriptor set
    /// `set` (written with [`RaycastPipeline::write_descriptors`]), draws the full-screen
    /// triangle and ends rendering.
    pub(crate) fn record_draw(&self, cmd: vk::CommandBuffer, set: usize, target: &DrawTarget) {
        let (load_op, clear) = match target.clear {
            None => (vk::AttachmentLoadOp::LOAD, [0.0; 4]),
            Some(c) => (vk::AttachmentLoadOp::CLEAR, c),
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
            width: target.extent.width as f32,
            height: target.extent.height as f32,
            min_depth: 0.0,
            max_depth: 1.0,
        };
        let device = &self.shared.device;
        // SAFETY: `cmd` is recording outside a rendering scope (caller contract); the pipeline,
        // its layout and descriptor set `set` are live (owned here); the set was written while
        // not in use by pending work (caller contract of `write_descriptors`).
        unsafe {
            device.cmd_begin_rendering(cmd, &rendering);
            device.cmd_set_viewport(cmd, 0, &[viewport]);
            device.cmd_set_scissor(cmd, 0, &[area]);
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.pipeline);
            device.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::GRAPHICS,
                self.layout,
                0,
                &[self.descriptors.sets[set]],
                &[],
            );
            device.cmd_draw(cmd, 3, 1, 0, 0);
            device.cmd_end_rendering(cmd);
        }
    }
}

impl Drop for RaycastPipeline {
    fn drop(&mut self) {
        let device = &self.shared.device;
        // SAFETY: owners wait idle before dropping; the pipeline goes before its layout (the
        // descriptor bundle and sampler fields drop after this); null handles are ignored.
        unsafe {
            device.destroy_pipeline(self.pipeline, None);
            device.destroy_pipeline_layout(self.layout, None);
        }
    }
}
