//! A series' slices as one regular stack: checks that they share size, pixel spacing and
//! orientation, sorts them along the slice normal (the cross product of the row and column
//! directions of ImageOrientationPatient) by ImagePositionPatient, measures the slice spacing
//! (refusing irregular gaps, duplicates and sheared stacks), and builds the voxel-to-patient
//! affine, converted from DICOM's LPS to RAS+.
use super::error::DicomError;
use super::slice::DicomSlice;
use crate::volume::VolumeError;
use std::path::{Path, PathBuf};

/// Relative tolerance on gaps and spacings (1 %); gaps also tolerate [`ABS_TOLERANCE_MM`].
pub const GAP_TOLERANCE: f64 = 0.01;

/// Absolute tolerance on positions, in mm (DICOM decimal strings carry limited digits).
pub const ABS_TOLERANCE_MM: f64 = 1e-3;

/// The slices of a series arranged as one volume.
#[derive(Clone, Debug)]
pub(super) struct Stack {
    /// Indices into the series' slices, in volume z order.
    pub order: Vec<usize>,
    /// Voxels along x (Columns), y (Rows), z (slices).
    pub dims: [u64; 3],
    /// Voxel spacing along x, y, z in mm (PixelSpacing columns / rows, slice gap).
    pub spacing: [f64; 3],
    /// Voxel (file order) to RAS+ patient space, 3 rows of 4; `None` without
    /// ImageOrientationPatient / ImagePositionPatient.
    pub affine_ras: Option<[[f64; 4]; 3]>,
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn text<T: std::fmt::Debug>(v: T) -> String {
    format!("{v:?}")
}

/// Arranges `slices` (file-name order; the first is the reference for shared attributes).
pub(super) fn arrange(
    folder: &Path,
    slices: &[(PathBuf, DicomSlice)],
) -> Result<Stack, VolumeError> {
    let (ref_path, reference) = &slices[0];
    let inconsistent = |file: &Path, field: &str, expected: String, found: String| {
        VolumeError::from(DicomError::Inconsistent {
            folder: folder.to_path_buf(),
            reference: ref_path.clone(),
            file: file.to_path_buf(),
            field: field.into(),
            expected,
            found,
        })
    };
    let close = |a: &[f64], b: &[f64], tol: f64| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
    for (path, s) in &slices[1..] {
        let shared: [(&str, String, String); 5] = [
            ("Rows", text(reference.rows), text(s.rows)),
            ("Columns", text(reference.columns), text(s.columns)),
            (
                "BitsAllocated",
                text(reference.bits_allocated),
                text(s.bits_allocated),
            ),
            (
                "PixelRepresentation",
                text(reference.signed as u8),
                text(s.signed as u8),
            ),
            (
                "SamplesPerPixel",
                text(reference.samples_per_pixel),
                text(s.samples_per_pixel),
            ),
        ];
        for (field, want, got) in shared {
            if want != got {
                return Err(inconsistent(path, field, want, got));
            }
        }
        let spacing_ok = match (reference.pixel_spacing, s.pixel_spacing) {
            (Some(a), Some(b)) => close(&a, &b, GAP_TOLERANCE * a[0].min(a[1])),
            (a, b) => a.is_none() && b.is_none(),
        };
        if !spacing_ok {
            return Err(inconsistent(
                path,
                "PixelSpacing",
                text(reference.pixel_spacing),
                text(s.pixel_spacing),
            ));
        }
        let orientation_ok = match (reference.orientation, s.orientation) {
            (Some(a), Some(b)) => close(&a, &b, 1e-4),
            (a, b) => a.is_none() && b.is_none(),
        };
        if !orientation_ok {
            return Err(inconsistent(
                path,
                "ImageOrientationPatient",
                text(reference.orientation),
                text(s.orientation),
            ));
        }
        if reference.position.is_some() != s.position.is_some() {
            return Err(inconsistent(
                path,
                "ImagePositionPatient",
                text(reference.position),
                text(s.position),
            ));
        }
    }
    let [dy, dx] = reference.pixel_spacing.unwrap_or([1.0, 1.0]);
    let n = slices.len();
    let dims = [
        u64::from(reference.columns),
        u64::from(reference.rows),
        n as u64,
    ];
    let single_dz = reference
        .spacing_between_slices
        .or(reference.slice_thickness)
        .unwrap_or(1.0);
    let (Some(iop), Some(_)) = (reference.orientation, reference.position) else {
        // No geometry: InstanceNumber orders the slices.
        let mut order: Vec<usize> = (0..n).collect();
        if n > 1 {
            let missing: Vec<&PathBuf> = slices
                .iter()
                .filter(|(_, s)| s.instance_number.is_none())
                .map(|(path, _)| path)
                .collect();
            if let Some(first) = missing.first() {
                return Err(DicomError::Unordered {
                    folder: folder.to_path_buf(),
                    first: first.to_path_buf(),
                    missing: missing.len(),
                    count: n,
                }
                .into());
            }
            let mut keyed: Vec<_> = slices
                .iter()
                .enumerate()
                .filter_map(|(i, (_, s))| s.instance_number.map(|k| (k, i)))
                .collect();
            keyed.sort();
            for w in keyed.windows(2) {
                if w[0].0 == w[1].0 {
                    return Err(DicomError::DuplicatePosition {
                        folder: folder.to_path_buf(),
                        first: slices[w[0].1].0.clone(),
                        second: slices[w[1].1].0.clone(),
                        position: w[0].0 as f64,
                    }
                    .into());
                }
            }
            order = keyed.into_iter().map(|(_, i)| i).collect();
        }
        return Ok(Stack {
            order,
            dims,
            spacing: [dx, dy, single_dz],
            affine_ras: None,
        });
    };
    let row = [iop[0], iop[1], iop[2]];
    let col = [iop[3], iop[4], iop[5]];
    let normal = cross(row, col);
    let position = |i: usize| slices[i].1.position.expect("checked above");
    let mut keyed: Vec<(f64, usize)> = (0..n).map(|i| (dot(normal, position(i)), i)).collect();
    keyed.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let gaps: Vec<f64> = keyed.windows(2).map(|w| w[1].0 - w[0].0).collect();
    for (i, g) in gaps.iter().enumerate() {
        if *g <= ABS_TOLERANCE_MM {
            return Err(DicomError::DuplicatePosition {
                folder: folder.to_path_buf(),
                first: slices[keyed[i].1].0.clone(),
                second: slices[keyed[i + 1].1].0.clone(),
                position: keyed[i].0,
            }
            .into());
        }
    }
    let dz = if n > 1 {
        let mut sorted = gaps.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let tol = ABS_TOLERANCE_MM.max(GAP_TOLERANCE * median);
        if let Some(i) = gaps.iter().position(|g| (g - median).abs() > tol) {
            return Err(DicomError::IrregularSpacing {
                folder: folder.to_path_buf(),
                first_index: i,
                first: slices[keyed[i].1].0.clone(),
                second: slices[keyed[i + 1].1].0.clone(),
                gap: gaps[i],
                expected: median,
            }
            .into());
        }
        let first = position(keyed[0].1);
        for &(s, i) in &keyed[1..] {
            let p = position(i);
            let along = s - keyed[0].0;
            let off: f64 = (0..3)
                .map(|a| (p[a] - first[a] - along * normal[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            if off > tol {
                return Err(DicomError::Sheared {
                    folder: folder.to_path_buf(),
                    file: slices[i].0.clone(),
                    offset: off,
                }
                .into());
            }
        }
        (keyed[n - 1].0 - keyed[0].0) / (n - 1) as f64
    } else {
        single_dz
    };
    let origin = position(keyed[0].1);
    // Columns of the LPS affine: x steps along the row direction by the column spacing, y along
    // the column direction by the row spacing, z along the normal by the slice gap.
    let columns = [
        row.map(|v| v * dx),
        col.map(|v| v * dy),
        normal.map(|v| v * dz),
    ];
    let mut affine = [[0.0; 4]; 3];
    for r in 0..3 {
        // LPS -> RAS: negate x and y.
        let sign = if r < 2 { -1.0 } else { 1.0 };
        for (c, column) in columns.iter().enumerate() {
            affine[r][c] = sign * column[r];
        }
        affine[r][3] = sign * origin[r];
    }
    Ok(Stack {
        order: keyed.into_iter().map(|(_, i)| i).collect(),
        dims,
        spacing: [dx, dy, dz],
        affine_ras: Some(affine),
    })
}
