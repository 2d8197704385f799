//! Raw voxel files described by a small JSON sidecar:
//!
//! ```json
//! {
//!   "data": "head.raw",
//!   "dims": [256, 256, 128],
//!   "type": "i16",
//!   "endianness": "little",
//!   "spacing": [0.9, 0.9, 2.0],
//!   "header_bytes": 0,
//!   "encoding": "raw"
//! }
//! ```
//!
//! `dims` and `type` are required; `endianness` (`little` / `big`) is required for multi-byte
//! types; the rest is optional: `data` defaults to the sidecar's name with `.json` removed
//! (`head.raw.json` → `head.raw`) or replaced by `.raw` (`head.json` → `head.raw`), relative to
//! the sidecar's folder; `spacing` defaults to `[1, 1, 1]`; `header_bytes` (bytes skipped at the
//! start of the data file) to 0; `encoding` (`raw` / `gzip`; `header_bytes` then counts decoded
//! bytes) to `raw`. `type` is one of `u8 i8 u16 i16 u32 i32 f32 f64` (or `uint8`, `int16`,
//! `float32`, `float64`, ...). Unknown keys are errors, so a misspelt key is not silently ignored.
use super::read::{self, format_err, layout, Described, Payload};
use super::{Encoding, FileFormat, LoadedVolume, StoredType, VolumeMeta, MAX_HEADER_BYTES};
use crate::volume::VolumeError;
use glam::Vec3;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A parsed and validated JSON sidecar (see the module docs for the keys).
#[derive(Clone, Debug, PartialEq)]
pub struct Sidecar {
    /// `data`: the data file, as written (`None`: derived from the sidecar's name).
    pub data: Option<String>,
    /// `dims`.
    pub dims: [u64; 3],
    /// `type`.
    pub stored: StoredType,
    /// `endianness: "big"`.
    pub big_endian: bool,
    /// `spacing` (positive, finite).
    pub spacing: [f64; 3],
    /// `header_bytes`.
    pub header_bytes: u64,
    /// `encoding`.
    pub encoding: Encoding,
}

impl Sidecar {
    /// The data file for a sidecar at `json`: `data` relative to the sidecar's folder, or the
    /// sidecar's name without `.json` if that ends in `.raw`, else with `.json` replaced by `.raw`.
    pub fn data_path(&self, json: &Path) -> PathBuf {
        let dir = json.parent().unwrap_or(Path::new(""));
        match &self.data {
            Some(name) => dir.join(name),
            None => {
                let stem = json.file_stem().unwrap_or_default();
                if Path::new(stem)
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("raw"))
                {
                    dir.join(stem)
                } else {
                    json.with_extension("raw")
                }
            }
        }
    }
}

const KEYS: &[&str] = &[
    "data",
    "dims",
    "type",
    "endianness",
    "spacing",
    "header_bytes",
    "encoding",
];

/// Parses a JSON sidecar (`path` is only named in errors), checking `dims` with checked
/// arithmetic against [`MAX_VOLUME_BYTES`](super::MAX_VOLUME_BYTES). Errors are
/// [`VolumeError::Format`] naming the key (`json` for syntax errors and a non-object document).
pub fn parse_sidecar(path: &Path, bytes: &[u8]) -> Result<Sidecar, VolumeError> {
    let err = |field: &str, message: String| format_err(path, field, message);
    let doc: Value =
        serde_json::from_slice(bytes).map_err(|e| err("json", format!("not valid JSON: {e}")))?;
    let Value::Object(map) = doc else {
        return Err(err("json", "the sidecar must be a JSON object".into()));
    };
    if let Some(unknown) = map.keys().find(|k| !KEYS.contains(&k.as_str())) {
        let shown: String = unknown.chars().take(60).collect();
        return Err(err(
            &shown,
            format!("unknown key (known: {})", KEYS.join(", ")),
        ));
    }
    let need = |key: &str| {
        map.get(key)
            .ok_or_else(|| err(key, "required key is missing".into()))
    };

    let dims = match need("dims")? {
        Value::Array(a) if a.len() == 3 => {
            let mut d = [0u64; 3];
            for (o, v) in d.iter_mut().zip(a) {
                *o = v
                    .as_u64()
                    .ok_or_else(|| err("dims", format!("{v} is not a whole number >= 0")))?;
            }
            d
        }
        _ => return Err(err("dims", "expected an array of 3 whole numbers".into())),
    };

    let stored = match need("type")? {
        Value::String(s) => StoredType::parse(s).ok_or_else(|| {
            err(
                "type",
                format!(
                    "unknown type `{}` (use u8, i8, u16, i16, u32, i32, f32 or f64)",
                    s.chars().take(60).collect::<String>()
                ),
            )
        })?,
        _ => return Err(err("type", "expected a string such as \"u16\"".into())),
    };

    layout(path, "dims", dims, stored)?;

    let big_endian = match map.get("endianness") {
        Some(Value::String(s)) if s == "little" => false,
        Some(Value::String(s)) if s == "big" => true,
        Some(_) => return Err(err("endianness", "expected \"little\" or \"big\"".into())),
        None if stored.size_bytes() > 1 => {
            return Err(err(
                "endianness",
                format!("required for type {} but missing", stored.name()),
            ))
        }
        None => false,
    };

    let spacing = match map.get("spacing") {
        None => [1.0; 3],
        Some(Value::Array(a)) if a.len() == 3 => {
            let mut s = [0.0; 3];
            for (o, v) in s.iter_mut().zip(a) {
                *o = v
                    .as_f64()
                    .filter(|x| x.is_finite() && *x > 0.0 && (*x as f32) > 0.0)
                    .ok_or_else(|| err("spacing", format!("{v} is not a positive number")))?;
            }
            s
        }
        Some(_) => {
            return Err(err(
                "spacing",
                "expected an array of 3 positive numbers".into(),
            ))
        }
    };

    let data = match map.get("data") {
        None => None,
        Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
        Some(_) => return Err(err("data", "expected a file name".into())),
    };

    let header_bytes = match map.get("header_bytes") {
        None => 0,
        Some(v) => v
            .as_u64()
            .ok_or_else(|| err("header_bytes", format!("{v} is not a whole number >= 0")))?,
    };

    let encoding = match map.get("encoding") {
        None => Encoding::Raw,
        Some(Value::String(s)) if s == "raw" => Encoding::Raw,
        Some(Value::String(s)) if s == "gzip" => Encoding::Gzip,
        Some(_) => return Err(err("encoding", "expected \"raw\" or \"gzip\"".into())),
    };

    Ok(Sidecar {
        data,
        dims,
        stored,
        big_endian,
        spacing,
        header_bytes,
        encoding,
    })
}

/// Loads the raw volume a JSON sidecar at `json` describes (see the module docs). Raw data must
/// be exactly `header_bytes` + the voxel bytes long; gzip data must decode to exactly that.
pub fn load_sidecar(json: &Path) -> Result<LoadedVolume, VolumeError> {
    let sidecar = read_sidecar(json)?;
    load_parsed(json, &sidecar)
}

/// Reads and parses the sidecar at `json` (at most [`MAX_HEADER_BYTES`]).
pub(super) fn read_sidecar(json: &Path) -> Result<Sidecar, VolumeError> {
    let (bytes, len) = read::read_prefix(json, MAX_HEADER_BYTES)?;
    if len > MAX_HEADER_BYTES {
        return Err(format_err(
            json,
            "json",
            format!("the sidecar is {len} bytes; at most {MAX_HEADER_BYTES} are read"),
        ));
    }
    parse_sidecar(json, &bytes)
}

/// Loads the data described by an already parsed sidecar at `json`.
pub(super) fn load_parsed(json: &Path, sidecar: &Sidecar) -> Result<LoadedVolume, VolumeError> {
    describe_parsed(json, sidecar)?.load()
}

/// Where and how the data of an already parsed sidecar at `json` is stored (no voxel is read).
pub(super) fn describe_parsed(json: &Path, sidecar: &Sidecar) -> Result<Described, VolumeError> {
    let layout = layout(json, "dims", sidecar.dims, sidecar.stored)?;
    let data_path = sidecar.data_path(json);
    let gzip = sidecar.encoding == Encoding::Gzip;
    let payload = Payload {
        header_path: json.to_path_buf(),
        size_field: "dims",
        data_path,
        offset: if gzip { 0 } else { sidecar.header_bytes },
        gzip,
        decoded_skip: if gzip { sidecar.header_bytes } else { 0 },
        big_endian: sidecar.big_endian,
    };
    let spacing = Vec3::from_array(sidecar.spacing.map(|s| s as f32));
    if !spacing.is_finite() {
        return Err(format_err(
            json,
            "spacing",
            format!("spacing {:?} does not fit in f32", sidecar.spacing),
        ));
    }
    Ok(Described {
        payload,
        layout,
        spacing,
        meta: VolumeMeta::plain(FileFormat::Sidecar, sidecar.stored, sidecar.big_endian),
    })
}
