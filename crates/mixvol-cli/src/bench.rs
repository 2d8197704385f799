//! `mixvol bench`: N frames of one scene, min / median / max of every GPU pass (upload, fixup,
//! ray-cast) and of the CPU frame time, as a table and as JSON. With a camera path, a GPU
//! budget or a brick store it benchmarks camera-driven residency instead (`path_bench`); with
//! `--soak N` it soaks the renderer for N frames instead (`soak`).

use crate::args::{BenchArgs, LevelsArg};
use crate::input::{load_volume, store_kind};
use crate::level_scene::three_level_plan;
use crate::levels::{level_pattern, swapped};
use crate::stats::Summary;
use mixvol::bricks::BrickGrid;
use mixvol::cache::pyramid_levels;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::RenderSettings;
use mixvol::{Error, Result};
use serde::Serialize;
use std::sync::Arc;

/// One pass's times in the JSON output.
#[derive(Serialize)]
struct PassJson<'a> {
    pass: &'a str,
    samples: usize,
    min_ms: f64,
    median_ms: f64,
    max_ms: f64,
}

/// The JSON output (fields in this order).
#[derive(Serialize)]
struct BenchJson<'a> {
    device: &'a str,
    device_type: String,
    width: u32,
    height: u32,
    frames: u32,
    volume: &'a str,
    passes: Vec<PassJson<'a>>,
}

/// Runs `mixvol bench`.
pub fn bench(args: &BenchArgs) -> Result<()> {
    let r = &args.render;
    if let Some(frames) = args.soak {
        return crate::soak::soak(args, frames);
    }
    if r.camera_path.is_path()
        || r.residency.gpu_budget_mb.is_some()
        || store_kind(std::path::Path::new(&r.volume)).is_some()
    {
        return crate::path_bench::bench_path(args);
    }
    crate::camera_path::check_frames("--frames", r.frames)?;
    if args.churn && r.mixed.levels.is_none() {
        return Err(Error::InvalidInput("--churn needs --levels".into()));
    }
    // Declared before the context: printed on failure too; `finish` reads the message log.
    let mut summary = crate::logging::ValidationSummary::default();
    let ctx = GpuContext::new(&ContextDesc {
        validation: r.validation,
        device_name: r.device.clone(),
    })?;
    summary.watch(&ctx);
    // A synthetic field is checked against the device's limits before it is generated.
    crate::input::check_plain_synthetic(r, &ctx)?;
    let volume = Arc::new(load_volume(r)?);
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&TransferFunction::preset(r.tf))?;
    let mut patterns = Vec::new();
    match r.mixed.levels {
        None => renderer.set_source(VolumeSource::Volume(&volume))?,
        Some(pattern) => {
            let grid = BrickGrid::new(volume.dims(), r.mixed.brick_size)?;
            // Levels 0 and 1 of a two-level pattern through two slot classes (the two-level
            // cache's capacity); the staircase through every level the grid takes.
            let (levels, max_levels) = match pattern {
                LevelsArg::Camera => {
                    return Err(Error::InvalidInput(
                        "bench --levels camera draws along a camera path: add --orbit N, \
                         --dolly N or --path FILE"
                            .into(),
                    ))
                }
                LevelsArg::Staircase => {
                    if args.churn {
                        return Err(Error::InvalidInput(
                            "--churn swaps levels 0 and 1 of a two-level pattern (all-hi, \
                             all-lo, checker, half), not the staircase"
                                .into(),
                        ));
                    }
                    let count = pyramid_levels(grid.brick_size(), grid.bricks_per_axis());
                    (three_level_plan(&grid, pattern, count)?.0, 0)
                }
                _ => (level_pattern(&grid, pattern)?, 2),
            };
            // The churn partner: the same pattern with levels 0 and 1 swapped.
            patterns.push(swapped(&levels));
            patterns.insert(0, levels);
            renderer.set_source(VolumeSource::Levels {
                volume: volume.clone(),
                levels: &patterns[0],
                config: MixedConfig {
                    max_levels,
                    ..r.mixed.config(&r.residency)?
                },
            })?;
        }
    }
    let camera = r.camera();
    let settings = r.optics.apply(RenderSettings {
        samples_per_voxel: r.samples_per_voxel,
        early_termination: r.early_termination,
        ..RenderSettings::default()
    })?;
    renderer.render(&camera, &settings, r.width, r.height)?; // warm-up
    let (mut upload, mut fixup, mut raycast, mut cpu) = (vec![], vec![], vec![], vec![]);
    let mut variant = None;
    for i in 0..r.frames {
        if args.churn {
            renderer.stage_brick_levels(&patterns[(i as usize + 1) % 2])?;
        }
        let frame = renderer.render(&camera, &settings, r.width, r.height)?;
        upload.extend(frame.timing.gpu_upload_ms);
        fixup.extend(frame.timing.gpu_fixup_ms);
        raycast.extend(frame.timing.gpu_raycast_ms);
        cpu.push(frame.timing.cpu_frame_ms);
        variant = Some(frame.variant);
    }
    let info = ctx.info();
    let rows = [
        ("upload (gpu)", &upload),
        ("fixup (gpu)", &fixup),
        ("ray-cast (gpu)", &raycast),
        ("frame (cpu)", &cpu),
    ];
    println!(
        "# {} frames, {}x{}, volume {} {:?}, device {} ({:?})",
        r.frames,
        r.width,
        r.height,
        r.volume,
        volume.dims().to_array(),
        info.name,
        info.device_type
    );
    println!("# variant {:?}", variant.expect("frames >= 1"));
    println!("| pass | samples | min ms | median ms | max ms |");
    println!("|---|---|---|---|---|");
    let mut passes = Vec::new();
    for (name, values) in rows {
        match Summary::of(values) {
            Some(s) => {
                println!(
                    "| {name} | {} | {:.3} | {:.3} | {:.3} |",
                    values.len(),
                    s.min,
                    s.median,
                    s.max
                );
                passes.push(PassJson {
                    pass: name,
                    samples: values.len(),
                    min_ms: s.min,
                    median_ms: s.median,
                    max_ms: s.max,
                });
            }
            None => println!("| {name} | 0 | - | - | - |"),
        }
    }
    crate::files::note_cpu_device(info);
    if let Some(path) = &args.json {
        let json = BenchJson {
            device: &info.name,
            device_type: format!("{:?}", info.device_type),
            width: r.width,
            height: r.height,
            frames: r.frames,
            volume: &r.volume,
            passes,
        };
        crate::files::write_json("the results JSON", path, &json)?;
    }
    drop(renderer);
    drop(ctx);
    summary.finish()
}
