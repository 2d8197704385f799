//! Fuzzes `mixvol::volume::formats::parse_nifti_header` on NIfTI-2 headers (hand-parsed, the
//! `nifti` crate reads NIfTI-1 only): the input's first byte picks the byte order, and
//! `sizeof_hdr` (540) and the magic `n+2\0\r\n\x1a\n` are written over the start of the rest so
//! that the fuzzer reaches the field checks (dim, datatype, pixdim, vox_offset, sform / qform).
//! It must return `Ok` or a typed `VolumeError` and never panic; it only parses, so it never
//! allocates from the sizes a header claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::{parse_nifti_header, NIFTI2_HEADER_BYTES};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&order, rest)) = data.split_first() else {
        return;
    };
    let mut header = rest.to_vec();
    if header.len() < 12 {
        header.resize(12, 0);
    }
    let size = if order & 1 == 1 {
        540i32.to_be_bytes()
    } else {
        540i32.to_le_bytes()
    };
    header[..4].copy_from_slice(&size);
    header[4..12].copy_from_slice(b"n+2\0\r\n\x1a\n");
    if order & 2 == 2 && header.len() < NIFTI2_HEADER_BYTES {
        // Also try the complete size, zero-padded.
        header.resize(NIFTI2_HEADER_BYTES, 0);
    }
    let _ = parse_nifti_header(Path::new("fuzz-input"), &header);
});
