//! Frame slots (the per-frame resources a frame in flight owns) and the GPU timings read from
//! their timestamps.

use crate::error::Result;
use crate::gpu::{Buffer, DeviceInfo, GpuContext, StagingUpload, TimestampPool};
use crate::optics::TF_SIZE;
use crate::scene::RaycastParams;
use ash::vk;
use gpu_allocator::MemoryLocation;

/// The timestamp queries of one frame slot, in recording order.
pub(super) mod query {
    /// Start of the frame's commands.
    pub(crate) const FRAME_START: u32 = 0;
    /// Brick / volume / transfer-function copies done.
    pub(crate) const UPLOAD_END: u32 = 1;
    /// The fixup compute pass done (written by the brick cache, right after `UPLOAD_END`).
    pub(crate) const FIXUP_END: u32 = 2;
    /// Ray-cast start.
    pub(crate) const RAYCAST_START: u32 = 3;
    /// Ray-cast end.
    pub(crate) const RAYCAST_END: u32 = 4;
    /// Queries per frame slot.
    pub(crate) const COUNT: u32 = 5;

    // The brick cache writes its two timestamps at `UPLOAD_END` and the one after.
    const _: () = assert!(FIXUP_END == UPLOAD_END + 1);
}

/// GPU times of one frame's passes, in milliseconds (`None` when the pass did not run in that
/// frame or the queue has no timestamps).
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct PassTimings {
    /// Brick / volume / transfer-function copies.
    pub upload_ms: Option<f64>,
    /// The fixup compute pass.
    pub fixup_ms: Option<f64>,
    /// The ray-cast.
    pub raycast_ms: Option<f64>,
}

/// What frame slot `frame` owns: the parameter buffer, staging for the source (plain volume or
/// brick cache) and for the two tables, and its timestamps. The host records a slot again only
/// after the GPU finished the frame that last used it (the module's contract), so everything
/// here may be rewritten then.
pub(super) struct FrameSlot {
    pub(super) params: Buffer,
    /// The plain volume's texels or the brick cache's bricks.
    pub(super) source_staging: StagingUpload,
    pub(super) tf_staging: StagingUpload,
    pub(super) preint_staging: StagingUpload,
    pub(super) queries: TimestampPool,
}

impl FrameSlot {
    /// Allocates the slot's buffers and query pool.
    pub(super) fn new(ctx: &GpuContext) -> Result<Self> {
        let shared = &ctx.shared;
        Ok(Self {
            params: Buffer::new(
                shared,
                "raycast params",
                std::mem::size_of::<RaycastParams>() as u64,
                vk::BufferUsageFlags::UNIFORM_BUFFER,
                MemoryLocation::CpuToGpu,
            )?,
            source_staging: StagingUpload::new(shared, "staging"),
            tf_staging: StagingUpload::with_capacity(
                shared,
                "transfer function staging",
                (TF_SIZE * 16) as u64,
            )?,
            preint_staging: StagingUpload::new(shared, "pre-integration staging"),
            queries: TimestampPool::new(shared, query::COUNT)?,
        })
    }

    /// Writes the frame's parameter block (the GPU must be done with the slot).
    pub(super) fn write_params(&mut self, params: &RaycastParams) -> Result<()> {
        self.params.mapped_mut()?[..std::mem::size_of::<RaycastParams>()]
            .copy_from_slice(bytemuck::bytes_of(params));
        Ok(())
    }

    /// The timings of the frame last recorded with this slot, from whichever timestamps are
    /// available (no wait).
    pub(super) fn timings(&self, info: &DeviceInfo) -> Result<PassTimings> {
        if !info.timestamps_supported {
            return Ok(PassTimings::default());
        }
        let ticks = self.queries.read_available()?;
        let period = f64::from(info.timestamp_period_ns) * 1e-6;
        let span = |a: u32, b: u32| match (ticks[a as usize], ticks[b as usize]) {
            (Some(x), Some(y)) => Some(y.wrapping_sub(x) as f64 * period),
            _ => None,
        };
        Ok(PassTimings {
            upload_ms: span(query::FRAME_START, query::UPLOAD_END),
            fixup_ms: span(query::UPLOAD_END, query::FIXUP_END),
            raycast_ms: span(query::RAYCAST_START, query::RAYCAST_END),
        })
    }
}
