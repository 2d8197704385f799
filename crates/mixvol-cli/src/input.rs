//! The volume a command renders: a synthetic field, a file with a header, a chosen OME-Zarr
//! level, headerless raw data described by the flags, or a brick store; and the value window.

use crate::args::RenderArgs;
use crate::parse::parse_floats;
use mixvol::gpu::GpuContext;
use mixvol::scene::ModelTransform;
use mixvol::store::levels::LEVEL_MAGIC;
use mixvol::store::{LevelStore, MAGIC};
use mixvol::volume::formats::{
    load_dicom, load_tiff_with, load_zarr_at, load_zarr_level, DicomOptions, FileFormat,
    RemoteOptions, SeriesSelector, ZarrLocation,
};
use mixvol::volume::memory::check_host_bytes;
use mixvol::volume::{load_raw, RawDescriptor, SyntheticField, Volume, VolumeError, VolumeMeta};
use mixvol::{Error, Result};
use std::path::Path;
use std::sync::Arc;

/// Loads or generates the volume `--volume` names (see `mixvol render --help`).
pub fn load_volume(args: &RenderArgs) -> Result<Volume> {
    Ok(load_volume_with_meta(args)?.0)
}

/// [`load_volume`], with the file's metadata (`None` for synthetic fields and headerless raw
/// data).
///
/// A Zarr level none of whose chunks exists is an error, one with some missing a warning on
/// stderr (review D7: both gave a blank or partly blank image, exit 0, without a word).
pub fn load_volume_with_meta(args: &RenderArgs) -> Result<(Volume, Option<VolumeMeta>)> {
    let (volume, meta) = load_any_volume(args)?;
    if let Some((found, total)) = meta.as_ref().and_then(|m| m.chunks_found) {
        let why = "missing chunks, or chunks stored under other names than the array's \
                   dimension_separator / chunk_key_encoding says";
        if found == 0 && total > 0 {
            return Err(Error::InvalidInput(format!(
                "{}: none of the {total} chunks of the level exists, so every voxel would be the \
                 fill value ({why}, or a server that answers 404 for them)",
                args.volume
            )));
        }
        if found < total {
            eprintln!(
                "warning: {}: {found} of {total} chunks exist; the rest read as the fill value \
                 ({why})",
                args.volume
            );
        }
    }
    Ok((volume, meta))
}

/// [`load_volume_with_meta`] before the check of a Zarr level's chunks.
fn load_any_volume(args: &RenderArgs) -> Result<(Volume, Option<VolumeMeta>)> {
    // A URL is never looked up as a local file: s3:// and http(s):// name remote OME-Zarr
    // images (timeouts and retries from MIXVOL_REMOTE_*), file:// a local path.
    let local;
    let path = if ZarrLocation::is_url(&args.volume) {
        match ZarrLocation::parse(&args.volume)? {
            ZarrLocation::Local(p) => {
                local = p;
                local.as_path()
            }
            remote => {
                let level = args.zarr_level.unwrap_or(0);
                let loaded = load_zarr_at(&remote, level, &RemoteOptions::from_env()?)?;
                return Ok((loaded.volume, Some(loaded.meta)));
            }
        }
    } else {
        Path::new(&args.volume)
    };
    let format = FileFormat::detect(path);
    if let Some(level) = args.zarr_level {
        if format != Some(FileFormat::Zarr) {
            return Err(Error::InvalidInput(format!(
                "--zarr-level applies to OME-Zarr images (a .zarr folder), not '{}'",
                args.volume
            )));
        }
        let loaded = load_zarr_level(path, level)?;
        return Ok((loaded.volume, Some(loaded.meta)));
    }
    if let Some(options) = args.tiff.options() {
        if format != Some(FileFormat::Tiff) {
            return Err(Error::InvalidInput(format!(
                "--tiff-image / --tiff-channel / --tiff-time apply to TIFF stacks (OME-TIFF, ImageJ hyperstacks), not '{}'",
                args.volume
            )));
        }
        let loaded = load_tiff_with(path, &options)?;
        return Ok((loaded.volume, Some(loaded.meta)));
    }
    if let Some(series) = &args.series {
        if format != Some(FileFormat::Dicom) {
            return Err(Error::InvalidInput(format!(
                "--series applies to DICOM input (a folder of DICOM files, a DICOMDIR or a .dcm \
                 file), not '{}'",
                args.volume
            )));
        }
        let selector = SeriesSelector::parse(series).ok_or_else(|| {
            Error::InvalidInput(format!(
                "--series {series}: expected a SeriesInstanceUID (digits and dots) or a series \
                 number"
            ))
        })?;
        let options = DicomOptions {
            series: Some(selector),
            ..DicomOptions::default()
        };
        let loaded = load_dicom(path, &options)?;
        return Ok((loaded.volume, Some(loaded.meta)));
    }
    if let Some(field) = SyntheticField::parse(&args.volume) {
        return Ok((field.generate(args.dims, args.scalar)?, None));
    }
    if format.is_some() {
        let loaded = mixvol::volume::load_volume_with_meta(path)?;
        return Ok((loaded.volume, Some(loaded.meta)));
    }
    if path.is_dir() {
        return Err(Error::InvalidInput(format!(
            "'{}' is a folder without Zarr metadata (zarr.json, .zattrs or .zarray), .tif \
             slices, DICOMDIR or DICOM files: give an OME-Zarr image or Zarr array folder, a \
             folder of TIFF slices, a DICOM series folder, a \
             volume file or a brick store",
            args.volume
        )));
    }
    let raw = load_raw(
        path,
        &RawDescriptor {
            dims: args.dims,
            scalar: args.scalar,
            spacing: args.spacing,
            header_bytes: args.header_bytes,
            big_endian: args.big_endian,
        },
    )
    .map_err(|e| match e {
        // Say why the file was read as raw data: its name matched no format.
        e @ VolumeError::FileSizeMismatch { .. } => Error::InvalidInput(format!(
            "{e}. '{}' matches no known format ({}), so it was read as headerless raw data \
             described by --dims {},{},{} --scalar {:?} --header-bytes {}: give the right \
             flags or a file with a header",
            args.volume,
            KNOWN_FORMATS,
            args.dims.x,
            args.dims.y,
            args.dims.z,
            args.scalar,
            args.header_bytes
        )),
        e => e.into(),
    })?;
    Ok((raw, None))
}

/// Checks a synthetic field the scene will draw as one plain texture (no `--levels`, no
/// `--gpu-budget-mb`) against the host-memory limit and `ctx`'s device limits before a voxel is
/// computed: generating a field the device then refused used to take minutes (a 1400^3 field
/// for lavapipe's 2 GiB `maxMemoryAllocationSize`). Other inputs are checked where their size
/// is known (the loaders, the brick cache).
pub fn check_plain_synthetic(args: &RenderArgs, ctx: &GpuContext) -> Result<()> {
    let plain = args.mixed.levels.is_none() && args.residency.gpu_budget_mb.is_none();
    if !plain || args.zarr_level.is_some() || SyntheticField::parse(&args.volume).is_none() {
        return Ok(());
    }
    let d = args.dims;
    let bytes_per_voxel = args.scalar.size_bytes() as u64;
    let bytes = u64::from(d.x)
        .saturating_mul(u64::from(d.y))
        .saturating_mul(u64::from(d.z))
        .saturating_mul(bytes_per_voxel);
    // The host-memory refusal first, worded as the generator's own.
    check_host_bytes(
        &format!(
            "a {}x{}x{} {:?} synthetic volume",
            d.x, d.y, d.z, args.scalar
        ),
        bytes,
    )?;
    ctx.check_volume_texture("volume", d, bytes_per_voxel)
}

/// The file names `FileFormat::detect` recognises, for messages.
const KNOWN_FORMATS: &str =
    ".nii, .nii.gz, .nrrd, .nhdr, .den, .json sidecar or .raw beside one, .tif / .tiff / .btf \
     (TIFF stack, OME-TIFF), .zarr folder, folder of .tif slices, .dcm, DICOMDIR or a folder \
     of DICOM files";

/// What `--volume` names: a volume loaded into RAM, or a brick store streamed from disk.
pub enum Input {
    /// An in-memory volume (a file, raw data or a synthetic field).
    Volume(Arc<Volume>),
    /// A level store (`mixvol convert` writes them), opened and checked: drawn through the
    /// level cache at levels chosen from the camera or `--levels staircase`.
    LevelStore(Arc<LevelStore>),
    /// An OME-Zarr image streamed chunk by chunk (`--stream`): where it is, its level, and
    /// what its metadata says (dimensions, scalar type).
    Zarr {
        /// Where the image is.
        location: ZarrLocation,
        /// The level streamed.
        level: usize,
        /// Its dimensions.
        dims: glam::UVec3,
        /// Its scalar type.
        scalar: mixvol::volume::ScalarType,
    },
}

impl Input {
    /// The in-memory volume, `None` for a store or a streamed image.
    pub fn volume(&self) -> Option<&Volume> {
        match self {
            Input::Volume(v) => Some(v),
            Input::LevelStore(_) | Input::Zarr { .. } => None,
        }
    }
}

/// The first 8 bytes of `path` when it is a regular file that has them.
fn magic_of(path: &Path) -> Option<[u8; 8]> {
    use std::io::Read;
    // The regular-file check comes first: opening a FIFO would block.
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return None;
    }
    let mut magic = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .ok()
        .map(|()| magic)
}

/// What kind of mixvol store `path` is by its magic bytes ("brick store", "level store"),
/// `None` for anything else (not a regular file, or another magic).
pub fn store_kind(path: &Path) -> Option<&'static str> {
    match magic_of(path)? {
        MAGIC => Some("brick store"),
        LEVEL_MAGIC => Some("level store"),
        _ => None,
    }
}

/// The error for a two-level brick store given to a command that draws it: the format is read
/// only by `mixvol convert`, which upgrades it to a level store.
pub fn upgrade_error(path: &str) -> Error {
    Error::InvalidInput(format!(
        "{path} is a two-level brick store (MIXVOLBS), which mixvol no longer draws: upgrade it \
         to a level store with `mixvol convert {path} NEW.mvl` (every voxel is kept; the \
         coarser levels are built anew)"
    ))
}

/// Opens `--volume`: a brick store when the file is one, else [`load_volume`]; with the
/// metadata of a volume file (`None` for a brick store, a synthetic field or headerless raw
/// data).
pub fn open_input_with_meta(args: &RenderArgs) -> Result<(Input, Option<VolumeMeta>)> {
    let path = Path::new(&args.volume);
    if args.stream {
        let location = ZarrLocation::parse(&args.volume)?;
        if let ZarrLocation::Local(p) = &location {
            if FileFormat::detect(p) != Some(FileFormat::Zarr) {
                return Err(Error::InvalidInput(format!(
                    "--stream applies to OME-Zarr images (a .zarr folder, s3:// or \
                     http(s)://); '{}' is not one",
                    args.volume
                )));
            }
        }
        let level = args.zarr_level.unwrap_or(0);
        let chunks = mixvol::volume::formats::ZarrChunks::open(
            &location,
            level,
            &RemoteOptions::from_env()?,
        )?;
        let meta = chunks.meta().clone();
        return Ok((
            Input::Zarr {
                location,
                level,
                dims: chunks.dims(),
                scalar: chunks.scalar(),
            },
            Some(meta),
        ));
    }
    if ZarrLocation::is_url(&args.volume) && args.volume.ends_with(".mvl") {
        // A level store on S3 or behind HTTP: read with range requests.
        let store = LevelStore::open_remote(&args.volume, &RemoteOptions::from_env()?)?;
        return Ok((Input::LevelStore(Arc::new(store)), None));
    }
    let magic = (!ZarrLocation::is_url(&args.volume))
        .then(|| magic_of(path))
        .flatten();
    if let Some(m) = magic.filter(|m| m.starts_with(b"MIXVOL") && *m != MAGIC && *m != LEVEL_MAGIC)
    {
        // Not read as headerless raw data (review D22).
        return Err(Error::InvalidInput(format!(
            "{}: starts with \"{}\", the mark of mixvol's stores, but is neither a brick store \
             (MIXVOLBS) nor a level store (MIXVOLLV): a damaged store, or one a newer mixvol wrote",
            args.volume,
            String::from_utf8_lossy(&m)
        )));
    }
    if magic == Some(MAGIC) || magic == Some(LEVEL_MAGIC) {
        if args.zarr_level.is_some() {
            return Err(Error::InvalidInput(format!(
                "--zarr-level applies to OME-Zarr images; '{}' is a brick store",
                args.volume
            )));
        }
        if magic == Some(LEVEL_MAGIC) {
            return Ok((Input::LevelStore(Arc::new(LevelStore::open(path)?)), None));
        }
        return Err(upgrade_error(&args.volume));
    }
    let (volume, meta) = load_volume_with_meta(args)?;
    Ok((Input::Volume(Arc::new(volume)), meta))
}

/// The model transform `mixvol render` draws the volume of `meta` with, and what to say about
/// it: the residual oblique rotation of a NIfTI file or DICOM series
/// ([`ModelTransform::of_volume`]), unless `--axis-aligned` or the rotation cannot be made
/// (then the identity, and why). Identity and no note for other inputs.
pub fn model_transform(args: &RenderArgs, meta: Option<&VolumeMeta>) -> (ModelTransform, String) {
    let Some(meta) = meta.filter(|m| m.reorientation.is_some()) else {
        return (ModelTransform::IDENTITY, String::new());
    };
    if args.axis_aligned {
        return (
            ModelTransform::IDENTITY,
            "NOT applied (--axis-aligned: rendered axis-aligned)".into(),
        );
    }
    match ModelTransform::of_volume(meta) {
        Ok(model) => (
            model,
            "applied (rendered in RAS+ patient space, rotated about the volume centre)".into(),
        ),
        Err(e) => (
            ModelTransform::IDENTITY,
            format!("NOT applied (rendered axis-aligned): {e}"),
        ),
    }
}

/// The lines `mixvol render` prints about a NIfTI file's (or DICOM series') orientation, e.g.
/// `orientation: LAS -> RAS (flipped x), from the sform (RAS+ world: +x right, +y anterior,
/// +z superior)`, with `oblique_note` (from [`model_transform`]) after a residual oblique
/// rotation: `...; residual oblique rotation of 20.00 deg applied (...)`; `None` for other inputs.
pub fn orientation_line(meta: Option<&VolumeMeta>, oblique_note: &str) -> Option<String> {
    let r = meta?.reorientation.as_ref()?;
    let mut what = r.describe();
    if r.oblique_degrees > 1e-3 && !oblique_note.is_empty() {
        what = format!("{what} {oblique_note}");
    }
    Some(format!(
        "orientation: {what} (RAS+ world: +x right, +y anterior, +z superior)"
    ))
}

/// How `mixvol render` prints a window: in normalised values, plus the file's units where they
/// differ (an i16 CT: HU), or in the file's physical units where `scl_slope` / `scl_inter` were
/// applied.
pub fn window_line(meta: Option<&VolumeMeta>, (lo, hi): (f32, f32)) -> String {
    match meta {
        Some(m) if m.scale_applied => format!(
            "window: [{lo:.4}, {hi:.4}] (file units after {} {} / {} {}: HU for CT)",
            if m.format == FileFormat::Dicom {
                "RescaleSlope"
            } else {
                "scl_slope"
            },
            m.scale_slope,
            if m.format == FileFormat::Dicom {
                "RescaleIntercept"
            } else {
                "scl_inter"
            },
            m.scale_inter
        ),
        Some(m) if m.stored.value_offset() != 0 => format!(
            "window: [{lo:.4}, {hi:.4}] (normalised values) = [{:.1}, {:.1}] in file units \
             ({} stored + {}: HU for CT)",
            m.file_value(lo),
            m.file_value(hi),
            m.stored.name(),
            m.stored.value_offset()
        ),
        _ => format!("window: [{lo:.4}, {hi:.4}] (normalised values)"),
    }
}

/// The value window from `--window` / `--preset`; `volume` is `None` for a brick store (whose
/// histogram is not in RAM: `auto` and the presets' automatic window then need `--window`).
pub fn window_of(args: &RenderArgs, volume: Option<&Volume>) -> Result<Option<(f32, f32)>> {
    let auto = || {
        volume.map(Volume::auto_window).ok_or_else(|| {
            Error::InvalidInput(format!(
                "an automatic window (--window auto or --preset) needs the histogram of an \
                 in-memory volume; '{}' is a brick store: pass --window lo,hi",
                args.volume
            ))
        })
    };
    match args.window.as_deref() {
        Some("auto") => Ok(Some(auto()?)),
        Some(text) => {
            let [lo, hi] = parse_floats::<2>(text).map_err(|e| {
                Error::InvalidInput(format!("--window: {e} (expected lo,hi or auto)"))
            })?;
            if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
                return Err(Error::InvalidInput(format!(
                    "--window: hi {hi} must exceed lo {lo}"
                )));
            }
            Ok(Some((lo, hi)))
        }
        None if args.preset.is_some() => Ok(Some(auto()?)),
        None => Ok(None),
    }
}
