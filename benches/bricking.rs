//! Throughput of bricking, all of it through the one kernel (`mixvol::bricks::kernel`): the
//! whole-volume build (`mixvol::bricks::build_bricks`: packed hi-res `(n+2)^3` bricks, packed
//! low-res `(n/2+1)^3` bricks, the whole low-res level and per-brick min/max) of a synthetic
//! `u16` volume, and the brick-store writer (`mixvol::store::write_store_from_volume` and
//! `write_store` from a voxel producer) on the same volume, against a plain memcpy of the same
//! bytes measured in the same run.
//!
//! Run: `cargo bench --bench bricking`. Environment: `MIXVOL_BENCH_DIM` (volume edge, default
//! 512), `MIXVOL_BENCH_RUNS` (timed runs per row, default 5; median and best are reported).
//! MB/s is input volume bytes (10^6 bytes) per second for every row. Volume generation is not
//! timed; the memcpy destination is allocated and touched before timing (a second memcpy row
//! copies into a fresh allocation instead). "cold" builds allocate a fresh store (the kernel
//! zeroes and maps every output page inside the timed region), "warm" rebuilds write into an
//! existing store, like the preallocated memcpy. The "/ memcpy" columns are memcpy time / row
//! time (medians, and bests), i.e. the row's throughput as a fraction of the preallocated
//! memcpy's. The writer rows write a store file into the system temporary directory (removed at
//! the end).

use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{
    available_threads, build_bricks, build_low_res_level, BrickGrid, DownsampleFilter,
    DEFAULT_BRICK_SIZE,
};
use mixvol::store::{write_store, write_store_from_volume, StoreDesc};
use mixvol::volume::{ScalarType, Volume, VoxelData};
use std::hint::black_box;
use std::time::Instant;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// `(median, best)` seconds of `runs` calls of `f`.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    let times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    (median(times), best)
}

/// A cheap analytic field with structure at several scales: a radial shell plus ripples.
fn synthetic_u16(dim: u32) -> Vec<u16> {
    let c = dim as f32 * 0.5;
    let mut out = Vec::with_capacity((dim as usize).pow(3));
    for z in 0..dim {
        for y in 0..dim {
            for x in 0..dim {
                let p = Vec3::new(x as f32 - c, y as f32 - c, z as f32 - c) / c;
                let r = p.length();
                let ripple = ((x ^ y ^ z) & 15) as f32 / 15.0;
                let v = (1.0 - r).clamp(0.0, 1.0) * 0.8 + 0.2 * ripple;
                out.push((v * 65535.0) as u16);
            }
        }
    }
    out
}

fn main() {
    let dim = env_usize("MIXVOL_BENCH_DIM", 512).max(1) as u32;
    let runs = env_usize("MIXVOL_BENCH_RUNS", 5).max(1);
    let threads = available_threads();
    let voxels = synthetic_u16(dim);
    let bytes = voxels.len() * 2;
    let mb = bytes as f64 / 1e6;
    let volume =
        Volume::new(UVec3::splat(dim), Vec3::ONE, VoxelData::U16(voxels)).expect("valid volume");
    let grid = BrickGrid::new(volume.dims(), DEFAULT_BRICK_SIZE).expect("valid grid");
    let VoxelData::U16(src) = volume.data() else {
        unreachable!("built as u16")
    };

    let mut dst = vec![0u16; src.len()];
    dst.copy_from_slice(src); // touch every page before timing
    let memcpy = time(runs, || {
        dst.copy_from_slice(black_box(src));
        black_box(&mut dst);
    });

    println!(
        "# mixvol::bricks::build_bricks, {dim}^3 u16 ({mb:.1} MB), n = {DEFAULT_BRICK_SIZE}, \
         u16 storage, {} bricks, median of {runs}",
        grid.brick_count()
    );
    println!();
    println!(
        "| operation | filter | threads | ms (median) | ms (best) | MB/s (median) | / memcpy \
         (median) | / memcpy (best) |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    let row = |what: &str, filter: &str, threads: usize, (median, best): (f64, f64)| {
        println!(
            "| {what} | {filter} | {threads} | {:.1} | {:.1} | {:.0} | {:.2} | {:.2} |",
            median * 1e3,
            best * 1e3,
            mb / median,
            memcpy.0 / median,
            memcpy.1 / best
        );
    };
    row("memcpy (copy_from_slice)", "-", 1, memcpy);
    let fresh = time(runs, || {
        black_box(black_box(src).to_vec());
    });
    row("memcpy into a fresh allocation (to_vec)", "-", 1, fresh);

    for filter in [DownsampleFilter::Mean2, DownsampleFilter::BSpline4] {
        let name = format!("{filter:?}");
        let cold = time(runs.min(3), || {
            let store =
                build_bricks(black_box(&volume), &grid, filter, ScalarType::U16).expect("builds");
            black_box(store);
        });
        row("bricks + low-res + min/max, cold", &name, threads, cold);
        let mut store = build_bricks(&volume, &grid, filter, ScalarType::U16).expect("builds");
        let warm = time(runs, || {
            store.rebuild(black_box(&volume), threads).expect("builds");
            black_box(&store);
        });
        row("bricks + low-res + min/max, warm", &name, threads, warm);
        let level = time(runs, || {
            let level = build_low_res_level(black_box(&volume), filter, threads).expect("builds");
            black_box(level);
        });
        row(
            "low-res level only (fresh output, part of the above)",
            &name,
            threads,
            level,
        );
        if threads > 1 {
            let single = time(runs.min(3), || {
                store.rebuild(black_box(&volume), 1).expect("builds");
                black_box(&store);
            });
            row("bricks + low-res + min/max, warm", &name, 1, single);
        }
        let out_mb = (store.hi_res_data().as_bytes().len() + store.low_res_data().as_bytes().len())
            as f64
            / 1e6;
        println!("|  ↳ output: {out_mb:.1} MB packed bricks | {name} | | | | | | |");
    }

    let path = std::env::temp_dir().join(format!("mixvol-bricking-{}.store", std::process::id()));
    let sample = |p: IVec3| volume.value(p.x as u32, p.y as u32, p.z as u32);
    for filter in [DownsampleFilter::Mean2, DownsampleFilter::BSpline4] {
        let name = format!("{filter:?}");
        let from_volume = time(runs.min(3), || {
            write_store_from_volume(&path, black_box(&volume), DEFAULT_BRICK_SIZE, filter)
                .expect("writes");
        });
        row(
            "store writer, in-memory volume (write_store_from_volume)",
            &name,
            threads,
            from_volume,
        );
        let desc = StoreDesc {
            dims: volume.dims(),
            brick_size: DEFAULT_BRICK_SIZE,
            scalar: ScalarType::U16,
            spacing: Vec3::ONE,
            filter,
        };
        let producer = time(runs.min(3), || {
            write_store(&path, desc, &sample, &mut |_, _| {}).expect("writes");
        });
        row(
            "store writer, voxel producer (write_store)",
            &name,
            threads,
            producer,
        );
    }
    // Best effort: the file is in the temporary directory anyway.
    let _ = std::fs::remove_file(&path);
}
