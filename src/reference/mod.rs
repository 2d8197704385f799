//! The CPU reference ray-caster: the oracle the GPU output is checked against. Plain Rust that
//! mirrors the GLSL function by function (`camera`, `sampling`, `crate::optics`, [`cast_ray`]).

mod camera;
mod level_cache;
mod level_field;
mod mixed;
mod modes;
mod sampling;

pub use camera::{clip_ray, depth_limit, generate_ray, intersect_box, safe_inverse, Ray};
pub use level_cache::{skeleton_fixup_value, slots_needed, LevelReferenceCache};
pub use level_field::{level_band, LevelField, LevelSampling};
pub use mixed::{
    active_axes, band, band_bounds, brick_of, feature_touches_low_res, fixup_brick, fixup_value,
    low_res_border_coord, neighbour_bit, sample_hi_res_transition, sample_in_brick, sample_mixed,
    CacheImage, MixedVolume, ReferenceCache, FIXUP_PRECEDENCE,
};
pub use modes::{RayProgram, RayState};
pub use sampling::{sample_rgba_volume, sample_tricubic, sample_volume, tricubic_taps};

use crate::error::Result;
use crate::optics::preintegration::PreintegrationTable;
use crate::optics::{ClassificationTable, SamplingModel, TransferFunction};
use crate::scene::Transition;
use crate::scene::{RayFeatures, RaycastParams, RenderSettings};
use crate::volume::{RgbaVolume, Volume};
use glam::{Vec2, Vec3, Vec4};

/// The features of the default program: none, except the clip planes `p` holds (its
/// `iso_colour.w` count), which the GPU applies whenever the settings have any (`CLIP_PLANES`).
/// Planes held in `p` are never silently dropped by the default entry points.
fn default_features(p: &RaycastParams) -> RayFeatures {
    RayFeatures {
        clip_planes: p.iso_colour.w > 0.0,
        ..RayFeatures::default()
    }
}

/// Casts one ray with the default program (DVR, opacity-based sampling, unlit, cut by the clip
/// planes of `p`). Mirrors `cast_ray` in `glsl/raycast.frag` step by step; returns
/// premultiplied RGB and opacity.
pub fn cast_ray(volume: &Volume, tf: &TransferFunction, p: &RaycastParams, ray: &Ray) -> Vec4 {
    cast_ray_until(volume, tf, p, ray, f32::INFINITY)
}

/// [`cast_ray`] with the ray also ending at `t_limit` (e.g. a host depth, see [`depth_limit`]):
/// `ray_end` in raycast.frag.
pub fn cast_ray_until(
    volume: &Volume,
    tf: &TransferFunction,
    p: &RaycastParams,
    ray: &Ray,
    t_limit: f32,
) -> Vec4 {
    let table = ClassificationTable::new(tf, SamplingModel::Opacity);
    let field = volume_field(volume, p);
    let program = RayProgram {
        features: default_features(p),
        table: &table,
        preintegration: None,
        params: p,
        field: &field,
    };
    cast_ray_program(volume, &program, ray, t_limit)
}

/// The single-resolution field at a voxel position: `field_at` in raycast.frag.
pub fn volume_field<'a>(
    volume: &'a Volume,
    p: &RaycastParams,
) -> impl Fn(Vec3) -> Option<f32> + 'a {
    let dims = p.volume_dims.truncate();
    move |x| Some(sample_volume(volume, x / dims))
}

/// The mixed-resolution field at a voxel position (clamped into the volume; `None` in an absent
/// brick): `field_at` in raycast.frag (MIXED_RESOLUTION).
pub fn mixed_field<'a>(
    mv: &'a MixedVolume<'a>,
    transition: Transition,
    p: &RaycastParams,
) -> impl Fn(Vec3) -> Option<f32> + 'a {
    let dims = p.volume_dims.truncate();
    move |x| sample_mixed(mv, x.clamp(Vec3::ZERO, dims), transition)
}

/// Casts one ray through a single-resolution volume with `program` (whose field must be
/// [`volume_field`] of `volume`), ending at `t_limit` too. Mirrors `cast_ray` in raycast.frag.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_program(volume: &Volume, program: &RayProgram, ray: &Ray, t_limit: f32) -> Vec4 {
    let p = program.params;
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w).min(t_limit);
    let (t0, t1) = program.clipped(ray, t0, t1);
    let mut s = RayState::default();
    if !(t0 < t1) {
        return s.acc;
    }
    let step_len = p.box_min.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let to_voxel = p.volume_dims.truncate() / box_size;
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    for i in 0..steps {
        let t_start = t0 + i as f32 * step_len;
        let len = step_len.min(t1 - t_start).max(0.0);
        let pos = ray.origin + ray.dir * (t_start + 0.5 * len);
        let x = (pos - p.box_min.truncate()) * to_voxel;
        let value = if program.features.tricubic {
            sample_tricubic(program.field, x)
        } else {
            sample_volume(volume, (pos - p.box_min.truncate()) / box_size)
        };
        if program.integrate_sample(&mut s, value, len, x, ray.dir) {
            break;
        }
    }
    program.finish_ray(&s, ray.dir)
}

/// LaMar's coarse sampling: in a low-res brick, sample `i` and sample `i + 1` (if it lies in the
/// same brick) merge into one sample at their common boundary standing for both segments.
/// Updates `len` and `x` and returns the index of the last sample consumed. Mirrors
/// `merge_low_res_pair` in raycast.frag (which the GPU calls in low-res bricks only).
#[allow(clippy::too_many_arguments)] // reason: mirrors the GLSL signature.
fn merge_low_res_pair(
    mv: &MixedVolume,
    i: i32,
    steps: i32,
    (t0, t1): (f32, f32),
    step_len: f32,
    voxel_ray: &Ray,
    len: &mut f32,
    x: &mut Vec3,
) -> i32 {
    let b = brick_of(*x, mv.brick_size, mv.bricks);
    let bi = (b.x as u32 + mv.bricks.x * (b.y as u32 + mv.bricks.y * b.z as u32)) as usize;
    if mv.layout[bi][3] != 0.5 || i + 1 >= steps {
        return i;
    }
    let t_start = t0 + i as f32 * step_len;
    let t_next = t0 + (i + 1) as f32 * step_len;
    let len_next = step_len.min(t1 - t_next).max(0.0);
    let x_next = voxel_ray.origin + voxel_ray.dir * (t_next + 0.5 * len_next);
    if brick_of(x_next, mv.brick_size, mv.bricks) != b {
        return i;
    }
    *len = (2.0 * step_len).min(t1 - t_start).max(0.0);
    *x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * *len);
    i + 1
}

/// Casts one ray through a mixed-resolution brick cache with the default program (cut by the
/// clip planes of `p`, as [`cast_ray`]). Mirrors the
/// MIXED_RESOLUTION `cast_ray` in `glsl/raycast.frag`: the same samples as [`cast_ray`]; samples
/// in absent bricks are skipped. `p` must come from [`RaycastParams::with_cache`].
pub fn cast_ray_mixed(
    mv: &MixedVolume,
    transition: Transition,
    tf: &TransferFunction,
    p: &RaycastParams,
    ray: &Ray,
) -> Vec4 {
    let table = ClassificationTable::new(tf, SamplingModel::Opacity);
    let field = mixed_field(mv, transition, p);
    let program = RayProgram {
        features: default_features(p),
        table: &table,
        preintegration: None,
        params: p,
        field: &field,
    };
    cast_ray_mixed_program(mv, transition, &program, ray)
}

/// [`cast_ray_mixed`] with `program` (whose field must be [`mixed_field`] of `mv`).
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_mixed_program(
    mv: &MixedVolume,
    transition: Transition,
    program: &RayProgram,
    ray: &Ray,
) -> Vec4 {
    let p = program.params;
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w);
    let (t0, t1) = program.clipped(ray, t0, t1);
    let mut s = RayState::default();
    if !(t0 < t1) {
        return s.acc;
    }
    let step_len = p.box_min.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let to_voxel = p.volume_dims.truncate() / box_size;
    let voxel_origin = (ray.origin - p.box_min.truncate()) * to_voxel;
    let voxel_dir = ray.dir * to_voxel;
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    let mut i = -1;
    while i + 1 < steps {
        i += 1;
        let t_start = t0 + i as f32 * step_len;
        let mut len = step_len.min(t1 - t_start).max(0.0);
        let mut x = voxel_origin + voxel_dir * (t_start + 0.5 * len);
        if program.features.coarse_low_res {
            let voxel_ray = Ray {
                origin: voxel_origin,
                dir: voxel_dir,
            };
            i = merge_low_res_pair(
                mv,
                i,
                steps,
                (t0, t1),
                step_len,
                &voxel_ray,
                &mut len,
                &mut x,
            );
        }
        let Some(value) = sample_mixed(mv, x, transition) else {
            program.break_ray(&mut s, ray.dir);
            continue;
        };
        let value = if program.features.tricubic {
            sample_tricubic(program.field, x)
        } else {
            value
        };
        if program.integrate_sample(&mut s, value, len, x, ray.dir) {
            break;
        }
    }
    program.finish_ray(&s, ray.dir)
}

/// Casts one ray through a pre-classified RGBA volume whose weighted voxels (for the program's
/// sampling model, see [`RgbaVolume::weighted`]) are `weighted`. Mirrors `cast_ray` in
/// raycast.frag with RGBA_VOLUME.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_rgba(
    dims: glam::UVec3,
    weighted: &[Vec4],
    program: &RayProgram,
    ray: &Ray,
) -> Vec4 {
    let p = program.params;
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w);
    let (t0, t1) = program.clipped(ray, t0, t1);
    let mut s = RayState::default();
    if !(t0 < t1) {
        return s.acc;
    }
    let step_len = p.box_min.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    for i in 0..steps {
        let t_start = t0 + i as f32 * step_len;
        let len = step_len.min(t1 - t_start).max(0.0);
        let pos = ray.origin + ray.dir * (t_start + 0.5 * len);
        let w = sample_rgba_volume(dims, weighted, (pos - p.box_min.truncate()) / box_size);
        if program.integrate_weighted(&mut s, w, len) {
            break;
        }
    }
    s.acc
}

/// Runs `f` with the program of a pre-classified RGBA frame: only the sampling model matters to
/// `integrate_weighted` (there is no transfer function and no scalar field).
fn with_rgba_program<R>(
    settings: &RenderSettings,
    p: &RaycastParams,
    f: impl FnOnce(&RayProgram) -> R,
) -> R {
    let table = ClassificationTable::new(
        &TransferFunction::preset(crate::optics::TfPreset::ConstantWhite),
        settings.sampling_model,
    );
    let field = |_: Vec3| None;
    f(&RayProgram {
        features: settings.features(),
        table: &table,
        preintegration: None,
        params: p,
        field: &field,
    })
}

/// Renders a whole image of a pre-classified RGBA volume with the sampling model of `settings`.
pub fn render_rgba(volume: &RgbaVolume, settings: &RenderSettings, p: &RaycastParams) -> Vec<Vec4> {
    let weighted = volume.weighted(settings.sampling_model);
    with_rgba_program(settings, p, |program| {
        render_with(p, |ray| {
            cast_ray_rgba(volume.dims(), &weighted, program, ray)
        })
    })
}

/// Casts one ray through a pre-classified RGBA brick cache given as one scalar
/// [`MixedVolume`] per weighted channel (r, g, b, coefficient; all with the same layout): the
/// cache construction, fixup and transition blend are linear in the texel values, so the RGBA
/// field is exactly the four scalar fields side by side. Mirrors the MIXED_RESOLUTION +
/// RGBA_VOLUME `cast_ray` in raycast.frag (including LaMar's coarse steps).
#[allow(clippy::neg_cmp_op_on_partial_ord)] // reason: `!(t0 < t1)` mirrors the GLSL and also rejects NaN.
pub fn cast_ray_rgba_mixed(
    channels: &[MixedVolume; 4],
    transition: Transition,
    program: &RayProgram,
    ray: &Ray,
) -> Vec4 {
    let p = program.params;
    let mv = &channels[3];
    let (enter, exit) = intersect_box(ray, p.box_min.truncate(), p.box_max.truncate());
    let t0 = enter.max(p.forward.w);
    let t1 = exit.min(p.right.w);
    let (t0, t1) = program.clipped(ray, t0, t1);
    let mut s = RayState::default();
    if !(t0 < t1) {
        return s.acc;
    }
    let step_len = p.box_min.w;
    let box_size = p.box_max.truncate() - p.box_min.truncate();
    let to_voxel = p.volume_dims.truncate() / box_size;
    let voxel_origin = (ray.origin - p.box_min.truncate()) * to_voxel;
    let voxel_dir = ray.dir * to_voxel;
    let steps = ((t1 - t0) / step_len).ceil().min(p.tf_window.w) as i32;
    let mut i = -1;
    while i + 1 < steps {
        i += 1;
        let t_start = t0 + i as f32 * step_len;
        let mut len = step_len.min(t1 - t_start).max(0.0);
        let mut x = voxel_origin + voxel_dir * (t_start + 0.5 * len);
        if program.features.coarse_low_res {
            let voxel_ray = Ray {
                origin: voxel_origin,
                dir: voxel_dir,
            };
            i = merge_low_res_pair(
                mv,
                i,
                steps,
                (t0, t1),
                step_len,
                &voxel_ray,
                &mut len,
                &mut x,
            );
        }
        let mut weighted = Vec4::ZERO;
        let mut present = true;
        for (c, channel) in channels.iter().enumerate() {
            match sample_mixed(channel, x, transition) {
                Some(v) => weighted[c] = v,
                None => present = false,
            }
        }
        if !present {
            program.break_ray(&mut s, ray.dir);
            continue;
        }
        if program.integrate_weighted(&mut s, weighted, len) {
            break;
        }
    }
    s.acc
}

/// Renders a whole image of a pre-classified RGBA brick cache (see [`cast_ray_rgba_mixed`]).
pub fn render_rgba_mixed(
    channels: &[MixedVolume; 4],
    transition: Transition,
    settings: &RenderSettings,
    p: &RaycastParams,
) -> Vec<Vec4> {
    with_rgba_program(settings, p, |program| {
        render_with(p, |ray| {
            cast_ray_rgba_mixed(channels, transition, program, ray)
        })
    })
}

/// The tables a scene's settings call for: the classification table for its sampling model and,
/// with pre-integration, the 2D table for its step.
pub fn scene_tables(
    tf: &TransferFunction,
    settings: &RenderSettings,
    p: &RaycastParams,
) -> Result<(ClassificationTable, Option<PreintegrationTable>)> {
    let features = settings.features();
    let table = ClassificationTable::new(tf, features.sampling_model);
    let preintegration = if features.preintegrated {
        Some(PreintegrationTable::build(
            &table,
            p.box_min.w / p.box_max.w,
        )?)
    } else {
        None
    };
    Ok((table, preintegration))
}

/// Renders a whole single-resolution image with every effect `settings` calls for.
pub fn render_scene(
    volume: &Volume,
    tf: &TransferFunction,
    settings: &RenderSettings,
    p: &RaycastParams,
) -> Result<Vec<Vec4>> {
    let (table, preintegration) = scene_tables(tf, settings, p)?;
    let field = volume_field(volume, p);
    let program = RayProgram {
        features: settings.features(),
        table: &table,
        preintegration: preintegration.as_ref(),
        params: p,
        field: &field,
    };
    Ok(render_with(p, |ray| {
        cast_ray_program(volume, &program, ray, f32::INFINITY)
    }))
}

/// The features a mixed-resolution frame runs with: those of `settings`, without tricubic
/// reconstruction while a brick coarser than level 0 is resident (as the GPU pass decides).
pub fn mixed_features(mv: &MixedVolume, settings: &RenderSettings) -> RayFeatures {
    let features = settings.features();
    RayFeatures {
        tricubic: features.tricubic && !mv.layout.iter().any(|e| e[3] != 0.0 && e[3] != 1.0),
        ..features
    }
}

/// Renders a whole mixed-resolution image with every effect `settings` calls for.
pub fn render_mixed_scene(
    mv: &MixedVolume,
    transition: Transition,
    tf: &TransferFunction,
    settings: &RenderSettings,
    p: &RaycastParams,
) -> Result<Vec<Vec4>> {
    let (table, preintegration) = scene_tables(tf, settings, p)?;
    let field = mixed_field(mv, transition, p);
    let program = RayProgram {
        features: mixed_features(mv, settings),
        table: &table,
        preintegration: preintegration.as_ref(),
        params: p,
        field: &field,
    };
    Ok(render_with(p, |ray| {
        cast_ray_mixed_program(mv, transition, &program, ray)
    }))
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
