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
}

impl CullRanges {
    /// The ranges for this frame: `source`'s conservative ones, with the learned range of every
    /// brick that it culls under `cull`.
    pub(super) fn ranges<'a>(
        &'a mut self,
        source: &'a dyn BrickSource,
        geometry: &BrickGeometry,
        cull: &CullParams,
    ) -> Result<&'a [ValueRange]> {
        let Some(learned) = source.learned_value_ranges() else {
            self.from = None;
            return Ok(source.value_ranges());
        };
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
        }
        Ok(&self.merged)
    }
}
