//! Where the drawn bricks of a [`LevelPlan`] go in a three-level cache ([`LevelPacking`]): slots
//! by packing class, one stored brick per block past level 2, the layout entries and coarser
//! bits the ray-caster reads (module docs of `cache::slot_geometry`).

use super::{LevelGrid, LevelPlan, SamplePlacement};
use crate::cache::{block_bricks, block_origin, slots_for_classes};
use crate::cache::{LevelSlot, LevelSlots, SlotGeometry, THREE_LEVELS};
use glam::UVec3;

/// Why the drawn bricks of a [`LevelPlan`] cannot be packed into a cache.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PackingError {
    /// A level's samples are not placed as the packing stores them.
    #[error("level {level} is {found:?}; the packing stores level 0 cell-centred and levels 1-2 on vertices")]
    Placement {
        /// The level.
        level: u32,
        /// Its placement.
        found: SamplePlacement,
    },
    /// The plan's bricks and the cache's differ in size.
    #[error("the plan has bricks of {field} voxels, the cache of {cache}")]
    BrickSize {
        /// Brick size of the plan.
        field: u32,
        /// Brick size of the cache.
        cache: u32,
    },
    /// The plan draws a level the cache has no slot class for (level 2 or coarser in a cache of
    /// two classes).
    #[error("the plan draws level 2 or coarser, but the cache has {classes} slot classes (levels 0 and 1)")]
    Classes {
        /// The cache's slot classes.
        classes: u32,
    },
    /// The drawn bricks need more slots than the cache has.
    #[error(
        "the plan needs {needed} slots ({per_level:?} stored bricks of level 0, level 1 and \
         level 2 or coarser, at 1, 8, 64 per slot) but the cache has {slots}"
    )]
    OverBudget {
        /// Slots needed.
        needed: u64,
        /// Stored bricks of level 0, level 1, and level 2 or coarser (a block counts once).
        per_level: [usize; 3],
        /// Slots in the cache.
        slots: u32,
    },
}

/// Where the drawn bricks of a [`LevelPlan`] go in a three-level cache, and the tables: the
/// packing without the image. The GPU staging packs each stored brick from it
/// ([`LevelPacking::stored_values`]).
#[derive(Clone, Debug)]
pub struct LevelPacking {
    /// Layout entry per brick ([`SlotGeometry::layout_entry`]).
    pub layout: Vec<[f32; 4]>,
    /// Coarser bits per brick ([`LevelPlan::coarser_bits`]): for a level-0 brick the 26
    /// neighbour bits of the two-level cache.
    pub neighbours: Vec<u32>,
    /// Where each brick lives, `None` when not drawn (the bricks of a block share a place).
    pub places: Vec<Option<LevelSlot>>,
    /// The bricks that hold a stored brick, in brick order: every drawn brick up to level 2,
    /// the first brick of each block past it.
    pub stored: Vec<usize>,
    /// Bricks per axis.
    pub bricks: UVec3,
    /// Brick size.
    pub brick_size: u32,
}

impl LevelPacking {
    /// [`LevelPacking::new`] for `plan` over the level grids `grids` (levels 0, 1, ... in
    /// order), which must be placed as the cache stores them: level 0 cell-centred, every other
    /// level on vertices.
    ///
    /// Errors: a level placed otherwise, and what [`LevelPacking::new`] refuses.
    pub fn for_grids(
        plan: &LevelPlan,
        grids: &[LevelGrid],
        geometry: &SlotGeometry,
    ) -> Result<Self, PackingError> {
        for g in grids {
            let expected = if g.level() == 0 {
                SamplePlacement::CellCentred
            } else {
                SamplePlacement::Vertex
            };
            if g.placement() != expected {
                return Err(PackingError::Placement {
                    level: g.level(),
                    found: g.placement(),
                });
            }
        }
        Self::new(plan, geometry)
    }

    /// Places every drawn brick of `plan` in a cache of `geometry`: slots filled by packing
    /// class (level 0, level 1, level 2 and coarser), in brick order; past level 2 one stored
    /// brick per block (module docs of `cache::slot_geometry`).
    ///
    /// Errors: a brick size other than the cache's, or more slots needed than the cache has.
    pub fn new(plan: &LevelPlan, geometry: &SlotGeometry) -> Result<Self, PackingError> {
        let wanted = Self::stored_levels(plan, geometry)?;
        let mut by_class: [Vec<usize>; 3] = Default::default();
        for (i, level) in wanted.iter().enumerate() {
            if let Some(level) = level {
                by_class[(*level).min(THREE_LEVELS - 1) as usize].push(i);
            }
        }
        let mut slots = LevelSlots::new(geometry.slot_count());
        let mut places = vec![None; wanted.len()];
        for i in by_class.iter().flatten() {
            // The budget was checked: every class fits.
            places[*i] = wanted[*i].and_then(|level| slots.allocate(level));
        }
        Ok(Self::from_places(plan, geometry, &places))
    }

    /// Per brick, the level of the stored brick whose block starts at it (`None` where none
    /// does: not drawn, or inside a block), after checking that `plan` suits a cache of
    /// `geometry`.
    ///
    /// Errors: a brick size other than the cache's, a level the cache has no class for, or
    /// more slots needed than the cache has.
    pub fn stored_levels(
        plan: &LevelPlan,
        geometry: &SlotGeometry,
    ) -> Result<Vec<Option<u32>>, PackingError> {
        let n = plan.brick_size();
        if n != geometry.brick_size() {
            return Err(PackingError::BrickSize {
                field: n,
                cache: geometry.brick_size(),
            });
        }
        let bricks = plan.bricks_per_axis();
        let count = bricks.element_product() as usize;
        let mut per_level = [0usize; 3];
        let wanted: Vec<Option<u32>> = (0..count)
            .map(|i| {
                let level = plan.brick_level(i)?;
                let b = brick_coords(bricks, i);
                (block_origin(b, level) == b).then(|| {
                    per_level[level.min(THREE_LEVELS - 1) as usize] += 1;
                    level
                })
            })
            .collect();
        if geometry.classes() < THREE_LEVELS && per_level[2] > 0 {
            return Err(PackingError::Classes {
                classes: geometry.classes(),
            });
        }
        let needed = slots_for_classes(per_level.map(|c| c as u64));
        if needed > u64::from(geometry.slot_count()) {
            return Err(PackingError::OverBudget {
                needed,
                per_level,
                slots: geometry.slot_count(),
            });
        }
        Ok(wanted)
    }

    /// The packing of `plan` with the stored brick whose block starts at brick `i` at
    /// `stored_places[i]` (one entry per brick; `None` where no stored brick starts): every
    /// brick of a block gets its block's place and layout entry. The places are taken as given
    /// (a [`LevelSlots`] hands out places that do not overlap).
    pub fn from_places(
        plan: &LevelPlan,
        geometry: &SlotGeometry,
        stored_places: &[Option<LevelSlot>],
    ) -> Self {
        let bricks = plan.bricks_per_axis();
        let count = bricks.element_product() as usize;
        let linear = |b: UVec3| (b.x + bricks.x * (b.y + bricks.y * b.z)) as usize;
        let mut places = vec![None; count];
        let mut layout = vec![[0.0; 4]; count];
        let mut stored = Vec::new();
        for (i, place) in stored_places.iter().enumerate().take(count) {
            let Some(place) = *place else {
                continue;
            };
            let first = brick_coords(bricks, i);
            let entry = geometry.layout_entry(first, place);
            // Every brick of the block (clipped to the grid) shares the stored brick.
            let end = (first + UVec3::splat(block_bricks(place.level))).min(bricks);
            for z in first.z..end.z {
                for y in first.y..end.y {
                    for x in first.x..end.x {
                        let j = linear(UVec3::new(x, y, z));
                        places[j] = Some(place);
                        layout[j] = entry;
                    }
                }
            }
            stored.push(i);
        }
        Self {
            layout,
            neighbours: (0..count).map(|i| plan.coarser_bits(i)).collect(),
            places,
            stored,
            bricks,
            brick_size: plan.brick_size(),
        }
    }

    /// The texels of the stored brick held by `brick` (one of [`Self::stored`]), x fastest,
    /// `stored_edge` of its level per axis: level 0 voxel `n*b - 2 + t`, level `k` sample
    /// `n*b0/2^k + t` (module docs of `cache::slot_geometry`), clamped by the grids. Empty for a
    /// brick that is not drawn.
    pub fn stored_values(
        &self,
        grids: &[LevelGrid],
        geometry: &SlotGeometry,
        brick: usize,
    ) -> Vec<f32> {
        let Some(place) = self.places[brick] else {
            return Vec::new();
        };
        let first = brick_coords(self.bricks, brick);
        debug_assert_eq!(geometry.brick_size(), self.brick_size);
        grids[place.level as usize].stored_brick(first, self.brick_size)
    }

    /// Whether a brick of the block held by stored brick `brick` (one of [`Self::stored`]) has
    /// a neighbour one level coarser: the block's fixup has work.
    pub fn block_has_coarser_neighbour(&self, brick: usize) -> bool {
        let Some(place) = self.places[brick] else {
            return false;
        };
        let b = self.bricks;
        let first = brick_coords(b, brick);
        let end = (first + UVec3::splat(block_bricks(place.level))).min(b);
        (first.z..end.z).any(|z| {
            (first.y..end.y).any(|y| {
                (first.x..end.x).any(|x| self.neighbours[(x + b.x * (y + b.y * z)) as usize] != 0)
            })
        })
    }
}

/// Brick coordinates of linear index `i` in a grid of `bricks` per axis (x fastest).
fn brick_coords(bricks: UVec3, i: usize) -> UVec3 {
    let i = i as u32;
    UVec3::new(
        i % bricks.x,
        (i / bricks.x) % bricks.y,
        i / (bricks.x * bricks.y),
    )
}
