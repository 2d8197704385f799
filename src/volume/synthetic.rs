//! Synthetic test fields: the Marschner-Lobb signal, a solid ball and a one-voxel-thick wall.
//!
//! All synthetic volumes have spacing (1, 1, 1). Values are computed in [0, 1] and quantised to
//! the requested scalar type (`round(v * max)`, clamped); f32 volumes store them as is.
use super::memory::check_host_bytes;
use super::{checked_voxel_count, ScalarType, Volume, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::f64::consts::PI;

/// Radius fraction used by [`SyntheticField::generate`] for [`SyntheticField::Sphere`].
pub const DEFAULT_SPHERE_RADIUS_FRACTION: f32 = 0.8;

/// Which synthetic field to generate.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum SyntheticField {
    /// Marschner-Lobb with fM = 6, alpha = 0.25 over [-1, 1]^3.
    MarschnerLobb,
    /// A solid ball.
    Sphere,
    /// A one-voxel-thick wall.
    Wall,
}

impl SyntheticField {
    /// Parses `ml` / `marschner-lobb`, `sphere` or `wall` (case-insensitive).
    pub fn parse(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "ml" | "marschner-lobb" => Some(SyntheticField::MarschnerLobb),
            "sphere" => Some(SyntheticField::Sphere),
            "wall" => Some(SyntheticField::Wall),
            _ => None,
        }
    }

    /// Generates the field with default parameters: a sphere of radius fraction
    /// [`DEFAULT_SPHERE_RADIUS_FRACTION`], a wall at `x = dims.x / 2`.
    pub fn generate(self, dims: UVec3, scalar: ScalarType) -> Result<Volume, VolumeError> {
        match self {
            SyntheticField::MarschnerLobb => marschner_lobb(dims, scalar),
            SyntheticField::Sphere => sphere(dims, scalar, DEFAULT_SPHERE_RADIUS_FRACTION),
            SyntheticField::Wall => wall(dims, scalar, dims.x / 2),
        }
    }
}

/// The analytic Marschner-Lobb signal (fM = 6, alpha = 0.25) at `p` in [-1, 1]^3:
///
/// `rho(x, y, z) = (1 - sin(pi z / 2) + alpha (1 + rho_r(sqrt(x^2 + y^2)))) / (2 (1 + alpha))`
/// with `rho_r(r) = cos(2 pi fM cos(pi r / 2))`. The result lies in [0, 1]. Computed in f64.
pub fn marschner_lobb_value(p: Vec3) -> f32 {
    const FM: f64 = 6.0;
    const ALPHA: f64 = 0.25;
    let (x, y, z) = (f64::from(p.x), f64::from(p.y), f64::from(p.z));
    let r = (x * x + y * y).sqrt();
    let rho_r = (2.0 * PI * FM * (PI * r / 2.0).cos()).cos();
    ((1.0 - (PI * z / 2.0).sin() + ALPHA * (1.0 + rho_r)) / (2.0 * (1.0 + ALPHA))) as f32
}

/// Marschner-Lobb test signal sampled at voxel centres: voxel `i` on each axis samples
/// coordinate `-1 + 2 (i + 0.5) / dims` (see [`marschner_lobb_value`]).
pub fn marschner_lobb(dims: UVec3, scalar: ScalarType) -> Result<Volume, VolumeError> {
    let d = dims.as_dvec3();
    build(dims, scalar, |x, y, z| {
        let c = |i: u32, n: f64| (-1.0 + 2.0 * (f64::from(i) + 0.5) / n) as f32;
        marschner_lobb_value(Vec3::new(c(x, d.x), c(y, d.y), c(z, d.z)))
    })
}

/// A solid ball centred at `dims / 2` (voxel space, voxel centres at `i + 0.5`) with radius
/// `radius_fraction * min(dims) / 2`. Voxels whose centre lies within the radius are 1.0 (the
/// type's maximum), all others 0. `radius_fraction` must be finite and in (0, 1].
pub fn sphere(
    dims: UVec3,
    scalar: ScalarType,
    radius_fraction: f32,
) -> Result<Volume, VolumeError> {
    if !(radius_fraction > 0.0 && radius_fraction <= 1.0) {
        return Err(VolumeError::InvalidParameter(format!(
            "sphere radius fraction {radius_fraction} must be finite and in (0, 1]"
        )));
    }
    let centre = dims.as_dvec3() / 2.0;
    let radius = f64::from(radius_fraction) * f64::from(dims.min_element()) / 2.0;
    let radius_sq = radius * radius;
    build(dims, scalar, |x, y, z| {
        let p = glam::DVec3::new(f64::from(x), f64::from(y), f64::from(z)) + 0.5;
        if p.distance_squared(centre) <= radius_sq {
            1.0
        } else {
            0.0
        }
    })
}

/// A one-voxel-thick wall perpendicular to x: voxels with `x == x_index` are 1.0 (the type's
/// maximum), all others 0. `x_index` must be below `dims.x`.
pub fn wall(dims: UVec3, scalar: ScalarType, x_index: u32) -> Result<Volume, VolumeError> {
    checked_voxel_count(dims)?;
    if x_index >= dims.x {
        return Err(VolumeError::InvalidParameter(format!(
            "wall x index {x_index} must be below dims.x = {}",
            dims.x
        )));
    }
    build(dims, scalar, |x, _, _| if x == x_index { 1.0 } else { 0.0 })
}

/// Evaluates `f` (values in [0, 1]) at every voxel in storage order, quantises to `scalar` and
/// builds a volume with unit spacing.
fn build(
    dims: UVec3,
    scalar: ScalarType,
    f: impl Fn(u32, u32, u32) -> f32,
) -> Result<Volume, VolumeError> {
    let voxels = checked_voxel_count(dims)?;
    check_host_bytes(
        &format!(
            "a {}x{}x{} {scalar:?} synthetic volume",
            dims.x, dims.y, dims.z
        ),
        (voxels as u64).saturating_mul(scalar.size_bytes() as u64),
    )?;
    let values = (0..dims.z)
        .flat_map(|z| (0..dims.y).flat_map(move |y| (0..dims.x).map(move |x| (x, y, z))));
    let values = values.map(|(x, y, z)| f(x, y, z));
    let quantise = |v: f32, max: f32| (v * max).round().clamp(0.0, max);
    let data = match scalar {
        ScalarType::U8 => VoxelData::U8(values.map(|v| quantise(v, 255.0) as u8).collect()),
        ScalarType::U16 => VoxelData::U16(values.map(|v| quantise(v, 65535.0) as u16).collect()),
        ScalarType::F32 => VoxelData::F32(values.collect()),
    };
    Volume::new(dims, Vec3::ONE, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL_TYPES: [ScalarType; 3] = [ScalarType::U8, ScalarType::U16, ScalarType::F32];

    fn count_nonzero(v: &Volume) -> usize {
        (0..v.data().len())
            .filter(|&i| v.data().normalized(i) != 0.0)
            .count()
    }

    #[test]
    fn ml_value_at_hand_computed_points() {
        // Centre: r = 0 -> rho_r = cos(12 pi) = 1 -> (1 + 0.5) / 2.5.
        assert!((marschner_lobb_value(Vec3::ZERO) - 0.6).abs() < 1e-6);
        // z = -1: (1 + 1 + 0.5) / 2.5 = 1 (the maximum).
        assert!((marschner_lobb_value(Vec3::new(0.0, 0.0, -1.0)) - 1.0).abs() < 1e-6);
        // z = 1: (1 - 1 + 0.5) / 2.5 = 0.2.
        assert!((marschner_lobb_value(Vec3::new(0.0, 0.0, 1.0)) - 0.2).abs() < 1e-6);
        // z = 1/3: sin(pi/6) = 0.5 -> (0.5 + 0.5) / 2.5 = 0.4.
        assert!((marschner_lobb_value(Vec3::new(0.0, 0.0, 1.0 / 3.0)) - 0.4).abs() < 1e-6);
        // r = 1: cos(pi/2) = 0 -> rho_r = 1 -> 0.6, whichever direction r points.
        assert!((marschner_lobb_value(Vec3::new(1.0, 0.0, 0.0)) - 0.6).abs() < 1e-6);
        let d = std::f32::consts::FRAC_1_SQRT_2;
        assert!((marschner_lobb_value(Vec3::new(d, d, 0.0)) - 0.6).abs() < 1e-5);
        // cos(pi r / 2) = 1/12 -> rho_r = cos(pi) = -1 -> (1 + 0) / 2.5 = 0.4.
        let r = (2.0 / std::f64::consts::PI * (1.0f64 / 12.0).acos()) as f32;
        assert!((marschner_lobb_value(Vec3::new(0.0, r, 0.0)) - 0.4).abs() < 1e-5);
        // cos(pi r / 2) = 1/24 -> rho_r = cos(pi / 2) = 0 -> (1 + 0.25) / 2.5 = 0.5.
        let r = (2.0 / std::f64::consts::PI * (1.0f64 / 24.0).acos()) as f32;
        assert!((marschner_lobb_value(Vec3::new(r, 0.0, 0.0)) - 0.5).abs() < 1e-5);
    }

    #[test]
    fn ml_volume_samples_voxel_centres() {
        // Odd dims: the middle voxel samples exactly the origin.
        let v = marschner_lobb(UVec3::new(33, 33, 33), ScalarType::F32).unwrap();
        assert!((v.value(16, 16, 16) - 0.6).abs() < 1e-6);
        // Non-cubic dims: every voxel equals the analytic value at its centre.
        let dims = UVec3::new(7, 5, 3);
        let v = marschner_lobb(dims, ScalarType::F32).unwrap();
        for z in 0..dims.z {
            for y in 0..dims.y {
                for x in 0..dims.x {
                    let p = Vec3::new(x as f32, y as f32, z as f32) + 0.5;
                    let p = -1.0 + 2.0 * p / dims.as_vec3();
                    assert!((v.value(x, y, z) - marschner_lobb_value(p)).abs() < 1e-5);
                }
            }
        }
        // The first voxel along x is at -1 + 1/7, not -1.
        let p = Vec3::new(-1.0 + 1.0 / 7.0, -1.0 + 1.0 / 5.0, -1.0 + 1.0 / 3.0);
        assert!((v.value(0, 0, 0) - marschner_lobb_value(p)).abs() < 1e-5);
    }

    #[test]
    fn ml_range_dims_and_types() {
        let dims = UVec3::new(24, 20, 16);
        for scalar in ALL_TYPES {
            let v = marschner_lobb(dims, scalar).unwrap();
            assert_eq!(v.dims(), dims);
            assert_eq!(v.scalar_type(), scalar);
            assert_eq!(v.spacing(), Vec3::ONE);
            assert_eq!(v.data().len(), 24 * 20 * 16);
            let (lo, hi) = v.value_range();
            assert!((0.0..=1.0).contains(&lo) && (0.0..=1.0).contains(&hi));
            // The signal oscillates: a wide spread of values.
            assert!(hi - lo > 0.5, "range {lo}..{hi}");
        }
    }

    #[test]
    fn ml_u8_quantisation() {
        let dims = UVec3::new(9, 8, 7);
        let f = marschner_lobb(dims, ScalarType::F32).unwrap();
        let VoxelData::U8(q) = marschner_lobb(dims, ScalarType::U8).unwrap().data().clone() else {
            panic!("expected u8 data");
        };
        for (i, &byte) in q.iter().enumerate() {
            assert_eq!(byte, (f.data().normalized(i) * 255.0).round() as u8);
        }
        let VoxelData::U16(q) = marschner_lobb(dims, ScalarType::U16)
            .unwrap()
            .data()
            .clone()
        else {
            panic!("expected u16 data");
        };
        for (i, &word) in q.iter().enumerate() {
            assert_eq!(word, (f.data().normalized(i) * 65535.0).round() as u16);
        }
    }

    #[test]
    fn sphere_voxel_count_matches_ball_volume() {
        for (dims, frac) in [
            (UVec3::splat(64), 0.8),
            (UVec3::new(48, 64, 40), 0.9),
            (UVec3::new(33, 33, 33), 0.5),
        ] {
            let v = sphere(dims, ScalarType::U8, frac).unwrap();
            let r = f64::from(frac) * f64::from(dims.min_element()) / 2.0;
            let expected = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
            let n = count_nonzero(&v) as f64;
            assert!(
                (n - expected).abs() / expected < 0.03,
                "{dims}: {n} voxels vs {expected}"
            );
        }
    }

    #[test]
    fn sphere_values_centre_and_symmetry() {
        let dims = UVec3::new(20, 16, 12);
        for scalar in ALL_TYPES {
            let v = sphere(dims, scalar, 0.75).unwrap();
            assert_eq!((v.dims(), v.scalar_type()), (dims, scalar));
            assert_eq!(v.value(10, 8, 6), 1.0);
            assert_eq!(v.value(9, 7, 5), 1.0);
            assert_eq!(v.value(0, 0, 0), 0.0);
            // Radius 4.5 (r^2 = 20.25) around (10, 8, 6). Voxel (10, 8, z) has centre offset
            // (0.5, 0.5, z + 0.5 - 6): z = 2 or 9 gives 12.75 (inside), z = 1 or 10 gives 20.75.
            assert_eq!(v.value(10, 8, 2), 1.0);
            assert_eq!(v.value(10, 8, 1), 0.0);
            assert_eq!(v.value(10, 8, 9), 1.0);
            assert_eq!(v.value(10, 8, 10), 0.0);
            assert_eq!(v.value(10, 12, 6), 0.0);
            assert_eq!(v.value(10, 11, 6), 1.0);
            for z in 0..dims.z {
                for y in 0..dims.y {
                    for x in 0..dims.x {
                        let a = v.value(x, y, z);
                        assert!(a == 0.0 || a == 1.0);
                        assert_eq!(a, v.value(dims.x - 1 - x, y, z));
                        assert_eq!(a, v.value(x, dims.y - 1 - y, z));
                        assert_eq!(a, v.value(x, y, dims.z - 1 - z));
                    }
                }
            }
        }
    }

    #[test]
    fn sphere_rejects_bad_radius() {
        for frac in [0.0, -0.5, 1.01, f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert!(
                matches!(
                    sphere(UVec3::splat(8), ScalarType::U8, frac),
                    Err(VolumeError::InvalidParameter(_))
                ),
                "radius fraction {frac} accepted"
            );
        }
        // Full radius is allowed: the ball reaches the faces of the smallest axis.
        let v = sphere(UVec3::splat(8), ScalarType::U8, 1.0).unwrap();
        assert_eq!(v.value(0, 4, 4), 1.0);
        assert_eq!(v.value(0, 0, 0), 0.0);
    }

    #[test]
    fn wall_is_exactly_one_slab() {
        let dims = UVec3::new(10, 6, 5);
        for scalar in ALL_TYPES {
            let v = wall(dims, scalar, 3).unwrap();
            assert_eq!((v.dims(), v.scalar_type()), (dims, scalar));
            assert_eq!(count_nonzero(&v), 6 * 5);
            for z in 0..dims.z {
                for y in 0..dims.y {
                    for x in 0..dims.x {
                        let expected = if x == 3 { 1.0 } else { 0.0 };
                        assert_eq!(v.value(x, y, z), expected);
                    }
                }
            }
        }
        let v = wall(dims, ScalarType::U8, 9).unwrap();
        assert_eq!(v.value(9, 5, 4), 1.0);
        assert_eq!(v.value(8, 5, 4), 0.0);
    }

    #[test]
    fn wall_rejects_out_of_range_index() {
        let dims = UVec3::new(10, 6, 5);
        assert!(matches!(
            wall(dims, ScalarType::U8, 10),
            Err(VolumeError::InvalidParameter(_))
        ));
        assert!(matches!(
            wall(dims, ScalarType::U8, u32::MAX),
            Err(VolumeError::InvalidParameter(_))
        ));
    }

    #[test]
    fn zero_dims_rejected() {
        let dims = UVec3::new(4, 0, 4);
        let zero = |r: Result<Volume, VolumeError>| {
            matches!(r, Err(VolumeError::ZeroDimension { axis: 'y', .. }))
        };
        assert!(zero(marschner_lobb(dims, ScalarType::U8)));
        assert!(zero(sphere(dims, ScalarType::U8, 0.5)));
        assert!(zero(wall(dims, ScalarType::U8, 0)));
    }

    #[test]
    fn parse_and_generate() {
        assert_eq!(
            SyntheticField::parse("ml"),
            Some(SyntheticField::MarschnerLobb)
        );
        assert_eq!(
            SyntheticField::parse("Marschner-Lobb"),
            Some(SyntheticField::MarschnerLobb)
        );
        assert_eq!(
            SyntheticField::parse("sphere"),
            Some(SyntheticField::Sphere)
        );
        assert_eq!(SyntheticField::parse("WALL"), Some(SyntheticField::Wall));
        assert_eq!(SyntheticField::parse("cube"), None);
        assert_eq!(SyntheticField::parse(""), None);

        let dims = UVec3::new(11, 8, 6);
        let g = |f: SyntheticField| f.generate(dims, ScalarType::U16).unwrap();
        assert_eq!(
            g(SyntheticField::MarschnerLobb),
            marschner_lobb(dims, ScalarType::U16).unwrap()
        );
        assert_eq!(
            g(SyntheticField::Sphere),
            sphere(dims, ScalarType::U16, 0.8).unwrap()
        );
        assert_eq!(
            g(SyntheticField::Wall),
            wall(dims, ScalarType::U16, 5).unwrap()
        );
    }
}
