//! Address-translation proof (`DESIGN.md` §1-2): random residency plans are packed into a CPU
//! cache image exactly as the upload list says, and trilinear filtering of the cache image at the
//! translated coordinate must equal trilinear filtering of the level's own grid.

use super::*;
use crate::bricks::{
    low_res_level, pack_hi_res_brick, pack_low_res_brick, BrickGrid, DownsampleFilter, LowResLevel,
};
use crate::volume::{Volume, VoxelData};
use glam::{DVec3, IVec3, UVec3, Vec3};

/// Xorshift64.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, m: u64) -> u64 {
        self.next() % m
    }

    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

/// A CPU copy of the cache image (x fastest); unwritten texels are NaN so reading one shows.
struct Image {
    extent: UVec3,
    texels: Vec<f32>,
}

impl Image {
    fn new(extent: UVec3) -> Self {
        let count = (extent.x * extent.y * extent.z) as usize;
        Self {
            extent,
            texels: vec![f32::NAN; count],
        }
    }

    fn index(&self, p: UVec3) -> usize {
        (p.x + self.extent.x * (p.y + self.extent.y * p.z)) as usize
    }

    /// Writes a packed cube of `extent` texels at `origin` (one copy region).
    fn write(&mut self, origin: UVec3, extent: UVec3, values: &[f32]) {
        assert_eq!(values.len(), (extent.x * extent.y * extent.z) as usize);
        let mut src = values.iter();
        for z in 0..extent.z {
            for y in 0..extent.y {
                for x in 0..extent.x {
                    let i = self.index(origin + UVec3::new(x, y, z));
                    self.texels[i] = *src.next().unwrap();
                }
            }
        }
    }

    /// Reads the cube of `extent` texels at `origin`.
    fn read(&self, origin: UVec3, extent: UVec3) -> Vec<f32> {
        let mut out = Vec::new();
        for z in 0..extent.z {
            for y in 0..extent.y {
                for x in 0..extent.x {
                    out.push(self.texels[self.index(origin + UVec3::new(x, y, z))]);
                }
            }
        }
        out
    }

    /// Trilinear filtering at texel coordinate `tex` (texel centres at `i + 0.5`), clamp to edge.
    fn trilinear(&self, tex: Vec3) -> f64 {
        let max = self.extent.as_ivec3() - IVec3::ONE;
        trilinear(tex.as_dvec3() - 0.5, |c| {
            f64::from(self.texels[self.index(c.clamp(IVec3::ZERO, max).as_uvec3())])
        })
    }
}

/// Trilinear interpolation of lattice values `f(c)` (integer points) at `p`; taps with zero weight
/// are skipped, as the hardware's result does not depend on them.
fn trilinear(p: DVec3, f: impl Fn(IVec3) -> f64) -> f64 {
    let base = p.floor();
    let t = p - base;
    let b = base.as_ivec3();
    let mut sum = 0.0;
    for corner in 0..8 {
        let o = IVec3::new(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        let w: f64 = (0..3)
            .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
            .product();
        if w != 0.0 {
            sum += w * f(b + o);
        }
    }
    sum
}

/// A smooth random field plus a little noise, dims not multiples of the brick size.
fn smooth_volume(dims: UVec3, rng: &mut Rng) -> Volume {
    let waves: Vec<(DVec3, f64, f64)> = (0..3)
        .map(|_| {
            let k = DVec3::new(
                rng.range(-0.6, 0.6),
                rng.range(-0.6, 0.6),
                rng.range(-0.6, 0.6),
            );
            (k, rng.range(0.0, 6.3), rng.range(0.05, 0.15))
        })
        .collect();
    let mut values = Vec::new();
    for z in 0..dims.z {
        for y in 0..dims.y {
            for x in 0..dims.x {
                let p = UVec3::new(x, y, z).as_dvec3();
                let smooth: f64 = waves
                    .iter()
                    .map(|(k, ph, a)| a * (k.dot(p) + ph).sin())
                    .sum();
                values.push((0.5 + smooth + 0.05 * (rng.unit() - 0.5)) as f32);
            }
        }
    }
    Volume::new(dims, Vec3::ONE, VoxelData::F32(values)).unwrap()
}

/// The level's own field: hi-res voxels at `i + 0.5`, low-res samples at `2k`, both trilinear with
/// clamp-to-edge.
fn reference_value(volume: &Volume, low: &LowResLevel, level: Level, x: DVec3) -> f64 {
    match level {
        Level::Hi => trilinear(x - 0.5, |c| {
            f64::from(volume.value_clamped(c.x.into(), c.y.into(), c.z.into()))
        }),
        Level::Lo => trilinear(x * 0.5, |k| f64::from(low.value(k))),
        Level::Absent => unreachable!("absent bricks are not sampled"),
    }
}

/// Random plans with at most `capacity` slots: random levels, then random demotions (Hi -> Lo,
/// then Lo -> Absent) until the count rule holds.
fn random_plan(rng: &mut Rng, bricks: usize, capacity: usize) -> Vec<Level> {
    let mut plan: Vec<Level> = (0..bricks)
        .map(|_| [Level::Hi, Level::Lo, Level::Absent][rng.below(3) as usize])
        .collect();
    loop {
        let hi: Vec<usize> = (0..bricks).filter(|&i| plan[i] == Level::Hi).collect();
        let lo: Vec<usize> = (0..bricks).filter(|&i| plan[i] == Level::Lo).collect();
        if BrickCache::slots_needed(hi.len(), lo.len()) <= capacity {
            return plan;
        }
        if hi.is_empty() {
            plan[lo[rng.below(lo.len() as u64) as usize]] = Level::Absent;
        } else {
            plan[hi[rng.below(hi.len() as u64) as usize]] = Level::Lo;
        }
    }
}

#[test]
fn translated_cache_samples_equal_the_levels_own_field() {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    let dims = UVec3::new(21, 17, 13);
    let n = 8;
    let volume = smooth_volume(dims, &mut rng);
    let low = low_res_level(&volume, DownsampleFilter::Mean2);
    let grid = BrickGrid::new(dims, n).unwrap();
    assert_eq!(grid.bricks_per_axis(), UVec3::new(3, 3, 2));
    let geometry = CacheGeometry::new(n, UVec3::splat(32)).unwrap(); // 3^3 slots of 10^3
    let mut checked = [0usize; 2];
    let mut max_error = 0.0f64;
    for run in 0..4 {
        let capacity = [5u32, 8, 12, 27][run];
        let mut cache = BrickCache::with_slot_limit(grid, geometry, capacity).unwrap();
        let mut image = Image::new(geometry.extent());
        for _plan in 0..10 {
            let wanted = random_plan(&mut rng, grid.brick_count(), capacity as usize);
            let update = cache.update(&wanted).unwrap();
            // Apply the upload list exactly as the GPU backend does.
            for upload in &update.uploads {
                let brick = grid.brick_coords(upload.brick as usize);
                let packed = match upload.level {
                    Level::Hi => pack_hi_res_brick(&volume, &grid, brick),
                    Level::Lo => pack_low_res_brick(&volume, &grid, DownsampleFilter::Mean2, brick),
                    Level::Absent => unreachable!("uploads are resident"),
                }
                .unwrap();
                let extent = UVec3::from_array(upload.extent);
                image.write(UVec3::from_array(upload.dst_origin), extent, &packed);
            }
            // The image holds every resident brick's data (no stale or missing uploads).
            let layout = cache.layout_table();
            for (i, &residency) in cache.residencies().iter().enumerate() {
                let Some((origin, extent)) = geometry.texel_box(residency) else {
                    continue;
                };
                let brick = grid.brick_coords(i);
                let packed = match residency.level() {
                    Level::Hi => pack_hi_res_brick(&volume, &grid, brick),
                    _ => pack_low_res_brick(&volume, &grid, DownsampleFilter::Mean2, brick),
                }
                .unwrap();
                assert_eq!(
                    image.read(origin, extent),
                    packed,
                    "brick {i} stale in the image"
                );

                // Random points: half inside the inner region (>= 0.5 from the faces), half
                // anywhere in the brick (clipped to the volume), faces included.
                let level = residency.level();
                let lo_face = (brick * n).as_dvec3();
                let hi_face = ((brick + UVec3::ONE) * n).min(dims).as_dvec3();
                let e = layout[i];
                for s in 0..40 {
                    let margin = if s % 2 == 0 { 0.5 } else { 0.0 };
                    let x = DVec3::new(
                        rng.range(lo_face.x + margin, hi_face.x - margin),
                        rng.range(lo_face.y + margin, hi_face.y - margin),
                        rng.range(lo_face.z + margin, hi_face.z - margin),
                    );
                    // Exactly what the shader does, in f32.
                    let xf = x.as_vec3();
                    let tex = xf * e[3] + Vec3::new(e[0], e[1], e[2]);
                    let cached = image.trilinear(tex);
                    let expected = reference_value(&volume, &low, level, xf.as_dvec3());
                    let error = (cached - expected).abs();
                    max_error = max_error.max(error);
                    assert!(
                        error <= 1e-5,
                        "brick {brick} {level:?} at {x}: cache {cached} vs level {expected}"
                    );
                    checked[(level == Level::Lo) as usize] += 1;
                }
                // The brick's corners, faces included.
                for c in 0..8 {
                    let o = IVec3::new(c & 1, (c >> 1) & 1, (c >> 2) & 1).as_dvec3();
                    let x = lo_face + o * (hi_face - lo_face);
                    let tex = x.as_vec3() * e[3] + Vec3::new(e[0], e[1], e[2]);
                    let expected = reference_value(&volume, &low, level, x);
                    assert!((image.trilinear(tex) - expected).abs() <= 1e-5);
                }
            }
        }
    }
    assert!(checked[0] > 1000 && checked[1] > 1000, "{checked:?}");
    assert!(max_error <= 1e-5);
}

/// The same proof catches a wrong translation: shifting a layout entry by one texel breaks it.
#[test]
fn a_wrong_layout_entry_is_detected() {
    let mut rng = Rng(77);
    let dims = UVec3::new(21, 17, 13);
    let volume = smooth_volume(dims, &mut rng);
    let low = low_res_level(&volume, DownsampleFilter::Mean2);
    let grid = BrickGrid::new(dims, 8).unwrap();
    let geometry = CacheGeometry::new(8, UVec3::splat(32)).unwrap();
    let mut cache = BrickCache::new(grid, geometry).unwrap();
    let mut wanted = vec![Level::Hi; grid.brick_count()];
    wanted[4] = Level::Lo;
    let update = cache.update(&wanted).unwrap();
    let mut image = Image::new(geometry.extent());
    for upload in &update.uploads {
        let brick = grid.brick_coords(upload.brick as usize);
        let packed = match upload.level {
            Level::Hi => pack_hi_res_brick(&volume, &grid, brick).unwrap(),
            _ => pack_low_res_brick(&volume, &grid, DownsampleFilter::Mean2, brick).unwrap(),
        };
        image.write(
            UVec3::from_array(upload.dst_origin),
            UVec3::from_array(upload.extent),
            &packed,
        );
    }
    let layout = cache.layout_table();
    for (i, shift) in [(0usize, 0.0f32), (0, 1.0), (4, 0.0), (4, 0.5)] {
        let level = wanted[i];
        let e = layout[i];
        let centre = (grid.brick_coords(i) * 8).as_vec3() + 4.3;
        let tex = centre * e[3] + Vec3::new(e[0] + shift, e[1], e[2]);
        let error =
            (image.trilinear(tex) - reference_value(&volume, &low, level, centre.as_dvec3())).abs();
        assert_eq!(
            error <= 1e-5,
            shift == 0.0,
            "brick {i} shift {shift}: {error}"
        );
    }
}
