//! The crate's error type: runtime conditions a caller can act on.

use crate::volume::VolumeError;

/// Everything that can go wrong at run time in this crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A Vulkan call failed.
    #[error("Vulkan call {call} failed: {result}")]
    Vulkan {
        /// The entry point that failed.
        call: &'static str,
        /// The result code it returned.
        result: ash::vk::Result,
    },
    /// The Vulkan loader could not be loaded.
    #[error("cannot load the Vulkan loader (is libvulkan1 installed?): {0}")]
    Loader(String),
    /// gpu-allocator refused an allocation.
    #[error("GPU memory allocation '{name}' failed: {source}")]
    Allocation {
        /// The debug name of the allocation.
        name: String,
        /// What the allocator said.
        #[source]
        source: gpu_allocator::AllocationError,
    },
    /// The device was lost (`VK_ERROR_DEVICE_LOST`: a driver reset, a hung or removed GPU).
    /// Nothing made from the context works any more: drop the renderers and the context, then
    /// create a new `gpu::GpuContext` (and renderers) to go on.
    #[error(
        "the GPU device was lost during {call}: drop the renderer and its GPU context and \
         create new ones to continue"
    )]
    DeviceLost {
        /// The call that reported the loss.
        call: &'static str,
    },
    /// GPU work did not finish within the wait's timeout (the GPU may be hung, or the work far
    /// too large): the submission is still pending; a later call waits for it again.
    #[error(
        "GPU work did not finish within {timeout_ms} ms ({call}); the device may be hung, or \
         the frame too expensive (set MIXVOL_GPU_TIMEOUT_MS to wait longer)"
    )]
    GpuTimeout {
        /// The wait that timed out.
        call: &'static str,
        /// The timeout in milliseconds.
        timeout_ms: u64,
    },
    /// A GPU memory request exceeds a device limit; refused before anything is allocated.
    #[error(
        "GPU allocation '{name}' needs {bytes} bytes but {limit_name} is {limit} bytes: request \
         less GPU memory (a smaller volume or scalar type, a smaller cache budget, or the brick \
         cache, which streams bricks through a cache of bounded size)"
    )]
    GpuMemoryLimit {
        /// The debug name of the request (what it is for).
        name: String,
        /// Bytes requested (the driver's memory requirements).
        bytes: u64,
        /// Which limit: `maxMemoryAllocationSize`, the largest heap, or the heap budget.
        limit_name: &'static str,
        /// The limit in bytes.
        limit: u64,
    },
    /// A GLSL source did not compile.
    #[error("{file}:{line}: {message}")]
    ShaderCompile {
        /// The GLSL file that holds the error (an include file where the error is in one).
        file: String,
        /// 1-based line number in `file` (0 when the compiler named none).
        line: u32,
        /// The compiler's full message.
        message: String,
    },
    /// The device or instance lacks something the renderer needs.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// A frame the caller asked to be complete shows bricks that failed to load (a corrupt
    /// stored brick, a failed fetch): it draws nothing, or draws them at a coarser level when
    /// no fallback was allowed.
    #[error("{failed} bricks failed to load (first: {first}): {consequence}")]
    FailedLoads {
        /// Bricks (stored bricks of a level source) whose load failed.
        failed: usize,
        /// The first failure's message.
        first: String,
        /// What that means for the frame.
        consequence: String,
    },
    /// The caller passed something unusable.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A volume could not be built or loaded.
    #[error(transparent)]
    Volume(#[from] VolumeError),
    /// A brick grid or brick packing request is unusable.
    #[error(transparent)]
    Brick(#[from] crate::bricks::BrickError),
    /// The brick cache cannot be laid out or updated as asked.
    #[error(transparent)]
    Cache(#[from] crate::cache::CacheError),
    /// Culling or level selection was given unusable input.
    #[error(transparent)]
    Lod(#[from] crate::lod::LodError),
    /// A brick source could not deliver a brick.
    #[error(transparent)]
    Source(#[from] crate::bricks::SourceError),
    /// The residency planner was given unusable input.
    #[error(transparent)]
    Plan(#[from] crate::plan::PlanError),
    /// The brick store could not be written, read or streamed.
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// A level plan or level grid is unusable: levels out of order or past the grids, adjacent
    /// bricks more than one level apart, a broken block, too many levels for the bricks.
    #[error(transparent)]
    Pyramid(#[from] crate::pyramid::PyramidError),
    /// A level plan does not fit the cache (more slots than it has, another brick size, a level
    /// placed otherwise than the cache stores it).
    #[error(transparent)]
    Packing(#[from] crate::pyramid::PackingError),
    /// The camera-driven level choice was given unusable input.
    #[error(transparent)]
    LevelChoice(#[from] crate::plan::LevelChoiceError),
    /// Streaming an OME-Zarr image failed (opening it, its configuration).
    #[error(transparent)]
    Stream(#[from] crate::stream::StreamError),
    /// A file other than an image (a JSON or CSV output) could not be written: `what` names
    /// it ("the stats JSON").
    #[error("cannot write {what} {path}: {message}")]
    FileWrite {
        /// What the file is, for the message.
        what: String,
        /// Destination path.
        path: std::path::PathBuf,
        /// What failed.
        message: String,
    },
    /// An image could not be written.
    #[error("cannot write image {path}: {message}")]
    ImageWrite {
        /// Destination path.
        path: std::path::PathBuf,
        /// What the encoder said.
        message: String,
    },
}

impl From<crate::optics::OpticsError> for Error {
    fn from(e: crate::optics::OpticsError) -> Self {
        Error::InvalidInput(e.0)
    }
}

impl From<crate::scene::SceneError> for Error {
    fn from(e: crate::scene::SceneError) -> Self {
        Error::InvalidInput(e.0)
    }
}

/// Result with the crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Attaches the Vulkan entry point name to a `vk::Result` error.
/// The error of the Vulkan call `call` returning `result`: device loss is its own variant.
pub(crate) fn vk_error(call: &'static str, result: ash::vk::Result) -> Error {
    match result {
        ash::vk::Result::ERROR_DEVICE_LOST => Error::DeviceLost { call },
        result => Error::Vulkan { call, result },
    }
}

pub(crate) trait VkResultExt<T> {
    /// Maps the error into [`Error::Vulkan`] naming `call`.
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkResultExt<T> for std::result::Result<T, ash::vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| vk_error(call, result))
    }
}
