//! Streaming a level store in the background (issue 19, item 4): `LevelStreamer` reads the
//! wanted stored bricks in priority order under its RAM budget, keeps failures, and
//! `VolumeSource::LevelStream` steps its camera plan only onto bricks already in RAM, reaching
//! the plan a synchronous source draws at once, frame for frame, under the validation layers.

mod common;

use common::levels::textured_volume;
use common::Rng;
use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::cache::{block_bricks, stored_bricks_per_axis, SlotGeometry};
use mixvol::reference::{self, LevelField, LevelReferenceCache};
use mixvol::renderer::{MixedConfig, Renderer, ResidencyConfig, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::{
    write_level_store, LevelStore, LevelStreamConfig, LevelStreamer, StoreError, StoredKey,
};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

const N: u32 = 8;
const W: u32 = 48;
const WAIT: Duration = Duration::from_secs(60);

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!(
        "mixvol-level-stream-{name}-{}.mvl",
        std::process::id()
    ))
}

/// A textured f32 store of `dims` at `path`.
fn write_store(path: &PathBuf, dims: UVec3, seed: u64) -> Arc<LevelStore> {
    let volume = textured_volume(&mut Rng(seed), dims);
    write_level_store(
        path,
        &volume,
        N,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    Arc::new(LevelStore::open(path).unwrap())
}

/// Every stored brick of `level`, as `(level, linear index of its first brick)`.
fn stored_keys(grid: &BrickGrid, level: u32) -> Vec<StoredKey> {
    let s = stored_bricks_per_axis(grid.bricks_per_axis(), level);
    let mut keys = Vec::new();
    for z in 0..s.z {
        for y in 0..s.y {
            for x in 0..s.x {
                let first = UVec3::new(x, y, z) * block_bricks(level);
                keys.push((level, grid.linear_index(first)));
            }
        }
    }
    keys
}

fn ready(streamer: &LevelStreamer, keys: &[StoredKey]) -> Vec<bool> {
    keys.iter().map(|&k| streamer.is_ready(k)).collect()
}

/// The loader reads the wanted bricks in priority order and stops at the first that does not
/// fit; a new request evicts what is no longer wanted first, then wanted bricks of lower
/// priority than the one to read, never one of higher priority; the bytes are the file's; a
/// lower budget evicts at once; `read_now` reads a missing brick on the caller's thread.
#[test]
fn the_streamer_keeps_the_highest_priority_prefix_that_fits_its_budget() {
    let path = temp_path("budget");
    let store = write_store(&path, UVec3::new(4 * N, 3 * N, 4 * N), 0x5713_0001);
    let grid = store.grid();
    let keys = stored_keys(&grid, 0);
    assert_eq!(keys.len(), 48);
    let brick_bytes = store.header().stored_bytes(0) as usize;
    // Room for four level-0 bricks and a bit.
    let budget = 4 * brick_bytes + brick_bytes / 2;
    let streamer = LevelStreamer::new(
        store.clone(),
        LevelStreamConfig {
            ram_budget_bytes: budget,
            ..LevelStreamConfig::default()
        },
    )
    .unwrap();
    streamer.request(&keys[..10]);
    assert!(streamer.wait_idle(WAIT));
    let expect: Vec<bool> = (0..10).map(|i| i < 4).collect();
    assert_eq!(ready(&streamer, &keys[..10]), expect, "the first four fit");
    let stats = streamer.stats();
    assert_eq!(
        (stats.loads, stats.evictions, stats.blocking_reads),
        (4, 0, 0)
    );
    assert!(stats.peak_bytes <= budget && stats.resident_bytes == 4 * brick_bytes);
    for &key in &keys[..4] {
        let bytes = streamer.get(key).unwrap().unwrap();
        let file = store
            .read_stored_bytes(key.0, grid.brick_coords(key.1))
            .unwrap();
        assert_eq!(&bytes[..], &file[..], "{key:?} holds the file's bytes");
    }

    // New wanted bricks take the room of the unwanted ones.
    streamer.request(&keys[20..24]);
    assert!(streamer.wait_idle(WAIT));
    assert_eq!(ready(&streamer, &keys[20..24]), vec![true; 4]);
    assert_eq!(ready(&streamer, &keys[..4]), vec![false; 4]);
    assert_eq!(streamer.stats().evictions, 4);

    // A new brick of highest priority evicts the lowest-priority wanted one, never a higher one.
    let mut order = vec![keys[30]];
    order.extend_from_slice(&keys[20..24]);
    streamer.request(&order);
    assert!(streamer.wait_idle(WAIT));
    assert_eq!(
        ready(&streamer, &order),
        vec![true, true, true, true, false]
    );
    // One of lowest priority cannot evict those above it: it waits.
    let mut order = keys[20..23].to_vec();
    order.push(keys[30]);
    order.push(keys[40]);
    streamer.request(&order);
    assert!(streamer.wait_idle(WAIT));
    assert_eq!(
        ready(&streamer, &order),
        vec![true, true, true, true, false]
    );
    let stats = streamer.stats();
    assert!(stats.peak_bytes <= budget, "{stats:?}");
    assert_eq!((stats.wanted_bricks, stats.wanted_resident), (5, 4));

    // A lower budget evicts at once, from the lowest priority up.
    streamer.set_ram_budget(2 * brick_bytes);
    assert_eq!(
        ready(&streamer, &order),
        vec![true, true, false, false, false]
    );
    assert!(streamer.stats().resident_bytes <= 2 * brick_bytes);

    // A brick in RAM comes from RAM; a missing one is read on this thread, and counted.
    let before = streamer.stats().blocking_reads;
    streamer.read_now(keys[20]).unwrap();
    assert_eq!(streamer.stats().blocking_reads, before);
    let bytes = streamer.read_now(keys[47]).unwrap();
    assert_eq!(streamer.stats().blocking_reads, before + 1);
    let file = store
        .read_stored_bytes(0, grid.brick_coords(keys[47].1))
        .unwrap();
    assert_eq!(&bytes[..], &file[..]);
    drop(streamer);
    let _ = std::fs::remove_file(&path);
}

/// Random requests over every level's stored bricks (duplicates, reordering, bricks of
/// different sizes), budget changes and reads: after the loader settles, the highest-priority
/// prefix of each request that fits the budget is in RAM, the bytes in RAM never exceed the
/// budget, the counters agree with what `is_ready` reports, and every brick returned holds the
/// file's bytes.
#[test]
fn random_requests_keep_the_budget_and_the_priority_prefix() {
    let path = temp_path("random");
    let store = write_store(&path, UVec3::new(4 * N, 3 * N, 4 * N), 0x5713_0004);
    let grid = store.grid();
    let all: Vec<StoredKey> = (0..store.level_count())
        .flat_map(|level| stored_keys(&grid, level))
        .collect();
    let bytes = |key: StoredKey| store.header().stored_bytes(key.0) as usize;
    let mut rng = Rng(0x5713_0005);
    let mut budget = 6 * bytes((0, 0));
    let streamer = LevelStreamer::new(
        store.clone(),
        LevelStreamConfig {
            ram_budget_bytes: budget,
            ..LevelStreamConfig::default()
        },
    )
    .unwrap();
    for round in 0..60 {
        if round % 10 == 9 {
            budget = (2 + (rng.next() % 10) as usize) * bytes((0, 0));
            streamer.set_ram_budget(budget);
        }
        let count = 1 + (rng.next() % 24) as usize;
        let request: Vec<StoredKey> = (0..count)
            .map(|_| all[(rng.next() % all.len() as u64) as usize])
            .collect();
        streamer.request(&request);
        assert!(
            streamer.wait_idle(WAIT),
            "round {round}: the loader settles"
        );
        // The request without duplicates, in priority order.
        let mut seen = std::collections::HashSet::new();
        let wanted: Vec<StoredKey> = request.into_iter().filter(|k| seen.insert(*k)).collect();
        let mut sum = 0;
        for &key in &wanted {
            sum += bytes(key);
            if sum > budget {
                break;
            }
            assert!(
                streamer.is_ready(key),
                "round {round}: {key:?} of the prefix is in RAM"
            );
        }
        let stats = streamer.stats();
        assert!(stats.resident_bytes <= budget, "round {round}: {stats:?}");
        assert_eq!(stats.wanted_bricks, wanted.len());
        let ready = wanted.iter().filter(|&&k| streamer.is_ready(k)).count();
        assert_eq!(stats.wanted_resident, ready, "round {round}: {stats:?}");
        assert_eq!(stats.failures, 0);
        let key = wanted[(rng.next() % wanted.len() as u64) as usize];
        if let Some(got) = streamer.get(key) {
            let file = store
                .read_stored_bytes(key.0, grid.brick_coords(key.1))
                .unwrap();
            assert_eq!(&got.unwrap()[..], &file[..], "round {round}: {key:?}");
        }
    }
    let stats = streamer.stats();
    assert!(stats.evictions > 0 && stats.loads > 60, "{stats:?}");
    drop(streamer);
    let _ = std::fs::remove_file(&path);
}

/// A stored brick whose bytes no longer match their CRC fails its background read: the error
/// names the level and is kept (not read again) until `clear_failures`; the other bricks load.
#[test]
fn a_failed_background_read_is_kept_and_named() {
    let path = temp_path("damage");
    let store = write_store(&path, UVec3::new(2 * N, 2 * N, 2 * N), 0x5713_0002);
    let data_offset = store.header().data_offset as usize;
    drop(store);
    // A texel of level 0's first stored brick.
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[data_offset + 5] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let store = Arc::new(LevelStore::open(&path).unwrap());
    let keys = stored_keys(&store.grid(), 0);
    let streamer = LevelStreamer::new(store, LevelStreamConfig::default()).unwrap();
    streamer.request(&keys);
    assert!(streamer.wait_idle(WAIT));
    match streamer.get(keys[0]) {
        Some(Err(e)) => assert!(
            matches!(*e, StoreError::StoredBrickChecksum { level: 0, .. }),
            "{e}"
        ),
        other => panic!("expected the checksum error, got {other:?}"),
    }
    match streamer.read_now(keys[0]) {
        Err(e @ StoreError::EarlierReadFailed { level: 0, .. }) => {
            assert!(e.to_string().contains("CRC-32"), "{e}")
        }
        other => panic!("expected the kept error, got {other:?}"),
    }
    assert!(keys[1..].iter().all(|&k| streamer.is_ready(k)));
    let stats = streamer.stats();
    assert_eq!((stats.failures, stats.loads), (1, keys.len() as u64 - 1));
    // Not read again until the failures are cleared (review M3: no read happens, the kept
    // error stays), then read once more: with the file repaired, it loads.
    streamer.request(&keys);
    assert!(streamer.wait_idle(WAIT));
    let stats = streamer.stats();
    assert_eq!((stats.failures, stats.loads), (1, keys.len() as u64 - 1));
    assert!(streamer.first_failure().is_some());
    bytes[data_offset + 5] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    streamer.clear_failures();
    streamer.request(&keys);
    assert!(streamer.wait_idle(WAIT));
    let stats = streamer.stats();
    assert_eq!((stats.failures, stats.loads), (0, keys.len() as u64));
    let expected = LevelStore::open(&path)
        .unwrap()
        .read_stored_bytes(0, UVec3::ZERO)
        .unwrap();
    match streamer.get(keys[0]) {
        Some(Ok(got)) => assert_eq!(&got[..], &expected[..]),
        other => panic!("the repaired brick did not load: {other:?}"),
    }
    assert!(streamer.first_failure().is_none());
    drop(streamer);
    let _ = std::fs::remove_file(&path);
}

fn config() -> MixedConfig {
    MixedConfig {
        brick_size: N,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 64 << 20,
        transition: Transition::Smooth,
        max_levels: 0,
    }
}

fn camera() -> Camera {
    Camera::perspective(Vec3::new(1.1, 0.8, 1.5), Vec3::ZERO, 40.0)
}

fn settings() -> RenderSettings {
    RenderSettings {
        samples_per_voxel: 1.5,
        ..RenderSettings::default()
    }
}

fn renderer_for(ctx: &mixvol::gpu::GpuContext, source: VolumeSource<'_>) -> Renderer {
    let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
    let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap();
    renderer.set_transfer_function(&tf).unwrap();
    renderer.set_source(source).unwrap();
    renderer
}

/// The CPU reference frame of `renderer`'s current levels over the grids read back from `store`.
fn reference_frame(renderer: &Renderer, store: &LevelStore) -> Vec<Vec4> {
    let grids = store.read_grids().unwrap();
    let levels = renderer.brick_levels().unwrap().to_vec();
    let field = LevelField::new(&store.grid(), &grids, &levels).unwrap();
    let geometry = SlotGeometry::new(N, 3, UVec3::splat(128)).unwrap();
    let cpu = LevelReferenceCache::build(&field, &geometry, Transition::Smooth).unwrap();
    let params = renderer.params(&camera(), &settings(), W, W).unwrap();
    let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
    reference::render_mixed(&cpu.view(), Transition::Smooth, &tf, &params)
}

/// A streamed store never waits on the disk when the camera plans: the first plan after
/// attaching has nothing in RAM and keeps the drawn levels; as the reader catches up the source
/// steps under a small upload budget to exactly the plan a synchronous store draws at once, its frame equal to that source's and to the CPU reference, and no stored
/// brick was read on the render thread after attaching.
#[test]
fn a_streamed_level_store_steps_onto_bricks_in_ram_and_reaches_the_camera_plan() {
    // Drawn voxels of at most a pixel and a half: enough level-0 bricks that the smallest
    // upload budget takes several steps.
    const TARGET_PX: f32 = 1.5;
    let ctx = common::validated_context();
    {
        let path = temp_path("gpu");
        let store = write_store(&path, UVec3::new(6 * N, 5 * N, 6 * N), 0x5713_0003);
        let streamer =
            Arc::new(LevelStreamer::new(store.clone(), LevelStreamConfig::default()).unwrap());
        let mut streamed = renderer_for(
            &ctx,
            VolumeSource::LevelStream {
                streamer: streamer.clone(),
                levels: &[],
                config: config(),
            },
        );
        let mut direct = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &[],
                config: config(),
            },
        );
        // The smallest upload budget (`MIN_STEP_BRICKS` level-0 stored bricks of 12^3 f32: a
        // step also uploads again the level-0 bricks whose neighbours it refines): the
        // streamed source takes several steps.
        let budget: u64 = mixvol::embed::MIN_STEP_BRICKS * 12 * 12 * 12 * 4;
        streamed.set_residency_config(ResidencyConfig {
            upload_bytes_per_frame: budget,
            ..ResidencyConfig::default()
        });
        let coarsest = streamed.brick_levels().unwrap().to_vec();
        let at_attach = streamer.stats().blocking_reads;
        assert!(at_attach >= 1, "attaching reads the coarsest level");

        let choice =
            common::step_levels(&mut streamed, &camera(), &settings(), W, W, TARGET_PX).unwrap();
        assert_eq!(streamed.brick_levels().unwrap(), &coarsest[..]);
        assert!(choice.waiting > 0, "the camera wants finer levels");
        common::step_levels(&mut direct, &camera(), &settings(), W, W, TARGET_PX).unwrap();
        let wanted = direct.brick_levels().unwrap().to_vec();
        assert_eq!(choice.levels, wanted);
        let distinct: std::collections::BTreeSet<_> = wanted.iter().flatten().collect();
        assert!(distinct.len() >= 2, "the camera mixes levels: {distinct:?}");

        let mut previous = coarsest;
        let mut steps = 0;
        loop {
            assert!(streamer.wait_idle(WAIT));
            let choice =
                common::step_levels(&mut streamed, &camera(), &settings(), W, W, TARGET_PX)
                    .unwrap();
            steps += 1;
            // A hard cap (review H2), re-fixed and moved bricks included.
            let update = streamed.last_level_update().unwrap();
            assert!(
                update.uploaded_bytes as u64 <= budget,
                "step {steps} uploads {} bytes: {update:?}",
                update.uploaded_bytes
            );
            let now = streamed.brick_levels().unwrap().to_vec();
            assert_ne!(now, previous, "step {steps} moves: the reader caught up");
            previous = now;
            if choice.waiting == 0 {
                break;
            }
            assert!(steps < 16, "the streamed source converges");
        }
        assert_eq!(previous, wanted);
        assert!(
            steps >= 2,
            "the small upload budget takes several steps: {steps}"
        );
        let stats = streamer.stats();
        assert_eq!(stats.blocking_reads, at_attach, "{stats:?}");
        assert_eq!(stats.failures, 0);
        let a = streamed.render(&camera(), &settings(), W, W).unwrap();
        let b = direct.render(&camera(), &settings(), W, W).unwrap();
        let same = common::diff(&a.pixels, &b.pixels, 1.0 / 255.0);
        eprintln!("streamed against direct: {same:?}");
        assert!(same.max < 1e-5, "streamed and direct frames: {same:?}");
        // The tolerances of `tests/gpu_mixed.rs` for an f32 cache.
        let d = common::diff(&a.pixels, &reference_frame(&streamed, &store), 1.0 / 255.0);
        assert!(
            d.mean < 1e-3 && d.max < 6.0 / 255.0 && d.large_fraction < 0.005,
            "GPU frame against the CPU reference: {d:?}"
        );
        drop((streamed, direct));
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// `ResidencyConfig::ram_bytes` cuts a level source's request list (the planner's RAM budget,
/// issue 36): the background reader then reads at most that many bytes of stored bricks, while
/// without the cut the same view asks for more.
#[test]
fn the_ram_budget_cuts_the_request_list() {
    let ctx = common::validated_context();
    {
        let path = temp_path("ram_cut");
        let store = write_store(&path, UVec3::new(6 * N, 5 * N, 6 * N), 0x5713_0004);
        let mut read = Vec::new();
        for ram_bytes in [None, Some(40_000u64)] {
            let streamer =
                Arc::new(LevelStreamer::new(store.clone(), LevelStreamConfig::default()).unwrap());
            let mut renderer = renderer_for(
                &ctx,
                VolumeSource::LevelStream {
                    streamer: streamer.clone(),
                    levels: &[],
                    config: config(),
                },
            );
            renderer.set_residency_config(ResidencyConfig {
                ram_bytes,
                ..ResidencyConfig::default()
            });
            let before = streamer.stats().bytes_read;
            common::step_levels(&mut renderer, &camera(), &settings(), W, W, 1.5).unwrap();
            assert!(streamer.wait_idle(WAIT));
            let stats = streamer.stats();
            assert!(stats.wanted_bricks > 0, "{ram_bytes:?}: {stats:?}");
            read.push(stats.bytes_read - before);
        }
        assert!(
            read[0] > 40_000,
            "without the cut the view asks for more: {read:?}"
        );
        assert!(
            read[1] <= 40_000 && read[1] > 0,
            "with the cut the reader reads at most the budget: {read:?}"
        );
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}
