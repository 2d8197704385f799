//! Where a renderer gets packed brick bytes from, and how it copes with bricks not loaded yet.
//!
//! [`BrickSource`] is the supplier: the store's streamer
//! (`BrickStreamer`, from disk, or over an OME-Zarr image, local
//! or remote: `stream::ZarrBrickSource`) or the in-memory sources here
//! ([`VolumeBrickSource`], [`RgbaBrickSource`], packed on demand by the [kernel](super::kernel)).
//! Its errors are [`SourceError`]s: a brick it does not have, or a load that failed in its
//! backend (the streamer's `store::StoreError` is kept as the source).

use super::build::{available_threads, build_value_ranges};
use super::kernel::{BrickKernel, VoxelWindow};
use super::{BrickError, BrickGrid, DownsampleFilter, Level, ValueRange};
use crate::optics::SamplingModel;
use crate::volume::{RgbaVolume, ScalarType, Volume, VoxelData};
use glam::Vec3;
use std::sync::Arc;

/// Which levels of one brick a source has loaded (one bit per level), as
/// [`BrickSource::loaded_levels`] reports them.
/// One byte (`repr(transparent)`): a slice of them is as compact as a byte array.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, bytemuck::NoUninit)]
#[repr(transparent)]
pub struct LoadedLevels(u8);

impl LoadedLevels {
    /// No level loaded.
    pub const NONE: Self = Self(0);
    /// Both levels loaded.
    pub const BOTH: Self = Self(Self::bit(Level::Hi) | Self::bit(Level::Lo));

    const fn bit(level: Level) -> u8 {
        match level {
            Level::Hi => 1,
            Level::Lo => 2,
            Level::Absent => 0,
        }
    }

    /// These levels with `level` loaded too when `loaded` (`Level::Absent` changes nothing).
    #[must_use]
    pub const fn with(self, level: Level, loaded: bool) -> Self {
        Self(self.0 | if loaded { Self::bit(level) } else { 0 })
    }

    /// True when `level` is loaded (never for `Level::Absent`, which has no bytes).
    pub const fn contains(self, level: Level) -> bool {
        self.0 & Self::bit(level) != 0
    }

    /// The bits of `levels` (bit 0: `Hi` loaded, bit 1: `Lo` loaded; the others 0), for code
    /// that reads them in blocks.
    pub(crate) fn bits(levels: &[Self]) -> &[u8] {
        bytemuck::cast_slice(levels)
    }

    /// The bits of one brick's levels, as [`LoadedLevels::bits`] gives them.
    pub(crate) const fn bits_of(self) -> u8 {
        self.0
    }

    /// The levels loaded in both `self` and `other`.
    #[must_use]
    pub const fn intersection(self, other: Self) -> Self {
        Self(self.0 & other.0)
    }
}

/// Why a [`BrickSource`] cannot deliver a brick, or an in-memory source cannot be built.
#[derive(Debug, Clone, thiserror::Error)]
pub enum SourceError {
    /// The brick index is beyond the grid.
    #[error("brick {brick} is out of range: the grid has {count} bricks")]
    BrickOutOfRange {
        /// The brick index asked for.
        brick: u32,
        /// Bricks in the grid.
        count: u32,
    },
    /// `Level::Absent` has no bytes.
    #[error("brick {brick}: the absent level has no bytes")]
    AbsentLevel {
        /// The brick index asked for.
        brick: u32,
    },
    /// The input of an in-memory source is unusable.
    #[error("invalid {field}: {message}")]
    InvalidInput {
        /// What is wrong (`"brick_size"`, `"rgba volume"`, ...).
        field: &'static str,
        /// Why.
        message: String,
    },
    /// Loading the brick failed in the source's backend (it is not retried until the backend
    /// is told to, e.g. `store::BrickStreamer::clear_failures`).
    #[error("brick {brick} ({level:?}) failed to load: {source}")]
    Load {
        /// The brick index.
        brick: u32,
        /// The level.
        level: Level,
        /// The backend's error (a `store::StoreError` for the streamer).
        #[source]
        source: Arc<dyn std::error::Error + Send + Sync>,
    },
}

/// A supplier of packed brick bytes for the brick cache.
///
/// Bytes are what [`crate::bricks::quantize_to`] returns for the packed brick: `(n+2)^3` (`Hi`)
/// or `(n/2+1)^3` (`Lo`) native-endian texels of [`BrickSource::scalar`], x fastest, ready for a
/// staging buffer. [`BrickSource::brick_bytes`] never blocks on I/O: `Ok(None)` means "not loaded
/// yet" (ask again later; see [`fallback_levels`]).
pub trait BrickSource: Send + Sync {
    /// The brick grid.
    fn grid(&self) -> BrickGrid;

    /// Storage scalar type of the texels' channels.
    fn scalar(&self) -> ScalarType;

    /// Channels per texel: 1 (scalar volumes) or 4 (pre-classified RGBA, f32 channels
    /// interleaved).
    fn channels(&self) -> u32 {
        1
    }

    /// Filter that built the low-res bricks.
    fn filter(&self) -> DownsampleFilter;

    /// Physical voxel spacing.
    fn spacing(&self) -> Vec3;

    /// Per-brick conservative value ranges for culling (indexed by linear brick index), as
    /// [`crate::bricks::brick_value_ranges_for_storage`] defines them.
    fn value_ranges(&self) -> &[ValueRange];

    /// The per-brick ranges as far as a streaming source has learned them so far, when they
    /// can tighten while it streams (a source that cannot read every voxel up front reports
    /// conservative [`BrickSource::value_ranges`] and learns a brick's exact range, as
    /// [`crate::bricks::brick_value_ranges_for_storage`] defines it, once the voxels it reads
    /// have arrived; see the `stream` module). A host culls with these when given, and culls
    /// again when they change. `None` (the default): [`BrickSource::value_ranges`] are final.
    /// Never blocks on I/O.
    fn learned_value_ranges(&self) -> Option<Arc<[ValueRange]>> {
        None
    }

    /// Smallest and largest voxel value of the whole volume. The default is the union of the
    /// brick ranges (conservative: it includes the low-res samples).
    fn value_range(&self) -> ValueRange {
        let mut all = ValueRange::EMPTY;
        for r in self.value_ranges() {
            all.include(r.min);
            all.include(r.max);
        }
        all
    }

    /// The packed bytes of `brick` at `level` if they are available now, `Ok(None)` if they are
    /// not loaded yet. Errors: brick out of range, `Level::Absent`, or a load that failed.
    fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError>;

    /// True when [`BrickSource::brick_bytes`] would return bytes now.
    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        matches!(self.brick_bytes(brick, level), Ok(Some(_)))
    }

    /// Fills `loaded` with one entry per brick of the grid: which of its levels
    /// [`BrickSource::is_loaded`] would call loaded now, all in one call (what the residency
    /// planner asks about every brick every frame). A streaming source keeps what it reports
    /// here until its next [`BrickSource::request_levels`], as it keeps the levels `is_loaded`
    /// answered. The default asks `is_loaded` about both levels of every brick.
    fn loaded_levels(&self, loaded: &mut Vec<LoadedLevels>) {
        let count = self.grid().brick_count() as u32;
        loaded.clear();
        loaded.extend((0..count).map(|b| {
            LoadedLevels::NONE
                .with(Level::Hi, self.is_loaded(b, Level::Hi))
                .with(Level::Lo, self.is_loaded(b, Level::Lo))
        }));
    }

    /// Tells a streaming source what to load next: `(brick, level, priority)`, higher priority
    /// first, replacing the previous request (as `store::BrickStreamer::request`). The
    /// camera-driven pass calls it once per frame with the planner's requests, after the frame's
    /// bricks were fetched. Must not block on I/O. The default (for sources that hold every
    /// level in memory) does nothing.
    fn request_levels(&self, requests: &[(u32, Level, f32)]) -> Result<(), SourceError> {
        let _ = requests;
        Ok(())
    }
}

/// The levels to draw now, given the levels the LOD selector wants (one per brick) and what
/// `source` has loaded:
///
/// - a wanted `Hi` brick stays `Hi` when its hi-res bytes are loaded, falls back to `Lo` when only
///   its low-res bytes are, and is `Absent` for now when neither is;
/// - a wanted `Lo` brick stays `Lo` when its low-res bytes are loaded, else is `Absent` for now;
/// - `Absent` stays `Absent`.
///
/// This is what keeps the renderer from ever blocking on disk: it draws what is there and the
/// streamer fills in the rest in the background. The result never needs more cache slots than
/// `wanted` (`#Hi + ceil(#Lo / 8)` can only shrink), so it fits wherever `wanted` fits. Bricks the
/// source reports an error for are treated as not loaded. A brick already resident on the GPU
/// still needs its bytes here (for re-uploads: compaction moves, border restores): keep the
/// bricks you draw in the streamer's wanted set so that their bytes stay in RAM.
///
/// With a `store::BrickStreamer`, every level this function reports drawable stays loaded until
/// the next `store::BrickStreamer::request` (it is pinned), so the uploads that follow in the
/// same frame always find their bytes.
pub fn fallback_levels(wanted: &[Level], source: &dyn BrickSource) -> Vec<Level> {
    wanted
        .iter()
        .enumerate()
        .map(|(i, &level)| {
            let brick = i as u32;
            match level {
                Level::Hi if source.is_loaded(brick, Level::Hi) => Level::Hi,
                Level::Hi | Level::Lo if source.is_loaded(brick, Level::Lo) => Level::Lo,
                _ => Level::Absent,
            }
        })
        .collect()
}

/// A streaming request for the levels the LOD selector wants: every non-absent brick's low-res
/// level first (so that a complete low-res picture arrives quickly and every hi-res brick has its
/// fallback), then the hi-res levels of the `Hi` bricks; within each tier by descending
/// `priority[brick]` (the caller's LOD error, tie-broken by distance; equal priorities keep brick
/// order). Missing or NaN priorities count as lowest.
///
/// The returned priorities are ranks (`len - position`), so `store::BrickStreamer::request`
/// keeps exactly this order.
pub fn request_plan(wanted: &[Level], priority: &[f32]) -> Vec<(u32, Level, f32)> {
    let p = |i: usize| match priority.get(i) {
        Some(v) if !v.is_nan() => *v,
        _ => f32::NEG_INFINITY,
    };
    let mut lo: Vec<usize> = Vec::new();
    let mut hi: Vec<usize> = Vec::new();
    for (i, level) in wanted.iter().enumerate() {
        match level {
            Level::Hi => {
                lo.push(i);
                hi.push(i);
            }
            Level::Lo => lo.push(i),
            Level::Absent => {}
        }
    }
    lo.sort_by(|&a, &b| p(b).total_cmp(&p(a)));
    hi.sort_by(|&a, &b| p(b).total_cmp(&p(a)));
    let total = lo.len() + hi.len();
    lo.iter()
        .map(|&i| (i, Level::Lo))
        .chain(hi.iter().map(|&i| (i, Level::Hi)))
        .enumerate()
        .map(|(pos, (i, level))| (i as u32, level, (total - pos) as f32))
        .collect()
}

/// A pre-classified RGBA volume as a [`BrickSource`] of RGBA32F texels, in the weighted form of
/// one [`SamplingModel`] (see [`RgbaVolume::weighted`]): each channel is bricked and filtered as
/// its own f32 volume, so the low-res level averages opacity- or extinction-weighted colour and
/// the coefficient channel, as Kraus et al. recommend for downsampling. Value ranges (for
/// culling) are those of the coefficient channel.
#[derive(Clone, Debug)]
pub struct RgbaBrickSource {
    channels: [VolumeBrickSource; 4],
    model: SamplingModel,
}

impl RgbaBrickSource {
    /// Bricks `volume` for `model` into `brick_size`^3 bricks with low-res level `filter`.
    pub fn new(
        volume: &RgbaVolume,
        model: SamplingModel,
        brick_size: u32,
        filter: DownsampleFilter,
    ) -> Result<Self, SourceError> {
        let channels = Self::channel_volumes(volume, model)?;
        let [r, g, b, a] =
            channels.map(|v| VolumeBrickSource::new(Arc::new(v), brick_size, filter));
        Ok(Self {
            channels: [r?, g?, b?, a?],
            model,
        })
    }

    /// The four weighted channels of `volume` for `model` as f32 volumes (what the CPU reference
    /// builds its per-channel caches from).
    pub fn channel_volumes(
        volume: &RgbaVolume,
        model: SamplingModel,
    ) -> Result<[Volume; 4], SourceError> {
        let weighted = volume.weighted(model);
        let channel = |c: usize| {
            Volume::new(
                volume.dims(),
                volume.spacing(),
                VoxelData::F32(weighted.iter().map(|v| v[c]).collect()),
            )
            .map_err(|e| SourceError::InvalidInput {
                field: "rgba volume",
                message: e.to_string(),
            })
        };
        Ok([channel(0)?, channel(1)?, channel(2)?, channel(3)?])
    }

    /// The sampling model the bricks hold.
    pub fn model(&self) -> SamplingModel {
        self.model
    }
}

impl BrickSource for RgbaBrickSource {
    fn grid(&self) -> BrickGrid {
        self.channels[3].grid()
    }

    fn scalar(&self) -> ScalarType {
        ScalarType::F32
    }

    fn channels(&self) -> u32 {
        4
    }

    fn filter(&self) -> DownsampleFilter {
        self.channels[3].filter()
    }

    fn spacing(&self) -> Vec3 {
        self.channels[3].spacing()
    }

    fn value_ranges(&self) -> &[ValueRange] {
        self.channels[3].value_ranges()
    }

    fn value_range(&self) -> ValueRange {
        self.channels[3].value_range()
    }

    fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError> {
        let mut parts = Vec::with_capacity(4);
        for c in &self.channels {
            match c.brick_bytes(brick, level)? {
                Some(bytes) => parts.push(bytes),
                None => return Ok(None),
            }
        }
        let texels = parts[0].len() / 4;
        let mut out = Vec::with_capacity(texels * 16);
        for t in 0..texels {
            for part in &parts {
                out.extend_from_slice(&part[4 * t..4 * t + 4]);
            }
        }
        Ok(Some(out.into()))
    }

    /// Every level of every brick is in memory (as for each channel): no packing to find out.
    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        self.channels.iter().all(|c| c.is_loaded(brick, level))
    }

    fn loaded_levels(&self, loaded: &mut Vec<LoadedLevels>) {
        let mut channel = Vec::new();
        for (i, c) in self.channels.iter().enumerate() {
            if i == 0 {
                c.loaded_levels(loaded);
            } else {
                c.loaded_levels(&mut channel);
                for (l, &c) in loaded.iter_mut().zip(&channel) {
                    *l = l.intersection(c);
                }
            }
        }
    }
}

/// An in-memory volume as a [`BrickSource`]: every brick is always available, packed on demand
/// by the [kernel](super::kernel) straight from the volume (the bytes are what
/// [`crate::bricks::pack_hi_res_brick`] / [`crate::bricks::pack_low_res_brick`] and
/// [`crate::bricks::quantize_to`] give; the volume's scalar type is the storage type).
#[derive(Clone, Debug)]
pub struct VolumeBrickSource {
    volume: Arc<Volume>,
    grid: BrickGrid,
    filter: DownsampleFilter,
    ranges: Vec<ValueRange>,
    value_range: ValueRange,
}

impl VolumeBrickSource {
    /// Bricks `volume` into `brick_size`^3 bricks with low-res level `filter` (computes the value
    /// ranges up front, on all cores).
    pub fn new(
        volume: Arc<Volume>,
        brick_size: u32,
        filter: DownsampleFilter,
    ) -> Result<Self, SourceError> {
        let grid = BrickGrid::new(volume.dims(), brick_size).map_err(invalid("brick_size"))?;
        let storage = volume.scalar_type();
        let ranges = build_value_ranges(&volume, &grid, filter, storage, available_threads())
            .map_err(invalid("brick_size"))?;
        let (min, max) = volume.value_range();
        Ok(Self {
            volume,
            grid,
            filter,
            ranges,
            value_range: ValueRange { min, max },
        })
    }

    /// The volume.
    pub fn volume(&self) -> &Arc<Volume> {
        &self.volume
    }
}

/// Maps a bricking error to [`SourceError::InvalidInput`] naming `field`.
fn invalid(field: &'static str) -> impl Fn(BrickError) -> SourceError {
    move |e| SourceError::InvalidInput {
        field,
        message: e.to_string(),
    }
}

impl BrickSource for VolumeBrickSource {
    fn grid(&self) -> BrickGrid {
        self.grid
    }

    fn scalar(&self) -> ScalarType {
        self.volume.scalar_type()
    }

    fn filter(&self) -> DownsampleFilter {
        self.filter
    }

    fn spacing(&self) -> Vec3 {
        self.volume.spacing()
    }

    fn value_ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    fn value_range(&self) -> ValueRange {
        self.value_range
    }

    fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError> {
        let count = self.ranges.len() as u32;
        if brick >= count {
            return Err(SourceError::BrickOutOfRange { brick, count });
        }
        if level == Level::Absent {
            return Err(SourceError::AbsentLevel { brick });
        }
        let storage = self.volume.scalar_type();
        let packed = BrickKernel::new(&self.grid, self.filter, storage)
            .pack_level(
                &VoxelWindow::of_volume(&self.volume),
                self.grid.brick_coords(brick as usize),
                level == Level::Hi,
            )
            .map_err(invalid("brick"))?;
        Ok(Some(packed.as_bytes().into()))
    }

    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        (brick as usize) < self.ranges.len() && level != Level::Absent
    }

    fn loaded_levels(&self, loaded: &mut Vec<LoadedLevels>) {
        loaded.clear();
        loaded.resize(self.ranges.len(), LoadedLevels::BOTH);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::RgbaVolume;
    use glam::{UVec3, Vec4};

    #[test]
    fn rgba_is_loaded_says_what_brick_bytes_delivers() {
        let dims = UVec3::new(12, 8, 8);
        let voxels = (0..dims.element_product())
            .map(|i| Vec4::new(0.5, 0.25, 1.0, (i % 7) as f32 / 7.0))
            .collect();
        let volume = RgbaVolume::new(dims, Vec3::ONE, voxels).unwrap();
        let source =
            RgbaBrickSource::new(&volume, SamplingModel::Opacity, 4, DownsampleFilter::Mean2)
                .unwrap();
        let count = source.grid().brick_count() as u32;
        assert_eq!(count, 12);
        // In range, out of range, every level (the override is what the planner asks per brick).
        for brick in [0, 5, count - 1, count, count + 3, u32::MAX] {
            for level in [Level::Hi, Level::Lo, Level::Absent] {
                let delivers = matches!(source.brick_bytes(brick, level), Ok(Some(_)));
                assert_eq!(
                    source.is_loaded(brick, level),
                    delivers,
                    "brick {brick} {level:?}"
                );
                assert_eq!(delivers, brick < count && level != Level::Absent);
            }
        }
    }
}
