//! `mixvol render`: one volume (or brick store) along one view or a camera path, a PNG per
//! frame, the frame timing, and with camera-driven residency a per-frame residency log; and
//! optionally the CPU reference for comparison.

use crate::args::LevelsArg;
use crate::args::RenderArgs;
use crate::camera_path::{dolly, load_path, orbit};
use crate::compare::Difference;
use crate::files::create_parent;
use crate::frame_log::{write_log, FrameRow};
use crate::input::{
    model_transform, open_input_with_meta, orientation_line, window_line, window_of, Input,
};
use crate::level_scene::{
    least_level_upload, level_scene, level_stream_line, print_three_level, set_level_residency,
    three_level_plan,
};
use crate::levels::{level_pattern, per_level_counts};
use crate::stats::{peak_rss_bytes, Summary};
use mixvol::bricks::BrickGrid;
use mixvol::gpu::{ContextDesc, GpuContext, MessageLog};
use mixvol::optics::TransferFunction;
use mixvol::pyramid::LevelGrid;
use mixvol::renderer::{Frame, FrameReport, MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::LevelStreamer;
use mixvol::stream::ZarrLevels;
use mixvol::volume::Volume;
use mixvol::{Error, Result};
use mixvol_experiments::oracle::{reference_frame, Drawn};
use std::sync::Arc;
use std::time::Duration;

/// Most frames a single view renders while camera-driven residency converges.
const MAX_CONVERGE_FRAMES: usize = 200;

/// What the renderer draws and how its residency is driven.
pub struct Scene {
    /// The in-memory volume (absent for a brick store).
    pub volume: Option<Arc<Volume>>,
    /// Whether the camera drives residency (else a plain texture or a fixed pattern).
    pub planned: bool,
    /// The brick-cache configuration, when one is used.
    pub config: Option<MixedConfig>,
    /// The background reader of a level store or of an image's pyramid drawn through the
    /// three-level cache (the CPU reference of `--compare` reads its levels back).
    pub level_streamer: Option<Arc<LevelStreamer>>,
    /// The streamed OME-Zarr image the level streamer reads (its chunk counters).
    pub zarr: Option<Arc<ZarrLevels>>,
}

/// The views of `--orbit`, `--dolly`, `--path`, or the single `--eye` view.
pub fn views(args: &RenderArgs) -> Result<Vec<Camera>> {
    let base = args.camera();
    let p = &args.camera_path;
    if let Some(n) = p.orbit {
        orbit(&base, n, p.elevation)
    } else if let Some(n) = p.dolly {
        dolly(&base, n, p.dolly_to)
    } else if let Some(file) = &p.path {
        load_path(file, &base)
    } else {
        Ok(vec![base])
    }
}

/// Sets the renderer's source from `input` and the flags: a brick store (always camera-driven),
/// a volume with `--gpu-budget-mb` (camera-driven), with `--levels` (a fixed pattern), or a
/// plain texture. Prints what it set up.
pub fn set_up_scene(
    renderer: &mut Renderer,
    args: &RenderArgs,
    input: &Input,
    transition: Transition,
) -> Result<Scene> {
    let r = &args.residency;
    if args.mixed.level_count.is_some() && !matches!(input, Input::Volume(_)) {
        return Err(Error::InvalidInput(
            "--level-count applies to a volume in memory; a store or a streamed image has its \
             own levels (convert --level-count N writes a level store of N)"
                .into(),
        ));
    }
    match input {
        Input::Zarr {
            location, level, ..
        } => {
            // Every level of the image's own pyramid from `--zarr-level` down, through the
            // level cache.
            let ram = r.ram_bytes()?;
            let brick_size = args.mixed.config(&args.residency)?.brick_size;
            let window = window_of(args, None)?;
            let zarr = crate::stream::open_zarr_levels(location, *level, brick_size, ram, window)?;
            let note = if *level == 0 {
                " from the image's pyramid".to_string()
            } else {
                format!(" from the image's pyramid, level {level} down")
            };
            let mut scene = level_scene(renderer, args, zarr.clone(), ram / 2, transition, &note)?;
            scene.zarr = Some(zarr);
            Ok(scene)
        }
        Input::LevelStore(store) => {
            let note = format!(" from {} levels on disk", store.level_count());
            level_scene(
                renderer,
                args,
                store.clone(),
                r.ram_bytes()?,
                transition,
                &note,
            )
        }
        Input::Volume(volume) => {
            let volume = volume.clone();
            // A volume under a GPU budget is drawn at levels chosen from the camera.
            let pattern = args
                .mixed
                .levels
                .or(r.gpu_budget_mb.map(|_| LevelsArg::Camera));
            let Some(pattern) = pattern else {
                if r.upload_mb.is_some() {
                    // Review D29: it used to be ignored without a word.
                    return Err(Error::InvalidInput(
                        "--upload-mb applies to the brick cache (--gpu-budget-mb, --levels, a \
                         store or a streamed image); a plain volume is uploaded once, whole"
                            .into(),
                    ));
                }
                renderer.set_source(VolumeSource::Volume(&volume))?;
                return Ok(Scene {
                    volume: Some(volume),
                    planned: false,
                    config: None,
                    level_streamer: None,
                    zarr: None,
                });
            };
            let config = MixedConfig {
                transition,
                ..args.mixed.config(&args.residency)?
            };
            let grid = BrickGrid::new(volume.dims(), args.mixed.brick_size)?;
            let (plan, camera_levels, config) =
                if matches!(pattern, LevelsArg::Camera | LevelsArg::Staircase) {
                    let all =
                        mixvol::cache::pyramid_levels(grid.brick_size(), grid.bricks_per_axis());
                    let levels = match args.mixed.level_count {
                        Some(0) => {
                            return Err(Error::InvalidInput(
                                "--level-count 0: expected at least 1".into(),
                            ))
                        }
                        Some(count) => count.min(all),
                        None => all,
                    };
                    let (plan, camera_levels) = three_level_plan(&grid, pattern, levels)?;
                    let config = MixedConfig {
                        max_levels: levels,
                        ..config
                    };
                    (plan, camera_levels, config)
                } else {
                    // A two-level pattern: levels 0 and 1 through two slot classes (the
                    // two-level cache's bytes and capacity).
                    if args.mixed.level_count.is_some_and(|count| count != 2) {
                        return Err(Error::InvalidInput(format!(
                            "--levels {pattern:?} draws two levels; --level-count applies to \
                             --levels camera, --levels staircase and --gpu-budget-mb"
                        )));
                    }
                    let two = MixedConfig {
                        max_levels: 2,
                        ..config
                    };
                    (level_pattern(&grid, pattern)?, false, two)
                };
            // Levels from the camera step under the upload cap: it must hold the smallest step.
            let least = if camera_levels {
                least_level_upload(&grid, volume.scalar_type().size_bytes() as u64)
            } else {
                0
            };
            let (cache, upload) = r.level_budgets(least)?;
            let config = MixedConfig {
                cache_budget_bytes: cache,
                ..config
            };
            set_level_residency(renderer, args, upload)?;
            renderer.set_source(VolumeSource::Levels {
                volume: volume.clone(),
                levels: &plan,
                config,
            })?;
            print_three_level(&grid, &plan, camera_levels, "");
            Ok(Scene {
                volume: Some(volume),
                planned: camera_levels,
                config: Some(config),
                level_streamer: None,
                zarr: None,
            })
        }
    }
}

/// The first failed load's message of `report`.
fn first_failure(report: &FrameReport) -> String {
    report
        .first_source_error
        .clone()
        .unwrap_or_else(|| "no message".into())
}

/// The bricks that failed to load in `report` (issue 42, D1 and D6): none is fine; a frame
/// that draws nothing because of them, or (with `strict`) draws their regions at a fallback, is
/// an error; otherwise a warning on stderr names the count and the first failure. `what`
/// names the frame in messages.
fn check_failed_loads(report: &FrameReport, strict: bool, what: &str) -> Result<()> {
    let failed = report.source_errors;
    if failed == 0 {
        return Ok(());
    }
    let first = first_failure(report);
    let drawn: usize = report.per_level.iter().map(|l| l.drawn).sum();
    let consequence = if drawn == 0 {
        format!("{what} draws nothing; no image written")
    } else if strict {
        format!("{what} would draw their regions at a coarser level (--strict); no image written")
    } else {
        eprintln!(
            "warning: {failed} bricks failed to load (first: {first}); {what} draws their \
             regions at a coarser level where one is loaded, else not at all"
        );
        return Ok(());
    };
    Err(Error::FailedLoads {
        failed,
        first,
        consequence,
    })
}

/// One line on the residency of `report`: the bricks drawn per level (level 0, full
/// resolution, first), what was culled, dropped, is waiting or failed, the slots and the worst
/// screen-space error.
pub fn residency_line(report: &FrameReport) -> String {
    let p = &report.plan;
    let drawn: Vec<usize> = report.per_level.iter().map(|l| l.drawn).collect();
    format!(
        "residency: {drawn:?} bricks drawn per level, {} wanted but absent, {} culled, {} dropped, {} waiting; {}/{} slots ({:.0} % full, {:.1} MB cache); worst screen-space error {:.3}; planner {:.2} ms{}",
        p.drawn_absent,
        p.culled,
        p.dropped,
        report.waiting,
        p.slots_used,
        p.slot_budget,
        100.0 * p.slots_used as f64 / p.slot_budget.max(1) as f64,
        report.cache_bytes as f64 / 1e6,
        p.max_drawn_error,
        report.plan_ms,
        match &report.first_source_error {
            Some(e) => format!("; {} bricks failed to load (first: {e})", report.source_errors),
            None => String::new(),
        }
    )
}

/// Renders one frame and its log row.
fn frame_row(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    index: usize,
    camera: &Camera,
    settings: &RenderSettings,
    args: &RenderArgs,
) -> Result<(Frame, FrameRow)> {
    let frame = renderer.render(camera, settings, args.width, args.height)?;
    let row = FrameRow::of(index, &frame, ctx.allocated_bytes());
    Ok((frame, row))
}

/// Runs `mixvol render`.
pub fn render(args: &RenderArgs) -> Result<()> {
    crate::camera_path::check_frames("--frames", args.frames)?;
    let cameras = views(args)?;
    let is_path = args.camera_path.is_path();
    let frames_dir = &args.camera_path.frames_dir;
    if is_path && frames_dir.exists() && !frames_dir.is_dir() {
        // Checked before any work (review D20): the frames would fail to write at the end.
        return Err(Error::InvalidInput(format!(
            "--frames-dir {} is a file, not a folder",
            frames_dir.display()
        )));
    }
    if is_path && args.compare {
        return Err(Error::InvalidInput(
            "--compare renders one view; drop --orbit / --dolly / --path".into(),
        ));
    }
    // Declared before the context: a failing render still prints the validation summary.
    let mut summary = crate::logging::ValidationSummary::default();
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: args.device.clone(),
    })?;
    summary.watch(&ctx);
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
    // The context comes first so that a synthetic field is checked against the device's
    // limits before it is generated.
    crate::input::check_plain_synthetic(args, &ctx)?;
    let (input, meta) = open_input_with_meta(args)?;
    let (dims, scalar, volume_for_window) = match &input {
        Input::Volume(v) => (v.dims(), v.scalar_type(), Some(&**v)),
        Input::LevelStore(s) => (s.header().dims, s.header().scalar, None),
        Input::Zarr { dims, scalar, .. } => (*dims, *scalar, None),
    };
    println!(
        "volume: {} {}x{}x{} {:?}{}",
        args.volume,
        dims.x,
        dims.y,
        dims.z,
        scalar,
        if matches!(input, Input::Zarr { .. }) {
            " (streamed OME-Zarr)"
        } else if matches!(input, Input::LevelStore(_)) {
            " (level store)"
        } else if volume_for_window.is_none() {
            " (brick store)"
        } else {
            ""
        }
    );
    let (model, oblique_note) = model_transform(args, meta.as_ref());
    if let Some(line) = orientation_line(meta.as_ref(), &oblique_note) {
        println!("{line}");
    }
    let tf = TransferFunction::preset(args.preset.unwrap_or(args.tf));
    let value_window = window_of(args, volume_for_window)?;
    if let Some(window) = value_window {
        println!("{}", window_line(meta.as_ref(), window));
    }
    let settings = args.optics.apply(RenderSettings {
        samples_per_voxel: args.samples_per_voxel,
        early_termination: args.early_termination,
        value_window,
        ..RenderSettings::default()
    })?;
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&tf)?;
    renderer.set_model_transform(model);
    let scene = set_up_scene(
        &mut renderer,
        args,
        &input,
        args.mixed.transition.transition(),
    )?;
    drop(input);
    if is_path {
        render_path(&mut renderer, &ctx, &scene, &cameras, &settings, args)?;
    } else {
        render_view(
            &mut renderer,
            &ctx,
            &scene,
            &cameras[0],
            &settings,
            &tf,
            args,
        )?;
    }
    if info.device_type == ash::vk::PhysicalDeviceType::CPU {
        println!(
            "  note: {} is a CPU implementation; these times are not GPU times",
            info.name
        );
    }
    if let Some(peak) = peak_rss_bytes() {
        println!("peak RSS: {:.1} MB", peak as f64 / 1e6);
    }
    drop(renderer);
    drop(scene);
    drop(ctx);
    summary.finish()
}

/// What converging one view's residency did.
struct Converged {
    /// Residency updates run.
    steps: usize,
    /// The last update's report.
    last: FrameReport,
    /// Bytes all the updates uploaded.
    uploaded: u64,
    /// Wall time of the updates (plans, uploads, fixups, waits for the source), in ms.
    ms: f64,
}

/// Runs camera-driven residency updates of one view ([`Renderer::update`]: plan, uploads and
/// fixups, no drawing) until they converge, at most [`MAX_CONVERGE_FRAMES`]: when nothing
/// waits, or when a step after the first moves nothing once the reader is idle (what is left
/// failed to read or does not fit the RAM budget: no later step could move either).
fn converge(
    renderer: &mut Renderer,
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    args: &RenderArgs,
) -> Result<Converged> {
    let start = std::time::Instant::now();
    let (width, height) = (args.width, args.height);
    let mut uploaded = 0u64;
    let done = |steps: usize, last: FrameReport, uploaded: u64| Converged {
        steps,
        last,
        uploaded,
        ms: start.elapsed().as_secs_f64() * 1e3,
    };
    let mut last = FrameReport::default();
    for step in 1..=MAX_CONVERGE_FRAMES {
        let before = renderer.brick_levels().map(<[_]>::to_vec);
        let report = renderer.update(camera, settings, width, height)?;
        uploaded += report.residency.uploaded_bytes as u64;
        let moved = renderer.brick_levels().map(<[_]>::to_vec) != before;
        if report.waiting == 0 || (!moved && step > 1) {
            return Ok(done(step, report, uploaded));
        }
        if let Some(streamer) = &scene.level_streamer {
            // Let the reader catch up before the next step.
            streamer.wait_idle(Duration::from_secs(60));
        }
        last = report;
    }
    Ok(done(MAX_CONVERGE_FRAMES, last, uploaded))
}

/// Prints how one view's residency converged: the levels of a level source (bricks per level,
/// slots, the largest drawn voxel, steps, what still waits, the reader's counts).
fn print_converged(renderer: &Renderer, scene: &Scene, c: &Converged) {
    let Some(levels) = renderer.brick_levels() else {
        return;
    };
    let plan = &c.last.plan;
    let (deepest, per_level) = per_level_counts(levels);
    println!(
        "levels from the camera: {per_level:?} bricks at levels 0..={deepest}, {} slots, drawn voxels at most {:.2} px; choice, upload and fixups {:.1} ms",
        plan.slots_used, plan.max_drawn_error, c.ms
    );
    if plan.dropped > 0 {
        println!(
            "the cache cannot hold every brick even at the coarsest level: {} bricks not drawn \
             (the least important: out of view first, then the farthest); raise --gpu-budget-mb",
            plan.dropped
        );
    }
    println!(
        "level steps: {} under the upload budget ({:.1} MB in all), {} bricks still waiting",
        c.steps,
        c.uploaded as f64 / 1e6,
        c.last.waiting
    );
    if let Some(streamer) = &scene.level_streamer {
        println!("{}", level_stream_line(&streamer.stats()));
        if let Some(e) = streamer.first_failure() {
            println!("level stream: first failed read: {e}");
        }
    }
    if let Some(zarr) = &scene.zarr {
        println!("{}", crate::stream::chunk_line(zarr));
    }
}

/// A single view: converge (camera-driven residency), one warm-up frame, `--frames` timed
/// frames, the PNG, the timing and residency summary, and the CPU comparison.
fn render_view(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tf: &TransferFunction,
    args: &RenderArgs,
) -> Result<()> {
    if scene.planned {
        let converged = converge(renderer, scene, camera, settings, args)?;
        print_converged(renderer, scene, &converged);
        if let Some(zarr) = &scene.zarr {
            crate::stream::check_absent_chunks(zarr, &args.volume)?;
        }
    }
    // Warm-up: llvmpipe compiles shaders at the first draw.
    let (mut frame, _) = frame_row(renderer, ctx, 0, camera, settings, args)?;
    let mut rows = Vec::new();
    for i in 0..args.frames as usize {
        let (f, row) = frame_row(renderer, ctx, i, camera, settings, args)?;
        frame = f;
        rows.push(row);
    }
    if let Some(report) = &frame.residency {
        if let Err(e) = check_failed_loads(report, args.residency.strict, "the view") {
            println!("{}", residency_line(report));
            return Err(e);
        }
    }
    create_parent(&args.output)?;
    frame.save_png(&args.output, args.background)?;
    println!(
        "wrote {} ({}x{})",
        args.output.display(),
        args.width,
        args.height
    );
    print_timing(&rows, "after 1 warm-up");
    if let Some(report) = &frame.residency {
        println!("{}", residency_line(report));
        println!(
            "gpu memory: {:.1} MB allocated in all (the {:.1} MB cache image and the upload staging within the budget; the render target and its read-back besides)",
            ctx.allocated_bytes() as f64 / 1e6,
            report.cache_bytes as f64 / 1e6
        );
    }
    println!("pipeline variant: {:?}", frame.variant);
    if let Some(log) = &args.camera_path.frame_log {
        write_log(log, &rows)?;
        println!("wrote {} (and .json)", log.display());
    }
    if args.compare {
        compare(renderer, scene, camera, settings, tf, args, &frame)?;
    }
    Ok(())
}

/// Prints min / median / max of the CPU frame and GPU ray-cast times of `rows`.
fn print_timing(rows: &[FrameRow], note: &str) {
    let cpu: Vec<f64> = rows.iter().map(|r| r.cpu_frame_ms).collect();
    let gpu: Vec<f64> = rows.iter().filter_map(|r| r.gpu_raycast_ms).collect();
    if let Some(s) = Summary::of(&cpu) {
        println!(
            "frame timing over {} frames ({note}): cpu min {:.2} / median {:.2} / max {:.2} ms",
            rows.len(),
            s.min,
            s.median,
            s.max
        );
    }
    if let Some(s) = Summary::of(&gpu) {
        println!(
            "  gpu ray-cast pass: min {:.2} / median {:.2} / max {:.2} ms",
            s.min, s.median, s.max
        );
    }
}

/// A camera path: one frame per view, each written as `frame_NNNN.png`, and the per-frame log.
fn render_path(
    renderer: &mut Renderer,
    ctx: &GpuContext,
    scene: &Scene,
    cameras: &[Camera],
    settings: &RenderSettings,
    args: &RenderArgs,
) -> Result<()> {
    let dir = &args.camera_path.frames_dir;
    create_parent(&dir.join("frame_0000.png"))?;
    let mut rows = Vec::with_capacity(cameras.len());
    let mut last = None;
    // Failed loads (issue 42, D1 and D6): the frame with the most, and whether any frame drew.
    let (mut failing, mut drew_any): (Option<FrameReport>, bool) = (None, false);
    for (i, camera) in cameras.iter().enumerate() {
        let (frame, row) = frame_row(renderer, ctx, i, camera, settings, args)?;
        if let Some(report) = &frame.residency {
            drew_any |= report.per_level.iter().any(|l| l.drawn > 0);
            if report.source_errors > failing.as_ref().map_or(0, |r| r.source_errors) {
                if args.residency.strict {
                    check_failed_loads(report, true, &format!("frame {i}"))?;
                }
                failing = Some(report.clone());
            }
        }
        frame.save_png(&dir.join(format!("frame_{i:04}.png")), args.background)?;
        rows.push(row);
        last = Some(frame);
    }
    let csv = dir.join("frames.csv");
    write_log(&csv, &rows)?;
    println!(
        "wrote {} frames as {}/frame_0000.png ... and {} (and .json)",
        cameras.len(),
        dir.display(),
        csv.display()
    );
    print_timing(&rows, "first frame included");
    if let Some(report) = &failing {
        let what = "the path";
        if drew_any {
            check_failed_loads(report, false, what)?;
        } else {
            return Err(Error::FailedLoads {
                failed: report.source_errors,
                first: first_failure(report),
                consequence: "no frame of the path draws anything".into(),
            });
        }
    }
    if scene.planned {
        let uploaded: f64 = rows.iter().map(|r| r.uploaded_mb).sum();
        let changed = rows.iter().filter(|r| r.uploaded_bricks > 0).count();
        let waiting = rows.iter().map(|r| r.waiting).max().unwrap_or(0);
        let worst = rows.iter().map(|r| r.worst_error).fold(0.0f32, f32::max);
        println!(
            "residency along the path: {uploaded:.1} MB uploaded in {changed} of {} frames, at most {waiting} bricks waiting, worst screen-space error {worst:.3}",
            rows.len()
        );
        if let Some(report) = last.as_ref().and_then(|f| f.residency.as_ref()) {
            println!("last frame {}", residency_line(report));
        }
    }
    Ok(())
}

/// Renders the CPU reference of the frame just drawn and prints the difference.
fn compare(
    renderer: &Renderer,
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tf: &TransferFunction,
    args: &RenderArgs,
    frame: &Frame,
) -> Result<()> {
    let params = renderer.params(camera, settings, args.width, args.height)?;
    // The levels' samples of a level source: the volume's own pyramid, or read back.
    let mut level_grids = None;
    let drawn = match (
        renderer.brick_cache(),
        &scene.config,
        renderer.brick_levels(),
    ) {
        (None, Some(config), Some(levels)) => {
            let deepest = levels.iter().flatten().max().copied().unwrap_or(0);
            let backend = scene.level_streamer.as_ref().map(|s| s.backend().clone());
            let (grid, grids, scalar) = match (backend, &scene.volume) {
                (Some(backend), _) => {
                    let mut grids = backend.read_grids()?;
                    grids.truncate(deepest as usize + 1);
                    (backend.grid(), grids, backend.scalar())
                }
                (None, Some(volume)) => (
                    BrickGrid::new(volume.dims(), config.brick_size)?,
                    LevelGrid::vertex_pyramid(volume, deepest + 1, config.filter),
                    volume.scalar_type(),
                ),
                (None, None) => return Err(no_volume()),
            };
            let grids = level_grids.insert(grids);
            Drawn::Levels {
                grid,
                grids,
                levels,
                scalar,
                transition: config.transition,
            }
        }
        (Some(cache), Some(config), _) => Drawn::BrickCache {
            volume: scene.volume.as_ref().ok_or_else(no_volume)?,
            filter: config.filter,
            cache,
            transition: config.transition,
        },
        _ => Drawn::Volume(scene.volume.as_ref().ok_or_else(no_volume)?),
    };
    let reference = reference_frame(drawn, tf, settings, &params)?;
    let d = Difference::between(&reference, &frame.pixels);
    println!(
        "cpu reference: max per-channel difference {:.4} ({:.1}/255), mean {:.2e}, {:.3} % of channels above 1/255",
        d.max,
        d.max * 255.0,
        d.mean,
        100.0 * d.above_one_step
    );
    Ok(())
}

fn no_volume() -> Error {
    Error::InvalidInput("--compare needs an in-memory volume or a level store".into())
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
