//! `mixvol bench` along a camera path with camera-driven residency: smooth and discontinuous
//! transitions rendered side by side (frame by frame, interleaved, each through its own cache)
//! along `--orbit`, `--dolly` or `--path`, then held at the last view until residency
//! converges. Per transition: median, p95 and max of the CPU frame time and the GPU ray-cast,
//! upload + fixup per frame, MB uploaded, the planner's CPU time, and the frames to converge
//! after the camera stops; a table and JSON.

use crate::args::BenchArgs;
use crate::frame_log::FrameRow;
use crate::input::{model_transform, open_input_with_meta};
use crate::render::{set_up_scene, views, Scene};
use crate::stats::Summary;
use mixvol::bricks::Level;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{Renderer, TargetFormat};
use mixvol::scene::{RenderSettings, Transition};
use mixvol::{Error, Result};
use serde::Serialize;
use std::time::Duration;

/// Frames the last view is held at most while residency converges.
const MAX_SETTLE_FRAMES: usize = 500;

/// One summary in the JSON output.
#[derive(Serialize)]
struct StatJson {
    median: f64,
    p95: f64,
    max: f64,
}

impl From<Summary> for StatJson {
    fn from(s: Summary) -> Self {
        Self {
            median: s.median,
            p95: s.p95,
            max: s.max,
        }
    }
}

/// One transition's results.
#[derive(Serialize)]
struct TransitionJson {
    transition: String,
    frames: usize,
    cpu_frame_ms: Option<StatJson>,
    gpu_raycast_ms: Option<StatJson>,
    gpu_upload_fixup_ms: Option<StatJson>,
    uploaded_mb_per_frame: Option<StatJson>,
    planner_ms: Option<StatJson>,
    frames_to_converge: Option<usize>,
}

/// The JSON output.
#[derive(Serialize)]
struct PathBenchJson<'a> {
    device: &'a str,
    device_type: String,
    width: u32,
    height: u32,
    volume: &'a str,
    path_frames: usize,
    transitions: Vec<TransitionJson>,
}

/// One renderer and what it measured.
struct Run {
    transition: Transition,
    renderer: Renderer,
    scene: Scene,
    rows: Vec<FrameRow>,
    settle: Option<usize>,
}

fn summary(rows: &[FrameRow], value: impl Fn(&FrameRow) -> Option<f64>) -> Option<Summary> {
    Summary::of(&rows.iter().filter_map(value).collect::<Vec<_>>())
}

/// Runs `mixvol bench` with a camera path or a GPU budget.
pub fn bench_path(args: &BenchArgs) -> Result<()> {
    let r = &args.render;
    if args.churn {
        return Err(Error::InvalidInput(
            "--churn alternates fixed patterns; a camera path drives residency itself".into(),
        ));
    }
    let cameras = views(r)?;
    let (input, meta) = open_input_with_meta(r)?;
    let (model, _) = model_transform(r, meta.as_ref());
    // Declared before the context: printed on failure too; `finish` reads the message log.
    let mut validation = crate::logging::ValidationSummary::default();
    let ctx = GpuContext::new(&ContextDesc {
        validation: r.validation,
        device_name: r.device.clone(),
    })?;
    validation.watch(&ctx);
    let settings = r.optics.apply(RenderSettings {
        samples_per_voxel: r.samples_per_voxel,
        early_termination: r.early_termination,
        value_window: crate::input::window_of(r, input.volume())?,
        ..RenderSettings::default()
    })?;
    let tf = TransferFunction::preset(r.preset.unwrap_or(r.tf));
    let mut runs = Vec::new();
    for transition in [Transition::Smooth, Transition::Discontinuous] {
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        renderer.set_transfer_function(&tf)?;
        renderer.set_model_transform(model);
        let scene = set_up_scene(&mut renderer, r, &input, transition)?;
        if !scene.planned {
            return Err(Error::InvalidInput(
                "bench along a path needs camera-driven residency: --gpu-budget-mb, a brick \
                 store, levels from the camera (--levels camera) or a level store"
                    .into(),
            ));
        }
        // Warm-up at a far view (compiles the variants; llvmpipe compiles at first draw), then
        // start from nothing resident.
        renderer.render(&cameras[0], &settings, r.width, r.height)?;
        if let Some(count) = renderer.brick_levels().map(<[_]>::len) {
            renderer.set_brick_levels(&vec![None; count])?;
        } else {
            let bricks = renderer.brick_cache().map_or(0, |c| c.grid().brick_count());
            renderer.set_levels(&vec![Level::Absent; bricks])?;
        }
        renderer.set_planned(true);
        runs.push(Run {
            transition,
            renderer,
            scene,
            rows: Vec::new(),
            settle: None,
        });
    }
    drop(input);
    for (i, camera) in cameras.iter().enumerate() {
        for run in &mut runs {
            let frame = run.renderer.render(camera, &settings, r.width, r.height)?;
            run.rows
                .push(FrameRow::of(i, &frame, ctx.allocated_bytes()));
        }
    }
    let last = cameras.last().expect("paths have frames");
    for run in &mut runs {
        for k in 1..=MAX_SETTLE_FRAMES {
            let frame = run.renderer.render(last, &settings, r.width, r.height)?;
            let streamed = match &run.scene.level_streamer {
                Some(s) => s.wait_idle(Duration::from_secs(2)),
                None => true,
            };
            if frame.residency.is_none_or(|f| f.plan.is_settled()) && streamed {
                run.settle = Some(k - 1);
                break;
            }
        }
    }
    let info = ctx.info();
    println!(
        "# camera path of {} frames, {}x{}, volume {}, device {} ({:?})",
        cameras.len(),
        r.width,
        r.height,
        r.volume,
        info.name,
        info.device_type
    );
    println!(
        "| transition | frame ms (cpu) median / p95 / max | ray-cast ms (gpu) median / p95 / max | upload+fixup ms median / max | MB uploaded per frame median / max | planner ms median / max | frames to converge |"
    );
    println!("|---|---|---|---|---|---|---|");
    let three = |s: Option<Summary>| {
        s.map(|s| format!("{:.2} / {:.2} / {:.2}", s.median, s.p95, s.max))
            .unwrap_or_else(|| "-".into())
    };
    let two = |s: Option<Summary>| {
        s.map(|s| format!("{:.3} / {:.3}", s.median, s.max))
            .unwrap_or_else(|| "-".into())
    };
    let mut out = Vec::new();
    for run in &runs {
        let rows = &run.rows;
        let cpu = summary(rows, |r| Some(r.cpu_frame_ms));
        let gpu = summary(rows, |r| r.gpu_raycast_ms);
        let update = summary(rows, |r| match (r.gpu_upload_ms, r.gpu_fixup_ms) {
            (None, None) => None,
            (u, f) => Some(u.unwrap_or(0.0) + f.unwrap_or(0.0)),
        });
        let mb = summary(rows, |r| Some(r.uploaded_mb));
        let plan = summary(rows, |r| Some(r.plan_ms));
        println!(
            "| {:?} | {} | {} | {} | {} | {} | {} |",
            run.transition,
            three(cpu),
            three(gpu),
            two(update),
            two(mb),
            two(plan),
            run.settle
                .map(|k| k.to_string())
                .unwrap_or_else(|| format!("> {MAX_SETTLE_FRAMES}"))
        );
        out.push(TransitionJson {
            transition: format!("{:?}", run.transition),
            frames: rows.len(),
            cpu_frame_ms: cpu.map(Into::into),
            gpu_raycast_ms: gpu.map(Into::into),
            gpu_upload_fixup_ms: update.map(Into::into),
            uploaded_mb_per_frame: mb.map(Into::into),
            planner_ms: plan.map(Into::into),
            frames_to_converge: run.settle,
        });
    }
    let ratio = |f: fn(&Summary) -> f64, g: fn(&FrameRow) -> Option<f64>| {
        let a = summary(&runs[0].rows, g)?;
        let b = summary(&runs[1].rows, g)?;
        Some(f(&a) / f(&b))
    };
    if let Some(x) = ratio(|s| s.median, |r| r.gpu_raycast_ms) {
        println!("smooth / discontinuous ray-cast (median): {x:.3}x");
    }
    crate::files::note_cpu_device(info);
    if let Some(path) = &args.json {
        let json = PathBenchJson {
            device: &info.name,
            device_type: format!("{:?}", info.device_type),
            width: r.width,
            height: r.height,
            volume: &r.volume,
            path_frames: cameras.len(),
            transitions: out,
        };
        crate::files::write_json("the results JSON", path, &json)?;
    }
    drop(runs);
    drop(ctx);
    validation.finish()
}
