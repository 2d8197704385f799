//! The volume's model transform: how the ray-caster's axis-aligned volume frame sits in world
//! space.
//!
//! # Convention
//!
//! The **volume frame** is the frame the ray-caster, the CPU reference and the residency planner
//! work in: the volume box centred at the origin, its x, y and z axes along the volume's index
//! axes, longest physical side 1 (see [`crate::scene`]). The **world** is the frame the host's
//! camera, clip planes and depth buffer are given in. A [`ModelTransform`] is a rotation
//! `world = R * volume` **about the volume box's centre** (the world origin stays the box centre;
//! the scale stays "longest side 1"): for a NIfTI file or a DICOM series, `R`'s columns are the
//! RAS+ patient directions of the reordered volume axes ([`crate::volume::VolumeMeta::directions`],
//! the residual oblique rotation left after the flips and permutations), so the world is patient
//! space with +x right, +y anterior, +z superior, translated so the volume's centre is at the
//! origin (the file's [`crate::volume::VolumeMeta::origin`] is not a translation of the render:
//! one volume is always drawn about its centre, so the default camera frames it however it is
//! rotated; its bounding sphere does not change).
//!
//! # How it is applied
//!
//! The GPU ray-caster stays in the volume frame: everything given in world space is mapped into
//! the volume frame by `R^-1 = R^T` before a frame's parameters and its level-of-detail view are
//! built ([`ModelTransform::volume_camera`]: eye, target and up; [`ModelTransform::volume_clip_planes`];
//! [`ModelTransform::clip_from_volume`] for a host depth buffer's `clip_from_world`). A rotation
//! preserves distances, so ray parameters, step lengths, near / far and opacities are those of
//! the world-space rays; shading uses a headlight (light along the ray), which is
//! camera-relative and needs no change. `embed::VolumePass::set_model_transform` (and
//! `renderer::Renderer::set_model_transform`) does all of this; the parameter block a
//! frame reports (`embed::RecordedFrame::params`) is in the volume frame, which is what
//! the CPU reference takes.

use super::{Camera, ClipPlanes, RenderSettings};
use crate::volume::VolumeMeta;
use glam::{DMat3, DVec3, Mat3, Mat4, Vec3};

/// Why direction vectors cannot be a model rotation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelTransformError {
    /// A component is NaN or infinite.
    #[error("direction vectors {directions:?} are not finite")]
    NonFinite {
        /// The directions given (columns: the world direction of volume axis x, y, z).
        directions: [[f64; 3]; 3],
    },
    /// The directions are (nearly) coplanar or left-handed: no rotation takes the volume axes to
    /// them (a mirror would be needed, which a model rotation is not).
    #[error(
        "direction vectors {directions:?} are degenerate or left-handed (determinant \
         {determinant:.3e} of the unit vectors): no rotation takes the volume axes onto them"
    )]
    NotARotation {
        /// The directions given.
        directions: [[f64; 3]; 3],
        /// The determinant of the column-normalised directions.
        determinant: f64,
    },
}

/// A volume's model transform: a rotation about the volume box's centre from the volume frame
/// into world space (see the module docs for the convention). Orthonormal with determinant 1 by
/// construction.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ModelTransform {
    world_from_volume: Mat3,
}

impl Default for ModelTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// Determinants of the unit directions below this are refused as degenerate.
const MIN_DETERMINANT: f64 = 1e-3;

impl ModelTransform {
    /// The rotation that places a loaded volume in its world frame when rendered
    /// (`renderer::Renderer::set_model_transform`; module docs for the convention): for
    /// NIfTI and DICOM, whose voxels were reordered to RAS+ ([`VolumeMeta::reorientation`]), the
    /// residual rotation in [`VolumeMeta::directions`] (identity for an axis-aligned file), so
    /// the volume renders in RAS+ patient space about its centre; identity for the other
    /// formats, which keep file order (their directions may hold mirrors, which a rotation
    /// cannot apply).
    ///
    /// Errors: residual directions that are degenerate or left-handed (a pathological affine):
    /// render axis-aligned then.
    pub fn of_volume(meta: &VolumeMeta) -> Result<Self, ModelTransformError> {
        if meta.reorientation.is_none() {
            return Ok(Self::IDENTITY);
        }
        Self::from_directions(meta.directions)
    }

    /// No rotation: the volume axes are the world axes (what every render did before model
    /// transforms, and what a volume without orientation gets).
    pub const IDENTITY: Self = Self {
        world_from_volume: Mat3::IDENTITY,
    };

    /// The rotation taking volume axis `i` to `directions[i]` (world-space column vectors, as
    /// [`crate::volume::VolumeMeta::directions`]). The vectors are normalised, and when they are
    /// not exactly orthogonal (a sheared affine, or rounding in a file) the nearest rotation is
    /// taken (the orthogonal factor of the polar decomposition; the shear is not rendered).
    /// Refused when not finite, degenerate or left-handed.
    pub fn from_directions(directions: [[f64; 3]; 3]) -> Result<Self, ModelTransformError> {
        if !directions.iter().flatten().all(|v| v.is_finite()) {
            return Err(ModelTransformError::NonFinite { directions });
        }
        let mut columns = [DVec3::ZERO; 3];
        for (c, d) in columns.iter_mut().zip(directions) {
            let v = DVec3::from_array(d);
            let n = v.length();
            if !(n > 0.0 && n.is_finite()) {
                return Err(ModelTransformError::NotARotation {
                    directions,
                    determinant: 0.0,
                });
            }
            *c = v / n;
        }
        let mut m = DMat3::from_cols(columns[0], columns[1], columns[2]);
        let determinant = m.determinant();
        if determinant.is_nan() || determinant <= MIN_DETERMINANT {
            return Err(ModelTransformError::NotARotation {
                directions,
                determinant,
            });
        }
        // Newton's iteration for the orthogonal polar factor: X <- (X + X^-T) / 2, quadratic
        // convergence for any invertible start, determinant sign kept.
        for _ in 0..64 {
            let next = (m + m.inverse().transpose()) * 0.5;
            let change = (next - m)
                .to_cols_array()
                .iter()
                .map(|v| v.abs())
                .sum::<f64>();
            m = next;
            if change < 1e-15 {
                break;
            }
        }
        Ok(Self {
            world_from_volume: m.as_mat3(),
        })
    }

    /// The rotation `R` (columns: the world directions of the volume axes).
    pub fn world_from_volume(&self) -> Mat3 {
        self.world_from_volume
    }

    /// The model matrix (4x4, no translation: the rotation is about the box centre, the origin
    /// of both frames).
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_mat3(self.world_from_volume)
    }

    /// True for the identity (nothing to transform).
    pub fn is_identity(&self) -> bool {
        self.world_from_volume == Mat3::IDENTITY
    }

    /// The rotation angle in degrees (about its own axis; 0 for the identity).
    pub fn angle_degrees(&self) -> f32 {
        let m = self.world_from_volume;
        let cos = 0.5 * (m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0);
        cos.clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// A world-space point in the volume frame (`R^T p`).
    pub fn volume_point(&self, world: Vec3) -> Vec3 {
        self.world_from_volume.transpose() * world
    }

    /// A volume-frame point in world space (`R p`).
    pub fn world_point(&self, volume: Vec3) -> Vec3 {
        self.world_from_volume * volume
    }

    /// A world-space camera as the volume frame sees it: eye, target and up rotated by `R^T`;
    /// projection, near and far unchanged (a rotation keeps distances and angles).
    pub fn volume_camera(&self, camera: &Camera) -> Camera {
        Camera {
            eye: self.volume_point(camera.eye),
            target: self.volume_point(camera.target),
            up: self.volume_point(camera.up),
            ..*camera
        }
    }

    /// World-space clip planes in the volume frame: `n . (R p) + d = (R^T n) . p + d`, so each
    /// normal is rotated by `R^T` and each offset kept.
    pub fn volume_clip_planes(&self, planes: &ClipPlanes) -> ClipPlanes {
        let r_t = self.world_from_volume.transpose();
        planes.map_normals(|n| r_t * n)
    }

    /// `settings` with its world-space parts (the clip planes) in the volume frame.
    pub fn volume_settings(&self, settings: &RenderSettings) -> RenderSettings {
        RenderSettings {
            clip_planes: self.volume_clip_planes(&settings.clip_planes),
            ..*settings
        }
    }

    /// The host's `clip_from_world` (its projection times its view) followed after the model
    /// matrix: `clip_from_world * M`, which takes volume-frame points to the host's clip space,
    /// where its depth buffer was written.
    pub fn clip_from_volume(&self, clip_from_world: Mat4) -> Mat4 {
        clip_from_world * self.matrix()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ClipPlane, Projection};

    const EPS: f32 = 1e-6;

    /// Rotation by `deg` degrees about z, written out (not through glam).
    fn rz(deg: f64) -> [[f64; 3]; 3] {
        let (s, c) = deg.to_radians().sin_cos();
        [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]
    }

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < EPS
    }

    #[test]
    fn thirty_degrees_about_z_maps_world_points_to_the_expected_volume_points() {
        let m = ModelTransform::from_directions(rz(30.0)).unwrap();
        let (s, c) = (0.5f32, 0.75f32.sqrt());
        // The volume's x axis points to world (cos 30, sin 30, 0): that world point is volume
        // (1, 0, 0), and world +x is volume (cos 30, -sin 30, 0).
        assert!(close(m.volume_point(Vec3::new(c, s, 0.0)), Vec3::X));
        assert!(close(m.volume_point(Vec3::X), Vec3::new(c, -s, 0.0)));
        assert!(close(m.volume_point(Vec3::Y), Vec3::new(s, c, 0.0)));
        assert!(close(m.volume_point(Vec3::new(0.2, -0.3, 0.7)), {
            Vec3::new(0.2 * c - 0.3 * s, -0.2 * s - 0.3 * c, 0.7)
        }));
        assert!(close(m.world_point(Vec3::Y), Vec3::new(-s, c, 0.0)));
        assert!((m.angle_degrees() - 30.0).abs() < 1e-3);

        let camera = Camera {
            up: Vec3::Z,
            ..Camera::perspective(Vec3::new(2.0, 0.0, 0.5), Vec3::new(0.1, 0.0, 0.0), 35.0)
        };
        let v = m.volume_camera(&camera);
        assert!(close(v.eye, Vec3::new(2.0 * c, -2.0 * s, 0.5)));
        assert!(close(v.target, Vec3::new(0.1 * c, -0.1 * s, 0.0)));
        assert!(close(v.up, Vec3::Z));
        assert_eq!(
            v.projection,
            Projection::Perspective {
                fov_y_degrees: 35.0
            }
        );
        assert_eq!((v.near, v.far), (camera.near, camera.far));

        // A plane keeping world x >= 0.1 keeps the volume points whose world image has x >= 0.1.
        let planes = ClipPlanes::new(&[ClipPlane::new(Vec3::X, -0.1)]).unwrap();
        let p = m.volume_clip_planes(&planes).planes()[0];
        assert!(close(p.normal, Vec3::new(c, -s, 0.0)));
        assert_eq!(p.offset, -0.1);
        for q in [Vec3::new(0.3, 0.2, 0.1), Vec3::new(-0.2, 0.4, 0.0)] {
            let world = planes.planes()[0].signed_distance(m.world_point(q));
            assert!((p.signed_distance(q) - world).abs() < EPS);
        }

        // The host's clip transform of a volume point is that of its world image.
        let clip_from_world = Mat4::perspective_rh(0.6, 1.0, 0.1, 10.0)
            * Mat4::look_at_rh(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y);
        let q = Vec3::new(0.25, -0.1, 0.3);
        let a = m.clip_from_volume(clip_from_world) * q.extend(1.0);
        let b = clip_from_world * m.world_point(q).extend(1.0);
        assert!((a - b).abs().max_element() < EPS);
    }

    #[test]
    fn directions_are_normalised_and_orthogonalised_and_mirrors_refused() {
        // Scaled columns with a small shear: the nearest rotation of the unit columns, which for
        // a pure scaling of a rotation is that rotation.
        let mut d = rz(20.0);
        d[0] = d[0].map(|v| v * 3.0);
        let m = ModelTransform::from_directions(d).unwrap();
        let expected = ModelTransform::from_directions(rz(20.0)).unwrap();
        let diff = (m.world_from_volume() - expected.world_from_volume()).abs();
        assert!(diff.to_cols_array().iter().all(|v| *v < EPS));
        let mut sheared = rz(0.0);
        sheared[1] = [0.05, 1.0, 0.0];
        let r = ModelTransform::from_directions(sheared)
            .unwrap()
            .world_from_volume();
        let rtr = r.transpose() * r;
        assert!((rtr - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|v| v.abs() < EPS));
        assert!((r.determinant() - 1.0).abs() < EPS);
        assert!(ModelTransform::from_directions(rz(0.0))
            .unwrap()
            .is_identity());

        let mut mirrored = rz(10.0);
        mirrored[2] = [0.0, 0.0, -1.0];
        assert!(matches!(
            ModelTransform::from_directions(mirrored),
            Err(ModelTransformError::NotARotation { .. })
        ));
        let mut flat = rz(0.0);
        flat[2] = [1.0, 0.0, 0.0];
        assert!(matches!(
            ModelTransform::from_directions(flat),
            Err(ModelTransformError::NotARotation { .. })
        ));
        let mut nan = rz(0.0);
        nan[0][1] = f64::NAN;
        assert!(matches!(
            ModelTransform::from_directions(nan),
            Err(ModelTransformError::NonFinite { .. })
        ));
    }
}
