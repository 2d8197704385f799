//! The scene of the accuracy report's transition rows: a close-up of an edge-on junction
//! between low-res and hi-res bricks, where a seam is an image jump the measure can see.
//!
//! Why not the report's overview. Seen from outside at about one voxel per pixel, the two
//! transitions differ by less than a pixel: the smooth one ramps over half a hi-res voxel, and a
//! face crossed at an angle integrates into a continuous image either way (see
//! [`crate::metrics::seam`]). Measured on the 48 px overview: the seam measure of smooth and
//! discontinuous agreed to 0.1-0.4%. Here the face between the halves (world `x = 0`, the
//! volume's middle) holds the view direction, so every ray stays on one side of it and the
//! image jumps on its projected line (the image's middle column) by the whole difference
//! between the two reconstructions, and the view is magnified to several pixels per voxel so
//! that the smooth ramp spans pixels.

use crate::accuracy::Result;
use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, Level};
use mixvol::scene::Camera;
use mixvol::volume::{ScalarType, SyntheticField, Volume};

/// The junction close-up: volume, bricks, image and magnification.
#[derive(Clone, Debug, PartialEq)]
pub struct JunctionScene {
    /// Edge of the cubic Marschner-Lobb volume (f32: lavapipe filters 8-bit textures in 8-bit
    /// fixed point, which terraces a magnified view).
    pub volume_size: u32,
    /// Brick edge in voxels.
    pub brick_size: u32,
    /// Image width and height in pixels.
    pub size: u32,
    /// Voxels across the image (`size / width_voxels` pixels per voxel).
    pub width_voxels: f32,
}

impl JunctionScene {
    /// The quick scene: 64^3 in bricks of 8 (Marschner-Lobb has detail at the brick scale
    /// there), 64 x 64 pixels over 4 voxels, 16 pixels per voxel: the smooth ramp (half a
    /// voxel) spans 8 pixels. Measured (lavapipe): at 8 pixels per voxel the smooth rows' seam
    /// max is 0.019 unshaded (the ramp's curvature, 0.0045 at 16), against 0.025 discontinuous.
    pub fn quick() -> Self {
        Self {
            volume_size: 64,
            brick_size: 8,
            size: 64,
            width_voxels: 4.0,
        }
    }

    /// The full report's scene: the quick one at 128 x 128 pixels over 8 voxels (16 pixels per
    /// voxel, a taller strip of the junction).
    pub fn full() -> Self {
        Self {
            size: 128,
            width_voxels: 8.0,
            ..Self::quick()
        }
    }

    /// The volume: Marschner-Lobb, f32.
    pub fn volume(&self) -> Result<Volume> {
        Ok(SyntheticField::MarschnerLobb
            .generate(UVec3::splat(self.volume_size), ScalarType::F32)
            .map_err(mixvol::Error::from)?)
    }

    /// The levels: bricks below the middle in x low-res, the others hi-res (identical for both
    /// transitions).
    pub fn levels(grid: &BrickGrid) -> Vec<Level> {
        let half = grid.bricks_per_axis().x / 2;
        (0..grid.brick_count())
            .map(|i| {
                if grid.brick_coords(i).x >= half {
                    Level::Hi
                } else {
                    Level::Lo
                }
            })
            .collect()
    }

    /// The camera: orthographic, looking down -z at the junction plane `x = 0` from outside the
    /// volume, `width_voxels` voxels tall, centred at `y = 0.1` (off the field's axis, where the
    /// Marschner-Lobb rings cross the plane).
    pub fn camera(&self) -> Camera {
        Camera::orthographic(
            Vec3::new(0.0, 0.1, 2.0),
            Vec3::new(0.0, 0.1, 0.0),
            self.width_voxels / self.volume_size as f32,
        )
    }
}
