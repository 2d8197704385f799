//! DICOM series: a folder (or a DICOMDIR) holding the slices of one series becomes a volume,
//! through the dicom-rs crates (dicom-object parses the files, dicom-pixeldata decodes the pixel
//! data).
//!
//! # Input
//!
//! [`load_dicom`] takes a folder, a DICOMDIR file or one DICOM file:
//! - a folder holding a `DICOMDIR` is read through it (below); any other folder contributes
//!   the regular files directly in it (not its subfolders) that start with the DICOM Part 10
//!   preamble and `DICM`. A file without them that has a DICOM extension (`.dcm`, `.dicom`,
//!   `.dic`, `.ima`) or is named in the scheme of the DICOM files beside it (the same name
//!   with its digits taken out: `IM0015.dcm` beside `IM0001.dcm`) is a slice damaged, cut
//!   short or emptied: the load is refused, naming it ([`DicomError::LostSlices`]), as the
//!   series would load a slice short. Other files (a README) are skipped with a warning (the
//!   `log` crate) that names them and the count;
//! - a `DICOMDIR` file contributes every file its directory records reference
//!   (ReferencedFileID, relative to its folder);
//! - a single file (`.dcm`) is a one-slice series on its own (give the folder to load the whole
//!   series).
//!
//! Files without an image (no Rows: reports, structure sets) are skipped. The images are grouped
//! by SeriesInstanceUID. One series loads; with several, [`DicomOptions::series`] (the CLI's
//! `--series`) chooses one by UID or SeriesNumber, and without it the error
//! ([`DicomError::SeveralSeries`]) lists each series' UID, number, description, modality and
//! slice count ([`list_dicom_series`] gives the same list).
//!
//! # Geometry and orientation: LPS in the files, RAS+ in the volume
//!
//! DICOM patient coordinates are LPS (+x to the patient's left, +y posterior, +z superior).
//! ImageOrientationPatient gives the row direction (increasing column) and the column direction
//! (increasing row); their cross product is the slice normal, and the slices are sorted by the
//! projection of ImagePositionPatient on it, whatever the file names or the file order
//! (InstanceNumber is only used, and required, when no slice has a position). The volume's file
//! order is x = column, y = row, z = sorted slice; spacing is PixelSpacing (x: between columns,
//! y: between rows; 1 mm when absent) and the slice gap along the normal (one slice:
//! SpacingBetweenSlices, else SliceThickness, else 1 mm). Every slice must share Rows, Columns,
//! BitsAllocated, PixelRepresentation, PixelSpacing and ImageOrientationPatient
//! ([`DicomError::Inconsistent`]).
//!
//! The gaps between consecutive slices must be equal within 1 % (or 0.001 mm): an irregular
//! series (a missing slice, a varying table increment) is **refused**, not resampled, with
//! [`DicomError::IrregularSpacing`] naming the two slices, their gap and the series' median gap.
//! Two slices at one position ([`DicomError::DuplicatePosition`]) and slice origins off the
//! line along the normal (gantry tilt, [`DicomError::Sheared`]) are refused too.
//!
//! The voxel-to-patient affine is converted from LPS to RAS+ (x and y negated) and the voxels are
//! reordered exactly as NIfTI's are (flips and permutations to the axes closest to R, A, S; see
//! [`crate::volume::formats::load_nifti`]): the volume's x, y, z are right, anterior, superior,
//! [`VolumeMeta::reorientation`] says what was done (source [`TransformSource::Dicom`]),
//! [`VolumeMeta::directions`] holds the residual (oblique) rotation, rendered as the volume's
//! model transform as for NIfTI (`scene::ModelTransform::of_volume`), and
//! [`VolumeMeta::origin`] the RAS+ position of voxel (0, 0, 0). So a series written from a
//! NIfTI volume, in any axis-aligned orientation, loads to the same volume as the NIfTI file.
//! Without ImageOrientationPatient / ImagePositionPatient the file order is kept.
//!
//! # Values
//!
//! Stored values come from BitsAllocated 8, 16 or 32 and PixelRepresentation (unsigned or two's
//! complement), masked to BitsStored (signed values sign-extended from it), and map as the table
//! of [`crate::volume::formats`] says: u8 as is, i8 + 128, u16 as is, **i16 + 32768** (u16
//! volume; [`VolumeMeta::normalized`] converts), 32-bit to f32. When any slice has a
//! RescaleSlope / RescaleIntercept other than (1, 0), every slice's own modality rescale is
//! applied: the volume holds f32 `slope * stored + intercept` (Hounsfield units for CT,
//! [`VolumeMeta::scale_applied`]; [`VolumeMeta::scale_slope`] / `scale_inter` hold the first
//! slice's), so `--preset ct` and `--window` are in HU. MONOCHROME1 images load as stored (not
//! inverted). Colour images (SamplesPerPixel > 1) and multi-frame (enhanced) objects are refused.
//!
//! # Transfer syntaxes
//!
//! Decoded by dicom-rs' adapters (pure Rust, except CharLS for JPEG-LS, built from the C++
//! sources charls-sys bundles and linked statically), each checked against pydicom on its own
//! test files (tests/dicom.rs): implicit VR little endian, explicit VR little and big endian,
//! deflated explicit VR little endian, RLE lossless, JPEG 2000 lossless and lossy (the Rust port
//! of OpenJPEG; identical to pydicom's openjpeg plugin on `693_J2KI.dcm` and `JPEG2000.dcm`),
//! JPEG-LS lossless and near-lossless (identical to pydicom's libjpeg plugin; the frame header
//! must match Columns x Rows, one component and BitsAllocated before CharLS decodes it). JPEG
//! baseline (8-bit) and lossless go through jpeg-decoder but have no grey test file here; 12-bit
//! JPEG extended (pydicom's `JPGExtended.dcm`) is not decoded by it and fails with a typed error
//! on the pixel data. Refused by name before decoding: JPEG XL, the video syntaxes. A decoder
//! that fails (or panics) on corrupt data gives a [`VolumeError::Format`] error on `PixelData`.
//!
//! # Safety
//!
//! A file is read only after the `DICM` magic is seen; files above
//! [`crate::volume::formats::MAX_VOLUME_BYTES`] and slices above [`MAX_SLICE_PIXELS`] are
//! refused, decoded pixel data shorter than Rows x Columns is an error, and the volume's size is
//! checked against the host-memory limit before its buffer is allocated. Header problems are
//! [`VolumeError::Format`] errors naming the file and the attribute.
mod discover;
mod error;
mod geometry;
mod pixels;
mod slice;

pub use error::{DicomError, SeriesSummary};
pub use geometry::{ABS_TOLERANCE_MM, GAP_TOLERANCE};
pub use pixels::decode_dicom_slice;
pub use slice::{
    has_dicom_magic, parse_dicom_slice, DicomSlice, DICOM_PREAMBLE_BYTES, MAX_SLICE_PIXELS,
};

pub(super) use discover::{is_dicom_folder, is_dicomdir_name};

/// The error of the slab reader (`mixvol convert`) for a DICOM input, which only loads whole.
pub(super) fn no_slabs(path: &Path) -> VolumeError {
    format_err(
        path,
        "format",
        "a DICOM series is sorted, checked and reoriented as a whole, so it is not read slab by \
         slab: load it whole (load_dicom; mixvol convert and render do, within their budgets)",
    )
}

use super::nii::{reorder, reorientation, TransformSource};
use super::{FileFormat, LoadedVolume, VolumeMeta, MAX_VOLUME_BYTES};
use crate::volume::formats::read::format_err;
use crate::volume::{Volume, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::fmt;
use std::path::Path;

/// Which series of a folder to load: by SeriesInstanceUID or by SeriesNumber.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum SeriesSelector {
    /// SeriesInstanceUID (0020,000E), exactly.
    Uid(String),
    /// SeriesNumber (0020,0011); must name one series.
    Number(i64),
}

impl SeriesSelector {
    /// Parses a series number (an integer) or a UID (digits and dots); `None` otherwise.
    pub fn parse(text: &str) -> Option<Self> {
        let text = text.trim();
        if let Ok(n) = text.parse::<i64>() {
            return Some(SeriesSelector::Number(n));
        }
        let uid_chars = text.chars().all(|c| c.is_ascii_digit() || c == '.');
        (uid_chars && !text.is_empty() && text.len() <= 64)
            .then(|| SeriesSelector::Uid(text.to_string()))
    }
}

impl fmt::Display for SeriesSelector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SeriesSelector::Uid(uid) => write!(f, "{uid}"),
            SeriesSelector::Number(n) => write!(f, "{n}"),
        }
    }
}

/// Options of [`load_dicom`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DicomOptions {
    /// The series to load when the input holds several (`None`: there must be one).
    pub series: Option<SeriesSelector>,
    /// A limit on the loaded volume's bytes, checked from the headers before any pixel data is
    /// decoded ([`VolumeError::TooLarge`] above it; `None`: only the host-memory and
    /// [`MAX_VOLUME_BYTES`] limits). `mixvol convert` passes its RAM budget here, since a series
    /// is sorted and reoriented as a whole.
    pub max_bytes: Option<u64>,
}

/// The image series of a folder, DICOMDIR or file (see the module docs), ordered by series
/// number then UID.
pub fn list_dicom_series(path: &Path) -> Result<Vec<SeriesSummary>, VolumeError> {
    Ok(discover::discover(path)?.summaries())
}

/// Loads one DICOM series as a volume: discovery and series choice, slices sorted along the
/// normal with regular spacing checked, values mapped (rescale to f32 physical values, i16 +
/// 32768 otherwise) and voxels reordered to RAS+, as the module docs say.
pub fn load_dicom(path: &Path, options: &DicomOptions) -> Result<LoadedVolume, VolumeError> {
    let found = discover::discover(path)?;
    let series = discover::choose(found, options.series.as_ref())?;
    for (file, s) in &series.slices {
        pixels::check_loadable(file, s)?;
    }
    let stack = geometry::arrange(path, &series.slices)?;
    let first = &series.slices[stack.order[0]].1;
    let stored = pixels::stored_type(first);
    let rescaled = series
        .slices
        .iter()
        .any(|(_, s)| (s.rescale_slope, s.rescale_intercept) != (1.0, 0.0));
    let voxels = stack.dims.iter().product::<u64>();
    let bytes_per = if rescaled {
        4
    } else {
        stored.volume_scalar().size_bytes() as u64
    };
    let bytes = voxels.saturating_mul(bytes_per);
    if bytes > MAX_VOLUME_BYTES {
        return Err(format_err(
            path,
            "dims",
            format!(
                "{:?} voxels of {bytes_per} bytes exceed {MAX_VOLUME_BYTES} bytes",
                stack.dims
            ),
        ));
    }
    crate::volume::memory::check_host_bytes(&format!("DICOM series {}", path.display()), bytes)?;
    if let Some(limit) = options.max_bytes.filter(|&limit| bytes > limit) {
        return Err(VolumeError::TooLarge {
            what: format!("DICOM series {} (loaded whole)", path.display()),
            bytes,
            limit,
        });
    }
    let mut sink = pixels::Sink::new(stored, rescaled, voxels as usize);
    for &i in &stack.order {
        let (file, s) = &series.slices[i];
        let values = pixels::read_stored_values(file, s)?;
        let rescale = rescaled.then_some((s.rescale_slope, s.rescale_intercept));
        sink.push(&values, stored, rescale);
    }
    let data = match sink {
        pixels::Sink::U8(v) => VoxelData::U8(v),
        pixels::Sink::U16(v) => VoxelData::U16(v),
        pixels::Sink::F32(v) => VoxelData::F32(v),
    };
    let dims = UVec3::new(
        stack.dims[0] as u32,
        stack.dims[1] as u32,
        stack.dims[2] as u32,
    );
    let spacing = Vec3::from_array(stack.spacing.map(|s| s as f32));
    let volume = Volume::new(dims, spacing, data).map_err(|e| e.in_file(path))?;
    let (r, directions, origin) = reorientation(
        stack.affine_ras.map(|m| (m, TransformSource::Dicom)),
        stack.dims,
    );
    let volume = reorder(path, volume, &r)?;
    let big_endian = first.transfer_syntax == "1.2.840.10008.1.2.2";
    let mut meta = VolumeMeta::plain(FileFormat::Dicom, stored, big_endian);
    meta.directions = directions;
    meta.origin = origin;
    if rescaled {
        meta.scale_slope = first.rescale_slope;
        meta.scale_inter = first.rescale_intercept;
        meta.scale_applied = true;
    }
    meta.reorientation = Some(r);
    Ok(LoadedVolume { volume, meta })
}
