// The 26-neighbour bit table and feature tests. Mirrors src/reference/mixed.rs.
#ifndef NEIGHBOURS_GLSL
#define NEIGHBOURS_GLSL

// Bit of the neighbour at offset d (d != 0, components in -1..1).
uint neighbour_bit(ivec3 d) {
    int idx = (d.x + 1) + 3 * (d.y + 1) + 9 * (d.z + 1);
    int k = idx < 13 ? idx : idx - 1;
    return 1u << uint(k);
}

// The neighbour offset that selects axes `mask` (bit a = axis a) on sides `side`.
ivec3 offset_of(uint mask, ivec3 side) {
    return ivec3((mask & 1u) != 0u ? side.x : 0,
                 (mask & 2u) != 0u ? side.y : 0,
                 (mask & 4u) != 0u ? side.z : 0);
}

// Per axis, the neighbour bits of the nine bricks on its low side, on its high side, and level
// with the brick (SIDE_MASKS and CENTRE_MASKS in Rust).
const uvec3 LOW_SIDE = uvec3(0x925249u, 0xe0e07u, 0x1ffu);
const uvec3 HIGH_SIDE = uvec3(0x2492924u, 0x381c1c0u, 0x3fe0000u);
const uvec3 CENTRE = uvec3(0x1248492u, 0x703038u, 0x1fe00u);

// Per axis, the neighbour bits of the bricks on side `side` (0 where side is 0).
uvec3 toward(ivec3 side) {
    return mix(uvec3(0u), mix(HIGH_SIDE, LOW_SIDE, lessThan(side, ivec3(0))),
               notEqual(side, ivec3(0)));
}

// Neighbour bits of the bricks touching the feature of axes `mask` on sides `side`: offsets d != 0
// with d_a in {0, side_a} on the axes of `mask` and d_a = 0 on the others.
uint touching(uint mask, ivec3 side) {
    bvec3 on = notEqual(uvec3(mask) & uvec3(1u, 2u, 4u), uvec3(0u));
    uvec3 allowed = CENTRE | mix(uvec3(0u), toward(side), on);
    return allowed.x & allowed.y & allowed.z;
}

// Whether any brick touching the feature of axes `mask` on sides `side` is low-res.
bool feature_touches_low_res(uint bits, uint mask, ivec3 side) {
    return (bits & touching(mask, side)) != 0u;
}

// Band axes whose transition is active: some touching low-res brick lies across that axis.
uint active_axes(uint bits, uint band_mask, ivec3 side) {
    uint low = bits & touching(band_mask, side);
    bvec3 across = notEqual(uvec3(low) & toward(side), uvec3(0u));
    return (across.x ? 1u : 0u) | (across.y ? 2u : 0u) | (across.z ? 4u : 0u);
}

#endif
