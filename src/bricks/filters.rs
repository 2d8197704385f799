//! Downsampling filters that build the low-res level (`DESIGN.md` §1).
//!
//! Along each axis, low-res sample `k` sits at hi-res position `2k` (even integers: on brick faces
//! and between them), while hi-res voxel `i` sits at `i + 0.5`. A filter is a set of taps
//! `(offset, weight)`: the sample at `2k` is `sum weight * voxel[2k + offset]`, applied separably per
//! axis (tensor product in 3D), with clamp-to-edge addressing of the hi-res voxels at the volume
//! border.
//!
//! **Low-res grid extent.** Along an axis of `d` voxels the valid low-res indices are
//! `0..=K` with `K = ceil(d / 2)` ([`max_low_res_index`]), so the samples cover `[0, 2K] ⊇ [0, d]`:
//! `ceil(d / 2) + 1` samples ([`low_res_dims`]). Every function here clamps `k` into `0..=K` first
//! (clamp-to-edge on the low-res grid), so low-res bricks that reach past the volume (partial bricks)
//! repeat the last valid sample, just like hi-res bricks repeat the last voxel.

use super::taps::{AxisTaps, DownsampleFilter};
use super::BrickError;
use crate::volume::Volume;
use glam::{IVec3, UVec3};

/// Largest opacity used by the RGBA downsamplers: `alpha` is clamped to `[0, 1 - ALPHA_EPSILON]`
/// before converting to an extinction coefficient, so a fully opaque texel maps to the finite
/// `tau * d0 = -ln(ALPHA_EPSILON) ≈ 13.8` instead of infinity.
pub const ALPHA_EPSILON: f32 = 1e-6;

/// Largest valid low-res index per axis: `K = ceil(dims / 2)` (see the module docs).
pub fn max_low_res_index(dims: UVec3) -> UVec3 {
    (dims + UVec3::ONE) / 2
}

/// Low-res samples per axis: `ceil(dims / 2) + 1`, covering positions `0, 2, ..., 2K`.
pub fn low_res_dims(dims: UVec3) -> UVec3 {
    max_low_res_index(dims) + UVec3::ONE
}

/// The low-res sample `k` (position `2k`) of `volume` under `filter`; `k` is clamped to
/// `0..=max_low_res_index`. Straightforward reference evaluation; use [`low_res_block`] for bulk.
pub fn low_res_value(volume: &Volume, filter: DownsampleFilter, k: IVec3) -> f32 {
    let dims = volume.dims();
    let axis_taps = |axis: usize| -> Vec<(i64, f32)> {
        let d = dims[axis];
        let kc = clamp_low_res(i64::from(k[axis]), d);
        filter
            .taps()
            .iter()
            .map(|&(offset, w)| (clamp_hi_res(2 * kc + offset, d), w))
            .collect()
    };
    let (tx, ty, tz) = (axis_taps(0), axis_taps(1), axis_taps(2));
    let mut sum = 0.0_f64;
    for &(z, wz) in &tz {
        for &(y, wy) in &ty {
            for &(x, wx) in &tx {
                let v = volume.value_clamped(x, y, z);
                sum += f64::from(wx * wy * wz) * f64::from(v);
            }
        }
    }
    sum as f32
}

/// The low-res samples `k_min + j` for `j` in `0..size` (x fastest), each clamped to the valid
/// low-res range, computed separably (three 1D passes over the needed hi-res window).
pub fn low_res_block(
    volume: &Volume,
    filter: DownsampleFilter,
    k_min: IVec3,
    size: UVec3,
) -> Vec<f32> {
    let plan = BlockPlan::new(volume.dims(), filter, k_min, size);
    let source = |x: u32, y: u32, z: u32| [volume.value(x, y, z)];
    plan.run(source).into_iter().map(|[v]| v).collect()
}

/// A whole low-res level: `low_res_dims(volume dims)` samples, x fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct LowResLevel {
    /// Samples per axis.
    pub dims: UVec3,
    /// The samples, x fastest.
    pub values: Vec<f32>,
}

impl LowResLevel {
    /// Sample `k`, clamped to the grid (clamp-to-edge).
    pub fn value(&self, k: IVec3) -> f32 {
        let c = k
            .clamp(IVec3::ZERO, self.dims.as_ivec3() - IVec3::ONE)
            .as_uvec3();
        self.values[linear_index(self.dims, c)]
    }
}

/// Builds the whole low-res level of `volume` under `filter` (in z slabs, so the intermediate
/// window stays small).
pub fn low_res_level(volume: &Volume, filter: DownsampleFilter) -> LowResLevel {
    let dims = low_res_dims(volume.dims());
    let values = by_slabs(dims, |k_min, size| {
        low_res_block(volume, filter, k_min, size)
    });
    LowResLevel { dims, values }
}

/// A downsampled pre-classified RGBA level: straight (not premultiplied) colour and opacity.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaLevel {
    /// Texels per axis (`low_res_dims` of the input).
    pub dims: UVec3,
    /// `[r, g, b, alpha]` per texel, x fastest.
    pub texels: Vec<[f32; 4]>,
}

/// Downsamples a pre-classified RGBA volume by filtering extinction coefficients and
/// extinction-weighted colours (Kraus, §4.1).
///
/// Input texels are `[r, g, b, alpha]` with straight colour `C` and opacity `alpha` for a reference
/// distance `d0`. Each texel is converted to `tau * d0 = -ln(1 - alpha)` (alpha clamped to
/// `[0, 1 - ALPHA_EPSILON]`) and `tau * C`; both are filtered with `filter`'s weights, then
/// `alpha' = 1 - exp(-tau' d0)` and `C' = (tau C)' / tau'`. The output opacity refers to the same
/// `d0` (so `d0` cancels and is not a parameter); correct it for the step length when rendering.
/// Where the filtered extinction is zero (all inputs transparent) the colour weight is zero, and the
/// output colour is the plain filtered colour instead.
pub fn downsample_rgba_extinction(
    texels: &[[f32; 4]],
    dims: UVec3,
    filter: DownsampleFilter,
) -> Result<RgbaLevel, BrickError> {
    downsample_rgba_weighted(texels, dims, filter, OpacityModel::Extinction)
}

/// Downsamples a pre-classified RGBA volume by filtering opacities and opacity-weighted colours,
/// the common approach Kraus argues against (for comparison with [`downsample_rgba_extinction`]).
///
/// Filters `alpha` and `alpha * C` (alpha clamped to `[0, 1]`); `C' = (alpha C)' / alpha'`, or the
/// plain filtered colour where `alpha' = 0`. No opacity correction is applied.
pub fn downsample_rgba_opacity(
    texels: &[[f32; 4]],
    dims: UVec3,
    filter: DownsampleFilter,
) -> Result<RgbaLevel, BrickError> {
    downsample_rgba_weighted(texels, dims, filter, OpacityModel::Opacity)
}

/// Which quantity the RGBA downsamplers average and use as colour weight.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
enum OpacityModel {
    Extinction,
    Opacity,
}

impl OpacityModel {
    /// The linear quantity filtered for opacity `alpha`.
    fn weight(self, alpha: f32) -> f32 {
        match self {
            OpacityModel::Extinction => {
                let a = alpha.clamp(0.0, 1.0 - ALPHA_EPSILON);
                -(-a).ln_1p()
            }
            OpacityModel::Opacity => alpha.clamp(0.0, 1.0),
        }
    }

    /// Opacity of a filtered weight.
    fn opacity(self, weight: f32) -> f32 {
        match self {
            OpacityModel::Extinction => -(-weight).exp_m1(),
            OpacityModel::Opacity => weight,
        }
    }
}

/// Channels filtered for RGBA downsampling: weight, weight * rgb, plain rgb.
type RgbaChannels = [f32; 7];

fn downsample_rgba_weighted(
    texels: &[[f32; 4]],
    dims: UVec3,
    filter: DownsampleFilter,
    model: OpacityModel,
) -> Result<RgbaLevel, BrickError> {
    check_texel_count(texels, dims)?;
    let source = |x: u32, y: u32, z: u32| -> RgbaChannels {
        let [r, g, b, a] = texels[linear_index(dims, UVec3::new(x, y, z))];
        let w = model.weight(a);
        [w, w * r, w * g, w * b, r, g, b]
    };
    let out_dims = low_res_dims(dims);
    let filtered = by_slabs(out_dims, |k_min, size| {
        BlockPlan::new(dims, filter, k_min, size).run(source)
    });
    let texels = filtered.iter().map(|c| resolve_rgba(c, model)).collect();
    Ok(RgbaLevel {
        dims: out_dims,
        texels,
    })
}

/// Turns filtered channels back into straight colour and opacity.
fn resolve_rgba(c: &RgbaChannels, model: OpacityModel) -> [f32; 4] {
    let weight = c[0];
    let alpha = model.opacity(weight);
    if weight > f32::MIN_POSITIVE {
        [c[1] / weight, c[2] / weight, c[3] / weight, alpha]
    } else {
        [c[4], c[5], c[6], alpha.max(0.0)]
    }
}

fn check_texel_count(texels: &[[f32; 4]], dims: UVec3) -> Result<(), BrickError> {
    let expected = dims.x as usize * dims.y as usize * dims.z as usize;
    if dims.min_element() == 0 {
        return Err(BrickError::ZeroDimension {
            dims: dims.to_array(),
        });
    }
    if texels.len() != expected {
        return Err(BrickError::TexelCountMismatch {
            dims: dims.to_array(),
            expected,
            actual: texels.len(),
        });
    }
    Ok(())
}

/// Linear index of `p` in a grid of `dims` (x fastest).
fn linear_index(dims: UVec3, p: UVec3) -> usize {
    p.x as usize + dims.x as usize * (p.y as usize + dims.y as usize * p.z as usize)
}

/// Clamps low-res index `k` to `0..=ceil(d / 2)`.
fn clamp_low_res(k: i64, d: u32) -> i64 {
    k.clamp(0, i64::from(d.div_ceil(2)))
}

/// Clamps hi-res index `i` to `0..d` (clamp-to-edge).
fn clamp_hi_res(i: i64, d: u32) -> i64 {
    i.clamp(0, i64::from(d) - 1)
}

/// Slab depth (low-res samples along z) of whole-level builders.
const SLAB_DEPTH: u32 = 8;

/// Builds a whole grid of `dims` by calling `block(k_min, size)` on z slabs and concatenating.
fn by_slabs<T>(dims: UVec3, mut block: impl FnMut(IVec3, UVec3) -> Vec<T>) -> Vec<T> {
    let mut out = Vec::with_capacity(dims.x as usize * dims.y as usize * dims.z as usize);
    let mut z = 0;
    while z < dims.z {
        let depth = SLAB_DEPTH.min(dims.z - z);
        let k_min = IVec3::new(0, 0, z as i32);
        out.extend(block(k_min, UVec3::new(dims.x, dims.y, depth)));
        z += depth;
    }
    out
}

/// One axis of a block: a window of hi-res indices and, per output sample, its taps `(index into
/// the window, weight)` (the indices from the shared [`AxisTaps`] table).
struct BlockAxis {
    window_start: u32,
    window_len: usize,
    taps: Vec<Vec<(usize, f32)>>,
}

impl BlockAxis {
    fn new(d: u32, filter: DownsampleFilter, k_min: i64, count: u32) -> Self {
        let axis = AxisTaps::new(d, filter);
        let weights = filter.taps();
        let rows: Vec<&[usize]> = (0..i64::from(count))
            .map(|j| axis.row(clamp_low_res(k_min + j, d) as usize))
            .collect();
        let indices = || rows.iter().flat_map(|row| row.iter().copied());
        let start = indices().min().unwrap_or(0);
        let end = indices().max().map_or(start, |i| i + 1);
        let taps = rows
            .iter()
            .map(|row| {
                row.iter()
                    .zip(weights)
                    .map(|(&i, &(_, w))| (i - start, w))
                    .collect()
            })
            .collect();
        Self {
            window_start: start as u32,
            window_len: end - start,
            taps,
        }
    }
}

/// A separable filtering job: the taps of each axis for one block of low-res samples.
struct BlockPlan {
    axes: [BlockAxis; 3],
}

impl BlockPlan {
    fn new(dims: UVec3, filter: DownsampleFilter, k_min: IVec3, size: UVec3) -> Self {
        let axis = |a: usize| BlockAxis::new(dims[a], filter, i64::from(k_min[a]), size[a]);
        Self {
            axes: [axis(0), axis(1), axis(2)],
        }
    }

    /// Gathers the hi-res window from `source` and filters along x, then y, then z.
    fn run<const C: usize>(&self, source: impl Fn(u32, u32, u32) -> [f32; C]) -> Vec<[f32; C]> {
        let [ax, ay, az] = &self.axes;
        let window_dims = [ax.window_len, ay.window_len, az.window_len];
        let mut data = Vec::with_capacity(window_dims.iter().product());
        for z in 0..az.window_len as u32 {
            for y in 0..ay.window_len as u32 {
                for x in 0..ax.window_len as u32 {
                    data.push(source(
                        ax.window_start + x,
                        ay.window_start + y,
                        az.window_start + z,
                    ));
                }
            }
        }
        let mut dims = window_dims;
        for (axis, taps) in self.axes.iter().enumerate() {
            (data, dims) = filter_axis(&data, dims, axis, &taps.taps);
        }
        data
    }
}

/// One separable pass: replaces axis `axis` of the grid `data` (dims `dims`, x fastest) by the
/// filtered samples described by `taps`.
fn filter_axis<const C: usize>(
    data: &[[f32; C]],
    dims: [usize; 3],
    axis: usize,
    taps: &[Vec<(usize, f32)>],
) -> (Vec<[f32; C]>, [usize; 3]) {
    let mut out_dims = dims;
    out_dims[axis] = taps.len();
    let stride = [1, dims[0], dims[0] * dims[1]][axis];
    let mut out = Vec::with_capacity(out_dims.iter().product());
    for z in 0..out_dims[2] {
        for y in 0..out_dims[1] {
            for x in 0..out_dims[0] {
                let mut pos = [x, y, z];
                let row = &taps[pos[axis]];
                pos[axis] = 0;
                let base = pos[0] + dims[0] * (pos[1] + dims[1] * pos[2]);
                out.push(weighted_sum(data, base, stride, row));
            }
        }
    }
    (out, out_dims)
}

/// `sum weight * data[base + index * stride]` per channel, accumulated in f64.
fn weighted_sum<const C: usize>(
    data: &[[f32; C]],
    base: usize,
    stride: usize,
    row: &[(usize, f32)],
) -> [f32; C] {
    let mut acc = [0.0_f64; C];
    for &(index, weight) in row {
        let texel = &data[base + index * stride];
        for (a, v) in acc.iter_mut().zip(texel) {
            *a += f64::from(weight) * f64::from(*v);
        }
    }
    acc.map(|a| a as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::tests::pseudo_random;
    use crate::volume::VoxelData;
    use glam::Vec3;

    fn volume_from(dims: UVec3, f: impl Fn(UVec3) -> f32) -> Volume {
        let mut values = Vec::new();
        for z in 0..dims.z {
            for y in 0..dims.y {
                for x in 0..dims.x {
                    values.push(f(UVec3::new(x, y, z)));
                }
            }
        }
        Volume::new(dims, Vec3::ONE, VoxelData::F32(values)).unwrap()
    }

    fn all_k(dims: UVec3) -> impl Iterator<Item = IVec3> {
        let r = low_res_dims(dims).as_ivec3() + IVec3::splat(2);
        (-2..r.z).flat_map(move |z| {
            (-2..r.y).flat_map(move |y| (-2..r.x).map(move |x| IVec3::new(x, y, z)))
        })
    }

    #[test]
    fn weights_sum_to_one_and_are_symmetric_about_2k() {
        for filter in DownsampleFilter::ALL {
            let sum: f32 = filter.taps().iter().map(|t| t.1).sum();
            assert!((sum - 1.0).abs() < 1e-7, "{filter:?}");
            if filter != DownsampleFilter::LaMarSubsample {
                // Voxel 2k + o sits at 2k + o + 0.5; symmetric weights centre the sample at 2k.
                let centre: f32 = filter
                    .taps()
                    .iter()
                    .map(|&(o, w)| w * (o as f32 + 0.5))
                    .sum();
                assert!(centre.abs() < 1e-7, "{filter:?}");
            }
        }
        assert_eq!(DownsampleFilter::default(), DownsampleFilter::Mean2);
        assert_eq!(
            DownsampleFilter::parse("BSpline4"),
            Some(DownsampleFilter::BSpline4)
        );
        assert_eq!(DownsampleFilter::parse("nope"), None);
    }

    #[test]
    fn low_res_extent_covers_the_volume() {
        assert_eq!(low_res_dims(UVec3::new(1, 2, 3)), UVec3::new(2, 2, 3));
        assert_eq!(
            max_low_res_index(UVec3::new(64, 65, 7)),
            UVec3::new(32, 33, 4)
        );
    }

    #[test]
    fn constants_stay_constant() {
        let dims = UVec3::new(7, 5, 3);
        let volume = volume_from(dims, |_| 0.37);
        for filter in DownsampleFilter::ALL {
            for k in all_k(dims) {
                assert!((low_res_value(&volume, filter, k) - 0.37).abs() < 1e-6);
            }
            let level = low_res_level(&volume, filter);
            assert!(level.values.iter().all(|v| (v - 0.37).abs() < 1e-6));
        }
    }

    #[test]
    fn linear_ramp_is_reproduced_at_2k_away_from_the_border() {
        let dims = UVec3::new(12, 10, 14);
        let a = Vec3::new(0.01, -0.02, 0.015);
        let c = 0.4;
        let volume = volume_from(dims, |i| a.dot(i.as_vec3() + Vec3::splat(0.5)) + c);
        for filter in DownsampleFilter::ALL {
            // Taps reach 2k-2 ..= 2k+1: interior k in 1..=(d-2)/2 needs no clamping.
            for z in 1..=(dims.z as i32 - 2) / 2 {
                for y in 1..=(dims.y as i32 - 2) / 2 {
                    for x in 1..=(dims.x as i32 - 2) / 2 {
                        let k = IVec3::new(x, y, z);
                        let shift = match filter {
                            DownsampleFilter::LaMarSubsample => 0.5,
                            _ => 0.0,
                        };
                        let expected = a.dot(k.as_vec3() * 2.0 + Vec3::splat(shift)) + c;
                        let got = low_res_value(&volume, filter, k);
                        assert!(
                            (got - expected).abs() < 1e-6,
                            "{filter:?} {k}: {got} vs {expected}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn lamar_takes_voxel_2k() {
        let dims = UVec3::new(9, 6, 5);
        let volume = volume_from(dims, |i| (i.x + 10 * i.y + 100 * i.z) as f32 / 1000.0);
        for k in all_k(dims) {
            let kc = k.clamp(IVec3::ZERO, max_low_res_index(dims).as_ivec3());
            let i = (kc * 2).as_i64vec3();
            let expected = volume.value_clamped(i.x, i.y, i.z);
            assert_eq!(
                low_res_value(&volume, DownsampleFilter::LaMarSubsample, k),
                expected
            );
        }
    }

    /// 1D weight of the tap at offset `o` (0 when `o` is not a tap).
    fn tap_weight(filter: DownsampleFilter, o: i64) -> f32 {
        filter.taps().iter().find(|t| t.0 == o).map_or(0.0, |t| t.1)
    }

    #[test]
    fn impulse_gives_the_filter_weights() {
        let dims = UVec3::new(16, 16, 16);
        for filter in DownsampleFilter::ALL {
            for centre in [UVec3::new(8, 8, 8), UVec3::new(9, 8, 7)] {
                let volume = volume_from(dims, |i| if i == centre { 1.0 } else { 0.0 });
                let level = low_res_level(&volume, filter);
                for k in all_k(dims) {
                    let o = centre.as_i64vec3() - (k * 2).as_i64vec3();
                    let expected =
                        tap_weight(filter, o.x) * tap_weight(filter, o.y) * tap_weight(filter, o.z);
                    let got = low_res_value(&volume, filter, k);
                    assert!((got - expected).abs() < 1e-7, "{filter:?} {k}");
                    assert!((level.value(k) - expected).abs() < 1e-7, "{filter:?} {k}");
                }
            }
        }
        // The explicit numbers: the B-spline weights appear at the right k along x.
        let volume = volume_from(UVec3::new(16, 1, 1), |i| if i.x == 8 { 1.0 } else { 0.0 });
        let v = |k| low_res_value(&volume, DownsampleFilter::BSpline4, IVec3::new(k, 0, 0));
        assert!((v(5) - 13.0 / 64.0).abs() < 1e-7); // 8 = 2*5 - 2
        assert!((v(4) - 19.0 / 64.0).abs() < 1e-7); // 8 = 2*4 + 0
        let volume = volume_from(UVec3::new(16, 1, 1), |i| if i.x == 9 { 1.0 } else { 0.0 });
        let v = |k| low_res_value(&volume, DownsampleFilter::BSpline4, IVec3::new(k, 0, 0));
        assert!((v(5) - 19.0 / 64.0).abs() < 1e-7); // 9 = 2*5 - 1
        assert!((v(4) - 13.0 / 64.0).abs() < 1e-7); // 9 = 2*4 + 1
        assert_eq!(v(3), 0.0);
        assert_eq!(v(6), 0.0);
    }

    #[test]
    fn block_builder_matches_pointwise_values_including_clamped_k() {
        let dims = UVec3::new(11, 7, 5);
        let count = (dims.x * dims.y * dims.z) as usize;
        let volume =
            Volume::new(dims, Vec3::ONE, VoxelData::F32(pseudo_random(count, 11))).unwrap();
        let k_min = IVec3::new(-2, 1, -1);
        let size = UVec3::new(10, 4, 6);
        for filter in DownsampleFilter::ALL {
            let block = low_res_block(&volume, filter, k_min, size);
            assert_eq!(block.len(), 240);
            for (i, got) in block.iter().enumerate() {
                let j = IVec3::new(i as i32 % 10, (i as i32 / 10) % 4, i as i32 / 40);
                let expected = low_res_value(&volume, filter, k_min + j);
                assert!((got - expected).abs() < 1e-6, "{filter:?} {j}");
            }
        }
    }

    #[test]
    fn k_beyond_the_grid_is_clamped() {
        let dims = UVec3::new(9, 4, 3);
        let count = (dims.x * dims.y * dims.z) as usize;
        let volume = Volume::new(dims, Vec3::ONE, VoxelData::F32(pseudo_random(count, 5))).unwrap();
        let kmax = max_low_res_index(dims).as_ivec3();
        for filter in DownsampleFilter::ALL {
            assert_eq!(
                low_res_value(&volume, filter, kmax + IVec3::new(3, 1, 7)),
                low_res_value(&volume, filter, kmax)
            );
            assert_eq!(
                low_res_value(&volume, filter, IVec3::splat(-4)),
                low_res_value(&volume, filter, IVec3::ZERO)
            );
        }
    }

    fn rgba_volume(dims: UVec3, f: impl Fn(UVec3) -> [f32; 4]) -> Vec<[f32; 4]> {
        let mut texels = Vec::new();
        for z in 0..dims.z {
            for y in 0..dims.y {
                for x in 0..dims.x {
                    texels.push(f(UVec3::new(x, y, z)));
                }
            }
        }
        texels
    }

    fn assert_texel_near(got: [f32; 4], expected: [f32; 4], tol: f32) {
        for (g, e) in got.iter().zip(expected) {
            assert!((g - e).abs() < tol, "{got:?} vs {expected:?}");
        }
    }

    #[test]
    fn homogeneous_rgba_keeps_colour_and_alpha() {
        let dims = UVec3::new(6, 5, 4);
        for texel in [
            [0.2, 0.5, 0.9, 0.6],
            [0.7, 0.1, 0.3, 1.0],
            [0.4, 0.4, 0.8, 0.0],
        ] {
            let texels = rgba_volume(dims, |_| texel);
            for filter in DownsampleFilter::ALL {
                let ext = downsample_rgba_extinction(&texels, dims, filter).unwrap();
                let opa = downsample_rgba_opacity(&texels, dims, filter).unwrap();
                assert_eq!(ext.dims, low_res_dims(dims));
                let alpha_ext = texel[3].min(1.0 - ALPHA_EPSILON);
                for t in &ext.texels {
                    assert_texel_near(*t, [texel[0], texel[1], texel[2], alpha_ext], 1e-5);
                }
                for t in &opa.texels {
                    assert_texel_near(*t, texel, 1e-5);
                }
            }
        }
    }

    #[test]
    fn extinction_averaging_keeps_opacity_that_opacity_averaging_loses() {
        // Mean2 at k = 1 averages indices 1 and 2 along x.
        let dims = UVec3::new(4, 1, 1);
        let texels = vec![
            [0.0, 0.0, 0.0, 0.0],
            [1.0, 0.5, 0.0, 0.99],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
        ];
        let filter = DownsampleFilter::Mean2;
        let ext = downsample_rgba_extinction(&texels, dims, filter)
            .unwrap()
            .texels[1];
        let opa = downsample_rgba_opacity(&texels, dims, filter)
            .unwrap()
            .texels[1];
        // tau-mean: 1 - exp(ln(0.01) / 2) = 1 - sqrt(0.01) = 0.9.
        assert_texel_near(ext, [1.0, 0.5, 0.0, 0.9], 1e-5);
        assert_texel_near(opa, [1.0, 0.5, 0.0, 0.495], 1e-5);
        assert!(ext[3] > opa[3]);
    }

    #[test]
    fn extinction_weights_colour_by_extinction() {
        let dims = UVec3::new(4, 1, 1);
        let a = 1.0 - (-1.0_f32).exp(); // tau d0 = 1
        let b = 1.0 - (-3.0_f32).exp(); // tau d0 = 3
        let texels = vec![[0.0; 4], [1.0, 0.0, 0.0, a], [0.0, 1.0, 0.0, b], [0.0; 4]];
        let ext = downsample_rgba_extinction(&texels, dims, DownsampleFilter::Mean2).unwrap();
        let expected_alpha = 1.0 - (-2.0_f32).exp();
        assert_texel_near(ext.texels[1], [0.25, 0.75, 0.0, expected_alpha], 1e-5);
    }

    #[test]
    fn transparent_rgba_returns_plain_average_colour() {
        let dims = UVec3::new(4, 1, 1);
        let texels = vec![
            [0.0; 4],
            [1.0, 0.0, 0.2, 0.0],
            [0.0, 1.0, 0.4, 0.0],
            [0.0; 4],
        ];
        for result in [
            downsample_rgba_extinction(&texels, dims, DownsampleFilter::Mean2).unwrap(),
            downsample_rgba_opacity(&texels, dims, DownsampleFilter::Mean2).unwrap(),
        ] {
            assert_texel_near(result.texels[1], [0.5, 0.5, 0.3, 0.0], 1e-6);
            assert!(result.texels.iter().flatten().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn rgba_rejects_wrong_texel_count() {
        let result = downsample_rgba_extinction(
            &[[0.0; 4]; 5],
            UVec3::new(2, 2, 1),
            DownsampleFilter::Mean2,
        );
        assert_eq!(
            result,
            Err(BrickError::TexelCountMismatch {
                dims: [2, 2, 1],
                expected: 4,
                actual: 5
            })
        );
    }
}
