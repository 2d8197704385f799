//! Fuzzes `mixvol::volume::formats::parse_sidecar` with arbitrary bytes standing for a JSON
//! sidecar. It must return `Ok` or a typed `VolumeError` and never panic; it only parses, so it
//! never allocates from the sizes a header claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::parse_sidecar;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = parse_sidecar(Path::new("fuzz-input"), data);
});
