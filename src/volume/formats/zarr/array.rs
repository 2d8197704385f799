//! One Zarr array through zarrs: its metadata, stored type and byte order, and the chunk reader
//! that assembles the voxels under the size limits.

use super::declared::OuterCodec;
use super::*;
use std::borrow::Cow;
use std::ops::Range;
use zarrs::array::{ArrayBytes, ArrayToBytesCodecTraits, CodecOptions, FromArrayBytes};

/// Reads a metadata document of at most [`MAX_HEADER_BYTES`].
pub(super) fn read_metadata(path: &Path) -> Result<Vec<u8>, VolumeError> {
    let (bytes, len) = read_prefix(path, MAX_HEADER_BYTES)?;
    if len > MAX_HEADER_BYTES {
        return Err(format_err(
            path,
            "json",
            format!("the metadata is {len} bytes; at most {MAX_HEADER_BYTES} are read"),
        ));
    }
    Ok(bytes)
}

/// True when the array metadata declares big-endian values (v2 `dtype` starting with `>`, v3
/// a `bytes` codec with `"endian": "big"`). Only reported in [`VolumeMeta`]; `zarrs` decodes.
pub(super) fn declared_big_endian(text: &[u8], version: ZarrVersion) -> bool {
    let Ok(Value::Object(doc)) = serde_json::from_slice::<Value>(text) else {
        return false;
    };
    match version {
        ZarrVersion::V2 => doc
            .get("dtype")
            .and_then(Value::as_str)
            .is_some_and(|d| d.starts_with('>')),
        ZarrVersion::V3 => doc
            .get("codecs")
            .and_then(Value::as_array)
            .is_some_and(|codecs| {
                codecs.iter().any(|c| {
                    c.get("name").and_then(Value::as_str) == Some("bytes")
                        && c.pointer("/configuration/endian").and_then(Value::as_str) == Some("big")
                })
            }),
    }
}

/// The stored type of the array's data type.
pub(super) fn stored_type(
    array: &Array<dyn ReadableStorageTraits>,
    array_doc: &Path,
    version: ZarrVersion,
) -> Result<StoredType, VolumeError> {
    use zarrs::array::data_type::{
        Float32DataType, Float64DataType, Int16DataType, Int32DataType, Int8DataType,
        UInt16DataType, UInt32DataType, UInt8DataType,
    };
    let dt = array.data_type();
    Ok(if dt.is::<UInt8DataType>() {
        StoredType::U8
    } else if dt.is::<Int8DataType>() {
        StoredType::I8
    } else if dt.is::<UInt16DataType>() {
        StoredType::U16
    } else if dt.is::<Int16DataType>() {
        StoredType::I16
    } else if dt.is::<UInt32DataType>() {
        StoredType::U32
    } else if dt.is::<Int32DataType>() {
        StoredType::I32
    } else if dt.is::<Float32DataType>() {
        StoredType::F32
    } else if dt.is::<Float64DataType>() {
        StoredType::F64
    } else {
        return Err(format_err(
            array_doc,
            version.dtype_field(),
            format!(
                "data type {dt} is not supported (uint8, int8, uint16, int16, uint32, int32, \
                 float32, float64)"
            ),
        ));
    })
}

/// Maps `zarrs`' array-opening errors to the metadata field at fault.
pub(super) fn array_create_err(
    array_doc: &Path,
    version: ZarrVersion,
    e: ArrayCreateError,
) -> VolumeError {
    let field = match &e {
        ArrayCreateError::DataTypeCreateError(_) => version.dtype_field(),
        ArrayCreateError::InvalidFillValue { .. }
        | ArrayCreateError::InvalidFillValueMetadata { .. } => "fill_value",
        ArrayCreateError::CodecsCreateError(_) => version.codecs_field(),
        ArrayCreateError::StorageTransformersCreateError(_) => "storage_transformers",
        ArrayCreateError::ChunkGridCreateError(_)
        | ArrayCreateError::InvalidChunkGridDimensionality(..)
        | ArrayCreateError::InvalidSubchunkShape(_) => version.chunks_field(),
        ArrayCreateError::ChunkKeyEncodingCreateError(_) => match version {
            ZarrVersion::V2 => "dimension_separator",
            ZarrVersion::V3 => "chunk_key_encoding",
        },
        ArrayCreateError::InvalidDimensionNames(..) => "dimension_names",
        ArrayCreateError::AdditionalFieldUnsupportedError(a) => {
            return format_err(array_doc, short(a.name()), e.to_string())
        }
        ArrayCreateError::MissingMetadata => {
            return format_err(
                array_doc,
                "path",
                "the dataset's array metadata is missing".to_string(),
            )
        }
        ArrayCreateError::StorageError(StorageError::IOError(io)) => {
            return VolumeError::Io {
                path: array_doc.to_path_buf(),
                source: std::io::Error::new(io.kind(), io.to_string()),
            }
        }
        ArrayCreateError::StorageError(StorageError::InvalidMetadata(..)) => "json",
        ArrayCreateError::StorageError(e) if !matches!(e, StorageError::IOError(_)) => {
            return source::storage_err(array_doc, e)
        }
        // Raised for the byte order of `dtype`, or for `order` / `filters` / `compressor` (the
        // codec chain; the message names the part).
        ArrayCreateError::UnsupportedZarrV2Array(m) if m.contains("endian") => "dtype",
        ArrayCreateError::UnsupportedZarrV2Array(_) => "compressor",
        ArrayCreateError::NodePathError(_) | ArrayCreateError::StorageError(_) => "path",
    };
    format_err(array_doc, field, e.to_string())
}

/// A chunk cropped to the array: its first voxel (x, y, z), its extent (x, y, z), its values (x
/// fastest) and the stored bytes fetched.
pub(super) type CroppedChunk<U> = (Vec<usize>, [usize; 3], Vec<U>, u64);

impl ZarrLevel {
    /// The file (or remote object) of the chunk at `indices`.
    fn chunk_path(&self, indices: &[u64]) -> PathBuf {
        self.location
            .object_name(self.array.chunk_key(indices).as_str())
    }

    /// The chunks of the level read so far that exist, and the chunks the level has.
    pub(super) fn chunks_found(&self) -> (u64, u64) {
        let chunks: u64 = self.array.chunk_grid_shape().iter().product();
        let found = self.found_chunks.load(std::sync::atomic::Ordering::Relaxed);
        (found, chunks)
    }

    /// Reads volume z planes `z` into a new buffer (reserved fallibly), x fastest, each stored
    /// value mapped by `map`.
    pub(super) fn read_all<T: ElementOwned + Copy, U: Copy + Default>(
        &self,
        z: Range<usize>,
        map: impl Fn(T) -> U,
    ) -> Result<Vec<U>, VolumeError> {
        let count = self.dims[0] * self.dims[1] * z.len();
        let mut out: Vec<U> = Vec::new();
        out.try_reserve_exact(count).map_err(|_| {
            io_err(&self.array_doc)(std::io::Error::from(std::io::ErrorKind::OutOfMemory))
        })?;
        out.resize(count, U::default());
        self.read_planes(z, &mut out, map)?;
        Ok(out)
    }

    /// The chunk at volume chunk coordinates `c` (x, y, z), cropped to the array: its first voxel,
    /// its extent (x, y, z), its values (x fastest, each stored value mapped by `map`; the fill
    /// value for a missing chunk) and the stored bytes fetched (0 when missing).
    pub(super) fn read_chunk_cropped<T: ElementOwned + Copy, U: Copy>(
        &self,
        c: [u64; 3],
        map: impl Fn(T) -> U,
    ) -> Result<CroppedChunk<U>, VolumeError> {
        let chunks_field = self.version.chunks_field();
        let ndim = self.array.chunk_grid_shape().len();
        let mut indices = vec![0u64; ndim];
        indices[ndim - 1] = c[0];
        indices[ndim - 2] = c[1];
        indices[ndim - 3] = c[2];
        let decoded_bytes = self.chunk_bytes(&indices, chunks_field)?;
        let bounded = self
            .array
            .chunk_subset_bounded(&indices)
            .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?;
        let start = bounded.start();
        let shape = bounded.shape();
        let origin = vec![
            start[ndim - 1] as usize,
            start[ndim - 2] as usize,
            start[ndim - 3] as usize,
        ];
        let extent = [
            shape[ndim - 1] as usize,
            shape[ndim - 2] as usize,
            shape[ndim - 3] as usize,
        ];
        let count = extent.iter().product::<usize>();
        let Some(encoded) = self
            .array
            .retrieve_encoded_chunk(&indices)
            .map_err(|e| self.chunk_err(&indices, ArrayError::StorageError(e)))?
        else {
            let fill = map(self.fill_value::<T>()?);
            return Ok((origin, extent, vec![fill; count], 0));
        };
        let fetched = encoded.len() as u64;
        let values =
            self.decode_chunk::<T>(&indices, encoded, decoded_bytes, self.outer_codec())?;
        let full: Vec<usize> = self
            .array
            .chunk_shape(&indices)
            .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?
            .iter()
            .map(|d| d.get() as usize)
            .collect();
        if values.len() != full.iter().product::<usize>() {
            return Err(format_err(
                &self.chunk_path(&indices),
                chunks_field,
                format!(
                    "chunk {indices:?} decoded to {} values, expected {}",
                    values.len(),
                    full.iter().product::<usize>()
                ),
            ));
        }
        let (fy, fx) = (full[ndim - 2], full[ndim - 1]);
        let [cx, cy, cz] = extent;
        let mut out = Vec::with_capacity(count);
        for z in 0..cz {
            for y in 0..cy {
                let src = fx * (y + fy * z);
                out.extend(values[src..src + cx].iter().map(|&v| map(v)));
            }
        }
        Ok((origin, extent, out, fetched))
    }

    /// The object name of the chunk at volume chunk coordinates `c` (x, y, z).
    pub(super) fn chunk_name(&self, c: [u64; 3]) -> PathBuf {
        let ndim = self.array.chunk_grid_shape().len();
        let mut indices = vec![0u64; ndim];
        indices[ndim - 1] = c[0];
        indices[ndim - 2] = c[1];
        indices[ndim - 3] = c[2];
        self.chunk_path(&indices)
    }

    /// The largest decoded chunk, in bytes (checked against [`MAX_CHUNK_BYTES`]).
    pub(super) fn max_chunk_bytes(&self) -> Result<u64, VolumeError> {
        let chunks_field = self.version.chunks_field();
        let grid = self.array.chunk_grid_shape().to_vec();
        if grid.contains(&0) {
            return Ok(0);
        }
        // Regular grids (all zarrs builds here) have one chunk shape: the first chunk's.
        let first = vec![0u64; grid.len()];
        self.chunk_bytes(&first, chunks_field)
    }

    /// Decoded bytes of the chunk at `indices`, refused beyond [`MAX_CHUNK_BYTES`].
    fn chunk_bytes(&self, indices: &[u64], chunks_field: &str) -> Result<u64, VolumeError> {
        let chunk_shape = self
            .array
            .chunk_shape(indices)
            .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?;
        let elem_bytes = self.stored.size_bytes() as u64;
        chunk_shape
            .iter()
            .try_fold(elem_bytes, |acc, d| acc.checked_mul(d.get()))
            .filter(|&b| b <= MAX_CHUNK_BYTES)
            .ok_or_else(|| {
                format_err(
                    &self.array_doc,
                    chunks_field,
                    format!(
                        "chunk shape {:?} exceeds the {} MiB chunk size limit",
                        chunk_shape.iter().map(|d| d.get()).collect::<Vec<_>>(),
                        MAX_CHUNK_BYTES >> 20
                    ),
                )
            })
    }

    /// Reads volume z planes `z` into `out` (exactly `dims.x * dims.y * z.len()` values, x
    /// fastest), each stored value mapped by `map`: every chunk whose z range meets `z` is
    /// decoded whole (so a chunk that does not hold its full shape is an error even where the
    /// array ends inside it) and its part inside the array and `z` is copied. Missing chunks
    /// read as the fill value, written only where they meet the array (a missing chunk far
    /// larger than the array costs no memory).
    pub(super) fn read_planes<T: ElementOwned + Copy, U: Copy>(
        &self,
        z: Range<usize>,
        out: &mut [U],
        map: impl Fn(T) -> U,
    ) -> Result<(), VolumeError> {
        let chunks_field = self.version.chunks_field();
        let [nx, ny, _] = self.dims;
        if out.len() != nx * ny * z.len() {
            return Err(format_err(
                &self.array_doc,
                "shape",
                format!(
                    "{} values asked for z planes {z:?} of {nx}x{ny} voxels",
                    out.len()
                ),
            ));
        }
        let grid = self.array.chunk_grid_shape().to_vec();
        let ndim = grid.len();
        if grid.contains(&0) || z.is_empty() {
            return Ok(());
        }
        let za = ndim - 3;
        let outer = self.outer_codec();
        let mut indices = vec![0u64; ndim];
        // The chunk rows along the array's z axis that meet `z`.
        let mut rows = Vec::new();
        for i in 0..grid[za] {
            indices[za] = i;
            let bounded = self
                .array
                .chunk_subset_bounded(&indices)
                .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?;
            let (s, e) = (bounded.start()[za] as usize, bounded.shape()[za] as usize);
            if s < z.end && s + e > z.start {
                rows.push(i);
            }
        }
        for &row in &rows {
            indices.iter_mut().for_each(|i| *i = 0);
            indices[za] = row;
            loop {
                self.copy_chunk(&indices, &z, out, &map, chunks_field, outer)?;
                // Next chunk in this row, last axis fastest (the z axis stays at `row`).
                let mut axis = ndim;
                let done = loop {
                    if axis == 0 {
                        break true;
                    }
                    axis -= 1;
                    if axis == za {
                        continue;
                    }
                    indices[axis] += 1;
                    if indices[axis] < grid[axis] {
                        break false;
                    }
                    indices[axis] = 0;
                };
                if done {
                    break;
                }
            }
        }
        Ok(())
    }

    /// Decodes the chunk at `indices` and copies its part inside the array and the planes `z`; a
    /// missing chunk writes the fill value into that part only.
    fn copy_chunk<T: ElementOwned + Copy, U: Copy>(
        &self,
        indices: &[u64],
        z: &Range<usize>,
        out: &mut [U],
        map: &impl Fn(T) -> U,
        chunks_field: &str,
        outer: OuterCodec,
    ) -> Result<(), VolumeError> {
        let ndim = indices.len();
        let [nx, ny, _] = self.dims;
        let decoded_bytes = self.chunk_bytes(indices, chunks_field)?;
        let chunk_shape = self
            .array
            .chunk_shape(indices)
            .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?;
        let bounded = self
            .array
            .chunk_subset_bounded(indices)
            .map_err(|e| format_err(&self.array_doc, chunks_field, e.to_string()))?;
        if !bounded.shape().iter().all(|&s| s > 0) {
            return Ok(());
        }
        let start = bounded.start();
        let extent = bounded.shape();
        let at = |a: usize| (start[a] as usize, extent[a] as usize);
        let ((z0, cz), (y0, cy), (x0, cx)) = (at(ndim - 3), at(ndim - 2), at(ndim - 1));
        // Leading axes have size 1: their index is 0.
        let (lo, hi) = (z0.max(z.start), (z0 + cz).min(z.end));
        let Some(encoded) = self
            .array
            .retrieve_encoded_chunk(indices)
            .map_err(|e| self.chunk_err(indices, ArrayError::StorageError(e)))?
        else {
            // A missing chunk: its part inside the array is the fill value, written straight
            // into `out` (never a chunk-sized buffer of it).
            let fill = map(self.fill_value::<T>()?);
            for vz in lo..hi {
                for y in 0..cy {
                    let dst = x0 + nx * (y0 + y + ny * (vz - z.start));
                    out[dst..dst + cx].fill(fill);
                }
            }
            return Ok(());
        };
        self.found_chunks
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let values = self.decode_chunk::<T>(indices, encoded, decoded_bytes, outer)?;
        let full: Vec<usize> = chunk_shape.iter().map(|d| d.get() as usize).collect();
        let (fy, fx) = (full[ndim - 2], full[ndim - 1]);
        if values.len() != full.iter().product::<usize>() {
            return Err(format_err(
                &self.chunk_path(indices),
                chunks_field,
                format!(
                    "chunk {indices:?} decoded to {} values, expected {}",
                    values.len(),
                    full.iter().product::<usize>()
                ),
            ));
        }
        for vz in lo..hi {
            let cz = vz - z0;
            for y in 0..cy {
                let src = fx * (y + fy * cz);
                let dst = x0 + nx * (y0 + y + ny * (vz - z.start));
                for (o, &v) in out[dst..dst + cx].iter_mut().zip(&values[src..src + cx]) {
                    *o = map(v);
                }
            }
        }
        Ok(())
    }

    /// The codec whose output the stored chunks are (see [`OuterCodec`]).
    fn outer_codec(&self) -> OuterCodec {
        serde_json::to_value(self.array.metadata())
            .map_or(OuterCodec::Other, |doc| OuterCodec::of(&doc))
    }

    /// Decodes the stored chunk `encoded` at `indices` (of `decoded_bytes` bytes decoded) after
    /// checking the size it declares, as `zarrs`' `retrieve_chunk` does.
    fn decode_chunk<T: ElementOwned>(
        &self,
        indices: &[u64],
        encoded: Vec<u8>,
        decoded_bytes: u64,
        outer: OuterCodec,
    ) -> Result<Vec<T>, VolumeError> {
        if encoded.is_empty() && decoded_bytes > 0 {
            // Named as what it is, not as a field of the metadata (review D26).
            return Err(format_err(
                &self.chunk_path(indices),
                "chunk data",
                format!(
                    "chunk {indices:?} is empty (0 bytes), where {decoded_bytes} bytes decoded \
                     are expected: a chunk written cut short (a missing chunk has no file and \
                     reads as the fill value)"
                ),
            ));
        }
        outer.check(&encoded, decoded_bytes).map_err(|m| {
            format_err(
                &self.chunk_path(indices),
                self.version.codecs_field(),
                format!("chunk {indices:?} does not decode: {m}"),
            )
        })?;
        let dt = self.array.data_type();
        let shape = self
            .array
            .chunk_shape(indices)
            .map_err(|e| self.chunk_err(indices, e))?;
        let bytes = self
            .array
            .codecs()
            .decode(
                Cow::Owned(encoded),
                &shape,
                dt,
                self.array.fill_value(),
                &CodecOptions::default(),
            )
            .map_err(|e| self.chunk_err(indices, ArrayError::CodecError(e)))?;
        let shape: Vec<u64> = shape.iter().map(|d| d.get()).collect();
        Vec::<T>::from_array_bytes(bytes.into_owned(), &shape, dt)
            .map_err(|e| self.chunk_err(indices, e))
    }

    /// The array's fill value as one stored value.
    fn fill_value<T: ElementOwned + Copy>(&self) -> Result<T, VolumeError> {
        let dt = self.array.data_type();
        ArrayBytes::new_fill_value(dt, 1, self.array.fill_value())
            .map_err(|e| e.to_string())
            .and_then(|b| Vec::<T>::from_array_bytes(b, &[1], dt).map_err(|e| e.to_string()))
            .and_then(|v| v.first().copied().ok_or_else(|| "no value".to_string()))
            .map_err(|m| {
                format_err(
                    &self.array_doc,
                    "fill_value",
                    format!("the fill value does not decode as one {dt} value: {m}"),
                )
            })
    }

    /// A chunk that could not be read or decoded.
    fn chunk_err(&self, indices: &[u64], e: ArrayError) -> VolumeError {
        let file = self.chunk_path(indices);
        // A failed read (a file, a fetch), not a decode: no field is at fault.
        let e = match e {
            ArrayError::StorageError(se)
            | ArrayError::CodecError(zarrs::array::CodecError::StorageError(se)) => {
                return source::storage_err(&file, &se)
            }
            e => e,
        };
        let field = match &e {
            ArrayError::CodecError(
                zarrs::array::CodecError::UnexpectedChunkDecodedSize(_)
                | zarrs::array::CodecError::InvalidNumberOfElements(_)
                | zarrs::array::CodecError::InvalidArrayShape(_)
                | zarrs::array::CodecError::ExpectedFixedLengthBytes(_),
            ) => self.version.chunks_field(),
            ArrayError::UnexpectedChunkDecodedSize(..)
            | ArrayError::InvalidBytesInputSize(..)
            | ArrayError::UnexpectedChunkDecodedShape(..) => self.version.chunks_field(),
            _ => self.version.codecs_field(),
        };
        format_err(
            &file,
            field,
            format!("chunk {indices:?} does not decode: {e}"),
        )
    }
}
