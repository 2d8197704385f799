//! [`Coarser`]: the image's next coarser pyramid level, opened when a low-res brick first needs
//! it (a level-0 chunk it reads failed), and resampled trilinearly at level-0 positions.
//!
//! **Positions.** Each level maps its voxel indices to physical coordinates by its OME-Zarr
//! `scale` and `translation` ([`ZarrChunks::spacing`], [`VolumeMeta::origin`]): voxel centre
//! `i` of level 0 is at `t0 + s0 * i`, of the coarser level at `t1 + s1 * u`. A level-0 index
//! coordinate `i` (fractional) is therefore the coarser index coordinate
//! `u = (t0 - t1 + s0 * i) / s1`, per axis. The value there is the trilinear interpolation of
//! the coarser voxels, with `u` clamped to `[0, dims - 1]` (clamp-to-edge), of the values
//! normalised as [`VoxelData::normalized`].
//!
//! [`VolumeMeta::origin`]: crate::volume::formats::VolumeMeta

use super::chunk_cache::{ChunkCache, ChunkCacheStats};
use super::{chunks_meeting, copy_into, StreamError};
use crate::volume::formats::ZarrChunks;
use crate::volume::{VolumeError, VoxelData};
use glam::UVec3;

/// The next coarser level of the image a [`super::ZarrBricks`] streams.
pub(super) struct Coarser {
    chunks: ZarrChunks,
    cache: ChunkCache,
    /// Per axis (x, y, z): coarser index coordinate = `scale * level-0 index + offset`.
    scale: [f64; 3],
    offset: [f64; 3],
}

impl Coarser {
    /// Opens the level after `fine`'s (`None` when the image has none), its chunks cached under
    /// `cache_bytes` and fetched `concurrency` at a time.
    pub(super) fn open(
        fine: &ZarrChunks,
        cache_bytes: usize,
        concurrency: usize,
    ) -> Result<Option<Self>, VolumeError> {
        let level = fine.level() + 1;
        if level >= fine.level_count() {
            return Ok(None);
        }
        Self::open_level(fine, level, cache_bytes, concurrency).map(Some)
    }

    /// Opens level `level` of `fine`'s image (any level, `fine`'s own too: opened again),
    /// sampled at `fine`'s
    /// index coordinates, its chunks cached under `cache_bytes` and fetched `concurrency` at a
    /// time.
    pub(super) fn open_level(
        fine: &ZarrChunks,
        level: usize,
        cache_bytes: usize,
        concurrency: usize,
    ) -> Result<Self, VolumeError> {
        let chunks = fine.open_level(level)?;
        let (s0, s1) = (fine.spacing(), chunks.spacing());
        let (t0, t1) = (fine.meta().origin, chunks.meta().origin);
        let scale = [0, 1, 2].map(|a| f64::from(s0[a]) / f64::from(s1[a]));
        let offset = [0, 1, 2].map(|a| (t0[a] - t1[a]) / f64::from(s1[a]));
        if scale.iter().chain(&offset).any(|v| !v.is_finite()) {
            return Err(VolumeError::InvalidParameter(format!(
                "{}: levels {} and {level} have no finite mapping between their coordinates",
                fine.root().display(),
                fine.level()
            )));
        }
        Ok(Self {
            cache: ChunkCache::new(cache_bytes, concurrency),
            chunks,
            scale,
            offset,
        })
    }

    /// The level read.
    pub(super) fn chunks(&self) -> &ZarrChunks {
        &self.chunks
    }

    /// The counters of its chunk cache.
    pub(super) fn cache_stats(&self) -> ChunkCacheStats {
        self.cache.stats()
    }

    /// Forgets its failed chunks.
    pub(super) fn clear_failures(&self) {
        self.cache.clear_failures();
    }

    /// The coarser index coordinates (clamped to the level) of the level-0 index coordinates
    /// `point` (x, y, z).
    fn map(&self, point: [f64; 3]) -> [f64; 3] {
        let dims = self.chunks.dims();
        [0, 1, 2].map(|a| {
            let u = self.scale[a] * point[a] + self.offset[a];
            u.clamp(0.0, f64::from(dims[a].max(1) - 1))
        })
    }

    /// The normalised values at the level-0 index coordinates `points` (x, y, z), trilinear in
    /// this level (see the [module docs](self)). Errors: the first chunk of this level that
    /// failed, a [`StreamError::Chunk`] naming it.
    pub(super) fn sample(&self, points: &[[f64; 3]]) -> Result<Vec<f32>, StreamError> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let dims = self.chunks.dims();
        if dims.cmpeq(UVec3::ZERO).any() {
            return Err(StreamError::InvalidConfig {
                field: "level",
                message: format!(
                    "level {} of {} is empty",
                    self.chunks.level(),
                    self.chunks.root().display()
                ),
            });
        }
        let mapped: Vec<[f64; 3]> = points.iter().map(|&p| self.map(p)).collect();
        // The voxels the interpolation reads: floor(u) and the next one, inside the level.
        let mut lo = UVec3::MAX;
        let mut hi = UVec3::ZERO;
        for u in &mapped {
            for a in 0..3 {
                let i = u[a].floor() as u32;
                lo[a] = lo[a].min(i);
                hi[a] = hi[a].max((i + 1).min(dims[a] - 1));
            }
        }
        let extent = hi - lo + UVec3::ONE;
        let wanted = chunks_meeting(self.chunks.chunk_shape(), lo, extent);
        let chunks = self.cache.get_many(&self.chunks, &wanted)?;
        let mut window = VoxelData::zeroed(self.chunks.scalar(), extent.element_product() as usize);
        for chunk in &chunks {
            copy_into(&mut window, lo, extent, chunk);
        }
        drop(chunks);
        let at = |x: u32, y: u32, z: u32| {
            let (x, y, z) = (x - lo.x, y - lo.y, z - lo.z);
            f64::from(window.normalized(
                x as usize + extent.x as usize * (y as usize + extent.y as usize * z as usize),
            ))
        };
        Ok(mapped
            .iter()
            .map(|u| {
                let i0 = [0, 1, 2].map(|a| u[a].floor() as u32);
                let i1 = [0, 1, 2].map(|a| (i0[a] + 1).min(dims[a] - 1));
                let t = [0, 1, 2].map(|a| u[a] - f64::from(i0[a]));
                let mut sum = 0.0;
                for corner in 0..8 {
                    let pick = |a: usize| (corner >> a) & 1 == 1;
                    let c = [0, 1, 2].map(|a| if pick(a) { i1[a] } else { i0[a] });
                    let w: f64 = (0..3)
                        .map(|a| if pick(a) { t[a] } else { 1.0 - t[a] })
                        .product();
                    if w != 0.0 {
                        sum += w * at(c[0], c[1], c[2]);
                    }
                }
                sum as f32
            })
            .collect())
    }
}
