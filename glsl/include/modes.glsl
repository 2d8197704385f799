// What a ray computes from its samples: the render modes, shading and gradient opacity.
// Mirrors src/reference/modes.rs function by function.
// Needs, defined before inclusion: `params`, `tf_tex`, (PREINTEGRATED) `preint_tex`, and
// `float field_value(vec3 x, out bool present)`: the reconstructed field at voxel position x.
// Variant macros: MODE_DVR | MODE_ISO | MODE_MIP | MODE_MIDA; SHADING; GRADIENT_OPACITY;
// PREINTEGRATED; EXTINCTION_MODEL (optics.glsl).
#ifndef MODES_GLSL
#define MODES_GLSL
#include "optics.glsl"

// ISO_BISECTIONS (a macro from src/reference/modes.rs): bisection steps of the iso-surface
// refinement (then one secant step).

struct RayState {
    vec4 acc;         // premultiplied colour and opacity so far
    float max_pos;    // MIP, MIDA: largest TF position so far (-1: none yet)
    float prev_value; // ISO, PREINTEGRATED: the previous sample's value
    float prev_len;   // PREINTEGRATED: the length the previous sample stands for
    vec3 prev_g;      // PREINTEGRATED with gradients: the previous sample's gradient
    vec3 prev_x;      // ISO: the previous sample's position (voxels)
    bool has_prev;    // whether prev_* hold a sample (false after a gap)
    bool hit;         // ISO: the ray crossed the iso value between prev_x and hit_x
    vec3 hit_x;       // ISO: the first sample past the crossing
    float hit_value;  // ISO: its value
};

RayState begin_ray() {
    RayState s;
    s.acc = vec4(0.0);
    s.max_pos = -1.0;
    s.prev_value = 0.0;
    s.prev_len = 0.0;
    s.prev_g = vec3(0.0);
    s.prev_x = vec3(0.0);
    s.has_prev = false;
    s.hit = false;
    s.hit_x = vec3(0.0);
    s.hit_value = 0.0;
    return s;
}


// World-space gradient of the field at voxel position x by central differences `h` voxels
// apart; `value` is the field at x. A side whose point lies in an absent brick falls back to x
// itself (a one-sided difference).
vec3 field_gradient(vec3 x, float value) {
    float h = params.mode.w;
    vec3 to_voxel = params.volume_dims.xyz / (params.box_max.xyz - params.box_min.xyz);
    vec3 g = vec3(0.0);
    for (int k = 0; k < 3; ++k) {
        vec3 e = vec3(0.0);
        e[k] = h;
        bool present_hi;
        bool present_lo;
        float hi = field_value(x + e, present_hi);
        float lo = field_value(x - e, present_lo);
        float span = (present_hi ? h : 0.0) + (present_lo ? h : 0.0);
        hi = present_hi ? hi : value;
        lo = present_lo ? lo : value;
        g[k] = span > 0.0 ? (hi - lo) / span : 0.0;
    }
    return g * to_voxel;
}

// Blinn-Phong with a headlight along the ray, two-sided.
vec3 shade(vec3 rgb, vec3 gradient, vec3 view_dir) {
    float len = length(gradient);
    float n_dot_l = len > 0.0 ? min(abs(dot(gradient, view_dir)) / len, 1.0) : 1.0;
    return rgb * (params.shading.x + params.shading.y * n_dot_l)
        + params.shading.z * pow(n_dot_l, params.shading.w);
}

// Opacity scale from the gradient magnitude in TF positions per world unit.
float gradient_opacity(vec3 gradient) {
    return min(params.mode.z * length(gradient) * abs(params.tf_window.y), 1.0);
}

// The transfer function at the largest TF position (opacity of one reference length).
vec4 mip_colour(float max_pos) {
    if (max_pos < 0.0) {
        return vec4(0.0);
    }
    vec4 w = lookup_tf(tf_tex, max_pos);
    float alpha = reference_opacity(w.a);
    return vec4(sample_colour(w) * alpha, alpha);
}

// Iso-surface point between a (value fa) and b (value fb), on opposite sides of the iso value:
// bisection, then a secant step inside the last bracket.
vec3 refine_iso(vec3 a, float fa, vec3 b, float fb) {
    float iso = params.mode.x;
    bool a_below = fa < iso;
    for (int k = 0; k < ISO_BISECTIONS; ++k) {
        vec3 m = 0.5 * (a + b);
        bool present;
        float fm = field_value(m, present);
        if ((fm < iso) == a_below) {
            a = m;
            fa = fm;
        } else {
            b = m;
            fb = fm;
        }
    }
    float denom = fb - fa;
    float t = denom != 0.0 ? clamp((iso - fa) / denom, 0.0, 1.0) : 0.5;
    return a * (1.0 - t) + b * t;
}

// PREINTEGRATED (DVR, MIDA): composites the half step behind a run's last sample at its constant
// classification (samples lie at the middles of their steps; a run is a constant half step in
// front of its first sample, the segments between samples, and this). No-op otherwise.
void close_run(inout RayState s, vec3 view_dir) {
#if defined(PREINTEGRATED) && (defined(MODE_DVR) || defined(MODE_MIDA))
    if (!s.has_prev) {
        return;
    }
    float pos = tf_position(params.tf_window, s.prev_value);
    vec4 seg = texture(preint_tex, (vec2(pos, pos) * float(TF_SIZE - 1) + 0.5) / float(TF_SIZE));
    vec3 rgb = sample_colour(seg);
    float alpha = correct_opacity(seg.a, 0.5 * s.prev_len / params.box_min.w);
#ifdef GRADIENT_OPACITY
    alpha *= gradient_opacity(s.prev_g);
#endif
#ifdef SHADING
    rgb = shade(rgb, s.prev_g, view_dir);
#endif
    // MIDA: the maximum already holds this position (beta = 1), so its blend is "over".
    s.acc = composite(s.acc, rgb, alpha);
    s.prev_len = 0.0;
#endif
}

// A gap in the samples (an absent brick): closes a pre-integrated run; iso crossings and
// pre-integrated segments never bridge it.
void break_ray(inout RayState s, vec3 view_dir) {
    close_run(s, view_dir);
    s.has_prev = false;
}

// The colour and opacity of one sample (before gradient effects): pre-integrated over the
// segment from the previous sample (half of each one's length; from the run's start half a
// step in front, constant), or classified at the sample.
vec4 classify_sample(inout RayState s, float value, float len) {
    float pos = tf_position(params.tf_window, value);
#ifdef PREINTEGRATED
    float front = s.has_prev ? tf_position(params.tf_window, s.prev_value) : pos;
    float seg_len = s.has_prev ? 0.5 * (s.prev_len + len) : 0.5 * len;
    s.prev_value = value;
    s.prev_len = len;
    s.has_prev = true;
    vec4 seg = texture(preint_tex, (vec2(front, pos) * float(TF_SIZE - 1) + 0.5) / float(TF_SIZE));
    return vec4(sample_colour(seg), correct_opacity(seg.a, seg_len / params.box_min.w));
#else
    vec4 w = lookup_tf(tf_tex, pos);
    return vec4(sample_colour(w), sample_opacity(w.a, len / params.box_max.w));
#endif
}

// The world-space gradient at a sample, defined by the includer: `field_gradient`, or with
// `deep` (a compile-time constant at every call) the same values read through the sample's own
// brick `entry` (x +- h known to lie in the brick's plain region).
vec3 sample_gradient(vec3 x, float value, bool deep, vec4 entry);

// Adds the sample `value` at voxel position x, standing for a segment `len` world units long, to
// the ray; true once nothing further along the ray can change the result. `deep` and `entry`
// only choose how the gradient is read (`sample_gradient`), never its value.
bool integrate_sample(inout RayState s, float value, float len, vec3 x, vec3 view_dir, bool deep,
                      vec4 entry) {
#if defined(MODE_ISO)
    // Only the bracket is kept here: refinement and shading run once, in finish_ray, outside
    // the sample loop (a heavy branch body in the loop costs every sample on SIMD CPUs).
    float iso = params.mode.x;
    if (s.has_prev && ((s.prev_value < iso) != (value < iso))) {
        s.hit = true;
        s.hit_x = x;
        s.hit_value = value;
        return true;
    }
    s.prev_value = value;
    s.prev_x = x;
    s.has_prev = true;
    return false;
#elif defined(MODE_MIP)
    s.max_pos = max(s.max_pos, tf_position(params.tf_window, value));
    return s.max_pos >= 1.0;
#else
    vec4 sample_rgba = classify_sample(s, value, len);
    vec3 rgb = sample_rgba.rgb;
    float alpha = sample_rgba.a;
#if defined(SHADING) || defined(GRADIENT_OPACITY)
    vec3 g = sample_gradient(x, value, deep, entry);
#ifdef PREINTEGRATED
    s.prev_g = g;
#endif
#endif
#ifdef GRADIENT_OPACITY
    alpha *= gradient_opacity(g);
#endif
#ifdef SHADING
    rgb = shade(rgb, g, view_dir);
#endif
#ifdef MODE_MIDA
    float pos = tf_position(params.tf_window, value);
    float gamma = params.mode.y;
    float delta = max(pos - max(s.max_pos, 0.0), 0.0);
    float beta = 1.0 - delta * (1.0 + min(gamma, 0.0));
    float weight = (1.0 - beta * s.acc.a) * alpha;
    s.acc = vec4(beta * s.acc.rgb + weight * rgb, beta * s.acc.a + weight);
    s.max_pos = max(s.max_pos, pos);
    // Only once the maximum cannot grow (or at gamma = -1, plain DVR) is the opacity final.
    return s.acc.a >= params.tf_window.z && (s.max_pos >= 1.0 || gamma <= -1.0);
#else
    s.acc = composite(s.acc, rgb, alpha);
    return s.acc.a >= params.tf_window.z;
#endif
#endif
}

// Adds a pre-classified sample (weighted colour, coefficient: RGBA_VOLUME) standing for a
// segment `len` world units long; true once the ray is opaque enough to stop.
bool integrate_weighted(inout RayState s, vec4 weighted, float len) {
    float alpha = sample_opacity(weighted.a, len / params.box_max.w);
    s.acc = composite(s.acc, sample_colour(weighted), alpha);
    return s.acc.a >= params.tf_window.z;
}

// The ray's result once its samples are done (a pre-integrated run closed first).
vec4 finish_ray(RayState s, vec3 view_dir) {
    close_run(s, view_dir);
#if defined(MODE_ISO)
    if (!s.hit) {
        return vec4(0.0);
    }
    vec3 hit = refine_iso(s.prev_x, s.prev_value, s.hit_x, s.hit_value);
    vec3 rgb = params.iso_colour.rgb;
#ifdef SHADING
    bool present;
    rgb = shade(rgb, field_gradient(hit, field_value(hit, present)), view_dir);
#endif
    return vec4(rgb, 1.0);
#elif defined(MODE_MIP)
    return mip_colour(s.max_pos);
#elif defined(MODE_MIDA)
    float gamma = params.mode.y;
    return gamma > 0.0 ? s.acc * (1.0 - gamma) + mip_colour(s.max_pos) * gamma : s.acc;
#else
    return s.acc;
#endif
}

#endif
