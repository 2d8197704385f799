//! Frame time against accuracy for the single-resolution ray-caster, measured side by side in
//! one run: the default scene at several step sizes, timed on the GPU (timestamps) and the CPU,
//! and compared with a fine-step render (8 samples per voxel) for image error.
//!
//! Run: `cargo bench --bench raycast` (set MIXVOL_BENCH_SIZE / MIXVOL_BENCH_FRAMES to change the
//! image size and frame count). On lavapipe the absolute times are CPU times; compare ratios.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{ScalarType, SyntheticField};

fn main() -> mixvol::Result<()> {
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let frames = env_u32("MIXVOL_BENCH_FRAMES", 7).max(1);
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume = SyntheticField::MarschnerLobb.generate(UVec3::splat(128), ScalarType::U8)?;
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float)?;
    renderer.set_source(VolumeSource::Volume(&volume))?;
    renderer.set_transfer_function(&TransferFunction::preset(TfPreset::Fire))?;
    let camera = Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0);
    let settings = |spv: f32| RenderSettings {
        samples_per_voxel: spv,
        ..RenderSettings::default()
    };
    let reference = renderer.render(&camera, &settings(8.0), size, size)?;
    println!(
        "# single-resolution ray-cast, Marschner-Lobb 128^3 u8, {size}x{size}, {frames} frames, device: {} ({:?})",
        ctx.info().name,
        ctx.info().device_type
    );
    println!("| samples/voxel | gpu median ms | cpu median ms | time vs 1 spp/voxel | RMSE vs 8/voxel | PSNR dB |");
    println!("|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for spv in [0.5f32, 1.0, 2.0, 4.0] {
        renderer.render(&camera, &settings(spv), size, size)?; // warm-up
        let mut gpu = Vec::new();
        let mut cpu = Vec::new();
        let mut last = None;
        for _ in 0..frames {
            let f = renderer.render(&camera, &settings(spv), size, size)?;
            gpu.extend(f.timing.gpu_raycast_ms);
            cpu.push(f.timing.cpu_frame_ms);
            last = Some(f);
        }
        let frame = last.expect("frames >= 1");
        let sq: f64 = frame
            .pixels
            .iter()
            .zip(&reference.pixels)
            .map(|(a, b)| f64::from((*a - *b).length_squared()) / 4.0)
            .sum();
        let rmse = (sq / frame.pixels.len() as f64).sqrt();
        let psnr = if rmse > 0.0 {
            20.0 * (1.0 / rmse).log10()
        } else {
            f64::INFINITY
        };
        let gpu_ms = if gpu.is_empty() {
            f64::NAN
        } else {
            median(gpu)
        };
        let cpu_ms = median(cpu);
        rows.push((spv, gpu_ms, cpu_ms, rmse, psnr));
    }
    let base = rows.iter().find(|r| r.0 == 1.0).map_or(f64::NAN, |r| r.1);
    for (spv, gpu_ms, cpu_ms, rmse, psnr) in rows {
        let ratio = gpu_ms / base;
        println!("| {spv} | {gpu_ms:.2} | {cpu_ms:.2} | {ratio:.2} | {rmse:.5} | {psnr:.1} |");
    }
    Ok(())
}
