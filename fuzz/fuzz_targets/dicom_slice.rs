//! Fuzzes `mixvol::volume::formats::decode_dicom_slice` (and `parse_dicom_slice`) with arbitrary
//! bytes standing for a DICOM file after its 128-byte preamble and `DICM` magic (which the target
//! prepends, so the fuzzer spends its time on the file meta group, the data set and the pixel
//! data, including the JPEG-LS frame header that is checked before CharLS sizes its output).
//! Both must return `Ok` or a typed `VolumeError` and never panic; slices are capped at
//! `MAX_SLICE_PIXELS` before any pixel buffer is decoded.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::dicom::DICOM_PREAMBLE_BYTES;
use mixvol::volume::formats::{decode_dicom_slice, parse_dicom_slice};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let mut file = vec![0u8; DICOM_PREAMBLE_BYTES];
    file.extend_from_slice(b"DICM");
    file.extend_from_slice(data);
    let path = Path::new("fuzz-input.dcm");
    let _ = parse_dicom_slice(path, &file);
    let _ = decode_dicom_slice(path, &file);
});
