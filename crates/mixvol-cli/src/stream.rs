//! The streaming sources `mixvol render` drives: a brick store's streamer and a streamed
//! OME-Zarr image (`--stream`), behind what the command needs of them ([`Streaming`]).

use mixvol::bricks::ValueRange;
use mixvol::renderer::MixedConfig;
use mixvol::store::{BrickBackend, BrickStore, BrickStreamer, StreamerConfig};
use mixvol::stream::{ZarrBrickSource, ZarrBricks, ZarrLevels, ZarrLevelsConfig, ZarrStreamConfig};
use mixvol::volume::formats::{RemoteOptions, ZarrChunks, ZarrLocation};
use mixvol::volume::ScalarType;
use mixvol::{Error, Result};
use std::sync::Arc;
use std::time::Duration;

/// What `mixvol render` needs of a streaming brick source besides the brick bytes.
pub trait Streaming: mixvol::bricks::BrickSource {
    /// Blocks until the source has nothing left to load for the current request, or `timeout`.
    fn wait_settled(&self, timeout: Duration) -> bool;

    /// One line on what was streamed (levels loaded, bytes read or fetched).
    fn summary(&self) -> String;
}

/// The counters every streamer has.
fn streamer_line<B: BrickBackend>(s: &BrickStreamer<B>) -> String {
    let st = s.stats();
    format!(
        "streamed {} brick levels ({:.2} MB packed, peak {:.2} MB of the {:.2} MB budget), {} failed",
        st.loads,
        st.bytes_read as f64 / 1e6,
        st.peak_bytes as f64 / 1e6,
        st.ram_budget_bytes as f64 / 1e6,
        st.failures
    )
}

impl Streaming for BrickStreamer<BrickStore> {
    fn wait_settled(&self, timeout: Duration) -> bool {
        BrickStreamer::wait_settled(self, timeout)
    }

    fn summary(&self) -> String {
        streamer_line(self)
    }
}

impl Streaming for ZarrBrickSource {
    fn wait_settled(&self, timeout: Duration) -> bool {
        BrickStreamer::wait_settled(self, timeout)
    }

    fn summary(&self) -> String {
        let zarr = self.store();
        let c = zarr.cache_stats();
        let f = zarr.fallback_stats();
        let fallback = match f.level {
            Some(level) if f.bricks > 0 => format!(
                "; {} bricks drawn partly from pyramid level {level} ({} chunks fetched)",
                f.bricks, f.cache.fetches
            ),
            _ => String::new(),
        };
        format!(
            "{}; fetched {} chunks, {:.2} MB stored bytes ({} cache hits, chunk cache peak \
             {:.2} MB of {:.2} MB, {} failed chunks); exact value ranges of {} bricks \
             learned{fallback}",
            streamer_line(self),
            c.fetches,
            zarr.chunks().bytes_fetched() as f64 / 1e6,
            c.hits,
            c.peak_bytes as f64 / 1e6,
            c.budget_bytes as f64 / 1e6,
            c.failed_chunks,
            zarr.learned_ranges()
        )
    }
}

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

/// Opens level `level` of the image at `location` as a streaming source bricked as `config`
/// says, half of `ram` for decoded chunks and half for packed bricks; `window` (normalised) is
/// the value range of a float image.
pub fn open_streamed(
    location: &ZarrLocation,
    level: usize,
    config: &MixedConfig,
    ram: u64,
    window: Option<(f32, f32)>,
) -> Result<Arc<ZarrBrickSource>> {
    let chunks = ZarrChunks::open(location, level, &RemoteOptions::from_env()?)?;
    let value_range = float_range(location, chunks.scalar(), window)?;
    let half = usize::try_from(ram / 2).unwrap_or(usize::MAX);
    let bricks = ZarrBricks::new(
        chunks,
        ZarrStreamConfig {
            brick_size: config.brick_size,
            filter: config.filter,
            concurrency: concurrency()?,
            chunk_cache_bytes: half,
            value_range,
        },
    )?;
    println!(
        "streaming {location}: chunks of {} voxels, {} chunks, {:.1} MB chunk cache",
        bricks.chunks().chunk_shape(),
        bricks.chunks().chunk_grid().element_product(),
        half as f64 / 1e6
    );
    Ok(Arc::new(BrickStreamer::new(
        bricks,
        StreamerConfig {
            ram_budget_bytes: half,
            record_load_order: false,
        },
    )?))
}

/// Opens the image at `location` as the stored bricks of every level of the three-level cache,
/// read from its own pyramid levels (`--stream --levels camera`), bricks of `brick_size`, half
/// of `ram` for decoded chunks; `window` (normalised) is the value range of a float image.
pub fn open_zarr_levels(
    location: &ZarrLocation,
    brick_size: u32,
    ram: u64,
    window: Option<(f32, f32)>,
) -> Result<Arc<ZarrLevels>> {
    let options = RemoteOptions::from_env()?;
    let scalar = ZarrChunks::open(location, 0, &options)?.scalar();
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
