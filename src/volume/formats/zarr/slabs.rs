//! [`ZarrSlabs`]: one level of an OME-Zarr image read slab by slab, decoding only the chunks that
//! meet each slab (by the loader's own chunk reader, so the values are the loader's).

use super::{open_level, RemoteOptions, ZarrLevel, ZarrLocation};
use crate::volume::formats::{StoredType, VolumeMeta};
use crate::volume::slabs::{check_finite, check_request, SlabMut, SlabReader};
use crate::volume::{ScalarType, VolumeError};
use glam::{UVec3, Vec3};
use std::ops::Range;
use std::path::Path;

/// One level of an OME-Zarr image (or a plain Zarr array), read in slabs of z planes.
pub struct ZarrSlabs {
    level: ZarrLevel,
    /// Decoded bytes of the largest chunk.
    chunk_bytes: u64,
}

impl ZarrSlabs {
    /// Opens level `level` of the image at `root` (the checks of
    /// [`load_zarr_level`](super::load_zarr_level)), reading no chunk.
    pub fn open(root: &Path, level: usize) -> Result<Self, VolumeError> {
        Self::open_at(
            &ZarrLocation::Local(root.to_path_buf()),
            level,
            &RemoteOptions::default(),
        )
    }

    /// Opens level `level` of the image at `location`, a local folder or a remote store
    /// (fetched as `options` says), reading its metadata but no chunk.
    pub fn open_at(
        location: &ZarrLocation,
        level: usize,
        options: &RemoteOptions,
    ) -> Result<Self, VolumeError> {
        let level = open_level(location, level, options)?;
        let chunk_bytes = level.max_chunk_bytes()?;
        Ok(Self { level, chunk_bytes })
    }
}

impl SlabReader for ZarrSlabs {
    fn path(&self) -> &Path {
        &self.level.array_doc
    }

    fn dims(&self) -> UVec3 {
        self.level.layout.dims
    }

    fn scalar(&self) -> ScalarType {
        self.level.stored.volume_scalar()
    }

    fn spacing(&self) -> Vec3 {
        self.level.spacing
    }

    fn meta(&self) -> Option<&VolumeMeta> {
        Some(&self.level.meta)
    }

    fn forward_only(&self) -> bool {
        false
    }

    fn scratch_bytes(&self) -> u64 {
        // The encoded and the decoded chunk.
        self.chunk_bytes.saturating_mul(2)
    }

    fn read_slab(&mut self, z: Range<u32>, out: SlabMut<'_>) -> Result<(), VolumeError> {
        let level = &self.level;
        check_request(&level.array_doc, self.dims(), self.scalar(), &z, &out)?;
        let first = z.start as usize * level.dims[0] * level.dims[1];
        let z = z.start as usize..z.end as usize;
        match (level.stored, out) {
            (StoredType::U8, SlabMut::U8(o)) => level.read_planes::<u8, u8>(z, o, |v| v),
            (StoredType::I8, SlabMut::U8(o)) => {
                level.read_planes::<i8, u8>(z, o, |v| (v as u8) ^ 0x80)
            }
            (StoredType::U16, SlabMut::U16(o)) => level.read_planes::<u16, u16>(z, o, |v| v),
            (StoredType::I16, SlabMut::U16(o)) => {
                level.read_planes::<i16, u16>(z, o, |v| (v as u16) ^ 0x8000)
            }
            (StoredType::U32, SlabMut::F32(o)) => level.read_planes::<u32, f32>(z, o, |v| v as f32),
            (StoredType::I32, SlabMut::F32(o)) => level.read_planes::<i32, f32>(z, o, |v| v as f32),
            (StoredType::F32, SlabMut::F32(o)) => {
                level.read_planes::<f32, f32>(z, o, |v| v)?;
                check_finite(o, first, self.level.layout.dims)
                    .map_err(|e| e.in_file(&self.level.root))
            }
            (StoredType::F64, SlabMut::F32(o)) => {
                level.read_planes::<f64, f32>(z, o, |v| v as f32)?;
                check_finite(o, first, self.level.layout.dims)
                    .map_err(|e| e.in_file(&self.level.root))
            }
            // `check_request` matched the slab's type to the stored type's.
            _ => Ok(()),
        }
    }

    fn finish(&mut self) -> Result<(), VolumeError> {
        Ok(())
    }
}
