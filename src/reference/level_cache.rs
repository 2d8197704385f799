//! The CPU mirror of a three-level brick cache (issue 19): the levels of a [`LevelField`] packed
//! into a [`ThreeLevelGeometry`] cache image, the two fixups, and the tables the ray-caster
//! reads. Sampled through [`sample_mixed`](super::sample_mixed) unchanged: a level-0 brick blends
//! towards level-1 neighbours through its fixed-up inner border exactly as a hi-res brick of the
//! two-level cache does, and a brick of level 1 or 2 is a plain fetch of its fixed-up samples.
//!
//! # The fixups (Smooth only)
//! - **Border fixup** of every level-0 brick with a level-1 neighbour: the inner border layer
//!   (slot-local texels 1 and `n + 2`) gets the nearest level-1 sample of the first level-1
//!   neighbour in [`FIXUP_PRECEDENCE`](super::FIXUP_PRECEDENCE), as `reference::mixed::fixup_value` computes it for the
//!   two-level cache.
//! - **Skeleton fixup** of every stored brick of a level `k >= 1` with a level-`k + 1` neighbour
//!   ([`skeleton_fixup_value`]): each stored sample on a face, edge or corner that touches a
//!   level-`k + 1` brick becomes that brick's field at the sample's position, one trilinear fetch
//!   through its layout entry (the position is a level-`k` vertex, so the fetch weights are 0 or
//!   1/2: the exact mean of one, two or four coarser samples). This is
//!   [`LevelField::fixed_up_sample`] read from the cache. Past level 2 a stored brick holds a
//!   block of bricks, whose faces are its bricks' faces.
//!
//! The fixups never read what they write (`reference::level_field`, "The scheme the cache
//! builds"), so the order of bricks does not matter; this mirror runs them in brick order, in
//! place, as one dispatch would. A brick whose coarser neighbours change must be uploaded again
//! before the skeleton fixup: the fixup overwrites the brick's own samples and cannot restore them.

use super::level_field::{LevelField, SamplePlacement};
use super::level_plan::LevelPlan;
use super::mixed::{first_marked_neighbour, fixup_value, touching, CacheImage, MixedVolume};
use crate::bricks::{dequantize, quantize_to};
use crate::cache::{block_bricks, block_origin, slots_for_classes, slots_for_plan};
use crate::cache::{LevelSlot, LevelSlots, ThreeLevelGeometry, THREE_LEVELS};
use crate::scene::Transition;
use crate::volume::ScalarType;
use glam::{IVec3, UVec3};

/// Why a [`LevelReferenceCache`] cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LevelCacheError {
    /// A level's samples are not placed as the packing stores them.
    #[error("level {level} is {found:?}; the packing stores level 0 cell-centred and levels 1-2 on vertices")]
    Placement {
        /// The level.
        level: u32,
        /// Its placement.
        found: SamplePlacement,
    },
    /// The field's bricks and the cache's differ in size.
    #[error("the field has bricks of {field} voxels, the cache of {cache}")]
    BrickSize {
        /// Brick size of the field.
        field: u32,
        /// Brick size of the cache.
        cache: u32,
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

/// Where the drawn bricks of a [`LevelField`] go in a three-level cache, and the tables: the
/// packing without the image. The GPU staging packs each stored brick from it
/// ([`LevelPacking::stored_values`]); [`LevelReferenceCache`] fills its CPU image from it.
#[derive(Clone, Debug)]
pub struct LevelPacking {
    /// Layout entry per brick ([`ThreeLevelGeometry::layout_entry`]).
    pub layout: Vec<[f32; 4]>,
    /// Coarser bits per brick ([`LevelField::coarser_bits`]): for a level-0 brick the 26
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
    /// [`LevelPacking::new`] for the plan of `field`, whose grids must be placed as the cache
    /// stores them: level 0 cell-centred, every other level on vertices.
    ///
    /// Errors: a level placed otherwise, and what [`LevelPacking::new`] refuses.
    pub fn for_field(
        field: &LevelField,
        geometry: &ThreeLevelGeometry,
    ) -> Result<Self, LevelCacheError> {
        for g in field.grids() {
            let expected = if g.level() == 0 {
                SamplePlacement::CellCentred
            } else {
                SamplePlacement::Vertex
            };
            if g.placement() != expected {
                return Err(LevelCacheError::Placement {
                    level: g.level(),
                    found: g.placement(),
                });
            }
        }
        Self::new(field.plan(), geometry)
    }

    /// Places every drawn brick of `plan` in a cache of `geometry`: slots filled by packing
    /// class (level 0, level 1, level 2 and coarser), in brick order; past level 2 one stored
    /// brick per block (module docs of `cache::three_level`).
    ///
    /// Errors: a brick size other than the cache's, or more slots needed than the cache has.
    pub fn new(plan: &LevelPlan, geometry: &ThreeLevelGeometry) -> Result<Self, LevelCacheError> {
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
    /// Errors: a brick size other than the cache's, or more slots needed than the cache has.
    pub fn stored_levels(
        plan: &LevelPlan,
        geometry: &ThreeLevelGeometry,
    ) -> Result<Vec<Option<u32>>, LevelCacheError> {
        let n = plan.brick_size();
        if n != geometry.brick_size() {
            return Err(LevelCacheError::BrickSize {
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
        let needed = slots_for_classes(per_level.map(|c| c as u64));
        if needed > u64::from(geometry.slot_count()) {
            return Err(LevelCacheError::OverBudget {
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
        geometry: &ThreeLevelGeometry,
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
    /// `n*b0/2^k + t` (module docs of `cache::three_level`), clamped by the grids. Empty for a
    /// brick that is not drawn.
    pub fn stored_values(
        &self,
        field: &LevelField,
        geometry: &ThreeLevelGeometry,
        brick: usize,
    ) -> Vec<f32> {
        let Some(place) = self.places[brick] else {
            return Vec::new();
        };
        let first = brick_coords(self.bricks, brick);
        debug_assert_eq!(geometry.brick_size(), self.brick_size);
        field.grids()[place.level as usize].stored_brick(first, self.brick_size)
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

/// A three-level cache image filled from a [`LevelField`]'s levels, with its tables.
#[derive(Clone, Debug)]
pub struct LevelReferenceCache {
    /// The cache image.
    pub image: CacheImage,
    /// Layout entry per brick ([`ThreeLevelGeometry::layout_entry`]).
    pub layout: Vec<[f32; 4]>,
    /// Coarser bits per brick ([`LevelField::coarser_bits`]): for a level-0 brick the 26
    /// neighbour bits of the two-level cache.
    pub neighbours: Vec<u32>,
    /// Where each brick lives, `None` when not drawn (the bricks of a block share a place).
    pub places: Vec<Option<LevelSlot>>,
    /// The bricks that hold a stored brick, in brick order ([`LevelPacking::stored`]).
    pub stored: Vec<usize>,
    /// Bricks per axis.
    pub bricks: UVec3,
    /// Brick size.
    pub brick_size: u32,
}

impl LevelReferenceCache {
    /// Packs every drawn brick of `field` into a cache of `geometry` ([`LevelPacking::for_field`])
    /// and, for [`Transition::Smooth`], runs both fixups.
    ///
    /// Errors: those of [`LevelPacking::for_field`].
    pub fn build(
        field: &LevelField,
        geometry: &ThreeLevelGeometry,
        transition: Transition,
    ) -> Result<Self, LevelCacheError> {
        Self::build_stored_as(field, geometry, transition, ScalarType::F32)
    }

    /// [`LevelReferenceCache::build`] for a cache whose texels are `scalar`: every texel the
    /// packing or a fixup writes is rounded to it (`u8` / `u16` UNORM), as the GPU's image
    /// stores round them.
    pub fn build_stored_as(
        field: &LevelField,
        geometry: &ThreeLevelGeometry,
        transition: Transition,
        scalar: ScalarType,
    ) -> Result<Self, LevelCacheError> {
        let round = |values: &[f32]| dequantize(&quantize_to(values, scalar), scalar);
        let packing = LevelPacking::for_field(field, geometry)?;
        let mut image = CacheImage::new(geometry.extent());
        for &i in &packing.stored {
            let Some(place) = packing.places[i] else {
                continue;
            };
            let origin = geometry.origin(place).unwrap_or(UVec3::ZERO);
            let edge = UVec3::splat(geometry.stored_edge(place.level));
            image.write_box(
                origin,
                edge,
                &round(&packing.stored_values(field, geometry, i)),
            );
        }
        let LevelPacking {
            layout,
            neighbours,
            places,
            stored,
            bricks,
            brick_size: n,
        } = packing;
        if transition == Transition::Smooth {
            for &i in &stored {
                let Some(place) = places[i] else {
                    continue;
                };
                let brick = brick_coords(bricks, i);
                let origin = geometry.origin(place).unwrap_or(UVec3::ZERO);
                if place.level == 0 {
                    let bits = neighbours[i];
                    if bits == 0 {
                        continue;
                    }
                    // The inner (n+2)^3 box of the slot is the two-level cache's hi-res brick.
                    let inner = origin + UVec3::ONE;
                    for t in boundary_texels(n + 2, |t| t == 0 || t == n + 1) {
                        if let Some(v) =
                            fixup_value(&image, &layout, bits, bricks, n, brick.as_ivec3(), t)
                        {
                            image.set_texel((inner + t).as_ivec3(), round(&[v])[0]);
                        }
                    }
                } else {
                    let last = geometry.stored_edge(place.level) - 1;
                    for t in boundary_texels(last + 1, |t| t == 0 || t == last) {
                        if let Some(v) = skeleton_fixup_value(
                            &image,
                            &layout,
                            &neighbours,
                            bricks,
                            n,
                            brick.as_ivec3(),
                            place.level,
                            t,
                        ) {
                            image.set_texel((origin + t).as_ivec3(), round(&[v])[0]);
                        }
                    }
                }
            }
        }
        Ok(Self {
            image,
            layout,
            neighbours,
            places,
            stored,
            bricks,
            brick_size: n,
        })
    }

    /// The view [`sample_mixed`](super::sample_mixed) takes.
    pub fn view(&self) -> MixedVolume<'_> {
        MixedVolume {
            cache: &self.image,
            layout: &self.layout,
            neighbours: &self.neighbours,
            bricks: self.bricks,
            brick_size: self.brick_size,
        }
    }
}

/// The cache slots the drawn bricks of `field` take in the three-level packing
/// ([`slots_for_plan`]).
pub fn slots_needed(field: &LevelField) -> u64 {
    let bricks = field.bricks_per_axis();
    let levels: Vec<Option<u32>> = (0..bricks.element_product() as usize)
        .map(|i| field.brick_level(i))
        .collect();
    slots_for_plan(bricks, &levels)
}

/// The texels `t` of a box of `edge` per axis for which `on_boundary(t_a)` holds on some axis.
fn boundary_texels(edge: u32, on_boundary: impl Fn(u32) -> bool) -> Vec<UVec3> {
    let mut out = Vec::new();
    for z in 0..edge {
        for y in 0..edge {
            for x in 0..edge {
                if on_boundary(x) || on_boundary(y) || on_boundary(z) {
                    out.push(UVec3::new(x, y, z));
                }
            }
        }
    }
    out
}

/// The skeleton-fixed value of stored sample `t` (`0..=last` per axis, `last + 1` the stored
/// edge) of the stored brick of vertex level `level` whose block starts at brick `first`, or
/// `None` when the sample touches no brick of level `level + 1` (it keeps its value). The sample
/// sits at `n*first + 2^level t`; the brick of the block whose box holds it (the last one at the
/// block's far faces) says, through its coarser bits `neighbours[..]`, which bricks touch it.
/// The value is the field of the first touching coarser brick in [`FIXUP_PRECEDENCE`](super::FIXUP_PRECEDENCE) at the
/// sample's position: one trilinear fetch through that brick's layout entry. Mirrors
/// `glsl/skeleton_fixup.comp`.
#[allow(clippy::too_many_arguments)] // reason: mirrors a shader's per-texel inputs.
pub fn skeleton_fixup_value(
    cache: &CacheImage,
    layout: &[[f32; 4]],
    neighbours: &[u32],
    bricks: UVec3,
    brick_size: u32,
    first: IVec3,
    level: u32,
    t: UVec3,
) -> Option<f32> {
    let n = brick_size as i32;
    let position = first * n + (t.as_ivec3() << level as i32);
    let block = block_bricks(level) as i32;
    let last_brick = (first + IVec3::splat(block - 1)).min(bricks.as_ivec3() - IVec3::ONE);
    let brick = (position / n).clamp(first, last_brick);
    let bits = neighbours
        [(brick.x as u32 + bricks.x * (brick.y as u32 + bricks.y * brick.z as u32)) as usize];
    let mut mask = 0;
    let mut side = IVec3::ZERO;
    for a in 0..3 {
        if position[a] == n * brick[a] {
            mask |= 1 << a;
            side[a] = -1;
        } else if position[a] == n * (brick[a] + 1) {
            mask |= 1 << a;
            side[a] = 1;
        }
    }
    if mask == 0 || bits & touching(mask, side) == 0 {
        return None;
    }
    let (_, ni) = first_marked_neighbour(bits, mask, side, brick, bricks)?;
    let [tx, ty, tz, tw] = layout[ni];
    Some(cache.fetch(position.as_vec3() * tw + glam::Vec3::new(tx, ty, tz)))
}
