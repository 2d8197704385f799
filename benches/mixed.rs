//! Mixed-resolution costs, measured side by side in one run on one scene:
//! - frame time of the brick cache with every brick hi-res against the plain single-texture
//!   ray-caster (address translation + brick walking overhead; target <= 1.3x);
//! - frame time smooth / discontinuous on a plan with many hi/lo transitions (target <= 1.15x),
//!   unshaded and shaded;
//! - upload + fixup after a full residency change, as a fraction of one frame;
//! - re-uploaded vs resident bricks after a small change of the plan.
//!
//! The configurations are measured in interleaved rounds (one frame of each per round) and the
//! medians compared, so background load on the machine hits every configuration alike.
//! Run: `cargo bench --bench mixed` (MIXVOL_BENCH_SIZE, MIXVOL_BENCH_FRAMES to change). On lavapipe
//! the absolute times are CPU times; compare the ratios.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RenderSettings, Shading};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;

fn main() -> mixvol::Result<()> {
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let frames = env_u32("MIXVOL_BENCH_FRAMES", 9).max(1);
    let brick_size = 32;
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(128), ScalarType::U8)?);
    let grid = BrickGrid::new(volume.dims(), brick_size)?;
    let tf = TransferFunction::preset(TfPreset::Bands);
    let camera = Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0);
    let settings = RenderSettings::default();
    let bricks = grid.bricks_per_axis();
    let checker: Vec<Level> = (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i);
            if (b.x + b.y + b.z) % 2 == 0 {
                Level::Hi
            } else {
                Level::Lo
            }
        })
        .collect();
    let all_hi = vec![Level::Hi; grid.brick_count()];
    // The same plan with one brick culled (the far corner): both variants then carry the jump over
    // absent bricks, as scenes with empty space do.
    let mut checker_culled = checker.clone();
    checker_culled[0] = Level::Absent;
    let mixed = |transition, levels: &[Level]| -> mixvol::Result<Renderer> {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        r.set_transfer_function(&tf)?;
        r.set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config: MixedConfig {
                brick_size,
                filter: DownsampleFilter::Mean2,
                cache_budget_bytes: 64 << 20,
                transition,
                max_levels: 0,
            },
        })?;
        r.set_levels(levels)?;
        Ok(r)
    };
    let mut plain = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    plain.set_transfer_function(&tf)?;
    plain.set_source(VolumeSource::Volume(&volume))?;
    let mut configs: Vec<(&str, Renderer)> = vec![
        ("plain single-texture ray-cast", plain),
        (
            "brick cache, all hi-res",
            mixed(Transition::Smooth, &all_hi)?,
        ),
        (
            "checkerboard hi/lo, discontinuous",
            mixed(Transition::Discontinuous, &checker)?,
        ),
        (
            "checkerboard hi/lo, smooth (C0)",
            mixed(Transition::Smooth, &checker)?,
        ),
        (
            "checkerboard, one brick culled, discontinuous",
            mixed(Transition::Discontinuous, &checker_culled)?,
        ),
        (
            "checkerboard, one brick culled, smooth (C0)",
            mixed(Transition::Smooth, &checker_culled)?,
        ),
    ];
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
    // The same pair shaded (Blinn-Phong from central differences through the reconstruction):
    // the paper paid about 10x there.
    let shaded = RenderSettings {
        shading: Some(Shading::default()),
        ..settings
    };
    let mut shaded_times = vec![Vec::new(); 2];
    for (_, r) in configs[2..4].iter_mut() {
        r.render(&camera, &shaded, size, size)?;
    }
    for _ in 0..frames {
        for (k, (_, r)) in configs[2..4].iter_mut().enumerate() {
            let f = r.render(&camera, &shaded, size, size)?;
            shaded_times[k].push(f.timing.gpu_raycast_ms.unwrap_or(f.timing.cpu_frame_ms));
        }
    }
    let shaded_medians: Vec<f64> = shaded_times.into_iter().map(median).collect();
    let medians: Vec<f64> = times.into_iter().map(median).collect();
    let info = ctx.info();
    println!(
        "# mixed-resolution ray-cast, Marschner-Lobb 128^3 u8, bricks {brick_size}^3 ({}x{}x{}), {size}x{size}, median of {frames} interleaved frames",
        bricks.x, bricks.y, bricks.z
    );
    println!("# device: {} ({:?})", info.name, info.device_type);
    println!();
    // Issue 4's targets, for the ratios that have one (measured where they are meant on a GPU;
    // on a CPU device the verdict is only indicative).
    let verdict = |ratio: f64, target: f64| {
        if ratio <= target {
            format!("<= {target} met")
        } else {
            format!("<= {target} not met")
        }
    };
    let all_hi_ratio = medians[1] / medians[0];
    let smooth_ratio = medians[3] / medians[2];
    let shaded_ratio = shaded_medians[1] / shaded_medians[0];
    let culled_ratio = medians[5] / medians[4];
    println!("| configuration | frame ms | ratio | target |");
    println!("|---|---|---|---|");
    println!("| {} | {:.2} | 1.00 | |", configs[0].0, medians[0]);
    println!(
        "| {} | {:.2} | {all_hi_ratio:.2} vs plain | {} |",
        configs[1].0,
        medians[1],
        verdict(all_hi_ratio, 1.3)
    );
    println!("| {} | {:.2} | 1.00 | |", configs[2].0, medians[2]);
    println!(
        "| {} | {:.2} | {smooth_ratio:.2} vs discontinuous | {} |",
        configs[3].0,
        medians[3],
        verdict(smooth_ratio, 1.15)
    );
    println!("| {} | {:.2} | 1.00 | |", configs[4].0, medians[4]);
    println!(
        "| {} | {:.2} | {culled_ratio:.2} vs discontinuous | {} |",
        configs[5].0,
        medians[5],
        verdict(culled_ratio, 1.15)
    );
    println!(
        "| {}, shaded | {:.2} | 1.00 | |",
        configs[2].0, shaded_medians[0]
    );
    println!(
        "| {}, shaded | {:.2} | {shaded_ratio:.2} vs discontinuous shaded | (the paper: about 10) |",
        configs[3].0, shaded_medians[1],
    );

    // A full residency change and a small one, on the smooth checkerboard renderer.
    let smooth = &mut configs[3].1;
    let report = smooth.set_levels(&all_hi)?;
    let back = smooth.set_levels(&checker)?;
    println!();
    println!(
        "full residency change (all hi -> checkerboard): {} bricks / {:.1} MB uploaded, {} fixup bricks; pack {:.1} ms, upload+fixup submission {:.1} ms = {:.2} frames (the reverse change: {} bricks)",
        back.uploaded_bricks,
        back.uploaded_bytes as f64 / 1e6,
        back.fixup_bricks,
        back.pack_ms,
        back.update_ms,
        back.update_ms / medians[3],
        report.uploaded_bricks,
    );
    let mut moved = checker.clone();
    let i = grid.linear_index(bricks / 2);
    moved[i] = if moved[i] == Level::Hi {
        Level::Lo
    } else {
        Level::Hi
    };
    let small = smooth.set_levels(&moved)?;
    println!(
        "small change (one brick flipped): {} bricks re-uploaded of {} resident",
        small.uploaded_bricks,
        small.hi_bricks + small.lo_bricks
    );
    Ok(())
}
