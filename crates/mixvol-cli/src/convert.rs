//! `mixvol convert INPUT STORE`: any supported volume into a brick store, in bounded RAM.
//!
//! Files with a header (NRRD raw / gzip, NIfTI `.nii` / `.nii.gz`, raw or gzip data with a JSON
//! sidecar, `.den`), one level of an OME-Zarr image and headerless raw data are read slab by
//! slab ([`mixvol::store::write_store_from_slabs`]) under `--ram-budget-mb`; synthetic fields and
//! DICOM series (sorted and reoriented as a whole) are loaded whole, after checking that they fit
//! the budget. Everything is checked before any
//! work (the store's brick size, the budget against the slab the brick size needs, an existing
//! STORE without `--force`); the store is written to `STORE.partial` and renamed at the end, so a
//! failed convert leaves nothing under STORE (with `--force`, an existing STORE stays as it was).

use crate::args::ConvertArgs;
use crate::stats::peak_rss_bytes;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mixvol::store::{
    plan_slab_write, slab_store_desc, write_store_from_slabs,
    write_store_from_volume_with_progress, SlabPlan, StoreDesc, WriteSummary,
};
use mixvol::volume::formats::zarr::ZarrSlabs;
use mixvol::volume::formats::{
    load_dicom, DicomOptions, FileFormat, LoadedVolume, RemoteOptions, SeriesSelector, TiffSlabs,
    ZarrLocation,
};
use mixvol::volume::{open_raw_slabs, open_slabs, RawDescriptor, SlabReader, SyntheticField};
use mixvol::{Error, Result};
use serde_json::json;
use std::io::IsTerminal;
use std::path::Path;
use std::time::Instant;

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
    // A store is converted already (review D23): say so instead of "no known header".
    if let Some(kind) = crate::input::store_kind(Path::new(&args.input)) {
        return Err(Error::InvalidInput(format!(
            "INPUT {} is a {kind} (mixvol's own format, converted already): render it with \
             `mixvol render --volume {}`; convert reads volume files, DICOM series and Zarr",
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
    if args.all_levels {
        return crate::convert_levels::convert_levels(args, budget);
    }
    let filter = args.filter;
    let start = Instant::now();
    let (summary, input_bytes, plan, what) = if let Some(field) = SyntheticField::parse(&args.input)
    {
        let dims = args.dims.unwrap_or(glam::UVec3::splat(128));
        let scalar = args.scalar.unwrap_or(mixvol::volume::ScalarType::U8);
        let bytes =
            u64::from(dims.x) * u64::from(dims.y) * u64::from(dims.z) * scalar.size_bytes() as u64;
        if bytes > budget {
            return Err(Error::InvalidInput(format!(
                "INPUT {}: a synthetic field of {}x{}x{} {scalar:?} voxels is generated whole \
                 ({} MiB), more than --ram-budget-mb {}",
                args.input,
                dims.x,
                dims.y,
                dims.z,
                bytes.div_ceil(1 << 20),
                args.ram_budget_mb
            )));
        }
        let volume = field.generate(dims, scalar)?;
        let bar = progress_bar();
        let summary = write_store_from_volume_with_progress(
            store,
            &volume,
            args.brick_size,
            filter,
            &mut |done, total| update(&bar, done, total),
        )?;
        bar.finish_and_clear();
        (summary, bytes, None, format!("synthetic {}", args.input))
    } else if let Some(loaded) = load_dicom_input(args, budget)? {
        let bytes = loaded.volume.data().as_bytes().len() as u64;
        let bar = progress_bar();
        let summary = write_store_from_volume_with_progress(
            store,
            &loaded.volume,
            args.brick_size,
            filter,
            &mut |done, total| update(&bar, done, total),
        )?;
        bar.finish_and_clear();
        let what = format!(
            "{} (DICOM series, {:?}, loaded whole)",
            args.input, loaded.meta.stored
        );
        (summary, bytes, None, what)
    } else {
        let mut reader = open_input(args)?;
        let desc = slab_store_desc(&*reader, args.brick_size, filter);
        let plan = plan_slab_write(
            &desc,
            reader.scalar(),
            reader.scratch_bytes(),
            budget,
            mixvol::bricks::available_threads(),
        )?;
        let input_bytes = input_voxel_bytes(&*reader);
        let what = describe_input(&*reader);
        print_plan(&desc, &plan);
        let bar = progress_bar();
        let summary = write_store_from_slabs(store, desc, &mut *reader, budget, &mut |d, t| {
            update(&bar, d, t)
        })?;
        bar.finish_and_clear();
        (summary, input_bytes, Some(plan), what)
    };
    report(args, &summary, input_bytes, plan, &what, start)
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

/// Bytes of the input's voxels as stored (decoded, for compressed files).
fn input_voxel_bytes(reader: &dyn SlabReader) -> u64 {
    let d = reader.dims();
    let size = reader
        .meta()
        .map_or(reader.scalar().size_bytes(), |m| m.stored.size_bytes());
    u64::from(d.x) * u64::from(d.y) * u64::from(d.z) * size as u64
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

fn print_plan(desc: &StoreDesc, plan: &SlabPlan) {
    println!(
        "plan: {}x{}x{} voxels, bricks of {}, slab of {} planes ({:.1} MiB) + reader {:.1} MiB + \
         {} worker(s) x {:.1} MiB = {:.1} MiB of the {:.0} MiB budget",
        desc.dims.x,
        desc.dims.y,
        desc.dims.z,
        desc.brick_size,
        plan.planes,
        mib(plan.slab_bytes),
        mib(plan.reader_bytes),
        plan.threads,
        mib(plan.worker_bytes),
        mib(plan.total_bytes),
        mib(plan.budget_bytes)
    );
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

/// Prints the summary and writes `--stats-json`.
fn report(
    args: &ConvertArgs,
    summary: &WriteSummary,
    input_bytes: u64,
    plan: Option<SlabPlan>,
    what: &str,
    start: Instant,
) -> Result<()> {
    let h = &summary.header;
    let seconds = start.elapsed().as_secs_f64().max(1e-9);
    let peak = peak_rss_bytes();
    let input_mb_s = input_bytes as f64 / 1e6 / seconds;
    let store_mb_s = h.file_size as f64 / 1e6 / seconds;
    println!("input: {what}");
    println!(
        "store: {} ({}x{}x{} voxels, {:?}, bricks of {}, {:?}): {} bricks ({}x{}x{}), {:.1} MiB",
        summary.path.display(),
        h.dims.x,
        h.dims.y,
        h.dims.z,
        h.scalar,
        h.brick_size,
        h.filter,
        h.brick_count,
        h.grid().bricks_per_axis().x,
        h.grid().bricks_per_axis().y,
        h.grid().bricks_per_axis().z,
        mib(h.file_size)
    );
    println!(
        "time: {seconds:.2} s on {} thread(s): input {input_mb_s:.1} MB/s, store {store_mb_s:.1} MB/s; \
         peak RSS {}",
        summary.threads,
        peak.map_or("unknown".into(), |p| format!("{:.1} MiB", mib(p)))
    );
    if let Some(path) = &args.stats_json {
        let stats = json!({
            "input": what,
            "store": summary.path,
            "dims": h.dims.to_array(),
            "scalar": format!("{:?}", h.scalar),
            "brick_size": h.brick_size,
            "filter": format!("{:?}", h.filter),
            "bricks": h.brick_count,
            "store_bytes": h.file_size,
            "input_bytes": input_bytes,
            "seconds": seconds,
            "input_mb_per_s": input_mb_s,
            "store_mb_per_s": store_mb_s,
            "threads": summary.threads,
            "peak_rss_bytes": peak,
            "ram_budget_bytes": args.ram_budget_mb * (1 << 20),
            "plan_bytes": plan.map(|p| p.total_bytes),
            "slab_planes": plan.map(|p| p.planes),
        });
        crate::files::write_text("the stats JSON", path, &format!("{stats:#}\n"))?;
    }
    Ok(())
}
