//! Writing a brick store from a volume file read slab by slab ([`SlabReader`]), in bounded RAM.
//!
//! The bricks are written layer by layer (all bricks of one brick z index `bz`), in increasing z.
//! A layer's bricks need the z planes their hi-res windows (one voxel of border) and their
//! low-res filter taps reach, as [`BrickKernel::window_for`] gives them for the whole layer; the
//! writer holds exactly those planes (whole x-y planes) in one slab buffer of the reader's scalar
//! type. Moving to the next layer keeps the planes both layers need, and reads only the new ones,
//! so every plane is read once, in increasing z: a forward-only gzip stream is never asked to go
//! back. The layer's bricks are packed from the slab in place by the same kernel, workers and
//! chunks as [`super::write_store_from_volume`], so the store's bytes are identical to those of
//! the fully loaded volume (the value range too: it is folded over every plane as it is read).
//!
//! Memory ([`SlabPlan`]): the slab (the largest layer window: about `n + 2 + taps` planes of
//! `dims.x * dims.y` voxels), the reader's scratch ([`SlabReader::scratch_bytes`]), and per
//! worker thread the packed chunk (hi and low-res bricks, twice) plus the kernel's scratch. The
//! writer refuses, before creating anything, a budget that cannot hold the slab and one worker,
//! and uses only as many threads as the budget holds.

use super::writer::{assemble, layer_chunks, pack_chunks, Voxels, Worker};
use super::{StoreDesc, StoreError, WriteSummary};
use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, BrickBox, BrickGrid, BrickKernel, ValueRange,
    VoxelWindow,
};
use crate::volume::{ScalarType, SlabMut, SlabReader, VoxelData};
use glam::UVec3;
use std::ops::Range;
use std::path::Path;

/// How a slab write uses memory, worked out before anything is read or created
/// ([`plan_slab_write`]).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct SlabPlan {
    /// Most z planes held at once (the tallest layer window).
    pub planes: u32,
    /// Bytes of the slab buffer: `planes * dims.x * dims.y * voxel size`.
    pub slab_bytes: u64,
    /// Bytes the reader holds besides ([`SlabReader::scratch_bytes`]).
    pub reader_bytes: u64,
    /// Estimated bytes per worker thread (packed chunk and kernel scratch).
    pub worker_bytes: u64,
    /// Worker threads the budget allows (at most the cores available, at least 1).
    pub threads: usize,
    /// `slab_bytes + reader_bytes + threads * worker_bytes`: what the write holds at most.
    pub total_bytes: u64,
    /// The budget planned against.
    pub budget_bytes: u64,
}

/// The store description for `reader`'s volume: its dims, spacing and scalar type.
pub fn slab_store_desc(
    reader: &dyn SlabReader,
    brick_size: u32,
    filter: crate::bricks::DownsampleFilter,
) -> StoreDesc {
    StoreDesc {
        dims: reader.dims(),
        brick_size,
        scalar: reader.scalar(),
        spacing: reader.spacing(),
        filter,
    }
}

/// The z planes `z0..z1` each brick layer's bricks read.
fn layer_windows(grid: &BrickGrid, desc: &StoreDesc) -> Result<Vec<Range<u32>>, StoreError> {
    let kernel = BrickKernel::new(grid, desc.filter, desc.scalar);
    let b = grid.bricks_per_axis();
    (0..b.z)
        .map(|bz| {
            let layer = BrickBox {
                start: UVec3::new(0, 0, bz),
                end: UVec3::new(b.x, b.y, bz + 1),
            };
            let (origin, extent) =
                kernel
                    .window_for(&layer)
                    .map_err(|e| StoreError::InvalidDesc {
                        field: "brick",
                        message: e.to_string(),
                    })?;
            Ok(origin.z..origin.z + extent.z)
        })
        .collect()
}

/// Works out the memory of writing `desc` from a reader of `source` voxels holding
/// `reader_bytes` of scratch, under `budget_bytes`, with at most `max_threads` workers.
/// Errors: [`StoreError::InvalidDesc`] for an unusable description,
/// [`StoreError::RamBudget`] when the budget cannot hold the slab and one worker.
pub fn plan_slab_write(
    desc: &StoreDesc,
    source: ScalarType,
    reader_bytes: u64,
    budget_bytes: u64,
    max_threads: usize,
) -> Result<SlabPlan, StoreError> {
    let grid = super::writer::check_desc(desc)?;
    let windows = layer_windows(&grid, desc)?;
    let planes = windows.iter().map(|w| w.len() as u32).max().unwrap_or(0);
    let plane_bytes = u64::from(desc.dims.x) * u64::from(desc.dims.y) * source.size_bytes() as u64;
    let slab_bytes = plane_bytes.saturating_mul(u64::from(planes));
    let worker_bytes = worker_bytes(&grid, desc.scalar);
    let fixed = slab_bytes.saturating_add(reader_bytes);
    let room = budget_bytes.saturating_sub(fixed) / worker_bytes.max(1);
    if fixed.saturating_add(worker_bytes) > budget_bytes {
        return Err(StoreError::RamBudget {
            needed: fixed.saturating_add(worker_bytes),
            budget: budget_bytes,
            message: format!(
                "a slab of {planes} z planes of {}x{} {source:?} voxels ({} MiB) + the reader's \
                 {} MiB + one worker's {} MiB; raise the budget or use a smaller brick size",
                desc.dims.x,
                desc.dims.y,
                mib(slab_bytes),
                mib(reader_bytes),
                mib(worker_bytes)
            ),
        });
    }
    let threads = (room as usize).clamp(1, max_threads.max(1));
    Ok(SlabPlan {
        planes,
        slab_bytes,
        reader_bytes,
        worker_bytes,
        threads,
        total_bytes: fixed + threads as u64 * worker_bytes,
        budget_bytes,
    })
}

/// `bytes` in MiB, rounded up, for messages.
fn mib(bytes: u64) -> u64 {
    bytes.div_ceil(1 << 20)
}

/// Estimated peak bytes of one worker: its chunk's hi-res and low-res bricks (the kernel's output
/// and the interleaved copy written to the file, plus slack for the allocator), the kernel's f32
/// low-res block and its x-y filtered rows (each about the chunk's low-res samples, the rows once
/// per z tap: counted as four blocks), and 2 MiB for the rest (ranges, row tables, the thread's
/// stack, allocator slack).
fn worker_bytes(grid: &BrickGrid, storage: ScalarType) -> u64 {
    let n = grid.brick_size();
    let run = u64::from(layer_chunks(grid, 0).first().map_or(1, |c| c.bx1 - c.bx0));
    let texels =
        u64::from(hi_res_brick_extent(n)).pow(3) + u64::from(low_res_brick_extent(n)).pow(3);
    let bricks = 3 * run * texels * storage.size_bytes() as u64;
    let low_res = 4 * (run * u64::from(n / 2) + 3) * u64::from(n / 2 + 3).pow(2) * 4;
    bricks + low_res + (2 << 20)
}

/// Writes a brick store at `path` from `reader` (whose dims must be `desc.dims`), holding at most
/// about `ram_budget` bytes (see [`plan_slab_write`] and the [module docs](self)); like
/// [`super::write_store_from_volume`] it writes a fresh temporary file beside `path` and renames it at the end, and
/// removes it on any error. `progress(done, total)` gets brick counts on the calling thread.
///
/// With `desc.scalar == reader.scalar()` and `desc.spacing == reader.spacing()` (what
/// [`slab_store_desc`] gives) the file is byte for byte the one
/// [`super::write_store_from_volume`] writes from the loaded volume.
///
/// Errors: [`StoreError::RamBudget`] and [`StoreError::InvalidDesc`] before anything is created;
/// [`StoreError::Input`] when the reader fails (truncated or corrupt data, naming the file);
/// [`StoreError::Io`] for the store file.
pub fn write_store_from_slabs(
    path: &Path,
    desc: StoreDesc,
    reader: &mut dyn SlabReader,
    ram_budget: u64,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary, StoreError> {
    if reader.dims() != desc.dims {
        return Err(StoreError::InvalidDesc {
            field: "dims",
            message: format!(
                "{:?} but the input {} has {:?}",
                desc.dims.to_array(),
                reader.path().display(),
                reader.dims().to_array()
            ),
        });
    }
    let source = reader.scalar();
    let plan = plan_slab_write(
        &desc,
        source,
        reader.scratch_bytes(),
        ram_budget,
        crate::bricks::available_threads(),
    )?;
    let grid = super::writer::check_desc(&desc)?;
    let windows = layer_windows(&grid, &desc)?;
    let plane = desc.dims.x as usize * desc.dims.y as usize;
    let mut slab = empty_slab(source, plane * plan.planes as usize)?;
    assemble(path, desc, plan.threads, &mut |target| {
        let total = u64::from(target.header.brick_count);
        let mut ranges = vec![ValueRange::EMPTY; target.header.brick_count as usize];
        let mut crcs = vec![[0u32; 2]; target.header.brick_count as usize];
        let mut value_range = ValueRange::EMPTY;
        let mut done = 0u64;
        progress(0, total);
        let mut workers: Vec<Worker> = (0..plan.threads)
            .map(|_| Worker::new(target.grid, target.desc))
            .collect();
        // Planes held: `held.start .. held.end`, at the start of `slab`.
        let mut held = 0u32..0u32;
        for (bz, window) in windows.iter().enumerate() {
            let keep = window.start.max(held.start)..held.end.max(window.start);
            shift(
                &mut slab,
                (keep.start - held.start) as usize * plane,
                keep.len() * plane,
            );
            let fresh = keep.end..window.end;
            set_len(&mut slab, window.len() * plane);
            let at = keep.len() * plane;
            let out =
                SlabMut::of_range(&mut slab, at..at + fresh.len() * plane).ok_or_else(|| {
                    StoreError::InvalidDesc {
                        field: "dims",
                        message: "slab buffer smaller than a layer window".into(),
                    }
                })?;
            reader.read_slab(fresh.clone(), out)?;
            fold_range(&slab, at, &mut value_range);
            held = window.clone();
            let voxels = VoxelWindow::new(
                &slab,
                UVec3::new(0, 0, window.start),
                UVec3::new(desc.dims.x, desc.dims.y, window.len() as u32),
            )
            .map_err(|e| StoreError::InvalidDesc {
                field: "brick",
                message: e.to_string(),
            })?;
            let chunks = layer_chunks(target.grid, bz as u32);
            pack_chunks(
                target,
                Voxels::Window(voxels),
                &chunks,
                &mut workers,
                &mut |chunk| {
                    let first = chunk.first as usize;
                    ranges[first..first + chunk.ranges.len()].copy_from_slice(&chunk.ranges);
                    crcs[first..first + chunk.crcs.len()].copy_from_slice(&chunk.crcs);
                    done += chunk.ranges.len() as u64;
                    progress(done, total);
                },
            )?;
        }
        reader.finish()?;
        Ok((ranges, value_range, crcs))
    })
}

/// An empty slab of `source` voxels with room for `capacity` (reserved fallibly).
fn empty_slab(source: ScalarType, capacity: usize) -> Result<VoxelData, StoreError> {
    fn reserve<T>(capacity: usize) -> Result<Vec<T>, StoreError> {
        let mut v = Vec::new();
        v.try_reserve_exact(capacity)
            .map_err(|_| StoreError::RamBudget {
                needed: (capacity * std::mem::size_of::<T>()) as u64,
                budget: 0,
                message: "the allocator refused the slab buffer".into(),
            })?;
        Ok(v)
    }
    Ok(match source {
        ScalarType::U8 => VoxelData::U8(reserve(capacity)?),
        ScalarType::U16 => VoxelData::U16(reserve(capacity)?),
        ScalarType::F32 => VoxelData::F32(reserve(capacity)?),
    })
}

/// Moves voxels `from..from + len` of `slab` to its start.
fn shift(slab: &mut VoxelData, from: usize, len: usize) {
    match slab {
        VoxelData::U8(v) => v.copy_within(from..from + len, 0),
        VoxelData::U16(v) => v.copy_within(from..from + len, 0),
        VoxelData::F32(v) => v.copy_within(from..from + len, 0),
    }
}

/// Sets the slab's length to `len` voxels (within its capacity; new voxels are zero until read).
fn set_len(slab: &mut VoxelData, len: usize) {
    match slab {
        VoxelData::U8(v) => v.resize(len, 0),
        VoxelData::U16(v) => v.resize(len, 0),
        VoxelData::F32(v) => v.resize(len, 0.0),
    }
}

/// Folds the normalised values of voxels `from..` of `slab` into `range`.
fn fold_range(slab: &VoxelData, from: usize, range: &mut ValueRange) {
    let (lo, hi) = match slab {
        VoxelData::U8(v) => {
            minmax(&v[from..]).map(|(a, b)| (f32::from(a) / 255.0, f32::from(b) / 255.0))
        }
        VoxelData::U16(v) => {
            minmax(&v[from..]).map(|(a, b)| (f32::from(a) / 65535.0, f32::from(b) / 65535.0))
        }
        VoxelData::F32(v) => Some(
            v[from..]
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                }),
        ),
    }
    .unwrap_or((f32::INFINITY, f32::NEG_INFINITY));
    if lo <= hi {
        range.include(lo);
        range.include(hi);
    }
}

/// Smallest and largest of `values`.
fn minmax<T: Copy + Ord>(values: &[T]) -> Option<(T, T)> {
    let first = *values.first()?;
    Some(
        values
            .iter()
            .fold((first, first), |(a, b), &x| (a.min(x), b.max(x))),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::DownsampleFilter;
    use glam::Vec3;

    fn desc(dims: [u32; 3], n: u32, filter: DownsampleFilter) -> StoreDesc {
        StoreDesc {
            dims: UVec3::from_array(dims),
            brick_size: n,
            scalar: ScalarType::U8,
            spacing: Vec3::ONE,
            filter,
        }
    }

    #[test]
    fn layer_windows_cover_every_plane_once_in_order() {
        for filter in DownsampleFilter::ALL {
            for (dims, n) in [([20, 9, 37], 8), ([5, 5, 3], 4), ([9, 9, 64], 16)] {
                let d = desc(dims, n, filter);
                let grid = crate::store::writer::check_desc(&d).unwrap();
                let w = layer_windows(&grid, &d).unwrap();
                assert_eq!(w.len() as u32, grid.bricks_per_axis().z);
                assert_eq!((w[0].start, w.last().unwrap().end), (0, dims[2]));
                for pair in w.windows(2) {
                    // Monotone and overlapping or touching: planes are read once, forward.
                    assert!(pair[0].start <= pair[1].start && pair[0].end <= pair[1].end);
                    assert!(pair[1].start <= pair[0].end, "{filter:?} {pair:?}");
                }
                // A layer holds its bricks' voxels plus a border.
                for (bz, r) in w.iter().enumerate() {
                    let bz = bz as u32;
                    assert!(r.start <= (n * bz).saturating_sub(1));
                    assert!(r.end >= (n * bz + n + 1).min(dims[2]));
                }
            }
        }
    }

    #[test]
    fn plan_fits_the_budget_and_trades_threads_for_memory() {
        let d = desc([256, 256, 256], 32, DownsampleFilter::BSpline4);
        let big = plan_slab_write(&d, ScalarType::U16, 1 << 20, 1 << 30, 8).unwrap();
        assert_eq!(big.threads, 8);
        assert!(big.planes >= 34 && big.planes <= 32 + 8, "{}", big.planes);
        assert_eq!(big.slab_bytes, 256 * 256 * 2 * u64::from(big.planes));
        let tight_budget = big.slab_bytes + big.reader_bytes + 2 * big.worker_bytes + 10;
        let tight = plan_slab_write(&d, ScalarType::U16, 1 << 20, tight_budget, 8).unwrap();
        assert_eq!(tight.threads, 2);
        assert!(tight.total_bytes <= tight_budget);
        let err = plan_slab_write(&d, ScalarType::U16, 1 << 20, big.slab_bytes, 8).unwrap_err();
        assert!(matches!(err, StoreError::RamBudget { .. }), "{err:?}");
        assert!(plan_slab_write(
            &desc([0, 4, 4], 4, DownsampleFilter::Mean2),
            ScalarType::U8,
            0,
            1 << 30,
            1
        )
        .is_err());
    }
}
