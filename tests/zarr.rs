//! OME-Zarr loading (CPU only). Every store here is written by hand (JSON metadata and raw or
//! gzip chunk files, with std and flate2, never with zarrs): Zarr v2 (OME-Zarr 0.4 `.zattrs`) and
//! Zarr v3 (OME-Zarr 0.5 `zarr.json` with `attributes.ome`), chunk shapes that do not divide the
//! array shape, padding in edge chunks that must be ignored, missing chunks (fill value), leading
//! size-1 time / channel axes, both byte orders. Values are checked voxel by voxel; malformed
//! metadata and chunks must give `VolumeError::Format` naming the file and the field.
use flate2::write::GzEncoder;
use flate2::Compression;
use mixvol::volume::formats::zarr::{OmeAxis, MAX_CHUNK_BYTES};
use mixvol::volume::formats::{
    load_zarr_level, parse_zarr_root, ZarrRoot, ZarrVersion, I16_OFFSET, MAX_VOLUME_BYTES,
};
use mixvol::volume::{
    load_volume, load_volume_with_meta, load_zarr, FileFormat, LoadedVolume, StoredType,
    VolumeError, VoxelData,
};
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

// ---------------------------------------------------------------------------------------------
// Helpers

/// A unique temporary folder, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("mixvol-zarr-{}-{n}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

fn write_json(path: &Path, value: &Value) {
    write(
        path,
        serde_json::to_string_pretty(value).unwrap().as_bytes(),
    );
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Asserts a `VolumeError::Format` on `path` and `field`; returns the message.
fn expect_format<T: std::fmt::Debug>(
    result: Result<T, VolumeError>,
    path: &Path,
    field: &str,
) -> String {
    match result {
        Err(VolumeError::Format {
            path: p,
            field: f,
            message,
        }) => {
            assert_eq!(p, path, "wrong path in error: {message}");
            assert_eq!(f, field, "wrong field in error: {message}");
            message
        }
        other => panic!("expected a Format error on `{field}` of {path:?}, got {other:?}"),
    }
}

/// Element types written by the tests.
#[derive(Copy, Clone, Debug, PartialEq)]
enum Dtype {
    U8,
    I8,
    U16,
    I16,
    F32,
}

impl Dtype {
    fn size(self) -> usize {
        match self {
            Dtype::U8 | Dtype::I8 => 1,
            Dtype::U16 | Dtype::I16 => 2,
            Dtype::F32 => 4,
        }
    }

    fn v2(self, big: bool) -> String {
        let order = if self.size() == 1 {
            '|'
        } else if big {
            '>'
        } else {
            '<'
        };
        let code = match self {
            Dtype::U8 => "u1",
            Dtype::I8 => "i1",
            Dtype::U16 => "u2",
            Dtype::I16 => "i2",
            Dtype::F32 => "f4",
        };
        format!("{order}{code}")
    }

    fn v3(self) -> &'static str {
        match self {
            Dtype::U8 => "uint8",
            Dtype::I8 => "int8",
            Dtype::U16 => "uint16",
            Dtype::I16 => "int16",
            Dtype::F32 => "float32",
        }
    }

    fn fill_json(self, v: f64) -> Value {
        match self {
            Dtype::F32 => json!(v),
            _ => json!(v as i64),
        }
    }

    /// The bytes of one element of value `v`.
    fn encode(self, v: f64, big: bool, out: &mut Vec<u8>) {
        macro_rules! put {
            ($x:expr) => {
                if big {
                    out.extend_from_slice(&$x.to_be_bytes())
                } else {
                    out.extend_from_slice(&$x.to_le_bytes())
                }
            };
        }
        match self {
            Dtype::U8 => put!(v as u8),
            Dtype::I8 => put!(v as i8),
            Dtype::U16 => put!(v as u16),
            Dtype::I16 => put!(v as i16),
            Dtype::F32 => put!(v as f32),
        }
    }
}

/// A hand-written Zarr array.
#[derive(Clone)]
struct ArraySpec {
    shape: Vec<u64>,
    chunks: Vec<u64>,
    dtype: Dtype,
    big_endian: bool,
    gzip: bool,
    separator: &'static str,
    fill: f64,
    /// Chunks not written (read back as `fill`).
    missing: Vec<Vec<u64>>,
}

impl ArraySpec {
    fn new(shape: &[u64], chunks: &[u64], dtype: Dtype) -> Self {
        Self {
            shape: shape.to_vec(),
            chunks: chunks.to_vec(),
            dtype,
            big_endian: false,
            gzip: false,
            separator: ".",
            fill: 0.0,
            missing: Vec::new(),
        }
    }

    fn grid(&self) -> Vec<u64> {
        self.shape
            .iter()
            .zip(&self.chunks)
            .map(|(s, c)| s.div_ceil(*c))
            .collect()
    }

    /// Every chunk index of the grid, last axis fastest.
    fn chunk_indices(&self) -> Vec<Vec<u64>> {
        let grid = self.grid();
        let mut all = vec![vec![]];
        for &g in &grid {
            all = all
                .into_iter()
                .flat_map(|p: Vec<u64>| {
                    (0..g).map(move |i| {
                        let mut q = p.clone();
                        q.push(i);
                        q
                    })
                })
                .collect();
        }
        all
    }

    /// The bytes of chunk `idx`: the full chunk shape in C order; elements outside the array
    /// are padding (`PAD`), which a reader must ignore.
    fn chunk_bytes(&self, idx: &[u64], value: &dyn Fn(&[u64]) -> f64) -> Vec<u8> {
        const PAD: f64 = 99.0;
        let n: u64 = self.chunks.iter().product();
        let mut out = Vec::new();
        for linear in 0..n {
            let mut rest = linear;
            let mut global = vec![0u64; self.chunks.len()];
            for a in (0..self.chunks.len()).rev() {
                global[a] = idx[a] * self.chunks[a] + rest % self.chunks[a];
                rest /= self.chunks[a];
            }
            let inside = global.iter().zip(&self.shape).all(|(g, s)| g < s);
            let v = if inside { value(&global) } else { PAD };
            self.dtype.encode(v, self.big_endian, &mut out);
        }
        if self.gzip {
            gzip(&out)
        } else {
            out
        }
    }

    fn key(&self, idx: &[u64]) -> String {
        idx.iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(self.separator)
    }

    /// Writes a Zarr v2 array (`.zarray` + chunk files) into `dir`.
    fn write_v2(&self, dir: &Path, value: &dyn Fn(&[u64]) -> f64) {
        let compressor = if self.gzip {
            json!({"id": "gzip", "level": 1})
        } else {
            Value::Null
        };
        write_json(
            &dir.join(".zarray"),
            &json!({
                "zarr_format": 2,
                "shape": self.shape,
                "chunks": self.chunks,
                "dtype": self.dtype.v2(self.big_endian),
                "compressor": compressor,
                "fill_value": self.dtype.fill_json(self.fill),
                "order": "C",
                "filters": null,
                "dimension_separator": self.separator,
            }),
        );
        for idx in self.chunk_indices() {
            if !self.missing.contains(&idx) {
                let key = self.key(&idx);
                write(&dir.join(key), &self.chunk_bytes(&idx, value));
            }
        }
    }

    /// Writes a Zarr v3 array (`zarr.json` + chunk files, default key encoding) into `dir`.
    fn write_v3(&self, dir: &Path, value: &dyn Fn(&[u64]) -> f64) {
        let mut codecs = vec![json!({
            "name": "bytes",
            "configuration": {"endian": if self.big_endian { "big" } else { "little" }}
        })];
        if self.gzip {
            codecs.push(json!({"name": "gzip", "configuration": {"level": 1}}));
        }
        write_json(
            &dir.join("zarr.json"),
            &json!({
                "zarr_format": 3,
                "node_type": "array",
                "shape": self.shape,
                "data_type": self.dtype.v3(),
                "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": self.chunks}},
                "chunk_key_encoding": {"name": "default", "configuration": {"separator": self.separator}},
                "fill_value": self.dtype.fill_json(self.fill),
                "codecs": codecs,
                "attributes": {},
            }),
        );
        for idx in self.chunk_indices() {
            if !self.missing.contains(&idx) {
                let key = format!("c{}{}", self.separator, self.key(&idx));
                write(&dir.join(key), &self.chunk_bytes(&idx, value));
            }
        }
    }
}

/// OME-Zarr 0.4 axes objects for the given names (z, y, x spatial; t time; c channel).
fn axes(names: &[&str]) -> Value {
    Value::Array(
        names
            .iter()
            .map(|&n| {
                let kind = match n {
                    "t" => "time",
                    "c" => "channel",
                    _ => "space",
                };
                json!({"name": n, "type": kind, "unit": if kind == "space" { Some("micrometer") } else { None }})
            })
            .collect(),
    )
}

fn dataset(path: &str, scale: &[f64]) -> Value {
    json!({"path": path, "coordinateTransformations": [{"type": "scale", "scale": scale}]})
}

/// A Zarr v2 OME-Zarr 0.4 group: `.zgroup` and `.zattrs` holding `multiscale`.
fn write_v2_group(root: &Path, multiscale: Value) {
    write_json(&root.join(".zgroup"), &json!({"zarr_format": 2}));
    write_json(
        &root.join(".zattrs"),
        &json!({ "multiscales": [multiscale] }),
    );
}

/// A Zarr v3 OME-Zarr 0.5 group: `zarr.json` with `attributes.ome.multiscales`.
fn write_v3_group(root: &Path, multiscale: Value) {
    write_json(
        &root.join("zarr.json"),
        &json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": {"ome": {"version": "0.5", "multiscales": [multiscale]}},
        }),
    );
}

/// The raw volume value the loader must produce for a stored value `v` (see the value mapping
/// in `mixvol::volume::formats`).
fn expected_raw(dtype: Dtype, v: f64) -> f64 {
    match dtype {
        Dtype::I8 => v + 128.0,
        Dtype::I16 => v + f64::from(I16_OFFSET),
        _ => v,
    }
}

/// Checks every voxel of `loaded` against `value(z, y, x)` (stored values).
fn check_voxels(loaded: &LoadedVolume, dtype: Dtype, value: &dyn Fn(u64, u64, u64) -> f64) {
    let v = &loaded.volume;
    let d = v.dims();
    let mut checked = 0;
    for z in 0..d.z {
        for y in 0..d.y {
            for x in 0..d.x {
                let i = v.index(x, y, z);
                let got = match v.data() {
                    VoxelData::U8(a) => f64::from(a[i]),
                    VoxelData::U16(a) => f64::from(a[i]),
                    VoxelData::F32(a) => f64::from(a[i]),
                };
                let want = expected_raw(dtype, value(u64::from(z), u64::from(y), u64::from(x)));
                assert_eq!(got, want, "voxel x={x} y={y} z={z}");
                checked += 1;
            }
        }
    }
    assert_eq!(checked, d.x as usize * d.y as usize * d.z as usize);
}

/// A field with distinct values per voxel that fits u8 / i8 (wrapping into the type's range).
fn small_field(z: u64, y: u64, x: u64) -> f64 {
    ((x * 7 + y * 13 + z * 29) % 200) as f64
}

// ---------------------------------------------------------------------------------------------
// Loading

#[test]
fn v2_ome_0_4_u8_raw_chunks_not_dividing_the_shape() {
    let dir = TempDir::new("v2-u8");
    let root = dir.join("image.ome.zarr");
    let spec = ArraySpec::new(&[5, 7, 9], &[2, 3, 4], Dtype::U8);
    let value = |i: &[u64]| small_field(i[0], i[1], i[2]);
    spec.write_v2(&root.join("0"), &value);
    write_v2_group(
        &root,
        json!({
            "version": "0.4",
            "axes": axes(&["z", "y", "x"]),
            "datasets": [dataset("0", &[2.0, 0.5, 0.25])],
        }),
    );
    let loaded = load_volume_with_meta(&root).unwrap();
    assert_eq!(loaded.volume.dims().to_array(), [9, 7, 5]);
    assert_eq!(loaded.volume.spacing().to_array(), [0.25, 0.5, 2.0]);
    assert_eq!(loaded.meta.format, FileFormat::Zarr);
    assert_eq!(loaded.meta.stored, StoredType::U8);
    assert!(!loaded.meta.big_endian);
    assert_eq!(loaded.meta.origin, [0.0; 3]);
    check_voxels(&loaded, Dtype::U8, &small_field);
    // The same through load_volume and load_zarr.
    assert_eq!(load_volume(&root).unwrap(), loaded.volume);
    assert_eq!(load_zarr(&root).unwrap(), loaded);
}

#[test]
fn v2_big_endian_i16_gzip_with_channel_axis_and_levels() {
    let dir = TempDir::new("v2-i16");
    let root = dir.join("ct.zarr");
    let hu = |z: u64, y: u64, x: u64| -1000.0 + (x * 37 + y * 101 + z * 411) as f64;
    let mut level0 = ArraySpec::new(&[1, 6, 11, 10], &[1, 4, 5, 3], Dtype::I16);
    level0.big_endian = true;
    level0.gzip = true;
    level0.separator = "/";
    level0.write_v2(&root.join("s0"), &|i| hu(i[1], i[2], i[3]));
    let half = |z: u64, y: u64, x: u64| -(z as f64) * 100.0 - (y * 10 + x) as f64;
    let mut level1 = ArraySpec::new(&[1, 3, 6, 5], &[1, 2, 4, 4], Dtype::I16);
    level1.gzip = true;
    level1.write_v2(&root.join("s1"), &|i| half(i[1], i[2], i[3]));
    write_v2_group(
        &root,
        json!({
            "version": "0.4",
            "axes": axes(&["c", "z", "y", "x"]),
            "datasets": [
                dataset("s0", &[1.0, 1.5, 0.5, 0.5]),
                {"path": "s1", "coordinateTransformations": [
                    {"type": "scale", "scale": [1.0, 3.0, 1.0, 1.0]},
                    {"type": "translation", "translation": [0.0, 0.75, 0.25, 0.25]},
                ]},
            ],
            // Applied after the datasets' own transformations.
            "coordinateTransformations": [
                {"type": "scale", "scale": [1.0, 2.0, 2.0, 2.0]},
                {"type": "translation", "translation": [0.0, 10.0, 20.0, 30.0]},
            ],
        }),
    );
    let l0 = load_volume_with_meta(&root).unwrap();
    assert_eq!(l0.volume.dims().to_array(), [10, 11, 6]);
    assert_eq!(l0.volume.spacing().to_array(), [1.0, 1.0, 3.0]);
    assert_eq!(l0.meta.origin, [30.0, 20.0, 10.0]);
    assert_eq!(l0.meta.stored, StoredType::I16);
    assert!(l0.meta.big_endian);
    check_voxels(&l0, Dtype::I16, &hu);
    // -1000 HU through VolumeMeta::normalized, like the other i16 formats.
    assert_eq!(
        l0.meta.normalized(-1000.0),
        (32768.0 - 1000.0) / 65535.0_f32
    );

    let l1 = load_zarr_level(&root, 1).unwrap();
    assert_eq!(l1.volume.dims().to_array(), [5, 6, 3]);
    assert_eq!(l1.volume.spacing().to_array(), [2.0, 2.0, 6.0]);
    assert_eq!(l1.meta.origin, [30.5, 20.5, 11.5]);
    check_voxels(&l1, Dtype::I16, &half);

    let group = root.join(".zattrs");
    let msg = expect_format(load_zarr_level(&root, 2), &group, "datasets");
    assert!(msg.contains("2 levels"), "{msg}");
}

#[test]
fn v3_ome_0_5_u16_gzip_tczyx_missing_chunks_read_as_fill() {
    let dir = TempDir::new("v3-u16");
    let root = dir.join("cells.ome.zarr");
    let value = |z: u64, y: u64, x: u64| (x * 1000 + y * 100 + z * 7 + 1) as f64;
    let mut spec = ArraySpec::new(&[1, 1, 7, 5, 13], &[1, 1, 3, 2, 5], Dtype::U16);
    spec.gzip = true;
    spec.separator = "/";
    spec.fill = 4242.0;
    spec.missing = vec![vec![0, 0, 1, 1, 2], vec![0, 0, 2, 0, 0]];
    spec.write_v3(&root.join("0"), &|i| value(i[2], i[3], i[4]));
    write_v3_group(
        &root,
        json!({
            "axes": axes(&["t", "c", "z", "y", "x"]),
            "datasets": [{"path": "0", "coordinateTransformations": [
                {"type": "scale", "scale": [1.0, 1.0, 0.3, 0.2, 0.1]},
                {"type": "translation", "translation": [0.0, 0.0, -1.0, -2.0, -3.0]},
            ]}],
        }),
    );
    let loaded = load_volume_with_meta(&root).unwrap();
    assert_eq!(loaded.volume.dims().to_array(), [13, 5, 7]);
    assert_eq!(
        loaded.volume.spacing().to_array(),
        [0.1f64 as f32, 0.2f64 as f32, 0.3f64 as f32]
    );
    assert_eq!(loaded.meta.origin, [-3.0, -2.0, -1.0]);
    assert_eq!(loaded.meta.stored, StoredType::U16);
    let in_missing = |z: u64, y: u64, x: u64| {
        spec.missing
            .iter()
            .any(|c| c[2] == z / 3 && c[3] == y / 2 && c[4] == x / 5)
    };
    check_voxels(&loaded, Dtype::U16, &|z, y, x| {
        if in_missing(z, y, x) {
            4242.0
        } else {
            value(z, y, x)
        }
    });
}

#[test]
fn v3_big_endian_f32_raw_and_i8_and_plain_arrays() {
    let dir = TempDir::new("v3-f32");
    let root = dir.join("sim.zarr");
    let value = |z: u64, y: u64, x: u64| (x as f64 - 2.5) * 0.25 + y as f64 * 1e3 - z as f64;
    let mut spec = ArraySpec::new(&[4, 3, 6], &[3, 3, 4], Dtype::F32);
    spec.big_endian = true;
    spec.write_v3(&root.join("lvl/0"), &|i| value(i[0], i[1], i[2]));
    write_v3_group(
        &root,
        json!({
            "axes": axes(&["z", "y", "x"]),
            "datasets": [dataset("lvl/0", &[1.0, 1.0, 1.0])],
        }),
    );
    let loaded = load_volume_with_meta(&root).unwrap();
    assert!(loaded.meta.big_endian);
    assert_eq!(loaded.meta.stored, StoredType::F32);
    check_voxels(&loaded, Dtype::F32, &value);

    // A plain v3 array at the root (no OME metadata): unit spacing, last three axes z, y, x.
    let plain = dir.join("plain.zarr");
    let i8_spec = ArraySpec::new(&[3, 4, 5], &[2, 2, 2], Dtype::I8);
    let signed = |z: u64, y: u64, x: u64| small_field(z, y, x) - 100.0;
    i8_spec.write_v3(&plain, &|i| signed(i[0], i[1], i[2]));
    let loaded = load_volume_with_meta(&plain).unwrap();
    assert_eq!(loaded.volume.spacing().to_array(), [1.0; 3]);
    assert_eq!(loaded.meta.stored, StoredType::I8);
    check_voxels(&loaded, Dtype::I8, &signed);

    // A plain v2 array in a folder without the .zarr extension.
    let bare = dir.join("bare");
    let u16_spec = ArraySpec::new(&[2, 3, 3], &[2, 2, 2], Dtype::U16);
    u16_spec.write_v2(&bare, &|i| small_field(i[0], i[1], i[2]) * 300.0);
    let loaded = load_volume_with_meta(&bare).unwrap();
    check_voxels(&loaded, Dtype::U16, &|z, y, x| small_field(z, y, x) * 300.0);
}

#[test]
fn parse_zarr_root_reports_versions_axes_and_combined_transforms() {
    let p = Path::new("zarr.json");
    let doc = json!({
        "zarr_format": 3, "node_type": "group",
        "attributes": {"ome": {"version": "0.5", "multiscales": [{
            "axes": ["z", "y", "x"],
            "datasets": [
                {"path": "0", "coordinateTransformations": [{"type": "identity"}]},
                dataset("1", &[2.0, 2.0, 2.0]),
            ],
            "coordinateTransformations": [{"type": "scale", "scale": [0.5, 0.5, 0.5]}],
        }]}},
    });
    let ZarrRoot::Multiscales(m) =
        parse_zarr_root(p, doc.to_string().as_bytes(), ZarrVersion::V3).unwrap()
    else {
        panic!("expected multiscales");
    };
    assert_eq!(m.version.as_deref(), Some("0.5"));
    assert_eq!(
        m.axes[0],
        OmeAxis {
            name: "z".into(),
            kind: None
        }
    );
    assert_eq!(m.datasets[0].scale, vec![0.5; 3]);
    assert_eq!(m.datasets[1].scale, vec![1.0; 3]);
    assert_eq!(m.datasets[1].translation, vec![0.0; 3]);
    assert_eq!(
        FileFormat::from_path(Path::new("a/Image.OME.ZARR")),
        Some(FileFormat::Zarr)
    );
    assert_eq!(
        FileFormat::from_path(Path::new("b.zarr/")),
        Some(FileFormat::Zarr)
    );
    let array = json!({"zarr_format": 3, "node_type": "array"});
    assert_eq!(
        parse_zarr_root(p, array.to_string().as_bytes(), ZarrVersion::V3).unwrap(),
        ZarrRoot::Array
    );
}

// ---------------------------------------------------------------------------------------------
// Errors

/// A valid small v2 image whose `.zattrs` is then replaced by `multiscale`.
fn v2_image(dir: &TempDir, name: &str, multiscale: Value) -> PathBuf {
    let root = dir.join(name);
    ArraySpec::new(&[3, 3, 3], &[2, 2, 2], Dtype::U8).write_v2(&root.join("0"), &|_| 1.0);
    write_v2_group(&root, multiscale);
    root
}

fn good_multiscale() -> Value {
    json!({"version": "0.4", "axes": axes(&["z", "y", "x"]), "datasets": [dataset("0", &[1.0, 1.0, 1.0])]})
}

#[test]
fn bad_group_metadata_names_the_field() {
    let dir = TempDir::new("bad-group");
    // Sanity: the template loads.
    load_zarr(&v2_image(&dir, "ok.zarr", good_multiscale())).unwrap();

    let with = |key: &str, value: Value| {
        let mut m = good_multiscale();
        m[key] = value;
        m
    };
    let cases: Vec<(&str, Value, &str)> = vec![
        ("axes-2", with("axes", axes(&["y", "x"])), "axes"),
        (
            "axes-6",
            with("axes", axes(&["t", "c", "q", "z", "y", "x"])),
            "axes",
        ),
        (
            "axes-order",
            with("axes", axes(&["z", "c", "y", "x"])),
            "axes",
        ),
        ("axes-dup", with("axes", axes(&["z", "z", "x"])), "axes"),
        (
            "axes-type",
            with(
                "axes",
                json!([{"name": "z"}, {"name": "y", "type": 3}, {"name": "x"}]),
            ),
            "axes",
        ),
        // 4 axes but the array has 3 dimensions ("wrong dims").
        (
            "axes-vs-array",
            json!({"axes": axes(&["c", "z", "y", "x"]), "datasets": [dataset("0", &[1.0; 4])]}),
            "axes",
        ),
        ("no-datasets", with("datasets", json!([])), "datasets"),
        (
            "datasets-type",
            with("datasets", json!({"path": "0"})),
            "datasets",
        ),
        (
            "path-dotdot",
            with("datasets", json!([{"path": "../0"}])),
            "path",
        ),
        (
            "path-abs",
            with("datasets", json!([{"path": "/0"}])),
            "path",
        ),
        (
            "path-missing",
            with("datasets", json!([{"coordinateTransformations": []}])),
            "path",
        ),
        (
            "scale-negative",
            with("datasets", json!([dataset("0", &[1.0, -1.0, 1.0])])),
            "coordinateTransformations",
        ),
        (
            "scale-zero",
            with("datasets", json!([dataset("0", &[1.0, 0.0, 1.0])])),
            "coordinateTransformations",
        ),
        (
            "scale-length",
            with("datasets", json!([dataset("0", &[1.0, 1.0])])),
            "coordinateTransformations",
        ),
        (
            "scale-huge",
            with("datasets", json!([dataset("0", &[1.0, 1e300, 1.0])])),
            "coordinateTransformations",
        ),
        (
            "scale-path",
            with(
                "datasets",
                json!([{"path": "0", "coordinateTransformations": [{"type": "scale", "path": "s.bin"}]}]),
            ),
            "coordinateTransformations",
        ),
        (
            "transform-kind",
            with(
                "datasets",
                json!([{"path": "0", "coordinateTransformations": [{"type": "affine"}]}]),
            ),
            "coordinateTransformations",
        ),
        (
            "translation-first",
            with(
                "datasets",
                json!([{"path": "0", "coordinateTransformations": [
            {"type": "translation", "translation": [0.0, 0.0, 0.0]}, {"type": "scale", "scale": [1.0, 1.0, 1.0]}]}]),
            ),
            "coordinateTransformations",
        ),
    ];
    for (name, multiscale, field) in cases {
        let root = v2_image(&dir, &format!("{name}.zarr"), multiscale);
        let msg = expect_format(load_zarr(&root), &root.join(".zattrs"), field);
        eprintln!("{name}: {msg}");
    }

    // Missing multiscales: v2 .zattrs without it, a v2 group without .zattrs, a v3 group
    // without "ome", an empty list.
    let root = dir.join("no-ms.zarr");
    ArraySpec::new(&[3, 3, 3], &[2, 2, 2], Dtype::U8).write_v2(&root.join("0"), &|_| 1.0);
    write_json(&root.join(".zattrs"), &json!({"omero": {}}));
    expect_format(load_zarr(&root), &root.join(".zattrs"), "multiscales");
    std::fs::remove_file(root.join(".zattrs")).unwrap();
    write_json(&root.join(".zgroup"), &json!({"zarr_format": 2}));
    expect_format(load_zarr(&root), &root.join(".zattrs"), "multiscales");
    write_json(&root.join(".zattrs"), &json!({"multiscales": []}));
    expect_format(load_zarr(&root), &root.join(".zattrs"), "multiscales");
    let v3 = dir.join("no-ms-v3.zarr");
    write_json(
        &v3.join("zarr.json"),
        &json!({"zarr_format": 3, "node_type": "group", "attributes": {"other": 1}}),
    );
    expect_format(load_zarr(&v3), &v3.join("zarr.json"), "multiscales");
    write_json(
        &v3.join("zarr.json"),
        &json!({"zarr_format": 2, "node_type": "group"}),
    );
    expect_format(load_zarr(&v3), &v3.join("zarr.json"), "zarr_format");
    write_json(
        &v3.join("zarr.json"),
        &json!({"zarr_format": 3, "node_type": "tree"}),
    );
    expect_format(load_zarr(&v3), &v3.join("zarr.json"), "node_type");
    write(&v3.join("zarr.json"), b"{\"zarr_format\": 3,");
    expect_format(load_zarr(&v3), &v3.join("zarr.json"), "json");

    // Not a store at all.
    let empty = dir.join("empty.zarr");
    std::fs::create_dir_all(&empty).unwrap();
    expect_format(load_zarr(&empty), &empty, "zarr_format");
    // A missing dataset folder.
    let root = v2_image(
        &dir,
        "gone.zarr",
        with("datasets", json!([dataset("1", &[1.0; 3])])),
    );
    assert!(matches!(
        load_zarr(&root),
        Err(VolumeError::Io { .. } | VolumeError::Format { .. })
    ));
}

#[test]
fn bad_array_metadata_names_the_field() {
    let dir = TempDir::new("bad-array");
    let image = |name: &str, spec: &ArraySpec, v3: bool, axis_names: &[&str]| {
        let root = dir.join(name);
        let ms = json!({"axes": axes(axis_names), "datasets": [{"path": "0"}]});
        if v3 {
            spec.write_v3(&root.join("0"), &|_| 1.0);
            write_v3_group(&root, ms);
        } else {
            spec.write_v2(&root.join("0"), &|_| 1.0);
            write_v2_group(&root, ms);
        }
        root
    };
    let edit = |path: &Path, f: &dyn Fn(&mut Value)| {
        let mut doc: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
        f(&mut doc);
        write_json(path, &doc);
    };
    let zyx = ["z", "y", "x"];

    // Bad data types.
    for (v3, field, bad, fill) in [
        (false, "dtype", json!("<c8"), json!([0.0, 0.0])),
        (false, "dtype", json!("|b1"), json!(false)),
        (false, "dtype", json!("<x9"), json!(0)),
        (true, "data_type", json!("bool"), json!(false)),
        (true, "data_type", json!("complex64"), json!([0.0, 0.0])),
        (true, "data_type", json!("no-such-type"), json!(0)),
    ] {
        let root = image(
            &format!(
                "dtype-{v3}-{}.zarr",
                bad.as_str().unwrap().replace(['<', '|'], "")
            ),
            &ArraySpec::new(&[2, 2, 2], &[2, 2, 2], Dtype::U8),
            v3,
            &zyx,
        );
        let doc = root
            .join("0")
            .join(if v3 { "zarr.json" } else { ".zarray" });
        edit(&doc, &|d| {
            d[field] = bad.clone();
            d["fill_value"] = fill.clone();
        });
        let msg = expect_format(load_zarr(&root), &doc, field);
        eprintln!("{bad}: {msg}");
    }

    // A leading axis of size 3 (three channels): wrong dims for a volume.
    let root = image(
        "channels.zarr",
        &ArraySpec::new(&[3, 2, 2, 2], &[1, 2, 2, 2], Dtype::U8),
        false,
        &["c", "z", "y", "x"],
    );
    let msg = expect_format(load_zarr(&root), &root.join("0/.zarray"), "shape");
    assert!(msg.contains("size 3"), "{msg}");
    // A 2D plain array and a 6D plain array.
    for shape in [vec![4u64, 4], vec![1, 1, 1, 2, 2, 2]] {
        let root = dir.join(&format!("plain-{}d.zarr", shape.len()));
        ArraySpec::new(&shape, &shape, Dtype::U8).write_v3(&root, &|_| 1.0);
        expect_format(load_zarr(&root), &root.join("zarr.json"), "shape");
    }
    // A volume beyond the size limit (nothing is allocated; the chunks are missing anyway).
    let root = image(
        "huge.zarr",
        &ArraySpec::new(&[2, 2, 2], &[2, 2, 2], Dtype::U16),
        true,
        &zyx,
    );
    let doc = root.join("0/zarr.json");
    let side = ((MAX_VOLUME_BYTES / 2) as f64).cbrt() as u64 + 2;
    edit(&doc, &|d| d["shape"] = json!([side, side, side]));
    let msg = expect_format(load_zarr(&root), &doc, "shape");
    assert!(msg.contains("limit"), "{msg}");
    // A chunk beyond the chunk size limit.
    let root = image(
        "bigchunk.zarr",
        &ArraySpec::new(&[2, 2, 2], &[2, 2, 2], Dtype::U8),
        false,
        &zyx,
    );
    let doc = root.join("0/.zarray");
    let c = (MAX_CHUNK_BYTES as f64).cbrt() as u64 + 2;
    edit(&doc, &|d| d["chunks"] = json!([c, c, c]));
    let msg = expect_format(load_zarr(&root), &doc, "chunks");
    assert!(msg.contains("limit"), "{msg}");
    // Unbuilt codecs: bz2 (v2) and numcodecs.bz2 (v3). (Blosc and zstd are built: see
    // tests/zarr_python.rs.)
    let root = image(
        "bz2.zarr",
        &ArraySpec::new(&[2, 2, 2], &[2, 2, 2], Dtype::U8),
        false,
        &zyx,
    );
    let doc = root.join("0/.zarray");
    edit(&doc, &|d| {
        d["compressor"] = json!({"id": "bz2", "level": 1})
    });
    expect_format(load_zarr(&root), &doc, "compressor");
    let root = image(
        "v3-bz2.zarr",
        &ArraySpec::new(&[2, 2, 2], &[2, 2, 2], Dtype::U8),
        true,
        &zyx,
    );
    let doc = root.join("0/zarr.json");
    edit(&doc, &|d| {
        d["codecs"]
            .as_array_mut()
            .unwrap()
            .push(json!({"name": "numcodecs.bz2", "configuration": {"level": 1}}))
    });
    expect_format(load_zarr(&root), &doc, "codecs");
}

#[test]
fn truncated_and_corrupt_chunks_name_the_chunk_file() {
    let dir = TempDir::new("bad-chunk");
    let zyx = ["z", "y", "x"];
    for v3 in [false, true] {
        for gzip in [false, true] {
            let root = dir.join(&format!("trunc-{v3}-{gzip}.zarr"));
            let mut spec = ArraySpec::new(&[4, 5, 6], &[3, 3, 4], Dtype::U16);
            spec.gzip = gzip;
            let ms = json!({"axes": axes(&zyx), "datasets": [{"path": "0"}]});
            let (chunk, chunks_field, codecs_field) = if v3 {
                spec.write_v3(&root.join("0"), &|i| (i[0] + i[1] + i[2]) as f64);
                write_v3_group(&root, ms);
                (root.join("0/c.1.0.1"), "chunk_grid", "codecs")
            } else {
                spec.write_v2(&root.join("0"), &|i| (i[0] + i[1] + i[2]) as f64);
                write_v2_group(&root, ms);
                (root.join("0/1.0.1"), "chunks", "compressor")
            };
            let intact = load_zarr(&root).unwrap().volume;
            let bytes = std::fs::read(&chunk).unwrap();
            // Truncated: raw chunks no longer hold the chunk shape; gzip streams end early.
            write(&chunk, &bytes[..bytes.len() - 7]);
            let field = if gzip { codecs_field } else { chunks_field };
            let msg = expect_format(load_zarr(&root), &chunk, field);
            assert!(msg.contains("[1, 0, 1]"), "{msg}");
            eprintln!("v3 {v3} gzip {gzip} truncated: {msg}");
            // Too long. A raw chunk then holds more than its shape: refused. A gzip stream is
            // complete before the 8 zero bytes, which are ignored (as Python's gzip module, and so
            // numcodecs, ignores zero padding after the last member): the volume loads with
            // exactly the intact chunk's values.
            let mut long = bytes.clone();
            long.extend_from_slice(&[0; 8]);
            write(&chunk, &long);
            if gzip {
                let padded = load_zarr(&root)
                    .unwrap_or_else(|e| panic!("v3 {v3}: zero padding after gzip refused: {e}"))
                    .volume;
                assert_eq!(padded.dims(), intact.dims(), "v3 {v3}");
                assert_eq!(
                    padded.data(),
                    intact.data(),
                    "v3 {v3}: zero padding after the gzip stream changed the voxels"
                );
            } else {
                expect_format(load_zarr(&root), &chunk, chunks_field);
            }
            // Garbage instead of gzip.
            if gzip {
                write(&chunk, &vec![0x55; bytes.len()]);
                expect_format(load_zarr(&root), &chunk, codecs_field);
            }
        }
    }
}

/// CRC-32C (Castagnoli), as the `crc32c` codec appends it (little-endian).
fn crc32c(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[test]
fn v3_sharded_gzip_inner_chunks_with_crc32c_index() {
    let dir = TempDir::new("v3-shard");
    let root = dir.join("sharded.ome.zarr");
    let shape = [5u64, 7, 9];
    let shard = [4u64, 4, 6];
    let inner = [2u64, 2, 3];
    let value = |z: u64, y: u64, x: u64| (z * 5000 + y * 300 + x * 7) as f64;
    let array = root.join("0");
    write_json(
        &array.join("zarr.json"),
        &json!({
            "zarr_format": 3,
            "node_type": "array",
            "shape": shape,
            "data_type": "uint16",
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": shard}},
            "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
            "fill_value": 0,
            "codecs": [{"name": "sharding_indexed", "configuration": {
                "chunk_shape": inner,
                "codecs": [
                    {"name": "bytes", "configuration": {"endian": "little"}},
                    {"name": "gzip", "configuration": {"level": 1}},
                ],
                "index_codecs": [
                    {"name": "bytes", "configuration": {"endian": "little"}},
                    {"name": "crc32c"},
                ],
                "index_location": "end",
            }}],
        }),
    );
    let per_shard: Vec<u64> = shard.iter().zip(&inner).map(|(s, i)| s / i).collect();
    for sz in 0..shape[0].div_ceil(shard[0]) {
        for sy in 0..shape[1].div_ceil(shard[1]) {
            for sx in 0..shape[2].div_ceil(shard[2]) {
                let mut data = Vec::new();
                let mut index = Vec::new();
                for iz in 0..per_shard[0] {
                    for iy in 0..per_shard[1] {
                        for ix in 0..per_shard[2] {
                            let origin = [
                                sz * shard[0] + iz * inner[0],
                                sy * shard[1] + iy * inner[1],
                                sx * shard[2] + ix * inner[2],
                            ];
                            if origin.iter().zip(&shape).any(|(o, s)| o >= s) {
                                // Entirely outside the array: an empty inner chunk.
                                index.extend_from_slice(&u64::MAX.to_le_bytes());
                                index.extend_from_slice(&u64::MAX.to_le_bytes());
                                continue;
                            }
                            let mut raw = Vec::new();
                            for z in 0..inner[0] {
                                for y in 0..inner[1] {
                                    for x in 0..inner[2] {
                                        let p = [origin[0] + z, origin[1] + y, origin[2] + x];
                                        let inside = p.iter().zip(&shape).all(|(a, s)| a < s);
                                        let v = if inside { value(p[0], p[1], p[2]) } else { 7.0 };
                                        raw.extend_from_slice(&(v as u16).to_le_bytes());
                                    }
                                }
                            }
                            let encoded = gzip(&raw);
                            index.extend_from_slice(&(data.len() as u64).to_le_bytes());
                            index.extend_from_slice(&(encoded.len() as u64).to_le_bytes());
                            data.extend_from_slice(&encoded);
                        }
                    }
                }
                let crc = crc32c(&index);
                data.extend_from_slice(&index);
                data.extend_from_slice(&crc.to_le_bytes());
                write(&array.join(format!("c/{sz}/{sy}/{sx}")), &data);
            }
        }
    }
    write_v3_group(
        &root,
        json!({"axes": axes(&["z", "y", "x"]), "datasets": [dataset("0", &[1.0, 1.0, 1.0])]}),
    );
    let loaded = load_zarr(&root).unwrap();
    assert_eq!(loaded.volume.dims().to_array(), [9, 7, 5]);
    check_voxels(&loaded, Dtype::U16, &value);

    // A corrupted shard index fails its checksum: an error naming the shard file.
    let shard_file = array.join("c/1/1/1");
    let mut bytes = std::fs::read(&shard_file).unwrap();
    let n = bytes.len();
    bytes[n - 6] ^= 0x40;
    write(&shard_file, &bytes);
    let msg = expect_format(load_zarr(&root), &shard_file, "codecs");
    eprintln!("corrupt shard index: {msg}");
}

/// A gzip chunk that inflates past its chunk's size (a "bomb": 64 MiB of zeros in 300 KB for a
/// chunk of 512 bytes) is refused before `zarrs` inflates it into memory, naming the chunk file
/// and the codec field, in v3 (`gzip` codec) and v2 (`gzip` compressor) arrays; the same array
/// with honest gzip chunks loads (the check inflates into nothing, never holding the data).
#[test]
fn gzip_chunks_inflating_past_their_size_are_refused_before_decoding() {
    let dir = TempDir::new("gzip-bomb");
    let value = |i: &[u64]| ((i[0] * 13 + i[1] * 8 + i[2]) % 251) as f64;
    let bomb = gzip(&vec![0u8; 64 << 20]);
    assert!(bomb.len() < 1 << 20, "{} bytes", bomb.len());
    for (version, field) in [(3, "codecs"), (2, "compressor")] {
        let root = dir.join(&format!("v{version}.zarr"));
        let mut spec = ArraySpec::new(&[16, 8, 8], &[8, 8, 8], Dtype::U8);
        spec.gzip = true;
        spec.separator = "/";
        let chunk = if version == 3 {
            spec.write_v3(&root, &value);
            root.join("c/1/0/0")
        } else {
            spec.write_v2(&root, &value);
            root.join("1/0/0")
        };
        let honest = load_volume_with_meta(&root).unwrap();
        check_voxels(&honest, Dtype::U8, &|z, y, x| value(&[z, y, x]));
        write(&chunk, &bomb);
        let message = expect_format(load_volume_with_meta(&root), &chunk, field);
        assert!(
            message.contains("inflates past the 512 bytes the chunk holds"),
            "v{version}: {message}"
        );
    }
}
