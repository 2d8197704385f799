#version 460
// One ray per pixel: emission-absorption, front to back. Mirrors `cast_ray` (single resolution)
// and `cast_ray_mixed` (MIXED_RESOLUTION) in src/reference/mod.rs step by step.
// Variants (macros): MIXED_RESOLUTION reads the brick cache through the layout table and walks the
// ray brick by brick; SMOOTH_TRANSITIONS adds the C0 transition blend (mixed only).
#include "include/params.glsl"
#include "include/camera.glsl"
#include "include/optics.glsl"

layout(set = 0, binding = 0, std140) uniform Params {
    RaycastParams params;
};
layout(set = 0, binding = 2) uniform sampler1D tf_tex;

layout(location = 0) out vec4 out_color;

#ifdef MIXED_RESOLUTION
layout(set = 0, binding = 1) uniform sampler3D cache_tex;
layout(std430, set = 0, binding = 3) readonly buffer LayoutTable { vec4 layout_entries[]; };
layout(std430, set = 0, binding = 4) readonly buffer NeighbourTable { uint neighbour_bits[]; };

float cache_fetch(vec3 texel) {
    return textureLod(cache_tex, texel * params.cache_extent_inv.xyz, 0.0).r;
}
#include "include/mixed.glsl"
#else
#include "include/sampling.glsl"
layout(set = 0, binding = 1) uniform sampler3D volume_tex;
#endif

#ifndef MIXED_RESOLUTION
vec4 cast_ray(Ray ray) {
    vec2 hit = intersect_box(ray, params.box_min.xyz, params.box_max.xyz);
    float t0 = max(hit.x, params.forward.w);
    float t1 = min(hit.y, params.right.w);
    vec4 acc = vec4(0.0);
    if (!(t0 < t1)) {
        return acc;
    }
    float step_len = params.box_min.w;
    float inv_d0 = 1.0 / params.box_max.w;
    vec3 box_size = params.box_max.xyz - params.box_min.xyz;
    int steps = int(min(ceil((t1 - t0) / step_len), params.tf_window.w));
    for (int i = 0; i < steps; ++i) {
        float t_start = t0 + float(i) * step_len;
        float len = max(min(step_len, t1 - t_start), 0.0);
        vec3 p = ray.origin + ray.dir * (t_start + 0.5 * len);
        float value = sample_volume(volume_tex, (p - params.box_min.xyz) / box_size);
        vec4 rgba = classify(tf_tex, params.tf_window, value);
        float alpha = correct_opacity(rgba.a, len * inv_d0);
        acc = composite(acc, rgba.rgb, alpha);
        if (acc.a >= params.tf_window.z) {
            break;
        }
    }
    return acc;
}
#else
// Same samples as the single-resolution loop. The layout entry, neighbour bits and band bounds
// are read once per brick (when a sample lands in a new brick); absent bricks are skipped whole.
vec4 cast_ray(Ray ray) {
    vec2 hit = intersect_box(ray, params.box_min.xyz, params.box_max.xyz);
    float t0 = max(hit.x, params.forward.w);
    float t1 = min(hit.y, params.right.w);
    vec4 acc = vec4(0.0);
    if (!(t0 < t1)) {
        return acc;
    }
    float step_len = params.box_min.w;
    float inv_d0 = 1.0 / params.box_max.w;
    vec3 box_size = params.box_max.xyz - params.box_min.xyz;
    vec3 to_voxel = params.volume_dims.xyz / box_size;
    float n = params.volume_dims.w;
    ivec3 bricks = ivec3(ceil(params.volume_dims.xyz / n));
    Ray voxel_ray = Ray((ray.origin - params.box_min.xyz) * to_voxel, ray.dir * to_voxel);
    int steps = int(min(ceil((t1 - t0) / step_len), params.tf_window.w));
    ivec3 current = ivec3(-1);
    vec4 entry = vec4(0.0);
    uint bits = 0u;
    vec3 band_lo = vec3(-1.0);
    vec3 band_hi = vec3(n + 1.0);
    for (int i = 0; i < steps; ++i) {
        float t_start = t0 + float(i) * step_len;
        float len = max(min(step_len, t1 - t_start), 0.0);
        vec3 x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * len);
        ivec3 b = brick_of(x, n, bricks);
        if (any(notEqual(b, current))) {
            current = b;
            int bi = b.x + bricks.x * (b.y + bricks.y * b.z);
            entry = layout_entries[bi];
            if (entry.w == 0.0) {
                // Absent brick: jump to just before its exit; samples still inside are skipped
                // one by one below.
                float t_exit = intersect_box(voxel_ray, vec3(b) * n, vec3(b + 1) * n).y;
                i = max(i, int(floor((t_exit - t0) / step_len)) - 2);
                continue;
            }
            bits = neighbour_bits[bi];
#ifdef SMOOTH_TRANSITIONS
            band_bounds(bits, n, band_lo, band_hi);
#endif
        }
        if (entry.w == 0.0) {
            continue;
        }
        float value = sample_in_brick(x, b, entry, bits, band_lo, band_hi, n);
        vec4 rgba = classify(tf_tex, params.tf_window, value);
        float alpha = correct_opacity(rgba.a, len * inv_d0);
        acc = composite(acc, rgba.rgb, alpha);
        if (acc.a >= params.tf_window.z) {
            break;
        }
    }
    return acc;
}
#endif

void main() {
    out_color = cast_ray(generate_ray(params, gl_FragCoord.xy));
}
