#version 460
// One ray per pixel: emission-absorption, front to back. Mirrors `cast_ray` in
// src/reference/mod.rs step by step.
#include "include/params.glsl"
#include "include/camera.glsl"
#include "include/optics.glsl"
#include "include/sampling.glsl"

layout(set = 0, binding = 0, std140) uniform Params {
    RaycastParams params;
};
layout(set = 0, binding = 1) uniform sampler3D volume_tex;
layout(set = 0, binding = 2) uniform sampler1D tf_tex;

layout(location = 0) out vec4 out_color;

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

void main() {
    out_color = cast_ray(generate_ray(params, gl_FragCoord.xy));
}
