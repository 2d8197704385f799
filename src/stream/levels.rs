//! [`ZarrLevels`]: an OME-Zarr image, local or remote, as the stored bricks of every level of
//! the three-level cache (a [`LevelBackend`] for [`crate::store::LevelStreamer`]), read from the
//! image's own pyramid levels chunk by chunk, without converting it first.
//!
//! **Which image level.** Vertex level `k` of the cache has samples every `2^k` voxels. It is
//! read from the coarsest image level whose spacing is at most `2^k` times level 0's on every
//! axis (from the OME-Zarr `scale`s; a factor of `1.001` absorbs rounding): level `k` itself in
//! the usual pyramid of factor 2, the coarsest image level for vertex levels past the image's
//! pyramid, level 0 where the image has no other.
//!
//! **Positions.** Level 0's stored bricks are the image's level-0 voxels (`n + 4` per axis, two
//! border voxels per side, clamped to the volume), exactly. Vertex level `k`'s sample `j` lies
//! at hi-res vertex `2^k j`, that is at level-0 index coordinate `2^k j - 1/2` (voxel `i`'s
//! centre is vertex `i + 1/2`), with `j` clamped to the level's grid
//! (`LevelGrid::covering_dims`), as every other source clamps it. Its value is the image
//! level's voxels interpolated trilinearly there, after mapping through both levels' OME-Zarr
//! `scale` and `translation` (`coarser.rs`; clamp-to-edge). A pyramid written by 2x2x2 means
//! (translation `(2^k - 1)/2` voxels) maps sample `j` to `j - 1/2` in its level `k`: the mean of
//! the two image voxels on either side per axis. The result is a valid vertex level whatever
//! filter wrote the pyramid; the C0 transitions need nothing of the levels but that
//! neighbouring stored bricks agree on their shared samples, which they do (a sample's value
//! depends only on its index).
//!
//! **Value ranges.** Nothing is known before the chunks are fetched, so
//! [`LevelBackend::stored_range`] is `None` for every brick (no value culling), and the volume's
//! range is `[0, 1]` for 8- and 16-bit images, or the caller's for float ones
//! ([`ZarrLevelsConfig::value_range`], required).
//!
//! **Fetching.** Each image level has its own chunk cache ([`ZarrLevelsConfig::chunk_cache_bytes`]
//! shared equally between the levels), fetching with at most
//! [`ZarrLevelsConfig::concurrency`] requests in flight and the timeouts and retries of
//! [`RemoteOptions`]. A chunk that fails to fetch or decode fails the stored bricks that read
//! it with a [`StreamError::Chunk`] naming it (the streamer keeps the error; the brick stays at
//! the level drawn before).

use super::coarser::Coarser;
use super::{reported_range, ChunkCacheStats, StreamError};
use crate::bricks::{quantize_to, BrickGrid, ValueRange};
use crate::cache::{
    block_origin, min_brick_size_for_levels, pyramid_levels, stored_brick_edge, stored_first_sample,
};
use crate::pyramid::{LevelGrid, SamplePlacement};
use crate::store::{LevelBackend, StoreError};
use crate::volume::formats::{RemoteOptions, ZarrChunks, ZarrLocation};
use crate::volume::ScalarType;
use glam::{IVec3, UVec3, Vec3};

/// How a [`ZarrLevels`] bricks and fetches.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ZarrLevelsConfig {
    /// Brick edge `n` of level 0.
    pub brick_size: u32,
    /// Vertex levels (`None`: every level the brick size and the grid allow,
    /// [`pyramid_levels`]).
    pub levels: Option<u32>,
    /// Chunk requests in flight at most, per image level.
    pub concurrency: usize,
    /// Decoded bytes of chunks kept in RAM, over all image levels.
    pub chunk_cache_bytes: usize,
    /// The normalised value range of a float image (required for one); `None`: `[0, 1]`.
    pub value_range: Option<ValueRange>,
    /// The image level drawn as vertex level 0 (its voxels are level 0's stored bricks; the
    /// coarser vertex levels read this level or coarser ones). 0: the image's full resolution.
    pub base_level: usize,
}

impl Default for ZarrLevelsConfig {
    fn default() -> Self {
        Self {
            brick_size: 32,
            levels: None,
            concurrency: 8,
            chunk_cache_bytes: 256 << 20,
            value_range: None,
            base_level: 0,
        }
    }
}

/// An OME-Zarr image read as the stored bricks of every level (module docs).
pub struct ZarrLevels {
    name: String,
    grid: BrickGrid,
    levels: u32,
    scalar: ScalarType,
    spacing: Vec3,
    range: ValueRange,
    /// Per image level used: its sampler at level-0 index coordinates.
    samplers: Vec<Coarser>,
    /// Per vertex level: the index into `samplers`.
    sampler_of: Vec<usize>,
    /// Per vertex level: the image level read.
    image_level_of: Vec<usize>,
}

impl std::fmt::Debug for ZarrLevels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZarrLevels")
            .field("name", &self.name)
            .field("grid", &self.grid)
            .field("levels", &self.levels)
            .field("image_levels", &self.image_level_of)
            .finish()
    }
}

impl ZarrLevels {
    /// Opens the image at `location` (its level 0 and every image level a vertex level reads;
    /// metadata only, no chunk). Errors: the image cannot be opened, a brick size it cannot be
    /// bricked with, a level count outside `1..=31` or past what the brick size takes, a float
    /// image without [`ZarrLevelsConfig::value_range`], levels whose coordinates do not map.
    pub fn open(
        location: &ZarrLocation,
        options: &RemoteOptions,
        config: ZarrLevelsConfig,
    ) -> Result<Self, StreamError> {
        let invalid =
            |field: &'static str, message: String| StreamError::InvalidConfig { field, message };
        let base = ZarrChunks::open(location, config.base_level, options)?;
        let name = base.root().display().to_string();
        let grid = BrickGrid::new(base.dims(), config.brick_size)
            .map_err(|e| invalid("brick_size", e.to_string()))?;
        let n = config.brick_size;
        let levels = config
            .levels
            .unwrap_or(pyramid_levels(n, grid.bricks_per_axis()));
        let min_size = min_brick_size_for_levels(levels);
        if !(1..=31).contains(&levels) || n < min_size {
            return Err(invalid(
                "levels",
                format!(
                    "{levels} levels with bricks of {n}: 1..=31 levels, and {levels} levels \
                     need bricks of at least {min_size} voxels"
                ),
            ));
        }
        let scalar = base.scalar();
        let range = reported_range(config.value_range, scalar, &name)?;
        // The coarsest image level within 2^k of level 0's spacing, per vertex level.
        let s0 = base.spacing();
        // factors[i]: image level `base_level + i`.
        let mut factors = vec![1.0f32];
        for m in config.base_level + 1..base.level_count() {
            let s = base.open_level(m)?.spacing();
            factors.push((s / s0).max_element());
        }
        let image_level_of: Vec<usize> = (0..levels)
            .map(|k| {
                let reach = (1u64 << k) as f32 * 1.001;
                let i = (0..factors.len())
                    .rev()
                    .find(|&i| factors[i] <= reach)
                    .unwrap_or(0);
                config.base_level + i
            })
            .collect();
        let mut used: Vec<usize> = image_level_of.clone();
        used.dedup();
        let share = config.chunk_cache_bytes / used.len().max(1);
        let samplers = used
            .iter()
            .map(|&m| Coarser::open_level(&base, m, share, config.concurrency.max(1)))
            .collect::<Result<Vec<_>, _>>()?;
        let sampler_of = image_level_of
            .iter()
            .map(|m| used.iter().position(|u| u == m).unwrap_or(0))
            .collect();
        Ok(Self {
            name,
            grid,
            levels,
            scalar,
            spacing: s0,
            range,
            samplers,
            sampler_of,
            image_level_of,
        })
    }

    /// The image level each vertex level is read from (index: vertex level).
    pub fn image_levels(&self) -> &[usize] {
        &self.image_level_of
    }

    /// The counters of the chunk caches of every image level read, summed (`peak_bytes`: the
    /// sum of each cache's peak, an upper bound of the peak of their sum).
    pub fn cache_stats(&self) -> ChunkCacheStats {
        let mut sum = ChunkCacheStats::default();
        for s in self.samplers.iter().map(Coarser::cache_stats) {
            sum.budget_bytes += s.budget_bytes;
            sum.resident_bytes += s.resident_bytes;
            sum.peak_bytes += s.peak_bytes;
            sum.resident_chunks += s.resident_chunks;
            sum.hits += s.hits;
            sum.fetches += s.fetches;
            sum.absent_chunks += s.absent_chunks;
            sum.evictions += s.evictions;
            sum.failed_chunks += s.failed_chunks;
        }
        sum
    }

    /// Bytes fetched so far, over every image level read.
    pub fn bytes_fetched(&self) -> u64 {
        self.samplers
            .iter()
            .map(|s| s.chunks().bytes_fetched())
            .sum()
    }

    /// The level-0 index coordinates of the texels of the stored brick of `level` that holds
    /// `brick`, x fastest (module docs).
    pub fn sample_points(&self, level: u32, brick: UVec3) -> Vec<[f64; 3]> {
        let n = self.grid.brick_size();
        let first = block_origin(brick, level);
        let start = stored_first_sample(first, n, level);
        let edge = stored_brick_edge(n, level) as i32;
        let placement = if level == 0 {
            SamplePlacement::CellCentred
        } else {
            SamplePlacement::Vertex
        };
        let last =
            LevelGrid::covering_dims(level, placement, self.grid.dims()).as_ivec3() - IVec3::ONE;
        let step = f64::from(1u32 << level.min(30));
        let offset = if level == 0 { 0.0 } else { -0.5 };
        let mut points = Vec::with_capacity(edge.pow(3) as usize);
        for z in 0..edge {
            for y in 0..edge {
                for x in 0..edge {
                    let j = (start + IVec3::new(x, y, z)).clamp(IVec3::ZERO, last);
                    points.push([0, 1, 2].map(|a| step * f64::from(j[a]) + offset));
                }
            }
        }
        points
    }
}

impl LevelBackend for ZarrLevels {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn grid(&self) -> BrickGrid {
        self.grid
    }

    fn level_count(&self) -> u32 {
        self.levels
    }

    fn scalar(&self) -> ScalarType {
        self.scalar
    }

    fn spacing(&self) -> Vec3 {
        self.spacing
    }

    fn value_range(&self) -> ValueRange {
        self.range
    }

    fn stored_range(&self, _level: u32, _brick: UVec3) -> Option<ValueRange> {
        None
    }

    fn stored_bytes(&self, level: u32) -> usize {
        (stored_brick_edge(self.grid.brick_size(), level) as usize).pow(3)
            * self.scalar.size_bytes()
    }

    fn read_stored_bytes(&self, level: u32, brick: UVec3) -> Result<Vec<u8>, StoreError> {
        let sampler = self.sampler_of.get(level as usize);
        let Some(&sampler) = sampler.filter(|_| brick.cmplt(self.grid.bricks_per_axis()).all())
        else {
            return Err(StoreError::LevelOutOfRange {
                level,
                brick: brick.to_array(),
                levels: self.levels,
                bricks: self.grid.bricks_per_axis().to_array(),
            });
        };
        let values = self.samplers[sampler]
            .sample(&self.sample_points(level, brick))
            .map_err(|e| StoreError::Backend {
                backend: self.name(),
                source: Box::new(e),
            })?;
        Ok(quantize_to(&values, self.scalar))
    }
}
