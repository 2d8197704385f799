//! Command recording helpers: named accesses turned into synchronization2 barriers, and a
//! one-shot submitter that records, submits and waits.

use super::context::DeviceShared;
use super::memory::COLOR_RANGE;
use crate::error::{vk_error, Error, Result, VkResultExt};
use ash::vk;
use std::sync::Arc;

/// How a resource is used at one point of a command stream. Call sites name the access; one
/// table turns it into stage, access mask and image layout.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum Access {
    /// Not used yet (contents may be discarded).
    Nothing,
    /// Written by a transfer (copy) command.
    TransferWrite,
    /// Read by a transfer (copy) command.
    TransferRead,
    /// Sampled in a fragment shader.
    FragmentSampled,
    /// Written as a colour attachment.
    ColorAttachmentWrite,
    /// Read by the host after the commands complete.
    HostRead,
    /// Buffers written by a compute shader.
    ComputeWrite,
    /// Brick cache (GENERAL layout) read and written as a storage image by the fixup pass.
    CacheComputeReadWrite,
    /// Sampled in a compute shader (the field probe).
    ComputeSampled,
}

impl Access {
    fn stage_access_layout(self) -> (vk::PipelineStageFlags2, vk::AccessFlags2, vk::ImageLayout) {
        use vk::{AccessFlags2 as A, ImageLayout as L, PipelineStageFlags2 as S};
        match self {
            Access::Nothing => (S::NONE, A::NONE, L::UNDEFINED),
            Access::TransferWrite => (S::COPY, A::TRANSFER_WRITE, L::TRANSFER_DST_OPTIMAL),
            Access::TransferRead => (S::COPY, A::TRANSFER_READ, L::TRANSFER_SRC_OPTIMAL),
            Access::FragmentSampled => (
                S::FRAGMENT_SHADER,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
            ),
            Access::ColorAttachmentWrite => (
                S::COLOR_ATTACHMENT_OUTPUT,
                A::COLOR_ATTACHMENT_WRITE,
                L::COLOR_ATTACHMENT_OPTIMAL,
            ),
            Access::HostRead => (S::HOST, A::HOST_READ, L::GENERAL),
            Access::ComputeWrite => (S::COMPUTE_SHADER, A::SHADER_STORAGE_WRITE, L::GENERAL),
            Access::CacheComputeReadWrite => (
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE,
                L::GENERAL,
            ),
            Access::ComputeSampled => (
                S::COMPUTE_SHADER,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
            ),
        }
    }
}

/// Records an image layout transition + dependency from `prev` to `next` (whole colour image).
pub(crate) fn image_barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    image: vk::Image,
    prev: Access,
    next: Access,
) {
    let (src_stage, src_access, old_layout) = prev.stage_access_layout();
    let (dst_stage, dst_access, new_layout) = next.stage_access_layout();
    let barrier = vk::ImageMemoryBarrier2::default()
        .src_stage_mask(src_stage)
        .src_access_mask(src_access)
        .dst_stage_mask(dst_stage)
        .dst_access_mask(dst_access)
        .old_layout(old_layout)
        .new_layout(new_layout)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .image(image)
        .subresource_range(COLOR_RANGE);
    let barriers = [barrier];
    let dependency = vk::DependencyInfo::default().image_memory_barriers(&barriers);
    // SAFETY: `cmd` is in the recording state (callers record inside `Submitter::run`).
    unsafe { device.cmd_pipeline_barrier2(cmd, &dependency) };
}

/// Records a global memory dependency from `prev` to `next` (buffers; layouts are ignored).
pub(crate) fn memory_barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    prev: Access,
    next: Access,
) {
    let (src_stage, src_access, _) = prev.stage_access_layout();
    let (dst_stage, dst_access, _) = next.stage_access_layout();
    let barriers = [vk::MemoryBarrier2::default()
        .src_stage_mask(src_stage)
        .src_access_mask(src_access)
        .dst_stage_mask(dst_stage)
        .dst_access_mask(dst_access)];
    let dependency = vk::DependencyInfo::default().memory_barriers(&barriers);
    // SAFETY: `cmd` is in the recording state.
    unsafe { device.cmd_pipeline_barrier2(cmd, &dependency) };
}

/// The environment variable that sets the GPU wait timeout in milliseconds.
pub const GPU_TIMEOUT_ENV: &str = "MIXVOL_GPU_TIMEOUT_MS";

/// The default GPU wait timeout: generous for CPU implementations (lavapipe) on big frames, yet
/// a hung GPU is reported instead of blocking forever.
const DEFAULT_GPU_TIMEOUT_MS: u64 = 120_000;

/// The timeout of every fence wait, in milliseconds (`MIXVOL_GPU_TIMEOUT_MS`, else 120 s).
pub(crate) fn gpu_timeout_ms() -> u64 {
    std::env::var(GPU_TIMEOUT_ENV)
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
        .filter(|&ms| ms > 0)
        .unwrap_or(DEFAULT_GPU_TIMEOUT_MS)
}

#[cfg(test)]
thread_local! {
    /// Test hook: the result the next fence wait on this thread reports after the real wait
    /// (device loss and timeouts cannot be provoked on a healthy device).
    pub(crate) static INJECT_WAIT_RESULT: std::cell::Cell<Option<vk::Result>> =
        const { std::cell::Cell::new(None) };
}

/// One command pool, one command buffer and one fence: records, submits and waits (with a
/// timeout: [`gpu_timeout_ms`]).
pub(crate) struct Submitter {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    /// A submission whose wait failed (timeout, device loss) may still be pending: the next
    /// `run` (and drop) waits for it before touching the command buffer or the fence.
    pending: bool,
    shared: Arc<DeviceShared>,
}

impl Submitter {
    pub(crate) fn new(shared: &Arc<DeviceShared>) -> Result<Self> {
        let device = &shared.device;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(shared.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid create info on a live device.
        let pool =
            unsafe { device.create_command_pool(&pool_info, None) }.vk("vkCreateCommandPool")?;
        let mut submitter = Self {
            pool,
            cmd: vk::CommandBuffer::null(),
            fence: vk::Fence::null(),
            pending: false,
            shared: shared.clone(),
        };
        let alloc_info = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: the pool was created above from this device.
        submitter.cmd = unsafe { device.allocate_command_buffers(&alloc_info) }
            .vk("vkAllocateCommandBuffers")?[0];
        // SAFETY: valid create info on a live device.
        submitter.fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
            .vk("vkCreateFence")?;
        Ok(submitter)
    }

    /// Waits for the fence with the timeout; `Ok` once the submission completed. A timeout is
    /// [`Error::GpuTimeout`], device loss [`Error::DeviceLost`].
    fn wait(&self) -> Result<()> {
        let timeout_ms = gpu_timeout_ms();
        // SAFETY: the fence belongs to this device and was submitted (or is signalled).
        let waited = unsafe {
            self.shared.device.wait_for_fences(
                &[self.fence],
                true,
                timeout_ms.saturating_mul(1_000_000),
            )
        };
        #[cfg(test)]
        let waited = match INJECT_WAIT_RESULT.with(|c| c.take()) {
            Some(injected) => waited.and(Err(injected)),
            None => waited,
        };
        match waited {
            Ok(()) => Ok(()),
            Err(vk::Result::TIMEOUT) => Err(Error::GpuTimeout {
                call: "vkWaitForFences",
                timeout_ms,
            }),
            Err(result) => Err(vk_error("vkWaitForFences", result)),
        }
    }

    /// Waits for a submission left pending by a failed wait, then resets the fence.
    fn settle(&mut self) -> Result<()> {
        if self.pending {
            self.wait()?;
            // SAFETY: the fence's submission completed: it may be reset.
            unsafe { self.shared.device.reset_fences(&[self.fence]) }.vk("vkResetFences")?;
            self.pending = false;
        }
        Ok(())
    }

    /// Records commands with `record`, submits them and waits for completion (at most
    /// [`gpu_timeout_ms`]; a timeout or device loss is a typed error, and the submission is
    /// waited for again before the next one).
    pub(crate) fn run(
        &mut self,
        record: impl FnOnce(&ash::Device, vk::CommandBuffer) -> Result<()>,
    ) -> Result<()> {
        self.settle()?;
        let device = &self.shared.device;
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the previous submission (if any) completed before `run` returned, so the
        // command buffer is not pending and may be reset and re-recorded.
        unsafe {
            device
                .reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty())
                .vk("vkResetCommandBuffer")?;
            device
                .begin_command_buffer(self.cmd, &begin)
                .vk("vkBeginCommandBuffer")?;
        }
        let recorded = record(device, self.cmd);
        // SAFETY: the command buffer is recording; ending it is valid even after a failed record.
        let ended = unsafe { device.end_command_buffer(self.cmd) }.vk("vkEndCommandBuffer");
        recorded?;
        ended?;
        let cmd_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submits = [vk::SubmitInfo2::default().command_buffer_infos(&cmd_infos)];
        // The command buffer is executable and the fence unsignalled.
        let _queue = self
            .shared
            .queue_lock
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        // SAFETY: see above; `_queue` holds the queue's submit lock.
        unsafe {
            device
                .queue_submit2(self.shared.queue, &submits, self.fence)
                .vk("vkQueueSubmit2")?;
        }
        drop(_queue);
        if let Err(e) = self.wait() {
            self.pending = true;
            return Err(e);
        }
        // SAFETY: the submission completed: the fence may be reset.
        unsafe { device.reset_fences(&[self.fence]) }.vk("vkResetFences")
    }
}

impl Drop for Submitter {
    fn drop(&mut self) {
        if self.pending {
            if let Err(e) = self.wait() {
                log::error!("dropping a submitter whose work did not finish: {e}");
            }
        }
        // SAFETY: `run` waits for its submission, and a submission left pending by a failed
        // wait was waited for above (after device loss, waits return and nothing executes);
        // destroying the pool frees its command buffer. Null handles (half-built) are ignored.
        unsafe {
            self.shared.device.destroy_fence(self.fence, None);
            self.shared.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// A timestamp query pool with `count` queries: reset, write and read through its methods.
pub(crate) struct TimestampPool {
    raw: vk::QueryPool,
    count: u32,
    shared: Arc<DeviceShared>,
}

impl TimestampPool {
    pub(crate) fn new(shared: &Arc<DeviceShared>, count: u32) -> Result<Self> {
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::TIMESTAMP)
            .query_count(count);
        // SAFETY: valid create info on a live device.
        let raw =
            unsafe { shared.device.create_query_pool(&info, None) }.vk("vkCreateQueryPool")?;
        Ok(Self {
            raw,
            count,
            shared: shared.clone(),
        })
    }
}

impl TimestampPool {
    /// Records a reset of every query of the pool into `cmd` (before writing them again). The
    /// pool's previous results must have been read (or be no longer wanted) and no pending
    /// command buffer may still write them.
    pub(crate) fn record_reset(&self, cmd: vk::CommandBuffer) {
        // SAFETY: `cmd` is recording (caller contract, as for every recording helper here); the
        // range covers the pool, which is live.
        unsafe {
            self.shared
                .device
                .cmd_reset_query_pool(cmd, self.raw, 0, self.count)
        };
    }

    /// Records a timestamp into query `index` after all earlier commands of `cmd`'s queue
    /// (`ALL_COMMANDS`). The query must have been reset earlier in the command stream.
    pub(crate) fn write(&self, cmd: vk::CommandBuffer, index: u32) {
        debug_assert!(
            index < self.count,
            "timestamp query {index} of {}",
            self.count
        );
        // SAFETY: `cmd` is recording; `index` lies in the pool (checked by callers against
        // `count`), which is live.
        unsafe {
            self.shared.device.cmd_write_timestamp2(
                cmd,
                vk::PipelineStageFlags2::ALL_COMMANDS,
                self.raw,
                index,
            )
        };
    }

    /// Reads every timestamp that is available, without waiting: `None` for queries not
    /// written (or not yet complete) since their last reset.
    pub(crate) fn read_available(&self) -> Result<Vec<Option<u64>>> {
        let mut raw = vec![[0u64; 2]; self.count as usize];
        // SAFETY: the pool is live; WITH_AVAILABILITY writes a value + availability pair per
        // query and never blocks without WAIT.
        let result = unsafe {
            self.shared.device.get_query_pool_results(
                self.raw,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WITH_AVAILABILITY,
            )
        };
        match result {
            Ok(()) | Err(vk::Result::NOT_READY) => {}
            Err(result) => {
                return Err(crate::Error::Vulkan {
                    call: "vkGetQueryPoolResults",
                    result,
                })
            }
        }
        Ok(raw
            .into_iter()
            .map(|[value, available]| (available != 0).then_some(value))
            .collect())
    }
}

impl Drop for TimestampPool {
    fn drop(&mut self) {
        // SAFETY: owners wait for their submissions before dropping.
        unsafe { self.shared.device.destroy_query_pool(self.raw, None) };
    }
}
