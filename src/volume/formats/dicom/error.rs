//! The typed errors of DICOM series assembly: which series, and why a set of slices is not one
//! regular stack. Problems inside one file's header are [`VolumeError::Format`] errors naming the
//! file and the attribute.
//!
//! [`VolumeError::Format`]: crate::volume::VolumeError::Format
use std::fmt;
use std::path::PathBuf;

/// One image series found in a folder or DICOMDIR, as error messages and
/// [`super::list_dicom_series`] list it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SeriesSummary {
    /// SeriesInstanceUID (0020,000E).
    pub uid: String,
    /// SeriesNumber (0020,0011), when present.
    pub number: Option<i64>,
    /// SeriesDescription (0008,103E), empty when absent.
    pub description: String,
    /// Modality (0008,0060), empty when absent.
    pub modality: String,
    /// Number of image files (slices) in the series.
    pub slices: usize,
}

impl fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (", self.uid)?;
        if let Some(n) = self.number {
            write!(f, "series number {n}, ")?;
        }
        if !self.description.is_empty() {
            write!(f, "\"{}\", ", self.description)?;
        }
        if !self.modality.is_empty() {
            write!(f, "{}, ", self.modality)?;
        }
        let s = if self.slices == 1 { "" } else { "s" };
        write!(f, "{} slice{s})", self.slices)
    }
}

/// The series as one line each, for messages.
fn list(series: &[SeriesSummary]) -> String {
    series
        .iter()
        .map(|s| format!("\n  {s}"))
        .collect::<String>()
}

/// Up to eight file names (not their folders), comma-separated, and how many more.
pub(super) fn names<'a>(files: impl IntoIterator<Item = &'a PathBuf>) -> String {
    let files: Vec<&PathBuf> = files.into_iter().collect();
    let mut text = files
        .iter()
        .take(8)
        .map(|f| {
            f.file_name()
                .unwrap_or(f.as_os_str())
                .to_string_lossy()
                .into_owned()
        })
        .collect::<Vec<_>>()
        .join(", ");
    if files.len() > 8 {
        text.push_str(&format!(" and {} more", files.len() - 8));
    }
    text
}

/// `n` and `what`, plural when `n` is not 1.
fn count(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// Why a folder or DICOMDIR did not give one volume.
#[derive(Debug, thiserror::Error)]
pub enum DicomError {
    /// More than one image series and none chosen.
    #[error(
        "{folder}: {} image series; choose one by SeriesInstanceUID or series number \
         (mixvol: --series UID-or-number; library: DicomOptions::series):{}",
        series.len(),
        list(series)
    )]
    SeveralSeries {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// The series found.
        series: Vec<SeriesSummary>,
    },
    /// The chosen series is not there (or its number is shared by several series).
    #[error("{folder}: {why} `{wanted}`; the image series are:{}", list(series))]
    SeriesNotFound {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// The UID or number asked for.
        wanted: String,
        /// "no image series matches", or "several series have the number".
        why: String,
        /// The series found.
        series: Vec<SeriesSummary>,
    },
    /// Files of the folder named like its DICOM files (or with a DICOM extension) that are
    /// not DICOM files: slices damaged, cut short or emptied. Loading without them would give
    /// a volume slices short, so nothing is loaded.
    #[error(
        "{folder}: {} named like the series' files {} no \"DICM\" after a 128-byte preamble \
         (damaged, cut short or empty): {}; the series would load without {} and be short of \
         slices, so it is refused ({dicom_files} DICOM files read): repair or restore {}, or \
         move {} out of the folder",
        count(files.len(), "file"),
        if files.len() == 1 { "has" } else { "have" },
        names(files),
        if files.len() == 1 { "it" } else { "them" },
        if files.len() == 1 { "it" } else { "them" },
        if files.len() == 1 { "it" } else { "them" }
    )]
    LostSlices {
        /// The folder.
        folder: PathBuf,
        /// The files without the magic.
        files: Vec<PathBuf>,
        /// The DICOM files beside them.
        dicom_files: usize,
    },
    /// No DICOM file with pixel data.
    #[error(
        "{folder}: no DICOM image found ({files} DICOM files read, {non_image} of them without \
         an image; files without the DICM preamble are ignored)"
    )]
    NoImages {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// DICOM files read.
        files: usize,
        /// Of those, files without Rows / Columns (reports, structure sets, ...).
        non_image: usize,
    },
    /// The gaps between consecutive slices along the slice normal are not all equal.
    #[error(
        "{folder}: irregular slice spacing: slices {first_index} ({first}) and {} ({second}) are \
         {gap:.4} mm apart along the slice normal where the series' other gaps are {expected:.4} \
         mm; irregularly spaced series (a missing slice, a varying table increment) are refused, \
         not resampled",
        first_index + 1
    )]
    IrregularSpacing {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// Index, in sorted order, of the first slice of the odd gap.
        first_index: usize,
        /// File of that slice.
        first: PathBuf,
        /// File of the next slice.
        second: PathBuf,
        /// Their gap, in mm.
        gap: f64,
        /// The series' typical (median) gap, in mm.
        expected: f64,
    },
    /// Two slices at one position (two echoes or phases in one series, or a copied file).
    #[error(
        "{folder}: slices {first} and {second} lie at the same position ({position:.4} mm along \
         the slice normal, or the same InstanceNumber without positions): the series holds more \
         than one stack (echoes, phases) or a duplicate"
    )]
    DuplicatePosition {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// One file.
        first: PathBuf,
        /// The other.
        second: PathBuf,
        /// Their position along the slice normal (or InstanceNumber).
        position: f64,
    },
    /// A series without slice positions whose slices cannot be ordered by InstanceNumber
    /// (review D14).
    #[error(
        "{folder}: {missing} of the {count} slices have neither ImagePositionPatient nor \
         InstanceNumber (the first: {first}): they cannot be ordered into a stack"
    )]
    Unordered {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// The first slice without an InstanceNumber.
        first: PathBuf,
        /// Slices without one.
        missing: usize,
        /// Slices in the series.
        count: usize,
    },
    /// A slice disagrees with the series' first slice on an attribute that must be shared.
    #[error(
        "{folder}: {file} has {field} {found} but {reference} has {expected}: the files of a \
         series must form one stack of equal slices"
    )]
    Inconsistent {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// The slice the others are compared with.
        reference: PathBuf,
        /// The slice that differs.
        file: PathBuf,
        /// The DICOM attribute.
        field: String,
        /// Its value in `reference`.
        expected: String,
        /// Its value in `file`.
        found: String,
    },
    /// The slice origins do not lie on one line along the slice normal.
    #[error(
        "{folder}: {file} is {offset:.4} mm off the line through the first slice's origin along \
         the slice normal: a sheared stack (gantry tilt) is not supported"
    )]
    Sheared {
        /// The folder or DICOMDIR.
        folder: PathBuf,
        /// The offending slice.
        file: PathBuf,
        /// Its in-plane offset, in mm.
        offset: f64,
    },
}
