//! Reconstruction of the scalar field. Mirrors `glsl/include/sampling.glsl`.

use crate::volume::Volume;
use glam::Vec3;

/// Trilinear sample at normalised texture coordinate `tex` ([0,1]^3 spans the volume; voxel centres
/// at (i + 0.5) / dims), clamp-to-edge outside: what `texture()` on a linearly filtered
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
