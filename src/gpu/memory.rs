//! Owning wrappers for buffers and images whose memory comes from gpu-allocator. Each frees its
//! allocation and destroys its handle in Drop; each holds the device alive through an Arc.

use super::context::{DeviceShared, MemoryLimits};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// Checks a request of `bytes` named `name` (memory types allowed: `type_bits`; `device_local`:
/// it wants device-local memory) against the device's `limits` and, where given, the bytes still
/// available in each heap under VK_EXT_memory_budget (`budgets`). Errors are
/// [`Error::GpuMemoryLimit`] naming the request and the limit. Pure: nothing is queried.
pub(crate) fn check_request(
    name: &str,
    bytes: u64,
    type_bits: u32,
    device_local: bool,
    limits: &MemoryLimits,
    budgets: Option<&[u64]>,
) -> Result<()> {
    let refuse = |limit_name, limit| {
        Err(Error::GpuMemoryLimit {
            name: name.to_string(),
            bytes,
            limit_name,
            limit,
        })
    };
    if limits.max_allocation_bytes > 0 && bytes > limits.max_allocation_bytes {
        let limit_name = if limits.allocation_capped {
            "maxMemoryAllocationSize as capped by MIXVOL_GPU_MAX_ALLOCATION_MB"
        } else {
            "maxMemoryAllocationSize"
        };
        return refuse(limit_name, limits.max_allocation_bytes);
    }
    let allowed = |want_local: bool| {
        limits
            .types
            .iter()
            .enumerate()
            .filter(move |(i, (flags, _))| {
                *i < 32
                    && type_bits & (1 << i) != 0
                    && (!want_local || flags.contains(vk::MemoryPropertyFlags::DEVICE_LOCAL))
            })
            .map(|(_, (_, heap))| *heap as usize)
            .filter(|&h| h < limits.heaps.len())
            .collect::<Vec<usize>>()
    };
    let mut heaps = allowed(device_local);
    if heaps.is_empty() {
        heaps = allowed(false);
    }
    if heaps.is_empty() {
        return Ok(()); // Nothing known: leave it to the allocator.
    }
    let largest = heaps.iter().map(|&h| limits.heaps[h].0).max().unwrap_or(0);
    if bytes > largest {
        return refuse("the largest memory heap it may use", largest);
    }
    if let Some(budgets) = budgets {
        let available = heaps
            .iter()
            .filter_map(|&h| budgets.get(h).copied())
            .max()
            .unwrap_or(u64::MAX);
        if bytes > available {
            return refuse(
                "the memory still available in the heap's budget (VK_EXT_memory_budget)",
                available,
            );
        }
    }
    Ok(())
}

/// Checks `requirements` of the request `name` against the device behind `shared`.
fn check_requirements(
    shared: &DeviceShared,
    name: &str,
    requirements: &vk::MemoryRequirements,
    location: MemoryLocation,
) -> Result<()> {
    let budgets = shared.heap_budgets();
    check_request(
        name,
        requirements.size,
        requirements.memory_type_bits,
        location == MemoryLocation::GpuOnly,
        &shared.info.memory,
        budgets.as_deref(),
    )
}

impl super::GpuContext {
    /// Checks, before any voxel exists, that a single-texture volume of `dims` voxels of
    /// `bytes_per_voxel` bytes can be created on this device: each side against
    /// `maxImageDimension3D`, and its bytes (texels x bytes per voxel; the driver's exact
    /// requirement, larger where it pads, is checked again when the image is created) against
    /// `maxMemoryAllocationSize`, the largest device-local heap and the heap budget. A host
    /// calls it before generating or reading a volume it will draw as one texture, so a volume
    /// the device cannot hold is refused at once rather than after minutes of work. Errors name
    /// the request (`name`) and the limit: [`Error::GpuMemoryLimit`], or
    /// [`Error::Unsupported`] for a side over the dimension limit.
    pub fn check_volume_texture(
        &self,
        name: &str,
        dims: glam::UVec3,
        bytes_per_voxel: u64,
    ) -> Result<()> {
        let max = self.shared.info.limits.max_image_dimension3_d;
        if dims.max_element() > max {
            return Err(Error::Unsupported(format!(
                "image '{name}' extent {:?} exceeds the device's maxImageDimension3D {max}: use \
                 smaller dims, or draw the volume through the brick cache",
                dims.to_array()
            )));
        }
        let bytes = u64::from(dims.x)
            .saturating_mul(u64::from(dims.y))
            .saturating_mul(u64::from(dims.z))
            .saturating_mul(bytes_per_voxel);
        let budgets = self.shared.heap_budgets();
        check_request(
            name,
            bytes,
            u32::MAX,
            true,
            &self.shared.info.memory,
            budgets.as_deref(),
        )
    }
}

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
        if let Err(e) = check_requirements(shared, name, &requirements, location) {
            // SAFETY: the buffer is unused and unbound.
            unsafe { device.destroy_buffer(raw, None) };
            return Err(e);
        }
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
        if let Err(e) = check_requirements(shared, name, &requirements, MemoryLocation::GpuOnly) {
            // SAFETY: the image is unused and unbound.
            unsafe { device.destroy_image(raw, None) };
            return Err(e);
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{ContextDesc, GpuContext};

    /// One device-local heap of 4 GiB (type 0) and one host heap of 8 GiB (type 1), at most
    /// 1 GiB per allocation.
    fn fake() -> MemoryLimits {
        MemoryLimits {
            max_allocation_bytes: 1 << 30,
            allocation_capped: false,
            heaps: vec![(4 << 30, true), (8 << 30, false)],
            types: vec![
                (vk::MemoryPropertyFlags::DEVICE_LOCAL, 0),
                (vk::MemoryPropertyFlags::HOST_VISIBLE, 1),
            ],
            budget_extension: true,
        }
    }

    fn limit_of(r: Result<()>) -> Option<(&'static str, u64)> {
        match r {
            Ok(()) => None,
            Err(Error::GpuMemoryLimit {
                limit_name, limit, ..
            }) => Some((limit_name, limit)),
            Err(e) => panic!("unexpected error {e}"),
        }
    }

    #[test]
    fn requests_are_checked_against_the_allocation_size_heaps_and_budget() {
        let l = fake();
        // Within every limit.
        assert_eq!(
            limit_of(check_request("a", 1 << 20, 0b11, true, &l, None)),
            None
        );
        // Over maxMemoryAllocationSize: refused whatever the heaps say.
        assert_eq!(
            limit_of(check_request("a", (1 << 30) + 1, 0b11, true, &l, None)),
            Some(("maxMemoryAllocationSize", 1 << 30))
        );
        // Over the only heap it may use (with no per-allocation limit).
        let mut l2 = fake();
        l2.max_allocation_bytes = 0;
        assert_eq!(
            limit_of(check_request("a", 5 << 30, 0b01, true, &l2, None)),
            Some(("the largest memory heap it may use", 4 << 30))
        );
        // A host-visible request may use the 8 GiB heap.
        assert_eq!(
            limit_of(check_request("a", 5 << 30, 0b10, false, &l2, None)),
            None
        );
        // Over what the budget leaves in the heap.
        assert_eq!(
            limit_of(check_request(
                "a",
                600 << 20,
                0b01,
                true,
                &l,
                Some(&[512 << 20, 0])
            )),
            Some((
                "the memory still available in the heap's budget (VK_EXT_memory_budget)",
                512 << 20
            ))
        );
        // The message names the request, the size and the limit.
        let e = check_request("volume", 3 << 30, 0b01, true, &l, None).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("'volume'")
                && text.contains(&(3u64 << 30).to_string())
                && text.contains("maxMemoryAllocationSize")
                && text.contains(&(1u64 << 30).to_string()),
            "{text}"
        );
    }

    /// The pre-check of a volume texture refuses what the device cannot hold, naming the
    /// limit, before any voxel exists; what fits passes.
    #[test]
    fn a_volume_texture_is_checked_before_it_exists() {
        let ctx = GpuContext::new(&ContextDesc::default()).unwrap();
        let max = ctx.shared.info.memory.max_allocation_bytes;
        let max_dim = ctx.shared.info.limits.max_image_dimension3_d;
        ctx.check_volume_texture("volume", glam::UVec3::splat(64), 4)
            .unwrap();
        // The smallest u8 cube over maxMemoryAllocationSize.
        let edge = (max as f64).cbrt().ceil() as u32 + 1;
        assert!(edge <= max_dim);
        match ctx.check_volume_texture("volume", glam::UVec3::splat(edge), 1) {
            Err(Error::GpuMemoryLimit {
                name,
                bytes,
                limit_name,
                limit,
            }) => {
                assert_eq!(name, "volume");
                assert_eq!(bytes, u64::from(edge).pow(3));
                assert_eq!((limit_name, limit), ("maxMemoryAllocationSize", max));
            }
            other => panic!("expected GpuMemoryLimit, got {other:?}"),
        }
        let long = glam::UVec3::new(max_dim + 1, 1, 1);
        let e = ctx.check_volume_texture("volume", long, 1).unwrap_err();
        assert!(e.to_string().contains("maxImageDimension3D"), "{e}");
        assert_eq!(ctx.live_allocation_count(), 0);
    }

    /// A real image over the device's maxMemoryAllocationSize (created, never allocated) is
    /// refused with the typed error; nothing leaks and validation stays silent.
    #[test]
    fn an_image_over_the_allocation_limit_is_refused_before_allocating() {
        let ctx = GpuContext::new(&ContextDesc {
            validation: true,
            device_name: None,
        })
        .unwrap();
        let log = ctx.message_log();
        let max = ctx.shared.info.memory.max_allocation_bytes;
        let max_dim = ctx.shared.info.limits.max_image_dimension3_d;
        assert!(max > 0, "maxMemoryAllocationSize not queried");
        // The smallest R32 cube over the limit, if the device allows one that large.
        let edge = ((max / 4) as f64).cbrt().ceil() as u32 + 1;
        assert!(edge <= max_dim, "no 3D image can exceed {max} bytes here");
        let desc = ImageDesc::new_3d(
            vk::Format::R32_SFLOAT,
            [edge, edge, edge],
            vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
        );
        match Image::new(&ctx.shared, "huge volume", desc) {
            Err(Error::GpuMemoryLimit {
                name,
                bytes,
                limit_name,
                limit,
            }) => {
                assert_eq!(name, "huge volume");
                assert!(bytes > max, "{bytes} <= {max}");
                assert_eq!((limit_name, limit), ("maxMemoryAllocationSize", max));
            }
            Err(e) => panic!("expected GpuMemoryLimit, got {e}"),
            Ok(_) => panic!("an image of {edge}^3 R32 texels was allocated"),
        }
        assert_eq!(ctx.live_allocation_count(), 0);
        drop(ctx);
        let problems = log.warnings_and_errors();
        assert!(problems.is_empty(), "{problems:?}");
    }
}
