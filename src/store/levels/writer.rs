//! Writing a level store from an in-memory volume: every level of its vertex pyramid, packed as
//! the three-level cache stores it, into a fresh temporary file
//! beside it (created exclusively, never through a link), renamed into place once complete.
//! The pieces shared with the slab writer ([`super::slab_writer`]): the file's assembly and the
//! sink the stored bricks stream into.

use super::format::{
    canonical_level_header, encode_level_header, encode_level_table, finish_level_checksum,
    stored_per_level, LevelEntry, LevelStoreHeader,
};
use crate::bricks::{dequantize, quantize_to, BrickGrid, DownsampleFilter, ValueRange};
use crate::cache::{
    block_bricks, min_brick_size_for_levels, pyramid_levels, stored_bricks_per_axis,
};
use crate::pyramid::{LevelGrid, SamplePlacement, VolumeLevels};
use crate::store::format::brick_crc;
use crate::store::writer::{commit_partial, create_partial};
use crate::store::StoreError;
use crate::store::LEVEL_STORE;
use crate::volume::{ScalarType, Volume};
use glam::{UVec3, Vec3};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The store file's write buffer.
pub(super) const WRITE_BUFFER_BYTES: usize = 1 << 20;

/// What [`write_level_store`] wrote.
#[derive(Clone, Debug)]
pub struct LevelWriteSummary {
    /// The finished store.
    pub path: PathBuf,
    /// Its header.
    pub header: LevelStoreHeader,
    /// Wall time of the whole write.
    pub elapsed: Duration,
}

/// The levels a level store of a volume of `volume_dims` in bricks of `brick_size` gets by
/// default: levels 0-2 and the block levels up to one block covering the grid's longest axis
/// ([`crate::cache::pyramid_levels`]).
pub fn default_store_levels(volume_dims: UVec3, brick_size: u32) -> Result<u32, StoreError> {
    let grid = brick_grid(volume_dims, brick_size)?;
    Ok(pyramid_levels(brick_size, grid.bricks_per_axis()))
}

fn brick_grid(dims: UVec3, brick_size: u32) -> Result<BrickGrid, StoreError> {
    BrickGrid::new(dims, brick_size).map_err(|e| StoreError::InvalidDesc {
        field: "brick_size",
        message: e.to_string(),
    })
}

/// Checks a level store's description before any work: the brick grid, the level count
/// (`None`: the default) against the brick size, and the format's limits. Returns the grid and
/// the header (value range still empty).
pub(super) fn check_level_desc(
    dims: UVec3,
    brick_size: u32,
    levels: Option<u32>,
    scalar: ScalarType,
    spacing: Vec3,
    filter: DownsampleFilter,
) -> Result<(BrickGrid, LevelStoreHeader), StoreError> {
    let grid = brick_grid(dims, brick_size)?;
    let levels = levels.unwrap_or(pyramid_levels(brick_size, grid.bricks_per_axis()));
    let min_size = min_brick_size_for_levels(levels);
    if !(1..=31).contains(&levels) || brick_size < min_size {
        return Err(StoreError::InvalidDesc {
            field: "levels",
            message: format!(
                "{levels} levels with bricks of {brick_size}: 1..=31 levels, and {levels} levels \
                 need bricks of at least {min_size} voxels"
            ),
        });
    }
    let header = canonical_level_header(&grid, levels, scalar, spacing, ValueRange::EMPTY, filter)
        .ok_or_else(|| StoreError::InvalidDesc {
            field: "dims",
            message: format!(
                "{:?} in bricks of {brick_size} with {levels} levels overflows the format",
                dims.to_array()
            ),
        })?;
    Ok((grid, header))
}

/// Writes every level of `volume` (levels `0..levels`; `None`: [`default_store_levels`]) as a
/// level store at `path`: level 0 its normalised voxels, each coarser level the vertex level
/// downsampled from the one before ([`LevelGrid::downsampled`]; level 1 by `filter`, recorded
/// in the header), every stored brick exactly the
/// texels [`LevelGrid::stored_brick`] gives, in the volume's scalar type. `progress(done,
/// total)` is called after every stored brick.
///
/// RAM: the volume plus levels 1 and 2 as f32 (about 0.56 bytes per voxel at the peak; level 0
/// is cut from the voxels brick by brick);
/// the texels stream to disk level by level. [`super::write_level_store_from_slabs`] writes
/// the same bytes from a file under a RAM budget. The file is assembled in a fresh temporary file beside `path`
/// and renamed to `path` only once complete; on any error the partial file is removed.
///
/// Errors: a brick size the volume cannot be bricked with, a level count outside `1..=31` or
/// past what the brick size takes ([`min_brick_size_for_levels`]), a volume too large for the
/// format, or an OS failure.
pub fn write_level_store(
    path: &Path,
    volume: &Volume,
    brick_size: u32,
    levels: Option<u32>,
    filter: DownsampleFilter,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<LevelWriteSummary, StoreError> {
    let (grid, header) = check_level_desc(
        volume.dims(),
        brick_size,
        levels,
        volume.scalar_type(),
        volume.spacing(),
        filter,
    )?;
    let (min, max) = volume.value_range();
    assemble_level_store(
        path,
        header,
        &mut |sink| {
            // Level 0 cut from the voxels, level 1 built from them: level 0 is never held as f32.
            let n = grid.brick_size();
            sink.write_stored(&grid, 0, &|first| {
                VolumeLevels::level_zero_brick(volume, first, n)
            })?;
            let mut level_grid = None::<LevelGrid>;
            for _ in 1..header.levels {
                let next = match &level_grid {
                    None => LevelGrid::level_one(volume, filter),
                    Some(finer) => {
                        finer.downsampled(SamplePlacement::Vertex, volume.dims(), filter)
                    }
                };
                sink.write_level(&grid, &next)?;
                level_grid = Some(next);
            }
            Ok(ValueRange { min, max })
        },
        progress,
    )
}

/// Where the stored bricks of a level store go, in table order: the texels right after each
/// other from `data_offset`, and their table entries.
pub(super) struct TexelSink<'a> {
    out: BufWriter<&'a File>,
    partial: &'a Path,
    scalar: ScalarType,
    offset: u64,
    entries: Vec<LevelEntry>,
    total: u64,
    progress: &'a mut dyn FnMut(u64, u64),
}

impl TexelSink<'_> {
    /// Appends one stored brick (`values` normalised, x fastest): quantised to the store's
    /// scalar type, its range as read back, its CRC-32.
    pub(super) fn push(&mut self, values: &[f32]) -> Result<(), StoreError> {
        let bytes = quantize_to(values, self.scalar);
        let range = ValueRange::of(&dequantize(&bytes, self.scalar));
        self.out
            .write_all(&bytes)
            .map_err(|source| StoreError::Io {
                kind: LEVEL_STORE,
                path: self.partial.to_path_buf(),
                action: "write stored bricks",
                source,
            })?;
        self.entries.push(LevelEntry {
            offset: self.offset,
            crc: brick_crc(&bytes),
            range,
        });
        self.offset += bytes.len() as u64;
        (self.progress)(self.entries.len() as u64, self.total);
        Ok(())
    }

    /// Appends every stored brick of `level_grid`'s level for `grid`, blocks in linear order.
    pub(super) fn write_level(
        &mut self,
        grid: &BrickGrid,
        level_grid: &LevelGrid,
    ) -> Result<(), StoreError> {
        let n = grid.brick_size();
        self.write_stored(grid, level_grid.level(), &|first| {
            level_grid.stored_brick(first, n)
        })
    }

    /// Appends every stored brick of `level` for `grid` in table order (blocks in linear
    /// order), the texels of the one whose block starts at brick `first` from `texels(first)`.
    pub(super) fn write_stored(
        &mut self,
        grid: &BrickGrid,
        level: u32,
        texels: &dyn Fn(UVec3) -> Vec<f32>,
    ) -> Result<(), StoreError> {
        let stored = stored_bricks_per_axis(grid.bricks_per_axis(), level);
        let block = block_bricks(level);
        for z in 0..stored.z {
            for y in 0..stored.y {
                for x in 0..stored.x {
                    self.push(&texels(UVec3::new(x, y, z) * block))?;
                }
            }
        }
        Ok(())
    }
}

/// Creates a fresh temporary file beside `path` (`store::writer::create_partial`), lets `fill` stream every stored brick into the sink in table
/// order (and return the volume's value range), checks that it wrote them all, then writes the
/// table and the header and renames the file to `path`. On any error the partial file is
/// removed.
pub(super) fn assemble_level_store(
    path: &Path,
    mut header: LevelStoreHeader,
    fill: &mut dyn FnMut(&mut TexelSink<'_>) -> Result<ValueRange, StoreError>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<LevelWriteSummary, StoreError> {
    let start = Instant::now();
    let (file, partial) = create_partial(LEVEL_STORE, path)?;
    let io = |action: &'static str| {
        let p = partial.clone();
        move |source| StoreError::Io {
            kind: LEVEL_STORE,
            path: p,
            action,
            source,
        }
    };
    let result = (|| {
        let mut out = BufWriter::with_capacity(WRITE_BUFFER_BYTES, &file);
        out.seek(SeekFrom::Start(header.data_offset))
            .map_err(io("seek to the texels"))?;
        let grid = header.grid().ok_or_else(|| StoreError::InvalidDesc {
            field: "dims",
            message: "cannot brick".into(),
        })?;
        let mut sink = TexelSink {
            out,
            partial: &partial,
            scalar: header.scalar,
            offset: header.data_offset,
            entries: Vec::with_capacity(usize::try_from(header.stored_count).unwrap_or(0)),
            total: stored_per_level(&grid, header.levels).iter().sum(),
            progress,
        };
        header.value_range = fill(&mut sink)?;
        sink.out.flush().map_err(io("write stored bricks"))?;
        if sink.offset != header.file_size || sink.entries.len() as u64 != header.stored_count {
            return Err(StoreError::InvalidDesc {
                field: "stored_count",
                message: format!(
                    "wrote {} stored bricks ending at byte {}; the header expects {} ending at {}",
                    sink.entries.len(),
                    sink.offset,
                    header.stored_count,
                    header.file_size
                ),
            });
        }
        let table = encode_level_table(&sink.entries);
        let mut header_bytes = encode_level_header(&header);
        finish_level_checksum(&mut header_bytes, &table);
        file.write_all_at(&table, header_bytes.len() as u64)
            .map_err(io("write the table"))?;
        file.write_all_at(&header_bytes, 0)
            .map_err(io("write the header"))?;
        file.sync_all().map_err(io("sync"))
    })();
    drop(file);
    commit_partial(LEVEL_STORE, &partial, path, result)?;
    Ok(LevelWriteSummary {
        path: path.to_path_buf(),
        header,
        elapsed: start.elapsed(),
    })
}
