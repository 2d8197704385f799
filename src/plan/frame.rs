//! What the planner plans a frame from (the inputs, budgets and options) and what it returns
//! (the plan and its report), with the helpers that derive them from the render settings and
//! the brick size.

use super::PlanError;
use crate::bricks::{hi_res_brick_extent, low_res_brick_extent, BrickSource, Level, ValueRange};
use crate::cache::CacheGeometry;
use crate::lod::{BrickGeometry, CullParams, LodError, LodView, TfCullTable, ValueCulling};
use crate::optics::TransferFunction;
use crate::scene::{RenderMode, RenderSettings};

/// The culling criteria of `settings`: iso-surface mode culls by the iso-value; direct volume
/// rendering by the transfer function `tf` seen through `window` (the value window the frame is
/// classified with: [`RenderSettings::value_window`] or the volume's default); MIP and MIDA keep
/// every non-empty brick (a transparent brick can still hold a ray's maximum, so culling it could
/// change the image). The clip planes are those of `settings`.
pub fn cull_params(
    settings: &RenderSettings,
    tf: &TransferFunction,
    window: (f32, f32),
) -> Result<CullParams, LodError> {
    let value = match settings.mode {
        RenderMode::Iso { value, .. } => ValueCulling::IsoValue(value),
        RenderMode::Dvr => ValueCulling::TransferFunction(TfCullTable::new(tf, window)?),
        RenderMode::Mip | RenderMode::Mida { .. } => ValueCulling::None,
    };
    Ok(CullParams {
        value,
        clip: settings.clip_planes,
    })
}

/// Bytes one upload of `level` costs for bricks of `brick_size` voxels: `(n+2)^3` (`Hi`) or
/// `(n/2+1)^3` (`Lo`) texels times `bytes_per_texel` (saturating); 0 for `Absent`.
pub fn upload_bytes(level: Level, brick_size: u32, bytes_per_texel: u32) -> u64 {
    let extent = match level {
        Level::Hi => hi_res_brick_extent(brick_size),
        Level::Lo => low_res_brick_extent(brick_size),
        Level::Absent => return 0,
    };
    u64::from(extent)
        .saturating_pow(3)
        .saturating_mul(u64::from(bytes_per_texel))
}

/// The budgets of one frame.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct PlanBudget {
    /// GPU cache slots (one `Hi` brick or eight `Lo` bricks each).
    pub slots: usize,
    /// Bytes of brick uploads allowed this frame.
    pub upload_bytes_per_frame: u64,
    /// Bytes per texel of the packed bricks (channels x scalar size; must be > 0).
    pub bytes_per_texel: u32,
    /// Optional RAM budget of the streamer: the request list is cut to what fits.
    pub ram_bytes: Option<u64>,
}

impl PlanBudget {
    /// The budget of a cache of geometry `cache`: all its slots.
    pub fn for_cache(
        cache: &CacheGeometry,
        bytes_per_texel: u32,
        upload_bytes_per_frame: u64,
    ) -> Self {
        Self {
            slots: cache.slot_count() as usize,
            upload_bytes_per_frame,
            bytes_per_texel,
            ram_bytes: None,
        }
    }

    /// Slots of the largest cache image [`CacheGeometry::choose`] fits into `cache_bytes` for
    /// bricks of `brick_size` voxels, `bytes_per_texel` bytes per texel and an image side of at
    /// most `max_dim_3d`.
    pub fn slots_in_bytes(
        brick_size: u32,
        bytes_per_texel: u32,
        cache_bytes: u64,
        max_dim_3d: u32,
    ) -> Result<usize, PlanError> {
        let cache = CacheGeometry::choose(
            brick_size,
            bytes_per_texel,
            cache_bytes,
            max_dim_3d,
            u32::MAX,
        )?;
        Ok(cache.slot_count() as usize)
    }

    /// Bytes per texel of the bricks `source` delivers (channels x scalar size).
    pub fn bytes_per_texel_of(source: &dyn BrickSource) -> u32 {
        source.channels() * source.scalar().size_bytes() as u32
    }
}

/// Tuning of the planner.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PlanOptions {
    /// Screen-space error (pixels x value range, [`screen_space_error`](crate::lod::screen_space_error)) below which a brick is
    /// not refined; 0 refines whatever the slot budget allows. Finite, >= 0.
    pub error_threshold: f32,
    /// Relative hysteresis margin `m` (finite, >= 0): see the [planner](crate::plan).
    pub hysteresis: f32,
}

impl Default for PlanOptions {
    /// Budget-driven (threshold 0) with a 10 % hysteresis margin.
    fn default() -> Self {
        Self {
            error_threshold: 0.0,
            hysteresis: 0.1,
        }
    }
}

/// What one frame is planned from.
#[derive(Copy, Clone, Debug)]
pub struct FrameInput<'a> {
    /// The brick grid in world space.
    pub geometry: &'a BrickGeometry,
    /// The camera and viewport.
    pub view: &'a LodView,
    /// Per-brick value ranges (one per brick, linear index).
    pub ranges: &'a [ValueRange],
    /// A number the caller changes whenever `ranges` change (a counter, say), or `None`. A frame
    /// whose generation is `Some` and equal to the last frame's takes the ranges as unchanged
    /// without comparing them (a pass over both copies, 16 bytes per brick, which is a tenth of
    /// a moving frame's time at 10^5 bricks); with `None` the planner compares them. A caller
    /// that keeps the generation while changing the ranges gets the last frame's culling.
    pub ranges_generation: Option<u64>,
    /// Culling criteria ([`cull_params`]).
    pub cull: &'a CullParams,
    /// The frame's budgets.
    pub budget: PlanBudget,
}

/// The counts of one frame's plan.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct PlanReport {
    /// Bricks in the grid.
    pub bricks: usize,
    /// Bricks culled (transfer function, iso-value, clip planes).
    pub culled: usize,
    /// Active bricks dropped because even all-low-res did not fit the slot budget.
    pub dropped: usize,
    /// Bricks wanted `Hi`.
    pub wanted_hi: usize,
    /// Bricks wanted `Lo`.
    pub wanted_lo: usize,
    /// Bricks drawn `Hi`.
    pub drawn_hi: usize,
    /// Bricks drawn `Lo`.
    pub drawn_lo: usize,
    /// Wanted (not culled, not dropped) bricks drawn `Absent` this frame: not loaded yet, or
    /// their upload did not fit this frame.
    pub drawn_absent: usize,
    /// Bricks whose wanted level is not loaded by the source, so that their target differs from
    /// it: a lower loaded level, a kept `Hi` level (a brick wanted `Lo` but drawn `Hi`, see the
    /// [planner](crate::plan)), or absent.
    pub waiting_for_source: usize,
    /// Bricks whose drawn level differs from their target and follows in a later frame.
    pub deferred: usize,
    /// Slots the drawn levels need.
    pub slots_used: usize,
    /// The slot budget.
    pub slot_budget: usize,
    /// Bytes the staged uploads cost.
    pub upload_bytes: u64,
    /// The upload budget.
    pub upload_budget: u64,
    /// Bytes of the levels requested from the source (after the RAM cut).
    pub request_bytes: u64,
    /// Requests left out by the RAM budget.
    pub requests_cut: usize,
    /// Largest screen-space error of a brick drawn `Lo` (0 when none is; `Hi` bricks have none).
    /// A level source's: the largest on-screen size, in pixels, of a voxel at the levels the
    /// view wants (weighted by value range where its choice is; the drawn levels reach it once
    /// nothing waits), [`super::LevelChoice::pixels_per_voxel`].
    pub max_drawn_error: f32,
}

impl PlanReport {
    /// True when this frame uploads nothing and nothing is deferred: the plan has converged for
    /// what the source has loaded.
    pub fn is_settled(&self) -> bool {
        self.upload_bytes == 0 && self.deferred == 0
    }
}

/// One frame's plan.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FramePlan {
    /// The level to draw every brick at now (what the cache update gets).
    pub draw: Vec<Level>,
    /// The level the view wants for every brick (culled and dropped bricks `Absent`).
    pub wanted: Vec<Level>,
    /// The uploads staged this frame: `(brick, level)` for every brick whose drawn level changed
    /// to a resident level, in staging order.
    pub uploads: Vec<(u32, Level)>,
    /// Requests for the source, `(brick, level, priority)` in priority order (priorities are
    /// ranks, `len - position`, as [`request_plan`](crate::bricks::request_plan) returns them).
    pub requests: Vec<(u32, Level, f32)>,
    /// The counts.
    pub report: PlanReport,
}
