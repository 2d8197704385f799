//! Fuzzes `mixvol::volume::formats::parse_nifti_header` with arbitrary bytes standing for the first
//! 348 bytes of a NIfTI-1 file. It must return `Ok` or a typed `VolumeError` and never panic; it
//! only parses, so it never allocates from the sizes a header claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::parse_nifti_header;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = parse_nifti_header(Path::new("fuzz-input"), data);
});
