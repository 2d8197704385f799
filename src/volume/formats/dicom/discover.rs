//! Finding the DICOM files of an input (a folder, a DICOMDIR, one file), reading their headers
//! and grouping them into series by SeriesInstanceUID; choosing the series to load.
use super::error::{DicomError, SeriesSummary};
use super::slice::{file_has_dicom_magic, read_slice_header, DicomSlice};
use super::SeriesSelector;
use crate::volume::formats::read::{format_err, io_err};
use crate::volume::VolumeError;
use dicom_dictionary_std::tags;
use dicom_object::file::ReadPreamble;
use dicom_object::OpenFileOptions;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The files of one series, in file-name order, with their headers.
#[derive(Clone, Debug)]
pub(super) struct Series {
    /// (file, header) per slice.
    pub slices: Vec<(PathBuf, DicomSlice)>,
}

impl Series {
    /// The one-line description of the series.
    pub fn summary(&self) -> SeriesSummary {
        let first = &self.slices[0].1;
        SeriesSummary {
            uid: first.series_uid.clone(),
            number: first.series_number,
            description: first.series_description.clone(),
            modality: first.modality.clone(),
            slices: self.slices.len(),
        }
    }
}

/// Every image series of an input.
#[derive(Clone, Debug)]
pub(super) struct Found {
    /// The input as given (folder, DICOMDIR or file), for messages.
    pub input: PathBuf,
    /// DICOM files read.
    pub files: usize,
    /// Of those, files without an image.
    pub non_image: usize,
    /// The image series, ordered by series number, then UID.
    pub series: Vec<Series>,
}

impl Found {
    /// The summaries of every series.
    pub fn summaries(&self) -> Vec<SeriesSummary> {
        self.series.iter().map(Series::summary).collect()
    }
}

/// True when `path` names a DICOMDIR file (by name, case-insensitively).
pub(in crate::volume::formats) fn is_dicomdir_name(path: &Path) -> bool {
    path.file_name()
        .is_some_and(|n| n.to_string_lossy().eq_ignore_ascii_case("DICOMDIR"))
}

/// The DICOMDIR inside a folder, if any.
fn dicomdir_in(folder: &Path) -> Option<PathBuf> {
    ["DICOMDIR", "dicomdir"]
        .iter()
        .map(|n| folder.join(n))
        .find(|p| p.is_file())
}

/// True when `folder` holds a DICOMDIR, or a file with the DICOM magic among its first 64
/// regular files (in name order).
pub(in crate::volume::formats) fn is_dicom_folder(folder: &Path) -> bool {
    if !folder.is_dir() {
        return false;
    }
    if dicomdir_in(folder).is_some() {
        return true;
    }
    folder_files(folder)
        .map(|files| files.iter().take(64).any(|f| file_has_dicom_magic(f)))
        .unwrap_or(false)
}

/// The regular, non-hidden files directly in `folder`, in name order.
fn folder_files(folder: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(folder).map_err(io_err(folder))? {
        let entry = entry.map_err(io_err(folder))?;
        let hidden = entry.file_name().to_string_lossy().starts_with('.');
        let path = entry.path();
        if !hidden && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// The extensions of DICOM files (compared without case).
const DICOM_EXTENSIONS: [&str; 4] = ["dcm", "dicom", "dic", "ima"];

/// A file name without its digits, in lower case: the naming scheme of a series' files
/// (`IM0015.dcm` and `IM0001.dcm` give `im.dcm`, `1.2.840.5.15` gives `....`).
fn name_scheme(file: &Path) -> String {
    file.file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default()
        .chars()
        .filter(|c| !c.is_ascii_digit())
        .flat_map(char::to_lowercase)
        .collect()
}

/// The files of a series folder without the DICOM magic (issue 42, item 2): one with a DICOM
/// extension, or named in the scheme of the DICOM files beside it, is a slice lost (damaged,
/// cut short or emptied), an error naming it, since the series would load a slice short; any
/// other (a README, a checksum list) is skipped with a warning that names it and the count.
fn check_skipped(folder: &Path, dicom: &[PathBuf], skipped: &[PathBuf]) -> Result<(), VolumeError> {
    if skipped.is_empty() {
        return Ok(());
    }
    let schemes: std::collections::BTreeSet<String> =
        dicom.iter().map(|f| name_scheme(f)).collect();
    let (lost, others): (Vec<&PathBuf>, Vec<&PathBuf>) = skipped.iter().partition(|f| {
        let extension = f
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        extension.is_some_and(|e| DICOM_EXTENSIONS.contains(&e.as_str()))
            || schemes.contains(&name_scheme(f))
    });
    if !lost.is_empty() {
        return Err(DicomError::LostSlices {
            folder: folder.to_path_buf(),
            files: lost.into_iter().cloned().collect(),
            dicom_files: dicom.len(),
        }
        .into());
    }
    log::warn!(
        "{}: {} of {} files skipped, not DICOM (no \"DICM\" after a 128-byte preamble): {}; \
         the series is read from the other {} files",
        folder.display(),
        others.len(),
        dicom.len() + others.len(),
        super::error::names(others.iter().copied()),
        dicom.len()
    );
    Ok(())
}

/// The files a DICOMDIR references (ReferencedFileID of its directory records, relative to its
/// folder), sorted, without duplicates.
fn dicomdir_files(dicomdir: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    super::slice::check_file(dicomdir)?;
    let object = OpenFileOptions::new()
        .read_preamble(ReadPreamble::Always)
        .open_file(dicomdir)
        .map_err(|e| format_err(dicomdir, "header", format!("unreadable DICOMDIR: {e}")))?;
    let field = "DirectoryRecordSequence (0004,1220)";
    let records = object
        .get(tags::DIRECTORY_RECORD_SEQUENCE)
        .and_then(|e| e.items())
        .ok_or_else(|| format_err(dicomdir, field, "missing: not a DICOMDIR"))?;
    let base = dicomdir.parent().unwrap_or(Path::new("."));
    let mut files = Vec::new();
    for record in records {
        let Some(id) = record.get(tags::REFERENCED_FILE_ID) else {
            continue;
        };
        let parts = id.to_multi_str().map_err(|e| {
            format_err(
                dicomdir,
                "ReferencedFileID (0004,1500)",
                format!("unreadable: {e}"),
            )
        })?;
        let mut file = base.to_path_buf();
        for part in parts.iter() {
            let part = part.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            if part.is_empty() || part == "." || part == ".." || part.contains(['/', '\\']) {
                return Err(format_err(
                    dicomdir,
                    "ReferencedFileID (0004,1500)",
                    format!("{parts:?}: a path component must be a plain name"),
                ));
            }
            file.push(part);
        }
        files.push(file);
    }
    files.sort();
    files.dedup();
    Ok(files)
}

/// The DICOM files an input names: a DICOMDIR's references; a folder's DICOMDIR, else its
/// files with the DICOM magic (not its subfolders); a single file.
fn input_files(input: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    if input.is_dir() {
        if let Some(dicomdir) = dicomdir_in(input) {
            return dicomdir_files(&dicomdir);
        }
        let (dicom, skipped): (Vec<PathBuf>, Vec<PathBuf>) = folder_files(input)?
            .into_iter()
            .partition(|f| file_has_dicom_magic(f));
        check_skipped(input, &dicom, &skipped)?;
        return Ok(dicom);
    }
    if is_dicomdir_name(input) {
        return dicomdir_files(input);
    }
    Ok(vec![input.to_path_buf()])
}

/// Reads the header of every DICOM file of `input` and groups the images by series.
pub(super) fn discover(input: &Path) -> Result<Found, VolumeError> {
    let files = input_files(input)?;
    let mut by_uid: BTreeMap<String, Vec<(PathBuf, DicomSlice)>> = BTreeMap::new();
    let mut non_image = 0;
    for file in &files {
        match read_slice_header(file)? {
            Some(slice) => by_uid
                .entry(slice.series_uid.clone())
                .or_default()
                .push((file.clone(), slice)),
            None => non_image += 1,
        }
    }
    let mut series: Vec<Series> = by_uid
        .into_values()
        .map(|slices| Series { slices })
        .collect();
    series.sort_by(|a, b| {
        let (a, b) = (&a.slices[0].1, &b.slices[0].1);
        (a.series_number, &a.series_uid).cmp(&(b.series_number, &b.series_uid))
    });
    Ok(Found {
        input: input.to_path_buf(),
        files: files.len(),
        non_image,
        series,
    })
}

/// The series to load: the only one, or the one `selector` names.
pub(super) fn choose(
    found: Found,
    selector: Option<&SeriesSelector>,
) -> Result<Series, VolumeError> {
    if found.series.is_empty() {
        return Err(DicomError::NoImages {
            folder: found.input,
            files: found.files,
            non_image: found.non_image,
        }
        .into());
    }
    let Some(selector) = selector else {
        if found.series.len() == 1 {
            return Ok(found.series.into_iter().next().expect("one series"));
        }
        return Err(DicomError::SeveralSeries {
            series: found.summaries(),
            folder: found.input,
        }
        .into());
    };
    let matches = |s: &Series| {
        let first = &s.slices[0].1;
        match selector {
            SeriesSelector::Uid(uid) => first.series_uid == *uid,
            SeriesSelector::Number(n) => first.series_number == Some(*n),
        }
    };
    let count = found.series.iter().filter(|s| matches(s)).count();
    if count == 1 {
        let index = found.series.iter().position(matches).expect("a match");
        return Ok(found.series.into_iter().nth(index).expect("a match"));
    }
    Err(DicomError::SeriesNotFound {
        wanted: selector.to_string(),
        why: if count == 0 {
            "no image series matches".into()
        } else {
            format!("{count} series have the number (choose by UID)")
        },
        series: found.summaries(),
        folder: found.input,
    }
    .into())
}
