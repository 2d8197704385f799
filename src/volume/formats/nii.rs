//! NIfTI-1 single files (`.nii`, `.nii.gz`): the header is parsed by the `nifti` crate, then
//! validated here; the voxels are read by the shared, size-checked reader.
use super::read::{self, format_err, layout, Described, Payload};
use super::{FileFormat, LoadedVolume, StoredType, VolumeMeta, IDENTITY, MAX_VOLUME_BYTES};
use crate::volume::VolumeError;
use flate2::bufread::MultiGzDecoder;
use glam::Vec3;
use std::io::{BufReader, Read};
use std::path::Path;

/// Size of a NIfTI-1 header in bytes (`sizeof_hdr`).
pub const NIFTI1_HEADER_BYTES: usize = 348;

/// What a validated NIfTI-1 header describes.
#[derive(Clone, Debug, PartialEq)]
pub struct NiftiInfo {
    /// Voxel counts along x, y, z (`dim[1..=3]`; 1 for axes beyond `dim[0]`).
    pub dims: [u64; 3],
    /// Stored value type (`datatype`).
    pub stored: StoredType,
    /// True for a big-endian file (detected from `dim[0]`).
    pub big_endian: bool,
    /// Voxel spacing, `|pixdim[1..=3]|` (in the file's `xyzt_units`; only ratios matter here).
    pub spacing: [f64; 3],
    /// Byte offset of the voxels (`vox_offset`).
    pub vox_offset: u64,
    /// Orientation and value scaling (see [`VolumeMeta`]).
    pub meta: VolumeMeta,
}

/// Parses and validates the first [`NIFTI1_HEADER_BYTES`] bytes of a NIfTI-1 file (`path` is only
/// named in errors). Checks `sizeof_hdr` (348; NIfTI-2 is refused), the magic (`n+1`: single
/// `.nii` files only), `dim` (1 to 3 spatial axes of at least one voxel; a 4th or higher axis
/// must have size 1), `datatype` and `bitpix`, `pixdim[1..=3]` (finite, non-zero) and
/// `vox_offset` (whole number, at least 348), and that the volume's size is within
/// [`MAX_VOLUME_BYTES`] (field `dim`). Errors are [`VolumeError::Format`] naming the field.
pub fn parse_nifti_header(path: &Path, bytes: &[u8]) -> Result<NiftiInfo, VolumeError> {
    if bytes.len() < NIFTI1_HEADER_BYTES {
        return Err(format_err(
            path,
            "header",
            format!(
                "truncated NIfTI-1 header: {} of {NIFTI1_HEADER_BYTES} bytes",
                bytes.len()
            ),
        ));
    }
    let size_le = i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    let size_be = i32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    if size_le == 540 || size_be == 540 {
        return Err(format_err(
            path,
            "sizeof_hdr",
            "NIfTI-2 (sizeof_hdr 540) is not supported; convert to NIfTI-1",
        ));
    }
    if size_le != 348 && size_be != 348 {
        return Err(format_err(
            path,
            "sizeof_hdr",
            format!("sizeof_hdr is {size_le}, expected 348: not a NIfTI-1 file"),
        ));
    }
    let h =
        ::nifti::NiftiHeader::from_reader(&bytes[..NIFTI1_HEADER_BYTES]).map_err(|e| match e {
            ::nifti::NiftiError::InvalidFormat => format_err(
                path,
                "magic",
                "magic is not \"n+1\" or \"ni1\": not a NIfTI-1 file",
            ),
            other => format_err(
                path,
                "header",
                format!("unreadable NIfTI-1 header: {other}"),
            ),
        })?;
    if h.sizeof_hdr != 348 {
        // The crate guesses the byte order from dim[0] (1 to 7 when read right); sizeof_hdr
        // says otherwise, so dim[0] is out of range in the file's real byte order.
        let d = [bytes[40], bytes[41]];
        let dim0 = if size_le == 348 {
            i16::from_le_bytes(d)
        } else {
            i16::from_be_bytes(d)
        };
        return Err(format_err(
            path,
            "dim[0]",
            format!("dim[0] (number of axes) is {dim0}, expected 1 to 7"),
        ));
    }
    if &h.magic != ::nifti::header::MAGIC_CODE_NIP1 {
        return Err(format_err(
            path,
            "magic",
            "magic \"ni1\" means a separate .hdr/.img pair, which is not supported; \
             use a single .nii file (\"n+1\")",
        ));
    }

    // dim is i16 in the standard; the crate reads it as u16.
    let dim = h.dim.map(|d| d as i16);
    let ndim = dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(format_err(
            path,
            "dim[0]",
            format!("dim[0] (number of axes) is {ndim}, expected 1 to 7"),
        ));
    }
    let ndim = ndim as usize;
    let mut dims = [1u64; 3];
    for i in 1..=ndim {
        if dim[i] < 1 {
            return Err(format_err(
                path,
                format!("dim[{i}]"),
                format!("axis size is {}, expected at least 1", dim[i]),
            ));
        }
        if i <= 3 {
            dims[i - 1] = dim[i] as u64;
        } else if dim[i] != 1 {
            return Err(format_err(
                path,
                format!("dim[{i}]"),
                format!(
                    "axis {i} has size {}: only single 3-D volumes are supported, \
                     not 4-D or higher series",
                    dim[i]
                ),
            ));
        }
    }

    let stored = match h.datatype {
        2 => StoredType::U8,
        4 => StoredType::I16,
        8 => StoredType::I32,
        16 => StoredType::F32,
        64 => StoredType::F64,
        256 => StoredType::I8,
        512 => StoredType::U16,
        768 => StoredType::U32,
        code => {
            return Err(format_err(
                path,
                "datatype",
                format!(
                    "datatype code {code} is not supported (supported: 2 uint8, 4 int16, \
                     8 int32, 16 float32, 64 float64, 256 int8, 512 uint16, 768 uint32)"
                ),
            ))
        }
    };
    let bits = stored.size_bytes() as i16 * 8;
    if h.bitpix != bits {
        return Err(format_err(
            path,
            "bitpix",
            format!(
                "bitpix is {} but datatype {} has {bits} bits",
                h.bitpix, h.datatype
            ),
        ));
    }

    layout(path, "dim", dims, stored)?;

    let mut spacing = [1.0f64; 3];
    for (i, s) in spacing.iter_mut().enumerate().take(ndim.min(3)) {
        let p = f64::from(h.pixdim[i + 1]).abs();
        if !(p.is_finite() && p > 0.0) {
            return Err(format_err(
                path,
                format!("pixdim[{}]", i + 1),
                format!(
                    "voxel size is {}, expected a finite non-zero value",
                    h.pixdim[i + 1]
                ),
            ));
        }
        *s = p;
    }

    let vox = h.vox_offset;
    if !(vox.is_finite()
        && vox.fract() == 0.0
        && vox >= NIFTI1_HEADER_BYTES as f32
        && f64::from(vox) <= MAX_VOLUME_BYTES as f64)
    {
        return Err(format_err(
            path,
            "vox_offset",
            format!("vox_offset is {vox}, expected a whole number of bytes >= 348"),
        ));
    }

    let big_endian = h.endianness == ::nifti::Endianness::Big;
    let mut meta = VolumeMeta::plain(FileFormat::Nifti, stored, big_endian);
    let slope = f64::from(h.scl_slope);
    let inter = f64::from(h.scl_inter);
    if slope.is_finite() && slope != 0.0 {
        meta.scale_slope = slope;
        meta.scale_inter = if inter.is_finite() { inter } else { 0.0 };
    }
    if let Some((directions, origin)) = orientation(&h) {
        meta.directions = directions;
        meta.origin = origin;
    }
    Ok(NiftiInfo {
        dims,
        stored,
        big_endian,
        spacing,
        vox_offset: vox as u64,
        meta,
    })
}

/// Index-axis directions and origin: from the sform when `sform_code > 0`, else from the qform
/// when `qform_code > 0`; `None` (identity) when neither is usable.
fn orientation(h: &::nifti::NiftiHeader) -> Option<([[f64; 3]; 3], [f64; 3])> {
    let rows = [h.srow_x, h.srow_y, h.srow_z].map(|r| r.map(f64::from));
    if h.sform_code > 0 {
        let columns = [0, 1, 2].map(|i| [rows[0][i], rows[1][i], rows[2][i]]);
        if let Some(directions) = normalize_columns(columns) {
            let origin = [rows[0][3], rows[1][3], rows[2][3]];
            if origin.iter().all(|v| v.is_finite()) {
                return Some((directions, origin));
            }
        }
    }
    if h.qform_code > 0 {
        let (b, c, d) = (
            f64::from(h.quatern_b),
            f64::from(h.quatern_c),
            f64::from(h.quatern_d),
        );
        let sum = b * b + c * c + d * d;
        if !sum.is_finite() {
            return None;
        }
        // As nifti1_io's nifti_quatern_to_mat44.
        let (a, b, c, d) = if 1.0 - sum < 1e-7 {
            let s = 1.0 / sum.sqrt();
            (0.0, b * s, c * s, d * s)
        } else {
            ((1.0 - sum).sqrt(), b, c, d)
        };
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let columns = [0, 1, 2].map(|i| {
            let f = if i == 2 { qfac } else { 1.0 };
            [r[0][i] * f, r[1][i] * f, r[2][i] * f]
        });
        let origin = [h.quatern_x, h.quatern_y, h.quatern_z].map(f64::from);
        if let Some(directions) = normalize_columns(columns) {
            if origin.iter().all(|v| v.is_finite()) {
                return Some((directions, origin));
            }
        }
    }
    None
}

/// Unit vectors of three direction vectors; `None` if any is zero or not finite.
pub(super) fn normalize_columns(columns: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let mut out = IDENTITY;
    for (o, c) in out.iter_mut().zip(columns) {
        let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        *o = c.map(|v| v / n);
    }
    Some(out)
}

/// Loads a NIfTI-1 file (`.nii`, or gzip-compressed `.nii.gz`; compression is detected from the
/// content). The header is validated by [`parse_nifti_header`]; raw files must hold exactly
/// `vox_offset` + the voxel bytes, gzip streams must decode to exactly that. `scl_slope` /
/// `scl_inter` are reported in the metadata, not applied.
pub fn load_nifti(path: &Path) -> Result<LoadedVolume, VolumeError> {
    describe_nifti(path)?.load()
}

/// Parses and checks a NIfTI-1 file's header (see [`load_nifti`]), reading no voxel.
pub(super) fn describe_nifti(path: &Path) -> Result<Described, VolumeError> {
    let gzip = read::is_gzip(path)?;
    let header = if gzip {
        let (file, _) = read::open_regular(path)?;
        let mut bytes = Vec::with_capacity(NIFTI1_HEADER_BYTES);
        MultiGzDecoder::new(BufReader::new(file))
            .take(NIFTI1_HEADER_BYTES as u64)
            .read_to_end(&mut bytes)
            .map_err(|e| {
                format_err(
                    path,
                    "header",
                    format!("cannot decompress the NIfTI header: {e}"),
                )
            })?;
        bytes
    } else {
        read::read_prefix(path, NIFTI1_HEADER_BYTES as u64)?.0
    };
    let info = parse_nifti_header(path, &header)?;
    let layout = layout(path, "dim", info.dims, info.stored)?;
    let payload = Payload {
        header_path: path.to_path_buf(),
        size_field: "dim",
        data_path: path.to_path_buf(),
        offset: if gzip { 0 } else { info.vox_offset },
        gzip,
        decoded_skip: if gzip { info.vox_offset } else { 0 },
        big_endian: info.big_endian,
    };
    let spacing = Vec3::from_array(info.spacing.map(|s| s as f32));
    if !(spacing.is_finite() && spacing.min_element() > 0.0) {
        return Err(format_err(
            path,
            "pixdim",
            format!("pixdim {:?} does not fit in f32", info.spacing),
        ));
    }
    Ok(Described {
        payload,
        layout,
        spacing,
        meta: info.meta,
    })
}
