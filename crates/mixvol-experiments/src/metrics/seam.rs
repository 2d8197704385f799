//! The seam measure: how much the image jumps across the projected brick boundaries where the
//! resolution level changes, beyond what the full-resolution frame jumps there.
//!
//! The cache model says which bricks are at which level ([`Level`] per brick, linear index as in
//! [`BrickGrid`]). Every face between a [`Level::Hi`] and a [`Level::Lo`] brick is projected into
//! the image with the frame's camera (the view frame the ray-caster and the LOD selection share,
//! [`LodView`]); the four edges of each projected face are the *seam lines*.
//!
//! Where the image jumps. A discontinuous reconstruction puts a jump in the field on the face.
//! A ray that crosses the face transversally integrates over it, so in the continuum the image
//! stays continuous there (only its derivative breaks); what it does jump at is a face seen edge
//! on, a face whose plane holds the eye (or, orthographic, the view direction): rays on one side
//! of its projected line see only the low-res brick, rays on the other only the hi-res one. That
//! face projects to a line made of its edges, so the seam lines lie on it. Faces seen at an
//! angle leave only sampling artefacts (a sample crossing the face) along curves inside their
//! projection, at the scale of a sample; the accuracy report therefore measures transitions on a
//! close-up of an edge-on junction (`crate::junction`).
//!
//! What a jump is. A C0 reconstruction (the smooth transition) still bends the image at the line:
//! it ramps from the low-res to the hi-res value over half a hi-res voxel, so the plain difference
//! of two samples either side of the line is as large as the discontinuous jump once the ramp
//! spans less than their distance, and a kink of a steep feature gives large differences too.
//! The measure therefore extrapolates each side linearly to the line from two samples (bilinear,
//! at [`SIDE_OFFSET`] and `SIDE_OFFSET + 1` pixels from it, every [`LINE_SPACING`] pixels along
//! it) and takes the largest RGBA difference of the two extrapolations: a step of height `h`
//! scores `h`, a kink (continuous, two slopes) scores 0, whatever its slopes. `J` is that jump in
//! the frame, `J_ref` in the full-resolution frame of the same settings; a seam is a jump that
//! frame does not have, so the measure is the excess `max(0, J - J_ref)`: its largest and its
//! mean value over the samples; the plain jumps of both frames are kept beside it.
//!
//! Faces with a corner behind the eye are skipped (the report's cameras look at the volume from
//! outside, so none is), and so are samples with a side outside the image.

use super::{Frame, MetricError};
use glam::{UVec3, Vec2, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, Level};
use mixvol::lod::{BrickGeometry, LodView, ViewProjection};
use mixvol::scene::Camera;

/// The seam measure of one frame.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct SeamMeasure {
    /// Hi/Lo brick faces projected.
    pub faces: usize,
    /// Samples taken along the seam lines (pairs of image positions).
    pub samples: usize,
    /// Largest excess jump `max(0, J - J_ref)` over the samples, in [0, 1].
    pub max_excess: f64,
    /// Mean excess jump over the samples.
    pub mean_excess: f64,
    /// Largest jump `J` of the frame over the samples.
    pub max_jump: f64,
    /// Largest jump `J_ref` of the reference over the samples.
    pub reference_max_jump: f64,
    /// Mean jump of the frame over the samples.
    pub mean_jump: f64,
    /// Mean jump of the reference over the samples.
    pub reference_mean_jump: f64,
}

/// The image position (pixels, origin top-left, pixel centres at `i + 0.5`) of world point `p`,
/// or `None` behind the eye.
pub fn project(view: &LodView, p: Vec3) -> Option<Vec2> {
    let v = p - view.eye();
    let z = v.dot(view.forward());
    let aspect = view.image_width() as f32 / view.image_height() as f32;
    let (half_x, half_y) = match view.projection() {
        ViewProjection::Perspective { tan_half_y, .. } => {
            if z <= 1e-6 {
                return None;
            }
            (z * tan_half_y * aspect, z * tan_half_y)
        }
        ViewProjection::Orthographic { height } => (0.5 * height * aspect, 0.5 * height),
    };
    let ndc = Vec2::new(v.dot(view.right()) / half_x, v.dot(view.up()) / half_y);
    Some(Vec2::new(
        (ndc.x + 1.0) * 0.5 * view.image_width() as f32,
        (1.0 - ndc.y) * 0.5 * view.image_height() as f32,
    ))
}

/// The world-space corners of every face between a Hi and a Lo brick, in order around the face.
pub fn level_change_faces(
    geometry: &BrickGeometry,
    levels: &[Level],
) -> Result<Vec<[Vec3; 4]>, MetricError> {
    let grid: &BrickGrid = geometry.grid();
    if levels.len() != grid.brick_count() {
        return Err(MetricError::LevelCount {
            expected: grid.brick_count(),
            got: levels.len(),
        });
    }
    let mut faces = Vec::new();
    for brick in grid.bricks() {
        let level = levels[grid.linear_index(brick)];
        for axis in 0..3 {
            let next = brick + UVec3::AXES[axis];
            if !grid.contains(next) {
                continue;
            }
            let other = levels[grid.linear_index(next)];
            if !matches!(
                (level, other),
                (Level::Hi, Level::Lo) | (Level::Lo, Level::Hi)
            ) {
                continue;
            }
            let (min, max) = geometry.brick_box(brick);
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |a: f32, b: f32| {
                let mut c = Vec3::ZERO;
                c[axis] = max[axis];
                c[u] = a;
                c[v] = b;
                c
            };
            faces.push([
                corner(min[u], min[v]),
                corner(max[u], min[v]),
                corner(max[u], max[v]),
                corner(min[u], max[v]),
            ]);
        }
    }
    Ok(faces)
}

/// Pixels between the seam line and the nearer sample on each side (the farther one is a pixel
/// beyond): half a pixel, so the two nearer samples are neighbouring pixel centres when the line
/// runs between pixels.
pub const SIDE_OFFSET: f32 = 0.5;

/// Distance in pixels between samples along a seam line.
pub const LINE_SPACING: f32 = 0.5;

/// The projected seam lines of one frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SeamLines {
    /// Hi/Lo faces projected.
    pub faces: usize,
    /// Image-space segments (pixels, origin top-left): the edges of the projected faces.
    pub segments: Vec<(Vec2, Vec2)>,
}

/// The seam lines of a `width` x `height` frame of `camera` for the brick `levels`.
pub fn seam_lines(
    geometry: &BrickGeometry,
    levels: &[Level],
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<SeamLines, MetricError> {
    let view = LodView::new(camera, width, height)?;
    let mut lines = SeamLines::default();
    for face in level_change_faces(geometry, levels)? {
        let Some(quad) = face
            .iter()
            .map(|&c| project(&view, c))
            .collect::<Option<Vec<Vec2>>>()
        else {
            continue;
        };
        lines.faces += 1;
        lines
            .segments
            .extend((0..4).map(|i| (quad[i], quad[(i + 1) % 4])));
    }
    Ok(lines)
}

/// The frame at image position `p` (pixels, centres at `i + 0.5`), bilinear; `None` outside
/// the pixel centres.
fn bilinear(frame: &Frame<'_>, p: Vec2) -> Option<Vec4> {
    let q = p - Vec2::splat(0.5);
    let (x0, y0) = (q.x.floor(), q.y.floor());
    if x0 < 0.0
        || y0 < 0.0
        || x0 + 1.0 > (frame.width - 1) as f32
        || y0 + 1.0 > (frame.height - 1) as f32
    {
        return None;
    }
    let (fx, fy) = (q.x - x0, q.y - y0);
    let (x, y) = (x0 as u32, y0 as u32);
    let top = frame.at(x, y).lerp(frame.at(x + 1, y), fx);
    let bottom = frame.at(x, y + 1).lerp(frame.at(x + 1, y + 1), fx);
    Some(top.lerp(bottom, fy))
}

/// The seam measure of `image` against `full_resolution` along `lines` (from
/// [`seam_lines`]). All zero without lines.
pub fn seam_measure(
    image: &Frame<'_>,
    full_resolution: &Frame<'_>,
    lines: &SeamLines,
) -> Result<SeamMeasure, MetricError> {
    image.check_same_size(full_resolution)?;
    let mut m = SeamMeasure {
        faces: lines.faces,
        ..SeamMeasure::default()
    };
    if image.width < 2 || image.height < 2 {
        return Ok(m);
    }
    // The difference of the two sides' linear extrapolations to the line, `normal` one pixel
    // long: near sample plus half the step from the far one, on either side.
    let jump = |f: &Frame<'_>, p: Vec2, normal: Vec2| -> Option<f64> {
        let side = |s: f32| -> Option<Vec4> {
            let near = bilinear(f, p + normal * (s * SIDE_OFFSET))?;
            let far = bilinear(f, p + normal * (s * (SIDE_OFFSET + 1.0)))?;
            Some(near + (near - far) * SIDE_OFFSET)
        };
        Some(f64::from((side(1.0)? - side(-1.0)?).abs().max_element()))
    };
    let (mut excess_sum, mut jump_sum, mut ref_sum) = (0.0, 0.0, 0.0);
    for &(a, b) in &lines.segments {
        let along = b - a;
        let length = along.length();
        if !(length.is_finite() && length > 1e-6) {
            continue;
        }
        let normal = along.perp() / length;
        let steps = (length / LINE_SPACING).ceil() as usize;
        for k in 0..=steps {
            let p = a + along * (k as f32 / steps as f32);
            let (Some(j), Some(r)) = (jump(image, p, normal), jump(full_resolution, p, normal))
            else {
                continue;
            };
            let e = (j - r).max(0.0);
            m.samples += 1;
            m.max_excess = m.max_excess.max(e);
            m.max_jump = m.max_jump.max(j);
            m.reference_max_jump = m.reference_max_jump.max(r);
            excess_sum += e;
            jump_sum += j;
            ref_sum += r;
        }
    }
    if m.samples > 0 {
        let n = m.samples as f64;
        m.mean_excess = excess_sum / n;
        m.mean_jump = jump_sum / n;
        m.reference_mean_jump = ref_sum / n;
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

    #[test]
    fn projection_matches_the_view_centre_and_faces_follow_levels() {
        let camera = Camera::perspective(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, 40.0);
        let view = LodView::new(&camera, 40, 20).unwrap();
        let c = project(&view, Vec3::ZERO).unwrap();
        assert!((c - Vec2::new(20.0, 10.0)).length() < 1e-4, "{c}");
        // +x is to the right, +y up (smaller row).
        let p = project(&view, Vec3::new(0.1, 0.1, 0.0)).unwrap();
        assert!(p.x > 20.0 && p.y < 10.0, "{p}");
        assert!(project(&view, Vec3::new(0.0, 0.0, 4.0)).is_none());

        let grid = BrickGrid::new(UVec3::new(16, 8, 8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let faces = level_change_faces(&geometry, &[Level::Hi, Level::Lo]).unwrap();
        assert_eq!(faces.len(), 1);
        assert!(faces[0].iter().all(|c| c.x.abs() < 1e-6));
        assert!(level_change_faces(&geometry, &[Level::Hi, Level::Hi])
            .unwrap()
            .is_empty());
        assert!(level_change_faces(&geometry, &[Level::Hi, Level::Absent])
            .unwrap()
            .is_empty());
        assert!(level_change_faces(&geometry, &[Level::Hi]).is_err());
        // Seen from the side, the face x = 0 projects to a square around the image centre.
        let side = Camera::perspective(Vec3::new(3.0, 0.0, 0.0), Vec3::ZERO, 40.0);
        let lines = seam_lines(&geometry, &[Level::Hi, Level::Lo], &side, 32, 32).unwrap();
        assert_eq!((lines.faces, lines.segments.len()), (1, 4));
        for (a, b) in &lines.segments {
            assert!((a.x - 16.0).abs() > 3.0 || (a.y - 16.0).abs() > 3.0, "{a}");
            assert!(
                (a.x - 16.0).abs() < 10.0 && (b.y - 16.0).abs() < 10.0,
                "{a} {b}"
            );
        }
    }

    #[test]
    fn the_measure_sees_an_added_step_on_the_line_and_not_a_shared_one() {
        let (w, h) = (12u32, 8u32);
        let step = |x: u32, at: u32, v: f32| Vec4::splat(if x >= at { v } else { 0.0 });
        let full: Vec<Vec4> = (0..w * h).map(|i| step(i % w, 3, 0.3)).collect();
        let seamed: Vec<Vec4> = (0..w * h)
            .map(|i| step(i % w, 3, 0.3) + step(i % w, 8, 0.4))
            .collect();
        let f = Frame::new(w, h, &full).unwrap();
        // A vertical seam line between columns 7 and 8 (x = 8 in pixel coordinates).
        let lines = SeamLines {
            faces: 1,
            segments: vec![(Vec2::new(8.0, 2.0), Vec2::new(8.0, 6.0))],
        };
        let same = seam_measure(&f, &f, &lines).unwrap();
        assert_eq!((same.max_excess, same.samples), (0.0, 9));
        let m = seam_measure(&Frame::new(w, h, &seamed).unwrap(), &f, &lines).unwrap();
        assert!((m.max_excess - 0.4).abs() < 1e-6, "{m:?}");
        assert!((m.mean_excess - 0.4).abs() < 1e-6, "{m:?}");
        assert_eq!(m.reference_max_jump, 0.0);
        // The shared step at x = 3 under a line there: no excess, a jump in both.
        let at3 = SeamLines {
            faces: 1,
            segments: vec![(Vec2::new(3.0, 2.0), Vec2::new(3.0, 6.0))],
        };
        let shared = seam_measure(&Frame::new(w, h, &seamed).unwrap(), &f, &at3).unwrap();
        assert_eq!(shared.max_excess, 0.0);
        assert!((shared.reference_max_jump - 0.3).abs() < 1e-6);
        // A kink (continuous, slope 0 left of x = 8 and 0.1 per pixel right of it) is no jump;
        // the plain difference of the two nearer samples would see 0.05 there.
        let kink: Vec<Vec4> = (0..w * h)
            .map(|i| Vec4::splat(0.1 * ((i % w) as f32 + 0.5 - 8.0).max(0.0)))
            .collect();
        let bent = seam_measure(&Frame::new(w, h, &kink).unwrap(), &f, &lines).unwrap();
        assert!(bent.max_jump < 1e-6, "{bent:?}");
        // A line off the image takes no samples.
        let off = SeamLines {
            faces: 1,
            segments: vec![(Vec2::new(-5.0, -5.0), Vec2::new(-5.0, -1.0))],
        };
        assert_eq!(seam_measure(&f, &f, &off).unwrap().samples, 0);
    }
}
