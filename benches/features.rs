//! What each render mode and optical option costs: frame time with the feature on against the
//! same scene without it, measured side by side in interleaved rounds (every setting once per
//! round, so machine noise hits all alike), on single-resolution data and on a mixed-resolution
//! cache with smooth transitions (where gradients go through the warped reconstruction).
//!
//! Run: `cargo bench --bench features` (MIXVOL_BENCH_SIZE, MIXVOL_BENCH_FRAMES change the image
//! size and the rounds). On lavapipe the absolute times are CPU times; compare ratios.

mod common;

use common::{env_u32, median};
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{SamplingModel, TfPreset, TransferFunction};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{
    Camera, ClipPlane, ClipPlanes, Reconstruction, RenderMode, RenderSettings, Shading,
};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;

/// The settings compared, the first being the baseline.
fn settings() -> Vec<(&'static str, RenderSettings)> {
    let base = RenderSettings {
        samples_per_voxel: 1.0,
        ..RenderSettings::default()
    };
    let iso = RenderMode::Iso {
        value: 0.5,
        colour: Vec3::new(0.9, 0.75, 0.55),
    };
    vec![
        ("DVR (baseline)", base),
        (
            "DVR + shading",
            RenderSettings {
                shading: Some(Shading::default()),
                ..base
            },
        ),
        (
            "DVR + gradient opacity",
            RenderSettings {
                gradient_opacity: Some(0.5),
                ..base
            },
        ),
        (
            "DVR extinction-based",
            RenderSettings {
                sampling_model: SamplingModel::Extinction,
                ..base
            },
        ),
        (
            "DVR pre-integrated",
            RenderSettings {
                preintegrated: true,
                ..base
            },
        ),
        (
            "DVR tricubic B-spline",
            RenderSettings {
                reconstruction: Reconstruction::TricubicBSpline,
                ..base
            },
        ),
        (
            "DVR, low-res bricks at double step (LaMar; mixed only)",
            RenderSettings {
                coarse_low_res_steps: true,
                ..base
            },
        ),
        (
            "DVR, two clip planes",
            RenderSettings {
                clip_planes: ClipPlanes::new(&[
                    ClipPlane::new(Vec3::new(1.0, 0.0, 0.0), 0.3),
                    ClipPlane::new(Vec3::new(0.0, 0.0, -1.0), 0.3),
                ])
                .expect("valid planes"),
                ..base
            },
        ),
        (
            "DVR in the MIDA variant (gamma -1)",
            RenderSettings {
                mode: RenderMode::Mida { gamma: -1.0 },
                ..base
            },
        ),
        (
            "MIDA (gamma 0)",
            RenderSettings {
                mode: RenderMode::Mida { gamma: 0.0 },
                ..base
            },
        ),
        (
            "MIDA -> MIP (gamma 0.5)",
            RenderSettings {
                mode: RenderMode::Mida { gamma: 0.5 },
                ..base
            },
        ),
        (
            "MIP",
            RenderSettings {
                mode: RenderMode::Mip,
                ..base
            },
        ),
        ("iso-surface", RenderSettings { mode: iso, ..base }),
        (
            "iso-surface + shading",
            RenderSettings {
                mode: iso,
                shading: Some(Shading::default()),
                ..base
            },
        ),
    ]
}

fn measure(
    label: &str,
    renderer: &mut Renderer,
    camera: &Camera,
    size: u32,
    rounds: u32,
) -> mixvol::Result<()> {
    let all = settings();
    for (_, s) in &all {
        renderer.render(camera, s, size, size)?; // build the variant, warm up
    }
    let mut times = vec![Vec::new(); all.len()];
    for _ in 0..rounds {
        for (i, (_, s)) in all.iter().enumerate() {
            let f = renderer.render(camera, s, size, size)?;
            times[i].push(f.timing.gpu_raycast_ms.unwrap_or(f.timing.cpu_frame_ms));
        }
    }
    let medians: Vec<f64> = times.into_iter().map(median).collect();
    println!("\n## {label}\n");
    println!("| setting | ray-cast median ms | vs baseline |");
    println!("|---|---|---|");
    for ((name, _), ms) in all.iter().zip(&medians) {
        println!("| {name} | {ms:.2} | {:.2}x |", ms / medians[0]);
    }
    Ok(())
}

fn main() -> mixvol::Result<()> {
    let size = env_u32("MIXVOL_BENCH_SIZE", 256);
    let rounds = env_u32("MIXVOL_BENCH_FRAMES", 5).max(1);
    let ctx = GpuContext::new(&ContextDesc::default())?;
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(128), ScalarType::U8)?);
    let tf = TransferFunction::preset(TfPreset::Fire);
    let camera = Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0);
    println!(
        "# feature cost, Marschner-Lobb 128^3 u8, fire TF, {size}x{size}, 1 sample/voxel, {rounds} interleaved rounds, device: {} ({:?})",
        ctx.info().name,
        ctx.info().device_type
    );
    let mut single = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    single.set_transfer_function(&tf)?;
    single.set_source(VolumeSource::Volume(&volume))?;
    measure("single resolution", &mut single, &camera, size, rounds)?;
    drop(single);

    let brick_size = 32;
    let mut mixed = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
    mixed.set_transfer_function(&tf)?;
    mixed.set_source(VolumeSource::Mixed {
        volume: volume.clone(),
        config: MixedConfig {
            brick_size,
            filter: DownsampleFilter::Mean2,
            cache_budget_bytes: 256 << 20,
            transition: Transition::Smooth,
            max_levels: 0,
        },
    })?;
    let grid = BrickGrid::new(volume.dims(), brick_size).expect("valid grid");
    let levels: Vec<Level> = (0..grid.brick_count())
        .map(|i| {
            let b = grid.brick_coords(i);
            if (b.x + b.y + b.z).is_multiple_of(2) {
                Level::Hi
            } else {
                Level::Lo
            }
        })
        .collect();
    mixed.set_levels(&levels)?;
    measure(
        "mixed resolution, checkerboard of hi/lo bricks (32^3), smooth transitions",
        &mut mixed,
        &camera,
        size,
        rounds,
    )?;
    Ok(())
}
