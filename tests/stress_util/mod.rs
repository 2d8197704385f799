//! Helpers shared by the stress tests (`tests/stress_*.rs`): volume builders, the
//! GPU-vs-reference image comparison with the tolerances of `tests/gpu_vs_reference.rs`, and
//! mixed-resolution set-up.
#![allow(dead_code)] // reason: each stress test binary uses a different subset of these helpers.

use crate::common;
use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, DownsampleFilter, Level};
use mixvol::cache::{BrickCache, CacheGeometry};
use mixvol::optics::TransferFunction;
use mixvol::reference::{self, ReferenceCache};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{Volume, VoxelData};
use std::sync::Arc;

/// Tolerances of `tests/gpu_vs_reference.rs` (reasons there): mean absolute difference, the
/// "large" threshold, the fraction of channels allowed above it, and the largest difference.
pub const MEAN_TOLERANCE: f32 = 1.0 / 1000.0;
pub const LARGE: f32 = 1.0 / 255.0;
pub const LARGE_FRACTION_TOLERANCE: f32 = 0.005;
pub const MAX_TOLERANCE: f32 = 6.0 / 255.0;
/// The fraction of covered pixels' channels allowed above [`LARGE`]: twice
/// [`LARGE_FRACTION_TOLERANCE`], as it is no longer diluted by the background.
pub const COVERED_LARGE_FRACTION_TOLERANCE: f32 = 0.01;

/// An f32 volume with unit spacing (or `spacing`) whose voxel `(x, y, z)` holds `f(x, y, z)`.
pub fn f32_volume(dims: UVec3, spacing: Vec3, f: impl Fn(UVec3) -> f32) -> Volume {
    let mut values = Vec::with_capacity((dims.x * dims.y * dims.z) as usize);
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                values.push(f(UVec3::new(x, y, z)));
            }
        }
    }
    Volume::new(dims, spacing, VoxelData::F32(values)).unwrap()
}

/// Uniform random f32 voxels in [0, 1).
pub fn random_volume(rng: &mut common::Rng, dims: UVec3) -> Volume {
    let count = (dims.x * dims.y * dims.z) as usize;
    let values = (0..count).map(|_| rng.unit()).collect();
    Volume::new(dims, Vec3::ONE, VoxelData::F32(values)).unwrap()
}

/// Random levels: Lo, Hi and (when `absent`) Absent.
pub fn random_levels(rng: &mut common::Rng, count: usize, absent: bool) -> Vec<Level> {
    (0..count)
        .map(|_| match rng.below(if absent { 7 } else { 6 }) {
            0..=2 => Level::Lo,
            3..=5 => Level::Hi,
            _ => Level::Absent,
        })
        .collect()
}

/// A mixed configuration with bricks of `n` (Mean2 filter, 64 MiB budget).
pub fn mixed_config(n: u32, transition: Transition) -> MixedConfig {
    MixedConfig {
        brick_size: n,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 64 << 20,
        transition,
        max_levels: 0,
    }
}

/// A CPU brick cache for `volume` with bricks of `n`, a cache with room for every brick, moved to
/// `levels`.
pub fn cpu_cache(volume: &Volume, n: u32, levels: &[Level]) -> BrickCache {
    let grid = BrickGrid::new(volume.dims(), n).unwrap();
    let geometry = CacheGeometry::choose(
        n,
        volume.scalar_type().size_bytes() as u32,
        1 << 30,
        4096,
        grid.brick_count() as u32,
    )
    .unwrap();
    let mut cache = BrickCache::new(grid, geometry).unwrap();
    cache.update(levels).unwrap();
    cache
}

/// The CPU mirror of the renderer's current brick cache.
pub fn reference_cache(
    renderer: &Renderer,
    volume: &Volume,
    transition: Transition,
) -> ReferenceCache {
    ReferenceCache::build(
        volume,
        DownsampleFilter::Mean2,
        renderer.brick_cache().unwrap(),
        volume.scalar_type(),
        transition,
    )
    .unwrap()
}

/// Asserts every channel of every pixel is finite, premultiplied colour and opacity in
/// [0, 1 + slack] and colour not above the opacity times `max_emission` (+ slack).
pub fn assert_sane_pixels(name: &str, pixels: &[Vec4], max_emission: f32, slack: f32) {
    for (i, p) in pixels.iter().enumerate() {
        assert!(p.is_finite(), "{name}: pixel {i} is not finite: {p}");
        assert!(
            p.min_element() >= 0.0 && p.w <= 1.0 + slack,
            "{name}: pixel {i} out of range: {p}"
        );
        assert!(
            p.truncate().max_element() <= p.w * max_emission + slack,
            "{name}: pixel {i} colour above opacity * emission maximum {max_emission}: {p}"
        );
    }
}

/// Compares a GPU image with the CPU reference under the `tests/gpu_vs_reference.rs` tolerances;
/// writes failure images and panics on failure.
pub fn assert_images_match(name: &str, width: u32, height: u32, gpu: &[Vec4], cpu: &[Vec4]) {
    let d = common::diff(gpu, cpu, LARGE);
    let ok = d.mean <= MEAN_TOLERANCE
        && d.large_fraction <= LARGE_FRACTION_TOLERANCE
        && d.max <= MAX_TOLERANCE;
    if !ok {
        let dir = common::write_failure_images(name, width, height, gpu, cpu);
        panic!(
            "{name}: GPU differs from the CPU reference: {d:?} (images in {})",
            dir.display()
        );
    }
    let visible = cpu.iter().filter(|p| p.w > 0.05).count();
    eprintln!("{name}: {visible}/{} visible, {d:?}", cpu.len());
}

/// [`assert_images_match`], and: at least `min_visible` of the pixels of both images visible
/// (opacity above [`common::VISIBLE_ALPHA`]), so a blank pair cannot pass, and the covered pixels
/// alone (opacity above [`LARGE`] in either image) within the same tolerances, so the background
/// cannot dilute the mean or the fraction of large differences.
pub fn assert_images_match_covered(
    name: &str,
    width: u32,
    height: u32,
    gpu: &[Vec4],
    cpu: &[Vec4],
    min_visible: f32,
) {
    assert_images_match(name, width, height, gpu, cpu);
    let c = common::coverage(gpu, cpu, LARGE, LARGE);
    assert!(
        c.expected_visible >= min_visible && c.actual_visible >= min_visible,
        "{name}: less than {min_visible} of the image visible: {c:?}"
    );
    let d = &c.diff;
    let ok = d.mean <= MEAN_TOLERANCE
        && d.large_fraction <= COVERED_LARGE_FRACTION_TOLERANCE
        && d.max <= MAX_TOLERANCE;
    if !ok {
        let dir = common::write_failure_images(name, width, height, gpu, cpu);
        panic!(
            "{name}: covered pixels differ from the CPU reference: {c:?} (images in {})",
            dir.display()
        );
    }
    eprintln!(
        "{name}: visible {:.3} / {:.3}, covered {c:?}",
        c.actual_visible, c.expected_visible
    );
}

/// Renders `volume` single-resolution on the GPU and with the CPU reference; returns both images.
pub fn render_single(
    renderer: &mut Renderer,
    volume: &Volume,
    tf: &TransferFunction,
    camera: &Camera,
    settings: &RenderSettings,
    size: (u32, u32),
) -> (Vec<Vec4>, Vec<Vec4>) {
    renderer.set_source(VolumeSource::Volume(volume)).unwrap();
    renderer.set_transfer_function(tf).unwrap();
    let frame = renderer.render(camera, settings, size.0, size.1).unwrap();
    let params = renderer.params(camera, settings, size.0, size.1).unwrap();
    (frame.pixels, reference::render(volume, tf, &params))
}

/// Renders the renderer's current mixed volume (levels already set) on the GPU and with the CPU
/// reference of its cache; returns both images.
pub fn render_mixed(
    renderer: &mut Renderer,
    volume: &Volume,
    transition: Transition,
    tf: &TransferFunction,
    camera: &Camera,
    settings: &RenderSettings,
    size: (u32, u32),
) -> (Vec<Vec4>, Vec<Vec4>) {
    renderer.set_transfer_function(tf).unwrap();
    let frame = renderer.render(camera, settings, size.0, size.1).unwrap();
    let params = renderer.params(camera, settings, size.0, size.1).unwrap();
    let cache = reference_cache(renderer, volume, transition);
    let cpu = reference::render_mixed(&cache.view(), transition, tf, &params);
    (frame.pixels, cpu)
}

/// A renderer with an RGBA32F target (comparisons without 8-bit quantisation).
pub fn float_renderer(ctx: &mixvol::gpu::GpuContext) -> Renderer {
    Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap()
}

/// Sets `volume` as the renderer's mixed volume with bricks of `n` and moves it to `levels`.
pub fn set_mixed(
    renderer: &mut Renderer,
    volume: &Arc<Volume>,
    config: MixedConfig,
    levels: &[Level],
) {
    renderer
        .set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config,
        })
        .unwrap();
    renderer.set_levels(levels).unwrap();
}
