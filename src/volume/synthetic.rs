//! Synthetic test fields. (Being written.)
use super::{ScalarType, Volume, VolumeError};
use glam::UVec3;

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

/// Marschner-Lobb test signal.
pub fn marschner_lobb(_dims: UVec3, _scalar: ScalarType) -> Result<Volume, VolumeError> {
    todo!()
}

/// A sphere.
pub fn sphere(_dims: UVec3, _scalar: ScalarType, _radius_fraction: f32) -> Result<Volume, VolumeError> {
    todo!()
}

/// A one-voxel-thick wall perpendicular to x.
pub fn wall(_dims: UVec3, _scalar: ScalarType, _x_index: u32) -> Result<Volume, VolumeError> {
    todo!()
}
