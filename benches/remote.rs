//! Chunk throughput of the OME-Zarr loader from loopback servers against the same chunks from
//! disk: one hand-written Zarr v3 image (u16, raw chunks, every chunk present) loaded whole with
//! `load_zarr_at` from its folder, from tests/servers/range_server.py over `http://` and from
//! moto's S3 server over `s3://` (both started here on loopback, from the Python environment
//! `scripts/python-env.sh` creates). The loader fetches chunks one after another (no
//! concurrency), so the remote rows measure per-request latency as much as bandwidth.
//!
//! Then, for the streaming brick source (`mixvol::stream`): chunk throughput over HTTP with 1, 4
//! and 16 fetches in flight ([`ChunkCache::get_many`], the path the streamer takes); the bytes a
//! Lo-only frame fetches, derived from level 0 (what the source does) against reading a pyramid
//! level 1 of half the edge (the same chunk shape and codec: all its chunks); and, on the
//! offscreen renderer (lavapipe here) under the planner, the time to the first frame that draws
//! anything and to full detail (nothing waits for the source, the plan settled) for the remote
//! image over HTTP, with the bytes fetched.
//!
//! Run: `cargo bench --bench remote`. Environment: `MIXVOL_BENCH_RUNS` (repeats, default 5),
//! `MIXVOL_BENCH_EDGE` (volume edge in voxels, default 128), `MIXVOL_BENCH_CHUNK` (chunk edge,
//! default 32). Prints a Markdown table: median seconds per load, chunks/s, MiB/s of decoded
//! chunk bytes, and the ratio to disk; the machine's load average is printed with it.

mod common;
#[path = "../tests/remote_util/mod.rs"]
mod remote_util;

use common::{env_u32, median};
use mixvol::bricks::{request_plan, BrickSource, DownsampleFilter, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, ResidencyConfig, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::StreamerConfig;
use mixvol::stream::{open_zarr_source, ChunkCache, ZarrStreamConfig};
use mixvol::volume::formats::{load_zarr_at, RemoteOptions, ZarrChunks, ZarrLocation};
use remote_util::*;
use std::sync::Arc;
use std::time::{Duration, Instant};

fn main() {
    let runs = env_u32("MIXVOL_BENCH_RUNS", 5).max(1);
    let edge = u64::from(env_u32("MIXVOL_BENCH_EDGE", 128));
    let chunk = u64::from(env_u32("MIXVOL_BENCH_CHUNK", 32));
    let spec = ImageSpec {
        shape: [edge; 3],
        chunks: [chunk; 3],
        v3: true,
        missing: None,
        fill: 0,
    };
    let dir = TempDir::new("bench");
    let image = dir.0.join("bench.zarr");
    let chunks = spec.write(&image);
    let chunk_bytes = chunk.pow(3) * 2;
    let total_mib = (chunks as u64 * chunk_bytes) as f64 / f64::from(1 << 20);

    let http = range_server(&dir.0);
    let moto = moto_server();
    s3_upload(&moto, &image, "bench", "bench.zarr");
    let s3 = moto_options(&moto);
    let rows = [
        (
            "disk (folder)",
            ZarrLocation::Local(image.clone()),
            RemoteOptions::default(),
        ),
        (
            "HTTP (range_server.py)",
            ZarrLocation::parse(&format!("{}/ok/bench.zarr", http.base())).unwrap(),
            RemoteOptions::default(),
        ),
        (
            "S3 (moto server)",
            ZarrLocation::parse("s3://bench/bench.zarr").unwrap(),
            s3,
        ),
    ];

    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{edge}^3 u16 volume, {chunks} raw chunks of {chunk}^3 ({} KiB each, {total_mib:.1} MiB), \
         {runs} runs, sequential fetches; load average {}",
        chunk_bytes / 1024,
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!();
    println!("| source | s / load (median) | chunks/s | MiB/s | time vs disk |");
    println!("| --- | --- | --- | --- | --- |");
    let mut disk = None;
    for (name, location, options) in &rows {
        let mut times = Vec::new();
        for _ in 0..runs {
            let start = Instant::now();
            let loaded = load_zarr_at(location, 0, options).expect("load");
            times.push(start.elapsed().as_secs_f64());
            check_volume(&loaded.volume, &spec);
        }
        let t = median(times);
        let base = *disk.get_or_insert(t);
        println!(
            "| {name} | {t:.3} | {:.0} | {:.1} | {:.1}x |",
            chunks as f64 / t,
            total_mib / t,
            t / base
        );
    }
    streaming(&spec, &dir.0, &http, runs);
}

/// The chunk throughput, Lo-only bytes and planner timings of the streaming source.
fn streaming(spec: &ImageSpec, dir: &std::path::Path, http: &Server, runs: u32) {
    let url = format!("{}/ok/bench.zarr", http.base());
    let location = ZarrLocation::parse(&url).unwrap();
    let options = RemoteOptions::default();
    let slow = ZarrLocation::parse(&format!("{}/slow/bench.zarr", http.base())).unwrap();
    let chunks = ZarrChunks::open(&location, 0, &options).expect("open");
    let grid = chunks.chunk_grid();
    let all: Vec<glam::UVec3> = (0..grid.z)
        .flat_map(|z| {
            (0..grid.y).flat_map(move |y| (0..grid.x).map(move |x| glam::UVec3::new(x, y, z)))
        })
        .collect();
    let mib = (all.len() as u64 * spec.chunks[0].pow(3) * 2) as f64 / f64::from(1 << 20);
    println!();
    println!(
        "Streaming source, HTTP (range_server.py), {} chunks:",
        all.len()
    );
    println!();
    println!("| server | chunk fetches in flight | s (median) | chunks/s | MiB/s | speed-up |");
    println!("| --- | --- | --- | --- | --- | --- |");
    let slow_chunks = ZarrChunks::open(&slow, 0, &options).expect("open");
    for (name, source) in [("ok", &chunks), ("slow (+20 ms per chunk)", &slow_chunks)] {
        let mut sequential = None;
        for concurrency in [1usize, 4, 16] {
            let mut times = Vec::new();
            for _ in 0..runs {
                let cache = ChunkCache::new(1 << 30, concurrency);
                let start = Instant::now();
                let got = cache.get_many(source, &all).expect("chunks");
                times.push(start.elapsed().as_secs_f64());
                assert_eq!(got.len(), all.len());
            }
            let t = median(times);
            let base = *sequential.get_or_insert(t);
            println!(
                "| {name} | {concurrency} | {t:.3} | {:.0} | {:.1} | {:.2}x |",
                all.len() as f64 / t,
                mib / t,
                base / t
            );
        }
    }

    // A Lo-only frame: every brick's low-res level, derived from level 0, against reading a
    // level 1 of half the edge (same chunks and codec) whole.
    let edge = spec.shape[0];
    let half = ImageSpec {
        shape: [edge / 2; 3],
        chunks: spec.chunks,
        v3: spec.v3,
        missing: None,
        fill: spec.fill,
    };
    half.write(&dir.join("half.zarr"));
    let lo_source = open_zarr_source(
        &location,
        0,
        &options,
        config(),
        StreamerConfig {
            ram_budget_bytes: 1 << 30,
            record_load_order: false,
        },
    )
    .expect("open source");
    let bricks = lo_source.grid().brick_count();
    let wanted = vec![Level::Lo; bricks];
    lo_source
        .request_levels(&request_plan(&wanted, &[]))
        .expect("request");
    assert!(lo_source.wait_settled(Duration::from_secs(600)));
    let derived = lo_source.store().chunks().bytes_fetched();
    let level1 = ZarrChunks::open(
        &ZarrLocation::parse(&format!("{}/ok/half.zarr", http.base())).unwrap(),
        0,
        &options,
    )
    .expect("open level 1");
    let g1 = level1.chunk_grid();
    let all1: Vec<glam::UVec3> = (0..g1.z)
        .flat_map(|z| {
            (0..g1.y).flat_map(move |y| (0..g1.x).map(move |x| glam::UVec3::new(x, y, z)))
        })
        .collect();
    ChunkCache::new(1 << 30, 8)
        .get_many(&level1, &all1)
        .expect("level 1 chunks");
    let pyramid = level1.bytes_fetched();
    println!();
    println!(
        "Lo-only frame ({bricks} bricks of {}^3): derived from level 0 fetches {:.2} MiB ({} chunks); \
         a pyramid level 1 would fetch {:.2} MiB ({} chunks): {:.1}x less",
        config().brick_size,
        derived as f64 / f64::from(1 << 20),
        lo_source.store().cache_stats().fetches,
        pyramid as f64 / f64::from(1 << 20),
        all1.len(),
        derived as f64 / pyramid.max(1) as f64
    );
    drop(lo_source);

    // Time to first frame and to full detail under the planner.
    let ctx = GpuContext::new(&ContextDesc {
        validation: false,
        device_name: None,
    })
    .expect("Vulkan");
    println!();
    println!("| run | source loaded all it was asked (s) | first frame drawing anything (s) | full detail (s) | frames | bytes fetched (MiB) | of the image |");
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    let total = (all.len() as u64 * spec.chunks[0].pow(3) * 2) as f64;
    // Run 0 compiles the pipelines (seconds on lavapipe); later runs start from its pipeline
    // cache, so their times are the streaming's.
    let mut pipelines: Option<Vec<u8>> = None;
    for run in 0..runs.min(3) {
        let start = Instant::now();
        let source = Arc::new(
            open_zarr_source(
                &location,
                0,
                &options,
                config(),
                StreamerConfig {
                    ram_budget_bytes: 256 << 20,
                    record_load_order: false,
                },
            )
            .expect("open source"),
        );
        let mut renderer = match &pipelines {
            Some(data) => Renderer::with_pipeline_cache(&ctx, TargetFormat::Rgba8Unorm, data),
            None => Renderer::new(&ctx, TargetFormat::Rgba8Unorm),
        }
        .expect("renderer");
        renderer
            .set_transfer_function(&TransferFunction::preset(TfPreset::Bands))
            .expect("tf");
        renderer.set_residency_config(ResidencyConfig {
            ram_bytes: Some(256 << 20),
            ..ResidencyConfig::default()
        });
        renderer
            .set_source(VolumeSource::Bricks {
                source: source.clone(),
                config: MixedConfig {
                    brick_size: config().brick_size,
                    filter: DownsampleFilter::Mean2,
                    cache_budget_bytes: 64 << 20,
                    transition: Transition::Smooth,
                    max_levels: 0,
                },
            })
            .expect("source");
        let camera = Camera::perspective(glam::Vec3::new(0.6, 0.5, 1.6), glam::Vec3::ZERO, 40.0);
        let settings = RenderSettings::default();
        let (mut first, mut full, mut frames, mut loaded) = (None, None, 0, None);
        for f in 0..400 {
            let frame = renderer
                .render(&camera, &settings, 256, 256)
                .expect("frame");
            frames = f + 1;
            let report = frame.residency.expect("planned");
            if first.is_none() && report.plan.drawn_hi + report.plan.drawn_lo > 0 {
                first = Some(start.elapsed().as_secs_f64());
            }
            if report.plan.waiting_for_source == 0 && report.plan.is_settled() && f > 0 {
                full = Some(start.elapsed().as_secs_f64());
                break;
            }
            if source.wait_settled(Duration::from_millis(20)) && loaded.is_none() {
                loaded = Some(start.elapsed().as_secs_f64());
            }
        }
        if pipelines.is_none() {
            pipelines = renderer.pipeline_cache_data().ok();
        }
        let fetched = source.store().chunks().bytes_fetched() as f64;
        println!(
            "| {run}{} | {} | {:.2} | {} | {frames} | {:.2} | {:.0} % |",
            if run == 0 {
                " (compiles pipelines)"
            } else {
                ""
            },
            loaded.map_or("-".to_string(), |t| format!("{t:.2}")),
            first.unwrap_or(f64::NAN),
            full.map_or("not reached".to_string(), |t| format!("{t:.2}")),
            fetched / f64::from(1 << 20),
            100.0 * fetched / total
        );
    }
}

fn config() -> ZarrStreamConfig {
    ZarrStreamConfig {
        brick_size: 32,
        filter: DownsampleFilter::Mean2,
        concurrency: 8,
        chunk_cache_bytes: 256 << 20,
        value_range: None,
    }
}
