//! Mixed-resolution costs, measured side by side in one run on one scene:
//! - frame time of the brick cache with every brick hi-res against the plain single-texture
//!   ray-caster (address translation + brick walking overhead; target <= 1.3x);
//! - frame time smooth / discontinuous on a plan with many hi/lo transitions (target <= 1.15x);
//! - upload + fixup after a full residency change, as a fraction of one frame;
//! - re-uploaded vs resident bricks after a small change of the plan.
//!
//! Run: `cargo bench --bench mixed` (MIXVOL_BENCH_SIZE, MIXVOL_BENCH_FRAMES to change). On lavapipe
//! the absolute times are CPU times; compare the ratios.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::cache::Level;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference::Transition;
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;

fn time_frames(
    renderer: &mut Renderer,
    camera: &Camera,
    settings: &RenderSettings,
    size: u32,
    frames: u32,
) -> mixvol::Result<f64> {
    renderer.render(camera, settings, size, size)?; // warm-up (llvmpipe compiles at first draw)
    let mut gpu = Vec::new();
    for _ in 0..frames {
        let f = renderer.render(camera, settings, size, size)?;
        gpu.push(f.timing.gpu_raycast_ms.unwrap_or(f.timing.cpu_frame_ms));
    }
    Ok(median(gpu))
}

fn main() -> mixvol::Result<()> {
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let frames = env_u32("MIXVOL_BENCH_FRAMES", 7).max(1);
    let brick_size = 32;
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(128), ScalarType::U8)?);
    let grid = BrickGrid::new(volume.dims(), brick_size)
        .map_err(|e| mixvol::Error::InvalidInput(e.to_string()))?;
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

    let mut plain = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    plain.set_transfer_function(&tf)?;
    plain.set_volume(&volume)?;
    let plain_ms = time_frames(&mut plain, &camera, &settings, size, frames)?;
    drop(plain);

    let mut rows = Vec::new();
    let mut full_change = None;
    let mut small_change = None;
    for transition in [Transition::Discontinuous, Transition::Smooth] {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        r.set_transfer_function(&tf)?;
        let config = MixedConfig {
            brick_size,
            filter: DownsampleFilter::Mean2,
            cache_budget_bytes: 64 << 20,
            transition,
        };
        r.set_mixed_volume(volume.clone(), config)?;
        r.set_levels(&all_hi)?;
        let hi_ms = time_frames(&mut r, &camera, &settings, size, frames)?;
        let report = r.set_levels(&checker)?;
        let checker_ms = time_frames(&mut r, &camera, &settings, size, frames)?;
        if transition == Transition::Smooth {
            full_change = Some((report, checker_ms));
            // A small change: flip one brick next to the centre.
            let mut moved = checker.clone();
            let i = grid.linear_index(bricks / 2);
            moved[i] = if moved[i] == Level::Hi {
                Level::Lo
            } else {
                Level::Hi
            };
            small_change = Some(r.set_levels(&moved)?);
        }
        rows.push((transition, hi_ms, checker_ms, r.current_variant()));
    }
    let info = ctx.info();
    println!("# mixed-resolution ray-cast, Marschner-Lobb 128^3 u8, bricks {brick_size}^3 ({}x{}x{}), {size}x{size}, median of {frames} frames", bricks.x, bricks.y, bricks.z);
    println!("# device: {} ({:?})", info.name, info.device_type);
    println!();
    println!("| configuration | frame ms | ratio |");
    println!("|---|---|---|");
    println!("| plain single-texture ray-cast | {plain_ms:.2} | 1.00 |");
    for (t, hi, _, _) in &rows {
        println!(
            "| brick cache, all hi-res ({t:?} build) | {hi:.2} | {:.2} vs plain |",
            hi / plain_ms
        );
    }
    let disc = rows[0].2;
    let smooth = rows[1].2;
    println!("| checkerboard hi/lo, discontinuous | {disc:.2} | 1.00 |");
    println!(
        "| checkerboard hi/lo, smooth (C0) | {smooth:.2} | {:.2} vs discontinuous |",
        smooth / disc
    );
    if let Some((report, frame_ms)) = full_change {
        println!();
        println!(
            "full residency change (all hi -> checkerboard): {} bricks / {:.1} MB uploaded, {} fixup bricks; pack {:.1} ms, upload+fixup submission {:.1} ms = {:.2} frames",
            report.uploaded_bricks,
            report.uploaded_bytes as f64 / 1e6,
            report.fixup_bricks,
            report.pack_ms,
            report.update_ms,
            report.update_ms / frame_ms
        );
    }
    if let Some(report) = small_change {
        println!(
            "small change (one brick flipped): {} bricks re-uploaded of {} resident",
            report.uploaded_bricks,
            report.hi_bricks + report.lo_bricks
        );
    }
    Ok(())
}
