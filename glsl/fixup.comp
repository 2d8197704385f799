#version 460
// Border fixup: for every hi-res brick with a low-res neighbour, rewrite its duplicated border
// texels to the nearest low-res sample of the first low-res neighbour (faces, then edges, then the
// corner). Original samples are never touched. Mirrors `fixup_value` in src/reference/mixed.rs.
// One workgroup layer per (job, face): the z workgroup index is job * FIXUP_FACES_PER_JOB + face.
// Bindings, group sizes and the push-constant block: src/gpu/shared_defs.rs.
#include "include/neighbours.glsl"

layout(local_size_x = FIXUP_GROUP_SIZE, local_size_y = FIXUP_GROUP_SIZE, local_size_z = 1) in;

layout(set = 0, binding = FIXUP_BINDING_CACHE, CACHE_IMAGE_FORMAT) uniform image3D cache_image;
layout(std430, set = 0, binding = FIXUP_BINDING_LAYOUT_TABLE) readonly buffer LayoutTable { vec4 layout_entries[]; };
layout(std430, set = 0, binding = FIXUP_BINDING_NEIGHBOUR_TABLE) readonly buffer NeighbourTable { uint neighbour_bits[]; };
layout(std430, set = 0, binding = FIXUP_BINDING_REVERSE_TABLE) readonly buffer ReverseTable { uint reverse_entries[]; };
layout(std430, set = 0, binding = FIXUP_BINDING_JOBS) readonly buffer FixupJobs { uint fixup_slots[]; };

// Mirrors `FixupPush` in src/gpu/shared_defs.rs (32 bytes).
layout(push_constant) uniform FixupParams {
    ivec4 bricks;          // xyz: bricks per axis; w: brick size n
    ivec4 slots_per_axis;  // xyz: cache slots per axis; w: number of jobs
} pc;

// Border texels per side of a slot: 1 in the two-level cache ((n+2)^3 slots), 2 in the
// three-level packing ((n+4)^3 slots, src/cache/three_level.rs), whose inner (n+2)^3 box is the
// two-level brick: its inner border layer is fixed up, the outer one keeps the duplicated voxels.
#ifndef SLOT_BORDER
#define SLOT_BORDER 1
#endif

const uint PRECEDENCE[7] = uint[7](1u, 2u, 4u, 3u, 5u, 6u, 7u);

ivec3 unflatten(uint index, ivec3 dims) {
    int i = int(index);
    return ivec3(i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y));
}

void main() {
    uint job = gl_WorkGroupID.z / uint(FIXUP_FACES_PER_JOB);
    int face = int(gl_WorkGroupID.z % uint(FIXUP_FACES_PER_JOB));
    if (job >= uint(pc.slots_per_axis.w)) {
        return;
    }
    int n = pc.bricks.w;
    int extent = n + 2;
    ivec2 uv = ivec2(gl_GlobalInvocationID.xy);
    if (uv.x >= extent || uv.y >= extent) {
        return;
    }
    int axis = face / 2;
    ivec3 t;
    t[axis] = (face % 2 == 0) ? 0 : extent - 1;
    t[(axis + 1) % 3] = uv.x;
    t[(axis + 2) % 3] = uv.y;

    uint slot = fixup_slots[job];
    uint brick_index = reverse_entries[slot * uint(SUB_SLOTS_PER_SLOT)];
    ivec3 brick = unflatten(brick_index, pc.bricks.xyz);
    ivec3 slot_origin = unflatten(slot, pc.slots_per_axis.xyz) * (n + 2 * SLOT_BORDER)
        + ivec3(SLOT_BORDER - 1);
    uint bits = neighbour_bits[brick_index];

    uint border_mask = 0u;
    ivec3 side = ivec3(0);
    for (int a = 0; a < 3; ++a) {
        if (t[a] == 0) {
            border_mask |= 1u << uint(a);
            side[a] = -1;
        } else if (t[a] == extent - 1) {
            border_mask |= 1u << uint(a);
            side[a] = 1;
        }
    }
    for (int c = 0; c < 7; ++c) {
        uint candidate = PRECEDENCE[c];
        if ((candidate & ~border_mask) != 0u) {
            continue;
        }
        ivec3 d = offset_of(candidate, side);
        if ((bits & neighbour_bit(d)) == 0u) {
            continue;
        }
        ivec3 nb = brick + d;
        uint ni = uint(nb.x + pc.bricks.x * (nb.y + pc.bricks.y * nb.z));
        vec4 entry = layout_entries[ni];
        ivec3 sample_pos;
        for (int a = 0; a < 3; ++a) {
            if (d[a] == -1) {
                sample_pos[a] = n * brick[a];
            } else if (d[a] == 1) {
                sample_pos[a] = n * (brick[a] + 1);
            } else {
                // Texel t sits at n*b - 1 + t + 0.5; p + 1 >= 0, so integer division rounds down.
                int p = n * brick[a] - 1 + t[a];
                int even = 2 * ((p + 1) / 2);
                sample_pos[a] = clamp(even, n * nb[a], n * (nb[a] + 1));
            }
        }
        ivec3 texel = ivec3(floor(vec3(sample_pos) * 0.5 + entry.xyz));
        imageStore(cache_image, slot_origin + t, imageLoad(cache_image, texel));
        return;
    }
}
