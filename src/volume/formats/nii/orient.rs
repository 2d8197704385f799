//! NIfTI orientation (also used for DICOM series, see [`crate::volume::formats::dicom`]): the voxel-to-world transform (sform, else qform, else none) in NIfTI's RAS+
//! world (+x right, +y anterior, +z superior, as nibabel), the flips and permutation that bring
//! the voxel axes closest to R, A and S, and the reordering of the voxels that applies them.
use super::RawHeader;
use crate::volume::formats::read::format_err;
use crate::volume::{Volume, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::path::Path;

/// Which header transform the orientation came from.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum TransformSource {
    /// `sform_code > 0`: the `srow_x/y/z` affine.
    Sform,
    /// `qform_code > 0` (and no usable sform): the quaternion, `qoffset` and `pixdim`.
    Qform,
    /// Neither is set (or usable): the voxel axes are taken as R, A, S.
    None,
    /// A DICOM series: ImageOrientationPatient, ImagePositionPatient, PixelSpacing and the
    /// slice gap, converted from LPS to RAS+ (see [`crate::volume::formats::dicom`]).
    Dicom,
}

impl TransformSource {
    /// `sform`, `qform` or `none`.
    pub const fn name(self) -> &'static str {
        match self {
            TransformSource::Sform => "sform",
            TransformSource::Qform => "qform",
            TransformSource::None => "none",
            TransformSource::Dicom => "DICOM image orientation / position",
        }
    }
}

/// How a NIfTI volume's (or DICOM series') voxels were reordered to RAS+ (see the module docs of
/// [`crate::volume::formats`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Reorientation {
    /// The transform the orientation was read from.
    pub source: TransformSource,
    /// The file's axis code: the world direction (one of `RLAPSI`) each file voxel axis points
    /// closest to, e.g. `['L', 'A', 'S']`.
    pub file_axes: [char; 3],
    /// For each volume axis (x, y, z = R, A, S), the file voxel axis it was taken from.
    pub permutation: [usize; 3],
    /// For each volume axis, true when the file axis ran the other way (L, P or I) and was
    /// reversed.
    pub flipped: [bool; 3],
    /// The largest angle, in degrees, between a volume axis and its world axis after the
    /// reordering: the residual oblique rotation (0 for an axis-aligned file). The voxels are
    /// not resampled for it: the renderer applies it as the volume's model transform
    /// (`scene::ModelTransform::of_volume`, `scene::model`) when asked to.
    pub oblique_degrees: f64,
}

impl Reorientation {
    /// The file's axis code as text, e.g. `LAS`.
    pub fn file_code(&self) -> String {
        self.file_axes.iter().collect()
    }

    /// True when the voxels were kept in file order.
    pub fn is_identity(&self) -> bool {
        self.permutation == [0, 1, 2] && self.flipped == [false; 3]
    }

    /// One line for logs: `LAS -> RAS (flipped x), from the sform`, plus the residual oblique
    /// rotation when there is one (`; residual oblique rotation of 20.00 deg`; whether it is
    /// rendered is the caller's to say).
    pub fn describe(&self) -> String {
        let mut what = Vec::new();
        if self.permutation != [0, 1, 2] {
            what.push(format!(
                "axes permuted: x,y,z from file axes {},{},{}",
                self.permutation[0], self.permutation[1], self.permutation[2]
            ));
        }
        let flips: Vec<&str> = ["x", "y", "z"]
            .iter()
            .zip(self.flipped)
            .filter(|(_, f)| *f)
            .map(|(a, _)| *a)
            .collect();
        if !flips.is_empty() {
            what.push(format!("flipped {}", flips.join(",")));
        }
        if what.is_empty() {
            what.push("no reordering".into());
        }
        let from = match self.source {
            TransformSource::None => "no sform or qform: voxel axes taken as RAS".to_string(),
            s => format!("from the {}", s.name()),
        };
        let mut line = format!("{} -> RAS ({}), {from}", self.file_code(), what.join("; "));
        if self.oblique_degrees > 1e-3 {
            line.push_str(&format!(
                "; residual oblique rotation of {:.2} deg",
                self.oblique_degrees
            ));
        }
        line
    }
}

/// The voxel-to-world affine (3 rows of 4) of a header, and where it came from. The sform wins
/// when `sform_code > 0` and its 3x3 part is finite and invertible; else the qform when
/// `qform_code > 0` (as nifti1_io's `nifti_quatern_to_mat44`, scaled by `pixdim`); else `None`.
pub(super) fn affine(h: &RawHeader) -> Option<([[f64; 4]; 3], TransformSource)> {
    if h.sform_code > 0 && usable(&h.srow) {
        return Some((h.srow, TransformSource::Sform));
    }
    if h.qform_code > 0 {
        let [b, c, d] = h.quatern;
        let sum = b * b + c * c + d * d;
        if !sum.is_finite() {
            return None;
        }
        let (a, b, c, d) = if 1.0 - sum < 1e-7 {
            let s = 1.0 / sum.sqrt();
            (0.0, b * s, c * s, d * s)
        } else {
            ((1.0 - sum).sqrt(), b, c, d)
        };
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let scale = [
            h.pixdim[1].abs(),
            h.pixdim[2].abs(),
            h.pixdim[3].abs() * qfac,
        ];
        let mut m = [[0.0; 4]; 3];
        for row in 0..3 {
            for col in 0..3 {
                m[row][col] = r[row][col] * scale[col];
            }
            m[row][3] = h.qoffset[row];
        }
        if usable(&m) {
            return Some((m, TransformSource::Qform));
        }
    }
    None
}

/// Finite, with a 3x3 part far from singular.
fn usable(m: &[[f64; 4]; 3]) -> bool {
    if !m.iter().flatten().all(|v| v.is_finite()) {
        return false;
    }
    let col = |i: usize| Vec3d([m[0][i], m[1][i], m[2][i]]);
    let (a, b, c) = (col(0), col(1), col(2));
    let det = a.dot(&b.cross(&c));
    let norms = a.norm() * b.norm() * c.norm();
    norms > 0.0 && (det / norms).abs() > 1e-6
}

#[derive(Copy, Clone)]
struct Vec3d([f64; 3]);

impl Vec3d {
    fn dot(&self, o: &Self) -> f64 {
        (0..3).map(|i| self.0[i] * o.0[i]).sum()
    }
    fn cross(&self, o: &Self) -> Self {
        let (a, b) = (self.0, o.0);
        Vec3d([
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ])
    }
    fn norm(&self) -> f64 {
        self.dot(self).sqrt()
    }
}

/// The reordering that brings the voxel axes of `affine` (or identity) closest to RAS+, as
/// nibabel's `io_orientation`: the file axis and world axis with the largest `|component|` of the
/// (column-normalised) direction matrix are paired first, then the next among the rest. Also
/// returns the unit directions of the reordered axes (columns; the residual rotation) and the
/// world position of the reordered volume's voxel (0, 0, 0).
pub(in crate::volume::formats) fn reorientation(
    affine: Option<([[f64; 4]; 3], TransformSource)>,
    dims: [u64; 3],
) -> (Reorientation, [[f64; 3]; 3], [f64; 3]) {
    let Some((m, source)) = affine else {
        let r = Reorientation {
            source: TransformSource::None,
            file_axes: ['R', 'A', 'S'],
            permutation: [0, 1, 2],
            flipped: [false; 3],
            oblique_degrees: 0.0,
        };
        return (r, crate::volume::formats::IDENTITY, [0.0; 3]);
    };
    let column = |i: usize| [m[0][i], m[1][i], m[2][i]];
    let unit = [0, 1, 2].map(|i| {
        let c = column(i);
        let n = Vec3d(c).norm();
        c.map(|v| v / n)
    });
    // world axis of each file axis
    let mut world_of = [usize::MAX; 3];
    let mut free_file = [true; 3];
    let mut free_world = [true; 3];
    for _ in 0..3 {
        let mut best = (0, 0, -1.0);
        for (i, u) in unit.iter().enumerate() {
            for (w, v) in u.iter().enumerate() {
                if free_file[i] && free_world[w] && v.abs() > best.2 {
                    best = (i, w, v.abs());
                }
            }
        }
        let (i, w, _) = best;
        world_of[i] = w;
        free_file[i] = false;
        free_world[w] = false;
    }
    let mut permutation = [0; 3];
    let mut flipped = [false; 3];
    let mut file_axes = ['?'; 3];
    for i in 0..3 {
        let w = world_of[i];
        permutation[w] = i;
        let negative = unit[i][w] < 0.0;
        flipped[w] = negative;
        file_axes[i] = [['R', 'L'], ['A', 'P'], ['S', 'I']][w][usize::from(negative)];
    }
    let mut residual = crate::volume::formats::IDENTITY;
    let mut origin = [m[0][3], m[1][3], m[2][3]];
    let mut oblique: f64 = 0.0;
    for j in 0..3 {
        let i = permutation[j];
        let s = if flipped[j] { -1.0 } else { 1.0 };
        residual[j] = unit[i].map(|v| v * s);
        oblique = oblique.max(residual[j][j].clamp(-1.0, 1.0).acos().to_degrees());
        if flipped[j] {
            let steps = dims[i].saturating_sub(1) as f64;
            for (o, c) in origin.iter_mut().zip(column(i)) {
                *o += steps * c;
            }
        }
    }
    let r = Reorientation {
        source,
        file_axes,
        permutation,
        flipped,
        oblique_degrees: oblique,
    };
    (r, residual, origin)
}

/// Reorders `volume`'s voxels as `r` says: volume axis `j` is file axis `r.permutation[j]`,
/// reversed where `r.flipped[j]`; the spacing is permuted alike. Needs a second voxel buffer
/// (checked against the host-memory limit first).
pub(in crate::volume::formats) fn reorder(
    path: &Path,
    volume: Volume,
    r: &Reorientation,
) -> Result<Volume, VolumeError> {
    if r.is_identity() {
        return Ok(volume);
    }
    let old = volume.dims().to_array();
    let p = r.permutation;
    let dims = UVec3::new(old[p[0]], old[p[1]], old[p[2]]);
    let sp = volume.spacing().to_array();
    let spacing = Vec3::new(sp[p[0]], sp[p[1]], sp[p[2]]);
    crate::volume::memory::check_host_bytes(
        &format!("{} (reoriented copy)", path.display()),
        volume.data().as_bytes().len() as u64,
    )?;
    // Linear index in the old volume of each new voxel, by axis.
    let stride_old = [1usize, old[0] as usize, old[0] as usize * old[1] as usize];
    let axis_index = |j: usize, a: usize| -> usize {
        let n = old[p[j]] as usize;
        let i = if r.flipped[j] { n - 1 - a } else { a };
        i * stride_old[p[j]]
    };
    let (nx, ny, nz) = (dims.x as usize, dims.y as usize, dims.z as usize);
    let xs: Vec<usize> = (0..nx).map(|a| axis_index(0, a)).collect();
    fn gather<T: Copy>(
        src: &[T],
        xs: &[usize],
        ny: usize,
        nz: usize,
        yz: impl Fn(usize, usize) -> usize,
    ) -> Vec<T> {
        let mut out = Vec::with_capacity(src.len());
        for z in 0..nz {
            for y in 0..ny {
                let base = yz(y, z);
                out.extend(xs.iter().map(|&x| src[base + x]));
            }
        }
        out
    }
    let yz = |y: usize, z: usize| axis_index(1, y) + axis_index(2, z);
    let data = match volume.data() {
        VoxelData::U8(v) => VoxelData::U8(gather(v, &xs, ny, nz, yz)),
        VoxelData::U16(v) => VoxelData::U16(gather(v, &xs, ny, nz, yz)),
        VoxelData::F32(v) => VoxelData::F32(gather(v, &xs, ny, nz, yz)),
    };
    drop(volume);
    Volume::new(dims, spacing, data).map_err(|e| e.in_file(path))
}

/// The error for a file whose reordering or value scaling a slab reader cannot do.
pub(super) fn needs_loader(path: &Path, why: &str) -> VolumeError {
    format_err(
        path,
        "orientation",
        format!(
            "{why}: slab-by-slab reading keeps the file's voxel order and stored values, so it \
             would disagree with the loader; load the file whole (mixvol render --volume) or \
             store it RAS+ without scl_slope / scl_inter"
        ),
    )
}

/// Unit vectors of three direction vectors; `None` if any is zero or not finite.
pub(in crate::volume::formats) fn normalize_columns(
    columns: [[f64; 3]; 3],
) -> Option<[[f64; 3]; 3]> {
    let mut out = crate::volume::formats::IDENTITY;
    for (o, c) in out.iter_mut().zip(columns) {
        let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        *o = c.map(|v| v / n);
    }
    Some(out)
}
