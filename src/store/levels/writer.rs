//! Writing a level store from an in-memory volume: every level of its vertex pyramid, packed as
//! the three-level cache stores it, into `<path>.partial`, renamed into place once complete.

use super::format::{
    canonical_level_header, encode_level_header, encode_level_table, finish_level_checksum,
    stored_per_level, LevelEntry, LevelStoreHeader,
};
use crate::bricks::{dequantize, quantize_to, BrickGrid, ValueRange};
use crate::cache::{min_brick_size_for_levels, pyramid_levels, stored_bricks_per_axis};
use crate::reference::{LevelGrid, SamplePlacement};
use crate::store::format::brick_crc;
use crate::store::writer::partial_path;
use crate::store::StoreError;
use crate::volume::Volume;
use glam::UVec3;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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

/// The levels a level store of `volume` in bricks of `brick_size` gets by default: levels 0-2
/// and the block levels up to one block covering the grid's longest axis
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

/// Writes every level of `volume` (levels `0..levels`; `None`: [`default_store_levels`]) as a
/// level store at `path`: level 0 its normalised voxels, each coarser level the vertex level
/// downsampled from the one before ([`LevelGrid::downsampled`]), every stored brick exactly the
/// texels [`LevelGrid::stored_brick`] gives, in the volume's scalar type. `progress(done,
/// total)` is called after every stored brick.
///
/// RAM: the volume plus two adjacent levels as f32 (about 4.5 bytes per voxel at the peak);
/// the texels stream to disk level by level. The file is assembled as `<path>.partial` and
/// renamed to `path` only once complete; on any error the partial file is removed.
///
/// Errors: a brick size the volume cannot be bricked with, a level count outside
/// `1..=31` or past what the brick size takes ([`min_brick_size_for_levels`]), a volume too large
/// for the format, or an OS failure.
pub fn write_level_store(
    path: &Path,
    volume: &Volume,
    brick_size: u32,
    levels: Option<u32>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<LevelWriteSummary, StoreError> {
    let start = Instant::now();
    let grid = brick_grid(volume.dims(), brick_size)?;
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
    let (min, max) = volume.value_range();
    let value_range = ValueRange { min, max };
    let scalar = volume.scalar_type();
    let header = canonical_level_header(&grid, levels, scalar, volume.spacing(), value_range)
        .ok_or_else(|| StoreError::InvalidDesc {
            field: "dims",
            message: format!(
                "{:?} in bricks of {brick_size} with {levels} levels overflows the format",
                volume.dims().to_array()
            ),
        })?;
    let partial = partial_path(path);
    let io = |action: &'static str| {
        let p = partial.clone();
        move |source| StoreError::Io {
            path: p,
            action,
            source,
        }
    };
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(&partial)
        .map_err(io("create"))?;
    let result = (|| {
        let entries = write_texels(&file, &grid, volume, &header, progress)
            .map_err(|(action, source)| io(action)(source))?;
        let table = encode_level_table(&entries);
        let mut header_bytes = encode_level_header(&header);
        finish_level_checksum(&mut header_bytes, &table);
        file.write_all_at(&table, header_bytes.len() as u64)
            .map_err(io("write the table"))?;
        file.write_all_at(&header_bytes, 0)
            .map_err(io("write the header"))?;
        file.sync_all().map_err(io("sync"))
    })();
    drop(file);
    if let Err(e) = result {
        // Best effort: the partial file is useless (its header is zero until the very end).
        let _ = std::fs::remove_file(&partial);
        return Err(e);
    }
    std::fs::rename(&partial, path).map_err(|source| {
        let _ = std::fs::remove_file(&partial);
        StoreError::Io {
            path: path.to_path_buf(),
            action: "rename the finished level store into place",
            source,
        }
    })?;
    Ok(LevelWriteSummary {
        path: path.to_path_buf(),
        header,
        elapsed: start.elapsed(),
    })
}

/// Writes every stored brick from `header.data_offset` on, level by level (one level and the
/// next in RAM at a time), and returns the table.
fn write_texels(
    file: &File,
    grid: &BrickGrid,
    volume: &Volume,
    header: &LevelStoreHeader,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Vec<LevelEntry>, (&'static str, std::io::Error)> {
    let mut out = BufWriter::with_capacity(1 << 20, file);
    out.seek(SeekFrom::Start(header.data_offset))
        .map_err(|e| ("seek to the texels", e))?;
    let total: u64 = stored_per_level(grid, header.levels).iter().sum();
    let mut entries = Vec::with_capacity(total as usize);
    let mut offset = header.data_offset;
    let n = grid.brick_size();
    let mut level_grid = LevelGrid::from_volume(volume);
    for level in 0..header.levels {
        if level > 0 {
            level_grid = level_grid.downsampled(SamplePlacement::Vertex, volume.dims());
        }
        let stored = stored_bricks_per_axis(grid.bricks_per_axis(), level);
        let block = crate::cache::block_bricks(level);
        for z in 0..stored.z {
            for y in 0..stored.y {
                for x in 0..stored.x {
                    let first = UVec3::new(x, y, z) * block;
                    let bytes = quantize_to(&level_grid.stored_brick(first, n), header.scalar);
                    let range = ValueRange::of(&dequantize(&bytes, header.scalar));
                    out.write_all(&bytes)
                        .map_err(|e| ("write stored bricks", e))?;
                    entries.push(LevelEntry {
                        offset,
                        crc: brick_crc(&bytes),
                        range,
                    });
                    offset += bytes.len() as u64;
                    progress(entries.len() as u64, total);
                }
            }
        }
    }
    out.flush().map_err(|e| ("write stored bricks", e))?;
    debug_assert_eq!(offset, header.file_size);
    Ok(entries)
}
