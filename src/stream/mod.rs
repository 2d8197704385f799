//! Streaming bricks from an OME-Zarr image, local or remote, chunk by chunk.
//!
//! [`ZarrBricks`] is a [`BrickBackend`]: the store's [`BrickStreamer`] (wanted set and priorities
//! from the planner through [`BrickSource::request_levels`](crate::bricks::BrickSource), RAM
//! budget for packed bricks, pins, failures; [`BrickSource::brick_bytes`](crate::bricks::BrickSource)
//! never blocks) drives it exactly as it drives a brick store file, so [`ZarrBrickSource`] is a
//! `BrickStreamer<ZarrBricks>`. To pack one brick level, the backend:
//!
//! 1. asks the [kernel](crate::bricks::kernel) which voxels that level reads
//!    ([`BrickKernel::window_for_outputs`]: the brick and its one-voxel border for `Hi`; the
//!    downsampling filter's footprint for `Lo`);
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
//! ours (`docs/performance.md` counts the bytes fetched both ways).
//!
//! **Missing and failed chunks.** A missing chunk object is the fill value (as the Zarr spec
//! says). A chunk whose fetch fails (after the retries: HTTP 5xx, a timeout, a truncated body) or
//! that does not decode is a [`StreamError::Chunk`] naming the chunk and its object; it is
//! remembered (not fetched again until [`ZarrBricks::clear_failures`]), and every brick level
//! that needs it fails with that error: the streamer reports the level as failed
//! ([`SourceError::Load`](crate::bricks::SourceError::Load)), and
//! [`fallback_levels`](crate::bricks::fallback_levels) treats it as not loaded: a `Hi` brick
//! falls back to `Lo` when its low-res level loaded, else is drawn empty, and the frame renders.
//!
//! **Value ranges.** The per-brick ranges the planner culls with would need every voxel; before
//! anything is fetched they are conservative: the whole normalised range `[0, 1]` for 8- and
//! 16-bit images, the caller's [`ZarrStreamConfig::value_range`] for float images (required).

mod chunk_cache;

pub use chunk_cache::{ChunkCache, ChunkCacheStats};

use crate::bricks::kernel::{BrickBox, BrickKernel, VoxelWindow};
use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, BrickError, BrickGrid, DownsampleFilter, Level,
    ValueRange,
};
use crate::error::Result;
use crate::store::{BrickBackend, BrickStreamer, StoreError, StreamerConfig};
use crate::volume::formats::{RemoteOptions, ZarrChunk, ZarrChunks, ZarrLocation};
use crate::volume::{ScalarType, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::sync::Arc;

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

/// One level of an OME-Zarr image as a [`BrickBackend`]: packs brick levels from its chunks.
pub struct ZarrBricks {
    chunks: ZarrChunks,
    cache: ChunkCache,
    grid: BrickGrid,
    filter: DownsampleFilter,
    scalar: ScalarType,
    ranges: Vec<ValueRange>,
    range: ValueRange,
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
        let range = match (config.value_range, scalar) {
            (Some(r), _) => r,
            (None, ScalarType::U8 | ScalarType::U16) => ValueRange { min: 0.0, max: 1.0 },
            (None, ScalarType::F32) => {
                return Err(StreamError::InvalidConfig {
                    field: "value_range",
                    message: format!(
                        "{} holds float values: give their range (it cannot be known before \
                         every chunk is fetched)",
                        chunks.root().display()
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
        Ok(Self {
            cache: ChunkCache::new(config.chunk_cache_bytes, config.concurrency),
            ranges: vec![range; grid.brick_count()],
            chunks,
            grid,
            filter: config.filter,
            scalar,
            range,
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

    /// Forgets failed chunks (fetched again when next needed; the streamer's own failures are
    /// cleared with [`BrickStreamer::clear_failures`]).
    pub fn clear_failures(&self) {
        self.cache.clear_failures();
    }

    /// The voxels `(origin, extent)` that packing `brick` at `level` reads.
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
        Ok(kernel.window_for_outputs(&bricks, level == Level::Hi, level == Level::Lo)?)
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
        let wanted = chunks_meeting(self.chunks.chunk_shape(), origin, extent);
        let chunks = self.cache.get_many(&self.chunks, &wanted)?;
        let mut window = VoxelData::zeroed(self.scalar, extent.element_product() as usize);
        for chunk in &chunks {
            copy_into(&mut window, origin, extent, chunk);
        }
        drop(chunks);
        let packed = BrickKernel::new(&self.grid, self.filter, self.scalar).pack_level(
            &VoxelWindow::new(&window, origin, extent)?,
            self.grid.brick_coords(brick as usize),
            level == Level::Hi,
        )?;
        let bytes = packed.as_bytes();
        if bytes.len() != out.len() {
            return Err(StreamError::InvalidConfig {
                field: "buffer",
                message: format!(
                    "{} bytes for a {level:?} brick of {} bytes",
                    out.len(),
                    bytes.len()
                ),
            });
        }
        out.copy_from_slice(bytes);
        Ok(())
    }
}

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
fn chunks_meeting(chunk: UVec3, origin: UVec3, extent: UVec3) -> Vec<UVec3> {
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
fn copy_into(window: &mut VoxelData, origin: UVec3, extent: UVec3, chunk: &ZarrChunk) {
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
