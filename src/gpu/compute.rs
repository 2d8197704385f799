//! A small compute pipeline: one descriptor set layout of storage/sampled resources (a set per
//! frame in flight), push constants, one shader. The fixup pass and the field probe use it.

use super::context::DeviceShared;
use super::descriptors::DescriptorBundle;
use super::shaders::{compile, ShaderStage};
use crate::error::{Result, VkResultExt};
use ash::vk;
use std::sync::Arc;

/// One binding of a compute pipeline's descriptor set, and what it points at.
#[derive(Copy, Clone, Debug)]
pub(crate) enum ComputeResource {
    /// A storage image in GENERAL layout.
    StorageImage(vk::ImageView),
    /// A combined image sampler in SHADER_READ_ONLY_OPTIMAL layout.
    SampledImage(vk::ImageView, vk::Sampler),
    /// A whole storage buffer.
    StorageBuffer(vk::Buffer),
}

impl ComputeResource {
    fn descriptor_type(self) -> vk::DescriptorType {
        match self {
            ComputeResource::StorageImage(_) => vk::DescriptorType::STORAGE_IMAGE,
            ComputeResource::SampledImage(..) => vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ComputeResource::StorageBuffer(_) => vk::DescriptorType::STORAGE_BUFFER,
        }
    }
}

/// A compute pipeline; descriptor sets (one per frame slot) have the bindings given at creation.
pub(crate) struct ComputePipeline {
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    descriptors: DescriptorBundle,
    bindings: Vec<(u32, vk::DescriptorType)>,
    shared: Arc<DeviceShared>,
}

impl ComputePipeline {
    /// Compiles `shader` (a file under `glsl/`) with `defines`; `bindings` lists (binding number,
    /// descriptor type) of its set (numbers from [`super::shared_defs`]).
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        shader: &str,
        defines: &[(&str, String)],
        bindings: &[(u32, vk::DescriptorType)],
        push_constant_bytes: u32,
        sets: u32,
    ) -> Result<Self> {
        let code = compile(shader, ShaderStage::Compute, defines)?;
        let device = &shared.device;
        let descriptors =
            DescriptorBundle::new(shared, bindings, vk::ShaderStageFlags::COMPUTE, sets)?;
        let ranges = [vk::PushConstantRange {
            stage_flags: vk::ShaderStageFlags::COMPUTE,
            offset: 0,
            size: push_constant_bytes,
        }];
        let set_layouts = [descriptors.set_layout];
        // SAFETY: valid create info on a live device.
        let layout = unsafe {
            device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(&set_layouts)
                    .push_constant_ranges(&ranges),
                None,
            )
        }
        .vk("vkCreatePipelineLayout")?;
        let mut this = Self {
            pipeline: vk::Pipeline::null(),
            layout,
            descriptors,
            bindings: bindings.to_vec(),
            shared: shared.clone(),
        };
        // SAFETY: valid create infos on a live device; the module is destroyed before returning.
        unsafe {
            let module = device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
                .vk("vkCreateShaderModule")?;
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(c"main");
            let info = vk::ComputePipelineCreateInfo::default()
                .stage(stage)
                .layout(this.layout);
            let result = device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None);
            device.destroy_shader_module(module, None);
            this.pipeline = result.map_err(|(_, result)| crate::Error::Vulkan {
                call: "vkCreateComputePipelines",
                result,
            })?[0];
        }
        Ok(this)
    }

    /// Points descriptor set `set` at `resources`: (binding number, resource), one per binding
    /// given at creation, of the kind given there. The set must not be in use by pending GPU
    /// work.
    pub(crate) fn write_descriptors(&self, set: usize, resources: &[(u32, ComputeResource)]) {
        assert_eq!(
            resources.len(),
            self.bindings.len(),
            "one resource per binding"
        );
        let mut image_infos = Vec::with_capacity(resources.len());
        let mut buffer_infos = Vec::with_capacity(resources.len());
        for (_, r) in resources {
            image_infos.push(match *r {
                ComputeResource::StorageImage(view) => [vk::DescriptorImageInfo {
                    sampler: vk::Sampler::null(),
                    image_view: view,
                    image_layout: vk::ImageLayout::GENERAL,
                }],
                ComputeResource::SampledImage(view, sampler) => [vk::DescriptorImageInfo {
                    sampler,
                    image_view: view,
                    image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                }],
                ComputeResource::StorageBuffer(_) => [vk::DescriptorImageInfo::default()],
            });
            buffer_infos.push(match *r {
                ComputeResource::StorageBuffer(buffer) => [vk::DescriptorBufferInfo {
                    buffer,
                    offset: 0,
                    range: vk::WHOLE_SIZE,
                }],
                _ => [vk::DescriptorBufferInfo::default()],
            });
        }
        let writes: Vec<_> = resources
            .iter()
            .enumerate()
            .map(|(i, (binding, r))| {
                assert!(
                    self.bindings.contains(&(*binding, r.descriptor_type())),
                    "binding {binding} kind"
                );
                let write = vk::WriteDescriptorSet::default()
                    .dst_set(self.descriptors.sets[set])
                    .dst_binding(*binding)
                    .descriptor_type(r.descriptor_type());
                match r {
                    ComputeResource::StorageBuffer(_) => write.buffer_info(&buffer_infos[i]),
                    _ => write.image_info(&image_infos[i]),
                }
            })
            .collect();
        // SAFETY: all handles are live; the caller guarantees no pending GPU use of the set.
        unsafe { self.shared.device.update_descriptor_sets(&writes, &[]) };
    }

    /// Records bind + push constants + dispatch.
    pub(crate) fn record_dispatch(
        &self,
        cmd: vk::CommandBuffer,
        set: usize,
        push_constants: &[u8],
        groups: [u32; 3],
    ) {
        let device = &self.shared.device;
        // SAFETY: `cmd` is recording; the set was written; the push range matches creation.
        unsafe {
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, self.pipeline);
            device.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::COMPUTE,
                self.layout,
                0,
                &[self.descriptors.sets[set]],
                &[],
            );
            device.cmd_push_constants(
                cmd,
                self.layout,
                vk::ShaderStageFlags::COMPUTE,
                0,
                push_constants,
            );
            device.cmd_dispatch(cmd, groups[0], groups[1], groups[2]);
        }
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        let device = &self.shared.device;
        // SAFETY: owners wait idle before dropping; the pipeline goes before its layout (the
        // descriptor bundle field drops after this); null handles are ignored.
        unsafe {
            device.destroy_pipeline(self.pipeline, None);
            device.destroy_pipeline_layout(self.layout, None);
        }
    }
}
