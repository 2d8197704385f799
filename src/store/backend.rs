//! [`BrickBackend`]: where a [`BrickStreamer`](super::BrickStreamer) reads brick levels from.
//!
//! The streamer's policy (wanted set, priorities, RAM budget, pins, failures) does not depend on
//! where the bytes come from: a [`BrickStore`] file (one positioned read per level) or an
//! OME-Zarr image packed from its chunks while streaming
//! (`stream::ZarrBricks`). Both implement this trait.

use super::{BrickStore, StoreError};
use crate::bricks::{BrickGrid, DownsampleFilter, Level, ValueRange};
use crate::volume::ScalarType;
use glam::Vec3;
use std::sync::Arc;

/// A supplier of packed brick levels that may block (disk, network): the streamer calls
/// [`BrickBackend::read_brick_into`] on its loader thread only.
pub trait BrickBackend: Send + Sync + 'static {
    /// The error of a failed read (kept as the source of
    /// [`SourceError::Load`](crate::bricks::SourceError::Load)).
    type Error: std::error::Error + Send + Sync + 'static;

    /// What is read, for messages (a file, a URL).
    fn name(&self) -> String;

    /// The brick grid.
    fn grid(&self) -> BrickGrid;

    /// Storage scalar type of the brick texels.
    fn scalar(&self) -> ScalarType;

    /// Filter that builds the low-res bricks.
    fn filter(&self) -> DownsampleFilter;

    /// Physical voxel spacing.
    fn spacing(&self) -> Vec3;

    /// Per-brick conservative value ranges (indexed by linear brick index).
    fn value_ranges(&self) -> &[ValueRange];

    /// Smallest and largest voxel value of the whole volume (conservative).
    fn value_range(&self) -> ValueRange;

    /// The per-brick ranges learned so far (see
    /// [`BrickSource::learned_value_ranges`](crate::bricks::BrickSource::learned_value_ranges));
    /// `None` (the default): [`BrickBackend::value_ranges`] are final. Called by the renderer's
    /// thread once per frame: must not block on I/O.
    fn learned_value_ranges(&self) -> Option<Arc<[ValueRange]>> {
        None
    }

    /// Bytes of one brick at `level` (0 for `Absent`).
    fn level_bytes(&self, level: Level) -> usize;

    /// Reads `brick` at `level` into `out` (exactly [`BrickBackend::level_bytes`] long): packed
    /// native-endian texels as [`crate::bricks::quantize_to`] returns them. May block.
    fn read_brick_into(&self, brick: u32, level: Level, out: &mut [u8]) -> Result<(), Self::Error>;
}

impl BrickBackend for BrickStore {
    type Error = StoreError;

    fn name(&self) -> String {
        self.path().display().to_string()
    }

    fn grid(&self) -> BrickGrid {
        BrickStore::grid(self)
    }

    fn scalar(&self) -> ScalarType {
        BrickStore::scalar(self)
    }

    fn filter(&self) -> DownsampleFilter {
        BrickStore::filter(self)
    }

    fn spacing(&self) -> Vec3 {
        BrickStore::spacing(self)
    }

    fn value_ranges(&self) -> &[ValueRange] {
        BrickStore::value_ranges(self)
    }

    fn value_range(&self) -> ValueRange {
        BrickStore::value_range(self)
    }

    fn level_bytes(&self, level: Level) -> usize {
        BrickStore::level_bytes(self, level)
    }

    fn read_brick_into(&self, brick: u32, level: Level, out: &mut [u8]) -> Result<(), StoreError> {
        BrickStore::read_brick_into(self, brick, level, out)
    }
}
