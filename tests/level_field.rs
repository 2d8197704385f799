//! The mixed-resolution field over any number of levels (issue 19): the CPU reference
//! `mixvol::reference::LevelField`, its C0 construction at every level pair and boundary class
//! (up to level 4, whose bricks come in blocks of 4^3), and the skeleton fixup that lets the
//! cache draw transitions between vertex levels with a plain fetch.
//!
//! The continuity probe is the one of `tests/continuity.rs`: at a point p, the spread (max - min)
//! of the field at p + eps * d over the 26 directions d. A C0 (Lipschitz) field keeps spread / eps
//! bounded as eps shrinks; a jump keeps the spread finite. The discontinuous baseline must jump,
//! so every continuity check can fail.

mod common;

use common::levels::{
    boundary_classes, per_brick, probe_points, spread, staircase_plan, textured_volume,
    SMOOTH_RATIO_BOUND,
};
use common::Rng;
use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{low_res_level, BrickGrid, DownsampleFilter, Level};
use mixvol::cache::block_bricks;
use mixvol::cache::tables::{brick_neighbour_bits, coarser_neighbour_bits};
use mixvol::cache::{BrickCache, CacheGeometry};
use mixvol::pyramid::{LevelGrid, PyramidError, SamplePlacement};
use mixvol::reference::{sample_mixed, sample_volume, LevelField, LevelSampling, ReferenceCache};
use mixvol::scene::Transition;
use mixvol::volume::{ScalarType, Volume, VoxelData};

/// Brick size: the smallest that takes levels past 2.
const N: u32 = 8;
/// Levels of the pyramid the tests build: 0-2, and the block levels 3 (blocks of 2^3 bricks)
/// and 4 (4^3).
const LEVELS: u32 = 5;

/// A textured volume of `bricks` bricks per axis, its grid and its first `levels` levels.
fn setup(rng: &mut Rng, bricks: UVec3, levels: u32) -> (BrickGrid, Vec<LevelGrid>) {
    let volume = textured_volume(rng, bricks * N);
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    (
        grid,
        LevelGrid::vertex_pyramid(&volume, levels, DownsampleFilter::Mean2),
    )
}

/// Checks the smooth field (both formulations) is Lipschitz at every probe point and, when
/// `expect_jump`, that the discontinuous baseline jumps.
fn check_continuity(
    name: &str,
    grid: &BrickGrid,
    grids: &[LevelGrid],
    levels: &[Option<u32>],
    rng: &mut Rng,
    expect_jump: bool,
) {
    let field = LevelField::new(grid, grids, levels).unwrap();
    let points = probe_points(rng, grid.dims(), N, grids.len() as u32, 2500);
    let smooth = |x: Vec3| field.sample(x, Transition::Smooth);
    let fixed_up = |x: Vec3| field.sample_fixed_up(x);
    for (form, f) in [
        ("blend", &smooth as &dyn Fn(Vec3) -> Option<f32>),
        ("fixed-up", &fixed_up),
    ] {
        let (coarse, _) = spread(f, &points, 1e-2);
        let (fine, worst) = spread(f, &points, 1e-4);
        eprintln!("{name} ({form}): smooth spread/eps {coarse} (1e-2) {fine} (1e-4)");
        assert!(
            coarse < SMOOTH_RATIO_BOUND && fine < SMOOTH_RATIO_BOUND,
            "{name} ({form}): the smooth field jumps: spread/eps {coarse} at 1e-2, {fine} at 1e-4 (spread {worst})"
        );
    }
    let discontinuous = |x: Vec3| field.sample(x, Transition::Discontinuous);
    let (_, worst) = spread(&discontinuous, &points, 1e-4);
    eprintln!("{name}: discontinuous spread {worst} (1e-4)");
    if expect_jump {
        assert!(
            worst > 1e-2,
            "{name}: the discontinuous baseline should jump, largest spread {worst}"
        );
    }
}

/// The boundary classes of `tests/continuity.rs`, one level apart: a 3x3x3 grid of cells, each
/// a block of the coarser level (one brick up to level 2), the centre cell at `level`, the class
/// at `level + 1`, the rest at `level`.
#[test]
fn every_level_pair_and_boundary_class_is_continuous() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0001);
    for level in 0..LEVELS - 1 {
        let cell = block_bricks(level + 1);
        let (grid, grids) = setup(&mut rng, UVec3::splat(3 * cell), level + 2);
        for (class, coarser) in boundary_classes() {
            let levels = per_brick(grid.bricks_per_axis(), |b| {
                Some(level + u32::from(coarser(b / cell)))
            });
            let name = format!("levels {level}-{}, {class}", level + 1);
            check_continuity(&name, &grid, &grids, &levels, &mut rng, true);
        }
    }
}

/// A middle level is the fine side towards its coarser neighbours and the coarse side towards its
/// finer ones: slabs of three consecutive levels, an edge column finer and the opposite one
/// coarser, and the staircase of all five levels over 16^3 bricks, where every level meets both
/// neighbours across faces, edges and corners.
#[test]
fn a_middle_level_is_continuous_towards_both_neighbours() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0002);
    for first in 0..LEVELS - 2 {
        let cell = block_bricks(first + 2);
        let (grid, grids) = setup(&mut rng, UVec3::splat(3 * cell), first + 3);
        let bricks = grid.bricks_per_axis();
        let levels = per_brick(bricks, |b| Some(first + b.x / cell));
        let name = format!("slabs {first}-{}-{}", first + 1, first + 2);
        check_continuity(&name, &grid, &grids, &levels, &mut rng, true);
        // The centre at the middle level, finer along one edge column, coarser along the
        // opposite one (two cells apart, so the rule holds).
        let levels = per_brick(bricks, |b| {
            let c = b / cell;
            Some(first + 1 + u32::from(c.x == 2 && c.y == 2) - u32::from(c.x == 0 && c.y == 0))
        });
        let name = format!("edge columns {first}-{}-{}", first + 1, first + 2);
        check_continuity(&name, &grid, &grids, &levels, &mut rng, true);
    }
    let (grid, grids) = setup(&mut rng, UVec3::splat(16), LEVELS);
    let levels = staircase_plan(grid.bricks_per_axis(), 0, LEVELS);
    assert_eq!(levels.iter().flatten().max(), Some(&(LEVELS - 1)));
    check_continuity(
        "staircase 0-1-2-3-4",
        &grid,
        &grids,
        &levels,
        &mut rng,
        true,
    );
}

/// Staircases shifted up and down (aligned blocks, the rule kept), with undrawn bricks among the
/// levels without blocks, on dims that are not multiples of the brick size (blocks clipped at the
/// far faces).
#[test]
fn random_plans_over_five_levels_are_continuous_on_awkward_dims() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0003);
    let dims = UVec3::new(11 * N + 5, 6 * N + 3, 9 * N - 3);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    for plan in 0..6 {
        let shift = plan % 3 - 1;
        let mut levels = staircase_plan(grid.bricks_per_axis(), shift, LEVELS);
        if plan >= 3 {
            for _ in 0..4 {
                let hole = rng.below(levels.len() as u32) as usize;
                if levels[hole].is_some_and(|l| block_bricks(l) == 1) {
                    levels[hole] = None;
                }
            }
        }
        check_continuity(
            &format!("random plan {plan} (shift {shift})"),
            &grid,
            &grids,
            &levels,
            &mut rng,
            false,
        );
    }
}

/// The skeleton fixup draws the blend: in every brick of a vertex level whose band fits half a
/// brick (levels 1 and 2 here), the plain trilinear interpolation of the fixed-up samples equals
/// the band blend (the ray-caster needs no blend beyond level 0), and the fixup changes samples
/// (it is not vacuous).
#[test]
fn fixed_up_vertex_levels_draw_the_blend() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0004);
    let (grid, grids) = setup(&mut rng, UVec3::splat(6), 4);
    let levels = staircase_plan(grid.bricks_per_axis(), 0, 4);
    let field = LevelField::new(&grid, &grids, &levels).unwrap();
    let mut largest_change = 0.0f32;
    let mut compared = 0;
    for p in probe_points(&mut rng, grid.dims(), N, 4, 20_000) {
        let brick = grid.linear_index((p / N as f32).floor().as_uvec3().min(UVec3::splat(5)));
        let level = field.brick_level(brick).unwrap();
        let fixed_up = field.sample_fixed_up(p).unwrap();
        largest_change = largest_change.max((fixed_up - grids[level as usize].trilinear(p)).abs());
        if grids[level as usize].band_width() > 0.5 * N as f32 {
            continue;
        }
        let blend = field.sample(p, Transition::Smooth).unwrap();
        assert!(
            (blend - fixed_up).abs() < 1e-5,
            "{p}: blend {blend}, fixed-up samples {fixed_up}"
        );
        compared += 1;
    }
    assert!(compared > 5_000, "{compared} points compared");
    assert!(
        largest_change > 1e-2,
        "the fixup should change the field near coarser bricks (largest change {largest_change})"
    );
    // A sample that touches a coarser brick holds the coarser field; one that does not keeps its
    // own value. Level-1 sample (4, 4, 4) at position (8, 8, 8) is the corner shared by the
    // bricks with coordinates 0 and 1: levels 0 and 1 only.
    let corner = IVec3::splat(4);
    assert_eq!(field.fixed_up_sample(1, corner), grids[1].value(corner));
    // Level-1 sample (8, 4, 4) at position (16, 8, 8) touches brick (2, 1, 1), level 2.
    let on_face = IVec3::new(8, 4, 4);
    let coarse = grids[2].trilinear(on_face.as_vec3() * 2.0);
    assert_eq!(field.fixed_up_sample(1, on_face), coarse);
    assert_ne!(coarse, grids[1].value(on_face));
}

/// With all bricks at one level the field is that level's trilinear field, whatever the
/// transition; level 0 is the single-resolution field, level 1 the library's `Mean2` low-res
/// level, and every level reproduces a linear function away from the volume's clamped edge.
#[test]
fn each_level_alone_is_the_trilinear_field_of_its_own_samples() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0005);
    let dims = UVec3::new(2 * N + 3, N + 5, 2 * N);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let points = probe_points(&mut rng, dims, N, LEVELS, 2000);
    for level in 0..LEVELS {
        let levels = vec![Some(level); grid.brick_count()];
        let field = LevelField::new(&grid, &grids, &levels).unwrap();
        for &p in &points {
            let own = grids[level as usize].trilinear(p);
            for transition in [Transition::Smooth, Transition::Discontinuous] {
                assert_eq!(
                    field.sample(p, transition),
                    Some(own),
                    "level {level} at {p}"
                );
            }
            assert_eq!(field.sample_fixed_up(p), Some(own), "level {level} at {p}");
        }
    }
    for &p in &points {
        let single = sample_volume(&volume, p / dims.as_vec3());
        assert!(
            (grids[0].trilinear(p) - single).abs() < 1e-6,
            "level 0 at {p}"
        );
    }
    let low = low_res_level(&volume, DownsampleFilter::Mean2);
    assert_eq!(grids[1].dims(), low.dims);
    assert_eq!(grids[1].placement(), SamplePlacement::Vertex);
    for (i, (a, b)) in grids[1].values().iter().zip(&low.values).enumerate() {
        assert!((a - b).abs() < 1e-6, "level 1 sample {i}: {a} vs {b}");
    }

    // A ramp: a level-k sample is exact once its support (about 2^k voxels each way) misses the
    // clamped edge, so points 2^(k+1) inside see only exact samples.
    let dims = UVec3::new(80, 72, 68);
    let slope = Vec3::new(0.013, -0.007, 0.004);
    let linear = |p: Vec3| 0.5 + slope.dot(p);
    let data = (0..dims.x * dims.y * dims.z)
        .map(|i| {
            let v = UVec3::new(i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y));
            linear(v.as_vec3() + Vec3::splat(0.5))
        })
        .collect();
    let ramp = Volume::new(dims, Vec3::ONE, VoxelData::F32(data)).unwrap();
    let ramp_grids = LevelGrid::vertex_pyramid(&ramp, LEVELS, DownsampleFilter::Mean2);
    let margin = (1 << LEVELS) as f32;
    for _ in 0..2000 {
        let p = Vec3::new(rng.unit(), rng.unit(), rng.unit()) * (dims.as_vec3() - 2.0 * margin)
            + Vec3::splat(margin);
        for g in &ramp_grids {
            let v = g.trilinear(p);
            assert!(
                (v - linear(p)).abs() < 1e-5,
                "level {} at {p}: {v} vs {}",
                g.level(),
                linear(p)
            );
        }
    }
}

/// Level 1 is the chosen filter over the voxels around each vertex, written out here from the
/// filters' definitions (not from the library's tap tables): per axis, Mean2 averages voxels
/// `2j-1, 2j`, LaMar takes voxel `2j`, Box4 averages `2j-2 ..= 2j+1`, BSpline4 weighs them
/// `13, 19, 19, 13` / 64, each index clamped to the volume; every coarser level does not
/// depend on the filter but through level 1.
#[test]
fn level_one_is_the_chosen_filter_around_each_vertex() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_000a);
    let dims = UVec3::new(2 * N + 3, N + 5, N + 2);
    let volume = textured_volume(&mut rng, dims);
    let voxel = |v: IVec3| {
        let c = v
            .clamp(IVec3::ZERO, dims.as_ivec3() - IVec3::ONE)
            .as_uvec3();
        volume
            .data()
            .normalized((c.x + dims.x * (c.y + dims.y * c.z)) as usize) as f64
    };
    let axis_weights = |filter: DownsampleFilter| -> Vec<(i32, f64)> {
        match filter {
            DownsampleFilter::Mean2 => vec![(-1, 0.5), (0, 0.5)],
            DownsampleFilter::LaMarSubsample => vec![(0, 1.0)],
            DownsampleFilter::Box4 => vec![(-2, 0.25), (-1, 0.25), (0, 0.25), (1, 0.25)],
            DownsampleFilter::BSpline4 => vec![
                (-2, 13.0 / 64.0),
                (-1, 19.0 / 64.0),
                (0, 19.0 / 64.0),
                (1, 13.0 / 64.0),
            ],
        }
    };
    let mean2 = LevelGrid::vertex_pyramid(&volume, 3, DownsampleFilter::Mean2);
    for filter in DownsampleFilter::ALL {
        let grids = LevelGrid::vertex_pyramid(&volume, 3, filter);
        let level1 = &grids[1];
        assert_eq!(level1.dims(), (dims + UVec3::ONE) / 2 + UVec3::ONE);
        let w = axis_weights(filter);
        for z in 0..level1.dims().z as i32 {
            for y in 0..level1.dims().y as i32 {
                for x in 0..level1.dims().x as i32 {
                    let mut expected = 0.0f64;
                    for &(oz, wz) in &w {
                        for &(oy, wy) in &w {
                            for &(ox, wx) in &w {
                                let v = IVec3::new(2 * x + ox, 2 * y + oy, 2 * z + oz);
                                expected += wx * wy * wz * voxel(v);
                            }
                        }
                    }
                    let got = level1.value(IVec3::new(x, y, z));
                    assert!(
                        (f64::from(got) - expected).abs() < 1e-6,
                        "{filter:?} sample ({x}, {y}, {z}): {got} vs {expected}"
                    );
                }
            }
        }
        let differs = level1
            .values()
            .iter()
            .zip(mean2[1].values())
            .any(|(a, b)| a != b);
        assert_eq!(differs, filter != DownsampleFilter::Mean2, "{filter:?}");
        // Level 2 is the tent over level 1, whatever built level 1.
        let tent = level1.downsampled(SamplePlacement::Vertex, dims, DownsampleFilter::Box4);
        assert_eq!(grids[2], tent, "{filter:?}: level 2 from level 1");
    }
}

/// With two levels the field is the brick cache's (`reference::mixed`): the same values, smooth
/// and discontinuous, for random plans with undrawn bricks and every downsampling filter; the
/// coarser bits are the 26 neighbour bits.
#[test]
fn two_levels_equal_the_brick_cache_field() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0006);
    let dims = UVec3::new(3 * N + 3, 2 * N + 5, 2 * N + 1);
    let volume = textured_volume(&mut rng, dims);
    let grid = BrickGrid::new(dims, N).unwrap();
    let geometry = CacheGeometry::choose(N, 4, 1 << 30, 4096, grid.brick_count() as u32).unwrap();
    // Every level-0-to-1 filter: level 1 is the brick cache's low-res level of that filter.
    for (plan, filter) in (0..8).zip(DownsampleFilter::ALL.iter().cycle()) {
        let filter = *filter;
        let grids = LevelGrid::vertex_pyramid(&volume, 2, filter);
        let levels: Vec<Level> = (0..grid.brick_count())
            .map(|_| match rng.below(7) {
                0 => Level::Absent,
                1..=3 => Level::Lo,
                _ => Level::Hi,
            })
            .collect();
        let numbers: Vec<Option<u32>> = levels
            .iter()
            .map(|l| match l {
                Level::Hi => Some(0),
                Level::Lo => Some(1),
                Level::Absent => None,
            })
            .collect();
        let field = LevelField::new(&grid, &grids, &numbers).unwrap();
        for (i, brick) in grid.bricks().enumerate() {
            let bits = brick_neighbour_bits(&grid, brick, |j| levels[j]);
            assert_eq!(field.coarser_bits(i), bits, "plan {plan} brick {brick}");
            let numbered = coarser_neighbour_bits(&grid, brick, |j| numbers[j]);
            assert_eq!(numbered, bits, "plan {plan} brick {brick}");
        }
        let mut cache = BrickCache::new(grid, geometry).unwrap();
        cache.update(&levels).unwrap();
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            let reference =
                ReferenceCache::build(&volume, filter, &cache, ScalarType::F32, transition)
                    .unwrap();
            let view = reference.view();
            for p in probe_points(&mut rng, dims, N, LEVELS, 3000) {
                let from_cache = sample_mixed(&view, p, transition);
                let from_levels = field.sample(p, transition);
                match (from_cache, from_levels) {
                    (Some(a), Some(b)) => assert!(
                        (a - b).abs() < 2e-5,
                        "plan {plan} {filter:?} {transition:?} at {p}: cache {a}, levels {b}"
                    ),
                    (a, b) => assert_eq!(a, b, "plan {plan} at {p}: drawn in one, not the other"),
                }
            }
        }
    }
}

#[test]
fn bad_level_inputs_are_refused_with_what_was_expected() {
    let mut rng = Rng(0x1e7e_1f1e_1d00_0007);
    let volume = textured_volume(&mut rng, UVec3::new(3 * N, 2 * N, 2 * N));
    let grid = BrickGrid::new(volume.dims(), N).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, LEVELS, DownsampleFilter::Mean2);
    let row = |levels: [Option<u32>; 3]| {
        // The first row of bricks as given, the rest as the brick below in x.
        per_brick(grid.bricks_per_axis(), |b| levels[b.x as usize])
    };

    // Level 0 next to level 2 breaks the rule; 0-1-2 keeps it.
    let err = LevelField::new(&grid, &grids, &row([Some(0), Some(2), Some(2)])).unwrap_err();
    assert_eq!(err, PyramidError::LevelRule);
    assert!(LevelField::new(&grid, &grids, &row([Some(0), Some(1), Some(2)])).is_ok());
    // An undrawn brick between them separates them.
    assert!(LevelField::new(&grid, &grids, &row([Some(1), None, Some(2)])).is_ok());
    // Level 3 comes in aligned blocks of 2^3 bricks: bricks x = 2 alone (the block of x = 2..3,
    // clipped to the grid, is whole) is fine; level 3 at x = 1 shares its block with x = 0.
    assert!(LevelField::new(&grid, &grids, &row([Some(1), Some(2), Some(3)])).is_ok());
    let err = LevelField::new(&grid, &grids, &row([Some(2), Some(3), Some(3)])).unwrap_err();
    assert_eq!(
        err,
        PyramidError::BrokenBlock {
            brick: 1,
            level: 3,
            block: 2
        }
    );
    let mut holey = row([Some(2), Some(3), Some(3)]);
    holey.iter_mut().for_each(|l| *l = l.map(|_| 3));
    holey[grid.linear_index(UVec3::new(1, 1, 1))] = None;
    assert!(matches!(
        LevelField::new(&grid, &grids, &holey),
        Err(PyramidError::BrokenBlock { level: 3, .. })
    ));

    let three = row([Some(0), Some(1), Some(2)]);
    let err = LevelField::new(&grid, &grids[..2], &three).unwrap_err();
    assert!(matches!(
        err,
        PyramidError::UnknownLevel {
            level: 2,
            levels: 2,
            ..
        }
    ));
    let err = LevelField::new(&grid, &grids, &[Some(0)]).unwrap_err();
    assert_eq!(
        err,
        PyramidError::BrickLevelCount {
            given: 1,
            bricks: grid.brick_count()
        }
    );
    let none = vec![None; grid.brick_count()];
    assert_eq!(
        LevelField::new(&grid, &[], &none).unwrap_err(),
        PyramidError::NoLevels
    );
    let err = LevelField::new(&grid, &grids[1..], &none).unwrap_err();
    assert_eq!(err, PyramidError::LevelOrder { index: 0, level: 1 });
    // Bricks of 4 voxels take three levels, not four (the block levels need 8).
    let small = BrickGrid::new(volume.dims(), 4).unwrap();
    let none = vec![None; small.brick_count()];
    assert!(LevelField::new(&small, &grids[..3], &none).is_ok());
    let err = LevelField::new(&small, &grids[..4], &none).unwrap_err();
    assert_eq!(
        err,
        PyramidError::TooManyLevels {
            levels: 4,
            min_brick_size: 8,
            brick_size: 4
        }
    );
    assert!(err.to_string().contains("at least 8 voxels"), "{err}");

    let err = LevelGrid::new(
        1,
        SamplePlacement::Vertex,
        UVec3::new(2, 2, 2),
        vec![0.0; 7],
    )
    .unwrap_err();
    assert_eq!(
        err,
        PyramidError::SampleCount {
            level: 1,
            dims: [2, 2, 2],
            values: 7,
            expected: 8
        }
    );
    assert!(matches!(
        LevelGrid::new(0, SamplePlacement::CellCentred, UVec3::new(0, 2, 2), vec![]),
        Err(PyramidError::InvalidGrid { level: 0, .. })
    ));
}

/// Levels 2 and up are the tent `1/4, 1/2, 1/4` over the level below, on vertices, clamp-to-edge
/// (review H4: every level store, the GPU source and the reference build them with one function,
/// so they cannot catch a wrong filter; a linear ramp cannot either, since point sampling and
/// any symmetric filter reproduce it).
///
/// Two independent checks: (1) a quadratic along x, `v = s x^2` at voxel centres: level 1 (the
/// mean of two centres) is `s (x^2 + 1/4)` at its vertices `x = 2j`, and each tent over samples
/// `h` apart adds `h^2 / 2`, so level `k` is `s (x^2 + c_k)` with `c_k = c_{k-1} + 2^(2k-3)`
/// away from the clamped edges (point sampling keeps `c_1`, a box of three adds `2 h^2 / 3`);
/// (2) on a random volume every sample of levels 2-4, clamped edges included, equals the tent
/// over the level below written out here.
#[test]
fn levels_two_and_up_are_the_tent_over_the_level_below() {
    // (1) The quadratic.
    let dims = UVec3::new(128, 4, 4);
    let s = 1.0 / 16384.0;
    let data = (0..dims.element_product())
        .map(|i| {
            let x = (i % dims.x) as f32 + 0.5;
            s * x * x
        })
        .collect();
    let volume = Volume::new(dims, Vec3::ONE, VoxelData::F32(data)).unwrap();
    let grids = LevelGrid::vertex_pyramid(&volume, 5, DownsampleFilter::Mean2);
    let mut c = 0.25f64;
    for (k, g) in grids.iter().enumerate().skip(1) {
        if k >= 2 {
            let h = f64::from(1u32 << (k - 1));
            c += h * h / 2.0;
        }
        let spacing = 1u32 << k;
        let mut checked = 0;
        for j in 0..g.dims().x {
            let x = j * spacing;
            // The support of a level-k sample reaches about 2^k voxels each way.
            if x < 2 * spacing || x + 2 * spacing > dims.x {
                continue;
            }
            let expected = s as f64 * (f64::from(x) * f64::from(x) + c);
            let got = f64::from(g.value(IVec3::new(j as i32, 1, 1)));
            assert!(
                (got - expected).abs() < 1e-6,
                "level {k} at x = {x}: {got} vs {expected} (c_k = {c})"
            );
            checked += 1;
        }
        assert!(checked >= 3, "level {k}: only {checked} samples checked");
    }

    // (2) A random volume, every sample, written-out tent with clamp-to-edge.
    let mut rng = Rng(0x7e47_0000_0000_0004);
    let volume = textured_volume(&mut rng, UVec3::new(37, 29, 21));
    let grids = LevelGrid::vertex_pyramid(&volume, 5, DownsampleFilter::Mean2);
    for k in 2..grids.len() {
        let (below, g) = (&grids[k - 1], &grids[k]);
        let last = below.dims().as_ivec3() - IVec3::ONE;
        let at = |i: IVec3| f64::from(below.value(i.clamp(IVec3::ZERO, last)));
        let w = [0.25f64, 0.5, 0.25];
        for z in 0..g.dims().z as i32 {
            for y in 0..g.dims().y as i32 {
                for x in 0..g.dims().x as i32 {
                    let mut expected = 0.0;
                    for (dz, wz) in w.iter().enumerate() {
                        for (dy, wy) in w.iter().enumerate() {
                            for (dx, wx) in w.iter().enumerate() {
                                let d = IVec3::new(dx as i32, dy as i32, dz as i32) - IVec3::ONE;
                                expected += wx * wy * wz * at(2 * IVec3::new(x, y, z) + d);
                            }
                        }
                    }
                    let got = f64::from(g.value(IVec3::new(x, y, z)));
                    assert!(
                        (got - expected).abs() < 1e-6,
                        "level {k} sample ({x}, {y}, {z}): {got} vs {expected}"
                    );
                }
            }
        }
    }
}

/// A volume's levels for the cache with level 0 read on demand (`pyramid::VolumeLevels`, what a
/// `VolumeSource::Levels` holds) give every stored brick of every level exactly as the whole
/// vertex pyramid does, for 8-bit and float volumes and any filter, and hold the coarser
/// levels only: not the four bytes per voxel of level 0.
#[test]
fn volume_levels_read_level_zero_on_demand_and_equal_the_pyramid() {
    use mixvol::cache::{stored_brick_edge, stored_bricks_per_axis};
    use mixvol::pyramid::VolumeLevels;
    use std::sync::Arc;
    let mut rng = Rng(0x1e7e_1f1e_1d00_000b);
    let dims = UVec3::new(3 * N + 5, 2 * N + 3, 2 * N + 7);
    let float = textured_volume(&mut rng, dims);
    let bytes: Vec<u8> = (0..dims.element_product())
        .map(|_| rng.below(256) as u8)
        .collect();
    let u8_volume = Volume::new(dims, Vec3::ONE, VoxelData::U8(bytes)).unwrap();
    for (volume, filter) in [
        (float, DownsampleFilter::Mean2),
        (u8_volume, DownsampleFilter::BSpline4),
    ] {
        let grid = BrickGrid::new(dims, N).unwrap();
        let levels = 4;
        let pyramid = LevelGrid::vertex_pyramid(&volume, levels, filter);
        assert_eq!(LevelGrid::level_one(&volume, filter), pyramid[1]);
        let on_demand = VolumeLevels::new(Arc::new(volume.clone()), levels, filter);
        assert_eq!(on_demand.level_count(), levels);
        for level in 0..levels {
            let stored = stored_bricks_per_axis(grid.bricks_per_axis(), level);
            for z in 0..stored.z {
                for y in 0..stored.y {
                    for x in 0..stored.x {
                        let first = UVec3::new(x, y, z) * block_bricks(level);
                        let texels = on_demand.stored_brick(level, first, N).unwrap();
                        assert_eq!(texels.len(), stored_brick_edge(N, level).pow(3) as usize);
                        assert!(
                            texels == pyramid[level as usize].stored_brick(first, N),
                            "{filter:?} level {level} block at {first}"
                        );
                    }
                }
            }
        }
        assert_eq!(on_demand.stored_brick(levels, UVec3::ZERO, N), None);
        let voxels = dims.as_u64vec3().element_product();
        let pyramid_bytes: u64 = pyramid.iter().map(|g| g.values().len() as u64 * 4).sum();
        // Level 0 (four bytes a voxel) is not held; levels 1.. are (at large sizes an eighth,
        // 0.57 bytes a voxel in all).
        assert_eq!(on_demand.held_bytes(), pyramid_bytes - 4 * voxels);
    }
}
