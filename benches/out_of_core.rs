//! Out-of-core figures (issue 8): preprocessing throughput against reading the same bytes, and
//! time to first frame against time to a fully refined frame when rendering from the brick store.
//!
//! 1. **Preprocessing.** A raw u16 volume file (`MIXVOL_BENCH_PRE_DIM`^3, default 512^3 =
//!    268 MB) is written once. Rows: reading the file into memory (`std::fs::read`), loading it
//!    as a volume (`load_raw`), preprocessing the loaded volume into a brick store
//!    (`write_store_from_volume`: hi-res + low-res bricks + ranges, all cores), and the whole
//!    file-to-store path (load + preprocess). MB/s is input bytes (10^6) per second; each read row
//!    runs with the file's pages dropped from the page cache (`dd iflag=nocache`, this file only)
//!    and warm; medians of `MIXVOL_BENCH_RUNS` (default 3).
//! 2. **Time to first frame.** A `MIXVOL_BENCH_DIM`^3 u8 store (default 1024^3, 1.35 GB, written
//!    from an analytic field brick by brick) is opened with a streamer (RAM budget 512 MiB) and a
//!    renderer (GPU cache budget 256 MiB), the transfer function culls bricks and the LOD
//!    selector picks hi-res bricks within the cache budget for a 128x128 perspective view. Then
//!    the interactive loop runs: each frame requests the plan (non-blocking), lets the renderer
//!    fall back to what is loaded (`set_levels`), uploads and renders. Reported: time to the
//!    first frame (whatever is loaded), to the first complete frame (every wanted brick drawn,
//!    at least low-res), and to the fully refined frame (every wanted hi-res brick hi-res), with
//!    the frame count and ray-cast time. Run twice: page cache dropped (`dd iflag=nocache`, the
//!    store file only) and warm.
//!
//! Run by `cargo test --benches` (without `--bench`), it is a smoke test on tiny volumes (64^3
//! and 128^3, one run) unless the environment sets the sizes.
//!
//! On lavapipe the "GPU" is the CPU: frame times are CPU times, and the two cores are shared by
//! the streamer's loader thread and the ray-caster. Run: `cargo bench --bench out_of_core`.

mod common;

use common::{env_u32, median};
use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{request_plan, DownsampleFilter, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::lod::{
    cull_bricks, select_levels, BrickGeometry, CullParams, LodView, SelectionOptions, TfCullTable,
    ValueCulling,
};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, ClipPlanes, RenderSettings};
use mixvol::store::{
    write_store, write_store_from_volume, BrickStreamer, StoreDesc, StreamerConfig,
};
use mixvol::volume::{load_raw, RawDescriptor, ScalarType};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

const BRICK: u32 = 32;
/// Above the plan's bytes (about 270 MiB at 1024^3), so the frame can fully refine.
const RAM_BUDGET: usize = 512 << 20;
const CACHE_BUDGET: u64 = 256 << 20;
const SIZE: u32 = 128;

/// Removes a file however the benchmark ends.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Syncs `path` and drops its pages from the page cache (this file only).
fn drop_page_cache(path: &Path) -> bool {
    std::fs::File::open(path).and_then(|f| f.sync_all()).is_ok()
        && std::process::Command::new("dd")
            .arg(format!("if={}", path.display()))
            .args(["iflag=nocache", "count=0", "status=none"])
            .status()
            .is_ok_and(|s| s.success())
}

/// Separable analytic field in [0.04, 0.96] (cheap to evaluate, varied enough to cull).
struct Field {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl Field {
    fn new(d: u32) -> Self {
        let tau = std::f32::consts::TAU;
        let table =
            |f: &dyn Fn(f32) -> f32| (0..d).map(|i| f(i as f32 / d as f32)).collect::<Vec<_>>();
        Self {
            x: table(&|t| 0.5 + 0.25 * (tau * 3.0 * t).sin()),
            y: table(&|t| 0.12 * (tau * 2.0 * t + 0.3).sin()),
            z: table(&|t| 0.09 * (tau * 5.0 * t).cos()),
        }
    }

    fn value(&self, p: IVec3) -> f32 {
        self.x[p.x as usize] + self.y[p.y as usize] + self.z[p.z as usize]
    }
}

fn mb_per_s(bytes: u64, seconds: f64) -> f64 {
    bytes as f64 / seconds / 1e6
}

fn preprocessing(dir: &Path, runs: usize, cold: bool) {
    let dim = env_u32("MIXVOL_BENCH_PRE_DIM", if smoke() { 64 } else { 512 });
    let raw = dir.join(format!("bench-pre-{dim}-{}.raw", std::process::id()));
    let store = dir.join(format!("bench-pre-{dim}-{}.mvbs", std::process::id()));
    let _c1 = RemoveOnDrop(raw.clone());
    let _c2 = RemoveOnDrop(store.clone());
    let field = Field::new(dim);
    {
        let mut out = std::io::BufWriter::new(std::fs::File::create(&raw).expect("create raw"));
        let mut row = Vec::with_capacity(dim as usize * 2);
        for z in 0..dim as i32 {
            for y in 0..dim as i32 {
                row.clear();
                for x in 0..dim as i32 {
                    let v = (field.value(IVec3::new(x, y, z)) * 65535.0).round() as u16;
                    row.extend_from_slice(&v.to_le_bytes());
                }
                out.write_all(&row).expect("write raw");
            }
        }
        out.flush().expect("flush raw");
    }
    let bytes = u64::from(dim).pow(3) * 2;
    let desc = RawDescriptor {
        dims: UVec3::splat(dim),
        scalar: ScalarType::U16,
        spacing: Vec3::ONE,
        header_bytes: 0,
        big_endian: false,
    };
    println!(
        "# Preprocessing {dim}^3 u16 ({:.0} MB raw file) into a brick store (n = {BRICK}, \
         Mean2), median of {runs}",
        bytes as f64 / 1e6
    );
    println!();
    println!("| operation | page cache | s (median) | MB/s of input | / read |");
    println!("|---|---|---:|---:|---:|");
    let time = |prepare: &dyn Fn(), f: &mut dyn FnMut()| {
        let t: Vec<f64> = (0..runs)
            .map(|_| {
                prepare();
                let start = Instant::now();
                f();
                start.elapsed().as_secs_f64()
            })
            .collect();
        median(t)
    };
    let caches: &[bool] = if cold { &[true, false] } else { &[false] };
    for &drop_cache in caches {
        let state = if drop_cache { "dropped" } else { "warm" };
        let prepare = || {
            if drop_cache {
                assert!(drop_page_cache(&raw), "dd could not drop the page cache");
            }
        };
        let read = time(&prepare, &mut || {
            std::hint::black_box(std::fs::read(&raw).expect("read"));
        });
        let load = time(&prepare, &mut || {
            std::hint::black_box(load_raw(&raw, &desc).expect("load"));
        });
        let whole = time(&prepare, &mut || {
            let v = load_raw(&raw, &desc).expect("load");
            write_store_from_volume(&store, &v, BRICK, DownsampleFilter::Mean2).expect("store");
        });
        let row = |name: &str, s: f64| {
            println!(
                "| {name} | {state} | {s:.3} | {:.0} | {:.2} |",
                mb_per_s(bytes, s),
                s / read
            );
        };
        row("read the raw file (std::fs::read)", read);
        row("load_raw (read + volume)", load);
        row("load_raw + write_store_from_volume", whole);
    }
    let volume = load_raw(&raw, &desc).expect("load");
    let mut out_bytes = 0;
    let pre = time(&|| {}, &mut || {
        let s = write_store_from_volume(&store, &volume, BRICK, DownsampleFilter::Mean2)
            .expect("store");
        out_bytes = s.header.file_size;
    });
    println!(
        "| write_store_from_volume (volume in RAM) | - | {pre:.3} | {:.0} | - |",
        mb_per_s(bytes, pre)
    );
    // The same number of output bytes written with std::fs::write + fsync, for the disk's share.
    let zeros = vec![1u8; out_bytes as usize];
    let plain_write = time(&|| {}, &mut || {
        std::fs::write(&store, &zeros).expect("write");
        std::fs::File::open(&store)
            .and_then(|f| f.sync_all())
            .expect("sync");
    });
    println!(
        "| std::fs::write + fsync of the store's {:.0} MB (disk only) | - | {plain_write:.3} | {:.0} | - |",
        out_bytes as f64 / 1e6,
        mb_per_s(bytes, plain_write)
    );
    println!();
    println!(
        "Store file: {:.0} MB ({:.2} x the input); {} threads.",
        out_bytes as f64 / 1e6,
        out_bytes as f64 / bytes as f64,
        mixvol::bricks::available_threads()
    );
    println!();
}

/// One frame of the interactive loop.
struct FrameRecord {
    at: Duration,
    hi: usize,
    lo: usize,
    fallback: usize,
    raycast_ms: f64,
}

fn first_frames(dir: &Path, cold: bool) {
    let dim = env_u32("MIXVOL_BENCH_DIM", if smoke() { 128 } else { 1024 });
    let path = dir.join(format!("bench-ttff-{dim}-{}.mvbs", std::process::id()));
    let _cleanup = RemoveOnDrop(path.clone());
    let field = Field::new(dim);
    let desc = StoreDesc {
        dims: UVec3::splat(dim),
        brick_size: BRICK,
        scalar: ScalarType::U8,
        spacing: Vec3::ONE,
        filter: DownsampleFilter::Mean2,
    };
    let summary =
        write_store(&path, desc, &|p| field.value(p), &mut |_, _| {}).expect("write store");
    println!(
        "# Time to first frame: {dim}^3 u8 store ({:.2} GB, {} bricks of {BRICK}^3, written in \
         {:.1} s), {SIZE}x{SIZE}, RAM budget {} MiB, cache budget {} MiB",
        summary.header.file_size as f64 / 1e9,
        summary.header.brick_count,
        summary.elapsed.as_secs_f64(),
        RAM_BUDGET >> 20,
        CACHE_BUDGET >> 20
    );
    println!();
    let ctx = GpuContext::new(&ContextDesc {
        validation: false,
        device_name: None,
    })
    .expect("Vulkan");
    let tf = TransferFunction::preset(TfPreset::Bands);
    let camera = Camera::perspective(Vec3::new(0.9, 0.6, 1.3), Vec3::ZERO, 40.0);
    let settings = RenderSettings::default();
    let config = MixedConfig {
        brick_size: BRICK,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: CACHE_BUDGET,
        transition: Transition::Smooth,
        max_levels: 0,
    };
    // Compile the pipelines once (not part of the timings).
    {
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).expect("renderer");
        r.set_transfer_function(&tf).expect("tf");
        let s =
            Arc::new(BrickStreamer::open(&path, StreamerConfig::default()).expect("open store"));
        r.set_source(VolumeSource::Bricks { source: s, config })
            .expect("source");
        r.render(&camera, &settings, SIZE, SIZE).expect("render");
    }
    println!(
        "| page cache | first frame (s) | first complete frame (s) | fully refined (s) | frames \
         | hi / lo drawn at the end | wanted MiB | ray-cast ms (median) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    let states: &[bool] = if cold { &[true, false] } else { &[false] };
    for &drop_cache in states {
        if drop_cache {
            assert!(drop_page_cache(&path), "dd could not drop the page cache");
        }
        let start = Instant::now();
        let streamer = Arc::new(
            BrickStreamer::open(
                &path,
                StreamerConfig {
                    ram_budget_bytes: RAM_BUDGET,
                    record_load_order: false,
                },
            )
            .expect("open store"),
        );
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).expect("renderer");
        renderer.set_transfer_function(&tf).expect("tf");
        renderer
            .set_source(VolumeSource::Bricks {
                source: streamer.clone(),
                config,
            })
            .expect("source");
        let slots = renderer
            .brick_cache()
            .expect("cache")
            .geometry()
            .slot_count() as usize;
        let grid = streamer.store().grid();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).expect("geometry");
        let ranges = streamer.store().value_ranges();
        let params = CullParams {
            value: ValueCulling::TransferFunction(TfCullTable::new(&tf, (0.0, 1.0)).expect("tf")),
            clip: ClipPlanes::NONE,
        };
        let active = cull_bricks(&geometry, ranges, &params).expect("cull");
        let view = LodView::new(&camera, SIZE, SIZE).expect("view");
        let wanted = select_levels(
            &geometry,
            &view,
            ranges,
            &active,
            &SelectionOptions::with_slots(slots),
        )
        .expect("select");
        let eye = camera.eye;
        let priority: Vec<f32> = (0..grid.brick_count())
            .map(|i| {
                let (lo, hi) = geometry.brick_box(grid.brick_coords(i));
                -eye.distance(0.5 * (lo + hi))
            })
            .collect();
        let plan = request_plan(&wanted, &priority);
        let wanted_bytes: usize = plan
            .iter()
            .map(|&(_, l, _)| streamer.store().level_bytes(l))
            .sum();
        let want_hi = wanted.iter().filter(|&&l| l == Level::Hi).count();
        let want_drawn = wanted.iter().filter(|&&l| l != Level::Absent).count();
        let mut frames: Vec<FrameRecord> = Vec::new();
        loop {
            streamer.request(&plan).expect("request");
            let report = renderer.set_levels(&wanted).expect("levels");
            let frame = renderer
                .render(&camera, &settings, SIZE, SIZE)
                .expect("render");
            frames.push(FrameRecord {
                at: start.elapsed(),
                hi: report.hi_bricks,
                lo: report.lo_bricks,
                fallback: report.fallback_bricks,
                raycast_ms: frame
                    .timing
                    .gpu_raycast_ms
                    .unwrap_or(frame.timing.cpu_frame_ms),
            });
            let refined = report.hi_bricks == want_hi && report.fallback_bricks == 0;
            if refined || start.elapsed() > Duration::from_secs(120) {
                break;
            }
        }
        let first = frames[0].at.as_secs_f64();
        let complete = frames
            .iter()
            .find(|f| f.hi + f.lo == want_drawn)
            .map_or(f64::NAN, |f| f.at.as_secs_f64());
        let last = frames.last().expect("a frame");
        let refined = if last.hi == want_hi && last.fallback == 0 {
            last.at.as_secs_f64()
        } else {
            f64::NAN
        };
        println!(
            "| {} | {first:.3} | {complete:.3} | {refined:.3} | {} | {} / {} (wanted {want_hi} / {}) | {:.0} | {:.0} |",
            if drop_cache { "dropped" } else { "warm" },
            frames.len(),
            last.hi,
            last.lo,
            want_drawn - want_hi,
            wanted_bytes as f64 / (1 << 20) as f64,
            median(frames.iter().map(|f| f.raycast_ms).collect()),
        );
        let stats = streamer.stats();
        eprintln!(
            "  first frame: {} hi + {} lo drawn, {} fell back; loads {} ({:.0} MB/s), peak {:.0} MiB",
            frames[0].hi,
            frames[0].lo,
            frames[0].fallback,
            stats.loads,
            stats.bytes_read as f64 / stats.read_time.as_secs_f64().max(1e-9) / 1e6,
            stats.peak_bytes as f64 / (1 << 20) as f64,
        );
    }
    println!();
}

/// True when run as a test (`cargo test --benches` passes no `--bench`): tiny default sizes.
fn smoke() -> bool {
    !std::env::args().any(|a| a == "--bench")
}

fn main() {
    let runs = env_u32("MIXVOL_BENCH_RUNS", if smoke() { 1 } else { 3 }).max(1) as usize;
    let cold = true;
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bench-out-of-core");
    std::fs::create_dir_all(&dir).expect("bench folder");
    if std::env::var_os("MIXVOL_BENCH_SKIP_PRE").is_none() {
        preprocessing(&dir, runs, cold);
    }
    first_frames(&dir, cold);
}
