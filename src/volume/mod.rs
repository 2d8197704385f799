//! Scalar volumes: voxel storage (u8, u16, f32), dimensions, spacing, synthetic fields and loaders.
//!
//! Voxel `(x, y, z)` is stored at linear index `x + dims.x * (y + dims.y * z)` (x fastest). Values are
//! exposed *normalised* the way the GPU sees them: u8 / 255, u16 / 65535 (UNORM formats) and f32 as
//! is (SFLOAT). Every sampler in the crate, CPU and GPU, works on normalised values.

pub mod formats;
mod loader;
pub mod memory;
mod rgba;
pub mod slabs;
mod synthetic;

pub use formats::{
    load_den, load_nifti, load_nrrd, load_sidecar, load_volume, load_volume_with_meta, load_zarr,
    FileFormat, LoadedVolume, StoredType, VolumeMeta,
};
pub use loader::{load_raw, save_raw, RawDescriptor};
pub use rgba::RgbaVolume;
pub use slabs::{open_raw_slabs, open_slabs, SlabMut, SlabReader};
pub use synthetic::{
    marschner_lobb, marschner_lobb_value, sphere, wall, SyntheticField,
    DEFAULT_SPHERE_RADIUS_FRACTION,
};

use glam::{UVec3, Vec3};
use std::path::PathBuf;

/// The scalar type of a volume's voxels.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ScalarType {
    /// Unsigned 8-bit, normalised to [0, 1].
    U8,
    /// Unsigned 16-bit, normalised to [0, 1].
    U16,
    /// 32-bit float, used as is.
    F32,
}

impl ScalarType {
    /// Bytes per voxel.
    pub const fn size_bytes(self) -> usize {
        match self {
            ScalarType::U8 => 1,
            ScalarType::U16 => 2,
            ScalarType::F32 => 4,
        }
    }

    /// Parses `u8`, `u16` or `f32` (case-insensitive).
    pub fn parse(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "u8" | "uint8" => Some(ScalarType::U8),
            "u16" | "uint16" => Some(ScalarType::U16),
            "f32" | "float" | "float32" => Some(ScalarType::F32),
            _ => None,
        }
    }
}

/// Voxel values in one of the supported scalar types.
#[derive(Clone, Debug, PartialEq)]
pub enum VoxelData {
    /// 8-bit unsigned voxels.
    U8(Vec<u8>),
    /// 16-bit unsigned voxels.
    U16(Vec<u16>),
    /// 32-bit float voxels (finite values only).
    F32(Vec<f32>),
}

impl VoxelData {
    /// `len` zero voxels of `scalar`.
    pub fn zeroed(scalar: ScalarType, len: usize) -> Self {
        match scalar {
            ScalarType::U8 => VoxelData::U8(vec![0; len]),
            ScalarType::U16 => VoxelData::U16(vec![0; len]),
            ScalarType::F32 => VoxelData::F32(vec![0.0; len]),
        }
    }

    /// Number of voxels stored.
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(v) => v.len(),
            VoxelData::U16(v) => v.len(),
            VoxelData::F32(v) => v.len(),
        }
    }

    /// True when no voxel is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The scalar type of the stored voxels.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            VoxelData::U8(_) => ScalarType::U8,
            VoxelData::U16(_) => ScalarType::U16,
            VoxelData::F32(_) => ScalarType::F32,
        }
    }

    /// The voxels as native-endian bytes, ready for a staging buffer.
    pub fn as_bytes(&self) -> &[u8] {
        match self {
            VoxelData::U8(v) => v,
            VoxelData::U16(v) => bytemuck::cast_slice(v),
            VoxelData::F32(v) => bytemuck::cast_slice(v),
        }
    }

    /// The normalised value of voxel `index` (see the module docs).
    #[inline]
    pub fn normalized(&self, index: usize) -> f32 {
        match self {
            VoxelData::U8(v) => f32::from(v[index]) / 255.0,
            VoxelData::U16(v) => f32::from(v[index]) / 65535.0,
            VoxelData::F32(v) => v[index],
        }
    }
}

/// Errors from building or loading a volume.
#[derive(Debug, thiserror::Error)]
pub enum VolumeError {
    /// A dimension is zero.
    #[error(
        "volume dimension {axis} is zero (dims {dims:?}); every axis needs at least one voxel"
    )]
    ZeroDimension {
        /// 'x', 'y' or 'z'.
        axis: char,
        /// The dimensions given.
        dims: [u32; 3],
    },
    /// The voxel count or byte size does not fit in memory-size arithmetic.
    #[error("volume dimensions {dims:?} overflow the addressable size")]
    SizeOverflow {
        /// The dimensions given.
        dims: [u32; 3],
    },
    /// The number of voxels does not match the dimensions.
    #[error("volume data holds {actual} voxels but dims {dims:?} need {expected}")]
    VoxelCountMismatch {
        /// The dimensions given.
        dims: [u32; 3],
        /// Voxels the dimensions imply.
        expected: usize,
        /// Voxels supplied.
        actual: usize,
    },
    /// A spacing component is not a positive finite number.
    #[error("voxel spacing {spacing:?} must be positive and finite on every axis")]
    InvalidSpacing {
        /// The spacing given.
        spacing: [f32; 3],
    },
    /// A float voxel is NaN or infinite (policy: rejected at load, never rendered as black).
    #[error(
        "{}voxel {index} (x={x}, y={y}, z={z}) is {value}; volumes must hold finite values",
        .file.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default()
    )]
    NonFinite {
        /// The file the voxel was read from, when it came from one.
        file: Option<PathBuf>,
        /// Linear index of the first offending voxel.
        index: usize,
        /// Its x coordinate.
        x: u32,
        /// Its y coordinate.
        y: u32,
        /// Its z coordinate.
        z: u32,
        /// The value found.
        value: f32,
    },
    /// The file could not be read.
    #[error("cannot read volume file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("cannot write volume file {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
    /// The header bytes to skip plus the voxel bytes overflow any file size.
    #[error(
        "{path}: {header} header bytes to skip plus {data} voxel bytes overflow any file size; \
         the header size is wrong"
    )]
    HeaderTooLarge {
        /// The file.
        path: PathBuf,
        /// Header bytes to skip.
        header: u64,
        /// Bytes of the voxels described.
        data: u64,
    },
    /// The file size does not match the described dimensions and type.
    #[error("{path}: file holds {actual} bytes but {dims:?} x {scalar:?} (+{header} header bytes) needs {expected}")]
    FileSizeMismatch {
        /// The file.
        path: PathBuf,
        /// The dimensions described.
        dims: [u32; 3],
        /// The scalar type described.
        scalar: ScalarType,
        /// Header bytes skipped.
        header: u64,
        /// Bytes expected.
        expected: u64,
        /// Bytes in the file.
        actual: u64,
    },
    /// A volume would not fit the host-memory limit ([`memory::host_memory_limit`]); checked
    /// before any voxel is allocated or computed.
    #[error(
        "{what} needs {bytes} bytes of RAM but the host-memory limit is {limit} bytes (memory \
         available, or MIXVOL_HOST_MEMORY_MB): use smaller dims or a smaller scalar type, or \
         convert the volume into a brick store and stream it"
    )]
    TooLarge {
        /// What was to be allocated.
        what: String,
        /// Bytes it needs.
        bytes: u64,
        /// The limit.
        limit: u64,
    },
    /// A parameter is out of range: of a synthetic field, a chunk or level request, an S3
    /// setting (the message names which).
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// An environment variable that sets an option (`MIXVOL_HOST_MEMORY_MB`,
    /// `MIXVOL_REMOTE_*`) holds a value that cannot be used; never ignored.
    #[error("environment variable {name}={value:?}: {expected}")]
    Environment {
        /// The variable.
        name: String,
        /// Its value.
        value: String,
        /// What it must hold.
        expected: String,
    },
    /// A slab was asked for that the reader cannot give: outside the volume, of the wrong size or
    /// scalar type, or backwards on a forward-only (gzip) reader.
    #[error("{path}: slab request: {message}")]
    SlabRequest {
        /// The file being read.
        path: PathBuf,
        /// What is wrong with the request.
        message: String,
    },
    /// A remote object (an OME-Zarr metadata document or chunk over S3 or HTTP) could not be
    /// fetched: the server failed (after the retries), stalled past the timeout, or sent a
    /// truncated body; or the remote client could not be set up.
    #[error("cannot fetch {url}: {message}")]
    Remote {
        /// The object's URL (or the store's, for a set-up failure).
        url: String,
        /// What failed.
        message: String,
    },
    /// A volume location that does not parse: a URL with an unsupported scheme, no host or
    /// bucket, a query, ...
    #[error("invalid volume location `{location}`: {message}")]
    InvalidLocation {
        /// The location as given.
        location: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// A page of a TIFF stack (a page of a multi-page file, or one file of a folder stack) is
    /// unsupported, disagrees with the stack's first page, or cannot be decoded.
    #[error("{path}: page {page}: field `{field}`: {message}")]
    TiffPage {
        /// The TIFF file holding the page.
        path: PathBuf,
        /// The page: its IFD index in the file (for a folder stack, the file's position in the
        /// stack).
        page: u64,
        /// The TIFF tag at fault (`ImageWidth`, `BitsPerSample`, `SampleFormat`,
        /// `PhotometricInterpretation`, `Compression`, ...; `data` for the page's pixel data).
        field: String,
        /// What is wrong.
        message: String,
    },
    /// A volume file's header (or the data it describes) is invalid or unsupported.
    #[error("{path}: field `{field}`: {message}")]
    Format {
        /// The file whose header is at fault.
        path: PathBuf,
        /// The header field at fault, as the format names it (`sizes`, `type`, `encoding`,
        /// `dim[3]`, `vox_offset`, `dims`, `map_length`, ...; `magic` / `header` / `json` for
        /// the file's structure, `extension` for an unknown file type).
        field: String,
        /// What is wrong.
        message: String,
    },
    /// A DICOM folder or DICOMDIR did not give one volume: several series, irregular spacing,
    /// inconsistent slices (see [`formats::DicomError`]; boxed to keep this error small).
    #[error(transparent)]
    Dicom(Box<formats::DicomError>),
}

impl From<formats::DicomError> for VolumeError {
    fn from(e: formats::DicomError) -> Self {
        VolumeError::Dicom(Box::new(e))
    }
}

impl VolumeError {
    /// This error with `path` as the file a non-finite voxel was read from (other errors name
    /// their file already and are returned unchanged).
    pub(crate) fn in_file(self, path: &std::path::Path) -> Self {
        match self {
            VolumeError::NonFinite {
                file: None,
                index,
                x,
                y,
                z,
                value,
            } => VolumeError::NonFinite {
                file: Some(path.to_path_buf()),
                index,
                x,
                y,
                z,
                value,
            },
            other => other,
        }
    }
}

/// What a path that is not a regular file is, for error messages.
fn non_file_kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_block_device() || t.is_char_device() {
            return "a device";
        }
    }
    if meta.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

/// Opens the regular file `path` for reading and returns it with its length. The file type is
/// checked with [`std::fs::metadata`] (which does not open the path) before opening, so a FIFO
/// or a device is refused at once instead of blocking in `open`; folders and other non-files are
/// [`VolumeError::Io`] errors that say what the path is.
pub(crate) fn open_regular_file(
    path: &std::path::Path,
) -> Result<(std::fs::File, u64), VolumeError> {
    use std::io::{Error, ErrorKind};
    let err = |source: Error| VolumeError::Io {
        path: path.to_path_buf(),
        source,
    };
    let refuse = |meta: &std::fs::Metadata| {
        let kind = if meta.is_dir() {
            ErrorKind::IsADirectory
        } else {
            ErrorKind::InvalidInput
        };
        let what = non_file_kind(meta);
        let message = if what == "not a regular file" {
            what.to_string()
        } else {
            format!("{what}, not a regular file; volumes are read from regular files")
        };
        err(Error::new(kind, message))
    };
    let meta = std::fs::metadata(path).map_err(err)?;
    if !meta.is_file() {
        return Err(refuse(&meta));
    }
    let file = std::fs::File::open(path).map_err(err)?;
    // The path may have been replaced between the two calls: check what was opened.
    let meta = file.metadata().map_err(err)?;
    if !meta.is_file() {
        return Err(refuse(&meta));
    }
    Ok((file, meta.len()))
}

/// A scalar volume: dimensions, voxel spacing and voxel values.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    dims: UVec3,
    spacing: Vec3,
    data: VoxelData,
}

/// Checks dims for zero axes and returns the voxel count with checked arithmetic.
pub fn checked_voxel_count(dims: UVec3) -> Result<usize, VolumeError> {
    for (axis, d) in ['x', 'y', 'z'].into_iter().zip(dims.to_array()) {
        if d == 0 {
            return Err(VolumeError::ZeroDimension {
                axis,
                dims: dims.to_array(),
            });
        }
    }
    (dims.x as usize)
        .checked_mul(dims.y as usize)
        .and_then(|n| n.checked_mul(dims.z as usize))
        .filter(|n| n.checked_mul(4).is_some())
        .ok_or(VolumeError::SizeOverflow {
            dims: dims.to_array(),
        })
}

impl Volume {
    /// Builds a volume, checking dims, spacing, voxel count and (for f32) finiteness.
    pub fn new(dims: UVec3, spacing: Vec3, data: VoxelData) -> Result<Self, VolumeError> {
        let expected = checked_voxel_count(dims)?;
        if !(spacing.is_finite() && spacing.min_element() > 0.0) {
            return Err(VolumeError::InvalidSpacing {
                spacing: spacing.to_array(),
            });
        }
        if data.len() != expected {
            return Err(VolumeError::VoxelCountMismatch {
                dims: dims.to_array(),
                expected,
                actual: data.len(),
            });
        }
        if let VoxelData::F32(values) = &data {
            if let Some(index) = values.iter().position(|v| !v.is_finite()) {
                let x = (index % dims.x as usize) as u32;
                let y = ((index / dims.x as usize) % dims.y as usize) as u32;
                let z = (index / (dims.x as usize * dims.y as usize)) as u32;
                return Err(VolumeError::NonFinite {
                    file: None,
                    index,
                    x,
                    y,
                    z,
                    value: values[index],
                });
            }
        }
        Ok(Self {
            dims,
            spacing,
            data,
        })
    }

    /// Voxel counts along x, y, z.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// Physical size of one voxel along x, y, z.
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// The voxel values.
    pub fn data(&self) -> &VoxelData {
        &self.data
    }

    /// The scalar type of the voxels.
    pub fn scalar_type(&self) -> ScalarType {
        self.data.scalar_type()
    }

    /// Physical extent `dims * spacing`.
    pub fn physical_extent(&self) -> Vec3 {
        self.dims.as_vec3() * self.spacing
    }

    /// Linear index of voxel `(x, y, z)`; the caller keeps coordinates inside `dims`.
    #[inline]
    pub fn index(&self, x: u32, y: u32, z: u32) -> usize {
        x as usize + self.dims.x as usize * (y as usize + self.dims.y as usize * z as usize)
    }

    /// Normalised value of voxel `(x, y, z)` (coordinates inside `dims`).
    #[inline]
    pub fn value(&self, x: u32, y: u32, z: u32) -> f32 {
        self.data.normalized(self.index(x, y, z))
    }

    /// Normalised value with coordinates clamped to the volume (clamp-to-edge addressing).
    #[inline]
    pub fn value_clamped(&self, x: i64, y: i64, z: i64) -> f32 {
        let c = |v: i64, d: u32| v.clamp(0, i64::from(d) - 1) as u32;
        self.value(c(x, self.dims.x), c(y, self.dims.y), c(z, self.dims.z))
    }

    /// A window (normalised values mapped to transfer-function positions 0 and 1) from the
    /// histogram: the 1st to 99.5th percentile of the voxels, leaving out the background (the
    /// most populated of 1024 bins when it is the lowest one, as air in CT and MRI is).
    pub fn auto_window(&self) -> (f32, f32) {
        const BINS: usize = 1024;
        let (lo, hi) = self.value_range();
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            return (lo, lo + 1.0);
        }
        let bin_of = |v: f32| (((v - lo) / (hi - lo)) * (BINS - 1) as f32).round() as usize;
        let mut histogram = vec![0u64; BINS];
        for i in 0..self.data.len() {
            histogram[bin_of(self.data.normalized(i))] += 1;
        }
        let fullest = (0..BINS).max_by_key(|&b| histogram[b]).unwrap_or(0);
        if fullest == 0 {
            histogram[0] = 0;
        }
        let total: u64 = histogram.iter().sum();
        if total == 0 {
            return (lo, hi);
        }
        let value_at = |fraction: f64| {
            let target = (total as f64 * fraction) as u64;
            let mut seen = 0;
            for (b, count) in histogram.iter().enumerate() {
                seen += count;
                if seen > target {
                    return lo + (hi - lo) * b as f32 / (BINS - 1) as f32;
                }
            }
            hi
        };
        let (a, b) = (value_at(0.01), value_at(0.995));
        if b > a {
            (a, b)
        } else {
            (lo, hi)
        }
    }

    /// Smallest and largest normalised voxel value.
    pub fn value_range(&self) -> (f32, f32) {
        (0..self.data.len()).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), i| {
            let v = self.data.normalized(i);
            (lo.min(v), hi.max(v))
        })
    }
}

#[cfg(test)]
mod window_tests {
    use super::*;

    #[test]
    fn auto_window_skips_background_and_outliers() {
        // 70 % background at 0, tissue spread over [0.3, 0.5], one outlier voxel at 1.0.
        let mut values = vec![0.0f32; 7000];
        values.extend((0..2999).map(|i| 0.3 + 0.2 * i as f32 / 2998.0));
        values.push(1.0);
        let v = Volume::new(UVec3::new(10, 10, 100), Vec3::ONE, VoxelData::F32(values)).unwrap();
        let (lo, hi) = v.auto_window();
        assert!((lo - 0.3).abs() < 0.01, "{lo}");
        assert!((hi - 0.5).abs() < 0.01, "{hi}");
        let constant = Volume::new(UVec3::splat(2), Vec3::ONE, VoxelData::U8(vec![7; 8])).unwrap();
        let (a, b) = constant.auto_window();
        assert!(b > a);
    }
}
