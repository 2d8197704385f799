#version 460
// One ray per pixel: emission-absorption, front to back. Mirrors `cast_ray` (single resolution)
// and `cast_ray_mixed` (MIXED_RESOLUTION) in src/reference/mod.rs step by step.
// Variants (macros): MIXED_RESOLUTION reads the brick cache through the layout table and walks the
// ray brick by brick; SMOOTH_TRANSITIONS adds the C0 transition blend and ABSENT_BRICKS the jump
// over absent bricks (mixed only; a cache with every brick resident leaves it out); what each
// sample does (mode, shading, sampling model, ...) is include/modes.glsl's business.
#include "include/params.glsl"
#include "include/camera.glsl"
#include "include/optics.glsl"
#include "include/sampling.glsl"

layout(set = 0, binding = BINDING_PARAMS, std140) uniform Params {
    RaycastParams params;
};
layout(set = 0, binding = BINDING_TF) uniform sampler1D tf_tex;

layout(location = 0) out vec4 out_color;

#ifdef HOST_DEPTH
layout(set = 0, binding = BINDING_HOST_DEPTH) uniform sampler2D depth_tex;
#endif
#ifdef PREINTEGRATED
layout(set = 0, binding = BINDING_PREINTEGRATION) uniform sampler2D preint_tex;
#endif

// The far end of the ray: the volume box exit, the far plane and (HOST_DEPTH) the host's depth.
float ray_end(Ray ray, float box_exit) {
    float t1 = min(box_exit, params.right.w);
#ifdef HOST_DEPTH
    float depth = texelFetch(depth_tex, ivec2(gl_FragCoord.xy), 0).r;
    t1 = min(t1, depth_limit(params, ray, gl_FragCoord.xy, depth));
#endif
    return t1;
}

#ifdef MIXED_RESOLUTION
layout(set = 0, binding = BINDING_VOLUME) uniform sampler3D cache_tex;
layout(std430, set = 0, binding = BINDING_LAYOUT_TABLE) readonly buffer LayoutTable { vec4 layout_entries[]; };
layout(std430, set = 0, binding = BINDING_NEIGHBOUR_TABLE) readonly buffer NeighbourTable { uint neighbour_bits[]; };

#ifdef RGBA_VOLUME
#define FIELD vec4
// The field's value to the scalar-only code (gradients, iso): the coefficient channel.
float field_scalar(vec4 v) {
    return v.a;
}
#else
#define FIELD float
float field_scalar(float v) {
    return v;
}
#endif

// Implicit-LOD fetch, as for the plain volume texture: the cache has one mip level and equal
// min/mag filters, so the (possibly undefined) derivatives cannot change the result, and
// llvmpipe's explicit-LOD path (textureLod/textureGrad) costs 1.45x against 1.28x of the plain
// ray-cast (docs/performance.md).
FIELD cache_fetch(vec3 texel) {
#ifdef RGBA_VOLUME
    return texture(cache_tex, texel * params.cache_extent_inv.xyz);
#else
    return texture(cache_tex, texel * params.cache_extent_inv.xyz).r;
#endif
}
#include "include/mixed.glsl"

// The brick b of volume point x and what sampling in it needs: its layout entry, neighbour bits
// and band bounds (bits are 0 for low-res and absent bricks, so they have no band; without
// transitions no brick has one). Mirrors the lookup in `sample_mixed`.
void look_up_brick(vec3 x, float n, ivec3 bricks, out ivec3 b, out vec4 entry, out uint bits,
                   out vec3 band_lo, out vec3 band_hi) {
    b = brick_of(x, n, bricks);
    int bi = b.x + bricks.x * (b.y + bricks.y * b.z);
    entry = layout_entries[bi];
#ifdef SMOOTH_TRANSITIONS
    // Only a level-0 brick (t_w = 1) blends; the coarser bits of a coarser brick in the
    // three-level cache serve its skeleton fixup alone.
    bits = entry.w == 1.0 ? neighbour_bits[bi] : 0u;
#else
    bits = 0u;
#endif
    band_bounds(bits, n, band_lo, band_hi);
}

// The reconstructed field at voxel position x (clamped into the volume), as the ray's samples
// see it; `present` is false in an absent brick.
float field_at(vec3 x, out bool present) {
    float n = params.volume_dims.w;
    ivec3 bricks = ivec3(ceil(params.volume_dims.xyz / n));
    x = clamp(x, vec3(0.0), params.volume_dims.xyz);
#ifdef SMOOTH_TRANSITIONS
    ivec3 b;
    vec4 entry;
    uint bits;
    vec3 band_lo;
    vec3 band_hi;
    look_up_brick(x, n, bricks, b, entry, bits, band_lo, band_hi);
    present = entry.w != 0.0;
    return present ? field_scalar(sample_in_brick(x, b, entry, bits, band_lo, band_hi, n)) : 0.0;
#else
    ivec3 b = brick_of(x, n, bricks);
    vec4 entry = layout_entries[b.x + bricks.x * (b.y + bricks.y * b.z)];
    present = entry.w != 0.0;
    return present ? field_scalar(cache_fetch(x * entry.w + entry.xyz)) : 0.0;
#endif
}
#else
#include "include/sampling.glsl"
layout(set = 0, binding = BINDING_VOLUME) uniform sampler3D volume_tex;

// The reconstructed field at voxel position x (clamp-to-edge outside the volume); for an RGBA
// volume its coefficient channel (unused: RGBA volumes have no gradient effects).
float field_at(vec3 x, out bool present) {
    present = true;
#ifdef RGBA_VOLUME
    return texture(volume_tex, x / params.volume_dims.xyz).a;
#else
    return sample_volume(volume_tex, x / params.volume_dims.xyz);
#endif
}
#endif

#ifdef TRICUBIC
// The cubic B-spline of the field at voxel position x from 8 trilinear fetches; a fetch in an
// absent brick takes the trilinear value at x itself. Mirrors `sample_tricubic`.
float sample_tricubic(vec3 x) {
    mat3 taps = tricubic_taps(x);
    bool present;
    float centre = field_at(x, present);
    float sum = 0.0;
    for (int k = 0; k < 8; ++k) {
        ivec3 side = ivec3(k & 1, (k >> 1) & 1, (k >> 2) & 1);
        vec3 p = mix(taps[0], taps[1], vec3(side));
        vec3 w = mix(taps[2], 1.0 - taps[2], vec3(side));
        float v = field_at(p, present);
        sum += w.x * w.y * w.z * (present ? v : centre);
    }
    return sum;
}
#endif

// The field the samples, gradients and iso refinement see: trilinear, or TRICUBIC its B-spline.
float field_value(vec3 x, out bool present) {
#ifdef TRICUBIC
    present = true;
    return sample_tricubic(x);
#else
    return field_at(x, present);
#endif
}
#include "include/modes.glsl"

vec3 sample_gradient(vec3 x, float value, bool deep, vec4 entry) {
#ifdef MIXED_RESOLUTION
    if (deep) {
        // The plain fetches field_at would make (same brick, no band), without its lookups.
        float h = params.mode.w;
        vec3 to_voxel = params.volume_dims.xyz / (params.box_max.xyz - params.box_min.xyz);
        vec3 g;
        for (int k = 0; k < 3; ++k) {
            vec3 e = vec3(0.0);
            e[k] = h;
            float hi = field_scalar(cache_fetch((x + e) * entry.w + entry.xyz));
            float lo = field_scalar(cache_fetch((x - e) * entry.w + entry.xyz));
            g[k] = (hi - lo) / (h + h);
        }
        return g * to_voxel;
    }
#endif
    return field_gradient(x, value);
}

// One sample of the mixed-resolution loops: scalar samples go through the render mode,
// pre-classified RGBA samples are composited directly.
#if defined(MIXED_RESOLUTION) && defined(RGBA_VOLUME)
#define INTEGRATE(s, value, len, x, dir, deep, entry) integrate_weighted(s, value, len)
#else
#define INTEGRATE(s, value, len, x, dir, deep, entry) integrate_sample(s, value, len, x, dir, deep, entry)
#endif

#ifndef MIXED_RESOLUTION
vec4 cast_ray(Ray ray) {
    vec2 hit = intersect_box(ray, params.box_min.xyz, params.box_max.xyz);
    float t0 = max(hit.x, params.forward.w);
    float t1 = ray_end(ray, hit.y);
#ifdef CLIP_PLANES
    vec2 kept = clip_ray(ray, t0, t1, params.clip_planes, int(params.iso_colour.w));
    t0 = kept.x;
    t1 = kept.y;
#endif
    RayState s = begin_ray();
    if (!(t0 < t1)) {
        return s.acc;
    }
    float step_len = params.box_min.w;
    vec3 box_size = params.box_max.xyz - params.box_min.xyz;
    vec3 to_voxel = params.volume_dims.xyz / box_size;
    int steps = int(min(ceil((t1 - t0) / step_len), params.tf_window.w));
    for (int i = 0; i < steps; ++i) {
        float t_start = t0 + float(i) * step_len;
        float len = max(min(step_len, t1 - t_start), 0.0);
        vec3 p = ray.origin + ray.dir * (t_start + 0.5 * len);
#if defined(RGBA_VOLUME)
        vec4 weighted = texture(volume_tex, (p - params.box_min.xyz) / box_size);
        if (integrate_weighted(s, weighted, len)) {
            break;
        }
#else
#ifdef TRICUBIC
        float value = sample_tricubic((p - params.box_min.xyz) * to_voxel);
#else
        float value = sample_volume(volume_tex, (p - params.box_min.xyz) / box_size);
#endif
        if (integrate_sample(s, value, len, (p - params.box_min.xyz) * to_voxel, ray.dir, false,
                             vec4(0.0))) {
            break;
        }
#endif
    }
    return finish_ray(s, ray.dir);
}
#else
// One run of interior samples up to END; DEEP (a constant) picks the gradient path. A finished
// ray sets i = steps and leaves: finish_ray runs once, after the loops (inlined in a loop body it
// would run, masked, at every sample on SIMD CPUs).
#ifdef COARSE_LOW_RES
#define COARSE_PAIR(i) if (entry.w == 0.5) { \
    i = merge_low_res_pair(i, steps, t0, t1, step_len, voxel_ray, b, n, bricks, len, x); }
#else
#define COARSE_PAIR(i)
#endif
#define INTERIOR_RUN(END, DEEP) \
        for (; i < END; ++i) { \
            t_start = t0 + float(i) * step_len; \
            len = max(min(step_len, t1 - t_start), 0.0); \
            x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * len); \
            COARSE_PAIR(i) \
            if (INTEGRATE(s, cache_fetch(x * entry.w + entry.xyz), len, x, ray.dir, DEEP, entry)) { \
                i = steps; \
                break; \
            } \
        }

// Index of the first sample whose midpoint t0 + (i + 0.5) * step lies at or after t.
int first_sample_after(float t, float t0, float step_len) {
    return int(ceil((t - t0) / step_len - 0.5));
}

#ifdef COARSE_LOW_RES
// LaMar's coarse sampling: in a low-res brick, sample i and sample i + 1 (if it lies in the same
// brick) merge into one sample at their common boundary standing for both segments. Updates
// `len` and `x` and returns the index of the last sample consumed. Mirrors the
// `coarse_low_res` step of `cast_ray_mixed_program`.
int merge_low_res_pair(int i, int steps, float t0, float t1, float step_len, Ray voxel_ray,
                       ivec3 b, float n, ivec3 bricks, inout float len, inout vec3 x) {
    if (i + 1 >= steps) {
        return i;
    }
    float t_start = t0 + float(i) * step_len;
    float t_next = t0 + float(i + 1) * step_len;
    float len_next = max(min(step_len, t1 - t_next), 0.0);
    vec3 x_next = voxel_ray.origin + voxel_ray.dir * (t_next + 0.5 * len_next);
    if (any(notEqual(brick_of(x_next, n, bricks), b))) {
        return i;
    }
    len = max(min(2.0 * step_len, t1 - t_start), 0.0);
    x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * len);
    return i + 1;
}
#endif

// Which loop walks the bricks. With transitions, or with a gradient at every sample (shading or
// gradient opacity in DVR / MIDA), the run schedule below: interior runs read a sample's six
// gradient points through its own brick's layout entry instead of looking each one up (six
// lookups per sample: 1.6-1.9x the plain texture, shaded). The B-spline keeps the flat loop
// (it reads across bricks at every sample).
#if (defined(SHADING) || defined(GRADIENT_OPACITY)) && !defined(MODE_ISO) && !defined(MODE_MIP)
#define SAMPLE_GRADIENTS
#endif
#if defined(SMOOTH_TRANSITIONS) || (defined(SAMPLE_GRADIENTS) && !defined(TRICUBIC))
#define RUN_SCHEDULE
#endif

#ifndef RUN_SCHEDULE
// Without transitions or per-sample gradients every sample is one fetch: a single loop over the
// samples that reloads the layout entry only when a sample lands in a new brick (cheaper on SIMD
// CPUs than nested loops).
vec4 cast_ray(Ray ray) {
    vec2 hit = intersect_box(ray, params.box_min.xyz, params.box_max.xyz);
    float t0 = max(hit.x, params.forward.w);
    float t1 = ray_end(ray, hit.y);
#ifdef CLIP_PLANES
    vec2 kept = clip_ray(ray, t0, t1, params.clip_planes, int(params.iso_colour.w));
    t0 = kept.x;
    t1 = kept.y;
#endif
    RayState s = begin_ray();
    if (!(t0 < t1)) {
        return s.acc;
    }
    float step_len = params.box_min.w;
    vec3 box_size = params.box_max.xyz - params.box_min.xyz;
    vec3 to_voxel = params.volume_dims.xyz / box_size;
    float n = params.volume_dims.w;
    ivec3 bricks = ivec3(ceil(params.volume_dims.xyz / n));
    Ray voxel_ray = Ray((ray.origin - params.box_min.xyz) * to_voxel, ray.dir * to_voxel);
    int steps = int(min(ceil((t1 - t0) / step_len), params.tf_window.w));
    ivec3 current = ivec3(-1);
    vec4 entry = vec4(0.0);
    for (int i = 0; i < steps; ++i) {
        float t_start = t0 + float(i) * step_len;
        float len = max(min(step_len, t1 - t_start), 0.0);
        vec3 x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * len);
        ivec3 b = brick_of(x, n, bricks);
        if (any(notEqual(b, current))) {
            current = b;
            entry = layout_entries[b.x + bricks.x * (b.y + bricks.y * b.z)];
#ifdef ABSENT_BRICKS
            if (entry.w == 0.0) {
                // Absent brick: jump to just before its exit.
                float t_exit = intersect_box(voxel_ray, vec3(b) * n, vec3(b + 1) * n).y;
                i = max(i, first_sample_after(t_exit, t0, step_len) - 2);
                break_ray(s, ray.dir);
                continue;
            }
#endif
        }
#ifdef ABSENT_BRICKS
        if (entry.w == 0.0) {
            continue;
        }
#endif
#ifdef COARSE_LOW_RES
        if (entry.w == 0.5) {
            i = merge_low_res_pair(i, steps, t0, t1, step_len, voxel_ray, b, n, bricks, len, x);
        }
#endif
#ifdef TRICUBIC
        float value = sample_tricubic(x);
#else
        FIELD value = cache_fetch(x * entry.w + entry.xyz);
#endif
        if (INTEGRATE(s, value, len, x, ray.dir, false, entry)) {
            break;
        }
    }
    return finish_ray(s, ray.dir);
}
#else
// The same samples as the single-resolution loop (and as `cast_ray_mixed` in the CPU reference,
// which tests each sample's brick), scheduled in alternating runs so the plain samples carry no
// transition code (SIMD CPUs such as llvmpipe execute every branch body and at least one pass of
// every loop, taken or not; docs/performance.md):
// - a general run: consecutive samples that need the general path, each looked up on its own (it
//   may cross from one brick into the next): samples in the half-voxel band of a hi-res brick next
//   to a low-res brick, blended; with gradients also the samples whose gradient points x +- h
//   leave their brick's plain region. It ends at the first sample inside a brick's run region;
// - then that brick's run up to where the ray leaves the run region (one ray/box intersection;
//   layout entry, neighbour bits and band bounds were read once for it): plain fetches, and
//   gradients read through the brick's own entry; or the jump over an absent brick.
#if defined(SHADING) || defined(GRADIENT_OPACITY)
#define RUN_DEEP true
#else
#define RUN_DEEP false
#endif
vec4 cast_ray(Ray ray) {
    vec2 hit = intersect_box(ray, params.box_min.xyz, params.box_max.xyz);
    float t0 = max(hit.x, params.forward.w);
    float t1 = ray_end(ray, hit.y);
#ifdef CLIP_PLANES
    vec2 kept = clip_ray(ray, t0, t1, params.clip_planes, int(params.iso_colour.w));
    t0 = kept.x;
    t1 = kept.y;
#endif
    RayState s = begin_ray();
    if (!(t0 < t1)) {
        return s.acc;
    }
    float step_len = params.box_min.w;
    vec3 box_size = params.box_max.xyz - params.box_min.xyz;
    vec3 to_voxel = params.volume_dims.xyz / box_size;
    float n = params.volume_dims.w;
    ivec3 bricks = ivec3(ceil(params.volume_dims.xyz / n));
    Ray voxel_ray = Ray((ray.origin - params.box_min.xyz) * to_voxel, ray.dir * to_voxel);
    int steps = int(min(ceil((t1 - t0) / step_len), params.tf_window.w));
    // The run region of a brick is its plain region (off its bands), shrunk with gradients by the
    // gradient's reach h (and a small margin) so that x +- h stays inside.
#if defined(SHADING) || defined(GRADIENT_OPACITY)
    float margin = params.mode.w + 1e-3;
#else
    float margin = 0.0;
#endif
    // With gradients and coarse low-res pairs, a pair merged at a run's last sample reaches one
    // step further: a run starts a step inside the region and ends a sample early.
#if defined(COARSE_LOW_RES) && (defined(SHADING) || defined(GRADIENT_OPACITY))
    float guard = step_len * length(voxel_ray.dir);
    int trim = 1;
#else
    float guard = 0.0;
    int trim = 0;
#endif
    int i = 0;
    while (i < steps) {
        // General run; its last pass looks up the brick of the run that follows.
        float t_start;
        float len;
        vec3 x;
        ivec3 b;
        vec4 entry;
        uint bits;
        vec3 band_lo;
        vec3 band_hi;
        for (; i < steps; ++i) {
            t_start = t0 + float(i) * step_len;
            len = max(min(step_len, t1 - t_start), 0.0);
            x = voxel_ray.origin + voxel_ray.dir * (t_start + 0.5 * len);
            look_up_brick(x, n, bricks, b, entry, bits, band_lo, band_hi);
            vec3 q = x - vec3(b) * n;
#if defined(SHADING) || defined(GRADIENT_OPACITY)
            vec3 start_lo = max(band_lo, vec3(0.0)) + (margin + guard);
            vec3 start_hi = min(band_hi, vec3(n)) - (margin + guard);
#else
            // Only band samples take the blend; a low-res brick's samples never do.
            vec3 start_lo = band_lo;
            vec3 start_hi = band_hi;
#endif
            bool starts_run = all(greaterThanEqual(q, start_lo)) && all(lessThanEqual(q, start_hi));
#ifdef ABSENT_BRICKS
            starts_run = starts_run || entry.w == 0.0;
#endif
            if (starts_run) {
                break;
            }
            COARSE_PAIR(i)
#if defined(SHADING) || defined(GRADIENT_OPACITY)
            FIELD value = sample_in_brick(x, b, entry, bits, band_lo, band_hi, n);
#else
            FIELD value = sample_hi_res_transition(q, vec3(b) * n + entry.xyz, bits, n);
#endif
            if (INTEGRATE(s, value, len, x, ray.dir, false, entry)) {
                i = steps;
                break;
            }
        }
        if (i >= steps) {
            break;
        }
        // The brick's run (sample i lies in it, so it holds at least that sample), or the jump
        // over an absent brick (its whole box).
        vec3 origin = vec3(b) * n;
#ifdef ABSENT_BRICKS
        float run_margin = entry.w == 0.0 ? 0.0 : margin;
#else
        float run_margin = margin;
#endif
        vec3 run_lo = max(band_lo, vec3(0.0)) + run_margin;
        vec3 run_hi = min(band_hi, vec3(n)) - run_margin;
        float t_leave = intersect_box(voxel_ray, origin + run_lo, origin + run_hi).y;
        int i_out = clamp(first_sample_after(t_leave, t0, step_len) - trim, i + 1, steps);
#ifdef ABSENT_BRICKS
        if (entry.w == 0.0) {
            i = clamp(first_sample_after(t_leave, t0, step_len), i + 1, steps);
            break_ray(s, ray.dir);
            continue;
        }
#endif
        INTERIOR_RUN(i_out, RUN_DEEP)
    }
    return finish_ray(s, ray.dir);
}
#endif
#endif

void main() {
    out_color = cast_ray(generate_ray(params, gl_FragCoord.xy));
}
