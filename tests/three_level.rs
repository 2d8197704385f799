//! The paper's three-level packing (issue 19, item 1) on the CPU: `(n+4)^3` slots holding one
//! level-0, eight level-1 or sixty-four level-2 bricks, address translation through the layout
//! table, the border fixup (level 0 towards level 1) and the skeleton fixup (level 1 towards level
//! 2), read through the two-level cache's sampler `sample_mixed` unchanged. Checked against the
//! field defined from each level's own samples (`LevelField`), which `tests/level_field.rs`
//! proves C0 at every level pair.

mod common;

use common::levels::{
    boundary_classes, distance_plan, per_brick, probe_points, spread, staircase_plan,
    textured_volume, SMOOTH_RATIO_BOUND,
};
use common::Rng;
use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::DownsampleFilter;
use mixvol::bricks::{BrickGrid, Level};
use mixvol::cache::block_origin;
use mixvol::cache::{BrickCache, CacheError, CacheGeometry, SlotGeometry};
use mixvol::pyramid::{LevelGrid, PackingError, SamplePlacement};
use mixvol::reference::{sample_mixed, LevelField, LevelReferenceCache, LevelSampling};
use mixvol::scene::Transition;

const N: u32 = 8;
const LEVELS: u32 = 3;

/// A cache big enough for every brick of `grid` at level 0.
fn roomy_geometry(grid: &BrickGrid) -> SlotGeometry {
    let mut extent = UVec3::splat((N + 4).next_power_of_two());
    while (extent / (N + 4)).element_product() < grid.brick_count() as u32 {
        let smallest = (0..3).min_by_key(|&a| extent[a]).unwrap_or(0);
        extent[smallest] *= 2;
    }
    SlotGeometry::new(N, 3, extent).unwrap()
}

/// Compares the cache's field with the level field at `points`, smooth and discontinuous.
fn assert_cache_matches_levels(name: &str, grid: &BrickGrid, field: &LevelField, points: &[Vec3]) {
    let geometry = roomy_geometry(grid);
    for transition in [Transition::Smooth, Transition::Discontinuous] {
        let cache = LevelReferenceCache::build(field, &geometry, transition).unwrap();
        let view = cache.view();
        for &p in points {
            let from_cache = sample_mixed(&view, p, transition);
            let from_levels = field.sample(p, transition);
            match (from_cache, from_levels) {
                (Some(a), Some(b)) => assert!(
                    (a - b).abs() < 2e-5,
                    "{name} {transition:?} at {p}: cache {a}, levels {b}"
                ),
                (a, b) => assert_eq!(a, b, "{name} at {p}: drawn in one, not the other"),
            }
        }
    }
}

/// Each level read through the layout table is the trilinear field of its own samples in every
/// brick of that level, up to and on the brick's faces (no fixup: the discontinuous cache).
#[test]
fn address_translation_reads_each_level_on_its_own_grid() {
    let mut rng = Rng(0x3_1e7e_0001);
    let volume = textured_volume(&mut rng, UVec3::new(4 * N, 3 * N, 2 * N));
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let geometry = roomy_geometry(&grid);
    for level in 0..LEVELS {
        // Every brick but the first at `level`: the first is left undrawn.
        let one_level = per_brick(grid.bricks_per_axis(), |b| {
            Some(level).filter(|_| b != UVec3::ZERO)
        });
        let field = LevelField::new(&grid, &grids, &one_level).unwrap();
        let cache =
            LevelReferenceCache::build(&field, &geometry, Transition::Discontinuous).unwrap();
        for (i, brick) in grid.bricks().enumerate() {
            let entry = cache.packing.layout[i];
            if one_level[i].is_none() {
                assert_eq!(entry, [0.0; 4], "an undrawn brick is skipped");
                continue;
            }
            assert_eq!(entry[3], 1.0 / (1 << level) as f32);
            let t = Vec3::new(entry[0], entry[1], entry[2]);
            for _ in 0..200 {
                // The closed box, faces included.
                let u = Vec3::new(rng.unit(), rng.unit(), rng.unit()).map(|c| {
                    if c < 0.1 {
                        0.0
                    } else if c > 0.9 {
                        1.0
                    } else {
                        c
                    }
                });
                let p = (brick.as_vec3() + u) * N as f32;
                let fetched = cache.image.fetch(p * entry[3] + t);
                let own = grids[level as usize].trilinear(p);
                assert!(
                    (fetched - own).abs() < 1e-5,
                    "level {level} brick {brick} at {p}: cache {fetched}, own grid {own}"
                );
            }
        }
    }
}

/// The cache's field equals the level field, smooth (both fixups) and discontinuous, for every
/// boundary class at both level pairs, three-level slabs, and random plans with undrawn bricks.
#[test]
fn the_fixed_up_cache_draws_the_level_field() {
    let mut rng = Rng(0x3_1e7e_0002);
    let volume = textured_volume(&mut rng, UVec3::splat(3 * N));
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let points = probe_points(&mut rng, grid.dims(), N, LEVELS, 4000);
    let classes = boundary_classes();
    for level in 0..LEVELS - 1 {
        for (class, coarser) in classes {
            let levels = per_brick(UVec3::splat(3), |b| Some(level + u32::from(coarser(b))));
            let field = LevelField::new(&grid, &grids, &levels).unwrap();
            assert_cache_matches_levels(
                &format!("{level}-{}, {class}", level + 1),
                &grid,
                &field,
                &points,
            );
        }
    }
    let slabs = per_brick(UVec3::splat(3), |b| Some(b.x));
    let field = LevelField::new(&grid, &grids, &slabs).unwrap();
    assert_cache_matches_levels("slabs 0-1-2", &grid, &field, &points);

    let dims = UVec3::new(4 * N + 3, 3 * N + 5, 3 * N - 3);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let bricks = grid.bricks_per_axis();
    let points = probe_points(&mut rng, dims, N, LEVELS, 4000);
    for plan in 0..6 {
        let centre = UVec3::new(
            rng.below(bricks.x),
            rng.below(bricks.y),
            rng.below(bricks.z),
        );
        let mut levels = distance_plan(bricks, centre.as_ivec3(), rng.below(2) as i32, LEVELS);
        if plan % 2 == 1 {
            let hole = rng.below(levels.len() as u32) as usize;
            levels[hole] = None;
        }
        let field = LevelField::new(&grid, &grids, &levels).unwrap();
        assert_cache_matches_levels(&format!("random plan {plan}"), &grid, &field, &points);
    }
}

/// The cache's own field is continuous across both level pairs (the staircase of three levels,
/// probed through the cache), and the cache without fixups jumps.
#[test]
fn the_three_level_cache_is_continuous_and_its_baseline_jumps() {
    let mut rng = Rng(0x3_1e7e_0003);
    let volume = textured_volume(&mut rng, UVec3::splat(3 * N));
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let levels = per_brick(UVec3::splat(3), |b| Some(b.max_element()));
    let field = LevelField::new(&grid, &grids, &levels).unwrap();
    let geometry = roomy_geometry(&grid);
    let points = probe_points(&mut rng, grid.dims(), N, LEVELS, 4000);
    for transition in [Transition::Smooth, Transition::Discontinuous] {
        let cache = LevelReferenceCache::build(&field, &geometry, transition).unwrap();
        let view = cache.view();
        let f = |x: Vec3| sample_mixed(&view, x, transition);
        let (coarse, _) = spread(&f, &points, 1e-2);
        let (fine, worst) = spread(&f, &points, 1e-4);
        eprintln!("{transition:?}: spread/eps {coarse} (1e-2) {fine} (1e-4), spread {worst}");
        match transition {
            Transition::Smooth => assert!(
                coarse < SMOOTH_RATIO_BOUND && fine < SMOOTH_RATIO_BOUND,
                "the fixed-up cache jumps: spread/eps {coarse} at 1e-2, {fine} at 1e-4"
            ),
            Transition::Discontinuous => {
                assert!(
                    worst > 1e-2,
                    "the baseline should jump, largest spread {worst}"
                )
            }
        }
    }
}

/// A volume whose two-level representation does not fit the cache (even every brick at level 1
/// needs more slots than the image holds) is drawn whole with three levels: no undrawn point,
/// and the field of its levels.
#[test]
fn a_volume_too_big_for_two_levels_is_drawn_whole_with_three() {
    let mut rng = Rng(0x3_1e7e_0004);
    let dims = UVec3::new(8 * N, 8 * N, 4 * N);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let extent = UVec3::splat(32);

    // Two levels: 27 slots of (n+2)^3 hold at most 216 level-1 bricks; the grid has 256.
    let two_level = CacheGeometry::new(N, extent).unwrap();
    assert!(two_level.slot_count() as usize * 8 < grid.brick_count());
    let mut two_level_cache = BrickCache::new(grid, two_level).unwrap();
    let all_low = vec![Level::Lo; grid.brick_count()];
    assert!(matches!(
        two_level_cache.update(&all_low),
        Err(CacheError::OverBudget { .. })
    ));

    // Three levels in the same image: 8 slots of (n+4)^3. One level-0 brick on the volume's
    // face (1 slot), the 17 bricks around it at level 1 (3 slots), 238 at level 2 (4 slots).
    let three_level = SlotGeometry::new(N, 3, extent).unwrap();
    assert_eq!(three_level.slot_count(), 8);
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let levels = distance_plan(grid.bricks_per_axis(), IVec3::new(0, 4, 1), 0, LEVELS);
    let field = LevelField::new(&grid, &grids, &levels).unwrap();
    let cache = LevelReferenceCache::build(&field, &three_level, Transition::Smooth).unwrap();
    assert!(
        cache.packing.places.iter().all(Option::is_some),
        "every brick is resident"
    );
    let view = cache.view();
    for p in probe_points(&mut rng, dims, N, LEVELS, 5000) {
        let drawn = sample_mixed(&view, p, Transition::Smooth)
            .unwrap_or_else(|| panic!("{p} is not drawn"));
        let expected = field.sample(p, Transition::Smooth).unwrap();
        assert!(
            (drawn - expected).abs() < 2e-5,
            "{p}: cache {drawn}, levels {expected}"
        );
    }

    // All at level 1 needs 32 slots: refused, with the count.
    let ones = vec![Some(1); grid.brick_count()];
    let field = LevelField::new(&grid, &grids, &ones).unwrap();
    let err = LevelReferenceCache::build(&field, &three_level, Transition::Smooth).unwrap_err();
    assert_eq!(
        err,
        PackingError::OverBudget {
            needed: 32,
            per_level: [0, 256, 0],
            slots: 8
        }
    );
}

/// Past level 2 a stored brick holds a block of bricks: the staircase of five levels over 16^3
/// bricks (4096) fits five slots, every brick of a block shares its block's stored brick, and the
/// cache draws the level field, continuous, smooth and discontinuous.
#[test]
fn block_levels_share_one_stored_brick_and_draw_the_level_field() {
    let mut rng = Rng(0x3_1e7e_0006);
    let dims = UVec3::splat(16 * N);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, 5, DownsampleFilter::Mean2);
    let levels = staircase_plan(grid.bricks_per_axis(), 0, 5);
    let field = LevelField::new(&grid, &grids, &levels).unwrap();
    let geometry = SlotGeometry::new(N, 3, UVec3::splat(32)).unwrap();
    assert_eq!(geometry.slot_count(), 8);
    let points = probe_points(&mut rng, dims, N, 5, 4000);
    for transition in [Transition::Smooth, Transition::Discontinuous] {
        let cache = LevelReferenceCache::build(&field, &geometry, transition).unwrap();
        // 1 level-0 brick, 7 level-1 bricks, 56 + 56 + 56 of the level-2 size (levels 2, 3, 4).
        let slots_used = cache.packing.places.iter().flatten().map(|p| p.slot).max();
        assert_eq!(slots_used, Some(4));
        for (i, brick) in grid.bricks().enumerate() {
            let level = levels[i].unwrap();
            let first = grid.linear_index(block_origin(brick, level));
            assert_eq!(
                cache.packing.places[i], cache.packing.places[first],
                "brick {brick}"
            );
            assert_eq!(
                cache.packing.layout[i], cache.packing.layout[first],
                "brick {brick}"
            );
            assert_eq!(cache.packing.places[i].unwrap().level, level);
        }
        let view = cache.view();
        for &p in &points {
            let from_cache = sample_mixed(&view, p, transition).unwrap();
            let from_levels = field.sample(p, transition).unwrap();
            assert!(
                (from_cache - from_levels).abs() < 2e-5,
                "{transition:?} at {p}: cache {from_cache}, levels {from_levels}"
            );
        }
        let f = |x: Vec3| sample_mixed(&view, x, transition);
        let (coarse, _) = spread(&f, &points, 1e-2);
        let (fine, worst) = spread(&f, &points, 1e-4);
        eprintln!("{transition:?}: spread/eps {coarse} (1e-2) {fine} (1e-4), spread {worst}");
        match transition {
            Transition::Smooth => assert!(coarse < SMOOTH_RATIO_BOUND && fine < SMOOTH_RATIO_BOUND),
            Transition::Discontinuous => assert!(worst > 1e-2, "largest spread {worst}"),
        }
    }
    // Every brick at level 2: 4096 stored bricks, 64 slots.
    let all_two = vec![Some(2); grid.brick_count()];
    let field = LevelField::new(&grid, &grids, &all_two).unwrap();
    let err = LevelReferenceCache::build(&field, &geometry, Transition::Smooth).unwrap_err();
    assert_eq!(
        err,
        PackingError::OverBudget {
            needed: 64,
            per_level: [0, 0, 4096],
            slots: 8
        }
    );
}

#[test]
fn fields_the_packing_cannot_hold_are_refused() {
    let mut rng = Rng(0x3_1e7e_0005);
    let volume = textured_volume(&mut rng, UVec3::new(2 * N, N, N));
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    let geometry = roomy_geometry(&grid);
    let levels = [Some(0), Some(1)];
    let pyramid = LevelGrid::vertex_pyramid(&volume, 2, DownsampleFilter::Mean2);
    let other = SlotGeometry::new(2 * N, 3, UVec3::splat(32)).unwrap();
    let field = LevelField::new(&grid, &pyramid, &levels).unwrap();
    assert_eq!(
        LevelReferenceCache::build(&field, &other, Transition::Smooth).unwrap_err(),
        PackingError::BrickSize {
            field: N,
            cache: 2 * N
        }
    );
    // A cell-centred level 1 is not what the packing stores.
    let cell_centred = [
        pyramid[0].clone(),
        pyramid[0].downsampled(
            SamplePlacement::CellCentred,
            volume.dims(),
            DownsampleFilter::Mean2,
        ),
    ];
    let field = LevelField::new(&grid, &cell_centred, &levels).unwrap();
    assert_eq!(
        LevelReferenceCache::build(&field, &geometry, Transition::Smooth).unwrap_err(),
        PackingError::Placement {
            level: 1,
            found: SamplePlacement::CellCentred
        }
    );
}
