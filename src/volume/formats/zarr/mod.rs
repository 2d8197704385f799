//! OME-Zarr images (Zarr v2 and v3) through the `zarrs` crate.
//!
//! A path names the root folder of an OME-Zarr image (usually `NAME.zarr` / `NAME.ome.zarr`):
//!
//! - **Zarr v3, OME-Zarr 0.5**: the root `zarr.json` is a group (`"node_type": "group"`) whose
//!   `attributes.ome.multiscales` describes the levels (a bare `attributes.multiscales` is accepted
//!   too).
//! - **Zarr v2, OME-Zarr 0.1-0.4**: the root `.zattrs` holds `multiscales`.
//! - A plain Zarr array (root `zarr.json` with `"node_type": "array"`, or a root `.zarray`) loads
//!   as a volume with unit spacing, its last three axes being z, y, x.
//!
//! Of the first multiscale, the dataset of the requested level (0, the finest, by default) is
//! opened with `zarrs` (chunk grid, chunk keys, codecs, fill value for missing chunks). Axes:
//! the last three must be spatial (`"type": "space"`, or named `z`, `y`, `x` where no type is
//! given) and are taken as volume z, y, x (the last array axis varies fastest, like the volume's
//! x); up to two leading axes (time, channel, ...) are allowed when their size is 1. OME-Zarr
//! before 0.3 has no `axes`: the last three array axes are then z, y, x. Spacing and origin come
//! from the dataset's `coordinateTransformations` (`scale`, then optional `translation`),
//! followed by the multiscale's own ones if present: spacing `s_d * s_m`, origin
//! `t_d * s_m + t_m` per axis. Units are not interpreted.
//!
//! Data types: `uint8`, `int8`, `uint16`, `int16`, `uint32`, `int32`, `float32`, `float64` (v2:
//! `|u1`, `<i2`, `>f4`, ...), in either byte order, mapped to the volume's scalar types like every
//! other format (see [`super`]: i16 is stored as u16 + [`I16_OFFSET`](super::I16_OFFSET), ...).
//! Codecs built in: raw, gzip, zlib, zstd, Blosc (lz4, lz4hc, zstd, zlib, snappy, blosclz; any
//! shuffle) and sharding (with crc32c index checksums). Missing chunks read as the fill value,
//! written only where they meet the array.
//!
//! # Safety against hostile stores
//!
//! Metadata documents are read only up to [`MAX_HEADER_BYTES`]. The volume size is checked with
//! checked arithmetic against [`MAX_VOLUME_BYTES`](super::MAX_VOLUME_BYTES), and every chunk's
//! decoded size against [`MAX_CHUNK_BYTES`], before anything is allocated or decoded; the volume
//! buffer is reserved fallibly. Chunks are decoded one at a time (`zarrs`), each bounded to the
//! array, and copied into the volume. A chunk that does not decode to its shape (a truncated raw
//! chunk, corrupt gzip / Blosc / Zstd) is a [`VolumeError::Format`] naming the chunk file.
//! The decoded size a zstd frame or a Blosc header declares is checked against the chunk's
//! before `zarrs` reserves it (`declared.rs`; a 17-byte zstd chunk declaring 1 TiB aborted the
//! process), and a gzip or zlib chunk is inflated once into nothing, stopping one byte past the
//! chunk's size, before `zarrs` decodes it (a 0.5 MB gzip chunk reached 1.1 GB before the
//! size check). Limitations: zstd frames that declare no size are decoded by `zarrs` without an
//! output limit (they grow only with the data streamed, but a bomb can still allocate many
//! times the file's size), and the chunks inside a shard are not checked.
//!
//! # Remote images
//!
//! A [`ZarrLocation`] is a local folder, `s3://BUCKET/PATH.zarr` on any S3-compatible object
//! store (endpoint, region and credentials from the usual AWS environment variables:
//! `AWS_ENDPOINT_URL`, `AWS_REGION`, `AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`,
//! `AWS_SESSION_TOKEN`, `AWS_ALLOW_HTTP` for a plain-HTTP endpoint, `AWS_SKIP_SIGNATURE=true`
//! for a public bucket), or `http(s)://HOST/PATH.zarr` (GET, and Range requests for partial
//! reads). Remote objects are fetched through `object_store` with the timeouts and bounded
//! retries of [`RemoteOptions`]; every location is read by the same chunk and metadata code
//! (zarrs over an `Arc<dyn ReadableStorageTraits>`). A missing chunk object (HTTP 404) is the
//! fill value, as for a missing chunk file; a missing metadata document is a
//! [`VolumeError::Io`] (not found) naming it; a failed fetch is a [`VolumeError::Remote`] naming
//! the object's URL.
//!
//! [`parse_zarr_root`] parses a root metadata document from bytes (the fuzz target's entry
//! point); [`load_zarr`] / [`load_zarr_level`] load a folder, [`load_zarr_at`] any location.
//!
//! Files: this one loads (`load_zarr`, `load_zarr_level`, `load_zarr_at`); `ome.rs` parses the
//! root metadata (Zarr version, OME-Zarr multiscales, axes and coordinate transformations);
//! `array.rs` opens an array through zarrs and reads its chunks under the limits above;
//! `declared.rs` checks the decoded size a compressed chunk declares; `location.rs` parses
//! locations; `remote.rs` opens their storage; `source.rs` probes and reads the metadata
//! documents.

mod array;
mod chunks;
mod declared;
mod location;
mod ome;
mod remote;
mod slabs;
mod source;

pub use chunks::{ZarrChunk, ZarrChunks};
pub use location::ZarrLocation;
pub use ome::{parse_zarr_root, OmeAxis, OmeDataset, OmeMultiscale, ZarrRoot, ZarrVersion};
pub use remote::{RemoteObject, RemoteOptions};
pub use slabs::ZarrSlabs;

use super::read::{format_err, io_err, layout, read_prefix, Layout};
use super::{FileFormat, LoadedVolume, StoredType, VolumeMeta, MAX_HEADER_BYTES};
use crate::volume::{Volume, VolumeError, VoxelData};
use array::*;
use glam::Vec3;
use ome::*;
use serde_json::{Map, Value};
use source::ZarrSource;
use std::path::{Path, PathBuf};
use zarrs::array::{Array, ArrayCreateError, ArrayError, ElementOwned};
use zarrs::storage::{ReadableStorageTraits, StorageError};

/// The largest decoded chunk accepted, in bytes: 1 GiB.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Chunks past this many are refused when they are smaller than [`MIN_CHUNK_BYTES`] (review
/// D8: 256^3 chunks of one voxel took 52 s and 2.8 GB to read as a blank volume).
pub const MAX_TINY_CHUNKS: u64 = 1 << 20;

/// Decoded bytes below which a chunk counts as tiny ([`MAX_TINY_CHUNKS`]).
pub const MIN_CHUNK_BYTES: u64 = 512;

/// Refuses an array of more than [`MAX_TINY_CHUNKS`] chunks of under [`MIN_CHUNK_BYTES`]
/// decoded bytes each, before any chunk is looked up: each costs a lookup (a file or an object
/// request) that its few voxels never repay.
fn check_chunk_count<TStorage: ?Sized>(
    array: &Array<TStorage>,
    array_doc: &Path,
    version: ZarrVersion,
    stored: StoredType,
) -> Result<(), VolumeError> {
    let count = array
        .chunk_grid_shape()
        .iter()
        .try_fold(1u64, |a, &c| a.checked_mul(c))
        .unwrap_or(u64::MAX);
    let first = vec![0u64; array.chunk_grid_shape().len()];
    let Ok(shape) = array.chunk_shape(&first) else {
        return Ok(());
    };
    let chunk_bytes = shape
        .iter()
        .try_fold(stored.size_bytes() as u64, |a, d| a.checked_mul(d.get()))
        .unwrap_or(u64::MAX);
    if count > MAX_TINY_CHUNKS && chunk_bytes < MIN_CHUNK_BYTES {
        return Err(format_err(
            array_doc,
            version.chunks_field(),
            format!(
                "{count} chunks of {chunk_bytes} bytes ({:?} voxels each): more than \
                 {MAX_TINY_CHUNKS} chunks under {MIN_CHUNK_BYTES} bytes, whose lookups would \
                 cost far more than their voxels; rechunk the array to larger chunks",
                shape.iter().map(|d| d.get()).collect::<Vec<_>>()
            ),
        ));
    }
    Ok(())
}

/// Axes an OME-Zarr image may have besides z, y, x (time, channel), each of size 1.
const MAX_LEADING_AXES: usize = 2;

/// Loads level 0 (the finest) of the OME-Zarr image (or plain Zarr array) at `root`. See the
/// module docs.
pub fn load_zarr(root: &Path) -> Result<LoadedVolume, VolumeError> {
    load_zarr_level(root, 0)
}

/// Loads level `level` (index into `multiscales[0].datasets`, 0 the finest) of the OME-Zarr
/// image at `root`; a plain Zarr array has only level 0. A level that does not exist is an
/// error on the field `datasets`.
pub fn load_zarr_level(root: &Path, level: usize) -> Result<LoadedVolume, VolumeError> {
    load_zarr_at(
        &ZarrLocation::Local(root.to_path_buf()),
        level,
        &RemoteOptions::default(),
    )
}

/// Loads level `level` of the OME-Zarr image at `location`, a local folder or a remote store
/// (fetched as `options` says), as [`load_zarr_level`] does.
pub fn load_zarr_at(
    location: &ZarrLocation,
    level: usize,
    options: &RemoteOptions,
) -> Result<LoadedVolume, VolumeError> {
    let level = open_level(location, level, options)?;
    let root = &level.root;
    super::read::check_layout_memory(root, &level.layout)?;
    let z = 0..level.dims[2];
    let data = match level.stored {
        StoredType::U8 => VoxelData::U8(level.read_all::<u8, u8>(z, |v| v)?),
        StoredType::I8 => VoxelData::U8(level.read_all::<i8, u8>(z, |v| (v as u8) ^ 0x80)?),
        StoredType::U16 => VoxelData::U16(level.read_all::<u16, u16>(z, |v| v)?),
        StoredType::I16 => VoxelData::U16(level.read_all::<i16, u16>(z, |v| (v as u16) ^ 0x8000)?),
        StoredType::U32 => VoxelData::F32(level.read_all::<u32, f32>(z, |v| v as f32)?),
        StoredType::I32 => VoxelData::F32(level.read_all::<i32, f32>(z, |v| v as f32)?),
        StoredType::F32 => VoxelData::F32(level.read_all::<f32, f32>(z, |v| v)?),
        StoredType::F64 => VoxelData::F32(level.read_all::<f64, f32>(z, |v| v as f32)?),
    };
    let mut meta = level.meta.clone();
    meta.chunks_found = Some(level.chunks_found());
    Ok(LoadedVolume {
        volume: Volume::new(level.layout.dims, level.spacing, data).map_err(|e| e.in_file(root))?,
        meta,
    })
}

/// One level of an OME-Zarr image, opened and checked (axes, shape, data type, spacing), before
/// any chunk is read.
pub(super) struct ZarrLevel {
    pub(super) array: Array<dyn ReadableStorageTraits>,
    /// Where the image is (chunk names in errors).
    pub(super) location: ZarrLocation,
    /// The image's root as errors name it (its folder or URL).
    pub(super) root: PathBuf,
    pub(super) array_doc: PathBuf,
    pub(super) version: ZarrVersion,
    /// Volume x, y, z sizes (array axes reversed).
    pub(super) dims: [usize; 3],
    pub(super) layout: Layout,
    pub(super) stored: StoredType,
    pub(super) spacing: Vec3,
    pub(super) meta: VolumeMeta,
    /// Levels of the image (1 for a plain array).
    pub(super) levels: usize,
    /// Chunks read so far that exist (a missing one reads as the fill value).
    pub(super) found_chunks: std::sync::atomic::AtomicU64,
}

/// Opens level `level` of the image at `location` (see [`load_zarr_level`]) without reading a
/// chunk.
pub(super) fn open_level(
    location: &ZarrLocation,
    level: usize,
    options: &RemoteOptions,
) -> Result<ZarrLevel, VolumeError> {
    let src = ZarrSource::open(location, options)?;
    let root = &location.root_name();
    let (version, root_desc) = if let Some(bytes) = src.find_doc("zarr.json")? {
        (
            ZarrVersion::V3,
            parse_zarr_root(&src.name("zarr.json"), &bytes, ZarrVersion::V3)?,
        )
    } else if src.exists(".zarray")? {
        (ZarrVersion::V2, ZarrRoot::Array)
    } else if let Some(bytes) = src.find_doc(".zattrs")? {
        (
            ZarrVersion::V2,
            parse_zarr_root(&src.name(".zattrs"), &bytes, ZarrVersion::V2)?,
        )
    } else if src.exists(".zgroup")? {
        return Err(format_err(
            &src.name(".zattrs"),
            "multiscales",
            "missing: the Zarr v2 group has no .zattrs, so no OME-Zarr multiscales",
        ));
    } else {
        return Err(format_err(
            root,
            "zarr_format",
            "not a Zarr store: no zarr.json (v3) nor .zattrs / .zgroup / .zarray (v2)",
        ));
    };
    let group_doc = src.name(version.attributes_file());
    let levels = match &root_desc {
        ZarrRoot::Array => 1,
        ZarrRoot::Multiscales(m) => m.datasets.len(),
    };
    let (dataset, axes) = match root_desc {
        ZarrRoot::Array => {
            if level != 0 {
                return Err(format_err(
                    root,
                    "datasets",
                    format!("level {level} requested, but a plain array has only level 0"),
                ));
            }
            (None, Vec::new())
        }
        ZarrRoot::Multiscales(m) => {
            let count = m.datasets.len();
            let Some(d) = m.datasets.into_iter().nth(level) else {
                return Err(format_err(
                    &group_doc,
                    "datasets",
                    format!("level {level} requested, but the image has {count} levels"),
                ));
            };
            (Some(d), m.axes)
        }
    };
    let array_key = match &dataset {
        Some(d) => format!("{}/{}", d.path, version.array_file()),
        None => version.array_file().to_string(),
    };
    let array_doc = src.name(&array_key);
    let array_text = src.read_doc(&array_key)?;
    let big_endian = declared_big_endian(&array_text, version);

    let node = match &dataset {
        Some(d) => format!("/{}", d.path),
        None => "/".to_string(),
    };
    let array = Array::open(src.storage.clone(), &node)
        .map_err(|e| array_create_err(&array_doc, version, e))?;

    // Axes and shape.
    let shape = array.shape().to_vec();
    let ndim = shape.len();
    if !axes.is_empty() && axes.len() != ndim {
        return Err(format_err(
            &group_doc,
            "axes",
            format!(
                "{} axes, but the array {} has {ndim} dimensions",
                axes.len(),
                array_doc.display()
            ),
        ));
    }
    let shape_field = "shape";
    if !(3..=3 + MAX_LEADING_AXES).contains(&ndim) {
        return Err(format_err(
            &array_doc,
            shape_field,
            format!("{ndim} dimensions {shape:?}; a volume needs 3 (z, y, x), after at most {MAX_LEADING_AXES} of size 1"),
        ));
    }
    let lead = ndim - 3;
    if let Some(i) = (0..lead).find(|&i| shape[i] != 1) {
        let name = axes
            .get(i)
            .map_or_else(|| format!("{i}"), |a| short(&a.name));
        return Err(format_err(
            &array_doc,
            shape_field,
            format!(
                "axis {name} has size {} in shape {shape:?}; only one time point / channel can \
                 be loaded as a volume",
                shape[i]
            ),
        ));
    }
    let stored = stored_type(&array, &array_doc, version)?;
    let dims = [shape[ndim - 1], shape[ndim - 2], shape[ndim - 3]];
    let lay = layout(&array_doc, shape_field, dims, stored)?;
    check_chunk_count(&array, &array_doc, version, stored)?;

    // Spacing and origin (x, y, z = the last three axes, reversed).
    let (spacing, origin) = match &dataset {
        Some(d) if !d.scale.is_empty() => {
            if d.scale.len() != ndim {
                return Err(format_err(
                    &group_doc,
                    "coordinateTransformations",
                    format!(
                        "{} scale values, but the array has {ndim} dimensions",
                        d.scale.len()
                    ),
                ));
            }
            let s = [d.scale[ndim - 1], d.scale[ndim - 2], d.scale[ndim - 3]];
            let t = [
                d.translation[ndim - 1],
                d.translation[ndim - 2],
                d.translation[ndim - 3],
            ];
            (s, t)
        }
        _ => ([1.0; 3], [0.0; 3]),
    };
    let spacing_f32 = Vec3::from_array(spacing.map(|s| s as f32));
    if !(spacing_f32.is_finite() && spacing_f32.min_element() > 0.0) {
        return Err(format_err(
            &group_doc,
            "coordinateTransformations",
            format!("spacing {spacing:?} does not fit in f32"),
        ));
    }

    let mut meta = VolumeMeta::plain(FileFormat::Zarr, stored, big_endian);
    meta.origin = origin;
    Ok(ZarrLevel {
        array,
        location: src.location,
        root: root.to_path_buf(),
        array_doc,
        version,
        dims: [dims[0] as usize, dims[1] as usize, dims[2] as usize],
        layout: lay,
        stored,
        spacing: spacing_f32,
        meta,
        levels,
        found_chunks: std::sync::atomic::AtomicU64::new(0),
    })
}
