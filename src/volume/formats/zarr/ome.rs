//! The root metadata of a Zarr store: its version, and for OME-Zarr images the multiscales
//! (datasets, axes, coordinate transformations), parsed from bytes and checked field by field.

use super::*;

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
    pub(super) const fn dtype_field(self) -> &'static str {
        match self {
            ZarrVersion::V2 => "dtype",
            ZarrVersion::V3 => "data_type",
        }
    }

    /// The array metadata field naming the chunk shape.
    pub(super) const fn chunks_field(self) -> &'static str {
        match self {
            ZarrVersion::V2 => "chunks",
            ZarrVersion::V3 => "chunk_grid",
        }
    }

    /// The array metadata field naming the codecs.
    pub(super) const fn codecs_field(self) -> &'static str {
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
pub(super) fn parse_multiscale(
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
pub(super) fn parse_axes(path: &Path, list: &[Value]) -> Result<Vec<OmeAxis>, VolumeError> {
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
pub(super) fn parse_transforms(
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
pub(super) fn combine(
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
pub(super) fn check_dataset_path(p: &str) -> Result<(), String> {
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
pub(super) fn short(s: &str) -> String {
    s.chars().take(60).collect()
}
