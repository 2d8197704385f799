//! The three-level brick cache on the GPU (issue 19, item 1): upload, the border fixup and the
//! skeleton fixup as compute dispatches, and the field read with the ray-caster's functions,
//! checked against the CPU mirror (`reference::LevelReferenceCache`, itself checked against the
//! field of the levels in `tests/three_level.rs`) under the validation layers.

mod common;

use common::levels::{distance_plan, per_brick, probe_points, textured_volume};
use common::Rng;
use glam::{UVec3, Vec3};
use mixvol::bricks::BrickGrid;
use mixvol::cache::ThreeLevelGeometry;
use mixvol::levels::GpuLevelCache;
use mixvol::reference::{sample_mixed, LevelField, LevelGrid, LevelReferenceCache};
use mixvol::scene::Transition;

const N: u32 = 8;
const LEVELS: u32 = 3;

/// The level plans of the checks: the staircase of three levels (every boundary class of both
/// level pairs), a plan around a random brick with an undrawn one, and the staircase with a
/// level-1 brick standing out into level 2.
fn plans(rng: &mut Rng, bricks: UVec3) -> Vec<(&'static str, Vec<Option<u32>>)> {
    let staircase = per_brick(bricks, |b| Some(b.max_element().min(2)));
    let centre = UVec3::new(
        rng.below(bricks.x),
        rng.below(bricks.y),
        rng.below(bricks.z),
    );
    let mut random = distance_plan(bricks, centre.as_ivec3(), 0, LEVELS);
    let hole = rng.below(random.len() as u32) as usize;
    random[hole] = None;
    let islands = per_brick(bricks, |b| {
        Some(if b == UVec3::ZERO {
            0
        } else if b.max_element() == 1 || b == UVec3::new(2, 1, 1) {
            1
        } else {
            2
        })
    });
    vec![
        ("staircase", staircase),
        ("random", random),
        ("islands", islands),
    ]
}

#[test]
fn the_gpu_three_level_cache_matches_its_cpu_mirror() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x3_1e7e_6a00_0001);
        let dims = UVec3::new(4 * N, 3 * N, 3 * N);
        let volume = textured_volume(&mut rng, dims);
        let grid = BrickGrid::new(dims, N).unwrap();
        let grids = LevelGrid::vertex_pyramid(&volume, LEVELS);
        // 2 x 2 x 2 slots of (n+4)^3 = 12^3 texels: fewer than the 36 bricks, so the plans must
        // use the coarser levels.
        let geometry = ThreeLevelGeometry::new(N, UVec3::new(32, 32, 32)).unwrap();
        for (name, levels) in plans(&mut rng, grid.bricks_per_axis()) {
            let field = LevelField::new(&grid, &grids, &levels).unwrap();
            for transition in [Transition::Smooth, Transition::Discontinuous] {
                let cpu = LevelReferenceCache::build(&field, &geometry, transition).unwrap();
                let mut gpu = GpuLevelCache::new(&ctx, &field, &geometry, transition).unwrap();

                // The texels of every drawn brick after upload and the GPU fixups.
                let texels = gpu.read_back().unwrap();
                let e = geometry.extent();
                let mut compared = 0;
                for place in cpu.places.iter().flatten() {
                    let origin = geometry.origin(*place).unwrap();
                    let edge = geometry.stored_edge(place.level);
                    for z in origin.z..origin.z + edge {
                        for y in origin.y..origin.y + edge {
                            for x in origin.x..origin.x + edge {
                                let i = (x + e.x * (y + e.y * z)) as usize;
                                let (g, c) = (texels[i], cpu.image.texels[i]);
                                assert!(
                                    (g - c).abs() < 1e-6,
                                    "{name} {transition:?} texel ({x}, {y}, {z}) of {place:?}: gpu {g}, cpu {c}"
                                );
                                compared += 1;
                            }
                        }
                    }
                }
                assert!(compared > 0);

                // The field, read with the ray-caster's functions.
                let points = probe_points(&mut rng, dims, N, LEVELS, 3000);
                let values = gpu.sample(&points).unwrap();
                let view = cpu.view();
                for (p, g) in points.iter().zip(&values) {
                    match (g, sample_mixed(&view, *p, transition)) {
                        (Some(g), Some(c)) => assert!(
                            (g - c).abs() < 2e-3,
                            "{name} {transition:?} at {p}: gpu {g}, cpu {c}"
                        ),
                        (g, c) => assert_eq!(g.is_some(), c.is_some(), "{name} at {p}"),
                    }
                }

                // Continuity on the GPU: the largest jump between p +- eps d shrinks with eps when
                // smooth (the bound of tests/gpu_mixed.rs: slope 14 over 2 sqrt(3) eps plus the
                // GPU's sub-texel weight quantisation) and stays when discontinuous.
                let dirs = [
                    Vec3::X,
                    Vec3::Y,
                    Vec3::Z,
                    Vec3::ONE,
                    Vec3::new(1.0, -1.0, 1.0),
                ];
                let eps_values = [1e-2f32, 1e-3];
                let mut max_jump = [0.0f32; 2];
                for (k, eps) in eps_values.iter().enumerate() {
                    let probes: Vec<Vec3> = points
                        .iter()
                        .flat_map(|p| {
                            dirs.iter()
                                .flat_map(move |d| [*p + *eps * *d, *p - *eps * *d])
                        })
                        .collect();
                    let values = gpu.sample(&probes).unwrap();
                    for pair in values.chunks_exact(2) {
                        if let (Some(a), Some(b)) = (pair[0], pair[1]) {
                            max_jump[k] = max_jump[k].max((a - b).abs());
                        }
                    }
                }
                eprintln!("{name} {transition:?}: max jump {max_jump:?} at eps {eps_values:?}");
                match transition {
                    Transition::Smooth => {
                        for k in 0..2 {
                            assert!(
                                max_jump[k] < 14.0 * 3.5 * eps_values[k] + 0.01,
                                "{name}: the smooth GPU field jumps: {max_jump:?}"
                            );
                        }
                        assert!(
                            max_jump[1] < 0.5 * max_jump[0],
                            "{name}: smooth jumps must shrink with eps: {max_jump:?}"
                        );
                    }
                    Transition::Discontinuous => assert!(
                        max_jump[1] > 0.05 && max_jump[1] > 0.5 * max_jump[0],
                        "{name}: the discontinuous GPU field should jump: {max_jump:?}"
                    ),
                }
            }
        }
    }
    common::finish(ctx);
}
