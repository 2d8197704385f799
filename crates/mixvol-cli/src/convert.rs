//! `mixvol convert INPUT STORE`: any supported volume into a level store, in bounded RAM
//! (the writing itself: [`crate::convert_levels`]).
//!
//! This module checks what is asked before any work (an existing STORE without `--force`, a
//! STORE that is not a regular file, INPUT naming STORE or a level store) and opens INPUT:
//! files with a header (NRRD raw / gzip, NIfTI `.nii` / `.nii.gz`, raw or gzip data with a JSON
//! sidecar, `.den`), TIFF stacks, one level of an OME-Zarr image, headerless raw data and a
//! two-level brick store written by an earlier mixvol (upgraded: its voxels are read back from
//! its level-0 bricks) are read slab by slab; synthetic fields and DICOM series (sorted and
//! reoriented as a whole) are loaded whole, after checking that they fit the budget. The store
//! is written to a temporary file and renamed at the end, so a failed convert leaves nothing
//! under STORE (with `--force`, an existing STORE stays as it was).

use crate::args::ConvertArgs;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mixvol::store::{BrickStore, BrickStoreSlabs};
use mixvol::volume::formats::zarr::ZarrSlabs;
use mixvol::volume::formats::{
    load_dicom, DicomOptions, FileFormat, LoadedVolume, RemoteOptions, SeriesSelector, TiffSlabs,
    ZarrLocation,
};
use mixvol::volume::{open_raw_slabs, open_slabs, RawDescriptor, SlabReader};
use mixvol::{Error, Result};
use std::io::IsTerminal;
use std::path::Path;

/// Runs `mixvol convert`.
pub fn convert(args: &ConvertArgs) -> Result<()> {
    let store = args.store.as_path();
    check_destination(store, args.force)?;
    if let (Ok(a), Ok(b)) = (Path::new(&args.input).canonicalize(), store.canonicalize()) {
        if a == b {
            return Err(Error::InvalidInput(format!(
                "STORE {} is the INPUT file; write the store to another path",
                store.display()
            )));
        }
    }
    // A level store is converted already (review D23): say so instead of "no known header".
    // A two-level brick store is read back and upgraded.
    if crate::input::store_kind(Path::new(&args.input)) == Some("level store") {
        return Err(Error::InvalidInput(format!(
            "INPUT {} is a level store (mixvol's own format, converted already): render it with \
             `mixvol render --volume {}`; convert reads volume files, DICOM series, Zarr and \
             the two-level brick stores of earlier versions",
            args.input, args.input
        )));
    }
    // The STORE's folder is created, as `render -o` creates the image's (review D24).
    if let Some(parent) = store.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| {
            Error::InvalidInput(format!(
                "cannot create the folder {} of STORE {}: {e}",
                parent.display(),
                store.display()
            ))
        })?;
    }
    let budget = args.ram_budget_mb.checked_mul(1 << 20).ok_or_else(|| {
        Error::InvalidInput(format!(
            "--ram-budget-mb {} is too large",
            args.ram_budget_mb
        ))
    })?;
    crate::convert_levels::convert_levels(args, budget)
}

/// Loads INPUT whole when it is a DICOM series (a folder of DICOM files, a DICOMDIR or a `.dcm`
/// file): a series is sorted along its normal, checked and reoriented as a whole, so it is not
/// read in slabs; its size, from the headers, is checked against `budget` before any pixel data
/// is decoded. `None` for every other input. `--series` on another input is an error.
pub(crate) fn load_dicom_input(args: &ConvertArgs, budget: u64) -> Result<Option<LoadedVolume>> {
    let path = Path::new(&args.input);
    let is_dicom =
        !ZarrLocation::is_url(&args.input) && FileFormat::detect(path) == Some(FileFormat::Dicom);
    if !is_dicom {
        return match args.series {
            Some(_) => Err(Error::InvalidInput(format!(
                "--series applies to DICOM input (a folder of DICOM files, a DICOMDIR or a .dcm \
                 file), not '{}'",
                args.input
            ))),
            None => Ok(None),
        };
    }
    let series = args
        .series
        .as_deref()
        .map(|text| {
            SeriesSelector::parse(text).ok_or_else(|| {
                Error::InvalidInput(format!(
                    "--series {text}: expected a SeriesInstanceUID (digits and dots) or a series \
                     number"
                ))
            })
        })
        .transpose()?;
    let options = DicomOptions {
        series,
        max_bytes: Some(budget),
    };
    Ok(Some(load_dicom(path, &options)?))
}

/// Refuses an existing STORE without `--force`, and, with or without it, a STORE that is not a
/// regular file: a folder, a symbolic link (convert never writes through one), a device, a FIFO
/// or a socket.
pub(crate) fn check_destination(store: &Path, force: bool) -> Result<()> {
    match std::fs::symlink_metadata(store) {
        Ok(meta) if meta.is_dir() => Err(Error::InvalidInput(format!(
            "STORE {} is a folder; give the path of the store file to write",
            store.display()
        ))),
        Ok(meta) if meta.file_type().is_symlink() => Err(Error::InvalidInput(format!(
            "STORE {} is a symbolic link; convert does not replace links, even with --force: \
             give the path of a regular file",
            store.display()
        ))),
        Ok(meta) if !meta.is_file() => Err(Error::InvalidInput(format!(
            "STORE {} exists and is not a regular file (a device, FIFO or socket); convert \
             replaces only a regular file, even with --force",
            store.display()
        ))),
        Ok(_) if !force => Err(Error::InvalidInput(format!(
            "STORE {} exists; pass --force to replace it",
            store.display()
        ))),
        _ => Ok(()),
    }
}

/// Opens INPUT for slab reading: a file with a header or an OME-Zarr folder, else headerless raw
/// data described by `--dims`, `--scalar`, `--spacing`, `--header-bytes`, `--big-endian`.
pub(crate) fn open_input(args: &ConvertArgs) -> Result<Box<dyn SlabReader + Send>> {
    // A URL first, never looked up as a local file: s3:// and http(s):// name remote OME-Zarr
    // images (timeouts and retries from MIXVOL_REMOTE_*), file:// a local path.
    let local;
    let path = if ZarrLocation::is_url(&args.input) {
        match ZarrLocation::parse(&args.input)? {
            ZarrLocation::Local(p) => {
                local = p;
                local.as_path()
            }
            remote => {
                let level = args.level.unwrap_or(0);
                let options = RemoteOptions::from_env()?;
                return Ok(Box::new(ZarrSlabs::open_at(&remote, level, &options)?));
            }
        }
    } else {
        Path::new(&args.input)
    };
    if crate::input::store_kind(path) == Some("brick store") {
        if args.level.is_some() || args.tiff.options().is_some() {
            return Err(Error::InvalidInput(format!(
                "INPUT {} is a brick store: --level and --tiff-* do not apply to it",
                args.input
            )));
        }
        return Ok(Box::new(BrickStoreSlabs::new(BrickStore::open(path)?)));
    }
    let format = FileFormat::detect(path);
    if let Some(options) = args.tiff.options() {
        if format != Some(FileFormat::Tiff) {
            return Err(Error::InvalidInput(format!(
                "--tiff-image / --tiff-channel / --tiff-time apply to TIFF stacks (OME-TIFF, ImageJ hyperstacks), not '{}'",
                args.input
            )));
        }
        return Ok(Box::new(TiffSlabs::open(path, &options)?));
    }
    if format.is_some() {
        if format != Some(FileFormat::Zarr) && args.level.is_some() {
            return Err(Error::InvalidInput(format!(
                "--level applies to OME-Zarr images (a .zarr folder), not '{}'",
                args.input
            )));
        }
        return Ok(open_slabs(path, args.level)?);
    }
    if !path.exists() {
        return Err(Error::InvalidInput(format!(
            "INPUT {}: no such file or folder (and not a synthetic field: ml, sphere, wall)",
            path.display()
        )));
    }
    let Some(dims) = args.dims else {
        return Err(Error::InvalidInput(format!(
            "INPUT {}: no known header (.nii, .nii.gz, .nrrd, .nhdr, .json, .raw with a sidecar, \
             .den, .tif / .tiff / .btf, .zarr); headerless raw data needs --dims x,y,z (and --scalar, --spacing, \
             --header-bytes, --big-endian as they apply)",
            path.display()
        )));
    };
    if args.level.is_some() {
        return Err(Error::InvalidInput(
            "--level applies to OME-Zarr images only".into(),
        ));
    }
    Ok(open_raw_slabs(
        path,
        &RawDescriptor {
            dims,
            scalar: args.scalar.unwrap_or(mixvol::volume::ScalarType::U8),
            spacing: args.spacing,
            header_bytes: args.header_bytes,
            big_endian: args.big_endian,
        },
    )?)
}

/// `path (format, stored type)` for the summary.
pub(crate) fn describe_input(reader: &dyn SlabReader) -> String {
    match reader.meta() {
        Some(m) => format!(
            "{} ({:?}, {}{})",
            reader.path().display(),
            m.format,
            m.stored.name(),
            if m.big_endian { ", big-endian" } else { "" }
        ),
        None => format!(
            "{} (headerless raw, {:?})",
            reader.path().display(),
            reader.scalar()
        ),
    }
}

pub(crate) fn mib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1 << 20)
}

/// A brick-count progress bar on stderr, hidden when stderr is not a terminal.
pub(crate) fn progress_bar() -> ProgressBar {
    let target = if std::io::stderr().is_terminal() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(None, target);
    if let Ok(style) = ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} bricks (eta {eta})",
    ) {
        bar.set_style(style);
    }
    bar
}

pub(crate) fn update(bar: &ProgressBar, done: u64, total: u64) {
    if bar.length() != Some(total) {
        bar.set_length(total);
    }
    bar.set_position(done);
}
