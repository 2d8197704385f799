//! What a level choice is (issue 19, item 4; issue 36, item 4): the level of every brick for
//! one view ([`LevelChoice`]), why a choice is refused ([`LevelChoiceError`]), the hysteresis
//! margin in levels, what a choice is made from ([`LevelRequest`]) and the one-call form of
//! [`LevelChooser::choose`] (the chooser and its method: `super::levels`).
use super::levels::LevelChooser;
use crate::bricks::ValueRange;
use crate::lod::{BrickGeometry, LodView};

/// Why [`choose_levels`] cannot choose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LevelChoiceError {
    /// The culling result, the value ranges or the previous choice do not have one entry per
    /// brick.
    #[error(
        "{given} culling flags, value ranges or previous levels for a grid of {bricks} bricks"
    )]
    ActiveCount {
        /// Entries given.
        given: usize,
        /// Bricks in the grid.
        bricks: usize,
    },
    /// No level, more than 31, or block levels with bricks below 8 voxels.
    #[error(
        "{levels} levels with bricks of {brick_size} voxels: give 1 to 3 levels, or up to 31 \
         with bricks of at least 8 voxels"
    )]
    Levels {
        /// Levels given.
        levels: u32,
        /// Brick size of the grid.
        brick_size: u32,
    },
    /// The hysteresis margin is not a finite number of levels >= 0.
    #[error("the hysteresis margin must be a finite number of levels >= 0, not {0}")]
    Hysteresis(f32),
    /// The target is not a positive finite number of pixels.
    #[error("the target voxel size on screen must be a positive number of pixels, not {0}")]
    Target(f32),
}

/// What [`choose_levels`] chose.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelChoice {
    /// The level of every brick (linear index), `None` for a brick that is not drawn.
    pub levels: Vec<Option<u32>>,
    /// Slots the plan takes.
    pub slots: u64,
    /// The on-screen voxel size the plan meets (in every brick in view but those at full
    /// resolution already): the target, grown by what the budget forced.
    pub pixels_per_voxel: f32,
    /// Bricks whose chosen level is not drawn yet because its stored brick waits for a later
    /// step's upload budget (`VolumePass::update`; 0 from [`choose_levels`]).
    pub waiting: usize,
    /// Bricks not drawn because the cache cannot hold even the coarsest plan: the least
    /// important blocks of the coarsest level (out of view first, then the farthest) are
    /// dropped until it fits (module docs, step 0). 0 when the cache holds the coarsest plan.
    pub dropped: usize,
    /// Stored bricks whose read failed while this view was staged
    /// (`VolumePass::update`; 0 from [`choose_levels`]): each is kept out of every
    /// later step, so its region keeps the level it draws (a coarser one), and the step is
    /// planned again without it.
    pub failed_reads: usize,
}

/// What one level choice is made from ([`LevelChooser::choose`]; module docs of
/// `super::levels`).
#[derive(Clone, Copy, Debug)]
pub struct LevelRequest<'a> {
    /// The brick grid in world space.
    pub geometry: &'a BrickGeometry,
    /// The camera and viewport.
    pub view: &'a LodView,
    /// Per brick (linear index): false for a culled brick.
    pub active: &'a [bool],
    /// Per brick, the normalised value range its error is weighted by (the two-level planner's
    /// screen-space error: [`crate::lod::screen_space_error`]): a brick whose range is `w`
    /// wide wants a level `log2(1 / w)` coarser than its voxels' size on screen alone asks
    /// for, a brick of one value (`w = 0`) is refined only where the rule forces it. Widths
    /// past 1 or NaN count as 1. Empty: no weighting (every brick as if `w = 1`).
    pub value_ranges: &'a [ValueRange],
    /// Levels there are (`0..levels`).
    pub levels: u32,
    /// The cache's slots.
    pub slots: u64,
    /// The largest screen-space error wanted: the on-screen size of a drawn voxel in pixels,
    /// times its brick's value-range width when `value_ranges` is given.
    pub target_pixels: f32,
    /// The last choice, one entry per brick, or empty for none (hysteresis).
    pub previous: &'a [Option<u32>],
    /// The hysteresis in levels ([`level_margin`] of the two-level planner's relative margin;
    /// 0 for none).
    pub margin: f32,
}

/// Chooses the level of every brick of `geometry` for `view` among `levels` levels (module
/// docs): `active[i]` false for a culled brick, `slots` the cache's slots, `target_pixels` the
/// largest on-screen size of a drawn voxel wanted; no value weighting, no hysteresis. A fresh
/// [`LevelChooser`]'s choice of that [`LevelRequest`]; a host that chooses every frame keeps
/// one.
///
/// Errors: a culling result of another length, 0 levels (or more than 31, or more than 3 with
/// bricks below 8 voxels), or a target that is not a positive number. A cache too small for
/// the coarsest plan is no error: the least important bricks are dropped (module docs, step 0).
pub fn choose_levels(
    geometry: &BrickGeometry,
    view: &LodView,
    active: &[bool],
    levels: u32,
    slots: u64,
    target_pixels: f32,
) -> Result<LevelChoice, LevelChoiceError> {
    LevelChooser::default()
        .choose(&LevelRequest {
            geometry,
            view,
            active,
            value_ranges: &[],
            levels,
            slots,
            target_pixels,
            previous: &[],
            margin: 0.0,
        })
        .cloned()
}

/// The hysteresis margin in levels (the log2 scale of the on-screen voxel size) of a relative
/// margin `m` ([`super::PlanOptions::hysteresis`], the two-level planner's): a brick keeps its
/// level while its drawn voxel is within a factor `1 + m` of a level boundary, so
/// `log2(1 + m)` levels (0.1375 for the default 10 %).
pub fn level_margin(relative: f32) -> f32 {
    (1.0 + relative.max(0.0)).log2()
}
