//! The frame header (SOF55) of a JPEG-LS codestream (ISO/IEC 14495-1), read from the file's
//! encapsulated pixel data and checked against the DICOM header before CharLS decodes the frame:
//! CharLS sizes its output buffer from the codestream's own width, height, component count and
//! precision, so a small corrupt file could otherwise make it allocate gigabytes.
use super::super::slice::DicomSlice;
use crate::volume::formats::read::format_err;
use crate::volume::VolumeError;
use dicom_object::DefaultDicomObject;
use std::path::Path;

/// JPEG-LS Lossless Image Compression.
pub const JPEG_LS_LOSSLESS: &str = "1.2.840.10008.1.2.4.80";
/// JPEG-LS Lossy (Near-Lossless) Image Compression.
pub const JPEG_LS_NEAR_LOSSLESS: &str = "1.2.840.10008.1.2.4.81";

/// True for the two JPEG-LS transfer syntaxes.
pub fn is_jpeg_ls(uid: &str) -> bool {
    matches!(
        uid.trim_end_matches(['\0', ' ']),
        JPEG_LS_LOSSLESS | JPEG_LS_NEAR_LOSSLESS
    )
}

/// The fields of a JPEG-LS frame header (SOF55) that size the decoded frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    /// P: bits per sample (2 to 16).
    pub precision: u8,
    /// Y: lines (0 when an LSE segment gives the height).
    pub height: u16,
    /// X: samples per line (0 when an LSE segment gives the width).
    pub width: u16,
    /// Nf: components.
    pub components: u8,
}

const SOI: u8 = 0xD8;
const EOI: u8 = 0xD9;
const SOS: u8 = 0xDA;
const SOF55: u8 = 0xF7;

/// Reads the frame header of the codestream `bytes` (the markers before it are skipped by their
/// lengths); the error says what was found instead.
pub fn frame_header(bytes: impl IntoIterator<Item = u8>) -> Result<FrameHeader, String> {
    let mut b = bytes.into_iter();
    let truncated = || "the JPEG-LS codestream ends before its frame header (SOF55)".to_string();
    let u16_of = |b: &mut dyn Iterator<Item = u8>| -> Result<u16, String> {
        let hi = b.next().ok_or_else(truncated)?;
        let lo = b.next().ok_or_else(truncated)?;
        Ok(u16::from_be_bytes([hi, lo]))
    };
    if (b.next(), b.next()) != (Some(0xFF), Some(SOI)) {
        return Err("the JPEG-LS codestream does not start with SOI (FFD8)".into());
    }
    loop {
        match b.next() {
            Some(0xFF) => {}
            Some(other) => {
                return Err(format!(
                    "the JPEG-LS codestream has byte {other:02X} where a marker (FFxx) must be"
                ))
            }
            None => return Err(truncated()),
        }
        // Fill bytes: any number of FF before the marker code.
        let code = loop {
            match b.next() {
                Some(0xFF) => continue,
                Some(code) => break code,
                None => return Err(truncated()),
            }
        };
        match code {
            SOF55 => {
                let length = u16_of(&mut b)?;
                let precision = b.next().ok_or_else(truncated)?;
                let height = u16_of(&mut b)?;
                let width = u16_of(&mut b)?;
                let components = b.next().ok_or_else(truncated)?;
                if usize::from(length) != 8 + 3 * usize::from(components) {
                    return Err(format!(
                        "the JPEG-LS frame header's length {length} does not fit its \
                         {components} components"
                    ));
                }
                return Ok(FrameHeader {
                    precision,
                    height,
                    width,
                    components,
                });
            }
            // Stand-alone markers (TEM, RSTn) carry no length.
            0x01 | 0xD0..=0xD7 => {}
            SOI | EOI | SOS => {
                return Err(format!(
                    "the JPEG-LS codestream has marker FF{code:02X} before its frame header \
                     (SOF55)"
                ))
            }
            0xC0..=0xCF if !matches!(code, 0xC4 | 0xC8 | 0xCC) => {
                return Err(format!(
                    "the codestream is JPEG (frame marker FF{code:02X}), not JPEG-LS (SOF55, \
                     FFF7)"
                ))
            }
            _ => {
                let length = u16_of(&mut b)?;
                if length < 2 {
                    return Err(format!(
                        "the JPEG-LS codestream's segment FF{code:02X} has length {length}"
                    ));
                }
                for _ in 2..length {
                    b.next().ok_or_else(truncated)?;
                }
            }
        }
    }
}

/// Checks the frame header of a JPEG-LS file's codestream against its slice record: Columns x
/// Rows samples of one component, whose precision decodes to BitsAllocated (8: up to 8 bits, 16:
/// 9 to 16 bits). Errors are [`VolumeError::Format`] on `PixelData`.
pub fn check_frame(
    path: &Path,
    object: &DefaultDicomObject,
    s: &DicomSlice,
) -> Result<(), VolumeError> {
    let field = "PixelData (7FE0,0010)";
    let err = |message: String| format_err(path, field, message);
    let fragments = super::pixel_fragments(path, object, "JPEG-LS")?;
    let header = frame_header(fragments.iter().flat_map(|f| f.iter().copied())).map_err(err)?;
    if (header.width, header.height) != (s.columns, s.rows) {
        return Err(err(format!(
            "the JPEG-LS frame is {}x{} samples, but Columns x Rows is {}x{}",
            header.width, header.height, s.columns, s.rows
        )));
    }
    if header.components != 1 {
        return Err(err(format!(
            "the JPEG-LS frame has {} components, expected 1 (grey)",
            header.components
        )));
    }
    let bytes: u16 = match header.precision {
        2..=8 => 1,
        9..=16 => 2,
        p => {
            return Err(err(format!(
                "the JPEG-LS frame has {p} bits per sample, expected 2 to 16"
            )))
        }
    };
    if bytes * 8 != s.bits_allocated {
        return Err(err(format!(
            "the JPEG-LS frame's {}-bit samples decode to {bytes} byte(s) each, but \
             BitsAllocated is {}",
            header.precision, s.bits_allocated
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SOI, then `segments`, then a frame header of `width` x `height`, `components`, `p` bits.
    fn codestream(segments: &[u8], p: u8, height: u16, width: u16, components: u8) -> Vec<u8> {
        let mut v = vec![0xFF, SOI];
        v.extend_from_slice(segments);
        v.extend_from_slice(&[0xFF, SOF55]);
        v.extend_from_slice(&(8 + 3 * u16::from(components)).to_be_bytes());
        v.push(p);
        v.extend_from_slice(&height.to_be_bytes());
        v.extend_from_slice(&width.to_be_bytes());
        v.push(components);
        for c in 0..components {
            v.extend_from_slice(&[c + 1, 0x11, 0]);
        }
        v.extend_from_slice(&[0xFF, SOS]);
        v
    }

    #[test]
    fn the_frame_header_is_found_after_other_segments_and_fill_bytes() {
        let want = FrameHeader {
            precision: 12,
            height: 300,
            width: 513,
            components: 1,
        };
        assert_eq!(frame_header(codestream(&[], 12, 300, 513, 1)), Ok(want));
        // An APP8 segment (4 bytes of payload), a COM, fill bytes before the SOF55 marker.
        let segments = [
            0xFF, 0xE8, 0, 6, b'S', b'P', b'I', b'F', 0xFF, 0xFE, 0, 3, b'x', 0xFF, 0xFF,
        ];
        assert_eq!(
            frame_header(codestream(&segments, 12, 300, 513, 1)),
            Ok(want)
        );
        let three = frame_header(codestream(&[], 8, 2, 3, 3)).unwrap();
        assert_eq!((three.components, three.width, three.height), (3, 3, 2));
    }

    #[test]
    fn codestreams_without_a_readable_frame_header_are_errors() {
        let full = codestream(&[], 16, 64, 64, 1);
        for cut in 0..12 {
            let e = frame_header(full[..cut].iter().copied()).unwrap_err();
            assert!(e.contains("SOI") || e.contains("ends before"), "{cut}: {e}");
        }
        // A JPEG baseline codestream (SOF0), a scan before any frame, a bad length.
        let e = frame_header([0xFF, SOI, 0xFF, 0xC0, 0, 11]).unwrap_err();
        assert!(e.contains("not JPEG-LS"), "{e}");
        let e = frame_header([0xFF, SOI, 0xFF, SOS, 0, 8]).unwrap_err();
        assert!(e.contains("FFDA before"), "{e}");
        let mut bad = full.clone();
        bad[5] = 20;
        assert!(frame_header(bad).unwrap_err().contains("length 20"));
        let e = frame_header([0xFF, SOI, 0x12]).unwrap_err();
        assert!(e.contains("byte 12"), "{e}");
    }

    #[test]
    fn only_the_two_jpeg_ls_syntaxes_are_jpeg_ls() {
        assert!(is_jpeg_ls("1.2.840.10008.1.2.4.80"));
        assert!(is_jpeg_ls("1.2.840.10008.1.2.4.81\0"));
        assert!(!is_jpeg_ls("1.2.840.10008.1.2.4.90"));
        assert!(!is_jpeg_ls("1.2.840.10008.1.2.4.8"));
    }
}
