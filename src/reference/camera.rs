//! Ray generation and ray/box intersection. Mirrors `glsl/include/camera.glsl`.

use crate::scene::{RaycastParams, RAY_DIR_EPSILON};
use glam::{Vec2, Vec3};

/// A ray in world space.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

/// The ray through pixel centre `pixel` (framebuffer coordinates, origin top-left).
pub fn generate_ray(p: &RaycastParams, pixel: Vec2) -> Ray {
    let ndc = Vec2::new(
        pixel.x / p.viewport.x * 2.0 - 1.0,
        1.0 - pixel.y / p.viewport.y * 2.0,
    );
    let offset = ndc.x * p.right.truncate() + ndc.y * p.up.truncate();
    if p.eye.w > 0.5 {
        Ray {
            origin: p.eye.truncate() + offset,
            dir: p.forward.truncate(),
        }
    } else {
        Ray {
            origin: p.eye.truncate(),
            dir: (p.forward.truncate() + offset).normalize(),
        }
    }
}

/// Reciprocal direction with components kept at least `RAY_DIR_EPSILON` in magnitude.
pub fn safe_inverse(dir: Vec3) -> Vec3 {
    let mag = dir.abs().max(Vec3::splat(RAY_DIR_EPSILON));
    let sign = Vec3::select(dir.cmpge(Vec3::ZERO), Vec3::ONE, Vec3::NEG_ONE);
    sign / mag
}

/// Slab test: `(t_enter, t_exit)`; the ray misses when `t_enter >= t_exit`.
pub fn intersect_box(ray: &Ray, box_min: Vec3, box_max: Vec3) -> (f32, f32) {
    let inv = safe_inverse(ray.dir);
    let t0 = (box_min - ray.origin) * inv;
    let t1 = (box_max - ray.origin) * inv;
    let t_near = t0.min(t1);
    let t_far = t0.max(t1);
    (t_near.max_element(), t_far.min_element())
}

/// Ray parameter of a host depth-buffer surface: `depth` is the stored depth (Vulkan clip z in
/// [0, 1]) at pixel centre `pixel`. Mirrors `depth_limit` in camera.glsl.
pub fn depth_limit(p: &RaycastParams, ray: &Ray, pixel: Vec2, depth: f32) -> f32 {
    let ndc = pixel / Vec2::new(p.viewport.x, p.viewport.y) * 2.0 - Vec2::ONE;
    let w = p.world_from_clip * glam::Vec4::new(ndc.x, ndc.y, depth, 1.0);
    (w.truncate() / w.w - ray.origin).dot(ray.dir)
}

/// Narrows the ray interval `[t0, t1]` to the kept side (`n . p + d >= 0`) of each plane
/// (xyz: n, w: d); an empty result has `t1 <= t0`. Mirrors `clip_ray` in camera.glsl.
pub fn clip_ray(ray: &Ray, mut t0: f32, mut t1: f32, planes: &[glam::Vec4]) -> (f32, f32) {
    for plane in planes {
        let start = plane.truncate().dot(ray.origin) + plane.w;
        let rate = plane.truncate().dot(ray.dir);
        if rate > 0.0 {
            t0 = t0.max(-start / rate);
        } else if rate < 0.0 {
            t1 = t1.min(-start / rate);
        } else if start < 0.0 {
            t1 = t1.min(t0);
        }
    }
    (t0, t1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_parallel_rays_hit_and_miss_correctly() {
        let (lo, hi) = (Vec3::splat(-0.5), Vec3::splat(0.5));
        let hit = Ray {
            origin: Vec3::new(0.2, -0.3, -2.0),
            dir: Vec3::Z,
        };
        let (a, b) = intersect_box(&hit, lo, hi);
        assert!((a - 1.5).abs() < 1e-6 && (b - 2.5).abs() < 1e-6, "{a} {b}");
        let miss = Ray {
            origin: Vec3::new(0.7, 0.0, -2.0),
            dir: Vec3::Z,
        };
        let (a, b) = intersect_box(&miss, lo, hi);
        assert!(a >= b, "{a} {b}");
        // Exactly on the face plane x = 0.5, parallel to it: finite results, no NaN.
        let grazing = Ray {
            origin: Vec3::new(0.5, 0.0, -2.0),
            dir: Vec3::Z,
        };
        let (a, b) = intersect_box(&grazing, lo, hi);
        assert!(a.is_finite() && b.is_finite());
        let negative = Ray {
            origin: Vec3::new(0.0, 0.0, 2.0),
            dir: -Vec3::Z,
        };
        let (a, b) = intersect_box(&negative, lo, hi);
        assert!((a - 1.5).abs() < 1e-6 && (b - 2.5).abs() < 1e-6);
    }

    #[test]
    fn ray_from_inside_enters_behind_the_origin() {
        let ray = Ray {
            origin: Vec3::ZERO,
            dir: Vec3::new(1.0, 1.0, 0.0).normalize(),
        };
        let (a, b) = intersect_box(&ray, Vec3::splat(-0.5), Vec3::splat(0.5));
        assert!(a < 0.0 && b > 0.0);
        assert!((b - 0.5 * 2f32.sqrt()).abs() < 1e-6);
    }
}
