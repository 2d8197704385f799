//! Fuzzes `mixvol::volume::formats::parse_zarr_root` with arbitrary bytes standing for an
//! OME-Zarr root metadata document, as Zarr v2 `.zattrs` and as Zarr v3 `zarr.json`. It must
//! return `Ok` or a typed `VolumeError` and never panic; it only parses (multiscales, axes,
//! datasets, coordinate transformations), so it never allocates from the sizes a document claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::{parse_zarr_root, ZarrVersion};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    for version in [ZarrVersion::V2, ZarrVersion::V3] {
        let _ = parse_zarr_root(Path::new("fuzz-input"), data, version);
    }
});
