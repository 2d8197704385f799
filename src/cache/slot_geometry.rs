//! The slots of a brick cache for any number of levels, parameterised by its packing classes
//! (issue 36): with **three classes**, the paper's three-level packing (Beyer et al. §3.1; issue
//! 19): cache slots of edge `n + 4` texels, each holding one level-0 brick with two duplicated
//! border texels per side, eight level-1 bricks in `(n/2 + 2)^3` sub-slots, or sixty-four
//! level-2 bricks in `(n/4 + 1)^3` sub-slots. A slot holds bricks of one class only.
//!
//! With **two classes** (a volume drawn at levels 0 and 1 only, [`classes_for_levels`]) the
//! slot edge is `n + 2`, a level-0 brick keeps one border texel per side and a level-1 sub-slot
//! is `n/2 + 1`: the two-level cache's bytes and capacity (`docs/cache-layout.md`, "Cache
//! image"; [`super::CacheGeometry`]). In general: slot edge `n + 2^(c-1)`, level-0 border
//! `2^(c-2)` ([`SlotGeometry::border`]). Stored bricks (a level store, `LevelGrid::stored_brick`)
//! keep two border texels at level 0 whatever the cache; [`SlotGeometry::cache_texels`] takes
//! the cache's inner box of one.
//!
//! Levels and what a brick stores (`pyramid::LevelGrid::vertex_pyramid`):
//! - level 0: hi-res voxels at cell centres; texel `origin + t` (t in `0..n+4`) holds voxel
//!   `n*b - 2 + t`, clamped to the volume. The ray-caster's band reads the inner border layer
//!   (slot-local texels 1 and `n + 2`), which the border fixup rewrites exactly as in the
//!   two-level cache; the outer layer keeps the duplicated voxels.
//! - level `k` in 1..=2: samples on vertices every `2^k` voxels; texel `origin + t` (t in
//!   `0..=n/2^k`) holds level-`k` sample `n*b/2^k + t`, both faces included. A level-1 sub-slot
//!   has one texel more per axis than its `n/2 + 1` samples; it is left unwritten.
//! - level `k > 2` (any number of levels): a brick of the level-2 size, `n/4 + 1` samples per
//!   axis every `2^k` voxels, in a level-2 sub-slot, for a whole aligned block of `2^(k - 2)`
//!   bricks per axis (`reference::block_bricks`): texel `origin + t` holds level-`k`
//!   sample `n*b0/2^k + t`, `b0` the block's first brick. Every brick of the block has the
//!   block's layout entry. Level-2 sub-slots hold bricks of any level from 2 up, mixed.
//!
//! Layout entries use the two-level cache's convention, `x_tex = x * t_w + t_xyz`:
//! - level 0: `t_w = 1`, `t_xyz = origin + border - n*b` (border 2 with three classes, 1 with
//!   two);
//! - level `k >= 1`: `t_w = 2^-k`, `t_xyz = origin + 0.5 - n*b0/2^k` (`b0 = b` up to level 2).
//!
//! `t_w` is exact in `f32`, and the ray-caster's test `t_w == 1` still singles out level 0.

use super::geometry::{check_brick_size, choose_extent, whole_slots};
use super::CacheError;
use glam::{IVec3, UVec3};

/// Levels of the three-level packing: its three sizes of stored brick (levels past 2 use the
/// level-2 size).
pub const THREE_LEVELS: u32 = 3;

/// Bricks per axis of a block of `level`: 1 up to level 2, `2^(level - 2)` past it (a stored
/// brick of level `k >= 2` holds `n/4 + 1` samples per axis every `2^k` voxels, so it covers
/// `2^(k - 2)` bricks; module docs).
pub fn block_bricks(level: u32) -> u32 {
    1 << level.saturating_sub(2).min(30)
}

/// The first brick of the block of `level` holding `brick`.
pub fn block_origin(brick: UVec3, level: u32) -> UVec3 {
    let block = block_bricks(level);
    brick / block * block
}

/// The smallest brick size that takes `levels` levels: up to three levels a brick must hold a
/// whole cell of the coarsest (`2^(levels - 1)`); past three, the block levels need bricks of at
/// least 8 voxels (their blocks' faces then lie on the next level's samples).
pub fn min_brick_size_for_levels(levels: u32) -> u32 {
    if levels <= THREE_LEVELS {
        1 << levels.saturating_sub(1)
    } else {
        8
    }
}

/// The levels a volume of bricks of `brick_size`, `bricks` per axis, gets by default: levels
/// 0-2, and past them (bricks of 8 voxels or more) as many block levels as it takes for one
/// block to cover the grid's longest axis; fewer when the bricks are too small for three.
pub fn pyramid_levels(brick_size: u32, bricks: UVec3) -> u32 {
    if brick_size < min_brick_size_for_levels(THREE_LEVELS + 1) {
        let fitting = (1..=THREE_LEVELS)
            .rev()
            .find(|&l| brick_size >= min_brick_size_for_levels(l));
        return fitting.unwrap_or(1);
    }
    let longest = bricks.max_element().max(1);
    // block_bricks(k) = 2^(k - 2) >= longest.
    THREE_LEVELS.max(2 + longest.next_power_of_two().trailing_zeros() + 1)
}

/// Stored bricks per axis of `level` for a grid of `bricks` per axis: one per block
/// ([`block_bricks`]), the last block clipped by the grid.
pub fn stored_bricks_per_axis(bricks: UVec3, level: u32) -> UVec3 {
    let block = block_bricks(level);
    (bricks + UVec3::splat(block - 1)) / block
}

/// Texels per axis a stored brick of `level` holds for bricks of `brick_size`: `n + 4` at level
/// 0 (two border texels per side), `n / 2^min(level, 2) + 1` vertex samples above (module docs).
pub fn stored_brick_edge(brick_size: u32, level: u32) -> u32 {
    match level {
        0 => brick_size + 4,
        k => (brick_size >> k.min(THREE_LEVELS - 1)) + 1,
    }
}

/// The level-`level` sample index of texel 0 of the stored brick whose block starts at brick
/// `first` (module docs): voxel `n*b - 2` at level 0, sample `n*b0 / 2^level` above. Samples past
/// the level's grid are clamped to it by whoever reads them.
pub fn stored_first_sample(first: UVec3, brick_size: u32, level: u32) -> IVec3 {
    if level == 0 {
        (first * brick_size).as_ivec3() - IVec3::splat(2)
    } else {
        (first.as_ivec3() * brick_size as i32) / (1 << level.min(30))
    }
}

/// The slots a plan takes in the three-level packing: one per level-0 brick, one per eight
/// level-1 bricks, one per sixty-four stored bricks of level 2 or coarser (a block counts once).
/// `levels` holds one entry per brick of a grid of `bricks` per axis (x fastest), `None` for a
/// brick that is not drawn.
pub fn slots_for_plan(bricks: UVec3, levels: &[Option<u32>]) -> u64 {
    let mut per_class = [0u64; THREE_LEVELS as usize];
    for (i, level) in levels.iter().enumerate() {
        let Some(level) = *level else {
            continue;
        };
        let i = i as u32;
        let b = UVec3::new(
            i % bricks.x,
            (i / bricks.x) % bricks.y,
            i / (bricks.x * bricks.y),
        );
        if block_origin(b, level) == b {
            per_class[level.min(THREE_LEVELS - 1) as usize] += 1;
        }
    }
    slots_for_classes(per_class)
}

/// The slots `per_class` stored bricks of level 0, level 1, and level 2 or coarser take: 1, 8
/// and 64 per slot.
pub fn slots_for_classes(per_class: [u64; THREE_LEVELS as usize]) -> u64 {
    (0..THREE_LEVELS)
        .map(|k| per_class[k as usize].div_ceil(u64::from(SlotGeometry::bricks_per_slot(k))))
        .sum()
}

/// Where a brick of the three-level packing lives: slot `slot`, at sub-slot `index` (`0` for
/// level 0, `0..8` for level 1, `0..64` for level 2 and up) of the size of level `level`.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct LevelSlot {
    /// Linear slot index.
    pub slot: u32,
    /// The level the slot holds.
    pub level: u32,
    /// The sub-slot inside the slot, x fastest over `2^level` per axis.
    pub index: u32,
}

/// The slot classes of a cache for `levels` levels: 2 (levels 0 and 1, the two-level cache's
/// slots) for one or two levels, 3 past them.
pub fn classes_for_levels(levels: u32) -> u32 {
    if levels <= 2 {
        2
    } else {
        THREE_LEVELS
    }
}

/// The geometry of a brick cache image of `c` slot classes (2 or 3; module docs): slot edge
/// `n + 2^(c-1)`, whole slots only (`floor(C / edge)` per axis), slot `s` at texel
/// `s * edge`, linear index x fastest.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct SlotGeometry {
    brick_size: u32,
    classes: u32,
    extent: UVec3,
    slots_per_axis: UVec3,
}

impl SlotGeometry {
    /// A cache of `extent` texels for bricks of `brick_size` voxels with `classes` slot classes
    /// (2 or 3): `brick_size` a power of two in `MIN_BRICK_SIZE..=MAX_BRICK_SIZE` (a level-2
    /// brick then has whole cells), every axis of `extent` a power of two holding at least one
    /// slot, and fewer slots than `u32::MAX`.
    pub fn new(brick_size: u32, classes: u32, extent: UVec3) -> Result<Self, CacheError> {
        check_brick_size(brick_size)?;
        check_classes(classes)?;
        let slots_per_axis = whole_slots(brick_size + (1 << (classes - 1)), extent)?;
        Ok(Self {
            brick_size,
            classes,
            extent,
            slots_per_axis,
        })
    }

    /// Chooses the cache extent for `slots_wanted` slots of `classes` classes under the same
    /// rule as [`super::CacheGeometry::choose`] (powers of two up to `max_dim_3d`, at most
    /// `byte_budget` bytes; the smallest that holds the slots, else the one with the most).
    ///
    /// Errors: invalid brick size or class count, zero `bytes_per_texel`, a slot larger than
    /// `max_dim_3d`, or a budget that cannot hold even one slot.
    pub fn choose(
        brick_size: u32,
        classes: u32,
        bytes_per_texel: u32,
        byte_budget: u64,
        max_dim_3d: u32,
        slots_wanted: u32,
    ) -> Result<Self, CacheError> {
        check_brick_size(brick_size)?;
        check_classes(classes)?;
        let extent = choose_extent(
            brick_size + (1 << (classes - 1)),
            bytes_per_texel,
            byte_budget,
            max_dim_3d,
            slots_wanted,
        )?;
        Self::new(brick_size, classes, extent)
    }

    /// Slot classes: 2 (levels 0 and 1) or 3 (levels 0, 1, and 2 and coarser).
    pub fn classes(&self) -> u32 {
        self.classes
    }

    /// Border texels per side of a level-0 brick in its slot: 1 with two classes, 2 with three.
    pub fn border(&self) -> u32 {
        1 << (self.classes - 2)
    }

    /// Brick size `n` in hi-res voxels.
    pub fn brick_size(&self) -> u32 {
        self.brick_size
    }

    /// Slot edge `n + 2 * border` texels (`n + 2` with two classes, `n + 4` with three).
    pub fn slot_edge(&self) -> u32 {
        self.brick_size + 2 * self.border()
    }

    /// Cache extent in texels.
    pub fn extent(&self) -> UVec3 {
        self.extent
    }

    /// Whole slots per axis.
    pub fn slots_per_axis(&self) -> UVec3 {
        self.slots_per_axis
    }

    /// Total number of slots.
    pub fn slot_count(&self) -> u32 {
        // `new` checked that the product fits in a u32.
        self.slots_per_axis.element_product()
    }

    /// Stored bricks of `level` one slot holds: 1, 8, 64 (`8^level`), and 64 past level 2.
    pub fn bricks_per_slot(level: u32) -> u32 {
        1 << (3 * level.min(THREE_LEVELS - 1))
    }

    /// Sub-slot edge of `level` in texels, the slot edge over `2^level`: with three classes
    /// `n + 4`, `n/2 + 2`, `n/4 + 1`, and `n/4 + 1` past level 2; with two `n + 2`, `n/2 + 1`.
    pub fn sub_slot_edge(&self, level: u32) -> u32 {
        self.slot_edge() >> level.min(THREE_LEVELS - 1)
    }

    /// Texels per axis the cache holds of a brick of `level`: `n + 2 * border` at level 0,
    /// `n / 2^level + 1` vertex samples above (what a stored brick holds,
    /// [`stored_brick_edge`]).
    pub fn stored_edge(&self, level: u32) -> u32 {
        match level {
            0 => self.slot_edge(),
            _ => stored_brick_edge(self.brick_size, level),
        }
    }

    /// The texels the cache holds of a stored brick of `level` (`stored`:
    /// [`stored_brick_edge`]`^3` values, x fastest): the stored brick itself, or at level 0
    /// with two classes its inner `(n + 2)^3` box (one border texel per side instead of two).
    pub fn cache_texels<'a>(&self, level: u32, stored: &'a [f32]) -> std::borrow::Cow<'a, [f32]> {
        let (from, to) = (
            stored_brick_edge(self.brick_size, level),
            self.stored_edge(level),
        );
        if from == to {
            return std::borrow::Cow::Borrowed(stored);
        }
        let (from, to, skip) = (from as usize, to as usize, ((from - to) / 2) as usize);
        let mut inner = Vec::with_capacity(to * to * to);
        for z in 0..to {
            for y in 0..to {
                let row = skip + from * ((y + skip) + from * (z + skip));
                inner.extend_from_slice(&stored[row..row + to]);
            }
        }
        std::borrow::Cow::Owned(inner)
    }

    /// Slot coordinates of linear slot index `slot` (x fastest).
    pub fn slot_coords(&self, slot: u32) -> UVec3 {
        let s = self.slots_per_axis;
        UVec3::new(slot % s.x, (slot / s.x) % s.y, slot / (s.x * s.y))
    }

    /// Texel origin of slot `slot`.
    pub fn slot_origin(&self, slot: u32) -> UVec3 {
        self.slot_coords(slot) * self.slot_edge()
    }

    /// Texel origin of `place`: the slot origin plus the sub-slot's coordinates (x fastest over
    /// `2^min(level, 2)` per axis) times the sub-slot edge. `None` when the level (past 30, or
    /// past 1 with two classes) or the index is out of range, or the slot is not in the cache.
    pub fn origin(&self, place: LevelSlot) -> Option<UVec3> {
        if place.level > 30
            || place.level >= self.classes && self.classes < THREE_LEVELS
            || place.index >= Self::bricks_per_slot(place.level)
            || place.slot >= self.slot_count()
        {
            return None;
        }
        let per_axis = 1 << place.level.min(THREE_LEVELS - 1);
        let sub = UVec3::new(
            place.index % per_axis,
            (place.index / per_axis) % per_axis,
            place.index / (per_axis * per_axis),
        );
        Some(self.slot_origin(place.slot) + sub * self.sub_slot_edge(place.level))
    }

    /// Layout entry `(t_x, t_y, t_z, t_w)` of the bricks stored at `place` (module docs), `brick`
    /// the first brick of the stored brick's block (the brick itself up to level 2); all zero (a
    /// skipped brick) when `place` is out of range.
    pub fn layout_entry(&self, brick: UVec3, place: LevelSlot) -> [f32; 4] {
        let Some(origin) = self.origin(place) else {
            return [0.0; 4];
        };
        let n = i64::from(self.brick_size);
        let b = brick.as_i64vec3();
        let o = origin.as_i64vec3();
        if place.level == 0 {
            let t = o + i64::from(self.border()) - n * b;
            [t.x as f32, t.y as f32, t.z as f32, 1.0]
        } else {
            // n * b is a multiple of 2^level: b is a block's first brick.
            let t = o - n * b / (1i64 << place.level);
            let scale = 1.0 / (1u32 << place.level) as f32;
            [t.x as f32 + 0.5, t.y as f32 + 0.5, t.z as f32 + 0.5, scale]
        }
    }
}

/// Refuses a class count other than 2 or 3.
fn check_classes(classes: u32) -> Result<(), CacheError> {
    if (2..=THREE_LEVELS).contains(&classes) {
        Ok(())
    } else {
        Err(CacheError::InvalidClasses { classes })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_slots_tile_the_slot_without_overlap() {
        for n in [4, 8, 16, 32, 64] {
            let geometry = SlotGeometry::new(n, 3, UVec3::splat(256)).unwrap();
            let s = geometry.slot_edge();
            for level in 0..THREE_LEVELS {
                let edge = geometry.sub_slot_edge(level);
                assert!(geometry.stored_edge(level) <= edge, "n {n} level {level}");
                let mut covered = vec![0u8; (s * s * s) as usize];
                for index in 0..SlotGeometry::bricks_per_slot(level) {
                    let place = LevelSlot {
                        slot: 1,
                        level,
                        index,
                    };
                    let o = geometry.origin(place).unwrap() - geometry.slot_origin(1);
                    for z in 0..edge {
                        for y in 0..edge {
                            for x in 0..edge {
                                let t = o + UVec3::new(x, y, z);
                                assert!(t.cmplt(UVec3::splat(s)).all(), "n {n} level {level}");
                                covered[(t.x + s * (t.y + s * t.z)) as usize] += 1;
                            }
                        }
                    }
                }
                // Every level's sub-slots fill the slot exactly, once.
                assert_eq!(edge << level, s, "n {n} level {level}");
                assert!(covered.iter().all(|&c| c == 1), "n {n} level {level}");
            }
        }
    }

    #[test]
    fn choose_finds_the_slots_wanted_within_the_budget() {
        let geometry = SlotGeometry::choose(32, 3, 4, 1 << 30, 4096, 100).unwrap();
        assert!(geometry.slot_count() >= 100);
        assert!(geometry.extent().element_product() as u64 * 4 <= 1 << 30);
        // Capped by the budget: the most slots that fit.
        let capped = SlotGeometry::choose(32, 3, 4, 64 * 64 * 64 * 4, 4096, 100).unwrap();
        assert_eq!(capped.slot_count(), 1);
        assert!(matches!(
            SlotGeometry::choose(32, 3, 4, 1000, 4096, 1),
            Err(CacheError::BudgetBelowOneSlot { .. })
        ));
        assert_eq!(
            SlotGeometry::choose(24, 3, 4, 1 << 30, 4096, 1),
            Err(CacheError::InvalidBrickSize { size: 24 })
        );
    }

    #[test]
    fn bad_geometry_and_places_are_refused() {
        assert_eq!(
            SlotGeometry::new(12, 3, UVec3::splat(64)),
            Err(CacheError::InvalidBrickSize { size: 12 })
        );
        assert_eq!(
            SlotGeometry::new(32, 3, UVec3::new(64, 32, 64)),
            Err(CacheError::InvalidExtent {
                extent: [64, 32, 64],
                slot_edge: 36
            })
        );
        let geometry = SlotGeometry::new(8, 3, UVec3::splat(32)).unwrap();
        assert_eq!(geometry.slot_count(), 8);
        let place = |slot, level, index| LevelSlot { slot, level, index };
        assert_eq!(geometry.origin(place(8, 0, 0)), None);
        assert_eq!(geometry.origin(place(0, 1, 8)), None);
        assert_eq!(geometry.origin(place(0, 31, 0)), None);
        assert_eq!(geometry.origin(place(0, 3, 64)), None);
        assert_eq!(
            geometry.origin(place(7, 3, 63)),
            geometry.origin(place(7, 2, 63))
        );
        assert_eq!(
            geometry.layout_entry(UVec3::ZERO, place(0, 2, 64)),
            [0.0; 4]
        );
        assert_eq!(
            geometry.origin(place(7, 2, 63)),
            Some(UVec3::splat(12 + 3 * 3))
        );
    }

    /// Two classes are the two-level cache's slots (issue 36): the same capacity for any
    /// budget, the same texel origins and the same layout entries for level 0 (`Hi`) and
    /// level 1 (`Lo`) in every slot and sub-slot; levels past 1 have no place.
    #[test]
    fn two_classes_are_the_two_level_cache() {
        use crate::cache::{layout_entry, CacheGeometry, Residency};
        for n in [4, 8, 16, 32, 64] {
            for budget in [1u64 << 16, 1 << 20, 3 << 22, 1 << 30] {
                let two = CacheGeometry::choose(n, 2, budget, 2048, u32::MAX);
                let ours = SlotGeometry::choose(n, 2, 2, budget, 2048, u32::MAX);
                let (two, ours) = match (two, ours) {
                    (Ok(t), Ok(o)) => (t, o),
                    (Err(_), Err(_)) => continue,
                    (t, o) => panic!("n {n} budget {budget}: {t:?} against {o:?}"),
                };
                assert_eq!(ours.extent(), two.extent(), "n {n} budget {budget}");
                assert_eq!(ours.slot_count(), two.slot_count(), "n {n} budget {budget}");
                assert_eq!((ours.slot_edge(), ours.border()), (n + 2, 1));
                assert_eq!(ours.sub_slot_edge(1), two.sub_slot_edge());
                let brick = UVec3::new(3, 1, 2);
                let last = ours.slot_count() - 1;
                for slot in [0, 1.min(last), last / 2, last] {
                    let place = |level, index| LevelSlot { slot, level, index };
                    assert_eq!(
                        ours.layout_entry(brick, place(0, 0)),
                        layout_entry(&two, brick, Residency::Hi { slot })
                    );
                    for sub_slot in 0..8 {
                        assert_eq!(
                            ours.origin(place(1, sub_slot)),
                            Some(two.sub_slot_origin(slot, sub_slot))
                        );
                        assert_eq!(
                            ours.layout_entry(brick, place(1, sub_slot)),
                            layout_entry(&two, brick, Residency::Lo { slot, sub_slot })
                        );
                    }
                    assert_eq!(ours.origin(place(2, 0)), None);
                }
            }
        }
        assert_eq!(
            SlotGeometry::new(8, 4, UVec3::splat(64)),
            Err(CacheError::InvalidClasses { classes: 4 })
        );
    }

    /// The cache's texels of a stored brick: the stored brick itself with three classes, its
    /// inner box at level 0 with two (texel `t` of the cache brick is stored texel `t + 1`).
    #[test]
    fn cache_texels_take_the_inner_box_with_two_classes() {
        let n = 8;
        let edge = stored_brick_edge(n, 0) as usize;
        let stored: Vec<f32> = (0..edge.pow(3)).map(|i| i as f32).collect();
        let three = SlotGeometry::new(n, 3, UVec3::splat(64)).unwrap();
        assert_eq!(&*three.cache_texels(0, &stored), &stored[..]);
        let two = SlotGeometry::new(n, 2, UVec3::splat(64)).unwrap();
        let inner = two.cache_texels(0, &stored);
        let e = (n + 2) as usize;
        assert_eq!(inner.len(), e.pow(3));
        for (z, y, x) in [(0, 0, 0), (e - 1, 0, 3), (2, e - 1, e - 1), (5, 4, 3)] {
            let at = |x: usize, y: usize, z: usize, w: usize| x + w * (y + w * z);
            assert_eq!(inner[at(x, y, z, e)], stored[at(x + 1, y + 1, z + 1, edge)]);
        }
        let level1: Vec<f32> = vec![0.5; (stored_brick_edge(n, 1) as usize).pow(3)];
        assert_eq!(&*two.cache_texels(1, &level1), &level1[..]);
    }
}
