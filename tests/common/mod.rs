//! Shared helpers for the GPU tests: a validated context, a finish step that fails on any
//! validation warning/error or leaked allocation, and image comparison with diagnostics.
#![allow(dead_code)] // reason: each test binary uses a different subset of these helpers.

pub mod levels;

use glam::{Vec3, Vec4};
use mixvol::gpu::{ContextDesc, GpuContext, MessageLog};
use std::path::PathBuf;
use std::sync::Arc;

/// A context with validation on. Fails (never skips) when Vulkan or the layer is missing: the
/// README's test command installs both.
pub fn validated_context() -> GpuContext {
    let ctx = GpuContext::new(&ContextDesc {
        validation: true,
        device_name: None,
    })
    .expect("Vulkan with VK_LAYER_KHRONOS_validation (scripts/setup.sh installs it)");
    assert!(ctx.info().validation);
    ctx
}

/// Drops the context and asserts that validation reported nothing at warning level or above and
/// that no allocation leaked (leaks are reported into the same log at shutdown).
pub fn finish(ctx: GpuContext) {
    let log: Arc<MessageLog> = ctx.message_log();
    assert_eq!(
        ctx.live_allocation_count(),
        0,
        "allocations still live at shutdown"
    );
    drop(ctx);
    let problems = log.warnings_and_errors();
    assert!(
        problems.is_empty(),
        "validation reported {} problem(s):\n{}",
        problems.len(),
        problems
            .iter()
            .map(|m| format!("{:?} {}: {}", m.severity, m.id_name, m.text))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Per-pixel comparison statistics.
#[derive(Clone, Copy, Debug)]
pub struct Diff {
    pub max: f32,
    pub mean: f32,
    /// Fraction of channels whose difference exceeds the "large" threshold passed in.
    pub large_fraction: f32,
}

/// The GPU-vs-reference tolerances of a camera-driven frame: mean and largest channel
/// difference, and the fraction of channels above [`FRAME_LARGE`].
pub const FRAME_MEAN_TOLERANCE: f32 = 1.0 / 1000.0;
/// A channel difference counted as large by [`assert_frame_matches`].
pub const FRAME_LARGE: f32 = 1.0 / 255.0;
/// At most this fraction of channels may differ by more than [`FRAME_LARGE`].
pub const FRAME_LARGE_FRACTION_TOLERANCE: f32 = 0.005;
/// No channel may differ by more than this.
pub const FRAME_MAX_TOLERANCE: f32 = 6.0 / 255.0;

/// Checks `frame` against `expected` (the CPU reference for the frame's residency) with the
/// `FRAME_*` tolerances over the covered pixels (alpha above 1/255 in either image, review M1:
/// the background no longer dilutes the statistics); writes both images and panics on failure.
/// Returns the covered pixels' differences. No floor on what is visible: a streamed source's
/// first frame may rightly be empty ([`assert_frame_matches_visible`] adds one).
pub fn assert_frame_matches(
    name: &str,
    frame: &mixvol::renderer::Frame,
    expected: &[Vec4],
) -> Diff {
    assert_frame_matches_visible(name, frame, expected, 0.0)
}

/// [`assert_frame_matches`], and both images show the volume over at least `floor` of the
/// pixels (so a regression that blanks both cannot pass).
pub fn assert_frame_matches_visible(
    name: &str,
    frame: &mixvol::renderer::Frame,
    expected: &[Vec4],
    floor: f32,
) -> Diff {
    let c = coverage(&frame.pixels, expected, 1.0 / 255.0, FRAME_LARGE);
    let d = c.diff;
    let ok = d.mean <= FRAME_MEAN_TOLERANCE
        && d.large_fraction <= FRAME_LARGE_FRACTION_TOLERANCE
        && d.max <= FRAME_MAX_TOLERANCE
        && c.actual_visible >= floor
        && c.expected_visible >= floor;
    if !ok {
        let dir = write_failure_images(name, frame.width, frame.height, &frame.pixels, expected);
        panic!(
            "{name}: GPU differs from the CPU reference for this residency (or shows less than \
             {floor} of the pixels): {c:?} (images in {})",
            dir.display()
        );
    }
    d
}

pub fn diff(a: &[Vec4], b: &[Vec4], large: f32) -> Diff {
    assert_eq!(a.len(), b.len());
    let mut max = 0.0f32;
    let mut sum = 0.0f64;
    let mut large_count = 0usize;
    for (x, y) in a.iter().zip(b) {
        for d in (*x - *y).abs().to_array() {
            max = max.max(d);
            sum += d as f64;
            if d > large {
                large_count += 1;
            }
        }
    }
    let n = (a.len() * 4) as f64;
    Diff {
        max,
        mean: (sum / n) as f32,
        large_fraction: (large_count as f64 / n) as f32,
    }
}

/// Writes actual / expected / difference PNGs under target/test-output/ for a failed comparison.
pub fn write_failure_images(
    name: &str,
    width: u32,
    height: u32,
    actual: &[Vec4],
    expected: &[Vec4],
) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("test-output");
    std::fs::create_dir_all(&dir).unwrap();
    let bg = Vec3::ZERO;
    let save = |suffix: &str, px: &[Vec4]| {
        let path = dir.join(format!("{name}-{suffix}.png"));
        mixvol::renderer::save_png(
            &mixvol::renderer::pixels_to_rgba8(px, width, height, bg),
            &path,
        )
        .unwrap();
    };
    save("actual", actual);
    save("expected", expected);
    let d: Vec<Vec4> = actual
        .iter()
        .zip(expected)
        .map(|(a, e)| ((*a - *e).abs() * 10.0).truncate().extend(1.0))
        .collect();
    save("difference-x10", &d);
    dir
}

/// A small deterministic xorshift generator for test inputs (no dependency, same on every run).
pub struct Rng(pub u64);

impl Rng {
    /// Next raw value.
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in 0..n.
    pub fn below(&mut self, n: u32) -> u32 {
        (self.next() % n as u64) as u32
    }
}

/// Coverage of an image pair: the visible fraction of each image, and the differences over the
/// covered pixels only (where either image has opacity above `covered_alpha`), so that a blank
/// or mostly-background image can neither pass a coverage floor nor dilute a mean.
#[derive(Debug)]
pub struct Coverage {
    /// Fraction of `actual`'s pixels with opacity above `VISIBLE_ALPHA`.
    pub actual_visible: f32,
    /// Fraction of `expected`'s pixels with opacity above `VISIBLE_ALPHA`.
    pub expected_visible: f32,
    /// Number of covered pixels compared.
    pub covered: usize,
    /// Differences over the covered pixels (all zero when none is covered).
    pub diff: Diff,
}

/// Opacity above which a pixel counts as visible for coverage floors.
pub const VISIBLE_ALPHA: f32 = 0.05;

/// [`Coverage`] of `actual` against `expected`; `large` as in [`diff`].
pub fn coverage(actual: &[Vec4], expected: &[Vec4], covered_alpha: f32, large: f32) -> Coverage {
    assert_eq!(actual.len(), expected.len());
    let n = actual.len().max(1) as f32;
    let visible = |img: &[Vec4]| img.iter().filter(|p| p.w > VISIBLE_ALPHA).count() as f32 / n;
    let (a, e): (Vec<Vec4>, Vec<Vec4>) = actual
        .iter()
        .zip(expected)
        .filter(|(a, e)| a.w > covered_alpha || e.w > covered_alpha)
        .map(|(a, e)| (*a, *e))
        .unzip();
    let diff = if a.is_empty() {
        Diff {
            max: 0.0,
            mean: 0.0,
            large_fraction: 0.0,
        }
    } else {
        diff(&a, &e, large)
    };
    Coverage {
        actual_visible: visible(actual),
        expected_visible: visible(expected),
        covered: a.len(),
        diff,
    }
}

/// One camera-driven residency step of a level source towards drawn voxels of at most
/// `target_pixels` on screen: `Renderer::update` with that error threshold (the renderer's
/// other budgets kept), and the choice it made. Renders then draw what the steps staged
/// without planning on their own (the caller steps).
pub fn step_levels(
    renderer: &mut mixvol::renderer::Renderer,
    camera: &mixvol::scene::Camera,
    settings: &mixvol::scene::RenderSettings,
    width: u32,
    height: u32,
    target_pixels: f32,
) -> mixvol::Result<mixvol::plan::LevelChoice> {
    let mut config = renderer.residency_config();
    config.options.error_threshold = target_pixels;
    renderer.set_residency_config(config);
    renderer.set_planned(false);
    renderer.update(camera, settings, width, height)?;
    Ok(renderer
        .last_level_choice()
        .expect("a level source's update chooses")
        .clone())
}

/// `count` points inside `dims` (voxel units) where levels meet or not: on the faces of bricks of
/// `brick` voxels, half a voxel either side, within half a voxel of a face, or anywhere.
pub fn critical_points(rng: &mut Rng, brick: u32, dims: glam::UVec3, count: usize) -> Vec<Vec3> {
    let coord = |rng: &mut Rng, extent: u32| -> f32 {
        let b = rng.below(extent / brick + 1) as f32 * brick as f32;
        let v = match rng.below(5) {
            0 => b,
            1 => b + 0.5 * (rng.unit() - 0.5),
            2 => b - 0.5,
            3 => b + 0.5,
            _ => rng.unit() * extent as f32,
        };
        v.clamp(0.02, extent as f32 - 0.02)
    };
    (0..count)
        .map(|_| Vec3::new(coord(rng, dims.x), coord(rng, dims.y), coord(rng, dims.z)))
        .collect()
}
