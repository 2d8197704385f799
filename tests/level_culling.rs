//! Value culling of a three-level source (issue 19, item 4): `Renderer::update` leaves undrawn
//! the bricks whose conservative range the transfer function maps to zero opacity, which saves
//! their slots and changes no pixel, and culls nothing where the mode reads every value.

mod common;

use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, ValueRange};
use mixvol::levels::conservative_ranges;
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderMode, RenderSettings, Transition};
use mixvol::volume::{Volume, VoxelData};
use std::sync::Arc;

const N: u32 = 8;

/// 0.05 (transparent under `Bands`, which is clear below 0.2) where x < 3n, a wave in
/// 0.3..1.0 beyond.
fn half_empty_volume() -> Volume {
    let dims = UVec3::new(6 * N, 4 * N, 4 * N);
    let mut data = Vec::new();
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                let p = UVec3::new(x, y, z).as_vec3();
                data.push(if x < 3 * N {
                    0.05
                } else {
                    0.65 + 0.35 * (0.4 * p.x).sin() * (0.3 * p.y + 0.5 * p.z).cos()
                });
            }
        }
    }
    Volume::new(dims, Vec3::ONE, VoxelData::F32(data)).unwrap()
}

/// The culling ranges: a brick's range covers its own and its neighbours' stored ranges at
/// levels 0 and 1, so the empty bricks next to the wave are not culled, and those farther away
/// hold 0.05 only; coarser levels do not count.
#[test]
fn culling_ranges_cover_levels_zero_and_one_and_every_neighbour() {
    let grid = BrickGrid::new(UVec3::new(6 * N, 4 * N, 4 * N), N).unwrap();
    // 0.05 left of x = 3 bricks, 0.9 right of it; level 1 of brick 2 reaches 0.5, and every
    // coarser level spans both (1.0), which must not count.
    let ranges = conservative_ranges(&grid, 5, &mut |level, first| {
        let v = match (level, first.x) {
            (0, x) | (1, x) if x != 2 => {
                if x < 3 {
                    0.05
                } else {
                    0.9
                }
            }
            (0, _) => 0.05,
            (1, _) => 0.5,
            _ => 1.0,
        };
        Ok(ValueRange { min: v, max: v })
    })
    .unwrap();
    for (i, b) in grid.bricks().enumerate() {
        let r = ranges[i];
        let (min, max) = match b.x {
            0 => (0.05, 0.05),
            1 => (0.05, 0.5),
            2 | 3 => (0.05, 0.9),
            _ => (0.9, 0.9),
        };
        assert_eq!((r.min, r.max), (min, max), "brick {b}");
    }
}

/// On the GPU: at full resolution, the bricks the transfer function leaves empty are not drawn
/// (fewer slots), and the frame equals the frame with every brick drawn; in MIP, which reads
/// every value, nothing is culled.
#[test]
fn culled_bricks_save_slots_and_change_no_pixel() {
    let ctx = common::validated_context();
    {
        let volume = half_empty_volume();
        let grid = BrickGrid::new(volume.dims(), N).unwrap();
        let tf = TransferFunction::preset(TfPreset::Bands);
        let camera = Camera::perspective(Vec3::new(1.3, 0.7, 1.2), Vec3::ZERO, 40.0);
        let settings = RenderSettings::default();
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer.set_transfer_function(&tf).unwrap();
        renderer
            .set_source(VolumeSource::Levels {
                volume: Arc::new(volume.clone()),
                levels: &[],
                config: MixedConfig {
                    brick_size: N,
                    filter: DownsampleFilter::Mean2,
                    cache_budget_bytes: 64 * 64 * 64 * 4,
                    transition: Transition::Smooth,
                    max_levels: 0,
                },
            })
            .unwrap();
        // A tiny target: every brick in view wants level 0.
        let choice = common::step_levels(&mut renderer, &camera, &settings, 48, 48, 0.01).unwrap();
        let culled: Vec<UVec3> = (0..grid.brick_count())
            .filter(|&i| choice.levels[i].is_none())
            .map(|i| grid.brick_coords(i))
            .collect();
        // Bricks x = 0, 1, 2 hold 0.05, but the level-0 stored brick of x = 2 reaches two
        // voxels into the wave (its border), so only x = 0 has nothing but 0.05 around it.
        assert_eq!(culled.len(), 4 * 4, "culled {culled:?}");
        assert!(culled.iter().all(|b| b.x == 0));
        assert!(choice.levels.iter().flatten().all(|&l| l == 0));
        assert_eq!(choice.slots, (grid.brick_count() - culled.len()) as u64);
        let with_culling = renderer.render(&camera, &settings, 48, 48).unwrap();
        assert!(with_culling.variant.absent_bricks);

        let all = vec![Some(0); grid.brick_count()];
        renderer.set_brick_levels(&all).unwrap();
        let everything = renderer.render(&camera, &settings, 48, 48).unwrap();
        let d = common::diff(&with_culling.pixels, &everything.pixels, 1e-5);
        assert!(d.max < 1e-5, "culling changed the frame: {d:?}");
        let covered = everything.pixels.iter().filter(|p| p.w > 0.05).count();
        assert!(covered > 48 * 48 / 10, "the frame shows the volume");

        // MIP reads every value: nothing is culled.
        let mip = RenderSettings {
            mode: RenderMode::Mip,
            ..settings
        };
        let choice = common::step_levels(&mut renderer, &camera, &mip, 48, 48, 0.01).unwrap();
        assert!(choice.levels.iter().all(Option::is_some));
    }
    common::finish(ctx);
}
