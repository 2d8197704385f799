//! The level of every brick from the camera for any number of levels (`plan::choose_levels`,
//! issue 19): the plans keep the one-level rule and the blocks, meet the on-screen target they
//! report, fit the cache, get finer with more slots, and leave culled bricks undrawn unless a
//! drawn block covers them.

mod common;

use common::levels::textured_volume;
use common::Rng;
use glam::{UVec3, Vec3};
use mixvol::bricks::DownsampleFilter;
use mixvol::bricks::{BrickGrid, ValueRange};
use mixvol::cache::{block_bricks, block_origin, slots_for_plan};
use mixvol::lod::{BrickGeometry, LodView};
use mixvol::plan::{
    choose_levels, level_margin, LevelChoiceError, LevelChooser, LevelRequest, PlanOptions,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// Counts the allocations of each thread (the tests of this file run on several threads).
struct CountingAllocator;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: every call is passed on to the system allocator unchanged; the count is a
// thread-local `Cell` with a const initialiser, which does not allocate.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
        // SAFETY: the caller's layout, passed on.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// Allocations this thread has made so far.
fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}
use mixvol::pyramid::LevelGrid;
use mixvol::reference::LevelField;
use mixvol::scene::Camera;

const N: u32 = 8;
const LEVELS: u32 = 5;

fn geometry(bricks: UVec3) -> BrickGeometry {
    BrickGeometry::new(BrickGrid::new(bricks * N, N).unwrap(), Vec3::ONE).unwrap()
}

fn random_camera(rng: &mut Rng) -> Camera {
    let eye = Vec3::new(rng.unit(), rng.unit(), rng.unit()) * 3.0 - Vec3::splat(1.5);
    let target = Vec3::new(rng.unit(), rng.unit(), rng.unit()) * 0.6 - Vec3::splat(0.3);
    Camera::perspective(eye, target, 30.0 + 40.0 * rng.unit())
}

/// The on-screen size of a hi-res voxel at the nearest point of `brick`, as the chooser sees it.
fn hi_res_pixels(geometry: &BrickGeometry, view: &LodView, brick: UVec3) -> f32 {
    let (min, max) = geometry.brick_box(brick);
    let voxel = geometry.voxel_size().max_element();
    let distance = (min - view.eye())
        .max(view.eye() - max)
        .max(Vec3::ZERO)
        .length();
    voxel * view.pixels_per_world_unit(distance.max(voxel))
}

#[test]
fn chosen_plans_keep_the_rule_and_the_blocks_and_meet_their_target() {
    let mut rng = Rng(0x91a4_0001);
    let bricks = UVec3::new(16, 12, 10);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let volume = textured_volume(&mut rng, bricks * N);
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let active = vec![true; grid.brick_count()];
    let mut levels_seen = [false; LEVELS as usize];
    for round in 0..24 {
        let camera = random_camera(&mut rng);
        let view = LodView::new(&camera, 128, 96).unwrap();
        let slots = [2, 8, 64, 100_000][round % 4];
        let choice = choose_levels(&geometry, &view, &active, LEVELS, slots, 1.5)
            .unwrap_or_else(|e| panic!("round {round}: {e}"));
        // The rule and the blocks: the level field accepts the plan.
        LevelField::new(&grid, &grids, &choice.levels)
            .unwrap_or_else(|e| panic!("round {round}: {e}"));
        assert!(
            choice.slots <= slots,
            "round {round}: {} slots of {slots}",
            choice.slots
        );
        assert_eq!(choice.slots, slots_for_plan(bricks, &choice.levels));
        assert!(choice.pixels_per_voxel >= 1.5);
        let undrawn = choice.levels.iter().filter(|l| l.is_none()).count();
        assert_eq!(
            undrawn, choice.dropped,
            "round {round}: only dropped bricks go undrawn"
        );
        // The largest drawn voxel of a coarser-than-full brick in view.
        let mut largest = 0.0f32;
        for (i, b) in grid.bricks().enumerate() {
            let Some(level) = choice.levels[i] else {
                continue;
            };
            levels_seen[level as usize] = true;
            let (min, max) = geometry.brick_box(b);
            if view.box_outside_frustum(min, max) {
                continue;
            }
            // A drawn voxel of a brick in view projects to at most the reported size, unless
            // the brick is at full resolution already.
            let pixels = hi_res_pixels(&geometry, &view, b) * (1u32 << level) as f32;
            assert!(
                level == 0 || pixels <= choice.pixels_per_voxel * 1.0001,
                "round {round}, brick {b}, level {level}: {pixels} px > {}",
                choice.pixels_per_voxel
            );
            if level > 0 {
                largest = largest.max(pixels);
            }
        }
        // Tight (review M5): when the slots bind, the reported size is what some brick in view
        // draws, within a quarter level (measured 2026-12-07 within 1.1 %, the chooser's
        // 1/64-level buckets, on these 18 binding views); a chooser that gave up (the coarsest
        // plan and an unbounded size) fails here.
        if choice.pixels_per_voxel > 1.5 && largest > 0.0 {
            assert!(
                choice.pixels_per_voxel <= 2f32.powf(0.25) * largest,
                "round {round}: reported {} px, the largest drawn {largest} px",
                choice.pixels_per_voxel
            );
        }
    }
    assert!(
        levels_seen.iter().all(|&s| s),
        "every level chosen somewhere: {levels_seen:?}"
    );
}

#[test]
fn more_slots_give_a_finer_plan_and_enough_slots_meet_the_target() {
    let mut rng = Rng(0x91a4_0002);
    let bricks = UVec3::splat(12);
    let geometry = geometry(bricks);
    let active = vec![true; geometry.grid().brick_count()];
    for _ in 0..8 {
        let camera = random_camera(&mut rng);
        let view = LodView::new(&camera, 200, 200).unwrap();
        let plans: Vec<_> = [4u64, 16, 64, 1_000_000]
            .iter()
            .map(|&slots| choose_levels(&geometry, &view, &active, LEVELS, slots, 1.0).unwrap())
            .collect();
        assert!(plans.len() >= 2, "the larger budgets fit");
        for pair in plans.windows(2) {
            assert!(pair[1].dropped <= pair[0].dropped);
            for (coarse, fine) in pair[0].levels.iter().zip(&pair[1].levels) {
                // A brick dropped in the smaller cache may be drawn at any level in the larger.
                assert!(
                    coarse.is_none() || fine.is_some_and(|f| Some(f) <= *coarse),
                    "a larger budget never coarsens or drops a brick: {coarse:?} -> {fine:?}"
                );
            }
            // A cache that drops bricks may draw the rest finer: compare targets without drops.
            if pair[0].dropped == 0 {
                assert!(pair[1].pixels_per_voxel <= pair[0].pixels_per_voxel);
            }
        }
        let roomy = plans.last().unwrap();
        assert_eq!(
            roomy.pixels_per_voxel, 1.0,
            "a roomy cache meets the target itself"
        );
    }
}

#[test]
fn culled_bricks_are_drawn_only_inside_a_drawn_block() {
    let bricks = UVec3::splat(16);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    // Far away: everything coarse, in blocks of 4^3 at level 4.
    let camera = Camera::perspective(Vec3::new(0.0, 0.0, 40.0), Vec3::ZERO, 30.0);
    let view = LodView::new(&camera, 64, 64).unwrap();
    // Active: one brick of the first 4^3 block, and nothing else.
    let mut active = vec![false; grid.brick_count()];
    active[grid.linear_index(UVec3::new(1, 2, 3))] = true;
    let choice = choose_levels(&geometry, &view, &active, LEVELS, 64, 1.0).unwrap();
    for (i, b) in grid.bricks().enumerate() {
        match choice.levels[i] {
            Some(level) => {
                assert_eq!(
                    block_origin(b, level),
                    UVec3::ZERO,
                    "{b} is drawn at {level}"
                );
                assert_eq!(block_bricks(level), 4);
            }
            None => assert!(b.max_element() >= 4, "{b} inside the active brick's block"),
        }
    }
    assert_eq!(choice.levels.iter().flatten().count(), 64);
    assert_eq!(choice.slots, 1);
    // Nothing active: nothing drawn.
    let none = vec![false; grid.brick_count()];
    let choice = choose_levels(&geometry, &view, &none, LEVELS, 1, 1.0).unwrap();
    assert!(choice.levels.iter().all(Option::is_none));
    assert_eq!(choice.slots, 0);
}

#[test]
fn bad_choices_are_refused() {
    let geometry = geometry(UVec3::splat(4));
    let count = geometry.grid().brick_count();
    let active = vec![true; count];
    let camera = Camera::perspective(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 40.0);
    let view = LodView::new(&camera, 64, 64).unwrap();
    assert_eq!(
        choose_levels(&geometry, &view, &active[1..], 3, 10, 1.0).unwrap_err(),
        LevelChoiceError::ActiveCount {
            given: count - 1,
            bricks: count
        }
    );
    assert!(matches!(
        choose_levels(&geometry, &view, &active, 0, 10, 1.0),
        Err(LevelChoiceError::Levels { levels: 0, .. })
    ));
    assert_eq!(
        choose_levels(&geometry, &view, &active, 3, 10, f32::NAN)
            .unwrap_err()
            .to_string(),
        "the target voxel size on screen must be a positive number of pixels, not NaN"
    );
    // 64 bricks at the coarsest of two levels need 8 slots (8 level-1 bricks a slot): with 7,
    // the 8 least important are dropped, not an error (the order is checked below).
    let choice = choose_levels(&geometry, &view, &active, 2, 7, 1.0).unwrap();
    assert_eq!((choice.slots, choice.dropped), (7, 8));
    assert_eq!(choice.levels.iter().filter(|l| l.is_none()).count(), 8);
    let small =
        BrickGeometry::new(BrickGrid::new(UVec3::splat(16), 4).unwrap(), Vec3::ONE).unwrap();
    let active = vec![true; small.grid().brick_count()];
    assert!(matches!(
        choose_levels(&small, &view, &active, 4, 10, 1.0),
        Err(LevelChoiceError::Levels {
            levels: 4,
            brick_size: 4
        })
    ));
}

/// Hysteresis: a camera that moves a little back and forth across a level boundary (the whole
/// volume in view, so only distances change) flips bricks without it and keeps the previous
/// plan with it; a large move still changes the plan, and with no previous plan the choice is
/// `choose_levels`' own.
#[test]
fn hysteresis_keeps_a_plan_while_the_camera_hovers_at_a_boundary() {
    let bricks = UVec3::new(12, 12, 12);
    let geometry = geometry(bricks);
    let active = vec![true; geometry.grid().brick_count()];
    let choose_with = |distance: f32, previous: &[Option<u32>], margin: f32| {
        let camera = Camera::perspective(Vec3::new(0.0, 0.2, distance), Vec3::ZERO, 70.0);
        let view = LodView::new(&camera, 160, 160).unwrap();
        LevelChooser::new()
            .choose(&LevelRequest {
                geometry: &geometry,
                view: &view,
                active: &active,
                value_ranges: &[],
                levels: LEVELS,
                slots: 1_000_000,
                target_pixels: 1.0,
                previous,
                margin,
            })
            .cloned()
            .unwrap()
    };
    // The default margin: the two-level planner's 10 %, 0.1375 levels.
    let margin = level_margin(PlanOptions::default().hysteresis);
    assert!((margin - 0.1375).abs() < 1e-3, "{margin}");
    let choose = |distance: f32, previous: &[Option<u32>]| choose_with(distance, previous, margin);
    let base = choose(2.5, &[]);
    let camera = Camera::perspective(Vec3::new(0.0, 0.2, 2.5), Vec3::ZERO, 70.0);
    let view = LodView::new(&camera, 160, 160).unwrap();
    assert_eq!(
        base,
        choose_levels(&geometry, &view, &active, LEVELS, 1_000_000, 1.0).unwrap()
    );
    // The smallest move (1 % steps closer) that changes the plan without hysteresis.
    let flip = (1..30)
        .map(|k| 2.5 * (1.0 - 0.01 * k as f32))
        .find(|&d| choose(d, &[]).levels != base.levels)
        .expect("some small move changes the plan");
    assert!(
        flip > 2.5 * 0.85,
        "the first change comes within 15 %: {flip}"
    );
    // With the previous plan: the move keeps it, and so does the way back.
    let kept = choose(flip, &base.levels);
    let moved = choose(flip, &[]);
    let diffs: Vec<_> = (0..kept.levels.len())
        .filter(|&i| kept.levels[i] != base.levels[i])
        .map(|i| (i, base.levels[i], kept.levels[i], moved.levels[i]))
        .collect();
    assert!(
        diffs.is_empty(),
        "hysteresis keeps the plan at {flip}: {diffs:?}"
    );
    assert_eq!(choose(2.5, &kept.levels).levels, base.levels);
    // A large move (twice as close) changes it all the same, to finer levels.
    let near = choose(1.25, &base.levels);
    assert_ne!(near.levels, base.levels);
    assert!(near.levels.iter().zip(&base.levels).all(|(n, b)| n <= b));
    assert_eq!(
        near.levels,
        choose(1.25, &[]).levels,
        "far from any boundary, no difference"
    );
    // The margin is the caller's: none keeps nothing, and a bad one is refused.
    assert_eq!(choose_with(flip, &base.levels, 0.0).levels, moved.levels);
    let camera = Camera::perspective(Vec3::new(0.0, 0.2, 2.5), Vec3::ZERO, 70.0);
    let view = LodView::new(&camera, 160, 160).unwrap();
    for bad in [-0.1, f32::NAN, f32::INFINITY] {
        assert!(matches!(
            LevelChooser::new()
                .choose(&LevelRequest {
                    geometry: &geometry,
                    view: &view,
                    active: &active,
                    value_ranges: &[],
                    levels: LEVELS,
                    slots: 100,
                    target_pixels: 1.0,
                    previous: &[],
                    margin: bad
                })
                .cloned(),
            Err(LevelChoiceError::Hysteresis(_))
        ));
    }
}

/// An orthographic view of the whole volume: every brick's voxels project to the same size, so
/// every brick crosses its level boundary at the same bias, and the bias alone would leave most
/// of a mid-sized cache empty. The chooser then refines bricks as far as the slots allow: the
/// plan fills at least half the cache, never more, and keeps the rule and the blocks.
#[test]
fn the_slots_left_by_the_bias_are_filled() {
    let bricks = UVec3::splat(12);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let mut rng = Rng(0x91a4_0005);
    let volume = textured_volume(&mut rng, bricks * N);
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let active = vec![true; grid.brick_count()];
    let camera = Camera::orthographic(Vec3::new(0.3, 0.2, 6.0), Vec3::ZERO, 1.6);
    let view = LodView::new(&camera, 256, 256).unwrap();
    let finest = choose_levels(&geometry, &view, &active, LEVELS, u64::MAX, 1.0).unwrap();
    let coarsest = choose_levels(&geometry, &view, &active, LEVELS, 1, 1.0).unwrap();
    assert!(
        finest.slots > 8 * coarsest.slots.max(1),
        "{} {}",
        finest.slots,
        coarsest.slots
    );
    let mut filled = 0;
    for slots in [
        finest.slots / 2,
        finest.slots / 4,
        finest.slots / 8,
        3 * coarsest.slots.max(1),
    ] {
        let choice = choose_levels(&geometry, &view, &active, LEVELS, slots, 1.0).unwrap();
        assert!(choice.slots <= slots);
        LevelField::new(&grid, &grids, &choice.levels).unwrap();
        if choice.slots * 2 >= slots {
            filled += 1;
        }
    }
    assert_eq!(filled, 4, "the plans fill every budget");
}

/// With room for every wanted level, a brick is drawn finer than it wants only where it must
/// be: a neighbour one level finer (the rule), or, at a block level's edge, a finer brick in
/// the aligned block of the next level (blocks are uniform). Bricks outside the frustum want the
/// coarsest level, whose block spans the grid; they must not pull the bricks in view finer.
#[test]
fn bricks_are_refined_only_where_the_rule_or_a_block_forces_it() {
    let mut rng = Rng(0x91a4_0006);
    let bricks = UVec3::new(16, 12, 14);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let active = vec![true; grid.brick_count()];
    let index = |b: UVec3| grid.linear_index(b);
    let mut forced = 0;
    for round in 0..12 {
        let camera = random_camera(&mut rng);
        let view = LodView::new(&camera, 160, 120).unwrap();
        let choice = choose_levels(&geometry, &view, &active, LEVELS, u64::MAX, 2.0).unwrap();
        assert_eq!(choice.pixels_per_voxel, 2.0);
        for (i, b) in grid.bricks().enumerate() {
            let (min, max) = geometry.brick_box(b);
            let wanted = if view.box_outside_frustum(min, max) {
                LEVELS - 1
            } else {
                let p = hi_res_pixels(&geometry, &view, b);
                ((2.0 / p).log2().floor().max(0.0) as u32).min(LEVELS - 1)
            };
            let level = choice.levels[i].unwrap();
            assert!(
                level <= wanted,
                "round {round} brick {b}: {level} > {wanted}"
            );
            if level == wanted {
                continue;
            }
            forced += 1;
            let finer_neighbour = (-1..=1).any(|z| {
                (-1..=1).any(|y| {
                    (-1..=1).any(|x| {
                        let n = b.as_ivec3() + glam::IVec3::new(x, y, z);
                        n.cmpge(glam::IVec3::ZERO).all()
                            && n.cmplt(bricks.as_ivec3()).all()
                            && choice.levels[index(n.as_uvec3())] == Some(level - 1)
                    })
                })
            });
            let next = level + 1;
            let finer_in_block = next >= 3 && {
                let block = block_bricks(next);
                let first = b / block * block;
                let end = (first + UVec3::splat(block)).min(bricks);
                (first.z..end.z).any(|z| {
                    (first.y..end.y).any(|y| {
                        (first.x..end.x).any(|x| {
                            choice.levels[index(UVec3::new(x, y, z))].unwrap() <= level
                                && UVec3::new(x, y, z) != b
                        })
                    })
                })
            };
            assert!(
                finer_neighbour || finer_in_block,
                "round {round} brick {b}: level {level} below its wanted {wanted} with no \
                 finer neighbour and no finer brick in its block"
            );
        }
    }
    assert!(forced > 0, "some bricks are forced finer");
}

/// A cache too small for the coarsest plan drops whole blocks of the coarsest level, the least
/// important first, never an error: blocks with no brick in view before any in view, and among
/// those alike the farthest first (the distance of a block's nearest brick to the eye, computed
/// here from the brick boxes); the plan fits and keeps the rules.
#[test]
fn a_cache_too_small_drops_the_least_important_blocks() {
    let mut rng = Rng(0x91a4_0003);
    let bricks = UVec3::new(8, 6, 5);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let volume = textured_volume(&mut rng, bricks * N);
    let active = vec![true; grid.brick_count()];
    for (levels, slots) in [(2u32, 3u64), (2, 1), (3, 1), (1, 50), (2, 0)] {
        let grids = LevelGrid::vertex_pyramid(&volume, levels, DownsampleFilter::Mean2);
        for round in 0..6 {
            let camera = random_camera(&mut rng);
            let view = LodView::new(&camera, 96, 96).unwrap();
            let choice = choose_levels(&geometry, &view, &active, levels, slots, 1.0).unwrap();
            let what = format!("{levels} levels, {slots} slots, round {round}");
            assert!(choice.slots <= slots, "{what}: {} slots", choice.slots);
            assert!(choice.dropped > 0, "{what}: the coarsest plan cannot fit");
            LevelField::new(&grid, &grids, &choice.levels)
                .unwrap_or_else(|e| panic!("{what}: {e}"));
            // Per coarsest block: dropped or drawn, whether a brick is in view, its distance.
            let block = block_bricks(levels - 1);
            let blocks = (bricks + UVec3::splat(block - 1)) / block;
            let mut kept = Vec::new();
            let mut gone = Vec::new();
            for z in 0..blocks.z {
                for y in 0..blocks.y {
                    for x in 0..blocks.x {
                        let first = UVec3::new(x, y, z) * block;
                        let end = (first + UVec3::splat(block)).min(bricks);
                        let (mut in_view, mut distance, mut drawn) = (false, f32::MAX, None);
                        for bz in first.z..end.z {
                            for by in first.y..end.y {
                                for bx in first.x..end.x {
                                    let b = UVec3::new(bx, by, bz);
                                    let (min, max) = geometry.brick_box(b);
                                    in_view |= !view.box_outside_frustum(min, max);
                                    let d = (min - view.eye()).max(view.eye() - max);
                                    distance = distance.min(d.max(Vec3::ZERO).length());
                                    let now = choice.levels[grid.linear_index(b)].is_some();
                                    assert!(
                                        drawn.is_none_or(|d| d == now),
                                        "{what}: a block is dropped whole"
                                    );
                                    drawn = Some(now);
                                }
                            }
                        }
                        let key = (in_view, distance);
                        if drawn == Some(true) {
                            kept.push(key)
                        } else {
                            gone.push(key)
                        }
                    }
                }
            }
            for g in &gone {
                for k in &kept {
                    let more_important = g.0 && !k.0 || g.0 == k.0 && g.1 < k.1 - 1e-4;
                    assert!(!more_important, "{what}: dropped {g:?} before {k:?}");
                }
            }
        }
    }
}

/// A view that wants far finer voxels than any level gives (a tiny target) still gets the
/// coarsest plan when that is all the cache holds: the bias search reaches every brick's
/// coarsest level, however large its hi-res voxels are on screen (it used to stop `levels`
/// levels up and call such a cache too small).
#[test]
fn a_cache_that_holds_the_coarsest_plan_draws_it_whatever_the_target() {
    let bricks = UVec3::new(8, 6, 5);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let active = vec![true; grid.brick_count()];
    let camera = Camera::perspective(Vec3::new(0.9, 0.7, 1.1), Vec3::ZERO, 50.0);
    let view = LodView::new(&camera, 256, 256).unwrap();
    let coarsest = vec![Some(LEVELS - 1); grid.brick_count()];
    let slots = slots_for_plan(bricks, &coarsest);
    for target in [1.0, 1e-3, 1e-6] {
        let choice = choose_levels(&geometry, &view, &active, LEVELS, slots, target).unwrap();
        assert_eq!(choice.dropped, 0, "target {target}: {choice:?}");
        assert!(choice.slots <= slots, "target {target}");
        assert!(
            choice.levels.iter().all(Option::is_some),
            "target {target}: every brick drawn"
        );
    }
}

/// A chooser kept across views (as `VolumePass` keeps one) gives what a fresh one gives, for
/// every view, culling, budget, level count and previous plan in a random sequence: nothing of
/// an earlier choice leaks into a later one, and a repeated call returns the same plan.
#[test]
fn a_kept_chooser_chooses_as_a_fresh_one() {
    let mut rng = Rng(0x91a4_0007);
    let bricks = UVec3::new(11, 9, 13);
    let geometry = geometry(bricks);
    let count = geometry.grid().brick_count();
    let mut chooser = LevelChooser::new();
    let mut previous: Vec<Option<u32>> = Vec::new();
    let mut active = vec![true; count];
    let margin = level_margin(0.1);
    for round in 0..40 {
        let levels = [5, 5, 3, 2, 6][round % 5];
        let slots = [4u64, 40, 400, 1_000_000][rng.below(4) as usize];
        if round % 7 == 3 {
            active = (0..count).map(|_| rng.unit() > 0.3).collect();
        }
        if round % 5 == 0 {
            previous.clear(); // the level count changed: no previous plan
        }
        let camera = random_camera(&mut rng);
        let view = LodView::new(&camera, 120, 90).unwrap();
        let request = LevelRequest {
            geometry: &geometry,
            view: &view,
            active: &active,
            value_ranges: &[],
            levels,
            slots,
            target_pixels: 1.5,
            previous: &previous,
            margin,
        };
        let fresh = LevelChooser::new().choose(&request).cloned().unwrap();
        let kept = chooser.choose(&request).unwrap();
        assert_eq!(*kept, fresh, "round {round}");
        let again = chooser.choose(&request).unwrap();
        assert_eq!(*again, fresh, "round {round}: the same inputs again");
        previous = fresh.levels;
    }
}

/// Once its buffers have grown to the views it has seen, the chooser allocates nothing: an
/// orbit of views chosen a third time (hysteresis against the last plan, the budget binding;
/// the second time, its first view meets a new previous plan) makes no allocation.
#[test]
fn a_kept_chooser_allocates_nothing_in_steady_state() {
    let bricks = UVec3::new(24, 20, 16);
    let geometry = geometry(bricks);
    let count = geometry.grid().brick_count();
    let active: Vec<bool> = (0..count).map(|i| i % 11 != 0).collect();
    let margin = level_margin(0.1);
    let mut chooser = LevelChooser::new();
    let mut previous = vec![None; count];
    let views: Vec<LodView> = (0..8)
        .map(|f| {
            let angle = (f as f32 * 2.0).to_radians();
            let eye = glam::Quat::from_rotation_y(angle) * Vec3::new(0.6, 0.5, 1.2);
            LodView::new(&Camera::perspective(eye, Vec3::ZERO, 45.0), 640, 480).unwrap()
        })
        .collect();
    let mut slots_used = Vec::new();
    for pass in 0..3 {
        let before = allocations();
        for view in &views {
            let choice = chooser
                .choose(&LevelRequest {
                    geometry: &geometry,
                    view,
                    active: &active,
                    value_ranges: &[],
                    levels: LEVELS,
                    slots: 600,
                    target_pixels: 1.0,
                    previous: &previous,
                    margin,
                })
                .unwrap();
            if pass == 0 {
                slots_used.push(choice.slots);
            }
            previous.copy_from_slice(&choice.levels);
        }
        if pass == 2 {
            assert_eq!(allocations() - before, 0, "the third pass allocated");
        }
    }
    assert!(
        slots_used.iter().all(|&s| s > 500 && s <= 600),
        "the budget binds: {slots_used:?}"
    );
}

/// The screen-space error weighs by value (the two-level planner's metric at any level count):
/// bricks whose ranges are all a quarter wide get the plan an unweighted choice makes for a
/// target four times larger; a narrower range never refines a brick, in any budget; a brick of
/// one value is refined only where the rule forces it (a neighbour one level finer); ranges of
/// another length are refused.
#[test]
fn value_ranges_weigh_the_screen_space_error() {
    let mut rng = Rng(0x91a4_0009);
    let bricks = UVec3::new(12, 10, 8);
    let geometry = geometry(bricks);
    let grid = *geometry.grid();
    let count = grid.brick_count();
    let active = vec![true; count];
    let quarter = vec![
        ValueRange {
            min: 0.5,
            max: 0.75
        };
        count
    ];
    // Random widths, a third of the bricks of one value (every level with bricks of 8 is
    // reachable with three levels: no block levels, so a brick's level is its own).
    let levels = 3;
    let mixed: Vec<ValueRange> = (0..count)
        .map(|_| match rng.below(3) {
            0 => ValueRange { min: 0.3, max: 0.3 },
            _ => {
                let min = 0.5 * rng.unit();
                ValueRange {
                    min,
                    max: min + 0.5 * rng.unit(),
                }
            }
        })
        .collect();
    let choose = |view: &LodView, ranges: &[ValueRange], levels: u32, slots: u64, target: f32| {
        LevelChooser::new()
            .choose(&LevelRequest {
                geometry: &geometry,
                view,
                active: &active,
                value_ranges: ranges,
                levels,
                slots,
                target_pixels: target,
                previous: &[],
                margin: 0.0,
            })
            .cloned()
            .unwrap()
    };
    let mut refined_somewhere = false;
    for round in 0..8 {
        let camera = random_camera(&mut rng);
        let view = LodView::new(&camera, 128, 96).unwrap();
        let weighted = choose(&view, &quarter, LEVELS, 1_000_000, 0.5);
        let scaled = choose(&view, &[], LEVELS, 1_000_000, 2.0);
        assert_eq!(weighted.levels, scaled.levels, "round {round}");
        for slots in [40, 1_000_000] {
            let plain = choose(&view, &[], levels, slots, 0.5);
            let by_value = choose(&view, &mixed, levels, slots, 0.5);
            for (i, b) in grid.bricks().enumerate() {
                let (p, v) = (plain.levels[i].unwrap(), by_value.levels[i].unwrap());
                if slots == 1_000_000 {
                    assert!(v >= p, "round {round} brick {b}: {p} -> {v} by value");
                }
                let width = mixed[i].max - mixed[i].min;
                if width == 0.0 && v < levels - 1 {
                    let forced = grid
                        .bricks()
                        .enumerate()
                        .filter(|(_, n)| {
                            let d = n.as_ivec3() - b.as_ivec3();
                            *n != b && d.abs().max_element() <= 1
                        })
                        .any(|(j, _)| by_value.levels[j] == Some(v - 1));
                    assert!(forced, "round {round} brick {b} of one value at {v}");
                    refined_somewhere = true;
                }
            }
        }
    }
    assert!(
        refined_somewhere,
        "the rule refined a brick of one value in some view"
    );
    let camera = random_camera(&mut rng);
    let view = LodView::new(&camera, 128, 96).unwrap();
    let err = LevelChooser::new()
        .choose(&LevelRequest {
            geometry: &geometry,
            view: &view,
            active: &active,
            value_ranges: &quarter[1..],
            levels,
            slots: 100,
            target_pixels: 1.0,
            previous: &[],
            margin: 0.0,
        })
        .unwrap_err();
    assert_eq!(
        err,
        LevelChoiceError::ActiveCount {
            given: count - 1,
            bricks: count
        }
    );
}
