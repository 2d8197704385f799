//! Camera-driven residency along a camera path, through `mixvol bench` (the same code a user
//! runs): a Marschner-Lobb volume of `MIXVOL_BENCH_DIM`^3 voxels (default 512, u8, bricks of 32)
//! under a GPU budget whose cache holds an eighth of its bricks hi-res, along a
//! `MIXVOL_BENCH_FRAMES`-frame orbit (default 60) and a dolly towards the volume of as many
//! frames, at `MIXVOL_BENCH_SIZE`^2 pixels (default 128). Smooth and discontinuous transitions
//! are rendered side by side, frame by frame, in each run. Prints `mixvol bench`'s tables: median,
//! p95 and max frame time, upload + fixup per frame, MB uploaded, the planner's CPU time, and the
//! frames to converge after the camera stops.
//!
//! Run: `cargo bench --bench camera_path` (at the workspace root or in crates/mixvol-cli).

use mixvol::cache::CacheGeometry;
use std::process::Command;

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let dim = env_u32("MIXVOL_BENCH_DIM", 512);
    let frames = env_u32("MIXVOL_BENCH_FRAMES", 60);
    let size = env_u32("MIXVOL_BENCH_SIZE", 128);
    const BRICK: u32 = 32;
    let bricks = u64::from(dim.div_ceil(BRICK)).pow(3);
    // The smallest cache image (power-of-two sides) holding an eighth of the bricks hi-res, for
    // u8 texels; the upload staging gets an eighth of the GPU budget on top.
    let wanted = (bricks / 8).max(1) as u32;
    let cache = CacheGeometry::choose(BRICK, 1, u64::MAX, 2048, wanted).expect("cache geometry");
    let e = cache.extent();
    let cache_bytes = u64::from(e.x) * u64::from(e.y) * u64::from(e.z);
    let gpu_mib = cache_bytes as f64 / f64::from(1 << 20) * 8.0 / 7.0 * 1.0001;
    println!(
        "# camera_path: Marschner-Lobb {dim}^3 u8, {bricks} bricks of {BRICK}^3, GPU budget {gpu_mib:.2} MiB (a {}x{}x{} cache of {} slots for {wanted} wanted), {frames}-frame paths at {size}x{size}",
        e.x, e.y, e.z, cache.slot_count()
    );
    for (name, path) in [
        (
            "orbit",
            vec![
                "--orbit".to_string(),
                frames.to_string(),
                "--elevation".into(),
                "20".into(),
            ],
        ),
        (
            "dolly",
            vec![
                "--dolly".to_string(),
                frames.to_string(),
                "--dolly-to".into(),
                "0.3".into(),
            ],
        ),
    ] {
        println!("\n## {name}");
        let dims = format!("{dim},{dim},{dim}");
        let size = size.to_string();
        let gpu = format!("{gpu_mib:.3}");
        let status = Command::new(env!("CARGO_BIN_EXE_mixvol"))
            .args([
                "bench",
                "--dims",
                &dims,
                "--brick-size",
                "32",
                "--gpu-budget-mb",
                &gpu,
                "--width",
                &size,
                "--height",
                &size,
            ])
            .args(&path)
            .status()
            .expect("run mixvol bench");
        assert!(status.success(), "mixvol bench failed for the {name} path");
    }
}
