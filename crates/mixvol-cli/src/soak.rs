//! `mixvol bench --soak N`: N frames along a moving camera with camera-driven residency and the
//! validation layers on, watching for what only shows over time: validation messages, leaked
//! GPU allocations, and growth of the resident set (RSS) or of the GPU memory in use.
//!
//! The camera turns about the target (one turn per [`ORBIT_FRAMES`] frames), dollies in to
//! [`DOLLY_NEAR`] of its distance and back out every [`DOLLY_FRAMES`] frames, and bobs in
//! elevation every [`BOB_FRAMES`] frames (periods with no common factor, so the path does not
//! repeat within a soak), so the planner changes brick levels every few frames. A three-level
//! scene (a level store, or `--levels camera`) chooses its levels from the camera before every
//! frame (each render plans, the level store's bricks streamed in the background) and prints
//! the levels it drew.
//!
//! Every `max(1, N / 1000)` frames (and at the end of the warm-up and the last frame) it samples
//! RSS (`VmRSS`, after returning free heap memory to the system, so freed chunks the allocator
//! keeps do not hide a leak), the GPU bytes in use, the live allocations, the validation
//! messages, and the residency changes so far: the curve, written atomically as CSV and as JSON
//! (with the summary) under `--soak-log`. The summary line gives first / after warm-up / last /
//! max and the least-squares slope after the warm-up.
//!
//! It fails (exit 1) on any validation warning or error, any allocation still live after the
//! renderer is dropped, RSS growing more than `--soak-rss-growth-mb` after the warm-up, GPU
//! bytes growing after the warm-up by more than the cache's staging buffer can (it grows to the
//! next power of two of the largest update, at most the cache image), or a residency that never
//! changed after the warm-up (a still scene tests nothing).

use crate::args::BenchArgs;
use crate::files::write_text;
use crate::input::{model_transform, open_input_with_meta, window_of};
use crate::render::set_up_scene;
use glam::{Quat, Vec3};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{Renderer, TargetFormat};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// Frames per turn about the target.
pub const ORBIT_FRAMES: u32 = 360;
/// Frames per dolly in and out.
pub const DOLLY_FRAMES: u32 = 97;
/// The nearest point of the dolly, as a fraction of the starting distance.
pub const DOLLY_NEAR: f32 = 0.5;
/// Frames per elevation bob.
pub const BOB_FRAMES: u32 = 251;
/// Elevation amplitude of the bob in radians (about the eye's own elevation).
const BOB_RADIANS: f32 = 0.35;
/// Most frames a soak may have.
const MAX_SOAK_FRAMES: u32 = 10_000_000;
/// About this many samples are taken along a soak.
const SAMPLES: u32 = 1000;

/// The soak's view at frame `i`, from the `base` view (see the module docs).
pub fn soak_camera(base: &Camera, i: u32) -> Result<Camera> {
    let up = base.up.normalize_or_zero();
    let offset = base.eye - base.target;
    let distance = offset.length();
    if up == Vec3::ZERO || !(distance > 0.0 && distance.is_finite()) {
        return Err(Error::InvalidInput(
            "--soak needs an eye away from the target and a non-zero --up".into(),
        ));
    }
    let tau = std::f32::consts::TAU;
    let phase = |period: u32| tau * (i % period) as f32 / period as f32;
    let planar = offset - up * offset.dot(up);
    let planar = if planar.length() > 1e-6 * distance {
        planar.normalize()
    } else {
        up.any_orthonormal_vector()
    };
    let elevation = (offset.dot(up) / distance).clamp(-1.0, 1.0).asin();
    let elevation = (elevation + BOB_RADIANS * phase(BOB_FRAMES).sin()).clamp(-1.4, 1.4);
    let dolly = 1.0 - (1.0 - DOLLY_NEAR) * 0.5 * (1.0 - phase(DOLLY_FRAMES).cos());
    let direction = Quat::from_axis_angle(up, phase(ORBIT_FRAMES)) * planar * elevation.cos()
        + up * elevation.sin();
    Ok(Camera {
        eye: base.target + direction * (distance * dolly),
        ..*base
    })
}

/// One point of the curve.
#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct Sample {
    /// Frames rendered before the sample (the sample follows frame `frame - 1`).
    pub frame: u32,
    /// Seconds since the first frame.
    pub seconds: f64,
    /// Resident set of the process in bytes.
    pub rss_bytes: u64,
    /// GPU bytes in use by the renderer's allocations.
    pub gpu_allocated_bytes: u64,
    /// Allocations of the renderer still live.
    pub live_allocations: usize,
    /// Validation warnings and errors so far.
    pub validation_problems: usize,
    /// Messages of any severity the validation layers sent so far.
    pub validation_messages: usize,
    /// Brick level changes so far (a brick whose level differs from the frame before).
    pub level_changes: u64,
    /// Bricks copied into the cache so far (level changes, moves, border restores).
    pub uploaded_bricks: u64,
}

/// First, after-warm-up, last and largest value of one series, and its growth.
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct Curve {
    /// At the first sample.
    pub first: u64,
    /// At the end of the warm-up.
    pub warm: u64,
    /// At the last sample.
    pub last: u64,
    /// The largest sample.
    pub max: u64,
    /// The largest sample after the warm-up, less the value at its end (0 when it fell).
    pub growth: u64,
    /// Least-squares slope after the warm-up, in bytes per 1000 frames.
    pub slope_per_1000_frames: f64,
}

impl Curve {
    /// The curve of `value` over `samples`, with the warm-up ending at frame `warm_frame`.
    pub fn of(samples: &[Sample], warm_frame: u32, value: impl Fn(&Sample) -> u64) -> Self {
        let after: Vec<&Sample> = samples.iter().filter(|s| s.frame >= warm_frame).collect();
        let warm = after.first().map_or(0, |s| value(s));
        let max_after = after.iter().map(|s| value(s)).max().unwrap_or(warm);
        Self {
            first: samples.first().map_or(0, &value),
            warm,
            last: samples.last().map_or(0, &value),
            max: samples.iter().map(&value).max().unwrap_or(0),
            growth: max_after.saturating_sub(warm),
            slope_per_1000_frames: slope(&after, &value) * 1000.0,
        }
    }
}

/// Least-squares slope of `value` against the frame (0 for fewer than two frames).
fn slope(samples: &[&Sample], value: &impl Fn(&Sample) -> u64) -> f64 {
    let n = samples.len() as f64;
    if samples.len() < 2 {
        return 0.0;
    }
    let mx = samples.iter().map(|s| f64::from(s.frame)).sum::<f64>() / n;
    let my = samples.iter().map(|s| value(s) as f64).sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for s in samples {
        let dx = f64::from(s.frame) - mx;
        sxy += dx * (value(s) as f64 - my);
        sxx += dx * dx;
    }
    if sxx == 0.0 {
        0.0
    } else {
        sxy / sxx
    }
}

/// The soak's summary (also the head of its JSON).
#[derive(Serialize, Debug)]
struct SoakSummary<'a> {
    device: &'a str,
    volume: &'a str,
    width: u32,
    height: u32,
    frames: u32,
    warm_up_frames: u32,
    seconds: f64,
    validation_problems: usize,
    live_allocations_at_shutdown: usize,
    level_changes: u64,
    level_changes_after_warm_up: u64,
    frames_uploading: u32,
    frames_deferring: u32,
    uploaded_bricks: u64,
    rss: Curve,
    rss_growth_bound: u64,
    gpu_allocated: Curve,
    gpu_growth_bound: u64,
    passed: bool,
    failures: Vec<String>,
}

#[derive(Serialize)]
struct SoakJson<'a> {
    summary: &'a SoakSummary<'a>,
    samples: &'a [Sample],
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
extern "C" {
    /// glibc: returns free heap memory to the system.
    fn malloc_trim(pad: usize) -> std::ffi::c_int;
}

/// `VmRSS` of this process in bytes after returning free heap memory to the system (0 where
/// /proc is missing).
fn rss_bytes() -> u64 {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free memory of the allocator.
    unsafe {
        malloc_trim(0);
    }
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
            line.split_whitespace().nth(1)?.parse::<u64>().ok()
        })
        .map_or(0, |kib| kib * 1024)
}

/// The level every brick is drawn at (level 0 full resolution; `None` not drawn): a level
/// source's, or a two-level cache's hi-res and low-res as 0 and 1.
fn drawn_levels(renderer: &Renderer) -> Option<Vec<Option<u32>>> {
    match renderer.brick_levels() {
        Some(levels) => Some(levels.to_vec()),
        None => renderer
            .brick_cache()
            .map(|c| c.levels().iter().map(|l| l.number()).collect()),
    }
}

/// The warm-up of an `n`-frame soak: its first tenth, but at least 100 frames (half the soak
/// when that is shorter).
pub fn warm_up_frames(n: u32) -> u32 {
    (n / 10).max(100.min(n / 2))
}

/// The curve as CSV text.
fn to_csv(samples: &[Sample]) -> String {
    let mut out = String::from(
        "frame,seconds,rss_bytes,gpu_allocated_bytes,live_allocations,validation_problems,\
         validation_messages,level_changes,uploaded_bricks\n",
    );
    for s in samples {
        out.push_str(&format!(
            "{},{:.3},{},{},{},{},{},{},{}\n",
            s.frame,
            s.seconds,
            s.rss_bytes,
            s.gpu_allocated_bytes,
            s.live_allocations,
            s.validation_problems,
            s.validation_messages,
            s.level_changes,
            s.uploaded_bricks
        ));
    }
    out
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1u32 << 20)
}

fn curve_line(name: &str, c: &Curve) -> String {
    format!(
        "{name}: first {:.2} MiB, after warm-up {:.2}, last {:.2}, max {:.2}; growth after \
         warm-up {:.3} MiB, slope {:+.4} MiB per 1000 frames",
        mib(c.first),
        mib(c.warm),
        mib(c.last),
        mib(c.max),
        mib(c.growth),
        c.slope_per_1000_frames / f64::from(1u32 << 20)
    )
}

/// Runs `mixvol bench --soak frames`.
pub fn soak(args: &BenchArgs, frames: u32) -> Result<()> {
    let r = &args.render;
    if frames == 0 || frames > MAX_SOAK_FRAMES {
        return Err(Error::InvalidInput(format!(
            "--soak {frames}: expected 1 to {MAX_SOAK_FRAMES} frames"
        )));
    }
    if args.churn || r.camera_path.is_path() {
        return Err(Error::InvalidInput(
            "--soak moves the camera itself: drop --churn, --orbit, --dolly and --path".into(),
        ));
    }
    let rss_bound = {
        let v = args.soak_rss_growth_mb;
        if !(0.0..=1.0e6).contains(&v) {
            return Err(Error::InvalidInput(format!(
                "--soak-rss-growth-mb {v}: expected a number of MiB from 0 to 1e6"
            )));
        }
        (v * f64::from(1u32 << 20)) as u64
    };
    let base = r.camera();
    soak_camera(&base, 0)?;
    let (input, meta) = open_input_with_meta(r)?;
    let (model, _) = model_transform(r, meta.as_ref());
    // Declared before the context: printed on failure too; `finish` reads the message log.
    let mut validation = crate::logging::ValidationSummary::default();
    let ctx = GpuContext::new(&ContextDesc {
        validation: true,
        device_name: r.device.clone(),
    })?;
    validation.watch(&ctx);
    let log = ctx.message_log();
    let settings = r.optics.apply(RenderSettings {
        samples_per_voxel: r.samples_per_voxel,
        early_termination: r.early_termination,
        value_window: window_of(r, input.volume())?,
        ..RenderSettings::default()
    })?;
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    renderer.set_transfer_function(&TransferFunction::preset(r.preset.unwrap_or(r.tf)))?;
    renderer.set_model_transform(model);
    let scene = set_up_scene(&mut renderer, r, &input, r.mixed.transition.transition())?;
    drop(input);
    if !scene.planned {
        return Err(Error::InvalidInput(
            "--soak needs camera-driven residency: --gpu-budget-mb, a brick store, or levels \
             from the camera (--levels camera, a level store)"
                .into(),
        ));
    }
    let warm_up = warm_up_frames(frames);
    let every = (frames / SAMPLES).max(1);
    println!(
        "soak: {frames} frames at {}x{}, validation on; warm-up {warm_up} frames; a sample \
         every {every} frames",
        r.width, r.height
    );
    let mut samples = Vec::new();
    let mut previous = drawn_levels(&renderer);
    let mut levels_drawn = std::collections::BTreeSet::new();
    let (mut level_changes, mut changes_at_warm, mut uploaded) = (0u64, 0u64, 0u64);
    let (mut uploading, mut deferring, mut largest_cache) = (0u32, 0u32, 0u64);
    let start = Instant::now();
    let sample = |frame: u32, level_changes: u64, uploaded: u64| Sample {
        frame,
        seconds: start.elapsed().as_secs_f64(),
        rss_bytes: rss_bytes(),
        gpu_allocated_bytes: ctx.allocated_bytes(),
        live_allocations: ctx.live_allocation_count(),
        validation_problems: log.problem_count(),
        validation_messages: log.len(),
        level_changes,
        uploaded_bricks: uploaded,
    };
    for i in 0..frames {
        let camera = soak_camera(&base, i)?;
        let frame = renderer.render(&camera, &settings, r.width, r.height)?;
        if let Some(report) = &frame.residency {
            uploaded += report.residency.uploaded_bricks as u64;
            uploading += u32::from(report.residency.uploaded_bricks > 0);
            deferring += u32::from(report.plan.deferred > 0);
            // The staging buffer grows to hold the largest change, at most the cache image.
            largest_cache = largest_cache
                .max(report.cache_bytes)
                .max(report.residency.uploaded_bytes as u64);
        }
        let levels = drawn_levels(&renderer);
        if let (Some(a), Some(b)) = (&previous, &levels) {
            level_changes += a.iter().zip(b).filter(|(x, y)| x != y).count() as u64;
        }
        levels_drawn.extend(levels.iter().flatten().flatten().copied());
        previous = levels;
        let done = i + 1;
        if done == warm_up {
            changes_at_warm = level_changes;
        }
        if i == 0 || done % every == 0 || done == warm_up || done == frames {
            samples.push(sample(done, level_changes, uploaded));
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    if renderer.brick_levels().is_some() {
        println!("soak: levels drawn {levels_drawn:?}");
    }
    drop(renderer);
    drop(scene);
    let live = ctx.live_allocation_count();
    let info = ctx.info().clone();
    drop(ctx);
    let problems = log.problem_count();
    let rss = Curve::of(&samples, warm_up, |s| s.rss_bytes);
    let gpu = Curve::of(&samples, warm_up, |s| s.gpu_allocated_bytes);
    // The cache's staging buffer grows to the next power of two of the largest update so far,
    // and an update is at most the cache image: all the growth allowed after the warm-up.
    let gpu_bound = largest_cache.next_power_of_two();
    let mut failures = Vec::new();
    if problems > 0 {
        failures.push(format!("{problems} validation warnings/errors"));
    }
    if live > 0 {
        failures.push(format!(
            "{live} GPU allocation(s) still live after the renderer was dropped"
        ));
    }
    if rss.growth > rss_bound {
        failures.push(format!(
            "RSS grew {:.3} MiB after the warm-up (bound {:.3} MiB, --soak-rss-growth-mb)",
            mib(rss.growth),
            mib(rss_bound)
        ));
    }
    if gpu.growth > gpu_bound {
        failures.push(format!(
            "GPU bytes grew {} B after the warm-up (bound {gpu_bound} B: the staging buffer's \
             largest growth)",
            gpu.growth
        ));
    }
    if frames > warm_up && level_changes == changes_at_warm {
        failures.push(
            "no brick changed level after the warm-up (a still scene: lower --gpu-budget-mb so \
             the camera decides what is resident)"
                .into(),
        );
    }
    let summary = SoakSummary {
        device: &info.name,
        volume: &r.volume,
        width: r.width,
        height: r.height,
        frames,
        warm_up_frames: warm_up,
        seconds,
        validation_problems: problems,
        live_allocations_at_shutdown: live,
        level_changes,
        level_changes_after_warm_up: level_changes - changes_at_warm,
        frames_uploading: uploading,
        frames_deferring: deferring,
        uploaded_bricks: uploaded,
        rss,
        rss_growth_bound: rss_bound,
        gpu_allocated: gpu,
        gpu_growth_bound: gpu_bound,
        passed: failures.is_empty(),
        failures: failures.clone(),
    };
    println!(
        "soak: {frames} frames in {seconds:.1} s ({:.1} frames/s) on {}",
        f64::from(frames) / seconds.max(1e-9),
        info.name
    );
    println!(
        "residency: {level_changes} level changes ({} after the warm-up), {uploaded} bricks \
         uploaded, {uploading} frames uploading, {deferring} deferring changes",
        summary.level_changes_after_warm_up
    );
    println!("{}", curve_line("RSS", &rss));
    println!("{}", curve_line("GPU allocated", &gpu));
    println!("live GPU allocations at shutdown: {live}");
    let csv = &args.soak_log;
    write_text("the soak log", csv, &to_csv(&samples))?;
    let json = serde_json::to_string_pretty(&SoakJson {
        summary: &summary,
        samples: &samples,
    })
    .map_err(|e| Error::InvalidInput(format!("soak results as JSON: {e}")))?;
    write_text("the soak log", &csv.with_extension("json"), &json)?;
    println!(
        "wrote {} and {}",
        csv.display(),
        csv.with_extension("json").display()
    );
    if let Some(path) = &args.json {
        crate::files::write_json("the soak summary JSON", path, &summary)?;
    }
    crate::files::note_cpu_device(&info);
    validation.finish()?;
    if failures.is_empty() {
        println!("soak: passed");
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "soak failed: {}",
            failures.join("; ")
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(frame: u32, rss: u64) -> Sample {
        Sample {
            frame,
            seconds: 0.0,
            rss_bytes: rss,
            gpu_allocated_bytes: 0,
            live_allocations: 0,
            validation_problems: 0,
            validation_messages: 0,
            level_changes: 0,
            uploaded_bricks: 0,
        }
    }

    #[test]
    fn the_curve_measures_growth_after_the_warm_up() {
        let samples = [
            at(1, 50),
            at(10, 100),
            at(20, 130),
            at(30, 120),
            at(40, 160),
        ];
        let c = Curve::of(&samples, 10, |s| s.rss_bytes);
        assert_eq!((c.first, c.warm, c.last, c.max), (50, 100, 160, 160));
        assert_eq!(c.growth, 60);
        // Least squares over (10,100) (20,130) (30,120) (40,160): 850 / 500 per frame.
        assert!((c.slope_per_1000_frames - 1700.0).abs() < 1e-9, "{c:?}");
        let falling = Curve::of(&[at(10, 100), at(20, 90)], 10, |s| s.rss_bytes);
        assert_eq!(falling.growth, 0);
    }

    #[test]
    fn the_camera_orbits_dollies_and_bobs() {
        let base = Camera::perspective(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 30.0);
        let c0 = soak_camera(&base, 0).unwrap();
        assert!((c0.eye - base.eye).length() < 1e-5, "{:?}", c0.eye);
        // Half a dolly period in: the nearest point.
        let near = soak_camera(&base, DOLLY_FRAMES / 2).unwrap();
        let d = near.eye.length();
        assert!((d - 2.0 * DOLLY_NEAR).abs() < 0.01, "{d}");
        // A quarter turn moves the eye about the up axis.
        let quarter = soak_camera(&base, ORBIT_FRAMES / 4).unwrap();
        assert!(quarter.eye.x > 0.5, "{:?}", quarter.eye);
        // A quarter bob raises it.
        let up = soak_camera(&base, BOB_FRAMES / 4).unwrap();
        assert!(up.eye.y > 0.3 * up.eye.length(), "{:?}", up.eye);
        let bad = Camera {
            up: Vec3::ZERO,
            ..base
        };
        assert!(soak_camera(&bad, 0).is_err());
    }

    #[test]
    fn the_warm_up_is_a_tenth_but_at_least_a_hundred_frames() {
        assert_eq!(warm_up_frames(10_000), 1000);
        assert_eq!(warm_up_frames(300), 100);
        assert_eq!(warm_up_frames(50), 25);
        assert_eq!(warm_up_frames(1), 0);
    }
}
