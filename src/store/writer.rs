//! Writing a brick store from a voxel producer, on all cores, with bounded memory.
//!
//! The bricks are produced in *chunks*: runs of consecutive bricks along x (fixed `by`, `bz`),
//! which are consecutive in linear brick order and therefore one contiguous byte range of the
//! file (the canonical layout stores brick `i` at `data_offset + i * (hi + lo)`). A worker
//! evaluates the voxel producer on the chunk's window (its bricks' voxels, the one-voxel border
//! and the filter's reach: `n*L + 8` by `(n + 8)^2` voxels for `L` bricks), builds the hi-res and
//! low-res bricks and their value ranges from it, and writes the chunk with one positioned write.
//! Chunks are as long as a window of [`CHUNK_WINDOW_BYTES`] allows (at least one brick), so the
//! writer's memory is about `threads * 2.5 * CHUNK_WINDOW_BYTES` whatever the volume size. The
//! table of value ranges and the header are written last, into `<path>.partial`, which is then
//! renamed to `path`: a crashed write never leaves a file that opens.
//!
//! The arithmetic is the reference's ([`crate::bricks::pack_hi_res_brick`],
//! [`crate::bricks::pack_low_res_brick`] via the separable `low_res_block`, `f64` accumulation in
//! tap order rounded to `f32` after each axis, [`crate::bricks::quantize_to`], and
//! [`crate::bricks::brick_value_ranges_for_storage`]), so a store written from a [`Volume`] holds
//! exactly the bytes and ranges those functions produce.

use super::format::{
    canonical_brick_offset, canonical_header, encode_header, encode_offsets, encode_ranges,
    finish_checksum, StoreHeader,
};
use super::{Result, StoreError};
use crate::bricks::{BrickGrid, DownsampleFilter, ValueRange};
use crate::volume::{ScalarType, Volume};
use glam::{IVec3, UVec3, Vec3};
use std::fs::{File, OpenOptions};
use std::io::Write as _;
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

/// A textual progress bar on stderr (`label [#####-----]  50.0%  512/1024 bricks  3.1 s`),
/// redrawn in place when the displayed per-mille value changes; silent when disabled.
#[derive(Clone, Debug)]
pub struct ProgressBar {
    label: String,
    enabled: bool,
    start: Instant,
    last_permille: Option<u64>,
}

impl ProgressBar {
    /// Width of the bar in characters.
    const WIDTH: u64 = 40;

    /// A bar labelled `label`, drawn only when `enabled`.
    pub fn new(label: &str, enabled: bool) -> Self {
        Self {
            label: label.to_string(),
            enabled,
            start: Instant::now(),
            last_permille: None,
        }
    }

    /// Reports `done` of `total` units; ends the line when `done == total`.
    pub fn update(&mut self, done: u64, total: u64) {
        if !self.enabled {
            return;
        }
        let permille = (done.min(total) * 1000).checked_div(total).unwrap_or(1000);
        if self.last_permille == Some(permille) {
            return;
        }
        self.last_permille = Some(permille);
        let filled = (permille * Self::WIDTH / 1000) as usize;
        let bar = format!(
            "{}{}",
            "#".repeat(filled),
            "-".repeat(Self::WIDTH as usize - filled)
        );
        let mut err = std::io::stderr().lock();
        // Progress output is best effort: a closed stderr must not fail the write.
        let _ = write!(
            err,
            "\r{} [{bar}] {:5.1}%  {done}/{total} bricks  {:.1} s",
            self.label,
            permille as f64 / 10.0,
            self.start.elapsed().as_secs_f64()
        );
        if done >= total {
            let _ = writeln!(err);
        }
        let _ = err.flush();
    }
}

/// Writes a brick store at `path` from the voxel producer `sample` on all cores
/// ([`crate::bricks::available_threads`]); see [`write_store_with_threads`].
pub fn write_store(
    path: &Path,
    desc: StoreDesc,
    sample: &(dyn Fn(IVec3) -> f32 + Sync),
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary> {
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
) -> Result<WriteSummary> {
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
    let threads = threads.max(1);
    let partial = partial_path(path);
    let io = |action: &'static str| {
        let p = partial.clone();
        move |source| StoreError::Io {
            path: p,
            action,
            source,
        }
    };
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(&partial)
        .map_err(io("create"))?;
    let result = (|| {
        file.set_len(header.file_size).map_err(io("set length"))?;
        let (ranges, value_range) = write_bricks(
            &file, &grid, &desc, &header, sample, threads, progress, &partial,
        )?;
        header.value_range = value_range;
        let offsets: Vec<[u64; 2]> = (0..header.brick_count)
            .map(|i| {
                let hi = canonical_brick_offset(&header, i);
                [hi, hi + header.hi_brick_bytes]
            })
            .collect();
        let ranges_bytes = encode_ranges(&ranges);
        let offsets_bytes = encode_offsets(&offsets);
        let mut header_bytes = encode_header(&header);
        finish_checksum(&mut header_bytes, &ranges_bytes, &offsets_bytes);
        file.write_all_at(&ranges_bytes, header.ranges_offset)
            .map_err(io("write value ranges"))?;
        file.write_all_at(&offsets_bytes, header.offsets_offset)
            .map_err(io("write offsets"))?;
        file.write_all_at(&header_bytes, 0)
            .map_err(io("write header"))?;
        Ok(())
    })();
    drop(file);
    if let Err(e) = result {
        // Best effort: the partial file is useless (and never opens: its header is zero).
        let _ = std::fs::remove_file(&partial);
        return Err(e);
    }
    std::fs::rename(&partial, path).map_err(|source| StoreError::Io {
        path: path.to_path_buf(),
        action: "rename the finished store into place",
        source,
    })?;
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
) -> Result<WriteSummary> {
    write_store_from_volume_with_progress(path, volume, brick_size, filter, &mut |_, _| {})
}

/// [`write_store_from_volume`] with a progress callback (see [`ProgressBar`]).
pub fn write_store_from_volume_with_progress(
    path: &Path,
    volume: &Volume,
    brick_size: u32,
    filter: DownsampleFilter,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<WriteSummary> {
    let desc = StoreDesc {
        dims: volume.dims(),
        brick_size,
        scalar: volume.scalar_type(),
        spacing: volume.spacing(),
        filter,
    };
    let sample = |p: IVec3| volume.value(p.x as u32, p.y as u32, p.z as u32);
    write_store(path, desc, &sample, progress)
}

/// `<path>.partial`, where the store is assembled before it is renamed into place.
fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

fn check_desc(desc: &StoreDesc) -> Result<BrickGrid> {
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
struct Chunk {
    bx0: u32,
    bx1: u32,
    by: u32,
    bz: u32,
}

/// A finished chunk: its first linear brick index and per-brick ranges, plus the raw (quantised)
/// voxel min/max of its window.
struct ChunkDone {
    first: u32,
    ranges: Vec<ValueRange>,
    voxels: ValueRange,
}

/// Produces and writes every brick; returns the per-brick ranges and the volume's value range.
#[allow(clippy::too_many_arguments)] // reason: private plumbing between two functions.
fn write_bricks(
    file: &File,
    grid: &BrickGrid,
    desc: &StoreDesc,
    header: &StoreHeader,
    sample: &(dyn Fn(IVec3) -> f32 + Sync),
    threads: usize,
    progress: &mut dyn FnMut(u64, u64),
    path: &Path,
) -> Result<(Vec<ValueRange>, ValueRange)> {
    let n = grid.brick_size();
    let b = grid.bricks_per_axis();
    let per_brick_window = n as usize * (n as usize + 8).pow(2) * 4;
    let run = ((CHUNK_WINDOW_BYTES / per_brick_window).max(1) as u32).min(b.x);
    let mut chunks = Vec::new();
    for bz in 0..b.z {
        for by in 0..b.y {
            let mut bx0 = 0;
            while bx0 < b.x {
                let bx1 = (bx0 + run).min(b.x);
                chunks.push(Chunk { bx0, bx1, by, bz });
                bx0 = bx1;
            }
        }
    }
    let total = header.brick_count as u64;
    let mut ranges = vec![ValueRange::EMPTY; header.brick_count as usize];
    let mut voxels = ValueRange::EMPTY;
    let next = AtomicUsize::new(0);
    let abort = AtomicBool::new(false);
    let mut first_error = None;
    progress(0, total);
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel::<Result<ChunkDone>>();
        for _ in 0..threads.min(chunks.len()) {
            let tx = tx.clone();
            let (chunks, next, abort) = (&chunks, &next, &abort);
            scope.spawn(move || {
                let mut worker = Worker::new(grid, desc);
                while !abort.load(Ordering::Relaxed) {
                    let Some(chunk) = chunks.get(next.fetch_add(1, Ordering::Relaxed)) else {
                        break;
                    };
                    let done = worker.build(chunk, sample).and_then(|()| {
                        let first =
                            grid.linear_index(UVec3::new(chunk.bx0, chunk.by, chunk.bz)) as u32;
                        let offset = canonical_brick_offset(header, first);
                        file.write_all_at(&worker.out, offset).map_err(|source| {
                            StoreError::Io {
                                path: path.to_path_buf(),
                                action: "write bricks",
                                source,
                            }
                        })?;
                        Ok(ChunkDone {
                            first,
                            ranges: std::mem::take(&mut worker.ranges),
                            voxels: worker.voxels,
                        })
                    });
                    if tx.send(done).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        let mut done = 0u64;
        for message in rx {
            match message {
                Ok(chunk) => {
                    let first = chunk.first as usize;
                    ranges[first..first + chunk.ranges.len()].copy_from_slice(&chunk.ranges);
                    voxels.include(chunk.voxels.min);
                    voxels.include(chunk.voxels.max);
                    done += chunk.ranges.len() as u64;
                    progress(done, total);
                }
                Err(e) => {
                    abort.store(true, Ordering::Relaxed);
                    first_error.get_or_insert(e);
                }
            }
        }
    });
    if let Some(e) = first_error {
        return Err(e);
    }
    Ok((ranges, voxels))
}

/// Per-axis indexing of one chunk: window of clamped hi-res indices, hi-res texel indices and
/// low-res taps into the window.
struct AxisPlan {
    /// First global voxel index of the window.
    start: i64,
    /// Window length.
    len: usize,
    /// Window index of hi-res texel `p` for `p` in `0 .. n*bricks + 2` (global voxel
    /// `n*b0 - 1 + p`, clamped).
    hi: Vec<usize>,
    /// Per low-res sample `k = n*b0/2 - 1 + s` (`s` in `0 .. n*bricks/2 + 3`): taps `(window
    /// index, weight)` in the filter's tap order.
    taps: Vec<Vec<(usize, f32)>>,
}

impl AxisPlan {
    fn new(d: u32, n: u32, b0: u32, b1: u32, filter: DownsampleFilter) -> Self {
        let last = i64::from(d) - 1;
        let kmax = i64::from(d.div_ceil(2));
        let (n64, b0, b1) = (i64::from(n), i64::from(b0), i64::from(b1));
        let hi_abs: Vec<i64> = (n64 * b0 - 1..=n64 * b1)
            .map(|p| p.clamp(0, last))
            .collect();
        let taps_abs: Vec<Vec<(i64, f32)>> = (n64 * b0 / 2 - 1..=n64 * b1 / 2 + 1)
            .map(|k| {
                let kc = k.clamp(0, kmax);
                filter
                    .taps()
                    .iter()
                    .map(|&(o, w)| ((2 * kc + o).clamp(0, last), w))
                    .collect()
            })
            .collect();
        let all = || {
            hi_abs
                .iter()
                .copied()
                .chain(taps_abs.iter().flatten().map(|&(i, _)| i))
        };
        let start = all().min().unwrap_or(0);
        let end = all().max().unwrap_or(0);
        Self {
            start,
            len: (end - start + 1) as usize,
            hi: hi_abs.iter().map(|&i| (i - start) as usize).collect(),
            taps: taps_abs
                .iter()
                .map(|row| {
                    row.iter()
                        .map(|&(i, w)| ((i - start) as usize, w))
                        .collect()
                })
                .collect(),
        }
    }
}

/// One worker's reusable buffers.
struct Worker {
    dims: UVec3,
    n: u32,
    scalar: ScalarType,
    filter: DownsampleFilter,
    window: Vec<f32>,
    pass_x: Vec<f32>,
    pass_y: Vec<f32>,
    low: Vec<f32>,
    /// The chunk's bytes: per brick hi then lo.
    out: Vec<u8>,
    /// The chunk's per-brick ranges.
    ranges: Vec<ValueRange>,
    /// Raw min/max of the chunk's (quantised) voxels.
    voxels: ValueRange,
}

impl Worker {
    fn new(grid: &BrickGrid, desc: &StoreDesc) -> Self {
        Self {
            dims: grid.dims(),
            n: grid.brick_size(),
            scalar: desc.scalar,
            filter: desc.filter,
            window: Vec::new(),
            pass_x: Vec::new(),
            pass_y: Vec::new(),
            low: Vec::new(),
            out: Vec::new(),
            ranges: Vec::new(),
            voxels: ValueRange::EMPTY,
        }
    }

    /// Builds the chunk's bytes into `out` and its ranges into `ranges`.
    fn build(&mut self, chunk: &Chunk, sample: &(dyn Fn(IVec3) -> f32 + Sync)) -> Result<()> {
        let (n, f) = (self.n, self.filter);
        let ax = AxisPlan::new(self.dims.x, n, chunk.bx0, chunk.bx1, f);
        let ay = AxisPlan::new(self.dims.y, n, chunk.by, chunk.by + 1, f);
        let az = AxisPlan::new(self.dims.z, n, chunk.bz, chunk.bz + 1, f);
        self.gather(&ax, &ay, &az, sample)?;
        self.filter_passes(&ax, &ay, &az);
        self.pack(chunk, &ax, &ay, &az);
        Ok(())
    }

    /// Evaluates the (quantised) producer on the window.
    fn gather(
        &mut self,
        ax: &AxisPlan,
        ay: &AxisPlan,
        az: &AxisPlan,
        sample: &(dyn Fn(IVec3) -> f32 + Sync),
    ) -> Result<()> {
        self.window.clear();
        self.window.reserve(ax.len * ay.len * az.len);
        // The normalised value of every u8 level, exactly as `VoxelData::normalized` computes it.
        let u8_levels: [f32; 256] = std::array::from_fn(|b| b as f32 / 255.0);
        for z in 0..az.len as i64 {
            for y in 0..ay.len as i64 {
                for x in 0..ax.len as i64 {
                    let p = IVec3::new(
                        (ax.start + x) as i32,
                        (ay.start + y) as i32,
                        (az.start + z) as i32,
                    );
                    let raw = sample(p);
                    let v = match self.scalar {
                        ScalarType::U8 => u8_levels[unorm(raw, 255.0) as usize],
                        ScalarType::U16 => unorm(raw, 65535.0) as f32 / 65535.0,
                        ScalarType::F32 => {
                            if !raw.is_finite() {
                                return Err(StoreError::NonFiniteSample {
                                    voxel: p.to_array(),
                                    value: raw,
                                });
                            }
                            raw
                        }
                    };
                    self.window.push(v);
                }
            }
        }
        Ok(())
    }

    /// The separable low-res filter over the window: x, then y, then z, `f64` accumulation in tap
    /// order rounded to `f32` after each axis (the reference `low_res_block` arithmetic).
    fn filter_passes(&mut self, ax: &AxisPlan, ay: &AxisPlan, az: &AxisPlan) {
        let (wx, wy, wz) = (ax.len, ay.len, az.len);
        let (cx, cy, cz) = (ax.taps.len(), ay.taps.len(), az.taps.len());
        let window = &self.window;
        self.pass_x.clear();
        for zy in 0..wz * wy {
            let row = &window[zy * wx..(zy + 1) * wx];
            for taps in &ax.taps {
                self.pass_x.push(weighted(taps, |i| row[i]));
            }
        }
        let px = &self.pass_x;
        self.pass_y.clear();
        for z in 0..wz {
            for taps in &ay.taps {
                for x in 0..cx {
                    self.pass_y
                        .push(weighted(taps, |i| px[x + cx * (i + wy * z)]));
                }
            }
        }
        let py = &self.pass_y;
        self.low.clear();
        for taps in &az.taps {
            for y in 0..cy {
                for x in 0..cx {
                    self.low.push(weighted(taps, |i| py[x + cx * (y + cy * i)]));
                }
            }
        }
        debug_assert_eq!(self.low.len(), cx * cy * cz);
    }

    /// Cuts the chunk's bricks from the window and the low-res block.
    fn pack(&mut self, chunk: &Chunk, ax: &AxisPlan, ay: &AxisPlan, az: &AxisPlan) {
        let n = self.n as usize;
        let (wx, wy) = (ax.len, ay.len);
        let (cx, cy) = (ax.taps.len(), ay.taps.len());
        let e_hi = n + 2;
        let e_lo = n / 2 + 1;
        self.out.clear();
        self.ranges.clear();
        // Every voxel is a hi-res texel of the brick owning it (and texels are only voxels), so
        // the union of the hi-res texel ranges is the range of the chunk's voxels.
        self.voxels = ValueRange::EMPTY;
        for i in 0..(chunk.bx1 - chunk.bx0) as usize {
            let mut raw = ValueRange::EMPTY;
            for &z in &az.hi[..e_hi] {
                for &y in &ay.hi[..e_hi] {
                    let row = &self.window[wx * (y + wy * z)..];
                    for &x in &ax.hi[n * i..n * i + e_hi] {
                        let v = row[x];
                        grow(&mut raw, v);
                        push_texel(&mut self.out, v, self.scalar);
                    }
                }
            }
            grow(&mut self.voxels, raw.min);
            grow(&mut self.voxels, raw.max);
            // Low-res block index s = n*i/2 + 1 + j holds the brick's texel j.
            let base = n * i / 2;
            for z in 1..=e_lo {
                for y in 1..=e_lo {
                    let row = &self.low[cx * (y + cy * z)..];
                    for &v in &row[base + 1..base + 1 + e_lo] {
                        push_texel(&mut self.out, v, self.scalar);
                    }
                }
            }
            // Range window: low-res samples s in [n*i/2, n*i/2 + n/2 + 2] (k in [n*b/2 - 1,
            // n*b/2 + n/2 + 1], positions [n*b - 2, n*(b+1) + 2]).
            for z in 0..e_lo + 2 {
                for y in 0..e_lo + 2 {
                    let row = &self.low[cx * (y + cy * z)..];
                    for &v in &row[base..base + e_lo + 2] {
                        grow(&mut raw, v);
                    }
                }
            }
            self.ranges.push(stored_range(raw, self.scalar));
        }
    }
}

/// `sum weight * value(index)` accumulated in `f64` in tap order, rounded to `f32`.
#[inline]
fn weighted(taps: &[(usize, f32)], value: impl Fn(usize) -> f32) -> f32 {
    let mut acc = 0.0_f64;
    for &(i, w) in taps {
        acc += f64::from(w) * f64::from(value(i));
    }
    acc as f32
}

/// `round(clamp(v, 0, 1) * max)` with ties away from zero, NaN to 0: exactly the
/// [`crate::bricks::quantize_to`] conversion (`f32::round`), without the libm call. For
/// `0 <= x <= 65535`, `x - trunc(x)` is exact, so comparing it with 0.5 rounds exactly.
#[inline]
fn unorm(v: f32, max: f32) -> u32 {
    let x = v.clamp(0.0, 1.0) * max;
    let whole = x as u32; // saturating: NaN becomes 0
    whole + u32::from(x - whole as f32 >= 0.5)
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

/// Appends `v` as a little-endian texel of `scalar` (what `quantize_to` gives on little-endian).
#[inline]
fn push_texel(out: &mut Vec<u8>, v: f32, scalar: ScalarType) {
    match scalar {
        ScalarType::U8 => out.push(unorm(v, 255.0) as u8),
        ScalarType::U16 => out.extend_from_slice(&(unorm(v, 65535.0) as u16).to_le_bytes()),
        ScalarType::F32 => out.extend_from_slice(&v.to_le_bytes()),
    }
}

/// The range the reference's per-value `include_stored` gives for raw values spanning `raw`:
/// rounding each value down and up to the storage grid is monotone, so only the ends matter.
fn stored_range(raw: ValueRange, scalar: ScalarType) -> ValueRange {
    let levels = match scalar {
        ScalarType::U8 => 255.0_f32,
        ScalarType::U16 => 65535.0,
        ScalarType::F32 => return raw,
    };
    let down = |v: f32| (v.clamp(0.0, 1.0) * levels).floor() / levels;
    let up = |v: f32| (v.clamp(0.0, 1.0) * levels).ceil() / levels;
    ValueRange {
        min: down(raw.min).min(up(raw.min)),
        max: up(raw.max).max(down(raw.max)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::quantize_to;

    #[test]
    fn fast_unorm_matches_quantize_to_bit_for_bit() {
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            2.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
        ];
        for levels in [255.0_f32, 65535.0] {
            for k in 0..=levels as u32 {
                for x in [k as f32 - 0.5, k as f32 + 0.5, k as f32] {
                    let v = x / levels;
                    // The neighbouring floats (v is positive or zero here).
                    let b = v.to_bits();
                    values.extend([v, f32::from_bits(b + 1), f32::from_bits(b.max(1) - 1)]);
                }
            }
        }
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        for _ in 0..1_000_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            values.push(f32::from_bits(state as u32 & 0x3FFF_FFFF));
        }
        let u8s = quantize_to(&values, ScalarType::U8);
        let u16s = quantize_to(&values, ScalarType::U16);
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(unorm(v, 255.0) as u8, u8s[i], "u8 {v:e}");
            let w = u16::from_ne_bytes([u16s[2 * i], u16s[2 * i + 1]]);
            assert_eq!(unorm(v, 65535.0) as u16, w, "u16 {v:e}");
        }
    }
}
