//! One level's samples on the global grid ([`LevelGrid`]) and how each coarser level is built
//! from the one before ([`LevelGrid::downsampled`], [`LevelGrid::vertex_pyramid`]).
//!
//! Level `k` samples the volume every `s_k = 2^k` hi-res voxels on one global grid, either
//! *cell-centred* (sample `j` at `s_k * (j + 1/2)`, as the hi-res voxels) or on *vertices*
//! (sample `j` at `s_k * j`, as the low-res samples of the two-level cache). The cache keeps
//! level 0 cell-centred and every coarser level on vertices (`docs/cache-layout.md`).

use crate::bricks::DownsampleFilter;
use glam::{IVec3, UVec3};

/// Where a level's samples sit in its cells.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SamplePlacement {
    /// Sample `j` at `s * (j + 1/2)`: cell centres, as hi-res voxels.
    CellCentred,
    /// Sample `j` at `s * j`: cell corners, on brick faces, as today's low-res samples.
    Vertex,
}

/// Why a [`LevelGrid`] or a [`LevelPlan`](super::LevelPlan) cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PyramidError {
    /// The sample values do not match the grid's extent.
    #[error("level {level}: {values} sample values for a {dims:?} grid (expected {expected})")]
    SampleCount {
        /// The level.
        level: u32,
        /// Samples per axis.
        dims: [u32; 3],
        /// Values given.
        values: usize,
        /// Values expected (`dims.x * dims.y * dims.z`).
        expected: usize,
    },
    /// A grid with no samples on some axis, or a level too deep for `2^level` to be a spacing.
    #[error("level {level}: invalid grid {dims:?} (every axis needs a sample, level below 31)")]
    InvalidGrid {
        /// The level.
        level: u32,
        /// Samples per axis.
        dims: [u32; 3],
    },
    /// The grids are not levels `0, 1, 2, ...` in order.
    #[error("grid {index} is level {level}; the grids must be levels 0, 1, 2, ... in order")]
    LevelOrder {
        /// Position in the list.
        index: usize,
        /// Its level.
        level: u32,
    },
    /// No level grid at all.
    #[error("no level grids")]
    NoLevels,
    /// The bricks are too small for this many levels: up to three levels a brick must hold a
    /// whole cell of the coarsest (`2^(levels - 1) <= n`); past three, the block levels need
    /// bricks of at least 8 voxels (their blocks' faces then lie on the next level's samples).
    #[error("{levels} levels need bricks of at least {min_brick_size} voxels; the bricks have {brick_size}")]
    TooManyLevels {
        /// Levels given.
        levels: usize,
        /// The smallest brick size that takes them.
        min_brick_size: u32,
        /// Brick size.
        brick_size: u32,
    },
    /// A brick of a block level is not part of a whole block at its level.
    #[error(
        "brick {brick} is level {level}, whose bricks come in aligned blocks of {block}^3; its \
         block has a brick at another level or not drawn"
    )]
    BrokenBlock {
        /// Linear brick index.
        brick: usize,
        /// Its level.
        level: u32,
        /// Bricks per axis of a block of that level.
        block: u32,
    },
    /// The per-brick levels do not have one entry per brick.
    #[error("{given} brick levels for a grid of {bricks} bricks")]
    BrickLevelCount {
        /// Entries given.
        given: usize,
        /// Bricks in the grid.
        bricks: usize,
    },
    /// A brick names a level with no grid.
    #[error("brick {brick} is level {level}, but only levels 0..{levels} have grids")]
    UnknownLevel {
        /// Linear brick index.
        brick: usize,
        /// Its level.
        level: u32,
        /// Grids given.
        levels: usize,
    },
    /// Two adjacent drawn bricks differ by more than one level.
    #[error("adjacent bricks differ by more than one level (face, edge or corner neighbours)")]
    LevelRule,
}

/// One level's samples on the global grid (values normalised, x fastest).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelGrid {
    level: u32,
    placement: SamplePlacement,
    dims: UVec3,
    values: Vec<f32>,
}

impl LevelGrid {
    /// Level `level`'s samples: `dims` per axis at the positions `placement` gives for spacing
    /// `2^level` (module docs), x fastest.
    pub fn new(
        level: u32,
        placement: SamplePlacement,
        dims: UVec3,
        values: Vec<f32>,
    ) -> Result<Self, PyramidError> {
        if dims.min_element() == 0 || level >= 31 {
            return Err(PyramidError::InvalidGrid {
                level,
                dims: dims.to_array(),
            });
        }
        let expected = dims.x as usize * dims.y as usize * dims.z as usize;
        if values.len() != expected {
            return Err(PyramidError::SampleCount {
                level,
                dims: dims.to_array(),
                values: values.len(),
                expected,
            });
        }
        Ok(Self {
            level,
            placement,
            dims,
            values,
        })
    }

    /// Samples per axis that cover a volume of `volume_dims` hi-res voxels at `level` with
    /// `placement`: `ceil(d / s)` cell-centred, `ceil(d / s) + 1` on vertices (as
    /// [`crate::bricks::low_res_dims`] for level 1).
    pub fn covering_dims(level: u32, placement: SamplePlacement, volume_dims: UVec3) -> UVec3 {
        let s = 1u32 << level.min(30);
        let cells = (volume_dims + UVec3::splat(s - 1)) / s;
        match placement {
            SamplePlacement::CellCentred => cells.max(UVec3::ONE),
            SamplePlacement::Vertex => cells + UVec3::ONE,
        }
    }

    /// Level 0 of `volume`: its normalised voxel values, cell-centred.
    pub fn from_volume(volume: &crate::volume::Volume) -> Self {
        let dims = volume.dims();
        let count = dims.x as usize * dims.y as usize * dims.z as usize;
        let values = (0..count).map(|i| volume.data().normalized(i)).collect();
        Self {
            level: 0,
            placement: SamplePlacement::CellCentred,
            dims,
            values,
        }
    }

    /// The levels `0..levels` of `volume` as the cache builds them (module docs): level 0 its
    /// voxels, each coarser level on vertices, downsampled from the one before
    /// ([`LevelGrid::downsampled`]; level 1 by `filter`, the two-level cache's low-res level of
    /// that filter). `levels` is at least 1.
    pub fn vertex_pyramid(
        volume: &crate::volume::Volume,
        levels: u32,
        filter: DownsampleFilter,
    ) -> Vec<Self> {
        let mut grids = vec![Self::from_volume(volume)];
        for _ in 1..levels.max(1) {
            let next =
                grids[grids.len() - 1].downsampled(SamplePlacement::Vertex, volume.dims(), filter);
            grids.push(next);
        }
        grids
    }

    /// The level number.
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Where the samples sit.
    pub fn placement(&self) -> SamplePlacement {
        self.placement
    }

    /// Samples per axis.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// The sample values, x fastest.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Sample spacing `2^level` in hi-res voxels.
    pub fn spacing(&self) -> f32 {
        (1u32 << self.level) as f32
    }

    /// Sample `k`, clamped to the grid (clamp-to-edge).
    pub fn value(&self, k: IVec3) -> f32 {
        let c = k
            .clamp(IVec3::ZERO, self.dims.as_ivec3() - IVec3::ONE)
            .as_uvec3();
        self.values[(c.x + self.dims.x * (c.y + self.dims.y * c.z)) as usize]
    }

    /// The texels of the stored brick of this level whose block starts at brick `first`, for
    /// bricks of `brick_size` (`crate::cache::stored_brick_edge` per axis, x fastest, from sample
    /// `crate::cache::stored_first_sample`, clamped to the grid): what the three-level cache and
    /// the level store hold for it.
    pub fn stored_brick(&self, first: UVec3, brick_size: u32) -> Vec<f32> {
        let start = crate::cache::stored_first_sample(first, brick_size, self.level);
        let edge = crate::cache::stored_brick_edge(brick_size, self.level) as i32;
        box_values(start, edge, |k| self.value(k))
    }

    /// The next coarser level (`level + 1`) with `placement`, covering a volume of `volume_dims`
    /// hi-res voxels: per axis, a new sample that coincides with one of this level's samples is
    /// the tent `1/4, 1/2, 1/4` over it and its two neighbours, one that lies halfway between two
    /// of them their mean (the paper's average of the eight finer samples around a cell centre),
    /// separably, clamp-to-edge. Both reproduce a linear function exactly. Level 1 on vertices
    /// from level 0 is the exception: `filter`'s taps ([`level_one_taps`]; `Mean2` is the mean
    /// above), which every other step ignores.
    pub fn downsampled(
        &self,
        placement: SamplePlacement,
        volume_dims: UVec3,
        filter: DownsampleFilter,
    ) -> Self {
        let s = self.spacing();
        let level_one = self.level == 0
            && self.placement == SamplePlacement::CellCentred
            && placement == SamplePlacement::Vertex;
        // Per axis and new index: (this level's index, weight) taps.
        let taps = |j: i32| {
            if level_one {
                level_one_taps(filter, j)
            } else {
                downsample_taps(s, self.placement, placement, j)
            }
        };
        Self::summed(self.level + 1, placement, volume_dims, taps, |k| {
            self.value(k)
        })
    }

    /// Level 1 of `volume` on vertices by `filter`, read straight from its voxels: what
    /// `LevelGrid::from_volume(volume).downsampled(SamplePlacement::Vertex, volume.dims(),
    /// filter)` gives, bit for bit, without holding level 0 as f32.
    pub fn level_one(volume: &crate::volume::Volume, filter: DownsampleFilter) -> Self {
        let dims = volume.dims();
        Self::summed(
            1,
            SamplePlacement::Vertex,
            dims,
            |j| level_one_taps(filter, j),
            |k| normalized_voxel(volume, k),
        )
    }

    /// Level `level` with `placement` over a volume of `volume_dims` voxels: every sample the
    /// [`downsample_sum`] of its `taps` per axis over the samples `value` gives (clamped by
    /// `value`), z outermost, x fastest.
    fn summed(
        level: u32,
        placement: SamplePlacement,
        volume_dims: UVec3,
        taps: impl Fn(i32) -> Vec<(i32, f32)>,
        value: impl Fn(IVec3) -> f32,
    ) -> Self {
        let dims = Self::covering_dims(level, placement, volume_dims);
        let taps_x: Vec<Vec<(i32, f32)>> = (0..dims.x as i32).map(&taps).collect();
        let mut values = Vec::with_capacity(dims.x as usize * dims.y as usize * dims.z as usize);
        for z in 0..dims.z as i32 {
            let tz = taps(z);
            for y in 0..dims.y as i32 {
                let ty = taps(y);
                for tx in &taps_x {
                    values.push(downsample_sum(&tz, &ty, tx, &value));
                }
            }
        }
        Self {
            level,
            placement,
            dims,
            values,
        }
    }
}

/// Voxel `v` of `volume`, clamped to it (clamp-to-edge), normalised: what level 0's grid holds
/// there ([`LevelGrid::from_volume`], [`LevelGrid::value`]).
pub(super) fn normalized_voxel(volume: &crate::volume::Volume, v: IVec3) -> f32 {
    let dims = volume.dims();
    let c = v
        .clamp(IVec3::ZERO, dims.as_ivec3() - IVec3::ONE)
        .as_uvec3();
    volume
        .data()
        .normalized((c.x + dims.x * (c.y + dims.y * c.z)) as usize)
}

/// The `edge^3` samples `value` gives from `start`, x fastest: a stored brick's texels, cut from
/// a level grid ([`LevelGrid::stored_brick`]) or from a window of planes (the slab writer).
pub fn box_values(start: IVec3, edge: i32, value: impl Fn(IVec3) -> f32) -> Vec<f32> {
    let mut values = Vec::with_capacity(edge.max(0).pow(3) as usize);
    for z in 0..edge {
        for y in 0..edge {
            for x in 0..edge {
                values.push(value(start + IVec3::new(x, y, z)));
            }
        }
    }
    values
}

/// The taps `(index, weight)` along one axis of the sample `j` of the next coarser level (placed
/// `to`) over a level of sample `spacing` placed `from` ([`LevelGrid::downsampled`]): the tent
/// `1/4, 1/2, 1/4` where the new sample coincides with an old one, else the mean of the two
/// around it. Indices may fall outside the level (clamp-to-edge is the reader's).
pub fn downsample_taps(
    spacing: f32,
    from: SamplePlacement,
    to: SamplePlacement,
    j: i32,
) -> Vec<(i32, f32)> {
    let p = match to {
        SamplePlacement::CellCentred => 2.0 * spacing * (j as f32 + 0.5),
        SamplePlacement::Vertex => 2.0 * spacing * j as f32,
    };
    let u = match from {
        SamplePlacement::CellCentred => p / spacing - 0.5,
        SamplePlacement::Vertex => p / spacing,
    };
    if u.fract() == 0.0 {
        let c = u as i32;
        vec![(c - 1, 0.25), (c, 0.5), (c + 1, 0.25)]
    } else {
        let c = u.floor() as i32;
        vec![(c, 0.5), (c + 1, 0.5)]
    }
}

/// The taps `(voxel index, weight)` along one axis of the level-1 (vertex) sample `j` over
/// level 0's voxels for the level-0-to-1 `filter`: its taps around voxel `2j`
/// ([`DownsampleFilter::taps`]), exactly the voxels the two-level cache's low-res sample `j`
/// of that filter reads. `Mean2` gives what [`downsample_taps`] gives for that step. Indices
/// may fall outside the volume (clamp-to-edge is the reader's).
pub fn level_one_taps(filter: DownsampleFilter, j: i32) -> Vec<(i32, f32)> {
    filter
        .taps()
        .iter()
        .map(|&(offset, weight)| (2 * j + offset as i32, weight))
        .collect()
}

/// One sample of the next coarser level from its taps per axis (`downsample_taps`) over the
/// samples `value` gives (clamped by the caller): the weighted sum in f64, z taps outermost, x
/// innermost, rounded once to f32. Every builder of coarser levels forms it through here, so
/// they agree bit for bit.
pub fn downsample_sum(
    tz: &[(i32, f32)],
    ty: &[(i32, f32)],
    tx: &[(i32, f32)],
    value: impl Fn(IVec3) -> f32,
) -> f32 {
    let mut sum = 0.0f64;
    for &(kz, wz) in tz {
        for &(ky, wy) in ty {
            for &(kx, wx) in tx {
                sum += f64::from(wx * wy * wz) * f64::from(value(IVec3::new(kx, ky, kz)));
            }
        }
    }
    sum as f32
}
