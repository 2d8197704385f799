//! Slab reading and the slab store writer (CPU only).
//!
//! Every fixture is written here by hand (headerless raw, raw + JSON sidecar, NRRD raw and gzip,
//! NIfTI-1 `.nii` and `.nii.gz`, `.den`, OME-Zarr v2 with raw and gzip chunks that do not divide
//! the shape). For each, a store written by `write_store_from_slabs` from the file must be byte
//! for byte the store `write_store_from_volume` writes from the fully loaded volume, for several
//! brick sizes, every filter and awkward dims; slabs of any size must hold the loader's voxels;
//! and failures (truncated data, a budget too small, a backwards read of a gzip stream) must be
//! typed errors that name the file and leave no store and no partial file behind.
use flate2::write::GzEncoder;
use flate2::Compression;
use glam::{UVec3, Vec3};
use mixvol::bricks::DownsampleFilter;
use mixvol::store::{
    slab_store_desc, write_level_store_from_slabs, write_store_from_slabs, write_store_from_volume,
    BrickStore, LevelStore, StoreError,
};
use mixvol::volume::{
    load_raw, load_volume_with_meta, open_raw_slabs, open_slabs, RawDescriptor, ScalarType,
    SlabMut, SlabReader, StoredType, Volume, VolumeError, VoxelData,
};
use serde_json::json;
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
            std::env::temp_dir().join(format!("mixvol-slabs-{}-{n}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&p, bytes).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// A stored value at voxel (x, y, z): smooth structure plus a hash, in the type's range.
fn value(t: StoredType, x: u64, y: u64, z: u64) -> f64 {
    let h = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663) ^ z.wrapping_mul(83_492_791))
        % 1000;
    let smooth = ((x as f64 * 0.3).sin() + (y as f64 * 0.2).cos() + z as f64 * 0.05) / 3.0;
    let unit = (0.5 + 0.4 * smooth + h as f64 * 0.0002).clamp(0.0, 1.0);
    match t {
        StoredType::U8 => (unit * 255.0).round(),
        StoredType::I8 => (unit * 255.0).round() - 128.0,
        StoredType::U16 => (unit * 65535.0).round(),
        StoredType::I16 => (unit * 65535.0).round() - 32768.0,
        StoredType::U32 => (unit * 1e6).round(),
        StoredType::I32 => (unit * 1e6).round() - 5e5,
        StoredType::F32 | StoredType::F64 => unit * 3.0 - 1.0,
    }
}

/// The voxels of `dims` of type `t` in file byte order (x fastest).
fn encode(t: StoredType, dims: [u64; 3], big: bool) -> Vec<u8> {
    let mut out = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let v = value(t, x, y, z);
                macro_rules! put {
                    ($e:expr) => {
                        if big {
                            out.extend_from_slice(&$e.to_be_bytes())
                        } else {
                            out.extend_from_slice(&$e.to_le_bytes())
                        }
                    };
                }
                match t {
                    StoredType::U8 => out.push(v as u8),
                    StoredType::I8 => out.push(v as i8 as u8),
                    StoredType::U16 => put!(v as u16),
                    StoredType::I16 => put!(v as i16),
                    StoredType::U32 => put!(v as u32),
                    StoredType::I32 => put!(v as i32),
                    StoredType::F32 => put!(v as f32),
                    StoredType::F64 => put!(v),
                }
            }
        }
    }
    out
}

const ALL_TYPES: [StoredType; 8] = [
    StoredType::U8,
    StoredType::I8,
    StoredType::U16,
    StoredType::I16,
    StoredType::U32,
    StoredType::I32,
    StoredType::F32,
    StoredType::F64,
];

fn nrrd_type(t: StoredType) -> &'static str {
    match t {
        StoredType::U8 => "uchar",
        StoredType::I8 => "signed char",
        StoredType::U16 => "unsigned short",
        StoredType::I16 => "short",
        StoredType::U32 => "uint",
        StoredType::I32 => "int",
        StoredType::F32 => "float",
        StoredType::F64 => "double",
    }
}

/// An attached NRRD file.
fn nrrd(t: StoredType, dims: [u64; 3], encoding: &str, big: bool) -> Vec<u8> {
    let mut bytes = format!(
        "NRRD0004\ntype: {}\ndimension: 3\nsizes: {} {} {}\nencoding: {encoding}\nendian: {}\n\
         spacings: 0.5 1 2.5\n\n",
        nrrd_type(t),
        dims[0],
        dims[1],
        dims[2],
        if big { "big" } else { "little" },
    )
    .into_bytes();
    let data = encode(t, dims, big);
    bytes.extend(if encoding == "gzip" {
        gzip(&data)
    } else {
        data
    });
    bytes
}

/// A NIfTI-1 single file: 348-byte header, 4 extension bytes, the voxels.
fn nifti(t: StoredType, dims: [u64; 3], big: bool) -> Vec<u8> {
    let (datatype, bits): (i16, i16) = match t {
        StoredType::U8 => (2, 8),
        StoredType::I16 => (4, 16),
        StoredType::I32 => (8, 32),
        StoredType::F32 => (16, 32),
        StoredType::F64 => (64, 64),
        StoredType::I8 => (256, 8),
        StoredType::U16 => (512, 16),
        StoredType::U32 => (768, 32),
    };
    let mut h = vec![0u8; 352];
    let mut put = |at: usize, bytes: &[u8]| h[at..at + bytes.len()].copy_from_slice(bytes);
    macro_rules! num {
        ($x:expr) => {
            if big {
                $x.to_be_bytes()
            } else {
                $x.to_le_bytes()
            }
        };
    }
    put(0, &num!(348i32));
    let dim = [
        3,
        dims[0] as i16,
        dims[1] as i16,
        dims[2] as i16,
        1,
        1,
        1,
        1,
    ];
    for (i, d) in dim.iter().enumerate() {
        put(40 + 2 * i, &num!(*d));
    }
    put(70, &num!(datatype));
    put(72, &num!(bits));
    for (i, p) in [1.0f32, 0.5, 1.0, 2.5, 1.0, 1.0, 1.0, 1.0]
        .iter()
        .enumerate()
    {
        put(76 + 4 * i, &num!(*p));
    }
    put(108, &num!(352.0f32));
    put(344, b"n+1\0");
    h.extend(encode(t, dims, big));
    h
}

/// A VolPack `.den` file (u8, little-endian): 62-byte header, then the voxels.
fn den(dims: [u64; 3]) -> Vec<u8> {
    let mut out = Vec::new();
    let short = |v: i16, out: &mut Vec<u8>| out.extend_from_slice(&v.to_le_bytes());
    short(1, &mut out);
    for _ in 0..3 {
        // orig, extr, map: min, max, len
        for _ in 0..3 {
            short(0, &mut out);
        }
        for d in dims {
            short(d as i16 - 1, &mut out);
        }
        for d in dims {
            short(d as i16, &mut out);
        }
    }
    short(0, &mut out); // map_warps
    out.extend_from_slice(&((dims[0] * dims[1] * dims[2]) as i32).to_le_bytes());
    assert_eq!(out.len(), 62);
    out.extend(encode(StoredType::U8, dims, false));
    out
}

/// A Zarr v2 array of `dims` (x, y, z) in chunks of `chunks` (z, y, x), raw or gzip.
fn zarr_v2(
    dir: &TempDir,
    name: &str,
    t: StoredType,
    dims: [u64; 3],
    chunks: [u64; 3],
    gz: bool,
) -> PathBuf {
    let root = dir.join(name);
    std::fs::create_dir_all(&root).unwrap();
    let dtype = match t {
        StoredType::U8 => "|u1",
        StoredType::I8 => "|i1",
        StoredType::U16 => "<u2",
        StoredType::I16 => "<i2",
        StoredType::U32 => "<u4",
        StoredType::I32 => "<i4",
        StoredType::F32 => "<f4",
        StoredType::F64 => "<f8",
    };
    let shape = [dims[2], dims[1], dims[0]];
    let meta = json!({
        "zarr_format": 2, "shape": shape, "chunks": chunks, "dtype": dtype,
        "compressor": if gz { json!({"id": "gzip", "level": 1}) } else { json!(null) },
        "fill_value": 0, "order": "C", "filters": null,
    });
    std::fs::write(root.join(".zarray"), meta.to_string()).unwrap();
    let grid: Vec<u64> = (0..3).map(|a| shape[a].div_ceil(chunks[a])).collect();
    for cz in 0..grid[0] {
        for cy in 0..grid[1] {
            for cx in 0..grid[2] {
                // A chunk holds its full shape; voxels past the array are padding (7).
                let mut chunk = Vec::new();
                for z in 0..chunks[0] {
                    for y in 0..chunks[1] {
                        let (vz, vy) = (cz * chunks[0] + z, cy * chunks[1] + y);
                        let mut row = Vec::new();
                        for x in 0..chunks[2] {
                            let vx = cx * chunks[2] + x;
                            if vz < shape[0] && vy < shape[1] && vx < shape[2] {
                                // One voxel of the volume, encoded alone.
                                let all = encode_one(t, vx, vy, vz);
                                row.extend(all);
                            } else {
                                row.extend(std::iter::repeat_n(7u8, t.size_bytes()));
                            }
                        }
                        chunk.extend(row);
                    }
                }
                let bytes = if gz { gzip(&chunk) } else { chunk };
                std::fs::write(root.join(format!("{cz}.{cy}.{cx}")), bytes).unwrap();
            }
        }
    }
    root
}

/// Voxel (x, y, z) of [`value`] in little-endian bytes.
fn encode_one(t: StoredType, x: u64, y: u64, z: u64) -> Vec<u8> {
    let v = value(t, x, y, z);
    match t {
        StoredType::U8 => vec![v as u8],
        StoredType::I8 => vec![v as i8 as u8],
        StoredType::U16 => (v as u16).to_le_bytes().to_vec(),
        StoredType::I16 => (v as i16).to_le_bytes().to_vec(),
        StoredType::U32 => (v as u32).to_le_bytes().to_vec(),
        StoredType::I32 => (v as i32).to_le_bytes().to_vec(),
        StoredType::F32 => (v as f32).to_le_bytes().to_vec(),
        StoredType::F64 => v.to_le_bytes().to_vec(),
    }
}

const FILTERS: [DownsampleFilter; 4] = [
    DownsampleFilter::Mean2,
    DownsampleFilter::LaMarSubsample,
    DownsampleFilter::Box4,
    DownsampleFilter::BSpline4,
];

const BUDGET: u64 = 64 << 20;

/// Writes a store from `volume` and one from `open()`'s slabs, for each brick size and filter,
/// and asserts the files are identical; returns how many pairs were compared.
fn assert_same_store(
    dir: &TempDir,
    tag: &str,
    volume: &Volume,
    open: &dyn Fn() -> Box<dyn SlabReader + Send>,
    cases: &[(u32, DownsampleFilter)],
) -> usize {
    for (i, &(n, filter)) in cases.iter().enumerate() {
        let a = dir.join(&format!("{tag}-{i}-mem.mvbs"));
        let b = dir.join(&format!("{tag}-{i}-slabs.mvbs"));
        write_store_from_volume(&a, volume, n, filter).unwrap();
        let mut reader = open();
        let desc = slab_store_desc(&*reader, n, filter);
        let mut calls = 0u64;
        let mut last = (0, 0);
        let summary = write_store_from_slabs(&b, desc, &mut *reader, BUDGET, &mut |d, t| {
            calls += 1;
            last = (d, t);
        })
        .unwrap_or_else(|e| panic!("{tag} n={n} {filter:?}: {e}"));
        assert_eq!(last.0, last.1, "{tag}: progress ends at the total");
        assert_eq!(last.1, u64::from(summary.header.brick_count));
        assert!(calls >= 2);
        let (ba, bb) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        assert!(
            ba == bb,
            "{tag} n={n} {filter:?}: stores differ ({} vs {} bytes; first difference at {:?})",
            ba.len(),
            bb.len(),
            ba.iter().zip(&bb).position(|(x, y)| x != y)
        );
        BrickStore::open(&b).unwrap();
        assert_no_partial(&b);
        std::fs::remove_file(&a).unwrap();
        std::fs::remove_file(&b).unwrap();
    }
    cases.len()
}

/// Every filter at brick size 8, and brick sizes 4 and 16 with Mean2 / BSpline4.
fn cases() -> Vec<(u32, DownsampleFilter)> {
    let mut c: Vec<_> = FILTERS.iter().map(|&f| (8, f)).collect();
    c.push((4, DownsampleFilter::BSpline4));
    c.push((16, DownsampleFilter::Mean2));
    c
}

/// Reads `reader` in slabs of `step` planes and compares them with `volume`'s voxels.
fn assert_slabs_match(reader: &mut dyn SlabReader, volume: &Volume, step: u32) {
    assert_eq!(reader.dims(), volume.dims());
    assert_eq!(reader.spacing(), volume.spacing());
    assert_eq!(reader.scalar(), volume.scalar_type());
    let dims = volume.dims();
    let plane = (dims.x * dims.y) as usize;
    let mut z = 0;
    while z < dims.z {
        let end = (z + step).min(dims.z);
        let range = z as usize * plane..end as usize * plane;
        let mut slab = match volume.data() {
            VoxelData::U8(_) => VoxelData::U8(vec![0; range.len()]),
            VoxelData::U16(_) => VoxelData::U16(vec![0; range.len()]),
            VoxelData::F32(_) => VoxelData::F32(vec![0.0; range.len()]),
        };
        let len = slab.len();
        reader
            .read_slab(z..end, SlabMut::of_range(&mut slab, 0..len).unwrap())
            .unwrap();
        let want = match volume.data() {
            VoxelData::U8(v) => VoxelData::U8(v[range].to_vec()),
            VoxelData::U16(v) => VoxelData::U16(v[range].to_vec()),
            VoxelData::F32(v) => VoxelData::F32(v[range].to_vec()),
        };
        assert_eq!(slab, want, "planes {z}..{end}");
        z = end;
    }
    reader.finish().unwrap();
}

// ---------------------------------------------------------------------------------------------
// Byte-identical stores, every format

const DIMS: [u64; 3] = [19, 13, 29];

#[test]
fn headerless_raw_stores_are_identical() {
    let dir = TempDir::new("raw");
    for (scalar, t) in [
        (ScalarType::U8, StoredType::U8),
        (ScalarType::U16, StoredType::U16),
        (ScalarType::F32, StoredType::F32),
    ] {
        let mut bytes = vec![9u8; 5];
        bytes.extend(encode(t, DIMS, true));
        let path = dir.write(&format!("v-{}.raw", t.name()), &bytes);
        let desc = RawDescriptor {
            dims: UVec3::new(19, 13, 29),
            scalar,
            spacing: Vec3::new(1.0, 2.0, 0.5),
            header_bytes: 5,
            big_endian: true,
        };
        let volume = load_raw(&path, &desc).unwrap();
        let open = || open_raw_slabs(&path, &desc).unwrap();
        assert_slabs_match(&mut *open(), &volume, 4);
        assert_eq!(open().meta(), None);
        assert_same_store(&dir, t.name(), &volume, &open, &cases());
    }
}

#[test]
fn sidecar_raw_and_gzip_every_type() {
    let dir = TempDir::new("sidecar");
    for t in ALL_TYPES {
        for encoding in ["raw", "gzip"] {
            let data = encode(t, DIMS, false);
            let data = if encoding == "gzip" {
                gzip(&data)
            } else {
                data
            };
            let name = format!("{}-{encoding}", t.name());
            dir.write(&format!("{name}.raw"), &data);
            let sidecar = json!({
                "dims": DIMS, "type": t.name(), "endianness": "little",
                "spacing": [0.5, 1.0, 2.0], "encoding": encoding,
            });
            let json = dir.write(&format!("{name}.raw.json"), sidecar.to_string().as_bytes());
            let volume = load_volume_with_meta(&json).unwrap().volume;
            for step in [1, 5, 29] {
                assert_slabs_match(&mut *open_slabs(&json, None).unwrap(), &volume, step);
            }
            // The .raw beside its sidecar opens too.
            let raw = dir.join(&format!("{name}.raw"));
            assert_slabs_match(&mut *open_slabs(&raw, None).unwrap(), &volume, 7);
            let case = [(8, FILTERS[(t as usize) % 4])];
            assert_same_store(
                &dir,
                &name,
                &volume,
                &|| open_slabs(&json, None).unwrap(),
                &case,
            );
        }
    }
}

#[test]
fn nrrd_raw_and_gzip_stores_are_identical() {
    let dir = TempDir::new("nrrd");
    for (t, big) in [
        (StoredType::U8, false),
        (StoredType::I16, true),
        (StoredType::F32, false),
        (StoredType::F64, true),
    ] {
        for encoding in ["raw", "gzip"] {
            let path = dir.write(
                &format!("{}-{encoding}.nrrd", t.name()),
                &nrrd(t, DIMS, encoding, big),
            );
            let loaded = load_volume_with_meta(&path).unwrap();
            let reader = open_slabs(&path, None).unwrap();
            assert_eq!(reader.meta(), Some(&loaded.meta));
            assert_eq!(reader.forward_only(), encoding == "gzip");
            assert_slabs_match(&mut *open_slabs(&path, None).unwrap(), &loaded.volume, 3);
            let tag = format!("{}-{encoding}", t.name());
            let cases = if t == StoredType::U8 {
                cases()
            } else {
                vec![(8, DownsampleFilter::Box4)]
            };
            assert_same_store(
                &dir,
                &tag,
                &loaded.volume,
                &|| open_slabs(&path, None).unwrap(),
                &cases,
            );
        }
    }
}

#[test]
fn nifti_nii_and_nii_gz_stores_are_identical() {
    let dir = TempDir::new("nifti");
    for (t, big) in [
        (StoredType::I16, false),
        (StoredType::U8, true),
        (StoredType::F32, true),
    ] {
        let file = nifti(t, DIMS, big);
        for (name, bytes) in [
            (format!("{}.nii", t.name()), file.clone()),
            (format!("{}.nii.gz", t.name()), gzip(&file)),
        ] {
            let path = dir.write(&name, &bytes);
            let loaded = load_volume_with_meta(&path).unwrap();
            assert_eq!(open_slabs(&path, None).unwrap().meta(), Some(&loaded.meta));
            assert_slabs_match(&mut *open_slabs(&path, None).unwrap(), &loaded.volume, 6);
            let cases = if t == StoredType::I16 {
                cases()
            } else {
                vec![(4, DownsampleFilter::Mean2)]
            };
            assert_same_store(
                &dir,
                &name,
                &loaded.volume,
                &|| open_slabs(&path, None).unwrap(),
                &cases,
            );
        }
    }
}

#[test]
fn den_stores_are_identical() {
    let dir = TempDir::new("den");
    let path = dir.write("v.den", &den(DIMS));
    let loaded = load_volume_with_meta(&path).unwrap();
    assert_slabs_match(&mut *open_slabs(&path, None).unwrap(), &loaded.volume, 8);
    assert_same_store(
        &dir,
        "den",
        &loaded.volume,
        &|| open_slabs(&path, None).unwrap(),
        &[(8, DownsampleFilter::BSpline4)],
    );
}

#[test]
fn ome_zarr_raw_and_gzip_chunks_stores_are_identical() {
    let dir = TempDir::new("zarr");
    for (t, gz, chunks) in [
        (StoredType::U8, false, [7, 5, 6]),
        (StoredType::U16, true, [10, 13, 8]),
        (StoredType::I16, false, [3, 4, 19]),
        (StoredType::F32, true, [29, 6, 6]),
    ] {
        let name = format!("{}-{gz}.zarr", t.name());
        let root = zarr_v2(&dir, &name, t, DIMS, chunks, gz);
        let loaded = load_volume_with_meta(&root).unwrap();
        for step in [1, 4, 11] {
            assert_slabs_match(
                &mut *open_slabs(&root, Some(0)).unwrap(),
                &loaded.volume,
                step,
            );
        }
        let cases = if t == StoredType::U8 {
            cases()
        } else {
            vec![(8, DownsampleFilter::LaMarSubsample)]
        };
        assert_same_store(
            &dir,
            &name,
            &loaded.volume,
            &|| open_slabs(&root, None).unwrap(),
            &cases,
        );
    }
}

#[test]
fn small_and_flat_volumes_are_identical() {
    // One brick layer, one plane, dims below the brick size.
    let dir = TempDir::new("small");
    for dims in [[3, 2, 1], [40, 1, 1], [1, 1, 37], [33, 17, 9]] {
        let path = dir.write(
            &format!("{}x{}x{}.nrrd", dims[0], dims[1], dims[2]),
            &nrrd(StoredType::U16, dims, "gzip", false),
        );
        let loaded = load_volume_with_meta(&path).unwrap();
        assert_same_store(
            &dir,
            &format!("{dims:?}"),
            &loaded.volume,
            &|| open_slabs(&path, None).unwrap(),
            &[
                (4, DownsampleFilter::BSpline4),
                (16, DownsampleFilter::Mean2),
            ],
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Failures

/// Asserts there is neither a store nor a partial file at `store`.
fn assert_nothing_at(store: &Path) {
    assert!(!store.exists(), "{} exists", store.display());
    assert_no_partial(store);
}

/// Asserts no temporary file of a write of `store` (`.NAME.partial-...` beside it) is left.
fn assert_no_partial(store: &Path) {
    let name = store.file_name().unwrap().to_string_lossy().into_owned();
    let prefix = format!(".{name}.partial");
    let Ok(entries) = std::fs::read_dir(store.parent().unwrap()) else {
        return; // no folder, no partial file
    };
    for entry in entries {
        let entry = entry.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!entry.starts_with(&prefix), "partial file {entry} left");
    }
}

#[test]
fn truncated_gzip_fails_mid_way_and_leaves_nothing() {
    let dir = TempDir::new("trunc");
    let dims = [64, 64, 64];
    let full = nrrd(StoredType::U8, dims, "gzip", false);
    // Cut the stream in the middle of the data.
    let path = dir.write("cut.nrrd", &full[..full.len() * 2 / 3]);
    let store = dir.join("cut.mvbs");
    let mut reader = open_slabs(&path, None).unwrap();
    let desc = slab_store_desc(&*reader, 8, DownsampleFilter::Mean2);
    let mut progressed = 0;
    let err = write_store_from_slabs(&store, desc, &mut *reader, BUDGET, &mut |d, _| {
        progressed = d
    })
    .unwrap_err();
    assert!(
        progressed > 0,
        "the failure must come mid-way, after some bricks"
    );
    let StoreError::Input(VolumeError::Format { path: p, field, .. }) = &err else {
        panic!("expected an input format error, got {err:?}");
    };
    assert_eq!((p.as_path(), field.as_str()), (path.as_path(), "sizes"));
    assert!(err.to_string().contains("cut.nrrd"), "{err}");
    assert_nothing_at(&store);

    // Raw data that is too short is refused when opened, before anything is written.
    let raw = nrrd(StoredType::U8, dims, "raw", false);
    let path = dir.write("short.nrrd", &raw[..raw.len() - 100]);
    let err = match open_slabs(&path, None) {
        Err(e) => e,
        Ok(_) => panic!("a short raw NRRD opened"),
    };
    assert!(err.to_string().contains("short.nrrd"), "{err}");
    assert!(err.to_string().contains("too short"), "{err}");

    // Trailing data after the gzip stream's voxels is refused at the end, as the loader does.
    let with_header = nrrd(StoredType::U8, [8, 8, 8], "gzip", false);
    let header_len = with_header.windows(2).position(|w| w == b"\n\n").unwrap() + 2;
    let mut gz = with_header[..header_len].to_vec();
    let mut data = encode(StoredType::U8, [8, 8, 8], false);
    data.extend([1, 2, 3]);
    gz.extend(gzip(&data));
    let path = dir.write("long.nrrd", &gz);
    let mut reader = open_slabs(&path, None).unwrap();
    let store = dir.join("long.mvbs");
    let desc = slab_store_desc(&*reader, 4, DownsampleFilter::Mean2);
    let err =
        write_store_from_slabs(&store, desc, &mut *reader, BUDGET, &mut |_, _| {}).unwrap_err();
    assert!(err.to_string().contains("more than the 512 bytes"), "{err}");
    assert_nothing_at(&store);
}

#[test]
fn non_finite_values_name_the_voxel_like_the_loader() {
    let dir = TempDir::new("nan");
    let dims = [5u64, 4, 6];
    let mut data = encode(StoredType::F32, dims, false);
    let index = 3 + 5 * (2 + 4 * 4);
    data[index * 4..index * 4 + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    dir.write("nan.raw", &data);
    let json = dir.write(
        "nan.raw.json",
        json!({"dims": dims, "type": "f32", "endianness": "little"})
            .to_string()
            .as_bytes(),
    );
    let loader_err = load_volume_with_meta(&json).unwrap_err();
    let mut reader = open_slabs(&json, None).unwrap();
    let store = dir.join("nan.mvbs");
    let desc = slab_store_desc(&*reader, 4, DownsampleFilter::Mean2);
    let err =
        write_store_from_slabs(&store, desc, &mut *reader, BUDGET, &mut |_, _| {}).unwrap_err();
    let StoreError::Input(e) = &err else {
        panic!("{err:?}");
    };
    assert_eq!(e.to_string(), loader_err.to_string());
    assert!(
        matches!(
            e,
            VolumeError::NonFinite {
                x: 3,
                y: 2,
                z: 4,
                ..
            }
        ),
        "{e:?}"
    );
    assert_nothing_at(&store);
}

#[test]
fn budget_too_small_is_refused_before_anything_is_created() {
    let dir = TempDir::new("budget");
    let path = dir.write(
        "v.nrrd",
        &nrrd(StoredType::U8, [256, 256, 40], "raw", false),
    );
    let store = dir.join("v.mvbs");
    let mut reader = open_slabs(&path, None).unwrap();
    let desc = slab_store_desc(&*reader, 32, DownsampleFilter::Mean2);
    let err = write_store_from_slabs(&store, desc, &mut *reader, 2 << 20, &mut |_, _| {
        panic!("no progress before the budget check")
    })
    .unwrap_err();
    let StoreError::RamBudget { needed, budget, .. } = &err else {
        panic!("{err:?}");
    };
    assert!(needed > budget);
    assert!(err.to_string().contains("256x256"), "{err}");
    assert_nothing_at(&store);
}

#[test]
fn unwritable_destination_is_an_io_error_naming_it() {
    let dir = TempDir::new("unwritable");
    let path = dir.write("v.nrrd", &nrrd(StoredType::U8, [8, 8, 8], "raw", false));
    let blocker = dir.write("file", b"not a folder");
    let store = blocker.join("v.mvbs");
    let mut reader = open_slabs(&path, None).unwrap();
    let desc = slab_store_desc(&*reader, 4, DownsampleFilter::Mean2);
    let err =
        write_store_from_slabs(&store, desc, &mut *reader, BUDGET, &mut |_, _| {}).unwrap_err();
    assert!(matches!(err, StoreError::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("v.mvbs"), "{err}");
    assert_nothing_at(&store);
}

#[test]
fn slab_requests_are_checked() {
    let dir = TempDir::new("requests");
    let path = dir.write("v.nrrd", &nrrd(StoredType::U16, [4, 3, 10], "gzip", false));
    let mut reader = open_slabs(&path, None).unwrap();
    let mut slab = VoxelData::U16(vec![0; 12 * 2]);
    let mut wrong = VoxelData::U8(vec![0; 12 * 2]);
    let request = |r: &mut dyn SlabReader, z: std::ops::Range<u32>, s: &mut VoxelData| {
        let len = s.len();
        r.read_slab(z, SlabMut::of_range(s, 0..len).unwrap())
    };
    for (z, bad) in [(9..11, &mut slab), (0..2, &mut wrong)] {
        let e = request(&mut *reader, z, bad).unwrap_err();
        assert!(matches!(e, VolumeError::SlabRequest { .. }), "{e:?}");
    }
    request(&mut *reader, 4..6, &mut slab).unwrap();
    // Backwards on a gzip stream.
    let e = request(&mut *reader, 2..4, &mut slab).unwrap_err();
    assert!(e.to_string().contains("forward only"), "{e}");
    request(&mut *reader, 8..10, &mut slab).unwrap();
    reader.finish().unwrap();
    // A zarr level on a NRRD file.
    assert!(open_slabs(&path, Some(1)).is_err());
}

/// Review D3 and D4 (../shared/reviews/reliability-2026-12-05.md): a store write never opens
/// what was already beside its target. A symbolic link at the old `STORE.partial` name (to a
/// file the user keeps) and a regular file there both stay as they were, and the store is a
/// regular file of its own; a target that is a FIFO is refused before any work, and stays a
/// FIFO. Both writers (brick store and level store).
#[test]
fn store_writes_never_open_what_was_beside_the_target() {
    let dir = TempDir::new("beside");
    let path = dir.write("v.nrrd", &nrrd(StoredType::U8, [16, 16, 16], "raw", false));
    let keep = dir.write("keep.bin", b"the user's file");
    for (tag, level_store) in [("mvbs", false), ("mvl", true)] {
        let write = |store: &Path| {
            let mut reader = open_slabs(&path, None).unwrap();
            if level_store {
                write_level_store_from_slabs(
                    store,
                    &mut *reader,
                    8,
                    None,
                    DownsampleFilter::Mean2,
                    BUDGET,
                    &mut |_, _| {},
                )
                .map(|_| ())
            } else {
                let desc = slab_store_desc(&*reader, 8, DownsampleFilter::Mean2);
                write_store_from_slabs(store, desc, &mut *reader, BUDGET, &mut |_, _| {})
                    .map(|_| ())
            }
        };
        let opens = |store: &Path| {
            if level_store {
                LevelStore::open(store).map(|_| ()).unwrap();
            } else {
                BrickStore::open(store).map(|_| ()).unwrap();
            }
        };
        // A link at STORE.partial: not followed.
        let store = dir.join(&format!("linked.{tag}"));
        let link = dir.join(&format!("linked.{tag}.partial"));
        std::os::unix::fs::symlink(&keep, &link).unwrap();
        write(&store).unwrap();
        assert_eq!(std::fs::read(&keep).unwrap(), b"the user's file", "{tag}");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert!(
            std::fs::symlink_metadata(&store).unwrap().is_file(),
            "{tag}"
        );
        opens(&store);
        assert_no_partial(&store);
        // A regular file at STORE.partial: not truncated, not renamed.
        let store = dir.join(&format!("beside.{tag}"));
        let mine = dir.write(&format!("beside.{tag}.partial"), b"mine");
        write(&store).unwrap();
        assert_eq!(std::fs::read(&mine).unwrap(), b"mine", "{tag}");
        opens(&store);
        // A FIFO as the target: refused, naming it, and left a FIFO.
        let fifo = dir.join(&format!("pipe.{tag}"));
        let status = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(status.success());
        let err = write(&fifo).unwrap_err();
        assert!(
            err.to_string().contains(&format!("pipe.{tag}"))
                && err.to_string().contains("not a regular file"),
            "{tag}: {err}"
        );
        assert!(std::os::unix::fs::FileTypeExt::is_fifo(
            &std::fs::symlink_metadata(&fifo).unwrap().file_type()
        ));
        assert_no_partial(&fifo);
    }
}
