//! Reading a volume file slab by slab: runs of whole z planes, never the whole volume.
//!
//! A [`SlabReader`] is a volume file whose header has been parsed and checked (by the same code
//! as the whole-volume loaders, so its dims, spacing and values are theirs), and whose voxels are
//! read on demand: [`SlabReader::read_slab`] fills z planes `z0..z1` (x fastest, then y, then z)
//! in the volume's scalar type, mapped from the stored type exactly as the loaders map them
//! (i16 + 32768 as u16, i8 + 128 as u8, 32-bit integers and f64 to f32; see
//! [`crate::volume::formats`]), with NaN and infinities refused as [`VolumeError::NonFinite`]
//! naming the same voxel the loader would name. Voxels stay in file order (the loaders never
//! flip or resample either).
//!
//! [`open_slabs`] opens any file with a header: raw and gzip NRRD, NIfTI-1 `.nii` / `.nii.gz`,
//! raw or gzip data with a JSON sidecar, `.den`, and one level of an OME-Zarr image;
//! [`open_raw_slabs`] opens headerless raw data described by a [`RawDescriptor`]. Raw data is
//! read with positioned reads, in any order; gzip streams only forward
//! ([`SlabReader::forward_only`]: each slab must start at or after the end of the previous one).
//! OME-Zarr slabs decode every chunk that meets the slab (a chunk taller than a slab is decoded
//! once per slab it meets).
//!
//! Memory: besides the caller's slab, a reader holds at most [`SlabReader::scratch_bytes`]
//! (a bounded read buffer; one decoded chunk for OME-Zarr).

use super::formats::{slab_readers, FileFormat, VolumeMeta};
use super::{RawDescriptor, ScalarType, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::ops::Range;
use std::path::Path;

/// Mutable voxels of one scalar type: the slab a [`SlabReader`] fills.
#[derive(Debug)]
pub enum SlabMut<'a> {
    /// `U8` voxels.
    U8(&'a mut [u8]),
    /// `U16` voxels.
    U16(&'a mut [u16]),
    /// `F32` voxels.
    F32(&'a mut [f32]),
}

impl<'a> SlabMut<'a> {
    /// The voxels `range` of `data`; `None` when the range leaves it.
    pub fn of_range(data: &'a mut VoxelData, range: Range<usize>) -> Option<Self> {
        Some(match data {
            VoxelData::U8(v) => SlabMut::U8(v.get_mut(range)?),
            VoxelData::U16(v) => SlabMut::U16(v.get_mut(range)?),
            VoxelData::F32(v) => SlabMut::F32(v.get_mut(range)?),
        })
    }

    /// The scalar type of the voxels.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            SlabMut::U8(_) => ScalarType::U8,
            SlabMut::U16(_) => ScalarType::U16,
            SlabMut::F32(_) => ScalarType::F32,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        match self {
            SlabMut::U8(v) => v.len(),
            SlabMut::U16(v) => v.len(),
            SlabMut::F32(v) => v.len(),
        }
    }

    /// True when there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A volume file read in slabs of whole z planes (see the [module docs](self)).
pub trait SlabReader {
    /// The file named in errors: the header (NRRD, NIfTI, sidecar, `.den`), the Zarr array's
    /// metadata document, or the raw file.
    fn path(&self) -> &Path;

    /// Volume dimensions in voxels.
    fn dims(&self) -> UVec3;

    /// The scalar type of the voxels [`SlabReader::read_slab`] writes.
    fn scalar(&self) -> ScalarType;

    /// Voxel spacing (positive and finite).
    fn spacing(&self) -> Vec3;

    /// What the header says besides the voxels; `None` for headerless raw data.
    fn meta(&self) -> Option<&VolumeMeta>;

    /// True when slabs must come in increasing z order without overlap (gzip streams): each
    /// slab starts at or after the end of the previous one.
    fn forward_only(&self) -> bool;

    /// Bytes the reader itself holds while reading a slab (read buffers, a decoded chunk), on
    /// top of the caller's slab.
    fn scratch_bytes(&self) -> u64;

    /// Reads z planes `z` into `out`, which holds exactly `dims.x * dims.y * z.len()` voxels of
    /// [`SlabReader::scalar`] (x fastest). Errors: the loaders' errors for the data (too short,
    /// corrupt, non-finite values) naming the file and field; [`VolumeError::SlabRequest`] for a
    /// request outside the volume, of the wrong size or type, or backwards on a forward-only
    /// reader.
    fn read_slab(&mut self, z: Range<u32>, out: SlabMut<'_>) -> Result<(), VolumeError>;

    /// Checks what is left after the last slab: a gzip stream must hold nothing more than the
    /// voxels (as the loaders check). Readers without such a check return `Ok`.
    fn finish(&mut self) -> Result<(), VolumeError>;
}

/// Opens `path` for slab reading, choosing the format as
/// [`load_volume`](crate::volume::load_volume) does, and reading level `zarr_level` (default 0)
/// of an OME-Zarr image. `zarr_level` on another format is a [`VolumeError::Format`] error on
/// the field `extension`, like a file without a known header.
pub fn open_slabs(
    path: &Path,
    zarr_level: Option<usize>,
) -> Result<Box<dyn SlabReader + Send>, VolumeError> {
    if let Some(level) = zarr_level {
        if FileFormat::detect(path) != Some(FileFormat::Zarr) {
            return Err(VolumeError::Format {
                path: path.to_path_buf(),
                field: "extension".into(),
                message: format!("zarr level {level} asked for, but this is not an OME-Zarr image"),
            });
        }
    }
    slab_readers::open(path, zarr_level.unwrap_or(0))
}

/// Opens headerless raw data described by `desc` for slab reading (the checks of
/// [`load_raw`](crate::volume::load_raw): the file must be exactly `header_bytes` + the voxels).
pub fn open_raw_slabs(
    path: &Path,
    desc: &RawDescriptor,
) -> Result<Box<dyn SlabReader + Send>, VolumeError> {
    slab_readers::open_raw(path, desc)
}

/// Checks a slab request against a reader's dims and scalar type; returns the voxels per plane.
pub(crate) fn check_request(
    path: &Path,
    dims: UVec3,
    scalar: ScalarType,
    z: &Range<u32>,
    out: &SlabMut<'_>,
) -> Result<usize, VolumeError> {
    let plane = dims.x as usize * dims.y as usize;
    let message = if z.start > z.end || z.end > dims.z {
        format!("z planes {z:?} leave the volume's {} planes", dims.z)
    } else if out.scalar_type() != scalar {
        format!(
            "a slab of {:?} voxels for a volume of {scalar:?}",
            out.scalar_type()
        )
    } else if out.len() != plane * z.len() {
        format!(
            "a slab of {} voxels for z planes {z:?} of {} voxels each",
            out.len(),
            plane
        )
    } else {
        return Ok(plane);
    };
    Err(VolumeError::SlabRequest {
        path: path.to_path_buf(),
        message,
    })
}

/// Refuses the first NaN or infinity of `values`, whose first voxel has linear index `first`.
pub(crate) fn check_finite(values: &[f32], first: usize, dims: UVec3) -> Result<(), VolumeError> {
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        let index = first + i;
        let x = (index % dims.x as usize) as u32;
        let y = ((index / dims.x as usize) % dims.y as usize) as u32;
        let z = (index / (dims.x as usize * dims.y as usize)) as u32;
        return Err(VolumeError::NonFinite {
            file: None,
            index,
            x,
            y,
            z,
            value: values[i],
        });
    }
    Ok(())
}
