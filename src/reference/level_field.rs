//! The mixed-resolution field for any number of levels, defined directly from each level's samples
//! (no cache image): the construction the brick cache, its fixup and the ray-caster must reproduce
//! when they hold more than two levels (issue 19). With two levels it is what
//! [`sample_mixed`](super::sample_mixed) computes from the cache, which a test checks.
//!
//! # Levels
//! Level `k` samples the volume every `s_k = 2^k` hi-res voxels on one global grid, either
//! *cell-centred* (sample `j` at `s_k * (j + 1/2)`, as the hi-res voxels, and the paper's
//! `(n/2+2)^3` level-1 bricks of its three-level packing) or on *vertices* (sample `j` at
//! `s_k * j`, as today's `(n/2+1)^3` low-res bricks and the paper's `(n/4+1)^3` level-2 bricks).
//! Each level alone is the trilinear (clamp-to-edge) interpolation of its own samples
//! ([`LevelGrid::trilinear`]), continuous across bricks of that level because the grid is global.
//! Bricks of size `n` (a power of two) hold whole cells of every level up to `2^k <= n`.
//!
//! # The construction: one pair of levels at a time
//! The planner keeps face-, edge- and corner-adjacent drawn bricks within one level of each other
//! ([`check_level_rule_with`]). A brick `B` of level `k` then blends towards the next coarser level
//! only, exactly as a hi-res brick blends towards low-res ones in the two-level scheme
//! (`reference::mixed`), with three changes of scale:
//!
//! - its *coarser bits* mark the neighbours of level `k + 1` ([`coarser_neighbour_bits`]; with two
//!   levels, the 26 neighbour bits);
//! - its *band* along axis `a` is the strip between a face and the nearest plane of its own
//!   samples: `w_k = s_k / 2` for cell-centred samples (half a voxel at level 0, one hi-res voxel
//!   at a cell-centred level 1), `w_k = s_k` for vertex samples (one level-`k` voxel: the samples
//!   on the face are the ones the coarser level replaces), with `beta_a = 1 - distance / w_k`;
//! - the skeleton value `G(P)` on a face, edge or corner that touches a brick of level `k + 1` is
//!   the plain trilinear field of level `k + 1`, elsewhere the plain field of level `k`.
//!
//! With active axes `A` (band axes across which a touching brick is coarser),
//! `f(q) = sum over S ⊆ A of prod_{a in S} beta_a prod_{a in A\S} (1 - beta_a) G(P_S)`, where `P_S`
//! puts the axes of `S` on the face and those of `A \ S` on the sample plane.
//!
//! **Why it is C0 for every level pair.** (1) Along a blended axis both `G` terms are linear over
//! the band, so `f` is the multilinear interpolation of the skeleton values over the band box: the
//! band ends on a knot of level `k` (its sample plane), and the nearest knot of level `k + 1` is no
//! closer to the face than the band is wide (`s_k` away when cell-centred, on the face and `2 s_k`
//! away on vertices), so on the face `f` equals the coarser field, and on the plane the brick's
//! own. (2) Neighbours of the same level see the same touching bricks (the touching set includes
//! the diagonal ones), hence the same blend. (3) The coarser brick `C` of level `k + 1` needs no
//! knowledge of `B`: what `B` reads of it is `C`'s *plain* field, because `C`'s own band (towards
//! level `k + 2`) never reaches a point `B` touches: a level-`k + 2` brick next to `C` is not a
//! neighbour of `B` (the rule), so it lies at least one brick (`n`) away from `B`, farther than
//! `C`'s band (`w_{k+1} <= n / 2`). So a *middle* level is the fine side towards its coarser
//! neighbours and, unchanged, the coarse side towards its finer ones, and the two roles never
//! meet in one point: no new boundary class appears at three or more levels, and the 26 bits,
//! the fixup (nearest samples of level `k + 1` into the borders of level-`k` bricks) and the
//! blend extend to any number of levels with only `w_k`, `s_k` and the coarser level's grid per
//! brick.
//!
//! [`Transition::Discontinuous`] draws every brick with the plain field of its own level: the
//! baseline that jumps at every level change.
//!
//! # The scheme the cache builds: level 0 cell-centred, every coarser level on vertices
//! [`LevelGrid::vertex_pyramid`] keeps level 0 at voxel centres and puts every level `k >= 1` on
//! vertices (level 1 is today's low-res level; the paper's `(n/2+2)^3` and `(n/4+1)^3` slots of its
//! three-level packing hold `n/2 + 1` and `n/4 + 1` vertex samples per axis). Then a transition
//! between two vertex levels costs the ray-caster nothing: the band of a level-`k` brick (`k >= 1`)
//! is exactly its outermost cell, whose outer samples lie on the skeleton, so the blend equals
//! the plain trilinear interpolation of the brick's samples once every sample on a face, edge or
//! corner that touches a drawn level-`k + 1` brick holds the coarser field there
//! ([`LevelField::fixed_up_sample`]; the coarser field is piecewise linear between its own
//! samples, which are level-`k` samples too, so interpolating it at level-`k` spacing is exact).
//! A fixed-up value depends on the sample's position alone (every brick holding a copy sees the
//! same touching bricks), so the copies agree. [`LevelField::sample_fixed_up`] is that field; a
//! test checks it equals [`LevelField::sample`].
//!
//! # Any number of levels: block levels
//! A brick of level `k >= 2` stores `n/4 + 1` samples per axis (the paper's level-2 brick), so
//! past level 2 it covers more than one brick of the grid: an aligned *block* of
//! [`block_bricks`]`(k) = 2^(k - 2)` bricks per axis, all drawn at level `k` (checked; clipped to
//! the grid at its far faces). Every brick of the grid keeps its own layout entry, so the
//! ray-caster does not change; the bricks of a block share one stored brick. Such a level's band
//! (one cell, `2^k`) can be wider than half a brick, so there the field is defined by the
//! skeleton fixup alone ([`LevelField::sample`] uses [`LevelField::sample_fixed_up`] for those
//! levels), and its C0 argument is the fixup's:
//!
//! - *across a face between levels `k` and `k + 1`*: the finer side's samples on the face hold
//!   the coarser field there. The face lies on samples of level `k + 1` (a block of level `k`
//!   spans `2^(k - 2) n` voxels, a multiple of `2^(k + 1)` once `n >= 8`), so the coarser field
//!   on the face is linear between level-`k` samples, and the finer side's bilinear face
//!   function equals it. The coarser side draws its own samples, unchanged on that face: a
//!   coarser sample there touches level `k` and so, by the rule, no level-`k + 2` brick, which
//!   alone would change it;
//! - *between bricks of one level*: a fixed-up value depends on the sample's position only;
//! - *inside a brick*: trilinear interpolation of one set of samples.
//!
//! With up to three levels the blend and the fixed-up field are the same function (tested). Only the level-0 transition needs the blend of
//! `reference::mixed` (cell-centred samples never lie on a face). Reads and writes of the fixup
//! never meet: a level-`k` brick writes only samples that touch a level-`k + 1` brick, and a
//! level-`k - 1` brick reads only the level-`k` samples it touches, which touch no level-`k + 1`
//! brick (the rule).

use crate::bricks::BrickGrid;
use crate::pyramid::{LevelGrid, LevelPlan, PyramidError, SamplePlacement};
use crate::scene::Transition;
use glam::{BVec3, IVec3, UVec3, Vec3};

use super::mixed::{active_axes, brick_of, feature_touches_low_res};
use super::sampling::trilinear;

/// The reference's reads of one level's samples: its band width and its plain trilinear field
/// (the functions `mixed.glsl` mirrors for the cache's levels).
pub trait LevelSampling {
    /// Width of a brick's transition band at this level: the distance from a brick face to the
    /// nearest plane of samples inside (`s / 2` cell-centred), or one cell when the samples lie
    /// on the face (`s` on vertices).
    fn band_width(&self) -> f32;
    /// The plain trilinear field of this level at hi-res point `x`, clamp-to-edge.
    fn trilinear(&self, x: Vec3) -> f32;
}

impl LevelSampling for LevelGrid {
    fn band_width(&self) -> f32 {
        match self.placement() {
            SamplePlacement::CellCentred => 0.5 * self.spacing(),
            SamplePlacement::Vertex => self.spacing(),
        }
    }

    fn trilinear(&self, x: Vec3) -> f32 {
        let u = match self.placement() {
            SamplePlacement::CellCentred => x / self.spacing() - Vec3::splat(0.5),
            SamplePlacement::Vertex => x / self.spacing(),
        };
        trilinear(u, |k| self.value(k))
    }
}

/// A brick grid whose bricks are drawn at different levels, with every level's samples: the
/// field of the module docs.
#[derive(Clone, Debug)]
pub struct LevelField<'a> {
    grids: &'a [LevelGrid],
    plan: LevelPlan,
}

impl<'a> LevelField<'a> {
    /// The field of `grid`'s bricks at `brick_levels` (one per brick, linear index; `None` for a
    /// brick that is not drawn) over the level grids `grids` (levels 0, 1, ... in order).
    ///
    /// Errors: no grids, grids out of order, more levels than the brick size allows
    /// (`2^(levels - 1) <= n`), a brick-level count other than the brick count, a brick at a level
    /// with no grid, or adjacent drawn bricks more than one level apart.
    pub fn new(
        grid: &BrickGrid,
        grids: &'a [LevelGrid],
        brick_levels: &[Option<u32>],
    ) -> Result<Self, PyramidError> {
        if grids.is_empty() {
            return Err(PyramidError::NoLevels);
        }
        if let Some((index, g)) = grids
            .iter()
            .enumerate()
            .find(|(i, g)| g.level() as usize != *i)
        {
            return Err(PyramidError::LevelOrder {
                index,
                level: g.level(),
            });
        }
        let n = grid.brick_size();
        // A cell-centred level's band (half a cell) must fit in half a brick.
        let cell_centred = grids
            .iter()
            .filter(|g| g.placement() == SamplePlacement::CellCentred)
            .map(|g| 1u32 << g.level())
            .max()
            .unwrap_or(1);
        let levels = u32::try_from(grids.len()).unwrap_or(u32::MAX);
        let min_brick_size = crate::cache::min_brick_size_for_levels(levels).max(cell_centred);
        if n < min_brick_size {
            return Err(PyramidError::TooManyLevels {
                levels: grids.len(),
                min_brick_size,
                brick_size: n,
            });
        }
        Ok(Self {
            grids,
            plan: LevelPlan::new(grid, levels, brick_levels)?,
        })
    }

    /// The checked plan: every brick's level and coarser bits.
    pub fn plan(&self) -> &LevelPlan {
        &self.plan
    }

    /// The coarser bits of linear brick `i` (see [`crate::cache::tables::coarser_neighbour_bits`]).
    pub fn coarser_bits(&self, brick: usize) -> u32 {
        self.plan.coarser_bits(brick)
    }

    /// The level grids, levels 0, 1, ... in order.
    pub fn grids(&self) -> &'a [LevelGrid] {
        self.grids
    }

    /// Brick size `n` in hi-res voxels.
    pub fn brick_size(&self) -> u32 {
        self.plan.brick_size()
    }

    /// Bricks per axis.
    pub fn bricks_per_axis(&self) -> UVec3 {
        self.plan.bricks_per_axis()
    }

    /// The level of linear brick `brick`, `None` when it is not drawn.
    pub fn brick_level(&self, brick: usize) -> Option<u32> {
        self.plan.brick_levels()[brick]
    }

    /// Whether a drawn brick of level `level` has hi-res point `p` in its closed box.
    fn level_touches(&self, p: Vec3, level: u32) -> bool {
        let n = self.plan.brick_size() as f32;
        let last = self.plan.bricks_per_axis().as_ivec3() - IVec3::ONE;
        // Per axis, the bricks whose closed span [n b, n (b + 1)] holds p.
        let low = ((p / n).ceil().as_ivec3() - IVec3::ONE).clamp(IVec3::ZERO, last);
        let high = (p / n).floor().as_ivec3().clamp(IVec3::ZERO, last);
        for z in low.z..=high.z {
            for y in low.y..=high.y {
                for x in low.x..=high.x {
                    let i = (x as u32
                        + self.plan.bricks_per_axis().x
                            * (y as u32 + self.plan.bricks_per_axis().y * z as u32))
                        as usize;
                    if self.plan.brick_levels()[i] == Some(level) {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Sample `j` of vertex level `level` after the skeleton fixup (module docs): the plain field
    /// of level `level + 1` where a drawn brick of that level touches the sample's position, the
    /// sample itself elsewhere. For a cell-centred level, or the coarsest, the sample itself.
    pub fn fixed_up_sample(&self, level: u32, j: IVec3) -> f32 {
        let own = &self.grids[level as usize];
        let Some(coarser) = self.grids.get(level as usize + 1) else {
            return own.value(j);
        };
        if own.placement() != SamplePlacement::Vertex {
            return own.value(j);
        }
        let p = j.as_vec3() * own.spacing();
        if self.level_touches(p, level + 1) {
            coarser.trilinear(p)
        } else {
            own.value(j)
        }
    }

    /// The field as the cache draws it (module docs), or `None` in a brick that is not drawn: in
    /// a brick of a vertex level the plain trilinear interpolation of the fixed-up samples
    /// ([`LevelField::fixed_up_sample`]), in a brick of a cell-centred level the blend of
    /// [`LevelField::sample`]. Equal to `sample(x, Transition::Smooth)` when every level above 0
    /// is on vertices.
    pub fn sample_fixed_up(&self, x: Vec3) -> Option<f32> {
        let b = brick_of(x, self.plan.brick_size(), self.plan.bricks_per_axis());
        let bi = (b.x as u32
            + self.plan.bricks_per_axis().x
                * (b.y as u32 + self.plan.bricks_per_axis().y * b.z as u32))
            as usize;
        let level = self.plan.brick_levels()[bi]?;
        let own = &self.grids[level as usize];
        if own.placement() != SamplePlacement::Vertex {
            return self.sample(x, Transition::Smooth);
        }
        Some(trilinear(x / own.spacing(), |k| {
            self.fixed_up_sample(level, k)
        }))
    }

    /// The field at hi-res point `x`, or `None` in a brick that is not drawn.
    pub fn sample(&self, x: Vec3, transition: Transition) -> Option<f32> {
        let b = brick_of(x, self.plan.brick_size(), self.plan.bricks_per_axis());
        let bi = (b.x as u32
            + self.plan.bricks_per_axis().x
                * (b.y as u32 + self.plan.bricks_per_axis().y * b.z as u32))
            as usize;
        let level = self.plan.brick_levels()[bi]? as usize;
        let own = &self.grids[level];
        let bits = self.plan.coarser_bits(bi);
        if transition == Transition::Discontinuous || bits == 0 {
            return Some(own.trilinear(x));
        }
        if own.placement() == SamplePlacement::Vertex
            && own.band_width() > 0.5 * self.plan.brick_size() as f32
        {
            // A block level: its band (one cell) is wider than half a brick; only the fixed-up
            // construction is defined there (module docs).
            return self.sample_fixed_up(x);
        }
        // bits != 0: a level-(k+1) neighbour exists, so its grid does too (checked in new).
        let coarser = &self.grids[level + 1];
        let origin = b.as_vec3() * self.plan.brick_size() as f32;
        Some(blend_towards_coarser(
            own,
            coarser,
            x - origin,
            origin,
            bits,
            self.plan.brick_size() as f32,
        ))
    }
}

/// Band axes of local point `q` for a band of width `w` in a brick of size `n`: (band mask,
/// sides, betas); `beta = 1` on the face, 0 on the sample plane `w` inside.
pub fn level_band(q: Vec3, w: f32, n: f32) -> (u32, IVec3, Vec3) {
    let mut mask = 0;
    let mut side = IVec3::ZERO;
    let mut beta = Vec3::ZERO;
    for a in 0..3 {
        if q[a] < w {
            mask |= 1 << a;
            side[a] = -1;
            beta[a] = 1.0 - q[a] / w;
        } else if q[a] > n - w {
            mask |= 1 << a;
            side[a] = 1;
            beta[a] = 1.0 - (n - q[a]) / w;
        }
    }
    (mask, side, beta)
}

/// The blend of the module docs inside a brick of level `own.level()` with coarser bits `bits`:
/// `q` brick-local, `origin` the brick's hi-res origin.
fn blend_towards_coarser(
    own: &LevelGrid,
    coarser: &LevelGrid,
    q: Vec3,
    origin: Vec3,
    bits: u32,
    n: f32,
) -> f32 {
    let w = own.band_width();
    let (band_mask, side, beta) = level_band(q, w, n);
    let active_mask = active_axes(bits, band_mask, side);
    if active_mask == 0 {
        return own.trilinear(origin + q);
    }
    let is_active = BVec3::new(
        active_mask & 1 != 0,
        active_mask & 2 != 0,
        active_mask & 4 != 0,
    );
    let pick = |low: f32, high: f32| {
        Vec3::new(
            if side.x < 0 { low } else { high },
            if side.y < 0 { low } else { high },
            if side.z < 0 { low } else { high },
        )
    };
    let face = pick(0.0, n);
    let plane = pick(w, n - w);
    let on_plane = Vec3::select(is_active, plane, q);
    let active: Vec<usize> = (0..3).filter(|&a| is_active.test(a)).collect();
    let mut sum = 0.0f64;
    for subset in 0..1u32 << active.len() {
        let mut on_face = BVec3::FALSE;
        for (bit, &a) in active.iter().enumerate() {
            on_face.set(a, subset >> bit & 1 != 0);
        }
        let weight: f64 = active
            .iter()
            .map(|&a| {
                f64::from(if on_face.test(a) {
                    beta[a]
                } else {
                    1.0 - beta[a]
                })
            })
            .product();
        let point = origin + Vec3::select(on_face, face, on_plane);
        let s = on_face.bitmask();
        let value = if s != 0 && feature_touches_low_res(bits, s, side) {
            coarser.trilinear(point)
        } else {
            own.trilinear(point)
        };
        sum += weight * f64::from(value);
    }
    sum as f32
}
