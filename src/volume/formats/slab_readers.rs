//! The [`SlabReader`]s of the file formats: one for every format whose voxels are one payload
//! (raw or gzip: NRRD, NIfTI-1, JSON sidecar, `.den`, headerless raw) and OME-Zarr's (in
//! `zarr/slabs.rs`). Headers are parsed by the loaders' own `describe_*` functions, so a slab
//! reader and a loader agree on dims, spacing, offsets and every check.

use super::read::{io_err, open_regular, Described, GzStream, Layout, Payload};
use super::{
    den, nii, nrrd, raw_sidecar_candidates, same_file, sidecar, FileFormat, StoredType, VolumeMeta,
};
use crate::volume::slabs::{check_finite, check_request, SlabMut, SlabReader};
use crate::volume::{RawDescriptor, ScalarType, VolumeError};
use glam::{UVec3, Vec3};
use std::fs::File;
use std::io::{self, ErrorKind, Read};
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// Bytes read (and decoded) at a time.
const READ_PIECE_BYTES: usize = 1 << 20;

/// Opens `path` (any format with a header; level `level` of an OME-Zarr image).
pub(crate) fn open(path: &Path, level: usize) -> Result<Box<dyn SlabReader + Send>, VolumeError> {
    let lower = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let described = match FileFormat::from_path(path) {
        Some(FileFormat::Nifti) => nii::describe_nifti(path)?,
        Some(FileFormat::Nrrd) => nrrd::describe_nrrd(path)?,
        Some(FileFormat::Den) => den::describe_den(path)?,
        Some(FileFormat::Zarr) => return Ok(Box::new(super::zarr::ZarrSlabs::open(path, level)?)),
        Some(FileFormat::Tiff) => {
            return Ok(Box::new(super::tiff::TiffSlabs::open(
                path,
                &super::tiff::TiffOptions::default(),
            )?))
        }
        Some(FileFormat::Sidecar) if lower.ends_with(".json") => {
            let parsed = sidecar::read_sidecar(path)?;
            sidecar::describe_parsed(path, &parsed)?
        }
        Some(FileFormat::Sidecar) => describe_raw_with_sidecar(path)?,
        None if super::is_zarr_folder(path) => {
            return Ok(Box::new(super::zarr::ZarrSlabs::open(path, level)?))
        }
        None if super::tiff::is_tiff_folder(path) => {
            return Ok(Box::new(super::tiff::TiffSlabs::open(
                path,
                &super::tiff::TiffOptions::default(),
            )?))
        }
        Some(FileFormat::Dicom) => return Err(super::dicom::no_slabs(path)),
        None if super::dicom::is_dicom_folder(path) => return Err(super::dicom::no_slabs(path)),
        None => return Err(super::unknown_extension(path)),
    };
    Ok(Box::new(PayloadSlabs::new(described)?))
}

/// A `.raw` file with a sibling sidecar, as [`super::load_volume`] reads it.
pub(super) fn describe_raw_with_sidecar(path: &Path) -> Result<Described, VolumeError> {
    let candidates = raw_sidecar_candidates(path);
    let Some(json) = candidates.iter().find(|p| p.is_file()) else {
        return Err(super::read::format_err(
            path,
            "extension",
            format!(
                "a .raw file needs a JSON sidecar ({} or {}) giving dims, type, endianness and \
                 spacing",
                candidates[0].display(),
                candidates[1].display()
            ),
        ));
    };
    let parsed = sidecar::read_sidecar(json)?;
    let described = parsed.data_path(json);
    if !same_file(&described, path) {
        return Err(super::read::format_err(
            json,
            "data",
            format!(
                "sidecar describes {}, not {}",
                described.display(),
                path.display()
            ),
        ));
    }
    sidecar::describe_parsed(json, &parsed)
}

/// Opens headerless raw data (the checks of [`crate::volume::load_raw`]).
pub(crate) fn open_raw(
    path: &Path,
    desc: &RawDescriptor,
) -> Result<Box<dyn SlabReader + Send>, VolumeError> {
    let (count, bytes, expected) = crate::volume::loader::raw_sizes(path, desc)?;
    let (_, len) = open_regular(path)?;
    if len != expected {
        return Err(VolumeError::FileSizeMismatch {
            path: path.to_path_buf(),
            dims: desc.dims.to_array(),
            scalar: desc.scalar,
            header: desc.header_bytes,
            expected,
            actual: len,
        });
    }
    if !(desc.spacing.is_finite() && desc.spacing.min_element() > 0.0) {
        return Err(VolumeError::InvalidSpacing {
            spacing: desc.spacing.to_array(),
        });
    }
    let stored = match desc.scalar {
        ScalarType::U8 => StoredType::U8,
        ScalarType::U16 => StoredType::U16,
        ScalarType::F32 => StoredType::F32,
    };
    let described = Described {
        payload: Payload {
            header_path: path.to_path_buf(),
            size_field: "dims",
            data_path: path.to_path_buf(),
            offset: desc.header_bytes,
            gzip: false,
            decoded_skip: 0,
            big_endian: desc.big_endian,
        },
        layout: Layout {
            dims: desc.dims,
            count,
            bytes,
            stored,
        },
        spacing: desc.spacing,
        meta: VolumeMeta::plain(FileFormat::Sidecar, stored, desc.big_endian),
    };
    let mut reader = PayloadSlabs::new(described)?;
    reader.headerless = true;
    Ok(Box::new(reader))
}

/// Where a payload's bytes come from.
enum Source {
    /// Raw data: positioned reads.
    Raw(File),
    /// A gzip stream at decoded voxel byte `at`.
    Gzip {
        /// The stream.
        stream: Box<GzStream>,
        /// Voxel bytes decoded so far.
        at: u64,
    },
}

/// The slab reader of one raw or gzip payload.
struct PayloadSlabs {
    payload: Payload,
    layout: Layout,
    spacing: Vec3,
    meta: VolumeMeta,
    /// Headerless raw data: no metadata to report.
    headerless: bool,
    source: Source,
    buf: Vec<u8>,
    /// The first z plane the next slab of a gzip stream may start at.
    next_z: u32,
}

impl PayloadSlabs {
    /// Opens the payload: raw data must fill its file exactly; a gzip stream is positioned after
    /// its skipped bytes.
    fn new(described: Described) -> Result<Self, VolumeError> {
        let Described {
            payload,
            layout,
            spacing,
            meta,
        } = described;
        let source = if payload.gzip {
            Source::Gzip {
                stream: Box::new(payload.open_gzip(&layout)?),
                at: 0,
            }
        } else {
            let (file, len) = open_regular(&payload.data_path)?;
            payload.check_raw_len(&layout, len)?;
            Source::Raw(file)
        };
        Ok(Self {
            payload,
            layout,
            spacing,
            meta,
            headerless: false,
            source,
            buf: Vec::new(),
            next_z: 0,
        })
    }

    fn plane_bytes(&self) -> u64 {
        u64::from(self.layout.dims.x)
            * u64::from(self.layout.dims.y)
            * self.layout.stored.size_bytes() as u64
    }

    /// Skips decoded bytes up to voxel byte `to` of a gzip stream.
    fn skip_to(&mut self, to: u64) -> Result<(), VolumeError> {
        let Source::Gzip { stream, at } = &mut self.source else {
            return Ok(());
        };
        if to <= *at {
            return Ok(());
        }
        let want = to - *at;
        let got = io::copy(&mut (&mut **stream).take(want), &mut io::sink())
            .map_err(|e| self.payload.gzip_err(e))?;
        *at += got;
        if got < want {
            return Err(self.payload.gzip_short(&self.layout, *at));
        }
        Ok(())
    }
}

impl SlabReader for PayloadSlabs {
    fn path(&self) -> &Path {
        &self.payload.header_path
    }

    fn dims(&self) -> UVec3 {
        self.layout.dims
    }

    fn scalar(&self) -> ScalarType {
        self.layout.stored.volume_scalar()
    }

    fn spacing(&self) -> Vec3 {
        self.spacing
    }

    fn meta(&self) -> Option<&VolumeMeta> {
        (!self.headerless).then_some(&self.meta)
    }

    fn forward_only(&self) -> bool {
        self.payload.gzip
    }

    fn scratch_bytes(&self) -> u64 {
        // The read buffer, plus the gzip decoder's window and input buffer.
        READ_PIECE_BYTES as u64 + if self.payload.gzip { 128 << 10 } else { 0 }
    }

    fn read_slab(&mut self, z: Range<u32>, mut out: SlabMut<'_>) -> Result<(), VolumeError> {
        let plane = check_request(
            &self.payload.header_path,
            self.layout.dims,
            self.scalar(),
            &z,
            &out,
        )?;
        if self.payload.gzip && z.start < self.next_z {
            return Err(VolumeError::SlabRequest {
                path: self.payload.header_path.clone(),
                message: format!(
                    "z planes {z:?} asked for after planes up to {} of a gzip stream, which is \
                     read forward only",
                    self.next_z
                ),
            });
        }
        let size = self.layout.stored.size_bytes();
        let first = z.start as usize * plane;
        let total = z.len() * plane;
        self.skip_to(u64::from(z.start) * self.plane_bytes())?;
        let piece = (READ_PIECE_BYTES / size).max(1);
        let mut done = 0usize;
        while done < total {
            let n = piece.min(total - done);
            self.buf.resize(n * size, 0);
            let byte_at = (first + done) as u64 * size as u64;
            match &mut self.source {
                Source::Raw(file) => {
                    file.read_exact_at(&mut self.buf, self.payload.offset + byte_at)
                        .map_err(|e| {
                            if e.kind() == ErrorKind::UnexpectedEof {
                                self.payload.raw_short(&self.layout, byte_at)
                            } else {
                                io_err(&self.payload.data_path)(e)
                            }
                        })?;
                }
                Source::Gzip { stream, at } => {
                    let mut filled = 0;
                    while filled < self.buf.len() {
                        match stream.read(&mut self.buf[filled..]) {
                            Ok(0) => {
                                return Err(self
                                    .payload
                                    .gzip_short(&self.layout, *at + filled as u64))
                            }
                            Ok(k) => filled += k,
                            Err(e) if e.kind() == ErrorKind::Interrupted => {}
                            Err(e) => return Err(self.payload.gzip_err(e)),
                        }
                    }
                    *at += filled as u64;
                }
            }
            decode(
                &self.buf,
                self.layout.stored,
                self.payload.big_endian,
                &mut out,
                done,
            );
            if let SlabMut::F32(values) = &out {
                check_finite(&values[done..done + n], first + done, self.layout.dims)
                    .map_err(|e| e.in_file(&self.payload.data_path))?;
            }
            done += n;
        }
        self.next_z = z.end;
        Ok(())
    }

    fn finish(&mut self) -> Result<(), VolumeError> {
        if !self.payload.gzip {
            return Ok(());
        }
        self.skip_to(self.layout.bytes)?;
        let Source::Gzip { stream, .. } = &mut self.source else {
            return Ok(());
        };
        self.next_z = self.layout.dims.z;
        self.payload.check_gzip_end(&self.layout, stream)
    }
}

/// Decodes `bytes` (whole values of `stored`, in file byte order) into `out[at..]`, mapped to the
/// volume's scalar type as the loaders map them (see [`super`]). `out` has the volume scalar type
/// of `stored` (checked by the caller).
fn decode(bytes: &[u8], stored: StoredType, big_endian: bool, out: &mut SlabMut<'_>, at: usize) {
    let u16_of = |b: &[u8]| {
        let b = [b[0], b[1]];
        if big_endian {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        }
    };
    let u32_of = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3]];
        if big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    };
    let u64_of = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
        if big_endian {
            u64::from_be_bytes(b)
        } else {
            u64::from_le_bytes(b)
        }
    };
    fn fill<T>(out: &mut [T], values: impl Iterator<Item = T>) {
        for (o, v) in out.iter_mut().zip(values) {
            *o = v;
        }
    }
    let n = bytes.len() / stored.size_bytes();
    match (stored, out) {
        (StoredType::U8, SlabMut::U8(o)) => o[at..at + n].copy_from_slice(bytes),
        // Two's complement + 128 == flipping the sign bit.
        (StoredType::I8, SlabMut::U8(o)) => {
            fill(&mut o[at..at + n], bytes.iter().map(|b| b ^ 0x80))
        }
        (StoredType::U16, SlabMut::U16(o)) => {
            fill(&mut o[at..at + n], bytes.chunks_exact(2).map(u16_of))
        }
        // Two's complement + 32768 == flipping the sign bit.
        (StoredType::I16, SlabMut::U16(o)) => fill(
            &mut o[at..at + n],
            bytes.chunks_exact(2).map(|b| u16_of(b) ^ 0x8000),
        ),
        (StoredType::U32, SlabMut::F32(o)) => fill(
            &mut o[at..at + n],
            bytes.chunks_exact(4).map(|b| u32_of(b) as f32),
        ),
        (StoredType::I32, SlabMut::F32(o)) => fill(
            &mut o[at..at + n],
            bytes.chunks_exact(4).map(|b| u32_of(b) as i32 as f32),
        ),
        (StoredType::F32, SlabMut::F32(o)) => fill(
            &mut o[at..at + n],
            bytes.chunks_exact(4).map(|b| f32::from_bits(u32_of(b))),
        ),
        (StoredType::F64, SlabMut::F32(o)) => fill(
            &mut o[at..at + n],
            bytes
                .chunks_exact(8)
                .map(|b| f64::from_bits(u64_of(b)) as f32),
        ),
        // Unreachable: `check_request` matched the slab's type to the stored type's.
        _ => {}
    }
}
