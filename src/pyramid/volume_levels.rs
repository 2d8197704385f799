//! A volume's levels as the three-level cache reads them ([`VolumeLevels`]): level 0 straight
//! from the volume's voxels whenever a stored brick of it is packed, every coarser level as a
//! grid built once (level 1 read from the voxels, [`LevelGrid::level_one`]). Besides the volume
//! this holds level 1 and coarser as f32, about 0.57 bytes per voxel, where the whole vertex
//! pyramid ([`LevelGrid::vertex_pyramid`]) holds 4.57.

use super::grid::{box_values, normalized_voxel, LevelGrid, SamplePlacement};
use crate::bricks::DownsampleFilter;
use crate::volume::Volume;
use glam::UVec3;
use std::sync::Arc;

/// The levels `0..levels` of a volume: the same samples as [`LevelGrid::vertex_pyramid`],
/// level 0 read from the volume's voxels whenever a stored brick of it is packed, level 1 and
/// coarser held as grids (about 0.57 bytes per voxel besides the volume, not 4.57).
#[derive(Clone, Debug)]
pub struct VolumeLevels {
    volume: Arc<Volume>,
    /// Levels 1, 2, ... (index `level - 1`).
    coarser: Vec<LevelGrid>,
}

impl VolumeLevels {
    /// The levels `0..levels` of `volume` (at least level 0), level 1 built by `filter`.
    pub fn new(volume: Arc<Volume>, levels: u32, filter: DownsampleFilter) -> Self {
        let mut coarser: Vec<LevelGrid> = Vec::new();
        for level in 1..levels {
            let next = match coarser.last() {
                None => LevelGrid::level_one(&volume, filter),
                Some(finer) => finer.downsampled(SamplePlacement::Vertex, volume.dims(), filter),
            };
            debug_assert_eq!(next.level(), level);
            coarser.push(next);
        }
        Self { volume, coarser }
    }

    /// Levels held (0 up to this, exclusive).
    pub fn level_count(&self) -> u32 {
        1 + self.coarser.len() as u32
    }

    /// The texels of the stored brick of `level` whose block starts at brick `first`, for
    /// bricks of `brick_size`: what [`LevelGrid::stored_brick`] of the pyramid's level gives
    /// (level 0 cut from the volume's voxels, clamped). `None` for a level not held.
    pub fn stored_brick(&self, level: u32, first: UVec3, brick_size: u32) -> Option<Vec<f32>> {
        match level {
            0 => Some(Self::level_zero_brick(&self.volume, first, brick_size)),
            _ => self
                .coarser
                .get(level as usize - 1)
                .map(|grid| grid.stored_brick(first, brick_size)),
        }
    }

    /// The texels of level 0's stored brick of brick `first` of `volume` in bricks of
    /// `brick_size`, cut from its voxels (normalised, clamped): what
    /// `LevelGrid::from_volume(volume).stored_brick(first, brick_size)` gives.
    pub fn level_zero_brick(volume: &Volume, first: UVec3, brick_size: u32) -> Vec<f32> {
        let start = crate::cache::stored_first_sample(first, brick_size, 0);
        let edge = crate::cache::stored_brick_edge(brick_size, 0) as i32;
        box_values(start, edge, |v| normalized_voxel(volume, v))
    }

    /// Bytes the levels hold besides the volume (the coarser grids' f32 samples).
    pub fn held_bytes(&self) -> u64 {
        self.coarser
            .iter()
            .map(|g| g.values().len() as u64 * 4)
            .sum()
    }
}
