//! OME-Zarr images (Zarr v2 and v3) through the `zarrs` crate.
//!
//! A path names the root folder of an OME-Zarr image (usually `NAME.zarr` / `NAME.ome.zarr`):
//!
//! - **Zarr v3, OME-Zarr 0.5**: the root `zarr.json` is a group (`"node_type": "group"`) whose
//!   `attributes.ome.multiscales` describes the levels (a bare `attributes.multiscales` is accepted
//!   too).
//! - **Zarr v2, OME-Zarr 0.1-0.4**: the root `.zattrs` holds `multiscales`.
//! - A plain Zarr array (root `zarr.json` with `"node_type": "array"`, or a root `.zarray`) loads
//!   as a volume with unit spacing, its last three axes being z, y, x.
//!
//! Of the first multiscale, the dataset of the requested level (0, the finest, by default) is
//! opened with `zarrs` (chunk grid, chunk keys, codecs, fill value for missing chunks). Axes:
//! the last three must be spatial (`"type": "space"`, or named `z`, `y`, `x` where no type is
//! given) and are taken as volume z, y, x (the last array axis varies fastest, like the volume's
//! x); up to two leading axes (time, channel, ...) are allowed when their size is 1. OME-Zarr
//! before 0.3 has no `axes`: the last three array axes are then z, y, x. Spacing and origin come
//! from the dataset's `coordinateTransformations` (`scale`, then optional `translation`),
//! followed by the multiscale's own ones if present: spacing `s_d * s_m`, origin
//! `t_d * s_m + t_m` per axis. Units are not interpreted.
//!
//! Data types: `uint8`, `int8`, `uint16`, `int16`, `uint32`, `int32`, `float32`, `float64` (v2:
//! `|u1`, `<i2`, `>f4`, ...), in either byte order, mapped to the volume's scalar types like every
//! other format (see [`super`]: i16 is stored as u16 + [`I16_OFFSET`](super::I16_OFFSET), ...).
//! Codecs built in: raw, gzip and sharding (with crc32c index checksums). Blosc and zstd need C
//! libraries and are not built (an array using them fails on the field `compressor` / `codecs`).
//!
//! # Safety against hostile stores
//!
//! Metadata documents are read only up to [`MAX_HEADER_BYTES`]. The volume size is checked with
//! checked arithmetic against [`MAX_VOLUME_BYTES`](super::MAX_VOLUME_BYTES), and every chunk's
//! decoded size against [`MAX_CHUNK_BYTES`], before anything is allocated or decoded; the volume
//! buffer is reserved fallibly. Chunks are decoded one at a time (`zarrs`), each bounded to the
//! array, and copied into the volume. A chunk that does not decode to its shape (a truncated raw
//! chunk, corrupt gzip) is a [`VolumeError::Format`] naming the chunk file. Limitation: `zarrs`
//! decodes gzip chunks without an output limit before checking their size, so a gzip bomb in a
//! chunk file can allocate up to about 1000 times the file's size.
//!
//! [`parse_zarr_root`] parses a root metadata document from bytes (the fuzz target's entry
//! point); [`load_zarr`] / [`load_zarr_level`] load.
use super::read::{format_err, io_err, layout, read_prefix};
use super::{FileFormat, LoadedVolume, StoredType, VolumeMeta, MAX_HEADER_BYTES};
use crate::volume::{Volume, VolumeError, VoxelData};
use glam::Vec3;
use serde_json::{Map, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use zarrs::array::{Array, ArrayCreateError, ArrayError, ElementOwned};
use zarrs::filesystem::FilesystemStore;
use zarrs::storage::StorageError;

/// The largest decoded chunk accepted, in bytes: 1 GiB.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Axes an OME-Zarr image may have besides z, y, x (time, channel), each of size 1.
const MAX_LEADING_AXES: usize = 2;

/// The Zarr storage format version of a store.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ZarrVersion {
    /// Zarr v2: `.zattrs`, `.zgroup`, `.zarray`.
    V2,
    /// Zarr v3: `zarr.json`.
    V3,
}

impl ZarrVersion {
    /// The metadata file of a group's attributes (v2) or of any node (v3).
    pub const fn attributes_file(self) -> &'static str {
        match self {
            ZarrVersion::V2 => ".zattrs",
            ZarrVersion::V3 => "zarr.json",
        }
    }

    /// The metadata file of an array.
    pub const fn array_file(self) -> &'static str {
        match self {
            ZarrVersion::V2 => ".zarray",
            ZarrVersion::V3 => "zarr.json",
        }
    }

    /// The array metadata field naming the data type.
    const fn dtype_field(self) -> &'static str {
        match self {
            ZarrVersion::V2 => "dtype",
            ZarrVersion::V3 => "data_type",
        }
    }

    /// The array metadata field naming the chunk shape.
    const fn chunks_field(self) -> &'static str {
        match self {
            ZarrVersion::V2 => "chunks",
            ZarrVersion::V3 => "chunk_grid",
        }
    }

    /// The array metadata field naming the codecs.
    const fn codecs_field(self) -> &'static str {
        match self {
            ZarrVersion::V2 => "compressor",
            ZarrVersion::V3 => "codecs",
        }
    }
}

/// One axis of an OME-Zarr multiscale.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OmeAxis {
    /// `name`.
    pub name: String,
    /// `type` (`space`, `time`, `channel`, ...), if given.
    pub kind: Option<String>,
}

/// One level (dataset) of an OME-Zarr multiscale.
#[derive(Clone, Debug, PartialEq)]
pub struct OmeDataset {
    /// `path` of the level's array, relative to the image root (validated: no `.`/`..`/empty
    /// segments, no leading `/`, no backslash).
    pub path: String,
    /// The effective scale per array axis (dataset `scale` times the multiscale's), or empty when
    /// neither gives one (unit spacing).
    pub scale: Vec<f64>,
    /// The effective translation per array axis (dataset translation scaled by the multiscale's
    /// scale, plus the multiscale's translation), or empty when neither gives one.
    pub translation: Vec<f64>,
}

/// The first multiscale of an OME-Zarr image.
#[derive(Clone, Debug, PartialEq)]
pub struct OmeMultiscale {
    /// `version` (of the multiscale in 0.1-0.4, of the `ome` attribute in 0.5), if given.
    pub version: Option<String>,
    /// `axes` (3 to 5, the last three spatial); empty before OME-Zarr 0.3.
    pub axes: Vec<OmeAxis>,
    /// `datasets`, finest level first.
    pub datasets: Vec<OmeDataset>,
}

/// What the root metadata document of a store describes.
#[derive(Clone, Debug, PartialEq)]
pub enum ZarrRoot {
    /// An OME-Zarr image.
    Multiscales(OmeMultiscale),
    /// A plain array (Zarr v3 `"node_type": "array"`).
    Array,
}

/// Parses a store's root metadata document: for [`ZarrVersion::V3`] the root `zarr.json`, for
/// [`ZarrVersion::V2`] the root `.zattrs`. `path` is only named in errors. Only the bytes are
/// parsed (nothing is read or allocated from the sizes they claim). Errors are
/// [`VolumeError::Format`] naming the field: `json`, `zarr_format`, `node_type`, `attributes`,
/// `ome`, `multiscales`, `axes`, `datasets`, `path`, `coordinateTransformations`.
pub fn parse_zarr_root(
    path: &Path,
    bytes: &[u8],
    version: ZarrVersion,
) -> Result<ZarrRoot, VolumeError> {
    let err = |field: &str, message: String| format_err(path, field, message);
    let doc: Value =
        serde_json::from_slice(bytes).map_err(|e| err("json", format!("not valid JSON: {e}")))?;
    let Value::Object(doc) = doc else {
        return Err(err("json", "expected a JSON object".into()));
    };
    let attributes = match version {
        ZarrVersion::V2 => &doc,
        ZarrVersion::V3 => {
            match doc.get("zarr_format") {
                Some(v) if v.as_u64() == Some(3) => {}
                Some(v) => return Err(err("zarr_format", format!("expected 3, found {v}"))),
                None => return Err(err("zarr_format", "required key is missing".into())),
            }
            match doc.get("node_type").and_then(Value::as_str) {
                Some("array") => return Ok(ZarrRoot::Array),
                Some("group") => {}
                _ => {
                    return Err(err(
                        "node_type",
                        "expected \"group\" (an OME-Zarr image) or \"array\"".into(),
                    ))
                }
            }
            match doc.get("attributes") {
                Some(Value::Object(a)) => a,
                Some(_) => return Err(err("attributes", "expected a JSON object".into())),
                None => {
                    return Err(err(
                        "multiscales",
                        "the group has no attributes, so no OME-Zarr multiscales".into(),
                    ))
                }
            }
        }
    };
    // OME-Zarr 0.5 nests everything under "ome"; earlier versions put "multiscales" at the top.
    let (ome_version, holder) = match attributes.get("ome") {
        Some(Value::Object(ome)) => (
            ome.get("version").and_then(Value::as_str).map(String::from),
            ome,
        ),
        Some(_) => return Err(err("ome", "expected a JSON object".into())),
        None => (None, attributes),
    };
    let first = match holder.get("multiscales") {
        Some(Value::Array(list)) => match list.first() {
            Some(Value::Object(m)) => m,
            Some(_) => return Err(err("multiscales", "entries must be JSON objects".into())),
            None => return Err(err("multiscales", "the list is empty".into())),
        },
        Some(_) => return Err(err("multiscales", "expected a list".into())),
        None => {
            return Err(err(
                "multiscales",
                "missing: not an OME-Zarr image (no multiscales metadata)".into(),
            ))
        }
    };
    parse_multiscale(path, first, ome_version)
}

/// Parses and validates one multiscale object.
fn parse_multiscale(
    path: &Path,
    m: &Map<String, Value>,
    ome_version: Option<String>,
) -> Result<ZarrRoot, VolumeError> {
    let err = |field: &str, message: String| format_err(path, field, message);
    let version = m
        .get("version")
        .and_then(Value::as_str)
        .map(String::from)
        .or(ome_version);
    let axes = match m.get("axes") {
        None => Vec::new(),
        Some(Value::Array(list)) => parse_axes(path, list)?,
        Some(_) => return Err(err("axes", "expected a list".into())),
    };
    let ndim = (!axes.is_empty()).then_some(axes.len());
    let (global_scale, global_translation) = match m.get("coordinateTransformations") {
        None => (None, None),
        Some(t) => parse_transforms(path, t, ndim)?,
    };
    let list = match m.get("datasets") {
        Some(Value::Array(list)) if !list.is_empty() => list,
        Some(Value::Array(_)) => return Err(err("datasets", "the list is empty".into())),
        Some(_) => return Err(err("datasets", "expected a list".into())),
        None => return Err(err("datasets", "required key is missing".into())),
    };
    let mut datasets = Vec::with_capacity(list.len().min(64));
    for (i, d) in list.iter().enumerate() {
        let Value::Object(d) = d else {
            return Err(err("datasets", format!("entry {i} is not a JSON object")));
        };
        let ds_path = match d.get("path") {
            Some(Value::String(p)) => p,
            _ => return Err(err("path", format!("dataset {i} needs a \"path\" string"))),
        };
        check_dataset_path(ds_path).map_err(|m| err("path", format!("dataset {i}: {m}")))?;
        let (scale, translation) = match d.get("coordinateTransformations") {
            None => (None, None),
            Some(t) => parse_transforms(path, t, ndim)?,
        };
        let (scale, translation) = combine(
            path,
            (scale, translation),
            (global_scale.as_deref(), global_translation.as_deref()),
        )?;
        datasets.push(OmeDataset {
            path: ds_path.clone(),
            scale,
            translation,
        });
    }
    Ok(ZarrRoot::Multiscales(OmeMultiscale {
        version,
        axes,
        datasets,
    }))
}

/// Parses `axes` (objects with `name` / `type`, or plain names as in OME-Zarr 0.3).
fn parse_axes(path: &Path, list: &[Value]) -> Result<Vec<OmeAxis>, VolumeError> {
    let err = |message: String| format_err(path, "axes", message);
    if !(3..=3 + MAX_LEADING_AXES).contains(&list.len()) {
        return Err(err(format!(
            "{} axes; a volume needs 3 spatial axes (z, y, x), after at most {MAX_LEADING_AXES} \
             others of size 1",
            list.len()
        )));
    }
    let mut axes = Vec::with_capacity(list.len());
    for (i, a) in list.iter().enumerate() {
        let (name, kind) = match a {
            Value::String(name) => (name.clone(), None),
            Value::Object(o) => {
                let name = match o.get("name") {
                    Some(Value::String(n)) => n.clone(),
                    _ => return Err(err(format!("axis {i} needs a \"name\" string"))),
                };
                let kind = match o.get("type") {
                    None | Some(Value::Null) => None,
                    Some(Value::String(t)) => Some(t.clone()),
                    Some(_) => return Err(err(format!("axis {i}: \"type\" must be a string"))),
                };
                (name, kind)
            }
            _ => return Err(err(format!("axis {i} is neither a name nor an object"))),
        };
        if axes.iter().any(|b: &OmeAxis| b.name == name) {
            return Err(err(format!("axis name {:?} appears twice", short(&name))));
        }
        axes.push(OmeAxis { name, kind });
    }
    let first_spatial = axes.len() - 3;
    for (i, axis) in axes.iter().enumerate() {
        let spatial = match &axis.kind {
            Some(kind) => kind == "space",
            None => matches!(axis.name.as_str(), "x" | "y" | "z"),
        };
        if spatial != (i >= first_spatial) {
            return Err(err(format!(
                "axis {i} ({:?}) {}: the last three axes must be the spatial ones (z, y, x)",
                short(&axis.name),
                if spatial {
                    "is spatial"
                } else {
                    "is not spatial"
                }
            )));
        }
    }
    Ok(axes)
}

/// A scale and a translation, each per array axis.
type Transforms = (Option<Vec<f64>>, Option<Vec<f64>>);

/// Parses a `coordinateTransformations` list: `identity`, or `scale` then optional
/// `translation`. Scales must be positive and finite, translations finite; with `ndim` known
/// (from `axes`) their length must match, else all given lengths must agree.
fn parse_transforms(
    path: &Path,
    value: &Value,
    ndim: Option<usize>,
) -> Result<Transforms, VolumeError> {
    const FIELD: &str = "coordinateTransformations";
    let err = |message: String| format_err(path, FIELD, message);
    let Value::Array(list) = value else {
        return Err(err("expected a list".into()));
    };
    let mut scale = None;
    let mut translation = None;
    for (i, t) in list.iter().enumerate() {
        let Value::Object(t) = t else {
            return Err(err(format!("entry {i} is not a JSON object")));
        };
        let kind = t.get("type").and_then(Value::as_str).unwrap_or_default();
        let numbers = |key: &str| -> Result<Vec<f64>, VolumeError> {
            let Some(Value::Array(v)) = t.get(key) else {
                return Err(err(format!(
                    "{kind} entry {i} needs a \"{key}\" list of numbers (\"path\" to a file is \
                     not supported)"
                )));
            };
            let v: Vec<f64> = v
                .iter()
                .map(|x| x.as_f64().filter(|x| x.is_finite()))
                .collect::<Option<_>>()
                .ok_or_else(|| err(format!("{kind} entry {i}: every value must be a number")))?;
            let expected = ndim.unwrap_or(v.len());
            if v.len() != expected || !(3..=3 + MAX_LEADING_AXES).contains(&v.len()) {
                return Err(err(format!(
                    "{kind} entry {i} has {} values, expected one per axis ({})",
                    v.len(),
                    expected
                )));
            }
            Ok(v)
        };
        match kind {
            "identity" => {}
            "scale" if scale.is_none() && translation.is_none() => {
                let s = numbers("scale")?;
                if s.iter().any(|&x| x <= 0.0) {
                    return Err(err(format!("scale {s:?} must be positive on every axis")));
                }
                scale = Some(s);
            }
            "translation" if translation.is_none() => translation = Some(numbers("translation")?),
            "scale" | "translation" => {
                return Err(err(format!(
                    "entry {i}: at most one scale followed by at most one translation"
                )))
            }
            other => {
                return Err(err(format!(
                    "entry {i}: unsupported transformation type {:?}",
                    short(other)
                )))
            }
        }
    }
    if let (Some(s), Some(t)) = (&scale, &translation) {
        if s.len() != t.len() {
            return Err(err(format!(
                "scale has {} values but translation {}",
                s.len(),
                t.len()
            )));
        }
    }
    Ok((scale, translation))
}

/// Combines a dataset's transforms with the multiscale's (applied after them).
fn combine(
    path: &Path,
    dataset: Transforms,
    global: (Option<&[f64]>, Option<&[f64]>),
) -> Result<(Vec<f64>, Vec<f64>), VolumeError> {
    let lens = [
        dataset.0.as_ref().map(Vec::len),
        dataset.1.as_ref().map(Vec::len),
        global.0.map(<[f64]>::len),
        global.1.map(<[f64]>::len),
    ];
    let mut known = lens.iter().flatten();
    let Some(&n) = known.next() else {
        return Ok((Vec::new(), Vec::new()));
    };
    if known.any(|&m| m != n) {
        return Err(format_err(
            path,
            "coordinateTransformations",
            "the datasets' and the multiscale's transformations have different lengths",
        ));
    }
    let ds = dataset.0.unwrap_or_else(|| vec![1.0; n]);
    let dt = dataset.1.unwrap_or_else(|| vec![0.0; n]);
    let gs = global.0.map_or_else(|| vec![1.0; n], <[f64]>::to_vec);
    let gt = global.1.map_or_else(|| vec![0.0; n], <[f64]>::to_vec);
    let scale: Vec<f64> = (0..n).map(|i| ds[i] * gs[i]).collect();
    let translation: Vec<f64> = (0..n).map(|i| dt[i] * gs[i] + gt[i]).collect();
    if scale.iter().chain(&translation).any(|x| !x.is_finite()) || scale.contains(&0.0) {
        return Err(format_err(
            path,
            "coordinateTransformations",
            "the combined transformations overflow",
        ));
    }
    Ok((scale, translation))
}

/// Checks a dataset path: relative, `/`-separated, no empty, `.` or `..` segments, no backslash.
fn check_dataset_path(p: &str) -> Result<(), String> {
    if p.is_empty() {
        return Err("the path is empty".into());
    }
    if p.len() > 1024 {
        return Err("the path is longer than 1024 bytes".into());
    }
    if p.contains('\\') || p.contains('\0') {
        return Err(format!("{:?} contains a backslash or NUL", short(p)));
    }
    if p.split('/').any(|s| s.is_empty() || s.starts_with('.')) {
        return Err(format!(
            "{:?} must be a relative path without empty segments or segments starting with \".\"",
            short(p)
        ));
    }
    Ok(())
}

/// At most 60 characters of `s`, for messages.
fn short(s: &str) -> String {
    s.chars().take(60).collect()
}

/// Loads level 0 (the finest) of the OME-Zarr image (or plain Zarr array) at `root`. See the
/// module docs.
pub fn load_zarr(root: &Path) -> Result<LoadedVolume, VolumeError> {
    load_zarr_level(root, 0)
}

/// Loads level `level` (index into `multiscales[0].datasets`, 0 the finest) of the OME-Zarr
/// image at `root`; a plain Zarr array has only level 0. A level that does not exist is an
/// error on the field `datasets`.
pub fn load_zarr_level(root: &Path, level: usize) -> Result<LoadedVolume, VolumeError> {
    let meta = std::fs::metadata(root).map_err(io_err(root))?;
    if !meta.is_dir() {
        return Err(format_err(
            root,
            "zarr_format",
            "an OME-Zarr image is a folder (holding zarr.json or .zattrs)",
        ));
    }
    let v3_doc = root.join("zarr.json");
    let (version, root_desc) = if v3_doc.is_file() {
        let bytes = read_metadata(&v3_doc)?;
        (
            ZarrVersion::V3,
            parse_zarr_root(&v3_doc, &bytes, ZarrVersion::V3)?,
        )
    } else if root.join(".zarray").is_file() {
        (ZarrVersion::V2, ZarrRoot::Array)
    } else if root.join(".zattrs").is_file() {
        let attrs = root.join(".zattrs");
        let bytes = read_metadata(&attrs)?;
        (
            ZarrVersion::V2,
            parse_zarr_root(&attrs, &bytes, ZarrVersion::V2)?,
        )
    } else if root.join(".zgroup").is_file() {
        return Err(format_err(
            &root.join(".zattrs"),
            "multiscales",
            "missing: the Zarr v2 group has no .zattrs, so no OME-Zarr multiscales",
        ));
    } else {
        return Err(format_err(
            root,
            "zarr_format",
            "not a Zarr store: no zarr.json (v3) nor .zattrs / .zgroup / .zarray (v2)",
        ));
    };
    let group_doc = root.join(version.attributes_file());
    let (dataset, axes) = match root_desc {
        ZarrRoot::Array => {
            if level != 0 {
                return Err(format_err(
                    root,
                    "datasets",
                    format!("level {level} requested, but a plain array has only level 0"),
                ));
            }
            (None, Vec::new())
        }
        ZarrRoot::Multiscales(m) => {
            let count = m.datasets.len();
            let Some(d) = m.datasets.into_iter().nth(level) else {
                return Err(format_err(
                    &group_doc,
                    "datasets",
                    format!("level {level} requested, but the image has {count} levels"),
                ));
            };
            (Some(d), m.axes)
        }
    };
    let array_dir = match &dataset {
        Some(d) => d.path.split('/').fold(root.to_path_buf(), |p, s| p.join(s)),
        None => root.to_path_buf(),
    };
    let array_doc = array_dir.join(version.array_file());
    let array_text = read_metadata(&array_doc)?;
    let big_endian = declared_big_endian(&array_text, version);

    let store = FilesystemStore::new(root).map_err(|e| {
        io_err(root)(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            e.to_string(),
        ))
    })?;
    let node = match &dataset {
        Some(d) => format!("/{}", d.path),
        None => "/".to_string(),
    };
    let array = Array::open(Arc::new(store), &node)
        .map_err(|e| array_create_err(&array_doc, version, e))?;

    // Axes and shape.
    let shape = array.shape().to_vec();
    let ndim = shape.len();
    if !axes.is_empty() && axes.len() != ndim {
        return Err(format_err(
            &group_doc,
            "axes",
            format!(
                "{} axes, but the array {} has {ndim} dimensions",
                axes.len(),
                array_doc.display()
            ),
        ));
    }
    let shape_field = "shape";
    if !(3..=3 + MAX_LEADING_AXES).contains(&ndim) {
        return Err(format_err(
            &array_doc,
            shape_field,
            format!("{ndim} dimensions {shape:?}; a volume needs 3 (z, y, x), after at most {MAX_LEADING_AXES} of size 1"),
        ));
    }
    let lead = ndim - 3;
    if let Some(i) = (0..lead).find(|&i| shape[i] != 1) {
        let name = axes
            .get(i)
            .map_or_else(|| format!("{i}"), |a| short(&a.name));
        return Err(format_err(
            &array_doc,
            shape_field,
            format!(
                "axis {name} has size {} in shape {shape:?}; only one time point / channel can \
                 be loaded as a volume",
                shape[i]
            ),
        ));
    }
    let stored = stored_type(&array, &array_doc, version)?;
    let dims = [shape[ndim - 1], shape[ndim - 2], shape[ndim - 3]];
    let lay = layout(&array_doc, shape_field, dims, stored)?;

    // Spacing and origin (x, y, z = the last three axes, reversed).
    let (spacing, origin) = match &dataset {
        Some(d) if !d.scale.is_empty() => {
            if d.scale.len() != ndim {
                return Err(format_err(
                    &group_doc,
                    "coordinateTransformations",
                    format!(
                        "{} scale values, but the array has {ndim} dimensions",
                        d.scale.len()
                    ),
                ));
            }
            let s = [d.scale[ndim - 1], d.scale[ndim - 2], d.scale[ndim - 3]];
            let t = [
                d.translation[ndim - 1],
                d.translation[ndim - 2],
                d.translation[ndim - 3],
            ];
            (s, t)
        }
        _ => ([1.0; 3], [0.0; 3]),
    };
    let spacing_f32 = Vec3::from_array(spacing.map(|s| s as f32));
    if !(spacing_f32.is_finite() && spacing_f32.min_element() > 0.0) {
        return Err(format_err(
            &group_doc,
            "coordinateTransformations",
            format!("spacing {spacing:?} does not fit in f32"),
        ));
    }

    let reader = ChunkReader {
        array: &array,
        root,
        array_doc: &array_doc,
        version,
        dims: [dims[0] as usize, dims[1] as usize, dims[2] as usize],
        count: lay.count,
        elem_bytes: stored.size_bytes() as u64,
    };
    let data = match stored {
        StoredType::U8 => VoxelData::U8(reader.read::<u8>()?),
        StoredType::I8 => VoxelData::U8(
            reader
                .read::<i8>()?
                .into_iter()
                .map(|v| (v as u8) ^ 0x80)
                .collect(),
        ),
        StoredType::U16 => VoxelData::U16(reader.read::<u16>()?),
        StoredType::I16 => VoxelData::U16(
            reader
                .read::<i16>()?
                .into_iter()
                .map(|v| (v as u16) ^ 0x8000)
                .collect(),
        ),
        StoredType::U32 => VoxelData::F32(
            reader
                .read::<u32>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
        ),
        StoredType::I32 => VoxelData::F32(
            reader
                .read::<i32>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
        ),
        StoredType::F32 => VoxelData::F32(reader.read::<f32>()?),
        StoredType::F64 => VoxelData::F32(
            reader
                .read::<f64>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
        ),
    };
    let mut meta = VolumeMeta::plain(FileFormat::Zarr, stored, big_endian);
    meta.origin = origin;
    Ok(LoadedVolume {
        volume: Volume::new(lay.dims, spacing_f32, data)?,
        meta,
    })
}

/// Reads a metadata document of at most [`MAX_HEADER_BYTES`].
fn read_metadata(path: &Path) -> Result<Vec<u8>, VolumeError> {
    let (bytes, len) = read_prefix(path, MAX_HEADER_BYTES)?;
    if len > MAX_HEADER_BYTES {
        return Err(format_err(
            path,
            "json",
            format!("the metadata is {len} bytes; at most {MAX_HEADER_BYTES} are read"),
        ));
    }
    Ok(bytes)
}

/// True when the array metadata declares big-endian values (v2 `dtype` starting with `>`, v3
/// a `bytes` codec with `"endian": "big"`). Only reported in [`VolumeMeta`]; `zarrs` decodes.
fn declared_big_endian(text: &[u8], version: ZarrVersion) -> bool {
    let Ok(Value::Object(doc)) = serde_json::from_slice::<Value>(text) else {
        return false;
    };
    match version {
        ZarrVersion::V2 => doc
            .get("dtype")
            .and_then(Value::as_str)
            .is_some_and(|d| d.starts_with('>')),
        ZarrVersion::V3 => doc
            .get("codecs")
            .and_then(Value::as_array)
            .is_some_and(|codecs| {
                codecs.iter().any(|c| {
                    c.get("name").and_then(Value::as_str) == Some("bytes")
                        && c.pointer("/configuration/endian").and_then(Value::as_str) == Some("big")
                })
            }),
    }
}

/// The stored type of the array's data type.
fn stored_type(
    array: &Array<FilesystemStore>,
    array_doc: &Path,
    version: ZarrVersion,
) -> Result<StoredType, VolumeError> {
    use zarrs::array::data_type::{
        Float32DataType, Float64DataType, Int16DataType, Int32DataType, Int8DataType,
        UInt16DataType, UInt32DataType, UInt8DataType,
    };
    let dt = array.data_type();
    Ok(if dt.is::<UInt8DataType>() {
        StoredType::U8
    } else if dt.is::<Int8DataType>() {
        StoredType::I8
    } else if dt.is::<UInt16DataType>() {
        StoredType::U16
    } else if dt.is::<Int16DataType>() {
        StoredType::I16
    } else if dt.is::<UInt32DataType>() {
        StoredType::U32
    } else if dt.is::<Int32DataType>() {
        StoredType::I32
    } else if dt.is::<Float32DataType>() {
        StoredType::F32
    } else if dt.is::<Float64DataType>() {
        StoredType::F64
    } else {
        return Err(format_err(
            array_doc,
            version.dtype_field(),
            format!(
                "data type {dt} is not supported (uint8, int8, uint16, int16, uint32, int32, \
                 float32, float64)"
            ),
        ));
    })
}

/// Maps `zarrs`' array-opening errors to the metadata field at fault.
fn array_create_err(array_doc: &Path, version: ZarrVersion, e: ArrayCreateError) -> VolumeError {
    let field = match &e {
        ArrayCreateError::DataTypeCreateError(_) => version.dtype_field(),
        ArrayCreateError::InvalidFillValue { .. }
        | ArrayCreateError::InvalidFillValueMetadata { .. } => "fill_value",
        ArrayCreateError::CodecsCreateError(_) => version.codecs_field(),
        ArrayCreateError::StorageTransformersCreateError(_) => "storage_transformers",
        ArrayCreateError::ChunkGridCreateError(_)
        | ArrayCreateError::InvalidChunkGridDimensionality(..)
        | ArrayCreateError::InvalidSubchunkShape(_) => version.chunks_field(),
        ArrayCreateError::ChunkKeyEncodingCreateError(_) => match version {
            ZarrVersion::V2 => "dimension_separator",
            ZarrVersion::V3 => "chunk_key_encoding",
        },
        ArrayCreateError::InvalidDimensionNames(..) => "dimension_names",
        ArrayCreateError::AdditionalFieldUnsupportedError(a) => {
            return format_err(array_doc, short(a.name()), e.to_string())
        }
        ArrayCreateError::MissingMetadata => {
            return format_err(
                array_doc,
                "path",
                "the dataset's array metadata is missing".to_string(),
            )
        }
        ArrayCreateError::StorageError(StorageError::IOError(io)) => {
            return VolumeError::Io {
                path: array_doc.to_path_buf(),
                source: std::io::Error::new(io.kind(), io.to_string()),
            }
        }
        ArrayCreateError::StorageError(StorageError::InvalidMetadata(..)) => "json",
        // Raised for the byte order of `dtype`, or for `order` / `filters` / `compressor` (the
        // codec chain; the message names the part).
        ArrayCreateError::UnsupportedZarrV2Array(m) if m.contains("endian") => "dtype",
        ArrayCreateError::UnsupportedZarrV2Array(_) => "compressor",
        ArrayCreateError::NodePathError(_) | ArrayCreateError::StorageError(_) => "path",
    };
    format_err(array_doc, field, e.to_string())
}

/// Reads an array's chunks one by one into a volume-ordered buffer.
struct ChunkReader<'a> {
    array: &'a Array<FilesystemStore>,
    root: &'a Path,
    array_doc: &'a Path,
    version: ZarrVersion,
    /// Volume x, y, z sizes (array axes reversed).
    dims: [usize; 3],
    /// Voxels in the volume (checked).
    count: usize,
    /// Bytes per stored element.
    elem_bytes: u64,
}

impl ChunkReader<'_> {
    /// The file of the chunk at `indices`.
    fn chunk_path(&self, indices: &[u64]) -> PathBuf {
        let key = self.array.chunk_key(indices);
        key.as_str()
            .split('/')
            .fold(self.root.to_path_buf(), |p, s| p.join(s))
    }

    /// Reads every chunk (bounded to the array) into a buffer of `count` values, x fastest.
    fn read<T: ElementOwned + Copy + Default>(&self) -> Result<Vec<T>, VolumeError> {
        let chunks_field = self.version.chunks_field();
        let mut out: Vec<T> = Vec::new();
        out.try_reserve_exact(self.count).map_err(|_| {
            io_err(self.array_doc)(std::io::Error::from(std::io::ErrorKind::OutOfMemory))
        })?;
        out.resize(self.count, T::default());
        let grid = self.array.chunk_grid_shape().to_vec();
        let ndim = grid.len();
        if grid.contains(&0) {
            return Ok(out);
        }
        let [nx, ny, _] = self.dims;
        let mut indices = vec![0u64; ndim];
        loop {
            let chunk_shape = self
                .array
                .chunk_shape(&indices)
                .map_err(|e| format_err(self.array_doc, chunks_field, e.to_string()))?;
            let bytes = chunk_shape
                .iter()
                .try_fold(self.elem_bytes, |acc, d| acc.checked_mul(d.get()))
                .filter(|&b| b <= MAX_CHUNK_BYTES);
            if bytes.is_none() {
                return Err(format_err(
                    self.array_doc,
                    chunks_field,
                    format!(
                        "chunk shape {:?} exceeds the {} MiB chunk size limit",
                        chunk_shape.iter().map(|d| d.get()).collect::<Vec<_>>(),
                        MAX_CHUNK_BYTES >> 20
                    ),
                ));
            }
            let bounded = self
                .array
                .chunk_subset_bounded(&indices)
                .map_err(|e| format_err(self.array_doc, chunks_field, e.to_string()))?;
            if bounded.shape().iter().all(|&s| s > 0) {
                // The whole chunk is decoded (so a chunk that does not hold its full shape is
                // an error even where the array ends inside it), then its part inside the
                // array is copied. Leading axes have size 1: their index is 0.
                let values: Vec<T> = self
                    .array
                    .retrieve_chunk::<Vec<T>>(&indices)
                    .map_err(|e| self.chunk_err(&indices, e))?;
                let full: Vec<usize> = chunk_shape.iter().map(|d| d.get() as usize).collect();
                let (fy, fx) = (full[ndim - 2], full[ndim - 1]);
                let start = bounded.start();
                let extent = bounded.shape();
                let at = |a: usize| (start[a] as usize, extent[a] as usize);
                let ((z0, cz), (y0, cy), (x0, cx)) = (at(ndim - 3), at(ndim - 2), at(ndim - 1));
                if values.len() != full.iter().product::<usize>() {
                    return Err(format_err(
                        &self.chunk_path(&indices),
                        chunks_field,
                        format!(
                            "chunk {indices:?} decoded to {} values, expected {}",
                            values.len(),
                            full.iter().product::<usize>()
                        ),
                    ));
                }
                for z in 0..cz {
                    for y in 0..cy {
                        let src = fx * (y + fy * z);
                        let dst = x0 + nx * (y0 + y + ny * (z0 + z));
                        out[dst..dst + cx].copy_from_slice(&values[src..src + cx]);
                    }
                }
            }
            // Next chunk, last axis fastest.
            let mut axis = ndim;
            loop {
                if axis == 0 {
                    return Ok(out);
                }
                axis -= 1;
                indices[axis] += 1;
                if indices[axis] < grid[axis] {
                    break;
                }
                indices[axis] = 0;
            }
        }
    }

    /// A chunk that could not be read or decoded.
    fn chunk_err(&self, indices: &[u64], e: ArrayError) -> VolumeError {
        let file = self.chunk_path(indices);
        let field = match &e {
            ArrayError::StorageError(StorageError::IOError(io)) => {
                return VolumeError::Io {
                    path: file,
                    source: std::io::Error::new(io.kind(), io.to_string()),
                }
            }
            ArrayError::CodecError(
                zarrs::array::CodecError::UnexpectedChunkDecodedSize(_)
                | zarrs::array::CodecError::InvalidNumberOfElements(_)
                | zarrs::array::CodecError::InvalidArrayShape(_)
                | zarrs::array::CodecError::ExpectedFixedLengthBytes(_),
            ) => self.version.chunks_field(),
            ArrayError::UnexpectedChunkDecodedSize(..)
            | ArrayError::InvalidBytesInputSize(..)
            | ArrayError::UnexpectedChunkDecodedShape(..) => self.version.chunks_field(),
            _ => self.version.codecs_field(),
        };
        format_err(
            &file,
            field,
            format!("chunk {indices:?} does not decode: {e}"),
        )
    }
}
