//! Geometry of the brick cache image: slot size, cache extent, slot and sub-slot origins
//! (`docs/cache-layout.md`, "Cache image").

use super::{CacheError, Residency};
use crate::bricks::{
    hi_res_brick_extent, low_res_brick_extent, subslot_offset, MAX_BRICK_SIZE, SUB_SLOTS_PER_SLOT,
};
use glam::UVec3;
use std::cmp::Reverse;

/// Smallest accepted brick size (`docs/cache-layout.md`: `n` is a power of two `>= 4`).
pub const MIN_BRICK_SIZE: u32 = 4;

/// The geometry of a brick cache image.
///
/// A cache of extent `C` texels (a power of two per axis) is divided into cubic slots of edge
/// `S = n + 2` texels, `floor(C / S)` per axis; slot `s = (sx, sy, sz)` starts at texel `s * S` and
/// has the linear index `sx + SXs * (sy + SYs * sz)`. The texels beyond the last whole slot on each
/// axis are unused. A slot holds one hi-res brick, or is split into eight sub-slots of edge
/// `n/2 + 1` that hold one low-res brick each.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct CacheGeometry {
    brick_size: u32,
    extent: UVec3,
    slots_per_axis: UVec3,
}

impl CacheGeometry {
    /// A cache of `extent` texels for bricks of `brick_size` hi-res voxels.
    ///
    /// `brick_size` must be a power of two in `4..=MAX_BRICK_SIZE`; every axis of `extent` must be a
    /// power of two holding at least one slot (`>= n + 2`), and the slot count must fit in a `u32`
    /// below [`super::EMPTY`].
    pub fn new(brick_size: u32, extent: UVec3) -> Result<Self, CacheError> {
        check_brick_size(brick_size)?;
        let slots_per_axis = whole_slots(hi_res_brick_extent(brick_size), extent)?;
        Ok(Self {
            brick_size,
            extent,
            slots_per_axis,
        })
    }

    /// Chooses the cache extent for `slots_wanted` slots of bricks of `brick_size` voxels.
    ///
    /// Every axis is a power of two between the smallest one holding a slot (`(n+2)` rounded up to
    /// a power of two) and the largest power of two `<= max_dim_3d` (the device's
    /// `maxImageDimension3D`), and the image must fit the budget:
    /// `Cx * Cy * Cz * bytes_per_texel <= byte_budget`. Among those extents:
    ///
    /// 1. if some hold `slots_wanted` slots (at least one slot is always wanted), the one with the
    ///    fewest texels wins, then the one with more slots, then the more cubic one (smaller largest
    ///    axis), then the one with the larger x, then y (so `256x256x128` rather than `128x256x256`);
    /// 2. otherwise the cache is capped: the extent with the most slots wins (then fewer texels and
    ///    the same tie-breaks). [`CacheGeometry::slot_count`] is then below `slots_wanted` and the
    ///    LOD selector has to demote or cull bricks to fit.
    ///
    /// Errors: invalid brick size, zero `bytes_per_texel`, a slot larger than `max_dim_3d`, or a
    /// budget that cannot hold even one slot.
    pub fn choose(
        brick_size: u32,
        bytes_per_texel: u32,
        byte_budget: u64,
        max_dim_3d: u32,
        slots_wanted: u32,
    ) -> Result<Self, CacheError> {
        check_brick_size(brick_size)?;
        let extent = choose_extent(
            hi_res_brick_extent(brick_size),
            bytes_per_texel,
            byte_budget,
            max_dim_3d,
            slots_wanted,
        )?;
        Self::new(brick_size, extent)
    }

    /// Brick size `n` in hi-res voxels.
    pub fn brick_size(&self) -> u32 {
        self.brick_size
    }

    /// Slot edge `S = n + 2` texels (one hi-res brick with its duplicated border).
    pub fn slot_edge(&self) -> u32 {
        hi_res_brick_extent(self.brick_size)
    }

    /// Sub-slot edge `n/2 + 1` texels (one low-res brick, both faces included).
    pub fn sub_slot_edge(&self) -> u32 {
        low_res_brick_extent(self.brick_size)
    }

    /// Cache extent `C` in texels (a power of two per axis).
    pub fn extent(&self) -> UVec3 {
        self.extent
    }

    /// Whole slots per axis: `floor(C / S)`.
    pub fn slots_per_axis(&self) -> UVec3 {
        self.slots_per_axis
    }

    /// Total number of slots.
    pub fn slot_count(&self) -> u32 {
        // `new` checked that the product fits in a u32.
        self.slots_per_axis.x * self.slots_per_axis.y * self.slots_per_axis.z
    }

    /// Texels in the cache image: `Cx * Cy * Cz`.
    pub fn texel_count(&self) -> u64 {
        u64::from(self.extent.x) * u64::from(self.extent.y) * u64::from(self.extent.z)
    }

    /// Bytes of the cache image at `bytes_per_texel` (saturating).
    pub fn byte_size(&self, bytes_per_texel: u32) -> u64 {
        self.texel_count()
            .saturating_mul(u64::from(bytes_per_texel))
    }

    /// Slot coordinates of linear slot index `slot` (x fastest).
    pub fn slot_coords(&self, slot: u32) -> UVec3 {
        let s = self.slots_per_axis;
        UVec3::new(slot % s.x, (slot / s.x) % s.y, slot / (s.x * s.y))
    }

    /// Linear index of slot coordinates `coords`: `sx + SXs * (sy + SYs * sz)`; the caller keeps
    /// `coords` inside [`CacheGeometry::slots_per_axis`].
    pub fn slot_index(&self, coords: UVec3) -> u32 {
        let s = self.slots_per_axis;
        coords.x + s.x * (coords.y + s.y * coords.z)
    }

    /// Texel origin of slot `slot`: `slot_coords * S`.
    pub fn slot_origin(&self, slot: u32) -> UVec3 {
        self.slot_coords(slot) * self.slot_edge()
    }

    /// Texel origin of sub-slot `sub_slot` (in `0..8`) of slot `slot`:
    /// `slot_origin + (j & 1, (j >> 1) & 1, (j >> 2) & 1) * (n/2 + 1)`.
    pub fn sub_slot_origin(&self, slot: u32, sub_slot: u32) -> UVec3 {
        debug_assert!(sub_slot < SUB_SLOTS_PER_SLOT);
        self.slot_origin(slot) + subslot_offset(self.brick_size, sub_slot)
    }

    /// The texel box a brick with `residency` occupies: `(origin, extent)` per axis, `None` when
    /// absent. Hi-res: the whole slot (`S^3`); low-res: its sub-slot (`(n/2+1)^3`).
    pub fn texel_box(&self, residency: Residency) -> Option<(UVec3, UVec3)> {
        match residency {
            Residency::Absent => None,
            Residency::Hi { slot } => {
                Some((self.slot_origin(slot), UVec3::splat(self.slot_edge())))
            }
            Residency::Lo { slot, sub_slot } => Some((
                self.sub_slot_origin(slot, sub_slot),
                UVec3::splat(self.sub_slot_edge()),
            )),
        }
    }
}

/// The cache extent [`CacheGeometry::choose`] picks for slots of `slot_edge` texels (its doc
/// comment gives the rule); shared with [`super::SlotGeometry::choose`].
pub(super) fn choose_extent(
    slot_edge: u32,
    bytes_per_texel: u32,
    byte_budget: u64,
    max_dim_3d: u32,
    slots_wanted: u32,
) -> Result<UVec3, CacheError> {
    if bytes_per_texel == 0 {
        return Err(CacheError::ZeroBytesPerTexel);
    }
    let min_axis = slot_edge.next_power_of_two();
    let max_axis = if max_dim_3d == 0 {
        0
    } else {
        1u32 << (31 - max_dim_3d.leading_zeros())
    };
    if max_axis < min_axis {
        return Err(CacheError::SlotExceedsMaxDimension {
            slot_edge,
            max_dim_3d,
        });
    }
    let bytes = |e: [u32; 3]| -> u128 {
        e.iter().map(|&c| u128::from(c)).product::<u128>() * u128::from(bytes_per_texel)
    };
    let smallest = [min_axis; 3];
    if bytes(smallest) > u128::from(byte_budget) {
        return Err(CacheError::BudgetBelowOneSlot {
            extent: smallest,
            needed_bytes: bytes(smallest),
            byte_budget,
        });
    }
    let axes: Vec<u32> = std::iter::successors(Some(min_axis), |&c| c.checked_mul(2))
        .take_while(|&c| c <= max_axis)
        .collect();
    let wanted = u128::from(slots_wanted.max(1));
    // Rank key, smallest wins (see the doc comment).
    type Key = (u8, u128, u128, u32, Reverse<u32>, Reverse<u32>);
    let mut best: Option<(Key, [u32; 3])> = None;
    for &x in &axes {
        for &y in &axes {
            for &z in &axes {
                let e = [x, y, z];
                if bytes(e) > u128::from(byte_budget) {
                    continue;
                }
                let texels = u128::from(x) * u128::from(y) * u128::from(z);
                let slots = e
                    .iter()
                    .map(|&c| u128::from(c / slot_edge))
                    .product::<u128>();
                let fewer_slots = u128::MAX - slots;
                let cubic = x.max(y).max(z);
                let key: Key = if slots >= wanted {
                    (0, texels, fewer_slots, cubic, Reverse(x), Reverse(y))
                } else {
                    (1, fewer_slots, texels, cubic, Reverse(x), Reverse(y))
                };
                if best.as_ref().is_none_or(|(k, _)| key < *k) {
                    best = Some((key, e));
                }
            }
        }
    }
    // `smallest` fits the budget and the dimension limit, so `best` is always set.
    Ok(UVec3::from_array(best.map_or(smallest, |(_, e)| e)))
}

/// Whole slots of edge `slot_edge` per axis of a cache of `extent` texels: every axis a power of
/// two holding at least one slot, fewer slots than a `u32` slot index below [`super::EMPTY`]
/// addresses. Shared with [`super::SlotGeometry::new`].
pub(super) fn whole_slots(slot_edge: u32, extent: UVec3) -> Result<UVec3, CacheError> {
    if extent
        .to_array()
        .iter()
        .any(|&c| !c.is_power_of_two() || c < slot_edge)
    {
        return Err(CacheError::InvalidExtent {
            extent: extent.to_array(),
            slot_edge,
        });
    }
    let slots_per_axis = extent / slot_edge;
    let slots = slots_per_axis.as_u64vec3().element_product();
    if slots >= u64::from(super::EMPTY) {
        return Err(CacheError::TooManySlots { slots });
    }
    Ok(slots_per_axis)
}

/// Checks `n` is a power of two in `MIN_BRICK_SIZE..=MAX_BRICK_SIZE`.
pub(super) fn check_brick_size(brick_size: u32) -> Result<(), CacheError> {
    if brick_size.is_power_of_two() && (MIN_BRICK_SIZE..=MAX_BRICK_SIZE).contains(&brick_size) {
        Ok(())
    } else {
        Err(CacheError::InvalidBrickSize { size: brick_size })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MIB: u64 = 1 << 20;

    fn slots(e: [u32; 3], slot_edge: u32) -> u64 {
        e.iter().map(|&c| u64::from(c / slot_edge)).product()
    }

    #[test]
    fn one_slot_gets_the_smallest_power_of_two() {
        let g = CacheGeometry::choose(32, 1, u64::MAX, 4096, 1).unwrap();
        assert_eq!(g.extent(), UVec3::splat(64));
        assert_eq!(g.slot_edge(), 34);
        assert_eq!(g.sub_slot_edge(), 17);
        assert_eq!(g.slot_count(), 1);
        // Zero wanted slots still gives one.
        assert_eq!(CacheGeometry::choose(32, 1, u64::MAX, 4096, 0).unwrap(), g);
    }

    #[test]
    fn nine_slots_pick_a_non_cubic_extent() {
        // 64 -> 1 slot, 128 -> 3 slots of 34 texels: 3 x 3 x 1 = 9 in 2^20 texels.
        let g = CacheGeometry::choose(32, 1, u64::MAX, 4096, 9).unwrap();
        assert_eq!(g.extent(), UVec3::new(128, 128, 64));
        assert_eq!(g.slots_per_axis(), UVec3::new(3, 3, 1));
        assert_eq!(g.slot_count(), 9);
    }

    #[test]
    fn papers_example_cache_size() {
        // Beyer et al. §3.1: a 512x512x1024 cache holds 15x15x30 bricks of 34^3.
        let g = CacheGeometry::choose(32, 1, u64::MAX, 4096, 15 * 15 * 30).unwrap();
        assert_eq!(g.texel_count(), 1 << 28);
        assert_eq!(g.slot_count(), 6750);
        assert_eq!(g.extent(), UVec3::new(1024, 512, 512));
    }

    #[test]
    fn budget_caps_the_extent() {
        // 2 bytes per texel, 64 MiB: at most 2^25 texels. Best: 512x256x256 (15*7*7 = 735 slots).
        let budget = 64 * MIB;
        let g = CacheGeometry::choose(32, 2, budget, 4096, 1000).unwrap();
        assert!(g.byte_size(2) <= budget);
        assert_eq!(g.slot_count(), 735);
        assert_eq!(g.extent(), UVec3::new(512, 256, 256));
    }

    #[test]
    fn max_dimension_caps_the_extent() {
        let g = CacheGeometry::choose(32, 1, u64::MAX, 128, 100).unwrap();
        assert_eq!(g.extent(), UVec3::splat(128));
        assert_eq!(g.slot_count(), 27);
        // A limit that is not a power of two rounds down.
        let g = CacheGeometry::choose(32, 1, u64::MAX, 200, 100).unwrap();
        assert_eq!(g.extent(), UVec3::splat(128));
    }

    #[test]
    fn errors_when_one_slot_does_not_fit() {
        assert_eq!(
            CacheGeometry::choose(32, 1, u64::MAX, 63, 1),
            Err(CacheError::SlotExceedsMaxDimension {
                slot_edge: 34,
                max_dim_3d: 63
            })
        );
        let err = CacheGeometry::choose(32, 2, 64 * 64 * 64 * 2 - 1, 4096, 1).unwrap_err();
        assert_eq!(
            err,
            CacheError::BudgetBelowOneSlot {
                extent: [64; 3],
                needed_bytes: 64 * 64 * 64 * 2,
                byte_budget: 64 * 64 * 64 * 2 - 1
            }
        );
        assert!(err.to_string().contains("budget"), "{err}");
        assert!(CacheGeometry::choose(32, 2, 64 * 64 * 64 * 2, 4096, 1).is_ok());
        assert_eq!(
            CacheGeometry::choose(32, 0, u64::MAX, 4096, 1),
            Err(CacheError::ZeroBytesPerTexel)
        );
        for size in [0, 2, 3, 12, 2048] {
            assert_eq!(
                CacheGeometry::choose(size, 1, u64::MAX, 4096, 1),
                Err(CacheError::InvalidBrickSize { size })
            );
        }
    }

    /// Random requests: every axis a power of two within the limits, the budget respected, and the
    /// choice minimal: halving any axis (where allowed) loses the wanted slots.
    #[test]
    fn random_choices_respect_limits_and_are_minimal() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = |m: u64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % m
        };
        for _ in 0..500 {
            let n = [4u32, 8, 16, 32, 64][next(5) as usize];
            let bpt = [1u32, 2, 4][next(3) as usize];
            let max_dim = 32 + next(4096) as u32;
            let budget = 1 + next(512 * MIB);
            let wanted = 1 + next(3000) as u32;
            let s = n + 2;
            match CacheGeometry::choose(n, bpt, budget, max_dim, wanted) {
                Ok(g) => {
                    let e = g.extent().to_array();
                    assert!(e
                        .iter()
                        .all(|&c| c.is_power_of_two() && c <= max_dim && c >= s));
                    assert!(g.byte_size(bpt) <= budget);
                    assert_eq!(u64::from(g.slot_count()), slots(e, s));
                    if u64::from(g.slot_count()) >= u64::from(wanted) {
                        for a in 0..3 {
                            let mut h = e;
                            h[a] /= 2;
                            if h[a] >= s {
                                assert!(slots(h, s) < u64::from(wanted), "{e:?} not minimal");
                            }
                        }
                    } else {
                        // Capped: doubling any axis breaks a limit.
                        for a in 0..3 {
                            let mut d = e;
                            d[a] *= 2;
                            let bytes =
                                d.iter().map(|&c| u64::from(c)).product::<u64>() * u64::from(bpt);
                            assert!(d[a] > max_dim || bytes > budget, "{e:?} could grow");
                        }
                    }
                }
                Err(err) => {
                    let min_axis = u64::from(s.next_power_of_two());
                    assert!(
                        u64::from(max_dim) < min_axis || min_axis.pow(3) * u64::from(bpt) > budget,
                        "unexpected {err}"
                    );
                }
            }
        }
    }

    #[test]
    fn slot_and_sub_slot_origins() {
        let g = CacheGeometry::new(4, UVec3::new(32, 32, 16)).unwrap();
        assert_eq!(g.slot_edge(), 6);
        assert_eq!(g.slots_per_axis(), UVec3::new(5, 5, 2));
        assert_eq!(g.slot_count(), 50);
        assert_eq!(g.slot_coords(7), UVec3::new(2, 1, 0));
        assert_eq!(g.slot_index(UVec3::new(2, 1, 0)), 7);
        assert_eq!(g.slot_origin(7), UVec3::new(12, 6, 0));
        assert_eq!(g.slot_origin(26), UVec3::new(6, 0, 6));
        // Sub-slot 5 = (1, 0, 1) * 3.
        assert_eq!(g.sub_slot_origin(7, 5), UVec3::new(15, 6, 3));
        assert_eq!(g.sub_slot_origin(7, 7), UVec3::new(15, 9, 3));
        for slot in 0..g.slot_count() {
            assert_eq!(g.slot_index(g.slot_coords(slot)), slot);
        }
        assert_eq!(
            g.texel_box(Residency::Lo {
                slot: 7,
                sub_slot: 2
            }),
            Some((UVec3::new(12, 9, 0), UVec3::splat(3)))
        );
        assert_eq!(g.texel_box(Residency::Absent), None);
    }

    #[test]
    fn new_rejects_bad_extents() {
        assert!(matches!(
            CacheGeometry::new(4, UVec3::new(32, 24, 32)),
            Err(CacheError::InvalidExtent { .. })
        ));
        assert!(matches!(
            CacheGeometry::new(8, UVec3::new(32, 8, 32)),
            Err(CacheError::InvalidExtent { .. })
        ));
        assert!(matches!(
            CacheGeometry::new(6, UVec3::splat(32)),
            Err(CacheError::InvalidBrickSize { size: 6 })
        ));
    }
}
