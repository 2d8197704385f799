//! The brick cache on the GPU: one 3D image (copy destination, storage image in GENERAL layout for
//! the fixup, sampled read-only by the ray-caster), the layout / neighbour / reverse tables and the fixup
//! job list as storage buffers, and the fixup compute pass. Conventions: `docs/cache-layout.md`.

use super::commands::{image_barrier, Access, Submitter};
use super::compute::{ComputePipeline, ComputeResource};
use super::context::DeviceShared;
use super::descriptors::Sampler;
use super::memory::{Buffer, Image, ImageDesc, COLOR_LAYERS};
use crate::error::{Error, Result};
use crate::volume::ScalarType;
use ash::vk;
use glam::UVec3;
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// The storage format of a cache for `scalar` volumes, and its GLSL image format qualifier.
pub(crate) fn cache_format(scalar: ScalarType) -> (vk::Format, &'static str) {
    match scalar {
        ScalarType::U8 => (vk::Format::R8_UNORM, "r8"),
        ScalarType::U16 => (vk::Format::R16_UNORM, "r16"),
        ScalarType::F32 => (vk::Format::R32_SFLOAT, "r32f"),
    }
}

/// One brick's worth of texels to copy into the cache.
pub(crate) struct CacheRegion<'a> {
    /// Destination texel origin.
    pub(crate) origin: UVec3,
    /// Extent in texels.
    pub(crate) extent: UVec3,
    /// Texel bytes in the cache format, x fastest.
    pub(crate) bytes: &'a [u8],
}

/// The tables the fixup and the ray-caster read (see `docs/cache-layout.md`).
pub(crate) struct CacheTables<'a> {
    pub(crate) layout: &'a [[f32; 4]],
    pub(crate) neighbours: &'a [u32],
    pub(crate) reverse: &'a [[u32; 8]],
    pub(crate) fixup_slots: &'a [u32],
    pub(crate) bricks: UVec3,
    pub(crate) brick_size: u32,
    pub(crate) slots_per_axis: UVec3,
}

/// Push constants of `fixup.comp`.
#[repr(C)]
#[derive(Copy, Clone, bytemuck::Pod, bytemuck::Zeroable)]
struct FixupPush {
    bricks: [i32; 4],
    slots_per_axis: [i32; 4],
}

/// A host-visible storage buffer that grows when needed.
fn table_buffer(
    shared: &Arc<DeviceShared>,
    slot: &mut Option<Buffer>,
    name: &str,
    bytes: &[u8],
) -> Result<()> {
    let size = (bytes.len() as u64).max(16);
    if slot.as_ref().is_none_or(|b| b.size < size) {
        *slot = Some(Buffer::new(
            shared,
            name,
            size.next_power_of_two(),
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?);
    }
    let buffer = slot.as_mut().expect("created above");
    buffer.mapped_mut()?[..bytes.len()].copy_from_slice(bytes);
    Ok(())
}

/// The GPU brick cache.
pub(crate) struct GpuBrickCache {
    pub(crate) image: Image,
    pub(crate) extent: UVec3,
    pub(crate) bytes_per_texel: usize,
    pub(crate) layout: Option<Buffer>,
    pub(crate) neighbours: Option<Buffer>,
    reverse: Option<Buffer>,
    jobs: Option<Buffer>,
    fixup: ComputePipeline,
    initialized: bool,
    shared: Arc<DeviceShared>,
}

impl GpuBrickCache {
    /// Creates the cache image (`extent` texels) for `scalar` data and the fixup pipeline.
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        scalar: ScalarType,
        extent: UVec3,
    ) -> Result<Self> {
        let (format, glsl_format) = cache_format(scalar);
        if scalar != ScalarType::F32 && !shared.info.storage_image_extended_formats {
            return Err(Error::Unsupported(format!(
                "the fixup pass writes {format:?} as a storage image, which needs \
                 shaderStorageImageExtendedFormats"
            )));
        }
        shared.require_format(
            format,
            vk::FormatFeatureFlags::SAMPLED_IMAGE
                | vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
                | vk::FormatFeatureFlags::STORAGE_IMAGE
                | vk::FormatFeatureFlags::TRANSFER_DST
                | vk::FormatFeatureFlags::TRANSFER_SRC,
            "brick cache",
        )?;
        let image = Image::new(
            shared,
            "brick cache",
            ImageDesc::new_3d(
                format,
                extent.to_array(),
                vk::ImageUsageFlags::SAMPLED
                    | vk::ImageUsageFlags::STORAGE
                    | vk::ImageUsageFlags::TRANSFER_DST
                    | vk::ImageUsageFlags::TRANSFER_SRC,
            ),
        )?;
        let fixup = ComputePipeline::new(
            shared,
            "fixup.comp",
            &[("CACHE_IMAGE_FORMAT", glsl_format.to_string())],
            &[
                vk::DescriptorType::STORAGE_IMAGE,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
            ],
            std::mem::size_of::<FixupPush>() as u32,
        )?;
        Ok(Self {
            image,
            extent,
            bytes_per_texel: scalar.size_bytes(),
            layout: None,
            neighbours: None,
            reverse: None,
            jobs: None,
            fixup,
            initialized: false,
            shared: shared.clone(),
        })
    }

    /// Writes the tables, copies `regions` into the cache with ONE vkCmdCopyBufferToImage (one
    /// region per brick) and runs the fixup over `tables.fixup_slots`, all in one submission.
    /// Leaves the cache ready for fragment-shader sampling.
    pub(crate) fn update(
        &mut self,
        submitter: &mut Submitter,
        regions: &[CacheRegion],
        tables: &CacheTables,
        smooth: bool,
    ) -> Result<()> {
        let shared = &self.shared;
        table_buffer(
            shared,
            &mut self.layout,
            "layout table",
            bytemuck::cast_slice(tables.layout),
        )?;
        table_buffer(
            shared,
            &mut self.neighbours,
            "neighbour table",
            bytemuck::cast_slice(tables.neighbours),
        )?;
        table_buffer(
            shared,
            &mut self.reverse,
            "reverse table",
            bytemuck::cast_slice(tables.reverse),
        )?;
        table_buffer(
            shared,
            &mut self.jobs,
            "fixup jobs",
            bytemuck::cast_slice(tables.fixup_slots),
        )?;
        let total: usize = regions.iter().map(|r| r.bytes.len()).sum();
        let mut staging = None;
        let mut copies = Vec::with_capacity(regions.len());
        if total > 0 {
            let mut buffer = Buffer::new(
                shared,
                "brick staging",
                total as u64,
                vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::CpuToGpu,
            )?;
            let mapped = buffer.mapped_mut()?;
            let mut offset = 0usize;
            for r in regions {
                let expected =
                    (r.extent.x * r.extent.y * r.extent.z) as usize * self.bytes_per_texel;
                if r.bytes.len() != expected {
                    return Err(Error::InvalidInput(format!(
                        "brick region {:?} holds {} bytes, expected {expected}",
                        r.extent,
                        r.bytes.len()
                    )));
                }
                mapped[offset..offset + r.bytes.len()].copy_from_slice(r.bytes);
                copies.push(
                    vk::BufferImageCopy::default()
                        .buffer_offset(offset as u64)
                        .image_subresource(COLOR_LAYERS)
                        .image_offset(vk::Offset3D {
                            x: r.origin.x as i32,
                            y: r.origin.y as i32,
                            z: r.origin.z as i32,
                        })
                        .image_extent(vk::Extent3D {
                            width: r.extent.x,
                            height: r.extent.y,
                            depth: r.extent.z,
                        }),
                );
                offset += r.bytes.len();
            }
            staging = Some(buffer);
        }
        let jobs = tables.fixup_slots.len() as u32;
        let run_fixup = smooth && jobs > 0;
        if run_fixup {
            self.fixup.write_descriptors(&[
                ComputeResource::StorageImage(self.image.view),
                ComputeResource::StorageBuffer(self.layout.as_ref().expect("written").raw),
                ComputeResource::StorageBuffer(self.neighbours.as_ref().expect("written").raw),
                ComputeResource::StorageBuffer(self.reverse.as_ref().expect("written").raw),
                ComputeResource::StorageBuffer(self.jobs.as_ref().expect("written").raw),
            ]);
        }
        let max_groups = shared.info.limits.max_compute_work_group_count[2];
        if jobs.saturating_mul(6) > max_groups {
            return Err(Error::Unsupported(format!(
                "{jobs} fixup jobs exceed maxComputeWorkGroupCount[2] = {max_groups}"
            )));
        }
        let push = FixupPush {
            bricks: [
                tables.bricks.x as i32,
                tables.bricks.y as i32,
                tables.bricks.z as i32,
                tables.brick_size as i32,
            ],
            slots_per_axis: [
                tables.slots_per_axis.x as i32,
                tables.slots_per_axis.y as i32,
                tables.slots_per_axis.z as i32,
                jobs as i32,
            ],
        };
        let groups_xy = (tables.brick_size + 2).div_ceil(8);
        let image = self.image.raw;
        let previous = if self.initialized {
            Access::FragmentSampled
        } else {
            Access::Nothing
        };
        let fixup = &self.fixup;
        submitter.run(|device, cmd| {
            image_barrier(device, cmd, image, previous, Access::TransferWrite);
            if let Some(staging) = &staging {
                // SAFETY: the staging buffer holds every region at its offset; the cache is in
                // TRANSFER_DST_OPTIMAL after the barrier.
                unsafe {
                    device.cmd_copy_buffer_to_image(
                        cmd,
                        staging.raw,
                        image,
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        &copies,
                    )
                };
            }
            if run_fixup {
                image_barrier(
                    device,
                    cmd,
                    image,
                    Access::TransferWrite,
                    Access::CacheComputeReadWrite,
                );
                fixup.record_dispatch(
                    cmd,
                    bytemuck::bytes_of(&push),
                    [groups_xy, groups_xy, jobs * 6],
                );
                image_barrier(
                    device,
                    cmd,
                    image,
                    Access::CacheComputeReadWrite,
                    Access::FragmentSampled,
                );
            } else {
                image_barrier(
                    device,
                    cmd,
                    image,
                    Access::TransferWrite,
                    Access::FragmentSampled,
                );
            }
            Ok(())
        })?;
        self.initialized = true;
        Ok(())
    }

    /// Reads the whole cache image back (for tests): texel bytes, x fastest.
    pub(crate) fn read_back(&self, submitter: &mut Submitter) -> Result<Vec<u8>> {
        let size = self.extent.x as u64
            * self.extent.y as u64
            * self.extent.z as u64
            * self.bytes_per_texel as u64;
        let readback = Buffer::new(
            &self.shared,
            "cache readback",
            size,
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        let image = self.image.raw;
        let copy = vk::BufferImageCopy::default()
            .image_subresource(COLOR_LAYERS)
            .image_extent(self.image.desc.extent);
        submitter.run(|device, cmd| {
            image_barrier(
                device,
                cmd,
                image,
                Access::FragmentSampled,
                Access::TransferRead,
            );
            // SAFETY: the buffer holds the whole image, in TRANSFER_SRC_OPTIMAL after the barrier.
            unsafe {
                device.cmd_copy_image_to_buffer(
                    cmd,
                    image,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    readback.raw,
                    &[copy],
                )
            };
            image_barrier(
                device,
                cmd,
                image,
                Access::TransferRead,
                Access::FragmentSampled,
            );
            super::commands::memory_barrier(device, cmd, Access::TransferWrite, Access::HostRead);
            Ok(())
        })?;
        Ok(readback.mapped()?.to_vec())
    }
}

/// Push constants of `probe.comp`.
#[repr(C)]
#[derive(Copy, Clone, bytemuck::Pod, bytemuck::Zeroable)]
struct ProbePush {
    volume_dims: [f32; 4],
    cache_extent_inv: [f32; 4],
}

/// Samples the GPU-reconstructed field at volume points (hi-res voxel units) with the ray-caster's
/// own functions (`probe.comp` includes `mixed.glsl`).
pub(crate) struct FieldProbe {
    pipeline: ComputePipeline,
    sampler: Sampler,
    shared: Arc<DeviceShared>,
}

impl FieldProbe {
    pub(crate) fn new(shared: &Arc<DeviceShared>, smooth: bool) -> Result<Self> {
        let mut defines = vec![];
        if smooth {
            defines.push(("SMOOTH_TRANSITIONS", "1".to_string()));
        }
        let pipeline = ComputePipeline::new(
            shared,
            "probe.comp",
            &defines,
            &[
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
            ],
            std::mem::size_of::<ProbePush>() as u32,
        )?;
        let sampler = Sampler::linear_clamp(shared)?;
        Ok(Self {
            pipeline,
            sampler,
            shared: shared.clone(),
        })
    }

    /// Values at `points`; `None` where the point lies in an absent brick.
    pub(crate) fn sample(
        &self,
        submitter: &mut Submitter,
        cache: &GpuBrickCache,
        volume_dims: UVec3,
        brick_size: u32,
        points: &[glam::Vec3],
    ) -> Result<Vec<Option<f32>>> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let shared = &self.shared;
        let packed: Vec<[f32; 4]> = points.iter().map(|p| p.extend(0.0).to_array()).collect();
        let mut input = None;
        table_buffer(
            shared,
            &mut input,
            "probe points",
            bytemuck::cast_slice(&packed),
        )?;
        let output = Buffer::new(
            shared,
            "probe values",
            (points.len() * 8) as u64,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::GpuToCpu,
        )?;
        let (Some(layout), Some(neighbours), Some(input)) =
            (&cache.layout, &cache.neighbours, &input)
        else {
            return Err(Error::InvalidInput(
                "probe before the first cache update".into(),
            ));
        };
        self.pipeline.write_descriptors(&[
            ComputeResource::SampledImage(cache.image.view, self.sampler.raw),
            ComputeResource::StorageBuffer(layout.raw),
            ComputeResource::StorageBuffer(neighbours.raw),
            ComputeResource::StorageBuffer(input.raw),
            ComputeResource::StorageBuffer(output.raw),
        ]);
        let push = ProbePush {
            volume_dims: volume_dims.as_vec3().extend(brick_size as f32).to_array(),
            cache_extent_inv: (glam::Vec3::ONE / cache.extent.as_vec3())
                .extend(points.len() as f32)
                .to_array(),
        };
        let image = cache.image.raw;
        let pipeline = &self.pipeline;
        submitter.run(|device, cmd| {
            image_barrier(
                device,
                cmd,
                image,
                Access::FragmentSampled,
                Access::ComputeSampled,
            );
            pipeline.record_dispatch(
                cmd,
                bytemuck::bytes_of(&push),
                [(points.len() as u32).div_ceil(64), 1, 1],
            );
            image_barrier(
                device,
                cmd,
                image,
                Access::ComputeSampled,
                Access::FragmentSampled,
            );
            super::commands::memory_barrier(device, cmd, Access::ComputeWrite, Access::HostRead);
            Ok(())
        })?;
        let values: Vec<[f32; 2]> =
            bytemuck::pod_collect_to_vec(&output.mapped()?[..points.len() * 8]);
        Ok(values
            .into_iter()
            .map(|[v, present]| (present > 0.5).then_some(v))
            .collect())
    }
}
