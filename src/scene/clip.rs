//! World-space clip planes: part of what a scene asks for. The ray-caster cuts each ray's
//! interval to the kept side once (`reference::clip_ray` and `glsl/include/camera.glsl`),
//! and brick culling (`lod::cull_bricks`) removes bricks entirely on the clipped side.

use glam::Vec3;

/// The most clip planes [`ClipPlanes`] accepts (and the ray-caster's parameter block holds;
/// passed to GLSL as a macro).
pub const MAX_CLIP_PLANES: usize = 6;

/// Why a list of clip planes was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ClipPlaneError {
    /// More clip planes than the ray-caster supports were given.
    #[error("{count} clip planes given; at most {MAX_CLIP_PLANES} are supported")]
    TooMany {
        /// Number of planes given.
        count: usize,
    },
    /// A clip plane has a non-finite normal or offset.
    #[error("clip plane {index} has a non-finite normal or offset")]
    NonFinite {
        /// Position of the plane in the list given.
        index: usize,
    },
    /// A clip plane has a zero normal (it would keep everything or clip everything).
    #[error("clip plane {index} has a zero normal: give nx,ny,nz pointing to the kept side")]
    ZeroNormal {
        /// Position of the plane in the list given.
        index: usize,
    },
}

/// A world-space plane `normal . p + offset = 0`. Points with `normal . p + offset < 0` lie on
/// the clipped side; the normal need not be unit length.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ClipPlane {
    /// Plane normal, pointing towards the kept side.
    pub normal: Vec3,
    /// Plane offset `d` in `n . p + d`.
    pub offset: f32,
}

impl ClipPlane {
    /// The plane `normal . p + offset = 0`.
    pub const fn new(normal: Vec3, offset: f32) -> Self {
        Self { normal, offset }
    }

    /// `normal . p + offset`: negative on the clipped side.
    pub fn signed_distance(&self, p: Vec3) -> f32 {
        self.normal.dot(p) + self.offset
    }

    /// True when all eight corners of the box `[min, max]` lie on the clipped side
    /// (`n . p + d < 0`). Evaluated at the one corner that maximises `n . p` (the "positive
    /// vertex"): the other seven are then below it too.
    pub fn box_clipped(&self, min: Vec3, max: Vec3) -> bool {
        let n = self.normal;
        let corner = Vec3::new(
            if n.x >= 0.0 { max.x } else { min.x },
            if n.y >= 0.0 { max.y } else { min.y },
            if n.z >= 0.0 { max.z } else { min.z },
        );
        self.signed_distance(corner) < 0.0
    }
}

/// Up to [`MAX_CLIP_PLANES`] clip planes; a brick is culled when its box lies entirely on the
/// clipped side of any one of them.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct ClipPlanes {
    planes: [ClipPlane; MAX_CLIP_PLANES],
    count: usize,
}

impl Default for ClipPlane {
    fn default() -> Self {
        Self::new(Vec3::ZERO, 0.0)
    }
}

impl ClipPlanes {
    /// No clip planes: nothing is clipped.
    pub const NONE: Self = Self {
        planes: [ClipPlane::new(Vec3::ZERO, 0.0); MAX_CLIP_PLANES],
        count: 0,
    };

    /// Validates `planes`: at most [`MAX_CLIP_PLANES`], every normal and offset finite, no zero
    /// normal.
    pub fn new(planes: &[ClipPlane]) -> Result<Self, ClipPlaneError> {
        if planes.len() > MAX_CLIP_PLANES {
            return Err(ClipPlaneError::TooMany {
                count: planes.len(),
            });
        }
        let mut out = Self::NONE;
        for (index, plane) in planes.iter().enumerate() {
            if !(plane.normal.is_finite() && plane.offset.is_finite()) {
                return Err(ClipPlaneError::NonFinite { index });
            }
            if plane.normal == Vec3::ZERO {
                return Err(ClipPlaneError::ZeroNormal { index });
            }
            out.planes[index] = *plane;
        }
        out.count = planes.len();
        Ok(out)
    }

    /// The planes.
    pub fn planes(&self) -> &[ClipPlane] {
        &self.planes[..self.count]
    }

    /// The same planes with each normal replaced by `f(normal)` (offsets kept), for a map that
    /// keeps normals finite and non-zero (a rotation: [`crate::scene::ModelTransform`]).
    pub(crate) fn map_normals(&self, f: impl Fn(Vec3) -> Vec3) -> Self {
        let mut out = *self;
        for plane in &mut out.planes[..self.count] {
            plane.normal = f(plane.normal);
        }
        out
    }

    /// True when the box `[min, max]` lies entirely on the clipped side of some plane.
    pub fn box_clipped(&self, min: Vec3, max: Vec3) -> bool {
        self.planes().iter().any(|p| p.box_clipped(min, max))
    }
}
