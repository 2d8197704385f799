//! Stress tests of volume data (issue item 6): u16 over its full range, f32 with huge and tiny
//! magnitudes, constant volumes (min == max), NaN / Inf voxels, anisotropic spacing, dimensions of
//! 1 along an axis. GPU images are compared with the CPU reference under the tolerances of
//! `tests/gpu_vs_reference.rs` (mean <= 1/1000, <= 0.5 % of channels above 1/255, none above
//! 6/255); closed forms where the data allow one.
//!
//! Policy for non-finite voxels (README, `VolumeError::NonFinite`): rejected when the volume is
//! built or loaded, with the first offending voxel's index and coordinates, so no NaN ever
//! reaches a renderer and no frame is silently black because of one.

mod common;
mod stress_util;

use common::Rng;
use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, Level};
use mixvol::optics::{TfPreset, TransferFunction, TF_SIZE};
use mixvol::reference;
use mixvol::renderer::{Renderer, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RaycastParams, RenderSettings};
use mixvol::volume::{
    load_raw, RawDescriptor, ScalarType, SyntheticField, Volume, VolumeError, VoxelData,
};
use std::sync::Arc;
use stress_util::*;

const N: u32 = 4;

fn camera() -> Camera {
    Camera::perspective(Vec3::new(1.1, 0.7, 1.5), Vec3::ZERO, 40.0)
}

fn ml(dims: UVec3, scalar: ScalarType) -> Volume {
    SyntheticField::MarschnerLobb
        .generate(dims, scalar)
        .unwrap()
}

/// `volume`'s normalised values, as an f32 volume with the same dims and spacing.
fn as_f32(volume: &Volume, map: impl Fn(f32) -> f32) -> Volume {
    let count = volume.data().len();
    let values = (0..count)
        .map(|i| map(volume.data().normalized(i)))
        .collect();
    Volume::new(volume.dims(), volume.spacing(), VoxelData::F32(values)).unwrap()
}

/// Renders `volume` single-resolution and through a mixed cache (`levels`) on the GPU and CPU;
/// checks each pair; returns (single gpu, single cpu, mixed gpu, mixed cpu).
fn render_both(
    renderer: &mut Renderer,
    name: &str,
    volume: &Arc<Volume>,
    levels: &[Level],
    tf: &TransferFunction,
    camera: &Camera,
    size: (u32, u32),
) -> [Vec<Vec4>; 4] {
    let settings = RenderSettings::default();
    render_both_with(renderer, name, volume, levels, tf, camera, &settings, size)
}

/// [`render_both`] with explicit render settings.
#[allow(clippy::too_many_arguments)] // reason: one scene, all of it needed.
fn render_both_with(
    renderer: &mut Renderer,
    name: &str,
    volume: &Arc<Volume>,
    levels: &[Level],
    tf: &TransferFunction,
    camera: &Camera,
    settings: &RenderSettings,
    size: (u32, u32),
) -> [Vec<Vec4>; 4] {
    let settings = *settings;
    let (sg, sc) = render_single(renderer, volume, tf, camera, &settings, size);
    assert_sane_pixels(&format!("{name}-single"), &sg, 1.0, 1e-5);
    assert_sane_pixels(&format!("{name}-single-cpu"), &sc, 1.0, 1e-5);
    assert_images_match(&format!("{name}-single"), size.0, size.1, &sg, &sc);
    set_mixed(
        renderer,
        volume,
        mixed_config(N, Transition::Smooth),
        levels,
    );
    let (mg, mc) = render_mixed(
        renderer,
        volume,
        Transition::Smooth,
        tf,
        camera,
        &settings,
        size,
    );
    assert_sane_pixels(&format!("{name}-mixed"), &mg, 1.0, 1e-5);
    assert_sane_pixels(&format!("{name}-mixed-cpu"), &mc, 1.0, 1e-5);
    assert_images_match(&format!("{name}-mixed"), size.0, size.1, &mg, &mc);
    [sg, sc, mg, mc]
}

// ---------------------------------------------------------------------------------------------
// NaN / Inf
// ---------------------------------------------------------------------------------------------

/// NaN, +Inf and -Inf voxels are refused by `Volume::new` and `load_raw` with
/// `VolumeError::NonFinite` naming the first offending voxel (index, x, y, z, value), and the
/// message (also through `mixvol::Error`) carries the coordinates.
#[test]
fn non_finite_voxels_are_rejected_naming_the_voxel() {
    let dims = UVec3::new(5, 4, 3);
    let count = 60;
    let at = |x: usize, y: usize, z: usize| x + 5 * (y + 4 * z);
    let cases = [
        (vec![(at(3, 1, 2), f32::NAN)], at(3, 1, 2), (3, 1, 2)),
        (vec![(at(0, 0, 0), f32::INFINITY)], 0, (0, 0, 0)),
        (vec![(at(4, 3, 2), f32::NEG_INFINITY)], 59, (4, 3, 2)),
        // Several: the first in storage order is named.
        (
            vec![(at(4, 3, 2), f32::NAN), (at(1, 2, 0), f32::INFINITY)],
            at(1, 2, 0),
            (1, 2, 0),
        ),
    ];
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    for (k, (bad, index, (x, y, z))) in cases.into_iter().enumerate() {
        let mut values = vec![0.25f32; count];
        for (i, v) in &bad {
            values[*i] = *v;
        }
        let check = |err: VolumeError, how: &str| {
            let message = err.to_string();
            match err {
                VolumeError::NonFinite {
                    index: i,
                    x: ex,
                    y: ey,
                    z: ez,
                    value,
                    ..
                } => {
                    assert_eq!((i, ex, ey, ez), (index, x, y, z), "{how} case {k}");
                    assert!(!value.is_finite(), "{how} case {k}: {value}");
                    let expected = values[index];
                    assert!(
                        value.to_bits() == expected.to_bits()
                            || (value.is_nan() && expected.is_nan()),
                        "{how} case {k}: reported {value}, voxel holds {expected}"
                    );
                }
                other => panic!("{how} case {k}: expected NonFinite, got {other:?}"),
            }
            assert!(
                message.contains(&format!("x={x}, y={y}, z={z}")),
                "{how} case {k}: message does not name the voxel: {message}"
            );
            let wrapped = mixvol::Error::from(VolumeError::NonFinite {
                file: None,
                index,
                x,
                y,
                z,
                value: values[index],
            });
            assert!(wrapped.to_string().contains(&format!("x={x}")), "{wrapped}");
        };
        let err = Volume::new(dims, Vec3::ONE, VoxelData::F32(values.clone())).unwrap_err();
        check(err, "Volume::new");
        // The same voxels from a raw file (little- and big-endian).
        for big_endian in [false, true] {
            let path = dir.join(format!(
                "stress-data-nonfinite-{}-{k}-{big_endian}.raw",
                std::process::id()
            ));
            let bytes: Vec<u8> = values
                .iter()
                .flat_map(|v| {
                    if big_endian {
                        v.to_be_bytes()
                    } else {
                        v.to_le_bytes()
                    }
                })
                .collect();
            std::fs::write(&path, bytes).unwrap();
            let desc = RawDescriptor {
                dims,
                scalar: ScalarType::F32,
                spacing: Vec3::ONE,
                header_bytes: 0,
                big_endian,
            };
            let result = load_raw(&path, &desc);
            std::fs::remove_file(&path).unwrap();
            check(result.unwrap_err(), "load_raw");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// u16 full range
// ---------------------------------------------------------------------------------------------

/// A u16 volume over the full range (0 and 65535 included) renders like the f32 volume of its
/// normalised values: the CPU images are bit-identical (the same normalised values), and the GPU
/// images (R16_UNORM vs R32_SFLOAT textures, single-resolution and through the brick cache) each
/// match the reference and each other under the comparison tolerances.
#[test]
fn u16_full_range_renders_like_f32() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(20, 18, 22);
        let base = ml(dims, ScalarType::F32);
        let mut rng = Rng(0x0016_ffff);
        let mut values: Vec<u16> = (0..base.data().len())
            .map(|i| (base.data().normalized(i) * 65535.0).round() as u16)
            .collect();
        // Extremes: runs of 0 and 65535 (and their neighbours 1 and 65534).
        for _ in 0..400 {
            let i = rng.below(values.len() as u32) as usize;
            values[i] = [0u16, 1, 65534, 65535][rng.below(4) as usize];
        }
        values[0] = 0;
        values[1] = 65535;
        let u16_volume = Arc::new(Volume::new(dims, Vec3::ONE, VoxelData::U16(values)).unwrap());
        let f32_volume = Arc::new(as_f32(&u16_volume, |v| v));
        assert_eq!(f32_volume.value_range(), (0.0, 1.0));
        let tf = TransferFunction::preset(TfPreset::Bands);
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        let levels = random_levels(&mut rng, count, true);
        let mut renderer = float_renderer(&ctx);
        let size = (40, 40);
        let u = render_both(
            &mut renderer,
            "u16",
            &u16_volume,
            &levels,
            &tf,
            &camera(),
            size,
        );
        let f = render_both(
            &mut renderer,
            "f32",
            &f32_volume,
            &levels,
            &tf,
            &camera(),
            size,
        );
        assert_eq!(u[1], f[1], "CPU single-resolution images differ");
        assert!(u[1].iter().filter(|p| p.w > 0.05).count() > 200);
        assert_images_match("u16-vs-f32-single", size.0, size.1, &u[0], &f[0]);
        assert_images_match("u16-vs-f32-mixed", size.0, size.1, &u[2], &f[2]);
        // The mixed CPU images differ only by the u16 rounding of low-res samples (1/131070).
        assert_images_match("u16-vs-f32-mixed-cpu", size.0, size.1, &u[3], &f[3]);
    }
    common::finish(ctx);
}

// ---------------------------------------------------------------------------------------------
// f32 magnitudes
// ---------------------------------------------------------------------------------------------

/// Renders `scaled` and compares its images with `unit` (the same structure in [0, 1]): with the
/// default window (the value range) the classification, hence the image, must not depend on the
/// magnitude.
fn assert_scale_invariant(
    renderer: &mut Renderer,
    name: &str,
    unit: &[Vec<Vec4>; 4],
    scaled: &Arc<Volume>,
    levels: &[Level],
    size: (u32, u32),
) {
    let tf = TransferFunction::preset(TfPreset::Bands);
    let s = render_both(renderer, name, scaled, levels, &tf, &camera(), size);
    for (k, what) in ["single-gpu", "single-cpu", "mixed-gpu", "mixed-cpu"]
        .iter()
        .enumerate()
    {
        assert_images_match(
            &format!("{name}-vs-unit-{what}"),
            size.0,
            size.1,
            &s[k],
            &unit[k],
        );
    }
}

/// f32 volumes of huge (1e30, 1e37, offset 1e20 +- 1e16) and tiny (1e-30) magnitudes render
/// like the same structure in [0, 1] (default window = value range), GPU and CPU, single and
/// mixed: images within the comparison tolerances of the unit-range images.
#[test]
fn f32_huge_and_tiny_magnitudes_render_like_unit_range() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(16, 20, 18);
        let unit = Arc::new(ml(dims, ScalarType::F32));
        let (lo, hi) = unit.value_range();
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        let mut rng = Rng(0x1e30);
        let levels = random_levels(&mut rng, count, false);
        let size = (32, 32);
        let mut renderer = float_renderer(&ctx);
        let tf = TransferFunction::preset(TfPreset::Bands);
        let unit_images = render_both(&mut renderer, "unit", &unit, &levels, &tf, &camera(), size);
        assert!(unit_images[1].iter().filter(|p| p.w > 0.05).count() > 100);
        type Map = Box<dyn Fn(f32) -> f32>;
        let maps: [(&str, Map); 4] = [
            ("x1e30", Box::new(|v| v * 1e30)),
            ("x1e37", Box::new(|v| v * 1e37)),
            ("x1e-30", Box::new(|v| v * 1e-30)),
            (
                "1e20+1e16x",
                Box::new(move |v| 1e20 + 1e16 * ((v - lo) / (hi - lo) * 64.0).round()),
            ),
        ];
        for (name, map) in maps {
            let scaled = Arc::new(as_f32(&unit, map));
            assert!(scaled.value_range().1 > scaled.value_range().0, "{name}");
            if name.starts_with("1e20") {
                // 65 distinct levels only: compare with the same quantisation in [0, 1].
                let q = Arc::new(as_f32(&unit, |v| ((v - lo) / (hi - lo) * 64.0).round()));
                let q_images = render_both(&mut renderer, "q64", &q, &levels, &tf, &camera(), size);
                assert_scale_invariant(&mut renderer, name, &q_images, &scaled, &levels, size);
            } else {
                assert_scale_invariant(&mut renderer, name, &unit_images, &scaled, &levels, size);
            }
        }
    }
    common::finish(ctx);
}

/// Found by this suite and fixed (f64 window, typed error for unclassifiable windows): f32 data at the ends
/// of the f32 range render wrongly. Bound: each volume either renders like the same structure in
/// [0, 1] (GPU and CPU, single and mixed, comparison tolerances), or is refused with a clear
/// `InvalidInput` error naming the value range / window (never NaN pixels or a blank frame).
/// Failing cases and causes:
/// - `x1e38` (values in [0, 1e38]): the default window's `1 / (hi - lo)` = 1e-38 is subnormal
///   (`RaycastParams::for_dims`, src/scene.rs); the GPU flushes it to 0 and every sample
///   classifies at TF position 0: blank GPU frame, correct CPU frame.
/// - `x1e-39` (subnormal data): `1 / (hi - lo)` overflows to +inf; on the CPU `(v - lo) * inf` is
///   NaN for `v == lo` (NaN pixels); the GPU flushes the subnormal texels: blank frame.
/// - `x1e-37` (normal data down to 1.6e-39 after quantisation, subnormal filter products): the
///   GPU's texture unit flushes subnormal values and products, the CPU reference does not.
/// - `+-max` (values in [-f32::MAX, f32::MAX]): `hi - lo` overflows, `1 / inf = 0`, and
///   `(v - lo) * 0 = inf * 0` is NaN on the CPU (410 NaN pixels); blank GPU frame.
#[test]
fn f32_extreme_value_ranges_render_like_unit_range() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::new(16, 20, 18);
        let unit = Arc::new(ml(dims, ScalarType::F32));
        let (lo, hi) = unit.value_range();
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        let levels = vec![Level::Hi; count];
        let size = (32, 32);
        let mut renderer = float_renderer(&ctx);
        let tf = TransferFunction::preset(TfPreset::Bands);
        // Quantise to 65 levels so every mapping below represents the structure exactly.
        let q = Arc::new(as_f32(&unit, |v| {
            ((v - lo) / (hi - lo) * 64.0).round() / 64.0
        }));
        let q_images = render_both(&mut renderer, "q", &q, &levels, &tf, &camera(), size);
        type Map = Box<dyn Fn(f32) -> f32>;
        let cases: [(&str, Map); 4] = [
            ("x1e38", Box::new(|v| v * 1e38)),
            ("x1e-39", Box::new(|v| v * 1e-39)),
            ("x1e-37", Box::new(|v| v * 1e-37)),
            ("+-max", Box::new(|v| (2.0 * v - 1.0) * f32::MAX)),
        ];
        let mut failures = Vec::new();
        for (name, map) in cases {
            let scaled = Arc::new(as_f32(&q, map));
            // A clear refusal is an accepted outcome.
            let settings = RenderSettings::default();
            let refused = renderer
                .set_source(VolumeSource::Volume(&scaled))
                .and_then(|_| renderer.render(&camera(), &settings, 4, 4))
                .err();
            if let Some(e) = refused {
                let message = e.to_string();
                if !(matches!(e, mixvol::Error::InvalidInput(_))
                    && (message.contains("range") || message.contains("window")))
                {
                    failures.push(format!("{name}: refused without naming the range: {e}"));
                }
                continue;
            }
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                assert_scale_invariant(&mut renderer, name, &q_images, &scaled, &levels, size)
            }));
            if let Err(e) = result {
                let message = e
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                failures.push(format!("{name}: {message}"));
            }
        }
        assert!(
            failures.is_empty(),
            "extreme f32 value ranges do not render like [0, 1]:\n{}",
            failures.join("\n")
        );
    }
    common::finish(ctx);
}

/// Found by this suite and fixed (f64 lerps in the reference filters): the CPU reference's
/// trilinear filter `lerp(a, b, t) = a + (b - a) * t` (src/reference/sampling.rs
/// `sample_volume`, src/reference/mixed.rs `CacheImage::fetch`) overflows `b - a` between finite
/// samples of opposite sign above f32::MAX / 2: +inf halfway between -MAX and +MAX (the GPU's
/// filter, and the exact value, give 0) and NaN (`inf * 0`) exactly at a texel centre. Bound: the
/// filtered value is finite and within 2^-22 * f32::MAX of the f64 interpolation.
#[test]
fn reference_filter_does_not_overflow_between_extreme_values() {
    use mixvol::reference::{sample_volume, CacheImage};
    let max = f32::MAX;
    let pairs = [(-max, max), (max, -max), (max, max), (-max, 0.5 * max)];
    let mut failures = Vec::new();
    for (a, b) in pairs {
        let volume =
            Volume::new(UVec3::new(2, 1, 1), Vec3::ONE, VoxelData::F32(vec![a, b])).unwrap();
        let mut cache = CacheImage::new(UVec3::new(2, 1, 1));
        cache.texels = vec![a, b];
        for t in [0.0f32, 0.25, 0.5, 0.75, 1.0] {
            let exact = (f64::from(a) * (1.0 - f64::from(t)) + f64::from(b) * f64::from(t)) as f32;
            let x = 0.5 + t; // between the two texel centres
            for (who, v) in [
                (
                    "sample_volume",
                    sample_volume(&volume, Vec3::new(x / 2.0, 0.5, 0.5)),
                ),
                ("CacheImage::fetch", cache.fetch(Vec3::new(x, 0.5, 0.5))),
            ] {
                let ok = v.is_finite()
                    && (f64::from(v) - f64::from(exact)).abs() <= 2f64.powi(-22) * f64::from(max);
                if !ok {
                    failures.push(format!(
                        "{who}({a:e}, {b:e}; t = {t}) = {v:e}, exact {exact:e}"
                    ));
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "trilinear filter overflows:\n{}",
        failures.join("\n")
    );
}

// ---------------------------------------------------------------------------------------------
// Constant volumes
// ---------------------------------------------------------------------------------------------

/// Constant volumes (min == max) of every scalar type: finite, GPU == CPU (single and mixed), and
/// a constant that the Grey TF shows (value 0.7 or 1e30: any window that contains the value at a
/// positive TF position) is not rendered as a silent black frame: for u8 / u16 (window [0, 1]) the
/// opacity of an orthographic ray through the unit cube is `1 - (1 - 0.25 v)^16` (1e-4).
///
/// Found by this suite and fixed (constant float volumes widen their window):
/// for f32 the default window is the value range, which is empty for a constant volume;
/// `RaycastParams::for_dims` (src/scene.rs) then sets `1 / range = 0`, every sample classifies at
/// TF position 0, and under the Grey TF (transparent at 0) the frame is black. Proposed policy:
/// an empty float range widens to `[min(v, 0), max(v, 1)]` (the integer window when v is in
/// [0, 1]).
#[test]
fn constant_volumes_are_not_silently_black() {
    let ctx = common::validated_context();
    {
        let dims = UVec3::splat(16);
        let tf = TransferFunction::preset(TfPreset::Grey);
        let count = BrickGrid::new(dims, N).unwrap().brick_count();
        let mut rng = Rng(0xc0457);
        let levels = random_levels(&mut rng, count, false);
        let ortho = Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 0.9);
        let size = (16, 16);
        let mut renderer = float_renderer(&ctx);
        let volumes: Vec<(&str, Volume, bool)> = vec![
            (
                "u8-178",
                Volume::new(dims, Vec3::ONE, VoxelData::U8(vec![178; 4096])).unwrap(),
                true,
            ),
            (
                "u16-45875",
                Volume::new(dims, Vec3::ONE, VoxelData::U16(vec![45875; 4096])).unwrap(),
                true,
            ),
            ("f32-0", f32_volume(dims, Vec3::ONE, |_| 0.0), false),
            ("f32--3", f32_volume(dims, Vec3::ONE, |_| -3.0), false),
            ("f32-0.7", f32_volume(dims, Vec3::ONE, |_| 0.7), true),
            ("f32-1e30", f32_volume(dims, Vec3::ONE, |_| 1e30), true),
        ];
        let mut black = Vec::new();
        for (name, volume, visible) in volumes {
            let volume = Arc::new(volume);
            let (lo, hi) = volume.value_range();
            assert_eq!(lo, hi, "{name}");
            let [sg, sc, mg, mc] =
                render_both(&mut renderer, name, &volume, &levels, &tf, &ortho, size);
            if volume.scalar_type() != ScalarType::F32 {
                let exact = 1.0 - (1.0 - 0.25 * f64::from(lo)).powf(16.0);
                for p in sg.iter().chain(&sc).chain(&mg).chain(&mc) {
                    assert!(
                        (f64::from(p.w) - exact).abs() < 1e-4,
                        "{name}: opacity {} vs {exact}",
                        p.w
                    );
                }
            }
            if visible
                && [&sg, &sc, &mg, &mc]
                    .iter()
                    .any(|img| img.iter().all(|p| p.w == 0.0))
            {
                black.push(name);
            }
        }
        assert!(
            black.is_empty(),
            "constant volumes rendered as a silent black frame: {black:?}"
        );
    }
    common::finish(ctx);
}

// ---------------------------------------------------------------------------------------------
// Anisotropic spacing and unit dimensions
// ---------------------------------------------------------------------------------------------

/// Anisotropic spacing (0.5, 2, 16) on 16 x 12 x 4 voxels: the box is 0.125 x 0.375 x 1 and
/// d0 = 1/128. A homogeneous volume (A = 0.01) seen along each axis by orthographic rays gives
/// `1 - 0.99^(L / d0)` with L / d0 = 16, 48, 128 (1e-5 CPU, 1e-4 GPU); a Marschner-Lobb volume
/// with spacing (0.3, 1.1, 9) renders like the reference, single and mixed.
#[test]
fn anisotropic_spacing_closed_form_and_reference() {
    let ctx = common::validated_context();
    {
        let mut renderer = float_renderer(&ctx);
        let a = 0.01f32;
        let tf_const =
            TransferFunction::from_entries(vec![Vec4::new(0.5, 0.7, 0.9, a); TF_SIZE]).unwrap();
        let volume = f32_volume(UVec3::new(16, 12, 4), Vec3::new(0.5, 2.0, 16.0), |_| 0.3);
        let settings = RenderSettings {
            early_termination: 1.0,
            ..RenderSettings::default()
        };
        let views = [
            (
                "along-x",
                Camera::orthographic(Vec3::new(2.0, 0.0, 0.0), Vec3::ZERO, 0.36),
                (8u32, 4u32),
                16.0,
            ),
            (
                "along-y",
                Camera {
                    up: Vec3::Z,
                    ..Camera::orthographic(Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, 0.9)
                },
                (1, 8),
                48.0,
            ),
            (
                "along-z",
                Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 0.36),
                (4, 12),
                128.0,
            ),
        ];
        for (name, camera, size, ratio) in views {
            let params = RaycastParams::new(&volume, &camera, &settings, size.0, size.1).unwrap();
            assert!((params.box_max.w - 1.0 / 128.0).abs() < 1e-9);
            let (gpu, cpu) =
                render_single(&mut renderer, &volume, &tf_const, &camera, &settings, size);
            let exact = 1.0 - (1.0 - f64::from(a)).powf(ratio);
            for (who, pixels, bound) in [("cpu", &cpu, 1e-5), ("gpu", &gpu, 1e-4)] {
                for p in pixels.iter() {
                    assert!(
                        (f64::from(p.w) - exact).abs() <= bound,
                        "anisotropic {name} {who}: opacity {} vs {exact}",
                        p.w
                    );
                }
            }
        }
        let ml_volume = ml(UVec3::new(24, 20, 6), ScalarType::F32);
        let ml_volume = Arc::new(
            Volume::new(
                ml_volume.dims(),
                Vec3::new(0.3, 1.1, 9.0),
                ml_volume.data().clone(),
            )
            .unwrap(),
        );
        let count = BrickGrid::new(ml_volume.dims(), N).unwrap().brick_count();
        let levels = random_levels(&mut Rng(0xa415), count, true);
        let tf = TransferFunction::preset(TfPreset::Bands);
        let images = render_both(
            &mut renderer,
            "anisotropic-ml",
            &ml_volume,
            &levels,
            &tf,
            &camera(),
            (32, 32),
        );
        assert!(images[1].iter().filter(|p| p.w > 0.05).count() > 50);
    }
    common::finish(ctx);
}

/// Dimensions of 1 along one, two and three axes (spacing chosen so the box is a cube): GPU ==
/// CPU single and mixed (bricks of 4), over the whole image and over its covered pixels, with
/// at least 30 % of the image visible (12 % for the single voxel); the sampler is constant along a unit axis (exactly the
/// voxel's value); a 1^3 volume seen by an orthographic ray gives exactly the TF opacity of its
/// value (1e-6), and the brick-cache probe of a 1 x 1 x 32 ramp (hi and lo bricks) reproduces
/// `z - 0.5` away from the clamped ends (5e-3 voxel: 8-bit sub-texel weights on a 2-voxel
/// low-res texel, plus rounding).
#[test]
fn unit_dimensions_render_like_reference() {
    let ctx = common::validated_context();
    {
        let tf = TransferFunction::preset(TfPreset::Bands);
        let mut renderer = float_renderer(&ctx);
        let mut rng = Rng(0x1d1);
        for dims in [
            UVec3::new(1, 16, 16),
            UVec3::new(16, 1, 16),
            UVec3::new(16, 16, 1),
            UVec3::new(1, 1, 32),
            UVec3::new(1, 7, 1),
            UVec3::new(1, 1, 1),
        ] {
            let name = format!("dims-{}x{}x{}", dims.x, dims.y, dims.z);
            let spacing = Vec3::splat(dims.max_element() as f32) / dims.as_vec3();
            let base = ml(dims, ScalarType::F32);
            let values = (0..base.data().len())
                .map(|i| base.data().normalized(i) * 0.8 + 0.1 * (i % 3) as f32)
                .collect();
            let volume = Arc::new(Volume::new(dims, spacing, VoxelData::F32(values)).unwrap());
            // Constant along unit axes: the sampler returns the voxel's value at any offset.
            for _ in 0..200 {
                let p = Vec3::new(rng.unit(), rng.unit(), rng.unit()) * 1.2 - 0.1;
                let mut moved = p;
                for a in 0..3 {
                    if dims[a] == 1 {
                        moved[a] = rng.unit();
                    }
                }
                assert_eq!(
                    reference::sample_volume(&volume, p),
                    reference::sample_volume(&volume, moved),
                    "{name}: not constant along a unit axis at {p}"
                );
            }
            let count = BrickGrid::new(dims, N).unwrap().brick_count();
            let levels = random_levels(&mut rng, count, false);
            let [sg, sc, mg, mc] = render_both(
                &mut renderer,
                &name,
                &volume,
                &levels,
                &tf,
                &camera(),
                (24, 24),
            );
            // Not blank, and equal over the covered pixels. Measured visible fractions: 0.62 to
            // 0.75, and 0.25 for the single voxel.
            let floor = if dims == UVec3::ONE { 0.12 } else { 0.3 };
            assert_images_match_covered(&format!("{name}-single"), 24, 24, &sg, &sc, floor);
            assert_images_match_covered(&format!("{name}-mixed"), 24, 24, &mg, &mc, floor);
        }
        // 1^3: one voxel, one ray sample of length d0 = 1 voxel.
        let one = Arc::new(f32_volume(UVec3::ONE, Vec3::ONE, |_| 0.25));
        let tf_grey = TransferFunction::preset(TfPreset::Grey);
        let ortho = Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 0.9);
        let settings = RenderSettings {
            value_window: Some((0.0, 1.0)),
            ..RenderSettings::default()
        };
        let (gpu, cpu) = render_single(&mut renderer, &one, &tf_grey, &ortho, &settings, (4, 4));
        let exact = tf_grey.lookup(0.25).w;
        for p in gpu.iter().chain(&cpu) {
            assert!(
                (p.w - exact).abs() <= 1e-6,
                "1^3: opacity {} vs {exact}",
                p.w
            );
        }
        // 1 x 1 x 32 ramp through the brick cache: hi-res bricks reproduce z - 0.5.
        let ramp = Arc::new(f32_volume(UVec3::new(1, 1, 32), Vec3::ONE, |v| v.z as f32));
        let count = BrickGrid::new(ramp.dims(), N).unwrap().brick_count();
        let levels: Vec<Level> = (0..count)
            .map(|i| if i % 2 == 0 { Level::Hi } else { Level::Lo })
            .collect();
        set_mixed(
            &mut renderer,
            &ramp,
            mixed_config(N, Transition::Smooth),
            &levels,
        );
        let points: Vec<Vec3> = (0..=320)
            .map(|i| Vec3::new(rng.unit(), rng.unit(), i as f32 * 0.1))
            .collect();
        let values = renderer.probe_field(&points).unwrap();
        for (p, v) in points.iter().zip(values) {
            let v = v.expect("resident");
            if p.z >= 2.0 && p.z <= 30.0 {
                let exact = p.z - 0.5;
                assert!(
                    (v - exact).abs() <= 5e-3,
                    "ramp probe at {p}: {v} vs {exact}"
                );
            }
        }
    }
    common::finish(ctx);
}
