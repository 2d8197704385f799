//! The decoded size a compressed chunk declares, checked before `zarrs` allocates it: a zstd
//! frame's content size (`zarrs` reserves it whole before decompressing, so a 17-byte chunk
//! declaring 1 TiB aborted the process) and a Blosc header's `nbytes`. A gzip or zlib stream
//! declares nothing trustworthy, so it is inflated once into nothing, stopping one byte past
//! the chunk's size (a 0.5 MB gzip chunk inflated to 1.1 GB inside `zarrs` before its size was
//! checked). Only the codec that comes last in the chain (the one whose output is the stored
//! bytes) is looked at.

use serde_json::Value;
use std::io::Read;

/// The codec whose encoding the stored chunk bytes are.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(super) enum OuterCodec {
    /// zstd (v3 `zstd`, v2 compressor `zstd`).
    Zstd,
    /// Blosc (v3 `blosc`, v2 compressor `blosc`).
    Blosc,
    /// gzip (v3 `gzip`, v2 compressor `gzip`).
    Gzip,
    /// zlib (v2 compressor `zlib`).
    Zlib,
    /// Anything else (raw, gzip, sharding, ...): nothing is checked here.
    Other,
}

impl OuterCodec {
    /// The last codec of the array metadata `doc` (`zarrs`' `ArrayMetadata` as JSON): the v2
    /// `compressor`'s `id`, or the name of the last entry of v3 `codecs`.
    pub(super) fn of(doc: &Value) -> Self {
        let name = match doc.get("codecs") {
            Some(Value::Array(codecs)) => codecs.last().and_then(|c| c.get("name")),
            _ => doc.get("compressor").and_then(|c| c.get("id")),
        };
        match name.and_then(Value::as_str) {
            Some("zstd") | Some("numcodecs.zstd") => Self::Zstd,
            Some("blosc") | Some("numcodecs.blosc") => Self::Blosc,
            Some("gzip") | Some("numcodecs.gzip") => Self::Gzip,
            Some("zlib") | Some("numcodecs.zlib") => Self::Zlib,
            _ => Self::Other,
        }
    }

    /// Checks that the chunk `encoded` declares at most `decoded` bytes (the chunk shape's
    /// size in bytes); the error says what it declares.
    pub(super) fn check(self, encoded: &[u8], decoded: u64) -> Result<(), String> {
        let inflated = match self {
            Self::Gzip => Some(inflated_len(
                flate2::read::MultiGzDecoder::new(encoded),
                decoded,
            )),
            Self::Zlib => Some(inflated_len(
                flate2::read::ZlibDecoder::new(encoded),
                decoded,
            )),
            _ => None,
        };
        if let Some(Some(n)) = inflated {
            if n > decoded {
                return Err(format!(
                    "its {self:?} data inflates past the {decoded} bytes the chunk holds"
                ));
            }
        }
        let declared = match self {
            // Summed over the frames; None for frames without a content size (decoded by
            // streaming, which grows only with the data).
            Self::Zstd => zstd::bulk::Decompressor::upper_bound(encoded).map(|n| n as u64),
            // Blosc 1 header: version, versionlz, flags, typesize, then nbytes (u32 LE).
            Self::Blosc => encoded
                .get(4..8)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u64),
            Self::Gzip | Self::Zlib | Self::Other => None,
        };
        match declared {
            Some(n) if n > decoded => Err(format!(
                "its {self:?} data declares {n} decoded bytes, but the chunk holds {decoded}"
            )),
            _ => Ok(()),
        }
    }
}

/// Bytes `stream` inflates to, read into nothing and stopped at `limit + 1`; `None` when the
/// stream is damaged (`zarrs` then names the fault as it decodes).
fn inflated_len(stream: impl Read, limit: u64) -> Option<u64> {
    std::io::copy(
        &mut stream.take(limit.saturating_add(1)),
        &mut std::io::sink(),
    )
    .ok()
}
