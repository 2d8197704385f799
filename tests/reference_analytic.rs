//! The CPU reference against analytic results: it is the oracle, so it is checked independently.

use glam::{UVec3, Vec2, Vec3, Vec4};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference::{cast_ray, generate_ray, sample_volume, Ray};
use mixvol::scene::{Camera, RaycastParams, RenderSettings};
use mixvol::volume::{marschner_lobb_value, ScalarType, SyntheticField, Volume, VoxelData};

fn constant_volume(dims: UVec3, value: f32) -> Volume {
    let n = (dims.x * dims.y * dims.z) as usize;
    Volume::new(dims, Vec3::ONE, VoxelData::F32(vec![value; n])).unwrap()
}

fn params_for(volume: &Volume, camera: &Camera, settings: &RenderSettings) -> RaycastParams {
    RaycastParams::new(volume, camera, settings, 64, 64).unwrap()
}

/// Emission-absorption through a homogeneous box: with per-voxel opacity a0 and path length L
/// (in voxels), opacity is 1 - (1 - a0)^L for every step size, including a last partial step.
#[test]
fn homogeneous_slab_matches_the_closed_form_for_any_step() {
    let dims = UVec3::new(20, 20, 20);
    let volume = constant_volume(dims, 0.5);
    let tf = TransferFunction::preset(TfPreset::ConstantWhite); // alpha 0.1 per voxel, white
    let a0 = 0.1f32;
    let camera = Camera::orthographic(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 1.0);
    for spv in [0.37f32, 1.0, 1.7, 4.0, 9.5] {
        let settings = RenderSettings {
            samples_per_voxel: spv,
            early_termination: 2.0, // never stops early
            value_window: Some((0.0, 1.0)),
            ..RenderSettings::default()
        };
        let p = params_for(&volume, &camera, &settings);
        // Axis-parallel ray along -z through the box: 20 voxels of path.
        let ray = Ray {
            origin: Vec3::new(0.013, -0.2, 3.0),
            dir: -Vec3::Z,
        };
        let acc = cast_ray(&volume, &tf, &p, &ray);
        let expected = 1.0 - (1.0 - a0).powf(20.0);
        assert!(
            (acc.w - expected).abs() < 2e-5,
            "spv {spv}: alpha {} vs {expected}",
            acc.w
        );
        // White emission: premultiplied colour equals opacity.
        assert!((acc.truncate() - Vec3::splat(acc.w)).abs().max_element() < 1e-5);
        // An oblique ray: path length from the slab geometry.
        let dir = Vec3::new(0.3, 0.2, -1.0).normalize();
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, 0.5) - dir * 2.0,
            dir,
        };
        // Enters through z = +0.5 at (0,0,0.5) ... exits through z = -0.5 (x, y stay inside).
        let path_world = 1.0 / dir.z.abs();
        let expected = 1.0 - (1.0 - a0).powf(path_world * 20.0);
        let acc = cast_ray(&volume, &tf, &p, &ray);
        assert!(
            (acc.w - expected).abs() < 5e-5,
            "spv {spv} oblique: {} vs {expected}",
            acc.w
        );
    }
}

/// Early termination stops exactly once the stated threshold is reached.
#[test]
fn early_termination_stops_at_the_threshold() {
    let volume = constant_volume(UVec3::splat(64), 0.5);
    let tf = TransferFunction::preset(TfPreset::ConstantWhite);
    let camera = Camera::orthographic(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 1.0);
    for threshold in [0.5f32, 0.9, 0.99] {
        let settings = RenderSettings {
            early_termination: threshold,
            ..RenderSettings::default()
        };
        let p = params_for(&volume, &camera, &settings);
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, 3.0),
            dir: -Vec3::Z,
        };
        let acc = cast_ray(&volume, &tf, &p, &ray);
        // One more voxel of alpha 0.1 adds at most 0.1 * (1 - threshold).
        assert!(
            acc.w >= threshold && acc.w < threshold + 0.1 * (1.0 - threshold) + 1e-6,
            "{threshold}: {}",
            acc.w
        );
    }
}

/// A solid ball: opacity along the central ray follows the chord length 2r within the
/// half-voxel blur of trilinear reconstruction at each side.
#[test]
fn sphere_chord_length_gives_the_expected_opacity() {
    let n = 64u32;
    let volume = SyntheticField::Sphere
        .generate(UVec3::splat(n), ScalarType::U8)
        .unwrap();
    // Opaque where the value exceeds 0.5: a sharp step in the TF at the iso-value 0.5.
    let mut entries = vec![Vec4::ZERO; mixvol::optics::TF_SIZE];
    for (i, e) in entries.iter_mut().enumerate() {
        if i >= mixvol::optics::TF_SIZE / 2 {
            *e = Vec4::new(1.0, 1.0, 1.0, 0.05);
        }
    }
    let tf = TransferFunction::from_entries(entries).unwrap();
    let camera = Camera::orthographic(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 1.0);
    let settings = RenderSettings {
        samples_per_voxel: 8.0,
        early_termination: 2.0,
        ..RenderSettings::default()
    };
    let p = params_for(&volume, &camera, &settings);
    let radius_voxels = 0.8 * n as f32 / 2.0;
    for offset_voxels in [0.0f32, 10.0, 20.0] {
        let x = offset_voxels / n as f32;
        let ray = Ray {
            origin: Vec3::new(x, 0.0, 3.0),
            dir: -Vec3::Z,
        };
        let chord = 2.0 * (radius_voxels * radius_voxels - offset_voxels * offset_voxels).sqrt();
        let alpha = cast_ray(&volume, &tf, &p, &ray).w;
        let opacity_for = |len: f32| 1.0 - 0.95f32.powf(len);
        // Voxelisation and the 0.5 iso-crossing move each end by at most one voxel.
        assert!(
            alpha >= opacity_for(chord - 2.0) && alpha <= opacity_for(chord + 2.0),
            "offset {offset_voxels}: alpha {alpha}, chord {chord}"
        );
    }
}

/// Trilinear reconstruction: exact at voxel centres, exact for linear fields, and close to the
/// analytic Marschner-Lobb signal at a resolution that resolves it.
#[test]
fn sampling_is_exact_for_linear_fields_and_close_to_marschner_lobb() {
    let dims = UVec3::new(9, 7, 5);
    let f = |p: Vec3| 0.01 * p.x + 0.02 * p.y + 0.05 * p.z + 0.1;
    let mut data = Vec::new();
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                data.push(f(Vec3::new(x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5)));
            }
        }
    }
    let volume = Volume::new(dims, Vec3::ONE, VoxelData::F32(data)).unwrap();
    let mut state = 12345u32;
    let mut rnd = || {
        state = state.wrapping_mul(1664525).wrapping_add(1013904223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    for _ in 0..500 {
        // Inside the voxel-centre hull, where clamping does not apply.
        let voxel = Vec3::new(0.5 + rnd() * 8.0, 0.5 + rnd() * 6.0, 0.5 + rnd() * 4.0);
        let v = sample_volume(&volume, voxel / dims.as_vec3());
        assert!((v - f(voxel)).abs() < 1e-5, "{voxel}: {v} vs {}", f(voxel));
    }
    // Marschner-Lobb at 128^3 (f32): trilinear error is bounded by h^2/8 * max|f''|, about 0.03.
    let ml = SyntheticField::MarschnerLobb
        .generate(UVec3::splat(128), ScalarType::F32)
        .unwrap();
    let mut worst = 0.0f32;
    for _ in 0..2000 {
        let tex = Vec3::new(0.05 + 0.9 * rnd(), 0.05 + 0.9 * rnd(), 0.05 + 0.9 * rnd());
        let err = (sample_volume(&ml, tex) - marschner_lobb_value(tex * 2.0 - Vec3::ONE)).abs();
        worst = worst.max(err);
    }
    assert!(worst < 0.03, "worst trilinear error {worst}");
}

/// Pixel rays: the centre pixel looks at the target; orthographic rays are parallel.
#[test]
fn generated_rays_follow_the_camera() {
    let volume = constant_volume(UVec3::splat(4), 0.0);
    let eye = Vec3::new(1.0, 2.0, 3.0);
    let persp = Camera::perspective(eye, Vec3::ZERO, 60.0);
    let p = RaycastParams::new(&volume, &persp, &RenderSettings::default(), 65, 33).unwrap();
    let centre = generate_ray(&p, Vec2::new(32.5, 16.5));
    assert!((centre.dir - (-eye).normalize()).length() < 1e-5);
    assert_eq!(centre.origin, eye);
    let ortho = Camera::orthographic(eye, Vec3::ZERO, 2.0);
    let p = RaycastParams::new(&volume, &ortho, &RenderSettings::default(), 64, 64).unwrap();
    let a = generate_ray(&p, Vec2::new(0.5, 0.5));
    let b = generate_ray(&p, Vec2::new(63.5, 40.5));
    assert_eq!(a.dir, b.dir);
    assert!(
        ((a.origin - b.origin).dot(a.dir)).abs() < 1e-5,
        "origins lie in the image plane"
    );
}

/// No ray is cut short, however fine the step: at 1000 samples per voxel a ray through 20
/// voxels takes 20 000 samples, more than the old fixed cap of 16 384 (which stopped it after
/// 16.4 voxels: alpha 0.822 instead of 0.878).
#[test]
fn very_fine_steps_still_reach_the_far_side_of_the_volume() {
    let dims = UVec3::new(20, 20, 20);
    let volume = constant_volume(dims, 0.5);
    let tf = TransferFunction::preset(TfPreset::ConstantWhite); // alpha 0.1 per voxel
    let camera = Camera::orthographic(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 1.0);
    let settings = RenderSettings {
        samples_per_voxel: 1000.0,
        early_termination: 2.0,
        value_window: Some((0.0, 1.0)),
        ..RenderSettings::default()
    };
    let p = params_for(&volume, &camera, &settings);
    assert!(p.tf_window.w >= 20_000.0 * 3f32.sqrt(), "{}", p.tf_window.w);
    let ray = Ray {
        origin: Vec3::new(0.013, -0.2, 3.0),
        dir: -Vec3::Z,
    };
    let acc = cast_ray(&volume, &tf, &p, &ray);
    let expected = 1.0 - 0.9f32.powf(20.0);
    assert!(
        (acc.w - expected).abs() < 1e-3,
        "alpha {} vs {expected}",
        acc.w
    );
}

/// Settings that used to give a blank or wrong image without a word are refused, naming what
/// to change.
#[test]
fn settings_that_cannot_render_correctly_are_refused() {
    let volume = constant_volume(UVec3::splat(8), 0.5);
    let camera = Camera::perspective(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 30.0);
    for early_termination in [0.0, -1.0, f32::NAN] {
        let settings = RenderSettings {
            early_termination,
            ..RenderSettings::default()
        };
        let e = RaycastParams::new(&volume, &camera, &settings, 8, 8).unwrap_err();
        assert!(e.to_string().contains("early termination"), "{e}");
    }
    // A side 1e-30 of the others: the step would be far below anything a ray can march.
    let flat = Volume::new(
        UVec3::splat(8),
        Vec3::new(1e-30, 1.0, 1.0),
        VoxelData::F32(vec![0.5; 512]),
    )
    .unwrap();
    let e = RaycastParams::new(&flat, &camera, &RenderSettings::default(), 8, 8).unwrap_err();
    assert!(e.to_string().contains("voxel spacing"), "{e}");
    let zero = mixvol::scene::ClipPlane::new(Vec3::ZERO, 0.0);
    let e = mixvol::scene::ClipPlanes::new(&[zero]).unwrap_err();
    assert!(e.to_string().contains("zero normal"), "{e}");
}
