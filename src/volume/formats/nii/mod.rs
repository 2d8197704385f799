//! NIfTI-1 and NIfTI-2 single files (`.nii`, `.nii.gz`). A NIfTI-1 header is parsed by the `nifti`
//! crate, a NIfTI-2 header (which the crate does not read) by [`header2`]; both are validated
//! here alike, and the voxels are read by the shared, size-checked reader.
//!
//! # Orientation: RAS+
//!
//! The world frame is NIfTI's (and nibabel's) RAS+: +x right, +y anterior, +z superior. The
//! voxel-to-world transform is the sform when `sform_code > 0`, else the qform when
//! `qform_code > 0`, else none (the voxel axes are then taken as R, A, S). [`load_nifti`]
//! reorders the voxels so that the volume's x, y and z axes are the file axes closest to R, A
//! and S (flips and permutations, as nibabel's `io_orientation` pairs them; spacing permuted
//! alike), so a LAS file and a RAS file holding the same anatomy load to identical volumes and
//! render identically. What was done is in [`VolumeMeta::reorientation`]; after it
//! [`VolumeMeta::directions`] holds the residual rotation (identity for an axis-aligned file) and
//! [`VolumeMeta::origin`] the world position of the reordered voxel (0, 0, 0). The voxels are not
//! resampled for an oblique residual rotation: it becomes the volume's model transform
//! (`scene::ModelTransform::of_volume`, a rotation about the volume's centre applied by the renderer,
//! see `scene::model`), so an oblique file renders in RAS+ patient space; without it
//! (`mixvol render --axis-aligned`) it renders axis-aligned in its nearest RAS orientation, and the
//! reorientation says by how many degrees it is oblique.
//!
//! # Values: `scl_slope` / `scl_inter`
//!
//! When `scl_slope` is finite and non-zero and (slope, inter) is not (1, 0), the voxels are
//! converted to f32 physical values `slope * stored + inter` (e.g. Hounsfield units), so windows
//! are in those units ([`VolumeMeta::scale_applied`]). Otherwise the stored values are kept
//! (integers normalised as the module docs of [`crate::volume::formats`] say; i16 as u16 + 32768,
//! whose file units [`VolumeMeta::normalized`] / [`VolumeMeta::file_value`] convert).
//!
//! The slab reader ([`crate::volume::open_slabs`], used by `mixvol convert`) reads file order and
//! stored values: it refuses files that need reordering or scaling, rather than disagree with
//! the loader.
mod header2;
mod orient;

pub use header2::NIFTI2_HEADER_BYTES;
pub(super) use orient::normalize_columns;
pub(super) use orient::{reorder, reorientation};
pub use orient::{Reorientation, TransformSource};

use super::read::{self, format_err, layout, Described, Payload};
use super::{FileFormat, LoadedVolume, StoredType, VolumeMeta, MAX_VOLUME_BYTES};
use crate::volume::{Volume, VolumeError, VoxelData};
use flate2::bufread::MultiGzDecoder;
use glam::Vec3;
use std::io::{BufReader, Read};
use std::path::Path;

/// Size of a NIfTI-1 header in bytes (`sizeof_hdr`).
pub const NIFTI1_HEADER_BYTES: usize = 348;

/// What a validated NIfTI-1 or NIfTI-2 header describes.
#[derive(Clone, Debug, PartialEq)]
pub struct NiftiInfo {
    /// 1 for NIfTI-1, 2 for NIfTI-2.
    pub version: u8,
    /// Voxel counts along the file's x, y, z (`dim[1..=3]`; 1 for axes beyond `dim[0]`).
    pub dims: [u64; 3],
    /// Stored value type (`datatype`).
    pub stored: StoredType,
    /// True for a big-endian file (detected from `sizeof_hdr`).
    pub big_endian: bool,
    /// Voxel spacing in file axis order: the lengths of the transform's columns (sform, else
    /// qform, which is `|pixdim[1..=3]|`), else `|pixdim[1..=3]|` (in the file's `xyzt_units`;
    /// only ratios matter here).
    pub spacing: [f64; 3],
    /// Byte offset of the voxels (`vox_offset`).
    pub vox_offset: u64,
    /// The voxel reordering to RAS+ that [`load_nifti`] applies.
    pub reorientation: Reorientation,
    /// Orientation and value scaling after the reordering (see [`VolumeMeta`]).
    pub meta: VolumeMeta,
}

/// The header fields the loader uses, from either version, widened to NIfTI-2's types.
#[derive(Clone, Debug)]
pub(super) struct RawHeader {
    version: u8,
    header_bytes: u64,
    big_endian: bool,
    datatype: i16,
    bitpix: i16,
    dim: [i64; 8],
    pixdim: [f64; 8],
    vox_offset: f64,
    scl_slope: f64,
    scl_inter: f64,
    qform_code: i32,
    sform_code: i32,
    quatern: [f64; 3],
    qoffset: [f64; 3],
    srow: [[f64; 4]; 3],
}

/// Parses and validates a NIfTI header: NIfTI-1 (the first [`NIFTI1_HEADER_BYTES`] bytes) or
/// NIfTI-2 (`sizeof_hdr` 540, the first [`NIFTI2_HEADER_BYTES`] bytes), in either byte order
/// (`path` is only named in errors). Checks `sizeof_hdr`, the magic (`n+1` / `n+2`: single
/// `.nii` files only), `dim` (1 to 3 spatial axes of at least one voxel; a 4th or higher axis
/// must have size 1), `datatype` and `bitpix`, `pixdim[1..=3]` (finite, non-zero) and
/// `vox_offset` (whole number, at least the header size), and that the volume's size is within
/// [`MAX_VOLUME_BYTES`] (field `dim`). Errors are [`VolumeError::Format`] naming the field.
pub fn parse_nifti_header(path: &Path, bytes: &[u8]) -> Result<NiftiInfo, VolumeError> {
    if bytes.len() < 4 {
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
    let raw = if size_le == 540 || size_be == 540 {
        header2::parse(path, bytes)?
    } else {
        header1(path, bytes, size_le, size_be)?
    };
    validate(path, &raw)
}

/// The NIfTI-1 header through the `nifti` crate.
fn header1(
    path: &Path,
    bytes: &[u8],
    size_le: i32,
    size_be: i32,
) -> Result<RawHeader, VolumeError> {
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
    if size_le != 348 && size_be != 348 {
        return Err(format_err(
            path,
            "sizeof_hdr",
            format!(
                "sizeof_hdr is {size_le}, expected 348 (NIfTI-1) or 540 (NIfTI-2): not a NIfTI \
                 file"
            ),
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
    let f = |v: [f32; 4]| v.map(f64::from);
    Ok(RawHeader {
        version: 1,
        header_bytes: NIFTI1_HEADER_BYTES as u64,
        big_endian: h.endianness == ::nifti::Endianness::Big,
        datatype: h.datatype,
        bitpix: h.bitpix,
        // dim is i16 in the standard; the crate reads it as u16.
        dim: h.dim.map(|d| i64::from(d as i16)),
        pixdim: h.pixdim.map(f64::from),
        vox_offset: f64::from(h.vox_offset),
        scl_slope: f64::from(h.scl_slope),
        scl_inter: f64::from(h.scl_inter),
        qform_code: i32::from(h.qform_code),
        sform_code: i32::from(h.sform_code),
        quatern: [h.quatern_b, h.quatern_c, h.quatern_d].map(f64::from),
        qoffset: [h.quatern_x, h.quatern_y, h.quatern_z].map(f64::from),
        srow: [f(h.srow_x), f(h.srow_y), f(h.srow_z)],
    })
}

/// The checks common to both versions.
fn validate(path: &Path, h: &RawHeader) -> Result<NiftiInfo, VolumeError> {
    let dim = h.dim;
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
        let p = h.pixdim[i + 1].abs();
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
        && vox >= h.header_bytes as f64
        && vox <= MAX_VOLUME_BYTES as f64)
    {
        return Err(format_err(
            path,
            "vox_offset",
            format!(
                "vox_offset is {vox}, expected a whole number of bytes >= {}",
                h.header_bytes
            ),
        ));
    }

    let mut meta = VolumeMeta::plain(FileFormat::Nifti, stored, h.big_endian);
    let (slope, inter) = (h.scl_slope, h.scl_inter);
    if slope.is_finite() && slope != 0.0 {
        meta.scale_slope = slope;
        meta.scale_inter = if inter.is_finite() { inter } else { 0.0 };
    }
    let affine = orient::affine(h);
    if let Some((m, _)) = &affine {
        // The voxel size in world space is the transform's (an sform need not agree with
        // pixdim, which nibabel keeps with the qform).
        for (i, s) in spacing.iter_mut().enumerate() {
            *s = (0..3).map(|r| m[r][i] * m[r][i]).sum::<f64>().sqrt();
        }
    }
    let (reorientation, directions, origin) = orient::reorientation(affine, dims);
    meta.directions = directions;
    meta.origin = origin;
    meta.reorientation = Some(reorientation.clone());
    Ok(NiftiInfo {
        version: h.version,
        dims,
        stored,
        big_endian: h.big_endian,
        spacing,
        vox_offset: vox as u64,
        reorientation,
        meta,
    })
}

/// Loads a NIfTI-1 or NIfTI-2 file (`.nii`, or gzip-compressed `.nii.gz`; compression is detected
/// from the content). The header is validated by [`parse_nifti_header`]; raw files must hold
/// exactly `vox_offset` + the voxel bytes, gzip streams must decode to exactly that.
///
/// The voxels are reordered to RAS+ (+x right, +y anterior, +z superior, as NIfTI and nibabel):
/// flips and permutations from the sform, else the qform, else none, recorded in
/// [`VolumeMeta::reorientation`]; a residual oblique rotation is reported there and is not
/// applied. `scl_slope` / `scl_inter` other than (1, 0) are applied, giving f32 physical values
/// ([`VolumeMeta::scale_applied`]).
pub fn load_nifti(path: &Path) -> Result<LoadedVolume, VolumeError> {
    let (described, reorientation) = describe(path)?;
    let LoadedVolume { volume, mut meta } = described.load()?;
    let volume = apply_scaling(path, volume, &mut meta)?;
    let volume = orient::reorder(path, volume, &reorientation)?;
    Ok(LoadedVolume { volume, meta })
}

/// Converts the voxels to f32 `slope * stored + inter` when the scaling is not the identity.
fn apply_scaling(
    path: &Path,
    volume: Volume,
    meta: &mut VolumeMeta,
) -> Result<Volume, VolumeError> {
    let (slope, inter) = (meta.scale_slope, meta.scale_inter);
    if slope == 1.0 && inter == 0.0 {
        return Ok(volume);
    }
    crate::volume::memory::check_host_bytes(
        &format!("{} (scl_slope / scl_inter applied, as f32)", path.display()),
        volume.data().len() as u64 * 4,
    )?;
    let offset = f64::from(meta.stored.value_offset());
    let physical = |raw: f64| (slope * (raw - offset) + inter) as f32;
    let values: Vec<f32> = match volume.data() {
        VoxelData::U8(v) => v.iter().map(|&x| physical(f64::from(x))).collect(),
        VoxelData::U16(v) => v.iter().map(|&x| physical(f64::from(x))).collect(),
        VoxelData::F32(v) => v.iter().map(|&x| physical(f64::from(x))).collect(),
    };
    let (dims, spacing) = (volume.dims(), volume.spacing());
    drop(volume);
    meta.scale_applied = true;
    // Non-finite results (a slope overflowing f32) are refused by Volume::new, naming the voxel.
    Volume::new(dims, spacing, VoxelData::F32(values)).map_err(|e| e.in_file(path))
}

/// Parses and checks a NIfTI file's header (see [`load_nifti`]), reading no voxel, for the slab
/// reader: refuses files that need reordering or value scaling, which it does not do.
pub(super) fn describe_nifti(path: &Path) -> Result<Described, VolumeError> {
    let (described, reorientation) = describe(path)?;
    if !reorientation.is_identity() {
        return Err(orient::needs_loader(
            path,
            &format!(
                "the voxels are stored {} and must be reordered to RAS",
                reorientation.file_code()
            ),
        ));
    }
    let m = &described.meta;
    if !(m.scale_slope == 1.0 && m.scale_inter == 0.0) {
        return Err(orient::needs_loader(
            path,
            &format!(
                "scl_slope {} / scl_inter {} must be applied",
                m.scale_slope, m.scale_inter
            ),
        ));
    }
    Ok(described)
}

/// The header, checked, and the reordering the loader applies.
fn describe(path: &Path) -> Result<(Described, Reorientation), VolumeError> {
    let gzip = read::is_gzip(path)?;
    let header = if gzip {
        let (file, _) = read::open_regular(path)?;
        let mut decoder = MultiGzDecoder::new(BufReader::new(file));
        let mut bytes = Vec::with_capacity(NIFTI2_HEADER_BYTES);
        let mut read_up_to = |bytes: &mut Vec<u8>, n: usize| {
            (&mut decoder)
                .take((n - bytes.len()) as u64)
                .read_to_end(bytes)
                .map_err(|e| {
                    format_err(
                        path,
                        "header",
                        format!("cannot decompress the NIfTI header: {e}"),
                    )
                })
        };
        // NIfTI-1's 348 bytes first (a small NIfTI-1 stream may end before 540), then the rest
        // of a NIfTI-2 header.
        read_up_to(&mut bytes, NIFTI1_HEADER_BYTES)?;
        if bytes.len() >= 4
            && (bytes[..4] == 540i32.to_le_bytes() || bytes[..4] == 540i32.to_be_bytes())
        {
            read_up_to(&mut bytes, NIFTI2_HEADER_BYTES)?;
        }
        bytes
    } else {
        read::read_prefix(path, NIFTI2_HEADER_BYTES as u64)?.0
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
    Ok((
        Described {
            payload,
            layout,
            spacing,
            meta: info.meta,
        },
        info.reorientation,
    ))
}
