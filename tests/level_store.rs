//! The level store (issue 19, item 4): a volume's every level written once, read back brick by
//! brick exactly as the three-level cache stores it, checked against the vertex pyramid of the
//! volume; every corruption of the file is an error naming what is wrong, never wrong texels.

mod common;

use common::levels::textured_volume;
use common::Rng;
use glam::{UVec3, Vec3};
use mixvol::bricks::BrickGrid;
use mixvol::bricks::DownsampleFilter;
use mixvol::cache::{block_bricks, stored_brick_edge, stored_bricks_per_axis};
use mixvol::pyramid::LevelGrid;
use mixvol::store::{write_level_store, LevelStore, StoreError};
use mixvol::volume::{Volume, VoxelData};
use std::path::{Path, PathBuf};

const N: u32 = 8;

fn temp_dir(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("mixvol-level-store-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write(path: &Path, volume: &Volume, levels: Option<u32>) -> mixvol::store::LevelWriteSummary {
    write_filtered(path, volume, levels, DownsampleFilter::Mean2)
}

fn write_filtered(
    path: &Path,
    volume: &Volume,
    levels: Option<u32>,
    filter: DownsampleFilter,
) -> mixvol::store::LevelWriteSummary {
    let mut calls = Vec::new();
    let summary = write_level_store(path, volume, N, levels, filter, &mut |done, total| {
        calls.push((done, total))
    })
    .unwrap();
    let total = summary.header.stored_count;
    assert_eq!(
        calls.len() as u64,
        total,
        "progress after every stored brick"
    );
    assert_eq!(calls.last(), Some(&(total, total)));
    summary
}

/// Every stored brick of every level, with the brick it starts at.
fn stored_bricks(grid: &BrickGrid, levels: u32) -> Vec<(u32, UVec3)> {
    let mut out = Vec::new();
    for level in 0..levels {
        let s = stored_bricks_per_axis(grid.bricks_per_axis(), level);
        for z in 0..s.z {
            for y in 0..s.y {
                for x in 0..s.x {
                    out.push((level, UVec3::new(x, y, z) * block_bricks(level)));
                }
            }
        }
    }
    out
}

/// An f32 volume's store holds every level of its vertex pyramid exactly: each stored brick
/// equals the pyramid's texels for it (any brick of a block reads the block's), the grids put
/// back together equal the pyramid, and each recorded range is its brick's texel range. The
/// level-0-to-1 filter is the writer's choice and the store records it: a store built with
/// `BSpline4` holds that filter's pyramid, and says so.
#[test]
fn an_f32_store_holds_every_level_of_the_vertex_pyramid() {
    let dir = temp_dir("f32");
    let mut rng = Rng(0x1e7e_1570_0001);
    // 5 x 4 x 3 bricks, the last ones clipped: default levels 0..6 (a block of 8 bricks covers
    // the longest axis).
    let volume = textured_volume(&mut rng, UVec3::new(37, 29, 20));
    for filter in [DownsampleFilter::Mean2, DownsampleFilter::BSpline4] {
        let path = dir.join("v.mvl");
        let _ = std::fs::remove_file(&path);
        f32_store_holds_the_pyramid(&dir, &path, &volume, filter);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn f32_store_holds_the_pyramid(dir: &Path, path: &Path, volume: &Volume, filter: DownsampleFilter) {
    let summary = write_filtered(path, volume, None, filter);
    assert!(!dir.join("v.mvl.partial").exists());
    let store = LevelStore::open(path).unwrap();
    assert_eq!(store.level_count(), 6);
    assert_eq!(summary.header, *store.header());
    assert_eq!(store.filter(), filter);
    let grid = store.grid();
    assert_eq!(grid.bricks_per_axis(), UVec3::new(5, 4, 3));
    let pyramid = LevelGrid::vertex_pyramid(volume, store.level_count(), filter);
    let stored = stored_bricks(&grid, store.level_count());
    assert_eq!(stored.len() as u64, store.header().stored_count);
    for &(level, first) in &stored {
        let expected = pyramid[level as usize].stored_brick(first, N);
        assert_eq!(expected.len(), stored_brick_edge(N, level).pow(3) as usize);
        let texels = store.read_stored(level, first).unwrap();
        assert_eq!(texels, expected, "level {level} block at {first}");
        // The last brick of the block (clipped to the grid) reads the same stored brick.
        let last = (first + UVec3::splat(block_bricks(level) - 1)).min(grid.bricks_per_axis() - 1);
        assert_eq!(store.read_stored(level, last).unwrap(), texels);
        let range = store.stored_range(level, first).unwrap();
        let min = texels.iter().copied().fold(f32::INFINITY, f32::min);
        let max = texels.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        assert_eq!((range.min, range.max), (min, max));
    }
    assert_eq!(store.read_grids().unwrap(), pyramid);
    // A level or brick outside the store.
    assert!(matches!(
        store.read_stored(6, UVec3::ZERO),
        Err(StoreError::LevelOutOfRange { level: 6, .. })
    ));
    assert!(matches!(
        store.read_stored(0, UVec3::new(5, 0, 0)),
        Err(StoreError::LevelOutOfRange { .. })
    ));
}

/// A u8 volume's store keeps u8 texels (a quarter of f32): every level within half a step of
/// 255 of the f32 pyramid of the normalised voxels, level 0 exactly.
#[test]
fn a_u8_store_rounds_each_level_to_the_nearest_step() {
    let dir = temp_dir("u8");
    let dims = UVec3::new(24, 16, 16);
    let mut data = Vec::new();
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                data.push(((x * 37 + y * 11 + z * 5 + (x * y) % 7) % 256) as u8);
            }
        }
    }
    let volume = Volume::new(dims, Vec3::new(1.0, 0.5, 2.0), VoxelData::U8(data)).unwrap();
    let path = dir.join("u8.mvl");
    write(&path, &volume, Some(4));
    let store = LevelStore::open(&path).unwrap();
    assert_eq!(store.header().spacing, Vec3::new(1.0, 0.5, 2.0));
    let f32_size = {
        let f = dir.join("f32.mvl");
        let as_f32: Vec<f32> = (0..dims.element_product() as usize)
            .map(|i| volume.data().normalized(i))
            .collect();
        let v = Volume::new(dims, volume.spacing(), VoxelData::F32(as_f32)).unwrap();
        write(&f, &v, Some(4));
        std::fs::metadata(&f).unwrap().len()
    };
    let u8_size = std::fs::metadata(&path).unwrap().len();
    assert!(
        u8_size * 3 < f32_size,
        "u8 store {u8_size} bytes, f32 store {f32_size} bytes"
    );
    let pyramid = LevelGrid::vertex_pyramid(&volume, 4, DownsampleFilter::Mean2);
    let grids = store.read_grids().unwrap();
    for (level, (got, want)) in grids.iter().zip(&pyramid).enumerate() {
        let worst = got
            .values()
            .iter()
            .zip(want.values())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        let bound = if level == 0 { 1e-7 } else { 0.5 / 255.0 + 1e-6 };
        assert!(worst <= bound, "level {level}: off by {worst}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Damage anywhere is caught: a changed texel fails that brick's read (naming its level) and
/// only that brick's; a changed table entry, a cut or lengthened file, another file kind and a
/// bad header field fail the open, naming the field.
#[test]
fn a_damaged_store_is_an_error_naming_what_is_wrong() {
    let dir = temp_dir("damage");
    let mut rng = Rng(0x1e7e_1570_0002);
    let volume = textured_volume(&mut rng, UVec3::new(16, 16, 16));
    let path = dir.join("v.mvl");
    write(&path, &volume, None);
    let good = std::fs::read(&path).unwrap();
    let store = LevelStore::open(&path).unwrap();
    let data_offset = store.header().data_offset as usize;
    drop(store);
    let field_of = |bytes: &[u8]| {
        let p = dir.join("bad.mvl");
        std::fs::write(&p, bytes).unwrap();
        match LevelStore::open(&p) {
            // Named as what it is (review D22: level-store errors said "brick store").
            Err(e @ StoreError::Format { field, .. }) => {
                assert!(e.to_string().starts_with("level store "), "{e}");
                field
            }
            other => panic!("expected a format error, got {other:?}"),
        }
    };
    // A texel of level 1's first stored brick (level 0 has 8 bricks of 12^3 f32).
    let mut texel = good.clone();
    let level1 = data_offset + 8 * 12 * 12 * 12 * 4;
    texel[level1 + 5] ^= 0x40;
    let p = dir.join("texel.mvl");
    std::fs::write(&p, &texel).unwrap();
    let store = LevelStore::open(&p).unwrap();
    match store.read_stored(1, UVec3::ZERO) {
        Err(e @ StoreError::StoredBrickChecksum { level: 1, .. }) => {
            assert!(e.to_string().contains("level 1"), "{e}");
        }
        other => panic!("expected a checksum error, got {other:?}"),
    }
    assert!(store.read_stored(0, UVec3::ZERO).is_ok());
    assert!(store.read_stored(1, UVec3::ONE).is_ok());
    // The table (its first entry's range), the length, the magic, the version, the levels.
    let mut table = good.clone();
    table[128 + 13] ^= 1;
    assert_eq!(field_of(&table), "table_checksum");
    assert_eq!(field_of(&good[..good.len() - 1]), "file_size");
    let mut longer = good.clone();
    longer.push(0);
    assert_eq!(field_of(&longer), "file_size");
    let mut magic = good.clone();
    magic[..8].copy_from_slice(b"MIXVOLBS");
    assert_eq!(field_of(&magic), "magic");
    let mut version = good.clone();
    version[8] = 9;
    assert_eq!(field_of(&version), "version");
    let mut levels = good.clone();
    levels[32] = 32;
    assert_eq!(field_of(&levels), "levels");
    // The level-0-to-1 filter: 0-3 (a store written before the field holds 0, Mean2).
    assert_eq!(u32::from_le_bytes(good[92..96].try_into().unwrap()), 0);
    let mut filter = good.clone();
    filter[92] = 4;
    assert_eq!(field_of(&filter), "filter");
    assert_eq!(field_of(&good[..40]), "header_size");
    // A folder is not a store.
    match LevelStore::open(&dir) {
        Err(e @ StoreError::Io { action: "open", .. }) => {
            assert!(e.to_string().starts_with("level store "), "{e}");
            assert!(
                e.to_string().contains("a level store is a regular file"),
                "{e}"
            );
        }
        other => panic!("expected an open error, got {other:?}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The writer refuses what it cannot write before any work, and a failed write leaves nothing
/// behind: no file at the path, no partial file.
#[test]
fn the_writer_refuses_bad_requests_and_leaves_nothing() {
    let dir = temp_dir("refuse");
    let mut rng = Rng(0x1e7e_1570_0003);
    let volume = textured_volume(&mut rng, UVec3::new(16, 16, 8));
    let path = dir.join("v.mvl");
    let levels_err = |levels| match write_level_store(
        &path,
        &volume,
        N,
        Some(levels),
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    ) {
        Err(StoreError::InvalidDesc { field, .. }) => field,
        other => panic!("expected a refusal, got {other:?}"),
    };
    assert_eq!(levels_err(0), "levels");
    assert_eq!(levels_err(32), "levels");
    // Four levels need bricks of 8; bricks of 4 take three.
    assert!(matches!(
        write_level_store(
            &path,
            &volume,
            4,
            Some(4),
            DownsampleFilter::Mean2,
            &mut |_, _| {}
        ),
        Err(StoreError::InvalidDesc {
            field: "levels",
            ..
        })
    ));
    assert!(matches!(
        write_level_store(
            &path,
            &volume,
            6,
            None,
            DownsampleFilter::Mean2,
            &mut |_, _| {}
        ),
        Err(StoreError::InvalidDesc {
            field: "brick_size",
            ..
        })
    ));
    let missing = dir.join("no-such-dir").join("v.mvl");
    assert!(matches!(
        write_level_store(
            &missing,
            &volume,
            N,
            None,
            DownsampleFilter::Mean2,
            &mut |_, _| {}
        ),
        Err(StoreError::Io {
            action: "create",
            ..
        })
    ));
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        0,
        "nothing left behind"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Files in `dir` left by a writer: partial stores and the levels it builds on disk.
fn temporary_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.contains(".partial"))
        .collect()
}

/// The slab writer writes, byte for byte, the store the in-memory writer writes from the loaded
/// volume: for every scalar type, extents that are no multiple of the brick size, default and
/// fewer levels, building the levels above 0 in temporary files that it removes; and refuses a
/// RAM budget below what it needs before creating anything.
#[test]
fn the_slab_writer_writes_the_same_bytes_as_the_volume_writer() {
    use mixvol::store::{level_slab_bytes, write_level_store_from_slabs};
    use mixvol::volume::{open_raw_slabs, save_raw, RawDescriptor, ScalarType, SyntheticField};
    let dir = temp_dir("slabs");
    for (dims, scalar, levels, filter) in [
        (
            UVec3::new(37, 29, 21),
            ScalarType::F32,
            None,
            DownsampleFilter::Mean2,
        ),
        (
            UVec3::new(40, 17, 33),
            ScalarType::U8,
            None,
            DownsampleFilter::Mean2,
        ),
        (
            UVec3::new(24, 24, 26),
            ScalarType::U16,
            Some(3),
            DownsampleFilter::Mean2,
        ),
        // The wider filters read two voxels on each side of a vertex: planes the window must
        // still hold.
        (
            UVec3::new(37, 29, 21),
            ScalarType::F32,
            None,
            DownsampleFilter::BSpline4,
        ),
        (
            UVec3::new(24, 17, 26),
            ScalarType::U16,
            Some(3),
            DownsampleFilter::LaMarSubsample,
        ),
    ] {
        let volume = SyntheticField::MarschnerLobb
            .generate(dims, scalar)
            .unwrap();
        let raw = dir.join("v.raw");
        save_raw(&volume, &raw).unwrap();
        let from_volume = dir.join("volume.mvl");
        write_level_store(&from_volume, &volume, N, levels, filter, &mut |_, _| {}).unwrap();
        let desc = RawDescriptor {
            dims,
            scalar,
            spacing: volume.spacing(),
            header_bytes: 0,
            big_endian: false,
        };
        let from_slabs = dir.join("slabs.mvl");
        let mut reader = open_raw_slabs(&raw, &desc).unwrap();
        let mut calls = 0u64;
        let summary = write_level_store_from_slabs(
            &from_slabs,
            &mut *reader,
            N,
            levels,
            filter,
            64 << 20,
            &mut |_, _| calls += 1,
        )
        .unwrap();
        assert_eq!(calls, summary.header.stored_count);
        assert!(
            std::fs::read(&from_slabs).unwrap() == std::fs::read(&from_volume).unwrap(),
            "{dims} {scalar:?} {filter:?}: the slab writer's bytes differ"
        );
        assert_eq!(
            temporary_files(&dir),
            Vec::<String>::new(),
            "levels built on disk are removed"
        );
        // A budget one byte short is refused, and nothing is written.
        let stored = LevelStore::open(&from_slabs).unwrap().header().stored_count;
        let needed = level_slab_bytes(
            dims,
            scalar.size_bytes() as u64,
            N,
            stored,
            reader.scratch_bytes(),
        );
        let mut reader = open_raw_slabs(&raw, &desc).unwrap();
        let short = dir.join("short.mvl");
        assert!(matches!(
            write_level_store_from_slabs(
                &short,
                &mut *reader,
                N,
                levels,
                filter,
                needed - 1,
                &mut |_, _| {}
            ),
            Err(StoreError::RamBudget { .. })
        ));
        assert!(!short.exists() && !dir.join("short.mvl.partial").exists());
    }
    // A file shorter than its description fails, naming the input, and leaves nothing.
    let raw = dir.join("short.raw");
    std::fs::write(&raw, vec![0u8; 1000]).unwrap();
    let desc = RawDescriptor {
        dims: UVec3::splat(16),
        scalar: ScalarType::U8,
        spacing: Vec3::ONE,
        header_bytes: 0,
        big_endian: false,
    };
    // (The reader may refuse the file when it opens it, or when it reads the missing planes.)
    match open_raw_slabs(&raw, &desc) {
        Err(e) => assert!(e.to_string().contains("short.raw"), "{e}"),
        Ok(mut reader) => {
            let out = dir.join("cut.mvl");
            let err = write_level_store_from_slabs(
                &out,
                &mut *reader,
                N,
                None,
                DownsampleFilter::Mean2,
                64 << 20,
                &mut |_, _| {},
            )
            .unwrap_err();
            assert!(matches!(err, StoreError::Input(_)), "{err}");
            assert!(!out.exists() && !dir.join("cut.mvl.partial").exists());
            assert_eq!(temporary_files(&dir), Vec::<String>::new());
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
