//! [`CullRanges`]: the per-brick value ranges [`VolumePass::update`](super::VolumePass::update)
//! hands the planner when the source learns exact ranges while streaming
//! ([`BrickSource::learned_value_ranges`]).
//!
//! A brick whose learned range is culled under this frame's criteria gets its learned range (so
//! the planner culls it: it is empty under the transfer function, and none of its levels is
//! requested any more); every other brick keeps its conservative range
//! ([`BrickSource::value_ranges`]). The learned ranges serve culling only, because the planner
//! also ranks bricks by their range width (the screen-space error): exact widths for the
//! bricks streamed so far against conservative ones for the rest would rank every brick not yet
//! streamed above the streamed ones, and under a RAM cut the request would then move on to
//! new bricks frame after frame until the whole image was fetched (the remote render test
//! fetched all of its image that way, against under half with this rule).
//!
//! The merged ranges are rebuilt only when the source hands out a new snapshot or the culling
//! criteria change, so they change (and the planner culls again) only when they must.

use crate::bricks::{BrickSource, ValueRange};
use crate::error::Result;
use crate::lod::{cull_bricks_into, BrickGeometry, CullParams};
use std::sync::Arc;

/// The ranges the planner culls and ranks with (see the [module docs](self)).
#[derive(Debug, Default)]
pub(super) struct CullRanges {
    /// The learned snapshot and criteria `merged` was built from.
    from: Option<(Arc<[ValueRange]>, CullParams)>,
    merged: Vec<ValueRange>,
    active: Vec<bool>,
    /// Changed whenever the ranges handed out may have changed
    /// ([`crate::plan::FrameInput::ranges_generation`]).
    generation: u64,
    /// The source's ranges handed out last (address and length), when they were not merged.
    handed_out: Option<(usize, usize)>,
}

impl CullRanges {
    /// The ranges for this frame: `source`'s conservative ones, with the learned range of every
    /// brick that it culls under `cull`; and their generation, which changes whenever they may
    /// have (a rebuild of the merged ranges, or another slice of the source's: a source's
    /// [`BrickSource::value_ranges`] borrow it immutably, so the same slice holds the same
    /// ranges).
    pub(super) fn ranges<'a>(
        &'a mut self,
        source: &'a dyn BrickSource,
        geometry: &BrickGeometry,
        cull: &CullParams,
    ) -> Result<(&'a [ValueRange], u64)> {
        let Some(learned) = source.learned_value_ranges() else {
            self.from = None;
            let ranges = source.value_ranges();
            let slice = (ranges.as_ptr() as usize, ranges.len());
            if self.handed_out != Some(slice) {
                self.handed_out = Some(slice);
                self.generation += 1;
            }
            return Ok((ranges, self.generation));
        };
        self.handed_out = None;
        let fresh = self
            .from
            .as_ref()
            .is_some_and(|(l, c)| Arc::ptr_eq(l, &learned) && c == cull);
        if !fresh {
            self.from = None;
            cull_bricks_into(geometry, &learned, cull, &mut self.active)?;
            let conservative = source.value_ranges();
            self.merged.clear();
            self.merged.extend(
                conservative
                    .iter()
                    .zip(learned.iter())
                    .zip(&self.active)
                    .map(|((&c, &l), &active)| if active { c } else { l }),
            );
            self.from = Some((learned, cull.clone()));
            self.generation += 1;
        }
        Ok((&self.merged, self.generation))
    }
}
