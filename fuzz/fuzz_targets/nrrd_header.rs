//! Fuzzes `mixvol::volume::formats::parse_nrrd_header` with arbitrary bytes standing for the start
//! of a NRRD file (header, perhaps attached data). It must return `Ok` or a typed `VolumeError` and
//! never panic; it only parses, so it never allocates from the sizes a header claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::parse_nrrd_header;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = parse_nrrd_header(Path::new("fuzz-input"), data);
});
