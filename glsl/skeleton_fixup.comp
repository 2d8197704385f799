#version 460
// Skeleton fixup (issue 19): for every brick of a vertex level (1 and up) with a neighbour drawn
// one level coarser, rewrite each stored sample on a face, edge or corner that touches a coarser
// brick to that brick's field at the sample's position: one trilinear read through its layout
// entry (the position is a vertex of the finer level, so the weights are 0 or 1/2). Then a plain
// fetch of the finer brick is C0 across the level change. Mirrors `skeleton_fixup_value` in
// src/reference/level_cache.rs. One workgroup layer per (job, face), as fixup.comp; a job is the
// first brick of a stored brick's block (the brick itself up to level 2). Bindings, group sizes
// and the push-constant block: src/gpu/shared_defs.rs.
#include "include/neighbours.glsl"

layout(local_size_x = FIXUP_GROUP_SIZE, local_size_y = FIXUP_GROUP_SIZE, local_size_z = 1) in;

layout(set = 0, binding = FIXUP_BINDING_CACHE, CACHE_IMAGE_FORMAT) uniform image3D cache_image;
layout(std430, set = 0, binding = FIXUP_BINDING_LAYOUT_TABLE) readonly buffer LayoutTable { vec4 layout_entries[]; };
layout(std430, set = 0, binding = FIXUP_BINDING_NEIGHBOUR_TABLE) readonly buffer NeighbourTable { uint neighbour_bits[]; };
layout(std430, set = 0, binding = FIXUP_BINDING_JOBS) readonly buffer SkeletonJobs { uint skeleton_bricks[]; };

// Mirrors `FixupPush` in src/gpu/shared_defs.rs (32 bytes).
layout(push_constant) uniform FixupParams {
    ivec4 bricks;          // xyz: bricks per axis; w: brick size n
    ivec4 slots_per_axis;  // xyz: unused here; w: number of jobs
} pc;

const uint PRECEDENCE[7] = uint[7](1u, 2u, 4u, 3u, 5u, 6u, 7u);

ivec3 unflatten(uint index, ivec3 dims) {
    int i = int(index);
    return ivec3(i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y));
}

// Trilinear read of the cache at texel coordinate c (texel centres at i + 0.5): what texture()
// with linear filtering computes. Mirrors `CacheImage::fetch`.
vec4 cache_trilinear(vec3 c) {
    vec3 x = c - 0.5;
    vec3 base = floor(x);
    vec3 f = x - base;
    ivec3 b = ivec3(base);
    vec4 c00 = mix(imageLoad(cache_image, b), imageLoad(cache_image, b + ivec3(1, 0, 0)), f.x);
    vec4 c10 = mix(imageLoad(cache_image, b + ivec3(0, 1, 0)), imageLoad(cache_image, b + ivec3(1, 1, 0)), f.x);
    vec4 c01 = mix(imageLoad(cache_image, b + ivec3(0, 0, 1)), imageLoad(cache_image, b + ivec3(1, 0, 1)), f.x);
    vec4 c11 = mix(imageLoad(cache_image, b + ivec3(0, 1, 1)), imageLoad(cache_image, b + ivec3(1, 1, 1)), f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

void main() {
    uint job = gl_WorkGroupID.z / uint(FIXUP_FACES_PER_JOB);
    int face = int(gl_WorkGroupID.z % uint(FIXUP_FACES_PER_JOB));
    if (job >= uint(pc.slots_per_axis.w)) {
        return;
    }
    uint first_index = skeleton_bricks[job];
    vec4 entry = layout_entries[first_index];
    // t_w = 2^-level exactly.
    int level = int(round(-log2(entry.w)));
    int n = pc.bricks.w;
    // Samples per axis less one: n / 2^level up to level 2, n / 4 past it (a block's brick).
    int last = n >> min(level, 2);
    ivec2 uv = ivec2(gl_GlobalInvocationID.xy);
    if (uv.x > last || uv.y > last) {
        return;
    }
    int axis = face / 2;
    ivec3 t;
    t[axis] = (face % 2 == 0) ? 0 : last;
    t[(axis + 1) % 3] = uv.x;
    t[(axis + 2) % 3] = uv.y;

    // The first brick of the stored brick's block (the brick itself up to level 2).
    ivec3 first = unflatten(first_index, pc.bricks.xyz);
    // t_xyz = origin + 0.5 - n*first/2^level (src/cache/three_level.rs); all terms are integers.
    ivec3 origin = ivec3(round(entry.xyz - 0.5)) + (first * n) / (1 << level);
    ivec3 position = first * n + t * (1 << level);
    // The brick of the block whose box holds the sample (the last one at the far faces).
    int block = 1 << max(level - 2, 0);
    ivec3 last_brick = min(first + (block - 1), pc.bricks.xyz - 1);
    ivec3 brick = clamp(position / n, first, last_brick);
    uint bits = neighbour_bits[uint(brick.x + pc.bricks.x * (brick.y + pc.bricks.y * brick.z))];

    uint mask = 0u;
    ivec3 side = ivec3(0);
    for (int a = 0; a < 3; ++a) {
        if (position[a] == n * brick[a]) {
            mask |= 1u << uint(a);
            side[a] = -1;
        } else if (position[a] == n * (brick[a] + 1)) {
            mask |= 1u << uint(a);
            side[a] = 1;
        }
    }
    if ((bits & touching(mask, side)) == 0u) {
        return;
    }
    vec3 p = vec3(position);
    for (int c = 0; c < 7; ++c) {
        uint candidate = PRECEDENCE[c];
        if ((candidate & ~mask) != 0u) {
            continue;
        }
        ivec3 d = offset_of(candidate, side);
        if ((bits & neighbour_bit(d)) == 0u) {
            continue;
        }
        ivec3 nb = brick + d;
        uint ni = uint(nb.x + pc.bricks.x * (nb.y + pc.bricks.y * nb.z));
        vec4 coarser = layout_entries[ni];
        imageStore(cache_image, origin + t, cache_trilinear(p * coarser.w + coarser.xyz));
        return;
    }
}
