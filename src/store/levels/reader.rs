//! Opening a level store and reading stored bricks with positioned reads.

use super::format::{
    parse_header, parse_table, stored_per_level, LevelEntry, LevelStoreHeader, LEVEL_ENTRY_BYTES,
    LEVEL_HEADER_SIZE,
};
use crate::bricks::{dequantize, BrickGrid, ValueRange};
use crate::cache::{block_bricks, block_origin, stored_brick_edge, stored_bricks_per_axis};
use crate::pyramid::{LevelGrid, SamplePlacement};
use crate::store::format::{brick_crc, format_error};
use crate::store::reader::open_regular_file;
use crate::store::StoreError;
use crate::store::LEVEL_STORE;
use crate::volume::formats::{RemoteObject, RemoteOptions};
use glam::{IVec3, UVec3};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// An open, checked level store: every level of a volume as the three-level cache stores it
/// (format in [`super::format`]). The header and the table (24 bytes per stored brick) stay in
/// RAM; texels are read one stored brick at a time ([`LevelStore::read_stored`]). `&self`
/// methods are safe to call from several threads at once.
#[derive(Debug)]
pub struct LevelStore {
    path: PathBuf,
    source: Source,
    header: LevelStoreHeader,
    grid: BrickGrid,
    entries: Vec<LevelEntry>,
    /// Index of each level's first entry.
    level_starts: Vec<usize>,
}

/// Where a level store's bytes are read from.
#[derive(Debug)]
enum Source {
    /// A local file (positioned reads).
    Local(File),
    /// An object on S3 or behind HTTP (range requests).
    Remote(RemoteObject),
}

impl LevelStore {
    /// Opens the level store at `path` and checks its header and table: any inconsistency is a
    /// [`StoreError::Format`] naming the field, an OS failure a [`StoreError::Io`].
    pub fn open(path: impl AsRef<Path>) -> Result<Self, StoreError> {
        let path = path.as_ref().to_path_buf();
        let (file, len) = open_regular_file(&path, LEVEL_STORE)?;
        Self::open_source(path, Source::Local(file), len)
    }

    /// Opens the level store at `url` (`s3://BUCKET/PATH/STORE.mvl` with the AWS environment,
    /// or `http(s)://HOST/PATH/STORE.mvl`, fetched with range requests as `options` says) and
    /// checks its header and table as [`LevelStore::open`] does; every stored brick is then
    /// one range request. A failed request is a [`StoreError::Remote`] naming the URL.
    pub fn open_remote(url: &str, options: &RemoteOptions) -> Result<Self, StoreError> {
        let object = RemoteObject::open(url, options).map_err(|source| StoreError::Remote {
            url: url.to_string(),
            action: "open",
            source: Box::new(source),
        })?;
        let len = object.size().map_err(|source| StoreError::Remote {
            url: url.to_string(),
            action: "ask for its size",
            source: Box::new(source),
        })?;
        Self::open_source(PathBuf::from(url), Source::Remote(object), len)
    }

    /// Reads and checks the header and the table of the `len` bytes of `source`.
    fn open_source(path: PathBuf, source: Source, len: u64) -> Result<Self, StoreError> {
        let mut header_bytes = [0u8; LEVEL_HEADER_SIZE];
        let head_len = len.min(LEVEL_HEADER_SIZE as u64) as usize;
        read_at(
            &source,
            &path,
            &mut header_bytes[..head_len],
            0,
            "read header",
        )?;
        let header = parse_header(&header_bytes[..head_len], len, &path)?;
        // parse_header checked that the table ends before the texels, inside the file.
        let mut table = vec![0u8; (header.stored_count * LEVEL_ENTRY_BYTES) as usize];
        read_at(
            &source,
            &path,
            &mut table,
            LEVEL_HEADER_SIZE as u64,
            "read the table",
        )?;
        let entries = parse_table(&header, &header_bytes, &table, &path)?;
        let grid = header
            .grid()
            .ok_or_else(|| format_error(LEVEL_STORE, &path, "dims", "cannot brick".into()))?;
        let mut level_starts = vec![0];
        for count in stored_per_level(&grid, header.levels) {
            level_starts.push(level_starts[level_starts.len() - 1] + count as usize);
        }
        Ok(Self {
            path,
            source,
            header,
            grid,
            entries,
            level_starts,
        })
    }

    /// The file (or URL) this store was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The checked header.
    pub fn header(&self) -> &LevelStoreHeader {
        &self.header
    }

    /// The brick grid of level 0.
    pub fn grid(&self) -> BrickGrid {
        self.grid
    }

    /// Levels stored (0 up to this, exclusive).
    pub fn level_count(&self) -> u32 {
        self.header.levels
    }

    /// The filter that built level 1 from level 0 (`Mean2` for stores written before the
    /// header recorded it).
    pub fn filter(&self) -> crate::bricks::DownsampleFilter {
        self.header.filter
    }

    /// The table entry of the stored brick of `level` holding brick `brick` (any brick of its
    /// block).
    fn entry(&self, level: u32, brick: UVec3) -> Result<(usize, &LevelEntry), StoreError> {
        let bricks = self.grid.bricks_per_axis();
        if level >= self.header.levels || brick.cmpge(bricks).any() {
            return Err(StoreError::LevelOutOfRange {
                level,
                brick: brick.to_array(),
                levels: self.header.levels,
                bricks: bricks.to_array(),
            });
        }
        let s = stored_bricks_per_axis(bricks, level);
        let b = block_origin(brick, level) / block_bricks(level);
        let index = self.level_starts[level as usize] + (b.x + s.x * (b.y + s.y * b.z)) as usize;
        Ok((index, &self.entries[index]))
    }

    /// The smallest and largest texel of the stored brick of `level` that holds brick `brick`:
    /// the range of the samples that brick draws at that level before the fixups.
    pub fn stored_range(&self, level: u32, brick: UVec3) -> Result<ValueRange, StoreError> {
        Ok(self.entry(level, brick)?.1.range)
    }

    /// The texels of the stored brick of `level` that holds brick `brick` (any brick of its
    /// block), normalised to f32, `stored_brick_edge(n, level)^3` of them, x fastest: what
    /// [`LevelGrid::stored_brick`] gives for the block's first brick, in the store's scalar type.
    /// One positioned read; the bytes are checked against their CRC-32.
    pub fn read_stored(&self, level: u32, brick: UVec3) -> Result<Vec<f32>, StoreError> {
        Ok(dequantize(
            &self.read_stored_bytes(level, brick)?,
            self.header.scalar,
        ))
    }

    /// The stored brick of `level` that holds brick `brick`, as the file keeps it: texels of
    /// the store's scalar type, little-endian ([`LevelStoreHeader::stored_bytes`] of them),
    /// checked against their CRC-32. [`LevelStore::read_stored`] normalises them.
    pub fn read_stored_bytes(&self, level: u32, brick: UVec3) -> Result<Vec<u8>, StoreError> {
        let (index, entry) = self.entry(level, brick)?;
        let mut bytes = vec![0u8; self.header.stored_bytes(level) as usize];
        read_at(
            &self.source,
            &self.path,
            &mut bytes,
            entry.offset,
            "read a stored brick",
        )?;
        let computed = brick_crc(&bytes);
        if computed != entry.crc {
            return Err(StoreError::StoredBrickChecksum {
                path: self.path.clone(),
                level,
                entry: index,
                stored: entry.crc,
                computed,
            });
        }
        Ok(bytes)
    }

    /// Every level's samples put back together from the stored bricks (normalised, level 0
    /// cell-centred, the others on vertices): the grids the store was written from, after the
    /// scalar type's rounding. Reads the whole store; RAM about 4.6 bytes per voxel. For the
    /// CPU reference and for checks, not for drawing.
    pub fn read_grids(&self) -> Result<Vec<LevelGrid>, StoreError> {
        assemble_grids(
            &self.grid,
            self.header.levels,
            |level, first| self.read_stored(level, first),
            |message| format_error(LEVEL_STORE, &self.path, "dims", message),
        )
    }
}

/// Every level's samples put back together from the stored bricks of a `levels`-level
/// pyramid over `grid` that `read(level, first brick)` returns (normalised, x fastest):
/// [`LevelStore::read_grids`] and [`super::LevelBackend::read_grids`]. `bad_dims` makes the
/// error of a level grid that cannot be built.
pub(crate) fn assemble_grids<E>(
    grid: &BrickGrid,
    levels: u32,
    mut read: impl FnMut(u32, UVec3) -> Result<Vec<f32>, E>,
    bad_dims: impl Fn(String) -> E,
) -> Result<Vec<LevelGrid>, E> {
    let n = grid.brick_size();
    let dims = grid.dims();
    let bricks = grid.bricks_per_axis();
    let mut grids = Vec::with_capacity(levels as usize);
    for level in 0..levels {
        let placement = if level == 0 {
            SamplePlacement::CellCentred
        } else {
            SamplePlacement::Vertex
        };
        let gdims = LevelGrid::covering_dims(level, placement, dims);
        let mut values = vec![0.0f32; gdims.element_product() as usize];
        let edge = stored_brick_edge(n, level) as i32;
        // Level 0's stored bricks overlap by their borders: only the n^3 inside is taken.
        let (skip, keep) = if level == 0 { (2, n as i32) } else { (0, edge) };
        let stored = stored_bricks_per_axis(bricks, level);
        let block = block_bricks(level);
        for z in 0..stored.z {
            for y in 0..stored.y {
                for x in 0..stored.x {
                    let first = UVec3::new(x, y, z) * block;
                    let texels = read(level, first)?;
                    let start = crate::cache::stored_first_sample(first, n, level);
                    for t in iter_box(keep) {
                        let j = start + t + IVec3::splat(skip);
                        if j.cmplt(IVec3::ZERO).any() || j.cmpge(gdims.as_ivec3()).any() {
                            continue;
                        }
                        let u = t + IVec3::splat(skip);
                        let src = (u.x + edge * (u.y + edge * u.z)) as usize;
                        let dst =
                            (j.x as u32 + gdims.x * (j.y as u32 + gdims.y * j.z as u32)) as usize;
                        values[dst] = texels[src];
                    }
                }
            }
        }
        grids.push(
            LevelGrid::new(level, placement, gdims, values).map_err(|e| bad_dims(e.to_string()))?,
        );
    }
    Ok(grids)
}

/// Fills `buf` from byte `offset` of `source` (the store at `path`, for messages).
fn read_at(
    source: &Source,
    path: &Path,
    buf: &mut [u8],
    offset: u64,
    action: &'static str,
) -> Result<(), StoreError> {
    match source {
        Source::Local(file) => file
            .read_exact_at(buf, offset)
            .map_err(|source| StoreError::Io {
                kind: LEVEL_STORE,
                path: path.to_path_buf(),
                action,
                source,
            }),
        Source::Remote(object) => {
            object
                .read_exact_at(buf, offset)
                .map_err(|source| StoreError::Remote {
                    url: object.url().to_string(),
                    action,
                    source: Box::new(source),
                })
        }
    }
}

/// Every point of the box `0..edge` per axis, x fastest.
fn iter_box(edge: i32) -> impl Iterator<Item = IVec3> {
    (0..edge)
        .flat_map(move |z| (0..edge).flat_map(move |y| (0..edge).map(move |x| IVec3::new(x, y, z))))
}
