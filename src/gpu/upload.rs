//! The one staging path from the CPU into images: a host-visible staging buffer that grows to fit,
//! and the recording of buffer-to-image copies between the barriers that order them. The plain
//! volume, the brick cache and the transfer-function / pre-integration tables all upload
//! through it. The way back (an image into a host-readable buffer) is
//! [`record_image_readback`].

use super::commands::{image_barrier, memory_barrier, Access};
use super::context::DeviceShared;
use super::memory::{Buffer, Image, COLOR_LAYERS};
use crate::error::{Error, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// One copy of [`StagingUpload::record`]: bytes at `buffer_offset` of the staged bytes into a
/// box of the image.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) struct CopyRegion {
    /// Offset of the region's first texel in the staged bytes (a multiple of 4).
    pub(crate) buffer_offset: u64,
    /// Destination texel origin.
    pub(crate) origin: [u32; 3],
    /// Extent in texels (tightly packed, x fastest).
    pub(crate) extent: [u32; 3],
}

impl CopyRegion {
    /// The whole of `image`, from offset 0.
    pub(crate) fn whole(image: &Image) -> Self {
        let e = image.desc.extent;
        Self {
            buffer_offset: 0,
            origin: [0; 3],
            extent: [e.width, e.height, e.depth],
        }
    }

    fn vk(self) -> vk::BufferImageCopy {
        vk::BufferImageCopy::default()
            .buffer_offset(self.buffer_offset)
            .image_subresource(COLOR_LAYERS)
            .image_offset(vk::Offset3D {
                x: self.origin[0] as i32,
                y: self.origin[1] as i32,
                z: self.origin[2] as i32,
            })
            .image_extent(vk::Extent3D {
                width: self.extent[0],
                height: self.extent[1],
                depth: self.extent[2],
            })
    }
}

/// A staging buffer for one kind of upload (per frame slot: the GPU reads it while the frame
/// runs). Created on first use (or up front with [`StagingUpload::with_capacity`]) and replaced
/// by a larger one (the next power of two) when the bytes do not fit.
pub(crate) struct StagingUpload {
    name: &'static str,
    buffer: Option<Buffer>,
    shared: Arc<DeviceShared>,
}

impl StagingUpload {
    /// An empty staging path named `name` (for debugging and leak reports).
    pub(crate) fn new(shared: &Arc<DeviceShared>, name: &'static str) -> Self {
        Self {
            name,
            buffer: None,
            shared: shared.clone(),
        }
    }

    /// A staging path with a buffer of `bytes` bytes already allocated.
    pub(crate) fn with_capacity(
        shared: &Arc<DeviceShared>,
        name: &'static str,
        bytes: u64,
    ) -> Result<Self> {
        let mut upload = Self::new(shared, name);
        upload.buffer = Some(upload.allocate(bytes)?);
        Ok(upload)
    }

    fn allocate(&self, bytes: u64) -> Result<Buffer> {
        Buffer::new(
            &self.shared,
            self.name,
            bytes,
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )
    }

    /// Writes `bytes` to the start of the staging buffer (growing it first when they do not
    /// fit). The GPU must be done with earlier contents (the frame slot's contract).
    fn write(&mut self, bytes: &[u8]) -> Result<&Buffer> {
        let len = bytes.len() as u64;
        if self.buffer.as_ref().is_none_or(|b| b.size < len) {
            self.buffer = None;
            self.buffer = Some(self.allocate(len.next_power_of_two())?);
        }
        let buffer = self.buffer.as_mut().expect("allocated above");
        buffer.mapped_mut()?[..bytes.len()].copy_from_slice(bytes);
        Ok(buffer)
    }

    /// Stages `bytes` and records into `cmd`: a barrier moving `image` from `previous` to
    /// transfer-write, one `vkCmdCopyBufferToImage` with every region, and a barrier from
    /// transfer-write to `next`. With no regions (or no bytes) only the barriers are recorded.
    /// `cmd` must be recording; the regions must lie inside the bytes and the image.
    pub(crate) fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        image: &Image,
        bytes: &[u8],
        regions: &[CopyRegion],
        previous: Access,
        next: Access,
    ) -> Result<()> {
        let Some(texel) = texel_size(image.desc.format) else {
            return Err(Error::Unsupported(format!(
                "uploads into {:?} images",
                image.desc.format
            )));
        };
        let texel_bytes =
            |r: &CopyRegion| r.extent.iter().map(|&e| u64::from(e)).product::<u64>() * texel as u64;
        let image_extent = image.desc.extent;
        let limit = [image_extent.width, image_extent.height, image_extent.depth];
        for r in regions {
            let inside_image = (0..3).all(|a| {
                r.origin[a]
                    .checked_add(r.extent[a])
                    .is_some_and(|end| end <= limit[a])
            });
            if !inside_image
                || r.buffer_offset % 4 != 0
                || r.buffer_offset + texel_bytes(r) > bytes.len() as u64
            {
                return Err(Error::InvalidInput(format!(
                    "upload region {r:?} does not fit {} staged bytes or the {limit:?} image",
                    bytes.len()
                )));
            }
        }
        let staged = if regions.is_empty() || bytes.is_empty() {
            None
        } else {
            Some(self.write(bytes)?.raw)
        };
        let device = &self.shared.device;
        image_barrier(device, cmd, image.raw, previous, Access::TransferWrite);
        if let Some(buffer) = staged {
            let copies: Vec<vk::BufferImageCopy> = regions.iter().map(|r| r.vk()).collect();
            // SAFETY: the staging buffer holds every region at its offset (checked above); the
            // image is in TRANSFER_DST_OPTIMAL after the barrier; `cmd` is recording.
            unsafe {
                device.cmd_copy_buffer_to_image(
                    cmd,
                    buffer,
                    image.raw,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &copies,
                )
            };
        }
        image_barrier(device, cmd, image.raw, Access::TransferWrite, next);
        Ok(())
    }

    /// Stages `bytes` (all texels of `image`, x fastest) and records the whole-image copy,
    /// leaving the image ready for fragment-shader sampling. `previous` is how the image was
    /// used before ([`Access::Nothing`] for its first upload).
    pub(crate) fn record_whole_image(
        &mut self,
        cmd: vk::CommandBuffer,
        image: &Image,
        bytes: &[u8],
        previous: Access,
    ) -> Result<()> {
        self.record(
            cmd,
            image,
            bytes,
            &[CopyRegion::whole(image)],
            previous,
            Access::FragmentSampled,
        )
    }
}

/// Records into `cmd` a copy of the whole of `image` into `readback` (a host-readable buffer):
/// a barrier from `previous` to transfer-read, the copy, optionally a barrier back from
/// transfer-read to `after`, and a dependency making the copy visible to host reads once the
/// commands complete. `cmd` must be recording.
pub(crate) fn record_image_readback(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    image: &Image,
    readback: &Buffer,
    previous: Access,
    after: Option<Access>,
) -> Result<()> {
    let e = image.desc.extent;
    let texels = u64::from(e.width) * u64::from(e.height) * u64::from(e.depth);
    let bytes = texel_size(image.desc.format).map(|t| texels * t as u64);
    if bytes.is_none_or(|bytes| readback.size < bytes) {
        return Err(Error::InvalidInput(format!(
            "a {}-byte buffer cannot hold the {:?} {e:?} image",
            readback.size, image.desc.format
        )));
    }
    let copy = vk::BufferImageCopy::default()
        .image_subresource(COLOR_LAYERS)
        .image_extent(e);
    image_barrier(device, cmd, image.raw, previous, Access::TransferRead);
    // SAFETY: the buffer holds the whole image (checked above); the image is in
    // TRANSFER_SRC_OPTIMAL after the barrier; `cmd` is recording.
    unsafe {
        device.cmd_copy_image_to_buffer(
            cmd,
            image.raw,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            readback.raw,
            &[copy],
        )
    };
    if let Some(after) = after {
        image_barrier(device, cmd, image.raw, Access::TransferRead, after);
    }
    memory_barrier(device, cmd, Access::TransferWrite, Access::HostRead);
    Ok(())
}

/// Bytes per texel of `format` (the formats the crate copies), `None` for others.
fn texel_size(format: vk::Format) -> Option<usize> {
    Some(match format {
        vk::Format::R8_UNORM => 1,
        vk::Format::R16_UNORM => 2,
        vk::Format::R32_SFLOAT | vk::Format::R8G8B8A8_UNORM => 4,
        vk::Format::R32G32B32A32_SFLOAT => 16,
        _ => return None,
    })
}
