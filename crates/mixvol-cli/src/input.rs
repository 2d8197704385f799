//! The volume a command renders: a synthetic field, a file with a header, a chosen OME-Zarr
//! level, or headerless raw data described by the flags; and the value window.

use crate::args::RenderArgs;
use crate::parse::parse_floats;
use mixvol::volume::formats::{load_zarr_level, FileFormat};
use mixvol::volume::{load_raw, RawDescriptor, SyntheticField, Volume};
use mixvol::{Error, Result};
use std::path::Path;

/// Loads or generates the volume `--volume` names (see `mixvol render --help`).
pub fn load_volume(args: &RenderArgs) -> Result<Volume> {
    let path = Path::new(&args.volume);
    let format = FileFormat::detect(path);
    if let Some(level) = args.zarr_level {
        if format != Some(FileFormat::Zarr) {
            return Err(Error::InvalidInput(format!(
                "--zarr-level applies to OME-Zarr images (a .zarr folder), not '{}'",
                args.volume
            )));
        }
        return Ok(load_zarr_level(path, level)?.volume);
    }
    if let Some(field) = SyntheticField::parse(&args.volume) {
        return Ok(field.generate(args.dims, args.scalar)?);
    }
    if format.is_some() {
        return Ok(mixvol::volume::load_volume(path)?);
    }
    Ok(load_raw(
        path,
        &RawDescriptor {
            dims: args.dims,
            scalar: args.scalar,
            spacing: args.spacing,
            header_bytes: args.header_bytes,
            big_endian: args.big_endian,
        },
    )?)
}

/// The value window from `--window` / `--preset`.
pub fn window_of(args: &RenderArgs, volume: &Volume) -> Result<Option<(f32, f32)>> {
    match args.window.as_deref() {
        Some("auto") => Ok(Some(volume.auto_window())),
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
        None if args.preset.is_some() => Ok(Some(volume.auto_window())),
        None => Ok(None),
    }
}
