//! Chunk throughput of the OME-Zarr loader from loopback servers against the same chunks from
//! disk: one hand-written Zarr v3 image (u16, raw chunks, every chunk present) loaded whole with
//! `load_zarr_at` from its folder, from tests/servers/range_server.py over `http://` and from
//! moto's S3 server over `s3://` (both started here on loopback, from the Python environment
//! `scripts/python-env.sh` creates). The loader fetches chunks one after another (no
//! concurrency), so the remote rows measure per-request latency as much as bandwidth.
//!
//! Run: `cargo bench --bench remote`. Environment: `MIXVOL_BENCH_RUNS` (repeats, default 5),
//! `MIXVOL_BENCH_EDGE` (volume edge in voxels, default 128), `MIXVOL_BENCH_CHUNK` (chunk edge,
//! default 32). Prints a Markdown table: median seconds per load, chunks/s, MiB/s of decoded
//! chunk bytes, and the ratio to disk; the machine's load average is printed with it.

mod common;
#[path = "../tests/remote_util/mod.rs"]
mod remote_util;

use common::{env_u32, median};
use mixvol::volume::formats::{load_zarr_at, RemoteOptions, ZarrLocation};
use remote_util::*;
use std::time::Instant;

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
}
