// Classification, opacity correction and compositing. Mirrors src/optics.rs function by function.
#ifndef OPTICS_GLSL
#define OPTICS_GLSL

// Maps a normalised sample value through the window onto the 1D RGBA transfer function texture
// (TF_SIZE entries, linear filtering between entry centres).
vec4 classify(sampler1D tf, vec4 tf_window, float value) {
    float s = clamp((value - tf_window.x) * tf_window.y, 0.0, 1.0);
    return texture(tf, (s * float(TF_SIZE - 1) + 0.5) / float(TF_SIZE));
}

// Opacity of a segment `ratio` reference lengths long, given the opacity `alpha` of one
// reference length: 1 - (1 - alpha)^ratio, exact at alpha = 0 and alpha = 1.
float correct_opacity(float alpha, float ratio) {
    if (alpha >= 1.0) {
        return 1.0;
    }
    if (alpha <= 0.0) {
        return 0.0;
    }
    return 1.0 - exp2(ratio * log2(1.0 - alpha));
}

// Front-to-back "under" operator on premultiplied colour: emission `rgb` with opacity `alpha`
// behind what `acc` already holds.
vec4 composite(vec4 acc, vec3 rgb, float alpha) {
    float weight = (1.0 - acc.a) * alpha;
    return vec4(acc.rgb + weight * rgb, acc.a + weight);
}

#endif
