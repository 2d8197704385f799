//! NRRD (`NRRD0001` to `NRRD0005`): attached `.nrrd` files and detached `.nhdr` headers, raw or
//! gzip encoding, three axes.
use super::read::{self, format_err, layout, Described, Payload};
use super::{Encoding, FileFormat, LoadedVolume, StoredType, VolumeMeta, MAX_HEADER_BYTES};
use crate::volume::VolumeError;
use glam::Vec3;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A parsed and validated NRRD header (three axes).
#[derive(Clone, Debug, PartialEq)]
pub struct NrrdHeader {
    /// The format version, 1 to 5 (`NRRD000N`).
    pub version: u8,
    /// `type`.
    pub stored: StoredType,
    /// `sizes` (x fastest).
    pub sizes: [u64; 3],
    /// `encoding`.
    pub encoding: Encoding,
    /// `endian: big` (false for little, and for single-byte types without `endian`).
    pub big_endian: bool,
    /// Voxel spacing: norms of `space directions`, else `|spacings|` (1 for `nan`), else 1.
    pub spacing: [f64; 3],
    /// Unit `space directions` vectors, when they are given in a 3-D space.
    pub directions: Option<[[f64; 3]; 3]>,
    /// `space origin`, when given in a 3-D space.
    pub origin: Option<[f64; 3]>,
    /// `data file` (detached data), as written; relative names are relative to the header.
    pub data_file: Option<String>,
    /// `line skip`: lines skipped at the start of the data file (before decoding).
    pub line_skip: u64,
    /// `byte skip`: bytes skipped after the lines (after decoding, for gzip); -1 (raw only)
    /// means the data is the end of the file.
    pub byte_skip: i64,
    /// Bytes up to and including the blank line that ends the header: where attached data
    /// starts. `None` when the header has no blank line (a detached header).
    pub header_len: Option<u64>,
}

/// Field names whose values are parsed; aliases map to the first spelling.
const FIELDS: &[(&str, &str)] = &[
    ("dimension", "dimension"),
    ("type", "type"),
    ("sizes", "sizes"),
    ("encoding", "encoding"),
    ("endian", "endian"),
    ("spacings", "spacings"),
    ("space directions", "space directions"),
    ("space origin", "space origin"),
    ("space", "space"),
    ("space dimension", "space dimension"),
    ("data file", "data file"),
    ("datafile", "data file"),
    ("byte skip", "byte skip"),
    ("byteskip", "byte skip"),
    ("line skip", "line skip"),
    ("lineskip", "line skip"),
];

/// Parses a NRRD header from the start of a file (`path` is only named in errors). `bytes` may
/// extend past the header (attached data); parsing stops at the first blank line. Refuses: a
/// missing or unknown magic, non-text or malformed lines, repeated fields, `dimension` other than
/// 3, missing `type` / `sizes` / `encoding` (and `endian` for multi-byte types), unsupported
/// types (64-bit integers, block) and encodings (text, hex, bzip2, ...), axes that are not
/// spatial (`none` directions), non-finite or zero spacings, multi-file `data file` forms, and a
/// header with neither attached data (blank line) nor `data file`; `sizes` with a zero axis, an
/// axis over `u32::MAX` or a volume over [`MAX_VOLUME_BYTES`](super::MAX_VOLUME_BYTES) are
/// refused too. Other fields (`kinds`,
/// `units`, key/value pairs, ...) are accepted and ignored. Errors are
/// [`VolumeError::Format`] naming the field (`magic` and `header` for structural problems).
pub fn parse_nrrd_header(path: &Path, bytes: &[u8]) -> Result<NrrdHeader, VolumeError> {
    let err = |field: &str, message: String| format_err(path, field, message);
    let first_end = bytes.iter().position(|&b| b == b'\n');
    let first = &bytes[..first_end.unwrap_or(bytes.len())];
    let first = first.strip_suffix(b"\r").unwrap_or(first);
    let version = match first {
        [b'N', b'R', b'R', b'D', b'0', b'0', b'0', v @ b'1'..=b'5'] => v - b'0',
        _ => {
            return Err(err(
                "magic",
                "not a NRRD file: the first line is not NRRD0001 to NRRD0005".into(),
            ))
        }
    };

    let mut fields: BTreeMap<&'static str, (&str, usize)> = BTreeMap::new();
    let mut pos = first_end.map_or(bytes.len(), |e| e + 1);
    let mut header_len = None;
    let mut line_no = 1usize;
    while pos < bytes.len() {
        line_no += 1;
        let end = bytes[pos..].iter().position(|&b| b == b'\n');
        let raw = &bytes[pos..end.map_or(bytes.len(), |e| pos + e)];
        let next = end.map_or(bytes.len(), |e| pos + e + 1);
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        if raw.is_empty() {
            if end.is_some() {
                header_len = Some(next as u64);
            }
            break;
        }
        pos = next;
        let line = std::str::from_utf8(raw)
            .map_err(|_| err("header", format!("line {line_no} is not UTF-8 text")))?;
        if line.starts_with('#') {
            continue;
        }
        let field_sep = line
            .find(": ")
            .or_else(|| line.strip_suffix(':').map(str::len));
        let kv_sep = line.find(":=");
        let sep = match (field_sep, kv_sep) {
            (_, Some(k)) if field_sep.is_none_or(|f| k < f) => continue, // key:=value
            (Some(f), _) => f,
            _ => {
                return Err(err(
                    "header",
                    format!("line {line_no} is not `field: value`: {}", clip(line)),
                ))
            }
        };
        let name = line[..sep].trim();
        let value = line.get(sep + 1..).unwrap_or("").trim();
        let Some(&(_, canonical)) = FIELDS.iter().find(|(n, _)| *n == name) else {
            continue; // a field we do not need: kinds, units, labels, content, ...
        };
        if let Some((_, first_line)) = fields.insert(canonical, (value, line_no)) {
            return Err(err(
                canonical,
                format!("given twice (lines {first_line} and {line_no})"),
            ));
        }
    }

    let get = |name: &str| fields.get(name).map(|(v, _)| *v);
    let need =
        |name: &'static str| get(name).ok_or_else(|| err(name, "required field is missing".into()));

    let dimension = need("dimension")?;
    if dimension.parse::<u64>().ok() != Some(3) {
        return Err(err(
            "dimension",
            format!(
                "dimension is {}, only 3-D volumes are supported",
                clip(dimension)
            ),
        ));
    }

    let type_name = need("type")?;
    let stored = parse_type(type_name).ok_or_else(|| {
        err(
            "type",
            format!(
                "unsupported type `{}` (supported: 8-, 16- and 32-bit integers, float, double)",
                clip(type_name)
            ),
        )
    })?;

    let sizes_text = need("sizes")?;
    let sizes: Vec<u64> = sizes_text
        .split_whitespace()
        .map(|t| t.parse::<u64>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            err(
                "sizes",
                format!("`{}` is not a list of whole numbers", clip(sizes_text)),
            )
        })?;
    let sizes: [u64; 3] = sizes
        .try_into()
        .map_err(|v: Vec<u64>| err("sizes", format!("{} sizes given for dimension 3", v.len())))?;

    layout(path, "sizes", sizes, stored)?;

    let encoding_name = need("encoding")?;
    let encoding = match encoding_name {
        "raw" => Encoding::Raw,
        "gzip" | "gz" => Encoding::Gzip,
        other => {
            return Err(err(
                "encoding",
                format!(
                    "unsupported encoding `{}` (supported: raw, gzip)",
                    clip(other)
                ),
            ))
        }
    };

    let big_endian = match get("endian") {
        Some("little") => false,
        Some("big") => true,
        Some(other) => {
            return Err(err(
                "endian",
                format!("`{}` is neither `little` nor `big`", clip(other)),
            ))
        }
        None if stored.size_bytes() > 1 => {
            return Err(err(
                "endian",
                format!("required for type {} but missing", stored.name()),
            ))
        }
        None => false,
    };

    let mut spacing = [1.0; 3];
    if let Some(text) = get("spacings") {
        let values: Vec<&str> = text.split_whitespace().collect();
        if values.len() != 3 {
            return Err(err(
                "spacings",
                format!("{} spacings given for dimension 3", values.len()),
            ));
        }
        for (s, t) in spacing.iter_mut().zip(values) {
            let v: f64 = t
                .parse()
                .map_err(|_| err("spacings", format!("`{}` is not a number", clip(t))))?;
            if v.is_nan() {
                continue;
            }
            if !(v.is_finite() && v != 0.0) {
                return Err(err(
                    "spacings",
                    format!("spacing {v} is not finite and non-zero"),
                ));
            }
            *s = v.abs();
        }
    }

    let space_dim: Option<usize> = match get("space dimension") {
        Some(t) => Some(
            t.parse()
                .ok()
                .filter(|n| (1..=8).contains(n))
                .ok_or_else(|| {
                    err(
                        "space dimension",
                        format!("`{}` is not a whole number from 1 to 8", clip(t)),
                    )
                })?,
        ),
        None => get("space").map(|_| 3),
    };

    let mut directions = None;
    if let Some(text) = get("space directions") {
        let vectors = parse_vectors(text).map_err(|m| err("space directions", m))?;
        if vectors.len() != 3 {
            return Err(err(
                "space directions",
                format!("{} vectors given for dimension 3", vectors.len()),
            ));
        }
        let mut columns = [[0.0; 3]; 3];
        let len = vectors.iter().flatten().map(Vec::len).next().unwrap_or(0);
        for (i, v) in vectors.iter().enumerate() {
            let Some(v) = v else {
                return Err(err(
                    "space directions",
                    format!("axis {i} is `none`: all three axes must be spatial"),
                ));
            };
            if v.len() != len || space_dim.is_some_and(|d| d != len) {
                return Err(err(
                    "space directions",
                    format!(
                        "vector {i} has {} components; expected {}",
                        v.len(),
                        space_dim.unwrap_or(len)
                    ),
                ));
            }
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return Err(err(
                    "space directions",
                    format!("vector {i} has length {norm}; expected finite and non-zero"),
                ));
            }
            spacing[i] = norm;
            if len == 3 {
                columns[i] = [v[0], v[1], v[2]];
            }
        }
        if len == 3 {
            directions = super::nii::normalize_columns(columns);
        }
    }

    let mut origin = None;
    if let Some(text) = get("space origin") {
        let vectors = parse_vectors(text).map_err(|m| err("space origin", m))?;
        match vectors.as_slice() {
            [Some(v)] if v.iter().all(|x| x.is_finite()) => {
                if v.len() == 3 {
                    origin = Some([v[0], v[1], v[2]]);
                }
            }
            _ => {
                return Err(err(
                    "space origin",
                    format!("`{}` is not one finite vector", clip(text)),
                ))
            }
        }
    }

    let data_file = match get("data file") {
        Some(f) if f == "LIST" || f.contains('%') || f.is_empty() => {
            return Err(err(
                "data file",
                format!(
                    "`{}`: only a single data file name is supported (not LIST or numbered series)",
                    clip(f)
                ),
            ))
        }
        other => other.map(str::to_owned),
    };

    let line_skip = match get("line skip") {
        Some(t) => t.parse::<u64>().map_err(|_| {
            err(
                "line skip",
                format!("`{}` is not a whole number >= 0", clip(t)),
            )
        })?,
        None => 0,
    };
    let byte_skip = match get("byte skip") {
        Some(t) => t.parse::<i64>().ok().filter(|&n| n >= -1).ok_or_else(|| {
            err(
                "byte skip",
                format!("`{}` is not a whole number >= -1", clip(t)),
            )
        })?,
        None => 0,
    };
    if byte_skip == -1 && encoding != Encoding::Raw {
        return Err(err(
            "byte skip",
            "byte skip -1 (data at the end of the file) needs raw encoding".into(),
        ));
    }
    if data_file.is_none() && header_len.is_none() {
        return Err(err(
            "data file",
            "no `data file` field and no blank line ending the header before attached data".into(),
        ));
    }

    Ok(NrrdHeader {
        version,
        stored,
        sizes,
        encoding,
        big_endian,
        spacing,
        directions,
        origin,
        data_file,
        line_skip,
        byte_skip,
        header_len,
    })
}

/// NRRD type names (all the spellings of the format specification) for the supported types.
fn parse_type(name: &str) -> Option<StoredType> {
    Some(match name {
        "signed char" | "int8" | "int8_t" => StoredType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => StoredType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            StoredType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            StoredType::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => StoredType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => StoredType::U32,
        "float" => StoredType::F32,
        "double" => StoredType::F64,
        _ => return None,
    })
}

/// Parses `(a,b,c) none (d,e,f)`: a vector per token, `None` for `none`.
fn parse_vectors(text: &str) -> Result<Vec<Option<Vec<f64>>>, String> {
    let mut out = Vec::new();
    let mut rest = text.trim_start();
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("none") {
            out.push(None);
            rest = after.trim_start();
        } else if let Some(after) = rest.strip_prefix('(') {
            let close = after
                .find(')')
                .ok_or_else(|| format!("`{}` has an unclosed `(`", clip(text)))?;
            let values = after[..close]
                .split(',')
                .map(|t| t.trim().parse::<f64>())
                .collect::<Result<Vec<_>, _>>()
                .map_err(|_| format!("`{}` holds a value that is not a number", clip(text)))?;
            if values.len() > 8 || values.iter().any(|v| !v.is_finite()) {
                return Err(format!(
                    "`{}`: vectors need 1 to 8 finite components",
                    clip(text)
                ));
            }
            out.push(Some(values));
            rest = after[close + 1..].trim_start();
        } else {
            return Err(format!(
                "`{}` is not a list of `(x,y,z)` vectors or `none`",
                clip(text)
            ));
        }
        if out.len() > 16 {
            return Err("too many vectors".into());
        }
    }
    Ok(out)
}

/// At most 60 characters of `s`, for error messages.
fn clip(s: &str) -> String {
    match s.char_indices().nth(60) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s.to_owned(),
    }
}

/// Loads a NRRD file: attached data after the header's blank line, or the `data file` named by
/// the header (relative to the header's folder). `line skip` lines are skipped first, then
/// `byte skip` bytes (in the decoded stream for gzip; `-1` for raw data means the data ends the
/// file). Raw data must fill the rest of its file exactly; gzip data must decode to exactly the
/// described size. The header is read from the first [`MAX_HEADER_BYTES`] bytes.
pub fn load_nrrd(path: &Path) -> Result<LoadedVolume, VolumeError> {
    describe_nrrd(path)?.load()
}

/// Parses and checks a NRRD header and locates its data (see [`load_nrrd`]), reading no voxel.
pub(super) fn describe_nrrd(path: &Path) -> Result<Described, VolumeError> {
    let (bytes, len) = read::read_prefix(path, MAX_HEADER_BYTES)?;
    let h = parse_nrrd_header(path, &bytes).map_err(|e| match e {
        VolumeError::Format { ref field, .. } if field == "data file" && len > MAX_HEADER_BYTES => {
            format_err(
                path,
                "header",
                format!("no blank line ends the header within its first {MAX_HEADER_BYTES} bytes"),
            )
        }
        e => e,
    })?;
    let layout = layout(path, "sizes", h.sizes, h.stored)?;
    let (data_path, base): (PathBuf, u64) = match (&h.data_file, h.header_len) {
        (Some(name), _) => {
            let name = Path::new(name);
            let p = if name.is_absolute() {
                name.to_path_buf()
            } else {
                path.parent().unwrap_or(Path::new("")).join(name)
            };
            (p, 0)
        }
        (None, Some(n)) => (path.to_path_buf(), n),
        (None, None) => unreachable_header(path)?,
    };
    let base = read::skip_lines(path, "line skip", &data_path, base, h.line_skip)?;
    let gzip = h.encoding == Encoding::Gzip;
    let offset = if gzip {
        base
    } else if h.byte_skip == -1 {
        let (_, data_len) = read::open_regular(&data_path)?;
        data_len
            .checked_sub(layout.bytes)
            .filter(|&o| o >= base)
            .ok_or_else(|| {
                format_err(
                    path,
                    "sizes",
                    format!(
                        "{} holds {data_len} bytes, less than the {} data bytes described \
                         (after {base} bytes of header / skipped lines)",
                        data_path.display(),
                        layout.bytes
                    ),
                )
            })?
    } else {
        base.checked_add(h.byte_skip as u64)
            .ok_or_else(|| format_err(path, "byte skip", "offset overflows"))?
    };
    let payload = Payload {
        header_path: path.to_path_buf(),
        size_field: "sizes",
        data_path,
        offset,
        gzip,
        decoded_skip: if gzip { h.byte_skip.max(0) as u64 } else { 0 },
        big_endian: h.big_endian,
    };
    let spacing = Vec3::from_array(h.spacing.map(|s| s as f32));
    if !(spacing.is_finite() && spacing.min_element() > 0.0) {
        let field = if h.directions.is_some() {
            "space directions"
        } else {
            "spacings"
        };
        return Err(format_err(
            path,
            field,
            format!("spacing {:?} does not fit in f32", h.spacing),
        ));
    }
    let mut meta = VolumeMeta::plain(FileFormat::Nrrd, h.stored, h.big_endian);
    if let Some(d) = h.directions {
        meta.directions = d;
    }
    if let Some(o) = h.origin {
        meta.origin = o;
    }
    Ok(Described {
        payload,
        layout,
        spacing,
        meta,
    })
}

/// The parser guarantees a data file or attached data; this keeps the loader total anyway.
fn unreachable_header(path: &Path) -> Result<(PathBuf, u64), VolumeError> {
    Err(format_err(
        path,
        "data file",
        "no data file and no attached data",
    ))
}
