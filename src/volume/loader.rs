//! Raw file loader. (Being written.)
use super::{ScalarType, Volume, VolumeError};
use glam::{UVec3, Vec3};
use std::path::Path;

/// Describes a headerless raw file.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RawDescriptor {
    /// Voxel counts.
    pub dims: UVec3,
    /// Scalar type of the voxels.
    pub scalar: ScalarType,
    /// Voxel spacing.
    pub spacing: Vec3,
    /// Bytes to skip at the start of the file.
    pub header_bytes: u64,
    /// True when multi-byte values are big-endian.
    pub big_endian: bool,
}

/// Loads a raw volume file.
pub fn load_raw(_path: &Path, _desc: &RawDescriptor) -> Result<Volume, VolumeError> {
    todo!()
}
