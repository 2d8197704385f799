//! The CPU mirror of a three-level brick cache (issue 19): the levels of a [`LevelField`] packed
//! into a [`SlotGeometry`] cache image, the two fixups, and the tables the ray-caster
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

use super::level_field::LevelField;
use super::mixed::{first_marked_neighbour, fixup_value, touching, CacheImage, MixedVolume};
use crate::bricks::{dequantize, quantize_to};
use crate::cache::{block_bricks, slots_for_plan, SlotGeometry};
use crate::pyramid::{LevelPacking, PackingError};
use crate::scene::Transition;
use crate::volume::ScalarType;
use glam::{IVec3, UVec3};

/// A three-level cache image filled from a [`LevelField`]'s levels, with its tables.
#[derive(Clone, Debug)]
pub struct LevelReferenceCache {
    /// The cache image.
    pub image: CacheImage,
    /// Where every drawn brick lives and the tables the ray-caster reads (layout entries,
    /// coarser bits), as the GPU staging packs them.
    pub packing: LevelPacking,
}

impl LevelReferenceCache {
    /// Packs every drawn brick of `field` into a cache of `geometry` ([`LevelPacking::for_grids`])
    /// and, for [`Transition::Smooth`], runs both fixups.
    ///
    /// Errors: those of [`LevelPacking::for_grids`].
    pub fn build(
        field: &LevelField,
        geometry: &SlotGeometry,
        transition: Transition,
    ) -> Result<Self, PackingError> {
        Self::build_stored_as(field, geometry, transition, ScalarType::F32)
    }

    /// [`LevelReferenceCache::build`] for a cache whose texels are `scalar`: every texel the
    /// packing or a fixup writes is rounded to it (`u8` / `u16` UNORM), as the GPU's image
    /// stores round them.
    pub fn build_stored_as(
        field: &LevelField,
        geometry: &SlotGeometry,
        transition: Transition,
        scalar: ScalarType,
    ) -> Result<Self, PackingError> {
        let round = |values: &[f32]| dequantize(&quantize_to(values, scalar), scalar);
        let packing = LevelPacking::for_grids(field.plan(), field.grids(), geometry)?;
        let mut image = CacheImage::new(geometry.extent());
        for &i in &packing.stored {
            let Some(place) = packing.places[i] else {
                continue;
            };
            let origin = geometry.origin(place).unwrap_or(UVec3::ZERO);
            let edge = UVec3::splat(geometry.stored_edge(place.level));
            let stored = packing.stored_values(field.grids(), geometry, i);
            image.write_box(
                origin,
                edge,
                &round(&geometry.cache_texels(place.level, &stored)),
            );
        }
        let LevelPacking {
            layout,
            neighbours,
            places,
            stored,
            bricks,
            brick_size: n,
        } = &packing;
        let (bricks, n) = (*bricks, *n);
        if transition == Transition::Smooth {
            for &i in stored {
                let Some(place) = places[i] else {
                    continue;
                };
                let brick = grid_coords(bricks, i);
                let origin = geometry.origin(place).unwrap_or(UVec3::ZERO);
                if place.level == 0 {
                    let bits = neighbours[i];
                    if bits == 0 {
                        continue;
                    }
                    // The inner (n+2)^3 box of the slot is the two-level cache's hi-res brick
                    // (the slot itself with two classes).
                    let inner = origin + UVec3::splat(geometry.border() - 1);
                    for t in boundary_texels(n + 2, |t| t == 0 || t == n + 1) {
                        if let Some(v) =
                            fixup_value(&image, layout, bits, bricks, n, brick.as_ivec3(), t)
                        {
                            image.set_texel((inner + t).as_ivec3(), round(&[v])[0]);
                        }
                    }
                } else {
                    let last = geometry.stored_edge(place.level) - 1;
                    for t in boundary_texels(last + 1, |t| t == 0 || t == last) {
                        if let Some(v) = skeleton_fixup_value(
                            &image,
                            layout,
                            neighbours,
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
        Ok(Self { image, packing })
    }

    /// The view [`sample_mixed`](super::sample_mixed) takes.
    pub fn view(&self) -> MixedVolume<'_> {
        MixedVolume {
            cache: &self.image,
            layout: &self.packing.layout,
            neighbours: &self.packing.neighbours,
            bricks: self.packing.bricks,
            brick_size: self.packing.brick_size,
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

/// Brick coordinates of linear index `i` in a grid of `bricks` per axis (x fastest).
fn grid_coords(bricks: UVec3, i: usize) -> UVec3 {
    let i = i as u32;
    UVec3::new(
        i % bricks.x,
        (i / bricks.x) % bricks.y,
        i / (bricks.x * bricks.y),
    )
}
