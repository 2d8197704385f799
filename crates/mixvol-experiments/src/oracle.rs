//! The CPU reference image of what a renderer drew: the oracle (`mixvol::reference`) behind
//! `mixvol render --compare`, which the command line reaches only through here (the library's
//! production code never names the oracle, and the command line is a user of the library).

use glam::Vec4;
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::cache::{BrickCache, SlotGeometry};
use mixvol::optics::TransferFunction;
use mixvol::pyramid::LevelGrid;
use mixvol::reference::{self, slots_needed, LevelField, LevelReferenceCache, ReferenceCache};
use mixvol::scene::{RaycastParams, RenderSettings, Transition};
use mixvol::volume::{ScalarType, Volume};
use mixvol::{Error, Result};

/// What a renderer drew, as the CPU reference rebuilds it.
pub enum Drawn<'a> {
    /// A volume in memory, drawn whole.
    Volume(&'a Volume),
    /// A volume through the two-level brick cache, as `cache` holds it.
    BrickCache {
        /// The volume.
        volume: &'a Volume,
        /// The filter of its low-res level.
        filter: DownsampleFilter,
        /// The cache model the renderer drew.
        cache: &'a BrickCache,
        /// The reconstruction across level changes.
        transition: Transition,
    },
    /// A level source: every level's samples and the level of every brick drawn.
    Levels {
        /// The brick grid (level 0).
        grid: BrickGrid,
        /// The levels' samples, levels 0, 1, ... up to the deepest drawn.
        grids: &'a [LevelGrid],
        /// The level of every brick, `None` where none is drawn.
        levels: &'a [Option<u32>],
        /// The cache's texel type (the reference rounds its texels alike).
        scalar: ScalarType,
        /// The reconstruction across level changes.
        transition: Transition,
    },
}

/// The CPU reference frame of `drawn` under `tf`, `settings` and the frame's parameter block
/// `params` (the renderer's own, so both see the same rays).
///
/// Errors: levels that break the rules or do not match the grids, and what the reference
/// refuses (settings).
pub fn reference_frame(
    drawn: Drawn<'_>,
    tf: &TransferFunction,
    settings: &RenderSettings,
    params: &RaycastParams,
) -> Result<Vec<Vec4>> {
    match drawn {
        Drawn::Volume(volume) => reference::render_scene(volume, tf, settings, params),
        Drawn::BrickCache {
            volume,
            filter,
            cache,
            transition,
        } => {
            let cache =
                ReferenceCache::build(volume, filter, cache, volume.scalar_type(), transition)?;
            reference::render_mixed_scene(&cache.view(), transition, tf, settings, params)
        }
        Drawn::Levels {
            grid,
            grids,
            levels,
            scalar,
            transition,
        } => {
            // The three-level cache's CPU mirror; the slots' places do not change the field.
            let field = LevelField::new(&grid, grids, levels)?;
            let slots = u32::try_from(slots_needed(&field)).unwrap_or(u32::MAX);
            // The slot classes the pass's cache has for this many levels.
            let classes = mixvol::cache::classes_for_levels(grids.len() as u32);
            let geometry =
                SlotGeometry::choose(grid.brick_size(), classes, 4, u64::MAX, 16384, slots)
                    .map_err(Error::from)?;
            let cache =
                LevelReferenceCache::build_stored_as(&field, &geometry, transition, scalar)?;
            reference::render_mixed_scene(&cache.view(), transition, tf, settings, params)
        }
    }
}
