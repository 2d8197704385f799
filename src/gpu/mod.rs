//! The ash backend. Raw Vulkan calls live here only, behind small owning types:
//! [`GpuContext`] (instance, device, allocator, validation messenger), buffers and images
//! (`memory`), shader compilation (`shaders`), command recording (`commands`) and the ray-cast
//! pipeline (`raycast`).

mod brick_cache;
mod commands;
mod compute;
mod context;
mod descriptors;
mod memory;
mod pipeline_cache;
mod raycast;
pub mod shaders;

pub use context::{
    ContextDesc, DebugMessage, DeviceInfo, GpuContext, HostDevice, MessageLog, Severity,
};
pub use shaders::ShaderStage;

pub(crate) use brick_cache::{CacheRegion, CacheTables, FieldProbe, GpuBrickCache};
pub(crate) use commands::{image_barrier, memory_barrier, Access, Submitter, TimestampPool};
pub(crate) use memory::{Buffer, Image, ImageDesc, COLOR_LAYERS};
pub(crate) use pipeline_cache::PipelineCache;
pub(crate) use raycast::RaycastPipeline;
pub use raycast::RaycastVariant;
