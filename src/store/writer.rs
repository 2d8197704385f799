//! Writing a brick store from a voxel producer, on all cores, with bounded memory.
//!
//! The bricks are produced in *chunks*: runs of consecutive bricks along x (fixed `by`, `bz`),
//! which are consecutive in linear brick order and therefore one contiguous byte range of the
//! file (the canonical layout stores brick `i` at `data_offset + i * (hi + lo)`). A worker
//! evaluates the voxel producer on the chunk's window (its bricks' voxels, the one-voxel border
//! and the filter's reach: `n*L + 8` by `(n + 8)^2` voxels for `L` bricks, as
//! [`BrickKernel::window_for`] gives it), quantised to the storage type, hands it to the bricking
//! kernel ([`BrickKernel::pack_window`]) for the hi-res and low-res bricks and their value ranges,
//! and writes the chunk with one positioned write. Chunks are as long as a window of
//! [`CHUNK_WINDOW_BYTES`] allows (at least one brick), so the writer's memory is about
//! `threads * 2.5 * CHUNK_WINDOW_BYTES` whatever the volume size. An in-memory volume
//! ([`write_store_from_volume`]) needs no window: the kernel reads the volume itself. The table of
//! value ranges and the header are written last, into a fresh temporary file beside it (`.NAME.partial-PID-N`, created exclusively, so
//! nothing already there is written through), which is then renamed to
//! `path`: a crashed write never leaves a file that opens.
//!
//! The kernel's arithmetic is the reference's ([`crate::bricks::pack_hi_res_brick`],
//! [`crate::bricks::pack_low_res_brick`], [`crate::bricks::quantize_to`] and
//! [`crate::bricks::brick_value_ranges_for_storage`]), so a store written from a [`Volume`] holds
//! exactly the bytes and ranges those functions produce.

use super::format::{
    brick_crc, canonical_brick_offset, canonical_header, encode_header, encode_offsets,
    encode_ranges, finish_checksum, StoreHeader,
};
use super::StoreError;
use super::BRICK_STORE;
use crate::bricks::kernel::texel::Texel;
use crate::bricks::{
    BrickBox, BrickError, BrickGrid, BrickKernel, DownsampleFilter, PackOutputs, TexelsMut,
    ValueRange, VoxelWindow,
};
use crate::volume::{ScalarType, Volume, VoxelData};
use glam::{IVec3, UVec3, Vec3};
use std::fs::{File, OpenOptions};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Upper bound on the voxel window (as `f32`) one worker evaluates at a time; a chunk is always
/// at least one brick, whatever its window.
pub const CHUNK_WINDOW_BYTES: usize = 8 << 20;

/// What to write: the volume's shape and the store's storage format.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct StoreDesc {
    /// Volume dimensions in voxels (every axis at least 1).
    pub dims: UVec3,
    /// Brick edge length `n` (a power of two in `2..=MAX_BRICK_SIZE`).
    pub brick_size: u32,
    /// Storage scalar type of the brick texels; the producer's values are quantised to it
    /// ([`crate::bricks::quantize_to`]) *before* anything else, so the store describes the volume
    /// whose voxels are the quantised values.
    pub scalar: ScalarType,
    /// Physical voxel spacing (positive, finite).
    pub spacing: Vec3,
    /// Filter that builds the low-res bricks.
    pub filter: DownsampleFilter,
}

/// What [`write_store`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteSummary {
    /// The file written.
    pub path: PathBuf,
    /// The header written.
    pub header: StoreHeader,
    /// Threads that produced bricks.
    pub threads: usize,
    /// Wall-clock time of the whole write.
    pub elapsed: Duration,
}

impl WriteSummary {
    /// File bytes written per second.
    pub fn bytes_per_second(&self) -> f64 {
        self.header.file_size as f64 / self.elapsed.as_secs_f64().max(1e-9)
    }
}

/// Writes a brick store at `path` from the voxel producer `sample` on all cores
/// ([`crate::bricks::available_threads`]); see [`write_store_with_threads`].
pub fn write_store(
    path: &Path,
    desc: StoreDesc,
    sample: &(dyn Fn(IVec3) -> f32 + Sync),
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary, StoreError> {
    write_store_with_threads(
        path,
        desc,
        sample,
        crate::bricks::available_threads(),
        progress,
    )
}

/// Writes a brick store at `path` (replacing any file there) on `threads` worker threads (0
/// counts as 1; the output does not depend on it).
///
/// `sample(voxel)` returns the normalised value of voxel `voxel`; it is only called with
/// coordinates inside `desc.dims` (the writer clamps) and may be called several times for the
/// same voxel, so it must be deterministic. For `U8` / `U16` stores each value is quantised as
/// [`crate::bricks::quantize_to`] does (clamped to `[0, 1]`, NaN to 0) before any filtering; an
/// `F32` store rejects NaN and infinities with [`StoreError::NonFiniteSample`].
///
/// `progress(done, total)` is called on the calling thread after every chunk, with brick counts.
/// Peak memory is bounded by the thread count, not the volume size (see the
/// [module docs](self)).
pub fn write_store_with_threads(
    path: &Path,
    desc: StoreDesc,
    sample: &(dyn Fn(IVec3) -> f32 + Sync),
    threads: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary, StoreError> {
    write_with(path, desc, Voxels::Producer(sample), threads, progress)
}

/// Where the voxels come from.
#[derive(Copy, Clone)]
pub(super) enum Voxels<'a> {
    /// A producer, evaluated on each chunk's window.
    Producer(&'a (dyn Fn(IVec3) -> f32 + Sync)),
    /// An in-memory volume of the store's dimensions and scalar type, read in place.
    Volume(&'a Volume),
    /// A window of the volume (a slab of z planes), read in place; only chunks whose voxels it
    /// holds are packed from it.
    Window(VoxelWindow<'a>),
}

/// [`write_store_with_threads`] from `voxels`.
fn write_with(
    path: &Path,
    desc: StoreDesc,
    voxels: Voxels<'_>,
    threads: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary, StoreError> {
    let threads = threads.max(1);
    assemble(path, desc, threads, &mut |target| {
        write_bricks(target, voxels, threads, progress)
    })
}

/// Where the bricks of a store being written go, for the brick-producing part of a writer.
pub(super) struct Target<'a> {
    /// The partial file, already of its final length.
    pub file: &'a File,
    /// The brick grid.
    pub grid: &'a BrickGrid,
    /// What is written.
    pub desc: &'a StoreDesc,
    /// The store's header (its value range is filled in later).
    pub header: &'a StoreHeader,
    /// The partial file's path, named in errors.
    pub path: &'a Path,
}

/// What a brick producer returns: the per-brick value ranges, the volume's value range and the
/// per-brick `[hi, lo]` CRC-32s.
pub(super) type Written = (Vec<ValueRange>, ValueRange, Vec<[u32; 2]>);

/// Checks `desc`, creates a fresh temporary file beside `path` ([`create_partial`]) at its final length, lets `bricks` write every brick
/// into it (returning the per-brick ranges and the volume's value range), then writes the tables
/// and the header and renames the file to `path`. On any error the partial file is removed.
pub(super) fn assemble(
    path: &Path,
    desc: StoreDesc,
    threads: usize,
    bricks: &mut dyn FnMut(&Target<'_>) -> Result<Written, StoreError>,
) -> Result<WriteSummary, StoreError> {
    let start = Instant::now();
    let grid = check_desc(&desc)?;
    let mut header = canonical_header(
        &grid,
        desc.scalar,
        desc.filter,
        desc.spacing,
        ValueRange::EMPTY,
    )
    .ok_or_else(|| StoreError::InvalidDesc {
        field: "dims",
        message: format!(
            "{} bricks of size {} do not fit the format (u32 brick count, u64 offsets)",
            grid.brick_count(),
            desc.brick_size
        ),
    })?;
    let (file, partial) = create_partial(BRICK_STORE, path)?;
    let io = |action: &'static str| {
        let p = partial.clone();
        move |source| StoreError::Io {
            kind: BRICK_STORE,
            path: p,
            action,
            source,
        }
    };
    let result = (|| {
        file.set_len(header.file_size).map_err(io("set length"))?;
        let target = Target {
            file: &file,
            grid: &grid,
            desc: &desc,
            header: &header,
            path: &partial,
        };
        let (ranges, value_range, crcs) = bricks(&target)?;
        header.value_range = value_range;
        let offsets: Vec<[u64; 2]> = (0..header.brick_count)
            .map(|i| {
                let hi = canonical_brick_offset(&header, i);
                [hi, hi + header.hi_brick_bytes]
            })
            .collect();
        let ranges_bytes = encode_ranges(&ranges);
        let offsets_bytes = encode_offsets(&offsets, &crcs);
        let mut header_bytes = encode_header(&header);
        finish_checksum(&mut header_bytes, &ranges_bytes, &offsets_bytes);
        file.write_all_at(&ranges_bytes, header.ranges_offset)
            .map_err(io("write value ranges"))?;
        file.write_all_at(&offsets_bytes, header.offsets_offset)
            .map_err(io("write offsets"))?;
        file.write_all_at(&header_bytes, 0)
            .map_err(io("write header"))?;
        file.sync_all().map_err(io("sync"))?;
        Ok(())
    })();
    drop(file);
    commit_partial(BRICK_STORE, &partial, path, result)?;
    Ok(WriteSummary {
        path: path.to_path_buf(),
        header,
        threads,
        elapsed: start.elapsed(),
    })
}

/// Writes the bricks of the in-memory `volume` (storage type = the volume's scalar type, spacing
/// = the volume's) as a store at `path`, on all cores.
///
/// The bytes of every brick level equal `quantize_to(&pack_hi_res_brick(..), scalar)` /
/// `quantize_to(&pack_low_res_brick(.., filter, ..), scalar)` (little-endian; the same bytes on
/// little-endian hosts), and the ranges equal `brick_value_ranges_for_storage(volume, grid,
/// filter, scalar)`.
pub fn write_store_from_volume(
    path: &Path,
    volume: &Volume,
    brick_size: u32,
    filter: DownsampleFilter,
) -> Result<WriteSummary, StoreError> {
    write_store_from_volume_with_progress(path, volume, brick_size, filter, &mut |_, _| {})
}

/// [`write_store_from_volume`] with a progress callback `progress(done, total)` (brick counts,
/// called on the calling thread after every chunk). The kernel reads the volume in place (no
/// window is evaluated).
pub fn write_store_from_volume_with_progress(
    path: &Path,
    volume: &Volume,
    brick_size: u32,
    filter: DownsampleFilter,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary, StoreError> {
    let desc = StoreDesc {
        dims: volume.dims(),
        brick_size,
        scalar: volume.scalar_type(),
        spacing: volume.spacing(),
        filter,
    };
    let threads = crate::bricks::available_threads();
    write_with(path, desc, Voxels::Volume(volume), threads, progress)
}

/// Ends a write into `partial` (already closed) whose outcome is `result`: on success renames it
/// to `path`; on any error (or a failed rename) removes it, so nothing half-written stays.
pub(super) fn commit_partial(
    kind: &'static str,
    partial: &Path,
    path: &Path,
    result: Result<(), StoreError>,
) -> Result<(), StoreError> {
    if let Err(e) = result {
        // Best effort: the partial file is useless (and never opens: its header is zero).
        let _ = std::fs::remove_file(partial);
        return Err(e);
    }
    std::fs::rename(partial, path).map_err(|source| {
        let _ = std::fs::remove_file(partial);
        StoreError::Io {
            kind,
            path: path.to_path_buf(),
            action: "rename the finished store into place",
            source,
        }
    })
}

/// Creates the file a store for `path` is assembled in before it is renamed into place: a fresh
/// name beside `path` (`.NAME.partial-PID-N`, [`crate::output::partial_name`]), created
/// exclusively, so that nothing already there (a file, or a link the write would follow) is
/// opened. Errors: `path` exists and is not a regular file or a link (a folder, a device, a FIFO
/// or a socket is never replaced), or the file cannot be created.
pub(crate) fn create_partial(
    kind: &'static str,
    path: &Path,
) -> Result<(File, PathBuf), StoreError> {
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        let file_type = meta.file_type();
        if !(file_type.is_file() || file_type.is_symlink()) {
            return Err(StoreError::Io {
                kind,
                path: path.to_path_buf(),
                action: "replace the store",
                source: std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "the path exists and is not a regular file (a folder, device, FIFO or \
                     socket); give a file path",
                ),
            });
        }
    }
    let partial = crate::output::partial_name(path);
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(&partial)
        .map_err(|source| StoreError::Io {
            kind,
            path: partial.clone(),
            action: "create",
            source,
        })?;
    Ok((file, partial))
}

/// Checks a description and returns its brick grid.
pub(super) fn check_desc(desc: &StoreDesc) -> Result<BrickGrid, StoreError> {
    if desc.dims.min_element() == 0 {
        return Err(StoreError::InvalidDesc {
            field: "dims",
            message: format!("{:?} has a zero axis", desc.dims.to_array()),
        });
    }
    if desc.dims.max_element() > i32::MAX as u32 / 2 {
        return Err(StoreError::InvalidDesc {
            field: "dims",
            message: format!(
                "{:?} exceeds the i32 voxel coordinates",
                desc.dims.to_array()
            ),
        });
    }
    if !(desc.spacing.is_finite() && desc.spacing.min_element() > 0.0) {
        return Err(StoreError::InvalidDesc {
            field: "spacing",
            message: format!("{:?} must be positive and finite", desc.spacing.to_array()),
        });
    }
    BrickGrid::new(desc.dims, desc.brick_size).map_err(|e| StoreError::InvalidDesc {
        field: "brick_size",
        message: e.to_string(),
    })
}

/// A run of bricks `bx0..bx1` along x at `(by, bz)`.
#[derive(Copy, Clone, Debug)]
pub(super) struct Chunk {
    pub(super) bx0: u32,
    pub(super) bx1: u32,
    pub(super) by: u32,
    pub(super) bz: u32,
}

/// A finished chunk: its first linear brick index and per-brick ranges, plus the raw (quantised)
/// voxel min/max of its window.
pub(super) struct ChunkDone {
    pub(super) first: u32,
    pub(super) ranges: Vec<ValueRange>,
    pub(super) voxels: ValueRange,
    /// Per brick of the chunk, the `[hi, lo]` CRC-32s of the bytes written.
    pub(super) crcs: Vec<[u32; 2]>,
}

/// The chunks of brick layer `bz` (every `by`, runs along x as long as [`CHUNK_WINDOW_BYTES`]
/// allows), in linear brick order.
pub(super) fn layer_chunks(grid: &BrickGrid, bz: u32) -> Vec<Chunk> {
    let n = grid.brick_size();
    let b = grid.bricks_per_axis();
    let per_brick_window = n as usize * (n as usize + 8).pow(2) * 4;
    let run = ((CHUNK_WINDOW_BYTES / per_brick_window).max(1) as u32).min(b.x);
    let mut chunks = Vec::new();
    for by in 0..b.y {
        let mut bx0 = 0;
        while bx0 < b.x {
            let bx1 = (bx0 + run).min(b.x);
            chunks.push(Chunk { bx0, bx1, by, bz });
            bx0 = bx1;
        }
    }
    chunks
}

/// Produces and writes every brick; returns the per-brick ranges and the volume's value range.
fn write_bricks(
    target: &Target<'_>,
    voxels: Voxels<'_>,
    threads: usize,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Written, StoreError> {
    let chunks: Vec<Chunk> = (0..target.grid.bricks_per_axis().z)
        .flat_map(|bz| layer_chunks(target.grid, bz))
        .collect();
    let total = target.header.brick_count as u64;
    let mut ranges = vec![ValueRange::EMPTY; target.header.brick_count as usize];
    let mut crcs = vec![[0u32; 2]; target.header.brick_count as usize];
    let mut value_range = ValueRange::EMPTY;
    let mut done = 0u64;
    progress(0, total);
    let mut workers: Vec<Worker> = (0..threads.max(1).min(chunks.len()))
        .map(|_| Worker::new(target.grid, target.desc))
        .collect();
    pack_chunks(target, voxels, &chunks, &mut workers, &mut |chunk| {
        let first = chunk.first as usize;
        ranges[first..first + chunk.ranges.len()].copy_from_slice(&chunk.ranges);
        crcs[first..first + chunk.crcs.len()].copy_from_slice(&chunk.crcs);
        value_range.include(chunk.voxels.min);
        value_range.include(chunk.voxels.max);
        done += chunk.ranges.len() as u64;
        progress(done, total);
    })?;
    if let Voxels::Volume(volume) = voxels {
        let (min, max) = volume.value_range();
        value_range = ValueRange { min, max };
    }
    Ok((ranges, value_range, crcs))
}

/// Packs and writes `chunks` on one thread per worker of `workers` (whose buffers are reused from
/// call to call); `done` is called on the calling thread for every finished chunk. The first
/// error stops the workers and is returned.
pub(super) fn pack_chunks(
    target: &Target<'_>,
    voxels: Voxels<'_>,
    chunks: &[Chunk],
    workers: &mut [Worker],
    done: &mut dyn FnMut(ChunkDone),
) -> Result<(), StoreError> {
    let (grid, header, file, path) = (target.grid, target.header, target.file, target.path);
    let next = AtomicUsize::new(0);
    let abort = AtomicBool::new(false);
    let mut first_error = None;
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel::<Result<ChunkDone, StoreError>>();
        for worker in workers.iter_mut().take(chunks.len()) {
            let tx = tx.clone();
            let (next, abort) = (&next, &abort);
            scope.spawn(move || {
                while !abort.load(Ordering::Relaxed) {
                    let Some(chunk) = chunks.get(next.fetch_add(1, Ordering::Relaxed)) else {
                        break;
                    };
                    let result = worker.build(chunk, voxels).and_then(|()| {
                        let first =
                            grid.linear_index(UVec3::new(chunk.bx0, chunk.by, chunk.bz)) as u32;
                        let offset = canonical_brick_offset(header, first);
                        file.write_all_at(&worker.out, offset).map_err(|source| {
                            StoreError::Io {
                                kind: BRICK_STORE,
                                path: path.to_path_buf(),
                                action: "write bricks",
                                source,
                            }
                        })?;
                        let pair = (header.hi_brick_bytes + header.lo_brick_bytes) as usize;
                        let hi = header.hi_brick_bytes as usize;
                        let crcs = worker
                            .out
                            .chunks_exact(pair)
                            .map(|b| [brick_crc(&b[..hi]), brick_crc(&b[hi..])])
                            .collect();
                        Ok(ChunkDone {
                            first,
                            ranges: std::mem::take(&mut worker.ranges),
                            voxels: worker.voxels,
                            crcs,
                        })
                    });
                    if tx.send(result).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for message in rx {
            match message {
                Ok(chunk) => done(chunk),
                Err(e) => {
                    abort.store(true, Ordering::Relaxed);
                    first_error.get_or_insert(e);
                }
            }
        }
    });
    match first_error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// One worker's kernel and reusable buffers.
pub(super) struct Worker {
    kernel: BrickKernel,
    /// The chunk's window of quantised voxels (producer only).
    window: VoxelData,
    hi: VoxelData,
    lo: VoxelData,
    /// The chunk's bytes: per brick hi then lo, little-endian texels.
    out: Vec<u8>,
    /// The chunk's per-brick ranges.
    ranges: Vec<ValueRange>,
    /// Raw min/max of the chunk's window (of quantised voxels; producer only).
    voxels: ValueRange,
}

impl Worker {
    /// A worker for `desc`'s bricks of `grid`.
    pub(super) fn new(grid: &BrickGrid, desc: &StoreDesc) -> Self {
        let empty = || match desc.scalar {
            ScalarType::U8 => VoxelData::U8(Vec::new()),
            ScalarType::U16 => VoxelData::U16(Vec::new()),
            ScalarType::F32 => VoxelData::F32(Vec::new()),
        };
        Self {
            kernel: BrickKernel::new(grid, desc.filter, desc.scalar),
            window: empty(),
            hi: empty(),
            lo: empty(),
            out: Vec::new(),
            ranges: Vec::new(),
            voxels: ValueRange::EMPTY,
        }
    }

    /// Builds the chunk's bytes into `out` and its ranges into `ranges`.
    fn build(&mut self, chunk: &Chunk, voxels: Voxels<'_>) -> Result<(), StoreError> {
        let bricks = BrickBox::run(chunk.bx0..chunk.bx1, chunk.by, chunk.bz);
        let count = bricks.count();
        let n = self.kernel.grid().brick_size() as usize;
        let (hi_len, lo_len) = ((n + 2).pow(3), (n / 2 + 1).pow(3));
        resize(&mut self.hi, count * hi_len);
        resize(&mut self.lo, count * lo_len);
        self.ranges.clear();
        self.ranges.resize(count, ValueRange::EMPTY);
        self.voxels = ValueRange::EMPTY;
        let window = match voxels {
            Voxels::Producer(sample) => {
                let (origin, extent) = self.kernel.window_for(&bricks).map_err(internal)?;
                self.voxels = match &mut self.window {
                    VoxelData::U8(buf) => gather(buf, origin, extent, sample)?,
                    VoxelData::U16(buf) => gather(buf, origin, extent, sample)?,
                    VoxelData::F32(buf) => gather(buf, origin, extent, sample)?,
                };
                VoxelWindow::new(&self.window, origin, extent).map_err(internal)?
            }
            Voxels::Volume(volume) => VoxelWindow::of_volume(volume),
            Voxels::Window(window) => window,
        };
        let out = PackOutputs {
            hi: Some(TexelsMut::of(&mut self.hi)),
            lo: Some(TexelsMut::of(&mut self.lo)),
            ranges: Some(&mut self.ranges),
            level: false,
        };
        self.kernel
            .pack_window(&window, &bricks, out)
            .map_err(internal)?;
        self.out.clear();
        match (&self.hi, &self.lo) {
            (VoxelData::U8(hi), VoxelData::U8(lo)) => interleave(&mut self.out, hi, lo, count),
            (VoxelData::U16(hi), VoxelData::U16(lo)) => interleave(&mut self.out, hi, lo, count),
            (VoxelData::F32(hi), VoxelData::F32(lo)) => interleave(&mut self.out, hi, lo, count),
            _ => {
                return Err(internal(BrickError::OutputMismatch {
                    output: "lo",
                    reason: "hi-res and low-res buffers differ in storage type".into(),
                }))
            }
        }
        Ok(())
    }
}

/// A kernel error: the writer handed it something inconsistent (a bug, never the caller's input).
fn internal(e: BrickError) -> StoreError {
    StoreError::InvalidDesc {
        field: "brick",
        message: e.to_string(),
    }
}

/// Resizes `data` to `len` texels (contents unspecified).
fn resize(data: &mut VoxelData, len: usize) {
    match data {
        VoxelData::U8(v) => v.resize(len, 0),
        VoxelData::U16(v) => v.resize(len, 0),
        VoxelData::F32(v) => v.resize(len, 0.0),
    }
}

/// Evaluates the producer on the window `origin .. origin + extent` (inside the volume), quantised
/// to `T` as [`crate::bricks::quantize_to`] does; returns the min/max of the quantised values.
/// `F32` windows reject NaN and infinities.
fn gather<T: Texel>(
    buf: &mut Vec<T>,
    origin: UVec3,
    extent: UVec3,
    sample: &(dyn Fn(IVec3) -> f32 + Sync),
) -> Result<ValueRange, StoreError> {
    buf.clear();
    buf.reserve(extent.x as usize * extent.y as usize * extent.z as usize);
    let mut range = ValueRange::EMPTY;
    let origin = origin.as_ivec3();
    for z in 0..extent.z as i32 {
        for y in 0..extent.y as i32 {
            for x in 0..extent.x as i32 {
                let p = origin + IVec3::new(x, y, z);
                let raw = sample(p);
                if !T::UNORM && !raw.is_finite() {
                    return Err(StoreError::NonFiniteSample {
                        voxel: p.to_array(),
                        value: raw,
                    });
                }
                let texel = T::from_normalized(raw);
                grow(&mut range, texel.normalized());
                buf.push(texel);
            }
        }
    }
    Ok(range)
}

/// `ValueRange::include` for values known not to be NaN.
#[inline]
fn grow(range: &mut ValueRange, v: f32) {
    if v < range.min {
        range.min = v;
    }
    if v > range.max {
        range.max = v;
    }
}

/// Appends brick `i`'s hi-res then low-res texels for every brick, as little-endian bytes.
fn interleave<T: Texel>(out: &mut Vec<u8>, hi: &[T], lo: &[T], count: usize) {
    let (hi_len, lo_len) = (hi.len() / count, lo.len() / count);
    out.reserve(std::mem::size_of_val(hi) + std::mem::size_of_val(lo));
    for (hi, lo) in hi.chunks_exact(hi_len).zip(lo.chunks_exact(lo_len)) {
        extend_le(out, hi);
        extend_le(out, lo);
    }
}

/// Appends `texels` as little-endian bytes (their native bytes on little-endian hosts).
#[inline]
fn extend_le<T: Texel>(out: &mut Vec<u8>, texels: &[T]) {
    let bytes: &[u8] = bytemuck::cast_slice(texels);
    if cfg!(target_endian = "little") {
        out.extend_from_slice(bytes);
    } else {
        for texel in bytes.chunks_exact(std::mem::size_of::<T>()) {
            out.extend(texel.iter().rev());
        }
    }
}
