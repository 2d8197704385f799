//! Reconstruction of the scalar field. Mirrors `glsl/include/sampling.glsl`.

use crate::volume::Volume;
use glam::{IVec3, Vec3};

/// Trilinear sample at normalised texture coordinate `tex` (`[0,1]^3` spans the volume; voxel
/// centres at (i + 0.5) / dims), clamp-to-edge outside: what `texture()` on a linearly filtered
/// `sampler3D` with CLAMP_TO_EDGE computes (up to the GPU's sub-texel weight precision).
pub fn sample_volume(volume: &Volume, tex: Vec3) -> f32 {
    let x = tex * volume.dims().as_vec3() - Vec3::splat(0.5);
    let base = x.floor();
    let f = x - base;
    let (bx, by, bz) = (base.x as i64, base.y as i64, base.z as i64);
    // In f64: `b - a` cannot overflow between finite f32 samples (the GPU's weighted sum does
    // not either), and the result rounds once.
    let v = |dx: i64, dy: i64, dz: i64| f64::from(volume.value_clamped(bx + dx, by + dy, bz + dz));
    let f = f.as_dvec3();
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let c00 = lerp(v(0, 0, 0), v(1, 0, 0), f.x);
    let c10 = lerp(v(0, 1, 0), v(1, 1, 0), f.x);
    let c01 = lerp(v(0, 0, 1), v(1, 0, 1), f.x);
    let c11 = lerp(v(0, 1, 1), v(1, 1, 1), f.x);
    lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z) as f32
}

/// Trilinear sample of an RGBA volume's weighted voxels (`dims`, x fastest) at normalised
/// texture coordinate `tex`, clamp-to-edge: `texture()` on an RGBA32F `sampler3D`. Mirrors the
/// RGBA_VOLUME fetch in raycast.frag.
pub fn sample_rgba_volume(dims: glam::UVec3, voxels: &[glam::Vec4], tex: Vec3) -> glam::Vec4 {
    let x = tex * dims.as_vec3() - Vec3::splat(0.5);
    let base = x.floor();
    let f = (x - base).as_dvec3();
    let at = |dx: i64, dy: i64, dz: i64| {
        let c = |b: f32, d: i64, n: u32| (b as i64 + d).clamp(0, i64::from(n) - 1) as usize;
        let (ix, iy, iz) = (
            c(base.x, dx, dims.x),
            c(base.y, dy, dims.y),
            c(base.z, dz, dims.z),
        );
        voxels[ix + dims.x as usize * (iy + dims.y as usize * iz)].as_dvec4()
    };
    let lerp = |a: glam::DVec4, b: glam::DVec4, t: f64| a + (b - a) * t;
    let c00 = lerp(at(0, 0, 0), at(1, 0, 0), f.x);
    let c10 = lerp(at(0, 1, 0), at(1, 1, 0), f.x);
    let c01 = lerp(at(0, 0, 1), at(1, 0, 1), f.x);
    let c11 = lerp(at(0, 1, 1), at(1, 1, 1), f.x);
    lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z).as_vec4()
}

/// Per axis, the two fetch positions (voxel units) and the first weight of the cubic B-spline
/// at voxel position `x` folded into trilinear fetches (Sigg and Hadwiger): returns
/// `(position 0, position 1, weight 0)`; weight 1 is `1 - weight 0`. Mirrors `tricubic_taps` in
/// sampling.glsl.
pub fn tricubic_taps(x: Vec3) -> (Vec3, Vec3, Vec3) {
    let c = x - Vec3::splat(0.5);
    let i = c.floor();
    let f = c - i;
    let f2 = f * f;
    let f3 = f2 * f;
    let g = Vec3::ONE - f;
    let w0 = g * g * g / 6.0;
    let w1 = (3.0 * f3 - 6.0 * f2 + Vec3::splat(4.0)) / 6.0;
    let w3 = f3 / 6.0;
    let g0 = w0 + w1;
    let g1 = Vec3::ONE - g0;
    let p0 = i - Vec3::splat(0.5) + w1 / g0;
    let p1 = i + Vec3::splat(1.5) + w3 / g1;
    (p0, p1, g0)
}

/// The cubic B-spline of `field` (trilinear, `None` in an absent brick) at voxel position `x`
/// from 8 fetches; an absent fetch takes the value at `x`. Mirrors `sample_tricubic` in
/// raycast.frag.
pub fn sample_tricubic(field: &dyn Fn(Vec3) -> Option<f32>, x: Vec3) -> f32 {
    let (p0, p1, g0) = tricubic_taps(x);
    let centre = field(x).unwrap_or(0.0);
    let mut sum = 0.0;
    for k in 0..8 {
        let side = [k & 1 != 0, k & 2 != 0, k & 4 != 0];
        let mut p = p0;
        let mut w = g0;
        for a in 0..3 {
            if side[a] {
                p[a] = p1[a];
                w[a] = 1.0 - g0[a];
            }
        }
        sum += w.x * w.y * w.z * field(p).unwrap_or(centre);
    }
    sum
}

/// Trilinear interpolation at grid coordinate `u` (samples at integer coordinates) of the
/// samples `value(k)`, in f64 with one rounding at the end.
pub(super) fn trilinear(u: Vec3, value: impl Fn(IVec3) -> f32) -> f32 {
    let base = u.floor();
    let f = (u - base).as_dvec3();
    let b = base.as_ivec3();
    let v = |d: IVec3| f64::from(value(b + d));
    let lerp = |a: f64, c: f64, t: f64| a + (c - a) * t;
    let c00 = lerp(v(IVec3::new(0, 0, 0)), v(IVec3::new(1, 0, 0)), f.x);
    let c10 = lerp(v(IVec3::new(0, 1, 0)), v(IVec3::new(1, 1, 0)), f.x);
    let c01 = lerp(v(IVec3::new(0, 0, 1)), v(IVec3::new(1, 0, 1)), f.x);
    let c11 = lerp(v(IVec3::new(0, 1, 1)), v(IVec3::new(1, 1, 1)), f.x);
    lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The folded taps reproduce the 4 B-spline weights on a field linear between centres, and
    /// the B-spline of a quadratic is the quadratic plus h^2/12 * f'' (here f'' = 2).
    #[test]
    fn tricubic_taps_reproduce_the_b_spline() {
        let quadratic = |p: f32| p * p; // sampled at centres i + 0.5, linear in between
        let linear_between = |p: f32| {
            let c = p - 0.5;
            let i = c.floor();
            let t = c - i;
            quadratic(i + 0.5) * (1.0 - t) + quadratic(i + 1.5) * t
        };
        for k in 0..50 {
            let x = 3.0 + k as f32 * 0.137;
            let (p0, p1, g0) = tricubic_taps(Vec3::splat(x));
            let folded = g0.x * linear_between(p0.x) + (1.0 - g0.x) * linear_between(p1.x);
            // B-spline of samples of x^2 at centres: x^2 + 1/3 (variance of the cubic B-spline).
            let expected = x * x + 1.0 / 3.0;
            assert!(
                (folded - expected).abs() < 1e-4,
                "x={x}: {folded} vs {expected}"
            );
        }
    }
}
