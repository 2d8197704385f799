//! Pre-classified RGBA volumes: colour and opacity stored per voxel instead of a scalar and a
//! transfer function. The ray-caster interpolates them in the form the frame's
//! [`SamplingModel`] asks for (Kraus et al.): opacity-weighted colour and opacity of one voxel
//! length, or extinction-weighted colour and extinction per voxel length.

use super::{checked_voxel_count, VolumeError};
use crate::optics::{opacity_to_extinction, SamplingModel};
use glam::{UVec3, Vec3, Vec4};

/// A pre-classified volume: per voxel an emitted colour (rgb, not premultiplied) and the
/// opacity of one voxel length (a), all in [0, 1]. Voxel order as [`super::Volume`] (x fastest).
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaVolume {
    dims: UVec3,
    spacing: Vec3,
    voxels: Vec<Vec4>,
}

impl RgbaVolume {
    /// Checks dims against the voxel count, spacing, and every component in [0, 1].
    pub fn new(dims: UVec3, spacing: Vec3, voxels: Vec<Vec4>) -> Result<Self, VolumeError> {
        let expected = checked_voxel_count(dims)?;
        if !(spacing.is_finite() && spacing.min_element() > 0.0) {
            return Err(VolumeError::InvalidSpacing {
                spacing: spacing.to_array(),
            });
        }
        if voxels.len() != expected {
            return Err(VolumeError::VoxelCountMismatch {
                dims: dims.to_array(),
                expected,
                actual: voxels.len(),
            });
        }
        if let Some(index) = voxels
            .iter()
            .position(|v| !(v.is_finite() && v.min_element() >= 0.0 && v.max_element() <= 1.0))
        {
            let x = (index % dims.x as usize) as u32;
            let y = ((index / dims.x as usize) % dims.y as usize) as u32;
            let z = (index / (dims.x as usize * dims.y as usize)) as u32;
            let v = voxels[index];
            // The first component outside [0, 1] (or not finite) is reported.
            let value = v
                .to_array()
                .into_iter()
                .find(|c| !(c.is_finite() && (0.0..=1.0).contains(c)))
                .unwrap_or(f32::NAN);
            return Err(VolumeError::NonFinite {
                file: None,
                index,
                x,
                y,
                z,
                value,
            });
        }
        Ok(Self {
            dims,
            spacing,
            voxels,
        })
    }

    /// Dimensions in voxels.
    pub fn dims(&self) -> UVec3 {
        self.dims
    }

    /// Voxel spacing.
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// The voxels: colour and opacity of one voxel length.
    pub fn voxels(&self) -> &[Vec4] {
        &self.voxels
    }

    /// The voxels as the GPU texture holds them for `model`: `(colour * opacity, opacity)` or
    /// `(colour * tau, tau)` with `tau = -ln(1 - opacity)` per voxel length (capped at
    /// [`crate::optics::MAX_EXTINCTION`]).
    pub fn weighted(&self, model: SamplingModel) -> Vec<Vec4> {
        self.voxels
            .iter()
            .map(|v| {
                let coefficient = match model {
                    SamplingModel::Opacity => v.w,
                    SamplingModel::Extinction => opacity_to_extinction(v.w),
                };
                (v.truncate() * coefficient).extend(coefficient)
            })
            .collect()
    }
}
