//! OME-Zarr stores written by the real writers: zarr-python (Zarr v2 + Blosc with lz4 / zstd /
//! zlib / blosclz inside and byte / bit / no shuffle, Zarr v3 + Zstd, v3 sharded) and ome-zarr-py
//! (OME-Zarr 0.4 and 0.5 multiscales), installed from PyPI by scripts/python-env.sh (run by
//! scripts/test.sh, which exports the venv's python as `MIXVOL_PYTHON`).
//! tests/fixtures/write_zarr_fixtures.py writes them all in one run per test binary.
//!
//! Every voxel holds a closed-form value of its (z, y, x) index that [`expected`] recomputes here
//! (the loader is never compared with itself); chunks the writer left out hold the fill value.
//! The OME metadata (levels, scales, translations) is checked against the numbers the generator
//! passed to ome-zarr-py. A corrupted Blosc or Zstd chunk must be a `VolumeError::Format` naming
//! the chunk file.
mod python_env;

use mixvol::volume::formats::{load_zarr_level, parse_zarr_root, ZarrRoot, ZarrVersion};
use mixvol::volume::VoxelData;
use mixvol::volume::{load_volume, load_zarr, FileFormat, LoadedVolume, StoredType, VolumeError};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folder holding every fixture, written once per test binary.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_zarr_fixtures.py",
            "zarr-python-fixtures",
            "scripts/requirements-zarr.txt",
        )
    })
}

/// Element types of the fixtures.
#[derive(Copy, Clone, Debug)]
enum Kind {
    U8,
    U16,
    F32,
}

/// The value the generator wrote at array index (z, y, x), as f64 (exact for all three types).
fn expected(kind: Kind, z: u64, y: u64, x: u64) -> f64 {
    match kind {
        Kind::U8 => ((x + 3 * y + 7 * z + 11) % 256) as f64,
        Kind::U16 => ((x + 61 * y + 3001 * z + 5) % 65536) as f64,
        Kind::F32 => x as f64 - 0.5 * y as f64 + 0.25 * z as f64 + 0.0625,
    }
}

/// What one array of a fixture holds.
struct Expect {
    kind: Kind,
    /// z, y, x.
    shape: [u64; 3],
    /// z, y, x: level 1 of a pyramid samples level 0 at even indices (step 2).
    step: u64,
    /// Chunk shape (z, y, x), chunk index (z, y, x) of the missing chunk, and the fill value.
    missing: Option<([u64; 3], [u64; 3], f64)>,
}

/// Checks every voxel of `v` against `e`; returns the number checked.
fn check_voxels(name: &str, v: &LoadedVolume, e: &Expect) -> usize {
    let [nz, ny, nx] = e.shape;
    assert_eq!(
        v.volume.dims().to_array(),
        [nx as u32, ny as u32, nz as u32],
        "{name}: dims (x, y, z)"
    );
    let values: Vec<f64> = match (v.volume.data(), e.kind) {
        (VoxelData::U8(d), Kind::U8) => d.iter().map(|&v| v as f64).collect(),
        (VoxelData::U16(d), Kind::U16) => d.iter().map(|&v| v as f64).collect(),
        (VoxelData::F32(d), Kind::F32) => d.iter().map(|&v| v as f64).collect(),
        (_, k) => panic!(
            "{name}: {k:?} expected, loaded {:?}",
            v.volume.scalar_type()
        ),
    };
    let mut checked = 0;
    let mut fills = 0;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let want = match e.missing {
                    Some((c, m, fill)) if [z / c[0], y / c[1], x / c[2]] == m => {
                        fills += 1;
                        fill
                    }
                    _ => expected(e.kind, z * e.step, y * e.step, x * e.step),
                };
                let i = (x + nx * (y + ny * z)) as usize;
                let got = values[i];
                assert!(
                    got == want,
                    "{name}: voxel (z {z}, y {y}, x {x}) is {got}, expected {want}"
                );
                checked += 1;
            }
        }
    }
    if e.missing.is_some() {
        assert!(
            fills > 0,
            "{name}: the missing chunk lies outside the array"
        );
    }
    checked
}

fn stored(kind: Kind) -> StoredType {
    match kind {
        Kind::U8 => StoredType::U8,
        Kind::U16 => StoredType::U16,
        Kind::F32 => StoredType::F32,
    }
}

/// Loads the plain array fixture `name` and checks it voxel by voxel, with unit spacing.
fn check_array(name: &str, e: Expect) {
    let root = fixtures().join(name);
    let v = load_zarr(&root).unwrap_or_else(|err| panic!("{name}: {err}"));
    assert_eq!(v.meta.format, FileFormat::Zarr);
    assert_eq!(v.meta.stored, stored(e.kind), "{name}: stored type");
    assert_eq!(v.volume.spacing().to_array(), [1.0; 3], "{name}: spacing");
    let n = check_voxels(name, &v, &e);
    assert_eq!(n as u64, e.shape.iter().product::<u64>());
}

#[test]
fn v2_blosc_lz4_shuffle_u16_with_missing_chunk() {
    let root = fixtures().join("v2_blosc_lz4.zarr");
    assert!(
        !root.join("0.0.0").exists() && root.join("0.0.1").is_file(),
        "zarr-python should have left chunk 0.0.0 out (all fill value) and written 0.0.1"
    );
    check_array(
        "v2_blosc_lz4.zarr",
        Expect {
            kind: Kind::U16,
            shape: [21, 34, 45],
            step: 1,
            missing: Some(([8, 16, 16], [0, 0, 0], 7.0)),
        },
    );
}

#[test]
fn v2_blosc_zstd_shuffle_f32() {
    check_array(
        "v2_blosc_zstd.zarr",
        Expect {
            kind: Kind::F32,
            shape: [13, 19, 30],
            step: 1,
            missing: None,
        },
    );
}

#[test]
fn v2_blosc_zlib_bitshuffle_u8() {
    check_array(
        "v2_blosc_zlib.zarr",
        Expect {
            kind: Kind::U8,
            shape: [9, 17, 33],
            step: 1,
            missing: None,
        },
    );
}

#[test]
fn v2_blosc_blosclz_noshuffle_u16() {
    check_array(
        "v2_blosc_blosclz.zarr",
        Expect {
            kind: Kind::U16,
            shape: [10, 11, 12],
            step: 1,
            missing: None,
        },
    );
}

#[test]
fn v3_zstd_u16_with_missing_chunk() {
    let root = fixtures().join("v3_zstd.zarr");
    assert!(!root.join("c/1/0/1").exists() && root.join("c/1/0/0").is_file());
    check_array(
        "v3_zstd.zarr",
        Expect {
            kind: Kind::U16,
            shape: [19, 23, 40],
            step: 1,
            missing: Some(([8, 16, 16], [1, 0, 1], 3.0)),
        },
    );
}

#[test]
fn v3_sharded_zstd_f32() {
    check_array(
        "v3_sharded.zarr",
        Expect {
            kind: Kind::F32,
            shape: [25, 30, 35],
            step: 1,
            missing: None,
        },
    );
}

/// Checks an ome-zarr-py pyramid: two levels, their scales (x, y, z) and translations, and the
/// voxels of both (level 1 = level 0 at even indices).
fn check_ome(name: &str, version: ZarrVersion, kind: Kind, shape: [u64; 3], scale: [f32; 3]) {
    let root = fixtures().join(name);
    let doc = root.join(match version {
        ZarrVersion::V2 => ".zattrs",
        ZarrVersion::V3 => "zarr.json",
    });
    let bytes = std::fs::read(&doc).unwrap();
    let ZarrRoot::Multiscales(m) = parse_zarr_root(&doc, &bytes, version).unwrap() else {
        panic!("{name}: not a multiscales root");
    };
    let paths: Vec<&str> = m.datasets.iter().map(|d| d.path.as_str()).collect();
    assert_eq!(paths, ["s0", "s1"], "{name}: levels");
    let names: Vec<&str> = m.axes.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(&names[names.len() - 3..], ["z", "y", "x"], "{name}: axes");

    for level in 0..2u32 {
        let v = load_zarr_level(&root, level as usize)
            .unwrap_or_else(|err| panic!("{name} level {level}: {err}"));
        assert_eq!(v.meta.stored, stored(kind));
        let f = (1u32 << level) as f32;
        assert_eq!(
            v.volume.spacing().to_array(),
            scale.map(|s| s * f),
            "{name} level {level}: spacing (x, y, z)"
        );
        // ome-zarr-py writes a translation of half a level-0 voxel per halving (in its units:
        // 0.5 whatever the scale), which the loader reports as the origin.
        let t = if level == 0 { 0.0 } else { 0.5 };
        assert_eq!(
            v.meta.origin, [t; 3],
            "{name} level {level}: origin (x, y, z)"
        );
        let step = 1u64 << level;
        let e = Expect {
            kind,
            shape: shape.map(|n| n.div_ceil(step)),
            step,
            missing: None,
        };
        check_voxels(&format!("{name} level {level}"), &v, &e);
    }
    let err = load_zarr_level(&root, 2).unwrap_err();
    assert!(
        matches!(&err, VolumeError::Format { field, .. } if field == "datasets"),
        "{name}: level 2 gave {err:?}"
    );
}

#[test]
fn ome_zarr_04_multiscales_by_ome_zarr_py() {
    check_ome(
        "ome04.zarr",
        ZarrVersion::V2,
        Kind::U8,
        [12, 26, 34],
        [0.5, 0.5, 2.0],
    );
    // Through the format detection too.
    let v = load_volume(&fixtures().join("ome04.zarr")).unwrap();
    assert_eq!(v.dims().to_array(), [34, 26, 12]);
}

#[test]
fn ome_zarr_05_multiscales_by_ome_zarr_py() {
    check_ome(
        "ome05.zarr",
        ZarrVersion::V3,
        Kind::U16,
        [10, 22, 30],
        [0.25, 1.0, 3.0],
    );
}

/// A copy of fixture `name` in a fresh folder under the test binary's temporary folder.
fn copy_fixture(name: &str, tag: &str) -> PathBuf {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for entry in std::fs::read_dir(from).unwrap() {
            let entry = entry.unwrap();
            let target = to.join(entry.file_name());
            if entry.file_type().unwrap().is_dir() {
                copy(&entry.path(), &target);
            } else {
                std::fs::copy(entry.path(), target).unwrap();
            }
        }
    }
    let dst = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("zarr-python-{tag}-{}", std::process::id()))
        .join(name);
    let _ = std::fs::remove_dir_all(&dst);
    copy(&fixtures().join(name), &dst);
    dst
}

/// Corrupts `chunk` of a copy of fixture `name` with `corrupt` and expects a Format error naming
/// that chunk file.
fn expect_corrupt_chunk(name: &str, chunk: &str, tag: &str, corrupt: impl Fn(&[u8]) -> Vec<u8>) {
    let root = copy_fixture(name, tag);
    let file = chunk.split('/').fold(root.clone(), |p, s| p.join(s));
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, corrupt(&bytes)).unwrap();
    match load_zarr(&root) {
        Err(VolumeError::Format { path, message, .. }) => {
            assert_eq!(
                path, file,
                "{name} {tag}: wrong file in the error: {message}"
            );
            assert!(
                message.contains("does not decode"),
                "{name} {tag}: {message}"
            );
            eprintln!("{name} {tag}: {message}");
        }
        other => panic!("{name} {tag}: expected a Format error naming {file:?}, got {other:?}"),
    }
    let _ = std::fs::remove_dir_all(root.parent().unwrap());
}

#[test]
fn corrupt_blosc_chunk_is_a_format_error_naming_it() {
    // Truncated: the Blosc header announces more bytes than the file holds.
    expect_corrupt_chunk("v2_blosc_lz4.zarr", "1.1.2", "blosc-truncated", |b| {
        b[..b.len() / 2].to_vec()
    });
    // Garbage instead of a Blosc frame.
    expect_corrupt_chunk("v2_blosc_zstd.zarr", "0.1.0", "blosc-garbage", |b| {
        b.iter().map(|v| v ^ 0x5a).collect()
    });
}

#[test]
fn corrupt_zstd_chunk_is_a_format_error_naming_it() {
    expect_corrupt_chunk("v3_zstd.zarr", "c/2/1/0", "zstd-truncated", |b| {
        b[..b.len() / 2].to_vec()
    });
    expect_corrupt_chunk("v3_zstd.zarr", "c/0/0/1", "zstd-garbage", |b| {
        let mut b = b.to_vec();
        let n = b.len();
        b[n / 3..].iter_mut().for_each(|v| *v ^= 0xa5);
        b
    });
}

/// Replaces `chunk` of a copy of fixture `name` by `corrupt(bytes)` and loads `level`; expects a
/// Format error naming the chunk file on `field`; returns the message.
fn corrupt_and_load(
    name: &str,
    level: usize,
    chunk: &str,
    tag: &str,
    corrupt: impl Fn(&[u8]) -> Vec<u8>,
) -> (String, String) {
    let root = copy_fixture(name, tag);
    let file = chunk.split('/').fold(root.clone(), |p, s| p.join(s));
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, corrupt(&bytes)).unwrap();
    let r = load_zarr_level(&root, level);
    let _ = std::fs::remove_dir_all(root.parent().unwrap());
    match r {
        Err(VolumeError::Format {
            path,
            field,
            message,
        }) => {
            assert_eq!(path, file, "{name} {tag}: wrong file: {message}");
            (field, message)
        }
        other => panic!("{name} {tag}: expected a Format error naming {file:?}, got {other:?}"),
    }
}

/// A zstd frame of no data that declares `size` content bytes (single segment, 8-byte size
/// field, one empty last raw block).
fn zstd_frame_declaring(size: u64) -> Vec<u8> {
    let mut b = vec![0x28, 0xb5, 0x2f, 0xfd, 0xe0];
    b.extend_from_slice(&size.to_le_bytes());
    b.extend_from_slice(&[1, 0, 0]);
    b
}

#[test]
fn chunks_declaring_huge_decoded_sizes_are_refused_before_allocating() {
    // 17 bytes declaring 1 TiB: zarrs reserves the declared size before decompressing (the
    // process aborted on allocation failure before the check).
    for (name, chunk, field) in [
        ("v3_zstd.zarr", "c/0/0/0", "codecs"),
        ("ome04.zarr", "s0/0/0/0", "compressor"),
    ] {
        let (f, message) = corrupt_and_load(name, 0, chunk, "zstd-declared", |_| {
            zstd_frame_declaring(1 << 40)
        });
        assert_eq!(f, field, "{message}");
        assert!(message.contains("declares 1099511627776"), "{message}");
        eprintln!("{name}: {message}");
    }
    // A Blosc header whose nbytes is 2 GiB - 1.
    let (f, message) = corrupt_and_load("v2_blosc_lz4.zarr", 0, "0.0.1", "blosc-declared", |b| {
        let mut b = b.to_vec();
        b[4..8].copy_from_slice(&0x7fff_ffffu32.to_le_bytes());
        b
    });
    assert_eq!(f, "compressor", "{message}");
    assert!(message.contains("declares 2147483647"), "{message}");
    eprintln!("v2_blosc_lz4.zarr: {message}");
}
