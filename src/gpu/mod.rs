//! The ash backend. Raw Vulkan calls live here only, behind small owning types:
//! [`GpuContext`] (instance, device, allocator), what the validation layers say (`validation`:
//! the messenger callback and its [`MessageLog`]), buffers and images
//! (`memory`), the one staging path into images (`upload`), shader compilation ([`shaders`]),
//! the definitions Rust and GLSL share ([`shared_defs`]), command recording and timestamps
//! (`commands`), the brick cache and its fixup (`brick_cache`) and the ray-cast pipeline and its
//! draw (`raycast`).

mod brick_cache;
mod commands;
mod compute;
mod context;
mod descriptors;
mod memory;
mod pipeline_cache;
mod raycast;
pub mod shaders;
pub mod shared_defs;
mod upload;
mod validation;

pub(crate) use context::DeviceShared;
pub use context::{
    ContextDesc, DeviceInfo, GpuContext, HostDevice, MemoryLimits, ALLOCATION_CAP_ENV,
};
pub use shaders::ShaderStage;
pub use validation::{DebugMessage, MessageLog, Severity, INVALID_CALL_ENV};

pub(crate) use brick_cache::{CacheRegion, CacheTables, FieldProbe, GpuBrickCache, SlotPacking};
pub use commands::GPU_TIMEOUT_ENV;
#[cfg(test)]
pub(crate) use commands::INJECT_WAIT_RESULT;
pub(crate) use commands::{image_barrier, Access, Submitter, TimestampPool};
pub(crate) use memory::{Buffer, Image, ImageDesc};
pub(crate) use pipeline_cache::PipelineCache;
pub use raycast::RaycastVariant;
pub(crate) use raycast::{DrawTarget, RaycastPipeline};
pub(crate) use upload::{record_image_readback, StagingUpload};
