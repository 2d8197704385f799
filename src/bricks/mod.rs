//! Flat bricking, per-brick value ranges, downsampling filters and packed brick storage.
//!
//! Coordinates follow `DESIGN.md` §1, in *hi-res voxel units* along each axis:
//!
//! - the volume spans `[0, dims]`; hi-res voxel `i` sits at position `i + 0.5`;
//! - brick `b` (size `n`) spans positions `[n*b, n*(b+1)]` and owns the voxels `n*b .. n*(b+1)`;
//!   bricks at the far edge may be partial (dims need not be multiples of `n`);
//! - low-res sample `k` sits at the even position `2k` (see [`filters`]).
//!
//! [`BrickGrid`] describes the subdivision, [`brick_value_ranges`] computes the per-brick min/max
//! used for culling, [`filters`] builds the low-res level and [`packing`] lays bricks out for upload:
//! these are the reference functions, simple and per brick. [`kernel`] does all of that for a box
//! of bricks at once, bit for bit as the reference does, and is what everything that bricks a
//! volume calls; [`build`] runs it over every brick of an in-memory volume in parallel
//! ([`build_bricks`]). [`source`] is where a renderer gets packed bricks from ([`BrickSource`]),
//! per [`Level`].

pub mod build;
pub mod filters;
pub mod kernel;
pub mod level;
pub mod packing;
pub mod source;
mod taps;

pub use build::{
    available_threads, build_bricks, build_bricks_with_threads, build_low_res_level,
    build_value_ranges, PackedBricks,
};
pub use kernel::{BrickBox, BrickKernel, PackOutputs, TexelsMut, VoxelWindow};
pub use level::Level;
pub use source::{
    fallback_levels, request_plan, BrickSource, LoadedLevels, RgbaBrickSource, SourceError,
    VolumeBrickSource,
};
pub use taps::DownsampleFilter;

pub use filters::{
    downsample_rgba_extinction, downsample_rgba_opacity, low_res_block, low_res_dims,
    low_res_level, low_res_value, max_low_res_index, LowResLevel, RgbaLevel,
};
pub use packing::{
    dequantize, hi_res_brick_extent, low_res_brick_extent, pack_hi_res_brick, pack_low_res_brick,
    quantize_to, subslot_offset, SUB_SLOTS_PER_SLOT,
};

use crate::volume::{ScalarType, Volume};
use glam::{IVec3, UVec3};

/// The default brick edge length in hi-res voxels (the paper's `n = 32`).
pub const DEFAULT_BRICK_SIZE: u32 = 32;

/// The largest accepted brick edge length; keeps `(n + 2)^3` texel counts far from overflow.
pub const MAX_BRICK_SIZE: u32 = 1024;

/// Errors from bricking, downsampling and packing.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BrickError {
    /// The brick size is not a power of two in `2..=MAX_BRICK_SIZE`.
    #[error("brick size {size} must be a power of two between 2 and {MAX_BRICK_SIZE}")]
    InvalidBrickSize {
        /// The size given.
        size: u32,
    },
    /// A volume dimension is zero.
    #[error("volume dims {dims:?} have a zero axis; every axis needs at least one voxel")]
    ZeroDimension {
        /// The dimensions given.
        dims: [u32; 3],
    },
    /// The volume does not have the dimensions the grid was built for.
    #[error("brick grid was built for dims {grid_dims:?} but the volume has dims {volume_dims:?}")]
    DimsMismatch {
        /// Dimensions of the grid.
        grid_dims: [u32; 3],
        /// Dimensions of the volume.
        volume_dims: [u32; 3],
    },
    /// A brick coordinate lies outside the grid.
    #[error("brick {brick:?} lies outside the grid of {bricks_per_axis:?} bricks")]
    BrickOutOfRange {
        /// The brick coordinate given.
        brick: [u32; 3],
        /// Bricks per axis of the grid.
        bricks_per_axis: [u32; 3],
    },
    /// An RGBA texel slice does not match its dimensions.
    #[error("RGBA data holds {actual} texels but dims {dims:?} need {expected}")]
    TexelCountMismatch {
        /// The dimensions given.
        dims: [u32; 3],
        /// Texels the dimensions imply.
        expected: usize,
        /// Texels supplied.
        actual: usize,
    },
    /// A voxel window does not fit the volume, its data or the bricks asked for.
    #[error("voxel window at {origin:?} of {extent:?} voxels {reason}")]
    InvalidWindow {
        /// The window's first voxel.
        origin: [u32; 3],
        /// The window's voxels per axis.
        extent: [u32; 3],
        /// What is wrong.
        reason: String,
    },
    /// An output buffer handed to the kernel has the wrong length or texel type.
    #[error("kernel output `{output}` {reason}")]
    OutputMismatch {
        /// The output at fault (`hi`, `lo`, `ranges`).
        output: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The packed bricks of a grid would not fit in the address space.
    #[error("{bricks} packed bricks of size {brick_size} do not fit in memory")]
    StoreTooLarge {
        /// Bricks in the grid.
        bricks: usize,
        /// Brick edge length `n`.
        brick_size: u32,
    },
}

/// Flat bricking of a volume into `n^3` bricks (Beyer et al. 2008, §3.1).
///
/// Brick coordinates run over `0..bricks_per_axis()`, with `bricks_per_axis = ceil(dims / n)`; the
/// linear brick index is x fastest, like voxels.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BrickGrid {
    dims: UVec3,
    brick_size: u32,
    bricks_per_axis: UVec3,
}

impl BrickGrid {
    /// Bricks a volume of `dims` voxels into bricks of `brick_size^3` voxels.
    ///
    /// `brick_size` must be a power of two in `2..=MAX_BRICK_SIZE`, and every axis of `dims`
    /// non-zero.
    pub fn new(dims: UVec3, brick_size: u32) -> Result<Self, BrickError> {
        if !brick_size.is_power_of_two() || !(2..=MAX_BRICK_SIZE).contains(&brick_size) {
            return Err(BrickError::InvalidBrickSize { size: brick_size });
        }
        if dims.min_element() == 0 {
            return Err(BrickError::ZeroDimension {
                dims: dims.to_array(),
            });
        }
        let bricks_per_axis = (dims + UVec3::splat(brick_size - 1)) / brick_size;
        Ok(Self {
            dims,
            brick_size,
            bricks_per_axis,
        })
    }

    /// Bricks a volume with [`DEFAULT_BRICK_SIZE`].
    pub fn with_default_size(dims: UVec3) -> Result<Self, BrickError> {
        Self::new(dims, DEFAULT_BRICK_SIZE)
    }

    /// Voxel counts of the bricked volume.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// Brick edge length `n` in hi-res voxels.
    pub fn brick_size(&self) -> u32 {
        self.brick_size
    }

    /// Bricks along x, y, z: `ceil(dims / n)`.
    pub fn bricks_per_axis(&self) -> UVec3 {
        self.bricks_per_axis
    }

    /// Total number of bricks.
    pub fn brick_count(&self) -> usize {
        let b = self.bricks_per_axis;
        b.x as usize * b.y as usize * b.z as usize
    }

    /// True when `brick` is a valid brick coordinate.
    pub fn contains(&self, brick: UVec3) -> bool {
        brick.cmplt(self.bricks_per_axis).all()
    }

    /// Linear index of `brick` (x fastest); the caller keeps `brick` inside the grid.
    pub fn linear_index(&self, brick: UVec3) -> usize {
        let b = self.bricks_per_axis;
        brick.x as usize + b.x as usize * (brick.y as usize + b.y as usize * brick.z as usize)
    }

    /// Brick coordinate of linear index `index`; the caller keeps `index < brick_count()`.
    pub fn brick_coords(&self, index: usize) -> UVec3 {
        let b = self.bricks_per_axis;
        let (bx, by) = (b.x as usize, b.y as usize);
        UVec3::new(
            (index % bx) as u32,
            ((index / bx) % by) as u32,
            (index / (bx * by)) as u32,
        )
    }

    /// All brick coordinates in linear-index order.
    pub fn bricks(&self) -> impl Iterator<Item = UVec3> + '_ {
        (0..self.brick_count()).map(|i| self.brick_coords(i))
    }

    /// First hi-res voxel of `brick` (`n * brick`), which is also its lower face position.
    pub fn brick_origin(&self, brick: UVec3) -> IVec3 {
        brick.as_ivec3() * self.brick_size as i32
    }

    /// The voxels `brick` owns, `[start, end)` per axis, clipped to the volume (partial bricks).
    pub fn owned_voxels(&self, brick: UVec3) -> (UVec3, UVec3) {
        let start = brick * self.brick_size;
        let end = ((brick + UVec3::ONE) * self.brick_size).min(self.dims);
        (start, end)
    }

    /// Returns an error unless `brick` lies inside the grid.
    pub fn check_brick(&self, brick: UVec3) -> Result<(), BrickError> {
        if self.contains(brick) {
            Ok(())
        } else {
            Err(BrickError::BrickOutOfRange {
                brick: brick.to_array(),
                bricks_per_axis: self.bricks_per_axis.to_array(),
            })
        }
    }

    /// Returns an error unless `volume` has the dimensions of this grid.
    pub fn check_volume(&self, volume: &Volume) -> Result<(), BrickError> {
        if volume.dims() == self.dims {
            Ok(())
        } else {
            Err(BrickError::DimsMismatch {
                grid_dims: self.dims.to_array(),
                volume_dims: volume.dims().to_array(),
            })
        }
    }
}

/// A closed range `[min, max]` of normalised values.
#[derive(Copy, Clone, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct ValueRange {
    /// Smallest value.
    pub min: f32,
    /// Largest value.
    pub max: f32,
}

impl ValueRange {
    /// The empty range (`min = +inf`, `max = -inf`), the identity of [`ValueRange::include`].
    pub const EMPTY: Self = Self {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
    };

    /// The smallest range holding every value of `values` ([`ValueRange::EMPTY`] for none).
    pub fn of(values: &[f32]) -> Self {
        let mut range = Self::EMPTY;
        for &v in values {
            range.include(v);
        }
        range
    }

    /// Grows the range to contain `value`.
    pub fn include(&mut self, value: f32) {
        self.min = self.min.min(value);
        self.max = self.max.max(value);
    }

    /// True when `value` lies in `[min, max]`.
    pub fn contains(&self, value: f32) -> bool {
        self.min <= value && value <= self.max
    }

    /// True when no value has been included.
    pub fn is_empty(&self) -> bool {
        self.min > self.max
    }
}

/// Per-brick ranges conservative for the volume's own scalar type as GPU storage.
///
/// Same as [`brick_value_ranges_for_storage`] with `storage = volume.scalar_type()`.
pub fn brick_value_ranges(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
) -> Result<Vec<ValueRange>, BrickError> {
    brick_value_ranges_for_storage(volume, grid, filter, volume.scalar_type())
}

/// Per-brick min/max (indexed by [`BrickGrid::linear_index`]), conservative for every value a
/// renderer can produce while sampling inside the brick.
///
/// The range of brick `b` (size `n`) covers, per axis:
///
/// 1. the hi-res voxels `[n*b - 1, n*(b+1) + 1)`, clamped to the volume: the brick's own voxels plus
///    the duplicated one-voxel border on each side, i.e. every texel of the packed `(n+2)^3` brick
///    (clamp-to-edge duplicates only add values already in the range);
/// 2. the low-res samples at positions `2k` in `[n*b - 2, n*(b+1) + 2]` (with `k` clamped to the
///    low-res grid, see [`filters::max_low_res_index`]) computed with `filter`: every texel of the
///    brick's own `(n/2+1)^3` low-res brick, which includes both faces, plus one more sample layer
///    on each side, which covers the samples on the faces shared with any neighbour.
///
/// Why this is conservative: a sample point in the brick lies in `[n*b, n*(b+1)]`. Hardware
/// trilinear filtering of the hi-res brick reads the voxels `floor(p - 0.5)` and `floor(p - 0.5) + 1`
/// per axis, all within set 1. Trilinear filtering of the low-res brick reads samples on the
/// positions `2k` bracketing `p`, all within set 2. The smooth-transition warp only moves the
/// coordinate of one trilinear fetch inside the cell between the hi-res layer and the border layer
/// (with `u'` clamped to `[0, 1]`), and the fixed-up border texels hold low-res samples on the shared
/// face (nearest to the border texel, so inside `[n*b, n*(b+1)]` tangentially), which set 2 contains
/// because both bricks build their faces from the same global low-res function. Every value is
/// therefore a convex combination (non-negative weights summing to one) of values in the two sets,
/// and a convex combination never leaves `[min, max]` of its inputs. A renderer that *extrapolates*
/// fixup values (non-convex weights) would need a wider range.
///
/// `storage` is the scalar type the cache stores: for `U8` / `U16` each low-res value (not
/// generally on the storage grid) contributes the storage levels just below and above it, so the
/// range holds whatever rounding the upload applies (quantisation is monotone, and on-grid endpoints
/// are fixed points). For `F32` storage the values are used as they are.
pub fn brick_value_ranges_for_storage(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
) -> Result<Vec<ValueRange>, BrickError> {
    grid.check_volume(volume)?;
    Ok(grid
        .bricks()
        .map(|brick| brick_value_range(volume, grid, filter, storage, brick))
        .collect())
}

/// The conservative range of one brick (see [`brick_value_ranges_for_storage`]).
fn brick_value_range(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    brick: UVec3,
) -> ValueRange {
    let mut range = hi_res_window_range(volume, grid, brick, storage);
    let n = grid.brick_size() as i32;
    let k_min = grid.brick_origin(brick) / 2 - IVec3::ONE;
    let size = UVec3::splat((n / 2 + 3) as u32);
    for value in low_res_block(volume, filter, k_min, size) {
        include_stored(&mut range, value, storage);
    }
    range
}

/// Range of the hi-res voxels `[n*b - 1, n*(b+1) + 1)` clamped to the volume.
fn hi_res_window_range(
    volume: &Volume,
    grid: &BrickGrid,
    brick: UVec3,
    storage: ScalarType,
) -> ValueRange {
    let n = grid.brick_size();
    let start = (brick * n).saturating_sub(UVec3::ONE);
    let end = ((brick + UVec3::ONE) * n + UVec3::ONE).min(volume.dims());
    let mut range = ValueRange::EMPTY;
    for z in start.z..end.z {
        for y in start.y..end.y {
            for x in start.x..end.x {
                include_stored(&mut range, volume.value(x, y, z), storage);
            }
        }
    }
    range
}

/// Includes `value` as `storage` can hold it: the bracketing storage levels for UNORM types.
fn include_stored(range: &mut ValueRange, value: f32, storage: ScalarType) {
    let levels = match storage {
        ScalarType::U8 => 255.0_f32,
        ScalarType::U16 => 65535.0,
        ScalarType::F32 => {
            range.include(value);
            return;
        }
    };
    let scaled = value.clamp(0.0, 1.0) * levels;
    range.include(scaled.floor() / levels);
    range.include(scaled.ceil() / levels);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::VoxelData;
    use glam::Vec3;

    /// Deterministic pseudo-random values in [0, 1) (xorshift).
    pub(crate) fn pseudo_random(count: usize, seed: u64) -> Vec<f32> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..count)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect()
    }

    fn random_volume(dims: UVec3, seed: u64) -> Volume {
        let count = (dims.x * dims.y * dims.z) as usize;
        Volume::new(dims, Vec3::ONE, VoxelData::F32(pseudo_random(count, seed))).unwrap()
    }

    /// Trilinear interpolation of `f` on integer grid points, clamped to `[0, max]`.
    fn trilinear(p: Vec3, max: IVec3, f: impl Fn(IVec3) -> f32) -> f32 {
        let base = p.floor();
        let t = p - base;
        let b = base.as_ivec3();
        let mut sum = 0.0;
        for corner in 0..8 {
            let o = IVec3::new(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            let w = |axis: usize| if o[axis] == 1 { t[axis] } else { 1.0 - t[axis] };
            let c = (b + o).clamp(IVec3::ZERO, max);
            sum += w(0) * w(1) * w(2) * f(c);
        }
        sum
    }

    #[test]
    fn rejects_invalid_brick_sizes() {
        for size in [0, 1, 3, 6, 31, 2048] {
            assert_eq!(
                BrickGrid::new(UVec3::splat(8), size),
                Err(BrickError::InvalidBrickSize { size })
            );
        }
        for size in [2, 4, 32, 1024] {
            assert!(BrickGrid::new(UVec3::splat(8), size).is_ok());
        }
        assert!(matches!(
            BrickGrid::new(UVec3::new(4, 0, 4), 4),
            Err(BrickError::ZeroDimension { .. })
        ));
    }

    #[test]
    fn brick_counts_round_up_and_index_x_fastest() {
        let grid = BrickGrid::new(UVec3::new(65, 64, 1), 32).unwrap();
        assert_eq!(grid.bricks_per_axis(), UVec3::new(3, 2, 1));
        assert_eq!(grid.brick_count(), 6);
        assert_eq!(grid.linear_index(UVec3::new(1, 0, 0)), 1);
        assert_eq!(grid.linear_index(UVec3::new(0, 1, 0)), 3);
        for i in 0..grid.brick_count() {
            assert_eq!(grid.linear_index(grid.brick_coords(i)), i);
        }
        assert_eq!(
            grid.owned_voxels(UVec3::new(2, 1, 0)),
            (UVec3::new(64, 32, 0), UVec3::new(65, 64, 1))
        );
        assert_eq!(
            BrickGrid::with_default_size(UVec3::ONE)
                .unwrap()
                .brick_size(),
            DEFAULT_BRICK_SIZE
        );
        assert!(grid.check_brick(UVec3::new(3, 0, 0)).is_err());
    }

    #[test]
    fn ranges_reject_mismatched_volume() {
        let grid = BrickGrid::new(UVec3::splat(8), 4).unwrap();
        let volume = random_volume(UVec3::splat(9), 1);
        assert!(matches!(
            brick_value_ranges(&volume, &grid, DownsampleFilter::Mean2),
            Err(BrickError::DimsMismatch { .. })
        ));
    }

    /// Samples the hi-res and low-res trilinear fields densely inside every brick (including its
    /// faces, where fixed-up borders read the neighbour's low-res samples) and checks the range.
    #[test]
    fn ranges_contain_every_sampled_value() {
        let dims = UVec3::new(19, 13, 10);
        let volume = random_volume(dims, 7);
        let grid = BrickGrid::new(dims, 4).unwrap();
        let vmax = dims.as_ivec3() - IVec3::ONE;
        let kmax = max_low_res_index(dims).as_ivec3();
        for filter in DownsampleFilter::ALL {
            let ranges = brick_value_ranges(&volume, &grid, filter).unwrap();
            let level = low_res_level(&volume, filter);
            for brick in grid.bricks() {
                let range = ranges[grid.linear_index(brick)];
                let lo = grid.brick_origin(brick).as_vec3();
                let hi = (lo + Vec3::splat(4.0)).min(dims.as_vec3());
                let steps = ((hi - lo) * 4.0).as_uvec3();
                for sz in 0..=steps.z {
                    for sy in 0..=steps.y {
                        for sx in 0..=steps.x {
                            let p = lo + UVec3::new(sx, sy, sz).as_vec3() * 0.25;
                            let hi_res = trilinear(p - Vec3::splat(0.5), vmax, |c| {
                                volume.value(c.x as u32, c.y as u32, c.z as u32)
                            });
                            let low_res = trilinear(p * 0.5, kmax, |k| level.value(k));
                            for v in [hi_res, low_res] {
                                assert!(
                                    range.min - 1e-6 <= v && v <= range.max + 1e-6,
                                    "{filter:?} brick {brick} p {p}: {v} not in {range:?}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn ranges_include_the_duplicated_border_voxel_only() {
        let dims = UVec3::new(16, 1, 1);
        let mut values = vec![0.5; 16];
        values[8] = 1.0; // first voxel of brick 2 (n = 4), border voxel of brick 1
        let volume = Volume::new(dims, Vec3::ONE, VoxelData::F32(values)).unwrap();
        let grid = BrickGrid::new(dims, 4).unwrap();
        let ranges = brick_value_ranges(&volume, &grid, DownsampleFilter::Mean2).unwrap();
        assert_eq!(ranges[1].max, 1.0);
        assert_eq!(ranges[2].max, 1.0);
        assert_eq!(ranges[0], ValueRange { min: 0.5, max: 0.5 });
        assert!(ranges[3].max < 1.0);
    }

    #[test]
    fn ranges_include_low_res_samples_reaching_past_the_hi_res_border() {
        // Box4's face sample at position 4 (k = 2) reads voxels 2..=5; voxel 2 lies outside brick
        // 1's hi-res window [3, 9), so only the low-res part of the range can see it.
        let dims = UVec3::new(16, 1, 1);
        let mut values = vec![0.5; 16];
        values[2] = 1.0;
        let volume = Volume::new(dims, Vec3::ONE, VoxelData::F32(values)).unwrap();
        let grid = BrickGrid::new(dims, 4).unwrap();
        let ranges = brick_value_ranges(&volume, &grid, DownsampleFilter::Box4).unwrap();
        assert!(ranges[1].max >= 0.625, "{:?}", ranges[1]);
        assert!(ranges[3].max == 0.5);
    }

    #[test]
    fn unorm_storage_widens_low_res_values_to_storage_levels() {
        let dims = UVec3::new(8, 8, 8);
        let count = 512;
        let bytes: Vec<u8> = pseudo_random(count, 3)
            .iter()
            .map(|v| (v * 255.0) as u8)
            .collect();
        let volume = Volume::new(dims, Vec3::ONE, VoxelData::U8(bytes)).unwrap();
        let grid = BrickGrid::new(dims, 4).unwrap();
        let ranges = brick_value_ranges(&volume, &grid, DownsampleFilter::BSpline4).unwrap();
        for (brick, range) in grid.bricks().zip(&ranges) {
            for r in [range.min, range.max] {
                assert!(((r * 255.0).round() - r * 255.0).abs() < 1e-4);
            }
            let packed = pack_low_res_brick(&volume, &grid, DownsampleFilter::BSpline4, brick);
            let stored = quantize_to(&packed.unwrap(), ScalarType::U8);
            for byte in stored {
                assert!(range.contains(f32::from(byte) / 255.0));
            }
        }
    }
}
