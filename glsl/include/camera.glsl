// Ray generation and ray/box intersection. Mirrors src/reference/camera.rs function by function.
#ifndef CAMERA_GLSL
#define CAMERA_GLSL
#include "params.glsl"

struct Ray {
    vec3 origin;
    vec3 dir;
};

// `pixel` is a pixel centre in framebuffer coordinates (origin top-left), as gl_FragCoord.xy.
Ray generate_ray(RaycastParams p, vec2 pixel) {
    vec2 ndc = vec2(pixel.x / p.viewport.x * 2.0 - 1.0, 1.0 - pixel.y / p.viewport.y * 2.0);
    vec3 offset = ndc.x * p.right.xyz + ndc.y * p.up.xyz;
    Ray ray;
    if (p.eye.w > 0.5) {
        ray.origin = p.eye.xyz + offset;
        ray.dir = p.forward.xyz;
    } else {
        ray.origin = p.eye.xyz;
        ray.dir = normalize(p.forward.xyz + offset);
    }
    return ray;
}

// Narrows the ray interval [t0, t1] to the kept side (n . p + d >= 0) of each of the
// `count` planes (xyz: n, w: d); an empty result has t1 <= t0. Mirrors `clip_ray`.
vec2 clip_ray(Ray ray, float t0, float t1, vec4 planes[MAX_CLIP_PLANES], int count) {
    for (int k = 0; k < count; ++k) {
        float start = dot(planes[k].xyz, ray.origin) + planes[k].w;
        float rate = dot(planes[k].xyz, ray.dir);
        if (rate > 0.0) {
            t0 = max(t0, -start / rate);
        } else if (rate < 0.0) {
            t1 = min(t1, -start / rate);
        } else if (start < 0.0) {
            t1 = min(t1, t0);
        }
    }
    return vec2(t0, t1);
}

// Replaces direction components smaller than RAY_DIR_EPSILON in magnitude by +-RAY_DIR_EPSILON so
// the slab test never divides by zero (axis-parallel rays) and never forms 0 * inf.
vec3 safe_inverse(vec3 dir) {
    vec3 mag = max(abs(dir), vec3(RAY_DIR_EPSILON));
    vec3 s = mix(vec3(-1.0), vec3(1.0), greaterThanEqual(dir, vec3(0.0)));
    return s / mag;
}

// Slab test. Returns (t_enter, t_exit); the ray misses when t_enter >= t_exit.
vec2 intersect_box(Ray ray, vec3 box_min, vec3 box_max) {
    vec3 inv = safe_inverse(ray.dir);
    vec3 t0 = (box_min - ray.origin) * inv;
    vec3 t1 = (box_max - ray.origin) * inv;
    vec3 t_near = min(t0, t1);
    vec3 t_far = max(t0, t1);
    float t_enter = max(max(t_near.x, t_near.y), t_near.z);
    float t_exit = min(min(t_far.x, t_far.y), t_far.z);
    return vec2(t_enter, t_exit);
}

// Ray parameter of the host's depth-buffer surface at this pixel: `depth` is the stored depth
// (Vulkan clip z in [0, 1]), `pixel` the pixel centre; `world_from_clip` undoes the host's
// projection. Rays stop there, so the volume composites correctly with opaque geometry.
float depth_limit(RaycastParams p, Ray ray, vec2 pixel, float depth) {
    vec2 ndc = pixel / p.viewport.xy * 2.0 - 1.0;
    vec4 w = p.world_from_clip * vec4(ndc, depth, 1.0);
    return dot(w.xyz / w.w - ray.origin, ray.dir);
}

#endif
