//! What a residency change of the three-level cache costs, measured side by side in one run
//! (issue 19, item 4): along an orbit, the levels each view wants (`plan::choose_levels`) are
//! set on two renderers of one volume; one moves from the previous view's levels (uploading only
//! the new bricks, those moved to make room and those whose coarser neighbours changed), the
//! other is emptied first and so uploads every drawn brick (what every change cost before).
//! Each `set_brick_levels` is timed with its upload and fixups (it waits for the GPU).
//!
//! Run: `cargo bench --bench level_residency` (MIXVOL_BENCH_VIEWS, MIXVOL_BENCH_SIZE to change).
//! On lavapipe the absolute times are CPU times; compare the ratio.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::lod::{BrickGeometry, LodView};
use mixvol::plan::choose_levels;
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, Transition};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;
use std::time::Instant;

fn main() -> mixvol::Result<()> {
    let views = env_u32("MIXVOL_BENCH_VIEWS", 16).max(2);
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let brick_size = 16;
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume = SyntheticField::MarschnerLobb.generate(UVec3::splat(256), ScalarType::U8)?;
    let grid = BrickGrid::new(volume.dims(), brick_size)?;
    let geometry = BrickGeometry::new(grid, volume.spacing())?;
    let config = MixedConfig {
        brick_size,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 32 << 20,
        transition: Transition::Smooth,
        max_levels: 0,
    };
    let mut moving = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    let mut fresh = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    for r in [&mut moving, &mut fresh] {
        r.set_source(VolumeSource::Levels {
            volume: Arc::new(volume.clone()),
            levels: &[],
            config,
        })?;
    }
    let levels = mixvol::cache::pyramid_levels(brick_size, grid.bricks_per_axis());
    // The slots of the renderers' cache: 32 MiB of u8 texels.
    let slots = mixvol::cache::SlotGeometry::choose(
        brick_size,
        mixvol::cache::classes_for_levels(levels),
        1,
        config.cache_budget_bytes,
        ctx.info().limits.max_image_dimension3_d,
        grid.brick_count() as u32,
    )?
    .slot_count();
    let active = vec![true; grid.brick_count()];
    let none = vec![None; grid.brick_count()];
    let (mut moved_ms, mut fresh_ms, mut moved_bricks, mut fresh_bricks) =
        (Vec::new(), Vec::new(), 0, 0);
    for view in 0..views {
        let angle = view as f32 / views as f32 * std::f32::consts::TAU;
        let eye = Vec3::new(1.3 * angle.cos(), 0.5, 1.3 * angle.sin());
        let camera = Camera::perspective(eye, Vec3::ZERO, 40.0);
        let lod_view = LodView::new(&camera, size, size)?;
        let choice = choose_levels(&geometry, &lod_view, &active, levels, u64::from(slots), 1.0)
            .map_err(|e| mixvol::Error::InvalidInput(e.to_string()))?;
        fresh.set_brick_levels(&none)?;
        let start = Instant::now();
        let report = fresh.set_brick_levels(&choice.levels)?;
        let full = start.elapsed().as_secs_f64() * 1e3;
        let start = Instant::now();
        let moved = moving.set_brick_levels(&choice.levels)?;
        let part = start.elapsed().as_secs_f64() * 1e3;
        if view > 0 {
            // The first view fills both caches from empty.
            fresh_ms.push(full);
            moved_ms.push(part);
            fresh_bricks += report.uploaded_bricks;
            moved_bricks += moved.uploaded_bricks;
        }
        println!(
            "view {view:2}: {:5} stored bricks; moving uploads {:5} ({:3} moved) in {part:7.1} ms, \
             fresh uploads {:5} in {full:7.1} ms",
            report.stored_bricks, moved.uploaded_bricks, moved.moved_bricks, report.uploaded_bricks
        );
    }
    let (m, f) = (median(moved_ms), median(fresh_ms));
    println!(
        "\nMarschner-Lobb 256^3 u8, bricks of {brick_size}, {levels} levels, {slots} slots, {size}x{size}, \
         {} views after the first ({}):",
        views - 1,
        ctx.info().name
    );
    println!("| change | bricks uploaded (sum) | median ms per change |");
    println!("|---|---|---|");
    println!("| from the previous view (incremental) | {moved_bricks} | {m:.1} |");
    println!("| from empty (every drawn brick) | {fresh_bricks} | {f:.1} |");
    println!(
        "ratio incremental / fresh: {:.2}x time, {:.2}x bricks",
        m / f,
        moved_bricks as f64 / fresh_bricks.max(1) as f64
    );
    Ok(())
}
