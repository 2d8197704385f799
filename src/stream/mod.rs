//! Streaming bricks from an OME-Zarr image, local or remote, chunk by chunk.
//!
//! Two ways: the two-level cache's brick levels packed from level 0 ([`ZarrBricks`], below),
//! and the three-level cache's stored bricks of every level read from the image's own pyramid
//! levels ([`ZarrLevels`], `levels.rs`, a [`crate::store::LevelBackend`] for
//! [`crate::store::LevelStreamer`]).
//!
//! [`ZarrBricks`] is a [`BrickBackend`]: the store's [`BrickStreamer`] (wanted set and priorities
//! from the planner through [`BrickSource::request_levels`](crate::bricks::BrickSource), RAM
//! budget for packed bricks, pins, failures; [`BrickSource::brick_bytes`](crate::bricks::BrickSource)
//! never blocks) drives it exactly as it drives a brick store file, so [`ZarrBrickSource`] is a
//! `BrickStreamer<ZarrBricks>`. To pack one brick level, the backend:
//!
//! 1. asks the [kernel](crate::bricks::kernel) which voxels that level reads
//!    ([`BrickKernel::window_for_outputs`]: the brick and its one-voxel border for `Hi`; for `Lo`
//!    the downsampling filter's footprint widened to what the brick's value range reads, see
//!    below);
//! 2. takes the level-0 chunks that meet them from its [`ChunkCache`] (decoded chunks under a
//!    byte budget, least recently used evicted first), fetching the missing ones with at most
//!    [`ZarrStreamConfig::concurrency`] requests in flight; each request has the timeout and the
//!    retries with exponential backoff of [`RemoteOptions`] (object_store's client);
//! 3. packs the level from those voxels with the same kernel as every other source, so its
//!    bytes are those of [`crate::bricks::VolumeBrickSource`] over the loaded image, and the C0
//!    transitions hold as for any source.
//!
//! **Low-res bricks are derived from level 0** while streaming (the project's downsampling
//! filter), not read from the image's own pyramid level 1, whose sample positions differ from
//! ours (`docs/performance.md` counts the bytes fetched both ways); level 1 is read only where
//! level 0 failed (below).
//!
//! **Missing and failed chunks.** A missing chunk object is the fill value (as the Zarr spec
//! says). A chunk whose fetch fails (after the retries: HTTP 5xx, a timeout, a truncated body) or
//! that does not decode is a [`StreamError::Chunk`] naming the chunk and its object; it is
//! remembered (not fetched again until [`ZarrBricks::clear_failures`]).
//!
//! - A `Hi` level that reads a failed chunk fails with that error: the streamer reports it as
//!   failed ([`SourceError::Load`](crate::bricks::SourceError::Load), which is how the host
//!   learns of it: the frame report counts it and names the first error) and
//!   [`fallback_levels`](crate::bricks::fallback_levels) treats it as not loaded, so the brick
//!   falls back to its `Lo` level.
//! - A `Lo` level that reads a failed chunk **falls back to the image's own next coarser
//!   pyramid level** (level 1 when level 0 is streamed), opened when first needed (its chunks
//!   in a cache of its own, an eighth of [`ZarrStreamConfig::chunk_cache_bytes`], fetched with
//!   the same options and concurrency). The brick is packed from level 0 as usual, then every
//!   low-res sample whose filter taps read a voxel of a failed chunk is replaced by the coarser
//!   level resampled at that sample's position: sample `k` (hi-res position `2k`, level-0 index
//!   coordinate `2k - 1/2`) maps through both levels' OME-Zarr `scale` and `translation` to the
//!   coarser level's index coordinate, where the coarser voxels are interpolated trilinearly,
//!   clamped to the level's edges (`coarser.rs`; float values are also clamped to the reported
//!   [value range](ZarrStreamConfig::value_range)). The level loads, the brick is drawn `Lo`
//!   instead of empty, and the frame renders. The degradation is kept, not hidden:
//!   [`ZarrBricks::degraded_bricks`] lists every such brick with the [`StreamError::Chunk`] of
//!   the level-0 chunk it could not read, and [`ZarrBricks::fallback_stats`] counts the bricks
//!   (and samples, chunks, bytes) drawn from the coarser level. A brick whose `Lo` level later
//!   packs from level 0 alone (after [`ZarrBricks::clear_failures`]) leaves the list.
//! - **C0 transitions still hold.** Which samples come from the coarser level depends only on
//!   the sample and the failed chunks, not on the brick packing it: every brick whose low-res
//!   window meets a failed chunk reads all of that window's chunks, so two low-res bricks store
//!   the same values on their shared face (both from level 0 where its taps are intact, both
//!   resampled where not), exactly as two bricks packed from level 0 do. The low-res function
//!   is one global function again, just with some samples replaced, and every hi-res brick next
//!   to a low-res one goes through the fixup, which rewrites its border from the low-res
//!   neighbour's stored samples, whatever they hold. So the field is as continuous across such
//!   a brick as across any other. The one gap: a chunk whose fate changes between two packs (it
//!   loaded for one brick, was evicted, and failed when fetched again for its neighbour; or it
//!   loads after [`ZarrBricks::clear_failures`]) leaves those two bricks disagreeing on their
//!   shared face until the older one is packed again.
//! - **No coarser level** (a single-level image, a plain array, streaming the coarsest level),
//!   or one that cannot be opened, or a failed chunk of the coarser level too: the `Lo` level
//!   fails with the level-0 chunk's error as the `Hi` level does, and the brick is drawn
//!   `Absent` (the frame still renders).
//!
//! **Value ranges.** The per-brick ranges the planner culls with need the voxels a brick's
//! reconstruction reads. [`BrickBackend::value_ranges`] are the conservative ones, known before
//! anything is fetched: the whole normalised range `[0, 1]` for 8- and 16-bit images, the
//! caller's [`ZarrStreamConfig::value_range`] for float images (required). The source then
//! **learns each brick's exact range as its voxels arrive**: the window a `Lo` level is packed
//! from is the kernel's window for every output ([`BrickKernel::window_for`]: the low-res taps,
//! the hi-res brick with its border, and the taps of the one extra sample layer the range
//! covers; with a chunk shape that is a multiple of the brick size it meets the same chunks as
//! the low-res taps alone, for every filter but `LaMarSubsample`, whose taps do not reach the
//! voxel below a brick), so packing `Lo` also yields the range exactly as
//! [`crate::bricks::brick_value_ranges_for_storage`] defines it (the kernel's range output, bit
//! for bit that of [`crate::bricks::VolumeBrickSource`]). A `Lo` level packed with a failed chunk
//! in its window (even one resampled from the coarser level) teaches nothing: that brick keeps its
//! conservative range. [`BrickBackend::learned_value_ranges`] hands the ranges out (a shared
//! snapshot, copied once per change, so [`BrickBackend::value_ranges`] keeps its plain borrow of
//! ranges that never change). The pass (`embed::VolumePass::update`) culls with them:
//! a brick its culling rejects under its learned range is given the planner with that range,
//! every other brick keeps its conservative one (the planner also ranks bricks by range width,
//! and exact widths for streamed bricks against conservative ones for the others would rank
//! every brick not yet streamed first); the planner culls again whenever that changes
//! ([`crate::plan`], step 1). Because the planner requests every `Lo` level
//! before any `Hi` one, a brick that turns out empty under the transfer function is culled
//! before its `Hi` level is loaded, and that level is never packed, uploaded or held in RAM (its
//! chunks were fetched for `Lo` already; they are fetched again only when the chunk cache
//! evicted them, which no longer happens for such bricks).

mod chunk_cache;
mod coarser;
mod levels;

pub use chunk_cache::{ChunkCache, ChunkCacheStats};
pub use levels::{ZarrLevels, ZarrLevelsConfig};

use crate::bricks::kernel::{BrickBox, BrickKernel, PackOutputs, TexelsMut, VoxelWindow};
use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, max_low_res_index, quantize_to, BrickError,
    BrickGrid, DownsampleFilter, Level, ValueRange,
};
use crate::store::{BrickBackend, BrickStreamer, StoreError, StreamerConfig};
use crate::volume::formats::{RemoteOptions, ZarrChunk, ZarrChunks, ZarrLocation};
use crate::volume::{ScalarType, VolumeError, VoxelData};
use coarser::Coarser;
use glam::{UVec3, Vec3};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

/// A brick source streaming an OME-Zarr image (see the [module docs](self)).
pub type ZarrBrickSource = BrickStreamer<ZarrBricks>;

/// Why streaming an OME-Zarr image failed.
#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    /// A chunk could not be fetched or decoded (after the retries).
    #[error("chunk {chunk:?} ({object}) failed: {source}")]
    Chunk {
        /// Chunk coordinates (x, y, z).
        chunk: [u32; 3],
        /// Its object (file or URL).
        object: String,
        /// What went wrong.
        #[source]
        source: Arc<VolumeError>,
    },
    /// A chunk needed by a brick level failed.
    #[error("brick {brick} {level:?}: {source}")]
    Brick {
        /// The brick.
        brick: u32,
        /// The level.
        level: Level,
        /// The chunk's error ([`StreamError::Chunk`]) or the packing error.
        #[source]
        source: Box<StreamError>,
    },
    /// The brick kernel refused the brick (out of range, a wrong buffer).
    #[error("packing: {0}")]
    Pack(#[from] BrickError),
    /// Opening the image failed.
    #[error("opening the image: {0}")]
    Open(#[from] VolumeError),
    /// The configuration is unusable.
    #[error("invalid streaming configuration: `{field}`: {message}")]
    InvalidConfig {
        /// The field at fault.
        field: &'static str,
        /// Why.
        message: String,
    },
    /// The streamer could not start.
    #[error("starting the streamer: {0}")]
    Streamer(#[from] StoreError),
}

/// How a [`ZarrBricks`] bricks and fetches.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ZarrStreamConfig {
    /// Brick edge `n` (the grid of the packed bricks).
    pub brick_size: u32,
    /// The filter that derives the low-res bricks from level 0.
    pub filter: DownsampleFilter,
    /// Chunk requests in flight at most.
    pub concurrency: usize,
    /// Decoded bytes of chunks kept in RAM.
    pub chunk_cache_bytes: usize,
    /// The value range (normalised as [`VoxelData::normalized`]) to report for every brick;
    /// `None`: `[0, 1]`, which only 8- and 16-bit images allow.
    pub value_range: Option<ValueRange>,
}

impl Default for ZarrStreamConfig {
    fn default() -> Self {
        Self {
            brick_size: 32,
            filter: DownsampleFilter::Mean2,
            concurrency: 8,
            chunk_cache_bytes: 256 << 20,
            value_range: None,
        }
    }
}

/// What the fallback to the image's coarser pyramid level did (see the [module docs](self)).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FallbackStats {
    /// The coarser level (the streamed level's index plus one), once opened; `None` before it
    /// was first needed, and when the image has no coarser level.
    pub level: Option<usize>,
    /// Bricks whose low-res level is currently packed partly from the coarser level (each
    /// brick once, however often it was packed).
    pub bricks: usize,
    /// Low-res samples taken from the coarser level, over all packs.
    pub samples: u64,
    /// The counters of the coarser level's chunk cache.
    pub cache: ChunkCacheStats,
    /// Stored bytes fetched from the coarser level.
    pub bytes_fetched: u64,
}

/// The value ranges learned from packed low-res levels.
struct Learned {
    /// Per brick: the exact range where `known`, else the conservative one.
    ranges: Vec<ValueRange>,
    known: Vec<bool>,
    /// Bricks `known`.
    count: usize,
    /// `ranges` as last handed out; `None` after a change.
    snapshot: Option<Arc<[ValueRange]>>,
}

/// The coarser level, opened lazily.
enum CoarserState {
    /// Not needed yet.
    Unopened,
    /// Opened.
    Open(Arc<Coarser>),
    /// The image has none.
    Missing,
    /// Opening failed (tried again after [`ZarrBricks::clear_failures`]).
    Failed,
}

/// One level of an OME-Zarr image as a [`BrickBackend`]: packs brick levels from its chunks.
pub struct ZarrBricks {
    chunks: ZarrChunks,
    cache: ChunkCache,
    grid: BrickGrid,
    filter: DownsampleFilter,
    scalar: ScalarType,
    ranges: Vec<ValueRange>,
    range: ValueRange,
    concurrency: usize,
    coarser_cache_bytes: usize,
    coarser: Mutex<CoarserState>,
    /// Bricks whose `Lo` level came partly from the coarser level, with the level-0 chunk error
    /// that made it necessary.
    degraded: Mutex<BTreeMap<u32, Arc<StreamError>>>,
    coarser_samples: AtomicU64,
    learned: Mutex<Learned>,
}

/// Locks `m`, recovering from a poisoned lock (the data stays consistent: every update is one
/// assignment).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl std::fmt::Debug for ZarrBricks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZarrBricks")
            .field("chunks", &self.chunks)
            .field("grid", &self.grid)
            .finish()
    }
}

impl ZarrBricks {
    /// Bricks the opened level `chunks` as `config` says.
    pub fn new(chunks: ZarrChunks, config: ZarrStreamConfig) -> Result<Self, StreamError> {
        let grid = BrickGrid::new(chunks.dims(), config.brick_size).map_err(|e| {
            StreamError::InvalidConfig {
                field: "brick_size",
                message: e.to_string(),
            }
        })?;
        let scalar = chunks.scalar();
        let range = reported_range(config.value_range, scalar, &chunks.root().display())?;
        Ok(Self {
            cache: ChunkCache::new(config.chunk_cache_bytes, config.concurrency),
            ranges: vec![range; grid.brick_count()],
            chunks,
            grid,
            filter: config.filter,
            scalar,
            range,
            concurrency: config.concurrency,
            coarser_cache_bytes: config.chunk_cache_bytes / COARSER_CACHE_SHARE,
            coarser: Mutex::new(CoarserState::Unopened),
            degraded: Mutex::new(BTreeMap::new()),
            coarser_samples: AtomicU64::new(0),
            learned: Mutex::new(Learned {
                ranges: vec![range; grid.brick_count()],
                known: vec![false; grid.brick_count()],
                count: 0,
                snapshot: None,
            }),
        })
    }

    /// Opens level `level` of the image at `location` (fetched as `options` says) and bricks it.
    pub fn open(
        location: &ZarrLocation,
        level: usize,
        options: &RemoteOptions,
        config: ZarrStreamConfig,
    ) -> Result<Self, StreamError> {
        Self::new(ZarrChunks::open(location, level, options)?, config)
    }

    /// The image level read.
    pub fn chunks(&self) -> &ZarrChunks {
        &self.chunks
    }

    /// The chunk cache's counters.
    pub fn cache_stats(&self) -> ChunkCacheStats {
        self.cache.stats()
    }

    /// Forgets failed chunks, of both levels, and a failed opening of the coarser level (all
    /// tried again when next needed; the streamer's own failures are cleared with
    /// [`BrickStreamer::clear_failures`]).
    pub fn clear_failures(&self) {
        self.cache.clear_failures();
        let mut coarser = lock(&self.coarser);
        match &*coarser {
            CoarserState::Open(c) => c.clear_failures(),
            CoarserState::Failed => *coarser = CoarserState::Unopened,
            CoarserState::Unopened | CoarserState::Missing => {}
        }
    }

    /// Bricks whose exact value range is known (learned when their `Lo` level was packed from
    /// level 0 alone).
    pub fn learned_ranges(&self) -> usize {
        lock(&self.learned).count
    }

    /// What the fallback to the coarser pyramid level did.
    pub fn fallback_stats(&self) -> FallbackStats {
        let coarser = match &*lock(&self.coarser) {
            CoarserState::Open(c) => Some(c.clone()),
            _ => None,
        };
        FallbackStats {
            level: coarser.as_ref().map(|c| c.chunks().level()),
            bricks: lock(&self.degraded).len(),
            samples: self.coarser_samples.load(Ordering::Relaxed),
            cache: coarser
                .as_ref()
                .map(|c| c.cache_stats())
                .unwrap_or_default(),
            bytes_fetched: coarser.map_or(0, |c| c.chunks().bytes_fetched()),
        }
    }

    /// The bricks whose `Lo` level is packed partly from the coarser pyramid level, in brick
    /// order, each with the [`StreamError::Chunk`] of the (first) level-0 chunk it could not
    /// read: the host's record of what is drawn degraded.
    pub fn degraded_bricks(&self) -> Vec<(u32, Arc<StreamError>)> {
        lock(&self.degraded)
            .iter()
            .map(|(&b, e)| (b, e.clone()))
            .collect()
    }

    /// The coarser level, opened on first use; `None` when the image has none or opening it
    /// failed (logged once).
    fn coarser(&self) -> Option<Arc<Coarser>> {
        match &*lock(&self.coarser) {
            CoarserState::Open(c) => return Some(c.clone()),
            CoarserState::Missing | CoarserState::Failed => return None,
            CoarserState::Unopened => {}
        }
        // Opened without the lock (it may fetch metadata): only the loader thread packs.
        let opened = Coarser::open(&self.chunks, self.coarser_cache_bytes, self.concurrency);
        let mut state = lock(&self.coarser);
        if let CoarserState::Unopened = &*state {
            *state = match opened {
                Ok(Some(c)) => CoarserState::Open(Arc::new(c)),
                Ok(None) => CoarserState::Missing,
                Err(e) => {
                    log::warn!(
                        "{}: level {} (the fallback for failed chunks): {e}",
                        self.chunks.root().display(),
                        self.chunks.level() + 1
                    );
                    CoarserState::Failed
                }
            };
        }
        match &*state {
            CoarserState::Open(c) => Some(c.clone()),
            _ => None,
        }
    }

    /// The voxels `(origin, extent)` that packing `brick` at `level` reads: for `Hi` the brick
    /// and its one-voxel border ([`BrickKernel::window_for_outputs`]); for `Lo` the window of
    /// every output ([`BrickKernel::window_for`]), which holds the low-res filter's taps, the
    /// hi-res window and the taps of the extra sample layer of the brick's value range, so that
    /// packing `Lo` also learns the brick's exact range (see the [module docs](self)).
    pub fn window(&self, brick: u32, level: Level) -> Result<(UVec3, UVec3), StreamError> {
        let count = self.grid.brick_count();
        if brick as usize >= count || level == Level::Absent {
            return Err(StreamError::Pack(BrickError::BrickOutOfRange {
                brick: [brick, 0, 0],
                bricks_per_axis: self.grid.bricks_per_axis().to_array(),
            }));
        }
        let bricks = BrickBox::single(self.grid.brick_coords(brick as usize));
        let kernel = BrickKernel::new(&self.grid, self.filter, self.scalar);
        Ok(match level {
            Level::Lo => kernel.window_for(&bricks)?,
            _ => kernel.window_for_outputs(&bricks, true, false)?,
        })
    }

    /// The chunks (chunk coordinates) that packing `brick` at `level` reads, x fastest.
    pub fn chunks_for(&self, brick: u32, level: Level) -> Result<Vec<UVec3>, StreamError> {
        let (origin, extent) = self.window(brick, level)?;
        Ok(chunks_meeting(self.chunks.chunk_shape(), origin, extent))
    }

    /// Packs `brick` at `level` into a new buffer (what the streamer does on its loader thread).
    pub fn read_brick(&self, brick: u32, level: Level) -> Result<Vec<u8>, StreamError> {
        let mut out = vec![0u8; self.level_bytes(level)];
        self.read_brick_into(brick, level, &mut out)?;
        Ok(out)
    }

    fn pack(&self, brick: u32, level: Level, out: &mut [u8]) -> Result<(), StreamError> {
        let (origin, extent) = self.window(brick, level)?;
        let expected = self.level_bytes(level);
        if out.len() != expected {
            return Err(StreamError::InvalidConfig {
                field: "buffer",
                message: format!(
                    "{} bytes for a {level:?} brick of {expected} bytes",
                    out.len()
                ),
            });
        }
        let wanted = chunks_meeting(self.chunks.chunk_shape(), origin, extent);
        let mut window = VoxelData::zeroed(self.scalar, extent.element_product() as usize);
        let mut failed = Vec::new();
        for (c, chunk) in wanted
            .iter()
            .zip(self.cache.get_each(&self.chunks, &wanted))
        {
            match chunk {
                Ok(chunk) => copy_into(&mut window, origin, extent, &chunk),
                Err(e) => failed.push((*c, e)),
            }
        }
        let coords = self.grid.brick_coords(brick as usize);
        let mut kernel = BrickKernel::new(&self.grid, self.filter, self.scalar);
        let voxels = VoxelWindow::new(&window, origin, extent)?;
        if level == Level::Hi {
            if !failed.is_empty() {
                return Err(failed.swap_remove(0).1);
            }
            out.copy_from_slice(kernel.pack_level(&voxels, coords, true)?.as_bytes());
            return Ok(());
        }
        // Low-res: the samples whose taps meet a failed chunk (none when the failed chunks only
        // hold voxels of the range's extra layer) come from the coarser level.
        let bad: Vec<UVec3> = failed.iter().map(|(c, _)| *c).collect();
        let (texels, points, first_bad) = self.samples_meeting(coords, &bad);
        let coarser = match texels.is_empty() {
            true => None,
            false => match self.coarser() {
                Some(c) => Some(c),
                None => return Err(failed.swap_remove(first_bad).1),
            },
        };
        let mut packed = VoxelData::zeroed(self.scalar, expected / self.scalar.size_bytes());
        let mut range = [ValueRange::EMPTY];
        kernel.pack_window(
            &voxels,
            &BrickBox::single(coords),
            PackOutputs {
                lo: Some(TexelsMut::of(&mut packed)),
                // Exact only when every voxel read is the image's.
                ranges: failed.is_empty().then_some(&mut range[..]),
                ..PackOutputs::default()
            },
        )?;
        drop(window);
        out.copy_from_slice(packed.as_bytes());
        if failed.is_empty() {
            self.learn(brick, range[0]);
        }
        let Some(coarser) = coarser else {
            lock(&self.degraded).remove(&brick);
            return Ok(());
        };
        let first = failed.swap_remove(first_bad).1;
        match self.fill_from_coarser(&coarser, &texels, &points, out) {
            Ok(()) => {
                self.coarser_samples
                    .fetch_add(texels.len() as u64, Ordering::Relaxed);
                lock(&self.degraded).insert(brick, Arc::new(first));
                Ok(())
            }
            Err(e) => {
                log::warn!(
                    "{}: brick {brick} from level {}: {e}",
                    self.name(),
                    coarser.chunks().level()
                );
                Err(first)
            }
        }
    }

    /// Records `range` as the exact value range of `brick`.
    fn learn(&self, brick: u32, range: ValueRange) {
        let mut learned = lock(&self.learned);
        let b = brick as usize;
        if !learned.known[b] {
            learned.known[b] = true;
            learned.count += 1;
        }
        if learned.ranges[b] != range {
            learned.ranges[b] = range;
            learned.snapshot = None;
        }
    }

    /// The texels (indices into the packed low-res brick `brick`) whose samples' filter taps
    /// read a voxel of a `failed` chunk, their samples' level-0 index coordinates, and the
    /// index in `failed` of the first chunk such a tap reads (0 when none does).
    fn samples_meeting(
        &self,
        brick: UVec3,
        failed: &[UVec3],
    ) -> (Vec<usize>, Vec<[f64; 3]>, usize) {
        let (mut texels, mut points, mut first) = (Vec::new(), Vec::new(), None);
        if failed.is_empty() {
            return (texels, points, 0);
        }
        let n = self.grid.brick_size();
        let e = low_res_brick_extent(n) as usize;
        let dims = self.grid.dims();
        let kmax = max_low_res_index(dims);
        let chunk = self.chunks.chunk_shape();
        let taps = self.filter.taps();
        let first_tap = taps.iter().map(|t| t.0).min().unwrap_or(0);
        let last_tap = taps.iter().map(|t| t.0).max().unwrap_or(0);
        // Per axis: the clamped sample index of each texel, and for each failed chunk whether
        // the sample's taps meet the chunk along that axis.
        let ks: [Vec<u32>; 3] = std::array::from_fn(|a| {
            (0..e as u32)
                .map(|j| (n * brick[a] / 2 + j).min(kmax[a]))
                .collect()
        });
        let meets: Vec<[Vec<bool>; 3]> = failed
            .iter()
            .map(|c| {
                std::array::from_fn(|a| {
                    let last = i64::from(dims[a]) - 1;
                    let lo = i64::from(c[a] * chunk[a]);
                    let hi = (i64::from((c[a] + 1) * chunk[a]) - 1).min(last);
                    ks[a]
                        .iter()
                        .map(|&k| {
                            let first = (2 * i64::from(k) + first_tap).clamp(0, last);
                            let end = (2 * i64::from(k) + last_tap).clamp(0, last);
                            first <= hi && lo <= end
                        })
                        .collect()
                })
            })
            .collect();
        for z in 0..e {
            for y in 0..e {
                for x in 0..e {
                    let Some(i) = meets.iter().position(|m| m[0][x] && m[1][y] && m[2][z]) else {
                        continue;
                    };
                    first = Some(first.map_or(i, |f: usize| f.min(i)));
                    texels.push(x + e * (y + e * z));
                    // Sample k sits at hi-res position 2k: level-0 index coordinate 2k - 1/2.
                    let at = |a: usize, j: usize| 2.0 * f64::from(ks[a][j]) - 0.5;
                    points.push([at(0, x), at(1, y), at(2, z)]);
                }
            }
        }
        (texels, points, first.unwrap_or(0))
    }

    /// Overwrites `texels` of the packed low-res brick `out` with the coarser level resampled
    /// at their samples' level-0 index coordinates `points`.
    fn fill_from_coarser(
        &self,
        coarser: &Coarser,
        texels: &[usize],
        points: &[[f64; 3]],
        out: &mut [u8],
    ) -> Result<(), StreamError> {
        let range = self.range;
        let values: Vec<f32> = coarser
            .sample(points)?
            .into_iter()
            .map(|v| match self.scalar {
                // The reported value range must hold every texel.
                ScalarType::F32 => v.clamp(range.min, range.max),
                ScalarType::U8 | ScalarType::U16 => v,
            })
            .collect();
        let bytes = quantize_to(&values, self.scalar);
        let size = self.scalar.size_bytes();
        for (i, &t) in texels.iter().enumerate() {
            out[t * size..(t + 1) * size].copy_from_slice(&bytes[i * size..(i + 1) * size]);
        }
        Ok(())
    }
}

/// The value range a streamed image reports before its chunks arrive: `given`, else `[0, 1]`
/// for 8- and 16-bit images; a float image (`name`, for the message) must be given one, and it
/// must be finite.
pub(super) fn reported_range(
    given: Option<ValueRange>,
    scalar: ScalarType,
    name: &dyn std::fmt::Display,
) -> Result<ValueRange, StreamError> {
    let range = match (given, scalar) {
        (Some(r), _) => r,
        (None, ScalarType::U8 | ScalarType::U16) => ValueRange { min: 0.0, max: 1.0 },
        (None, ScalarType::F32) => {
            return Err(StreamError::InvalidConfig {
                field: "value_range",
                message: format!(
                    "{name} holds float values: give their range (it cannot be known before \
                     every chunk is fetched)"
                ),
            })
        }
    };
    if !(range.min.is_finite() && range.max.is_finite() && range.min <= range.max) {
        return Err(StreamError::InvalidConfig {
            field: "value_range",
            message: format!("{range:?} is not a finite range"),
        });
    }
    Ok(range)
}

/// The coarser level's chunk cache gets this share of [`ZarrStreamConfig::chunk_cache_bytes`]
/// (on top of it).
const COARSER_CACHE_SHARE: usize = 8;

/// Opens level `level` of the image at `location` as a streaming [`ZarrBrickSource`]: chunks as
/// `config` says, packed bricks under `streamer.ram_budget_bytes`.
pub fn open_zarr_source(
    location: &ZarrLocation,
    level: usize,
    options: &RemoteOptions,
    config: ZarrStreamConfig,
    streamer: StreamerConfig,
) -> Result<ZarrBrickSource, StreamError> {
    let bricks = ZarrBricks::open(location, level, options, config)?;
    Ok(BrickStreamer::new(bricks, streamer)?)
}

/// The chunks of shape `chunk` that meet the voxel box `(origin, extent)` (non-empty), x fastest.
pub(super) fn chunks_meeting(chunk: UVec3, origin: UVec3, extent: UVec3) -> Vec<UVec3> {
    let first = origin / chunk;
    let last = (origin + extent - UVec3::ONE) / chunk;
    let mut out = Vec::new();
    for z in first.z..=last.z {
        for y in first.y..=last.y {
            for x in first.x..=last.x {
                out.push(UVec3::new(x, y, z));
            }
        }
    }
    out
}

/// Copies the part of `chunk` inside the window `(origin, extent)` into `window`.
pub(super) fn copy_into(window: &mut VoxelData, origin: UVec3, extent: UVec3, chunk: &ZarrChunk) {
    match (window, &chunk.data) {
        (VoxelData::U8(w), VoxelData::U8(c)) => copy_box(w, origin, extent, c, chunk),
        (VoxelData::U16(w), VoxelData::U16(c)) => copy_box(w, origin, extent, c, chunk),
        (VoxelData::F32(w), VoxelData::F32(c)) => copy_box(w, origin, extent, c, chunk),
        // One level's chunks all map to the level's scalar type.
        _ => debug_assert!(false, "chunk and window scalar types differ"),
    }
}

fn copy_box<T: Copy>(dst: &mut [T], origin: UVec3, extent: UVec3, src: &[T], chunk: &ZarrChunk) {
    let lo = origin.max(chunk.origin);
    let hi = (origin + extent).min(chunk.origin + chunk.extent);
    if !lo.cmplt(hi).all() {
        return;
    }
    let len = (hi.x - lo.x) as usize;
    for z in lo.z..hi.z {
        for y in lo.y..hi.y {
            let s = (lo.x - chunk.origin.x) as usize
                + chunk.extent.x as usize
                    * ((y - chunk.origin.y) as usize
                        + chunk.extent.y as usize * (z - chunk.origin.z) as usize);
            let d = (lo.x - origin.x) as usize
                + extent.x as usize
                    * ((y - origin.y) as usize + extent.y as usize * (z - origin.z) as usize);
            dst[d..d + len].copy_from_slice(&src[s..s + len]);
        }
    }
}

impl BrickBackend for ZarrBricks {
    type Error = StreamError;

    fn name(&self) -> String {
        self.chunks.root().display().to_string()
    }

    fn grid(&self) -> BrickGrid {
        self.grid
    }

    fn scalar(&self) -> ScalarType {
        self.scalar
    }

    fn filter(&self) -> DownsampleFilter {
        self.filter
    }

    fn spacing(&self) -> Vec3 {
        self.chunks.spacing()
    }

    fn value_ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    fn value_range(&self) -> ValueRange {
        self.range
    }

    fn learned_value_ranges(&self) -> Option<Arc<[ValueRange]>> {
        let mut learned = lock(&self.learned);
        if learned.count == 0 {
            return None;
        }
        let Learned {
            ranges, snapshot, ..
        } = &mut *learned;
        Some(
            snapshot
                .get_or_insert_with(|| ranges.as_slice().into())
                .clone(),
        )
    }

    fn level_bytes(&self, level: Level) -> usize {
        let n = self.grid.brick_size();
        let edge = match level {
            Level::Hi => hi_res_brick_extent(n),
            Level::Lo => low_res_brick_extent(n),
            Level::Absent => return 0,
        };
        (edge as usize).pow(3) * self.scalar.size_bytes()
    }

    fn read_brick_into(&self, brick: u32, level: Level, out: &mut [u8]) -> Result<(), StreamError> {
        self.pack(brick, level, out)
            .map_err(|e| StreamError::Brick {
                brick,
                level,
                source: Box::new(e),
            })
    }
}
