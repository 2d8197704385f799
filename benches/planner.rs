//! CPU time of the residency planner (`plan::ResidencyPlanner`) per frame, for about
//! 10^5 bricks.
//!
//! Setup: a 64 x 64 x 25 grid of 16^3 bricks (102 400 bricks, a 1024 x 1024 x 400 volume of u16
//! voxels, spacing 1), random per-brick value ranges culled by a transfer function that is
//! transparent below 0.25 (about a tenth of the bricks culled), a 1920x1080 perspective camera
//! that sees the whole volume, a slot budget that holds 1/8 of the bricks hi-res and the rest
//! low-res, and an upload budget of 4 MiB per frame. Default planner options (budget-driven,
//! 10 % hysteresis). The ranges do not change and say so (`ranges_generation`).
//!
//! Rows, each with a source that has every level loaded and with one that has only the `Lo`
//! levels loaded:
//! - still camera: the plan is first run until it settles, then timed at the same view;
//! - orbit: from the settled plan, the eye orbits the target about +y by 1 degree per frame for
//!   60 frames;
//! - dolly: from the settled plan, the eye moves towards the target, 1 % of the start distance
//!   per frame, for 60 frames.
//!
//! Rows for each way of telling the planner what is loaded: `plan_frame_with_loaded` (one
//! `LoadedLevels` per brick, as `plan_frame_with_source`, and so `VolumePass::update`, plans;
//! filling the slice is the source's work and is not timed) and `plan_frame` (a closure asked
//! brick by brick). Only the planning call is timed (`timed_frame`, not inlined, so that
//! `valgrind --tool=callgrind --toggle-collect='planner::timed_frame*'` profiles only it).
//! Every run starts from a fresh planner. Run: `cargo bench --bench planner`. Environment:
//! `MIXVOL_BENCH_RUNS` (repeats, default 5; the per-frame times of all repeats are pooled) and
//! `MIXVOL_PLANNER_PATHS` (default `still,orbit,dolly`). Prints a Markdown table: thread CPU
//! time per frame (median, p95, max) and wall time (median, p95, min), with the machine's load
//! average, as other processes on the cores inflate the times; compare versions only when run
//! interleaved in the same minutes. Then one row for the level choice of any number of levels
//! (`plan::LevelChooser::choose`, [`level_rows`]), and one line of JSON per case with at least
//! `"bricks"`, `"levels"` and `"ms_per_frame"` (CPU median).
//!
//! Figures (2026-12-02 21:40 UTC, 2-core Intel Xeon VM, load average 1.1-1.2, three rounds of
//! three runs, median ms per frame): `plan_frame_with_loaded` still 0.065-0.070, orbit and
//! dolly 0.86-0.95 with every level loaded or only `Lo` loaded; `plan_frame` still
//! 0.09 / 0.18-0.19, moving 0.90-0.97 / 0.98-1.03 (all loaded / only `Lo`). The history of
//! each change, and what was tried and dropped: docs/performance.md, "The residency planner's
//! CPU time".

mod common;

use common::env_u32;
use glam::{Quat, UVec3, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, Level, LoadedLevels, ValueRange};
use mixvol::cache::pyramid_levels;
use mixvol::lod::{cull_bricks, BrickGeometry, CullParams, LodView, TfCullTable};
use mixvol::optics::{TransferFunction, TF_SIZE};
use mixvol::plan::{
    level_margin, upload_bytes, FrameInput, LevelChooser, LevelRequest, PlanBudget, PlanOptions,
    ResidencyPlanner,
};
use mixvol::scene::Camera;
use std::hint::black_box;
use std::time::Instant;

const BRICK_SIZE: u32 = 16;
const BRICKS: UVec3 = UVec3::new(64, 64, 25);
const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const BYTES_PER_TEXEL: u32 = 2;
const UPLOAD_BYTES: u64 = 4 << 20;
const FRAMES: usize = 60;

/// Deterministic pseudo-random numbers (xorshift64).
struct Rng(u64);

impl Rng {
    fn f32(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[derive(Copy, Clone)]
enum Path {
    Still,
    Orbit,
    Dolly,
}

impl Path {
    fn name(self) -> &'static str {
        match self {
            Path::Still => "still camera (settled)",
            Path::Orbit => "orbit 1 deg/frame",
            Path::Dolly => "dolly in 1 %/frame",
        }
    }

    /// The name `MIXVOL_PLANNER_PATHS` selects the row by.
    fn key(self) -> &'static str {
        match self {
            Path::Still => "still",
            Path::Orbit => "orbit",
            Path::Dolly => "dolly",
        }
    }

    fn camera(self, start: &Camera, frame: usize) -> Camera {
        let mut c = *start;
        let offset = c.eye - c.target;
        match self {
            Path::Still => {}
            Path::Orbit => {
                let angle = (frame as f32 + 1.0).to_radians();
                c.eye = c.target + Quat::from_rotation_y(angle) * offset;
            }
            Path::Dolly => c.eye = c.target + offset * (1.0 - 0.01 * (frame as f32 + 1.0)),
        }
        c
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

/// The 1-minute load average (`/proc/loadavg`): other processes on the cores inflate the
/// times; the `min` column is the least disturbed.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "unknown".into())
}

fn date() -> String {
    std::process::Command::new("date")
        .args(["-u", "+%Y-%m-%d %H:%M UTC"])
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown date".into())
}

/// The timed call, not inlined, so that a profiler can collect it alone
/// (`valgrind --tool=callgrind --toggle-collect='planner::timed_frame*'`).
/// The CPU time this thread has run, in milliseconds (`CLOCK_THREAD_CPUTIME_ID`): unlike the
/// wall clock, it leaves out the time other processes on a shared core take.
fn thread_cpu_ms() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid, writable timespec and the clock id is a constant the kernel knows.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
}

/// How the planner learns what is loaded.
#[derive(Copy, Clone)]
enum Query {
    /// One `LoadedLevels` per brick (`plan_frame_with_loaded`, as `plan_frame_with_source`
    /// and so `VolumePass::update` plan).
    PerBrick,
    /// A closure asked brick by brick (`plan_frame`).
    Closure,
}

impl Query {
    fn name(self) -> &'static str {
        match self {
            Query::PerBrick => "plan_frame_with_loaded",
            Query::Closure => "plan_frame (closure)",
        }
    }
}

/// One planned frame, asking as `query` says: `levels` (one per brick) or `loaded` (the same
/// answers as a closure).
#[inline(never)]
fn timed_frame<'p>(
    planner: &'p mut ResidencyPlanner,
    input: &FrameInput<'_>,
    query: Query,
    levels: &[LoadedLevels],
    loaded: impl Fn(u32, Level) -> bool,
) -> &'p mixvol::plan::FramePlan {
    match query {
        Query::PerBrick => planner.plan_frame_with_loaded(input, levels),
        Query::Closure => planner.plan_frame(input, loaded),
    }
    .expect("plan")
}

fn main() {
    let runs = env_u32("MIXVOL_BENCH_RUNS", 5).max(1) as usize;
    let rows = std::env::var("MIXVOL_PLANNER_PATHS").unwrap_or_else(|_| "still,orbit,dolly".into());
    let grid = BrickGrid::new(BRICKS * BRICK_SIZE, BRICK_SIZE).expect("grid");
    let geometry = BrickGeometry::new(grid, Vec3::ONE).expect("geometry");
    let bricks = grid.brick_count();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let ranges: Vec<ValueRange> = (0..bricks)
        .map(|_| {
            let a = rng.f32();
            ValueRange {
                min: a,
                max: a + rng.f32() * 0.3,
            }
        })
        .collect();
    let mut entries = vec![Vec4::ZERO; TF_SIZE];
    for e in &mut entries[TF_SIZE / 4..] {
        *e = Vec4::splat(0.5);
    }
    let tf = TransferFunction::from_entries(entries).expect("tf");
    let cull = CullParams::transfer_function(TfCullTable::new(&tf, (0.0, 1.0)).expect("table"));
    let hi_bricks = bricks / 8;
    let budget = PlanBudget {
        slots: hi_bricks + (bricks - hi_bricks).div_ceil(8),
        upload_bytes_per_frame: UPLOAD_BYTES,
        bytes_per_texel: BYTES_PER_TEXEL,
        ram_bytes: None,
    };
    let start = Camera::perspective(Vec3::new(1.1, 0.8, 1.5), Vec3::ZERO, 40.0);
    let hi_per_frame = UPLOAD_BYTES / upload_bytes(Level::Hi, BRICK_SIZE, BYTES_PER_TEXEL);

    println!(
        "Residency planner, {bricks} bricks of {BRICK_SIZE}^3 ({} x {} x {}), {WIDTH}x{HEIGHT} \
         perspective, {} slots, {} MiB uploads/frame ({hi_per_frame} hi-res bricks), {runs} runs",
        BRICKS.x,
        BRICKS.y,
        BRICKS.z,
        budget.slots,
        UPLOAD_BYTES >> 20,
    );
    println!(
        "Machine: {} cores (nproc), {}; {}; load average at start {}",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        cpu_model(),
        date(),
        load_average()
    );
    println!();
    println!("| query | source | camera | frames | CPU median ms | CPU p95 ms | CPU max ms | wall median ms | wall p95 ms | wall min ms | culled | drawn hi | drawn lo | uploads/frame |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");

    let mut json_lines = Vec::new();
    let sources = [("all loaded", false), ("only Lo loaded", true)];
    let queries = [Query::PerBrick, Query::Closure];
    for (query, (source, lo_only)) in queries
        .into_iter()
        .flat_map(|q| sources.into_iter().map(move |s| (q, s)))
    {
        let loaded = move |_: u32, level: Level| match level {
            Level::Hi => !lo_only,
            Level::Lo => true,
            Level::Absent => false,
        };
        let levels = vec![
            LoadedLevels::NONE
                .with(Level::Hi, !lo_only)
                .with(Level::Lo, true);
            bricks
        ];
        for path in [Path::Still, Path::Orbit, Path::Dolly] {
            if !rows.split(',').any(|r| r.trim() == path.key()) {
                continue;
            }
            let mut times = Vec::new();
            let mut cpu_times = Vec::new();
            let mut last = None;
            let mut uploads = 0usize;
            for _ in 0..runs {
                let mut planner = ResidencyPlanner::new(PlanOptions::default());
                let view = LodView::new(&start, WIDTH, HEIGHT).expect("view");
                let input = FrameInput {
                    geometry: &geometry,
                    view: &view,
                    ranges: &ranges,
                    ranges_generation: Some(0),
                    cull: &cull,
                    budget,
                };
                let mut settled = false;
                for _ in 0..1000 {
                    let plan = planner.plan_frame(&input, loaded).expect("plan");
                    if plan.report.is_settled() {
                        settled = true;
                        break;
                    }
                }
                assert!(settled, "the plan did not settle");
                for f in 0..FRAMES {
                    let view = LodView::new(&path.camera(&start, f), WIDTH, HEIGHT).expect("view");
                    let input = FrameInput {
                        view: &view,
                        ..input
                    };
                    let (t, cpu) = (Instant::now(), thread_cpu_ms());
                    let plan = timed_frame(&mut planner, &input, query, &levels, loaded);
                    cpu_times.push(thread_cpu_ms() - cpu);
                    times.push(t.elapsed().as_secs_f64() * 1e3);
                    uploads += plan.uploads.len();
                    black_box(plan);
                }
                last = Some(planner.last_plan().report);
            }
            times.sort_by(f64::total_cmp);
            cpu_times.sort_by(f64::total_cmp);
            let r = last.expect("one run");
            json_lines.push(format!(
                "{{\"planner\": \"two-level\", \"query\": \"{}\", \"source\": \"{source}\", \
                 \"camera\": \"{}\", \"bricks\": {bricks}, \"levels\": 2, \"slots\": {}, \
                 \"frames\": {}, \"ms_per_frame\": {:.4}, \"p95_ms\": {:.4}}}",
                query.name(),
                path.key(),
                budget.slots,
                times.len(),
                percentile(&cpu_times, 0.5),
                percentile(&cpu_times, 0.95),
            ));
            println!(
                "| {} | {source} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {} | {} | {:.0} |",
                query.name(),
                path.name(),
                times.len(),
                percentile(&cpu_times, 0.5),
                percentile(&cpu_times, 0.95),
                cpu_times[cpu_times.len() - 1],
                percentile(&times, 0.5),
                percentile(&times, 0.95),
                times[0],
                r.culled,
                r.drawn_hi,
                r.drawn_lo,
                uploads as f64 / times.len() as f64,
            );
        }
    }
    level_rows(&geometry, &ranges, &cull, &start, &mut json_lines);
    println!();
    println!("JSON, one line per case (CPU ms per frame, median and p95):");
    for line in json_lines {
        println!("{line}");
    }
}

/// The level choice for any number of levels (`plan::LevelChooser::choose`, what
/// `VolumePass::update` runs for each view of a level source) on the same grid, every level the bricks
/// take (`cache::pyramid_levels`), the slot budget binding (an eighth of the bricks),
/// hysteresis against the last choice, one chooser kept across the views as a host keeps it.
/// Rows: the still camera (settled, then the same view again: the chooser returns its last
/// plan), the orbit and the dolly of the two-level rows. `MIXVOL_PLANNER_LEVEL_FRAMES` views
/// per row (default 12).
fn level_rows(
    geometry: &BrickGeometry,
    ranges: &[ValueRange],
    cull: &CullParams,
    start: &Camera,
    json_lines: &mut Vec<String>,
) {
    let frames = env_u32("MIXVOL_PLANNER_LEVEL_FRAMES", 12).max(1) as usize;
    let bricks = geometry.grid().brick_count();
    let levels = pyramid_levels(BRICK_SIZE, BRICKS);
    let slots = (bricks / 8) as u64;
    let active = cull_bricks(geometry, ranges, cull).expect("cull");
    let margin = level_margin(PlanOptions::default().hysteresis);
    println!();
    for path in [Path::Still, Path::Orbit, Path::Dolly] {
        let mut previous: Vec<Option<u32>> = Vec::new();
        let mut chooser = LevelChooser::new();
        let (mut cpu_times, mut used) = (Vec::new(), Vec::new());
        // The still camera settles first (the plan no longer changes), untimed.
        let settle = if matches!(path, Path::Still) { 3 } else { 0 };
        for f in 0..settle + frames {
            let view = LodView::new(&path.camera(start, f), WIDTH, HEIGHT).expect("view");
            let cpu = thread_cpu_ms();
            let choice = chooser
                .choose(&LevelRequest {
                    geometry,
                    view: &view,
                    active: &active,
                    value_ranges: &[],
                    levels,
                    slots,
                    target_pixels: 1.0,
                    previous: &previous,
                    margin,
                })
                .expect("choice");
            let ms = thread_cpu_ms() - cpu;
            if f >= settle {
                cpu_times.push(ms);
                used.push(choice.slots);
            }
            previous.clone_from(&black_box(choice).levels);
        }
        cpu_times.sort_by(f64::total_cmp);
        println!(
            "Level choice (`LevelChooser::choose`), {bricks} bricks, {levels} levels, {slots} \
             slots, {}, {frames} views: CPU median {:.2} ms, p95 {:.2} ms, max {:.2} ms; slots \
             used per view {used:?}",
            path.name(),
            percentile(&cpu_times, 0.5),
            percentile(&cpu_times, 0.95),
            cpu_times[cpu_times.len() - 1],
        );
        json_lines.push(format!(
            "{{\"planner\": \"levels\", \"query\": \"LevelChooser::choose\", \"camera\": \
             \"{}\", \"bricks\": {bricks}, \"levels\": {levels}, \"slots\": {slots}, \
             \"frames\": {frames}, \"ms_per_frame\": {:.4}, \"p95_ms\": {:.4}}}",
            path.key(),
            percentile(&cpu_times, 0.5),
            percentile(&cpu_times, 0.95),
        ));
    }
}
