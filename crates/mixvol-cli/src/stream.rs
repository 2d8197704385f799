//! A streamed OME-Zarr image (`mixvol render --stream`): its own pyramid read chunk by chunk as
//! the stored bricks of the level cache, and what its chunk caches did.

use mixvol::bricks::ValueRange;
use mixvol::stream::{ZarrLevels, ZarrLevelsConfig};
use mixvol::volume::formats::{RemoteOptions, ZarrChunks, ZarrLocation};
use mixvol::volume::ScalarType;
use mixvol::{Error, Result};
use std::sync::Arc;

/// Chunk requests in flight: `MIXVOL_REMOTE_CONCURRENCY`, default 8.
fn concurrency() -> Result<usize> {
    match std::env::var("MIXVOL_REMOTE_CONCURRENCY") {
        Err(_) => Ok(8),
        Ok(text) => match text.trim().parse::<usize>() {
            Ok(n) if n >= 1 => Ok(n),
            _ => Err(Error::InvalidInput(format!(
                "MIXVOL_REMOTE_CONCURRENCY={text:?}: expected a whole number of at least 1"
            ))),
        },
    }
}

/// The value range to report for a streamed image of `scalar` values: `--window` (normalised)
/// for a float image, which needs one; `None` (the whole range) for 8- and 16-bit images.
fn float_range(
    location: &ZarrLocation,
    scalar: ScalarType,
    window: Option<(f32, f32)>,
) -> Result<Option<ValueRange>> {
    match (scalar, window) {
        (ScalarType::F32, Some((min, max))) => Ok(Some(ValueRange { min, max })),
        (ScalarType::F32, None) => Err(Error::InvalidInput(format!(
            "{location} holds float values: --stream needs their range (--window lo,hi)"
        ))),
        _ => Ok(None),
    }
}

/// Opens the image at `location` as the stored bricks of every level of the level cache, read
/// from its own pyramid levels from image level `base_level` down (`--stream`, `--zarr-level`),
/// bricks of `brick_size`, half of `ram` for decoded chunks; `window` (normalised) is the value
/// range of a float image.
pub fn open_zarr_levels(
    location: &ZarrLocation,
    base_level: usize,
    brick_size: u32,
    ram: u64,
    window: Option<(f32, f32)>,
) -> Result<Arc<ZarrLevels>> {
    let options = RemoteOptions::from_env()?;
    let scalar = ZarrChunks::open(location, base_level, &options)?.scalar();
    let value_range = float_range(location, scalar, window)?;
    let half = usize::try_from(ram / 2).unwrap_or(usize::MAX);
    let levels = ZarrLevels::open(
        location,
        &options,
        ZarrLevelsConfig {
            brick_size,
            levels: None,
            concurrency: concurrency()?,
            chunk_cache_bytes: half,
            value_range,
            base_level,
        },
    )?;
    println!(
        "streaming {location} at every level: vertex levels 0..{} read from image levels {:?}, \
         {:.1} MB chunk cache",
        mixvol::store::LevelBackend::level_count(&levels),
        levels.image_levels(),
        half as f64 / 1e6
    );
    Ok(Arc::new(levels))
}

/// Review D7 for a streamed image: an error when no chunk it fetched exists (every voxel drawn
/// would be the fill value: chunks stored under other names than the array's
/// `dimension_separator` / `chunk_key_encoding` say, or a server answering 404), a warning on
/// stderr with the count when some are absent.
pub fn check_absent_chunks(zarr: &ZarrLevels, location: &str) -> Result<()> {
    let c = zarr.cache_stats();
    let why = "missing chunks, or chunks stored under other names than the array's \
               dimension_separator / chunk_key_encoding says";
    if c.fetches > 0 && c.absent_chunks == c.fetches {
        return Err(Error::InvalidInput(format!(
            "{location}: none of the {} chunks fetched exists, so the image would be the fill \
             value throughout ({why}, or a server that answers 404 for them); no image written",
            c.fetches
        )));
    }
    if c.absent_chunks > 0 {
        eprintln!(
            "warning: {location}: {} of the {} chunks fetched do not exist and read as the fill \
             value ({why})",
            c.absent_chunks, c.fetches
        );
    }
    Ok(())
}

/// What the chunk caches of a streamed image did: chunks fetched (and absent), stored bytes,
/// cache hits, the peak against the budget, failed chunks.
pub fn chunk_line(zarr: &ZarrLevels) -> String {
    let c = zarr.cache_stats();
    format!(
        "fetched {} chunks ({} absent: the fill value), {:.2} MB stored bytes ({} cache hits, \
         chunk cache peak {:.2} MB of {:.2} MB, {} failed chunks)",
        c.fetches,
        c.absent_chunks,
        zarr.bytes_fetched() as f64 / 1e6,
        c.hits,
        c.peak_bytes as f64 / 1e6,
        c.budget_bytes as f64 / 1e6,
        c.failed_chunks
    )
}
