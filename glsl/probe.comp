#version 460
// Samples the GPU-reconstructed mixed-resolution field at given volume points (hi-res voxel
// units): the same functions the ray-caster uses, so tests can check the field itself.
// Output per point: x = value, y = 1 when the point lies in a resident brick, 0 otherwise.

layout(local_size_x = PROBE_GROUP_SIZE) in;

layout(set = 0, binding = PROBE_BINDING_CACHE) uniform sampler3D cache_tex;
layout(std430, set = 0, binding = PROBE_BINDING_LAYOUT_TABLE) readonly buffer LayoutTable { vec4 layout_entries[]; };
layout(std430, set = 0, binding = PROBE_BINDING_NEIGHBOUR_TABLE) readonly buffer NeighbourTable { uint neighbour_bits[]; };
layout(std430, set = 0, binding = PROBE_BINDING_POINTS) readonly buffer Points { vec4 points[]; };
layout(std430, set = 0, binding = PROBE_BINDING_VALUES) writeonly buffer Values { vec2 values[]; };

// Mirrors `ProbePush` in src/gpu/shared_defs.rs (32 bytes).
layout(push_constant) uniform ProbeParams {
    vec4 volume_dims;      // xyz: volume dimensions; w: brick size n
    vec4 cache_extent_inv; // xyz: 1 / cache extent in texels; w: number of points
} pc;

float cache_fetch(vec3 texel) {
    return textureLod(cache_tex, texel * pc.cache_extent_inv.xyz, 0.0).r;
}
#include "include/mixed.glsl"

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uint(pc.cache_extent_inv.w)) {
        return;
    }
    vec3 x = points[i].xyz;
    float n = pc.volume_dims.w;
    ivec3 bricks = ivec3(ceil(pc.volume_dims.xyz / n));
    ivec3 b = brick_of(x, n, bricks);
    int bi = b.x + bricks.x * (b.y + bricks.y * b.z);
    vec4 entry = layout_entries[bi];
    if (entry.w == 0.0) {
        values[i] = vec2(0.0, 0.0);
        return;
    }
    // Only a level-0 brick (t_w = 1) blends (as look_up_brick in raycast.frag).
    uint bits = entry.w == 1.0 ? neighbour_bits[bi] : 0u;
    vec3 lo = vec3(-1.0);
    vec3 hi = vec3(n + 1.0);
#ifdef SMOOTH_TRANSITIONS
    band_bounds(bits, n, lo, hi);
#endif
    values[i] = vec2(sample_in_brick(x, b, entry, bits, lo, hi, n), 1.0);
}
