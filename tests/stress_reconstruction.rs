//! Stress tests of the mixed-resolution reconstruction (issue items 1 and 2), CPU reference and
//! GPU (field probe and images).
//!
//! Item 1, the warp near its singularities. Inside a hi-res brick next to low-res bricks the
//! smooth field is a convex combination of fetched values (multilinear weights `beta`, `1 - beta`
//! of the half-voxel band, trilinear weights of each fetch), and every fetched texel is a hi-res
//! voxel `floor(x - 0.5) + {0, 1}` or a fixed-up low-res sample (Mean2: the mean of voxels
//! `2k - 1` and `2k`) at a position `2k` in `(x - 2, x + 2]`. So the field at `x` must lie within
//! the range of the voxels whose indices are within 2 of `floor(x)` on every axis (clamped to the
//! volume), up to float rounding of the sums (1e-5 on values in [0, 1]). The bound is tight: a
//! radius of 1 is violated (measured). Points are put exactly where the construction has its
//! special cases: the band apex (`beta -> 0`, the plane of hi-res centres at 0.5 voxel from a
//! face) from both sides, brick faces, edges and corners, hi-res texel centres, even low-res
//! positions, and the diagonals `u = v` and `u = 1 - v` between a band coordinate and another band
//! or low-res cell coordinate.
//!
//! Item 2, large volumes and coordinates: a volume as long as the device's `maxImageDimension3D`
//! in one axis, a brick cache filled to its last slot (normalised cache coordinates up to
//! 126/128), the brick at the far corner. The voxel values are the x index, so the exact field is
//! `x - 0.5` (Mean2 reproduces linear functions, and the smooth blend is a convex combination of
//! exact values): the difference is the position error in voxels.

mod common;
mod stress_util;

use common::Rng;
use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level};
use mixvol::cache::{BrickCache, CacheGeometry};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference::{brick_of, sample_mixed, sample_volume, MixedVolume, ReferenceCache};
use mixvol::renderer::{MixedConfig, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{volume_box, Camera, RenderSettings};
use mixvol::volume::{ScalarType, Volume};
use std::sync::Arc;
use stress_util::*;

/// Float slack on convex combinations of values in [0, 1].
const RANGE_SLACK: f32 = 1e-5;
/// Offset used to approach a singular coordinate from either side (a few f32 ulps at 40 voxels).
const NEAR: f32 = 1e-4;
/// GPU probe vs CPU reference (`tests/gpu_mixed.rs`: 8-bit sub-texel weights on lavapipe).
const PROBE_TOLERANCE: f32 = 2e-3;
/// Lipschitz bound of the smooth field on [0, 1] random voxels, per voxel (`tests/continuity.rs`).
const LIPSCHITZ: f32 = 14.0;

// ---------------------------------------------------------------------------------------------
// Item 1: warping near its singularities
// ---------------------------------------------------------------------------------------------

/// Min and max of the voxels with indices within 2 of `floor(x)` per axis (clamped).
fn neighbourhood_range(volume: &Volume, x: Vec3) -> (f32, f32) {
    let base = x.floor().as_ivec3();
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for dz in -2..=2 {
        for dy in -2..=2 {
            for dx in -2..=2 {
                let c = base + IVec3::new(dx, dy, dz);
                let v = volume.value_clamped(c.x.into(), c.y.into(), c.z.into());
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    (lo, hi)
}

/// Brick-local coordinates where the construction has special cases (see the module docs).
fn singular_coordinates(n: f32) -> Vec<f32> {
    let mut c = vec![
        0.0,
        NEAR,
        0.25,
        0.5 - NEAR,
        0.5,
        0.5 + NEAR,
        1.0,
        1.5,
        2.0,
        n * 0.5 + 0.5,
        n - 2.0,
        n - 1.5,
        n - 0.5 - NEAR,
        n - 0.5,
        n - 0.5 + NEAR,
        n - 0.25,
        n - NEAR,
        n,
    ];
    c.dedup();
    c
}

/// Points in every hi-res brick with low-res neighbours (where the transition code runs): every
/// combination of singular coordinates, and the `u = v` / `u = 1 - v` diagonals.
fn singular_points(
    rng: &mut Rng,
    dims: UVec3,
    n: u32,
    bricks: UVec3,
    levels: &[Level],
    neighbours: &[u32],
) -> Vec<Vec3> {
    let nf = n as f32;
    let coords = singular_coordinates(nf);
    let extent = dims.as_vec3();
    let mut points = Vec::new();
    let mut push = |p: Vec3| points.push(p.clamp(Vec3::ZERO, extent));
    for bz in 0..bricks.z {
        for by in 0..bricks.y {
            for bx in 0..bricks.x {
                let b = UVec3::new(bx, by, bz);
                let bi = (bx + bricks.x * (by + bricks.y * bz)) as usize;
                if levels[bi] != Level::Hi || neighbours[bi] == 0 {
                    continue;
                }
                let origin = b.as_vec3() * nf;
                for &z in &coords {
                    for &y in &coords {
                        for &x in &coords {
                            push(origin + Vec3::new(x, y, z));
                        }
                    }
                }
                // Diagonals: axis a in its band at depth v (0 on the face, 1 at the apex), axis
                // b either in its band at u or across a low-res cell at 2k + 2u, u = v or 1 - v.
                let band = |side: bool, v: f32| if side { 0.5 * v } else { nf - 0.5 * v };
                for a in 0..3 {
                    for b_axis in 0..3 {
                        if a == b_axis {
                            continue;
                        }
                        let c_axis = 3 - a - b_axis;
                        for v in [0.0, NEAR, 0.25, 0.5, 0.75, 1.0 - NEAR, 1.0] {
                            for u in [v, 1.0 - v] {
                                for sides in 0..4 {
                                    let mut q = Vec3::ZERO;
                                    q[a] = band(sides & 1 == 0, v);
                                    q[c_axis] = coords[rng.below(coords.len() as u32) as usize];
                                    q[b_axis] = band(sides & 2 == 0, u);
                                    push(origin + q);
                                    let k = rng.below(n / 2) as f32;
                                    q[b_axis] = 2.0 * k + 2.0 * u;
                                    push(origin + q);
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    points
}

/// Residency plans that put hi-res bricks next to low-res ones across faces only, edges only,
/// corners only, mixtures, and random plans with absent bricks.
fn singular_plans(rng: &mut Rng, bricks: UVec3) -> Vec<(String, Vec<Level>)> {
    let count = (bricks.x * bricks.y * bricks.z) as usize;
    let index = |b: IVec3| (b.x as u32 + bricks.x * (b.y as u32 + bricks.y * b.z as u32)) as usize;
    let centre = IVec3::new(1, 1, 1);
    let mut plans = Vec::new();
    // Centre hi, everything else lo: faces, edges and corners all active.
    let mut all_lo = vec![Level::Lo; count];
    all_lo[index(centre)] = Level::Hi;
    plans.push(("centre-hi".to_string(), all_lo));
    // Centre hi with only edge (or only corner) neighbours lo, the rest hi.
    for (name, nonzero) in [("edge-only", 2), ("corner-only", 3), ("face-only", 1)] {
        let mut levels = vec![Level::Hi; count];
        for d in 0..27 {
            let o = IVec3::new(d % 3, (d / 3) % 3, d / 9) - IVec3::ONE;
            if o.abs().element_sum() == nonzero {
                levels[index(centre + o)] = Level::Lo;
            }
        }
        plans.push((name.to_string(), levels));
    }
    // Checkerboard.
    let checker = (0..count)
        .map(|i| {
            let b = UVec3::new(
                i as u32 % bricks.x,
                (i as u32 / bricks.x) % bricks.y,
                i as u32 / (bricks.x * bricks.y),
            );
            if (b.x + b.y + b.z).is_multiple_of(2) {
                Level::Hi
            } else {
                Level::Lo
            }
        })
        .collect();
    plans.push(("checker".to_string(), checker));
    for k in 0..2 {
        plans.push((format!("random-{k}"), random_levels(rng, count, true)));
    }
    plans
}

/// Checks the bound on every point; returns the number of points checked.
fn check_range_bound(
    name: &str,
    volume: &Volume,
    points: &[Vec3],
    values: &[Option<f32>],
    slack: f32,
) -> usize {
    let mut checked = 0;
    for (p, v) in points.iter().zip(values) {
        let Some(v) = *v else { continue };
        assert!(v.is_finite(), "{name}: field at {p} is {v}");
        let (lo, hi) = neighbourhood_range(volume, *p);
        assert!(
            v >= lo - slack && v <= hi + slack,
            "{name}: field at {p} = {v} outside the blended samples' range [{lo}, {hi}]"
        );
        checked += 1;
    }
    checked
}

/// Across the band apex (local 0.5 and n - 0.5) and across brick faces the field is continuous:
/// `|f(c - NEAR) - f(c + NEAR)| <= LIPSCHITZ * 2 * NEAR` (plus float slack), where both sides are
/// resident.
fn check_apex_continuity(name: &str, mv: &MixedVolume, points: &[Vec3], n: f32) {
    let mut compared = 0;
    for p in points {
        for a in 0..3 {
            let local = p[a] - (p[a] / n).floor() * n;
            if ![0.5, n - 0.5, 0.0].contains(&local) {
                continue;
            }
            let (mut below, mut above) = (*p, *p);
            below[a] -= NEAR;
            above[a] += NEAR;
            if let (Some(f0), Some(f1)) = (
                sample_mixed(mv, below, Transition::Smooth),
                sample_mixed(mv, above, Transition::Smooth),
            ) {
                assert!(
                    (f0 - f1).abs() <= LIPSCHITZ * 2.0 * NEAR + RANGE_SLACK,
                    "{name}: field jumps across the singular plane at {p} (axis {a}): {f0} vs {f1}"
                );
                compared += 1;
            }
        }
    }
    assert!(compared > 100, "{name}: only {compared} apex/face pairs");
}

/// CPU reference: the smooth field at the warp's singular points is finite, within the range of
/// the samples it blends (+1e-5), and continuous across the apex and brick faces.
#[test]
fn warp_singularities_stay_within_blended_samples_cpu() {
    let mut rng = Rng(0x5eed_0001_0000_0001);
    for n in [4u32, 8] {
        // 3 x 3 x 3 bricks, the last ones partial on x and y.
        let dims = UVec3::new(3 * n - 1, 3 * n - 3, 3 * n);
        let volume = random_volume(&mut rng, dims);
        let grid = BrickGrid::new(dims, n).unwrap();
        for (plan, levels) in singular_plans(&mut rng, grid.bricks_per_axis()) {
            let cache = cpu_cache(&volume, n, &levels);
            let reference = ReferenceCache::build(
                &volume,
                DownsampleFilter::Mean2,
                &cache,
                ScalarType::F32,
                Transition::Smooth,
            )
            .unwrap();
            let mv = reference.view();
            let points = singular_points(
                &mut rng,
                dims,
                n,
                grid.bricks_per_axis(),
                &levels,
                &reference.neighbours,
            );
            let values: Vec<Option<f32>> = points
                .iter()
                .map(|p| sample_mixed(&mv, *p, Transition::Smooth))
                .collect();
            let name = format!("n={n} {plan}");
            let checked = check_range_bound(&name, &volume, &points, &values, RANGE_SLACK);
            assert!(checked > 1000, "{name}: only {checked} points checked");
            check_apex_continuity(&name, &mv, &points, n as f32);
        }
    }
}

/// GPU: the probe (the ray-caster's own mixed.glsl functions) at the same singular points equals
/// the CPU reference within 2e-3, is finite, agrees on residency, and obeys the same range bound
/// (the GPU's quantised filter weights still form convex combinations).
#[test]
fn warp_singularities_gpu_probe_matches_reference_and_bound() {
    let ctx = common::validated_context();
    {
        let mut rng = Rng(0x5eed_0002_0000_0002);
        let n = 8;
        let dims = UVec3::new(3 * n - 1, 3 * n - 3, 3 * n);
        let volume = Arc::new(random_volume(&mut rng, dims));
        let grid = BrickGrid::new(dims, n).unwrap();
        let mut renderer = float_renderer(&ctx);
        renderer
            .set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config: mixed_config(n, Transition::Smooth),
            })
            .unwrap();
        for (plan, levels) in singular_plans(&mut rng, grid.bricks_per_axis()) {
            renderer.set_levels(&levels).unwrap();
            let reference = reference_cache(&renderer, &volume, Transition::Smooth);
            let points = singular_points(
                &mut rng,
                dims,
                n,
                grid.bricks_per_axis(),
                &levels,
                &reference.neighbours,
            );
            let gpu = renderer.probe_field(&points).unwrap();
            let name = format!("gpu {plan}");
            let mut worst = 0.0f32;
            for (p, g) in points.iter().zip(&gpu) {
                let c = sample_mixed(&reference.view(), *p, Transition::Smooth);
                match (g, c) {
                    (Some(g), Some(c)) => {
                        worst = worst.max((g - c).abs());
                        assert!(
                            (g - c).abs() <= PROBE_TOLERANCE,
                            "{name}: at {p}: gpu {g} cpu {c}"
                        );
                    }
                    (g, c) => assert_eq!(g.is_some(), c.is_some(), "{name}: residency at {p}"),
                }
            }
            let checked = check_range_bound(&name, &volume, &points, &gpu, RANGE_SLACK);
            assert!(checked > 1000, "{name}: only {checked} points checked");
            eprintln!("{name}: {checked} points, largest gpu-cpu difference {worst}");
        }
    }
    common::finish(ctx);
}

// ---------------------------------------------------------------------------------------------
// Item 2: large volumes and coordinates
// ---------------------------------------------------------------------------------------------

/// Brick size of the long-volume tests.
const LONG_N: u32 = 4;
/// Budget that caps the long volume's cache below its brick count (f32: 128 x 32 x 32 texels,
/// 21 x 5 x 5 = 525 slots for 1024 bricks), so that a full plan reaches the cache's far corner.
const LONG_BUDGET: u64 = 512 << 10;
/// Position error bound of the CPU reference, in voxels: a value near 4096 is itself an f32 with
/// an ulp of 2^-12, so the field and the exact `x - 0.5` each round by up to 2^-13; translation
/// (`x + t`) and the world -> texture mapping add a few roundings of 2^-24 relative to 4096.
/// Measured: 6e-5 voxel.
const CPU_POSITION_ERROR: f32 = 1.0 / 2048.0;
/// Position error bound of the GPU probe, in voxels: the CPU bound plus the 8-bit sub-texel
/// weight quantisation real GPUs apply (1/512 texel, a low-res texel being 2 voxels). Lavapipe
/// filters f32 textures exactly (measured 8e-6 voxel).
const GPU_POSITION_ERROR: f32 = 1.0 / 2048.0 + 2.0 / 512.0;

/// `dims.x` voxels along x whose value is their x index; 2 x 2 across. Spacing makes the box
/// 1 x 1/8 x 1/8 so cameras can see it.
fn long_volume(length: u32) -> Volume {
    let spacing = Vec3::new(1.0, length as f32 / 16.0, length as f32 / 16.0);
    f32_volume(UVec3::new(length, 2, 2), spacing, |v| v.x as f32)
}

/// The exact field of [`long_volume`] on hi-res bricks: `x - 0.5` clamped to the voxel range.
fn long_exact(x: f32, length: u32) -> f32 {
    (x - 0.5).clamp(0.0, (length - 1) as f32)
}

/// A plan of `bricks` resident bricks that fills every one of `slots` slots
/// (`#hi + ceil(#lo / 8) == slots`): hi-res bricks spread evenly along the axis, the last three
/// (the far end, far-corner brick included) always hi-res.
fn full_plan(bricks: usize, slots: usize) -> Vec<Level> {
    // hi + ceil((bricks - hi) / 8) <= slots; take the largest such hi.
    let hi = (0..=bricks)
        .rev()
        .find(|&h| h + (bricks - h).div_ceil(8) <= slots)
        .unwrap();
    assert_eq!(
        hi + (bricks - hi).div_ceil(8),
        slots,
        "plan cannot fill the cache"
    );
    // Spread the hi-res bricks: brick i is hi when floor(i * hi / bricks) changes, and the last
    // three bricks (the far end) are always hi.
    let mut levels: Vec<Level> = (0..bricks)
        .map(|i| {
            if (i + 1) * hi / bricks != i * hi / bricks {
                Level::Hi
            } else {
                Level::Lo
            }
        })
        .collect();
    let count_hi = levels.iter().filter(|l| **l == Level::Hi).count();
    assert_eq!(count_hi, hi);
    for i in bricks - 3..bricks {
        if levels[i] == Level::Lo {
            // Keep the count: demote the first hi-res brick instead.
            let j = levels.iter().position(|l| *l == Level::Hi).unwrap();
            levels[j] = Level::Lo;
            levels[i] = Level::Hi;
        }
    }
    levels
}

/// Points near the far corner, on brick faces, and spread over the whole length.
fn long_points(rng: &mut Rng, length: u32) -> Vec<Vec3> {
    let l = length as f32;
    let mut points = Vec::new();
    let across = [0.0, NEAR, 0.5, 1.0, 1.5, 2.0 - NEAR, 2.0];
    for &y in &across {
        for &z in &across {
            for x in [
                l,
                l - NEAR,
                l - 0.25,
                l - 0.5,
                l - 1.0,
                l - 2.0,
                l - 4.0,
                l - 4.5,
            ] {
                points.push(Vec3::new(x, y, z));
            }
        }
    }
    // Uniform in [0, 1) with all 53 bits, so that f32 coordinates carry a full mantissa (points
    // built from `Rng::unit` are multiples of 2^-24 and translate exactly).
    let mut fine =
        |scale: f32| ((rng.next() >> 11) as f64 / (1u64 << 53) as f64 * f64::from(scale)) as f32;
    for k in 0..6000 {
        let x = match k % 4 {
            0 => (fine(1.0) * (length / LONG_N) as f32).floor() * LONG_N as f32,
            1 => (fine(1.0) * length as f32).floor() + 0.5,
            // Small x in bricks whose slots lie far out in the cache: x + t rounds.
            2 => fine(256.0),
            _ => fine(l),
        };
        points.push(Vec3::new(x, fine(2.0), fine(2.0)));
    }
    points
}

/// Points of `points` where the exact field is `x - 0.5` for every residency: away from the
/// volume ends, where low-res samples are clamped (positions 2 ..= length - 2), or inside a
/// hi-res brick.
fn exact_region(x: Vec3, length: u32, hi: bool) -> bool {
    hi || (x.x >= 2.0 && x.x <= length as f32 - 2.0)
}

/// CPU reference, item 2: volumes 4096 (lavapipe's maxImageDimension3D) and 4095 voxels long,
/// translated through a full, capped cache (cache texel coordinates up to 126 of 128, the
/// far-corner brick resident, slots far from their bricks), reproduce `x - 0.5` within 2^-11
/// voxel: the mixed field (smooth and discontinuous), the single-resolution sampler in
/// normalised coordinates, and the same through the ray-caster's world -> texture mapping.
#[test]
fn far_corner_translation_precision_cpu() {
    for length in [4096u32, 4095] {
        let volume = long_volume(length);
        let grid = BrickGrid::new(volume.dims(), LONG_N).unwrap();
        let geometry =
            CacheGeometry::choose(LONG_N, 4, LONG_BUDGET, 4096, grid.brick_count() as u32).unwrap();
        assert_eq!(geometry.extent(), UVec3::new(128, 32, 32));
        let slots = geometry.slot_count() as usize;
        let mut rng = Rng(0xfa4_c0e4 + u64::from(length));
        let points = long_points(&mut rng, length);
        let far_end: Vec<Level> = (0..grid.brick_count())
            .map(|i| {
                if i + slots >= grid.brick_count() {
                    Level::Hi
                } else {
                    Level::Absent
                }
            })
            .collect();
        for (plan, levels) in [
            ("full", full_plan(grid.brick_count(), slots)),
            ("hi-far-end", far_end),
        ] {
            let mut cache = BrickCache::new(grid, geometry).unwrap();
            cache.update(&levels).unwrap();
            let last_slot = geometry.slot_count() - 1;
            assert!(
                cache
                    .residencies()
                    .iter()
                    .any(|r| r.slot() == Some(last_slot)),
                "{plan}: the last slot is unused"
            );
            assert_eq!(levels[grid.brick_count() - 1], Level::Hi);
            for transition in [Transition::Smooth, Transition::Discontinuous] {
                let reference = ReferenceCache::build(
                    &volume,
                    DownsampleFilter::Mean2,
                    &cache,
                    ScalarType::F32,
                    transition,
                )
                .unwrap();
                let mv = reference.view();
                let mut worst = 0.0f32;
                let mut checked = 0;
                for p in &points {
                    let b = brick_of(*p, LONG_N, grid.bricks_per_axis());
                    let hi = levels[b.x as usize] == Level::Hi;
                    let Some(v) = sample_mixed(&mv, *p, transition) else {
                        continue;
                    };
                    assert!(v.is_finite(), "{plan}: {p}: {v}");
                    if !exact_region(*p, length, hi) {
                        continue;
                    }
                    let err = (v - long_exact(p.x, length)).abs();
                    worst = worst.max(err);
                    assert!(
                        err <= CPU_POSITION_ERROR,
                        "{length} {plan} {transition:?}: field at {p} = {v}, exact {}: \
                         error {err} voxel",
                        long_exact(p.x, length)
                    );
                    checked += 1;
                }
                assert!(checked > 1000, "{plan}: {checked} points");
                eprintln!("cpu {length} {plan} {transition:?}: worst error {worst} voxel");
            }
        }
        // The single-resolution sampler, in normalised coordinates directly and through the
        // world box as the ray-caster computes them.
        let (box_min, box_max) = volume_box(volume.dims(), volume.spacing());
        let size = box_max - box_min;
        let dims = volume.dims().as_vec3();
        let mut worst = [0.0f32; 2];
        for p in &points {
            let world = box_min + *p / dims * size;
            for (k, tex) in [*p / dims, (world - box_min) / size]
                .into_iter()
                .enumerate()
            {
                let v = sample_volume(&volume, tex);
                let err = (v - long_exact(p.x, length)).abs();
                worst[k] = worst[k].max(err);
                assert!(
                    err <= CPU_POSITION_ERROR,
                    "{length}: single-res sample at {p} (path {k}) = {v}: error {err} voxel"
                );
            }
        }
        eprintln!("cpu {length} single-res: worst error {worst:?} voxel (texture, world)");
    }
}

/// GPU, item 2: a volume as long as `maxImageDimension3D` renders single-resolution and mixed
/// (bricks of 4, a cache capped at 525 slots and filled to its last slot) like the CPU reference
/// (`tests/gpu_vs_reference.rs` tolerances); one voxel longer is refused with a typed error for
/// the 3D texture but works through the brick cache; the probe reproduces `x - 0.5` within
/// 2^-11 + 2^-8 voxel, far corner included.
#[test]
fn device_limit_volume_renders_like_reference() {
    let ctx = common::validated_context();
    {
        let limit = ctx.info().limits.max_image_dimension3_d;
        // Memory stays small: 2 x 2 voxels across.
        let length = limit.min(16384);
        let volume = Arc::new(long_volume(length));
        let tf = TransferFunction::preset(TfPreset::Bands);
        let settings = RenderSettings::default();
        let cameras = [
            // The whole length, rays across the 2 x 2 section.
            (
                "ortho-side",
                Camera::orthographic(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 0.15),
                (64u32, 8u32),
            ),
            // Inside the far end, looking back along the axis at a grazing angle: long rays.
            (
                "perspective-far-corner",
                Camera::perspective(Vec3::new(0.52, 0.07, 0.07), Vec3::new(0.3, 0.0, 0.0), 30.0),
                (16, 16),
            ),
        ];
        let mut renderer = float_renderer(&ctx);
        for (name, camera, size) in &cameras {
            let (gpu, cpu) = render_single(&mut renderer, &volume, &tf, camera, &settings, *size);
            let visible = cpu.iter().filter(|p| p.w > 0.05).count();
            assert!(
                visible * 4 > cpu.len(),
                "single {name}: {visible} visible pixels"
            );
            assert_sane_pixels(name, &gpu, 1.0, 1e-5);
            assert_images_match(&format!("long-single-{name}"), size.0, size.1, &gpu, &cpu);
        }
        // One voxel beyond the limit: the 3D texture is refused with a typed error.
        let too_long = long_volume(length + 1);
        match renderer.set_source(VolumeSource::Volume(&too_long)) {
            Err(mixvol::Error::Unsupported(message)) => {
                assert!(message.contains("limit"), "{message}")
            }
            other => panic!("a {}-voxel axis must be refused: {other:?}", length + 1),
        }

        // Mixed: bricks of 4, cache capped so that the full plan uses the last slot.
        let config = MixedConfig {
            cache_budget_bytes: LONG_BUDGET,
            ..mixed_config(LONG_N, Transition::Smooth)
        };
        renderer
            .set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config,
            })
            .unwrap();
        let geometry = *renderer.brick_cache().unwrap().geometry();
        let bricks = renderer.brick_cache().unwrap().grid().brick_count();
        let levels = if (geometry.slot_count() as usize) < bricks {
            full_plan(bricks, geometry.slot_count() as usize)
        } else {
            vec![Level::Hi; bricks]
        };
        renderer.set_levels(&levels).unwrap();
        for (name, camera, size) in &cameras {
            let (gpu, cpu) = render_mixed(
                &mut renderer,
                &volume,
                Transition::Smooth,
                &tf,
                camera,
                &settings,
                *size,
            );
            assert_sane_pixels(name, &gpu, 1.0, 1e-5);
            assert_images_match(&format!("long-mixed-{name}"), size.0, size.1, &gpu, &cpu);
        }
        // Probe: x - 0.5 within the GPU bound, far corner included.
        let mut rng = Rng(0x10ff);
        let points = long_points(&mut rng, length);
        let values = renderer.probe_field(&points).unwrap();
        let grid = *renderer.brick_cache().unwrap().grid();
        let mut worst = 0.0f32;
        for (p, v) in points.iter().zip(&values) {
            let v = v.expect("every brick is resident");
            assert!(v.is_finite(), "{p}: {v}");
            let b = brick_of(*p, LONG_N, grid.bricks_per_axis());
            if !exact_region(*p, length, levels[b.x as usize] == Level::Hi) {
                continue;
            }
            let err = (v - long_exact(p.x, length)).abs();
            worst = worst.max(err);
            assert!(
                err <= GPU_POSITION_ERROR,
                "gpu probe at {p} = {v}: error {err} voxel"
            );
        }
        eprintln!("gpu probe (length {length}): worst position error {worst} voxel");
        // Through the brick cache the axis may exceed the 3D texture limit.
        renderer
            .set_source(VolumeSource::Mixed {
                volume: Arc::new(too_long),
                config: mixed_config(32, Transition::Smooth),
            })
            .unwrap();
        let count = renderer.brick_cache().unwrap().grid().brick_count();
        renderer.set_levels(&vec![Level::Lo; count]).unwrap();
        let frame = renderer
            .render(&cameras[0].1, &settings, cameras[0].2 .0, cameras[0].2 .1)
            .unwrap();
        assert_sane_pixels("too-long-mixed", &frame.pixels, 1.0, 1e-5);
    }
    common::finish(ctx);
}
