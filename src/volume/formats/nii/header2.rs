//! The NIfTI-2 header (540 bytes, `sizeof_hdr` 540, magic `n+2\0\r\n\x1a\n`), parsed by hand: the
//! `nifti` crate reads NIfTI-1 only. The fields are those of NIfTI-1 widened (64-bit `dim` and
//! `vox_offset`, doubles for `pixdim`, scaling and the transforms) and reordered, as `nifti2.h`
//! lays them out.
use super::RawHeader;
use crate::volume::formats::read::format_err;
use crate::volume::VolumeError;
use std::path::Path;

/// Size of a NIfTI-2 header in bytes (`sizeof_hdr`).
pub const NIFTI2_HEADER_BYTES: usize = 540;

/// The magic of a single-file NIfTI-2 (`n+2` and the line-ending check bytes).
const MAGIC_SINGLE: [u8; 8] = *b"n+2\0\r\n\x1a\n";
/// The magic of a NIfTI-2 `.hdr` / `.img` pair.
const MAGIC_PAIR: [u8; 8] = *b"ni2\0\r\n\x1a\n";

/// Reads fixed-offset fields in the header's byte order.
struct Fields<'a> {
    bytes: &'a [u8],
    big: bool,
}

impl Fields<'_> {
    fn array<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.bytes[at..at + N]);
        out
    }
    fn i16(&self, at: usize) -> i16 {
        let a = self.array::<2>(at);
        if self.big {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    }
    fn i32(&self, at: usize) -> i32 {
        let a = self.array::<4>(at);
        if self.big {
            i32::from_be_bytes(a)
        } else {
            i32::from_le_bytes(a)
        }
    }
    fn i64(&self, at: usize) -> i64 {
        let a = self.array::<8>(at);
        if self.big {
            i64::from_be_bytes(a)
        } else {
            i64::from_le_bytes(a)
        }
    }
    fn f64(&self, at: usize) -> f64 {
        let a = self.array::<8>(at);
        if self.big {
            f64::from_be_bytes(a)
        } else {
            f64::from_le_bytes(a)
        }
    }
}

/// Parses the first [`NIFTI2_HEADER_BYTES`] of `bytes` (whose `sizeof_hdr` is 540 in one byte
/// order) into the fields the loader validates. Errors name the field: `header` (truncated),
/// `magic` (not `n+2`, or a `ni2` header / image pair).
pub(super) fn parse(path: &Path, bytes: &[u8]) -> Result<RawHeader, VolumeError> {
    // The magic first: a NIfTI-1 header whose sizeof_hdr is wrong is named as such.
    let mut magic = [0u8; 8];
    let got = bytes.len().min(12).saturating_sub(4);
    magic[..got].copy_from_slice(&bytes[4..4 + got]);
    if magic == MAGIC_PAIR {
        return Err(format_err(
            path,
            "magic",
            "magic \"ni2\" means a separate .hdr/.img pair, which is not supported; \
             use a single .nii file (\"n+2\")",
        ));
    }
    if magic != MAGIC_SINGLE {
        return Err(format_err(
            path,
            "magic",
            format!(
                "sizeof_hdr is 540 (NIfTI-2) but the magic is {:?}, expected \"n+2\": not a \
                 NIfTI-2 file",
                String::from_utf8_lossy(&magic[..got])
            ),
        ));
    }
    if bytes.len() < NIFTI2_HEADER_BYTES {
        return Err(format_err(
            path,
            "header",
            format!(
                "truncated NIfTI-2 header: {} of {NIFTI2_HEADER_BYTES} bytes",
                bytes.len()
            ),
        ));
    }
    let big = i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) != 540;
    let f = Fields { bytes, big };
    let dim = [0, 1, 2, 3, 4, 5, 6, 7].map(|i| f.i64(16 + 8 * i));
    let pixdim = [0, 1, 2, 3, 4, 5, 6, 7].map(|i| f.f64(104 + 8 * i));
    let row = |at: usize| [0, 1, 2, 3].map(|i| f.f64(at + 8 * i));
    Ok(RawHeader {
        version: 2,
        header_bytes: NIFTI2_HEADER_BYTES as u64,
        big_endian: big,
        datatype: f.i16(12),
        bitpix: f.i16(14),
        dim,
        pixdim,
        vox_offset: f.i64(168) as f64,
        scl_slope: f.f64(176),
        scl_inter: f.f64(184),
        qform_code: f.i32(344),
        sform_code: f.i32(348),
        quatern: [f.f64(352), f.f64(360), f.f64(368)],
        qoffset: [f.f64(376), f.f64(384), f.f64(392)],
        srow: [row(400), row(432), row(464)],
    })
}
