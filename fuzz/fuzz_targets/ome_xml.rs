//! Fuzzes `mixvol::volume::formats::parse_ome_xml` with arbitrary bytes standing for the OME-XML
//! in an OME-TIFF's `ImageDescription`, then asks every parsed image for the IFD of a few planes
//! (the look-up the TIFF loader does). It must return `Ok` or a typed `VolumeError` and never
//! panic; it only parses (sizes, dimension order, physical sizes and units, TiffData), so it never
//! allocates from the sizes a document claims.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mixvol::volume::formats::parse_ome_xml;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz-input.ome.tif");
    if let Ok(ome) = parse_ome_xml(path, data) {
        for pixels in &ome.images {
            let [_, _, z, c, t] = pixels.size;
            for zct in [[0, 0, 0], [z - 1, c - 1, t - 1], [z, c, t], [u64::MAX, 0, 0]] {
                let _ = pixels.ifd_of(path, zct);
            }
        }
    }
});
