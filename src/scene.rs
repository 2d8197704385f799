//! What to draw: the camera, render settings, and the per-frame parameter block that the GPU and
//! the CPU reference both consume ([`RaycastParams`]).
//!
//! World space: the volume box is centred at the origin and scaled so that its longest physical
//! side (dims * spacing) is 1. Anisotropic spacing therefore renders with the right aspect.

use crate::error::{Error, Result};
use crate::volume::Volume;
use glam::{Mat4, UVec3, Vec3, Vec4};

/// Smallest magnitude a ray direction component is given in the slab test (`RAY_DIR_EPSILON` in
/// GLSL): keeps axis-parallel rays finite.
pub const RAY_DIR_EPSILON: f32 = 1e-20;

/// Default opacity at which a ray stops (early ray termination).
pub const DEFAULT_EARLY_TERMINATION: f32 = 0.99;

/// How the camera projects.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Projection {
    /// Pinhole camera with a vertical field of view in degrees.
    Perspective {
        /// Vertical field of view, degrees, in (0, 180).
        fov_y_degrees: f32,
    },
    /// Parallel projection showing `height` world units vertically.
    Orthographic {
        /// Visible height in world units.
        height: f32,
    },
}

/// A look-at camera in world space.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (for orthographic: the centre of the image plane).
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Approximate up direction.
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
    /// Smallest ray parameter t rendered (distance from the eye along a unit ray).
    pub near: f32,
    /// Largest ray parameter t rendered.
    pub far: f32,
}

impl Camera {
    /// A perspective camera at `eye` looking at `target` with +y up.
    pub fn perspective(eye: Vec3, target: Vec3, fov_y_degrees: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y_degrees },
            near: 0.0,
            far: 1.0e6,
        }
    }

    /// An orthographic camera at `eye` looking at `target` with +y up, `height` world units tall.
    pub fn orthographic(eye: Vec3, target: Vec3, height: f32) -> Self {
        Self {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Orthographic { height },
            near: 0.0,
            far: 1.0e6,
        }
    }

    /// The default view: perspective, 30 degrees, from the front-right-top at distance 2.2.
    pub fn default_view() -> Self {
        Self::perspective(Vec3::new(1.2, 0.9, 1.6), Vec3::ZERO, 35.0)
    }
}

/// Settings for one render.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per voxel along a ray (step = smallest voxel side / this).
    pub samples_per_voxel: f32,
    /// A ray stops once its accumulated opacity reaches this.
    pub early_termination: f32,
    /// Normalised value mapped to TF position 0 and 1; `None` uses [0, 1] for integer volumes and
    /// the value range for float volumes (widened to `[min(v, 0), max(v, 1)]` when the volume is
    /// constant, so it is classified like an integer volume of the same value). A window that
    /// cannot be classified in f32 (width outside 2^-128..2^126, or float data below 2^-110 in
    /// magnitude) is an `InvalidInput` error, never a black frame.
    pub value_window: Option<(f32, f32)>,
    /// Upper bound on samples along one ray.
    pub max_steps: u32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            samples_per_voxel: 1.0,
            early_termination: DEFAULT_EARLY_TERMINATION,
            value_window: None,
            max_steps: 16384,
        }
    }
}

/// The per-frame parameter block, std140-compatible: vec4 fields and one mat4 (224 bytes). Mirrors `RaycastParams`
/// in `glsl/include/params.glsl`.
#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RaycastParams {
    /// xyz: eye or image-plane centre; w: 0 perspective, 1 orthographic.
    pub eye: Vec4,
    /// xyz: unit view direction; w: near.
    pub forward: Vec4,
    /// xyz: right scaled to half the image width at unit distance; w: far.
    pub right: Vec4,
    /// xyz: up scaled to half the image height at unit distance.
    pub up: Vec4,
    /// xyz: volume box minimum; w: step length.
    pub box_min: Vec4,
    /// xyz: volume box maximum; w: reference length d0 (one voxel).
    pub box_max: Vec4,
    /// x: window low; y: 1 / window range; z: early-termination alpha; w: max steps.
    pub tf_window: Vec4,
    /// x: width, y: height in pixels.
    pub viewport: Vec4,
    /// xyz: volume dimensions in voxels; w: brick size n (mixed resolution).
    pub volume_dims: Vec4,
    /// xyz: 1 / cache extent in texels (mixed resolution); w: unused.
    pub cache_extent_inv: Vec4,
    /// Inverse of the host's `clip_from_world` (used only when rays stop at a host depth buffer).
    pub world_from_clip: Mat4,
}

const _: () = assert!(std::mem::size_of::<RaycastParams>() == 224);

/// The world-space box of a volume: centred, longest physical side 1.
pub fn volume_box(dims: UVec3, spacing: Vec3) -> (Vec3, Vec3) {
    let extent = dims.as_vec3() * spacing;
    let size = extent / extent.max_element();
    (-0.5 * size, 0.5 * size)
}

impl RaycastParams {
    /// The same block set up for a brick cache of `cache_extent` texels and bricks of `brick_size`.
    pub fn with_cache(mut self, brick_size: u32, cache_extent: UVec3) -> Self {
        self.volume_dims.w = brick_size as f32;
        self.cache_extent_inv = (Vec3::ONE / cache_extent.as_vec3()).extend(0.0);
        self
    }

    /// Builds the parameter block for `volume` seen by `camera` at `width` x `height`.
    pub fn new(
        volume: &Volume,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        Self::for_dims(
            volume.dims(),
            volume.spacing(),
            volume.value_range(),
            volume.scalar_type() == crate::volume::ScalarType::F32,
            camera,
            settings,
            width,
            height,
        )
    }

    /// As [`RaycastParams::new`] from the volume's dims, spacing and value range.
    #[allow(clippy::too_many_arguments)] // reason: mirrors the fields it fills, all distinct.
    pub fn for_dims(
        dims: UVec3,
        spacing: Vec3,
        value_range: (f32, f32),
        is_float: bool,
        camera: &Camera,
        settings: &RenderSettings,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::InvalidInput(format!(
                "viewport {width}x{height} has a zero side"
            )));
        }
        let forward = camera.target - camera.eye;
        if !(forward.is_finite() && forward.length() > 1e-12) {
            return Err(Error::InvalidInput(
                "camera eye and target coincide (or are not finite)".into(),
            ));
        }
        let forward = forward.normalize();
        let right = forward.cross(camera.up);
        if right.length() < 1e-6 {
            return Err(Error::InvalidInput(
                "camera up vector is parallel to the view direction".into(),
            ));
        }
        let right = right.normalize();
        let up = right.cross(forward);
        let aspect = width as f32 / height as f32;
        let (half_h, ortho) = match camera.projection {
            Projection::Perspective { fov_y_degrees } => {
                if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
                    return Err(Error::InvalidInput(format!(
                        "perspective field of view {fov_y_degrees} must be in (0, 180) degrees"
                    )));
                }
                ((fov_y_degrees.to_radians() * 0.5).tan(), 0.0)
            }
            Projection::Orthographic { height } => {
                if !(height > 0.0 && height.is_finite()) {
                    return Err(Error::InvalidInput(format!(
                        "orthographic height {height} must be positive"
                    )));
                }
                (0.5 * height, 1.0)
            }
        };
        if !(settings.samples_per_voxel > 0.0 && settings.samples_per_voxel.is_finite()) {
            return Err(Error::InvalidInput(format!(
                "samples per voxel {} must be positive",
                settings.samples_per_voxel
            )));
        }
        if !(camera.near >= 0.0 && camera.near < camera.far) {
            return Err(Error::InvalidInput(format!(
                "near {} and far {} must satisfy 0 <= near < far",
                camera.near, camera.far
            )));
        }
        let (lo, hi) = match settings.value_window {
            Some(window) => window,
            // A constant float volume has an empty range: classify it as an integer volume of
            // the same value would be, inside [min(lo, 0), max(hi, 1)], not at TF position 0.
            None if is_float && value_range.1 <= value_range.0 => {
                (value_range.0.min(0.0), value_range.1.max(1.0))
            }
            None if is_float => value_range,
            None => (0.0, 1.0),
        };
        // `1 / (hi - lo)` must be a normal f32: GPUs flush subnormal uniforms to zero (every
        // sample would classify at TF position 0) and an infinite one makes `(v - lo) * inv` NaN;
        // data below 2^-110 in magnitude is flushed by GPU texture filtering.
        let range = f64::from(hi) - f64::from(lo);
        let inv_range = if range > 0.0 {
            (1.0 / range) as f32
        } else {
            0.0
        };
        let magnitude = value_range.0.abs().max(value_range.1.abs());
        if !(lo.is_finite() && hi.is_finite())
            || (range > 0.0 && !(inv_range.is_normal() && (range as f32).is_finite()))
            || (is_float
                && settings.value_window.is_none()
                && magnitude < 2f32.powi(-110)
                && magnitude > 0.0)
        {
            return Err(Error::InvalidInput(format!(
                "value window [{lo:e}, {hi:e}] (value range [{:e}, {:e}]) cannot be classified \
                 in f32: its width must be between 2^-128 and 2^126 and the data above 2^-110 in \
                 magnitude; pass RenderSettings::value_window or rescale the volume",
                value_range.0, value_range.1
            )));
        }
        let (box_min, box_max) = volume_box(dims, spacing);
        let voxel = ((box_max - box_min) / dims.as_vec3()).min_element();
        let step = voxel / settings.samples_per_voxel;
        Ok(Self {
            eye: camera.eye.extend(ortho),
            forward: forward.extend(camera.near),
            right: (right * half_h * aspect).extend(camera.far),
            up: (up * half_h).extend(0.0),
            box_min: box_min.extend(step),
            box_max: box_max.extend(voxel),
            tf_window: Vec4::new(
                lo,
                inv_range,
                settings.early_termination,
                settings.max_steps as f32,
            ),
            viewport: Vec4::new(width as f32, height as f32, 0.0, 0.0),
            volume_dims: dims.as_vec3().extend(0.0),
            cache_extent_inv: Vec4::ZERO,
            world_from_clip: Mat4::IDENTITY,
        })
    }
}
