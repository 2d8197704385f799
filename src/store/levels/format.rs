//! The level store file format, version 1 (specified byte by byte in `docs/brick-store.md`,
//! "Level stores").
//!
//! ```text
//! [0, 128)                         header (little-endian, see LevelStoreHeader / the docs)
//! [128, 128 + 24*stored_count)     per stored brick, level by level, each level's blocks in
//!                                  linear order (x fastest): offset u64, crc32 u32, min f32,
//!                                  max f32, reserved u32 (zero)
//! [data_offset, file_size)         the stored bricks' texels
//! ```
//!
//! A stored brick is what the three-level cache uploads for it (`crate::cache::slot_geometry`):
//! `stored_brick_edge(n, k)^3` texels of level `k` from `stored_first_sample`, clamped to the
//! level's grid, in the store's scalar type (`u8` / `u16` UNORM or `f32`), x fastest. Levels 0-2
//! store one brick per brick; a block level `k > 2` one per aligned block of
//! `block_bricks(k)^3` bricks. `min`/`max` are the brick's smallest and largest texel as read
//! back. The header and the table are covered by a 64-bit FNV-1a checksum, each stored brick by
//! its CRC-32, checked on every read.
//!
//! [`parse_header`] and [`parse_table`] check every field with checked arithmetic and name the
//! field at fault in [`StoreError::Format`]; they never panic on any input.

use super::super::format::{
    filter_id, format_error, le_f32, le_u32, le_u64, parse_filter_field, scalar_from_id, scalar_id,
    Fnv1a,
};
use super::super::StoreError;
use crate::bricks::{BrickGrid, DownsampleFilter, ValueRange, MAX_BRICK_SIZE};
use crate::cache::{min_brick_size_for_levels, stored_brick_edge, stored_bricks_per_axis};
use crate::store::LEVEL_STORE;
use crate::volume::ScalarType;
use glam::{UVec3, Vec3};
use std::path::Path;

/// The 8 magic bytes every level store starts with.
pub const LEVEL_MAGIC: [u8; 8] = *b"MIXVOLLV";

/// The level store format version this crate writes and reads.
pub const LEVEL_FORMAT_VERSION: u32 = 1;

/// Bytes of the fixed header.
pub const LEVEL_HEADER_SIZE: usize = 128;

/// Bytes per stored brick of the table.
pub const LEVEL_ENTRY_BYTES: u64 = 24;

/// The writer aligns the start of the texels to this many bytes.
const DATA_ALIGNMENT: u64 = 4096;

/// Byte offset of the checksum field; it covers `[0, CHECKSUM_OFFSET)` plus the table.
const CHECKSUM_OFFSET: usize = 120;

/// Everything the fixed header of a level store holds.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LevelStoreHeader {
    /// Volume extent in voxels.
    pub dims: UVec3,
    /// Brick edge `n` in voxels.
    pub brick_size: u32,
    /// Levels stored (0 up to this, exclusive).
    pub levels: u32,
    /// Storage scalar type of the texels.
    pub scalar: ScalarType,
    /// Physical voxel spacing.
    pub spacing: Vec3,
    /// Smallest and largest normalised voxel value of the volume.
    pub value_range: ValueRange,
    /// The filter that built level 1 from level 0 (every coarser level is the pyramid's tent
    /// or mean, `crate::pyramid::LevelGrid::downsampled`). Bytes `[92, 96)`, zero (`Mean2`)
    /// in every store written before the field existed.
    pub filter: DownsampleFilter,
    /// Stored bricks over all levels.
    pub stored_count: u64,
    /// Absolute offset of the first stored brick's texels.
    pub data_offset: u64,
    /// Length of the file in bytes.
    pub file_size: u64,
}

impl LevelStoreHeader {
    /// The brick grid of level 0.
    pub fn grid(&self) -> Option<BrickGrid> {
        BrickGrid::new(self.dims, self.brick_size).ok()
    }

    /// Bytes of one stored brick of `level`.
    pub fn stored_bytes(&self, level: u32) -> u64 {
        u64::from(stored_brick_edge(self.brick_size, level)).pow(3)
            * self.scalar.size_bytes() as u64
    }
}

/// Stored bricks of every level for `grid` and `levels` levels, in table order.
pub fn stored_per_level(grid: &BrickGrid, levels: u32) -> Vec<u64> {
    (0..levels)
        .map(|k| {
            let s = stored_bricks_per_axis(grid.bricks_per_axis(), k);
            u64::from(s.x) * u64::from(s.y) * u64::from(s.z)
        })
        .collect()
}

/// The header a writer produces (table right after the header, texels aligned to 4 KiB, stored
/// bricks back to back in table order). `None` when a size overflows `u64`.
pub fn canonical_level_header(
    grid: &BrickGrid,
    levels: u32,
    scalar: ScalarType,
    spacing: Vec3,
    value_range: ValueRange,
    filter: DownsampleFilter,
) -> Option<LevelStoreHeader> {
    let per_level = stored_per_level(grid, levels);
    let stored_count = per_level.iter().try_fold(0u64, |a, &c| a.checked_add(c))?;
    let table_end =
        (LEVEL_HEADER_SIZE as u64).checked_add(stored_count.checked_mul(LEVEL_ENTRY_BYTES)?)?;
    let data_offset = table_end.checked_next_multiple_of(DATA_ALIGNMENT)?;
    let mut header = LevelStoreHeader {
        dims: grid.dims(),
        brick_size: grid.brick_size(),
        levels,
        scalar,
        spacing,
        value_range,
        filter,
        stored_count,
        data_offset,
        file_size: 0,
    };
    let mut size = data_offset;
    for (k, count) in per_level.iter().enumerate() {
        size = size.checked_add(count.checked_mul(header.stored_bytes(k as u32))?)?;
    }
    header.file_size = size;
    Some(header)
}

/// One stored brick's table entry.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LevelEntry {
    /// Absolute file offset of its texels.
    pub offset: u64,
    /// CRC-32 of its bytes.
    pub crc: u32,
    /// Its smallest and largest texel as read back.
    pub range: ValueRange,
}

/// Encodes the header; bytes `[120, 128)` (the checksum) are left zero, see
/// [`finish_level_checksum`].
pub fn encode_level_header(h: &LevelStoreHeader) -> [u8; LEVEL_HEADER_SIZE] {
    let mut out = Vec::with_capacity(LEVEL_HEADER_SIZE);
    out.extend_from_slice(&LEVEL_MAGIC);
    out.extend_from_slice(&LEVEL_FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(LEVEL_HEADER_SIZE as u32).to_le_bytes());
    for v in h.dims.to_array() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&h.brick_size.to_le_bytes());
    out.extend_from_slice(&h.levels.to_le_bytes());
    out.extend_from_slice(&scalar_id(h.scalar).to_le_bytes());
    for v in h.spacing.to_array() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&h.value_range.min.to_le_bytes());
    out.extend_from_slice(&h.value_range.max.to_le_bytes());
    out.extend_from_slice(&h.stored_count.to_le_bytes());
    out.extend_from_slice(&(LEVEL_HEADER_SIZE as u64).to_le_bytes());
    out.extend_from_slice(&h.data_offset.to_le_bytes());
    out.extend_from_slice(&h.file_size.to_le_bytes());
    out.extend_from_slice(&filter_id(h.filter).to_le_bytes());
    debug_assert_eq!(out.len(), 96);
    out.resize(LEVEL_HEADER_SIZE, 0);
    let mut bytes = [0u8; LEVEL_HEADER_SIZE];
    bytes.copy_from_slice(&out);
    bytes
}

/// Encodes the table.
pub fn encode_level_table(entries: &[LevelEntry]) -> Vec<u8> {
    let mut out = Vec::with_capacity(entries.len() * LEVEL_ENTRY_BYTES as usize);
    for e in entries {
        out.extend_from_slice(&e.offset.to_le_bytes());
        out.extend_from_slice(&e.crc.to_le_bytes());
        out.extend_from_slice(&e.range.min.to_le_bytes());
        out.extend_from_slice(&e.range.max.to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
    }
    out
}

/// The checksum of an encoded header (bytes `[0, 120)`) and the encoded table.
pub fn level_checksum(header: &[u8; LEVEL_HEADER_SIZE], table: &[u8]) -> u64 {
    let mut h = Fnv1a::default();
    h.update(&header[..CHECKSUM_OFFSET]);
    h.update(table);
    h.finish()
}

/// Stores the checksum of `header` + `table` into header bytes `[120, 128)`.
pub fn finish_level_checksum(header: &mut [u8; LEVEL_HEADER_SIZE], table: &[u8]) {
    let sum = level_checksum(header, table);
    header[CHECKSUM_OFFSET..].copy_from_slice(&sum.to_le_bytes());
}

/// Parses and checks the fixed header. `actual_len` is the file's length on disk.
///
/// Checks, in order (each failure names its field): `magic`, `version`, `header_size`, `dims`,
/// `brick_size`, `levels`, `scalar`, `spacing`, `value_range`, `stored_count`, `table_offset`,
/// `data_offset`, `file_size`, `filter`. The checksum is checked with the table ([`parse_table`]).
pub fn parse_header(
    bytes: &[u8],
    actual_len: u64,
    path: &Path,
) -> Result<LevelStoreHeader, StoreError> {
    let err =
        |field: &'static str, message: String| format_error(LEVEL_STORE, path, field, message);
    if bytes.len() < LEVEL_MAGIC.len() || bytes[..LEVEL_MAGIC.len()] != LEVEL_MAGIC {
        return Err(err(
            "magic",
            format!(
                "expected the 8 bytes {:?} of a level store, found {:?}",
                String::from_utf8_lossy(&LEVEL_MAGIC),
                String::from_utf8_lossy(&bytes[..bytes.len().min(LEVEL_MAGIC.len())])
            ),
        ));
    }
    if bytes.len() < LEVEL_HEADER_SIZE {
        return Err(err(
            "header_size",
            format!(
                "file holds {} bytes but the header needs {LEVEL_HEADER_SIZE}",
                bytes.len()
            ),
        ));
    }
    let version = le_u32(bytes, 8);
    if version != LEVEL_FORMAT_VERSION {
        return Err(err(
            "version",
            format!("unsupported level store version {version}; this build reads version {LEVEL_FORMAT_VERSION}"),
        ));
    }
    let header_size = le_u32(bytes, 12);
    if header_size as usize != LEVEL_HEADER_SIZE {
        return Err(err(
            "header_size",
            format!("is {header_size}; version {LEVEL_FORMAT_VERSION} headers are {LEVEL_HEADER_SIZE} bytes"),
        ));
    }
    let dims = UVec3::new(le_u32(bytes, 16), le_u32(bytes, 20), le_u32(bytes, 24));
    if dims.min_element() == 0 {
        return Err(err(
            "dims",
            format!("{:?} has a zero axis", dims.to_array()),
        ));
    }
    let brick_size = le_u32(bytes, 28);
    if !brick_size.is_power_of_two() || !(2..=MAX_BRICK_SIZE).contains(&brick_size) {
        return Err(err(
            "brick_size",
            format!("{brick_size} is not a power of two in 2..={MAX_BRICK_SIZE}"),
        ));
    }
    let levels = le_u32(bytes, 32);
    if !(1..=31).contains(&levels) || brick_size < min_brick_size_for_levels(levels) {
        return Err(err(
            "levels",
            format!(
                "{levels} levels with bricks of {brick_size} (1..=31 levels; more than 3 need \
                 bricks of at least 8 voxels, up to 3 need 2^(levels - 1))"
            ),
        ));
    }
    let scalar_raw = le_u32(bytes, 36);
    let scalar = scalar_from_id(scalar_raw).ok_or_else(|| {
        err(
            "scalar",
            format!("unknown scalar type id {scalar_raw} (0 = u8, 1 = u16, 2 = f32)"),
        )
    })?;
    let spacing = Vec3::new(le_f32(bytes, 40), le_f32(bytes, 44), le_f32(bytes, 48));
    if !(spacing.is_finite() && spacing.min_element() > 0.0) {
        return Err(err(
            "spacing",
            format!("{:?} must be positive and finite", spacing.to_array()),
        ));
    }
    let value_range = ValueRange {
        min: le_f32(bytes, 52),
        max: le_f32(bytes, 56),
    };
    if !(value_range.min.is_finite() && value_range.max.is_finite())
        || value_range.min > value_range.max
    {
        return Err(err(
            "value_range",
            format!(
                "[{}, {}] is not a finite range",
                value_range.min, value_range.max
            ),
        ));
    }
    let grid =
        BrickGrid::new(dims, brick_size).map_err(|e| err("dims", format!("cannot brick: {e}")))?;
    let filter = parse_filter_field(LEVEL_STORE, bytes, 92, path)?;
    let Some(expected) =
        canonical_level_header(&grid, levels, scalar, spacing, value_range, filter)
    else {
        return Err(err(
            "dims",
            format!(
                "{:?} with bricks of {brick_size} and {levels} levels overflow the format",
                dims.to_array()
            ),
        ));
    };
    let stored_count = le_u64(bytes, 60);
    if stored_count != expected.stored_count {
        return Err(err(
            "stored_count",
            format!(
                "is {stored_count}; the grid and {levels} levels give {}",
                expected.stored_count
            ),
        ));
    }
    let table_offset = le_u64(bytes, 68);
    if table_offset != LEVEL_HEADER_SIZE as u64 {
        return Err(err(
            "table_offset",
            format!("is {table_offset}; the table follows the header at {LEVEL_HEADER_SIZE}"),
        ));
    }
    let data_offset = le_u64(bytes, 76);
    let table_end = LEVEL_HEADER_SIZE as u64 + stored_count * LEVEL_ENTRY_BYTES;
    if data_offset < table_end {
        return Err(err(
            "data_offset",
            format!("{data_offset} overlaps the table, which ends at {table_end}"),
        ));
    }
    let file_size = le_u64(bytes, 84);
    if file_size != actual_len {
        return Err(err(
            "file_size",
            format!(
                "header says {file_size} bytes but the file has {actual_len} (truncated or \
                 appended to)"
            ),
        ));
    }
    if file_size < data_offset {
        return Err(err(
            "file_size",
            format!("{file_size} ends before the texels start at {data_offset}"),
        ));
    }
    Ok(LevelStoreHeader {
        dims,
        brick_size,
        levels,
        scalar,
        spacing,
        value_range,
        filter,
        stored_count,
        data_offset,
        file_size,
    })
}

/// Parses and checks the table against `header`: the checksum over `header_bytes` and the
/// table, then every entry's texels inside `[data_offset, file_size)` and a finite range.
pub fn parse_table(
    header: &LevelStoreHeader,
    header_bytes: &[u8; LEVEL_HEADER_SIZE],
    table: &[u8],
    path: &Path,
) -> Result<Vec<LevelEntry>, StoreError> {
    let err =
        |field: &'static str, message: String| format_error(LEVEL_STORE, path, field, message);
    let expected_len = header.stored_count.saturating_mul(LEVEL_ENTRY_BYTES);
    if table.len() as u64 != expected_len {
        return Err(err(
            "stored_count",
            format!(
                "table of {} bytes for {} stored bricks",
                table.len(),
                header.stored_count
            ),
        ));
    }
    let stored = le_u64(header_bytes, CHECKSUM_OFFSET);
    let computed = level_checksum(header_bytes, table);
    if stored != computed {
        return Err(err(
            "table_checksum",
            format!(
                "header and table hash to {computed:#018x} but the store recorded {stored:#018x}"
            ),
        ));
    }
    let grid = header
        .grid()
        .ok_or_else(|| err("dims", "cannot brick".into()))?;
    let per_level = stored_per_level(&grid, header.levels);
    let mut entries = Vec::with_capacity(header.stored_count as usize);
    let mut at = 0usize;
    for (level, &count) in per_level.iter().enumerate() {
        let bytes = header.stored_bytes(level as u32);
        for i in 0..count {
            let e = &table[at..at + LEVEL_ENTRY_BYTES as usize];
            at += LEVEL_ENTRY_BYTES as usize;
            let entry = LevelEntry {
                offset: le_u64(e, 0),
                crc: le_u32(e, 8),
                range: ValueRange {
                    min: le_f32(e, 12),
                    max: le_f32(e, 16),
                },
            };
            let inside = entry.offset >= header.data_offset
                && entry
                    .offset
                    .checked_add(bytes)
                    .is_some_and(|end| end <= header.file_size);
            if !inside {
                return Err(err(
                    "offsets",
                    format!(
                        "level {level} brick {i}: {bytes} bytes at {} lie outside the texels \
                         [{}, {})",
                        entry.offset, header.data_offset, header.file_size
                    ),
                ));
            }
            let r = entry.range;
            if !(r.min.is_finite() && r.max.is_finite() && r.min <= r.max) {
                return Err(err(
                    "value_ranges",
                    format!(
                        "level {level} brick {i}: [{}, {}] is not a finite range",
                        r.min, r.max
                    ),
                ));
            }
            entries.push(entry);
        }
    }
    Ok(entries)
}
