//! Writing a level store from a volume file read in slabs of z planes, never holding the
//! volume or any level of it: level 0's stored bricks come from a window of `n + 4` planes that
//! slides along z, and level 1 (the vertex level, an eighth of the samples) is built plane by
//! plane from the same window into a temporary file next to the store (`plane_file.rs`); each
//! coarser level is then built plane by plane from the file of the level below into a file of
//! its own, and every level's stored bricks are read back from its file through a window of
//! planes. The temporary files are removed as soon as the next level is built (and on error).
//!
//! The bytes equal those [`super::write_level_store`] writes from the loaded volume: level 1's
//! samples are the same sums in the same order as [`LevelGrid::downsampled`] (the level-0-to-1
//! filter's taps around each vertex, clamped to the volume), and every coarser level the very sums
//! of [`LevelGrid::downsampled`], in its order.
//!
//! RAM: the window (`n + 4` planes as f32), one slab of raw planes, and a few planes of the
//! level being built or read (checked against the budget before any work). Disk: the temporary
//! files of two adjacent levels at a time, at most about half a byte per voxel (level 1 as f32).

use super::format::{LevelEntry, LEVEL_ENTRY_BYTES};
use super::plane_file::{downsample_file, PlaneFile, PlaneFileWriter, PlaneWindow};
use super::writer::{
    assemble_level_store, check_level_desc, LevelWriteSummary, TexelSink, WRITE_BUFFER_BYTES,
};
use crate::bricks::DownsampleFilter;
use crate::bricks::{BrickGrid, ValueRange};
use crate::cache::{block_bricks, stored_brick_edge, stored_bricks_per_axis, stored_first_sample};
use crate::pyramid::{box_values, downsample_sum, level_one_taps, LevelGrid, SamplePlacement};
use crate::store::StoreError;
use crate::volume::{SlabMut, SlabReader, VoxelData};
use glam::{IVec3, UVec3};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};

/// Planes read per slab.
const SLAB_PLANES: u32 = 8;

/// Bytes [`write_level_store_from_slabs`] needs for a volume of `dims` voxels of
/// `voxel_bytes` each in bricks of `brick_size`, written as `stored_count` stored bricks (the
/// header's count), with a reader holding `reader_bytes`.
pub fn level_slab_bytes(
    dims: UVec3,
    voxel_bytes: u64,
    brick_size: u32,
    stored_count: u64,
    reader_bytes: u64,
) -> u64 {
    let plane = u64::from(dims.x) * u64::from(dims.y);
    let window = plane * u64::from(brick_size + 4 + SLAB_PLANES) * 4;
    let slab = plane * u64::from(SLAB_PLANES) * voxel_bytes;
    // Level 1's window of planes (as f32): the planes of a stored brick, or the three a coarser
    // plane reads, whichever is more; coarser levels hold fewer, smaller planes.
    let level1 = LevelGrid::covering_dims(1, SamplePlacement::Vertex, dims).as_u64vec3();
    let level1_window = level1.x * level1.y * u64::from((brick_size / 2 + 1).max(3) + 1) * 4;
    // The table: an entry per stored brick while writing, then its encoding, and the file's
    // write buffer.
    let table = stored_count * (std::mem::size_of::<LevelEntry>() as u64 + LEVEL_ENTRY_BYTES);
    window + slab + level1_window + table + WRITE_BUFFER_BYTES as u64 + reader_bytes
}

/// Writes every level of the volume `reader` reads (levels `0..levels`; `None`: the default)
/// as a level store at `path`, holding about [`level_slab_bytes`] of RAM, at most
/// `ram_budget`. Same bytes, progress and atomic rename as [`super::write_level_store`].
///
/// Errors: [`StoreError::RamBudget`] and [`StoreError::InvalidDesc`] before anything is
/// created; [`StoreError::Input`] when the reader fails (naming the file); [`StoreError::Io`]
/// for the store file.
pub fn write_level_store_from_slabs(
    path: &Path,
    reader: &mut dyn SlabReader,
    brick_size: u32,
    levels: Option<u32>,
    filter: DownsampleFilter,
    ram_budget: u64,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<LevelWriteSummary, StoreError> {
    let dims = reader.dims();
    let (grid, header) = check_level_desc(
        dims,
        brick_size,
        levels,
        reader.scalar(),
        reader.spacing(),
        filter,
    )?;
    let needed = level_slab_bytes(
        dims,
        reader.scalar().size_bytes() as u64,
        brick_size,
        header.stored_count,
        reader.scratch_bytes(),
    );
    if needed > ram_budget {
        return Err(StoreError::RamBudget {
            needed,
            budget: ram_budget,
            message: format!(
                "a window of {} z planes of {}x{} voxels as f32 (a row of bricks and a slab; \
                 level 1 and coarser are built on disk)",
                brick_size + 4 + SLAB_PLANES,
                dims.x,
                dims.y
            ),
        });
    }
    assemble_level_store(
        path,
        header,
        &mut |sink| {
            let mut planes = Planes::new(&mut *reader, dims);
            let mut level1 = LevelOne::new(dims, filter, level_temp(path, 1))?;
            let n = brick_size;
            let bricks = grid.bricks_per_axis();
            // Level 0, one row of bricks along z at a time.
            for bz in 0..bricks.z {
                let first = (n * bz) as i32 - 2;
                let last = (n * bz + n + 1).min(dims.z - 1);
                // Planes neither this row of bricks nor level 1 reads go before the next are
                // read: the window holds the row's n + 4 planes, and at most a slab more.
                planes.drop_before((first.max(0) as u32).min(level1.oldest_needed()));
                planes.load_through(last, &mut |p, planes| level1.plane_ready(p, planes))?;
                for by in 0..bricks.y {
                    for bx in 0..bricks.x {
                        let start = IVec3::new((n * bx) as i32 - 2, (n * by) as i32 - 2, first);
                        sink.push(&planes.brick(start, (n + 4) as i32))?;
                    }
                }
            }
            planes.load_through(dims.z - 1, &mut |p, planes| level1.plane_ready(p, planes))?;
            planes.finish()?;
            // Level 1 from its file, then each level from the file of the one before.
            let mut level_file = level1.finish()?;
            for level in 1..header.levels {
                if level > 1 {
                    level_file = downsample_file(&level_file, dims, level_temp(path, level))?;
                }
                write_level_from_file(sink, &grid, &level_file)?;
            }
            Ok(planes.value_range)
        },
        progress,
    )
}

/// The window of z planes (normalised f32) the reader has read and not yet dropped.
struct Planes<'a> {
    reader: &'a mut dyn SlabReader,
    dims: UVec3,
    /// Planes `first..first + window.len()`.
    window: VecDeque<Vec<f32>>,
    first: u32,
    /// Planes read so far.
    read: u32,
    raw: VoxelData,
    value_range: ValueRange,
    /// Buffers of dropped planes, reused for the next planes read.
    spare: Vec<Vec<f32>>,
}

impl<'a> Planes<'a> {
    fn new(reader: &'a mut dyn SlabReader, dims: UVec3) -> Self {
        let plane = dims.x as usize * dims.y as usize;
        let raw = VoxelData::zeroed(reader.scalar(), plane * SLAB_PLANES as usize);
        Self {
            reader,
            dims,
            window: VecDeque::new(),
            first: 0,
            read: 0,
            raw,
            value_range: ValueRange::EMPTY,
            spare: Vec::new(),
        }
    }

    /// Reads planes up to `last` (inclusive), calling `ready(p, self)` after each plane `p`
    /// arrives.
    fn load_through(
        &mut self,
        last: u32,
        ready: &mut dyn FnMut(u32, &Planes<'_>) -> Result<(), StoreError>,
    ) -> Result<(), StoreError> {
        let plane = self.dims.x as usize * self.dims.y as usize;
        while self.read <= last {
            let end = (self.read + SLAB_PLANES).min(self.dims.z);
            let count = (end - self.read) as usize * plane;
            let out = SlabMut::of_range(&mut self.raw, 0..count).ok_or_else(|| {
                StoreError::InvalidDesc {
                    field: "dims",
                    message: "slab outside its buffer".into(),
                }
            })?;
            self.reader.read_slab(self.read..end, out)?;
            for k in 0..(end - self.read) as usize {
                // A dropped plane's buffer is reused: fresh plane-sized allocations freed in
                // turn fragment the heap, and the process would hold far more than the window.
                let mut values = self.spare.pop().unwrap_or_default();
                values.clear();
                values.extend((k * plane..(k + 1) * plane).map(|i| self.raw.normalized(i)));
                for &v in &values {
                    self.value_range.include(v);
                }
                self.window.push_back(values);
                let p = self.read + k as u32;
                ready(p, self)?;
            }
            self.read = end;
        }
        Ok(())
    }

    /// Drops the planes before `z`.
    fn drop_before(&mut self, z: u32) {
        while self.first < z {
            let Some(plane) = self.window.pop_front() else {
                break;
            };
            self.spare.push(plane);
            self.first += 1;
        }
        // Enough spares for the planes of one slab.
        self.spare.truncate(SLAB_PLANES as usize);
    }

    /// Voxel `v`, clamped to the volume (its plane must be in the window).
    fn voxel(&self, v: IVec3) -> f32 {
        let c = v
            .clamp(IVec3::ZERO, self.dims.as_ivec3() - IVec3::ONE)
            .as_uvec3();
        let plane = &self.window[(c.z - self.first) as usize];
        plane[(c.x + self.dims.x * c.y) as usize]
    }

    /// The `edge^3` voxels from `start` (clamped), x fastest.
    fn brick(&self, start: IVec3, edge: i32) -> Vec<f32> {
        box_values(start, edge, |v| self.voxel(v))
    }

    fn finish(&mut self) -> Result<(), StoreError> {
        Ok(self.reader.finish()?)
    }
}

/// Level 1 (vertex samples every 2 voxels) built plane by plane into its temporary file.
struct LevelOne {
    volume: UVec3,
    /// The level-0-to-1 filter.
    filter: DownsampleFilter,
    dims: UVec3,
    out: PlaneFileWriter,
    /// The next level-1 plane to build.
    next: u32,
}

impl LevelOne {
    fn new(volume: UVec3, filter: DownsampleFilter, path: PathBuf) -> Result<Self, StoreError> {
        let dims = LevelGrid::covering_dims(1, SamplePlacement::Vertex, volume);
        Ok(Self {
            volume,
            filter,
            dims,
            out: PlaneFileWriter::create(path, 1, dims)?,
            next: 0,
        })
    }

    /// The first voxel plane a level-1 plane still to be built reads (its lowest tap).
    fn oldest_needed(&self) -> u32 {
        level_one_taps(self.filter, self.next as i32)
            .iter()
            .map(|&(k, _)| k)
            .min()
            .unwrap_or(0)
            .max(0) as u32
    }

    /// Builds every level-1 plane whose voxel planes have all arrived once plane `p` has.
    fn plane_ready(&mut self, p: u32, planes: &Planes<'_>) -> Result<(), StoreError> {
        let last = self.volume.z as i32 - 1;
        while self.next < self.dims.z {
            let needs = level_one_taps(self.filter, self.next as i32)
                .iter()
                .map(|&(k, _)| k)
                .max()
                .unwrap_or(0);
            if needs.min(last) > p as i32 {
                break;
            }
            let plane = self.build_plane(self.next, planes);
            self.out.push(&plane)?;
            self.next += 1;
        }
        Ok(())
    }

    /// Level-1 plane `jz`: per sample the sum [`LevelGrid::downsampled`] forms over the voxels
    /// (`downsample_sum` of the filter's taps, the voxels clamped to the volume).
    fn build_plane(&self, jz: u32, planes: &Planes<'_>) -> Vec<f32> {
        let taps = |j: i32| level_one_taps(self.filter, j);
        let tz = taps(jz as i32);
        let taps_x: Vec<Vec<(i32, f32)>> = (0..self.dims.x as i32).map(taps).collect();
        let mut plane = Vec::with_capacity(self.dims.x as usize * self.dims.y as usize);
        for jy in 0..self.dims.y as i32 {
            let ty = taps(jy);
            for tx in &taps_x {
                plane.push(downsample_sum(&tz, &ty, tx, |k| planes.voxel(k)));
            }
        }
        plane
    }

    fn finish(self) -> Result<PlaneFile, StoreError> {
        self.out.finish()
    }
}

/// A fresh name for the temporary file of `level`'s samples while the store at `path` is
/// written (`.NAME.partial-PID-N.levelK` beside it; created exclusively).
fn level_temp(path: &Path, level: u32) -> PathBuf {
    let mut name = crate::output::partial_name(path).into_os_string();
    name.push(format!(".level{level}"));
    PathBuf::from(name)
}

/// Appends every stored brick of `file`'s level for `grid`, blocks in linear order, reading
/// the level's planes in order: the texels [`LevelGrid::stored_brick`] gives.
fn write_level_from_file(
    sink: &mut TexelSink<'_>,
    grid: &BrickGrid,
    file: &PlaneFile,
) -> Result<(), StoreError> {
    let (level, n) = (file.level, grid.brick_size());
    let stored = stored_bricks_per_axis(grid.bricks_per_axis(), level);
    let block = block_bricks(level);
    let edge = stored_brick_edge(n, level) as i32;
    let mut window = PlaneWindow::open(file)?;
    let mut values = Vec::with_capacity(edge.pow(3) as usize);
    for z in 0..stored.z {
        let start_z = stored_first_sample(UVec3::new(0, 0, z) * block, n, level).z;
        window.hold(start_z, start_z + edge - 1)?;
        for y in 0..stored.y {
            for x in 0..stored.x {
                let start = stored_first_sample(UVec3::new(x, y, z) * block, n, level);
                values.clear();
                for tz in 0..edge {
                    for ty in 0..edge {
                        for tx in 0..edge {
                            values.push(window.value(start + IVec3::new(tx, ty, tz)));
                        }
                    }
                }
                sink.push(&values)?;
            }
        }
    }
    Ok(())
}
