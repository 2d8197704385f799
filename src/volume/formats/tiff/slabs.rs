//! Reading a TIFF stack plane by plane: the [`SlabReader`] of TIFF stacks, which the loader
//! uses too (one path for both).

use super::page::{open_decoder, tiff_err, PageInfo, TiffDecoder};
use super::stack::{describe, Stack, TiffInfo};
use super::TiffOptions;
use crate::volume::formats::read::check_layout_memory;
use crate::volume::formats::{LoadedVolume, StoredType, VolumeMeta};
use crate::volume::slabs::{check_finite, check_request, SlabMut, SlabReader};
use crate::volume::{ScalarType, Volume, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::ops::Range;
use std::path::Path;

/// A TIFF stack read plane by plane: each z plane is one page, decoded straight into the
/// caller's slab (u8, i8, u16, i16, f32 pages) or through one page of scratch (u32, i32, f64
/// pages, converted to f32). Planes can be read in any order.
pub struct TiffSlabs {
    stack: Stack,
    /// The decoder of the file last read from (index into the stack's files).
    open: Option<(usize, TiffDecoder)>,
    /// One page of stored values, for the types converted to f32.
    scratch: Vec<u8>,
}

impl std::fmt::Debug for TiffSlabs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TiffSlabs")
            .field("path", &self.stack.path)
            .field("dims", &self.stack.layout.dims)
            .field("stored", &self.stack.layout.stored)
            .finish_non_exhaustive()
    }
}

impl TiffSlabs {
    /// Opens the stack at `path` (a TIFF file or a folder of single-page TIFFs): every page's
    /// tags are read and checked before this returns (see [`super`]).
    pub fn open(path: &Path, options: &TiffOptions) -> Result<Self, VolumeError> {
        Ok(Self {
            stack: describe(path, options)?,
            open: None,
            scratch: Vec::new(),
        })
    }

    /// What the stack is made of: pages, compression, tiling, the OME-XML read.
    pub fn info(&self) -> &TiffInfo {
        &self.stack.info
    }

    /// Reads every plane into a volume (after the host-memory check).
    pub fn load(mut self) -> Result<LoadedVolume, VolumeError> {
        let layout = self.stack.layout;
        check_layout_memory(&self.stack.path, &layout)?;
        let mut data = VoxelData::zeroed(layout.stored.volume_scalar(), layout.count);
        let out = SlabMut::of_range(&mut data, 0..layout.count).ok_or_else(|| {
            VolumeError::SlabRequest {
                path: self.stack.path.clone(),
                message: "voxel buffer of the wrong size".into(),
            }
        })?;
        self.read_slab(0..layout.dims.z, out)?;
        Ok(LoadedVolume {
            volume: Volume::new(layout.dims, self.stack.spacing, data)
                .map_err(|e| e.in_file(&self.stack.path))?,
            meta: self.stack.meta,
        })
    }

    /// The decoder of file `file`, on page `ifd`, with that page checked against the stack
    /// (the file may have changed since it was described).
    fn page(&mut self, file: usize, ifd: u64) -> Result<&mut TiffDecoder, VolumeError> {
        let path = &self.stack.files[file];
        if self.open.as_ref().map(|(f, _)| *f) != Some(file) {
            self.open = Some((file, open_decoder(path)?));
        }
        let Some((_, dec)) = self.open.as_mut() else {
            unreachable!("the decoder was just opened");
        };
        let index = usize::try_from(ifd).map_err(|_| VolumeError::TiffPage {
            path: path.clone(),
            page: ifd,
            field: "IFD".into(),
            message: "page index overflows".into(),
        })?;
        dec.seek_to_image(index)
            .map_err(|e| tiff_err(path, ifd, "IFD", e))?;
        let info = PageInfo::read(dec, path, ifd)?;
        let stored = info.stored_type(path, ifd)?;
        let dims = self.stack.layout.dims;
        if (info.width, info.height) != (dims.x, dims.y) || stored != self.stack.layout.stored {
            return Err(VolumeError::TiffPage {
                path: path.clone(),
                page: ifd,
                field: "ImageWidth".into(),
                message: format!(
                    "the page is now {}x{} {}, not the {}x{} {} the stack was opened with (the \
                     file changed?)",
                    info.width,
                    info.height,
                    stored.name(),
                    dims.x,
                    dims.y,
                    self.stack.layout.stored.name()
                ),
            });
        }
        Ok(dec)
    }

    /// Decodes plane `z` into `out[at..at + plane]`.
    fn read_plane(
        &mut self,
        z: u32,
        out: &mut SlabMut<'_>,
        at: usize,
        plane: usize,
    ) -> Result<(), VolumeError> {
        let p = self.stack.planes[z as usize];
        let stored = self.stack.layout.stored;
        let path = self.stack.files[p.file].clone();
        let mut scratch = std::mem::take(&mut self.scratch);
        let dec = self.page(p.file, p.ifd)?;
        let decode = |dec: &mut TiffDecoder, bytes: &mut [u8]| {
            dec.read_image_bytes(bytes)
                .map_err(|e| tiff_err(&path, p.ifd, "data", e))
        };
        let range = at..at + plane;
        match (stored, out) {
            (StoredType::U8, SlabMut::U8(o)) => decode(dec, &mut o[range])?,
            // Two's complement + 128 == flipping the sign bit.
            (StoredType::I8, SlabMut::U8(o)) => {
                decode(dec, &mut o[range.clone()])?;
                o[range].iter_mut().for_each(|v| *v ^= 0x80);
            }
            (StoredType::U16, SlabMut::U16(o)) => {
                decode(dec, bytemuck::cast_slice_mut(&mut o[range]))?
            }
            // Two's complement + 32768 == flipping the sign bit.
            (StoredType::I16, SlabMut::U16(o)) => {
                decode(dec, bytemuck::cast_slice_mut(&mut o[range.clone()]))?;
                o[range].iter_mut().for_each(|v| *v ^= 0x8000);
            }
            (StoredType::F32, SlabMut::F32(o)) => {
                decode(dec, bytemuck::cast_slice_mut(&mut o[range.clone()]))?;
                check_finite(&o[range], z as usize * plane, self.stack.layout.dims)
                    .map_err(|e| e.in_file(&path))?;
            }
            (StoredType::U32 | StoredType::I32 | StoredType::F64, SlabMut::F32(o)) => {
                scratch.resize(plane * stored.size_bytes(), 0);
                decode(dec, &mut scratch)?;
                let dst = &mut o[range.clone()];
                match stored {
                    StoredType::U32 => {
                        for (d, s) in dst.iter_mut().zip(scratch.chunks_exact(4)) {
                            *d = u32::from_ne_bytes([s[0], s[1], s[2], s[3]]) as f32;
                        }
                    }
                    StoredType::I32 => {
                        for (d, s) in dst.iter_mut().zip(scratch.chunks_exact(4)) {
                            *d = i32::from_ne_bytes([s[0], s[1], s[2], s[3]]) as f32;
                        }
                    }
                    _ => {
                        for (d, s) in dst.iter_mut().zip(scratch.chunks_exact(8)) {
                            let b = [s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]];
                            *d = f64::from_ne_bytes(b) as f32;
                        }
                    }
                }
                check_finite(&o[range], z as usize * plane, self.stack.layout.dims)
                    .map_err(|e| e.in_file(&path))?;
            }
            // Unreachable: `check_request` matched the slab's type to the stored type's.
            (_, out) => {
                return Err(VolumeError::SlabRequest {
                    path,
                    message: format!(
                        "a slab of {:?} for {} pages",
                        out.scalar_type(),
                        stored.name()
                    ),
                })
            }
        }
        self.scratch = scratch;
        Ok(())
    }
}

impl SlabReader for TiffSlabs {
    fn path(&self) -> &Path {
        &self.stack.path
    }

    fn dims(&self) -> UVec3 {
        self.stack.layout.dims
    }

    fn scalar(&self) -> ScalarType {
        self.stack.layout.stored.volume_scalar()
    }

    fn spacing(&self) -> Vec3 {
        self.stack.spacing
    }

    fn meta(&self) -> Option<&VolumeMeta> {
        Some(&self.stack.meta)
    }

    fn forward_only(&self) -> bool {
        false
    }

    fn scratch_bytes(&self) -> u64 {
        let d = self.stack.layout.dims;
        let page = u64::from(d.x) * u64::from(d.y) * self.stack.layout.stored.size_bytes() as u64;
        let converted = matches!(
            self.stack.layout.stored,
            StoredType::U32 | StoredType::I32 | StoredType::F64
        );
        // One page of scratch for converted types; the decoder's compressed-chunk buffer (at
        // most a page) and its read buffer.
        let scratch = if converted { page } else { 0 };
        scratch + page + (64 << 10)
    }

    fn read_slab(&mut self, z: Range<u32>, mut out: SlabMut<'_>) -> Result<(), VolumeError> {
        let plane = check_request(
            &self.stack.path,
            self.stack.layout.dims,
            self.scalar(),
            &z,
            &out,
        )?;
        for (i, zi) in z.clone().enumerate() {
            self.read_plane(zi, &mut out, i * plane, plane)?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), VolumeError> {
        Ok(())
    }
}
