//! Opening a brick store and reading brick levels with positioned reads.

use super::format::{
    brick_crc, format_error, parse_header, parse_tables, StoreHeader, HEADER_SIZE,
    OFFSET_ENTRY_BYTES, RANGE_ENTRY_BYTES,
};
use super::StoreError;
use super::BRICK_STORE;
use crate::bricks::{BrickGrid, DownsampleFilter, Level, ValueRange};
use crate::volume::ScalarType;
use glam::Vec3;
use std::fs::File;
use std::io::ErrorKind;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// An open, validated brick store file (the on-disk counterpart of the in-memory
/// [`crate::bricks::PackedBricks`]).
///
/// Holds the header, the per-brick value ranges and the offset table in RAM (32 bytes per
/// brick); brick texels stay on disk until [`BrickStore::read_brick`] reads one level of one brick
/// with one positioned read. `&self` methods are safe to call from several threads at once.
#[derive(Debug)]
pub struct BrickStore {
    path: PathBuf,
    file: File,
    header: StoreHeader,
    grid: BrickGrid,
    ranges: Vec<ValueRange>,
    offsets: Vec<[u64; 2]>,
    crcs: Vec<[u32; 2]>,
}

impl BrickStore {
    /// Opens the store at `path` and validates its header and tables (see
    /// [`super::format::parse_header`] and [`super::format::parse_tables`]): any inconsistency is a
    /// [`StoreError::Format`] naming the field, an OS failure a [`StoreError::Io`].
    pub fn open(path: impl AsRef<Path>) -> Result<Self, StoreError> {
        let path = path.as_ref().to_path_buf();
        let io = |action: &'static str| {
            let p = path.clone();
            move |source| StoreError::Io {
                kind: BRICK_STORE,
                path: p,
                action,
                source,
            }
        };
        let (file, len) = open_regular_file(&path, BRICK_STORE)?;
        let mut header_bytes = [0u8; HEADER_SIZE];
        let head_len = (len.min(HEADER_SIZE as u64)) as usize;
        file.read_exact_at(&mut header_bytes[..head_len], 0)
            .map_err(io("read header"))?;
        let header = parse_header(&header_bytes[..head_len], len, &path)?;
        // parse_header checked that both tables lie inside the file (whose length it verified),
        // so these allocations are bounded by the file size.
        let count = u64::from(header.brick_count);
        let mut ranges_bytes = vec![0u8; (count * RANGE_ENTRY_BYTES) as usize];
        let mut offsets_bytes = vec![0u8; (count * OFFSET_ENTRY_BYTES) as usize];
        file.read_exact_at(&mut ranges_bytes, header.ranges_offset)
            .map_err(io("read value ranges"))?;
        file.read_exact_at(&mut offsets_bytes, header.offsets_offset)
            .map_err(io("read offsets"))?;
        let tables = parse_tables(&header, &header_bytes, &ranges_bytes, &offsets_bytes, &path)?;
        let grid = BrickGrid::new(header.dims, header.brick_size)
            .map_err(|e| format_error(BRICK_STORE, &path, "dims", e.to_string()))?;
        Ok(Self {
            path,
            file,
            header,
            grid,
            ranges: tables.ranges,
            offsets: tables.offsets,
            crcs: tables.crcs,
        })
    }

    /// The file this store was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The validated header.
    pub fn header(&self) -> &StoreHeader {
        &self.header
    }

    /// The brick grid.
    pub fn grid(&self) -> BrickGrid {
        self.grid
    }

    /// Storage scalar type of the brick texels.
    pub fn scalar(&self) -> ScalarType {
        self.header.scalar
    }

    /// Filter that built the low-res bricks.
    pub fn filter(&self) -> DownsampleFilter {
        self.header.filter
    }

    /// Physical voxel spacing.
    pub fn spacing(&self) -> Vec3 {
        self.header.spacing
    }

    /// Number of bricks.
    pub fn brick_count(&self) -> u32 {
        self.header.brick_count
    }

    /// Per-brick conservative value ranges (indexed by linear brick index), as
    /// [`crate::bricks::brick_value_ranges_for_storage`] defines them for the store's scalar type.
    pub fn value_ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    /// Smallest and largest stored voxel value of the whole volume.
    pub fn value_range(&self) -> ValueRange {
        self.header.value_range
    }

    /// Bytes of one brick at `level` (0 for `Absent`).
    pub fn level_bytes(&self, level: Level) -> usize {
        match level {
            Level::Hi => self.header.hi_brick_bytes as usize,
            Level::Lo => self.header.lo_brick_bytes as usize,
            Level::Absent => 0,
        }
    }

    /// Absolute file offset of `brick` at `level`, after checking both.
    pub fn level_offset(&self, brick: u32, level: Level) -> Result<u64, StoreError> {
        let entry = self
            .offsets
            .get(brick as usize)
            .ok_or(StoreError::BrickOutOfRange {
                brick,
                count: self.header.brick_count,
            })?;
        match level {
            Level::Hi => Ok(entry[0]),
            Level::Lo => Ok(entry[1]),
            Level::Absent => Err(StoreError::AbsentLevel { brick }),
        }
    }

    /// Reads `brick` at `level`: `(n+2)^3` (Hi) or `(n/2+1)^3` (Lo) texels of the storage type, x
    /// fastest, native-endian (what [`crate::bricks::quantize_to`] returns), with one positioned
    /// read. A failed read (a file cut after opening) is a [`StoreError::Io`] whose message names
    /// the brick, the level and the byte range; bytes that do not match the level's recorded
    /// CRC-32 are a [`StoreError::BrickChecksum`] naming the brick and the level.
    pub fn read_brick(&self, brick: u32, level: Level) -> Result<Vec<u8>, StoreError> {
        let mut out = vec![0u8; self.level_bytes(level)];
        self.read_brick_into(brick, level, &mut out)?;
        Ok(out)
    }

    /// [`BrickStore::read_brick`] into `out`, which must be exactly
    /// [`BrickStore::level_bytes`]`(level)` long.
    pub fn read_brick_into(
        &self,
        brick: u32,
        level: Level,
        out: &mut [u8],
    ) -> Result<(), StoreError> {
        let offset = self.level_offset(brick, level)?;
        if out.len() != self.level_bytes(level) {
            return Err(StoreError::Io {
                kind: BRICK_STORE,
                path: self.path.clone(),
                action: "read brick",
                source: std::io::Error::new(
                    ErrorKind::InvalidInput,
                    format!(
                        "buffer of {} bytes for a {level:?} brick of {} bytes",
                        out.len(),
                        self.level_bytes(level)
                    ),
                ),
            });
        }
        self.file
            .read_exact_at(out, offset)
            .map_err(|source| StoreError::Io {
                kind: BRICK_STORE,
                path: self.path.clone(),
                action: "read brick",
                // The OS error, with the brick it happened on.
                source: std::io::Error::new(
                    source.kind(),
                    format!(
                        "brick {brick} level {level:?} (bytes {offset}..{}): {source}",
                        offset + out.len() as u64
                    ),
                ),
            })?;
        let stored = self.crcs[brick as usize][usize::from(level == Level::Lo)];
        let computed = brick_crc(out);
        if computed != stored {
            return Err(StoreError::BrickChecksum {
                path: self.path.clone(),
                brick,
                level,
                stored,
                computed,
            });
        }
        le_to_native(out, self.header.scalar);
        Ok(())
    }
}

/// Converts little-endian texels to native-endian in place (a no-op on little-endian hosts).
fn le_to_native(bytes: &mut [u8], scalar: ScalarType) {
    if cfg!(target_endian = "big") {
        let size = scalar.size_bytes();
        if size > 1 {
            for texel in bytes.chunks_exact_mut(size) {
                texel.reverse();
            }
        }
    }
}

/// Opens `path`, which must be a regular file (`kind` names it in the error:
/// [`BRICK_STORE`], [`LEVEL_STORE`](super::LEVEL_STORE)), checking the type first (opening a
/// FIFO would block); returns the file and its length.
pub(super) fn open_regular_file(
    path: &Path,
    kind: &'static str,
) -> Result<(File, u64), StoreError> {
    let io = |action: &'static str| {
        move |source| StoreError::Io {
            kind,
            path: path.to_path_buf(),
            action,
            source,
        }
    };
    let meta = std::fs::metadata(path).map_err(io("open"))?;
    if !meta.is_file() {
        return Err(io("open")(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file (a folder, FIFO or device); a {kind} is a regular file"),
        )));
    }
    let file = File::open(path).map_err(io("open"))?;
    let len = file.metadata().map_err(io("stat"))?.len();
    Ok((file, len))
}
