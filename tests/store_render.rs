//! Out-of-core rendering checked against the in-core renderer (issue 8, item 7).
//!
//! A u16 volume whose hi-res bricks exceed the GPU cache budget several times over is written
//! brick by brick from an analytic field (never whole in RAM), streamed from disk under a RAM
//! budget, LOD-selected into the cache budget (hi-res near the eye, low-res elsewhere, some hi-res
//! bricks falling back to low-res because the RAM budget cannot hold them all) and rendered
//! through the renderer's brick-source path. The image is compared with the plain (single
//! texture) renderer on a downsampled copy built directly at half the resolution.
//!
//! Why the comparison is exact up to GPU filtering: the field is affine in the voxel position,
//! `v(p) = A + s . p` with even integer slopes `s` (in u16 steps). Trilinear interpolation
//! reproduces an affine field exactly, the Mean2 low-res level (sample `k` = mean of voxels
//! `2k-1`, `2k`, at position `2k`) of an affine field is the field at the sample position, and
//! so is every voxel of the half-resolution copy (voxel `j` at position `2j + 1` holds the mean of
//! voxels `2j`, `2j + 1`); with even slopes all these means are integers, so quantisation loses
//! nothing. Hence hi-res bricks, low-res bricks, the C0 blends between them and the copy all
//! reconstruct the same function inside the volume, whatever the level plan and the fallbacks.
//! They differ only within one hi-res voxel of the faces (clamp-to-edge on different grids).
//! The copy's voxels are twice as long, so it is rendered at 2 samples per voxel (the same step
//! length) with opacities `1 - (1 - a)^2` (the same opacity per world length); the transfer
//! function's opacity is constant so this correction is exact.
//!
//! Peak RSS (VmHWM, process-wide, so this file holds a single test) must stay within the
//! streamer's RAM budget plus three times the GPU cache budget (on lavapipe device memory is host
//! memory: the cache image, the upload's staging buffer and the packed bricks of the update are
//! all in RSS) plus a small allowance, above a baseline taken after the context and the mixed
//! pipeline exist: a bound that does not grow with the volume.
//!
//! The edge length defaults to 512 (a 362 MB store, 5x the cache budget in hi-res bricks);
//! `MIXVOL_STORE_RENDER_DIM` overrides it (a multiple of 32, >= 512). Both budgets scale with the volume
//! (48 and 64 MiB at 512^3): the low-res level alone is an eighth of the volume and must fit both.
//! At 1024^3 that is a 2.9 GB store, 384 + 512 MiB of budgets and about 1.9 GB of RSS, too much
//! for CI; 512^3 keeps the store, the budgets and the runtime (about 5 s) modest.

mod common;

use glam::{IVec3, UVec3, Vec3, Vec4};
use mixvol::bricks::{request_plan, DownsampleFilter, Level, VolumeBrickSource};
use mixvol::lod::{select_levels, BrickGeometry, LodView, SelectionOptions};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RenderSettings};
use mixvol::store::{write_store, BrickStreamer, StoreDesc, StreamerConfig};
use mixvol::volume::{ScalarType, Volume, VoxelData};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

const BRICK: u32 = 32;
/// The streamer's RAM budget at 512^3 (scaled by `(dim / 512)^3`).
const RAM_BUDGET_512: u64 = 48 << 20;
/// The GPU cache budget at 512^3 (scaled likewise).
const CACHE_BUDGET_512: u64 = 64 << 20;
/// Memory the test allows beyond the RAM budget, in multiples of the cache budget: on lavapipe
/// the cache image, the upload's staging buffer and the update's packed bricks on the CPU (each
/// at most the cache's size) are all host memory.
const CACHE_COPIES: u64 = 3;
/// Further slack: brick tables, the frame, thread stacks, allocator.
const ALLOWANCE: u64 = 32 << 20;
const SIZE: u32 = 96;
/// Offset of the field in u16 steps.
const BASE: i64 = 4096;
/// Opacity per hi-res voxel length.
const ALPHA: f32 = 0.012;

/// `VmHWM` (peak RSS) of this process in bytes.
fn vm_hwm() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 20) as f64
}

/// Removes the store file however the test ends.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The affine field in u16 steps: `BASE + s . voxel` with even slopes `s = 2a (1, 2, 3)`, `a`
/// as large as fits u16 over the volume.
#[derive(Copy, Clone)]
struct Field {
    slope: IVec3,
}

impl Field {
    fn new(dim: u32) -> Self {
        let a = (65535 - BASE) / (12 * (i64::from(dim) - 1));
        assert!(a >= 1, "volume too large for an even-slope u16 field");
        let a = a as i32;
        Self {
            slope: IVec3::new(2 * a, 4 * a, 6 * a),
        }
    }

    /// Voxel `p`'s value in u16 steps.
    fn level(self, p: IVec3) -> i64 {
        BASE + i64::from(self.slope.dot(p))
    }

    /// Voxel `j` of the half-resolution copy: the field at position `2j + 1`, i.e. the mean of
    /// voxels `2j` and `2j + 1` per axis (an integer because the slopes are even).
    fn half_level(self, j: IVec3) -> i64 {
        BASE + i64::from(self.slope.dot(2 * j)) + i64::from(self.slope.element_sum() / 2)
    }
}

/// A transfer function with constant opacity `alpha` and a colour ramp.
fn transfer_function(alpha: f32) -> TransferFunction {
    TransferFunction::from_control_points(&[
        (0.0, Vec4::new(0.9, 0.1, 0.1, alpha)),
        (0.3, Vec4::new(0.9, 0.8, 0.1, alpha)),
        (0.6, Vec4::new(0.1, 0.8, 0.7, alpha)),
        (1.0, Vec4::new(0.2, 0.2, 0.9, alpha)),
    ])
    .unwrap()
}

fn config(cache_budget: u64) -> MixedConfig {
    MixedConfig {
        brick_size: BRICK,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: cache_budget,
        transition: Transition::Smooth,
        max_levels: 0,
    }
}

#[test]
fn streamed_volume_over_the_cache_budget_renders_like_the_in_core_downsampled_copy() {
    let dim: u32 = std::env::var("MIXVOL_STORE_RENDER_DIM")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(512);
    assert!(
        dim >= 512 && dim.is_multiple_of(BRICK),
        "dim must be a multiple of {BRICK} and >= 512"
    );
    let field = Field::new(dim);
    let scale = |bytes: u64| bytes * u64::from(dim).pow(3) / 512u64.pow(3);
    let (ram_budget, cache_budget) = (scale(RAM_BUDGET_512) as usize, scale(CACHE_BUDGET_512));
    let max_level = field.level(IVec3::splat(dim as i32 - 1));
    let window = (BASE as f32 / 65535.0, max_level as f32 / 65535.0);
    let settings = RenderSettings {
        value_window: Some(window),
        ..RenderSettings::default()
    };
    let camera = Camera::perspective(Vec3::new(0.75, 0.55, 1.0), Vec3::ZERO, 40.0);

    // 1. Write the store brick by brick.
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("store-tests");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("render-{dim}-{}.mvbs", std::process::id()));
    let _cleanup = RemoveOnDrop(path.clone());
    let desc = StoreDesc {
        dims: UVec3::splat(dim),
        brick_size: BRICK,
        scalar: ScalarType::U16,
        spacing: Vec3::ONE,
        filter: DownsampleFilter::Mean2,
    };
    let summary = write_store(
        &path,
        desc,
        &|p: IVec3| field.level(p) as f32 / 65535.0,
        &mut |_, _| {},
    )
    .unwrap();
    let hi_total = u64::from(summary.header.brick_count) * summary.header.hi_brick_bytes;
    eprintln!(
        "wrote {dim}^3 u16 (n = {BRICK}): {} bricks, {:.0} MiB in {:.2} s ({:.0} MB/s); hi-res \
         bricks {:.0} MiB = {:.1} x the cache budget",
        summary.header.brick_count,
        mib(summary.header.file_size),
        summary.elapsed.as_secs_f64(),
        summary.bytes_per_second() / 1e6,
        mib(hi_total),
        hi_total as f64 / cache_budget as f64
    );
    assert!(
        hi_total >= 4 * cache_budget,
        "the bricks must exceed the cache budget several times over"
    );

    // 2. Context and a warm-up of the mixed pipeline, then the RSS baseline.
    let ctx = common::validated_context();
    let tf = transfer_function(ALPHA);
    {
        let tiny = Arc::new(
            Volume::new(
                UVec3::splat(BRICK),
                Vec3::ONE,
                VoxelData::U16(vec![30000; BRICK.pow(3) as usize]),
            )
            .unwrap(),
        );
        let mut r = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        r.set_transfer_function(&tf).unwrap();
        r.set_source(VolumeSource::Bricks {
            source: Arc::new(VolumeBrickSource::new(tiny, BRICK, DownsampleFilter::Mean2).unwrap()),
            config: config(cache_budget),
        })
        .unwrap();
        r.set_levels(&[Level::Hi]).unwrap();
        r.render(&camera, &settings, SIZE, SIZE).unwrap();
    }
    let baseline = vm_hwm();

    // 3. Stream and render from the store.
    let start = Instant::now();
    let streamer = Arc::new(
        BrickStreamer::open(
            &path,
            StreamerConfig {
                ram_budget_bytes: ram_budget,
                record_load_order: false,
            },
        )
        .unwrap(),
    );
    let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
    renderer.set_transfer_function(&tf).unwrap();
    renderer
        .set_source(VolumeSource::Bricks {
            source: streamer.clone(),
            config: config(cache_budget),
        })
        .unwrap();
    let slots = renderer.brick_cache().unwrap().geometry().slot_count() as usize;
    let grid = streamer.store().grid();
    let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
    let active = vec![true; grid.brick_count()];
    let view = LodView::new(&camera, SIZE, SIZE).unwrap();
    let wanted = select_levels(
        &geometry,
        &view,
        streamer.store().value_ranges(),
        &active,
        &SelectionOptions::with_slots(slots),
    )
    .unwrap();
    let wanted_hi = wanted.iter().filter(|&&l| l == Level::Hi).count();
    let wanted_lo = wanted.iter().filter(|&&l| l == Level::Lo).count();
    assert!(
        wanted_hi > 0 && wanted_lo > 0,
        "a mixed plan: {wanted_hi} hi, {wanted_lo} lo"
    );
    let eye = camera.eye;
    let priority: Vec<f32> = (0..grid.brick_count())
        .map(|i| {
            let (lo, hi) = geometry.brick_box(grid.brick_coords(i));
            -eye.distance(0.5 * (lo + hi))
        })
        .collect();
    let plan = request_plan(&wanted, &priority);
    let wanted_bytes: usize = plan
        .iter()
        .map(|&(_, level, _)| streamer.store().level_bytes(level))
        .sum();
    streamer.request(&plan).unwrap();
    assert!(
        streamer.wait_settled(Duration::from_secs(60)),
        "the streamer did not settle"
    );
    let loaded_at = start.elapsed();
    let report = renderer.set_levels(&wanted).unwrap();
    let frame = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
    let stats = streamer.stats();
    let peak = vm_hwm();
    eprintln!(
        "cache: {slots} slots ({:.0} MiB budget); plan {wanted_hi} hi + {wanted_lo} lo, {:.1} MiB \
         wanted under a {:.0} MiB RAM budget; drawn {} hi + {} lo ({} fell back); loaded in \
         {:.2} s, frame at {:.2} s (ray-cast {:.0} ms); streamer peak {:.1} MiB",
        mib(cache_budget),
        wanted_bytes as f64 / (1 << 20) as f64,
        mib(ram_budget as u64),
        report.hi_bricks,
        report.lo_bricks,
        report.fallback_bricks,
        loaded_at.as_secs_f64(),
        start.elapsed().as_secs_f64(),
        frame
            .timing
            .gpu_raycast_ms
            .unwrap_or(frame.timing.cpu_frame_ms),
        mib(stats.peak_bytes as u64),
    );
    assert!(
        report.fallback_bricks > 0 && report.hi_bricks > 0,
        "the RAM budget should hold some but not all wanted hi-res bricks: {report:?}"
    );
    assert!(stats.peak_bytes <= ram_budget, "{stats:?}");
    eprintln!(
        "peak RSS (VmHWM) {:.1} MiB = baseline {:.1} MiB + {:.1} MiB (bound: RAM budget {:.0} + \
         {CACHE_COPIES} x cache budget {:.0} + {:.0} MiB)",
        mib(peak),
        mib(baseline),
        mib(peak.saturating_sub(baseline)),
        mib(ram_budget as u64),
        mib(cache_budget),
        mib(ALLOWANCE)
    );
    assert!(
        peak <= baseline + ram_budget as u64 + CACHE_COPIES * cache_budget + ALLOWANCE,
        "VmHWM {:.0} MiB exceeds the baseline {:.0} MiB + budgets + allowance",
        mib(peak),
        mib(baseline)
    );
    drop(renderer);
    drop(streamer);

    // 4. The in-core renderer on the half-resolution copy, built directly.
    let half = dim / 2;
    let mut voxels = Vec::with_capacity(half.pow(3) as usize);
    for z in 0..half as i32 {
        for y in 0..half as i32 {
            for x in 0..half as i32 {
                voxels.push(field.half_level(IVec3::new(x, y, z)) as u16);
            }
        }
    }
    let copy = Volume::new(UVec3::splat(half), Vec3::splat(2.0), VoxelData::U16(voxels)).unwrap();
    let mut plain = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
    plain
        .set_transfer_function(&transfer_function(1.0 - (1.0 - ALPHA).powi(2)))
        .unwrap();
    plain.set_source(VolumeSource::Volume(&copy)).unwrap();
    let expected = plain
        .render(
            &camera,
            &RenderSettings {
                samples_per_voxel: 2.0 * settings.samples_per_voxel,
                ..settings
            },
            SIZE,
            SIZE,
        )
        .unwrap()
        .pixels;
    drop(plain);

    // 5. Compare with the GPU-vs-reference tolerances.
    let visible = expected.iter().filter(|p| p.w > 0.5).count();
    assert!(
        visible > (SIZE * SIZE / 5) as usize,
        "the volume must cover the image ({visible} pixels)"
    );
    let d = common::diff(&frame.pixels, &expected, 1.0 / 255.0);
    eprintln!(
        "streamed vs in-core copy: max {:.5}, mean {:.6}, > 1/255: {:.4} %",
        d.max,
        d.mean,
        100.0 * d.large_fraction
    );
    let ok = d.mean <= 1.0 / 1000.0 && d.large_fraction <= 0.005 && d.max <= 6.0 / 255.0;
    if !ok {
        let out =
            common::write_failure_images("store-render", SIZE, SIZE, &frame.pixels, &expected);
        panic!("images differ: {d:?}; images in {}", out.display());
    }
    common::finish(ctx);
}
