//! Packed brick storage for upload into the brick cache (`DESIGN.md` §1, Beyer et al. §3.1-3.2).
//!
//! - A hi-res brick is `(n+2)^3` texels: texel `t` along an axis holds hi-res voxel `n*b - 1 + t`,
//!   i.e. the brick's `n` own voxels plus one duplicated border voxel on each side (positions
//!   `n*b - 0.5` and `n*(b+1) + 0.5`). Voxels outside the volume (the outer border, and the missing
//!   part of partial bricks) are clamped to the nearest voxel inside, like clamp-to-edge sampling.
//! - A low-res brick is `(n/2+1)^3` texels: texel `j` holds the low-res sample at position
//!   `n*b + 2j`, i.e. `k = n*b/2 + j`, clamped to the valid low-res range `0..=ceil(dims/2)`
//!   (see [`super::filters`]). Both brick faces carry samples, so adjacent low-res bricks store the
//!   same values on their shared face.
//! - Eight low-res bricks tile one `(n+2)^3` slot exactly (`2 * (n/2+1) = n+2`): sub-slot `s` starts
//!   at texel [`subslot_offset`]`(n, s) = ((s & 1), (s >> 1) & 1, (s >> 2) & 1) * (n/2+1)`.
//!
//! All packed bricks are `Vec<f32>` of normalised values, x fastest; [`quantize_to`] converts them to
//! the bytes of a storage format.

use super::filters::low_res_block;
use super::taps::DownsampleFilter;
use super::{BrickError, BrickGrid};
use crate::volume::{ScalarType, Volume};
use glam::{IVec3, UVec3};

/// Low-res bricks per `(n+2)^3` slot.
pub const SUB_SLOTS_PER_SLOT: u32 = 8;

/// Texels per axis of a packed hi-res brick: `n + 2`.
pub const fn hi_res_brick_extent(brick_size: u32) -> u32 {
    brick_size + 2
}

/// Texels per axis of a packed low-res brick: `n/2 + 1`.
pub const fn low_res_brick_extent(brick_size: u32) -> u32 {
    brick_size / 2 + 1
}

/// Texel offset of low-res sub-slot `subslot` (in `0..8`) inside an `(n+2)^3` slot:
/// `((s & 1), (s >> 1) & 1, (s >> 2) & 1) * (n/2 + 1)`.
pub const fn subslot_offset(brick_size: u32, subslot: u32) -> UVec3 {
    let e = low_res_brick_extent(brick_size);
    UVec3::new(
        (subslot & 1) * e,
        ((subslot >> 1) & 1) * e,
        ((subslot >> 2) & 1) * e,
    )
}

/// Packs hi-res brick `brick` as `(n+2)^3` normalised values (x fastest): texel `t` holds voxel
/// `n*brick - 1 + t`, clamped to the volume.
pub fn pack_hi_res_brick(
    volume: &Volume,
    grid: &BrickGrid,
    brick: UVec3,
) -> Result<Vec<f32>, BrickError> {
    grid.check_volume(volume)?;
    grid.check_brick(brick)?;
    let extent = hi_res_brick_extent(grid.brick_size()) as i64;
    let first = (grid.brick_origin(brick) - IVec3::ONE).as_i64vec3();
    let mut out = Vec::with_capacity((extent * extent * extent) as usize);
    for z in 0..extent {
        for y in 0..extent {
            for x in 0..extent {
                out.push(volume.value_clamped(first.x + x, first.y + y, first.z + z));
            }
        }
    }
    Ok(out)
}

/// Packs low-res brick `brick` as `(n/2+1)^3` normalised values (x fastest): texel `j` holds the
/// low-res sample `k = n*brick/2 + j` under `filter`, clamped to the low-res grid.
pub fn pack_low_res_brick(
    volume: &Volume,
    grid: &BrickGrid,
    filter: DownsampleFilter,
    brick: UVec3,
) -> Result<Vec<f32>, BrickError> {
    grid.check_volume(volume)?;
    grid.check_brick(brick)?;
    let k_min = grid.brick_origin(brick) / 2;
    let size = UVec3::splat(low_res_brick_extent(grid.brick_size()));
    Ok(low_res_block(volume, filter, k_min, size))
}

/// Converts normalised values to the native-endian bytes of `scalar` texels.
///
/// `U8` / `U16` (UNORM): `round(clamp(v, 0, 1) * (2^bits - 1))`, round-to-nearest with ties away
/// from zero (Rust's `f32::round`), the conversion Vulkan recommends for UNORM; NaN maps to 0.
/// Values that came from such a volume (`byte / 255`) convert back exactly. `F32`: the values as
/// they are.
pub fn quantize_to(values: &[f32], scalar: ScalarType) -> Vec<u8> {
    match scalar {
        ScalarType::U8 => values.iter().map(|&v| unorm(v, 255.0) as u8).collect(),
        ScalarType::U16 => values
            .iter()
            .flat_map(|&v| (unorm(v, 65535.0) as u16).to_ne_bytes())
            .collect(),
        ScalarType::F32 => bytemuck::cast_slice(values).to_vec(),
    }
}

/// `round(clamp(v, 0, 1) * max)`; NaN becomes 0 (saturating float-to-int casts).
fn unorm(v: f32, max: f32) -> f32 {
    (v.clamp(0.0, 1.0) * max).round()
}

/// Normalised values of texel bytes in the storage format (what the GPU's UNORM/SFLOAT read
/// gives): the inverse of [`quantize_to`] on values it produced.
pub fn dequantize(bytes: &[u8], storage: ScalarType) -> Vec<f32> {
    match storage {
        ScalarType::U8 => bytes.iter().map(|&b| f32::from(b) / 255.0).collect(),
        ScalarType::U16 => bytes
            .chunks_exact(2)
            .map(|c| f32::from(u16::from_ne_bytes([c[0], c[1]])) / 65535.0)
            .collect(),
        ScalarType::F32 => bytemuck::pod_collect_to_vec(bytes),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::filters::{low_res_value, max_low_res_index};
    use crate::bricks::tests::pseudo_random;
    use crate::volume::VoxelData;
    use glam::Vec3;

    fn random_volume(dims: UVec3, seed: u64) -> Volume {
        let count = (dims.x * dims.y * dims.z) as usize;
        Volume::new(dims, Vec3::ONE, VoxelData::F32(pseudo_random(count, seed))).unwrap()
    }

    fn texel(packed: &[f32], extent: u32, t: UVec3) -> f32 {
        packed[(t.x + extent * (t.y + extent * t.z)) as usize]
    }

    fn clamped(volume: &Volume, p: IVec3) -> f32 {
        volume.value_clamped(p.x as i64, p.y as i64, p.z as i64)
    }

    #[test]
    fn hi_res_interior_equals_voxels_and_border_clamps() {
        let dims = UVec3::new(10, 9, 5);
        let volume = random_volume(dims, 21);
        let grid = BrickGrid::new(dims, 4).unwrap();
        let e = hi_res_brick_extent(4);
        for brick in grid.bricks() {
            let packed = pack_hi_res_brick(&volume, &grid, brick).unwrap();
            assert_eq!(packed.len(), (e * e * e) as usize);
            for z in 0..e {
                for y in 0..e {
                    for x in 0..e {
                        let t = UVec3::new(x, y, z);
                        let voxel = grid.brick_origin(brick) - IVec3::ONE + t.as_ivec3();
                        assert_eq!(texel(&packed, e, t), clamped(&volume, voxel));
                    }
                }
            }
        }
        // Interior texel (1,1,1) is the brick's first voxel.
        let packed = pack_hi_res_brick(&volume, &grid, UVec3::new(1, 1, 0)).unwrap();
        assert_eq!(texel(&packed, e, UVec3::ONE), volume.value(4, 4, 0));
        // Volume border: texel 0 of brick 0 repeats voxel 0.
        let packed = pack_hi_res_brick(&volume, &grid, UVec3::ZERO).unwrap();
        assert_eq!(texel(&packed, e, UVec3::ZERO), volume.value(0, 0, 0));
    }

    #[test]
    fn hi_res_border_duplicates_the_neighbours_voxels() {
        let dims = UVec3::new(12, 8, 8);
        let volume = random_volume(dims, 4);
        let grid = BrickGrid::new(dims, 4).unwrap();
        let e = hi_res_brick_extent(4);
        let left = pack_hi_res_brick(&volume, &grid, UVec3::new(0, 1, 0)).unwrap();
        let right = pack_hi_res_brick(&volume, &grid, UVec3::new(1, 1, 0)).unwrap();
        for z in 0..e {
            for y in 0..e {
                // Left's far border = right's first voxel; right's near border = left's last voxel.
                let at = |x| UVec3::new(x, y, z);
                assert_eq!(texel(&left, e, at(5)), texel(&right, e, at(1)));
                assert_eq!(texel(&right, e, at(0)), texel(&left, e, at(4)));
            }
        }
    }

    #[test]
    fn partial_hi_res_brick_clamps_to_the_last_voxel() {
        let dims = UVec3::new(10, 5, 3);
        let volume = random_volume(dims, 8);
        let grid = BrickGrid::new(dims, 4).unwrap();
        assert_eq!(grid.bricks_per_axis(), UVec3::new(3, 2, 1));
        let e = hi_res_brick_extent(4);
        let packed = pack_hi_res_brick(&volume, &grid, UVec3::new(2, 1, 0)).unwrap();
        // Brick x-range 8..12: texels 1, 2 hold voxels 8, 9; texels 3, 4, 5 (voxels 10..12) clamp to 9.
        for t in 3..e {
            assert_eq!(
                texel(&packed, e, UVec3::new(t, 1, 1)),
                volume.value(9, 4, 0),
                "texel {t}"
            );
        }
        assert_eq!(
            texel(&packed, e, UVec3::new(1, 1, 1)),
            volume.value(8, 4, 0)
        );
        assert!(pack_hi_res_brick(&volume, &grid, UVec3::new(3, 0, 0)).is_err());
    }

    #[test]
    fn low_res_texels_hold_clamped_low_res_samples() {
        let dims = UVec3::new(13, 9, 6);
        let volume = random_volume(dims, 31);
        let grid = BrickGrid::new(dims, 4).unwrap();
        let e = low_res_brick_extent(4);
        let kmax = max_low_res_index(dims).as_ivec3();
        for filter in DownsampleFilter::ALL {
            for brick in grid.bricks() {
                let packed = pack_low_res_brick(&volume, &grid, filter, brick).unwrap();
                assert_eq!(packed.len(), (e * e * e) as usize);
                for z in 0..e {
                    for y in 0..e {
                        for x in 0..e {
                            let j = UVec3::new(x, y, z);
                            let k = grid.brick_origin(brick) / 2 + j.as_ivec3();
                            let expected = low_res_value(&volume, filter, k.min(kmax));
                            let got = texel(&packed, e, j);
                            assert!((got - expected).abs() < 1e-6, "{filter:?} {brick} {j}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn adjacent_low_res_bricks_share_face_values() {
        let dims = UVec3::new(16, 16, 16);
        let volume = random_volume(dims, 17);
        let grid = BrickGrid::new(dims, 8).unwrap();
        let e = low_res_brick_extent(8);
        for filter in DownsampleFilter::ALL {
            for axis in 0..3 {
                let mut next = UVec3::ZERO;
                next[axis] = 1;
                let a = pack_low_res_brick(&volume, &grid, filter, UVec3::ZERO).unwrap();
                let b = pack_low_res_brick(&volume, &grid, filter, next).unwrap();
                for v in 0..e {
                    for u in 0..e {
                        let mut on_a = UVec3::new(u, v, u);
                        let mut on_b = on_a;
                        (on_a[axis], on_b[axis]) = (e - 1, 0);
                        let (p, q) = (texel(&a, e, on_a), texel(&b, e, on_b));
                        assert_eq!(p, q, "{filter:?} axis {axis}");
                    }
                }
            }
        }
    }

    #[test]
    fn eight_subslots_tile_the_slot_exactly() {
        for n in [2, 4, 8, 32] {
            let slot = hi_res_brick_extent(n);
            let sub = low_res_brick_extent(n);
            assert_eq!(2 * sub, slot);
            let mut hits = vec![0u8; (slot * slot * slot) as usize];
            for s in 0..SUB_SLOTS_PER_SLOT {
                let o = subslot_offset(n, s);
                for z in 0..sub {
                    for y in 0..sub {
                        for x in 0..sub {
                            let t = o + UVec3::new(x, y, z);
                            hits[(t.x + slot * (t.y + slot * t.z)) as usize] += 1;
                        }
                    }
                }
            }
            assert!(hits.iter().all(|&h| h == 1), "n = {n}");
        }
        assert_eq!(subslot_offset(32, 5), UVec3::new(17, 0, 17));
    }

    #[test]
    fn quantize_rounds_to_nearest_and_clamps() {
        let values = [0.0, 1.0, -0.5, 2.0, 0.4 / 255.0, 0.6 / 255.0, 0.5, f32::NAN];
        assert_eq!(
            quantize_to(&values, ScalarType::U8),
            vec![0, 255, 0, 255, 0, 1, 128, 0]
        );
        let u16_bytes = quantize_to(&[0.5, 1.0, 0.6 / 65535.0], ScalarType::U16);
        let words: Vec<u16> = u16_bytes
            .chunks_exact(2)
            .map(|c| u16::from_ne_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(words, vec![32768, 65535, 1]);
        let f32_bytes = quantize_to(&[0.25, -3.0], ScalarType::F32);
        assert_eq!(f32_bytes.len(), 8);
        assert_eq!(
            f32::from_ne_bytes(f32_bytes[4..8].try_into().unwrap()),
            -3.0
        );
    }

    #[test]
    fn u8_volume_round_trips_through_packing() {
        let dims = UVec3::new(6, 6, 6);
        let bytes: Vec<u8> = (0..216).map(|i| (i * 37 % 256) as u8).collect();
        let volume = Volume::new(dims, Vec3::ONE, VoxelData::U8(bytes)).unwrap();
        let grid = BrickGrid::new(dims, 4).unwrap();
        let packed = pack_hi_res_brick(&volume, &grid, UVec3::ZERO).unwrap();
        let stored = quantize_to(&packed, ScalarType::U8);
        for (byte, value) in stored.iter().zip(&packed) {
            assert_eq!(f32::from(*byte) / 255.0, *value);
        }
    }
}
