//! Pre-classified RGBA volumes with opacity-based and extinction-based sampling (Kraus et al.):
//! the GPU against the CPU reference, the homogeneous slab analytically, and the paper's
//! one-voxel-thick opaque wall rendered on the GPU: extinction-based sampling keeps it opaque at
//! sampling distances where opacity-based sampling lets light through.

mod common;

use glam::{UVec3, Vec3, Vec4};
use mixvol::optics::SamplingModel;
use mixvol::reference;
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderMode, RenderSettings};
use mixvol::volume::{marschner_lobb_value, RgbaVolume};
use std::sync::Arc;

const SIZE: u32 = 64;

fn rgba_volume(dims: UVec3, f: impl Fn(Vec3) -> Vec4) -> Arc<RgbaVolume> {
    let mut voxels = Vec::new();
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                voxels.push(f(Vec3::new(x as f32, y as f32, z as f32) + 0.5));
            }
        }
    }
    Arc::new(RgbaVolume::new(dims, Vec3::ONE, voxels).unwrap())
}

fn settings(model: SamplingModel, samples_per_voxel: f32) -> RenderSettings {
    RenderSettings {
        sampling_model: model,
        samples_per_voxel,
        early_termination: 1.0,
        ..RenderSettings::default()
    }
}

#[test]
fn rgba_volumes_match_the_reference_in_both_models() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(20, 24, 16);
        let volume = rgba_volume(dims, |p| {
            let q = p / dims.as_vec3();
            let v = marschner_lobb_value(q * 2.0 - Vec3::ONE);
            // Colour varies with position, opacity with the field: interpolation matters.
            Vec4::new(
                q.x,
                1.0 - q.y,
                0.5 + 0.5 * q.z,
                (v * v * 0.6).clamp(0.0, 1.0),
            )
        });
        let camera = Camera::perspective(Vec3::new(1.0, 0.8, 1.4), Vec3::ZERO, 40.0);
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer
            .set_source(VolumeSource::Rgba(volume.clone()))
            .unwrap();
        let mut images = Vec::new();
        // Opacity, extinction, and opacity again: the texture is refilled when the model changes.
        for model in [
            SamplingModel::Opacity,
            SamplingModel::Extinction,
            SamplingModel::Opacity,
        ] {
            let s = settings(model, 1.3);
            let frame = renderer.render(&camera, &s, SIZE, SIZE).unwrap();
            assert!(frame.variant.rgba_volume);
            let params = renderer.params(&camera, &s, SIZE, SIZE).unwrap();
            let expected = reference::render_rgba(&volume, &s, &params);
            assert!(expected.iter().filter(|p| p.w > 0.05).count() > 1000);
            let d = common::diff(&frame.pixels, &expected, 1.0 / 255.0);
            assert!(
                d.mean <= 1e-3 && d.large_fraction <= 0.005 && d.max <= 6.0 / 255.0,
                "{model:?}: {d:?}"
            );
            eprintln!("{model:?}: {d:?}");
            images.push(frame.pixels);
        }
        let change = images[0]
            .iter()
            .zip(&images[1])
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(
            change > 3e-3,
            "the models must differ on this volume ({change}, measured 9e-3)"
        );
        assert_eq!(
            images[0], images[2],
            "switching back reproduces the first image"
        );

        // Scalar-only effects are refused with an error, not drawn wrongly.
        let iso = RenderSettings {
            mode: RenderMode::Iso {
                value: 0.5,
                colour: Vec3::ONE,
            },
            ..RenderSettings::default()
        };
        assert!(renderer.render(&camera, &iso, SIZE, SIZE).is_err());
    }
    common::finish(ctx);
}

/// A homogeneous RGBA slab is 1 - exp(-tau L) in both models and at every step size.
#[test]
fn homogeneous_rgba_slab_is_one_minus_exp() {
    let ctx = common::validated_context();
    {
        let volume = rgba_volume(UVec3::new(8, 8, 30), |_| Vec4::new(0.2, 0.6, 1.0, 0.08));
        let camera = Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 0.2);
        let expected = 1.0 - 0.92f64.powf(30.0);
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer.set_source(VolumeSource::Rgba(volume)).unwrap();
        for model in [SamplingModel::Extinction, SamplingModel::Opacity] {
            for spv in [0.35f32, 1.0, 1.7, 3.0] {
                let frame = renderer
                    .render(&camera, &settings(model, spv), SIZE, SIZE)
                    .unwrap();
                let centre = frame.pixels[(SIZE / 2 * SIZE + SIZE / 2) as usize];
                assert!(
                    (f64::from(centre.w) - expected).abs() < 2e-5,
                    "{model:?} {spv}: {} vs {expected}",
                    centre.w
                );
                let colour = centre.truncate() / centre.w;
                assert!((colour - Vec3::new(0.2, 0.6, 1.0)).abs().max_element() < 1e-4);
            }
        }
    }
    common::finish(ctx);
}

/// Kraus et al.'s one-voxel-thick opaque wall on the GPU: rays perpendicular to the wall at
/// sampling distances 0.6 to 1.6 voxels and five sampling phases each. Extinction-based
/// sampling keeps the wall opaque (measured minimum alpha 1.0); opacity-based sampling
/// lets light through (measured minimum 0.53 over these distances and phases; e.g. 0.75 at
/// d = 1 with two samples straddling the
/// wall at +-d/2, each of opacity 1 - (d/2)^d). Both agree with the CPU reference.
#[test]
fn the_opaque_wall_stays_opaque_only_with_extinction_based_sampling() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(17, 4, 4);
        let volume = rgba_volume(dims, |p| {
            if (p.x - 8.5).abs() < 0.1 {
                Vec4::new(1.0, 1.0, 1.0, 1.0)
            } else {
                Vec4::ZERO
            }
        });
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer
            .set_source(VolumeSource::Rgba(volume.clone()))
            .unwrap();
        let voxel = 1.0 / 17.0;
        let mut worst = [1.0f32; 2];
        for (m, model) in [SamplingModel::Extinction, SamplingModel::Opacity]
            .into_iter()
            .enumerate()
        {
            for d in [0.6f32, 0.8, 1.0, 1.25, 1.6] {
                for phase in 0..5 {
                    // The near plane cuts into the box: the first sample starts there.
                    let camera = Camera {
                        near: 2.0 - 0.5 + (1.0 + phase as f32 * 0.2 * d) * voxel,
                        up: Vec3::Y,
                        ..Camera::orthographic(Vec3::new(-2.0, 0.0, 0.0), Vec3::ZERO, 0.1)
                    };
                    let s = settings(model, 1.0 / d);
                    let frame = renderer.render(&camera, &s, 8, 8).unwrap();
                    let params = renderer.params(&camera, &s, 8, 8).unwrap();
                    let expected = reference::render_rgba(&volume, &s, &params);
                    let d_cpu = common::diff(&frame.pixels, &expected, 1e-4);
                    assert!(d_cpu.max < 1e-4, "{model:?} d={d}: GPU vs CPU {d_cpu:?}");
                    let alpha = frame.pixels[4 * 8 + 4].w;
                    worst[m] = worst[m].min(alpha);
                }
            }
        }
        eprintln!(
            "wall: minimum alpha extinction {} opacity {}",
            worst[0], worst[1]
        );
        assert!(worst[0] > 0.999, "extinction-based: {}", worst[0]);
        assert!(worst[1] < 0.8, "opacity-based: {}", worst[1]);
    }
    common::finish(ctx);
}

/// Pre-classified RGBA volumes through the brick cache (RGBA32F cache image, fixup and smooth
/// blend on all four channels): the GPU matches the CPU reference (built as four scalar caches,
/// the construction being linear in the texels) in both sampling models and both transition
/// modes, with absent bricks; with every brick hi-res the image equals the plain RGBA texture's;
/// a frame asking for another sampling model than the cache holds is an error.
#[test]
fn rgba_volumes_through_the_brick_cache_match_the_reference() {
    use common::Rng;
    use mixvol::bricks::{BrickGrid, DownsampleFilter, Level, RgbaBrickSource};
    use mixvol::reference::ReferenceCache;
    use mixvol::renderer::MixedConfig;
    use mixvol::scene::Transition;
    use mixvol::volume::ScalarType;

    const N: u32 = 8;
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(4 * N, 3 * N, 4 * N);
        let volume = rgba_volume(dims, |p| {
            let q = p / dims.as_vec3();
            let v = marschner_lobb_value(q * 2.0 - Vec3::ONE);
            Vec4::new(
                q.x,
                1.0 - q.y,
                0.5 + 0.5 * q.z,
                (v * v * 0.6).clamp(0.0, 1.0),
            )
        });
        let camera = Camera::perspective(Vec3::new(1.0, 0.8, 1.4), Vec3::ZERO, 40.0);
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        let mut rng = Rng(0xc0ffee);
        let config = |transition| MixedConfig {
            brick_size: N,
            filter: DownsampleFilter::Mean2,
            cache_budget_bytes: 64 << 20,
            transition,
            max_levels: 0,
        };
        for model in [SamplingModel::Opacity, SamplingModel::Extinction] {
            let channels = RgbaBrickSource::channel_volumes(&volume, model).unwrap();
            for transition in [Transition::Smooth, Transition::Discontinuous] {
                let levels: Vec<Level> = (0..count)
                    .map(|_| match rng.below(9) {
                        0..=3 => Level::Lo,
                        4..=7 => Level::Hi,
                        _ => Level::Absent,
                    })
                    .collect();
                let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
                renderer
                    .set_source(VolumeSource::RgbaMixed {
                        volume: &volume,
                        model,
                        config: config(transition),
                    })
                    .unwrap();
                renderer.set_levels(&levels).unwrap();
                let s = settings(model, 1.4);
                let frame = renderer.render(&camera, &s, SIZE, SIZE).unwrap();
                assert!(frame.variant.rgba_volume && frame.variant.mixed_resolution);
                assert_eq!(
                    frame.variant.smooth_transitions,
                    transition == Transition::Smooth
                );
                let params = renderer.params(&camera, &s, SIZE, SIZE).unwrap();
                let caches = channels.each_ref().map(|c| {
                    ReferenceCache::build(
                        c,
                        DownsampleFilter::Mean2,
                        renderer.brick_cache().unwrap(),
                        ScalarType::F32,
                        transition,
                    )
                    .unwrap()
                });
                let views = caches.each_ref().map(|c| c.view());
                let expected = reference::render_rgba_mixed(&views, transition, &s, &params);
                assert!(expected.iter().filter(|p| p.w > 0.05).count() > 500);
                let d = common::diff(&frame.pixels, &expected, 1.0 / 255.0);
                assert!(
                    d.mean <= 1e-3 && d.large_fraction <= 0.005 && d.max <= 6.0 / 255.0,
                    "{model:?} {transition:?}: {d:?}"
                );
                eprintln!("{model:?} {transition:?}: {d:?}");
                let other = settings(
                    match model {
                        SamplingModel::Opacity => SamplingModel::Extinction,
                        SamplingModel::Extinction => SamplingModel::Opacity,
                    },
                    1.4,
                );
                assert!(renderer.render(&camera, &other, SIZE, SIZE).is_err());
            }
            // Every brick hi-res: the plain RGBA texture's image.
            let mut cached = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            cached
                .set_source(VolumeSource::RgbaMixed {
                    volume: &volume,
                    model,
                    config: config(Transition::Smooth),
                })
                .unwrap();
            cached.set_levels(&vec![Level::Hi; count]).unwrap();
            let s = settings(model, 1.4);
            let a = cached.render(&camera, &s, SIZE, SIZE).unwrap().pixels;
            let mut plain = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            plain
                .set_source(VolumeSource::Rgba(volume.clone()))
                .unwrap();
            let b = plain.render(&camera, &s, SIZE, SIZE).unwrap().pixels;
            let d = common::diff(&a, &b, 1.0 / 255.0);
            assert!(
                d.mean < 1e-4 && d.max < 2.0 / 255.0,
                "{model:?} all hi: {d:?}"
            );
        }
    }
    common::finish(ctx);
}
