//! Owning wrappers for buffers and images whose memory comes from gpu-allocator. Each frees its
//! allocation and destroys its handle in Drop; each holds the device alive through an Arc.

use super::context::DeviceShared;
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// A buffer with its memory.
pub(crate) struct Buffer {
    pub(crate) raw: vk::Buffer,
    pub(crate) size: vk::DeviceSize,
    allocation: Option<Allocation>,
    shared: Arc<DeviceShared>,
}

impl Buffer {
    /// Creates a buffer of `size` bytes in `location`, named `name` for debugging and leak reports.
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        name: &str,
        size: vk::DeviceSize,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Self> {
        if size == 0 {
            return Err(Error::InvalidInput(format!("buffer '{name}' has size 0")));
        }
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let device = &shared.device;
        // SAFETY: valid create info on a live device.
        let raw = unsafe { device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        // SAFETY: `raw` was just created from this device.
        let requirements = unsafe { device.get_buffer_memory_requirements(raw) };
        let allocation = shared.allocator().allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: the buffer is unused and unbound.
                unsafe { device.destroy_buffer(raw, None) };
                return Err(Error::Allocation {
                    name: name.into(),
                    source,
                });
            }
        };
        // SAFETY: memory and offset come from an allocation made for these requirements.
        let bound =
            unsafe { device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) };
        shared
            .live_allocations
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let buffer = Self {
            raw,
            size,
            allocation: Some(allocation),
            shared: shared.clone(),
        };
        bound.vk("vkBindBufferMemory")?;
        Ok(buffer)
    }

    /// The mapped bytes of a host-visible buffer.
    pub(crate) fn mapped(&self) -> Result<&[u8]> {
        self.allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .ok_or_else(|| Error::InvalidInput("buffer is not host visible".into()))
    }

    /// The mapped bytes of a host-visible buffer, writable.
    pub(crate) fn mapped_mut(&mut self) -> Result<&mut [u8]> {
        self.allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .ok_or_else(|| Error::InvalidInput("buffer is not host visible".into()))
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        if let Some(allocation) = self.allocation.take() {
            let _ = self.shared.allocator().free(allocation);
            self.shared
                .live_allocations
                .fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
        }
        // SAFETY: owners wait for the GPU to finish with the buffer before dropping it.
        unsafe { self.shared.device.destroy_buffer(self.raw, None) };
    }
}

/// What an image is: a small `Copy` value with named constructors.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct ImageDesc {
    pub(crate) image_type: vk::ImageType,
    pub(crate) format: vk::Format,
    pub(crate) extent: vk::Extent3D,
    pub(crate) usage: vk::ImageUsageFlags,
}

impl ImageDesc {
    /// A 1D image.
    pub(crate) fn new_1d(format: vk::Format, width: u32, usage: vk::ImageUsageFlags) -> Self {
        Self {
            image_type: vk::ImageType::TYPE_1D,
            format,
            extent: vk::Extent3D {
                width,
                height: 1,
                depth: 1,
            },
            usage,
        }
    }

    /// A 2D image.
    pub(crate) fn new_2d(
        format: vk::Format,
        width: u32,
        height: u32,
        usage: vk::ImageUsageFlags,
    ) -> Self {
        Self {
            image_type: vk::ImageType::TYPE_2D,
            format,
            extent: vk::Extent3D {
                width,
                height,
                depth: 1,
            },
            usage,
        }
    }

    /// A 3D image.
    pub(crate) fn new_3d(format: vk::Format, extent: [u32; 3], usage: vk::ImageUsageFlags) -> Self {
        Self {
            image_type: vk::ImageType::TYPE_3D,
            format,
            extent: vk::Extent3D {
                width: extent[0],
                height: extent[1],
                depth: extent[2],
            },
            usage,
        }
    }

    fn view_type(&self) -> vk::ImageViewType {
        match self.image_type {
            vk::ImageType::TYPE_1D => vk::ImageViewType::TYPE_1D,
            vk::ImageType::TYPE_2D => vk::ImageViewType::TYPE_2D,
            _ => vk::ImageViewType::TYPE_3D,
        }
    }
}

/// The colour subresource range of a single-mip, single-layer image.
pub(crate) const COLOR_RANGE: vk::ImageSubresourceRange = vk::ImageSubresourceRange {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    base_mip_level: 0,
    level_count: 1,
    base_array_layer: 0,
    layer_count: 1,
};

/// The colour subresource layers of mip 0, layer 0.
pub(crate) const COLOR_LAYERS: vk::ImageSubresourceLayers = vk::ImageSubresourceLayers {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    mip_level: 0,
    base_array_layer: 0,
    layer_count: 1,
};

/// An image with its memory and a full view.
pub(crate) struct Image {
    pub(crate) raw: vk::Image,
    pub(crate) view: vk::ImageView,
    pub(crate) desc: ImageDesc,
    allocation: Option<Allocation>,
    shared: Arc<DeviceShared>,
}

impl Image {
    /// Creates a device-local, optimally tiled image and a view of all of it.
    pub(crate) fn new(shared: &Arc<DeviceShared>, name: &str, desc: ImageDesc) -> Result<Self> {
        let e = desc.extent;
        if e.width == 0 || e.height == 0 || e.depth == 0 {
            return Err(Error::InvalidInput(format!(
                "image '{name}' has a zero extent {e:?}"
            )));
        }
        let limits = &shared.info.limits;
        let max = match desc.image_type {
            vk::ImageType::TYPE_1D => limits.max_image_dimension1_d,
            vk::ImageType::TYPE_2D => limits.max_image_dimension2_d,
            _ => limits.max_image_dimension3_d,
        };
        if e.width.max(e.height).max(e.depth) > max {
            return Err(Error::Unsupported(format!(
                "image '{name}' extent {e:?} exceeds the device limit {max}"
            )));
        }
        let info = vk::ImageCreateInfo::default()
            .image_type(desc.image_type)
            .format(desc.format)
            .extent(desc.extent)
            .mip_levels(1)
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(desc.usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        let device = &shared.device;
        // SAFETY: valid create info; format support was checked by the caller.
        let raw = unsafe { device.create_image(&info, None) }.vk("vkCreateImage")?;
        // SAFETY: `raw` was just created from this device.
        let requirements = unsafe { device.get_image_memory_requirements(raw) };
        let allocation = shared.allocator().allocate(&AllocationCreateDesc {
            name,
            requirements,
            location: MemoryLocation::GpuOnly,
            linear: false,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: the image is unused and unbound.
                unsafe { device.destroy_image(raw, None) };
                return Err(Error::Allocation {
                    name: name.into(),
                    source,
                });
            }
        };
        shared
            .live_allocations
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let mut image = Self {
            raw,
            view: vk::ImageView::null(),
            desc,
            allocation: None,
            shared: shared.clone(),
        };
        // SAFETY: memory and offset come from an allocation made for these requirements.
        let bound =
            unsafe { device.bind_image_memory(raw, allocation.memory(), allocation.offset()) };
        image.allocation = Some(allocation);
        bound.vk("vkBindImageMemory")?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(raw)
            .view_type(desc.view_type())
            .format(desc.format)
            .subresource_range(COLOR_RANGE);
        // SAFETY: the image is bound to memory and the range covers it.
        image.view =
            unsafe { device.create_image_view(&view_info, None) }.vk("vkCreateImageView")?;
        Ok(image)
    }
}

impl Drop for Image {
    fn drop(&mut self) {
        // SAFETY: owners wait for the GPU to finish with the image before dropping it; a null
        // view (creation failed half-way) is ignored by vkDestroyImageView.
        unsafe {
            self.shared.device.destroy_image_view(self.view, None);
        }
        if let Some(allocation) = self.allocation.take() {
            let _ = self.shared.allocator().free(allocation);
        }
        self.shared
            .live_allocations
            .fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
        // SAFETY: as above; the view on it is already gone.
        unsafe { self.shared.device.destroy_image(self.raw, None) };
    }
}
