//! The mixed-resolution field: address translation through the layout table, the border fixup,
//! and the smooth (C0) transition reconstruction. Mirrors `glsl/include/mixed.glsl` (sampling)
//! and `glsl/fixup.comp` (fixup) function by function. Conventions: `docs/cache-layout.md`.
//!
//! # The smooth reconstruction
//! Inside a hi-res brick `H`, a point `q` (brick-local hi-res voxel units, `[0, n]^3`) lies in the
//! *band* of axis `a` when it is within half a voxel of one of `H`'s faces along `a`; `s_a` is that
//! side and `beta_a = 1 - 2 * distance` (1 on the face, 0 on the plane of hi-res sample centres).
//! The bricks that touch the band region are the neighbours `d != 0` with `d_a in {0, s_a}` on band
//! axes and `d_a = 0` elsewhere. A band axis is *active* when one of those touching bricks with
//! `d_a != 0` is low-res. With active axes `A`:
//!
//! `f(q) = sum over S ⊆ A of  prod_{a in S} beta_a * prod_{a in A\S} (1 - beta_a) * G(P_S)`
//!
//! where `P_S` snaps the axes of `S` onto the face and those of `A \ S` onto the hi-res plane
//! (0.5 voxel inside), and `G(P)` is the value on the skeleton of brick boundaries: on a face, edge
//! or corner of `H` that touches a low-res brick, the low-res (trilinear on the global low-res grid)
//! function, read from `H`'s fixed-up border with the low-res (trapezoid) warp along the remaining
//! axes; elsewhere plain hardware trilinear in `H`. On the face (`beta = 1`) `f` equals the low-res
//! neighbour's function, at `beta = 0` it equals plain trilinear, and both `G` terms are linear along
//! every blended axis over `[face, plane]` (low-res samples sit on even positions, hi-res ones at
//! half-integers), so the blend is C0 across faces, edges and corners for every neighbour
//! configuration, including low-res bricks that touch `H` only along an edge or at a corner.
//!
//! Why not the paper's single warped fetch everywhere: where a low-res brick touches `H` only
//! diagonally, the value on `H`'s face must mix three distinct texels (`(1-2v) * (L + H) / 2 +
//! 2v * C`), which no single bilinear fetch of UNORM texels reproduces (DESIGN.md §3 names this
//! trap). The warp survives as the low-res read of the border (`u' = (u + 1/2) / 2` on a trapezoid
//! cell, any `u'` on a triangle cell, whose two border texels both hold the apex).

use crate::scene::Transition;
use glam::{BVec3, IVec3, UVec3, Vec3};

/// A CPU copy of the 3D brick cache image (normalised values, x fastest).
#[derive(Clone, Debug, PartialEq)]
pub struct CacheImage {
    /// Extent in texels.
    pub extent: UVec3,
    /// Texel values, `extent.x * extent.y * extent.z` of them.
    pub texels: Vec<f32>,
}

impl CacheImage {
    /// A zero-filled cache image.
    pub fn new(extent: UVec3) -> Self {
        Self {
            extent,
            texels: vec![0.0; (extent.x * extent.y * extent.z) as usize],
        }
    }

    fn index(&self, t: IVec3) -> usize {
        let c = t.clamp(IVec3::ZERO, self.extent.as_ivec3() - IVec3::ONE);
        (c.x as u32 + self.extent.x * (c.y as u32 + self.extent.y * c.z as u32)) as usize
    }

    /// Texel `t` (clamped to the image).
    pub fn texel(&self, t: IVec3) -> f32 {
        self.texels[self.index(t)]
    }

    /// Writes texel `t` (clamped to the image).
    pub fn set_texel(&mut self, t: IVec3, value: f32) {
        let i = self.index(t);
        self.texels[i] = value;
    }

    /// Copies a packed box (x fastest) to texel origin `origin`.
    pub fn write_box(&mut self, origin: UVec3, extent: UVec3, values: &[f32]) {
        let mut i = 0;
        for z in 0..extent.z {
            for y in 0..extent.y {
                for x in 0..extent.x {
                    self.set_texel((origin + UVec3::new(x, y, z)).as_ivec3(), values[i]);
                    i += 1;
                }
            }
        }
    }

    /// Trilinear fetch at texel coordinate `p` (texel centres at `i + 0.5`), clamp to edge:
    /// `texture()` on the cache with unnormalised coordinates.
    pub fn fetch(&self, p: Vec3) -> f32 {
        super::sampling::trilinear(p - Vec3::splat(0.5), |t| self.texel(t))
    }
}

/// The cache image with the tables the ray-caster reads: enough to reconstruct the field.
#[derive(Copy, Clone, Debug)]
pub struct MixedVolume<'a> {
    /// The cache image.
    pub cache: &'a CacheImage,
    /// Layout entry per brick (`docs/cache-layout.md`).
    pub layout: &'a [[f32; 4]],
    /// Neighbour bits per brick.
    pub neighbours: &'a [u32],
    /// Bricks per axis.
    pub bricks: UVec3,
    /// Brick size `n`.
    pub brick_size: u32,
}

/// Bit of the neighbour at offset `d` (`d != 0`, components in -1..=1).
pub fn neighbour_bit(d: IVec3) -> u32 {
    let idx = (d.x + 1) + 3 * (d.y + 1) + 9 * (d.z + 1);
    let k = if idx < 13 { idx } else { idx - 1 };
    1u32 << k
}

/// Brick containing volume point `x`, clamped to the grid.
pub fn brick_of(x: Vec3, brick_size: u32, bricks: UVec3) -> IVec3 {
    // brick_size is a power of two: multiplying by its inverse is exact (as in the GLSL).
    (x * (1.0 / brick_size as f32))
        .floor()
        .as_ivec3()
        .clamp(IVec3::ZERO, bricks.as_ivec3() - IVec3::ONE)
}

/// The neighbour offset that selects axes `mask` (bit a = axis a) on sides `side`.
pub(super) fn offset_of(mask: u32, side: IVec3) -> IVec3 {
    IVec3::new(
        if mask & 1 != 0 { side.x } else { 0 },
        if mask & 2 != 0 { side.y } else { 0 },
        if mask & 4 != 0 { side.z } else { 0 },
    )
}

/// Per axis, the neighbour bits of the bricks on side `side` (the `SIDE_MASKS` entry; none where
/// the side is 0). Mirrors `toward` in neighbours.glsl.
fn toward(side: IVec3) -> [u32; 3] {
    std::array::from_fn(|a| match side[a] {
        s if s < 0 => SIDE_MASKS[a][0],
        s if s > 0 => SIDE_MASKS[a][1],
        _ => 0,
    })
}

/// Neighbour bits of the bricks touching the feature of axes `mask` (face: one axis, edge: two,
/// corner: three) on sides `side`: the offsets `d != 0` with `d_a in {0, side_a}` on the axes of
/// `mask` and `d_a = 0` on the others. Mirrors `touching` in neighbours.glsl.
pub fn touching(mask: u32, side: IVec3) -> u32 {
    let toward = toward(side);
    (0..3)
        .map(|a| CENTRE_MASKS[a] | if mask & (1 << a) != 0 { toward[a] } else { 0 })
        .fold(u32::MAX, |all, allowed| all & allowed)
}

/// Whether any brick touching the feature of axes `mask` on sides `side` is low-res.
pub fn feature_touches_low_res(bits: u32, mask: u32, side: IVec3) -> bool {
    bits & touching(mask, side) != 0
}

/// Band axes of local point `q` in a brick of size `n`: returns (band mask, sides, betas).
pub fn band(q: Vec3, n: f32) -> (u32, IVec3, Vec3) {
    let mut mask = 0;
    let mut side = IVec3::ZERO;
    let mut beta = Vec3::ZERO;
    for a in 0..3 {
        if q[a] < 0.5 {
            mask |= 1 << a;
            side[a] = -1;
            beta[a] = 1.0 - 2.0 * q[a];
        } else if q[a] > n - 0.5 {
            mask |= 1 << a;
            side[a] = 1;
            beta[a] = 1.0 - 2.0 * (n - q[a]);
        }
    }
    (mask, side, beta)
}

/// Band axes whose transition is active: some touching low-res brick lies across that axis.
pub fn active_axes(bits: u32, band_mask: u32, side: IVec3) -> u32 {
    let low = bits & touching(band_mask, side);
    let toward = toward(side);
    (0..3)
        .filter(|&a| low & toward[a] != 0)
        .fold(0, |mask, a| mask | 1 << a)
}

/// Brick-local coordinate at which a single trilinear fetch of the fixed-up border of the feature
/// `face_mask` reads the low-res function at local point `p`: border texel centres on the feature
/// axes, the low-res (trapezoid) warp `2k + 1/2 + (p - 2k) / 2` along the others.
pub fn low_res_border_coord(p: Vec3, face_mask: u32, side: IVec3, n: f32) -> Vec3 {
    let mut c = p;
    for a in 0..3 {
        if face_mask & (1 << a) != 0 {
            c[a] = if side[a] < 0 { -0.5 } else { n + 0.5 };
        } else {
            let k2 = (2.0 * (p[a] * 0.5).floor()).min(n - 2.0);
            c[a] = k2 + 0.5 + (p[a] - k2) * 0.5;
        }
    }
    c
}

/// The field value at volume point `x` (hi-res voxel units), or `None` in an absent brick:
/// the layout lookup, then [`sample_in_brick`].
pub fn sample_mixed(mv: &MixedVolume, x: Vec3, transition: Transition) -> Option<f32> {
    let b = brick_of(x, mv.brick_size, mv.bricks);
    let bi = (b.x as u32 + mv.bricks.x * (b.y as u32 + mv.bricks.y * b.z as u32)) as usize;
    let entry = mv.layout[bi];
    if entry[3] == 0.0 {
        return None;
    }
    // Only a level-0 brick (t_w = 1) blends: the coarser bits of a coarser brick in the
    // three-level cache serve its skeleton fixup alone (`look_up_brick` in raycast.frag).
    let bits = if entry[3] == 1.0 {
        mv.neighbours[bi]
    } else {
        0
    };
    let n = mv.brick_size as f32;
    let (lo, hi) = band_bounds(bits, n);
    Some(sample_in_brick(
        mv.cache,
        x,
        b,
        entry,
        bits,
        (lo, hi),
        n,
        transition,
    ))
}

/// Per-brick band bounds (brick-local): a sample below `lo` or above `hi` on some axis lies in a
/// half-voxel band on a side that touches a low-res neighbour and needs the transition blend;
/// every other sample is a plain fetch. Mirrors `band_bounds` in mixed.glsl.
pub fn band_bounds(bits: u32, n: f32) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(-1.0);
    let mut hi = Vec3::splat(n + 1.0);
    for a in 0..3 {
        if bits & SIDE_MASKS[a][0] != 0 {
            lo[a] = 0.5;
        }
        if bits & SIDE_MASKS[a][1] != 0 {
            hi[a] = n - 0.5;
        }
    }
    (lo, hi)
}

/// Per axis, the neighbour bits of the nine bricks on its low and its high side (`LOW_SIDE` and
/// `HIGH_SIDE` in neighbours.glsl).
pub const SIDE_MASKS: [[u32; 2]; 3] = [
    [0x0092_5249, 0x0249_2924],
    [0x000e_0e07, 0x0381_c1c0],
    [0x0000_01ff, 0x03fe_0000],
];

/// Per axis, the neighbour bits of the eight bricks level with the brick on that axis (`d_a = 0`;
/// `CENTRE` in neighbours.glsl).
pub const CENTRE_MASKS: [u32; 3] = [0x0124_8492, 0x0070_3038, 0x0001_fe00];

/// The field at volume point `x` inside brick `b` with layout entry `entry` (`t_w > 0`),
/// neighbour bits `bits` and band bounds `(lo, hi)` from [`band_bounds`]. Mirrors
/// `sample_in_brick` in mixed.glsl.
#[allow(clippy::too_many_arguments)] // reason: mirrors the GLSL signature, per-brick values.
pub fn sample_in_brick(
    cache: &CacheImage,
    x: Vec3,
    b: IVec3,
    entry: [f32; 4],
    bits: u32,
    (lo, hi): (Vec3, Vec3),
    n: f32,
    transition: Transition,
) -> f32 {
    let t = Vec3::new(entry[0], entry[1], entry[2]);
    if transition == Transition::Smooth && entry[3] == 1.0 && bits != 0 {
        let origin = b.as_vec3() * n;
        let q = x - origin;
        if q.cmplt(lo).any() || q.cmpgt(hi).any() {
            return sample_hi_res_transition(cache, q, origin + t, bits, n);
        }
    }
    cache.fetch(x * entry[3] + t)
}

/// The smooth reconstruction inside a hi-res brick: `q` brick-local, `texel_of_local` the texel
/// coordinate of local 0 (`n*b + t_xyz`), `bits` its neighbour bits.
pub fn sample_hi_res_transition(
    cache: &CacheImage,
    q: Vec3,
    texel_of_local: Vec3,
    bits: u32,
    n: f32,
) -> f32 {
    let (band_mask, side, beta) = band(q, n);
    let active_mask = active_axes(bits, band_mask, side);
    let face = Vec3::new(
        if side.x < 0 { 0.0 } else { n },
        if side.y < 0 { 0.0 } else { n },
        if side.z < 0 { 0.0 } else { n },
    );
    let plane = Vec3::new(
        if side.x < 0 { 0.5 } else { n - 0.5 },
        if side.y < 0 { 0.5 } else { n - 0.5 },
        if side.z < 0 { 0.5 } else { n - 0.5 },
    );
    // What a term reads per axis: on the axes of S the face (hi-res read) or the border texel
    // centre (low-res read through the fixed-up border); on the other active axes the hi-res
    // plane, or its low-res warp; on inactive axes q, or its low-res warp.
    let is_active = BVec3::new(
        active_mask & 1 != 0,
        active_mask & 2 != 0,
        active_mask & 4 != 0,
    );
    let hi_point = Vec3::select(is_active, plane, q);
    let lo_point = low_res_border_coord(hi_point, 0, side, n);
    let border = Vec3::new(
        if side.x < 0 { -0.5 } else { n + 0.5 },
        if side.y < 0 { -0.5 } else { n + 0.5 },
        if side.z < 0 { -0.5 } else { n + 0.5 },
    );
    // Every subset S of the active axes: bit rank[a] of k says whether active axis a is in S
    // (with no active axis, S = {} alone: weight 1 at q itself, a plain fetch).
    let rank = [
        0,
        u32::from(is_active.x),
        u32::from(is_active.x) + u32::from(is_active.y),
    ];
    let mut sum = 0.0;
    for k in 0..1u32 << active_mask.count_ones() {
        let on_face = BVec3::from(std::array::from_fn(|a| {
            is_active.test(a) && (k >> rank[a]) & 1 != 0
        }));
        let s = on_face.bitmask();
        let w = Vec3::select(
            is_active,
            Vec3::select(on_face, beta, Vec3::ONE - beta),
            Vec3::ONE,
        );
        let local = if s != 0 && feature_touches_low_res(bits, s, side) {
            Vec3::select(on_face, border, lo_point)
        } else {
            Vec3::select(on_face, face, hi_point)
        };
        sum += (w.x * w.y * w.z) * cache.fetch(local + texel_of_local);
    }
    sum
}

/// Candidate features of a border texel in precedence order: faces, then edges, then the corner
/// (x before y before z). Returns axis masks; only those inside `border_mask` are used.
pub const FIXUP_PRECEDENCE: [u32; 7] = [0b001, 0b010, 0b100, 0b011, 0b101, 0b110, 0b111];

/// Rewrites the duplicated border texels of the hi-res brick `brick` (whose slot starts at texel
/// `slot_origin`) to the nearest low-res sample of the first low-res neighbour in
/// [`FIXUP_PRECEDENCE`]; texels with no low-res candidate and all original samples stay as they
/// are. Mirrors `glsl/fixup.comp`.
pub fn fixup_brick(
    cache: &mut CacheImage,
    layout: &[[f32; 4]],
    neighbours: &[u32],
    bricks: UVec3,
    brick_size: u32,
    brick: UVec3,
    slot_origin: UVec3,
) {
    let bi = (brick.x + bricks.x * (brick.y + bricks.y * brick.z)) as usize;
    let bits = neighbours[bi];
    if bits == 0 {
        return;
    }
    let s = brick_size + 2;
    for tz in 0..s {
        for ty in 0..s {
            for tx in 0..s {
                let t = UVec3::new(tx, ty, tz);
                if let Some(value) =
                    fixup_value(cache, layout, bits, bricks, brick_size, brick.as_ivec3(), t)
                {
                    cache.set_texel((slot_origin + t).as_ivec3(), value);
                }
            }
        }
    }
}

/// The fixed-up value of texel `t` (slot-local) of hi-res brick `brick`, or `None` when the texel
/// is not on the border or has no low-res candidate.
pub fn fixup_value(
    cache: &CacheImage,
    layout: &[[f32; 4]],
    bits: u32,
    bricks: UVec3,
    brick_size: u32,
    brick: IVec3,
    t: UVec3,
) -> Option<f32> {
    let last = brick_size + 1;
    let mut border_mask = 0;
    let mut side = IVec3::ZERO;
    for a in 0..3 {
        if t[a] == 0 {
            border_mask |= 1 << a;
            side[a] = -1;
        } else if t[a] == last {
            border_mask |= 1 << a;
            side[a] = 1;
        }
    }
    if border_mask == 0 {
        return None;
    }
    let n = brick_size as i32;
    let (d, ni) = first_marked_neighbour(bits, border_mask, side, brick, bricks)?;
    let nb = brick + d;
    let [nx, ny, nz, _] = layout[ni];
    // Nearest low-res sample (even position) of the neighbour to the texel's position.
    let mut sample = IVec3::ZERO;
    for a in 0..3 {
        sample[a] = match d[a] {
            -1 => n * brick[a],
            1 => n * (brick[a] + 1),
            _ => {
                // Texel t sits at n*b - 1 + t + 0.5; nearest even integer, inside the neighbour.
                let p = n * brick[a] - 1 + t[a] as i32; // position - 0.5
                let even = 2 * ((p + 1).div_euclid(2)); // p + 0.5 rounded to even
                even.clamp(n * nb[a], n * (nb[a] + 1))
            }
        };
    }
    let texel = (sample.as_vec3() * 0.5 + Vec3::new(nx, ny, nz))
        .floor()
        .as_ivec3();
    Some(cache.texel(texel))
}

/// The first neighbour, in [`FIXUP_PRECEDENCE`] over the features inside `mask` (faces, then
/// edges, then the corner) on sides `side`, whose bit is set in `bits`: its offset from `brick`
/// and its linear index in a grid of `bricks`. Shared by the border fixup and the skeleton fixup
/// (`reference::level_cache`); mirrors their loops in fixup.comp and skeleton_fixup.comp.
pub fn first_marked_neighbour(
    bits: u32,
    mask: u32,
    side: IVec3,
    brick: IVec3,
    bricks: UVec3,
) -> Option<(IVec3, usize)> {
    FIXUP_PRECEDENCE
        .iter()
        .filter(|&&candidate| candidate & !mask == 0)
        .map(|&candidate| offset_of(candidate, side))
        .find(|&d| bits & neighbour_bit(d) != 0)
        .map(|d| {
            let nb = brick + d;
            let ni = (nb.x as u32 + bricks.x * (nb.y as u32 + bricks.y * nb.z as u32)) as usize;
            (d, ni)
        })
}

/// The CPU mirror of a GPU brick cache: the cache image filled from the volume exactly as the
/// uploads fill the GPU image (values quantised to the storage type), fixed up when smooth, plus
/// the tables. Built from the residency model alone, independently of the GPU.
#[derive(Clone, Debug)]
pub struct ReferenceCache {
    /// The cache image.
    pub image: CacheImage,
    /// Layout entry per brick.
    pub layout: Vec<[f32; 4]>,
    /// Neighbour bits per brick.
    pub neighbours: Vec<u32>,
    /// Bricks per axis.
    pub bricks: UVec3,
    /// Brick size.
    pub brick_size: u32,
}

impl ReferenceCache {
    /// Packs every resident brick of `cache` from `volume` with `filter`, stores it as the GPU
    /// does (`storage` quantisation) and, for [`Transition::Smooth`], runs the fixup.
    pub fn build(
        volume: &crate::volume::Volume,
        filter: crate::bricks::DownsampleFilter,
        cache: &crate::cache::BrickCache,
        storage: crate::volume::ScalarType,
        transition: Transition,
    ) -> crate::Result<Self> {
        use crate::bricks::{
            dequantize, pack_hi_res_brick, pack_low_res_brick, quantize_to, Level,
        };
        use crate::cache::Residency;
        let grid = cache.grid();
        let geometry = cache.geometry();
        let mut image = CacheImage::new(geometry.extent());
        for (index, residency) in cache.residencies().iter().enumerate() {
            let brick = grid.brick_coords(index);
            let (values, origin) = match *residency {
                Residency::Absent => continue,
                Residency::Hi { slot } => (
                    pack_hi_res_brick(volume, grid, brick)?,
                    geometry.slot_origin(slot),
                ),
                Residency::Lo { slot, sub_slot } => (
                    pack_low_res_brick(volume, grid, filter, brick)?,
                    geometry.sub_slot_origin(slot, sub_slot),
                ),
            };
            let stored = dequantize(&quantize_to(&values, storage), storage);
            let edge = match residency.level() {
                Level::Hi => geometry.slot_edge(),
                _ => geometry.sub_slot_edge(),
            };
            image.write_box(origin, UVec3::splat(edge), &stored);
        }
        let layout = cache.layout_table();
        let neighbours = cache.neighbour_bits();
        if transition == Transition::Smooth {
            for slot in cache.fixup_slots() {
                let brick = cache.reverse_table()[slot as usize][0];
                fixup_brick(
                    &mut image,
                    &layout,
                    &neighbours,
                    grid.bricks_per_axis(),
                    grid.brick_size(),
                    grid.brick_coords(brick as usize),
                    geometry.slot_origin(slot),
                );
            }
        }
        Ok(Self {
            image,
            layout,
            neighbours,
            bricks: grid.bricks_per_axis(),
            brick_size: grid.brick_size(),
        })
    }

    /// The view the samplers take.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_masks_collect_the_neighbours_on_each_side() {
        for a in 0..3 {
            for (side, sign) in [(0, -1), (1, 1)] {
                let mut mask = 0;
                for k in 0..27 {
                    let d = IVec3::new(k % 3, (k / 3) % 3, k / 9) - IVec3::ONE;
                    if k != 13 && d[a] == sign {
                        mask |= neighbour_bit(d);
                    }
                }
                assert_eq!(SIDE_MASKS[a][side], mask, "axis {a} side {sign}");
            }
            let level: u32 = (0..27)
                .map(|k| IVec3::new(k % 3, (k / 3) % 3, k / 9) - IVec3::ONE)
                .filter(|d| *d != IVec3::ZERO && d[a] == 0)
                .map(neighbour_bit)
                .fold(0, |m, b| m | b);
            assert_eq!(CENTRE_MASKS[a], level, "axis {a} level");
        }
    }

    /// The subset walks the masks replace: every nonempty subset `sub` of `mask` names the
    /// neighbour `offset_of(sub, side)`.
    fn touching_by_subsets(bits: u32, mask: u32, side: IVec3) -> (bool, u32) {
        let (mut touches, mut active) = (false, 0);
        let mut sub = mask;
        while sub != 0 {
            if bits & neighbour_bit(offset_of(sub, side)) != 0 {
                touches = true;
                active |= sub;
            }
            sub = (sub - 1) & mask;
        }
        (touches, active)
    }

    #[test]
    fn feature_and_active_masks_match_the_subset_walk() {
        // Every side vector and mask, single neighbours, and pseudo-random neighbour sets.
        let mut state = 0x9e37_79b9_u32;
        let mut patterns: Vec<u32> = (0..26).map(|k| 1 << k).collect();
        patterns.extend((0..400).map(|_| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state & ((1 << 26) - 1)
        }));
        patterns.extend([0, (1 << 26) - 1]);
        for k in 0..27 {
            let side = IVec3::new(k % 3, (k / 3) % 3, k / 9) - IVec3::ONE;
            // Masks only name axes with a side (as band() produces them).
            let allowed = (0..3).filter(|&a| side[a] != 0).fold(0, |m, a| m | 1 << a);
            for mask in (0..8u32).filter(|m| m & !allowed == 0) {
                for &bits in &patterns {
                    let (touches, active) = touching_by_subsets(bits, mask, side);
                    assert_eq!(feature_touches_low_res(bits, mask, side), touches);
                    assert_eq!(
                        active_axes(bits, mask, side),
                        active,
                        "{bits:#x} {mask} {side}"
                    );
                }
            }
        }
    }
}
