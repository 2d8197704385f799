//! `mixvol render`: one volume, one camera, N timed frames, a PNG, and optionally the CPU
//! reference for comparison.

use crate::args::RenderArgs;
use crate::compare::Difference;
use crate::files::create_parent;
use crate::input::{load_volume, window_of};
use crate::levels::level_pattern;
use crate::stats::Summary;
use mixvol::bricks::BrickGrid;
use mixvol::gpu::{ContextDesc, GpuContext, MessageLog};
use mixvol::optics::TransferFunction;
use mixvol::reference::{self, ReferenceCache};
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::RenderSettings;
use mixvol::{Error, Result};
use std::sync::Arc;

/// Runs `mixvol render`.
pub fn render(args: &RenderArgs) -> Result<()> {
    if args.frames == 0 {
        return Err(Error::InvalidInput("--frames must be at least 1".into()));
    }
    let volume = load_volume(args)?;
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: args.device.clone(),
    })?;
    let info = ctx.info();
    println!(
        "device: {} ({:?}){}",
        info.name,
        info.device_type,
        if info.validation {
            ", validation on"
        } else {
            ""
        }
    );
    let d = volume.dims();
    println!(
        "volume: {} {}x{}x{} {:?}",
        args.volume,
        d.x,
        d.y,
        d.z,
        volume.scalar_type()
    );
    let tf = TransferFunction::preset(args.preset.unwrap_or(args.tf));
    let value_window = window_of(args, &volume)?;
    if let Some((lo, hi)) = value_window {
        println!("window: [{lo:.4}, {hi:.4}] (normalised values)");
    }
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&tf)?;
    let volume = Arc::new(volume);
    let mut reference_cache = None;
    match args.mixed.levels {
        None => renderer.set_source(VolumeSource::Volume(&volume))?,
        Some(pattern) => {
            let config = args.mixed.config()?;
            renderer.set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config,
            })?;
            let grid = BrickGrid::new(volume.dims(), args.mixed.brick_size)?;
            let levels = level_pattern(&grid, pattern);
            let report = renderer.set_levels(&levels)?;
            println!(
                "brick cache: {} hi + {} lo bricks of {}^3, {} uploaded ({:.1} MB), {} fixed up; pack {:.1} ms, upload+fixup {:.1} ms",
                report.hi_bricks,
                report.lo_bricks,
                args.mixed.brick_size,
                report.uploaded_bricks,
                report.uploaded_bytes as f64 / 1e6,
                report.fixup_bricks,
                report.pack_ms,
                report.update_ms
            );
            if args.compare {
                let cache = renderer.brick_cache().expect("mixed volume set");
                reference_cache = Some(ReferenceCache::build(
                    &volume,
                    config.filter,
                    cache,
                    volume.scalar_type(),
                    config.transition,
                )?);
            }
        }
    }
    let camera = args.camera();
    let settings = args.optics.apply(RenderSettings {
        samples_per_voxel: args.samples_per_voxel,
        early_termination: args.early_termination,
        value_window,
        ..RenderSettings::default()
    })?;
    // Warm-up: llvmpipe compiles shaders at the first draw.
    let mut frame = renderer.render(&camera, &settings, args.width, args.height)?;
    let mut gpu = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..args.frames {
        frame = renderer.render(&camera, &settings, args.width, args.height)?;
        gpu.extend(frame.timing.gpu_raycast_ms);
        cpu.push(frame.timing.cpu_frame_ms);
    }
    create_parent(&args.output)?;
    frame.save_png(&args.output, args.background)?;
    println!(
        "wrote {} ({}x{})",
        args.output.display(),
        args.width,
        args.height
    );
    if let Some(s) = Summary::of(&cpu) {
        println!(
            "frame timing over {} frames (after 1 warm-up): cpu min {:.2} / median {:.2} / max {:.2} ms",
            args.frames, s.min, s.median, s.max
        );
    }
    if let Some(s) = Summary::of(&gpu) {
        println!(
            "  gpu ray-cast pass: min {:.2} / median {:.2} / max {:.2} ms",
            s.min, s.median, s.max
        );
    }
    if info.device_type == ash::vk::PhysicalDeviceType::CPU {
        println!(
            "  note: {} is a CPU implementation; these times are not GPU times",
            info.name
        );
    }
    println!("pipeline variant: {:?}", frame.variant);
    if args.compare {
        let params = renderer.params(&camera, &settings, args.width, args.height)?;
        let reference = match &reference_cache {
            Some(cache) => reference::render_mixed_scene(
                &cache.view(),
                args.mixed.transition.transition(),
                &tf,
                &settings,
                &params,
            )?,
            None => reference::render_scene(&volume, &tf, &settings, &params)?,
        };
        let d = Difference::between(&reference, &frame.pixels);
        println!(
            "cpu reference: max per-channel difference {:.4} ({:.1}/255), mean {:.2e}, {:.3} % of channels above 1/255",
            d.max,
            d.max * 255.0,
            d.mean,
            100.0 * d.above_one_step
        );
    }
    drop(renderer);
    let log = ctx.message_log();
    drop(ctx);
    if args.validation {
        check_validation(&log, true)?;
    }
    Ok(())
}

/// With `verbose`, prints the count and every warning or error the validation layers
/// reported; fails when there was any.
pub fn check_validation(log: &MessageLog, verbose: bool) -> Result<()> {
    let problems = log.warnings_and_errors();
    if verbose {
        println!("validation: {} warnings/errors", problems.len());
        for m in &problems {
            eprintln!("  {:?} {}: {}", m.severity, m.id_name, m.text);
        }
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "validation reported {} problem(s)",
            problems.len()
        )))
    }
}
