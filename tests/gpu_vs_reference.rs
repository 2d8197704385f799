//! The GPU ray-caster against the CPU reference on several cameras and scalar types.
//!
//! Tolerance, and why: both sides run the same arithmetic on the same parameter block, so the only
//! systematic difference is texture filtering. Vulkan hardware (and lavapipe) quantises trilinear
//! and 1D-TF filter weights to `subTexelPrecisionBits` (8 on lavapipe and current GPUs), so one
//! sample can differ by up to |v1 - v0| / 512 per axis, and FMA contraction changes the last bits
//! of the compositing sums. These errors average out along a ray: we require a mean absolute
//! difference below 1/1000, at most 0.5 % of channels above 1/255, and no channel above 6/255
//! (a ray grazing a sharp feature can cross a TF edge one sample earlier or later). Comparisons
//! use an RGBA32F target so 8-bit quantisation of the output does not hide differences.
//!
//! 8-bit volumes: lavapipe filters R8_UNORM textures in 8-bit fixed point, so the filtered value
//! itself is rounded to a multiple of 1/255 (measured: u16 and f32 volumes agree with the reference
//! to 1e-5, u8 volumes with a steep TF to 3/255 with about 2 % of channels above 1/255). The u8
//! test therefore uses the gentle grey ramp, under which the same bounds hold; the steep TF is
//! exercised on u16 and f32 volumes.

mod common;

use glam::{UVec3, Vec3};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference;
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, Projection, RenderSettings};
use mixvol::volume::{ScalarType, SyntheticField, Volume};

const SIZE: u32 = 96;
const MEAN_TOLERANCE: f32 = 1.0 / 1000.0;
const LARGE: f32 = 1.0 / 255.0;
const LARGE_FRACTION_TOLERANCE: f32 = 0.005;
const MAX_TOLERANCE: f32 = 6.0 / 255.0;

fn compare(
    name: &str,
    volume: &Volume,
    tf: TfPreset,
    cameras: &[(&str, Camera)],
    settings: RenderSettings,
) {
    let ctx = common::validated_context();
    {
        let tf = TransferFunction::preset(tf);
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer.set_source(VolumeSource::Volume(volume)).unwrap();
        renderer.set_transfer_function(&tf).unwrap();
        for (camera_name, camera) in cameras {
            let frame = renderer.render(camera, &settings, SIZE, SIZE).unwrap();
            let params = renderer.params(camera, &settings, SIZE, SIZE).unwrap();
            let expected = reference::render(volume, &tf, &params);
            let visible = expected.iter().filter(|p| p.w > 0.05).count();
            assert!(
                visible > (SIZE * SIZE / 20) as usize,
                "{name}/{camera_name}: the scene must cover part of the image ({visible} pixels)"
            );
            let d = common::diff(&frame.pixels, &expected, LARGE);
            let ok = d.mean <= MEAN_TOLERANCE
                && d.large_fraction <= LARGE_FRACTION_TOLERANCE
                && d.max <= MAX_TOLERANCE;
            if !ok {
                let dir = common::write_failure_images(
                    &format!("{name}-{camera_name}"),
                    SIZE,
                    SIZE,
                    &frame.pixels,
                    &expected,
                );
                panic!("{name}/{camera_name}: GPU differs from the CPU reference: {d:?} (images in {})", dir.display());
            }
            eprintln!("{name}/{camera_name}: {d:?}");
        }
    }
    common::finish(ctx);
}

fn cameras() -> Vec<(&'static str, Camera)> {
    let ortho_z = Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.2);
    let ortho_x = Camera {
        up: Vec3::Z,
        ..Camera::orthographic(Vec3::new(-2.0, 0.0, 0.0), Vec3::ZERO, 1.1)
    };
    vec![
        (
            "perspective-outside",
            Camera::perspective(Vec3::new(1.1, 0.7, 1.5), Vec3::ZERO, 40.0),
        ),
        // Every ray exactly parallel to the z axis (two direction components are exactly zero).
        ("orthographic-axis-z", ortho_z),
        ("orthographic-axis-x", ortho_x),
        (
            "orthographic-oblique",
            Camera::orthographic(Vec3::new(1.5, -1.0, 1.2), Vec3::ZERO, 1.6),
        ),
        // Eye inside the volume box: rays start at the eye.
        (
            "perspective-inside",
            Camera::perspective(Vec3::new(0.1, 0.05, 0.2), Vec3::new(0.0, 0.0, -1.0), 70.0),
        ),
        // Near plane cutting the volume.
        (
            "perspective-near-clip",
            Camera {
                near: 1.9,
                ..Camera::perspective(Vec3::new(0.0, 0.3, 2.2), Vec3::ZERO, 40.0)
            },
        ),
    ]
}

#[test]
fn marschner_lobb_u8_matches_reference_on_all_cameras() {
    let volume = SyntheticField::MarschnerLobb
        .generate(UVec3::splat(48), ScalarType::U8)
        .unwrap();
    // The grey ramp keeps the TF slope small, so the 8-bit filtered values (see the module docs)
    // are not amplified; u16/f32 below use the steep `Bands` preset.
    compare(
        "ml-u8",
        &volume,
        TfPreset::Grey,
        &cameras(),
        RenderSettings::default(),
    );
}

#[test]
fn marschner_lobb_u16_and_f32_match_reference() {
    let camera = cameras();
    for scalar in [ScalarType::U16, ScalarType::F32] {
        let volume = SyntheticField::MarschnerLobb
            .generate(UVec3::new(40, 36, 44), scalar)
            .unwrap();
        compare(
            &format!("ml-{scalar:?}"),
            &volume,
            TfPreset::Bands,
            &camera,
            RenderSettings::default(),
        );
    }
}

#[test]
fn sphere_with_fine_steps_and_early_termination_matches_reference() {
    let volume = SyntheticField::Sphere
        .generate(UVec3::splat(40), ScalarType::U8)
        .unwrap();
    let settings = RenderSettings {
        samples_per_voxel: 2.5,
        early_termination: 0.9,
        ..RenderSettings::default()
    };
    let cams = [cameras()[0], cameras()[1]];
    compare("sphere", &volume, TfPreset::Grey, &cams, settings);
}

#[test]
fn anisotropic_spacing_matches_reference() {
    let ml = SyntheticField::MarschnerLobb
        .generate(UVec3::new(32, 32, 16), ScalarType::F32)
        .unwrap();
    let volume = Volume::new(ml.dims(), Vec3::new(1.0, 1.0, 2.0), ml.data().clone()).unwrap();
    let cams = [(
        "perspective-outside",
        Camera {
            projection: Projection::Perspective {
                fov_y_degrees: 45.0,
            },
            ..cameras()[0].1
        },
    )];
    compare(
        "anisotropic",
        &volume,
        TfPreset::Bands,
        &cams,
        RenderSettings::default(),
    );
}
