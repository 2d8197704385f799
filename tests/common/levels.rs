//! Helpers of the multi-level tests (`tests/level_field.rs`, `tests/three_level.rs`): a volume
//! with structure at every level's scale, per-brick level plans, and the continuity probe of
//! `tests/continuity.rs` with points on every level's critical places.

use super::Rng;
use glam::{IVec3, UVec3, Vec3};
use mixvol::volume::{Volume, VoxelData};

/// The bound on spread / eps of a smooth field: the data varies by at most 1 per voxel, the
/// level-0 band doubles the slope, and the spread spans 2 sqrt(3) eps: 14 (as
/// `tests/continuity.rs`). A jump of 1e-2 at eps = 1e-4 gives 100.
pub const SMOOTH_RATIO_BOUND: f32 = 14.0;

/// Per-voxel noise on a wave of about 14 voxels, so that every level differs from the next by
/// more than the probes' thresholds (a jump between coarse levels needs structure at that scale).
pub fn textured_volume(rng: &mut Rng, dims: UVec3) -> Volume {
    let mut data = Vec::with_capacity((dims.x * dims.y * dims.z) as usize);
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                let p = UVec3::new(x, y, z).as_vec3() + Vec3::splat(0.5);
                let wave =
                    (0.45 * p.x + 1.3).sin() * (0.37 * p.y + 0.2).cos() * (0.29 * p.z + 0.8).sin();
                data.push(0.4 * rng.unit() + 0.6 * (0.5 + 0.5 * wave));
            }
        }
    }
    Volume::new(dims, Vec3::ONE, VoxelData::F32(data)).unwrap()
}

/// One entry per brick of a `bricks` grid, x fastest.
pub fn per_brick(bricks: UVec3, f: impl Fn(UVec3) -> Option<u32>) -> Vec<Option<u32>> {
    let mut out = Vec::new();
    for z in 0..bricks.z {
        for y in 0..bricks.y {
            for x in 0..bricks.x {
                out.push(f(UVec3::new(x, y, z)));
            }
        }
    }
    out
}

/// A plan that keeps the one-level rule: the Chebyshev distance (in bricks) from `centre`, less
/// `shift`, clamped to `0..levels`.
pub fn distance_plan(bricks: UVec3, centre: IVec3, shift: i32, levels: u32) -> Vec<Option<u32>> {
    per_brick(bricks, |b| {
        let distance = (b.as_ivec3() - centre).abs().max_element();
        Some((distance - shift).clamp(0, levels as i32 - 1) as u32)
    })
}

/// A coordinate on one of the places where the field could break in a grid of bricks of `n`
/// voxels with `levels` levels: brick faces, band planes of every level (`0.5` at level 0, `2^k`
/// at a vertex level `k`), samples of every level, or random.
fn critical_coordinate(rng: &mut Rng, extent: f32, n: u32, levels: u32) -> f32 {
    let bricks = (extent / n as f32).ceil() as u32;
    let face = rng.below(bricks + 1) as f32 * n as f32;
    let spacing = (1u32 << rng.below(levels)) as f32;
    let v = match rng.below(7) {
        0 => face,
        1 => face + 0.5,
        2 => face - 0.5,
        3 => face + spacing,
        4 => face - spacing,
        5 => spacing * rng.below((extent / spacing) as u32 + 1) as f32,
        _ => rng.unit() * extent,
    };
    v.clamp(0.01, extent - 0.01)
}

/// `count` probe points in a volume of `dims` (see [`critical_coordinate`]).
pub fn probe_points(rng: &mut Rng, dims: UVec3, n: u32, levels: u32, count: usize) -> Vec<Vec3> {
    let e = dims.as_vec3();
    (0..count)
        .map(|_| {
            Vec3::new(
                critical_coordinate(rng, e.x, n, levels),
                critical_coordinate(rng, e.y, n, levels),
                critical_coordinate(rng, e.z, n, levels),
            )
        })
        .collect()
}

/// Largest spread / eps over `points` and the largest spread, at step `eps`: the spread is max -
/// min of the field at p + eps d over the 27 offsets d in {-1, 0, 1}^3; points where a probe falls
/// in an undrawn brick are skipped.
pub fn spread(field: &dyn Fn(Vec3) -> Option<f32>, points: &[Vec3], eps: f32) -> (f32, f32) {
    let mut worst_ratio = 0.0f32;
    let mut worst = 0.0f32;
    'points: for &p in points {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for k in 0..27 {
            let d = IVec3::new(k % 3, (k / 3) % 3, k / 9) - IVec3::ONE;
            let Some(v) = field(p + eps * d.as_vec3()) else {
                continue 'points;
            };
            lo = lo.min(v);
            hi = hi.max(v);
        }
        worst = worst.max(hi - lo);
        worst_ratio = worst_ratio.max((hi - lo) / eps);
    }
    (worst_ratio, worst)
}

/// Whether a brick of a 3x3x3 grid belongs to a class of neighbours of the centre brick.
pub type InClass = fn(UVec3) -> bool;

/// The neighbour classes of the centre brick of a 3x3x3 grid (`tests/continuity.rs`): a face, an
/// edge, a corner (touching the centre only diagonally), a face with its edges and corners, all
/// of them, and a checkerboard.
pub fn boundary_classes() -> [(&'static str, InClass); 6] {
    [
        ("face", |b| b == UVec3::new(0, 1, 1)),
        ("edge-only", |b| b == UVec3::new(0, 0, 1)),
        ("corner-only", |b| b == UVec3::ZERO),
        ("face+edge+corner", |b| b.x == 0),
        ("all-but-centre", |b| b != UVec3::ONE),
        ("checkerboard", |b| (b.x + b.y + b.z).is_multiple_of(2)),
    ]
}

/// The level of a brick `d` bricks (Chebyshev) from the grid's first corner on the staircase of
/// powers of two: 0 at the corner, then `floor(log2 d) + 1`, shifted by `shift` and clamped to
/// `0..levels`. Its steps sit at powers of two, so every level past 2 comes in aligned blocks of
/// `2^(k - 2)` bricks, and adjacent bricks differ by at most one level.
pub fn staircase_plan(bricks: UVec3, shift: i32, levels: u32) -> Vec<Option<u32>> {
    per_brick(bricks, |b| {
        let d = b.max_element();
        let step = if d == 0 {
            0
        } else {
            32 - d.leading_zeros() as i32
        };
        Some((step + shift).clamp(0, levels as i32 - 1) as u32)
    })
}
