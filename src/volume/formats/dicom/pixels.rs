//! Pixel data: decoding one file's frame through dicom-pixeldata (native and the compressed
//! transfer syntaxes its adapters handle: RLE, JPEG and JPEG 2000 in Rust, JPEG-LS through
//! CharLS, whose frame header is checked first: [`jpegls`]; an RLE frame's header is checked
//! first too: [`rle`]), the stored values it holds
//! (BitsStored masked or sign-extended, as pydicom does), and the series' value mapping into the
//! volume.
mod jpegls;
mod rle;

use super::slice::{object_from_bytes, slice_of, DicomSlice};
use crate::volume::formats::read::format_err;
use crate::volume::formats::StoredType;
use crate::volume::VolumeError;
use dicom_encoding::transfer_syntax::TransferSyntaxIndex;
use dicom_object::DefaultDicomObject;
use dicom_pixeldata::PixelDecoder;
use dicom_transfer_syntax_registry::TransferSyntaxRegistry;
use std::path::Path;

/// The fragments of an object's encapsulated PixelData (`what`, e.g. "RLE", names the
/// encoding in the errors, which are [`VolumeError::Format`] on `PixelData`).
fn pixel_fragments<'a>(
    path: &Path,
    object: &'a DefaultDicomObject,
    what: &str,
) -> Result<&'a [Vec<u8>], VolumeError> {
    let field = "PixelData (7FE0,0010)";
    object
        .element(dicom_dictionary_std::tags::PIXEL_DATA)
        .map_err(|_| format_err(path, field, "no pixel data"))?
        .value()
        .fragments()
        .ok_or_else(|| {
            format_err(
                path,
                field,
                format!("{what} pixel data that is not encapsulated (no fragments)"),
            )
        })
}

/// The transfer syntax's name (e.g. `JPEG-LS Lossless Image Compression`), else its UID.
pub(super) fn transfer_syntax_name(uid: &str) -> String {
    TransferSyntaxRegistry
        .get(uid)
        .map(|ts| ts.name().to_string())
        .unwrap_or_else(|| format!("unknown transfer syntax {uid}"))
}

/// Checks that the series' slices can be loaded: one sample (grey), MONOCHROME1/2, one frame,
/// a transfer syntax whose pixel data this build decodes.
pub(super) fn check_loadable(path: &Path, s: &DicomSlice) -> Result<(), VolumeError> {
    if s.samples_per_pixel != 1 {
        return Err(format_err(
            path,
            "SamplesPerPixel (0028,0002)",
            format!(
                "{} samples per pixel ({}): only grey (1 sample) images form volumes",
                s.samples_per_pixel, s.photometric
            ),
        ));
    }
    if !matches!(s.photometric.as_str(), "MONOCHROME1" | "MONOCHROME2" | "") {
        return Err(format_err(
            path,
            "PhotometricInterpretation (0028,0004)",
            format!("{}: expected MONOCHROME1 or MONOCHROME2", s.photometric),
        ));
    }
    if s.frames != 1 {
        return Err(format_err(
            path,
            "NumberOfFrames (0028,0008)",
            format!(
                "{} frames: multi-frame (enhanced) objects are not supported; a series must \
                 hold one slice per file",
                s.frames
            ),
        ));
    }
    let decodable = TransferSyntaxRegistry
        .get(&s.transfer_syntax)
        .is_some_and(|ts| ts.can_decode_all());
    if !decodable {
        return Err(unsupported_syntax(path, &s.transfer_syntax));
    }
    Ok(())
}

fn unsupported_syntax(path: &Path, uid: &str) -> VolumeError {
    format_err(
        path,
        "TransferSyntaxUID (0002,0010)",
        format!(
            "{} ({uid}) is not decoded by this build (supported: implicit / explicit VR little \
             endian, explicit VR big endian, deflated, RLE lossless, JPEG baseline and lossless, \
             JPEG 2000, JPEG-LS lossless and near-lossless; not JPEG XL, video)",
            transfer_syntax_name(uid)
        ),
    )
}

/// Decodes one file's bytes whole: its slice record and stored pixel values (row by row, column
/// fastest); the fuzz target's entry point. Checks first that the slice can be loaded (grey, one
/// frame, a decodable transfer syntax: the checks of [`super::load_dicom`]), then that the
/// decoded pixel data covers Rows x Columns (trailing padding is ignored).
pub fn decode_dicom_slice(
    path: &Path,
    bytes: &[u8],
) -> Result<(DicomSlice, Vec<i64>), VolumeError> {
    let object = object_from_bytes(path, bytes, true)?;
    let slice = slice_of(path, &object)?;
    let values = stored_values(path, &object, &slice)?;
    Ok((slice, values))
}

/// Reads and decodes the file `path` (whose header is `slice`).
pub(super) fn read_stored_values(path: &Path, slice: &DicomSlice) -> Result<Vec<i64>, VolumeError> {
    let object = dicom_object::OpenFileOptions::new()
        .read_preamble(dicom_object::file::ReadPreamble::Always)
        .open_file(path)
        .map_err(|e| format_err(path, "header", format!("unreadable DICOM file: {e}")))?;
    let header = slice_of(path, &object)?;
    if header != *slice {
        return Err(format_err(
            path,
            "header",
            "the file changed while the series was read",
        ));
    }
    stored_values(path, &object, slice)
}

/// The stored values of an object's single frame.
fn stored_values(
    path: &Path,
    object: &DefaultDicomObject,
    s: &DicomSlice,
) -> Result<Vec<i64>, VolumeError> {
    check_loadable(path, s)?;
    if jpegls::is_jpeg_ls(&s.transfer_syntax) {
        jpegls::check_frame(path, object, s)?;
    }
    if rle::is_rle(&s.transfer_syntax) {
        rle::check_frame(path, object, s)?;
    }
    // dicom-rs' decoders can panic on corrupt encapsulated data (an index out of bounds in its
    // RLE adapter, found by tests/dicom.rs' mutations): that is a corrupt file, not a crash.
    let decoded =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| object.decode_pixel_data()))
            .map_err(|_| {
                format_err(
                    path,
                    "PixelData (7FE0,0010)",
                    format!(
                        "corrupt {} pixel data (the decoder failed on it)",
                        transfer_syntax_name(&s.transfer_syntax)
                    ),
                )
            })?
            .map_err(|e| {
                format_err(
                    path,
                    "PixelData (7FE0,0010)",
                    format!(
                        "cannot decode ({}): {e}",
                        transfer_syntax_name(&s.transfer_syntax)
                    ),
                )
            })?;
    let data = decoded.data();
    let bytes_per = usize::from(s.bits_allocated / 8);
    let pixels = s.pixels() as usize;
    let need = pixels * bytes_per;
    if data.len() < need {
        return Err(format_err(
            path,
            "PixelData (7FE0,0010)",
            format!(
                "{} bytes of pixel data (decoded), but {}x{} pixels of {} bits need {need}",
                data.len(),
                s.columns,
                s.rows,
                s.bits_allocated
            ),
        ));
    }
    let bits = u32::from(s.bits_stored);
    let mask: u64 = if bits >= 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    };
    let value = |raw: u64| -> i64 {
        let v = raw & mask;
        if s.signed && bits < 64 && v & (1u64 << (bits - 1)) != 0 {
            (v | !mask) as i64
        } else {
            v as i64
        }
    };
    let data = &data[..need];
    Ok(match bytes_per {
        1 => data.iter().map(|&b| value(u64::from(b))).collect(),
        2 => data
            .chunks_exact(2)
            .map(|c| value(u64::from(u16::from_le_bytes([c[0], c[1]]))))
            .collect(),
        _ => data
            .chunks_exact(4)
            .map(|c| value(u64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]]))))
            .collect(),
    })
}

/// The stored type of a series (BitsAllocated, PixelRepresentation).
pub(super) fn stored_type(s: &DicomSlice) -> StoredType {
    match (s.bits_allocated, s.signed) {
        (8, false) => StoredType::U8,
        (8, true) => StoredType::I8,
        (16, false) => StoredType::U16,
        (16, true) => StoredType::I16,
        (_, false) => StoredType::U32,
        (_, true) => StoredType::I32,
    }
}

/// The volume's voxels being filled slice by slice, in the volume type the value mapping gives.
pub(super) enum Sink {
    /// u8 (u8, or i8 + 128).
    U8(Vec<u8>),
    /// u16 (u16, or i16 + 32768).
    U16(Vec<u16>),
    /// f32 (u32 / i32, or rescaled values).
    F32(Vec<f32>),
}

impl Sink {
    /// An empty sink for `voxels` values of `stored`, rescaled to f32 when `rescaled`.
    pub fn new(stored: StoredType, rescaled: bool, voxels: usize) -> Self {
        if rescaled {
            return Sink::F32(Vec::with_capacity(voxels));
        }
        match stored {
            StoredType::U8 | StoredType::I8 => Sink::U8(Vec::with_capacity(voxels)),
            StoredType::U16 | StoredType::I16 => Sink::U16(Vec::with_capacity(voxels)),
            _ => Sink::F32(Vec::with_capacity(voxels)),
        }
    }

    /// Appends one slice's stored values of type `stored`: `slope * v + intercept` as f32 when
    /// `rescale` is given, else mapped as the table of [`crate::volume::formats`] says (i8 + 128,
    /// i16 + 32768, 32-bit integers converted to f32).
    pub fn push(&mut self, values: &[i64], stored: StoredType, rescale: Option<(f64, f64)>) {
        let offset = i64::from(stored.value_offset());
        match self {
            Sink::F32(out) => match rescale {
                Some((slope, inter)) => {
                    out.extend(values.iter().map(|&v| (slope * v as f64 + inter) as f32))
                }
                None => out.extend(values.iter().map(|&v| v as f32)),
            },
            // Values are within BitsStored <= BitsAllocated, so the offset brings them in range.
            Sink::U8(out) => out.extend(values.iter().map(|&v| (v + offset) as u8)),
            Sink::U16(out) => out.extend(values.iter().map(|&v| (v + offset) as u16)),
        }
    }
}
