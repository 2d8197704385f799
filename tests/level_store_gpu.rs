//! Drawing a level store (issue 19, item 4): `VolumeSource::LevelStore` reads every drawn brick
//! from the file, and its frames equal those of the same volume drawn from RAM
//! (`VolumeSource::Levels`) and the CPU reference over the levels read back from the store, at
//! host-set levels, after residency changes and at levels chosen from the camera, under the
//! validation layers.

mod common;

use common::levels::{staircase_plan, textured_volume};
use common::Rng;
use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::DownsampleFilter;
use mixvol::bricks::Level;
use mixvol::cache::{classes_for_levels, CacheGeometry, SlotGeometry};
use mixvol::pyramid::LevelGrid;
use mixvol::reference::{self, LevelField, LevelReferenceCache};
use mixvol::renderer::{Frame, MixedConfig, Renderer, ResidencyConfig, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::{write_level_store, LevelStore};
use mixvol::volume::{ScalarType, SyntheticField, Volume, VoxelData};
use std::path::PathBuf;
use std::sync::Arc;

const N: u32 = 8;
const W: u32 = 48;

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!(
        "mixvol-level-store-gpu-{name}-{}.mvl",
        std::process::id()
    ))
}

/// `volume` written as a level store of every level (Mean2) at a fresh temporary `name`, and
/// opened.
fn stored(volume: &Volume, name: &str) -> (PathBuf, Arc<LevelStore>) {
    let path = temp_path(name);
    write_level_store(
        &path,
        volume,
        N,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    let store = Arc::new(LevelStore::open(&path).unwrap());
    (path, store)
}

fn config(budget: u64) -> MixedConfig {
    MixedConfig {
        brick_size: N,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: budget,
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

/// The CPU reference frame of `renderer`'s current levels over the grids read back from `store`.
fn reference_frame(renderer: &Renderer, store: &LevelStore) -> Vec<Vec4> {
    let grids = store.read_grids().unwrap();
    let levels = renderer.brick_levels().unwrap().to_vec();
    let field = LevelField::new(&store.grid(), &grids, &levels).unwrap();
    // The slot classes the pass's cache has for the store's levels (two for two levels).
    let classes = classes_for_levels(store.level_count());
    let geometry = SlotGeometry::new(N, classes, UVec3::splat(128)).unwrap();
    // The cache holds the store's scalar type: the mirror rounds its texels alike.
    let scalar = store.header().scalar;
    let cpu = LevelReferenceCache::build_stored_as(&field, &geometry, Transition::Smooth, scalar)
        .unwrap();
    let params = renderer.params(&camera(), &settings(), W, W).unwrap();
    let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
    reference::render_mixed(&cpu.view(), Transition::Smooth, &tf, &params)
}

/// The tolerances of `tests/gpu_mixed.rs` for a GPU frame against the reference: those of an
/// f32 cache, and for a u8 cache those of its u8 frames (lavapipe filters 8-bit textures in
/// 8-bit fixed point).
fn assert_matches(name: &str, frame: &Frame, expected: &[Vec4]) {
    assert_matches_within(name, frame, expected, (1e-3, 6.0 / 255.0, 0.005));
}

fn assert_matches_u8(name: &str, frame: &Frame, expected: &[Vec4]) {
    assert_matches_within(
        name,
        frame,
        expected,
        (1.5e-3 + 0.5 / 255.0, 6.5 / 255.0, 0.01),
    );
}

fn assert_matches_within(
    name: &str,
    frame: &Frame,
    expected: &[Vec4],
    (mean, max, large): (f32, f32, f32),
) {
    let d = common::diff(&frame.pixels, expected, 1.0 / 255.0);
    eprintln!("{name}: {d:?}");
    assert!(
        d.mean < mean && d.max < max && d.large_fraction < large,
        "{name}: GPU frame differs from the reference: {d:?}"
    );
    let covered = expected.iter().filter(|p| p.w > 0.05).count();
    assert!(
        covered > expected.len() / 10,
        "{name}: the frame shows the volume"
    );
}

fn renderer_for(ctx: &mixvol::gpu::GpuContext, source: VolumeSource<'_>) -> Renderer {
    let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
    let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap();
    renderer.set_transfer_function(&tf).unwrap();
    renderer.set_source(source).unwrap();
    renderer
}

/// An f32 volume drawn from its level store gives the very frames it gives from RAM, at a
/// five-level staircase, after moving to other levels, and at the levels the camera chooses;
/// each matches the CPU reference over the store's levels.
#[test]
fn a_level_store_draws_as_the_volume_in_ram() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0001);
        let volume = textured_volume(&mut rng, UVec3::new(4 * N, 4 * N, 3 * N));
        let (path, store) = stored(&volume, "f32");
        assert_eq!(store.level_count(), 5);
        let bricks = store.grid().bricks_per_axis();
        let budget = 96 * 96 * 48 * 4;
        let plans = [
            ("staircase", staircase_plan(bricks, 0, 5)),
            ("staircase shifted", staircase_plan(bricks, 1, 5)),
            ("coarsest", vec![Some(4); store.grid().brick_count()]),
        ];
        let mut from_store = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &plans[0].1,
                config: config(budget),
            },
        );
        let mut from_ram = renderer_for(
            &ctx,
            VolumeSource::Levels {
                volume: Arc::new(volume.clone()),
                levels: &plans[0].1,
                config: config(budget),
            },
        );
        for (name, levels) in &plans {
            from_store.set_brick_levels(levels).unwrap();
            from_ram.set_brick_levels(levels).unwrap();
            let a = from_store.render(&camera(), &settings(), W, W).unwrap();
            let b = from_ram.render(&camera(), &settings(), W, W).unwrap();
            assert_eq!(a.pixels, b.pixels, "{name}: store and RAM frames are equal");
            assert_matches(name, &a, &reference_frame(&from_store, &store));
        }
        // Levels chosen from the camera (four pixels per drawn voxel wanted: a mix of levels).
        common::step_levels(&mut from_store, &camera(), &settings(), W, W, 4.0).unwrap();
        common::step_levels(&mut from_ram, &camera(), &settings(), W, W, 4.0).unwrap();
        let chosen = from_store.brick_levels().unwrap().to_vec();
        assert_eq!(Some(chosen.as_slice()), from_ram.brick_levels());
        let distinct: std::collections::BTreeSet<_> = chosen.iter().flatten().collect();
        assert!(distinct.len() >= 2, "the camera mixes levels: {distinct:?}");
        let a = from_store.render(&camera(), &settings(), W, W).unwrap();
        let b = from_ram.render(&camera(), &settings(), W, W).unwrap();
        assert_eq!(a.pixels, b.pixels, "camera: store and RAM frames are equal");
        assert_matches("camera", &a, &reference_frame(&from_store, &store));
        drop((from_store, from_ram));
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// A u8 store (a quarter of the bytes) draws its rounded levels through a u8 cache (a quarter
/// of the GPU memory): the frame matches the CPU reference over the levels read back, its
/// texels rounded as the cache rounds them; a store of other bricks than the config's is
/// refused.
#[test]
fn a_u8_level_store_matches_the_reference_of_its_levels() {
    let ctx = common::validated_context();
    {
        let volume: Volume = SyntheticField::MarschnerLobb
            .generate(UVec3::new(4 * N, 3 * N, 4 * N), ScalarType::U8)
            .unwrap();
        let (path, store) = stored(&volume, "u8");
        let bricks = store.grid().bricks_per_axis();
        let levels = staircase_plan(bricks, 0, store.level_count());
        let renderer = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &levels,
                config: config(96 * 96 * 48 * 4),
            },
        );
        let mut renderer = renderer;
        let frame = renderer.render(&camera(), &settings(), W, W).unwrap();
        assert_matches_u8("u8 staircase", &frame, &reference_frame(&renderer, &store));
        // 128 KiB of u8 texels hold 50 slots of 12^3 (64 x 64 x 32): every one of the 48 bricks
        // at level 0 fits, which 128 KiB of f32 texels (10 slots) would not hold.
        renderer
            .set_source(VolumeSource::LevelStore {
                store: store.clone(),
                levels: &vec![Some(0); store.grid().brick_count()],
                config: config(128 << 10),
            })
            .unwrap();
        let frame = renderer.render(&camera(), &settings(), W, W).unwrap();
        assert_matches_u8(
            "u8 all level 0",
            &frame,
            &reference_frame(&renderer, &store),
        );
        let wrong = MixedConfig {
            brick_size: 16,
            ..config(96 * 96 * 48 * 4)
        };
        let err = renderer
            .set_source(VolumeSource::LevelStore {
                store: store.clone(),
                levels: &levels,
                config: wrong,
            })
            .unwrap_err();
        assert!(err.to_string().contains("bricks of 8"), "{err}");
        drop(renderer);
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// A stored brick that cannot be read (a CRC mismatch) never aborts a view (issue 36): the
/// camera planner reads it once, counts it (`LevelChoice::failed_reads`), keeps it out of every
/// later step, and its region keeps drawing a coarser level; the frame equals the CPU reference
/// of the levels drawn, over the volume's own levels.
#[test]
fn an_unreadable_stored_brick_falls_back_and_is_counted() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0009);
        let volume = textured_volume(&mut rng, UVec3::new(4 * N, 4 * N, 3 * N));
        let path = temp_path("damaged");
        write_level_store(
            &path,
            &volume,
            N,
            None,
            DownsampleFilter::Mean2,
            &mut |_, _| {},
        )
        .unwrap();
        let data_offset = LevelStore::open(&path).unwrap().header().data_offset as usize;
        // A texel of the first stored brick: level 0, brick 0.
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[data_offset + 5] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        let store = Arc::new(LevelStore::open(&path).unwrap());
        assert!(
            store.read_stored(0, UVec3::ZERO).is_err(),
            "brick 0 is damaged"
        );
        assert!(store.read_stored(0, UVec3::new(1, 0, 0)).is_ok());
        let mut renderer = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &[],
                config: config(96 * 96 * 48 * 4),
            },
        );
        // Near brick 0's corner, fine voxels: brick 0 is wanted at level 0.
        let camera = Camera::perspective(Vec3::new(-1.0, -0.8, -1.2), Vec3::ZERO, 40.0);
        let (mut failed, mut last) = (0, Vec::new());
        let mut settled = None;
        for step in 0..12 {
            let choice = common::step_levels(&mut renderer, &camera, &settings(), W, W, 0.5)
                .unwrap_or_else(|e| panic!("step {step}: a failed read aborted the view: {e}"));
            failed += choice.failed_reads;
            let now = renderer.brick_levels().unwrap().to_vec();
            assert_ne!(now[0], Some(0), "step {step}: brick 0 drawn at level 0");
            if now == last {
                settled = Some(choice);
                break;
            }
            last = now;
        }
        let choice = settled.expect("the steps settle");
        assert_eq!(
            choice.levels[0],
            Some(0),
            "the camera wants brick 0 at level 0"
        );
        assert_eq!(failed, 1, "the damaged brick is read once, then kept out");
        assert!(choice.waiting >= 1, "brick 0 waits: {choice:?}");
        let drawn = renderer.brick_levels().unwrap().to_vec();
        assert!(drawn[0].is_some(), "brick 0 draws a coarser level");
        let level0 = drawn.iter().filter(|l| **l == Some(0)).count();
        assert!(level0 >= 4, "the rest refines: {level0} bricks at level 0");

        let frame = renderer.render(&camera, &settings(), W, W).unwrap();
        let grids =
            LevelGrid::vertex_pyramid(&volume, store.level_count(), DownsampleFilter::Mean2);
        let field = LevelField::new(&store.grid(), &grids, &drawn).unwrap();
        let geometry = SlotGeometry::new(N, 3, UVec3::splat(128)).unwrap();
        let cpu = LevelReferenceCache::build(&field, &geometry, Transition::Smooth).unwrap();
        let params = renderer.params(&camera, &settings(), W, W).unwrap();
        let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
        let expected = reference::render_mixed(&cpu.view(), Transition::Smooth, &tf, &params);
        assert_matches("around the damaged brick", &frame, &expected);
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// Two levels through the one level system take the two-level cache's slots (issue 36): a
/// store of two levels gets a cache of two slot classes, `(n+2)^3` slots, so a budget in
/// which the two-level cache holds every brick at level 0, and a cache of `(n+4)^3` slots does
/// not, draws every brick at level 0. Its frames, at level 0 everywhere and at a checker of
/// levels 0 and 1, match the CPU reference over the store's levels (mirrored with two
/// classes) and the two-level cache's frames of the same volume (`VolumeSource::Mixed`,
/// `Hi`/`Lo`), level 1 built by `Mean2` or by `Box4`, and so does the volume in memory capped at
/// two levels (`MixedConfig::max_levels`, the same slots); a store of five levels in the same
/// budget cannot draw every brick at level 0.
#[test]
fn two_levels_take_the_two_level_caches_slots() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0002);
        let volume = textured_volume(&mut rng, UVec3::new(4 * N, 4 * N, 3 * N));
        let count = 48;
        // 64 x 32 x 32 f32 texels: 6 x 3 x 3 = 54 slots of 10^3, but 5 x 2 x 2 = 20 of 12^3.
        let budget = 64 * 32 * 32 * 4;
        let two = CacheGeometry::choose(N, 4, budget, 4096, count).unwrap();
        let three = SlotGeometry::choose(N, 3, 4, budget, 4096, count).unwrap();
        assert!(two.slot_count() >= count && three.slot_count() < count);
        let two_classes = SlotGeometry::choose(N, 2, 4, budget, 4096, count).unwrap();
        assert_eq!(two_classes.slot_count(), two.slot_count());

        // Level 1 by the default filter and by a wider one, recorded in the store.
        for filter in [DownsampleFilter::Mean2, DownsampleFilter::Box4] {
            let path = temp_path("two-levels");
            write_level_store(&path, &volume, N, Some(2), filter, &mut |_, _| {}).unwrap();
            let store = Arc::new(LevelStore::open(&path).unwrap());
            assert_eq!(store.filter(), filter);
            assert_eq!(store.level_count(), 2);
            let bricks = store.grid().bricks_per_axis();
            let finest = vec![Some(0); count as usize];
            let checker: Vec<Option<u32>> = (0..count)
                .map(|i| {
                    let b = UVec3::new(
                        i % bricks.x,
                        (i / bricks.x) % bricks.y,
                        i / (bricks.x * bricks.y),
                    );
                    Some((b.x + b.y + b.z) % 2)
                })
                .collect();
            let mut from_store = renderer_for(
                &ctx,
                VolumeSource::LevelStore {
                    store: store.clone(),
                    levels: &finest,
                    config: config(budget),
                },
            );
            let mut two_level = renderer_for(
                &ctx,
                VolumeSource::Mixed {
                    volume: Arc::new(volume.clone()),
                    config: MixedConfig {
                        filter,
                        ..config(budget)
                    },
                },
            );
            let mut in_memory = renderer_for(
                &ctx,
                VolumeSource::Levels {
                    volume: Arc::new(volume.clone()),
                    levels: &finest,
                    config: MixedConfig {
                        filter,
                        max_levels: 2,
                        ..config(budget)
                    },
                },
            );
            assert_eq!(in_memory.level_slot_count(), Some(two.slot_count() as u64));
            for (name, levels) in [
                ("level 0", &finest),
                ("checker of levels 0 and 1", &checker),
            ] {
                from_store.set_brick_levels(levels).unwrap();
                in_memory.set_brick_levels(levels).unwrap();
                let hi_lo: Vec<Level> = levels
                    .iter()
                    .map(|l| if *l == Some(0) { Level::Hi } else { Level::Lo })
                    .collect();
                two_level.set_levels(&hi_lo).unwrap();
                let a = from_store.render(&camera(), &settings(), W, W).unwrap();
                let b = two_level.render(&camera(), &settings(), W, W).unwrap();
                assert_matches(name, &a, &reference_frame(&from_store, &store));
                let d = common::diff(&a.pixels, &b.pixels, 1.0 / 255.0);
                assert!(
                    d.max < 1e-4,
                    "{name} ({filter:?}): the one system and the two-level cache draw the same \
                 frame: {d:?}"
                );
                let c = in_memory.render(&camera(), &settings(), W, W).unwrap();
                let d = common::diff(&c.pixels, &b.pixels, 1.0 / 255.0);
                assert!(
                    d.max < 1e-4,
                    "{name} ({filter:?}): the volume in memory at two levels draws the two-level \
                     cache's frame: {d:?}"
                );
            }
            drop((from_store, two_level, in_memory));
            let _ = std::fs::remove_file(&path);
        }

        // Five levels in the same budget: slots of 12^3, too few for every brick at level 0.
        let (path, store) = stored(&volume, "five-levels");
        let coarsest = vec![Some(store.level_count() - 1); count as usize];
        let mut five = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &coarsest,
                config: config(budget),
            },
        );
        let err = five
            .set_brick_levels(&vec![Some(0); count as usize])
            .unwrap_err()
            .to_string();
        assert!(err.contains("slots"), "{err}");
        drop(five);
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// A level store given no levels is planned by every render, as a two-level source is
/// (`VolumePass::update` inside the render's own submission): with the default options the slots
/// decide (50 slots for 144 bricks: a quarter at level 0), each frame uploads at most the
/// per-frame cap (and the frame's GPU timing covers that upload), the report counts bricks per
/// level and those still waiting, the frames converge (nothing waits, nothing uploads) to a
/// plan that fills the slots and draws what the CPU reference draws for its levels; the same
/// levels a caller sets (`set_brick_levels`) stop the renders' own planning.
#[test]
fn a_level_store_given_no_levels_is_planned_by_every_render() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0005);
        let volume = textured_volume(&mut rng, UVec3::new(6 * N, 6 * N, 4 * N));
        let (path, store) = stored(&volume, "planned");
        let count = store.grid().brick_count();
        // About 80 slots of 12^3 f32 texels for 144 bricks (the image holds 50).
        let budget = 80 * 12 * 12 * 12 * 4;
        let mut renderer = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &[],
                config: config(budget),
            },
        );
        assert!(renderer.is_planned());
        let cap = 27 * 12 * 12 * 12 * 4;
        renderer.set_residency_config(ResidencyConfig {
            upload_bytes_per_frame: cap,
            ..ResidencyConfig::default()
        });
        let slots = renderer.level_slot_count().unwrap();
        let mut settled = None;
        for frame in 0..40 {
            let f = renderer.render(&camera(), &settings(), W, W).unwrap();
            let report = f.residency.clone().expect("a planned frame reports");
            assert!(
                report.residency.uploaded_bytes as u64 <= cap,
                "frame {frame}: {} bytes over the cap {cap}",
                report.residency.uploaded_bytes
            );
            if report.residency.uploaded_bytes > 0 {
                assert!(
                    f.timing.gpu_upload_ms.is_some(),
                    "frame {frame}: upload timed"
                );
            }
            assert_eq!(report.per_level.len(), store.level_count() as usize);
            let drawn = renderer.brick_levels().unwrap().to_vec();
            for (level, counts) in report.per_level.iter().enumerate() {
                let at = drawn.iter().filter(|l| **l == Some(level as u32)).count();
                assert_eq!(counts.drawn, at, "frame {frame} level {level}");
            }
            let wanted: usize = report.per_level.iter().map(|c| c.wanted).sum();
            assert_eq!(wanted + report.plan.culled + report.plan.dropped, count);
            assert!(report.plan.slots_used as u64 <= slots);
            if report.waiting == 0 && report.residency.uploaded_bytes == 0 {
                settled = Some((frame, report, f));
                break;
            }
        }
        let (frame, report, f) = settled.expect("the planned renders converge");
        assert!(
            frame >= 2,
            "the cap spreads the uploads over frames: {frame}"
        );
        assert!(
            report.per_level[0].drawn > 0 && report.per_level[0].drawn < count,
            "the slots decide how much is drawn at level 0: {:?}",
            report.per_level
        );
        // Budget-driven: one more level-0 brick would not fit (a slot holds one level-0 brick).
        assert!(
            report.plan.slots_used as u64 + 1 > slots - 8,
            "the plan fills the slots: {} of {slots}",
            report.plan.slots_used
        );
        assert_matches("converged", &f, &reference_frame(&renderer, &store));
        let converged = renderer.brick_levels().unwrap().to_vec();
        // `Renderer::update` steps the same residency without drawing: a second renderer
        // reaches the same levels under the same cap, still planned, and its next render
        // uploads nothing and draws what the reference draws.
        let mut stepped = renderer_for(
            &ctx,
            VolumeSource::LevelStore {
                store: store.clone(),
                levels: &[],
                config: config(budget),
            },
        );
        stepped.set_residency_config(ResidencyConfig {
            upload_bytes_per_frame: cap,
            ..ResidencyConfig::default()
        });
        let mut updates = 0;
        loop {
            let report = stepped.update(&camera(), &settings(), W, W).unwrap();
            assert!(report.residency.uploaded_bytes as u64 <= cap);
            updates += 1;
            if report.waiting == 0 && report.residency.uploaded_bytes == 0 {
                break;
            }
            assert!(updates < 40, "updates converge");
        }
        assert_eq!(updates, frame + 1, "one step per update, as per render");
        assert!(stepped.is_planned());
        assert_eq!(stepped.brick_levels().unwrap(), &converged[..]);
        let f = stepped.render(&camera(), &settings(), W, W).unwrap();
        let report = f.residency.as_ref().expect("still planned");
        assert_eq!(report.residency.uploaded_bytes, 0, "{report:?}");
        assert_matches("stepped", &f, &reference_frame(&stepped, &store));
        drop(stepped);
        // Levels the caller sets take over: renders draw them and plan no more.
        let coarsest = vec![Some(store.level_count() - 1); count];
        renderer.set_brick_levels(&coarsest).unwrap();
        assert!(!renderer.is_planned());
        let f = renderer.render(&camera(), &settings(), W, W).unwrap();
        assert!(f.residency.is_none());
        assert_eq!(renderer.brick_levels().unwrap(), &coarsest[..]);
        drop(renderer);
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// Issue 36, item 2 ("a cache too small drops the least important bricks, never an error"): a
/// volume left to the camera (no levels given) whose cache cannot hold even the coarsest plan
/// is attached with nothing drawn, not refused; the first planned render draws the bricks that
/// fit (the rest counted as dropped) and matches the CPU reference for what it draws.
#[test]
fn a_cache_too_small_for_the_coarsest_plan_starts_empty_and_drops_bricks() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0007);
        // 6 x 6 x 4 bricks at two levels (two slot classes): the coarsest plan needs 18 slots
        // of 10^3 f32 texels (4000 bytes); the cache gets 8.
        let volume = Arc::new(textured_volume(&mut rng, UVec3::new(6 * N, 6 * N, 4 * N)));
        let config = MixedConfig {
            max_levels: 2,
            ..config(8 * 4000)
        };
        let mut renderer = renderer_for(
            &ctx,
            VolumeSource::Levels {
                volume: volume.clone(),
                levels: &[],
                config,
            },
        );
        let slots = renderer.level_slot_count().unwrap();
        assert!(slots < 18, "{slots} slots");
        assert!(
            renderer.brick_levels().unwrap().iter().all(Option::is_none),
            "nothing drawn before the first update"
        );
        let frame = renderer.render(&camera(), &settings(), W, W).unwrap();
        let report = frame.residency.as_ref().expect("planned");
        let drawn: usize = report.per_level.iter().map(|l| l.drawn).sum();
        assert!(drawn > 0 && report.plan.dropped > 0, "{report:?}");
        assert!(report.plan.slots_used as u64 <= slots, "{report:?}");
        // The CPU reference at the drawn levels, over the same two levels written to a store.
        let path = temp_path("too-small");
        write_level_store(
            &path,
            &volume,
            N,
            Some(2),
            DownsampleFilter::Mean2,
            &mut |_, _| {},
        )
        .unwrap();
        let store = LevelStore::open(&path).unwrap();
        assert_matches("dropped", &frame, &reference_frame(&renderer, &store));
        drop(renderer);
        let _ = std::fs::remove_file(&path);
    }
    common::finish(ctx);
}

/// Review M6: the renderer's own level cache, probed at points (`Renderer::probe_field`,
/// the ray-caster's functions): after each of several camera-driven steps (incremental uploads,
/// bricks moved to make room, partial re-fixups) the field at brick faces and inside bricks
/// equals the CPU mirror of the same levels (`LevelReferenceCache`) within 2e-3 for an f32
/// store and is C0 (points a thousandth of a voxel apart differ by the field's slope only);
/// for a u8 store it stays within lavapipe's 8-bit filtering of the mirror built from the u8
/// texels, and jumps across faces by no more than that filtering and the half step
/// `docs/cache-layout.md` allows (lavapipe's 1/255 output rounding hides the half step itself).
#[test]
fn the_renderers_level_cache_probes_as_its_cpu_mirror() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1e7e_1570_6900_0008);
        let dims = UVec3::new(6 * N, 5 * N, 4 * N);
        for scalar in [ScalarType::F32, ScalarType::U8] {
            let volume = textured_volume(&mut rng, dims);
            let volume = if scalar == ScalarType::U8 {
                // The same texture in [0, 1], stored as u8.
                let VoxelData::F32(values) = volume.data() else {
                    unreachable!()
                };
                let bytes = values.iter().map(|v| (v * 255.0).round() as u8).collect();
                Volume::new(dims, Vec3::ONE, VoxelData::U8(bytes)).unwrap()
            } else {
                volume
            };
            let (path, store) = stored(&volume, &format!("probe-{scalar:?}"));
            // A cache for about half the bricks at level 0: steps move and re-fix bricks.
            let bytes = scalar.size_bytes() as u64;
            let budget = 70 * 12 * 12 * 12 * bytes;
            let mut renderer = renderer_for(
                &ctx,
                VolumeSource::LevelStore {
                    store: store.clone(),
                    levels: &[],
                    config: config(budget),
                },
            );
            renderer.set_residency_config(ResidencyConfig {
                upload_bytes_per_frame: 40 * 12 * 12 * 12 * bytes,
                ..ResidencyConfig::default()
            });
            let grids = store.read_grids().unwrap();
            let classes = classes_for_levels(store.level_count());
            let geometry = SlotGeometry::new(N, classes, UVec3::splat(128)).unwrap();
            let (mut worst, mut jump) = (0.0f32, 0.0f32);
            for step in 0..6 {
                let angle = step as f32 * 0.9;
                let camera = Camera::perspective(
                    Vec3::new(1.4 * angle.cos(), 0.7, 1.4 * angle.sin()),
                    Vec3::ZERO,
                    40.0,
                );
                // Render (plans, uploads, fixes up), then probe what the cache holds.
                renderer.render(&camera, &settings(), W, W).unwrap();
                let levels = renderer.brick_levels().unwrap().to_vec();
                let field = LevelField::new(&store.grid(), &grids, &levels).unwrap();
                let mirror = LevelReferenceCache::build_stored_as(
                    &field,
                    &geometry,
                    Transition::Smooth,
                    scalar,
                )
                .unwrap();
                let points = common::critical_points(&mut rng, N, dims, 1500);
                let gpu = renderer.probe_field(&points).unwrap();
                for (p, g) in points.iter().zip(&gpu) {
                    let cpu = reference::sample_mixed(&mirror.view(), *p, Transition::Smooth);
                    match (g, cpu) {
                        (Some(g), Some(c)) => worst = worst.max((g - c).abs()),
                        (g, c) => assert_eq!(
                            g.is_some(),
                            c.is_some(),
                            "{scalar:?} step {step} {p}: residency differs"
                        ),
                    }
                }
                // Jumps across faces: the same points nudged both ways along five directions.
                let eps = 1e-3f32;
                let mut pairs = Vec::new();
                for p in &points {
                    for d in [
                        Vec3::X,
                        Vec3::Y,
                        Vec3::Z,
                        Vec3::ONE,
                        Vec3::new(1.0, -1.0, 1.0),
                    ] {
                        pairs.push(*p + eps * d);
                        pairs.push(*p - eps * d);
                    }
                }
                let values = renderer.probe_field(&pairs).unwrap();
                for pair in values.chunks_exact(2) {
                    if let (Some(a), Some(b)) = (pair[0], pair[1]) {
                        jump = jump.max((a - b).abs());
                    }
                }
            }
            eprintln!("{scalar:?}: largest |gpu - cpu mirror| {worst}, largest jump {jump}");
            // Measured 2026-12-07: f32 1.1e-6 and a largest jump of 1.3e-3; u8 1.44/255 and
            // 2/255.
            let (bound, jump_bound) = match scalar {
                // C0: a jump only of the field's slope (at most about 0.75 per voxel in every
                // direction here) over the 2 * sqrt(3) * eps between the two points.
                ScalarType::F32 => (2e-3, 5e-3),
                // lavapipe filters UNORM8 texels in 8-bit fixed point and rounds what it returns
                // to 1/255: up to 1.5 steps from the mirror, and two such roundings across a
                // face, on top of the half step a transition may jump by.
                _ => (2.5 / 255.0, 2.5 / 255.0),
            };
            assert!(worst < bound, "{scalar:?}: {worst} >= {bound}");
            assert!(jump < jump_bound, "{scalar:?}: jump {jump} >= {jump_bound}");
            drop(renderer);
            let _ = std::fs::remove_file(&path);
        }
    }
    common::finish(ctx);
}
