//! Volume file formats: NIfTI-1 and NIfTI-2 (`.nii`, `.nii.gz`), NRRD (`.nrrd`, detached `.nhdr`; raw or gzip
//! encoding), raw data described by a JSON sidecar (`.json`, or `.raw` beside one) and VolPack /
//! Levoy density files (`.den`), OME-Zarr images (`.zarr` folders, Zarr v2 and v3, through
//! the `zarrs` crate; see [`zarr`]), TIFF stacks (multi-page TIFF and BigTIFF, OME-TIFF
//! with physical sizes, folders of single-page TIFFs; `.tif`, `.tiff`, `.btf`, through the
//! `tiff` crate; see [`tiff`]), and DICOM series (a folder, a DICOMDIR or a `.dcm` file,
//! through dicom-rs; see [`dicom`]).
//!
//! [`load_volume`] picks the format from the file name; the per-format loaders
//! ([`load_nifti`], [`load_nrrd`], [`load_sidecar`], [`load_den`], [`load_tiff`]) return the volume together
//! with [`VolumeMeta`] (stored type, value offset, orientation), and the header parsers
//! ([`parse_nifti_header`], [`parse_nrrd_header`], [`parse_sidecar`], [`parse_den_header`],
//! [`parse_ome_xml`]) work
//! on bytes, without touching the file system (they are the fuzz targets' entry points).
//!
//! # Safety against hostile files
//!
//! Every size is computed with checked arithmetic from the header before anything is allocated:
//! axes of size 0, sizes beyond `u32::MAX` per axis, and volumes above [`MAX_VOLUME_BYTES`] are
//! refused. Raw data must fill its file exactly. Gzip data is decoded through a `take` limit of
//! the described size (plus one byte, to detect a stream that is too long), and its buffer grows
//! with the data actually decoded, so a small file that claims a huge volume fails at its real
//! end instead of allocating the claimed size. Header-only reads (NRRD headers, sidecars) are
//! capped at [`MAX_HEADER_BYTES`]. Problems are [`VolumeError::Format`] errors naming the file and
//! the header field at fault; no input panics.
//!
//! # Value mapping
//!
//! Volumes hold u8, u16 or f32 (see [`crate::volume`]). Stored types map as follows
//! ([`StoredType::volume_scalar`], [`StoredType::value_offset`]):
//!
//! | stored      | volume | mapping                                       |
//! |-------------|--------|-----------------------------------------------|
//! | u8          | u8     | as is                                         |
//! | i8          | u8     | `+128` ([`I8_OFFSET`]): -128 → 0, 127 → 255    |
//! | u16         | u16    | as is                                         |
//! | i16         | u16    | `+32768` ([`I16_OFFSET`]): -32768 → 0, 0 → 32768, 32767 → 65535 |
//! | u32, i32    | f32    | converted (exact up to 2^24)                  |
//! | f32         | f32    | as is; NaN / infinity rejected                |
//! | f64         | f32    | rounded; values beyond f32 range rejected     |
//!
//! The integer offsets keep the data exact and keep the GPU's UNORM sampling; to set a window
//! in file units (e.g. Hounsfield units of an i16 CT) use [`VolumeMeta::normalized`], which maps
//! a stored value to the normalised value the renderer sees ([`VolumeMeta::file_value`] back).
//! NIfTI `scl_slope` / `scl_inter` other than (1, 0) are applied: the voxels become f32 physical
//! values (HU for CT; [`VolumeMeta::scale_applied`]), so windows are in those units.
//!
//! # Spacing and orientation
//!
//! NIfTI voxels are reordered to RAS+ (+x right, +y anterior, +z superior; flips and
//! permutations from the sform, else the qform; see [`load_nifti`] and
//! [`VolumeMeta::reorientation`]). DICOM series are reordered the same way from their LPS patient
//! geometry (see [`dicom`]). The voxels are never resampled: an oblique residual rotation is left
//! in [`VolumeMeta::directions`] and rendered as the volume's model transform
//! (`scene::ModelTransform::of_volume`: a rotation about the volume's centre into RAS+ patient space,
//! the ray-caster staying in the volume's own axis-aligned frame and the camera mapped into it;
//! see `scene::model`). `mixvol render` applies it by default and `--axis-aligned`
//! renders without it. Other formats keep
//! voxels in file order (first axis fastest), never resampled or flipped. Spacing is the
//! size of a voxel step along each index axis: NIfTI `|pixdim[1..=3]|`, NRRD the norms of the
//! `space directions` vectors (else `|spacings|`, else 1), the sidecar's `spacing`, 1 for `.den`,
//! OME-TIFF `PhysicalSizeX/Y/Z` in micrometres (1 for plain TIFF; see [`tiff`]).
//! So anisotropic voxels render with the right aspect. The direction of each index axis in the
//! file's world frame (NIfTI: sform, else qform, else identity; NRRD: `space directions`) is
//! reported as unit vectors in [`VolumeMeta::directions`], with [`VolumeMeta::origin`]; for NRRD
//! an axis whose direction points the "wrong" way therefore renders mirrored relative to the
//! world frame: for formats other than NIfTI and DICOM the renderer works in index space.

mod den;
pub mod dicom;
mod nii;
mod nrrd;
mod read;
mod sidecar;
pub(crate) mod slab_readers;
pub mod tiff;
pub mod zarr;

pub use den::{load_den, parse_den_header, DenHeader, DEN_HEADER_BYTES};
pub use dicom::{
    decode_dicom_slice, list_dicom_series, load_dicom, parse_dicom_slice, DicomError, DicomOptions,
    DicomSlice, SeriesSelector, SeriesSummary,
};
pub use nii::{
    load_nifti, parse_nifti_header, NiftiInfo, Reorientation, TransformSource, NIFTI1_HEADER_BYTES,
    NIFTI2_HEADER_BYTES,
};
pub use nrrd::{load_nrrd, parse_nrrd_header, NrrdHeader};
pub use sidecar::{load_sidecar, parse_sidecar, Sidecar};
pub use tiff::{load_tiff, load_tiff_with, parse_ome_xml, TiffOptions, TiffSlabs};
pub use zarr::{
    load_zarr, load_zarr_at, load_zarr_level, parse_zarr_root, RemoteObject, RemoteOptions,
    ZarrChunk, ZarrChunks, ZarrLocation, ZarrRoot, ZarrVersion,
};

use super::{ScalarType, Volume, VolumeError};
use read::format_err;
use std::path::{Path, PathBuf};

/// The largest volume a loader accepts, in bytes (stored and in memory): 16 GiB.
pub const MAX_VOLUME_BYTES: u64 = 16 << 30;

/// The largest text header (NRRD header, JSON sidecar) read, in bytes: 1 MiB.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Added to signed 16-bit values to store them as u16 (-32768 → 0).
pub const I16_OFFSET: i32 = 32768;

/// Added to signed 8-bit values to store them as u8 (-128 → 0).
pub const I8_OFFSET: i32 = 128;

/// The type of the values stored in a file (before mapping to the volume's [`ScalarType`]).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum StoredType {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit (stored as u8 with [`I8_OFFSET`]).
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit (stored as u16 with [`I16_OFFSET`]).
    I16,
    /// Unsigned 32-bit (converted to f32).
    U32,
    /// Signed 32-bit (converted to f32).
    I32,
    /// 32-bit float.
    F32,
    /// 64-bit float (converted to f32).
    F64,
}

impl StoredType {
    /// Bytes per stored value.
    pub const fn size_bytes(self) -> usize {
        match self {
            StoredType::U8 | StoredType::I8 => 1,
            StoredType::U16 | StoredType::I16 => 2,
            StoredType::U32 | StoredType::I32 | StoredType::F32 => 4,
            StoredType::F64 => 8,
        }
    }

    /// The volume scalar type the values are mapped to (see the module docs).
    pub const fn volume_scalar(self) -> ScalarType {
        match self {
            StoredType::U8 | StoredType::I8 => ScalarType::U8,
            StoredType::U16 | StoredType::I16 => ScalarType::U16,
            StoredType::U32 | StoredType::I32 | StoredType::F32 | StoredType::F64 => {
                ScalarType::F32
            }
        }
    }

    /// What is added to a stored value to get the volume's raw value: [`I8_OFFSET`] for i8,
    /// [`I16_OFFSET`] for i16, 0 otherwise.
    pub const fn value_offset(self) -> i32 {
        match self {
            StoredType::I8 => I8_OFFSET,
            StoredType::I16 => I16_OFFSET,
            _ => 0,
        }
    }

    /// Short lowercase name: `u8`, `i8`, `u16`, `i16`, `u32`, `i32`, `f32`, `f64`.
    pub const fn name(self) -> &'static str {
        match self {
            StoredType::U8 => "u8",
            StoredType::I8 => "i8",
            StoredType::U16 => "u16",
            StoredType::I16 => "i16",
            StoredType::U32 => "u32",
            StoredType::I32 => "i32",
            StoredType::F32 => "f32",
            StoredType::F64 => "f64",
        }
    }

    /// Parses a short name or a common alias (`uint8`, `int16`, `float32`, `float`, `double`,
    /// ...), case-insensitively.
    pub fn parse(name: &str) -> Option<Self> {
        Some(match name.to_ascii_lowercase().as_str() {
            "u8" | "uint8" => StoredType::U8,
            "i8" | "int8" => StoredType::I8,
            "u16" | "uint16" => StoredType::U16,
            "i16" | "int16" => StoredType::I16,
            "u32" | "uint32" => StoredType::U32,
            "i32" | "int32" => StoredType::I32,
            "f32" | "float32" | "float" => StoredType::F32,
            "f64" | "float64" | "double" => StoredType::F64,
            _ => return None,
        })
    }
}

/// How voxel data is encoded in its file (NRRD `encoding`, sidecar `encoding`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// The values as they are.
    Raw,
    /// A gzip stream of the values.
    Gzip,
}

/// The file formats [`load_volume`] knows.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum FileFormat {
    /// NIfTI-1, `.nii` or `.nii.gz`.
    Nifti,
    /// NRRD, `.nrrd` (attached or detached data) or `.nhdr` (detached header).
    Nrrd,
    /// Raw data with a JSON sidecar (`.json`, or `.raw` with a sibling `.json`).
    Sidecar,
    /// VolPack / Levoy density file, `.den`.
    Den,
    /// OME-Zarr image or plain Zarr array (v2 or v3): a folder, usually `.zarr` / `.ome.zarr`.
    Zarr,
    /// TIFF stack: `.tif` / `.tiff` / `.btf` / `.tf8` (plain, BigTIFF or OME-TIFF), or a folder
    /// of single-page TIFFs.
    Tiff,
    /// DICOM series: a folder of DICOM files, a `DICOMDIR`, or one `.dcm` / `.dicom` file.
    Dicom,
}

impl FileFormat {
    /// The format a file name implies (case-insensitive extension), if any. `.raw` files map to
    /// [`FileFormat::Sidecar`]; [`load_volume`] then looks for the sidecar next to them.
    pub fn from_path(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        let ends = |ext: &str| name.len() > ext.len() && name.ends_with(ext);
        if ends(".nii") || ends(".nii.gz") {
            Some(FileFormat::Nifti)
        } else if ends(".nrrd") || ends(".nhdr") {
            Some(FileFormat::Nrrd)
        } else if ends(".json") || ends(".raw") {
            Some(FileFormat::Sidecar)
        } else if ends(".den") {
            Some(FileFormat::Den)
        } else if ends(".zarr") {
            Some(FileFormat::Zarr)
        } else if tiff::has_tiff_extension(&name) {
            Some(FileFormat::Tiff)
        } else if ends(".dcm") || ends(".dicom") || dicom::is_dicomdir_name(path) {
            Some(FileFormat::Dicom)
        } else {
            None
        }
    }

    /// The format [`load_volume`] reads `path` as, looking at the file system as well as the
    /// name: [`FileFormat::from_path`], except that a `.raw` file counts only when its JSON
    /// sidecar exists (`NAME.raw.json` or `NAME.json`; a bare `.raw` is headerless data that the
    /// caller must describe), and a folder holding Zarr metadata (`zarr.json`, `.zattrs`,
    /// `.zarray`) is [`FileFormat::Zarr`] whatever its name, another folder holding `.tif`
    /// / `.tiff` files is [`FileFormat::Tiff`] (a folder stack), and another folder holding a
    /// `DICOMDIR` or DICOM files is [`FileFormat::Dicom`]. `None`: no format with a header.
    pub fn detect(path: &Path) -> Option<Self> {
        let lower = path
            .file_name()
            .map(|n| n.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match Self::from_path(path) {
            Some(FileFormat::Sidecar) if lower.ends_with(".raw") => raw_sidecar_candidates(path)
                .iter()
                .any(|p| p.is_file())
                .then_some(FileFormat::Sidecar),
            Some(format) => Some(format),
            None if is_zarr_folder(path) => Some(FileFormat::Zarr),
            None if tiff::is_tiff_folder(path) => Some(FileFormat::Tiff),
            None if dicom::is_dicom_folder(path) => Some(FileFormat::Dicom),
            None => None,
        }
    }
}

/// Whether `path` is a folder holding Zarr v2 or v3 metadata.
fn is_zarr_folder(path: &Path) -> bool {
    ["zarr.json", ".zattrs", ".zarray"]
        .iter()
        .any(|m| path.join(m).is_file())
}

/// What a loader learned besides the voxels.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeMeta {
    /// The format read.
    pub format: FileFormat,
    /// The type of the values in the file.
    pub stored: StoredType,
    /// True when the file's multi-byte values were big-endian.
    pub big_endian: bool,
    /// Unit vectors: the world direction of increasing x, y and z index (`directions[i]` for
    /// index axis `i`), in the file's world frame (NIfTI, DICOM: RAS+; NRRD: its `space`).
    /// Identity when the file has no orientation. NIfTI and DICOM voxels are reordered to RAS+ (see
    /// [`VolumeMeta::reorientation`]), so these are the residual rotation, near identity (rendered
    /// through `scene::ModelTransform::of_volume`); other formats keep file order and report the
    /// file's directions.
    pub directions: [[f64; 3]; 3],
    /// World position of voxel (0, 0, 0)'s centre; zero when the file has none.
    pub origin: [f64; 3],
    /// NIfTI `scl_slope` (DICOM: the first slice's RescaleSlope): physical value =
    /// `scale_slope * stored + scale_inter` (1 elsewhere, and where the file's slope is 0 or not
    /// finite).
    pub scale_slope: f64,
    /// NIfTI `scl_inter` (DICOM: the first slice's RescaleIntercept; 0 elsewhere).
    pub scale_inter: f64,
    /// True when the loader applied `scale_slope` / `scale_inter`: the volume then holds f32
    /// physical values (NIfTI with a non-identity scaling, DICOM with a non-identity rescale).
    pub scale_applied: bool,
    /// NIfTI and DICOM: how the voxels were reordered to RAS+ (`None` for the other formats,
    /// which keep file order).
    pub reorientation: Option<Reorientation>,
    /// A Zarr level read whole: how many of its chunks exist, and how many it has (`None` for
    /// other formats). A missing chunk is the fill value (the Zarr spec), but none or few found
    /// usually means chunks stored under other names (review D7), which a caller should say.
    pub chunks_found: Option<(u64, u64)>,
}

impl VolumeMeta {
    /// Metadata with no orientation and no value scaling.
    pub fn plain(format: FileFormat, stored: StoredType, big_endian: bool) -> Self {
        Self {
            format,
            stored,
            big_endian,
            directions: IDENTITY,
            origin: [0.0; 3],
            scale_slope: 1.0,
            scale_inter: 0.0,
            scale_applied: false,
            reorientation: None,
            chunks_found: None,
        }
    }

    /// The normalised value (what transfer functions see, see [`crate::volume`]) of a value in
    /// file units: as stored for integer volumes, `(stored + offset) / 255` for u8 / i8,
    /// `(stored + offset) / 65535` for u16 / i16, the value itself for float volumes and for
    /// volumes whose scaling was applied ([`VolumeMeta::scale_applied`]: the value is then the
    /// physical one, e.g. HU). Use it to place a window given in file units, e.g.
    /// `meta.normalized(-1000.0)` for air in an i16 CT.
    pub fn normalized(&self, value: f64) -> f32 {
        if self.scale_applied {
            return value as f32;
        }
        let raw = value + f64::from(self.stored.value_offset());
        match self.stored.volume_scalar() {
            ScalarType::U8 => (raw / 255.0) as f32,
            ScalarType::U16 => (raw / 65535.0) as f32,
            ScalarType::F32 => raw as f32,
        }
    }

    /// The inverse of [`VolumeMeta::normalized`]: the value in file units (HU for an i16 CT) of a
    /// normalised value, e.g. to print a window the renderer uses.
    pub fn file_value(&self, normalized: f32) -> f64 {
        let n = f64::from(normalized);
        if self.scale_applied {
            return n;
        }
        let offset = f64::from(self.stored.value_offset());
        match self.stored.volume_scalar() {
            ScalarType::U8 => n * 255.0 - offset,
            ScalarType::U16 => n * 65535.0 - offset,
            ScalarType::F32 => n - offset,
        }
    }

    /// True for each index axis whose direction has a negative component along its own world
    /// axis (x axis pointing to -x, ...): such an axis renders mirrored relative to world space.
    pub fn flipped(&self) -> [bool; 3] {
        [0, 1, 2].map(|i| self.directions[i][i] < 0.0)
    }
}

/// The 3x3 identity, as direction vectors.
pub(crate) const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// A loaded volume with its metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedVolume {
    /// The voxels, dims and spacing.
    pub volume: Volume,
    /// Stored type, orientation and value scaling.
    pub meta: VolumeMeta,
}

/// Loads a volume file, choosing the format from its name: `.nii` / `.nii.gz` (NIfTI-1),
/// `.nrrd` / `.nhdr` (NRRD), `.json` (raw data + JSON sidecar), `.raw` (with a sibling
/// `NAME.raw.json` or `NAME.json` sidecar), `.den` (VolPack), `.zarr` (OME-Zarr folder; any
/// folder holding `zarr.json`, `.zattrs` or `.zarray` too), `.tif` / `.tiff` / `.btf` (TIFF
/// stack, OME-TIFF at channel 0 and time 0; a folder of TIFFs too), `.dcm` / `.dicom` /
/// `DICOMDIR` and folders of DICOM files (one series, [`load_dicom`]; to choose among several
/// series call it with [`DicomOptions`]). Other names give a [`VolumeError::Format`] error on
/// the field `extension`. See the module docs for the value
/// mapping and the orientation policy.
pub fn load_volume(path: &Path) -> Result<Volume, VolumeError> {
    load_volume_with_meta(path).map(|loaded| loaded.volume)
}

/// [`load_volume`], also returning the file's [`VolumeMeta`].
pub fn load_volume_with_meta(path: &Path) -> Result<LoadedVolume, VolumeError> {
    let lower = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match FileFormat::from_path(path) {
        Some(FileFormat::Nifti) => load_nifti(path),
        Some(FileFormat::Nrrd) => load_nrrd(path),
        Some(FileFormat::Den) => load_den(path),
        Some(FileFormat::Zarr) => load_zarr(path),
        Some(FileFormat::Tiff) => load_tiff(path),
        Some(FileFormat::Sidecar) if lower.ends_with(".json") => load_sidecar(path),
        Some(FileFormat::Sidecar) => slab_readers::describe_raw_with_sidecar(path)?.load(),
        Some(FileFormat::Dicom) => load_dicom(path, &DicomOptions::default()),
        None if is_zarr_folder(path) => load_zarr(path),
        None if tiff::is_tiff_folder(path) => load_tiff(path),
        None if dicom::is_dicom_folder(path) => load_dicom(path, &DicomOptions::default()),
        None => Err(unknown_extension(path)),
    }
}

/// The error for a file whose name names no known format.
fn unknown_extension(path: &Path) -> VolumeError {
    format_err(
        path,
        "extension",
        "unknown volume file type; expected .nii, .nii.gz, .nrrd, .nhdr, .json, \
         .raw (with a .json sidecar), .den, .tif / .tiff / .btf, .dcm, DICOMDIR, a .zarr \
         folder, a folder of .tif files or a folder of DICOM files",
    )
}

/// `NAME.raw.json` and `NAME.json` for `NAME.raw`.
fn raw_sidecar_candidates(raw: &Path) -> [PathBuf; 2] {
    let mut appended = raw.as_os_str().to_owned();
    appended.push(".json");
    [PathBuf::from(appended), raw.with_extension("json")]
}

/// True when both paths name the same file (compared canonically when possible).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}
