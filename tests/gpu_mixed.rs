//! The GPU mixed-resolution path against the CPU reference: cache contents after upload and
//! fixup, the reconstructed field (probe), its continuity, images, and a long sequence of
//! residency changes under validation.

mod common;

use common::Rng;

use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level, VolumeBrickSource};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference::{self, sample_mixed, ReferenceCache};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, ClipPlane, ClipPlanes, RenderSettings, Shading};
use mixvol::volume::{ScalarType, SyntheticField, Volume, VoxelData};
use std::sync::Arc;

const N: u32 = 8;

/// Least visible fraction of the 80 x 80 Marschner-Lobb images (the volume fills about a third
/// of the frame; absent bricks remove part of it).
const COVERAGE_FLOOR: f32 = 0.15;

/// GPU probe vs CPU reference on a u8 cache: the 2e-3 of the f32 field test (8-bit sub-texel
/// weights) plus one 8-bit step, because lavapipe filters 8-bit textures in 8-bit fixed point
/// (measured: the probed u8 field is piecewise constant in steps of exactly 1/255, 4.1e-3 from
/// the reference at worst, the same from a freshly built renderer).
const U8_PROBE_TOLERANCE: f32 = 2e-3 + 1.0 / 255.0;

fn smooth_random_volume(rng: &mut Rng, dims: UVec3, scalar: ScalarType) -> Volume {
    let count = (dims.x * dims.y * dims.z) as usize;
    let values: Vec<f32> = (0..count).map(|_| rng.unit()).collect();
    let data = match scalar {
        ScalarType::F32 => VoxelData::F32(values),
        ScalarType::U8 => VoxelData::U8(values.iter().map(|v| (v * 255.0).round() as u8).collect()),
        ScalarType::U16 => VoxelData::U16(
            values
                .iter()
                .map(|v| (v * 65535.0).round() as u16)
                .collect(),
        ),
    };
    Volume::new(dims, Vec3::ONE, data).unwrap()
}

fn random_levels(rng: &mut Rng, count: usize, absent: bool) -> Vec<Level> {
    (0..count)
        .map(|_| match rng.below(if absent { 7 } else { 6 }) {
            0..=2 => Level::Lo,
            3..=5 => Level::Hi,
            _ => Level::Absent,
        })
        .collect()
}

fn config(transition: Transition) -> MixedConfig {
    MixedConfig {
        brick_size: N,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 64 << 20,
        transition,
        max_levels: 0,
    }
}

#[test]
fn cache_contents_after_upload_and_fixup_match_the_reference() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x1234_5678_9abc_def1);
        for scalar in [ScalarType::U8, ScalarType::F32] {
            let dims = UVec3::new(3 * N + 2, 2 * N + 3, 2 * N);
            let volume = Arc::new(smooth_random_volume(&mut rng, dims, scalar));
            let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).unwrap();
            renderer
                .set_source(VolumeSource::Mixed {
                    volume: volume.clone(),
                    config: config(Transition::Smooth),
                })
                .unwrap();
            let count = BrickGrid::new(dims, N).unwrap().brick_count();
            for round in 0..4 {
                let levels = random_levels(&mut rng, count, true);
                renderer.set_levels(&levels).unwrap();
                let gpu = renderer.read_cache().unwrap();
                let cache = renderer.brick_cache().unwrap();
                let expected = ReferenceCache::build(
                    &volume,
                    DownsampleFilter::Mean2,
                    cache,
                    scalar,
                    Transition::Smooth,
                )
                .unwrap();
                // Compare the texels of resident bricks (free slots hold stale data by design).
                let geometry = cache.geometry();
                let mut compared = 0;
                for (brick, residency) in cache.residencies().iter().enumerate() {
                    let Some((origin, size)) = geometry.texel_box(*residency) else {
                        continue;
                    };
                    for z in origin.z..origin.z + size.z {
                        for y in origin.y..origin.y + size.y {
                            for x in origin.x..origin.x + size.x {
                                let e = geometry.extent();
                                let i = (x + e.x * (y + e.y * z)) as usize;
                                assert_eq!(
                                    gpu[i], expected.image.texels[i],
                                    "{scalar:?} round {round} brick {brick} texel ({x},{y},{z})"
                                );
                                compared += 1;
                            }
                        }
                    }
                }
                assert!(compared > 0);
            }
        }
    }
    common::finish(ctx);
}

/// The GPU field (probe) equals the CPU reference field, and is continuous where the reference is.
#[test]
fn gpu_field_matches_reference_and_is_continuous() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x0bad_cafe_0000_0001);
        let dims = UVec3::new(3 * N, 3 * N, 2 * N + 4);
        let volume = Arc::new(smooth_random_volume(&mut rng, dims, ScalarType::F32));
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).unwrap();
            renderer
                .set_source(VolumeSource::Mixed {
                    volume: volume.clone(),
                    config: config(transition),
                })
                .unwrap();
            // Largest jump across probe points at two step sizes: it must shrink with eps in
            // smooth mode (C0) and stay put in discontinuous mode.
            let mut max_jump = [0.0f32; 2];
            let eps_values = [1e-2f32, 1e-3];
            for _ in 0..3 {
                let levels = random_levels(&mut rng, count, false);
                renderer.set_levels(&levels).unwrap();
                let reference = ReferenceCache::build(
                    &volume,
                    DownsampleFilter::Mean2,
                    renderer.brick_cache().unwrap(),
                    ScalarType::F32,
                    transition,
                )
                .unwrap();
                let points = common::critical_points(&mut rng, N, dims, 4000);
                let gpu = renderer.probe_field(&points).unwrap();
                for (p, g) in points.iter().zip(&gpu) {
                    let cpu = sample_mixed(&reference.view(), *p, transition);
                    match (g, cpu) {
                        (Some(g), Some(c)) => {
                            assert!((g - c).abs() < 2e-3, "{transition:?} {p}: gpu {g} cpu {c}")
                        }
                        (g, c) => assert_eq!(g.is_some(), c.is_some(), "{p}: residency differs"),
                    }
                }
                let dirs = [
                    Vec3::X,
                    Vec3::Y,
                    Vec3::Z,
                    Vec3::ONE,
                    Vec3::new(1.0, -1.0, 1.0),
                ];
                for (k, eps) in eps_values.iter().enumerate() {
                    let mut probes = Vec::new();
                    for p in &points {
                        for d in dirs {
                            probes.push(*p + *eps * d);
                            probes.push(*p - *eps * d);
                        }
                    }
                    let values = renderer.probe_field(&probes).unwrap();
                    for pair in values.chunks_exact(2) {
                        if let (Some(a), Some(b)) = (pair[0], pair[1]) {
                            max_jump[k] = max_jump[k].max((a - b).abs());
                        }
                    }
                }
            }
            eprintln!(
                "{transition:?}: max jump {:?} at eps {eps_values:?}",
                max_jump
            );
            match transition {
                // Lipschitz bound 14 per voxel (tests/continuity.rs) over 2 * sqrt(3) * eps, plus
                // the GPU's sub-texel weight quantisation (1/256 voxel on real hardware, ~0.01).
                Transition::Smooth => {
                    assert!(
                        max_jump[0] < 14.0 * 3.5 * eps_values[0] + 0.01,
                        "smooth GPU field jumps: {max_jump:?}"
                    );
                    assert!(
                        max_jump[1] < 14.0 * 3.5 * eps_values[1] + 0.01,
                        "smooth GPU field jumps: {max_jump:?}"
                    );
                    assert!(
                        max_jump[1] < 0.5 * max_jump[0],
                        "smooth jumps must shrink with eps: {max_jump:?}"
                    );
                }
                Transition::Discontinuous => {
                    assert!(
                        max_jump[1] > 0.1 && max_jump[1] > 0.5 * max_jump[0],
                        "discontinuous GPU field should jump: {max_jump:?}"
                    );
                }
            }
        }
    }
    common::finish(ctx);
}

fn render_pair(
    ctx: &mixvol::gpu::GpuContext,
    volume: Arc<Volume>,
    levels: &[Level],
    transition: Transition,
    camera: &Camera,
) -> (
    Vec<glam::Vec4>,
    Vec<glam::Vec4>,
    mixvol::gpu::RaycastVariant,
) {
    let tf = TransferFunction::preset(TfPreset::Bands);
    let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap();
    renderer.set_transfer_function(&tf).unwrap();
    renderer
        .set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config: config(transition),
        })
        .unwrap();
    renderer.set_levels(levels).unwrap();
    let settings = RenderSettings {
        samples_per_voxel: 1.5,
        ..RenderSettings::default()
    };
    let frame = renderer.render(camera, &settings, 80, 80).unwrap();
    let params = renderer.params(camera, &settings, 80, 80).unwrap();
    let reference = ReferenceCache::build(
        &volume,
        DownsampleFilter::Mean2,
        renderer.brick_cache().unwrap(),
        volume.scalar_type(),
        transition,
    )
    .unwrap();
    let expected = reference::render_mixed(&reference.view(), transition, &tf, &params);
    (frame.pixels, expected, frame.variant)
}

#[test]
fn mixed_images_match_the_reference_and_all_hi_matches_single_resolution() {
    let ctx = common::validated_context();
    {
        let volume = Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::new(4 * N, 3 * N, 4 * N), ScalarType::F32)
                .unwrap(),
        );
        let count = BrickGrid::new(volume.dims(), N).unwrap().brick_count();
        let camera = Camera::perspective(Vec3::new(1.0, 0.8, 1.5), Vec3::ZERO, 40.0);
        let mut rng = Rng(0x77);
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            // With absent bricks, and with every brick resident (the variant without the jump).
            for absent in [true, false] {
                let levels = random_levels(&mut rng, count, absent);
                let (gpu, cpu, variant) =
                    render_pair(&ctx, volume.clone(), &levels, transition, &camera);
                assert_eq!(variant.smooth_transitions, transition == Transition::Smooth);
                assert_eq!(variant.absent_bricks, levels.contains(&Level::Absent));
                assert_eq!(variant.absent_bricks, absent);
                let d = common::diff(&gpu, &cpu, 1.0 / 255.0);
                assert!(
                    d.mean < 1e-3 && d.max < 6.0 / 255.0 && d.large_fraction < 0.005,
                    "{transition:?} absent {absent}: {d:?}"
                );
                // Not blank, and the same over the covered pixels alone (the mean above is
                // diluted by the background).
                let c = common::coverage(&gpu, &cpu, 1.0 / 255.0, 1.0 / 255.0);
                eprintln!("{transition:?} absent {absent}: {c:?}");
                assert!(
                    c.expected_visible >= COVERAGE_FLOOR && c.actual_visible >= COVERAGE_FLOOR,
                    "{transition:?} absent {absent}: image mostly empty: {c:?}"
                );
                assert!(
                    c.diff.mean < 1e-3 && c.diff.large_fraction < 0.01,
                    "{transition:?} absent {absent}: covered pixels differ: {c:?}"
                );
            }
        }
        // Every brick hi-res: the variant has no transition code and the image equals the
        // single-resolution renderer's.
        let all_hi = vec![Level::Hi; count];
        let (mixed, _, variant) =
            render_pair(&ctx, volume.clone(), &all_hi, Transition::Smooth, &camera);
        assert!(variant.mixed_resolution && !variant.smooth_transitions && !variant.absent_bricks);
        let tf = TransferFunction::preset(TfPreset::Bands);
        let mut single = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        single.set_transfer_function(&tf).unwrap();
        single.set_source(VolumeSource::Volume(&volume)).unwrap();
        let settings = RenderSettings {
            samples_per_voxel: 1.5,
            ..RenderSettings::default()
        };
        let frame = single.render(&camera, &settings, 80, 80).unwrap();
        assert!(!frame.variant.mixed_resolution);
        let d = common::diff(&mixed, &frame.pixels, 1.0 / 255.0);
        assert!(
            d.mean < 1e-4 && d.max < 2.0 / 255.0,
            "all-hi mixed vs single: {d:?}"
        );
        let c = common::coverage(&mixed, &frame.pixels, 1.0 / 255.0, 1.0 / 255.0);
        assert!(
            c.expected_visible >= COVERAGE_FLOOR && c.actual_visible >= COVERAGE_FLOOR,
            "all-hi mixed vs single: image mostly empty: {c:?}"
        );
        assert!(c.diff.mean < 1e-4, "all-hi mixed vs single, covered: {c:?}");
    }
    common::finish(ctx);
}

/// A hundred residency changes (small edits, and a full reshuffle every tenth step) under
/// validation; after every change the GPU field at 150 critical points (brick faces, texel
/// centres, random) equals the CPU reference of that cache state ([`U8_PROBE_TOLERANCE`];
/// residency exactly), and
/// every fifth state's frame equals the reference render of that state over its covered pixels
/// (RGBA8: reference tolerances plus half a quantisation step), with at least 15 % of the frame
/// visible. A stale or misplaced brick changes the field where it lies.
#[test]
fn a_hundred_residency_changes_stay_validation_clean() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0xdead_beef_0042);
        let volume = Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::splat(4 * N), ScalarType::U8)
                .unwrap(),
        );
        let count = BrickGrid::new(volume.dims(), N).unwrap().brick_count();
        let tf = TransferFunction::preset(TfPreset::Bands);
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).unwrap();
        renderer.set_transfer_function(&tf).unwrap();
        renderer
            .set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config: config(Transition::Smooth),
            })
            .unwrap();
        let camera = Camera::default_view();
        let settings = RenderSettings::default();
        let size = 24u32;
        let mut previous = random_levels(&mut rng, count, true);
        let mut compared_points = 0usize;
        let mut compared_frames = 0usize;
        for step in 0..100 {
            // Small changes most of the time, a full reshuffle now and then.
            let levels = if step % 10 == 0 {
                random_levels(&mut rng, count, true)
            } else {
                let mut l = previous.clone();
                for _ in 0..3 {
                    let i = rng.below(count as u32) as usize;
                    l[i] = [Level::Hi, Level::Lo, Level::Absent][rng.below(3) as usize];
                }
                l
            };
            let report = renderer.set_levels(&levels).unwrap();
            assert_eq!(
                report.hi_bricks,
                levels.iter().filter(|l| **l == Level::Hi).count()
            );
            let frame = renderer.render(&camera, &settings, size, size).unwrap();
            assert!(frame.pixels.iter().all(|p| p.is_finite()));
            let reference = ReferenceCache::build(
                &volume,
                DownsampleFilter::Mean2,
                renderer.brick_cache().unwrap(),
                ScalarType::U8,
                Transition::Smooth,
            )
            .unwrap();
            let points = common::critical_points(&mut rng, N, volume.dims(), 150);
            let gpu = renderer.probe_field(&points).unwrap();
            for (p, g) in points.iter().zip(&gpu) {
                let cpu = sample_mixed(&reference.view(), *p, Transition::Smooth);
                match (g, cpu) {
                    (Some(g), Some(c)) => {
                        assert!(
                            (g - c).abs() < U8_PROBE_TOLERANCE,
                            "step {step} {p}: gpu field {g}, reference {c}"
                        );
                        compared_points += 1;
                    }
                    (g, c) => assert_eq!(
                        g.is_some(),
                        c.is_some(),
                        "step {step} {p}: residency differs (gpu {g:?}, reference {c:?})"
                    ),
                }
            }
            if step % 5 == 4 {
                let params = renderer.params(&camera, &settings, size, size).unwrap();
                let expected =
                    reference::render_mixed(&reference.view(), Transition::Smooth, &tf, &params);
                let c = common::coverage(&frame.pixels, &expected, 1.0 / 255.0, 1.5 / 255.0);
                assert!(
                    c.expected_visible >= 0.15 && c.actual_visible >= 0.15,
                    "step {step}: frame mostly empty: {c:?}"
                );
                assert!(
                    c.diff.mean < 1.5e-3 + 0.5 / 255.0
                        && c.diff.max < 6.5 / 255.0
                        && c.diff.large_fraction < 0.01,
                    "step {step}: frame differs from the reference of its cache state: {c:?}"
                );
                compared_frames += 1;
            }
            previous = levels;
        }
        assert!(
            compared_points > 5000,
            "few resident points: {compared_points}"
        );
        assert_eq!(compared_frames, 20);
    }
    common::finish(ctx);
}

/// Half the world-space box of [`anisotropic_volume`]: spacing 0.5, 1, 2 (x, y, z).
const ANISO_HALF: Vec3 = Vec3::new(0.125, 0.25, 0.5);

/// Marschner-Lobb on 32^3 voxels with spacing 0.5 x 1 x 2 (index and world space differ).
fn anisotropic_volume() -> Arc<Volume> {
    let ml = SyntheticField::MarschnerLobb
        .generate(UVec3::splat(4 * N), ScalarType::F32)
        .unwrap();
    Arc::new(Volume::new(ml.dims(), Vec3::new(0.5, 1.0, 2.0), ml.data().clone()).unwrap())
}

/// Two world-space clip planes on [`anisotropic_volume`]: an oblique one through the bricks
/// (keeps x + 0.3 y >= -0.02; culls the bricks of the lowest x slab with y <= 0) and one that
/// keeps z <= 0.2 (cuts the third z slab of bricks, culls the fourth).
fn aniso_clip_planes() -> ClipPlanes {
    ClipPlanes::new(&[
        ClipPlane::new(Vec3::new(1.0, 0.3, 0.0), 0.02),
        ClipPlane::new(Vec3::new(0.0, 0.0, -1.0), 0.2),
    ])
    .unwrap()
}

/// The clipped scenes: plain DVR and shaded DVR (gradients next to the cut).
fn clipped_scenes() -> [(&'static str, RenderSettings); 2] {
    let base = RenderSettings {
        samples_per_voxel: 1.5,
        clip_planes: aniso_clip_planes(),
        ..RenderSettings::default()
    };
    [
        ("clip", base),
        (
            "clip-shaded",
            RenderSettings {
                shading: Some(Shading {
                    ambient: 0.2,
                    diffuse: 0.6,
                    specular: 0.4,
                    shininess: 12.0,
                }),
                ..base
            },
        ),
    ]
}

/// `frame` against the reference of `renderer`'s residency drawn with every feature of
/// `settings` (clip planes included), with the standard GPU-vs-reference tolerances.
fn check_clipped(
    name: &str,
    renderer: &Renderer,
    volume: &Volume,
    transition: Transition,
    camera: &Camera,
    settings: &RenderSettings,
    frame: &mixvol::renderer::Frame,
) {
    const SIZE: u32 = 48;
    let tf = TransferFunction::preset(TfPreset::Bands);
    let cache = ReferenceCache::build(
        volume,
        DownsampleFilter::Mean2,
        renderer.brick_cache().unwrap(),
        volume.scalar_type(),
        transition,
    )
    .unwrap();
    let params = renderer.params(camera, settings, SIZE, SIZE).unwrap();
    let expected =
        reference::render_mixed_scene(&cache.view(), transition, &tf, settings, &params).unwrap();
    let d = common::diff(&frame.pixels, &expected, 1.0 / 255.0);
    let c = common::coverage(&frame.pixels, &expected, 1.0 / 255.0, 1.0 / 255.0);
    eprintln!("{name}: {d:?} {c:?}");
    if !(d.mean <= 1e-3 && d.large_fraction <= 0.005 && d.max <= 6.0 / 255.0) {
        let dir = common::write_failure_images(name, SIZE, SIZE, &frame.pixels, &expected);
        panic!(
            "{name}: GPU differs from the CPU reference: {d:?} (images in {})",
            dir.display()
        );
    }
    assert!(
        c.expected_visible >= 0.1,
        "{name}: image mostly empty: {c:?}"
    );
    if settings.shading.is_none() {
        // The default program (`render_mixed`, no settings) cuts the rays by the planes the
        // params hold, as the GPU does: the same image as the program of the settings.
        let default = reference::render_mixed(&cache.view(), transition, &tf, &params);
        let e = common::diff(&default, &expected, 1.0 / 255.0);
        assert!(e.max <= 1e-6, "{name}: default program vs settings: {e:?}");
        // The planes matter: without them the reference draws another image.
        let mut unclipped_params = params;
        unclipped_params.iso_colour.w = 0.0;
        let unclipped = reference::render_mixed(&cache.view(), transition, &tf, &unclipped_params);
        let u = common::diff(&frame.pixels, &unclipped, 1.0 / 255.0);
        eprintln!("{name}: against the reference without the planes: {u:?}");
        assert!(
            u.max > 0.1 && u.mean > 1e-3,
            "{name}: the planes change nothing: {u:?}"
        );
    }
}

/// Clip planes with the brick cache on anisotropic voxels, mixed levels (hi, lo and absent),
/// both transitions: one plane cuts through bricks, the bricks it and the other plane remove
/// entirely are absent (as the planner's culling makes them), and the GPU image equals the CPU
/// reference drawn with the same planes.
#[test]
fn clip_planes_with_mixed_levels_match_the_reference() {
    const SIZE: u32 = 48;
    let ctx = common::validated_context();
    {
        let volume = anisotropic_volume();
        let grid = BrickGrid::new(volume.dims(), N).unwrap();
        let geometry = mixvol::lod::BrickGeometry::new(grid, volume.spacing()).unwrap();
        let mut rng = Rng(0xc11f);
        let mut levels = random_levels(&mut rng, grid.brick_count(), true);
        let clip = aniso_clip_planes();
        let mut culled = 0;
        let per_axis = grid.bricks_per_axis();
        for z in 0..per_axis.z {
            for y in 0..per_axis.y {
                for x in 0..per_axis.x {
                    let brick = UVec3::new(x, y, z);
                    let (min, max) = geometry.brick_box(brick);
                    if clip.box_clipped(min, max) {
                        levels[grid.linear_index(brick)] = Level::Absent;
                        culled += 1;
                    }
                }
            }
        }
        assert!(culled >= 8, "{culled} bricks culled");
        let camera = Camera::perspective(Vec3::new(0.9, 0.7, 1.4), Vec3::ZERO, 40.0);
        let tf = TransferFunction::preset(TfPreset::Bands);
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            renderer.set_transfer_function(&tf).unwrap();
            renderer
                .set_source(VolumeSource::Mixed {
                    volume: volume.clone(),
                    config: config(transition),
                })
                .unwrap();
            renderer.set_levels(&levels).unwrap();
            for (name, settings) in clipped_scenes() {
                let frame = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
                assert!(frame.variant.features.clip_planes && frame.variant.absent_bricks);
                check_clipped(
                    &format!("{name}-{transition:?}"),
                    &renderer,
                    &volume,
                    transition,
                    &camera,
                    &settings,
                    &frame,
                );
            }
        }
    }
    common::finish(ctx);
}

/// The same through the planner (camera-driven levels, bricks culled by the clip planes) over an
/// in-memory [`VolumeBrickSource`]: every frame until it settles equals the CPU reference of its
/// residency drawn with the planes, and the planes cull bricks.
#[test]
fn clip_planes_through_the_planner_match_the_reference() {
    const SIZE: u32 = 48;
    let ctx = common::validated_context();
    {
        let volume = anisotropic_volume();
        let tf = TransferFunction::preset(TfPreset::Bands);
        let camera = Camera::perspective(Vec3::new(0.7, 0.8, 1.4), 0.3 * ANISO_HALF, 30.0);
        for (name, settings) in clipped_scenes() {
            let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            renderer.set_transfer_function(&tf).unwrap();
            renderer
                .set_source(VolumeSource::Bricks {
                    source: Arc::new(
                        VolumeBrickSource::new(volume.clone(), N, DownsampleFilter::Mean2).unwrap(),
                    ),
                    // Room for 24 of the 64 bricks hi-res ((8 + 2)^3 f32 texels each): the
                    // planner draws the far bricks low-res.
                    config: MixedConfig {
                        cache_budget_bytes: 24 * 4000,
                        ..config(Transition::Smooth)
                    },
                })
                .unwrap();
            assert!(renderer.is_planned());
            let unclipped = RenderSettings {
                clip_planes: ClipPlanes::NONE,
                ..settings
            };
            renderer.render(&camera, &unclipped, SIZE, SIZE).unwrap();
            let culled_unclipped = renderer.last_plan().unwrap().report.culled;
            let mut levels_seen = (false, false);
            for f in 0..4 {
                let frame = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
                let plan = renderer.last_plan().unwrap();
                assert!(
                    plan.report.culled >= culled_unclipped + 8,
                    "{name}: {} culled with the planes, {culled_unclipped} without",
                    plan.report.culled
                );
                let levels = renderer.brick_cache().unwrap().levels();
                levels_seen.0 |= levels.contains(&Level::Hi);
                levels_seen.1 |= levels.contains(&Level::Lo);
                check_clipped(
                    &format!("{name}-planned-{f}"),
                    &renderer,
                    &volume,
                    Transition::Smooth,
                    &camera,
                    &settings,
                    &frame,
                );
            }
            assert!(levels_seen.0 && levels_seen.1, "{name}: {levels_seen:?}");
        }
    }
    common::finish(ctx);
}
