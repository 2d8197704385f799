//! World-space geometry of the brick grid and the view it is seen from.
//!
//! World space follows [`crate::scene`]: the volume box is centred at the origin with its longest
//! physical side 1 ([`volume_box`]). Brick `b` of size `n` spans the hi-res voxel positions
//! `[n*b, min(n*(b+1), dims)]` (partial bricks at the far faces are clipped to the volume, see
//! `docs/cache-layout.md`).

use super::error::LodError;
use crate::bricks::BrickGrid;
use crate::scene::{volume_box, Camera, ClipPlane, Projection};
use glam::{UVec3, Vec3};

/// A brick grid placed in world space: the grid plus the voxel spacing.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct BrickGeometry {
    grid: BrickGrid,
    spacing: Vec3,
    box_min: Vec3,
    box_max: Vec3,
    voxel: Vec3,
}

impl BrickGeometry {
    /// Places `grid` in world space for voxels of physical size `spacing` (positive, finite).
    pub fn new(grid: BrickGrid, spacing: Vec3) -> Result<Self, LodError> {
        if !(spacing.is_finite() && spacing.min_element() > 0.0) {
            return Err(LodError::InvalidSpacing {
                spacing: spacing.to_array(),
            });
        }
        let (box_min, box_max) = volume_box(grid.dims(), spacing);
        let voxel = (box_max - box_min) / grid.dims().as_vec3();
        Ok(Self {
            grid,
            spacing,
            box_min,
            box_max,
            voxel,
        })
    }

    /// The brick grid.
    pub fn grid(&self) -> &BrickGrid {
        &self.grid
    }

    /// The voxel spacing given to [`BrickGeometry::new`].
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// The world-space volume box `(min, max)`.
    pub fn volume_box(&self) -> (Vec3, Vec3) {
        (self.box_min, self.box_max)
    }

    /// World-space size of one hi-res voxel along each axis.
    pub fn voxel_size(&self) -> Vec3 {
        self.voxel
    }

    /// World-space box `(min, max)` of `brick` (clipped to the volume for partial bricks). The
    /// caller keeps `brick` inside the grid.
    pub fn brick_box(&self, brick: UVec3) -> (Vec3, Vec3) {
        let n = self.grid.brick_size();
        let dims = self.grid.dims();
        let lo = (brick * n).min(dims).as_vec3();
        let hi = ((brick + UVec3::ONE) * n).min(dims).as_vec3();
        (
            self.box_min + lo * self.voxel,
            self.box_min + hi * self.voxel,
        )
    }

    /// World-space box bounds of every brick slab per axis: `bounds[axis][b] = (lo, hi)`. Lets
    /// per-brick loops build boxes without divisions.
    pub(crate) fn axis_bounds(&self) -> [Vec<(f32, f32)>; 3] {
        let n = self.grid.brick_size();
        let dims = self.grid.dims();
        let per_axis = self.grid.bricks_per_axis();
        std::array::from_fn(|axis| {
            (0..per_axis[axis])
                .map(|b| {
                    let lo = (b * n).min(dims[axis]) as f32;
                    let hi = ((b + 1) * n).min(dims[axis]) as f32;
                    (
                        self.box_min[axis] + lo * self.voxel[axis],
                        self.box_min[axis] + hi * self.voxel[axis],
                    )
                })
                .collect()
        })
    }

    /// Calls `f(index, min, max)` for every brick in linear-index order (x fastest) with its
    /// world-space box.
    pub(crate) fn for_each_brick_box(&self, mut f: impl FnMut(usize, Vec3, Vec3)) {
        let [bx, by, bz] = self.axis_bounds();
        let mut index = 0;
        for &(z0, z1) in &bz {
            for &(y0, y1) in &by {
                for &(x0, x1) in &bx {
                    f(index, Vec3::new(x0, y0, z0), Vec3::new(x1, y1, z1));
                    index += 1;
                }
            }
        }
    }
}

/// How the view projects, with the constants the selection needs.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum ViewProjection {
    /// Pinhole camera.
    Perspective {
        /// Vertical field of view in radians.
        fov_y: f32,
        /// `tan(fov_y / 2)`.
        tan_half_y: f32,
    },
    /// Parallel projection.
    Orthographic {
        /// Visible height in world units.
        height: f32,
    },
}

/// A camera seen as the level-of-detail selection needs it: the view frame, the projection, the
/// image size in pixels and the six world-space frustum planes (inside: `n.p + d >= 0`).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct LodView {
    eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    projection: ViewProjection,
    image_width: u32,
    image_height: u32,
    frustum: [ClipPlane; 6],
}

impl LodView {
    /// Builds the view of `camera` rendered at `image_width` x `image_height` pixels. The view
    /// frame is the one [`crate::scene::RaycastParams`] uses (forward = target - eye, right =
    /// forward x up, up = right x forward), so the frustum matches the rays cast.
    pub fn new(camera: &Camera, image_width: u32, image_height: u32) -> Result<Self, LodError> {
        if image_width == 0 || image_height == 0 {
            return Err(LodError::ZeroViewport {
                width: image_width,
                height: image_height,
            });
        }
        let forward = camera.target - camera.eye;
        if !(camera.eye.is_finite() && forward.is_finite() && forward.length() > 1e-12) {
            return Err(LodError::DegenerateCamera {
                reason: "eye and target coincide or are not finite",
            });
        }
        let forward = forward.normalize();
        let right = forward.cross(camera.up);
        if !(right.is_finite() && right.length() >= 1e-6) {
            return Err(LodError::DegenerateCamera {
                reason: "up vector is parallel to the view direction or not finite",
            });
        }
        let right = right.normalize();
        let up = right.cross(forward);
        if !(camera.near >= 0.0 && camera.near < camera.far) {
            return Err(LodError::DegenerateCamera {
                reason: "near and far must satisfy 0 <= near < far",
            });
        }
        let aspect = image_width as f32 / image_height as f32;
        let (projection, side) = match camera.projection {
            Projection::Perspective { fov_y_degrees } => {
                if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
                    return Err(LodError::InvalidProjection {
                        reason: "perspective field of view must be in (0, 180) degrees",
                    });
                }
                let fov_y = fov_y_degrees.to_radians();
                let tan_half_y = (0.5 * fov_y).tan();
                let tan_half_x = tan_half_y * aspect;
                // Side planes through the eye, normals pointing inwards.
                let through_eye = |normal: Vec3| ClipPlane::new(normal, -normal.dot(camera.eye));
                let side = [
                    through_eye(tan_half_x * forward - right),
                    through_eye(tan_half_x * forward + right),
                    through_eye(tan_half_y * forward - up),
                    through_eye(tan_half_y * forward + up),
                ];
                (ViewProjection::Perspective { fov_y, tan_half_y }, side)
            }
            Projection::Orthographic { height } => {
                if !(height > 0.0 && height.is_finite()) {
                    return Err(LodError::InvalidProjection {
                        reason: "orthographic height must be positive and finite",
                    });
                }
                let half_h = 0.5 * height;
                let half_w = half_h * aspect;
                // Slab planes around the image-plane centre, normals pointing inwards.
                let side = [
                    ClipPlane::new(-right, half_w + right.dot(camera.eye)),
                    ClipPlane::new(right, half_w - right.dot(camera.eye)),
                    ClipPlane::new(-up, half_h + up.dot(camera.eye)),
                    ClipPlane::new(up, half_h - up.dot(camera.eye)),
                ];
                (ViewProjection::Orthographic { height }, side)
            }
        };
        let near = ClipPlane::new(forward, -forward.dot(camera.eye) - camera.near);
        let far = ClipPlane::new(-forward, camera.far + forward.dot(camera.eye));
        Ok(Self {
            eye: camera.eye,
            forward,
            right,
            up,
            projection,
            image_width,
            image_height,
            frustum: [side[0], side[1], side[2], side[3], near, far],
        })
    }

    /// Eye position (orthographic: the image-plane centre).
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// Unit view direction.
    pub fn forward(&self) -> Vec3 {
        self.forward
    }

    /// Unit right vector.
    pub fn right(&self) -> Vec3 {
        self.right
    }

    /// Unit up vector (orthogonal to forward and right).
    pub fn up(&self) -> Vec3 {
        self.up
    }

    /// The projection.
    pub fn projection(&self) -> ViewProjection {
        self.projection
    }

    /// Image width in pixels.
    pub fn image_width(&self) -> u32 {
        self.image_width
    }

    /// Image height in pixels.
    pub fn image_height(&self) -> u32 {
        self.image_height
    }

    /// The frustum planes: right, left, top, bottom, near, far; a point `p` is inside when
    /// `n.p + d >= 0` for all six.
    pub fn frustum_planes(&self) -> &[ClipPlane; 6] {
        &self.frustum
    }

    /// Pixels covered by one world unit seen at `distance` from the eye: `image_height / (2
    /// tan(fov_y / 2) * distance)` for perspective, `image_height / height` for orthographic.
    pub fn pixels_per_world_unit(&self, distance: f32) -> f32 {
        match self.projection {
            ViewProjection::Perspective { tan_half_y, .. } => {
                self.image_height as f32 / (2.0 * tan_half_y * distance)
            }
            ViewProjection::Orthographic { height } => self.image_height as f32 / height,
        }
    }

    /// True when the box `[min, max]` lies entirely outside one frustum plane (conservative: a
    /// box reported inside may still miss the frustum near its edges).
    pub fn box_outside_frustum(&self, min: Vec3, max: Vec3) -> bool {
        self.frustum.iter().any(|p| p.box_clipped(min, max))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn brick_boxes_tile_the_volume_box() {
        // 20 x 8 x 8 voxels, spacing 1 x 2 x 2: physical 20 x 16 x 16, longest side 1.
        let grid = BrickGrid::new(UVec3::new(20, 8, 8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::new(1.0, 2.0, 2.0)).unwrap();
        let (min, max) = geometry.volume_box();
        assert!((max - min - Vec3::new(1.0, 0.8, 0.8)).abs().max_element() < 1e-6);
        assert!(
            (geometry.voxel_size() - Vec3::new(0.05, 0.1, 0.1))
                .abs()
                .max_element()
                < 1e-6
        );
        // The partial brick at the far x face is clipped to the volume.
        let (lo, hi) = geometry.brick_box(UVec3::new(2, 0, 0));
        assert!((lo.x - 0.3).abs() < 1e-6 && (hi.x - 0.5).abs() < 1e-6);
        let mut seen = 0;
        geometry.for_each_brick_box(|index, lo, hi| {
            let (a, b) = geometry.brick_box(grid.brick_coords(index));
            assert_eq!((lo, hi), (a, b));
            seen += 1;
        });
        assert_eq!(seen, grid.brick_count());
        assert!(matches!(
            BrickGeometry::new(grid, Vec3::new(1.0, 0.0, 1.0)),
            Err(LodError::InvalidSpacing { .. })
        ));
    }

    #[test]
    fn frustum_planes_contain_what_the_camera_sees() {
        let camera = Camera::perspective(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 40.0);
        let view = LodView::new(&camera, 200, 100).unwrap();
        let inside = |p: Vec3| {
            view.frustum_planes()
                .iter()
                .all(|pl| pl.signed_distance(p) >= 0.0)
        };
        assert!(inside(Vec3::ZERO));
        assert!(!inside(Vec3::new(0.0, 0.0, 3.5)), "behind the eye");
        // Vertical half-angle 20 degrees: at distance 3, |y| <= 1.092; horizontal twice that.
        assert!(inside(Vec3::new(0.0, 1.05, 0.0)));
        assert!(!inside(Vec3::new(0.0, 1.15, 0.0)));
        assert!(inside(Vec3::new(2.1, 0.0, 0.0)));
        assert!(!inside(Vec3::new(2.3, 0.0, 0.0)));
        assert!(view.box_outside_frustum(Vec3::new(3.0, -0.1, -0.1), Vec3::new(3.2, 0.1, 0.1)));
        assert!(!view.box_outside_frustum(Vec3::splat(-0.1), Vec3::splat(0.1)));
        let ppu = view.pixels_per_world_unit(3.0);
        assert!((ppu - 100.0 / (2.0 * 20f32.to_radians().tan() * 3.0)).abs() < 1e-3);
    }

    #[test]
    fn unusable_views_are_typed_errors() {
        let camera = Camera::default_view();
        assert_eq!(
            LodView::new(&camera, 0, 10),
            Err(LodError::ZeroViewport {
                width: 0,
                height: 10
            })
        );
        let same = Camera::perspective(Vec3::ONE, Vec3::ONE, 30.0);
        assert!(matches!(
            LodView::new(&same, 8, 8),
            Err(LodError::DegenerateCamera { .. })
        ));
        let straight_down = Camera::perspective(Vec3::Y, Vec3::ZERO, 30.0);
        assert!(matches!(
            LodView::new(&straight_down, 8, 8),
            Err(LodError::DegenerateCamera { .. })
        ));
        let wide = Camera::perspective(Vec3::Z, Vec3::ZERO, 180.0);
        assert!(matches!(
            LodView::new(&wide, 8, 8),
            Err(LodError::InvalidProjection { .. })
        ));
        let flat = Camera::orthographic(Vec3::Z, Vec3::ZERO, 0.0);
        assert!(matches!(
            LodView::new(&flat, 8, 8),
            Err(LodError::InvalidProjection { .. })
        ));
    }
}
