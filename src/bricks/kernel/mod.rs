//! The bricking kernel: one function, [`BrickKernel::pack_window`], turns a window of voxels into
//! the packed bricks of a box of bricks, in the storage format, and their value ranges.
//!
//! Everything that bricks a volume calls it: the in-memory brick source
//! ([`VolumeBrickSource`](super::VolumeBrickSource), one brick at a time), the brick-store writer
//! (`store::write_store`, runs of bricks along x from a window it evaluates) and the
//! parallel whole-volume build ([`super::build_bricks`], rows of bricks straight from the volume).
//! The reference functions are its oracle, bit for bit:
//!
//! - hi-res brick: `quantize_to(&pack_hi_res_brick(volume, grid, brick), storage)`;
//! - low-res brick: `quantize_to(&pack_low_res_brick(volume, grid, filter, brick), storage)`;
//! - value range: `brick_value_ranges_for_storage(volume, grid, filter, storage)[brick]`;
//! - the low-res samples it computes on the way: `low_res_level(volume, filter)`.
//!
//! # What a call does
//!
//! For a box of bricks `b0..b1` per axis (brick coordinates) the kernel reads each voxel row of
//! the window it needs once (per axis the hi-res window `n*b0 - 1 .. n*b1 + 1` and the taps of the
//! low-res samples `n*b0/2 - 1 ..= n*b1/2 + 1`, clamped to the volume; less when only some outputs
//! are asked for) and
//!
//! - cuts it into the `(n+2)`-texel rows of every hi-res brick of the box with constant-length
//!   slice copies (clamping only for the pad texels at the volume border; verbatim when the storage
//!   type equals the voxel type, because UNORM normalisation followed by quantisation is the
//!   identity on the storage grid),
//! - folds it into column-wise minima / maxima (long vectorised passes; each brick then reduces its
//!   own x window of those), and
//! - filters it along x (one fused pass for `f32`-exact filters, contiguous even / odd slices
//!   otherwise, clamped index tables only for the few samples at the border); the y and z passes
//!   follow per plane.
//!
//! The low-res bricks are then cut from the filtered block (quantised on the way) and the ranges
//! finished. **Value ranges.** Normalisation and the storage rounding the reference applies to
//! every value are monotone, so the range of a brick follows from the raw minimum and maximum of its
//! hi-res window and of its low-res window; the rounding is applied to those two only.

mod pack;
mod rows;
pub(crate) mod texel;

#[cfg(test)]
mod tests;

use super::packing::{hi_res_brick_extent, low_res_brick_extent};
use super::taps::AxisTaps;
use super::taps::DownsampleFilter;
use super::{BrickError, BrickGrid, ValueRange};
use crate::volume::{ScalarType, Volume, VoxelData};
use glam::UVec3;
use std::ops::Range;
use texel::Texel;

/// A box of bricks: brick coordinates `start.x..end.x` by `start.y..end.y` by `start.z..end.z`.
///
/// The kernel lays the bricks of a box out in box order: x fastest, then y, then z (for a box of
/// whole rows that is linear brick order, [`BrickGrid::linear_index`]).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BrickBox {
    /// The first brick of the box.
    pub start: UVec3,
    /// One past the last brick of the box, per axis.
    pub end: UVec3,
}

impl BrickBox {
    /// The box holding the single brick `brick`.
    pub fn single(brick: UVec3) -> Self {
        Self {
            start: brick,
            end: brick + UVec3::ONE,
        }
    }

    /// The bricks `x` along x at row `(y, z)`.
    pub fn run(x: Range<u32>, y: u32, z: u32) -> Self {
        Self {
            start: UVec3::new(x.start, y, z),
            end: UVec3::new(x.end, y + 1, z + 1),
        }
    }

    /// Bricks in the box (0 when any axis is empty).
    pub fn count(&self) -> usize {
        let e = self.end.saturating_sub(self.start);
        e.x as usize * e.y as usize * e.z as usize
    }

    /// The brick coordinates of the box in box order (x fastest).
    pub fn bricks(&self) -> impl Iterator<Item = UVec3> + '_ {
        (self.start.z..self.end.z).flat_map(move |z| {
            (self.start.y..self.end.y)
                .flat_map(move |y| (self.start.x..self.end.x).map(move |x| UVec3::new(x, y, z)))
        })
    }
}

/// A box of voxels of a volume: voxel `origin + (x, y, z)` is `data[x + extent.x * (y + extent.y *
/// z)]`, normalised like [`VoxelData::normalized`].
#[derive(Copy, Clone, Debug)]
pub struct VoxelWindow<'a> {
    data: &'a VoxelData,
    origin: UVec3,
    extent: UVec3,
}

impl<'a> VoxelWindow<'a> {
    /// The window of `extent` voxels at `origin` holding `data` (x fastest). Errors:
    /// [`BrickError::InvalidWindow`] unless `data` holds exactly `extent` voxels.
    pub fn new(data: &'a VoxelData, origin: UVec3, extent: UVec3) -> Result<Self, BrickError> {
        let expected = extent
            .to_array()
            .iter()
            .try_fold(1usize, |acc, &e| acc.checked_mul(e as usize));
        if expected != Some(data.len()) {
            return Err(BrickError::InvalidWindow {
                origin: origin.to_array(),
                extent: extent.to_array(),
                reason: format!("holds {} voxels", data.len()),
            });
        }
        Ok(Self {
            data,
            origin,
            extent,
        })
    }

    /// The whole of `volume` as a window (no copy).
    pub fn of_volume(volume: &'a Volume) -> Self {
        Self {
            data: volume.data(),
            origin: UVec3::ZERO,
            extent: volume.dims(),
        }
    }

    /// The first voxel of the window.
    pub fn origin(&self) -> UVec3 {
        self.origin
    }

    /// Voxels per axis.
    pub fn extent(&self) -> UVec3 {
        self.extent
    }
}

/// Mutable texels of one storage type, for the kernel's outputs.
#[derive(Debug)]
pub enum TexelsMut<'a> {
    /// `U8` texels.
    U8(&'a mut [u8]),
    /// `U16` texels.
    U16(&'a mut [u16]),
    /// `F32` texels.
    F32(&'a mut [f32]),
}

impl<'a> TexelsMut<'a> {
    /// All texels of `data`.
    pub fn of(data: &'a mut VoxelData) -> Self {
        match data {
            VoxelData::U8(v) => TexelsMut::U8(v),
            VoxelData::U16(v) => TexelsMut::U16(v),
            VoxelData::F32(v) => TexelsMut::F32(v),
        }
    }

    /// The storage type of the texels.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            TexelsMut::U8(_) => ScalarType::U8,
            TexelsMut::U16(_) => ScalarType::U16,
            TexelsMut::F32(_) => ScalarType::F32,
        }
    }

    /// Number of texels.
    pub fn len(&self) -> usize {
        match self {
            TexelsMut::U8(v) => v.len(),
            TexelsMut::U16(v) => v.len(),
            TexelsMut::F32(v) => v.len(),
        }
    }

    /// True when there are no texels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// What one [`BrickKernel::pack_window`] call produces; `None` / `false` parts are skipped (and
/// cost nothing).
#[derive(Debug, Default)]
pub struct PackOutputs<'a> {
    /// The packed hi-res bricks of the box, `(n+2)^3` texels each, back to back in box order
    /// (exactly `count * (n+2)^3` texels of the kernel's storage type).
    pub hi: Option<TexelsMut<'a>>,
    /// The packed low-res bricks of the box, `(n/2+1)^3` texels each, back to back in box order.
    pub lo: Option<TexelsMut<'a>>,
    /// One conservative value range per brick of the box, in box order.
    pub ranges: Option<&'a mut [ValueRange]>,
    /// Also compute the box's own part of the low-res level: samples `n*b/2 .. n*(b+1)/2` per
    /// axis (the last brick up to the end of the level).
    pub level: bool,
}

/// The low-res samples the last [`BrickKernel::pack_window`] call computed: `k_start + (x, y, z)`
/// for `(x, y, z)` in `0..dims`, x fastest.
#[derive(Clone, Debug, Default)]
pub(crate) struct LowResBlock {
    pub(crate) k_start: [usize; 3],
    pub(crate) dims: [usize; 3],
    pub(crate) values: Vec<f32>,
}

/// Per-call reusable buffers.
#[derive(Clone, Debug, Default)]
struct Scratch {
    split: rows::RowSplit,
    /// x-filtered rows of one hi-res z plane, for the y taps.
    x_rows: Vec<f32>,
    /// xy-filtered rows, per hi-res z plane of the z taps.
    xy_rows: Vec<f32>,
    /// Per axis and hi-res index of the tap span: whether any tap reads it.
    needed: [Vec<bool>; 3],
    /// Column-wise min / max of the low-res samples of one brick row's range window.
    lo_min: Vec<f32>,
    lo_max: Vec<f32>,
}

/// What the kernel reads and computes along one axis for one call.
#[derive(Clone, Debug)]
struct AxisNeeds {
    /// Voxels of the hi-res windows (for the hi-res bricks and the ranges).
    hi: Range<usize>,
    /// Low-res samples to compute.
    ks: Range<usize>,
    /// Voxels the taps of `ks` read.
    taps: Range<usize>,
}

impl AxisNeeds {
    /// Every voxel read along the axis.
    fn read(&self) -> Range<usize> {
        match (self.hi.is_empty(), self.taps.is_empty()) {
            (true, _) => self.taps.clone(),
            (_, true) => self.hi.clone(),
            _ => self.hi.start.min(self.taps.start)..self.hi.end.max(self.taps.end),
        }
    }
}

/// The bricking kernel of one grid, filter and storage type, with its reusable buffers (keep one
/// per thread). See the [module documentation](self).
#[derive(Clone, Debug)]
pub struct BrickKernel {
    grid: BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    axes: [AxisTaps; 3],
    scratch: Scratch,
    block: LowResBlock,
}

impl BrickKernel {
    /// A kernel packing the bricks of `grid` with low-res filter `filter` into `storage` texels.
    pub fn new(grid: &BrickGrid, filter: DownsampleFilter, storage: ScalarType) -> Self {
        let dims = grid.dims();
        Self {
            grid: *grid,
            filter,
            storage,
            axes: std::array::from_fn(|a| AxisTaps::new(dims[a], filter)),
            scratch: Scratch::default(),
            block: LowResBlock::default(),
        }
    }

    /// The brick grid.
    pub fn grid(&self) -> &BrickGrid {
        &self.grid
    }

    /// The downsampling filter of the low-res bricks.
    pub fn filter(&self) -> DownsampleFilter {
        self.filter
    }

    /// The storage type of the packed texels.
    pub fn storage(&self) -> ScalarType {
        self.storage
    }

    /// The voxels `(origin, extent)` a call with every output (hi, lo, ranges, level) reads for
    /// `bricks`: the window to hand to [`BrickKernel::pack_window`]. Errors:
    /// [`BrickError::BrickOutOfRange`] unless `bricks` is a non-empty box inside the grid.
    pub fn window_for(&self, bricks: &BrickBox) -> Result<(UVec3, UVec3), BrickError> {
        self.check_box(bricks)?;
        let needs = self.needs(bricks, true, true, true, false);
        let read = needs.map(|a| a.read());
        let origin = UVec3::from_array(read.clone().map(|r| r.start as u32));
        let extent = UVec3::from_array(read.map(|r| (r.end - r.start) as u32));
        Ok((origin, extent))
    }

    /// The voxels `(origin, extent)` that packing only the hi-res (`hi`) and / or low-res (`lo`)
    /// bricks of `bricks` reads (a sub-box of [`BrickKernel::window_for`]'s): what a streaming
    /// source must fetch for one level. Errors as [`BrickKernel::window_for`].
    pub fn window_for_outputs(
        &self,
        bricks: &BrickBox,
        hi: bool,
        lo: bool,
    ) -> Result<(UVec3, UVec3), BrickError> {
        self.check_box(bricks)?;
        let needs = self.needs(bricks, hi, lo, false, false);
        let read = needs.map(|a| a.read());
        let origin = UVec3::from_array(read.clone().map(|r| r.start as u32));
        let extent = UVec3::from_array(read.map(|r| (r.end - r.start) as u32));
        Ok((origin, extent))
    }

    /// Packs one level of one brick from `window` into a new buffer: the hi-res brick
    /// (`(n+2)^3` texels) when `hi`, else the low-res brick (`(n/2+1)^3`). The window must hold
    /// what [`BrickKernel::window_for_outputs`] says that level reads. Errors as
    /// [`BrickKernel::pack_window`].
    pub fn pack_level(
        &mut self,
        window: &VoxelWindow<'_>,
        brick: UVec3,
        hi: bool,
    ) -> Result<VoxelData, BrickError> {
        let n = self.grid.brick_size();
        let edge = if hi {
            hi_res_brick_extent(n)
        } else {
            low_res_brick_extent(n)
        };
        let mut packed = VoxelData::zeroed(self.storage, (edge as usize).pow(3));
        let texels = Some(TexelsMut::of(&mut packed));
        let out = if hi {
            PackOutputs {
                hi: texels,
                ..PackOutputs::default()
            }
        } else {
            PackOutputs {
                lo: texels,
                ..PackOutputs::default()
            }
        };
        self.pack_window(window, &BrickBox::single(brick), out)?;
        Ok(packed)
    }

    /// Packs the box `bricks` from `window` into `out` (see [`PackOutputs`] and the
    /// [module documentation](self)).
    ///
    /// Errors: [`BrickError::BrickOutOfRange`] unless `bricks` is a non-empty box inside the grid;
    /// [`BrickError::InvalidWindow`] when the window leaves the volume or misses a voxel the
    /// requested outputs read (use [`BrickKernel::window_for`]); [`BrickError::OutputMismatch`]
    /// when an output has the wrong length or texel type.
    pub fn pack_window(
        &mut self,
        window: &VoxelWindow<'_>,
        bricks: &BrickBox,
        out: PackOutputs<'_>,
    ) -> Result<(), BrickError> {
        self.check_box(bricks)?;
        let count = bricks.count();
        let n = self.grid.brick_size();
        let texels = |extent: u32| count * (extent as usize).pow(3);
        check_output(
            "hi",
            out.hi.as_ref(),
            texels(hi_res_brick_extent(n)),
            self.storage,
        )?;
        check_output(
            "lo",
            out.lo.as_ref(),
            texels(low_res_brick_extent(n)),
            self.storage,
        )?;
        if let Some(ranges) = &out.ranges {
            if ranges.len() != count {
                return Err(BrickError::OutputMismatch {
                    output: "ranges",
                    reason: format!("holds {} ranges for {count} bricks", ranges.len()),
                });
            }
        }
        let needs = self.needs(
            bricks,
            out.hi.is_some(),
            out.lo.is_some(),
            out.ranges.is_some(),
            out.level,
        );
        self.check_window(window, &needs)?;
        match self.storage {
            ScalarType::U8 => self.with_storage::<u8>(window, bricks, &needs, out),
            ScalarType::U16 => self.with_storage::<u16>(window, bricks, &needs, out),
            ScalarType::F32 => self.with_storage::<f32>(window, bricks, &needs, out),
        }
        Ok(())
    }

    /// The low-res samples the last call computed.
    pub(crate) fn low_res_block(&self) -> &LowResBlock {
        &self.block
    }

    fn check_box(&self, bricks: &BrickBox) -> Result<(), BrickError> {
        let inside = bricks.start.cmplt(bricks.end).all()
            && bricks.end.cmple(self.grid.bricks_per_axis()).all();
        if inside {
            Ok(())
        } else {
            let outside = if bricks.start.cmplt(bricks.end).all() {
                bricks.end - UVec3::ONE
            } else {
                bricks.end
            };
            Err(BrickError::BrickOutOfRange {
                brick: outside.to_array(),
                bricks_per_axis: self.grid.bricks_per_axis().to_array(),
            })
        }
    }

    fn check_window(
        &self,
        window: &VoxelWindow<'_>,
        needs: &[AxisNeeds; 3],
    ) -> Result<(), BrickError> {
        let dims = self.grid.dims();
        for a in 0..3 {
            let (o, e) = (window.origin[a] as usize, window.extent[a] as usize);
            let read = needs[a].read();
            let reason = if o + e > dims[a] as usize {
                Some(format!("leaves the volume of {:?} voxels", dims.to_array()))
            } else if !read.is_empty() && (read.start < o || read.end > o + e) {
                Some(format!("misses voxels {read:?} along axis {a}"))
            } else {
                None
            };
            if let Some(reason) = reason {
                return Err(BrickError::InvalidWindow {
                    origin: window.origin.to_array(),
                    extent: window.extent.to_array(),
                    reason,
                });
            }
        }
        Ok(())
    }

    /// What a call reads and computes along each axis.
    fn needs(
        &self,
        bricks: &BrickBox,
        hi: bool,
        lo: bool,
        ranges: bool,
        level: bool,
    ) -> [AxisNeeds; 3] {
        let n = self.grid.brick_size() as usize;
        let half = n / 2;
        let dims = self.grid.dims();
        let per_axis = self.grid.bricks_per_axis();
        std::array::from_fn(|a| {
            let d = dims[a] as usize;
            let kmax = self.axes[a].kmax();
            let (b0, b1) = (bricks.start[a] as usize, bricks.end[a] as usize);
            let hi = if hi || ranges {
                (n * b0).saturating_sub(1)..(n * b1 + 1).min(d)
            } else {
                0..0
            };
            let mut ks: Option<Range<usize>> = None;
            let mut add = |r: Range<usize>| {
                ks = Some(match ks.take() {
                    None => r,
                    Some(k) => k.start.min(r.start)..k.end.max(r.end),
                });
            };
            if lo {
                add(half * b0..(half * b1).min(kmax) + 1);
            }
            if ranges {
                add((half * b0).saturating_sub(1)..(half * b1 + 1).min(kmax) + 1);
            }
            if level {
                let end = if b1 == per_axis[a] as usize {
                    kmax + 1
                } else {
                    half * b1
                };
                add(half * b0..end);
            }
            let ks = ks.unwrap_or(0..0);
            let taps = self.axes[a].span(&ks);
            AxisNeeds { hi, ks, taps }
        })
    }

    fn with_storage<D: Texel>(
        &mut self,
        window: &VoxelWindow<'_>,
        bricks: &BrickBox,
        needs: &[AxisNeeds; 3],
        out: PackOutputs<'_>,
    ) {
        // The types were checked by `check_output`.
        let hi = out.hi.and_then(D::of_texels);
        let lo = out.lo.and_then(D::of_texels);
        let outputs = pack::Outputs {
            hi,
            lo,
            ranges: out.ranges,
        };
        match window.data {
            VoxelData::U8(src) => self.with_source(src, window, bricks, needs, outputs),
            VoxelData::U16(src) => self.with_source(src, window, bricks, needs, outputs),
            VoxelData::F32(src) => self.with_source(src, window, bricks, needs, outputs),
        }
    }

    fn with_source<S: Texel, D: Texel>(
        &mut self,
        src: &[S],
        window: &VoxelWindow<'_>,
        bricks: &BrickBox,
        needs: &[AxisNeeds; 3],
        out: pack::Outputs<'_, D>,
    ) {
        let job = pack::Job {
            grid: &self.grid,
            storage: self.storage,
            axes: &self.axes,
            src,
            origin: window.origin.to_array().map(|c| c as usize),
            extent: window.extent.to_array().map(|c| c as usize),
            bricks,
            needs,
        };
        let (scratch, block) = (&mut self.scratch, &mut self.block);
        match self.filter {
            DownsampleFilter::LaMarSubsample => job.run::<D, 1>(self.filter, scratch, block, out),
            DownsampleFilter::Mean2 => job.run::<D, 2>(self.filter, scratch, block, out),
            DownsampleFilter::Box4 | DownsampleFilter::BSpline4 => {
                job.run::<D, 4>(self.filter, scratch, block, out)
            }
        }
    }
}

/// Checks the length and texel type of one texel output.
fn check_output(
    output: &'static str,
    texels: Option<&TexelsMut<'_>>,
    expected: usize,
    storage: ScalarType,
) -> Result<(), BrickError> {
    let Some(texels) = texels else {
        return Ok(());
    };
    let reason = if texels.scalar_type() != storage {
        format!(
            "holds {:?} texels, the kernel packs {storage:?}",
            texels.scalar_type()
        )
    } else if texels.len() != expected {
        format!("holds {} texels, the box needs {expected}", texels.len())
    } else {
        return Ok(());
    };
    Err(BrickError::OutputMismatch { output, reason })
}
