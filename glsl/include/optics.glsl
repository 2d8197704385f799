// Classification, opacity correction and compositing. Mirrors src/optics/mod.rs function by function.
#ifndef OPTICS_GLSL
#define OPTICS_GLSL

// The transfer-function position of a sample value: through the window, clamped to [0, 1].
float tf_position(vec4 tf_window, float value) {
    return clamp((value - tf_window.x) * tf_window.y, 0.0, 1.0);
}

// The classification table (a 1D texture of TF_SIZE weighted entries: colour * coefficient,
// coefficient) at TF position s, linearly filtered between entry centres. `ClassificationTable::lookup`.
vec4 lookup_tf(sampler1D tf, float s) {
    return texture(tf, (s * float(TF_SIZE - 1) + 0.5) / float(TF_SIZE));
}

// The emitted colour of an interpolated weighted entry (black where the coefficient is 0).
vec3 sample_colour(vec4 weighted) {
    return weighted.a > 0.0 ? weighted.rgb / weighted.a : vec3(0.0);
}

// 1 - exp(y) for y <= 0, with a third-order series near 0 (keeps tiny results' relative accuracy).
float one_minus_exp(float y) {
    return y > -1e-3 ? -y * (1.0 + y * (0.5 + y / 6.0)) : 1.0 - exp(y);
}

// Opacity of a segment `ratio` reference lengths long, given the opacity `alpha` of one
// reference length: 1 - (1 - alpha)^ratio = -expm1(ratio * log1p(-alpha)), exact at alpha = 0 and
// alpha = 1. Small arguments use third-order series for log1p and expm1, so tiny opacities keep
// their relative accuracy (1 - exp(y) loses it below 2^-24).
float correct_opacity(float alpha, float ratio) {
    if (alpha >= 1.0) {
        return 1.0;
    }
    if (alpha <= 0.0) {
        return 0.0;
    }
    float l = alpha < 1e-3 ? -alpha * (1.0 + alpha * (0.5 + alpha / 3.0)) : log(1.0 - alpha);
    return one_minus_exp(ratio * l);
}

// Opacity of a segment `len` long in a medium of extinction `tau` per unit length:
// 1 - exp(-tau * len), never negative, 1 once exp underflows.
float extinction_opacity(float tau, float len) {
    float depth = tau * len;
    return depth > 0.0 ? one_minus_exp(-depth) : 0.0;
}

// Opacity of a segment `ratio` reference lengths long with coefficient `coefficient` (opacity of
// one reference length, or EXTINCTION_MODEL: extinction per reference length).
float sample_opacity(float coefficient, float ratio) {
#ifdef EXTINCTION_MODEL
    return extinction_opacity(coefficient, ratio);
#else
    return correct_opacity(coefficient, ratio);
#endif
}

// Opacity of one reference length.
float reference_opacity(float coefficient) {
#ifdef EXTINCTION_MODEL
    return extinction_opacity(coefficient, 1.0);
#else
    return min(coefficient, 1.0);
#endif
}

// Front-to-back "under" operator on premultiplied colour: emission `rgb` with opacity `alpha`
// behind what `acc` already holds.
vec4 composite(vec4 acc, vec3 rgb, float alpha) {
    float weight = (1.0 - acc.a) * alpha;
    return vec4(acc.rgb + weight * rgb, acc.a + weight);
}

#endif
