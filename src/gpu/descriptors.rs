//! Small owning types shared by the pipelines: a one-set descriptor bundle and a sampler.

use super::context::DeviceShared;
use crate::error::{Result, VkResultExt};
use ash::vk;
use std::sync::Arc;

/// A descriptor set layout with the given `(binding, type)` pairs, a pool, and `count` sets of
/// that layout (one per frame in flight).
pub(crate) struct DescriptorBundle {
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pool: vk::DescriptorPool,
    pub(crate) sets: Vec<vk::DescriptorSet>,
    shared: Arc<DeviceShared>,
}

impl DescriptorBundle {
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        bindings: &[(u32, vk::DescriptorType)],
        stages: vk::ShaderStageFlags,
        count: u32,
    ) -> Result<Self> {
        let device = &shared.device;
        let mut this = Self {
            set_layout: vk::DescriptorSetLayout::null(),
            pool: vk::DescriptorPool::null(),
            sets: Vec::new(),
            shared: shared.clone(),
        };
        let layout_bindings: Vec<_> = bindings
            .iter()
            .map(|(binding, ty)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(*binding)
                    .descriptor_type(*ty)
                    .descriptor_count(1)
                    .stage_flags(stages)
            })
            .collect();
        let pool_sizes: Vec<_> = bindings
            .iter()
            .map(|(_, ty)| vk::DescriptorPoolSize {
                ty: *ty,
                descriptor_count: count,
            })
            .collect();
        // SAFETY: valid create infos on a live device; handles are stored in `this` at once so
        // Drop releases them on a later error.
        unsafe {
            this.set_layout = device
                .create_descriptor_set_layout(
                    &vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings),
                    None,
                )
                .vk("vkCreateDescriptorSetLayout")?;
            this.pool = device
                .create_descriptor_pool(
                    &vk::DescriptorPoolCreateInfo::default()
                        .max_sets(count)
                        .pool_sizes(&pool_sizes),
                    None,
                )
                .vk("vkCreateDescriptorPool")?;
            let set_layouts = vec![this.set_layout; count as usize];
            this.sets = device
                .allocate_descriptor_sets(
                    &vk::DescriptorSetAllocateInfo::default()
                        .descriptor_pool(this.pool)
                        .set_layouts(&set_layouts),
                )
                .vk("vkAllocateDescriptorSets")?;
        }
        Ok(this)
    }
}

impl Drop for DescriptorBundle {
    fn drop(&mut self) {
        // SAFETY: owners wait for their GPU work before dropping; destroying the pool frees the
        // sets; null handles (half-built) are ignored.
        unsafe {
            self.shared.device.destroy_descriptor_pool(self.pool, None);
            self.shared
                .device
                .destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

/// An owned sampler.
pub(crate) struct Sampler {
    pub(crate) raw: vk::Sampler,
    shared: Arc<DeviceShared>,
}

impl Sampler {
    /// Linear filtering, clamp to edge on every axis, one mip level: `texture()` on volumes,
    /// caches and transfer functions.
    pub(crate) fn linear_clamp(shared: &Arc<DeviceShared>) -> Result<Self> {
        Self::clamp(shared, vk::Filter::LINEAR)
    }

    /// Nearest filtering, clamp to edge: for formats without linear filtering (host depth).
    pub(crate) fn nearest_clamp(shared: &Arc<DeviceShared>) -> Result<Self> {
        Self::clamp(shared, vk::Filter::NEAREST)
    }

    fn clamp(shared: &Arc<DeviceShared>, filter: vk::Filter) -> Result<Self> {
        let info = vk::SamplerCreateInfo::default()
            .mag_filter(filter)
            .min_filter(filter)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .max_lod(0.0);
        // SAFETY: valid create info on a live device.
        let raw = unsafe { shared.device.create_sampler(&info, None) }.vk("vkCreateSampler")?;
        Ok(Self {
            raw,
            shared: shared.clone(),
        })
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        // SAFETY: owners wait for their GPU work before dropping.
        unsafe { self.shared.device.destroy_sampler(self.raw, None) };
    }
}
