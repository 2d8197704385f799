//! `mixvol convert INPUT STORE`, run as a user runs it.
//!
//! - A 96 MiB NRRD converted under `--ram-budget-mb 40`: the process's peak RSS (`VmHWM`, which
//!   the command reports in `--stats-json`) stays within its baseline plus the budget.
//! - Every slab-read format (headerless raw, NRRD gzip, NIfTI `.nii.gz`, OME-Zarr): the
//!   converted level store is byte for byte the one the library writes from the fully loaded
//!   volume.
//! - Failures (gzip cut mid-way, an unwritable destination, an existing STORE without --force, a
//!   budget too small) exit non-zero, name the file, and leave neither STORE nor STORE.partial.
//! - A two-level brick store of an earlier version (a checked-in fixture) is upgraded; cut or
//!   corrupted, it gives typed errors: truncation names the first missing brick, table
//!   corruption the checksum field, a read under a cut file the brick, altered brick bytes
//!   their level's CRC-32 (naming the brick and the level).
use flate2::write::GzEncoder;
use flate2::Compression;
use mixvol::bricks::{DownsampleFilter, Level};
use mixvol::store::{write_level_store, BrickStore, LevelStore, StoreError};
use mixvol::volume::{load_raw, load_volume, RawDescriptor, ScalarType};
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh temporary folder for one test, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let dir =
            std::env::temp_dir().join(format!("mixvol-cli-convert-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn convert(input: &Path, store: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .arg("convert")
        .arg(input)
        .arg(store)
        .args(extra)
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// u16 voxels of `dims` (little-endian, x fastest): a ramp plus a hash.
fn u16_voxels(dims: [u64; 3]) -> Vec<u8> {
    let mut out = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let h = (x * 7919 + y * 104_729 + z * 1_299_709) % 4096;
                let v = (x * 300 + y * 200 + z * 500 + h) as u16;
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    out
}

/// An attached NRRD header for `dims` of `type_name`.
fn nrrd_header(type_name: &str, dims: [u64; 3], encoding: &str) -> Vec<u8> {
    format!(
        "NRRD0004\ntype: {type_name}\ndimension: 3\nsizes: {} {} {}\nencoding: {encoding}\n\
         endian: little\nspacings: 1 1 2\n\n",
        dims[0], dims[1], dims[2]
    )
    .into_bytes()
}

/// A u16 NIfTI-1 file of `dims` with `data`.
fn nifti_u16(dims: [u64; 3], data: &[u8]) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let mut put = |at: usize, bytes: &[u8]| h[at..at + bytes.len()].copy_from_slice(bytes);
    put(0, &348i32.to_le_bytes());
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
        put(40 + 2 * i, &d.to_le_bytes());
    }
    put(70, &512i16.to_le_bytes());
    put(72, &16i16.to_le_bytes());
    for (i, p) in [1.0f32, 0.8, 0.8, 1.5, 1.0, 1.0, 1.0, 1.0]
        .iter()
        .enumerate()
    {
        put(76 + 4 * i, &p.to_le_bytes());
    }
    put(108, &352.0f32.to_le_bytes());
    put(344, b"n+1\0");
    h.extend_from_slice(data);
    h
}

/// A u16 OME-Zarr 0.4 image (Zarr v2, one level, gzip chunks of 5 x 8 x 16) of `dims` x, y, z.
fn zarr_u16(root: &Path, dims: [u64; 3], data: &[u8]) {
    let level = root.join("0");
    std::fs::create_dir_all(&level).unwrap();
    let shape = [dims[2], dims[1], dims[0]];
    let chunks = [5u64, 8, 16];
    std::fs::write(root.join(".zgroup"), json!({"zarr_format": 2}).to_string()).unwrap();
    let axes: Vec<Value> = ["z", "y", "x"]
        .iter()
        .map(|n| json!({"name": n, "type": "space"}))
        .collect();
    let ms = json!({"version": "0.4", "axes": axes, "datasets": [{"path": "0",
        "coordinateTransformations": [{"type": "scale", "scale": [2.0, 1.0, 1.0]}]}]});
    std::fs::write(
        root.join(".zattrs"),
        json!({"multiscales": [ms]}).to_string(),
    )
    .unwrap();
    let meta = json!({"zarr_format": 2, "shape": shape, "chunks": chunks, "dtype": "<u2",
        "compressor": {"id": "gzip", "level": 1}, "fill_value": 0, "order": "C", "filters": null});
    std::fs::write(level.join(".zarray"), meta.to_string()).unwrap();
    let grid: Vec<u64> = (0..3).map(|a| shape[a].div_ceil(chunks[a])).collect();
    for cz in 0..grid[0] {
        for cy in 0..grid[1] {
            for cx in 0..grid[2] {
                let mut chunk = Vec::new();
                for z in 0..chunks[0] {
                    for y in 0..chunks[1] {
                        for x in 0..chunks[2] {
                            let (vz, vy, vx) =
                                (cz * chunks[0] + z, cy * chunks[1] + y, cx * chunks[2] + x);
                            if vz < shape[0] && vy < shape[1] && vx < shape[2] {
                                let i = (vx + dims[0] * (vy + dims[1] * vz)) as usize * 2;
                                chunk.extend_from_slice(&data[i..i + 2]);
                            } else {
                                chunk.extend_from_slice(&[0xAB, 0xCD]);
                            }
                        }
                    }
                }
                std::fs::write(level.join(format!("{cz}.{cy}.{cx}")), gzip(&chunk)).unwrap();
            }
        }
    }
}

/// Asserts that neither `store` nor its partial file exists.
fn assert_nothing_at(store: &Path) {
    assert!(!store.exists(), "{} exists", store.display());
    let mut partial = store.as_os_str().to_owned();
    partial.push(".partial");
    assert!(
        !Path::new(&partial).exists(),
        "partial file of {} left",
        store.display()
    );
}

// ---------------------------------------------------------------------------------------------

#[test]
fn file_larger_than_the_budget_converts_with_bounded_peak_rss() {
    let dir = TempDir::new("rss");
    // 512 x 512 x 384 u8 = 96 MiB of voxels behind a NRRD header.
    let dims = [512u64, 512, 384];
    let mut file = nrrd_header("uchar", dims, "raw");
    let plane: Vec<u8> = (0..512 * 512u64)
        .map(|i| ((i % 512) ^ (i / 512)) as u8)
        .collect();
    for z in 0..dims[2] {
        file.extend(plane.iter().map(|v| v.wrapping_add(z as u8)));
    }
    let file_len = file.len() as u64;
    let input = dir.write("big.nrrd", &file);
    drop(file);
    let store = dir.join("big.mvl");
    let stats = dir.join("stats.json");
    // Bricks of 16: the level writer holds a window of 16 + 12 level-0 planes as f32 (28 MiB)
    // and the store's table.
    let out = convert(
        &input,
        &store,
        &[
            "--brick-size",
            "16",
            "--ram-budget-mb",
            "40",
            "--stats-json",
            stats.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("512x512x384"), "{stdout}");
    assert!(stdout.contains("peak RSS"), "{stdout}");
    let s: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let peak = s["peak_rss_bytes"].as_u64().expect("peak RSS measured");
    assert_eq!(s["ram_budget_bytes"].as_u64(), Some(40 << 20));
    // The process's own baseline: a convert of 8^3 voxels.
    let tiny = dir.join("tiny.json");
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["convert", "ml", dir.join("tiny.mvl").to_str().unwrap()])
        .args(["--dims", "8,8,8", "--brick-size", "8", "--stats-json"])
        .arg(&tiny)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let t: Value = serde_json::from_str(&std::fs::read_to_string(&tiny).unwrap()).unwrap();
    let baseline = t["peak_rss_bytes"].as_u64().unwrap();
    // The voxels alone are 96 MiB: the process holds the baseline and the budget at most.
    assert!(
        peak < baseline + (40 << 20) && peak < file_len * 3 / 5,
        "peak RSS {peak} bytes (baseline {baseline}) for a {file_len}-byte file under a 40 MiB \
         budget"
    );
    let opened = LevelStore::open(&store).unwrap();
    assert_eq!(opened.header().dims.to_array(), [512, 512, 384]);
    assert_eq!(
        s["store_bytes"].as_u64(),
        Some(std::fs::metadata(&store).unwrap().len())
    );
}

/// `convert` of every format (a forward-only gzip stream and an OME-Zarr image
/// included) writes, read in slabs under a small RAM budget, the very level store
/// `write_level_store` writes from the loaded volume; `--filter` builds its level 1.
#[test]
fn converted_level_stores_equal_the_in_memory_path_for_every_format() {
    let dir = TempDir::new("level-formats");
    let dims = [45u64, 38, 27];
    let data = u16_voxels(dims);
    let check = |tag: &str, input: &Path, volume: &mixvol::volume::Volume, extra: &[&str]| {
        let ours = dir.join(&format!("{tag}.mvl"));
        let theirs = dir.join(&format!("{tag}-mem.mvl"));
        let mut args = vec!["--brick-size", "8", "--ram-budget-mb", "3"];
        args.extend_from_slice(extra);
        let out = convert(input, &ours, &args);
        assert!(out.status.success(), "{tag}: {}", text(&out));
        assert!(text(&out).contains("level store:"), "{}", text(&out));
        // --filter builds level 1 (Mean2 by default), and the store and the summary say which.
        let filter = extra
            .iter()
            .position(|a| *a == "--filter")
            .map_or(DownsampleFilter::Mean2, |i| {
                DownsampleFilter::parse(extra[i + 1]).unwrap()
            });
        assert!(
            text(&out).contains(&format!("level 1 by {filter:?}")),
            "{tag}: {}",
            text(&out)
        );
        assert_eq!(
            mixvol::store::LevelStore::open(&ours).unwrap().filter(),
            filter
        );
        write_level_store(&theirs, volume, 8, None, filter, &mut |_, _| {}).unwrap();
        assert!(
            std::fs::read(&ours).unwrap() == std::fs::read(&theirs).unwrap(),
            "{tag}: the converted level store differs from the in-memory one"
        );
    };
    let raw = dir.write("v.bin", &data);
    let desc = RawDescriptor {
        dims: glam::UVec3::new(45, 38, 27),
        scalar: ScalarType::U16,
        spacing: glam::Vec3::new(1.0, 1.0, 2.0),
        header_bytes: 0,
        big_endian: false,
    };
    let raw_args = [
        "--dims",
        "45,38,27",
        "--scalar",
        "u16",
        "--spacing",
        "1,1,2",
    ];
    check("raw", &raw, &load_raw(&raw, &desc).unwrap(), &raw_args);
    let bspline = [&raw_args[..], &["--filter", "bspline4"]].concat();
    check(
        "raw-bspline4",
        &raw,
        &load_raw(&raw, &desc).unwrap(),
        &bspline,
    );
    let mut nrrd_gz = nrrd_header("ushort", dims, "gzip");
    nrrd_gz.extend(gzip(&data));
    let path = dir.write("v-gz.nrrd", &nrrd_gz);
    check("nrrd-gz", &path, &load_volume(&path).unwrap(), &[]);
    let path = dir.write("v.nii.gz", &gzip(&nifti_u16(dims, &data)));
    check("nii-gz", &path, &load_volume(&path).unwrap(), &[]);
    let root = dir.join("v.ome.zarr");
    zarr_u16(&root, dims, &data);
    check(
        "zarr",
        &root,
        &load_volume(&root).unwrap(),
        &["--level", "0"],
    );
    // A budget below what the slab writer needs is refused before anything is written.
    let out = convert(
        &raw,
        &dir.join("tight.mvl"),
        &[
            &["--brick-size", "8", "--ram-budget-mb", "0"][..],
            &raw_args,
        ]
        .concat(),
    );
    assert!(!out.status.success());
    assert!(text(&out).contains("RAM budget"), "{}", text(&out));
    assert_nothing_at(&dir.join("tight.mvl"));
}

#[test]
fn failed_converts_leave_nothing_and_name_the_file() {
    let dir = TempDir::new("fail");
    let dims = [64u64, 64, 64];
    let data = u16_voxels(dims);
    // A gzip stream cut two thirds of the way in: found mid-way, after bricks were written.
    let mut cut = nrrd_header("ushort", dims, "gzip");
    let gz = gzip(&data);
    cut.extend_from_slice(&gz[..gz.len() * 2 / 3]);
    let input = dir.write("cut.nrrd", &cut);
    let store = dir.join("cut.mvl");
    let out = convert(&input, &store, &["--brick-size", "8"]);
    assert!(!out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cut.nrrd") && err.contains("sizes"), "{err}");
    assert_nothing_at(&store);

    // A destination whose folder is a file.
    let mut whole = nrrd_header("ushort", dims, "raw");
    whole.extend_from_slice(&data);
    let input = dir.write("ok.nrrd", &whole);
    let blocker = dir.write("not-a-folder", b"x");
    let store = blocker.join("ok.mvl");
    let out = convert(&input, &store, &[]);
    assert!(!out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("ok.mvl"), "{err}");
    assert_nothing_at(&store);

    // A budget that cannot hold one slab: refused before anything is created.
    let store = dir.join("small-budget.mvl");
    let out = convert(&input, &store, &["--ram-budget-mb", "0"]);
    assert!(!out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("RAM budget") && err.contains("64x64"), "{err}");
    assert_nothing_at(&store);

    // An existing STORE is kept without --force and replaced with it.
    let store = dir.write("existing.mvl", b"precious");
    let out = convert(&input, &store, &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--force"));
    assert_eq!(std::fs::read(&store).unwrap(), b"precious");
    let out = convert(&input, &store, &["--force"]);
    assert!(out.status.success(), "{}", text(&out));
    LevelStore::open(&store).unwrap();

    // Review D4: with or without --force, STORE is replaced only when it is a regular file: a
    // FIFO stays a FIFO, a link and the file it points to stay as they were.
    let fifo = dir.join("pipe.mvl");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let out = convert(&input, &fifo, &["--force"]);
    assert!(!out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("pipe.mvl") && err.contains("not a regular file"),
        "{err}"
    );
    assert!(std::os::unix::fs::FileTypeExt::is_fifo(
        &std::fs::symlink_metadata(&fifo).unwrap().file_type()
    ));
    let kept = dir.write("kept.bin", b"precious");
    let link = dir.join("link.mvl");
    std::os::unix::fs::symlink(&kept, &link).unwrap();
    let out = convert(&input, &link, &["--force"]);
    assert!(!out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("link.mvl") && err.contains("symbolic link"),
        "{err}"
    );
    assert_eq!(std::fs::read(&kept).unwrap(), b"precious");
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    // Review D3: a link at STORE.partial is not written through (`--all-levels`, the old
    // spelling of the default, is still accepted).
    for (name, extra) in [
        ("through.mvl", &[][..]),
        ("again.mvl", &["--all-levels"][..]),
    ] {
        let store = dir.join(name);
        let partial = dir.join(&format!("{name}.partial"));
        std::os::unix::fs::symlink(&kept, &partial).unwrap();
        let out = convert(&input, &store, extra);
        assert!(out.status.success(), "{}", text(&out));
        assert_eq!(std::fs::read(&kept).unwrap(), b"precious", "{name}");
        assert!(
            std::fs::symlink_metadata(&store).unwrap().is_file(),
            "{name}"
        );
    }

    // The input itself is never the store, even with --force.
    let out = convert(&input, &input, &["--force"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("is the INPUT"));
    assert_eq!(std::fs::read(&input).unwrap(), whole);

    // A synthetic field larger than the budget is refused before it is generated.
    let out = convert(
        Path::new("ml"),
        &dir.join("ml.mvl"),
        &["--dims", "512,512,512", "--ram-budget-mb", "16"],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("built from the whole volume"));
    assert_nothing_at(&dir.join("ml.mvl"));

    // A missing input and a headerless file without --dims name the file.
    let out = convert(&dir.join("missing.nrrd"), &dir.join("m.mvl"), &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.nrrd"));
    let bare = dir.write("bare.bin", &data);
    let out = convert(&bare, &dir.join("b.mvl"), &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bare.bin") && err.contains("--dims"), "{err}");
    assert_nothing_at(&dir.join("b.mvl"));
}

/// A two-level brick store written by an earlier version (`tests/fixtures/brick_stores`, 20 x 12
/// x 9 u8 voxels of the `ml` field, bricks of 8).
fn old_store() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/brick_stores/ml_u8.mvbs")
}

#[test]
fn an_old_brick_store_is_upgraded_and_refused_by_render_with_the_command() {
    let dir = TempDir::new("upgrade");
    let old = old_store();
    // `render` does not draw it: it names the command that upgrades it.
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["render", "--volume", old.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("two-level brick store") && err.contains("mixvol convert"),
        "{err}"
    );
    // `convert` upgrades it: the level store of the volume it holds (the field regenerated
    // here), byte for byte.
    let upgraded = dir.join("up.mvl");
    let out = convert(&old, &upgraded, &["--brick-size", "8"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("level store:"), "{}", text(&out));
    let volume = mixvol::volume::SyntheticField::parse("ml")
        .unwrap()
        .generate(glam::UVec3::new(20, 12, 9), ScalarType::U8)
        .unwrap();
    let direct = dir.join("direct.mvl");
    write_level_store(
        &direct,
        &volume,
        8,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    assert!(
        std::fs::read(&upgraded).unwrap() == std::fs::read(&direct).unwrap(),
        "the upgraded store differs from the level store of its volume"
    );
    // Options of other inputs are refused on it.
    let out = convert(&old, &dir.join("x.mvl"), &["--level", "1"]);
    assert!(!out.status.success());
    assert!(text(&out).contains("is a brick store"), "{}", text(&out));
}

#[test]
fn cut_or_corrupted_old_stores_give_typed_errors() {
    let dir = TempDir::new("corrupt");
    let good = std::fs::read(old_store()).unwrap();
    let opened = BrickStore::open(old_store()).unwrap();
    let header = *opened.header();
    assert_eq!(opened.brick_count(), 12);
    let pair = header.hi_brick_bytes + header.lo_brick_bytes;
    drop(opened);

    // Cut inside brick 7: opening names the field and the first brick cut off.
    let cut = dir.write(
        "cut.mvbs",
        &good[..(header.data_offset + 7 * pair + 5) as usize],
    );
    match BrickStore::open(&cut) {
        Err(
            e @ StoreError::Format {
                field: "file_size", ..
            },
        ) => {
            let m = e.to_string();
            assert!(m.contains("brick 7 of") && m.contains("cut.mvbs"), "{m}");
        }
        other => panic!("{other:?}"),
    }

    // A byte of the offset table flipped: the table checksum catches it.
    let mut bad = good.clone();
    bad[header.offsets_offset as usize + 16 * 3 + 2] ^= 0x40;
    let bad_table = dir.write("table.mvbs", &bad);
    assert!(matches!(
        BrickStore::open(&bad_table),
        Err(StoreError::Format {
            field: "table_checksum",
            ..
        })
    ));

    // Cut under an open store: reading a lost brick is an I/O error naming that brick.
    let live = dir.write("live.mvbs", &good);
    let opened = BrickStore::open(&live).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&live)
        .unwrap()
        .set_len(header.data_offset + 9 * pair)
        .unwrap();
    assert!(opened.read_brick(8, Level::Lo).is_ok());
    let e = opened.read_brick(10, Level::Hi).unwrap_err();
    assert!(matches!(e, StoreError::Io { .. }), "{e:?}");
    assert!(e.to_string().contains("brick 10 level Hi"), "{e}");

    // Every brick level carries a CRC-32: a flipped texel is an error naming the brick and the
    // level when that level is read; its other level still reads. Upgrading it fails, naming
    // the brick, and leaves nothing.
    let mut flipped = good.clone();
    let at = (header.data_offset + 5 * pair + 3) as usize;
    flipped[at] ^= 0xFF;
    let path = dir.write("flipped.mvbs", &flipped);
    let opened = BrickStore::open(&path).unwrap();
    let e = opened.read_brick(5, Level::Hi).unwrap_err();
    assert!(
        matches!(
            e,
            StoreError::BrickChecksum {
                brick: 5,
                level: Level::Hi,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("brick 5 level Hi"), "{e}");
    let orig = BrickStore::open(old_store()).unwrap();
    assert_eq!(
        opened.read_brick(5, Level::Lo).unwrap(),
        orig.read_brick(5, Level::Lo).unwrap()
    );
    let target = dir.join("flipped.mvl");
    let out = convert(&path, &target, &["--brick-size", "8"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        text(&out).contains("flipped.mvbs") && text(&out).contains("brick 5 level Hi"),
        "{}",
        text(&out)
    );
    assert_nothing_at(&target);
}

#[test]
fn help_lists_the_convert_flags() {
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["convert", "--help"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--brick-size",
        "--filter",
        "--ram-budget-mb",
        "--level",
        "--force",
        "--dims",
        "--scalar",
        "--stats-json",
    ] {
        assert!(help.contains(flag), "{flag} missing from:\n{help}");
    }
}
