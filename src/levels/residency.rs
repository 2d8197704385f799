//! Residency changes of a three-level cache that keep what stays (issue 19, item 4): every
//! stored brick still drawn at its level keeps its sub-slot and is not uploaded again, unless a
//! fixup rewrote its texels for neighbours that changed.
//!
//! A stored brick's texels in the cache are its own samples with, where it has a coarser
//! neighbour, the fixups' values: the border fixup rewrites a level-0 brick's inner border from
//! its level-1 neighbours, the skeleton fixup a coarser brick's boundary samples from the next
//! level (the CPU reference's `LevelField::fixed_up_sample`). Those values depend only on which
//! neighbours are one level coarser (the coarser bits of the block's bricks) and on those
//! neighbours' samples, which are the same wherever they sit. So a change uploads:
//! - every stored brick that is new (not drawn before at that level), into a free sub-slot;
//! - every kept stored brick whose block's coarser bits changed (its fixed-up texels are stale:
//!   uploaded again, and fixed up again when it has coarser neighbours now);
//!
//! and the fixups run on those bricks only. Bricks that stay keep their texels, fixed up or
//! not. When the free sub-slots cannot take the new bricks (the kept ones of a class are spread
//! over more slots than they fill), the bricks of the emptiest partly filled slot of that class
//! move into the free sub-slots of the others (each moved brick is uploaded at its new place),
//! until the new bricks fit: that always succeeds when the plan fits the cache at all. Only
//! after a change that was staged but never recorded is everything packed afresh.

use crate::cache::{block_bricks, LevelSlot, LevelSlots, SlotGeometry};
use crate::pyramid::{LevelPacking, LevelPlan, PackingError};
use glam::UVec3;

/// What one residency change stages.
#[derive(Clone, Debug)]
pub struct LevelUpdate {
    /// The packing of the new plan (tables and places of every drawn brick).
    pub packing: LevelPacking,
    /// The stored bricks to upload (and fix up), in brick order.
    pub upload: Vec<usize>,
    /// Kept stored bricks moved to another sub-slot to make room (in `upload`).
    pub moved: usize,
    /// Whether everything was packed afresh (every stored brick is in `upload`).
    pub repacked: bool,
}

/// The stored bricks a three-level cache holds and where, across residency changes.
#[derive(Clone, Debug)]
pub struct LevelResidency {
    slots: LevelSlots,
    /// Per brick: the place of the stored brick whose block starts at it.
    stored: Vec<Option<LevelSlot>>,
    /// Per brick: its coarser bits in the cache now.
    bits: Vec<u32>,
    /// Whether the cache holds what `stored` says (else the next change packs afresh).
    valid: bool,
}

impl LevelResidency {
    /// An empty cache of `geometry` for `brick_count` bricks.
    pub fn new(geometry: &SlotGeometry, brick_count: usize) -> Self {
        Self {
            slots: LevelSlots::new(geometry.slot_count()),
            stored: vec![None; brick_count],
            bits: vec![0; brick_count],
            valid: false,
        }
    }

    /// Whether the cache holds the stored brick of `level` whose block starts at brick `first`
    /// (false while the residency is invalid: the next change packs afresh).
    pub fn holds(&self, first: usize, level: u32) -> bool {
        self.valid
            && self
                .stored
                .get(first)
                .copied()
                .flatten()
                .is_some_and(|p| p.level == level)
    }

    /// Forgets what the cache holds: the next [`LevelResidency::update`] packs afresh (after a
    /// staged change was discarded or failed half-way).
    pub fn invalidate(&mut self) {
        self.valid = false;
    }

    /// Moves the cache to `plan` (module docs): the packing, and the stored bricks to upload.
    /// The residency is updated only when this succeeds.
    ///
    /// Errors: those of [`LevelPacking::stored_levels`] (another brick size, more slots than
    /// the cache has).
    pub fn update(
        &mut self,
        plan: &LevelPlan,
        geometry: &SlotGeometry,
    ) -> Result<LevelUpdate, PackingError> {
        let wanted = LevelPacking::stored_levels(plan, geometry)?;
        let count = wanted.len();
        if !self.valid || self.stored.len() != count {
            return self.repack(plan, geometry);
        }
        let bricks = plan.bricks_per_axis();
        let mut slots = self.slots.clone();
        let mut stored = self.stored.clone();
        for (i, place) in stored.iter_mut().enumerate() {
            if let Some(p) = *place {
                if wanted[i] != Some(p.level) {
                    slots.release(p);
                    *place = None;
                }
            }
        }
        let mut upload = vec![false; count];
        let mut fresh = Vec::new();
        for (i, level) in wanted.iter().enumerate() {
            let Some(level) = *level else {
                continue;
            };
            if stored[i].is_none() {
                fresh.push((i, level));
            } else if self.block_bits_changed(plan, bricks, i, level) {
                upload[i] = true;
            }
        }
        // New bricks into free sub-slots; when they do not fit, move the bricks of the emptiest
        // partly filled slot into the others of its class (each move an upload) and try again.
        let mut moved = 0;
        loop {
            let mut trial = slots.clone();
            let places: Option<Vec<LevelSlot>> = fresh
                .iter()
                .map(|&(_, level)| trial.allocate(level))
                .collect();
            if let Some(places) = places {
                for (&(i, _), place) in fresh.iter().zip(places) {
                    stored[i] = Some(place);
                    upload[i] = true;
                }
                slots = trial;
                break;
            }
            match compact_one_slot(&mut slots, &mut stored, &mut upload) {
                Some(count) => moved += count,
                None => return self.repack(plan, geometry),
            }
        }
        let upload: Vec<usize> = (0..count).filter(|&i| upload[i]).collect();
        let packing = LevelPacking::from_places(plan, geometry, &stored);
        self.slots = slots;
        self.stored = stored;
        self.bits = packing.neighbours.clone();
        Ok(LevelUpdate {
            packing,
            upload,
            moved,
            repacked: false,
        })
    }

    /// Whether a brick of the block of `level` starting at brick `first` has other coarser bits
    /// in `plan` than in the cache now.
    fn block_bits_changed(
        &self,
        plan: &LevelPlan,
        bricks: UVec3,
        first: usize,
        level: u32,
    ) -> bool {
        let i = first as u32;
        let start = UVec3::new(
            i % bricks.x,
            (i / bricks.x) % bricks.y,
            i / (bricks.x * bricks.y),
        );
        let end = (start + UVec3::splat(block_bricks(level))).min(bricks);
        (start.z..end.z).any(|z| {
            (start.y..end.y).any(|y| {
                (start.x..end.x).any(|x| {
                    let j = (x + bricks.x * (y + bricks.y * z)) as usize;
                    plan.coarser_bits(j) != self.bits[j]
                })
            })
        })
    }

    /// Packs `plan` afresh ([`LevelPacking::new`]): every stored brick uploaded.
    fn repack(
        &mut self,
        plan: &LevelPlan,
        geometry: &SlotGeometry,
    ) -> Result<LevelUpdate, PackingError> {
        let packing = LevelPacking::new(plan, geometry)?;
        let mut slots = LevelSlots::new(geometry.slot_count());
        let mut stored = vec![None; packing.places.len()];
        // Take the packing's places so that later changes allocate around them.
        for &i in &packing.stored {
            if let Some(p) = packing.places[i] {
                let taken = slots.take(p);
                debug_assert!(taken, "a packing never places two stored bricks together");
                stored[i] = Some(p);
            }
        }
        self.slots = slots;
        self.stored = stored;
        self.bits = packing.neighbours.clone();
        self.valid = true;
        Ok(LevelUpdate {
            upload: packing.stored.clone(),
            packing,
            moved: 0,
            repacked: true,
        })
    }
}

/// Empties one partly filled slot of level 1 or of level 2 and past, the one with the fewest
/// stored bricks whose bricks the other partly filled slots of its class can take: its bricks
/// move there (`stored` updated, each marked in `upload`). Returns how many moved, `None` when
/// no slot can be emptied.
fn compact_one_slot(
    slots: &mut LevelSlots,
    stored: &mut [Option<LevelSlot>],
    upload: &mut [bool],
) -> Option<usize> {
    let victim = slots.emptiable_slot()?;
    let moving: Vec<usize> = (0..stored.len())
        .filter(|&i| stored[i].is_some_and(|p| p.slot == victim))
        .collect();
    for &i in &moving {
        if let Some(p) = stored[i] {
            slots.release(p);
        }
    }
    for &i in &moving {
        let Some(old) = stored[i] else {
            continue;
        };
        // The other slots of the class have room (emptiable_slot checked): the brick lands there.
        let place = slots.allocate(old.level);
        debug_assert!(place.is_some_and(|p| p.slot != victim));
        stored[i] = place;
        upload[i] = true;
    }
    Some(moving.len())
}
