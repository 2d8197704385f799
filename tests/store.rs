//! The on-disk brick store: byte identity with the in-memory packers, format validation, and
//! priority streaming under a RAM budget (CPU only).

use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{
    brick_value_ranges_for_storage, fallback_levels, pack_hi_res_brick, pack_low_res_brick,
    quantize_to, request_plan, BrickGrid, BrickSource, DownsampleFilter, Level, SourceError,
    ValueRange, VolumeBrickSource,
};
use mixvol::store::format::{self, HEADER_SIZE};
use mixvol::store::{
    write_store, write_store_from_volume, write_store_with_threads, BrickStore, BrickStreamer,
    StoreDesc, StoreError, StreamerConfig,
};
use mixvol::volume::{ScalarType, Volume, VoxelData};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A fresh path under the cargo test tmp dir.
/// A fresh path per call: tests run in parallel threads and may share a `name`.
fn temp_path(name: &str) -> PathBuf {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let unique = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("store-tests");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}-{}-{unique}.mvbs", std::process::id()));
    let _ = std::fs::remove_file(&path);
    path
}

/// Deterministic pseudo-random values in [0, 1) (xorshift).
fn pseudo_random(count: usize, seed: u64) -> Vec<f32> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..count)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

fn random_volume(dims: UVec3, scalar: ScalarType, seed: u64) -> Volume {
    let count = (dims.x * dims.y * dims.z) as usize;
    let values = pseudo_random(count, seed);
    let data = match scalar {
        ScalarType::U8 => VoxelData::U8(values.iter().map(|v| (v * 256.0) as u8).collect()),
        ScalarType::U16 => VoxelData::U16(values.iter().map(|v| (v * 65536.0) as u16).collect()),
        ScalarType::F32 => VoxelData::F32(values.iter().map(|v| v * 3.0 - 1.0).collect()),
    };
    Volume::new(dims, Vec3::new(1.0, 0.5, 2.0), data).unwrap()
}

/// Checks every brick level and range of the store at `path` against the in-memory reference.
fn assert_matches_reference(path: &PathBuf, volume: &Volume, n: u32, filter: DownsampleFilter) {
    let store = BrickStore::open(path).unwrap();
    let scalar = volume.scalar_type();
    let grid = BrickGrid::new(volume.dims(), n).unwrap();
    let h = store.header();
    assert_eq!(h.dims, volume.dims());
    assert_eq!(h.brick_size, n);
    assert_eq!(h.scalar, scalar);
    assert_eq!(h.filter, filter);
    assert_eq!(h.spacing, volume.spacing());
    assert_eq!(store.grid(), grid);
    let (vmin, vmax) = volume.value_range();
    assert_eq!(
        store.value_range(),
        ValueRange {
            min: vmin,
            max: vmax
        }
    );
    let ranges = brick_value_ranges_for_storage(volume, &grid, filter, scalar).unwrap();
    assert_eq!(store.value_ranges(), &ranges[..], "{scalar:?} {filter:?}");
    for (i, brick) in grid.bricks().enumerate() {
        let hi = quantize_to(&pack_hi_res_brick(volume, &grid, brick).unwrap(), scalar);
        let lo = quantize_to(
            &pack_low_res_brick(volume, &grid, filter, brick).unwrap(),
            scalar,
        );
        assert_eq!(store.read_brick(i as u32, Level::Hi).unwrap(), hi, "hi {i}");
        assert_eq!(store.read_brick(i as u32, Level::Lo).unwrap(), lo, "lo {i}");
    }
}

#[test]
fn store_bytes_equal_the_reference_packers() {
    let cases = [
        (UVec3::new(13, 9, 6), 4, ScalarType::U8),
        (UVec3::new(37, 20, 11), 8, ScalarType::U16),
        (UVec3::new(19, 1, 23), 4, ScalarType::F32),
        (UVec3::new(1, 1, 1), 2, ScalarType::U8),
        (UVec3::new(33, 17, 9), 16, ScalarType::F32),
    ];
    for (c, &(dims, n, scalar)) in cases.iter().enumerate() {
        let volume = random_volume(dims, scalar, 7 + c as u64);
        for filter in DownsampleFilter::ALL {
            let path = temp_path(&format!("identity-{c}-{filter:?}"));
            let summary = write_store_from_volume(&path, &volume, n, filter).unwrap();
            assert_eq!(
                summary.header.file_size,
                std::fs::metadata(&path).unwrap().len()
            );
            assert_matches_reference(&path, &volume, n, filter);
            std::fs::remove_file(&path).unwrap();
        }
    }
}

#[test]
fn rows_split_into_several_chunks_stay_identical() {
    // n = 64: a chunk holds at most 6 bricks (8 MiB window), so the 8-brick rows split.
    let dims = UVec3::new(450, 3, 70);
    let volume = random_volume(dims, ScalarType::U8, 99);
    let path = temp_path("chunks");
    write_store_from_volume(&path, &volume, 64, DownsampleFilter::BSpline4).unwrap();
    assert_matches_reference(&path, &volume, 64, DownsampleFilter::BSpline4);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn producer_windows_of_split_rows_equal_the_reference_packers() {
    // The producer path evaluates a window per chunk (write_store_from_volume reads the volume in
    // place); n = 64 splits the 8-brick rows into several chunks, so windows start mid-volume.
    for (scalar, filter) in [
        (ScalarType::U8, DownsampleFilter::BSpline4),
        (ScalarType::U16, DownsampleFilter::Mean2),
        (ScalarType::F32, DownsampleFilter::Box4),
    ] {
        let dims = UVec3::new(450, 3, 70);
        let volume = random_volume(dims, scalar, 41);
        let desc = StoreDesc {
            dims,
            brick_size: 64,
            scalar,
            spacing: volume.spacing(),
            filter,
        };
        let sample = |p: IVec3| volume.value(p.x as u32, p.y as u32, p.z as u32);
        let path = temp_path(&format!("producer-{scalar:?}"));
        write_store_with_threads(&path, desc, &sample, 2, &mut |_, _| {}).unwrap();
        assert_matches_reference(&path, &volume, 64, filter);
        std::fs::remove_file(&path).unwrap();
    }
}

#[test]
fn output_does_not_depend_on_threads_and_matches_the_quantised_volume() {
    let dims = UVec3::new(21, 14, 30);
    let f = |p: IVec3| {
        ((p.x as f32 * 0.37).sin() + (p.y * p.z) as f32 * 0.01)
            .fract()
            .abs()
    };
    let desc = StoreDesc {
        dims,
        brick_size: 8,
        scalar: ScalarType::U16,
        spacing: Vec3::ONE,
        filter: DownsampleFilter::Box4,
    };
    let mut files = Vec::new();
    for threads in [1, 2, 5] {
        let path = temp_path(&format!("threads-{threads}"));
        let mut calls = Vec::new();
        write_store_with_threads(&path, desc, &f, threads, &mut |d, t| calls.push((d, t))).unwrap();
        let total = BrickGrid::new(dims, 8).unwrap().brick_count() as u64;
        assert_eq!(calls.first(), Some(&(0, total)));
        assert_eq!(calls.last(), Some(&(total, total)));
        assert!(calls.windows(2).all(|w| w[0].0 <= w[1].0));
        files.push(std::fs::read(&path).unwrap());
        std::fs::remove_file(&path).unwrap();
    }
    assert!(files.windows(2).all(|w| w[0] == w[1]));
    // The producer's values are quantised first: the store equals the quantised volume's.
    let mut words = Vec::new();
    for z in 0..dims.z as i32 {
        for y in 0..dims.y as i32 {
            for x in 0..dims.x as i32 {
                words.push((f(IVec3::new(x, y, z)).clamp(0.0, 1.0) * 65535.0).round() as u16);
            }
        }
    }
    let volume = Volume::new(dims, Vec3::ONE, VoxelData::U16(words)).unwrap();
    let path = temp_path("quantised");
    write_store_from_volume(&path, &volume, 8, DownsampleFilter::Box4).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), files[0]);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn invalid_descriptions_and_samples_are_rejected() {
    let good = StoreDesc {
        dims: UVec3::splat(8),
        brick_size: 4,
        scalar: ScalarType::F32,
        spacing: Vec3::ONE,
        filter: DownsampleFilter::Mean2,
    };
    let path = temp_path("invalid-desc");
    let zero = |_: IVec3| 0.0;
    let cases = [
        (
            StoreDesc {
                dims: UVec3::new(8, 0, 8),
                ..good
            },
            "dims",
        ),
        (
            StoreDesc {
                brick_size: 6,
                ..good
            },
            "brick_size",
        ),
        (
            StoreDesc {
                spacing: Vec3::new(1.0, -1.0, 1.0),
                ..good
            },
            "spacing",
        ),
    ];
    for (desc, field) in cases {
        match write_store(&path, desc, &zero, &mut |_, _| {}) {
            Err(StoreError::InvalidDesc { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {other:?}"),
        }
    }
    let nan = |p: IVec3| {
        if p == IVec3::new(5, 6, 7) {
            f32::NAN
        } else {
            0.5
        }
    };
    match write_store(&path, good, &nan, &mut |_, _| {}) {
        Err(StoreError::NonFiniteSample { voxel, .. }) => assert_eq!(voxel, [5, 6, 7]),
        other => panic!("{other:?}"),
    }
    assert!(!path.exists(), "a failed write leaves no file");
    // UNORM stores clamp and map NaN to 0, like quantize_to.
    let desc = StoreDesc {
        scalar: ScalarType::U8,
        ..good
    };
    write_store(&path, desc, &nan, &mut |_, _| {}).unwrap();
    let store = BrickStore::open(&path).unwrap();
    assert_eq!(
        store.value_range(),
        ValueRange {
            min: 0.0,
            max: 128.0 / 255.0
        }
    );
    std::fs::remove_file(&path).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Validation.

/// A small valid store's bytes.
fn small_store_bytes() -> Vec<u8> {
    let volume = random_volume(UVec3::new(10, 7, 5), ScalarType::U16, 3);
    let path = temp_path("small");
    write_store_from_volume(&path, &volume, 4, DownsampleFilter::Mean2).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    bytes
}

/// Opens `bytes` as a store file.
fn open_bytes(bytes: &[u8], name: &str) -> Result<BrickStore, StoreError> {
    let path = temp_path(name);
    std::fs::write(&path, bytes).unwrap();
    let result = BrickStore::open(&path);
    std::fs::remove_file(&path).unwrap();
    result
}

fn field_of(result: Result<BrickStore, StoreError>) -> &'static str {
    match result {
        Err(StoreError::Format { field, .. }) => field,
        other => panic!("expected a format error, got {other:?}"),
    }
}

/// Rewrites the checksum so that a deliberate table edit reaches the table validation.
fn reseal(bytes: &mut [u8]) {
    let h = BrickStoreLayout::of(bytes);
    let mut header = [0u8; HEADER_SIZE];
    header.copy_from_slice(&bytes[..HEADER_SIZE]);
    let ranges = bytes[h.ranges.clone()].to_vec();
    let offsets = bytes[h.offsets.clone()].to_vec();
    format::finish_checksum(&mut header, &ranges, &offsets);
    bytes[..HEADER_SIZE].copy_from_slice(&header);
}

/// Table positions of a canonical small store.
struct BrickStoreLayout {
    ranges: std::ops::Range<usize>,
    offsets: std::ops::Range<usize>,
    data: usize,
}

impl BrickStoreLayout {
    fn of(bytes: &[u8]) -> Self {
        let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
        let count = u32::from_le_bytes(bytes[52..56].try_into().unwrap()) as usize;
        let (r, o) = (u64_at(72), u64_at(80));
        Self {
            ranges: r..r + 8 * count,
            offsets: o..o + format::OFFSET_ENTRY_BYTES as usize * count,
            data: u64_at(88),
        }
    }
}

#[test]
fn header_fields_are_validated_by_name() {
    let good = small_store_bytes();
    assert!(open_bytes(&good, "good").is_ok());
    let patch = |at: usize, value: &[u8]| {
        let mut b = good.clone();
        b[at..at + value.len()].copy_from_slice(value);
        b
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (patch(0, b"MIXVOLBX"), "magic"),
        (patch(8, &3u32.to_le_bytes()), "version"),
        (patch(8, &1u32.to_le_bytes()), "version"),
        (patch(8, &0u32.to_le_bytes()), "version"),
        (patch(12, &64u32.to_le_bytes()), "header_size"),
        (patch(20, &0u32.to_le_bytes()), "dims"),
        (patch(28, &3u32.to_le_bytes()), "brick_size"),
        (patch(28, &2048u32.to_le_bytes()), "brick_size"),
        (patch(32, &3u32.to_le_bytes()), "scalar"),
        (patch(36, &4u32.to_le_bytes()), "filter"),
        (patch(44, &f32::NAN.to_le_bytes()), "spacing"),
        (patch(48, &0f32.to_le_bytes()), "spacing"),
        (patch(16, &13u32.to_le_bytes()), "brick_count"),
        (patch(16, &11u32.to_le_bytes()), "table_checksum"),
        (patch(52, &99u32.to_le_bytes()), "brick_count"),
        (patch(56, &1u64.to_le_bytes()), "hi_brick_bytes"),
        (patch(64, &1u64.to_le_bytes()), "lo_brick_bytes"),
        (patch(72, &8u64.to_le_bytes()), "ranges_offset"),
        (patch(72, &u64::MAX.to_le_bytes()), "ranges_offset"),
        (patch(80, &0u64.to_le_bytes()), "offsets_offset"),
        (patch(80, &(u64::MAX - 3).to_le_bytes()), "offsets_offset"),
        (patch(88, &0u64.to_le_bytes()), "data_offset"),
        (patch(96, &100u64.to_le_bytes()), "file_size"),
        (patch(96, &u64::MAX.to_le_bytes()), "file_size"),
        (patch(104, &f32::INFINITY.to_le_bytes()), "value_range"),
        (patch(108, &(-1f32).to_le_bytes()), "value_range"),
        (patch(112, &[1]), "reserved"),
        (patch(120, &[0x55]), "table_checksum"),
    ];
    for (i, (bytes, field)) in cases.into_iter().enumerate() {
        assert_eq!(field_of(open_bytes(&bytes, "field")), field, "case {i}");
    }
    // Trailing bytes are as wrong as missing ones.
    let mut longer = good.clone();
    longer.push(0);
    assert_eq!(field_of(open_bytes(&longer, "longer")), "file_size");
}

#[test]
fn truncated_files_name_the_field_they_end_in() {
    let good = small_store_bytes();
    let layout = BrickStoreLayout::of(&good);
    let cuts = [
        (0, "magic"),
        (5, "magic"),
        (8, "version"),
        (11, "version"),
        (12, "header_size"),
        (127, "header_size"),
        (128, "file_size"),
        (layout.ranges.start + 3, "file_size"),
        (layout.offsets.start + 5, "file_size"),
        (layout.data, "file_size"),
        (good.len() - 1, "file_size"),
    ];
    for (len, field) in cuts {
        assert_eq!(
            field_of(open_bytes(&good[..len], "cut")),
            field,
            "cut at {len}"
        );
    }
}

#[test]
fn table_contents_are_validated() {
    let good = small_store_bytes();
    let layout = BrickStoreLayout::of(&good);
    // An unsealed edit fails the checksum.
    let mut b = good.clone();
    b[layout.ranges.start + 9] ^= 0x40;
    assert_eq!(field_of(open_bytes(&b, "flip")), "table_checksum");
    // Sealed edits reach the field checks.
    let mut b = good.clone();
    b[layout.ranges.start..layout.ranges.start + 4].copy_from_slice(&0.9f32.to_le_bytes());
    b[layout.ranges.start + 4..layout.ranges.start + 8].copy_from_slice(&0.1f32.to_le_bytes());
    reseal(&mut b);
    assert_eq!(field_of(open_bytes(&b, "range")), "value_ranges");
    let mut b = good.clone();
    let entry = format::OFFSET_ENTRY_BYTES as usize;
    let at = layout.offsets.start + entry;
    b[at..at + 8].copy_from_slice(&(good.len() as u64 - 10).to_le_bytes());
    reseal(&mut b);
    assert_eq!(field_of(open_bytes(&b, "offset-out")), "offsets");
    let mut b = good.clone();
    let first = b[layout.offsets.start..layout.offsets.start + 8].to_vec();
    b[at..at + 8].copy_from_slice(&first);
    reseal(&mut b);
    assert_eq!(field_of(open_bytes(&b, "offset-overlap")), "offsets");
    let mut b = good.clone();
    b[at..at + 8].copy_from_slice(&2u64.to_le_bytes());
    reseal(&mut b);
    assert_eq!(field_of(open_bytes(&b, "offset-header")), "offsets");
    // A sealed permutation of the offsets is a valid (non-canonical) store.
    let mut b = good.clone();
    let (x, y) = (layout.offsets.start, layout.offsets.start + entry);
    let (first, second) = (b[x..x + entry].to_vec(), b[y..y + entry].to_vec());
    b[x..x + entry].copy_from_slice(&second);
    b[y..y + entry].copy_from_slice(&first);
    reseal(&mut b);
    let path = temp_path("permuted");
    std::fs::write(&path, &b).unwrap();
    let original = open_bytes(&good, "orig").unwrap();
    let permuted = BrickStore::open(&path).unwrap();
    assert_eq!(
        permuted.read_brick(0, Level::Hi).unwrap(),
        original.read_brick(1, Level::Hi).unwrap()
    );
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn every_corrupted_header_or_table_byte_is_an_error_never_a_panic() {
    let good = small_store_bytes();
    let layout = BrickStoreLayout::of(&good);
    let path = temp_path("fuzz");
    for at in 0..layout.offsets.end {
        if (layout.offsets.end..layout.data).contains(&at) {
            continue;
        }
        for mask in [0x01u8, 0x80, 0xFF] {
            let mut b = good.clone();
            b[at] ^= mask;
            std::fs::write(&path, &b).unwrap();
            match BrickStore::open(&path) {
                Err(StoreError::Format { .. }) => {}
                other => panic!("byte {at} ^ {mask:#x}: {other:?}"),
            }
        }
    }
    // Brick data carries a CRC-32 per level: a flipped data byte opens (the tables are intact)
    // and the read of that brick level is an error naming it; the other levels read fine.
    let original = open_bytes(&good, "fuzz-orig").unwrap();
    let lo_of_0 = original.level_offset(0, Level::Lo).unwrap() as usize;
    for (at, brick, level) in [
        (layout.data, 0, Level::Hi),
        (lo_of_0 + 3, 0, Level::Lo),
        (good.len() - 1, original.brick_count() - 1, Level::Lo),
    ] {
        let mut b = good.clone();
        b[at] ^= 0x10;
        std::fs::write(&path, &b).unwrap();
        let store = BrickStore::open(&path).unwrap();
        match store.read_brick(brick, level) {
            Err(StoreError::BrickChecksum {
                brick: b, level: l, ..
            }) => assert_eq!((b, l), (brick, level)),
            other => panic!("byte {at}: {other:?}"),
        }
        let other = if level == Level::Hi {
            Level::Lo
        } else {
            Level::Hi
        };
        assert_eq!(
            store.read_brick(brick, other).unwrap(),
            original.read_brick(brick, other).unwrap()
        );
    }
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn open_and_read_errors_are_typed() {
    match BrickStore::open(temp_path("missing")) {
        Err(StoreError::Io { action, .. }) => assert_eq!(action, "open"),
        other => panic!("{other:?}"),
    }
    let good = small_store_bytes();
    let path = temp_path("read-errors");
    std::fs::write(&path, &good).unwrap();
    let store = BrickStore::open(&path).unwrap();
    let count = store.brick_count();
    assert!(matches!(
        store.read_brick(count, Level::Hi),
        Err(StoreError::BrickOutOfRange { brick, .. }) if brick == count
    ));
    assert!(matches!(
        store.read_brick(0, Level::Absent),
        Err(StoreError::AbsentLevel { brick: 0 })
    ));
    // Truncated after opening: the read fails with an I/O error, no panic.
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(HEADER_SIZE as u64 + 10)
        .unwrap();
    assert!(matches!(
        store.read_brick(count - 1, Level::Lo),
        Err(StoreError::Io { .. })
    ));
    std::fs::remove_file(&path).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Streaming.

/// A 64^3 u8 store with n = 8 (512 bricks; hi 1000 bytes, lo 125 bytes).
fn streaming_store(name: &str) -> (PathBuf, Arc<Volume>) {
    let volume = Arc::new(random_volume(UVec3::splat(64), ScalarType::U8, 11));
    let path = temp_path(name);
    write_store_from_volume(&path, &volume, 8, DownsampleFilter::Mean2).unwrap();
    (path, volume)
}

fn config(budget: usize) -> StreamerConfig {
    StreamerConfig {
        ram_budget_bytes: budget,
        record_load_order: true,
    }
}

/// Polls until settled, at most 60 s (a hang guard, not a timing check: the machine may be busy).
fn settle(streamer: &BrickStreamer) {
    let start = Instant::now();
    while !streamer.is_settled() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "streamer did not settle: {:?}",
            streamer.stats()
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// A priority permutation of 0..count.
fn shuffled_priorities(count: usize, seed: u64) -> Vec<f32> {
    let r = pseudo_random(count, seed);
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by(|&a, &b| r[a].total_cmp(&r[b]));
    let mut p = vec![0.0; count];
    for (rank, &i) in order.iter().enumerate() {
        p[i] = rank as f32;
    }
    p
}

#[test]
fn streamer_loads_everything_in_priority_order_with_a_large_budget() {
    let (path, volume) = streaming_store("stream-all");
    let streamer = BrickStreamer::open(&path, config(64 << 20)).unwrap();
    let reference = VolumeBrickSource::new(volume, 8, DownsampleFilter::Mean2).unwrap();
    assert_eq!(streamer.value_ranges(), reference.value_ranges());
    assert_eq!(streamer.grid(), reference.grid());
    let count = streamer.store().brick_count();
    let p = shuffled_priorities(count as usize, 5);
    let mut request: Vec<(u32, Level, f32)> =
        (0..count).map(|b| (b, Level::Hi, p[b as usize])).collect();
    request.extend((0..count).map(|b| (b, Level::Lo, -1.0 - p[b as usize])));
    streamer.request(&request).unwrap();
    settle(&streamer);
    let mut expected = request.clone();
    expected.sort_by(|a, b| b.2.total_cmp(&a.2));
    let expected: Vec<(u32, Level)> = expected.iter().map(|&(b, l, _)| (b, l)).collect();
    assert_eq!(streamer.loaded_order(), expected);
    for b in 0..count {
        for level in [Level::Hi, Level::Lo] {
            let got = streamer.brick_bytes(b, level).unwrap().unwrap();
            let want = reference.brick_bytes(b, level).unwrap().unwrap();
            assert_eq!(got, want, "brick {b} {level:?}");
        }
    }
    let stats = streamer.stats();
    assert_eq!(stats.loads, 2 * u64::from(count));
    assert_eq!(stats.evictions, 0);
    assert_eq!(stats.resident_bytes, count as usize * 1125);
    assert!(stats.peak_bytes <= 64 << 20);
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn streamer_reports_its_loaded_levels_in_one_call() {
    let (path, _) = streaming_store("stream-loaded-levels");
    // 100 hi-res bricks of 1000 bytes and 100 low-res ones of 125.
    let streamer = BrickStreamer::open(&path, config(112_500)).unwrap();
    let count = streamer.store().brick_count();
    let p = shuffled_priorities(count as usize, 4);
    let mut request: Vec<(u32, Level, f32)> =
        (0..count).map(|b| (b, Level::Hi, p[b as usize])).collect();
    request.extend((0..count).map(|b| (b, Level::Lo, p[b as usize] - 0.5)));
    streamer.request(&request).unwrap();
    settle(&streamer);
    let resident: std::collections::HashSet<(u32, Level)> =
        streamer.resident().into_iter().collect();
    assert!(resident.len() > 100, "{}", resident.len());
    let mut loaded = Vec::new();
    streamer.loaded_levels(&mut loaded);
    assert_eq!(loaded.len(), count as usize);
    for b in 0..count {
        for level in [Level::Hi, Level::Lo] {
            let held = resident.contains(&(b, level));
            assert_eq!(
                loaded[b as usize].contains(level),
                held,
                "brick {b} {level:?}"
            );
            assert_eq!(streamer.is_loaded(b, level), held, "brick {b} {level:?}");
        }
        assert!(!loaded[b as usize].contains(Level::Absent));
    }
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn streamer_keeps_the_highest_priority_prefix_within_the_budget() {
    let (path, _) = streaming_store("stream-budget");
    let budget = 100_500; // 100 hi-res bricks of 1000 bytes
    let streamer = BrickStreamer::open(&path, config(budget)).unwrap();
    let count = streamer.store().brick_count() as usize;
    let top = |p: &[f32], k: usize| {
        let mut idx: Vec<u32> = (0..count as u32).collect();
        idx.sort_by(|&a, &b| p[b as usize].total_cmp(&p[a as usize]));
        idx.truncate(k);
        idx
    };
    let mut all_loaded = Vec::new();
    for (round, seed) in [1u64, 2, 3].into_iter().enumerate() {
        let p = shuffled_priorities(count, seed);
        let request: Vec<_> = (0..count as u32)
            .map(|b| (b, Level::Hi, p[b as usize]))
            .collect();
        let before = streamer.loaded_order().len();
        streamer.request(&request).unwrap();
        settle(&streamer);
        let stats = streamer.stats();
        assert!(stats.peak_bytes <= budget, "{stats:?}");
        assert!(stats.resident_bytes <= budget, "{stats:?}");
        assert_eq!(stats.wanted_resident, 100, "round {round}: {stats:?}");
        let mut resident: Vec<u32> = streamer.resident().iter().map(|k| k.0).collect();
        resident.sort_unstable();
        let mut want = top(&p, 100);
        want.sort_unstable();
        assert_eq!(resident, want, "round {round}");
        // This round's loads came in priority order.
        let loads: Vec<u32> = streamer.loaded_order()[before..]
            .iter()
            .map(|k| k.0)
            .collect();
        assert!(
            loads
                .windows(2)
                .all(|w| p[w[0] as usize] > p[w[1] as usize]),
            "round {round}"
        );
        all_loaded.extend(loads);
        // Settled means stable: nothing else loads while the request is unchanged.
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(streamer.stats().loads, stats.loads);
    }
    assert!(streamer.stats().evictions > 0);
    // Lowering the budget evicts at once, lowest priority first.
    streamer.set_ram_budget(10_000);
    let stats = streamer.stats();
    assert!(stats.resident_bytes <= 10_000, "{stats:?}");
    assert_eq!(stats.resident_levels, 10);
    // A budget below one level loads nothing and still settles.
    streamer.set_ram_budget(999);
    streamer.request(&[(0, Level::Hi, 1.0)]).unwrap();
    settle(&streamer);
    assert!(streamer.brick_bytes(0, Level::Hi).unwrap().is_none());
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn unwanted_levels_are_evicted_least_recently_used_first() {
    let (path, _) = streaming_store("stream-lru");
    let streamer = BrickStreamer::open(&path, config(4_000)).unwrap();
    streamer
        .request(&[
            (0, Level::Hi, 4.0),
            (1, Level::Hi, 3.0),
            (2, Level::Hi, 2.0),
            (3, Level::Hi, 1.0),
        ])
        .unwrap();
    settle(&streamer);
    assert_eq!(streamer.stats().resident_levels, 4);
    // Use 0 and 2 (most recent: 2), then want two new bricks: 1 and 3 go first (LRU), not 0, 2.
    assert!(streamer.brick_bytes(0, Level::Hi).unwrap().is_some());
    assert!(streamer.brick_bytes(2, Level::Hi).unwrap().is_some());
    streamer
        .request(&[(10, Level::Hi, 1.0), (11, Level::Hi, 0.5)])
        .unwrap();
    settle(&streamer);
    let mut resident: Vec<u32> = streamer.resident().iter().map(|k| k.0).collect();
    resident.sort_unstable();
    assert_eq!(resident, vec![0, 2, 10, 11]);
    // Unwanted but cached levels are still served.
    assert!(streamer.brick_bytes(0, Level::Hi).unwrap().is_some());
    // Wanted, resident levels are not evicted for lower-priority ones.
    streamer
        .request(&[
            (10, Level::Hi, 9.0),
            (11, Level::Hi, 8.0),
            (0, Level::Hi, 7.0),
            (2, Level::Hi, 6.0),
            (20, Level::Hi, 1.0),
        ])
        .unwrap();
    settle(&streamer);
    let mut resident: Vec<u32> = streamer.resident().iter().map(|k| k.0).collect();
    resident.sort_unstable();
    assert_eq!(resident, vec![0, 2, 10, 11]);
    assert!(streamer.brick_bytes(20, Level::Hi).unwrap().is_none());
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn requests_validate_dedupe_and_order_ties_stably() {
    let (path, _) = streaming_store("stream-request");
    let streamer = BrickStreamer::open(&path, config(1 << 20)).unwrap();
    assert!(matches!(
        streamer.request(&[(0, Level::Hi, 1.0), (512, Level::Lo, 1.0)]),
        Err(StoreError::BrickOutOfRange {
            brick: 512,
            count: 512
        })
    ));
    assert!(matches!(
        streamer.brick_bytes(600, Level::Hi),
        Err(SourceError::BrickOutOfRange { .. })
    ));
    assert!(matches!(
        streamer.brick_bytes(0, Level::Absent),
        Err(SourceError::AbsentLevel { .. })
    ));
    streamer
        .request(&[
            (5, Level::Hi, f32::NAN),
            (3, Level::Lo, 1.0),
            (4, Level::Absent, 9.0),
            (1, Level::Lo, 1.0),
            (3, Level::Lo, 0.5),
            (2, Level::Hi, 2.0),
        ])
        .unwrap();
    settle(&streamer);
    assert_eq!(
        streamer.loaded_order(),
        vec![
            (2, Level::Hi),
            (3, Level::Lo),
            (1, Level::Lo),
            (5, Level::Hi)
        ]
    );
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn fallback_levels_use_what_is_loaded() {
    let (path, volume) = streaming_store("stream-fallback");
    let streamer = BrickStreamer::open(&path, config(1 << 20)).unwrap();
    let mut wanted = vec![Level::Absent; 512];
    wanted[0] = Level::Hi;
    wanted[1] = Level::Hi;
    wanted[2] = Level::Lo;
    wanted[3] = Level::Hi;
    wanted[4] = Level::Lo;
    // Nothing loaded yet: all absent.
    assert!(fallback_levels(&wanted, &streamer)
        .iter()
        .all(|l| *l == Level::Absent));
    streamer
        .request(&[
            (0, Level::Hi, 3.0),
            (1, Level::Lo, 2.0),
            (2, Level::Lo, 1.0),
            (3, Level::Hi, 1.0),
        ])
        .unwrap();
    settle(&streamer);
    let got = fallback_levels(&wanted, &streamer);
    assert_eq!(
        &got[..5],
        &[Level::Hi, Level::Lo, Level::Lo, Level::Hi, Level::Absent]
    );
    assert!(got[5..].iter().all(|l| *l == Level::Absent));
    // An in-memory source has everything.
    let memory = VolumeBrickSource::new(volume, 8, DownsampleFilter::Mean2).unwrap();
    assert_eq!(fallback_levels(&wanted, &memory), wanted);
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn request_plan_loads_low_res_fallbacks_first() {
    let wanted = [Level::Hi, Level::Lo, Level::Absent, Level::Hi, Level::Lo];
    let priority = [1.0, 5.0, 9.0, 3.0, f32::NAN];
    let plan = request_plan(&wanted, &priority);
    let keys: Vec<(u32, Level)> = plan.iter().map(|&(b, l, _)| (b, l)).collect();
    assert_eq!(
        keys,
        vec![
            (1, Level::Lo),
            (3, Level::Lo),
            (0, Level::Lo),
            (4, Level::Lo),
            (3, Level::Hi),
            (0, Level::Hi),
        ]
    );
    assert!(plan.windows(2).all(|w| w[0].2 > w[1].2));
}

#[test]
fn failed_loads_are_reported_not_retried_and_drop_joins() {
    let (path, _) = streaming_store("stream-fail");
    let streamer = BrickStreamer::open(&path, config(1 << 20)).unwrap();
    // Cut the file under the open store: the last bricks can no longer be read.
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(streamer.store().header().data_offset + 10_000)
        .unwrap();
    streamer
        .request(&[(0, Level::Hi, 2.0), (511, Level::Hi, 1.0)])
        .unwrap();
    settle(&streamer);
    assert!(streamer.brick_bytes(0, Level::Hi).unwrap().is_some());
    match streamer.brick_bytes(511, Level::Hi) {
        Err(SourceError::Load {
            brick: 511, source, ..
        }) => {
            assert!(matches!(
                source.downcast_ref::<StoreError>(),
                Some(StoreError::Io { .. })
            ))
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(streamer.stats().failures, 1);
    assert!(!streamer.is_loaded(511, Level::Hi));
    streamer.clear_failures();
    settle(&streamer);
    assert_eq!(
        streamer.stats().failures,
        1,
        "retried once after clearing, failed again"
    );
    // Dropping while busy returns promptly.
    let (path2, _) = streaming_store("stream-drop");
    let busy = BrickStreamer::open(&path2, config(64 << 20)).unwrap();
    let all: Vec<_> = (0..512).map(|b| (b, Level::Hi, 0.0)).collect();
    busy.request(&all).unwrap();
    let start = Instant::now();
    drop(busy);
    // Generous: a hang guard (the loader finishes at most one in-flight read before it exits).
    assert!(start.elapsed() < Duration::from_secs(20));
    drop(streamer);
    std::fs::remove_file(&path).unwrap();
    std::fs::remove_file(&path2).unwrap();
}
