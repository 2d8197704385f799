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

// Whether any brick touching the feature of axes `mask` on sides `side` is low-res.
bool feature_touches_low_res(uint bits, uint mask, ivec3 side) {
    uint sub = mask;
    while (sub != 0u) {
        if ((bits & neighbour_bit(offset_of(sub, side))) != 0u) {
            return true;
        }
        sub = (sub - 1u) & mask;
    }
    return false;
}

// Band axes whose transition is active: some touching low-res brick lies across that axis.
uint active_axes(uint bits, uint band_mask, ivec3 side) {
    uint active_mask = 0u;
    uint sub = band_mask;
    while (sub != 0u) {
        if ((bits & neighbour_bit(offset_of(sub, side))) != 0u) {
            active_mask |= sub;
        }
        sub = (sub - 1u) & band_mask;
    }
    return active_mask;
}

#endif
