//! VolPack / Marc Levoy density files (`.den`), as read by VolPack's `examples/denfile.c`: a
//! 62-byte header of 16-bit fields (`map_version`, then `orig`, `extr` and `map` min / max / len
//! triples, `map_warps`) and a 32-bit `map_length`, in the writer's byte order (detected from
//! `map_version`, which is 1), followed by `map_len[0] * map_len[1] * map_len[2]` unsigned bytes,
//! x fastest. The format stores no voxel spacing: volumes load with spacing 1.
use super::read::{self, format_err, layout, Described, Payload};
use super::{FileFormat, LoadedVolume, StoredType, VolumeMeta};
use crate::volume::VolumeError;
use glam::Vec3;
use std::path::Path;

/// Size of a `.den` header in bytes.
pub const DEN_HEADER_BYTES: usize = 62;

/// A parsed and validated `.den` header.
#[derive(Clone, Debug, PartialEq)]
pub struct DenHeader {
    /// True when the header was written big-endian (`map_version` reads 0x0100 little-endian).
    pub big_endian: bool,
    /// `map_len`: voxel counts along x, y, z.
    pub dims: [u64; 3],
    /// `map_warps`: number of warps since extraction (informative).
    pub map_warps: i16,
    /// `map_length`: number of voxels (the product of `map_len`).
    pub map_length: u64,
}

/// Parses the first [`DEN_HEADER_BYTES`] bytes of a `.den` file (`path` is only named in
/// errors). Refuses a short header, a `map_version` other than 1 (in either byte order),
/// `map_len` entries below 1, a `map_length` that is not their product and a volume over
/// [`MAX_VOLUME_BYTES`](super::MAX_VOLUME_BYTES) (field `map_len`). Errors are
/// [`VolumeError::Format`] naming the field.
pub fn parse_den_header(path: &Path, bytes: &[u8]) -> Result<DenHeader, VolumeError> {
    if bytes.len() < DEN_HEADER_BYTES {
        return Err(format_err(
            path,
            "header",
            format!(
                "truncated .den header: {} of {DEN_HEADER_BYTES} bytes",
                bytes.len()
            ),
        ));
    }
    let big_endian = match [bytes[0], bytes[1]] {
        [1, 0] => false,
        [0, 1] => true,
        v => {
            return Err(format_err(
                path,
                "map_version",
                format!(
                    "map_version bytes {v:02x?} are not 1 in either byte order: not a .den file"
                ),
            ))
        }
    };
    let short = |offset: usize| {
        let b = [bytes[offset], bytes[offset + 1]];
        if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    // map_version (2) + orig/extr min/max/len (6 triples of shorts: 36) + map_min, map_max (12).
    let map_len_at = 2 + 6 * 6 + 2 * 6;
    let mut dims = [0u64; 3];
    for (i, d) in dims.iter_mut().enumerate() {
        let n = short(map_len_at + 2 * i);
        if n < 1 {
            return Err(format_err(
                path,
                format!("map_len[{i}]"),
                format!("axis size is {n}, expected at least 1"),
            ));
        }
        *d = n as u64;
    }
    let map_warps = short(map_len_at + 6);
    let w = [bytes[58], bytes[59], bytes[60], bytes[61]];
    let map_length = if big_endian {
        i32::from_be_bytes(w)
    } else {
        i32::from_le_bytes(w)
    };
    let product = dims[0] * dims[1] * dims[2]; // each < 2^15: no overflow
    if u64::try_from(map_length).ok() != Some(product) {
        return Err(format_err(
            path,
            "map_length",
            format!(
                "map_length is {map_length} but map_len {}x{}x{} = {product}",
                dims[0], dims[1], dims[2]
            ),
        ));
    }
    layout(path, "map_len", dims, StoredType::U8)?;
    Ok(DenHeader {
        big_endian,
        dims,
        map_warps,
        map_length: product,
    })
}

/// Loads a `.den` file as a u8 volume with spacing 1. The file must hold exactly the header and
/// `map_length` bytes.
pub fn load_den(path: &Path) -> Result<LoadedVolume, VolumeError> {
    describe_den(path)?.load()
}

/// Parses and checks a `.den` header (see [`load_den`]), reading no voxel.
pub(super) fn describe_den(path: &Path) -> Result<Described, VolumeError> {
    let (bytes, _) = read::read_prefix(path, DEN_HEADER_BYTES as u64)?;
    let h = parse_den_header(path, &bytes)?;
    let layout = layout(path, "map_len", h.dims, StoredType::U8)?;
    let payload = Payload {
        header_path: path.to_path_buf(),
        size_field: "map_length",
        data_path: path.to_path_buf(),
        offset: DEN_HEADER_BYTES as u64,
        gzip: false,
        decoded_skip: 0,
        big_endian: h.big_endian,
    };
    Ok(Described {
        payload,
        layout,
        spacing: Vec3::ONE,
        meta: VolumeMeta::plain(FileFormat::Den, StoredType::U8, h.big_endian),
    })
}
