//! What the render thread pays for a camera-driven three-level residency change, read from a
//! level store synchronously (`VolumeSource::LevelStore`: the stored bricks are read inside
//! `Renderer::update`) against in the background (`VolumeSource::LevelStream`: the call steps
//! onto bricks already in RAM and asks the streamer for the rest), side by side in one run along
//! an orbit (issue 19, item 4). Each view times `update` (choice, reads, staging, upload) and
//! then renders a frame on both renderers; the streamed one never waits for its reader.
//!
//! Run: `cargo bench --bench level_stream` (MIXVOL_BENCH_VIEWS, MIXVOL_BENCH_SIZE to change).
//! The store lies in the page cache after it is written, so a read costs its copy, CRC and
//! conversion, not a disk seek; on lavapipe the absolute times are CPU times.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::DownsampleFilter;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::{write_level_store, LevelStore, LevelStreamConfig, LevelStreamer};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;
use std::time::Instant;

fn main() -> mixvol::Result<()> {
    let views = env_u32("MIXVOL_BENCH_VIEWS", 24).max(2);
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let brick_size = 16;
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let path = std::env::temp_dir().join(format!(
        "mixvol-bench-level-stream-{}.mvl",
        std::process::id()
    ));
    let volume = SyntheticField::MarschnerLobb.generate(UVec3::splat(256), ScalarType::U8)?;
    write_level_store(
        &path,
        &volume,
        brick_size,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )?;
    drop(volume);
    let store = Arc::new(LevelStore::open(&path)?);
    let config = MixedConfig {
        brick_size,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 32 << 20,
        transition: Transition::Smooth,
        max_levels: 0,
    };
    let streamer = Arc::new(LevelStreamer::new(
        store.clone(),
        LevelStreamConfig::default(),
    )?);
    let mut direct = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    direct.set_source(VolumeSource::LevelStore {
        store: store.clone(),
        levels: &[],
        config,
    })?;
    let mut streamed = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    streamed.set_source(VolumeSource::LevelStream {
        streamer: streamer.clone(),
        levels: &[],
        config,
    })?;
    // One step per view, a drawn voxel of a pixel wanted; the renders draw what it staged.
    for r in [&mut direct, &mut streamed] {
        let mut config = r.residency_config();
        config.options.error_threshold = 1.0;
        r.set_residency_config(config);
        r.set_planned(false);
    }
    let settings = RenderSettings::default();
    let (mut direct_ms, mut streamed_ms) = (Vec::new(), Vec::new());
    let (mut direct_stage, mut streamed_stage) = (Vec::new(), Vec::new());
    let (mut direct_bytes, mut streamed_bytes, mut behind) = (0usize, 0usize, 0usize);
    for view in 0..views {
        let angle = view as f32 / views as f32 * std::f32::consts::TAU;
        let eye = Vec3::new(1.3 * angle.cos(), 0.5, 1.3 * angle.sin());
        let camera = Camera::perspective(eye, Vec3::ZERO, 40.0);
        // (call ms, staging ms, bytes staged, bricks waiting)
        let step = |r: &mut Renderer| -> mixvol::Result<(f64, f64, usize, usize)> {
            let before = r.brick_levels().map(<[_]>::to_vec);
            let start = Instant::now();
            r.update(&camera, &settings, size, size)?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            let waiting = r.last_level_choice().map_or(0, |c| c.waiting);
            let changed = r.brick_levels() != before.as_deref();
            let (stage_ms, bytes) = match r.last_level_update() {
                Some(u) if changed => (u.stage_ms, u.uploaded_bytes),
                _ => (0.0, 0),
            };
            r.render(&camera, &settings, size, size)?;
            Ok((ms, stage_ms, bytes, waiting))
        };
        let (d_ms, d_stage, d_bytes, _) = step(&mut direct)?;
        let (s_ms, s_stage, s_bytes, waiting) = step(&mut streamed)?;
        direct_ms.push(d_ms);
        streamed_ms.push(s_ms);
        direct_stage.push(d_stage);
        streamed_stage.push(s_stage);
        direct_bytes += d_bytes;
        streamed_bytes += s_bytes;
        behind += usize::from(waiting > 0);
        println!(
            "view {view:2}: direct {d_ms:7.1} ms ({:6.2} MB read and staged), streamed {s_ms:7.1} ms \
             ({:6.2} MB staged, {waiting:5} bricks still waiting)",
            d_bytes as f64 / 1e6,
            s_bytes as f64 / 1e6
        );
    }
    let stats = streamer.stats();
    let max = |v: &[f64]| v.iter().copied().fold(0.0f64, f64::max);
    let (dm, sm) = (median(direct_ms.clone()), median(streamed_ms.clone()));
    println!(
        "\nMarschner-Lobb 256^3 u8 level store, bricks of {brick_size}, a 32 MiB u8 cache, {size}x{size}, \
         {views} views ({}):",
        ctx.info().name
    );
    println!(
        "| source | update median ms | max ms | of which staging (reads, packing), median ms | MB staged |"
    );
    println!("|---|---|---|---|---|");
    println!(
        "| level store, read in the call | {dm:.1} | {:.1} | {:.1} | {:.1} |",
        max(&direct_ms),
        median(direct_stage),
        direct_bytes as f64 / 1e6
    );
    println!(
        "| level store, streamed | {sm:.1} | {:.1} | {:.1} | {:.1} |",
        max(&streamed_ms),
        median(streamed_stage),
        streamed_bytes as f64 / 1e6
    );
    println!(
        "ratio streamed / direct: {:.2}x median, {:.2}x max; the streamed source was behind the \
         camera in {behind} of {views} views; its reader read {} stored bricks ({:.1} MB in \
         {:.1} ms), {} on the render thread (attaching)",
        sm / dm,
        max(&streamed_ms) / max(&direct_ms),
        stats.loads,
        stats.bytes_read as f64 / 1e6,
        stats.read_time.as_secs_f64() * 1e3,
        stats.blocking_reads
    );
    drop((direct, streamed, streamer, store));
    let _ = std::fs::remove_file(&path);
    Ok(())
}
