//! Residency changes of the three-level cache upload only what changed (issue 19, item 4):
//! `levels::LevelResidency` keeps every stored brick that stays, uploads the new ones into free
//! sub-slots and the kept ones whose coarser neighbours changed; on the GPU, a renderer moved
//! through many changes draws what a renderer set up afresh at each plan draws.

mod common;

use common::levels::{distance_plan, staircase_plan, textured_volume};
use common::Rng;
use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::cache::{block_bricks, block_origin, SlotGeometry};
use mixvol::levels::LevelResidency;
use mixvol::pyramid::{LevelPlan, PackingError};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::Error;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

const N: u32 = 8;

/// A plan as the cache drew it: the plan, its stored bricks' levels and their (slot, sub-slot).
type Drawn = (LevelPlan, BTreeMap<usize, u32>, BTreeMap<usize, (u32, u32)>);

/// The stored bricks of `plan` (first brick of each drawn block) and their levels.
fn stored_of(grid: &BrickGrid, levels: &[Option<u32>]) -> BTreeMap<usize, u32> {
    let mut out = BTreeMap::new();
    for (i, level) in levels.iter().enumerate() {
        if let Some(level) = *level {
            let b = grid.brick_coords(i);
            if block_origin(b, level) == b {
                out.insert(i, level);
            }
        }
    }
    out
}

/// A random plan that keeps the rules: a staircase from a random corner of the grid (whose
/// extent must be a multiple of the largest block, so that blocks stay aligned when mirrored),
/// or, up to level 2, the distance from a random brick; with a hole now and then (an undrawn
/// brick at level 0-2, so that no block breaks).
fn random_plan(rng: &mut Rng, bricks: UVec3, levels: u32) -> Vec<Option<u32>> {
    let mut plan = if rng.below(2) == 0 {
        let flip = [rng.below(2) == 1, rng.below(2) == 1, rng.below(2) == 1];
        let stairs = staircase_plan(bricks, rng.below(3) as i32 - 1, levels);
        let mirrored = |b: UVec3| {
            let mut m = b;
            for a in 0..3 {
                if flip[a] {
                    m[a] = bricks[a] - 1 - b[a];
                }
            }
            (m.x + bricks.x * (m.y + bricks.y * m.z)) as usize
        };
        (0..stairs.len() as u32)
            .map(|i| {
                let b = UVec3::new(
                    i % bricks.x,
                    (i / bricks.x) % bricks.y,
                    i / (bricks.x * bricks.y),
                );
                stairs[mirrored(b)]
            })
            .collect()
    } else {
        let centre = UVec3::new(
            rng.below(bricks.x),
            rng.below(bricks.y),
            rng.below(bricks.z),
        );
        distance_plan(
            bricks,
            centre.as_ivec3(),
            rng.below(3) as i32 - 1,
            levels.min(3),
        )
    };
    if rng.below(3) == 0 {
        let hole = rng.below(plan.len() as u32) as usize;
        if plan[hole].is_some_and(|l| l <= 2) {
            plan[hole] = None;
        }
    }
    plan
}

/// Level 0 at bricks (1,1,1) and (2,2,2) of a 4^3 grid, level 1 next to them (44 bricks),
/// level 2 beyond (18 bricks).
fn two_centres_plan(grid: &BrickGrid) -> Vec<Option<u32>> {
    let centres = [IVec3::ONE, IVec3::splat(2)];
    (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i).as_ivec3();
            let d = centres
                .iter()
                .map(|c| (b - *c).abs().max_element())
                .min()
                .unwrap();
            Some(d.min(2) as u32)
        })
        .collect()
}

/// Over a long random walk of plans (levels 0-4, block levels included), each change keeps the
/// place of every stored brick that stays, gives new ones places no other stored brick holds,
/// and uploads exactly the new stored bricks and the kept ones whose block's coarser bits
/// changed; a plan staged twice uploads nothing the second time.
#[test]
fn a_change_uploads_exactly_the_new_bricks_and_those_whose_neighbours_changed() {
    let mut rng = Rng(0x0001_e7e1_2e51_0001);
    let grid = BrickGrid::new(UVec3::new(8 * N, 8 * N, 4 * N), N).unwrap();
    let bricks = grid.bricks_per_axis();
    // 1000 slots: every plan fits, so no change needs a fresh packing.
    let geometry = SlotGeometry::new(N, 3, UVec3::splat(128)).unwrap();
    let mut residency = LevelResidency::new(&geometry, grid.brick_count());
    let mut previous: Option<Drawn> = None;
    let (mut kept_total, mut refixed_total) = (0, 0);
    for change in 0..60 {
        let levels = if change % 10 == 9 {
            previous.as_ref().unwrap().0.brick_levels().to_vec()
        } else {
            random_plan(&mut rng, bricks, 5)
        };
        let plan = LevelPlan::new(&grid, 5, &levels).unwrap();
        let update = residency.update(&plan, &geometry).unwrap();
        let stored = stored_of(&grid, &levels);
        assert_eq!(
            update
                .packing
                .stored
                .iter()
                .copied()
                .collect::<BTreeSet<_>>(),
            stored.keys().copied().collect()
        );
        // Places: one stored brick per sub-slot, of its own level.
        let mut places = BTreeMap::new();
        for (&i, &level) in &stored {
            let p = update.packing.places[i].unwrap();
            assert_eq!(p.level, level);
            assert!(places.insert(i, (p.slot, p.index)).is_none());
        }
        let distinct: BTreeSet<_> = places.values().collect();
        assert_eq!(
            distinct.len(),
            places.len(),
            "change {change}: two bricks share a sub-slot"
        );
        // Every brick of a block has the block's place.
        for (i, level) in levels.iter().enumerate() {
            if let Some(level) = *level {
                let first = grid.linear_index(block_origin(grid.brick_coords(i), level));
                assert_eq!(update.packing.places[i], update.packing.places[first]);
            }
        }
        let expected_upload: BTreeSet<usize> = match &previous {
            None => stored.keys().copied().collect(),
            Some((old_plan, old_stored, old_places)) => {
                assert!(!update.repacked, "change {change}: the cache has room");
                stored
                    .iter()
                    .filter(|&(&i, &level)| {
                        if old_stored.get(&i) != Some(&level) {
                            return true;
                        }
                        assert_eq!(
                            old_places[&i], places[&i],
                            "change {change}: a kept brick moved"
                        );
                        kept_total += 1;
                        let first = grid.brick_coords(i);
                        let end = (first + UVec3::splat(block_bricks(level))).min(bricks);
                        let refixed = (first.z..end.z).any(|z| {
                            (first.y..end.y).any(|y| {
                                (first.x..end.x).any(|x| {
                                    let j = grid.linear_index(UVec3::new(x, y, z));
                                    plan.coarser_bits(j) != old_plan.coarser_bits(j)
                                })
                            })
                        });
                        refixed_total += usize::from(refixed);
                        refixed
                    })
                    .map(|(&i, _)| i)
                    .collect()
            }
        };
        let upload: BTreeSet<usize> = update.upload.iter().copied().collect();
        assert_eq!(upload, expected_upload, "change {change}");
        if change % 10 == 9 {
            assert!(upload.is_empty(), "the same plan again uploads nothing");
        }
        previous = Some((plan, stored, places));
    }
    assert!(
        kept_total > 1000 && refixed_total > 0 && refixed_total < kept_total / 2,
        "the walk keeps bricks ({kept_total}) and re-fixes some ({refixed_total})"
    );
}

/// When the free sub-slots cannot take a change (the kept level-1 bricks leave too few empty
/// slots for the new ones), the bricks of the emptiest level-1 slot move into the others: a
/// few bricks uploaded at new places instead of the whole cache. After a change that was staged
/// but never drawn (`invalidate`), everything is packed afresh.
#[test]
fn a_change_the_free_sub_slots_cannot_take_moves_a_few_bricks() {
    let grid = BrickGrid::new(UVec3::new(4 * N, 4 * N, 4 * N), N).unwrap();
    // 5 x 2 x 1 = 10 slots of 12^3.
    let geometry = SlotGeometry::new(N, 3, UVec3::new(64, 32, 16)).unwrap();
    assert_eq!(geometry.slot_count(), 10);
    let mut residency = LevelResidency::new(&geometry, grid.brick_count());
    // Every brick at level 1: 64 bricks in slots 0-7.
    let all_one = vec![Some(1); grid.brick_count()];
    let first = residency
        .update(&LevelPlan::new(&grid, 3, &all_one).unwrap(), &geometry)
        .unwrap();
    assert!(first.repacked);
    let before = first.packing.places.clone();
    // Level 0 at bricks (1,1,1) and (2,2,2), level 1 next to them (44 bricks, one or more in
    // each of slots 0-7), level 2 beyond (18 bricks): 2 + 6 + 1 = 9 slots when packed afresh,
    // but only slots 8 and 9 are empty for the three new ones.
    let two_centres = two_centres_plan(&grid);
    let plan = LevelPlan::new(&grid, 3, &two_centres).unwrap();
    let update = residency.update(&plan, &geometry).unwrap();
    assert!(!update.repacked);
    let new: BTreeSet<usize> = (0..grid.brick_count())
        .filter(|&i| two_centres[i] != Some(1))
        .collect();
    assert_eq!(new.len(), 2 + 18);
    let upload: BTreeSet<usize> = update.upload.iter().copied().collect();
    assert!(upload.is_superset(&new));
    // Kept bricks are uploaded again when they moved or their coarser neighbours changed; the
    // moves empty one level-1 slot (at most 8 bricks); the others stay where they were.
    let moved: Vec<usize> = (0..grid.brick_count())
        .filter(|&i| two_centres[i] == Some(1) && update.packing.places[i] != before[i])
        .collect();
    assert!(!moved.is_empty() && moved.len() <= 8, "moved {moved:?}");
    assert!(moved.iter().all(|i| upload.contains(i)));
    assert!(upload.len() < 64, "{} of 64 uploaded", upload.len());
    let used: BTreeSet<u32> = update
        .packing
        .places
        .iter()
        .flatten()
        .map(|p| p.slot)
        .collect();
    assert!(used.len() <= 10);
    // The same plan again uploads nothing; after an invalidation, everything.
    let again = residency.update(&plan, &geometry).unwrap();
    assert!(!again.repacked && again.upload.is_empty());
    residency.invalidate();
    let fresh = residency.update(&plan, &geometry).unwrap();
    assert!(fresh.repacked);
    assert_eq!(fresh.upload.len(), 2 + 44 + 18);
}

/// On the GPU: a renderer moved through random changes (each uploading only what changed)
/// draws, after every change, what a renderer set up afresh at that plan draws, under the
/// validation layers; in a roomy cache and in a tight one (10 slots) where bricks must move to
/// make room. The changes upload fewer bricks than they draw.
#[test]
fn incremental_changes_draw_what_a_fresh_cache_draws() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x0001_e7e1_2e51_0002);
        let volume = textured_volume(&mut rng, UVec3::new(4 * N, 4 * N, 4 * N));
        let bricks = UVec3::splat(4);
        let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
        let camera = Camera::perspective(Vec3::new(1.2, 0.9, 1.4), Vec3::ZERO, 40.0);
        let settings = RenderSettings::default();
        // 72^3 f32 texels: a 64^3 cache of 125 slots; 128 KiB: 64 x 32 x 16, 10 slots.
        for (name, budget) in [("roomy", 72 * 72 * 72 * 4), ("tight", 64 * 32 * 16 * 4)] {
            let config = MixedConfig {
                brick_size: N,
                filter: DownsampleFilter::Mean2,
                cache_budget_bytes: budget,
                transition: Transition::Smooth,
                max_levels: 0,
            };
            let start = staircase_plan(bricks, 0, 4);
            let mut moving = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            moving.set_transfer_function(&tf).unwrap();
            moving
                .set_source(VolumeSource::Levels {
                    volume: Arc::new(volume.clone()),
                    levels: &start,
                    config,
                })
                .unwrap();
            let mut fresh = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            fresh.set_transfer_function(&tf).unwrap();
            let (mut stored, mut uploaded, mut moved, mut drawn) = (0, 0, 0, 0);
            // The tight cache starts with every brick at level 1 (slots 0-7), then a plan whose
            // new bricks only fit once a level-1 slot is emptied.
            let grid = BrickGrid::new(volume.dims(), N).unwrap();
            let mut scripted = if name == "tight" {
                vec![vec![Some(1); 64], two_centres_plan(&grid)]
            } else {
                Vec::new()
            };
            scripted.reverse();
            for change in 0..24 {
                let levels = scripted
                    .pop()
                    .unwrap_or_else(|| random_plan(&mut rng, bricks, 4));
                let report = match moving.set_brick_levels(&levels) {
                    Ok(report) => report,
                    // More slots than the tight cache has: refused, the drawn plan kept.
                    Err(Error::Packing(PackingError::OverBudget { needed, slots, .. })) => {
                        assert_eq!(name, "tight", "change {change}");
                        assert!(
                            needed > u64::from(slots),
                            "{needed} slots, {slots} in the cache"
                        );
                        continue;
                    }
                    Err(e) => panic!("{name} change {change}: refused for another reason: {e}"),
                };
                // The first change finds the source's own upload not yet recorded: it packs
                // afresh; every later one moves what it must.
                assert_eq!(report.repacked, drawn == 0, "{name} change {change}");
                drawn += 1;
                stored += report.stored_bricks;
                uploaded += report.uploaded_bricks;
                moved += report.moved_bricks;
                let a = moving.render(&camera, &settings, 40, 40).unwrap();
                fresh
                    .set_source(VolumeSource::Levels {
                        volume: Arc::new(volume.clone()),
                        levels: &levels,
                        config,
                    })
                    .unwrap();
                let b = fresh.render(&camera, &settings, 40, 40).unwrap();
                let d = common::diff(&a.pixels, &b.pixels, 1e-4);
                assert!(
                    d.max < 1e-4,
                    "{name} change {change}: moved and fresh caches differ: {d:?}"
                );
            }
            eprintln!(
                "{name}: {drawn} changes uploaded {uploaded} of {stored} drawn stored bricks \
                 ({moved} moved)"
            );
            assert!(drawn >= 12, "{name}: most plans fit");
            assert!(
                uploaded < stored,
                "{name}: changes upload less than they draw"
            );
            if name == "tight" {
                assert!(moved > 0, "the tight cache moves bricks to make room");
            }
        }
    }
    common::finish(ctx);
}
