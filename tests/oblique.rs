//! Oblique volumes render in RAS+ patient space: tests/fixtures/write_oblique_fixtures.py
//! (nibabel and pydicom, installed by scripts/python-env.sh) writes one voxel grid axis-aligned
//! (aligned.nii), with an oblique sform (oblique.nii, rotation R = Rz(30) Rx(15) computed by
//! numpy) and as a DICOM series of the same oblique geometry stored L, P, S (oblique_dicom/).
//!
//! The expected images never come from the model transform under test: the oblique file drawn
//! with its model transform must match the aligned file drawn with the camera (and clip plane)
//! rotated by R^T, computed here from numpy's R; drawing the oblique file without the transform
//! must differ from that. The DICOM series gets the rotation numpy wrote, as the NIfTI file does.
mod python_env;

mod common;

use glam::{DVec3, Vec3};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{Frame, MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{
    Camera, ClipPlane, ClipPlanes, ModelTransform, Projection, RenderSettings, Shading,
};
use mixvol::volume::{load_volume_with_meta, LoadedVolume};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

/// The folder holding every fixture, written once per test binary.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_oblique_fixtures.py",
            "oblique-fixtures",
            "scripts/requirements-dicom.txt",
        )
    })
}

fn load(name: &str) -> LoadedVolume {
    let p = fixtures().join(name);
    load_volume_with_meta(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// numpy's R as its columns (the RAS+ directions of the volume's x, y, z axes).
fn numpy_directions() -> [DVec3; 3] {
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(fixtures().join("rotation.json")).unwrap()).unwrap();
    let column = |i: usize| {
        let c: Vec<f64> = json["directions"][i]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        DVec3::new(c[0], c[1], c[2])
    };
    [column(0), column(1), column(2)]
}

/// A world vector in the volume frame: its components along numpy's directions (R^T v).
fn numpy_volume_vector(v: Vec3) -> Vec3 {
    let v = v.as_dvec3();
    let d = numpy_directions();
    DVec3::new(d[0].dot(v), d[1].dot(v), d[2].dot(v)).as_vec3()
}

/// Checks that `model` is numpy's rotation within `tolerance` per component.
fn assert_is_numpy_rotation(what: &str, model: &ModelTransform, tolerance: f64) {
    let m = model.world_from_volume();
    for (i, d) in numpy_directions().iter().enumerate() {
        let got = m.col(i).as_dvec3();
        assert!(
            (got - *d).abs().max_element() < tolerance,
            "{what}: column {i} is {got}, numpy wrote {d}"
        );
    }
}

#[test]
fn the_oblique_nifti_and_dicom_series_get_numpys_rotation() {
    let nii = load("oblique.nii");
    let dicom = load("oblique_dicom");
    let aligned = load("aligned.nii");
    // Same voxels: the DICOM series was stored L, P, S and reordered back to RAS+.
    assert_eq!(nii.volume, aligned.volume, "oblique.nii voxels");
    assert_eq!(dicom.volume.dims(), nii.volume.dims());
    assert!(
        (dicom.volume.spacing() - nii.volume.spacing())
            .abs()
            .max_element()
            < 1e-5,
        "{} vs {}",
        dicom.volume.spacing(),
        nii.volume.spacing()
    );
    assert_eq!(dicom.volume.data(), nii.volume.data(), "DICOM voxels");
    let r = dicom.meta.reorientation.as_ref().unwrap();
    assert_eq!(r.file_code(), "LPS", "{}", r.describe());
    assert_eq!(r.flipped, [true, true, false]);
    // The residual rotation's largest axis angle, from numpy's directions.
    let d = numpy_directions();
    let expected_degrees = (0..3)
        .map(|j| d[j][j].acos().to_degrees())
        .fold(0.0, f64::max);
    for (what, l) in [("oblique.nii", &nii), ("oblique_dicom", &dicom)] {
        let r = l.meta.reorientation.as_ref().unwrap();
        assert!(
            (r.oblique_degrees - expected_degrees).abs() < 1e-3,
            "{what}: {} vs {expected_degrees}",
            r.oblique_degrees
        );
        assert!(r.describe().contains("residual oblique rotation"), "{what}");
        assert_is_numpy_rotation(what, &ModelTransform::of_volume(&l.meta).unwrap(), 1e-5);
    }
    let model = ModelTransform::of_volume(&aligned.meta).unwrap();
    assert!(model.is_identity(), "aligned.nii: {model:?}");
}

const SIZE: u32 = 64;

/// A world-space view that cuts the volume with a world-space clip plane, shaded.
fn scene() -> (Camera, RenderSettings) {
    let camera = Camera {
        up: Vec3::new(0.1, 0.2, 1.0),
        ..Camera::perspective(
            Vec3::new(1.3, -1.1, 0.7),
            Vec3::new(0.03, -0.02, 0.01),
            35.0,
        )
    };
    let planes = ClipPlanes::new(&[ClipPlane::new(Vec3::new(-1.0, 0.3, 0.2), 0.2)]).unwrap();
    let settings = RenderSettings {
        shading: Some(Shading::default()),
        clip_planes: planes,
        samples_per_voxel: 2.0,
        ..RenderSettings::default()
    };
    (camera, settings)
}

/// `camera` and `settings` in the volume frame by numpy's R (not by [`ModelTransform`]).
fn numpy_volume_frame(camera: &Camera, settings: &RenderSettings) -> (Camera, RenderSettings) {
    let c = Camera {
        eye: numpy_volume_vector(camera.eye),
        target: numpy_volume_vector(camera.target),
        up: numpy_volume_vector(camera.up),
        ..*camera
    };
    let planes: Vec<ClipPlane> = settings
        .clip_planes
        .planes()
        .iter()
        .map(|p| ClipPlane::new(numpy_volume_vector(p.normal), p.offset))
        .collect();
    let s = RenderSettings {
        clip_planes: ClipPlanes::new(&planes).unwrap(),
        ..*settings
    };
    (c, s)
}

/// A renderer drawing `source` with `model`.
fn renderer(
    ctx: &mixvol::gpu::GpuContext,
    source: VolumeSource<'_>,
    model: ModelTransform,
) -> Renderer {
    let mut r = Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap();
    r.set_transfer_function(&TransferFunction::preset(TfPreset::Fire))
        .unwrap();
    r.set_source(source).unwrap();
    r.set_model_transform(model);
    r
}

/// Renders until camera-driven residency settles (one frame for a plain volume).
fn render(r: &mut Renderer, camera: &Camera, settings: &RenderSettings) -> Frame {
    for _ in 0..16 {
        let frame = r.render(camera, settings, SIZE, SIZE).unwrap();
        match &frame.residency {
            Some(report) if !report.plan.is_settled() => continue,
            _ => return frame,
        }
    }
    panic!("residency did not settle within 16 frames");
}

#[test]
fn an_oblique_file_renders_as_the_aligned_file_seen_by_the_inversely_rotated_camera() {
    let ctx = common::validated_context();
    let nii = load("oblique.nii");
    let dicom = load("oblique_dicom");
    let aligned = load("aligned.nii");
    let model = ModelTransform::of_volume(&nii.meta).unwrap();
    let (camera, settings) = scene();
    let (v_camera, v_settings) = numpy_volume_frame(&camera, &settings);

    // Plain 3D textures.
    let expected = render(
        &mut renderer(
            &ctx,
            VolumeSource::Volume(&aligned.volume),
            ModelTransform::IDENTITY,
        ),
        &v_camera,
        &v_settings,
    );
    assert!(
        expected.pixels.iter().filter(|p| p.w > 0.1).count() > 200,
        "the expected view shows the volume"
    );
    let oblique = render(
        &mut renderer(&ctx, VolumeSource::Volume(&nii.volume), model),
        &camera,
        &settings,
    );
    common::assert_frame_matches("oblique-nifti", &oblique, &expected.pixels);
    let unrotated = render(
        &mut renderer(
            &ctx,
            VolumeSource::Volume(&nii.volume),
            ModelTransform::IDENTITY,
        ),
        &camera,
        &settings,
    );
    let d = common::diff(&unrotated.pixels, &expected.pixels, common::FRAME_LARGE);
    assert!(
        d.large_fraction > 0.05 && d.max > 0.2,
        "the axis-aligned render of the oblique file must differ: {d:?}"
    );
    // The DICOM series with its own rotation draws the same.
    let from_dicom = render(
        &mut renderer(
            &ctx,
            VolumeSource::Volume(&dicom.volume),
            ModelTransform::of_volume(&dicom.meta).unwrap(),
        ),
        &camera,
        &settings,
    );
    common::assert_frame_matches("oblique-dicom", &from_dicom, &expected.pixels);

    // Through the brick cache with camera-driven residency, from closer, with slots for only
    // some bricks hi-res: which bricks the planner draws hi-res depends on its view, which must
    // be in the volume frame too (planned from the world camera instead, this frame differs).
    let near = Camera {
        eye: Vec3::new(0.45, -0.75, 0.35),
        target: Vec3::new(0.2, 0.1, 0.05),
        projection: Projection::Perspective {
            fov_y_degrees: 22.0,
        },
        ..camera
    };
    let (v_near, _) = numpy_volume_frame(&near, &settings);
    let config = MixedConfig {
        brick_size: 4,
        cache_budget_bytes: 6000,
        ..MixedConfig::default()
    };
    let mixed = |volume: &LoadedVolume| VolumeSource::Mixed {
        volume: Arc::new(volume.volume.clone()),
        config,
    };
    let expected = render(
        &mut renderer(&ctx, mixed(&aligned), ModelTransform::IDENTITY),
        &v_near,
        &v_settings,
    );
    let mut r = renderer(&ctx, mixed(&nii), model);
    let oblique = render(&mut r, &near, &settings);
    let plan = r.last_plan().unwrap().report;
    assert!(
        plan.drawn_hi > 0 && plan.drawn_lo > 0,
        "the slot budget makes the levels depend on the view: {plan:?}"
    );
    common::assert_frame_matches("oblique-mixed", &oblique, &expected.pixels);
    drop(r);
    common::finish(ctx);
}

/// The host-depth convention end to end on the CPU reference (which mirrors the GLSL; moved
/// here from `src/scene/model.rs` so that no file of `src/` but the oracle's names it): a
/// host draws a surface point `P` in world space with its own `clip_from_world`; the rays,
/// cast in the volume frame, must stop at `P`'s distance when the depth is unprojected
/// through `(clip_from_world * M)^-1`, as `VolumePass::record` sets it, and not through
/// `clip_from_world^-1` alone.
#[test]
fn host_depth_unprojects_into_the_volume_frame_at_the_hosts_surface() {
    use glam::{Mat4, UVec3, Vec2};
    use mixvol::reference::{depth_limit, generate_ray};
    use mixvol::scene::RaycastParams;
    let m = ModelTransform::from_directions(rotation_about_z(30.0)).unwrap();
    let (w, h) = (40, 30);
    let camera = Camera::perspective(Vec3::new(2.0, 0.4, 0.5), Vec3::new(0.05, 0.0, 0.0), 40.0);
    let params = |c: &Camera| {
        RaycastParams::for_dims(
            UVec3::splat(8),
            Vec3::ONE,
            (0.0, 1.0),
            false,
            c,
            &RenderSettings::default(),
            w,
            h,
        )
        .unwrap()
    };
    let world = params(&camera);
    let mut volume = params(&m.volume_camera(&camera));
    // The host's camera: the same view, Vulkan clip space (y down, depth in [0, 1]).
    let clip_from_world = Mat4::from_scale(Vec3::new(1.0, -1.0, 1.0))
        * Mat4::perspective_rh(40f32.to_radians(), w as f32 / h as f32, 0.1, 10.0)
        * Mat4::look_at_rh(camera.eye, camera.target, camera.up);
    let pixel = Vec2::new(27.5, 8.5);
    let distance = 1.7;
    let p = {
        let ray = generate_ray(&world, pixel);
        ray.origin + distance * ray.dir
    };
    let clip = clip_from_world * p.extend(1.0);
    let ndc = clip.truncate() / clip.w;
    let expected_ndc = pixel / Vec2::new(w as f32, h as f32) * 2.0 - Vec2::ONE;
    assert!(
        (ndc.truncate() - expected_ndc).abs().max_element() < 1e-5,
        "{ndc}"
    );
    let ray = generate_ray(&volume, pixel);
    volume.world_from_clip = m.clip_from_volume(clip_from_world).inverse();
    let t = depth_limit(&volume, &ray, pixel, ndc.z);
    assert!((t - distance).abs() < 1e-4, "{t} vs {distance}");
    volume.world_from_clip = clip_from_world.inverse();
    let wrong = depth_limit(&volume, &ray, pixel, ndc.z);
    assert!((wrong - distance).abs() > 0.05, "{wrong}");
}

/// Rotation by `deg` degrees about z, written out (not through glam).
fn rotation_about_z(deg: f64) -> [[f64; 3]; 3] {
    let (s, c) = deg.to_radians().sin_cos();
    [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]
}
