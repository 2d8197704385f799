//! [`ZarrChunks`]: one level of an OME-Zarr image read chunk by chunk (the streaming brick
//! source's access to it): its geometry, and one chunk at a time decoded and cropped to the
//! array, by the loader's own chunk reader (so the values are the loader's), with the stored
//! bytes fetched counted.

use super::array::CroppedChunk;
use super::{open_level, RemoteOptions, StoredType, ZarrLevel, ZarrLocation};
use crate::volume::formats::VolumeMeta;
use crate::volume::{ScalarType, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// One chunk of a [`ZarrChunks`] level, cropped to the array.
#[derive(Clone, Debug, PartialEq)]
pub struct ZarrChunk {
    /// The chunk's first voxel (x, y, z).
    pub origin: UVec3,
    /// Its voxels inside the array (x, y, z).
    pub extent: UVec3,
    /// Its values, x fastest, in the volume's scalar type (as [`super::load_zarr_at`] maps them).
    pub data: VoxelData,
    /// Stored (encoded) bytes fetched for it: 0 for a missing chunk (the fill value).
    pub stored_bytes: u64,
}

impl ZarrChunk {
    /// Decoded bytes held.
    pub fn decoded_bytes(&self) -> usize {
        self.data.len() * self.data.scalar_type().size_bytes()
    }
}

/// One level of an OME-Zarr image (or plain Zarr array), opened for reading single chunks.
/// `&self` methods may be called from several threads at once (chunks are fetched
/// concurrently).
pub struct ZarrChunks {
    level: ZarrLevel,
    /// The level's index in the image's multiscale (0 the finest).
    index: usize,
    /// How it was fetched (to open the image's other levels alike).
    options: RemoteOptions,
    chunk_shape: UVec3,
    grid: UVec3,
    fetched: AtomicU64,
    fetches: AtomicU64,
}

impl std::fmt::Debug for ZarrChunks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZarrChunks")
            .field("root", &self.level.root)
            .field("dims", &self.dims())
            .field("chunk_shape", &self.chunk_shape)
            .finish()
    }
}

impl ZarrChunks {
    /// Opens level `level` of the image at `location` (the checks of
    /// [`super::load_zarr_at`]), reading its metadata but no chunk.
    pub fn open(
        location: &ZarrLocation,
        level: usize,
        options: &RemoteOptions,
    ) -> Result<Self, VolumeError> {
        let index = level;
        let level = open_level(location, level, options)?;
        level.max_chunk_bytes()?;
        let grid_shape = level.array.chunk_grid_shape().to_vec();
        let ndim = grid_shape.len();
        let dims = level.layout.dims;
        let (chunk_shape, grid) = if grid_shape.contains(&0) {
            (UVec3::ONE, UVec3::ZERO)
        } else {
            let first = vec![0u64; ndim];
            let shape = level.array.chunk_shape(&first).map_err(|e| {
                super::format_err(
                    &level.array_doc,
                    level.version.chunks_field(),
                    e.to_string(),
                )
            })?;
            let c = |a: usize| shape[a].get().min(u64::from(u32::MAX)) as u32;
            let g = |a: usize| grid_shape[a].min(u64::from(u32::MAX)) as u32;
            (
                UVec3::new(c(ndim - 1), c(ndim - 2), c(ndim - 3)),
                UVec3::new(g(ndim - 1), g(ndim - 2), g(ndim - 3)),
            )
        };
        debug_assert!(grid == UVec3::ZERO || grid == (dims + chunk_shape - 1) / chunk_shape);
        Ok(Self {
            level,
            index,
            options: options.clone(),
            chunk_shape,
            grid,
            fetched: AtomicU64::new(0),
            fetches: AtomicU64::new(0),
        })
    }

    /// Opens level `level` of the same image, fetched with the same options.
    pub fn open_level(&self, level: usize) -> Result<Self, VolumeError> {
        Self::open(&self.level.location, level, &self.options)
    }

    /// This level's index in the image's multiscale (0 the finest).
    pub fn level(&self) -> usize {
        self.index
    }

    /// Levels the image has (its multiscale's datasets; 1 for a plain array).
    pub fn level_count(&self) -> usize {
        self.level.levels
    }

    /// The image's root as errors name it (its folder or URL).
    pub fn root(&self) -> &std::path::Path {
        &self.level.root
    }

    /// Volume dimensions (x, y, z).
    pub fn dims(&self) -> UVec3 {
        self.level.layout.dims
    }

    /// Physical voxel spacing.
    pub fn spacing(&self) -> Vec3 {
        self.level.spacing
    }

    /// The volume scalar type the values are mapped to.
    pub fn scalar(&self) -> ScalarType {
        self.level.stored.volume_scalar()
    }

    /// The image's metadata (stored type, origin, ...).
    pub fn meta(&self) -> &VolumeMeta {
        &self.level.meta
    }

    /// Voxels of a (full) chunk, x, y, z.
    pub fn chunk_shape(&self) -> UVec3 {
        self.chunk_shape
    }

    /// Chunks along x, y, z.
    pub fn chunk_grid(&self) -> UVec3 {
        self.grid
    }

    /// The object (file or URL) of chunk `c` (chunk coordinates x, y, z).
    pub fn chunk_name(&self, c: UVec3) -> PathBuf {
        self.level
            .chunk_name([u64::from(c.x), u64::from(c.y), u64::from(c.z)])
    }

    /// Stored bytes fetched so far by [`ZarrChunks::read_chunk`] (missing chunks count 0).
    pub fn bytes_fetched(&self) -> u64 {
        self.fetched.load(Ordering::Relaxed)
    }

    /// Chunks read so far (missing ones included).
    pub fn chunks_read(&self) -> u64 {
        self.fetches.load(Ordering::Relaxed)
    }

    /// Reads chunk `c` (chunk coordinates x, y, z; must be inside [`ZarrChunks::chunk_grid`]):
    /// fetched, decoded and cropped to the array. A missing chunk is the fill value; a failed
    /// fetch a [`VolumeError::Remote`] (or [`VolumeError::Io`]) and a chunk that does not decode
    /// a [`VolumeError::Format`], each naming the chunk's object.
    pub fn read_chunk(&self, c: UVec3) -> Result<ZarrChunk, VolumeError> {
        if !c.cmplt(self.grid).all() {
            return Err(VolumeError::InvalidParameter(format!(
                "chunk {c} is outside the {} chunk grid of {}",
                self.grid,
                self.level.root.display()
            )));
        }
        let level = &self.level;
        let at = [u64::from(c.x), u64::from(c.y), u64::from(c.z)];
        let Cropped {
            origin,
            extent,
            data,
            bytes,
        } = match level.stored {
            StoredType::U8 => wrap(level.read_chunk_cropped::<u8, u8>(at, |v| v), VoxelData::U8)?,
            StoredType::I8 => wrap(
                level.read_chunk_cropped::<i8, u8>(at, |v| (v as u8) ^ 0x80),
                VoxelData::U8,
            )?,
            StoredType::U16 => wrap(
                level.read_chunk_cropped::<u16, u16>(at, |v| v),
                VoxelData::U16,
            )?,
            StoredType::I16 => wrap(
                level.read_chunk_cropped::<i16, u16>(at, |v| (v as u16) ^ 0x8000),
                VoxelData::U16,
            )?,
            StoredType::U32 => wrap(
                level.read_chunk_cropped::<u32, f32>(at, |v| v as f32),
                VoxelData::F32,
            )?,
            StoredType::I32 => wrap(
                level.read_chunk_cropped::<i32, f32>(at, |v| v as f32),
                VoxelData::F32,
            )?,
            StoredType::F32 => wrap(
                level.read_chunk_cropped::<f32, f32>(at, |v| v),
                VoxelData::F32,
            )?,
            StoredType::F64 => wrap(
                level.read_chunk_cropped::<f64, f32>(at, |v| v as f32),
                VoxelData::F32,
            )?,
        };
        if let VoxelData::F32(values) = &data {
            if let Some(v) = values.iter().find(|v| !v.is_finite()) {
                return Err(super::format_err(
                    &self.chunk_name(c),
                    "data",
                    format!("chunk {c} holds the non-finite value {v}"),
                ));
            }
        }
        self.fetched.fetch_add(bytes, Ordering::Relaxed);
        self.fetches.fetch_add(1, Ordering::Relaxed);
        let to_u32 = |v: usize| v as u32;
        Ok(ZarrChunk {
            origin: UVec3::new(to_u32(origin[0]), to_u32(origin[1]), to_u32(origin[2])),
            extent: UVec3::from_array(extent.map(to_u32)),
            data,
            stored_bytes: bytes,
        })
    }
}

/// A cropped chunk with its values in their [`VoxelData`] variant.
struct Cropped {
    origin: Vec<usize>,
    extent: [usize; 3],
    data: VoxelData,
    bytes: u64,
}

/// Wraps the values of a cropped chunk in their [`VoxelData`] variant.
fn wrap<U>(
    read: Result<CroppedChunk<U>, VolumeError>,
    variant: fn(Vec<U>) -> VoxelData,
) -> Result<Cropped, VolumeError> {
    read.map(|(origin, extent, values, bytes)| Cropped {
        origin,
        extent,
        data: variant(values),
        bytes,
    })
}
