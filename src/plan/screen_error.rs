//! Per-brick screen-space errors for the planner, from per-axis squared distance components,
//! with the same floating-point operations as [`crate::lod::screen_space_error`] (so the same
//! values).

use crate::bricks::ValueRange;
use crate::lod::{BrickGeometry, LodView, ViewProjection};

/// What the screen-space error of a brick with value range `range` is its projected pixel size
/// times, as [`crate::lod::screen_space_error`] computes it: the range width, `+inf` for a NaN
/// width, 0 for an empty or zero width; `-inf` for an inactive brick.
pub(super) fn width_factor(range: ValueRange, active: bool) -> f32 {
    let width = range.max - range.min;
    if !active {
        f32::NEG_INFINITY
    } else if width.is_nan() {
        f32::INFINITY
    } else if width > 0.0 {
        width
    } else {
        0.0
    }
}

/// Fills `error` for every brick from `width` ([`width_factor`]) and `axis_sq` with the squared
/// per-axis components of the box distance from the eye (one per brick slab, x, y, z; what
/// [`super::order::Distances`] reads the distances from): the error is
/// [`crate::lod::screen_space_error`] with the same floating-point operations, so that the
/// per-brick work is two additions, a square root, a division and a multiplication.
pub(super) fn compute_errors(
    geometry: &BrickGeometry,
    view: &LodView,
    width: &[f32],
    axis_sq: &mut [Vec<f32>; 3],
    error: &mut Vec<f32>,
) {
    let count = geometry.grid().brick_count();
    if count == 0 {
        return;
    }
    let eye = view.eye();
    let bounds = geometry.axis_bounds();
    for (axis, (sq, slabs)) in axis_sq.iter_mut().zip(&bounds).enumerate() {
        let p = eye[axis];
        sq.clear();
        sq.extend(slabs.iter().map(|&(lo, hi)| {
            // As `(min - p).max(p - max).max(0)` of `box_distance`, one axis.
            let (a, b) = (lo - p, p - hi);
            let c = if a > b { a } else { b };
            let c = if c > 0.0 { c } else { 0.0 };
            c * c
        }));
    }
    let lo_voxel = 2.0 * geometry.voxel_size().max_element();
    let height = view.image_height() as f32;
    // `lo_voxel * pixels_per_world_unit(d.max(lo_voxel))`, split by projection.
    let (scale, constant) = match view.projection() {
        ViewProjection::Perspective { tan_half_y, .. } => (2.0 * tan_half_y, None),
        ViewProjection::Orthographic { height: h } => (0.0, Some(lo_voxel * (height / h))),
    };
    error.resize(count, 0.0);
    let [sx, sy, sz] = &*axis_sq;
    let nx = sx.len();
    let mut rows = error.chunks_exact_mut(nx).zip(width.chunks_exact(nx));
    for &z2 in sz {
        for &y2 in sy {
            let Some((error, width)) = rows.next() else {
                return;
            };
            for ((e, &w), &x2) in error.iter_mut().zip(width).zip(sx) {
                let pixels = match constant {
                    Some(c) => c,
                    None => {
                        let dist = ((x2 + y2) + z2).sqrt();
                        lo_voxel * (height / (scale * dist.max(lo_voxel)))
                    }
                };
                *e = if w == 0.0 || w.is_infinite() {
                    w
                } else {
                    pixels * w
                };
            }
        }
    }
}

/// True when `a` and `b` hold the same bits (compared as bytes: one `memcmp`).
pub(super) fn same_bits(a: &[ValueRange], b: &[ValueRange]) -> bool {
    let (a, b): (&[u32], &[u32]) = (bytemuck::cast_slice(a), bytemuck::cast_slice(b));
    a == b
}
