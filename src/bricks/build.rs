//! The parallel whole-volume build: a thin driver that runs the [kernel](super::kernel) over the
//! rows of bricks (fixed `(by, bz)`, all `bx`) of an in-memory volume on all cores, straight from
//! the volume's voxels (the window is the whole volume: nothing is copied).
//!
//! [`build_bricks`] produces exactly what the single-threaded reference functions produce, bit for
//! bit (the kernel's guarantee):
//!
//! - hi-res brick `i`: `quantize_to(&pack_hi_res_brick(volume, grid, brick), storage)`;
//! - low-res brick `i`: `quantize_to(&pack_low_res_brick(volume, grid, filter, brick), storage)`;
//! - value range `i`: `brick_value_ranges_for_storage(volume, grid, filter, storage)[i]`;
//! - the low-res level: `low_res_level(volume, filter)` (each row of bricks copies its own part of
//!   the samples the kernel computed).
//!
//! The rows are handed out through a shared queue to `threads` scoped threads (the calling thread
//! included), each with its own [`BrickKernel`]. Each row computes the low-res samples its value
//! ranges need (one sample layer beyond its own part on each side), so the samples on the layers
//! shared with the neighbouring rows are computed twice.

use super::filters::{low_res_dims, max_low_res_index, LowResLevel};
use super::kernel::texel::Texel;
use super::kernel::{BrickBox, BrickKernel, PackOutputs, VoxelWindow};
use super::packing::{hi_res_brick_extent, low_res_brick_extent};
use super::taps::DownsampleFilter;
use super::{BrickError, BrickGrid, ValueRange};
use crate::volume::{ScalarType, Volume, VoxelData};
use glam::UVec3;
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
/// fastest, as native-endian texels of [`PackedBricks::storage`] (what [`super::quantize_to`]
/// returns). Built by [`build_bricks`] / [`build_bricks_with_threads`].
#[derive(Clone, Debug, PartialEq)]
pub struct PackedBricks {
    grid: BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    hi: VoxelData,
    lo: VoxelData,
    ranges: Vec<ValueRange>,
    low_res: LowResLevel,
    threads: usize,
}

impl PackedBricks {
    /// The brick grid the bricks were built for.
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
    /// [`PackedBricks::storage`].
    pub fn value_ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    /// The whole low-res level, as [`super::low_res_level`] computes it.
    pub fn low_res_level(&self) -> &LowResLevel {
        &self.low_res
    }

    /// Rebuilds every brick from `volume` (same dimensions as the grid) on `threads` threads (0
    /// counts as 1), writing into the existing buffers: the large outputs are not allocated (and
    /// their pages not faulted in) again.
    pub fn rebuild(&mut self, volume: &Volume, threads: usize) -> Result<(), BrickError> {
        self.grid.check_volume(volume)?;
        let threads = threads.max(1);
        self.threads = threads;
        let job = Drive {
            volume,
            grid: &self.grid,
            filter: self.filter,
            storage: self.storage,
            threads,
        };
        let level = Some(&mut self.low_res.values[..]);
        let ranges = Some(&mut self.ranges[..]);
        match (&mut self.hi, &mut self.lo) {
            (VoxelData::U8(hi), VoxelData::U8(lo)) => job.run(Some(hi), Some(lo), ranges, level),
            (VoxelData::U16(hi), VoxelData::U16(lo)) => job.run(Some(hi), Some(lo), ranges, level),
            (VoxelData::F32(hi), VoxelData::F32(lo)) => job.run(Some(hi), Some(lo), ranges, level),
            _ => Err(BrickError::OutputMismatch {
                output: "lo",
                reason: "hi-res and low-res bricks differ in storage type".into(),
            }),
        }
    }
}

/// Builds every brick of `volume` on all cores ([`available_threads`]); see [`PackedBricks`] and
/// the [module documentation](self).
///
/// Errors: [`BrickError::DimsMismatch`] when `volume` does not have the grid's dimensions,
/// [`BrickError::StoreTooLarge`] when the packed bricks would not fit in memory addresses.
pub fn build_bricks(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
) -> Result<PackedBricks, BrickError> {
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
) -> Result<PackedBricks, BrickError> {
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
    let zeroed = |len: usize| VoxelData::zeroed(storage, len);
    let level_dims = low_res_dims(grid.dims());
    let mut packed = PackedBricks {
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
        threads: 1,
    };
    packed.rebuild(volume, threads)?;
    Ok(packed)
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
    let dims = low_res_dims(volume.dims());
    let mut values = vec![0.0; grid_len(dims)];
    let job = Drive {
        volume,
        grid: &grid,
        filter,
        storage: ScalarType::F32,
        threads: threads.max(1),
    };
    job.run::<f32>(None, None, None, Some(&mut values))?;
    Ok(LowResLevel { dims, values })
}

/// The per-brick value ranges of `volume` for `storage` on `threads` threads (0 counts as 1):
/// identical to [`super::brick_value_ranges_for_storage`].
pub fn build_value_ranges(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    threads: usize,
) -> Result<Vec<ValueRange>, BrickError> {
    grid.check_volume(volume)?;
    let mut ranges = vec![ValueRange::EMPTY; grid.brick_count()];
    let job = Drive {
        volume,
        grid,
        filter,
        storage,
        threads: threads.max(1),
    };
    job.run::<u8>(None, None, Some(&mut ranges), None)?;
    Ok(ranges)
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

/// One whole-volume build: the volume, its grid and what to pack.
struct Drive<'a> {
    volume: &'a Volume,
    grid: &'a BrickGrid,
    filter: DownsampleFilter,
    storage: ScalarType,
    threads: usize,
}

/// One kernel call: the brick rows `by` at `bz`, all `bx`, and slices of the whole-volume outputs.
struct BoxWork<'a, D> {
    by: Range<usize>,
    bz: usize,
    hi: Option<&'a mut [D]>,
    lo: Option<&'a mut [D]>,
    ranges: Option<&'a mut [ValueRange]>,
    /// The box's part of the level: per low-res `kz` of the part, its `ky` rows (contiguous).
    level: Vec<&'a mut [f32]>,
}

/// Splits the first `len` elements off `rest`.
fn take<'a, X>(rest: &mut Option<&'a mut [X]>, len: usize) -> Option<&'a mut [X]> {
    let (head, tail) = rest.take()?.split_at_mut(len);
    *rest = Some(tail);
    Some(head)
}

impl Drive<'_> {
    /// Runs the kernel over every row of bricks, writing the given outputs (each covering the
    /// whole grid; `None` is not computed).
    fn run<D: Texel>(
        &self,
        mut hi: Option<&mut [D]>,
        mut lo: Option<&mut [D]>,
        mut ranges: Option<&mut [ValueRange]>,
        level: Option<&mut [f32]>,
    ) -> Result<(), BrickError> {
        let n = self.grid.brick_size();
        let [bx, by, bz] = self.grid.bricks_per_axis().to_array().map(|c| c as usize);
        // One row of bricks per call. (Taller boxes share more of the low-res samples that the
        // rows' ranges overlap on, but their larger working set made them no faster.)
        let boxes: Vec<(Range<usize>, usize)> = (0..bz)
            .flat_map(|z| (0..by).map(move |y| (y..y + 1, z)))
            .collect();
        let with_level = level.is_some();
        let mut level_parts = level
            .map(|values| split_level(self.grid, values, &boxes))
            .unwrap_or_default()
            .into_iter();
        let (hi_len, lo_len) = (
            texels_per_brick(hi_res_brick_extent(n)),
            texels_per_brick(low_res_brick_extent(n)),
        );
        let work: Vec<BoxWork<'_, D>> = boxes
            .iter()
            .map(|(rows, z)| {
                let bricks = rows.len() * bx;
                BoxWork {
                    by: rows.clone(),
                    bz: *z,
                    hi: take(&mut hi, bricks * hi_len),
                    lo: take(&mut lo, bricks * lo_len),
                    ranges: take(&mut ranges, bricks),
                    level: level_parts.next().unwrap_or_default(),
                }
            })
            .collect();
        let kernel = BrickKernel::new(self.grid, self.filter, self.storage);
        let window = VoxelWindow::of_volume(self.volume);
        let first_error = Mutex::new(None);
        parallel_for_each(
            self.threads,
            work.into_iter(),
            || kernel.clone(),
            |kernel, work| {
                let result = pack_box(kernel, &window, with_level, work);
                if let Err(e) = result {
                    first_error
                        .lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .get_or_insert(e);
                }
            },
        );
        match first_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// Packs one box of brick rows and copies its part of the level.
fn pack_box<D: Texel>(
    kernel: &mut BrickKernel,
    window: &VoxelWindow<'_>,
    with_level: bool,
    work: BoxWork<'_, D>,
) -> Result<(), BrickError> {
    let grid = *kernel.grid();
    let bricks = BrickBox {
        start: UVec3::new(0, work.by.start as u32, work.bz as u32),
        end: UVec3::new(
            grid.bricks_per_axis().x,
            work.by.end as u32,
            work.bz as u32 + 1,
        ),
    };
    let out = PackOutputs {
        hi: work.hi.map(D::texels),
        lo: work.lo.map(D::texels),
        ranges: work.ranges,
        level: with_level,
    };
    kernel.pack_window(window, &bricks, out)?;
    if !with_level {
        return Ok(());
    }
    let block = kernel.low_res_block();
    let [nx, ny, _] = block.dims;
    let kys = level_part(&grid, 1, work.by.start).start..level_part(&grid, 1, work.by.end - 1).end;
    let kzs = level_part(&grid, 2, work.bz);
    for (kz, rows) in kzs.zip(work.level) {
        for (ky, row) in kys.clone().zip(rows.chunks_exact_mut(nx)) {
            let (y, z) = (ky - block.k_start[1], kz - block.k_start[2]);
            row.copy_from_slice(&block.values[(z * ny + y) * nx..][..nx]);
        }
    }
    Ok(())
}

/// The low-res samples along `axis` that brick row / column `b` owns: `n/2 * b .. n/2 * (b+1)`,
/// the last one up to the end of the level.
fn level_part(grid: &BrickGrid, axis: usize, b: usize) -> Range<usize> {
    let half = grid.brick_size() as usize / 2;
    let end = if b + 1 == grid.bricks_per_axis()[axis] as usize {
        max_low_res_index(grid.dims())[axis] as usize + 1
    } else {
        half * (b + 1)
    };
    half * b..end
}

/// Cuts the level into the parts of `boxes` (brick rows `by` at `bz`, in order): for each box and
/// each `kz` of its part, the contiguous `ky` rows of its part.
fn split_level<'a>(
    grid: &BrickGrid,
    values: &'a mut [f32],
    boxes: &[(Range<usize>, usize)],
) -> Vec<Vec<&'a mut [f32]>> {
    let [lx, ly, _] = low_res_dims(grid.dims()).to_array().map(|c| c as usize);
    let half = grid.brick_size() as usize / 2;
    let bz_count = grid.bricks_per_axis().z as usize;
    let mut parts: Vec<Vec<&'a mut [f32]>> = boxes.iter().map(|_| Vec::new()).collect();
    for (kz, plane) in values.chunks_mut(lx * ly).enumerate() {
        let bz = (kz / half).min(bz_count - 1);
        let mut rest = plane;
        for (part, (rows, _)) in parts.iter_mut().zip(boxes).filter(|(_, (_, z))| *z == bz) {
            let ky = level_part(grid, 1, rows.start).start..level_part(grid, 1, rows.end - 1).end;
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(ky.len() * lx);
            part.push(head);
            rest = tail;
        }
    }
    parts
}

/// Runs `work(state, item)` for every item of `items` on `threads` threads (the calling thread
/// included); each thread builds its `state` with `init` and pulls items from a shared queue.
pub(crate) fn parallel_for_each<I, W>(
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
    fn assert_matches_reference(volume: &Volume, grid: &BrickGrid, store: &PackedBricks) {
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
}
