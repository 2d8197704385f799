//! Shared reading machinery for the file formats: size checks, file opening, voxel decoding and
//! bounded (bomb-safe) gzip reading.
use super::{LoadedVolume, StoredType, VolumeMeta, MAX_VOLUME_BYTES};
use crate::volume::{checked_voxel_count, Volume, VolumeError, VoxelData};
use flate2::bufread::MultiGzDecoder;
use glam::{UVec3, Vec3};
use std::fs::File;
use std::io::{self, BufRead, BufReader, ErrorKind, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Elements reserved up front when the final size is not yet backed by data (gzip streams): the
/// buffer then grows geometrically with the data actually decoded, never past the header's size.
const INITIAL_STREAM_ELEMS: usize = 1 << 20;

/// A [`VolumeError::Format`] naming `path` and `field`.
pub(super) fn format_err(
    path: &Path,
    field: impl Into<String>,
    message: impl Into<String>,
) -> VolumeError {
    VolumeError::Format {
        path: path.to_path_buf(),
        field: field.into(),
        message: message.into(),
    }
}

/// Maps an IO error on `path` to [`VolumeError::Io`].
pub(super) fn io_err(path: &Path) -> impl Fn(io::Error) -> VolumeError + '_ {
    move |source| VolumeError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Opens a regular file and returns it with its length; directories and other non-files are
/// [`VolumeError::Io`] errors (see [`crate::volume::open_regular_file`]: a FIFO is refused
/// before it is opened, so it cannot block).
pub(super) fn open_regular(path: &Path) -> Result<(File, u64), VolumeError> {
    crate::volume::open_regular_file(path)
}

/// Reads at most `max` bytes from the start of `path` (a header, a sidecar).
pub(super) fn read_prefix(path: &Path, max: u64) -> Result<(Vec<u8>, u64), VolumeError> {
    let (file, len) = open_regular(path)?;
    let mut bytes = Vec::new();
    file.take(max)
        .read_to_end(&mut bytes)
        .map_err(io_err(path))?;
    Ok((bytes, len))
}

/// True when the file starts with the gzip magic bytes.
pub(super) fn is_gzip(path: &Path) -> Result<bool, VolumeError> {
    let (bytes, _) = read_prefix(path, 2)?;
    Ok(bytes == [0x1f, 0x8b])
}

/// A checked voxel layout: dimensions, voxel count and byte size in the file.
#[derive(Copy, Clone, Debug)]
pub(super) struct Layout {
    /// Voxel counts.
    pub dims: UVec3,
    /// Voxels in the volume.
    pub count: usize,
    /// Bytes the voxels take in the file (decoded, for compressed encodings).
    pub bytes: u64,
    /// Type of the stored values.
    pub stored: StoredType,
}

/// Checks `dims` (from the header field `field` of `path`) and `stored` with checked arithmetic:
/// every axis at least 1 and at most `u32::MAX`, and the stored and in-memory byte sizes at most
/// [`MAX_VOLUME_BYTES`]. Nothing is allocated.
pub(super) fn layout(
    path: &Path,
    field: &str,
    dims: [u64; 3],
    stored: StoredType,
) -> Result<Layout, VolumeError> {
    let mut d = [0u32; 3];
    for (i, (&n, out)) in dims.iter().zip(&mut d).enumerate() {
        let axis = ['x', 'y', 'z'][i];
        if n == 0 {
            return Err(format_err(path, field, format!("axis {axis} has size 0")));
        }
        *out = u32::try_from(n).map_err(|_| {
            format_err(
                path,
                field,
                format!("axis {axis} size {n} exceeds {}", u32::MAX),
            )
        })?;
    }
    let too_big = || {
        format_err(
            path,
            field,
            format!(
                "{}x{}x{} voxels of {} exceed the {} GiB size limit",
                dims[0],
                dims[1],
                dims[2],
                stored.name(),
                MAX_VOLUME_BYTES >> 30
            ),
        )
    };
    let count = dims[0]
        .checked_mul(dims[1])
        .and_then(|n| n.checked_mul(dims[2]))
        .ok_or_else(too_big)?;
    let widest = stored.size_bytes().max(stored.volume_scalar().size_bytes()) as u64;
    if count
        .checked_mul(widest)
        .is_none_or(|b| b > MAX_VOLUME_BYTES)
    {
        return Err(too_big());
    }
    let dims = UVec3::from_array(d);
    let count = checked_voxel_count(dims)?;
    Ok(Layout {
        dims,
        count,
        bytes: count as u64 * stored.size_bytes() as u64,
        stored,
    })
}

/// Checks the in-memory size of a volume of `layout` (read from `path`) against the host-memory
/// limit ([`crate::volume::memory`]) before its voxel buffer is allocated.
pub(super) fn check_layout_memory(path: &Path, layout: &Layout) -> Result<(), VolumeError> {
    let bytes =
        (layout.count as u64).saturating_mul(layout.stored.volume_scalar().size_bytes() as u64);
    crate::volume::memory::check_host_bytes(
        &format!(
            "{} ({}x{}x{} {})",
            path.display(),
            layout.dims.x,
            layout.dims.y,
            layout.dims.z,
            layout.stored.name()
        ),
        bytes,
    )
}

/// Why reading voxel values failed.
pub(super) enum ReadFail {
    /// The data ended after `got` of the bytes needed.
    Short {
        /// Bytes read before the end.
        got: u64,
    },
    /// The reader failed (IO, corrupt compressed data, allocation refused).
    Io(io::Error),
}

/// Reads `count` values of `T` in file byte order. With `reserve_all` (the data is known to be
/// there) the buffer is reserved once; otherwise it grows geometrically as data arrives, so a
/// header that lies about the size of a compressed stream cannot make us allocate more than about
/// twice what the stream really holds. Allocation failures are `OutOfMemory` IO errors.
fn read_pod<T: bytemuck::Pod>(
    reader: &mut dyn Read,
    count: usize,
    reserve_all: bool,
) -> Result<Vec<T>, ReadFail> {
    let oom = |_| ReadFail::Io(io::Error::from(ErrorKind::OutOfMemory));
    let mut values: Vec<T> = Vec::new();
    let first = if reserve_all {
        count
    } else {
        count.min(INITIAL_STREAM_ELEMS)
    };
    values.try_reserve_exact(first).map_err(oom)?;
    let size = std::mem::size_of::<T>() as u64;
    while values.len() < count {
        if values.len() == values.capacity() {
            let grow = values.len().max(1).min(count - values.len());
            values.try_reserve_exact(grow).map_err(oom)?;
        }
        let start = values.len();
        let end = values.capacity().min(count);
        values.resize(end, T::zeroed());
        let chunk: &mut [u8] = bytemuck::cast_slice_mut(&mut values[start..end]);
        let mut filled = 0;
        while filled < chunk.len() {
            match reader.read(&mut chunk[filled..]) {
                Ok(0) => {
                    return Err(ReadFail::Short {
                        got: start as u64 * size + filled as u64,
                    })
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(ReadFail::Io(e)),
            }
        }
    }
    Ok(values)
}

/// Reads and decodes `layout.count` voxels, mapping them to the volume's scalar types (see
/// [`StoredType::volume_scalar`]).
pub(super) fn read_voxels(
    reader: &mut dyn Read,
    layout: &Layout,
    big_endian: bool,
    reserve_all: bool,
) -> Result<VoxelData, ReadFail> {
    let n = layout.count;
    let u16_of = if big_endian {
        u16::from_be
    } else {
        u16::from_le
    };
    let u32_of = if big_endian {
        u32::from_be
    } else {
        u32::from_le
    };
    let u64_of = if big_endian {
        u64::from_be
    } else {
        u64::from_le
    };
    Ok(match layout.stored {
        StoredType::U8 => VoxelData::U8(read_pod(reader, n, reserve_all)?),
        StoredType::I8 => {
            let mut v: Vec<u8> = read_pod(reader, n, reserve_all)?;
            // Two's complement + 128 == flipping the sign bit.
            v.iter_mut().for_each(|x| *x ^= 0x80);
            VoxelData::U8(v)
        }
        StoredType::U16 => {
            let mut v: Vec<u16> = read_pod(reader, n, reserve_all)?;
            v.iter_mut().for_each(|x| *x = u16_of(*x));
            VoxelData::U16(v)
        }
        StoredType::I16 => {
            let mut v: Vec<u16> = read_pod(reader, n, reserve_all)?;
            // Two's complement + 32768 == flipping the sign bit.
            v.iter_mut().for_each(|x| *x = u16_of(*x) ^ 0x8000);
            VoxelData::U16(v)
        }
        StoredType::U32 => {
            let v: Vec<u32> = read_pod(reader, n, reserve_all)?;
            VoxelData::F32(v.into_iter().map(|x| u32_of(x) as f32).collect())
        }
        StoredType::I32 => {
            let v: Vec<u32> = read_pod(reader, n, reserve_all)?;
            VoxelData::F32(v.into_iter().map(|x| u32_of(x) as i32 as f32).collect())
        }
        StoredType::F32 => {
            let v: Vec<u32> = read_pod(reader, n, reserve_all)?;
            VoxelData::F32(v.into_iter().map(|x| f32::from_bits(u32_of(x))).collect())
        }
        StoredType::F64 => {
            let v: Vec<u64> = read_pod(reader, n, reserve_all)?;
            VoxelData::F32(
                v.into_iter()
                    .map(|x| f64::from_bits(u64_of(x)) as f32)
                    .collect(),
            )
        }
    })
}

/// Where and how a volume's voxel values are stored.
#[derive(Clone, Debug)]
pub(super) struct Payload {
    /// The header file, named in format errors.
    pub header_path: PathBuf,
    /// The header field blamed when the data is too short or too long.
    pub size_field: &'static str,
    /// The file holding the data.
    pub data_path: PathBuf,
    /// Byte offset of the (possibly compressed) data in `data_path`.
    pub offset: u64,
    /// True for a gzip stream starting at `offset`.
    pub gzip: bool,
    /// Decoded bytes to skip before the voxels (gzip only; raw skips are part of `offset`).
    pub decoded_skip: u64,
    /// True when multi-byte values are big-endian.
    pub big_endian: bool,
}

/// A volume file's header, parsed and checked, before any voxel is read: where the voxels are,
/// their layout, the spacing and the metadata. Loading it ([`Described::load`]) and reading it
/// slab by slab ([`super::slabs::PayloadSlabs`]) see the same voxels.
#[derive(Clone, Debug)]
pub(super) struct Described {
    /// Where the voxels are.
    pub payload: Payload,
    /// Their layout.
    pub layout: Layout,
    /// The voxel spacing (checked: positive and finite in f32).
    pub spacing: Vec3,
    /// What the header says besides.
    pub meta: VolumeMeta,
}

impl Described {
    /// Reads every voxel into a volume.
    pub fn load(self) -> Result<LoadedVolume, VolumeError> {
        check_layout_memory(&self.payload.header_path, &self.layout)?;
        let data = read_payload(&self.payload, &self.layout)?;
        Ok(LoadedVolume {
            volume: Volume::new(self.layout.dims, self.spacing, data)
                .map_err(|e| e.in_file(&self.payload.data_path))?,
            meta: self.meta,
        })
    }
}

/// A gzip stream positioned at the first voxel byte, limited to one byte past the voxels.
/// How far past the described size a gzip stream is decoded to tell a longer stream from a
/// corrupt one (bounded: a gzip bomb must not run on).
const EXTRA_GZIP_PROBE_BYTES: u64 = 64 << 20;

pub(super) type GzStream = io::Take<MultiGzDecoder<BufReader<File>>>;

impl Payload {
    /// `WxHxD type voxels need N bytes`, for error messages.
    pub fn describe(&self, layout: &Layout) -> String {
        format!(
            "{}x{}x{} {} voxels need {} bytes",
            layout.dims.x,
            layout.dims.y,
            layout.dims.z,
            layout.stored.name(),
            layout.bytes
        )
    }

    /// Checks that raw data fills the data file (of `len` bytes) exactly from `offset`.
    pub fn check_raw_len(&self, layout: &Layout, len: u64) -> Result<(), VolumeError> {
        let need = self.offset.checked_add(layout.bytes).ok_or_else(|| {
            format_err(
                &self.header_path,
                self.size_field,
                "data offset + size overflows",
            )
        })?;
        if len != need {
            let what = if len < need { "short" } else { "long" };
            return Err(format_err(
                &self.header_path,
                self.size_field,
                format!(
                    "{} is too {what}: it holds {len} bytes but {} + header/offset {} = {need}",
                    self.data_path.display(),
                    self.describe(layout),
                    self.offset
                ),
            ));
        }
        Ok(())
    }

    /// The error for raw data that ended after `got` data bytes.
    pub fn raw_short(&self, layout: &Layout, got: u64) -> VolumeError {
        format_err(
            &self.header_path,
            self.size_field,
            format!(
                "{} ended after {got} data bytes; {}",
                self.data_path.display(),
                self.describe(layout)
            ),
        )
    }

    /// Maps an error of the gzip stream to a format error (truncated, corrupt) or an IO error.
    pub fn gzip_err(&self, e: io::Error) -> VolumeError {
        let data_name = self.data_path.display();
        match e.kind() {
            ErrorKind::UnexpectedEof => format_err(
                &self.header_path,
                self.size_field,
                format!("gzip data in {data_name} is truncated: {e}"),
            ),
            ErrorKind::InvalidInput | ErrorKind::InvalidData => format_err(
                &self.header_path,
                "encoding",
                format!("corrupt gzip data in {data_name}: {e}"),
            ),
            _ => io_err(&self.data_path)(e),
        }
    }

    /// The error for a gzip stream that ended after `got` data bytes.
    pub fn gzip_short(&self, layout: &Layout, got: u64) -> VolumeError {
        format_err(
            &self.header_path,
            self.size_field,
            format!(
                "gzip data in {} ends after {got} data bytes; {}",
                self.data_path.display(),
                self.describe(layout)
            ),
        )
    }

    /// Opens the gzip stream of a gzip payload, skips `decoded_skip` bytes and returns it at the
    /// first voxel byte, limited to one byte past the voxels.
    pub fn open_gzip(&self, layout: &Layout) -> Result<GzStream, VolumeError> {
        let (mut file, len) = open_regular(&self.data_path)?;
        let data_name = self.data_path.display();
        if self.offset > len {
            return Err(format_err(
                &self.header_path,
                self.size_field,
                format!(
                    "data offset {} is past the end of {data_name} ({len} bytes)",
                    self.offset
                ),
            ));
        }
        file.seek(SeekFrom::Start(self.offset))
            .map_err(io_err(&self.data_path))?;
        let limit = self
            .decoded_skip
            .checked_add(layout.bytes)
            .and_then(|n| n.checked_add(1))
            .ok_or_else(|| {
                format_err(
                    &self.header_path,
                    self.size_field,
                    "data skip + size overflows",
                )
            })?;
        let mut stream = MultiGzDecoder::new(BufReader::new(file)).take(limit);
        let skipped = io::copy(&mut (&mut stream).take(self.decoded_skip), &mut io::sink())
            .map_err(|e| self.gzip_err(e))?;
        if skipped < self.decoded_skip {
            return Err(format_err(
                &self.header_path,
                self.size_field,
                format!(
                    "gzip data in {data_name} ends after {skipped} bytes, before the {} bytes to skip",
                    self.decoded_skip
                ),
            ));
        }
        Ok(stream)
    }

    /// Checks that the gzip stream holds nothing after the voxels.
    pub fn check_gzip_end(
        &self,
        layout: &Layout,
        stream: &mut GzStream,
    ) -> Result<(), VolumeError> {
        let mut extra = [0u8; 1];
        let n = loop {
            match stream.read(&mut extra) {
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                other => break other.map_err(|e| self.gzip_err(e))?,
            }
        };
        if n != 0 {
            // Decode on (bounded) to tell a longer stream from a corrupt one: a damaged deflate
            // stream often decodes to garbage past the described size before its CRC or its
            // structure fails, and then the data, not the header's size, is wrong.
            let mut rest = stream.get_mut().take(EXTRA_GZIP_PROBE_BYTES);
            let extra = match io::copy(&mut rest, &mut io::sink()) {
                Ok(extra) => extra,
                Err(e) => return Err(self.gzip_err(e)),
            };
            let holds = if extra < EXTRA_GZIP_PROBE_BYTES {
                format!("{} bytes", layout.bytes + 1 + extra)
            } else {
                format!("more than {} bytes", layout.bytes + 1 + extra)
            };
            return Err(format_err(
                &self.header_path,
                self.size_field,
                format!(
                    "gzip data in {} decodes intact to {holds}, more than the {} bytes \
                     described; {}",
                    self.data_path.display(),
                    layout.bytes,
                    self.describe(layout)
                ),
            ));
        }
        Ok(())
    }
}

/// Reads the voxels described by `payload` and `layout`. Raw data must fill the file exactly
/// from `offset`; a gzip stream must decode to exactly `decoded_skip + layout.bytes` bytes (it is
/// read through a `take` limit, so a stream that decodes to more stops there).
pub(super) fn read_payload(payload: &Payload, layout: &Layout) -> Result<VoxelData, VolumeError> {
    if !payload.gzip {
        let (mut file, len) = open_regular(&payload.data_path)?;
        payload.check_raw_len(layout, len)?;
        file.seek(SeekFrom::Start(payload.offset))
            .map_err(io_err(&payload.data_path))?;
        let mut reader = BufReader::new(file);
        return read_voxels(&mut reader, layout, payload.big_endian, true).map_err(|e| match e {
            ReadFail::Short { got } => payload.raw_short(layout, got),
            ReadFail::Io(e) => io_err(&payload.data_path)(e),
        });
    }
    let mut stream = payload.open_gzip(layout)?;
    let data =
        read_voxels(&mut stream, layout, payload.big_endian, false).map_err(|e| match e {
            ReadFail::Short { got } => payload.gzip_short(layout, got),
            ReadFail::Io(e) => payload.gzip_err(e),
        })?;
    payload.check_gzip_end(layout, &mut stream)?;
    Ok(data)
}

/// Skips `lines` newline-terminated lines of `path` starting at `offset` and returns the offset
/// after them (NRRD `line skip`). Reaching the end of the file first is a format error.
pub(super) fn skip_lines(
    header: &Path,
    field: &str,
    path: &Path,
    offset: u64,
    lines: u64,
) -> Result<u64, VolumeError> {
    if lines == 0 {
        return Ok(offset);
    }
    let (mut file, _) = open_regular(path)?;
    file.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
    let mut reader = BufReader::new(file);
    let mut pos = offset;
    for done in 0..lines {
        let n = skip_line(&mut reader).map_err(io_err(path))?;
        if n == 0 {
            return Err(format_err(
                header,
                field,
                format!(
                    "{} ends after {done} of {lines} lines to skip",
                    path.display()
                ),
            ));
        }
        pos += n;
    }
    Ok(pos)
}

/// Consumes bytes up to and including the next `\n`; returns how many (0 at end of file).
fn skip_line(reader: &mut impl BufRead) -> io::Result<u64> {
    let mut total = 0u64;
    loop {
        let buf = match reader.fill_buf() {
            Ok(b) => b,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if buf.is_empty() {
            return Ok(total);
        }
        if let Some(i) = buf.iter().position(|&b| b == b'\n') {
            reader.consume(i + 1);
            return Ok(total + i as u64 + 1);
        }
        let n = buf.len();
        reader.consume(n);
        total += n as u64;
    }
}
