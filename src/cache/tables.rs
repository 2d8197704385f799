//! The tables the GPU reads: layout entries, 26-neighbour bits, the reverse table and the fixup
//! dispatch list (`docs/cache-layout.md`). Free functions so that code holding only a residency
//! plan (the CPU reference, tests) computes exactly what [`super::BrickCache`] returns.

use super::{CacheGeometry, Level, Residency};
use crate::bricks::BrickGrid;
use glam::{IVec3, UVec3};

/// Marker for an unused reverse-table entry.
pub const EMPTY: u32 = u32::MAX;

/// Number of neighbours of a brick (`3^3 - 1`), i.e. of neighbour bits.
pub const NEIGHBOUR_COUNT: u32 = 26;

/// Bit index `k` of the neighbour at offset `d` (components in `-1..=1`, `d != 0`):
/// `idx = (dx+1) + 3(dy+1) + 9(dz+1)`, `k = idx < 13 ? idx : idx - 1`, so `k` runs over `0..26`.
///
/// Out-of-range components are clamped to `-1..=1`; `d == 0` (the brick itself, no bit) is a
/// caller error caught by a debug assertion.
pub fn neighbour_bit_index(d: IVec3) -> u32 {
    debug_assert!(d != IVec3::ZERO, "the brick itself has no neighbour bit");
    let d = d.clamp(IVec3::NEG_ONE, IVec3::ONE);
    let idx = (d.x + 1) + 3 * (d.y + 1) + 9 * (d.z + 1);
    (if idx < 13 { idx } else { idx - 1 }) as u32
}

/// Mask of the neighbour at offset `d`: `1 << neighbour_bit_index(d)`. Same function (and return
/// convention) as `neighbour_bit` in `glsl/include/neighbours.glsl` and `src/reference/mixed.rs`.
pub fn neighbour_bit(d: IVec3) -> u32 {
    1 << neighbour_bit_index(d)
}

/// The neighbour offset of bit index `k` (in `0..26`), the inverse of [`neighbour_bit_index`];
/// `k` is taken modulo 26.
pub fn neighbour_offset(k: u32) -> IVec3 {
    let k = (k % NEIGHBOUR_COUNT) as i32;
    let idx = if k < 13 { k } else { k + 1 };
    IVec3::new(idx % 3, (idx / 3) % 3, idx / 9) - IVec3::ONE
}

/// Layout entry `(t_x, t_y, t_z, t_w)` of brick `brick` with `residency`, in texel units: a volume
/// point `x` (hi-res voxel units) inside the brick maps to cache texel coordinate
/// `x * t_w + t_xyz` (texel centres at `i + 0.5`).
///
/// - `Hi` in slot with texel origin `o`: `t = o + 1 - n*b`, `t_w = 1`;
/// - `Lo` in sub-slot with texel origin `o`: `t = o + 0.5 - n*b/2`, `t_w = 0.5`;
/// - `Absent`: all zero (`t_w == 0` marks a skipped brick).
pub fn layout_entry(geometry: &CacheGeometry, brick: UVec3, residency: Residency) -> [f32; 4] {
    let n = i64::from(geometry.brick_size());
    let b = brick.as_i64vec3();
    match residency {
        Residency::Absent => [0.0; 4],
        Residency::Hi { slot } => {
            let t = geometry.slot_origin(slot).as_i64vec3() + 1 - n * b;
            [t.x as f32, t.y as f32, t.z as f32, 1.0]
        }
        Residency::Lo { slot, sub_slot } => {
            let t = geometry.sub_slot_origin(slot, sub_slot).as_i64vec3() - n / 2 * b;
            [t.x as f32 + 0.5, t.y as f32 + 0.5, t.z as f32 + 0.5, 0.5]
        }
    }
}

/// Neighbour bits of one brick: for a `Hi` brick, bit `k` set when its neighbour at offset
/// [`neighbour_offset`]`(k)` lies inside the grid and is `Lo`; zero for `Lo` and `Absent` bricks.
/// `level(i)` gives the level of linear brick `i`.
pub fn brick_neighbour_bits(grid: &BrickGrid, brick: UVec3, level: impl Fn(usize) -> Level) -> u32 {
    let number = |i: usize| match level(i) {
        Level::Hi => Some(0),
        Level::Lo => Some(1),
        Level::Absent => None,
    };
    coarser_neighbour_bits(grid, brick, number)
}

/// Neighbour bits for any number of levels: bit `k` set when the neighbour at offset
/// [`neighbour_offset`]`(k)` lies inside the grid and is drawn exactly one level coarser than
/// `brick`; zero for a brick that is not drawn. `level_of(i)` is the level number of linear brick
/// `i` (0 = full resolution), `None` when it is not drawn. With levels `Hi` = 0 and `Lo` = 1 these
/// are [`brick_neighbour_bits`]: a brick's transition looks only at the next coarser level, since
/// neighbours differ by at most one level (`reference::LevelField`).
pub fn coarser_neighbour_bits(
    grid: &BrickGrid,
    brick: UVec3,
    level_of: impl Fn(usize) -> Option<u32>,
) -> u32 {
    let Some(own) = level_of(grid.linear_index(brick)) else {
        return 0;
    };
    let size = grid.bricks_per_axis().as_ivec3();
    let mut bits = 0;
    for k in 0..NEIGHBOUR_COUNT {
        let nb = brick.as_ivec3() + neighbour_offset(k);
        if nb.cmpge(IVec3::ZERO).all()
            && nb.cmplt(size).all()
            && level_of(grid.linear_index(nb.as_uvec3())) == own.checked_add(1)
        {
            bits |= 1 << k;
        }
    }
    bits
}

/// Neighbour bits of every brick of `grid` (see [`brick_neighbour_bits`]) for per-brick `levels`
/// (linear brick index); bricks missing from `levels` count as `Absent`.
pub fn compute_neighbour_bits(grid: &BrickGrid, levels: &[Level]) -> Vec<u32> {
    let level = |i: usize| levels.get(i).copied().unwrap_or(Level::Absent);
    grid.bricks()
        .map(|b| brick_neighbour_bits(grid, b, level))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_numbering_matches_the_doc() {
        assert_eq!(neighbour_bit_index(IVec3::new(-1, -1, -1)), 0);
        assert_eq!(neighbour_bit_index(IVec3::new(1, 0, 0)), 13); // idx 14
        assert_eq!(neighbour_bit_index(IVec3::new(-1, 0, 0)), 12); // idx 12
        assert_eq!(neighbour_bit_index(IVec3::new(1, 1, 1)), 25);
        assert_eq!(neighbour_bit(IVec3::new(0, 0, 1)), 1 << 21); // idx 22
        let mut seen = 0u32;
        for k in 0..NEIGHBOUR_COUNT {
            let d = neighbour_offset(k);
            assert_ne!(d, IVec3::ZERO);
            assert_eq!(neighbour_bit_index(d), k);
            seen |= neighbour_bit(d);
        }
        assert_eq!(seen, (1 << 26) - 1);
    }

    #[test]
    fn layout_entries_for_hand_computed_examples() {
        let g = CacheGeometry::new(4, UVec3::splat(32)).unwrap(); // S = 6, 5 slots per axis
                                                                  // Hi brick b = (1, 0, 2) in slot (0, 1, 0): origin (0, 6, 0), t = o + 1 - 4b.
        let slot = g.slot_index(UVec3::new(0, 1, 0));
        assert_eq!(
            layout_entry(&g, UVec3::new(1, 0, 2), Residency::Hi { slot }),
            [0.0 * 6.0 + 1.0 - 4.0, 6.0 + 1.0 - 0.0, 0.0 + 1.0 - 8.0, 1.0]
        );
        // Lo brick b = (3, 1, 0) in sub-slot 6 = (0, 1, 1) * 3 of slot (2, 0, 1): origin
        // (12, 3, 9); t = o + 0.5 - 2b = (12.5 - 6, 3.5 - 2, 9.5 - 0).
        let slot = g.slot_index(UVec3::new(2, 0, 1));
        assert_eq!(
            layout_entry(&g, UVec3::new(3, 1, 0), Residency::Lo { slot, sub_slot: 6 }),
            [6.5, 1.5, 9.5, 0.5]
        );
        assert_eq!(layout_entry(&g, UVec3::ONE, Residency::Absent), [0.0; 4]);
    }

    /// Position `n*b` (the brick's lower face) maps to the border/first-texel boundary for hi-res
    /// and to the first low-res texel centre for low-res bricks.
    #[test]
    fn lower_face_lands_where_the_doc_says() {
        let g = CacheGeometry::new(8, UVec3::splat(64)).unwrap();
        let brick = UVec3::new(2, 1, 3);
        let face = (brick * 8).as_vec3();
        let apply = |e: [f32; 4]| face * e[3] + glam::Vec3::new(e[0], e[1], e[2]);
        let hi = apply(layout_entry(&g, brick, Residency::Hi { slot: 9 }));
        assert_eq!(hi, g.slot_origin(9).as_vec3() + 1.0);
        let lo = apply(layout_entry(
            &g,
            brick,
            Residency::Lo {
                slot: 9,
                sub_slot: 3,
            },
        ));
        assert_eq!(lo, g.sub_slot_origin(9, 3).as_vec3() + 0.5);
    }

    /// A hand-made 3x3x3 configuration: centre Hi; face neighbour (-1,0,0), edge neighbour
    /// (1,1,0) and corner neighbour (-1,-1,-1) Lo; one face neighbour Hi; the rest Absent.
    #[test]
    fn neighbour_bits_of_a_hand_made_configuration() {
        let grid = BrickGrid::new(UVec3::splat(12), 4).unwrap();
        let mut levels = vec![Level::Absent; 27];
        let at = |x, y, z| grid.linear_index(UVec3::new(x, y, z));
        levels[at(1, 1, 1)] = Level::Hi;
        levels[at(0, 1, 1)] = Level::Lo; // face, d = (-1, 0, 0): idx 12 -> bit 12
        levels[at(2, 2, 1)] = Level::Lo; // edge, d = (1, 1, 0): idx 17 -> bit 16
        levels[at(0, 0, 0)] = Level::Lo; // corner, d = (-1, -1, -1): idx 0 -> bit 0
        levels[at(2, 1, 1)] = Level::Hi; // Hi neighbours contribute nothing
        let bits = compute_neighbour_bits(&grid, &levels);
        assert_eq!(bits[at(1, 1, 1)], (1 << 12) | (1 << 16) | 1);
        // (2,1,1) sees (2,2,1) at d = (0,1,0): idx 16 -> bit 15; (0,1,1) is two bricks away.
        assert_eq!(bits[at(2, 1, 1)], 1 << 15);
        for (i, &b) in bits.iter().enumerate() {
            if i != at(1, 1, 1) && i != at(2, 1, 1) {
                assert_eq!(b, 0, "brick {i}");
            }
        }
        // A Hi brick at the grid corner: all 26 neighbours Lo where they exist (7 of them).
        let mut levels = vec![Level::Lo; 27];
        levels[at(0, 0, 0)] = Level::Hi;
        let bits = compute_neighbour_bits(&grid, &levels);
        let expected = (0..NEIGHBOUR_COUNT)
            .filter(|&k| neighbour_offset(k).min_element() >= 0)
            .fold(0, |acc, k| acc | (1 << k));
        assert_eq!(bits[at(0, 0, 0)], expected);
        assert_eq!(expected.count_ones(), 7);
        assert_eq!(bits[at(1, 1, 1)], 0);
    }
}
