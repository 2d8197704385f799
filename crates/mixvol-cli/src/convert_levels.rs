//! `mixvol convert INPUT STORE`: any supported volume into a level store (every
//! level, as the three-level cache stores it; `mixvol::store::levels`).
//!
//! Files (and OME-Zarr images) are read slab by slab: level 0 streams through a window of
//! planes, level 1 and each coarser level are built plane by plane in temporary files next to
//! the store ([`mixvol::store::write_level_store_from_slabs`]). Synthetic fields and DICOM series are
//! generated or loaded whole, and the levels built from the volume in RAM. Either way the RAM
//! the write needs is checked against `--ram-budget-mb` before any work. The store is written
//! to `STORE.partial` and renamed at the end, as `convert` does.

use crate::args::ConvertArgs;
use crate::convert::{describe_input, load_dicom_input, mib, open_input, progress_bar, update};
use crate::stats::peak_rss_bytes;
use mixvol::store::{write_level_store, write_level_store_from_slabs, LevelWriteSummary};
use mixvol::volume::{SyntheticField, Volume};
use mixvol::{Error, Result};
use serde_json::json;
use std::time::Instant;

/// Bytes per voxel the level writer holds besides the volume: levels 1 and 2 as f32 while
/// level 2 is built (level 0 is cut from the voxels brick by brick), about 0.56 for a large
/// volume, up to about 1.2 for one of 8^3 voxels (a vertex level has one more sample per axis).
const WRITER_BYTES_PER_VOXEL: f64 = 1.25;

/// Runs `mixvol convert` under a RAM budget of `budget` bytes.
pub fn convert_levels(args: &ConvertArgs, budget: u64) -> Result<()> {
    // `convert` checked the destination and that INPUT is not STORE.
    let store = args.store.as_path();
    let start = Instant::now();
    let bar = progress_bar();
    let mut tick = |done, total| update(&bar, done, total);
    let levels = args.level_count;
    let (summary, what) = if let Some((volume, what)) = read_whole_input(args, budget)? {
        let summary = write_level_store(
            store,
            &volume,
            args.brick_size,
            levels,
            args.filter,
            &mut tick,
        )?;
        (summary, what)
    } else {
        let mut reader = open_input(args)?;
        let what = describe_input(&*reader);
        let summary = write_level_store_from_slabs(
            store,
            &mut *reader,
            args.brick_size,
            levels,
            args.filter,
            budget,
            &mut tick,
        )?;
        (summary, what)
    };
    bar.finish_and_clear();
    report(args, &summary, &what, start)
}

/// The bytes a volume of `voxels` voxels of `voxel_bytes` each needs to be written as a level
/// store, checked against `budget` (a message naming the input and the budget when it does not
/// fit).
fn check_budget(
    input: &str,
    voxels: u64,
    voxel_bytes: u64,
    budget: u64,
    budget_mb: u64,
) -> Result<()> {
    let needed = voxels as f64 * (voxel_bytes as f64 + WRITER_BYTES_PER_VOXEL);
    if needed > budget as f64 {
        return Err(Error::InvalidInput(format!(
            "INPUT {input}: a level store is built from the whole volume: {voxels} voxels of \
             {voxel_bytes} byte(s) plus {WRITER_BYTES_PER_VOXEL} bytes each for the levels need \
             {:.0} MiB, more than --ram-budget-mb {budget_mb}",
            needed / f64::from(1 << 20)
        )));
    }
    Ok(())
}

/// A synthetic field or a DICOM series, generated or loaded whole (after the budget check),
/// and how to describe it; `None` for every other input, which is read in slabs.
fn read_whole_input(args: &ConvertArgs, budget: u64) -> Result<Option<(Volume, String)>> {
    if let Some(field) = SyntheticField::parse(&args.input) {
        let dims = args.dims.unwrap_or(glam::UVec3::splat(128));
        let scalar = args.scalar.unwrap_or(mixvol::volume::ScalarType::U8);
        let voxels = u64::from(dims.x) * u64::from(dims.y) * u64::from(dims.z);
        check_budget(
            &args.input,
            voxels,
            scalar.size_bytes() as u64,
            budget,
            args.ram_budget_mb,
        )?;
        let volume = field.generate(dims, scalar)?;
        return Ok(Some((volume, format!("synthetic {}", args.input))));
    }
    // A DICOM series is loaded within the budget by the loader itself; the levels come on top.
    let Some(loaded) = load_dicom_input(args, budget)? else {
        return Ok(None);
    };
    let v = &loaded.volume;
    let voxels = u64::from(v.dims().x) * u64::from(v.dims().y) * u64::from(v.dims().z);
    check_budget(
        &args.input,
        voxels,
        v.scalar_type().size_bytes() as u64,
        budget,
        args.ram_budget_mb,
    )?;
    let what = format!("{} (DICOM series, {:?})", args.input, loaded.meta.stored);
    Ok(Some((loaded.volume, what)))
}

/// Prints the summary and writes `--stats-json`.
fn report(
    args: &ConvertArgs,
    summary: &LevelWriteSummary,
    what: &str,
    start: Instant,
) -> Result<()> {
    let h = &summary.header;
    let seconds = start.elapsed().as_secs_f64().max(1e-9);
    let peak = peak_rss_bytes();
    println!("input: {what}");
    println!(
        "level store: {} ({}x{}x{} voxels, {:?}, bricks of {}): {} levels (level 1 by {:?}), {} \
         stored bricks, {:.1} MiB",
        summary.path.display(),
        h.dims.x,
        h.dims.y,
        h.dims.z,
        h.scalar,
        h.brick_size,
        h.levels,
        h.filter,
        h.stored_count,
        mib(h.file_size)
    );
    println!(
        "time: {seconds:.2} s (write {:.2} s); peak RSS {}",
        summary.elapsed.as_secs_f64(),
        peak.map_or("unknown".into(), |p| format!("{:.1} MiB", mib(p)))
    );
    if let Some(path) = &args.stats_json {
        let stats = json!({
            "input": what,
            "store": summary.path,
            "kind": "levels",
            "dims": h.dims.to_array(),
            "scalar": format!("{:?}", h.scalar),
            "brick_size": h.brick_size,
            "levels": h.levels,
            "filter": format!("{:?}", h.filter),
            "stored_bricks": h.stored_count,
            "store_bytes": h.file_size,
            "seconds": seconds,
            "peak_rss_bytes": peak,
            "ram_budget_bytes": args.ram_budget_mb * (1 << 20),
        });
        crate::files::write_text("the stats JSON", path, &format!("{stats:#}\n"))?;
    }
    Ok(())
}
