// Reconstruction of the scalar field. Mirrors src/reference/sampling.rs.
#ifndef SAMPLING_GLSL
#define SAMPLING_GLSL

// Trilinear sample of the volume at normalised texture coordinate `tex` ([0,1]^3 spans the
// volume; voxel centres sit at (i + 0.5) / dims), clamp-to-edge outside.
float sample_volume(sampler3D volume, vec3 tex) {
    return texture(volume, tex).r;
}

// Cubic B-spline reconstruction from 8 trilinear fetches (Sigg and Hadwiger, GPU Gems 2 ch. 20):
// per axis, the 4 B-spline weights of the texels around x fold into 2 fetch positions (voxel
// units) and 2 weights. `tricubic_taps` returns (position 0, position 1, weight 0) per axis in
// the columns of a mat3; weight 1 = 1 - weight 0. Mirrors `tricubic_taps`.
mat3 tricubic_taps(vec3 x) {
    vec3 c = x - 0.5;
    vec3 i = floor(c);
    vec3 f = c - i;
    vec3 f2 = f * f;
    vec3 f3 = f2 * f;
    vec3 g = 1.0 - f;
    vec3 w0 = g * g * g / 6.0;
    vec3 w1 = (3.0 * f3 - 6.0 * f2 + 4.0) / 6.0;
    vec3 w3 = f3 / 6.0;
    vec3 g0 = w0 + w1;
    vec3 g1 = 1.0 - g0;
    vec3 p0 = i - 0.5 + w1 / g0;
    vec3 p1 = i + 1.5 + w3 / g1;
    return mat3(p0, p1, g0);
}

#endif
