//! An owned `VkPipelineCache`: pipeline variants built through it reuse the driver's compiled
//! code, and its data can be saved and handed back on the next run.

use super::context::DeviceShared;
use crate::error::{Result, VkResultExt};
use ash::vk;
use std::sync::Arc;

/// Bytes of the version-one pipeline cache header (Vulkan spec, "Pipeline Cache Header").
const HEADER_BYTES: usize = 16 + vk::UUID_SIZE;

/// A pipeline cache, destroyed on drop.
pub(crate) struct PipelineCache {
    pub(crate) raw: vk::PipelineCache,
    /// Whether the initial data was accepted (its header matched this device).
    pub(crate) seeded: bool,
    shared: Arc<DeviceShared>,
}

impl PipelineCache {
    /// A cache seeded with `initial_data` when its header names this device (vendor, device and
    /// pipeline-cache UUID); data for another device or driver is ignored, never passed on.
    pub(crate) fn new(shared: &Arc<DeviceShared>, initial_data: &[u8]) -> Result<Self> {
        let seeded = header_matches(shared, initial_data);
        let data = if seeded { initial_data } else { &[] };
        let info = vk::PipelineCacheCreateInfo::default().initial_data(data);
        // SAFETY: valid create info on a live device; the data's header was checked above.
        let raw = unsafe { shared.device.create_pipeline_cache(&info, None) }
            .vk("vkCreatePipelineCache")?;
        Ok(Self {
            raw,
            seeded,
            shared: shared.clone(),
        })
    }

    /// The cache's current contents (to store and pass to [`PipelineCache::new`] next time).
    pub(crate) fn data(&self) -> Result<Vec<u8>> {
        // SAFETY: `raw` is a live pipeline cache of this device; the caller holds `&self`, and
        // pipelines are only built through `&mut` owners, so no other thread writes it now.
        unsafe { self.shared.device.get_pipeline_cache_data(self.raw) }.vk("vkGetPipelineCacheData")
    }
}

/// Whether `data` starts with a version-one header for this physical device.
fn header_matches(shared: &DeviceShared, data: &[u8]) -> bool {
    if data.len() < HEADER_BYTES {
        return false;
    }
    let word = |i: usize| u32::from_le_bytes(data[4 * i..4 * i + 4].try_into().expect("4 bytes"));
    // SAFETY: `physical_device` belongs to the live instance behind `shared`.
    let props = unsafe {
        shared
            .instance()
            .get_physical_device_properties(shared.physical_device)
    };
    word(0) as usize >= HEADER_BYTES
        && word(1) == vk::PipelineCacheHeaderVersion::ONE.as_raw() as u32
        && word(2) == props.vendor_id
        && word(3) == props.device_id
        && data[16..HEADER_BYTES] == props.pipeline_cache_uuid
}

impl Drop for PipelineCache {
    fn drop(&mut self) {
        // SAFETY: owners drop the cache after the pipelines built through it were created (a
        // cache may be destroyed while pipelines built from it live on).
        unsafe { self.shared.device.destroy_pipeline_cache(self.raw, None) };
    }
}
