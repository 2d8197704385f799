//! Parallel whole-volume brick building: every brick's packed hi-res and low-res texels in the
//! cache's storage format, the whole low-res level and the per-brick value ranges, on all cores.
//!
//! [`build_bricks`] produces exactly what the single-threaded reference functions produce, bit for
//! bit:
//!
//! - hi-res brick `i`: `quantize_to(&pack_hi_res_brick(volume, grid, brick), storage)`;
//! - low-res brick `i`: `quantize_to(&pack_low_res_brick(volume, grid, filter, brick), storage)`;
//! - value range `i`: `brick_value_ranges_for_storage(volume, grid, filter, storage)[i]`;
//! - the low-res level: `low_res_level(volume, filter)`.
//!
//! # How it is fast
//!
//! Two parallel phases, each over the rows of bricks (fixed `(by, bz)`, all `bx`), handed out
//! through a shared queue to `threads` scoped threads (the calling thread included):
//!
//! 1. **Source pass.** A row of bricks reads each source voxel row of its hi-res window
//!    (`n*b - 1 .. n*(b+1) + 1` per axis, clamped) and of the filter taps of its part of the
//!    low-res level (samples `n/2 * b .. n/2 * (b+1)` per axis) exactly once, while it is in
//!    cache, and
//!    - cuts it into the `(n+2)`-texel rows of every brick of the row with constant-length slice
//!      copies (clamping only for the pad texels at the volume border; verbatim when the storage
//!      type equals the volume's, because UNORM normalisation followed by quantisation is the
//!      identity on the storage grid),
//!    - folds it into column-wise minima / maxima (long vectorised passes; each brick then reduces
//!      its own x window of those), and
//!    - filters it along x into the row's part of the level (one fused pass for `f32`-exact
//!      filters, contiguous even / odd slices otherwise; clamped index tables only for the few
//!      samples at the border). The y and z passes follow per plane and per part, and the z pass
//!      also writes the level in the storage type.
//!
//!    The arithmetic is the reference's (`f64` accumulation in tap order, rounded to `f32` after
//!    each axis, or `f32` where that provably gives the same bits, see `Weights::new`), so the
//!    level is identical to [`super::low_res_level`].
//! 2. **Level pass.** A row of bricks cuts its low-res bricks from the finished level (in the
//!    storage type) and finishes the value ranges.
//!
//! **Value ranges.** Normalisation and the storage rounding the reference applies to every value
//! are monotone, so the range of a brick follows from the raw minimum and maximum of its hi-res
//! window and of its low-res window; the rounding is applied to those two only.

use super::filters::{low_res_dims, max_low_res_index, DownsampleFilter, LowResLevel};
use super::packing::{hi_res_brick_extent, low_res_brick_extent};
use super::{include_stored, BrickError, BrickGrid, ValueRange};
use crate::volume::{ScalarType, Volume, VoxelData};
use glam::UVec3;
use std::any::TypeId;
use std::ops::Range;
use std::sync::Mutex;

/// Threads [`build_bricks`] uses: `std::thread::available_parallelism()`, or 1 when unknown.
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Every brick of a volume, packed for upload: hi-res `(n+2)^3` and low-res `(n/2+1)^3` texels in
/// the storage format, plus the per-brick value ranges and the whole low-res level.
///
/// Bricks are stored back to back in linear brick order ([`BrickGrid::linear_index`]), texels x
/// fastest, as native-endian texels of [`BrickStore::storage`] (what [`super::quantize_to`]
/// returns). Built by [`build_bricks`] / [`build_bricks_with_threads`].
#[derive(Clone, Debug, PartialEq)]
pub struct BrickStore {
    grid: BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    hi: VoxelData,
    lo: VoxelData,
    ranges: Vec<ValueRange>,
    low_res: LowResLevel,
    /// The low-res level in the storage type (empty for `F32` storage, which uses `low_res`).
    level_stored: VoxelData,
    threads: usize,
}

impl BrickStore {
    /// The brick grid the store was built for.
    pub fn grid(&self) -> &BrickGrid {
        &self.grid
    }

    /// The downsampling filter of the low-res level.
    pub fn filter(&self) -> DownsampleFilter {
        self.filter
    }

    /// The texel format of the packed bricks.
    pub fn storage(&self) -> ScalarType {
        self.storage
    }

    /// Threads the last build ran on.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Bytes of one packed hi-res brick: `(n+2)^3` texels.
    pub fn hi_res_brick_bytes(&self) -> usize {
        texels_per_brick(hi_res_brick_extent(self.grid.brick_size())) * self.storage.size_bytes()
    }

    /// Bytes of one packed low-res brick: `(n/2+1)^3` texels.
    pub fn low_res_brick_bytes(&self) -> usize {
        texels_per_brick(low_res_brick_extent(self.grid.brick_size())) * self.storage.size_bytes()
    }

    /// The packed hi-res brick of linear index `index`, `None` outside the grid.
    pub fn hi_res_brick(&self, index: usize) -> Option<&[u8]> {
        brick_slice(self.hi.as_bytes(), self.hi_res_brick_bytes(), index)
    }

    /// The packed low-res brick of linear index `index`, `None` outside the grid.
    pub fn low_res_brick(&self, index: usize) -> Option<&[u8]> {
        brick_slice(self.lo.as_bytes(), self.low_res_brick_bytes(), index)
    }

    /// All packed hi-res bricks, back to back in linear brick order.
    pub fn hi_res_data(&self) -> &VoxelData {
        &self.hi
    }

    /// All packed low-res bricks, back to back in linear brick order.
    pub fn low_res_data(&self) -> &VoxelData {
        &self.lo
    }

    /// Per-brick value ranges, as [`super::brick_value_ranges_for_storage`] computes them for
    /// [`BrickStore::storage`].
    pub fn value_ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    /// The whole low-res level, as [`super::low_res_level`] computes it.
    pub fn low_res_level(&self) -> &LowResLevel {
        &self.low_res
    }

    /// Rebuilds every brick from `volume` (same dimensions as the grid) on `threads` threads (0
    /// counts as 1), writing into the store's existing buffers: the large outputs are not
    /// allocated (and their pages not faulted in) again.
    pub fn rebuild(&mut self, volume: &Volume, threads: usize) -> Result<(), BrickError> {
        self.grid.check_volume(volume)?;
        let threads = threads.max(1);
        self.threads = threads;
        let plan = Plan::new(&self.grid, self.filter, self.storage, threads);
        match volume.data() {
            VoxelData::U8(src) => self.rebuild_from(src, &plan),
            VoxelData::U16(src) => self.rebuild_from(src, &plan),
            VoxelData::F32(src) => self.rebuild_from(src, &plan),
        }
        Ok(())
    }

    fn rebuild_from<S: Texel>(&mut self, src: &[S], plan: &Plan) {
        let level = &mut self.low_res.values[..];
        let ranges = &mut self.ranges[..];
        match (&mut self.hi, &mut self.lo, &mut self.level_stored) {
            (VoxelData::U8(hi), VoxelData::U8(lo), VoxelData::U8(stored)) => {
                build_all(src, plan, Outputs::new(level, stored, hi, lo, ranges));
            }
            (VoxelData::U16(hi), VoxelData::U16(lo), VoxelData::U16(stored)) => {
                build_all(src, plan, Outputs::new(level, stored, hi, lo, ranges));
            }
            // F32 storage: the level itself is in the storage type (`level_stored` is empty).
            (VoxelData::F32(hi), VoxelData::F32(lo), _) => {
                build_all(src, plan, Outputs::new(level, &mut [], hi, lo, ranges));
            }
            _ => unreachable!("hi-res bricks, low-res bricks and level share the storage type"),
        }
    }
}

/// Builds every brick of `volume` on all cores ([`available_threads`]); see [`BrickStore`] and
/// the [module documentation](self).
///
/// Errors: [`BrickError::DimsMismatch`] when `volume` does not have the grid's dimensions,
/// [`BrickError::StoreTooLarge`] when the packed bricks would not fit in memory addresses.
pub fn build_bricks(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
) -> Result<BrickStore, BrickError> {
    build_bricks_with_threads(volume, grid, filter, storage, available_threads())
}

/// [`build_bricks`] on `threads` threads (the calling thread included; 0 counts as 1). The result
/// does not depend on the thread count.
pub fn build_bricks_with_threads(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    threads: usize,
) -> Result<BrickStore, BrickError> {
    grid.check_volume(volume)?;
    let bricks = grid.brick_count();
    let texels = |extent: u32| {
        bricks
            .checked_mul(texels_per_brick(extent))
            .filter(|t| t.checked_mul(storage.size_bytes()).is_some())
            .ok_or(BrickError::StoreTooLarge {
                bricks,
                brick_size: grid.brick_size(),
            })
    };
    let hi_len = texels(hi_res_brick_extent(grid.brick_size()))?;
    let lo_len = texels(low_res_brick_extent(grid.brick_size()))?;
    let zeroed = |len: usize| match storage {
        ScalarType::U8 => VoxelData::U8(vec![0; len]),
        ScalarType::U16 => VoxelData::U16(vec![0; len]),
        ScalarType::F32 => VoxelData::F32(vec![0.0; len]),
    };
    let level_dims = low_res_dims(grid.dims());
    let mut store = BrickStore {
        grid: *grid,
        filter,
        storage,
        hi: zeroed(hi_len),
        lo: zeroed(lo_len),
        ranges: vec![ValueRange::EMPTY; bricks],
        low_res: LowResLevel {
            dims: level_dims,
            values: vec![0.0; grid_len(level_dims)],
        },
        level_stored: match storage {
            ScalarType::F32 => zeroed(0),
            _ => zeroed(grid_len(level_dims)),
        },
        threads: 1,
    };
    store.rebuild(volume, threads)?;
    Ok(store)
}

/// The whole low-res level of `volume` under `filter` on `threads` threads (0 counts as 1):
/// identical to [`super::low_res_level`].
pub fn build_low_res_level(
    volume: &Volume,
    filter: DownsampleFilter,
    threads: usize,
) -> Result<LowResLevel, BrickError> {
    // The level is computed in parts of one brick row each; any brick size gives the same values.
    let grid = BrickGrid::new(volume.dims(), super::DEFAULT_BRICK_SIZE)?;
    let plan = Plan::new(&grid, filter, volume.scalar_type(), threads.max(1));
    let dims = low_res_dims(volume.dims());
    let mut values = vec![0.0; grid_len(dims)];
    let out = Outputs::<f32>::new(&mut values, &mut [], &mut [], &mut [], &mut []);
    match volume.data() {
        VoxelData::U8(src) => build_all(src, &plan, out),
        VoxelData::U16(src) => build_all(src, &plan, out),
        VoxelData::F32(src) => build_all(src, &plan, out),
    }
    Ok(LowResLevel { dims, values })
}

fn texels_per_brick(extent: u32) -> usize {
    (extent as usize).pow(3)
}

fn grid_len(dims: UVec3) -> usize {
    dims.x as usize * dims.y as usize * dims.z as usize
}

fn brick_slice(bytes: &[u8], brick_bytes: usize, index: usize) -> Option<&[u8]> {
    let start = index.checked_mul(brick_bytes)?;
    bytes.get(start..start.checked_add(brick_bytes)?)
}

/// A voxel / texel type: how it normalises, quantises and orders.
trait Texel: bytemuck::Pod + Send + Sync + 'static {
    /// Larger than or equal to every value (identity of `min_of`).
    const HIGHEST: Self;
    /// Smaller than or equal to every value (identity of `max_of`).
    const LOWEST: Self;
    /// True for UNORM types: normalised values are `0` or at least `1 / 65535`.
    const UNORM: bool;
    /// The normalised value, exactly as [`VoxelData::normalized`] computes it.
    fn normalized(self) -> f32;
    /// The texel storing normalised `v`, exactly as [`super::quantize_to`] computes it.
    fn from_normalized(v: f32) -> Self;
    /// `(min, max)` of `values` and `init` (finite values only for `f32`).
    fn min_max(values: &[Self], init: (Self, Self)) -> (Self, Self);
    /// Column-wise `lo[i] = min(lo[i], values[i])`, `hi[i] = max(hi[i], values[i])`.
    fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]);
}

/// The UNORM texel types differ only in their maximum; one definition serves both.
macro_rules! unorm_texel {
    ($t:ty, $max:expr) => {
        impl Texel for $t {
            const HIGHEST: Self = <$t>::MAX;
            const LOWEST: Self = 0;
            const UNORM: bool = true;
            #[inline]
            fn normalized(self) -> f32 {
                f32::from(self) / $max
            }
            #[inline]
            fn from_normalized(v: f32) -> Self {
                unorm_round(v, $max) as $t
            }
            #[inline]
            fn min_max(values: &[Self], (mut lo, mut hi): (Self, Self)) -> (Self, Self) {
                // A plain reduction: the compiler vectorises it.
                for &v in values {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                (lo, hi)
            }
            #[inline]
            fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]) {
                for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(values) {
                    *l = (*l).min(v);
                    *h = (*h).max(v);
                }
            }
        }
    };
}

unorm_texel!(u8, 255.0);
unorm_texel!(u16, 65535.0);

impl Texel for f32 {
    const HIGHEST: Self = f32::INFINITY;
    const LOWEST: Self = f32::NEG_INFINITY;
    const UNORM: bool = false;
    #[inline]
    fn normalized(self) -> f32 {
        self
    }
    #[inline]
    fn from_normalized(v: f32) -> Self {
        v
    }
    #[inline]
    fn min_max(values: &[Self], init: (Self, Self)) -> (Self, Self) {
        // Reduce order-preserving integer keys, which vectorises (float min / max reductions do
        // not without fast-math). Volumes and low-res levels hold finite values only.
        let (mut lo, mut hi) = (f32_key(init.0), f32_key(init.1));
        for &v in values {
            let key = f32_key(v);
            lo = lo.min(key);
            hi = hi.max(key);
        }
        (f32_from_key(lo), f32_from_key(hi))
    }
    #[inline]
    fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]) {
        // Plain comparisons: element-wise, so they vectorise (finite values only).
        for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(values) {
            *l = if v < *l { v } else { *l };
            *h = if v > *h { v } else { *h };
        }
    }
}

/// An `i32` ordered like the (non-NaN) `f32` `v`: negative values get their magnitude bits
/// flipped, so the total order of the keys is the order of the values (`-0.0` just below `0.0`).
#[inline]
fn f32_key(v: f32) -> i32 {
    let bits = v.to_bits() as i32;
    bits ^ ((bits >> 31) & 0x7FFF_FFFF)
}

/// The inverse of [`f32_key`].
#[inline]
fn f32_from_key(key: i32) -> f32 {
    f32::from_bits((key ^ ((key >> 31) & 0x7FFF_FFFF)) as u32)
}

/// `(v.clamp(0.0, 1.0) * max).round()` as an integer (NaN gives 0), exactly as
/// [`super::quantize_to`] computes it, for `max <= 65535`, in operations that vectorise (no
/// saturating float-to-int cast):
///
/// - after the clamp, `x = v * max` is the same `f32` product in `[0, max]`;
/// - `y = x + 2^23` rounds `x` to the nearest integer, ties to even (the `f32` spacing in
///   `[2^23, 2^24)` is 1), and the low mantissa bits of `y` are that integer `r`;
/// - `x - r` is exact (Sterbenz), and equals `0.5` exactly when `x` was a tie that went down to an
///   even `r`: `f32::round` rounds ties away from zero, so add one there.
#[inline]
fn unorm_round(v: f32, max: f32) -> u32 {
    const TWO_POW_23: f32 = 8_388_608.0;
    let v = if v > 0.0 { v } else { 0.0 }; // also maps NaN (and -0.0) to 0
    let v = if v < 1.0 { v } else { 1.0 };
    let x = v * max;
    let y = x + TWO_POW_23;
    let nearest_even = y.to_bits() - TWO_POW_23.to_bits();
    let tie_down = x - (y - TWO_POW_23) == 0.5;
    nearest_even + u32::from(tie_down)
}

/// Converts `src` to `dst` texel by texel (normalise, then quantise); a plain copy when both
/// types are the same (the conversion is the identity then).
#[inline]
fn convert_into<S: Texel, D: Texel>(src: &[S], dst: &mut [D]) {
    if TypeId::of::<S>() == TypeId::of::<D>() {
        dst.copy_from_slice(bytemuck::cast_slice(src));
    } else {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = D::from_normalized(s.normalized());
        }
    }
}

/// One converted texel.
#[inline]
fn convert_one<S: Texel, D: Texel>(s: S) -> D {
    let mut one = [D::zeroed()];
    convert_into(&[s], &mut one);
    one[0]
}

/// [`convert_into`] for the short rows of packed bricks: the usual row lengths (`n + 2` and
/// `n/2 + 1` for `n` = 8, 16, 32, 64) get a copy of constant length, which compiles to a few
/// vector moves instead of a `memcpy` call.
#[inline]
fn convert_short<S: Texel, D: Texel>(src: &[S], dst: &mut [D]) {
    #[inline]
    fn fixed<S: Texel, D: Texel, const N: usize>(src: &[S], dst: &mut [D]) -> bool {
        match (<&[S; N]>::try_from(src), <&mut [D; N]>::try_from(dst)) {
            (Ok(src), Ok(dst)) => {
                convert_into(src, dst);
                true
            }
            _ => false,
        }
    }
    let done = match dst.len() {
        9 => fixed::<S, D, 9>(src, dst),
        10 => fixed::<S, D, 10>(src, dst),
        17 => fixed::<S, D, 17>(src, dst),
        18 => fixed::<S, D, 18>(src, dst),
        33 => fixed::<S, D, 33>(src, dst),
        34 => fixed::<S, D, 34>(src, dst),
        65 => fixed::<S, D, 65>(src, dst),
        66 => fixed::<S, D, 66>(src, dst),
        _ => false,
    };
    if !done {
        convert_into(src, dst);
    }
}

/// Fills `dst` with the texels `row[clamp(start + t, 0, len - 1)]`, converted; returns the range
/// of `row` indices that was copied without clamping (it contains every index read).
#[inline]
fn copy_clamped_row<S: Texel, D: Texel>(row: &[S], start: i64, dst: &mut [D]) -> Range<usize> {
    let len = dst.len() as i64;
    let last = row.len() as i64 - 1;
    let left = (-start).clamp(0, len) as usize;
    let mid_end = (last + 1 - start).clamp(left as i64, len) as usize;
    let first = (start + left as i64) as usize;
    let copied = first..first + (mid_end - left);
    convert_short(&row[copied.clone()], &mut dst[left..mid_end]);
    if left > 0 {
        dst[..left].fill(convert_one(row[0]));
    }
    if mid_end < dst.len() {
        dst[mid_end..].fill(convert_one(row[last as usize]));
    }
    copied
}

/// Runs `work(state, item)` for every item of `items` on `threads` threads (the calling thread
/// included); each thread builds its `state` with `init` and pulls items from a shared queue.
fn parallel_for_each<I, W>(
    threads: usize,
    items: I,
    init: impl Fn() -> W + Sync,
    work: impl Fn(&mut W, I::Item) + Sync,
) where
    I: Iterator + Send,
    I::Item: Send,
{
    let queue = Mutex::new(items);
    let run = || {
        let mut state = init();
        loop {
            let next = queue.lock().unwrap_or_else(|p| p.into_inner()).next();
            match next {
                Some(item) => work(&mut state, item),
                None => break,
            }
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads {
            scope.spawn(run);
        }
        run();
    });
}

/// Everything the workers need to know about the volume, grid and filter.
struct Plan {
    dims: [usize; 3],
    level_dims: [usize; 3],
    kmax: [usize; 3],
    brick_size: usize,
    bricks: [usize; 3],
    filter: DownsampleFilter,
    storage: ScalarType,
    threads: usize,
}

impl Plan {
    fn new(
        grid: &BrickGrid,
        filter: DownsampleFilter,
        storage: ScalarType,
        threads: usize,
    ) -> Self {
        let to_usize = |v: UVec3| v.to_array().map(|c| c as usize);
        Self {
            dims: to_usize(grid.dims()),
            level_dims: to_usize(low_res_dims(grid.dims())),
            kmax: to_usize(max_low_res_index(grid.dims())),
            brick_size: grid.brick_size() as usize,
            bricks: to_usize(grid.bricks_per_axis()),
            filter,
            storage,
            threads,
        }
    }
}

/// The taps of one axis of the separable filter.
struct AxisTaps<const T: usize> {
    /// Per low-res sample `k`: the clamped hi-res index of each tap, in tap order.
    index: Vec<[usize; T]>,
    /// Samples whose taps are the unclamped consecutive indices `2k + first_offset + t`.
    interior: Range<usize>,
    first_offset: i64,
}

impl<const T: usize> AxisTaps<T> {
    fn new(d: usize, kmax: usize, offsets: [i64; T]) -> Self {
        let last = d as i64 - 1;
        let index = (0..=kmax as i64)
            .map(|k| offsets.map(|o| (2 * k + o).clamp(0, last) as usize))
            .collect();
        let consecutive = offsets.windows(2).all(|w| w[1] == w[0] + 1);
        let (first, final_) = (offsets[0], offsets[T - 1]);
        // 2k + first >= 0 and 2k + final <= last.
        let k_lo = ((-first).max(0) + 1) / 2;
        let k_hi = ((last - final_).div_euclid(2) + 1).clamp(0, kmax as i64 + 1);
        let interior = if consecutive && k_lo < k_hi {
            k_lo as usize..k_hi as usize
        } else {
            0..0
        };
        Self {
            index,
            interior,
            first_offset: first,
        }
    }
}

/// Per-worker row buffers of the x pass: the normalised row split into even and odd indices.
struct RowSplit {
    even: Vec<f32>,
    odd: Vec<f32>,
}

impl RowSplit {
    fn new(d: usize) -> Self {
        Self {
            even: vec![0.0; d.div_ceil(2)],
            odd: vec![0.0; d / 2],
        }
    }

    /// Normalises `row` into the even / odd halves.
    #[inline]
    fn load<S: Texel>(&mut self, row: &[S]) {
        let pairs = row.chunks_exact(2);
        if let [last] = pairs.remainder() {
            self.even[row.len() / 2] = last.normalized();
        }
        for ((e, o), pair) in self.even.iter_mut().zip(self.odd.iter_mut()).zip(pairs) {
            *e = pair[0].normalized();
            *o = pair[1].normalized();
        }
    }
}

/// The filter weights of one axis, and how to accumulate them.
struct Weights<const T: usize> {
    f64: [f64; T],
    f32: [f32; T],
    /// Accumulating in `f32` gives the reference's `f64`-then-`f32` result bit for bit.
    exact_in_f32: bool,
}

impl<const T: usize> Weights<T> {
    /// The weights of `taps` for a source whose normalised values are UNORM (`unorm`) or
    /// arbitrary finite `f32`.
    ///
    /// The reference accumulates `sum w_t v_t` in `f64` (from 0.0, in tap order) and rounds the sum
    /// to `f32`. With one tap of weight 1 that is `v` itself; with two taps of weight 1/2 it is
    /// `RN32(RN64(a/2 + b/2))` with `a/2`, `b/2` exact, and rounding a sum of two `f32` values
    /// through `f64` first is innocuous (53 >= 2 * 24 + 2), so it equals the `f32` sum
    /// `a * 0.5 + b * 0.5` as long as the halves do not underflow, which holds for UNORM inputs
    /// (nonzero values are at least `2^-16`, and averages stay above `2^-18` after three
    /// passes) and their averages. Every other case keeps `f64`.
    fn new(taps: [f32; T], unorm: bool) -> Self {
        let mean_of_two = T == 2 && taps.iter().all(|&w| w == 0.5);
        let single = T == 1 && taps[0] == 1.0;
        Self {
            f64: taps.map(f64::from),
            f32: taps,
            exact_in_f32: unorm && (mean_of_two || single),
        }
    }
}

/// Filters one hi-res source row into `out`, one value per low-res sample: clamped index tables
/// at the border; inside, either one fused pass over the source (`f32`-exact filters with at most
/// two taps) or contiguous slices of the row split into even / odd indices.
#[inline]
fn filter_row<S: Texel, const T: usize>(
    src: &[S],
    split: &mut RowSplit,
    taps: &AxisTaps<T>,
    w: &Weights<T>,
    out: &mut [f32],
) {
    let interior = taps.interior.clone();
    for k in (0..interior.start).chain(interior.end..out.len()) {
        let mut acc = 0.0_f64;
        for (&wt, &i) in w.f64.iter().zip(&taps.index[k]) {
            acc += wt * f64::from(src[i].normalized());
        }
        out[k] = acc as f32;
    }
    if interior.start >= interior.end {
        return;
    }
    // Tap t of sample k reads index 2k + o + t.
    let k0 = interior.start;
    let first = (2 * k0 as i64 + taps.first_offset) as usize;
    let out = &mut out[interior];
    if w.exact_in_f32 && T == 1 {
        for (o, v) in out.iter_mut().zip(src[first..].iter().step_by(2)) {
            *o = 0.0 + w.f32[0] * v.normalized();
        }
    } else if w.exact_in_f32 && T == 2 {
        // Interior samples have both taps inside the row, so the pairs are complete.
        for (o, pair) in out.iter_mut().zip(src[first..].chunks_exact(2)) {
            *o = 0.0 + w.f32[0] * pair[0].normalized() + w.f32[T - 1] * pair[1].normalized();
        }
    } else {
        split.load(src);
        // Tap t reads half (o + t) mod 2 of the split row at position k + (o + t) div 2.
        let rows: [&[f32]; T] = std::array::from_fn(|t| {
            let offset = taps.first_offset + t as i64;
            let half = if offset.rem_euclid(2) == 0 {
                &split.even
            } else {
                &split.odd
            };
            &half[(k0 as i64 + offset.div_euclid(2)) as usize..]
        });
        combine_rows(rows, w, out);
    }
}

/// `out[i] = sum_t w[t] * rows[t][i]`, accumulated in tap order from 0 in `f64` and rounded to
/// `f32` (the reference's arithmetic), or in `f32` where that is provably the same
/// ([`Weights::new`]). Every row must hold at least `out.len()` values.
#[inline]
fn combine_rows<const T: usize>(rows: [&[f32]; T], w: &Weights<T>, out: &mut [f32]) {
    let len = out.len();
    let rows = rows.map(|r| &r[..len]);
    if w.exact_in_f32 {
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0_f32;
            for (r, &wt) in rows.iter().zip(&w.f32) {
                acc += wt * r[i];
            }
            *o = acc;
        }
    } else {
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0_f64;
            for (r, &wt) in rows.iter().zip(&w.f64) {
                acc += wt * f64::from(r[i]);
            }
            *o = acc as f32;
        }
    }
}

/// Output buffers of a build: the `f32` level, the level in the storage type (empty for `F32`
/// storage or a level-only build) and, unless empty, the packed bricks and their ranges.
struct Outputs<'a, D> {
    level: &'a mut [f32],
    stored: &'a mut [D],
    hi: &'a mut [D],
    lo: &'a mut [D],
    ranges: &'a mut [ValueRange],
}

impl<'a, D> Outputs<'a, D> {
    fn new(
        level: &'a mut [f32],
        stored: &'a mut [D],
        hi: &'a mut [D],
        lo: &'a mut [D],
        ranges: &'a mut [ValueRange],
    ) -> Self {
        Self {
            level,
            stored,
            hi,
            lo,
            ranges,
        }
    }
}

/// Builds the level and (unless `out.hi` is empty) every brick of `src`.
fn build_all<S: Texel, D: Texel>(src: &[S], plan: &Plan, out: Outputs<'_, D>) {
    match plan.filter {
        DownsampleFilter::LaMarSubsample => build_all_taps::<S, D, 1>(src, plan, out),
        DownsampleFilter::Mean2 => build_all_taps::<S, D, 2>(src, plan, out),
        DownsampleFilter::Box4 | DownsampleFilter::BSpline4 => {
            build_all_taps::<S, D, 4>(src, plan, out)
        }
    }
}

/// The first-phase work of one row of bricks (fixed `by`, `bz`): everything that needs the
/// source volume.
struct RowWork<'a, S, D> {
    row: usize,
    /// The row's packed hi-res bricks (empty for a level-only build).
    bricks: &'a mut [D],
    /// Raw min / max of each brick's hi-res window.
    minmax: &'a mut [(S, S)],
    /// The row's part of the level: per low-res `kz` of the part, its `ky` rows (contiguous).
    level: Vec<&'a mut [f32]>,
    /// The same rows in the storage type (empty when not stored separately).
    stored: Vec<&'a mut [D]>,
}

/// Per-worker buffers.
struct Scratch<S> {
    /// The source row split into even / odd indices (`f64` path of the x pass).
    split: RowSplit,
    /// x-filtered rows of one hi-res z plane, for the y taps of the current part.
    x_rows: Vec<f32>,
    /// xy-filtered rows, per hi-res z plane of the z taps of the current part.
    xy_rows: Vec<f32>,
    /// Column-wise min / max over the source rows of the current hi-res window.
    hi_min: Vec<S>,
    hi_max: Vec<S>,
}

/// Column-wise min / max over the level rows of a brick row's low-res range window.
struct LevelColumns {
    min: Vec<f32>,
    max: Vec<f32>,
}

/// The separable filter of one build and the partition of the level into brick rows.
struct LevelFilter<const T: usize> {
    w: Weights<T>,
    axes: [AxisTaps<T>; 3],
    /// Per axis and hi-res index: whether any tap reads it.
    needed: [Vec<bool>; 3],
}

impl<const T: usize> LevelFilter<T> {
    fn new(plan: &Plan, unorm: bool) -> Self {
        let taps = plan.filter.taps();
        debug_assert_eq!(taps.len(), T);
        let offsets: [i64; T] = std::array::from_fn(|t| taps[t].0);
        let w = Weights::new(std::array::from_fn(|t| taps[t].1), unorm);
        let axes: [AxisTaps<T>; 3] =
            std::array::from_fn(|a| AxisTaps::new(plan.dims[a], plan.kmax[a], offsets));
        let needed = std::array::from_fn(|a| {
            let mut needed = vec![false; plan.dims[a]];
            for taps in &axes[a].index {
                for &i in taps {
                    needed[i] = true;
                }
            }
            needed
        });
        Self { w, axes, needed }
    }

    /// The hi-res indices `lo..hi` the taps of the low-res samples `ks` read along `axis`.
    fn tap_span(&self, axis: usize, ks: &Range<usize>) -> Range<usize> {
        let taps = &self.axes[axis].index[ks.clone()];
        let lo = taps.iter().flatten().copied().min().unwrap_or(0);
        let hi = taps.iter().flatten().copied().max().map_or(lo, |i| i + 1);
        lo..hi
    }

    /// Phase-1 work of one brick row: reads each source row of the row's hi-res window and of
    /// the taps of its level part once, cutting it into the hi-res bricks (and folding it into
    /// the min / max) and filtering it along x; then filters along y per plane and along z.
    fn row<S: Texel, D: Texel>(
        &self,
        src: &[S],
        plan: &Plan,
        scratch: &mut Scratch<S>,
        work: RowWork<'_, S, D>,
    ) {
        let n = plan.brick_size;
        let he = n + 2;
        let hi_len = he * he * he;
        let [dx, dy, dz] = plan.dims;
        let lx = plan.level_dims[0];
        let (by, bz) = (work.row % plan.bricks[1], work.row / plan.bricks[1]);
        let (kys, kzs) = (level_part(plan, 1, by), level_part(plan, 2, bz));
        let (ty_span, tz_span) = (self.tap_span(1, &kys), self.tap_span(2, &kzs));
        let with_bricks = !work.bricks.is_empty();
        let window = |b: usize, d: usize| (n * b).saturating_sub(1)..(n * b + n + 1).min(d);
        let (hy_span, hz_span) = if with_bricks {
            (window(by, dy), window(bz, dz))
        } else {
            (0..0, 0..0)
        };
        let union = |a: &Range<usize>, b: &Range<usize>| match (a.is_empty(), b.is_empty()) {
            (true, _) => b.clone(),
            (_, true) => a.clone(),
            _ => a.start.min(b.start)..a.end.max(b.end),
        };
        let (ys, zs) = (union(&ty_span, &hy_span), union(&tz_span, &hz_span));
        let nky = kys.len();
        let Scratch {
            split,
            x_rows,
            xy_rows,
            hi_min,
            hi_max,
            ..
        } = scratch;
        x_rows.resize(ty_span.len() * lx, 0.0);
        xy_rows.resize(tz_span.len() * nky * lx, 0.0);
        hi_min.fill(S::HIGHEST);
        hi_max.fill(S::LOWEST);
        // Texel layers of brick row `b` that hold voxel layer `h` (several at a clamped face).
        let layers = |h: usize, b: usize, d: usize| -> Range<usize> {
            let base = (n * b) as i64 - 1;
            let first = if h == 0 { 0 } else { h as i64 - base };
            let last = if h == d - 1 {
                he as i64 - 1
            } else {
                h as i64 - base
            };
            first.max(0) as usize..(last + 1).clamp(0, he as i64) as usize
        };
        for hz in zs {
            let z_level = tz_span.contains(&hz) && self.needed[2][hz];
            let z_hi = hz_span.contains(&hz);
            for hy in ys.clone() {
                let y_level = z_level && ty_span.contains(&hy) && self.needed[1][hy];
                let y_hi = z_hi && hy_span.contains(&hy);
                if !(y_level || y_hi) {
                    continue;
                }
                let src_row = &src[(hz * dy + hy) * dx..][..dx];
                if y_hi {
                    for tz in layers(hz, bz, dz) {
                        for ty in layers(hy, by, dy) {
                            let texels = (tz * he + ty) * he..(tz * he + ty + 1) * he;
                            for (bx, brick) in work.bricks.chunks_exact_mut(hi_len).enumerate() {
                                let start = (n * bx) as i64 - 1;
                                copy_clamped_row(src_row, start, &mut brick[texels.clone()]);
                            }
                        }
                    }
                    S::fold_columns(hi_min, hi_max, src_row);
                }
                if y_level {
                    let x_row = &mut x_rows[(hy - ty_span.start) * lx..][..lx];
                    filter_row(src_row, split, &self.axes[0], &self.w, x_row);
                }
            }
            if z_level {
                let plane = &mut xy_rows[(hz - tz_span.start) * nky * lx..][..nky * lx];
                for (ky, out) in kys.clone().zip(plane.chunks_exact_mut(lx)) {
                    let rows =
                        self.axes[1].index[ky].map(|hy| &x_rows[(hy - ty_span.start) * lx..][..lx]);
                    combine_rows(rows, &self.w, out);
                }
            }
        }
        let mut stored = work.stored.into_iter();
        for (kz, level_rows) in kzs.zip(work.level) {
            let mut stored_rows = stored.next();
            for (j, out) in level_rows.chunks_exact_mut(lx).enumerate() {
                let rows = self.axes[2].index[kz]
                    .map(|hz| &xy_rows[((hz - tz_span.start) * nky + j) * lx..][..lx]);
                combine_rows(rows, &self.w, out);
                if let Some(stored_rows) = stored_rows.as_deref_mut() {
                    convert_into(out, &mut stored_rows[j * lx..][..lx]);
                }
            }
        }
        for (bx, minmax) in work.minmax.iter_mut().enumerate() {
            let xs = window(bx, dx);
            let (min, _) = S::min_max(&hi_min[xs.clone()], (S::HIGHEST, S::LOWEST));
            let (_, max) = S::min_max(&hi_max[xs], (S::HIGHEST, S::LOWEST));
            *minmax = (min, max);
        }
    }
}

/// The low-res samples along `axis` that brick row / column `b` computes: `n/2 * b ..
/// n/2 * (b+1)`, the last one up to the end of the level.
fn level_part(plan: &Plan, axis: usize, b: usize) -> Range<usize> {
    let half = plan.brick_size / 2;
    let end = if b + 1 == plan.bricks[axis] {
        plan.kmax[axis] + 1
    } else {
        half * (b + 1)
    };
    half * b..end
}

/// Cuts the level (or its stored copy) into the parts of the brick rows: for brick row `r` and
/// each of its `kz`, the contiguous `ky` rows of its part.
fn split_level<'a, X>(plan: &Plan, values: &'a mut [X], rows: usize) -> Vec<Vec<&'a mut [X]>> {
    let [lx, ly, _] = plan.level_dims;
    let by_count = plan.bricks[1];
    let mut parts: Vec<Vec<&'a mut [X]>> = (0..rows).map(|_| Vec::new()).collect();
    if values.is_empty() {
        return parts;
    }
    for (kz, plane) in values.chunks_mut(lx * ly).enumerate() {
        let bz = (kz / (plan.brick_size / 2)).min(plan.bricks[2] - 1);
        let mut rest = plane;
        for by in 0..by_count {
            let len = level_part(plan, 1, by).len() * lx;
            let (part, tail) = std::mem::take(&mut rest).split_at_mut(len);
            parts[bz * by_count + by].push(part);
            rest = tail;
        }
    }
    parts
}

/// [`build_all`] for a filter with `T` taps.
///
/// Phase 1, per row of bricks: the hi-res bricks and the row's part of the level (each source
/// row is read from memory once for both). Phase 2, per row of bricks: the low-res bricks cut
/// from the finished level, and the value ranges.
fn build_all_taps<S: Texel, D: Texel, const T: usize>(src: &[S], plan: &Plan, out: Outputs<'_, D>) {
    let filter = LevelFilter::<T>::new(plan, S::UNORM);
    let [dx, _, _] = plan.dims;
    let lx = plan.level_dims[0];
    let n = plan.brick_size;
    let [bx_count, by_count, bz_count] = plan.bricks;
    let rows = by_count * bz_count;
    let hi_len = (n + 2).pow(3);
    let Outputs {
        level,
        stored,
        hi,
        lo,
        ranges,
    } = out;
    let with_bricks = !hi.is_empty();

    let mut hi_minmax = vec![(S::HIGHEST, S::LOWEST); ranges.len()];
    {
        let mut hi_rows = hi.chunks_mut(bx_count * hi_len);
        let mut minmax_rows = hi_minmax.chunks_mut(bx_count);
        let mut level_parts = split_level(plan, level, rows).into_iter();
        let mut stored_parts = split_level(plan, stored, rows).into_iter();
        let work: Vec<RowWork<'_, S, D>> = (0..rows)
            .map(|row| RowWork {
                row,
                bricks: hi_rows.next().unwrap_or_default(),
                minmax: minmax_rows.next().unwrap_or_default(),
                level: level_parts.next().unwrap_or_default(),
                stored: stored_parts.next().unwrap_or_default(),
            })
            .collect();
        let init = || Scratch {
            split: RowSplit::new(dx),
            x_rows: Vec::new(),
            xy_rows: Vec::new(),
            hi_min: vec![S::HIGHEST; dx],
            hi_max: vec![S::LOWEST; dx],
        };
        parallel_for_each(plan.threads, work.into_iter(), init, |scratch, work| {
            filter.row(src, plan, scratch, work);
        });
    }

    if !with_bricks {
        return;
    }
    let stored: &[D] = if TypeId::of::<D>() == TypeId::of::<f32>() {
        // F32 storage: the level itself is in the storage type.
        bytemuck::cast_slice(level)
    } else {
        stored
    };
    let level: &[f32] = level;
    let lo_len = (n / 2 + 1).pow(3);
    let items = lo
        .chunks_mut(bx_count * lo_len)
        .zip(ranges.chunks_mut(bx_count))
        .zip(hi_minmax.chunks(bx_count))
        .enumerate();
    let init = || LevelColumns {
        min: vec![f32::HIGHEST; lx],
        max: vec![f32::LOWEST; lx],
    };
    parallel_for_each(
        plan.threads,
        items,
        init,
        |columns, (row, ((lo, ranges), hi_minmax))| {
            pack_lo_row(level, stored, plan, columns, row, lo, ranges, hi_minmax);
        },
    );
}

/// Packs the low-res bricks of brick row `row` from the finished level and writes the value
/// ranges: the raw hi-res window min / max (`hi_minmax`) plus the min / max of the low-res samples
/// `n*b/2 - 1 ..= n*b/2 + n/2 + 1` per axis (clamped), each rounded as the storage needs.
#[allow(clippy::too_many_arguments)] // reason: one brick row's slices of every output.
fn pack_lo_row<S: Texel, D: Texel>(
    level: &[f32],
    stored: &[D],
    plan: &Plan,
    columns: &mut LevelColumns,
    row: usize,
    lo: &mut [D],
    ranges: &mut [ValueRange],
    hi_minmax: &[(S, S)],
) {
    let n = plan.brick_size;
    let le = n / 2 + 1;
    let lo_len = le * le * le;
    let [lx, ly, _] = plan.level_dims;
    let kmax = plan.kmax;
    let (by, bz) = (row % plan.bricks[1], row / plan.bricks[1]);
    // Texel j holds level sample n*b/2 + j, clamped.
    for tz in 0..le {
        let kz = (n * bz / 2 + tz).min(kmax[2]);
        for ty in 0..le {
            let ky = (n * by / 2 + ty).min(kmax[1]);
            let level_row = &stored[(kz * ly + ky) * lx..][..lx];
            let texels = (tz * le + ty) * le..(tz * le + ty + 1) * le;
            for (bx, brick) in lo.chunks_exact_mut(lo_len).enumerate() {
                copy_clamped_row(level_row, (n * bx / 2) as i64, &mut brick[texels.clone()]);
            }
        }
    }
    let window = |b: usize, axis: usize| {
        (n * b / 2).saturating_sub(1)..(n * b / 2 + n / 2 + 2).min(kmax[axis] + 1)
    };
    columns.min.fill(f32::HIGHEST);
    columns.max.fill(f32::LOWEST);
    for kz in window(bz, 2) {
        for ky in window(by, 1) {
            let level_row = &level[(kz * ly + ky) * lx..][..lx];
            f32::fold_columns(&mut columns.min, &mut columns.max, level_row);
        }
    }
    let none = (f32::HIGHEST, f32::LOWEST);
    for (bx, (range, &(vmin, vmax))) in ranges.iter_mut().zip(hi_minmax).enumerate() {
        let ks = window(bx, 0);
        let (lmin, _) = f32::min_max(&columns.min[ks.clone()], none);
        let (_, lmax) = f32::min_max(&columns.max[ks], none);
        let mut r = ValueRange::EMPTY;
        for value in [vmin.normalized(), vmax.normalized(), lmin, lmax] {
            include_stored(&mut r, value, plan.storage);
        }
        *range = r;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::tests::pseudo_random;
    use crate::bricks::{
        brick_value_ranges_for_storage, low_res_level, pack_hi_res_brick, pack_low_res_brick,
        quantize_to,
    };
    use glam::Vec3;

    const STORAGES: [ScalarType; 3] = [ScalarType::U8, ScalarType::U16, ScalarType::F32];

    fn volume_of(dims: UVec3, scalar: ScalarType, seed: u64) -> Volume {
        let count = (dims.x * dims.y * dims.z) as usize;
        let values = pseudo_random(count, seed);
        let data = match scalar {
            ScalarType::U8 => VoxelData::U8(values.iter().map(|v| (v * 256.0) as u8).collect()),
            ScalarType::U16 => {
                VoxelData::U16(values.iter().map(|v| (v * 65536.0) as u16).collect())
            }
            ScalarType::F32 => VoxelData::F32(values),
        };
        Volume::new(dims, Vec3::ONE, data).unwrap()
    }

    /// Compares a store against the single-threaded reference functions, bit for bit.
    fn assert_matches_reference(volume: &Volume, grid: &BrickGrid, store: &BrickStore) {
        let (filter, storage) = (store.filter(), store.storage());
        let what = format!(
            "dims {} n {} {filter:?} {:?} -> {storage:?}, {} threads",
            grid.dims(),
            grid.brick_size(),
            volume.scalar_type(),
            store.threads()
        );
        let level = low_res_level(volume, filter);
        assert_eq!(store.low_res_level().dims, level.dims, "{what}");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&store.low_res_level().values),
            bits(&level.values),
            "{what}"
        );
        let ranges = brick_value_ranges_for_storage(volume, grid, filter, storage).unwrap();
        assert_eq!(store.value_ranges(), &ranges[..], "{what}");
        for (i, brick) in grid.bricks().enumerate() {
            let hi = quantize_to(&pack_hi_res_brick(volume, grid, brick).unwrap(), storage);
            assert_eq!(
                store.hi_res_brick(i),
                Some(&hi[..]),
                "{what} hi brick {brick}"
            );
            let lo = pack_low_res_brick(volume, grid, filter, brick).unwrap();
            let lo = quantize_to(&lo, storage);
            assert_eq!(
                store.low_res_brick(i),
                Some(&lo[..]),
                "{what} lo brick {brick}"
            );
        }
        assert_eq!(store.hi_res_brick(grid.brick_count()), None);
        assert_eq!(store.low_res_brick(grid.brick_count()), None);
        assert_eq!(
            store.hi_res_data().as_bytes().len(),
            grid.brick_count() * store.hi_res_brick_bytes()
        );
    }

    #[test]
    fn matches_the_reference_packers_on_awkward_dims() {
        let cases = [
            (UVec3::new(37, 1, 23), 8),
            (UVec3::new(1, 1, 1), 4),
            (UVec3::new(31, 29, 17), 8),
            (UVec3::new(31, 29, 17), 4),
            (UVec3::new(2, 3, 5), 2),
            (UVec3::new(1, 17, 1), 4),
            (UVec3::new(16, 16, 16), 16),
            (UVec3::new(33, 7, 9), 32),
        ];
        for (case, &(dims, n)) in cases.iter().enumerate() {
            let grid = BrickGrid::new(dims, n).unwrap();
            for source in STORAGES {
                let volume = volume_of(dims, source, case as u64 + 1);
                for filter in DownsampleFilter::ALL {
                    for storage in STORAGES {
                        let threads = 1 + (case % 3);
                        let store =
                            build_bricks_with_threads(&volume, &grid, filter, storage, threads)
                                .unwrap();
                        assert_matches_reference(&volume, &grid, &store);
                    }
                }
            }
        }
    }

    #[test]
    fn result_does_not_depend_on_the_thread_count() {
        let dims = UVec3::new(45, 38, 27);
        let grid = BrickGrid::new(dims, 8).unwrap();
        let volume = volume_of(dims, ScalarType::U16, 99);
        for filter in DownsampleFilter::ALL {
            let one =
                build_bricks_with_threads(&volume, &grid, filter, ScalarType::U16, 1).unwrap();
            assert_matches_reference(&volume, &grid, &one);
            for threads in [0, 2, 3, 8, 64] {
                let many =
                    build_bricks_with_threads(&volume, &grid, filter, ScalarType::U16, threads)
                        .unwrap();
                assert_eq!(many.threads(), threads.max(1));
                assert_eq!(
                    many.hi_res_data(),
                    one.hi_res_data(),
                    "{filter:?} {threads}"
                );
                assert_eq!(
                    many.low_res_data(),
                    one.low_res_data(),
                    "{filter:?} {threads}"
                );
                assert_eq!(many.value_ranges(), one.value_ranges());
                assert_eq!(many.low_res_level(), one.low_res_level());
            }
        }
        let all = build_bricks(&volume, &grid, DownsampleFilter::Box4, ScalarType::U8).unwrap();
        assert_eq!(all.threads(), available_threads());
        assert_matches_reference(&volume, &grid, &all);
    }

    #[test]
    fn rebuild_reuses_the_store_for_a_new_volume() {
        let dims = UVec3::new(20, 11, 6);
        let grid = BrickGrid::new(dims, 4).unwrap();
        let first = volume_of(dims, ScalarType::U8, 5);
        let second = volume_of(dims, ScalarType::U8, 6);
        let filter = DownsampleFilter::BSpline4;
        let mut store = build_bricks(&first, &grid, filter, ScalarType::U16).unwrap();
        store.rebuild(&second, 2).unwrap();
        assert_matches_reference(&second, &grid, &store);
        let wrong = volume_of(UVec3::new(20, 11, 7), ScalarType::U8, 5);
        assert!(matches!(
            store.rebuild(&wrong, 2),
            Err(BrickError::DimsMismatch { .. })
        ));
        assert!(matches!(
            build_bricks(&wrong, &grid, filter, ScalarType::U8),
            Err(BrickError::DimsMismatch { .. })
        ));
    }

    #[test]
    fn parallel_level_equals_the_serial_level() {
        for (dims, seed) in [(UVec3::new(53, 2, 41), 3), (UVec3::new(1, 1, 9), 4)] {
            for source in STORAGES {
                let volume = volume_of(dims, source, seed);
                for filter in DownsampleFilter::ALL {
                    for threads in [1, 3] {
                        let fast = build_low_res_level(&volume, filter, threads).unwrap();
                        assert_eq!(fast, low_res_level(&volume, filter), "{dims} {filter:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn fast_quantisation_equals_quantize_to() {
        let mut values = vec![
            f32::NAN,
            -0.0,
            0.0,
            -1.0,
            2.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            1.0,
            0.5,
            1.0 - f32::EPSILON,
        ];
        let next = |v: f32, d: i32| f32::from_bits(v.to_bits().wrapping_add_signed(d));
        for (levels, count) in [(65535.0_f32, 65535u32), (255.0, 255)] {
            for k in 0..=count {
                let tie = (k as f32 + 0.5) / levels;
                values.extend((-2..=2).map(|d| next(tie, d)));
            }
        }
        // A stride through every bit pattern of [0, 1].
        values.extend((0..=1.0_f32.to_bits()).step_by(1009).map(f32::from_bits));
        values.extend(pseudo_random(100_000, 9).iter().map(|v| v * 1.2 - 0.1));
        let ties = values
            .iter()
            .filter(|&&v| (v * 65535.0).fract() == 0.5 && v < 1.0)
            .count();
        assert!(ties > 1000, "only {ties} exact ties exercised");
        let words = quantize_to(&values, ScalarType::U16);
        let bytes = quantize_to(&values, ScalarType::U8);
        for (i, &v) in values.iter().enumerate() {
            let word = u16::from_ne_bytes([words[2 * i], words[2 * i + 1]]);
            assert_eq!(u16::from_normalized(v), word, "{v:e} ({:#x})", v.to_bits());
            assert_eq!(
                u8::from_normalized(v),
                bytes[i],
                "{v:e} ({:#x})",
                v.to_bits()
            );
        }
    }

    #[test]
    fn same_type_copy_equals_normalise_then_quantise() {
        // The verbatim-copy path relies on quantise(normalise(v)) == v on the storage grid.
        for v in 0..=u16::MAX {
            assert_eq!(u16::from_normalized(v.normalized()), v);
            let packed = quantize_to(&[VoxelData::U16(vec![v]).normalized(0)], ScalarType::U16);
            assert_eq!(packed, v.to_ne_bytes());
        }
        for v in 0..=u8::MAX {
            assert_eq!(u8::from_normalized(v.normalized()), v);
        }
        let mut out = [0u8; 7];
        let range = copy_clamped_row(&[10u8, 20, 30], -2, &mut out);
        assert_eq!(out, [10, 10, 10, 20, 30, 30, 30]);
        assert_eq!(range, 0..3);
        let mut out = [0u8; 3];
        assert_eq!(copy_clamped_row(&[1u8, 2, 3, 4, 5], 1, &mut out), 1..4);
        assert_eq!(out, [2, 3, 4]);
    }
}
