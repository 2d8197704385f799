//! [`LevelBackend`]: where a [`super::LevelStreamer`] reads the stored bricks of every level
//! from: a level store file ([`LevelStore`], one positioned read each) or an OME-Zarr pyramid
//! resampled from its chunks while streaming (`stream::ZarrLevels`).

use super::reader::assemble_grids;
use super::LevelStore;
use crate::bricks::{dequantize, BrickGrid, ValueRange};
use crate::pyramid::LevelGrid;
use crate::store::StoreError;
use crate::volume::ScalarType;
use glam::{UVec3, Vec3};

/// A supplier of the stored bricks of a volume's every level, as the three-level cache
/// uploads them (`crate::cache::slot_geometry`: level 0 `(n+4)^3` with two border voxels, levels
/// 1-2 `(n/2^k+1)^3` vertex samples, one `(n/4+1)^3` brick per block past level 2). Reads may
/// block (disk, network): the streamer calls [`LevelBackend::read_stored_bytes`] on its loader
/// thread, the render thread only for what is not in RAM.
pub trait LevelBackend: Send + Sync + 'static {
    /// What is read, for messages (a file, a URL).
    fn name(&self) -> String;

    /// The brick grid (level 0).
    fn grid(&self) -> BrickGrid;

    /// Levels there are (0 up to this, exclusive).
    fn level_count(&self) -> u32;

    /// The texels' scalar type (u8 / u16 UNORM or f32, normalised as the volume's).
    fn scalar(&self) -> ScalarType;

    /// Physical voxel spacing of level 0.
    fn spacing(&self) -> Vec3;

    /// Smallest and largest normalised value of the whole volume (conservative).
    fn value_range(&self) -> ValueRange;

    /// The range of the texels of the stored brick of `level` that holds `brick`, when known
    /// without reading it (`None`: not known, the whole [`LevelBackend::value_range`] is
    /// assumed and nothing is culled).
    fn stored_range(&self, level: u32, brick: UVec3) -> Option<ValueRange>;

    /// Bytes of one stored brick of `level`.
    fn stored_bytes(&self, level: u32) -> usize;

    /// The stored brick of `level` that holds brick `brick` (any brick of its block): texels
    /// of [`LevelBackend::scalar`], native-endian, x fastest. May block.
    fn read_stored_bytes(&self, level: u32, brick: UVec3) -> Result<Vec<u8>, StoreError>;

    /// Every level's samples put back together from the stored bricks (normalised; level 0
    /// cell-centred, the others on vertices): for the CPU reference and checks. Reads every
    /// stored brick.
    fn read_grids(&self) -> Result<Vec<LevelGrid>, StoreError> {
        let scalar = self.scalar();
        assemble_grids(
            &self.grid(),
            self.level_count(),
            |level, first| Ok(dequantize(&self.read_stored_bytes(level, first)?, scalar)),
            |message| StoreError::Backend {
                backend: self.name(),
                source: message.into(),
            },
        )
    }
}

impl LevelBackend for LevelStore {
    fn name(&self) -> String {
        self.path().display().to_string()
    }

    fn grid(&self) -> BrickGrid {
        LevelStore::grid(self)
    }

    fn level_count(&self) -> u32 {
        LevelStore::level_count(self)
    }

    fn scalar(&self) -> ScalarType {
        self.header().scalar
    }

    fn spacing(&self) -> Vec3 {
        self.header().spacing
    }

    fn value_range(&self) -> ValueRange {
        self.header().value_range
    }

    fn stored_range(&self, level: u32, brick: UVec3) -> Option<ValueRange> {
        LevelStore::stored_range(self, level, brick).ok()
    }

    fn stored_bytes(&self, level: u32) -> usize {
        self.header().stored_bytes(level) as usize
    }

    fn read_stored_bytes(&self, level: u32, brick: UVec3) -> Result<Vec<u8>, StoreError> {
        LevelStore::read_stored_bytes(self, level, brick)
    }

    fn read_grids(&self) -> Result<Vec<LevelGrid>, StoreError> {
        LevelStore::read_grids(self)
    }
}
