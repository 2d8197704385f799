//! The header of an RLE Lossless frame (DICOM PS3.5 Annex G), read from the file's encapsulated
//! pixel data and checked against the DICOM header before dicom-rs' RLE adapter decodes it: the
//! adapter sizes its segment table from the header's segment count before it checks the
//! fragment's length, so 300 bytes of garbage could make it ask for 13 GB and abort (review D5).
use super::super::slice::DicomSlice;
use crate::volume::formats::read::format_err;
use crate::volume::VolumeError;
use dicom_object::DefaultDicomObject;
use std::path::Path;

/// RLE Lossless.
pub const RLE_LOSSLESS: &str = "1.2.840.10008.1.2.5";

/// The bytes of an RLE header: the segment count and 15 segment offsets, 32-bit little endian.
const HEADER_BYTES: usize = 64;

/// True for RLE Lossless.
pub fn is_rle(uid: &str) -> bool {
    uid.trim_end_matches(['\0', ' ']) == RLE_LOSSLESS
}

/// The segment offsets of an RLE frame `frame` that holds `segments` segments (one per byte of
/// a grey sample), each checked to lie inside the frame after the header and after the one
/// before; the error says what was found instead.
pub fn segment_offsets(frame: &[u8], segments: usize) -> Result<Vec<usize>, String> {
    if frame.len() < HEADER_BYTES {
        return Err(format!(
            "the RLE frame is {} bytes, shorter than its {HEADER_BYTES}-byte header",
            frame.len()
        ));
    }
    let word = |i: usize| u32::from_le_bytes(frame[4 * i..4 * i + 4].try_into().expect("4 bytes"));
    let count = word(0) as usize;
    if count != segments {
        return Err(format!(
            "the RLE header lists {count} segments, but one grey sample of {} byte(s) takes \
             {segments}",
            segments
        ));
    }
    let mut offsets = Vec::with_capacity(count);
    for i in 0..count {
        let offset = word(1 + i) as usize;
        let after = offsets.last().map_or(HEADER_BYTES, |&o: &usize| o + 1);
        if i == 0 && offset != HEADER_BYTES {
            return Err(format!(
                "the RLE header puts segment 1 at byte {offset}, not right after its \
                 {HEADER_BYTES}-byte header"
            ));
        }
        if offset < after || offset >= frame.len() {
            return Err(format!(
                "the RLE header puts segment {} at byte {offset}, outside the {}-byte frame or \
                 before the segment ahead of it",
                i + 1,
                frame.len()
            ));
        }
        offsets.push(offset);
    }
    Ok(offsets)
}

/// Checks the RLE header of a file's one frame against its slice record: one fragment, as many
/// segments as a grey sample has bytes (BitsAllocated / 8), each inside the fragment. Errors
/// are [`VolumeError::Format`] on `PixelData`.
pub fn check_frame(
    path: &Path,
    object: &DefaultDicomObject,
    s: &DicomSlice,
) -> Result<(), VolumeError> {
    let field = "PixelData (7FE0,0010)";
    let err = |message: String| format_err(path, field, message);
    let fragments = super::pixel_fragments(path, object, "RLE")?;
    let frame = match fragments {
        [frame] => frame,
        _ => {
            return Err(err(format!(
                "{} fragments for one RLE frame: RLE Lossless holds each frame in one fragment",
                fragments.len()
            )))
        }
    };
    segment_offsets(frame, usize::from(s.bits_allocated / 8).max(1)).map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `len` bytes whose header lists `count` segments at `offsets`.
    fn frame(count: u32, offsets: &[u32], len: usize) -> Vec<u8> {
        let mut v = count.to_le_bytes().to_vec();
        for i in 0..15 {
            v.extend_from_slice(&offsets.get(i).copied().unwrap_or(0).to_le_bytes());
        }
        v.resize(len, 0);
        v
    }

    #[test]
    fn rle_headers_are_read_and_checked() {
        assert_eq!(
            segment_offsets(&frame(2, &[64, 90], 100), 2),
            Ok(vec![64, 90])
        );
        assert_eq!(segment_offsets(&frame(1, &[64], 65), 1), Ok(vec![64]));
        let refused = |f: Vec<u8>, segments: usize, why: &str| {
            let e = segment_offsets(&f, segments).unwrap_err();
            assert!(e.contains(why), "{e}");
        };
        refused(vec![0; 63], 1, "shorter than its 64-byte header");
        refused(
            frame(0x0FFF_FFF0, &[64], 300),
            2,
            "lists 268435440 segments",
        );
        refused(frame(3, &[64, 70, 80], 100), 2, "lists 3 segments");
        refused(frame(2, &[60, 90], 100), 2, "segment 1 at byte 60");
        refused(frame(2, &[64, 100], 100), 2, "segment 2 at byte 100");
        refused(frame(2, &[64, 64], 100), 2, "before the segment ahead");
    }
}
