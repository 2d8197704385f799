//! One DICOM file as a slice record: the attributes that group it into a series, place it in
//! patient space and say how its pixels are stored, read through dicom-object (the pixel data
//! itself is decoded later, by [`super::pixels`]).
use crate::volume::formats::read::{format_err, io_err};
use crate::volume::formats::MAX_VOLUME_BYTES;
use crate::volume::VolumeError;
use dicom_core::header::HasLength;
use dicom_dictionary_std::tags;
use dicom_object::file::ReadPreamble;
use dicom_object::{DefaultDicomObject, InMemDicomObject, OpenFileOptions, Tag};
use std::io::Read;
use std::path::Path;

/// The bytes before the `DICM` magic of a DICOM file (the preamble).
pub const DICOM_PREAMBLE_BYTES: usize = 128;

/// The largest slice accepted, in pixels (8192 x 8192): checked from Rows and Columns before
/// pixel data is decoded.
pub const MAX_SLICE_PIXELS: u64 = 1 << 26;

/// What one DICOM image file says about itself (see [`parse_dicom_slice`]).
#[derive(Clone, Debug, PartialEq)]
pub struct DicomSlice {
    /// SOPInstanceUID (0008,0018), empty when absent.
    pub sop_instance_uid: String,
    /// SeriesInstanceUID (0020,000E): the series the slice belongs to (required).
    pub series_uid: String,
    /// SeriesNumber (0020,0011).
    pub series_number: Option<i64>,
    /// SeriesDescription (0008,103E), empty when absent.
    pub series_description: String,
    /// Modality (0008,0060), empty when absent.
    pub modality: String,
    /// The transfer syntax UID of the file meta group.
    pub transfer_syntax: String,
    /// Rows (0028,0010): pixels along a column, the slice's y.
    pub rows: u16,
    /// Columns (0028,0011): pixels along a row, the slice's x.
    pub columns: u16,
    /// BitsAllocated (0028,0100).
    pub bits_allocated: u16,
    /// BitsStored (0028,0101); BitsAllocated when absent.
    pub bits_stored: u16,
    /// PixelRepresentation (0028,0103) is 1: two's complement values.
    pub signed: bool,
    /// SamplesPerPixel (0028,0002); 1 when absent.
    pub samples_per_pixel: u16,
    /// PhotometricInterpretation (0028,0004), e.g. `MONOCHROME2`.
    pub photometric: String,
    /// NumberOfFrames (0028,0008); 1 when absent.
    pub frames: u32,
    /// PixelSpacing (0028,0030): `[between rows, between columns]` in mm (the slice's y, x).
    pub pixel_spacing: Option<[f64; 2]>,
    /// ImageOrientationPatient (0020,0037), normalised: the row direction (increasing column)
    /// then the column direction (increasing row), in the patient's LPS frame.
    pub orientation: Option<[f64; 6]>,
    /// ImagePositionPatient (0020,0032): the centre of the first pixel, LPS, mm.
    pub position: Option<[f64; 3]>,
    /// SliceThickness (0018,0050).
    pub slice_thickness: Option<f64>,
    /// SpacingBetweenSlices (0018,0088).
    pub spacing_between_slices: Option<f64>,
    /// InstanceNumber (0020,0013).
    pub instance_number: Option<i64>,
    /// RescaleSlope (0028,1053); 1 when absent.
    pub rescale_slope: f64,
    /// RescaleIntercept (0028,1052); 0 when absent.
    pub rescale_intercept: f64,
}

impl DicomSlice {
    /// Pixels in one frame (Rows x Columns).
    pub fn pixels(&self) -> u64 {
        u64::from(self.rows) * u64::from(self.columns)
    }
}

/// True when `bytes` (a file's start) holds the `DICM` magic after the 128-byte preamble.
pub fn has_dicom_magic(bytes: &[u8]) -> bool {
    bytes.len() >= DICOM_PREAMBLE_BYTES + 4
        && &bytes[DICOM_PREAMBLE_BYTES..DICOM_PREAMBLE_BYTES + 4] == b"DICM"
}

/// True when `path` is a regular file starting with a DICOM preamble and `DICM`.
pub(super) fn file_has_dicom_magic(path: &Path) -> bool {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return false;
    }
    let mut head = [0u8; DICOM_PREAMBLE_BYTES + 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok()
        && has_dicom_magic(&head)
}

/// Parses a DICOM file's bytes (128-byte preamble, `DICM`, file meta group, data set) into its
/// slice record, without decoding the pixel data (`path` is only named in errors). Checks that
/// the file is an image (Rows, Columns, BitsAllocated present), that the series UID is there,
/// and that every geometry and value attribute present is well formed: PixelSpacing two
/// positive values, ImageOrientationPatient two orthogonal non-zero vectors, ImagePositionPatient
/// three finite values, RescaleSlope finite and non-zero, BitsStored within BitsAllocated, a
/// slice of at most [`MAX_SLICE_PIXELS`]. Errors are [`VolumeError::Format`] naming the
/// attribute (`magic`, `header` for the file's structure).
pub fn parse_dicom_slice(path: &Path, bytes: &[u8]) -> Result<DicomSlice, VolumeError> {
    let object = object_from_bytes(path, bytes, false)?;
    slice_of(path, &object)
}

/// Reads a file's header (up to the pixel data) into its slice record; `Ok(None)` for a DICOM
/// file that holds no image (no Rows): a report, a structure set, a DICOMDIR.
pub(super) fn read_slice_header(path: &Path) -> Result<Option<DicomSlice>, VolumeError> {
    check_file(path)?;
    let object = OpenFileOptions::new()
        .read_preamble(ReadPreamble::Always)
        .read_until(tags::PIXEL_DATA)
        .open_file(path)
        .map_err(|e| format_err(path, "header", format!("unreadable DICOM file: {e}")))?;
    if object.get(tags::ROWS).is_none() {
        return Ok(None);
    }
    slice_of(path, &object).map(Some)
}

/// Checks that `path` is a regular file within the size limit with the `DICM` magic.
pub(super) fn check_file(path: &Path) -> Result<(), VolumeError> {
    let meta = std::fs::metadata(path).map_err(io_err(path))?;
    if !meta.is_file() {
        return Err(format_err(path, "file", "not a regular file"));
    }
    if meta.len() > MAX_VOLUME_BYTES {
        return Err(format_err(
            path,
            "file",
            format!("{} bytes: larger than {MAX_VOLUME_BYTES}", meta.len()),
        ));
    }
    if !file_has_dicom_magic(path) {
        return Err(not_dicom(path));
    }
    Ok(())
}

fn not_dicom(path: &Path) -> VolumeError {
    format_err(
        path,
        "magic",
        "no \"DICM\" after a 128-byte preamble: not a DICOM Part 10 file",
    )
}

/// Parses bytes into a DICOM object (whole, or up to the pixel data).
pub(super) fn object_from_bytes(
    path: &Path,
    bytes: &[u8],
    with_pixels: bool,
) -> Result<DefaultDicomObject, VolumeError> {
    if !has_dicom_magic(bytes) {
        return Err(not_dicom(path));
    }
    let options = OpenFileOptions::new().read_preamble(ReadPreamble::Always);
    let options = if with_pixels {
        options
    } else {
        options.read_until(tags::PIXEL_DATA)
    };
    options
        .from_reader(bytes)
        .map_err(|e| format_err(path, "header", format!("unreadable DICOM file: {e}")))
}

/// The attribute's name for messages, e.g. `Rows (0028,0010)`.
fn name(field: &str, tag: Tag) -> String {
    format!("{field} ({:04X},{:04X})", tag.group(), tag.element())
}

/// The slice record of a parsed object.
pub(super) fn slice_of(path: &Path, file: &DefaultDicomObject) -> Result<DicomSlice, VolumeError> {
    let transfer_syntax = file.meta().transfer_syntax().to_string();
    let o: &InMemDicomObject = file;
    let text = |tag: Tag| -> String {
        o.get(tag)
            .and_then(|e| e.to_str().ok())
            .map(|s| {
                s.trim_matches(|c: char| c == '\0' || c.is_whitespace())
                    .to_string()
            })
            .unwrap_or_default()
    };
    let int = |field: &str, tag: Tag| -> Result<Option<i64>, VolumeError> {
        match o.get(tag) {
            None => Ok(None),
            Some(e) if e.is_empty() => Ok(None),
            Some(e) => e.to_int::<i64>().map(Some).map_err(|err| {
                format_err(path, name(field, tag), format!("not an integer: {err}"))
            }),
        }
    };
    let floats = |field: &str, tag: Tag, n: usize| -> Result<Option<Vec<f64>>, VolumeError> {
        match o.get(tag) {
            None => Ok(None),
            Some(e) if e.is_empty() => Ok(None),
            Some(e) => {
                let v = e.to_multi_float64().map_err(|err| {
                    format_err(path, name(field, tag), format!("not numbers: {err}"))
                })?;
                if v.len() != n || !v.iter().all(|x| x.is_finite()) {
                    return Err(format_err(
                        path,
                        name(field, tag),
                        format!("{v:?}: expected {n} finite numbers"),
                    ));
                }
                Ok(Some(v))
            }
        }
    };
    let float = |field: &str, tag: Tag| -> Result<Option<f64>, VolumeError> {
        Ok(floats(field, tag, 1)?.map(|v| v[0]))
    };
    let required = |field: &str, tag: Tag| -> Result<i64, VolumeError> {
        int(field, tag)?.ok_or_else(|| format_err(path, name(field, tag), "missing"))
    };
    let u16_in = |field: &str, tag: Tag, v: i64, lo: i64| -> Result<u16, VolumeError> {
        u16::try_from(v)
            .ok()
            .filter(|&x| i64::from(x) >= lo)
            .ok_or_else(|| {
                format_err(
                    path,
                    name(field, tag),
                    format!("{v}: expected {lo} to 65535"),
                )
            })
    };

    let series_uid = text(tags::SERIES_INSTANCE_UID);
    if series_uid.is_empty() {
        return Err(format_err(
            path,
            name("SeriesInstanceUID", tags::SERIES_INSTANCE_UID),
            "missing: the file cannot be placed in a series",
        ));
    }
    let rows = u16_in("Rows", tags::ROWS, required("Rows", tags::ROWS)?, 1)?;
    let columns = u16_in(
        "Columns",
        tags::COLUMNS,
        required("Columns", tags::COLUMNS)?,
        1,
    )?;
    let pixels = u64::from(rows) * u64::from(columns);
    if pixels > MAX_SLICE_PIXELS {
        return Err(format_err(
            path,
            name("Rows", tags::ROWS),
            format!("{columns}x{rows} pixels: more than {MAX_SLICE_PIXELS} in one slice"),
        ));
    }
    let bits_allocated = required("BitsAllocated", tags::BITS_ALLOCATED)?;
    if ![8, 16, 32].contains(&bits_allocated) {
        return Err(format_err(
            path,
            name("BitsAllocated", tags::BITS_ALLOCATED),
            format!(
                "{bits_allocated}: expected 8, 16 or 32 (1-bit and 64-bit data are not supported)"
            ),
        ));
    }
    let bits_allocated = bits_allocated as u16;
    let bits_stored = int("BitsStored", tags::BITS_STORED)?.unwrap_or(i64::from(bits_allocated));
    if !(1..=i64::from(bits_allocated)).contains(&bits_stored) {
        return Err(format_err(
            path,
            name("BitsStored", tags::BITS_STORED),
            format!("{bits_stored}: expected 1 to BitsAllocated ({bits_allocated})"),
        ));
    }
    let signed = match int("PixelRepresentation", tags::PIXEL_REPRESENTATION)?.unwrap_or(0) {
        0 => false,
        1 => true,
        v => {
            return Err(format_err(
                path,
                name("PixelRepresentation", tags::PIXEL_REPRESENTATION),
                format!("{v}: expected 0 (unsigned) or 1 (signed)"),
            ))
        }
    };
    let samples = int("SamplesPerPixel", tags::SAMPLES_PER_PIXEL)?.unwrap_or(1);
    let samples_per_pixel = u16_in("SamplesPerPixel", tags::SAMPLES_PER_PIXEL, samples, 1)?;
    let frames = int("NumberOfFrames", tags::NUMBER_OF_FRAMES)?.unwrap_or(1);
    let frames = u32::try_from(frames)
        .ok()
        .filter(|&f| f >= 1)
        .ok_or_else(|| {
            format_err(
                path,
                name("NumberOfFrames", tags::NUMBER_OF_FRAMES),
                format!("{frames}: expected at least 1"),
            )
        })?;
    let pixel_spacing = match floats("PixelSpacing", tags::PIXEL_SPACING, 2)? {
        Some(v) if v.iter().all(|&s| s > 0.0) => Some([v[0], v[1]]),
        Some(v) => {
            return Err(format_err(
                path,
                name("PixelSpacing", tags::PIXEL_SPACING),
                format!("{v:?}: expected two positive values"),
            ))
        }
        None => None,
    };
    let orientation = match floats(
        "ImageOrientationPatient",
        tags::IMAGE_ORIENTATION_PATIENT,
        6,
    )? {
        Some(v) => Some(unit_orientation(path, &v)?),
        None => None,
    };
    let position = floats("ImagePositionPatient", tags::IMAGE_POSITION_PATIENT, 3)?
        .map(|v| [v[0], v[1], v[2]]);
    let rescale_slope = float("RescaleSlope", tags::RESCALE_SLOPE)?.unwrap_or(1.0);
    if rescale_slope == 0.0 {
        return Err(format_err(
            path,
            name("RescaleSlope", tags::RESCALE_SLOPE),
            "0: expected a non-zero slope",
        ));
    }
    let rescale_intercept = float("RescaleIntercept", tags::RESCALE_INTERCEPT)?.unwrap_or(0.0);
    let positive = |v: Option<f64>| v.filter(|&s| s > 0.0);
    Ok(DicomSlice {
        sop_instance_uid: text(tags::SOP_INSTANCE_UID),
        series_uid,
        series_number: int("SeriesNumber", tags::SERIES_NUMBER).ok().flatten(),
        series_description: text(tags::SERIES_DESCRIPTION),
        modality: text(tags::MODALITY),
        transfer_syntax,
        rows,
        columns,
        bits_allocated,
        bits_stored: bits_stored as u16,
        signed,
        samples_per_pixel,
        photometric: text(tags::PHOTOMETRIC_INTERPRETATION),
        frames,
        pixel_spacing,
        orientation,
        position,
        slice_thickness: positive(
            float("SliceThickness", tags::SLICE_THICKNESS)
                .ok()
                .flatten(),
        ),
        spacing_between_slices: positive(
            float("SpacingBetweenSlices", tags::SPACING_BETWEEN_SLICES)
                .ok()
                .flatten(),
        ),
        instance_number: int("InstanceNumber", tags::INSTANCE_NUMBER).ok().flatten(),
        rescale_slope,
        rescale_intercept,
    })
}

/// ImageOrientationPatient normalised, checked for two non-zero orthogonal directions.
fn unit_orientation(path: &Path, v: &[f64]) -> Result<[f64; 6], VolumeError> {
    let field = name("ImageOrientationPatient", tags::IMAGE_ORIENTATION_PATIENT);
    let norm = |a: &[f64]| (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    let (nr, nc) = (norm(&v[..3]), norm(&v[3..]));
    if !(nr > 1e-6 && nc > 1e-6) {
        return Err(format_err(path, field, format!("{v:?}: a zero direction")));
    }
    let mut out = [0.0; 6];
    for i in 0..3 {
        out[i] = v[i] / nr;
        out[i + 3] = v[i + 3] / nc;
    }
    let dot: f64 = (0..3).map(|i| out[i] * out[i + 3]).sum();
    if dot.abs() > 1e-3 {
        return Err(format_err(
            path,
            field,
            format!("{v:?}: the row and column directions are not orthogonal (cosine {dot:.4})"),
        ));
    }
    Ok(out)
}
