//! The CPU reference ray-caster: the oracle the GPU output is checked against. Plain Rust that
//! mirrors the GLSL function by function (`camera`, `sampling`, `crate::optics`, [`cast_ray`]).

mod camera;
mod mixed;
mod sampling;

pub use camera::{depth_limit, generate_ray, intersect_box, safe_inverse, Ray};
pub use mixed::{
    active_axes, band, band_bounds, brick_of, dequantize, feature_touches_low_res, fixup_brick,
    fixup_value, low_res_border_coord, neighbour_bit, sample_hi_res_transition, sample_in_brick,
    sample_mixed, CacheImage, MixedVolume, ReferenceCache, Transition, FIXUP_PRECEDENCE,
};
pub use sampling::sample_volume;

use crate::optics::{classify, composite, correct_opacity, TransferFunction};
use crate::scene::RaycastParams;
use crate::volume::Volume;
use glam::{Vec2, Vec4};

/// Casts one ray. Mirrors `cast_ray` in `glsl/raycast.frag` step by step; returns premultiplied
/// RGB and opacity.
pub fn cast_ray(volume: &Volume, tf: &TransferFunction, p: &RaycastParams, ray: &Ray) -> Vec4 {
    cast_ray_until(volume, tf, p, ray, f32::INFINITY)
}

/// [`cast_ray`] with the ray also ending at `t_limit` (e.g. a host depth, see [`depth_limit`]):
/// `ray_end` in raycast.frag.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_until(
    volume: &Volume,
    tf: &TransferFunction,
    p: &RaycastParams,
    ray: &Ray,
    t_limit: f32,
) -> Vec4 {
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w).min(t_limit);
    let mut acc = Vec4::ZERO;
    if !(t0 < t1) {
        return acc;
    }
    let step_len = p.box_min.w;
    let inv_d0 = 1.0 / p.box_max.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    for i in 0..steps {
        let t_start = t0 + i as f32 * step_len;
        let len = step_len.min(t1 - t_start).max(0.0);
        let pos = ray.origin + ray.dir * (t_start + 0.5 * len);
        let value = sample_volume(volume, (pos - p.box_min.truncate()) / box_size);
        let rgba = classify(tf, p.tf_window.x, p.tf_window.y, value);
        let alpha = correct_opacity(rgba.w, len * inv_d0);
        acc = composite(acc, rgba.truncate(), alpha);
        if acc.w >= p.tf_window.z {
            break;
        }
    }
    acc
}

/// Casts one ray through a mixed-resolution brick cache. Mirrors the MIXED_RESOLUTION
/// `cast_ray` in `glsl/raycast.frag`: the same samples as [`cast_ray`]; samples in absent bricks
/// are skipped. `p` must come from [`RaycastParams::with_cache`].
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_mixed(
    mv: &MixedVolume,
    transition: Transition,
    tf: &TransferFunction,
    p: &RaycastParams,
    ray: &Ray,
) -> Vec4 {
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w);
    let mut acc = Vec4::ZERO;
    if !(t0 < t1) {
        return acc;
    }
    let step_len = p.box_min.w;
    let inv_d0 = 1.0 / p.box_max.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let to_voxel = p.volume_dims.truncate() / box_size;
    let voxel_origin = (ray.origin - p.box_min.truncate()) * to_voxel;
    let voxel_dir = ray.dir * to_voxel;
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    for i in 0..steps {
        let t_start = t0 + i as f32 * step_len;
        let len = step_len.min(t1 - t_start).max(0.0);
        let x = voxel_origin + voxel_dir * (t_start + 0.5 * len);
        let Some(value) = sample_mixed(mv, x, transition) else {
            continue;
        };
        let rgba = classify(tf, p.tf_window.x, p.tf_window.y, value);
        let alpha = correct_opacity(rgba.w, len * inv_d0);
        acc = composite(acc, rgba.truncate(), alpha);
        if acc.w >= p.tf_window.z {
            break;
        }
    }
    acc
}

/// Renders a whole image, row-major from the top-left pixel, premultiplied RGBA per pixel.
pub fn render(volume: &Volume, tf: &TransferFunction, p: &RaycastParams) -> Vec<Vec4> {
    render_with(p, |ray| cast_ray(volume, tf, p, ray))
}

/// Renders a whole mixed-resolution image (see [`cast_ray_mixed`]).
pub fn render_mixed(
    mv: &MixedVolume,
    transition: Transition,
    tf: &TransferFunction,
    p: &RaycastParams,
) -> Vec<Vec4> {
    render_with(p, |ray| cast_ray_mixed(mv, transition, tf, p, ray))
}

fn render_with(p: &RaycastParams, cast: impl Fn(&Ray) -> Vec4) -> Vec<Vec4> {
    let (w, h) = (p.viewport.x as u32, p.viewport.y as u32);
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            out.push(cast(&generate_ray(
                p,
                Vec2::new(x as f32 + 0.5, y as f32 + 0.5),
            )));
        }
    }
    out
}
