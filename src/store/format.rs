//! The brick store file format, version 2 (specified byte by byte in `docs/brick-store.md`).
//!
//! ```text
//! [0, 128)                       header (little-endian, see StoreHeader / the docs)
//! [ranges_offset, +8*count)      per brick: min f32, max f32
//! [offsets_offset, +24*count)    per brick: hi_offset u64, lo_offset u64 (absolute file offsets),
//!                                hi_crc32 u32, lo_crc32 u32 (CRC-32 of each level's bytes)
//! [data_offset, file_size)       brick data: per brick the hi-res brick then the low-res brick
//! ```
//!
//! Every integer and float is little-endian. Brick texels are the storage scalar type
//! (`u8` / `u16` UNORM or `f32`), x fastest, little-endian. The header and both tables are covered
//! by a 64-bit FNV-1a checksum; every brick level by its CRC-32 (IEEE, as `crc32fast` computes
//! it), checked on every read, so a corrupt brick is an error naming the brick, never a wrong
//! image. A brick level is one positioned read of `hi_brick_bytes` / `lo_brick_bytes` at its
//! offset. Version 1 (no CRCs, 16-byte offset entries) is refused with a message to convert
//! again.
//!
//! [`parse_header`] and [`parse_tables`] validate every field with checked arithmetic and name the
//! field at fault in [`StoreError::Format`]; they never panic on any input.

use super::StoreError;
use super::BRICK_STORE;
use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, BrickGrid, DownsampleFilter, ValueRange,
    MAX_BRICK_SIZE,
};
use crate::volume::ScalarType;
use glam::{UVec3, Vec3};
use std::path::Path;

/// The 8 magic bytes every store starts with.
pub const MAGIC: [u8; 8] = *b"MIXVOLBS";

/// The format version this crate writes and reads.
pub const FORMAT_VERSION: u32 = 2;

/// Bytes of the fixed header.
pub const HEADER_SIZE: usize = 128;

/// Bytes per brick of the value-range table (min f32, max f32).
pub const RANGE_ENTRY_BYTES: u64 = 8;

/// Bytes per brick of the offset table (hi u64, lo u64, hi CRC-32 u32, lo CRC-32 u32).
pub const OFFSET_ENTRY_BYTES: u64 = 24;

/// The CRC-32 a store records for a brick level's (little-endian) bytes.
pub fn brick_crc(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// The writer aligns the start of the brick data to this many bytes.
pub const DATA_ALIGNMENT: u64 = 4096;

/// Byte offset of the checksum field; the checksum covers `[0, CHECKSUM_OFFSET)` plus the tables.
const CHECKSUM_OFFSET: usize = 120;

/// Everything the fixed header of a store holds (see `docs/brick-store.md` for the byte layout).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct StoreHeader {
    /// Format version (always [`FORMAT_VERSION`] after parsing).
    pub version: u32,
    /// Volume dimensions in voxels.
    pub dims: UVec3,
    /// Brick edge length `n`.
    pub brick_size: u32,
    /// Storage scalar type of the brick texels.
    pub scalar: ScalarType,
    /// Filter that built the low-res bricks.
    pub filter: DownsampleFilter,
    /// Physical voxel spacing.
    pub spacing: Vec3,
    /// Number of bricks, `prod(ceil(dims / n))`.
    pub brick_count: u32,
    /// Bytes of one packed hi-res brick: `(n+2)^3 * scalar size`.
    pub hi_brick_bytes: u64,
    /// Bytes of one packed low-res brick: `(n/2+1)^3 * scalar size`.
    pub lo_brick_bytes: u64,
    /// File offset of the value-range table.
    pub ranges_offset: u64,
    /// File offset of the brick offset table.
    pub offsets_offset: u64,
    /// File offset of the first brick byte.
    pub data_offset: u64,
    /// Total file length.
    pub file_size: u64,
    /// Smallest and largest stored voxel value (normalised), over the whole volume.
    pub value_range: ValueRange,
}

impl StoreHeader {
    /// The brick grid of the store.
    pub fn grid(&self) -> BrickGrid {
        // Validated at parse / construction time.
        BrickGrid::new(self.dims, self.brick_size).expect("validated brick grid")
    }

    /// Bytes of one brick at both levels.
    pub fn brick_pair_bytes(&self) -> u64 {
        self.hi_brick_bytes + self.lo_brick_bytes
    }
}

/// Numeric id of a scalar type in the header (`0` u8, `1` u16, `2` f32).
pub fn scalar_id(scalar: ScalarType) -> u32 {
    match scalar {
        ScalarType::U8 => 0,
        ScalarType::U16 => 1,
        ScalarType::F32 => 2,
    }
}

/// The scalar type of header id `id`.
pub fn scalar_from_id(id: u32) -> Option<ScalarType> {
    match id {
        0 => Some(ScalarType::U8),
        1 => Some(ScalarType::U16),
        2 => Some(ScalarType::F32),
        _ => None,
    }
}

/// Numeric id of a filter in the header (`0` Mean2, `1` LaMarSubsample, `2` Box4, `3` BSpline4).
pub fn filter_id(filter: DownsampleFilter) -> u32 {
    match filter {
        DownsampleFilter::Mean2 => 0,
        DownsampleFilter::LaMarSubsample => 1,
        DownsampleFilter::Box4 => 2,
        DownsampleFilter::BSpline4 => 3,
    }
}

/// The filter of header id `id`.
pub fn filter_from_id(id: u32) -> Option<DownsampleFilter> {
    match id {
        0 => Some(DownsampleFilter::Mean2),
        1 => Some(DownsampleFilter::LaMarSubsample),
        2 => Some(DownsampleFilter::Box4),
        3 => Some(DownsampleFilter::BSpline4),
        _ => None,
    }
}

/// The filter whose id is the `u32` at `offset` of a header read from `path` (a store of
/// `kind`); an unknown id is a [`StoreError::Format`] naming the field `filter` (both store
/// formats read it so).
pub(crate) fn parse_filter_field(
    kind: &'static str,
    bytes: &[u8],
    offset: usize,
    path: &Path,
) -> Result<DownsampleFilter, StoreError> {
    let raw = le_u32(bytes, offset);
    filter_from_id(raw).ok_or_else(|| {
        format_error(
            kind,
            path,
            "filter",
            format!("unknown filter id {raw} (0 = mean2, 1 = lamar, 2 = box4, 3 = bspline4)"),
        )
    })
}

/// 64-bit FNV-1a, incrementally.
#[derive(Copy, Clone, Debug)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    /// Feeds `bytes`.
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }

    /// The hash so far.
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// The header a writer produces for `grid` (the canonical layout: tables right after the header,
/// data aligned to [`DATA_ALIGNMENT`], bricks back to back in linear order, hi then lo).
pub fn canonical_header(
    grid: &BrickGrid,
    scalar: ScalarType,
    filter: DownsampleFilter,
    spacing: Vec3,
    value_range: ValueRange,
) -> Option<StoreHeader> {
    let n = grid.brick_size();
    let size = scalar.size_bytes() as u64;
    let hi_brick_bytes = u64::from(hi_res_brick_extent(n)).pow(3) * size;
    let lo_brick_bytes = u64::from(low_res_brick_extent(n)).pow(3) * size;
    let brick_count = u32::try_from(grid.brick_count()).ok()?;
    let count = u64::from(brick_count);
    let ranges_offset = HEADER_SIZE as u64;
    let offsets_offset = ranges_offset.checked_add(count.checked_mul(RANGE_ENTRY_BYTES)?)?;
    let tables_end = offsets_offset.checked_add(count.checked_mul(OFFSET_ENTRY_BYTES)?)?;
    let data_offset = tables_end.checked_next_multiple_of(DATA_ALIGNMENT)?;
    let file_size =
        data_offset.checked_add(count.checked_mul(hi_brick_bytes.checked_add(lo_brick_bytes)?)?)?;
    Some(StoreHeader {
        version: FORMAT_VERSION,
        dims: grid.dims(),
        brick_size: n,
        scalar,
        filter,
        spacing,
        brick_count,
        hi_brick_bytes,
        lo_brick_bytes,
        ranges_offset,
        offsets_offset,
        data_offset,
        file_size,
        value_range,
    })
}

/// The canonical offset of brick `index`'s hi-res bytes (its low-res bytes follow directly).
pub fn canonical_brick_offset(header: &StoreHeader, index: u32) -> u64 {
    header.data_offset + u64::from(index) * header.brick_pair_bytes()
}

/// Encodes the header; bytes `[120, 128)` (the checksum) are left zero, see [`finish_checksum`].
pub fn encode_header(h: &StoreHeader) -> [u8; HEADER_SIZE] {
    let mut out = [0u8; HEADER_SIZE];
    let mut w = Writer {
        buf: &mut out,
        at: 0,
    };
    w.bytes(&MAGIC);
    w.u32(h.version);
    w.u32(HEADER_SIZE as u32);
    for v in h.dims.to_array() {
        w.u32(v);
    }
    w.u32(h.brick_size);
    w.u32(scalar_id(h.scalar));
    w.u32(filter_id(h.filter));
    for v in h.spacing.to_array() {
        w.f32(v);
    }
    w.u32(h.brick_count);
    w.u64(h.hi_brick_bytes);
    w.u64(h.lo_brick_bytes);
    w.u64(h.ranges_offset);
    w.u64(h.offsets_offset);
    w.u64(h.data_offset);
    w.u64(h.file_size);
    w.f32(h.value_range.min);
    w.f32(h.value_range.max);
    debug_assert_eq!(w.at, 112);
    out
}

/// Encodes the value-range table (`min, max` f32 per brick).
pub fn encode_ranges(ranges: &[ValueRange]) -> Vec<u8> {
    ranges
        .iter()
        .flat_map(|r| {
            let mut e = [0u8; 8];
            e[..4].copy_from_slice(&r.min.to_le_bytes());
            e[4..].copy_from_slice(&r.max.to_le_bytes());
            e
        })
        .collect()
}

/// Encodes the offset table (`hi, lo` u64 and their CRC-32s per brick; `crcs` has one pair per
/// brick of `offsets`).
pub fn encode_offsets(offsets: &[[u64; 2]], crcs: &[[u32; 2]]) -> Vec<u8> {
    offsets
        .iter()
        .zip(crcs)
        .flat_map(|([hi, lo], [hi_crc, lo_crc])| {
            let mut e = [0u8; OFFSET_ENTRY_BYTES as usize];
            e[..8].copy_from_slice(&hi.to_le_bytes());
            e[8..16].copy_from_slice(&lo.to_le_bytes());
            e[16..20].copy_from_slice(&hi_crc.to_le_bytes());
            e[20..].copy_from_slice(&lo_crc.to_le_bytes());
            e
        })
        .collect()
}

/// The checksum of an encoded header (bytes `[0, 120)`) and the encoded tables.
pub fn checksum(header: &[u8; HEADER_SIZE], ranges: &[u8], offsets: &[u8]) -> u64 {
    let mut h = Fnv1a::default();
    h.update(&header[..CHECKSUM_OFFSET]);
    h.update(ranges);
    h.update(offsets);
    h.finish()
}

/// Stores the checksum of `header` + tables into header bytes `[120, 128)`.
pub fn finish_checksum(header: &mut [u8; HEADER_SIZE], ranges: &[u8], offsets: &[u8]) {
    let sum = checksum(header, ranges, offsets);
    header[CHECKSUM_OFFSET..].copy_from_slice(&sum.to_le_bytes());
}

/// Little-endian field writer over a fixed buffer.
struct Writer<'a> {
    buf: &'a mut [u8; HEADER_SIZE],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        self.buf[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.bytes(&v.to_le_bytes());
    }
}

/// Little-endian u32 at `at` of a slice long enough (callers pass fixed-size headers).
pub(crate) fn le_u32(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}

pub(crate) fn le_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

pub(crate) fn le_f32(b: &[u8], at: usize) -> f32 {
    f32::from_bits(le_u32(b, at))
}

/// Builds a [`StoreError::Format`].
pub(crate) fn format_error(
    kind: &'static str,
    path: &Path,
    field: &'static str,
    message: String,
) -> StoreError {
    StoreError::Format {
        kind,
        path: path.to_path_buf(),
        field,
        message,
    }
}

/// Parses and validates the fixed header. `actual_len` is the file's length on disk.
///
/// Checks, in order (each failure names its field): `magic`, `version`, `header_size`, `dims`,
/// `brick_size`, `scalar`, `filter`, `spacing`, `brick_count`, `hi_brick_bytes`,
/// `lo_brick_bytes`, `ranges_offset`, `offsets_offset`, `data_offset`, `file_size` (against the
/// layout and `actual_len`), `value_range`, `reserved`. The checksum is checked by
/// [`parse_tables`] once the tables are read.
pub fn parse_header(bytes: &[u8], actual_len: u64, path: &Path) -> Result<StoreHeader, StoreError> {
    let err =
        |field: &'static str, message: String| format_error(BRICK_STORE, path, field, message);
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
        return Err(err(
            "magic",
            format!(
                "expected the 8 bytes {:?}, found {:?}",
                String::from_utf8_lossy(&MAGIC),
                String::from_utf8_lossy(&bytes[..bytes.len().min(MAGIC.len())])
            ),
        ));
    }
    if bytes.len() < 12 {
        return Err(err(
            "version",
            format!("file ends after {} bytes, inside the header", bytes.len()),
        ));
    }
    let version = le_u32(bytes, 8);
    if version != FORMAT_VERSION {
        return Err(err(
            "version",
            format!(
                "unsupported format version {version}; this build reads version {FORMAT_VERSION}"
            ),
        ));
    }
    if bytes.len() < HEADER_SIZE {
        return Err(err(
            "header_size",
            format!(
                "file holds {} bytes but the version {FORMAT_VERSION} header needs {HEADER_SIZE}",
                bytes.len()
            ),
        ));
    }
    let header_size = le_u32(bytes, 12);
    if header_size as usize != HEADER_SIZE {
        return Err(err(
            "header_size",
            format!("is {header_size}; version {FORMAT_VERSION} headers are {HEADER_SIZE} bytes"),
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
    let scalar_raw = le_u32(bytes, 32);
    let scalar = scalar_from_id(scalar_raw).ok_or_else(|| {
        err(
            "scalar",
            format!("unknown scalar type id {scalar_raw} (0 = u8, 1 = u16, 2 = f32)"),
        )
    })?;
    let filter = parse_filter_field(BRICK_STORE, bytes, 36, path)?;
    let spacing = Vec3::new(le_f32(bytes, 40), le_f32(bytes, 44), le_f32(bytes, 48));
    if !(spacing.is_finite() && spacing.min_element() > 0.0) {
        return Err(err(
            "spacing",
            format!("{:?} must be positive and finite", spacing.to_array()),
        ));
    }
    let grid =
        BrickGrid::new(dims, brick_size).map_err(|e| err("dims", format!("cannot brick: {e}")))?;
    let b = grid.bricks_per_axis();
    let expected_count = u64::from(b.x) * u64::from(b.y) * u64::from(b.z);
    let brick_count = le_u32(bytes, 52);
    if u64::from(brick_count) != expected_count {
        return Err(err(
            "brick_count",
            format!(
                "is {brick_count} but dims {:?} with brick size {brick_size} give {expected_count} bricks",
                dims.to_array()
            ),
        ));
    }
    let size = scalar.size_bytes() as u64;
    let expect_hi = u64::from(hi_res_brick_extent(brick_size)).pow(3) * size;
    let expect_lo = u64::from(low_res_brick_extent(brick_size)).pow(3) * size;
    let hi_brick_bytes = le_u64(bytes, 56);
    if hi_brick_bytes != expect_hi {
        return Err(err(
            "hi_brick_bytes",
            format!("is {hi_brick_bytes}; (n+2)^3 texels of {scalar:?} are {expect_hi} bytes"),
        ));
    }
    let lo_brick_bytes = le_u64(bytes, 64);
    if lo_brick_bytes != expect_lo {
        return Err(err(
            "lo_brick_bytes",
            format!("is {lo_brick_bytes}; (n/2+1)^3 texels of {scalar:?} are {expect_lo} bytes"),
        ));
    }
    let count = u64::from(brick_count);
    let ranges_offset = le_u64(bytes, 72);
    if ranges_offset < HEADER_SIZE as u64 {
        return Err(err(
            "ranges_offset",
            format!("{ranges_offset} overlaps the {HEADER_SIZE}-byte header"),
        ));
    }
    let ranges_end = count
        .checked_mul(RANGE_ENTRY_BYTES)
        .and_then(|len| ranges_offset.checked_add(len))
        .ok_or_else(|| {
            err(
                "ranges_offset",
                format!("{ranges_offset} + table overflows"),
            )
        })?;
    let offsets_offset = le_u64(bytes, 80);
    if offsets_offset < ranges_end {
        return Err(err(
            "offsets_offset",
            format!("{offsets_offset} overlaps the value-range table ending at {ranges_end}"),
        ));
    }
    let offsets_end = count
        .checked_mul(OFFSET_ENTRY_BYTES)
        .and_then(|len| offsets_offset.checked_add(len))
        .ok_or_else(|| {
            err(
                "offsets_offset",
                format!("{offsets_offset} + table overflows"),
            )
        })?;
    let data_offset = le_u64(bytes, 88);
    if data_offset < offsets_end {
        return Err(err(
            "data_offset",
            format!("{data_offset} overlaps the offset table ending at {offsets_end}"),
        ));
    }
    let file_size = le_u64(bytes, 96);
    let data_len = hi_brick_bytes
        .checked_add(lo_brick_bytes)
        .and_then(|pair| pair.checked_mul(count))
        .and_then(|len| data_offset.checked_add(len));
    match data_len {
        Some(min_size) if file_size >= min_size => {}
        _ => {
            return Err(err(
                "file_size",
                format!(
                    "{file_size} cannot hold {brick_count} bricks of {} bytes from offset {data_offset}",
                    hi_brick_bytes + lo_brick_bytes
                ),
            ))
        }
    }
    if actual_len != file_size {
        let what = if actual_len >= file_size {
            "trailing bytes".to_string()
        } else if actual_len < data_offset {
            "truncated inside the tables, before brick 0".to_string()
        } else {
            // In the canonical layout (every writer's) brick i starts at data_offset + i * pair.
            let pair = hi_brick_bytes + lo_brick_bytes;
            let first = (actual_len - data_offset) / pair.max(1);
            format!(
                "truncated: brick {first} of {brick_count} and those after it are cut off in \
                 the canonical layout"
            )
        };
        return Err(err(
            "file_size",
            format!("header says {file_size} bytes but the file holds {actual_len} ({what})"),
        ));
    }
    let value_range = ValueRange {
        min: le_f32(bytes, 104),
        max: le_f32(bytes, 108),
    };
    check_range(&value_range, scalar)
        .map_err(|m| err("value_range", format!("{value_range:?}: {m}")))?;
    if le_u64(bytes, 112) != 0 {
        return Err(err("reserved", "bytes 112..120 must be zero".into()));
    }
    Ok(StoreHeader {
        version,
        dims,
        brick_size,
        scalar,
        filter,
        spacing,
        brick_count,
        hi_brick_bytes,
        lo_brick_bytes,
        ranges_offset,
        offsets_offset,
        data_offset,
        file_size,
        value_range,
    })
}

/// A range is valid when both ends are finite, `min <= max` and, for UNORM storage, in `[0, 1]`.
fn check_range(range: &ValueRange, scalar: ScalarType) -> std::result::Result<(), &'static str> {
    if !(range.min.is_finite() && range.max.is_finite()) {
        return Err("ends must be finite");
    }
    if range.min > range.max {
        return Err("min exceeds max");
    }
    if scalar != ScalarType::F32 && (range.min < 0.0 || range.max > 1.0) {
        return Err("UNORM values lie in [0, 1]");
    }
    Ok(())
}

/// The parsed tables of a store.
#[derive(Clone, Debug, PartialEq)]
pub struct StoreTables {
    /// Per-brick value ranges.
    pub ranges: Vec<ValueRange>,
    /// Per-brick `[hi, lo]` absolute file offsets.
    pub offsets: Vec<[u64; 2]>,
    /// Per-brick `[hi, lo]` CRC-32s of the levels' bytes ([`brick_crc`]).
    pub crcs: Vec<[u32; 2]>,
}

/// Parses and validates the value-range and offset tables against `header` and the checksum in
/// `header_bytes` (fields `table_checksum`, `value_ranges`, `offsets`).
///
/// Every brick level must lie inside `[data_offset, file_size)`, and no two brick levels may
/// overlap.
pub fn parse_tables(
    header: &StoreHeader,
    header_bytes: &[u8; HEADER_SIZE],
    ranges_bytes: &[u8],
    offsets_bytes: &[u8],
    path: &Path,
) -> Result<StoreTables, StoreError> {
    let err =
        |field: &'static str, message: String| format_error(BRICK_STORE, path, field, message);
    let count = header.brick_count as usize;
    if ranges_bytes.len() as u64 != count as u64 * RANGE_ENTRY_BYTES
        || offsets_bytes.len() as u64 != count as u64 * OFFSET_ENTRY_BYTES
    {
        return Err(err(
            "brick_count",
            "table lengths do not match the brick count".into(),
        ));
    }
    let stored = le_u64(header_bytes, CHECKSUM_OFFSET);
    let computed = checksum(header_bytes, ranges_bytes, offsets_bytes);
    if stored != computed {
        return Err(err(
            "table_checksum",
            format!("stored {stored:#018x} but header and tables hash to {computed:#018x}: the file is corrupt"),
        ));
    }
    let mut ranges = Vec::with_capacity(count);
    for (i, e) in ranges_bytes.chunks_exact(8).enumerate() {
        let r = ValueRange {
            min: le_f32(e, 0),
            max: le_f32(e, 4),
        };
        check_range(&r, header.scalar)
            .map_err(|m| err("value_ranges", format!("brick {i}: {r:?}: {m}")))?;
        ranges.push(r);
    }
    let lens = [header.hi_brick_bytes, header.lo_brick_bytes];
    let mut offsets = Vec::with_capacity(count);
    let mut crcs = Vec::with_capacity(count);
    let mut extents = Vec::with_capacity(2 * count);
    for (i, e) in offsets_bytes
        .chunks_exact(OFFSET_ENTRY_BYTES as usize)
        .enumerate()
    {
        let pair = [le_u64(e, 0), le_u64(e, 8)];
        crcs.push([le_u32(e, 16), le_u32(e, 20)]);
        for (level, (&start, &len)) in ["hi", "lo"].iter().zip(pair.iter().zip(&lens)) {
            let inside = start >= header.data_offset
                && start
                    .checked_add(len)
                    .is_some_and(|end| end <= header.file_size);
            if !inside {
                return Err(err(
                    "offsets",
                    format!(
                        "brick {i} {level}: {len} bytes at {start} leave the data section [{}, {})",
                        header.data_offset, header.file_size
                    ),
                ));
            }
            extents.push((start, len, i, *level));
        }
        offsets.push(pair);
    }
    extents.sort_unstable_by_key(|&(start, ..)| start);
    for w in extents.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if a.0 + a.1 > b.0 {
            return Err(err(
                "offsets",
                format!(
                    "brick {} {} at {} overlaps brick {} {} at {}",
                    a.2, a.3, a.0, b.2, b.3, b.0
                ),
            ));
        }
    }
    Ok(StoreTables {
        ranges,
        offsets,
        crcs,
    })
}
