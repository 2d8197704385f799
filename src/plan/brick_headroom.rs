//! A brick's headroom for [`super::LevelChooser`] (its step 1), computed for every brick from
//! per-axis terms: log2 of the target over the projected size of a hi-res voxel at the brick's
//! nearest point, infinite outside the frustum; the box tests and distances are summed in the
//! order [`crate::lod::LodView::box_outside_frustum`] and a box's distance take them, a row of
//! bricks at a time on vector lanes.
use crate::bricks::ValueRange;
use crate::lod::{BrickGeometry, LodView, ViewProjection};
use glam::UVec3;

/// The brick slabs' terms along one axis (step 1), one entry per slab.
#[derive(Clone, Debug, Default)]
pub(super) struct AxisTerms {
    /// Per frustum plane: the normal's component times the slab's bound on the side it points
    /// to (the box's positive vertex, as [`crate::scene::ClipPlane::box_clipped`] takes it).
    pub corner: [Vec<f32>; 6],
    /// The squared distance from the eye to the slab along the axis (0 inside it).
    pub distance2: Vec<f32>,
}

/// A brick's headroom from its squared distance `d2` to the eye: `constant +
/// half_log_distance * log2(max(d2, voxel2))`.
#[derive(Clone, Copy, Debug)]
pub(super) struct HeadroomTerms {
    pub constant: f32,
    /// 0.5 for a perspective view, 0 for an orthographic one.
    pub half_log_distance: f32,
    pub voxel2: f32,
}

/// Step 1 for one row of bricks along x (`out`, one per brick): the headroom of each brick
/// in the frustum, infinite for one outside. `yz` holds the row's y and z terms of the planes,
/// `distance2` its squared distances along y and z. Straight-line arithmetic per brick, so
/// that it runs on vector lanes.
pub(super) fn headroom_row(
    x: &AxisTerms,
    yz: [[f32; 6]; 2],
    offsets: [f32; 6],
    distance2: [f32; 2],
    terms: HeadroomTerms,
    out: &mut [f32],
) {
    let n = out.len();
    let corner: [&[f32]; 6] = std::array::from_fn(|p| &x.corner[p][..n]);
    let dx2 = &x.distance2[..n];
    for (i, out) in out.iter_mut().enumerate() {
        let mut inside = f32::INFINITY;
        for p in 0..6 {
            inside = inside.min(corner[p][i] + yz[0][p] + yz[1][p] + offsets[p]);
        }
        let d2 = (dx2[i] + distance2[0] + distance2[1]).max(terms.voxel2);
        let h = terms.constant + terms.half_log_distance * fast_log2(d2);
        *out = if inside >= 0.0 { h } else { f32::INFINITY };
    }
}

impl AxisTerms {
    /// The terms of the `bricks[axis]` brick slabs of `geometry` along `axis` for `view`.
    pub(super) fn fill(&mut self, geometry: &BrickGeometry, view: &LodView, axis: usize) {
        let eye = view.eye();
        let planes = view.frustum_planes();
        for corner in &mut self.corner {
            corner.clear();
        }
        self.distance2.clear();
        for i in 0..geometry.grid().bricks_per_axis()[axis] {
            let mut brick = UVec3::ZERO;
            brick[axis] = i;
            let (min, max) = geometry.brick_box(brick);
            let (lo, hi) = (min[axis], max[axis]);
            for (p, corner) in self.corner.iter_mut().enumerate() {
                let n = planes[p].normal[axis];
                corner.push(n * if n >= 0.0 { hi } else { lo });
            }
            let d = (lo - eye[axis]).max(eye[axis] - hi).max(0.0);
            self.distance2.push(d * d);
        }
    }
}

impl HeadroomTerms {
    /// headroom = log2(target / (voxel * pixels per world unit at the distance)): a constant,
    /// plus log2 of the distance (at least a voxel) for a perspective view; `voxel` the longest
    /// side of a hi-res voxel, `target_pixels` the largest on-screen size of a drawn voxel.
    pub(super) fn new(view: &LodView, voxel: f32, target_pixels: f32) -> Self {
        Self {
            constant: (target_pixels / (voxel * view.pixels_per_world_unit(1.0))).log2(),
            half_log_distance: match view.projection() {
                ViewProjection::Perspective { .. } => 0.5,
                ViewProjection::Orthographic { .. } => 0.0,
            },
            voxel2: voxel * voxel,
        }
    }
}

/// What a brick's value range adds to its headroom ([`super::LevelRequest::value_ranges`]):
/// `log2(1 / w)` levels for a range `w` wide (the screen-space error is the voxel's size times
/// `w`), infinite for a range of one value, none for a range 1 or more wide or NaN.
pub(super) fn value_headroom(range: ValueRange) -> f32 {
    let width = range.max - range.min;
    if width.is_nan() || width >= 1.0 {
        0.0
    } else if width > 0.0 {
        -fast_log2(width)
    } else {
        f32::INFINITY
    }
}

/// log2 of a positive finite `x` (as [`f32::log2`] within 1e-6, relative past 1, tested), without a call: the
/// exponent, and of the mantissa `m` in `[sqrt(1/2), sqrt(2))` the series
/// `2 atanh(s) = ln m`, `s = (m - 1) / (m + 1)`, to `s^9`.
fn fast_log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let high = m > std::f32::consts::SQRT_2;
    let m = if high { m * 0.5 } else { m };
    exponent += i32::from(high);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = 1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 / 9.0)));
    exponent as f32 + 2.0 * s * series * std::f32::consts::LOG2_E
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_log2_is_log2() {
        let mut worst = 0.0f32;
        let mut x = 1e-12f32;
        while x < 1e12 {
            worst = worst.max((fast_log2(x) - x.log2()).abs() / x.log2().abs().max(1.0));
            x *= 1.000_37;
        }
        for x in [1.0, 2.0, 0.5, std::f32::consts::SQRT_2, 3.0, 1e-30, 1e30] {
            worst = worst.max((fast_log2(x) - x.log2()).abs() / x.log2().abs().max(1.0));
        }
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn a_value_range_adds_log2_of_its_inverse_width() {
        let range = |min: f32, max: f32| ValueRange { min, max };
        assert!((value_headroom(range(0.25, 0.5)) - 2.0).abs() < 1e-6);
        assert!((value_headroom(range(0.0, 0.1)) - 10f32.log2()).abs() < 1e-5);
        assert_eq!(value_headroom(range(0.0, 1.0)), 0.0);
        assert_eq!(value_headroom(range(-1.0, 2.0)), 0.0);
        assert_eq!(value_headroom(range(f32::NAN, 1.0)), 0.0);
        assert_eq!(value_headroom(range(0.5, 0.5)), f32::INFINITY);
        assert_eq!(value_headroom(ValueRange::EMPTY), f32::INFINITY);
    }
}
