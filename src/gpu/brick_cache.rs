//! The brick cache on the GPU: one 3D image (copy destination, storage image in GENERAL layout for
//! the fixup, sampled read-only by the ray-caster), the layout / neighbour / reverse tables and the fixup
//! job list as storage buffers, and the fixup compute pass. Conventions: `docs/cache-layout.md`.
//! A cache of the three-level packing ([`SlotPacking::ThreeLevel`]) also runs the skeleton fixup
//! (`skeleton_fixup.comp`) over its level-1 and level-2 bricks.

use super::commands::{image_barrier, Access, Submitter, TimestampPool};
use super::compute::{ComputePipeline, ComputeResource};
use super::context::DeviceShared;
use super::descriptors::Sampler;
use super::memory::{Buffer, Image, ImageDesc};
use super::shared_defs::{
    FixupPush, ProbePush, FIXUP_BINDING_CACHE, FIXUP_BINDING_JOBS, FIXUP_BINDING_LAYOUT_TABLE,
    FIXUP_BINDING_NEIGHBOUR_TABLE, FIXUP_BINDING_REVERSE_TABLE, FIXUP_FACES_PER_JOB,
    FIXUP_GROUP_SIZE, PROBE_BINDING_CACHE, PROBE_BINDING_LAYOUT_TABLE,
    PROBE_BINDING_NEIGHBOUR_TABLE, PROBE_BINDING_POINTS, PROBE_BINDING_VALUES, PROBE_GROUP_SIZE,
};
use super::upload::{record_image_readback, CopyRegion, StagingUpload};
use crate::bricks::SUB_SLOTS_PER_SLOT;
use crate::error::{Error, Result};
use crate::volume::ScalarType;
use ash::vk;
use bytemuck::Zeroable;
use glam::UVec3;
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// The storage format of a cache for `scalar` volumes with `channels` channels (1, or 4 for
/// RGBA f32), and its GLSL image format qualifier.
pub(crate) fn cache_format(
    scalar: ScalarType,
    channels: u32,
) -> Result<(vk::Format, &'static str)> {
    Ok(match (scalar, channels) {
        (ScalarType::U8, 1) => (vk::Format::R8_UNORM, "r8"),
        (ScalarType::U16, 1) => (vk::Format::R16_UNORM, "r16"),
        (ScalarType::F32, 1) => (vk::Format::R32_SFLOAT, "r32f"),
        (ScalarType::F32, 4) => (vk::Format::R32G32B32A32_SFLOAT, "rgba32f"),
        _ => {
            return Err(Error::Unsupported(format!(
                "brick caches hold 1-channel u8/u16/f32 or 4-channel f32 texels, not {channels} x {scalar:?}"
            )))
        }
    })
}

/// How a cache packs its slots.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum SlotPacking {
    /// `(n+2)^3` slots holding a level-0 brick or eight level-1 bricks
    /// ([`crate::cache::CacheGeometry`], and a [`crate::cache::SlotGeometry`] of two classes).
    TwoLevel,
    /// `(n+4)^3` slots of the three-level packing (a [`crate::cache::SlotGeometry`] of three
    /// classes): the
    /// border fixup works on the inner `(n+2)^3` box of a level-0 slot, and the skeleton fixup
    /// runs over the bricks of the coarser levels.
    ThreeLevel,
}

impl SlotPacking {
    /// Border texels per side of a level-0 slot (`SLOT_BORDER` in fixup.comp).
    fn slot_border(self) -> u32 {
        match self {
            SlotPacking::TwoLevel => 1,
            SlotPacking::ThreeLevel => 2,
        }
    }
}

/// The descriptor bindings of a fixup pass: the cache as a storage image, the layout and neighbour
/// tables, the job list, and for `fixup.comp` (`reverse`) the reverse table, which
/// `skeleton_fixup.comp` does not read.
fn fixup_bindings(reverse: bool) -> Vec<(u32, vk::DescriptorType)> {
    let mut bindings = vec![
        (FIXUP_BINDING_CACHE, vk::DescriptorType::STORAGE_IMAGE),
        (
            FIXUP_BINDING_LAYOUT_TABLE,
            vk::DescriptorType::STORAGE_BUFFER,
        ),
        (
            FIXUP_BINDING_NEIGHBOUR_TABLE,
            vk::DescriptorType::STORAGE_BUFFER,
        ),
        (FIXUP_BINDING_JOBS, vk::DescriptorType::STORAGE_BUFFER),
    ];
    if reverse {
        bindings.push((
            FIXUP_BINDING_REVERSE_TABLE,
            vk::DescriptorType::STORAGE_BUFFER,
        ));
    }
    bindings
}

/// One reverse-table entry: the bricks in a cache slot (`SUB_SLOTS_PER_SLOT` words in GLSL).
type ReverseEntry = [u32; SUB_SLOTS_PER_SLOT as usize];

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
    pub(crate) reverse: &'a [ReverseEntry],
    pub(crate) fixup_slots: &'a [u32],
    /// Bricks of the coarser levels with a coarser neighbour (three-level packing only).
    pub(crate) skeleton_bricks: &'a [u32],
    pub(crate) bricks: UVec3,
    pub(crate) brick_size: u32,
    pub(crate) slots_per_axis: UVec3,
}

/// A host-visible storage buffer of at least `bytes` bytes (16 minimum).
fn host_buffer(shared: &Arc<DeviceShared>, name: &str, bytes: usize) -> Result<Buffer> {
    Buffer::new(
        shared,
        name,
        (bytes as u64).max(16),
        vk::BufferUsageFlags::STORAGE_BUFFER,
        MemoryLocation::CpuToGpu,
    )
}

/// Copies `bytes` to the start of a host-visible buffer.
fn write_buffer(buffer: &mut Buffer, bytes: &[u8]) -> Result<()> {
    let mapped = buffer.mapped_mut()?;
    if bytes.len() > mapped.len() {
        return Err(Error::InvalidInput(format!(
            "{} bytes do not fit a {}-byte table",
            bytes.len(),
            mapped.len()
        )));
    }
    mapped[..bytes.len()].copy_from_slice(bytes);
    Ok(())
}

/// One frame slot's copy of the tables: the GPU may still read an older slot while the CPU
/// writes this one.
struct SlotTables {
    layout: Buffer,
    neighbours: Buffer,
    reverse: Buffer,
    jobs: Buffer,
    skeleton_jobs: Buffer,
    version: u64,
}

/// The CPU copy of the current tables.
#[derive(Default)]
struct OwnedTables {
    layout: Vec<[f32; 4]>,
    neighbours: Vec<u32>,
    reverse: Vec<ReverseEntry>,
    fixup_slots: Vec<u32>,
    skeleton_bricks: Vec<u32>,
}

/// Brick bytes and copy regions waiting to be recorded.
struct PendingUpdate {
    bytes: Vec<u8>,
    copies: Vec<CopyRegion>,
    jobs: u32,
    skeleton_jobs: u32,
    push: FixupPush,
}

/// The GPU brick cache.
pub(crate) struct GpuBrickCache {
    pub(crate) image: Image,
    pub(crate) extent: UVec3,
    pub(crate) bytes_per_texel: usize,
    slots: Vec<SlotTables>,
    tables: OwnedTables,
    version: u64,
    pending: Option<PendingUpdate>,
    fixup: ComputePipeline,
    skeleton: Option<ComputePipeline>,
    smooth: bool,
    initialized: bool,
    shared: Arc<DeviceShared>,
}

impl GpuBrickCache {
    /// Creates the cache image (`extent` texels) for `scalar` data, per-frame tables for
    /// `brick_count` bricks and `slot_count` cache slots, and the fixup pipelines of `packing`.
    #[allow(clippy::too_many_arguments)] // reason: one argument per property of the cache.
    pub(crate) fn new(
        shared: &Arc<DeviceShared>,
        scalar: ScalarType,
        channels: u32,
        extent: UVec3,
        brick_count: usize,
        slot_count: usize,
        frames: u32,
        smooth: bool,
        packing: SlotPacking,
    ) -> Result<Self> {
        let (format, glsl_format) = cache_format(scalar, channels)?;
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
            &[
                ("CACHE_IMAGE_FORMAT", glsl_format.to_string()),
                ("SLOT_BORDER", packing.slot_border().to_string()),
            ],
            &fixup_bindings(true),
            std::mem::size_of::<FixupPush>() as u32,
            frames,
        )?;
        let skeleton = match packing {
            SlotPacking::TwoLevel => None,
            SlotPacking::ThreeLevel => Some(ComputePipeline::new(
                shared,
                "skeleton_fixup.comp",
                &[("CACHE_IMAGE_FORMAT", glsl_format.to_string())],
                &fixup_bindings(false),
                std::mem::size_of::<FixupPush>() as u32,
                frames,
            )?),
        };
        let skeleton_capacity = if skeleton.is_some() { brick_count } else { 0 };
        let slots = (0..frames)
            .map(|_| {
                Ok(SlotTables {
                    layout: host_buffer(shared, "layout table", brick_count * 16)?,
                    neighbours: host_buffer(shared, "neighbour table", brick_count * 4)?,
                    reverse: host_buffer(
                        shared,
                        "reverse table",
                        slot_count * std::mem::size_of::<ReverseEntry>(),
                    )?,
                    jobs: host_buffer(shared, "fixup jobs", slot_count * 4)?,
                    skeleton_jobs: host_buffer(shared, "skeleton jobs", skeleton_capacity * 4)?,
                    version: 0,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            image,
            extent,
            bytes_per_texel: scalar.size_bytes() * channels as usize,
            slots,
            tables: OwnedTables::default(),
            version: 0,
            pending: None,
            fixup,
            skeleton,
            smooth,
            initialized: false,
            shared: shared.clone(),
        })
    }

    /// Takes the tables and the bricks of one residency change; they reach the GPU with the
    /// next [`GpuBrickCache::record`]. A second call before that merges into the same update.
    pub(crate) fn stage(&mut self, regions: &[CacheRegion], tables: &CacheTables) -> Result<()> {
        let mut pending = self.pending.take().unwrap_or(PendingUpdate {
            bytes: Vec::new(),
            copies: Vec::new(),
            jobs: 0,
            skeleton_jobs: 0,
            push: FixupPush::zeroed(),
        });
        for r in regions {
            let expected = (r.extent.x * r.extent.y * r.extent.z) as usize * self.bytes_per_texel;
            if r.bytes.len() != expected {
                return Err(Error::InvalidInput(format!(
                    "brick region {:?} holds {} bytes, expected {expected}",
                    r.extent,
                    r.bytes.len()
                )));
            }
            // Regions are 4-byte aligned in the staging buffer (the copy offset rule for any
            // texel size we use).
            while !pending.bytes.len().is_multiple_of(4) {
                pending.bytes.push(0);
            }
            pending.copies.push(CopyRegion {
                buffer_offset: pending.bytes.len() as u64,
                origin: r.origin.to_array(),
                extent: r.extent.to_array(),
            });
            pending.bytes.extend_from_slice(r.bytes);
        }
        let jobs = tables.fixup_slots.len() as u32;
        let skeleton_jobs = tables.skeleton_bricks.len() as u32;
        if skeleton_jobs > 0 && self.skeleton.is_none() {
            return Err(Error::InvalidInput(
                "skeleton fixup jobs for a cache without the three-level packing".into(),
            ));
        }
        let max_groups = self.shared.info.limits.max_compute_work_group_count[2];
        if jobs.max(skeleton_jobs).saturating_mul(FIXUP_FACES_PER_JOB) > max_groups {
            return Err(Error::Unsupported(format!(
                "{} fixup jobs exceed maxComputeWorkGroupCount[2] = {max_groups}",
                jobs.max(skeleton_jobs)
            )));
        }
        pending.jobs = jobs;
        pending.skeleton_jobs = skeleton_jobs;
        pending.push = FixupPush {
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
        self.tables = OwnedTables {
            layout: tables.layout.to_vec(),
            neighbours: tables.neighbours.to_vec(),
            reverse: tables.reverse.to_vec(),
            fixup_slots: tables.fixup_slots.to_vec(),
            skeleton_bricks: tables.skeleton_bricks.to_vec(),
        };
        self.version += 1;
        self.pending = Some(pending);
        Ok(())
    }

    /// Brings frame slot `frame`'s table copy up to date (the GPU must be done with that slot).
    pub(crate) fn sync_slot(&mut self, frame: usize) -> Result<()> {
        let slot = &mut self.slots[frame];
        if slot.version != self.version {
            write_buffer(&mut slot.layout, bytemuck::cast_slice(&self.tables.layout))?;
            write_buffer(
                &mut slot.neighbours,
                bytemuck::cast_slice(&self.tables.neighbours),
            )?;
            write_buffer(
                &mut slot.reverse,
                bytemuck::cast_slice(&self.tables.reverse),
            )?;
            write_buffer(
                &mut slot.jobs,
                bytemuck::cast_slice(&self.tables.fixup_slots),
            )?;
            write_buffer(
                &mut slot.skeleton_jobs,
                bytemuck::cast_slice(&self.tables.skeleton_bricks),
            )?;
            slot.version = self.version;
        }
        Ok(())
    }

    /// The layout and neighbour tables of frame slot `frame`, for the ray-caster's descriptors.
    pub(crate) fn slot_tables(&self, frame: usize) -> (vk::Buffer, vk::Buffer) {
        (
            self.slots[frame].layout.raw,
            self.slots[frame].neighbours.raw,
        )
    }

    /// Drops a staged update that was not recorded (its regions and jobs); the tables keep
    /// what was staged last, so a new update must be staged before the next frame.
    pub(crate) fn discard_pending(&mut self) {
        self.pending = None;
    }

    /// True when a staged update waits to be recorded.
    pub(crate) fn has_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Records the staged update into `cmd` for frame slot `frame`: the bricks through `staging`
    /// (grown as needed; the GPU must be done with it) with ONE vkCmdCopyBufferToImage, one region
    /// per brick, then the fixup over the hi-res bricks with low-res neighbours. Between two
    /// timestamps of `queries` (upload end at the given index, fixup end at the next) when given.
    /// Leaves the cache ready for fragment-shader sampling. Returns false when nothing was staged.
    pub(crate) fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: usize,
        staging: &mut StagingUpload,
        queries: Option<(&TimestampPool, u32)>,
    ) -> Result<bool> {
        let Some(pending) = self.pending.take() else {
            return Ok(false);
        };
        self.sync_slot(frame)?;
        let previous = if self.initialized {
            Access::FragmentSampled
        } else {
            Access::Nothing
        };
        let fixup = self.smooth && (pending.jobs > 0 || pending.skeleton_jobs > 0);
        let after_copy = if fixup {
            Access::CacheComputeReadWrite
        } else {
            Access::FragmentSampled
        };
        staging.record(
            cmd,
            &self.image,
            &pending.bytes,
            &pending.copies,
            previous,
            after_copy,
        )?;
        let write_timestamp = |index: u32| {
            if let Some((pool, base)) = queries {
                pool.write(cmd, base + index);
            }
        };
        write_timestamp(0);
        if fixup && pending.jobs > 0 {
            let slot = &self.slots[frame];
            self.fixup.write_descriptors(
                frame,
                &self.fixup_resources(slot, slot.jobs.raw, Some(slot.reverse.raw)),
            );
            // A brick face with its border: n + 2 texels a side.
            let groups_xy = (pending.push.bricks[3] as u32 + 2).div_ceil(FIXUP_GROUP_SIZE);
            self.fixup.record_dispatch(
                cmd,
                frame,
                bytemuck::bytes_of(&pending.push),
                [groups_xy, groups_xy, pending.jobs * FIXUP_FACES_PER_JOB],
            );
        }
        if let (true, Some(skeleton)) = (fixup && pending.skeleton_jobs > 0, &self.skeleton) {
            if pending.jobs > 0 {
                // The passes touch disjoint texels (`reference::level_cache`), but both write the
                // image: order them.
                image_barrier(
                    &self.shared.device,
                    cmd,
                    self.image.raw,
                    Access::CacheComputeReadWrite,
                    Access::CacheComputeReadWrite,
                );
            }
            let slot = &self.slots[frame];
            skeleton.write_descriptors(
                frame,
                &self.fixup_resources(slot, slot.skeleton_jobs.raw, None),
            );
            // A level-1 brick face: n/2 + 1 samples a side (level-2 jobs use fewer).
            let groups_xy = (pending.push.bricks[3] as u32 / 2 + 1).div_ceil(FIXUP_GROUP_SIZE);
            let mut push = pending.push;
            push.slots_per_axis[3] = pending.skeleton_jobs as i32;
            skeleton.record_dispatch(
                cmd,
                frame,
                bytemuck::bytes_of(&push),
                [
                    groups_xy,
                    groups_xy,
                    pending.skeleton_jobs * FIXUP_FACES_PER_JOB,
                ],
            );
        }
        if fixup {
            image_barrier(
                &self.shared.device,
                cmd,
                self.image.raw,
                Access::CacheComputeReadWrite,
                Access::FragmentSampled,
            );
        }
        write_timestamp(1);
        self.initialized = true;
        Ok(true)
    }

    /// The resources of [`fixup_bindings`] for frame slot tables `slot`: the job list `jobs`,
    /// and the reverse table where the pass reads it.
    fn fixup_resources(
        &self,
        slot: &SlotTables,
        jobs: vk::Buffer,
        reverse: Option<vk::Buffer>,
    ) -> Vec<(u32, ComputeResource)> {
        let mut resources = vec![
            (
                FIXUP_BINDING_CACHE,
                ComputeResource::StorageImage(self.image.view),
            ),
            (
                FIXUP_BINDING_LAYOUT_TABLE,
                ComputeResource::StorageBuffer(slot.layout.raw),
            ),
            (
                FIXUP_BINDING_NEIGHBOUR_TABLE,
                ComputeResource::StorageBuffer(slot.neighbours.raw),
            ),
            (FIXUP_BINDING_JOBS, ComputeResource::StorageBuffer(jobs)),
        ];
        if let Some(reverse) = reverse {
            resources.push((
                FIXUP_BINDING_REVERSE_TABLE,
                ComputeResource::StorageBuffer(reverse),
            ));
        }
        resources
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
        let image = &self.image;
        submitter.run(|device, cmd| {
            record_image_readback(
                device,
                cmd,
                image,
                &readback,
                Access::FragmentSampled,
                Some(Access::FragmentSampled),
            )
        })?;
        Ok(readback.mapped()?.to_vec())
    }
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
                (
                    PROBE_BINDING_CACHE,
                    vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                ),
                (
                    PROBE_BINDING_LAYOUT_TABLE,
                    vk::DescriptorType::STORAGE_BUFFER,
                ),
                (
                    PROBE_BINDING_NEIGHBOUR_TABLE,
                    vk::DescriptorType::STORAGE_BUFFER,
                ),
                (PROBE_BINDING_POINTS, vk::DescriptorType::STORAGE_BUFFER),
                (PROBE_BINDING_VALUES, vk::DescriptorType::STORAGE_BUFFER),
            ],
            std::mem::size_of::<ProbePush>() as u32,
            1,
        )?;
        let sampler = Sampler::linear_clamp(shared)?;
        Ok(Self {
            pipeline,
            sampler,
            shared: shared.clone(),
        })
    }

    /// Values at `points`; `None` where the point lies in an absent brick. Reads the tables of
    /// frame slot `frame` (synced first) and submits through `submitter`.
    pub(crate) fn sample(
        &self,
        submitter: &mut Submitter,
        cache: &mut GpuBrickCache,
        frame: usize,
        volume_dims: UVec3,
        brick_size: u32,
        points: &[glam::Vec3],
    ) -> Result<Vec<Option<f32>>> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let shared = &self.shared;
        let packed: Vec<[f32; 4]> = points.iter().map(|p| p.extend(0.0).to_array()).collect();
        let mut input = host_buffer(shared, "probe points", packed.len() * 16)?;
        write_buffer(&mut input, bytemuck::cast_slice(&packed))?;
        let output = Buffer::new(
            shared,
            "probe values",
            (points.len() * 8) as u64,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::GpuToCpu,
        )?;
        if !cache.initialized || cache.has_pending() {
            return Err(Error::InvalidInput(
                "probe before the cache update was recorded".into(),
            ));
        }
        cache.sync_slot(frame)?;
        let (layout, neighbours) = cache.slot_tables(frame);
        self.pipeline.write_descriptors(
            0,
            &[
                (
                    PROBE_BINDING_CACHE,
                    ComputeResource::SampledImage(cache.image.view, self.sampler.raw),
                ),
                (
                    PROBE_BINDING_LAYOUT_TABLE,
                    ComputeResource::StorageBuffer(layout),
                ),
                (
                    PROBE_BINDING_NEIGHBOUR_TABLE,
                    ComputeResource::StorageBuffer(neighbours),
                ),
                (
                    PROBE_BINDING_POINTS,
                    ComputeResource::StorageBuffer(input.raw),
                ),
                (
                    PROBE_BINDING_VALUES,
                    ComputeResource::StorageBuffer(output.raw),
                ),
            ],
        );
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
                0,
                bytemuck::bytes_of(&push),
                [(points.len() as u32).div_ceil(PROBE_GROUP_SIZE), 1, 1],
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
