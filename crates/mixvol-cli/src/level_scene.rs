//! Scenes drawn through the three-level cache from stored bricks read in the background: a
//! level store, or an OME-Zarr image's own pyramid (`--stream`); and the
//! plans, budgets and report lines every three-level scene shares.

use crate::args::{LevelsArg, RenderArgs};
use crate::levels::{per_level_counts, staircase};
use crate::render::Scene;
use mixvol::bricks::BrickGrid;
use mixvol::plan::PlanOptions;
use mixvol::renderer::{MixedConfig, Renderer, ResidencyConfig, VolumeSource};
use mixvol::scene::Transition;
use mixvol::store::{LevelBackend, LevelStreamConfig, LevelStreamer};
use mixvol::{Error, Result};
use std::sync::Arc;

/// Draws `backend` through the three-level cache at `--levels` (default: from the camera),
/// its stored bricks read in the background into `stream_ram` bytes of RAM (`ram`: the whole
/// budget, for the message), and prints the set-up (`note` names where the levels come from).
pub fn level_scene(
    renderer: &mut Renderer,
    args: &RenderArgs,
    backend: Arc<dyn LevelBackend>,
    stream_ram: u64,
    transition: Transition,
    note: &str,
) -> Result<Scene> {
    let pattern = args.mixed.levels.unwrap_or(LevelsArg::Camera);
    let grid = backend.grid();
    let least = least_level_upload(&grid, backend.scalar().size_bytes() as u64);
    let (cache, upload) = args.residency.level_budgets(least)?;
    let config = MixedConfig {
        brick_size: grid.brick_size(),
        transition,
        cache_budget_bytes: cache,
        ..args.mixed.config(&args.residency)?
    };
    let (plan, camera_levels) = three_level_plan(&grid, pattern, backend.level_count())?;
    set_level_residency(renderer, args, upload)?;
    // Stored bricks are read in the background: views step onto those in RAM.
    let streamer = Arc::new(LevelStreamer::new(
        backend.clone(),
        LevelStreamConfig {
            ram_budget_bytes: usize::try_from(stream_ram).unwrap_or(usize::MAX),
            ..LevelStreamConfig::default()
        },
    )?);
    renderer.set_source(VolumeSource::LevelStream {
        streamer: streamer.clone(),
        levels: &plan,
        config,
    })?;
    print_three_level(&grid, &plan, camera_levels, note);
    Ok(Scene {
        volume: None,
        planned: camera_levels,
        config: Some(config),
        level_streamer: Some(streamer),
        zarr: None,
    })
}

/// The first plan of a three-level scene of `grid` with `levels` levels: empty for
/// `--levels camera` (every brick coarsest until the first view chooses; the flag returned),
/// the staircase capped at the last level for `--levels staircase`. Other patterns are
/// two-level ones, an error here.
pub fn three_level_plan(
    grid: &BrickGrid,
    pattern: LevelsArg,
    levels: u32,
) -> Result<(Vec<Option<u32>>, bool)> {
    match pattern {
        LevelsArg::Camera => Ok((Vec::new(), true)),
        LevelsArg::Staircase => {
            let last = levels.saturating_sub(1);
            let plan = staircase(grid)
                .into_iter()
                .map(|l| l.map(|k| k.min(last)))
                .collect();
            Ok((plan, false))
        }
        other => Err(Error::InvalidInput(format!(
            "--levels {other:?} is a two-level pattern; a level store is drawn with --levels \
             camera (the default) or --levels staircase"
        ))),
    }
}

/// The upload bytes of the largest single residency step of a level scene of `grid` with
/// `scalar_bytes` bytes a texel ([`mixvol::embed::largest_step_bytes`]), for full-resolution
/// stored bricks with two border texels a side (the most any cache keeps).
pub fn least_level_upload(grid: &BrickGrid, scalar_bytes: u64) -> u64 {
    let edge = u64::from(grid.brick_size()) + 4;
    mixvol::embed::largest_step_bytes(edge * edge * edge * scalar_bytes, grid.brick_count())
}

/// The residency of a three-level scene whose levels come from the camera: `upload` (the
/// upload share of `--gpu-budget-mb`, [`crate::args::ResidencyArgs::level_budgets`]) as the
/// per-step upload budget, `--voxel-px` as the target of the level choice, and
/// `--weigh-by-value`.
pub fn set_level_residency(renderer: &mut Renderer, args: &RenderArgs, upload: u64) -> Result<()> {
    let voxel_px = args.mixed.voxel_px;
    if !(voxel_px.is_finite() && voxel_px > 0.0) {
        return Err(Error::InvalidInput(format!(
            "--voxel-px {voxel_px}: expected a positive number of pixels"
        )));
    }
    renderer.set_residency_config(ResidencyConfig {
        upload_bytes_per_frame: upload,
        weigh_by_value: args.residency.weigh_by_value,
        options: PlanOptions {
            error_threshold: voxel_px,
            ..PlanOptions::default()
        },
        ..ResidencyConfig::default()
    });
    Ok(())
}

/// What a level store's background reader did.
pub fn level_stream_line(s: &mixvol::store::LevelStreamStats) -> String {
    format!(
        "level stream: {} stored bricks read in the background ({:.1} MB in {:.1} ms), {} on the render thread, {} failed; peak {:.1} of {:.1} MB RAM",
        s.loads,
        s.bytes_read as f64 / 1e6,
        s.read_time.as_secs_f64() * 1e3,
        s.blocking_reads,
        s.failures,
        s.peak_bytes as f64 / 1e6,
        s.ram_budget_bytes as f64 / 1e6
    )
}

/// Prints the three-level cache a scene draws through.
pub fn print_three_level(grid: &BrickGrid, plan: &[Option<u32>], camera_levels: bool, note: &str) {
    let drawn = if camera_levels {
        "levels chosen from the camera".to_string()
    } else {
        let (deepest, per_level) = per_level_counts(plan);
        format!("at levels 0..={deepest} ({per_level:?} bricks per level)")
    };
    println!(
        "brick cache: {} bricks of {}^3 {drawn}{note}",
        grid.brick_count(),
        grid.brick_size(),
    );
}
