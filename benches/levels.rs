//! Three levels against two, measured side by side in one run on one scene (issue 19):
//! - frame time of the three-level cache (`VolumeSource::Levels`, `(n+4)^3` slots) against the
//!   two-level cache (`VolumeSource::Mixed`, `(n+2)^3` slots) with the same residency of levels
//!   0-1 (a checkerboard), smooth and discontinuous;
//! - the smooth / discontinuous ratio at each level pair of the three-level cache: 0-1 (the
//!   ray-caster blends in the half-voxel bands) and 1-2 (the skeleton fixup does the work, the
//!   ray-caster only fetches), and the three-level checkerboards against all level 0;
//! - the same ratio at the block level pairs 2-3 and 3-4 (bricks of 16, halves of the volume).
//!
//! The configurations are measured in interleaved rounds (one frame of each per round) and the
//! medians compared. Both caches hold f32 texels (an f32 volume). Run: `cargo bench --bench
//! levels` (MIXVOL_BENCH_SIZE, MIXVOL_BENCH_FRAMES to change; MIXVOL_BENCH_SHADED=1 shades).
//! On lavapipe the absolute times are CPU times; compare the ratios.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Shading, Transition};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;

fn main() -> mixvol::Result<()> {
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let frames = env_u32("MIXVOL_BENCH_FRAMES", 9).max(1);
    let shaded = env_u32("MIXVOL_BENCH_SHADED", 0) != 0;
    let brick_size = 32;
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(128), ScalarType::F32)?);
    let grid = BrickGrid::new(volume.dims(), brick_size)?;
    let tf = TransferFunction::preset(TfPreset::Bands);
    let camera = Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0);
    let settings = RenderSettings {
        shading: shaded.then(Shading::default),
        ..RenderSettings::default()
    };
    let bricks = grid.bricks_per_axis();
    let odd = |i: usize| {
        let b = grid.brick_coords(i);
        (b.x + b.y + b.z) % 2 == 1
    };
    let checker: Vec<Level> = (0..grid.brick_count())
        .map(|i| if odd(i) { Level::Lo } else { Level::Hi })
        .collect();
    let checker_levels = |fine: u32| -> Vec<Option<u32>> {
        (0..grid.brick_count())
            .map(|i| Some(fine + u32::from(odd(i))))
            .collect()
    };
    let config = |transition| MixedConfig {
        brick_size,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 256 << 20,
        transition,
        max_levels: 0,
    };
    let two_level = |transition| -> mixvol::Result<Renderer> {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        r.set_transfer_function(&tf)?;
        r.set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config: config(transition),
        })?;
        r.set_levels(&checker)?;
        Ok(r)
    };
    let three_level = |transition, levels: &[Option<u32>]| -> mixvol::Result<Renderer> {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        r.set_transfer_function(&tf)?;
        r.set_source(VolumeSource::Levels {
            volume: volume.clone(),
            levels,
            config: config(transition),
        })?;
        Ok(r)
    };
    let all_fine = vec![Some(0); grid.brick_count()];
    let mut configs: Vec<(&str, Renderer)> = vec![
        (
            "two levels, checkerboard 0/1, discontinuous",
            two_level(Transition::Discontinuous)?,
        ),
        (
            "two levels, checkerboard 0/1, smooth",
            two_level(Transition::Smooth)?,
        ),
        (
            "three levels, checkerboard 0/1, discontinuous",
            three_level(Transition::Discontinuous, &checker_levels(0))?,
        ),
        (
            "three levels, checkerboard 0/1, smooth",
            three_level(Transition::Smooth, &checker_levels(0))?,
        ),
        (
            "three levels, checkerboard 1/2, discontinuous",
            three_level(Transition::Discontinuous, &checker_levels(1))?,
        ),
        (
            "three levels, checkerboard 1/2, smooth",
            three_level(Transition::Smooth, &checker_levels(1))?,
        ),
        (
            "three levels, all level 0",
            three_level(Transition::Smooth, &all_fine)?,
        ),
    ];
    let measure = |configs: &mut [(&str, Renderer)]| -> mixvol::Result<Vec<f64>> {
        let mut times = vec![Vec::new(); configs.len()];
        for (_, r) in configs.iter_mut() {
            r.render(&camera, &settings, size, size)?; // warm-up: llvmpipe compiles at first draw
        }
        for _ in 0..frames {
            for (i, (_, r)) in configs.iter_mut().enumerate() {
                let f = r.render(&camera, &settings, size, size)?;
                times[i].push(f.timing.gpu_raycast_ms.unwrap_or(f.timing.cpu_frame_ms));
            }
        }
        Ok(times.into_iter().map(median).collect())
    };
    let m = measure(&mut configs)?;
    let info = ctx.info();
    println!(
        "# three levels against two, Marschner-Lobb 128^3 f32, bricks {brick_size}^3 ({}x{}x{}), {size}x{size}, {}, median of {frames} interleaved frames",
        bricks.x,
        bricks.y,
        bricks.z,
        if shaded { "shaded" } else { "unshaded" }
    );
    println!("# device: {} ({:?})", info.name, info.device_type);
    println!();
    println!("| configuration | frame ms | ratio |");
    println!("|---|---|---|");
    let row = |i: usize, ratio: String| println!("| {} | {:.2} | {ratio} |", configs[i].0, m[i]);
    row(0, "1.00".into());
    row(1, format!("{:.2} vs discontinuous", m[1] / m[0]));
    row(2, format!("{:.2} vs two levels", m[2] / m[0]));
    row(
        3,
        format!(
            "{:.2} vs discontinuous, {:.2} vs two levels",
            m[3] / m[2],
            m[3] / m[1]
        ),
    );
    row(4, format!("{:.2} vs all level 0", m[4] / m[6]));
    row(5, format!("{:.2} vs discontinuous", m[5] / m[4]));
    row(6, "1.00".into());

    // The block levels (past 2): bricks of 16 (8x8x8), the halves x < 4 and x >= 4 one level
    // apart, so levels 3 and 4 come in whole aligned blocks.
    let block_size = 16;
    let grid = BrickGrid::new(volume.dims(), block_size)?;
    let halves = |low: u32| -> Vec<Option<u32>> {
        (0..grid.brick_count())
            .map(|i| Some(low + u32::from(grid.brick_coords(i).x >= 4)))
            .collect()
    };
    let block_config = |transition| MixedConfig {
        brick_size: block_size,
        ..config(transition)
    };
    let blocks = |transition, levels: &[Option<u32>]| -> mixvol::Result<Renderer> {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        r.set_transfer_function(&tf)?;
        r.set_source(VolumeSource::Levels {
            volume: volume.clone(),
            levels,
            config: block_config(transition),
        })?;
        Ok(r)
    };
    let mut deep: Vec<(&str, Renderer)> = vec![
        (
            "halves 2/3, discontinuous",
            blocks(Transition::Discontinuous, &halves(2))?,
        ),
        (
            "halves 2/3, smooth",
            blocks(Transition::Smooth, &halves(2))?,
        ),
        (
            "halves 3/4, discontinuous",
            blocks(Transition::Discontinuous, &halves(3))?,
        ),
        (
            "halves 3/4, smooth",
            blocks(Transition::Smooth, &halves(3))?,
        ),
        (
            "all level 0",
            blocks(Transition::Smooth, &vec![Some(0); grid.brick_count()])?,
        ),
    ];
    let d = measure(&mut deep)?;
    println!();
    println!("Block levels, bricks {block_size}^3 (8x8x8), the same scene and frames:");
    println!();
    println!("| configuration | frame ms | ratio |");
    println!("|---|---|---|");
    let row = |i: usize, ratio: String| println!("| {} | {:.2} | {ratio} |", deep[i].0, d[i]);
    row(0, format!("{:.2} vs all level 0", d[0] / d[4]));
    row(1, format!("{:.2} vs discontinuous", d[1] / d[0]));
    row(2, format!("{:.2} vs all level 0", d[2] / d[4]));
    row(3, format!("{:.2} vs discontinuous", d[3] / d[2]));
    row(4, "1.00".into());
    Ok(())
}
