// Mixed-resolution field: address translation and the smooth (C0) transition blend. Mirrors
// src/reference/mixed.rs function by function; see its module docs for the construction.
// The includer defines `FIELD cache_fetch(vec3 texel)`: a trilinear fetch of the brick cache at
// an unnormalised texel coordinate (texel centres at i + 0.5).
#ifndef MIXED_GLSL
#define MIXED_GLSL
#include "neighbours.glsl"

// The field's type: float, or vec4 for pre-classified RGBA caches (every channel is blended
// alike; the construction is linear in the texel values).
#ifndef FIELD
#define FIELD float
#endif

// Brick containing volume point x (hi-res voxel units), clamped to the grid.
ivec3 brick_of(vec3 x, float brick_size, ivec3 bricks) {
    // brick_size is a power of two: multiplying by its inverse is exact (and cheaper).
    return clamp(ivec3(floor(x * (1.0 / brick_size))), ivec3(0), bricks - 1);
}

// Band axes of brick-local point q: returns the band mask, writes sides and betas.
uint band(vec3 q, float n, out ivec3 side, out vec3 beta) {
    uint mask = 0u;
    side = ivec3(0);
    beta = vec3(0.0);
    for (int a = 0; a < 3; ++a) {
        if (q[a] < 0.5) {
            mask |= 1u << uint(a);
            side[a] = -1;
            beta[a] = 1.0 - 2.0 * q[a];
        } else if (q[a] > n - 0.5) {
            mask |= 1u << uint(a);
            side[a] = 1;
            beta[a] = 1.0 - 2.0 * (n - q[a]);
        }
    }
    return mask;
}

// Local coordinate at which one fetch of the fixed-up border of feature `face_mask` reads the
// low-res function at local point p (trapezoid warp along the non-feature axes).
vec3 low_res_border_coord(vec3 p, uint face_mask, ivec3 side, float n) {
    vec3 c = p;
    for (int a = 0; a < 3; ++a) {
        if ((face_mask & (1u << uint(a))) != 0u) {
            c[a] = side[a] < 0 ? -0.5 : n + 0.5;
        } else {
            float k2 = min(2.0 * floor(p[a] * 0.5), n - 2.0);
            c[a] = k2 + 0.5 + (p[a] - k2) * 0.5;
        }
    }
    return c;
}

// The smooth reconstruction inside a hi-res brick (q brick-local, texel_of_local the texel
// coordinate of local 0, bits its neighbour bits).
FIELD sample_hi_res_transition(vec3 q, vec3 texel_of_local, uint bits, float n) {
    ivec3 side;
    vec3 beta;
    uint band_mask = band(q, n, side, beta);
    uint active_mask = active_axes(bits, band_mask, side);
    vec3 face = mix(vec3(n), vec3(0.0), lessThan(side, ivec3(0)));
    vec3 plane = mix(vec3(n - 0.5), vec3(0.5), lessThan(side, ivec3(0)));
    // What a term reads per axis: on the axes of S the face (hi-res read) or the border texel
    // centre (low-res read through the fixed-up border); on the other active axes the hi-res
    // plane, or its low-res warp; on inactive axes q, or its low-res warp.
    bvec3 is_active = notEqual(uvec3(active_mask) & uvec3(1u, 2u, 4u), uvec3(0u));
    vec3 hi_point = mix(q, plane, is_active);
    vec3 lo_point = low_res_border_coord(hi_point, 0u, side, n);
    vec3 border = mix(vec3(n + 0.5), vec3(-0.5), lessThan(side, ivec3(0)));
    // Every subset S of the active axes: bit rank[a] of k says whether active axis a is in S. A
    // counted loop without early exit (a for(;;) with break gave wrong sums on llvmpipe 22.3).
    ivec3 rank = ivec3(0, int(is_active.x), int(is_active.x) + int(is_active.y));
    int subsets = 1 << bitCount(active_mask);
    FIELD sum = FIELD(0.0);
    for (int k = 0; k < subsets; ++k) {
        bvec3 on_face = bvec3(uvec3(is_active) & (uvec3(k) >> uvec3(rank)) & 1u);
        uint s = (on_face.x ? 1u : 0u) | (on_face.y ? 2u : 0u) | (on_face.z ? 4u : 0u);
        vec3 w = mix(vec3(1.0), mix(1.0 - beta, beta, on_face), is_active);
        vec3 local = (s != 0u && feature_touches_low_res(bits, s, side))
            ? mix(lo_point, border, on_face)
            : mix(hi_point, face, on_face);
        sum += (w.x * w.y * w.z) * cache_fetch(local + texel_of_local);
    }
    return sum;
}

// Per-brick band bounds (brick-local): a sample below `lo` or above `hi` on some axis lies in a
// half-voxel band on a side that touches a low-res neighbour (face, edge or corner) and needs the
// transition blend; every other sample of the brick is a plain fetch. Computed once per brick.
void band_bounds(uint bits, float n, out vec3 lo, out vec3 hi) {
    // A low-res neighbour on the low / high side of an axis (LOW_SIDE, HIGH_SIDE) puts a band there.
    lo = mix(vec3(-1.0), vec3(0.5), notEqual(uvec3(bits) & LOW_SIDE, uvec3(0u)));
    hi = mix(vec3(n + 1.0), vec3(n - 0.5), notEqual(uvec3(bits) & HIGH_SIDE, uvec3(0u)));
}

// The field at volume point x inside brick b with layout entry `entry` (t_w > 0), neighbour bits
// `bits` and band bounds `lo`, `hi`. Mirrors `sample_in_brick` in src/reference/mixed.rs.
FIELD sample_in_brick(vec3 x, ivec3 b, vec4 entry, uint bits, vec3 lo, vec3 hi, float n) {
#ifdef SMOOTH_TRANSITIONS
    if (entry.w == 1.0 && bits != 0u) {
        vec3 origin = vec3(b) * n;
        vec3 q = x - origin;
        if (any(lessThan(q, lo)) || any(greaterThan(q, hi))) {
            return sample_hi_res_transition(q, origin + entry.xyz, bits, n);
        }
    }
#endif
    return cache_fetch(x * entry.w + entry.xyz);
}

#endif
