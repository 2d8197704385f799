//! The brick cache model: which brick lives where in the 3D cache image, what must be uploaded when
//! the residency plan changes, and the tables the shaders read (Beyer et al. 2008 §3.2-3.3, §4.2-4.3).
//!
//! Everything here is CPU-only bookkeeping; the contract with the shaders and the CPU reference is
//! `docs/cache-layout.md`, which this module implements exactly.
//!
//! # Pieces
//!
//! - [`CacheGeometry`]: brick size `n`, cache extent `C` (a power of two per axis, chosen by
//!   [`CacheGeometry::choose`] within `maxImageDimension3D` and a byte budget), `(n+2)^3` slots and
//!   their eight `(n/2+1)^3` sub-slots.
//! - [`Level`] (`Hi`, `Lo`, `Absent`; defined beside the bricks, [`crate::bricks::Level`]) is
//!   what the LOD selector wants per brick; [`Residency`] is where the cache put it (slot, or slot
//!   and sub-slot).
//! - [`BrickCache::update`] turns a wanted-level vector into a new residency and a
//!   [`CacheUpdate`]: the minimal [`BrickUpload`] list, the evicted bricks and whether the tables
//!   changed.
//! - The tables ([`BrickCache::layout_table`], [`BrickCache::neighbour_bits`],
//!   [`BrickCache::reverse_table`], [`BrickCache::fixup_slots`]) are computed from the current
//!   residency on demand; [`tables`] has the per-brick formulas as free functions.
//!
//! # Allocation design
//!
//! Live slot allocations are held in a [`slotmap::SlotMap`]: each allocated slot (a whole hi-res
//! slot, or a split slot with its eight sub-slot occupants) gets a generation-checked key, and a
//! per-slot-index table points at the key of the allocation occupying it. Freed slot indices go to
//! a free list (an ordered set, so allocation always takes the lowest free index and results are
//! deterministic). A slot index reused by a new allocation gets a new key, so a stale reference to
//! the old allocation can never alias the new one.
//!
//! # Update rules
//!
//! The cache never chooses levels: a plan needs `#Hi + ceil(#Lo / 8)` slots and is rejected with
//! [`CacheError::OverBudget`] (state unchanged) when that exceeds the capacity; demoting is the
//! LOD selector's job. Otherwise the update always succeeds:
//!
//! 1. *Stability.* A brick whose level is unchanged keeps its slot / sub-slot and is not
//!    re-uploaded (except low-res bricks moved by compaction, below).
//! 2. *Release.* Bricks whose level changed (or that became absent) release their storage first. A
//!    split slot whose eight sub-slots are all free merges back into a free whole slot at once.
//! 3. *Placement.* New low-res bricks first fill free sub-slots of already split slots (fullest slot
//!    first, so split slots fill up), then split free whole slots. New hi-res bricks take free whole
//!    slots (lowest index first).
//! 4. *Compaction.* When the new hi-res bricks need more whole slots than are free but free space
//!    exists only as scattered sub-slots, the least occupied split slot is evacuated: its low-res
//!    bricks move into free sub-slots of the fullest other split slots, and the emptied slot merges
//!    back into a free whole slot. This repeats until enough whole slots are free. Each moved brick
//!    is re-uploaded at its new place (and listed in [`CacheUpdate::moved`]). Compaction always
//!    succeeds when the count rule holds: while there are more split slots than `ceil(#Lo / 8)`,
//!    the other split slots have room for the least occupied one's bricks.
//! 5. *Border restore.* The fixup pass overwrites the duplicated border of a hi-res brick next to
//!    a low-res neighbour and never restores it. A hi-res brick that stays in place but loses a
//!    low-res neighbour (the neighbour became hi-res or absent) therefore holds stale border
//!    texels; it is re-uploaded (listed in [`CacheUpdate::restored_borders`]) so that its border
//!    holds the original duplicated voxels again before the fixup reruns.
//!
//! The upload list is the diff between the old and the new residency: exactly the bricks whose
//! slot / sub-slot (or level) changed and are resident now, plus the border restores of rule 5.
//! Since the final texel boxes of resident bricks never overlap, a brick that keeps its place keeps
//! its texels.

mod geometry;
mod level_slots;
mod residency;
mod slot_geometry;
pub mod tables;

#[cfg(test)]
mod translation_tests;

pub use geometry::{CacheGeometry, MIN_BRICK_SIZE};
pub use level_slots::LevelSlots;
pub use residency::{BrickCache, BrickUpload, CacheUpdate};
pub use slot_geometry::{
    block_bricks, block_origin, classes_for_levels, min_brick_size_for_levels, pyramid_levels,
    slots_for_classes, slots_for_plan, stored_brick_edge, stored_bricks_per_axis,
    stored_first_sample, LevelSlot, SlotGeometry, THREE_LEVELS,
};
pub use tables::{
    compute_neighbour_bits, layout_entry, neighbour_bit, neighbour_bit_index, neighbour_offset,
    EMPTY, NEIGHBOUR_COUNT,
};

use crate::bricks::Level;

/// Where a brick lives in the cache.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub enum Residency {
    /// Not in the cache.
    #[default]
    Absent,
    /// A hi-res brick occupying the whole slot `slot`.
    Hi {
        /// Linear slot index.
        slot: u32,
    },
    /// A low-res brick in sub-slot `sub_slot` (in `0..8`) of the split slot `slot`.
    Lo {
        /// Linear slot index.
        slot: u32,
        /// Sub-slot index `j`; its offset in the slot is `(j & 1, (j >> 1) & 1, (j >> 2) & 1) *
        /// (n/2 + 1)`.
        sub_slot: u32,
    },
}

impl Residency {
    /// The level this residency stores.
    pub fn level(self) -> Level {
        match self {
            Residency::Absent => Level::Absent,
            Residency::Hi { .. } => Level::Hi,
            Residency::Lo { .. } => Level::Lo,
        }
    }

    /// The slot index, `None` when absent.
    pub fn slot(self) -> Option<u32> {
        match self {
            Residency::Absent => None,
            Residency::Hi { slot } | Residency::Lo { slot, .. } => Some(slot),
        }
    }
}

/// Errors from cache geometry selection and residency updates.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CacheError {
    /// The brick size is not a power of two in `MIN_BRICK_SIZE..=MAX_BRICK_SIZE`.
    #[error(
        "brick size {size} must be a power of two between {MIN_BRICK_SIZE} and {}",
        crate::bricks::MAX_BRICK_SIZE
    )]
    InvalidBrickSize {
        /// The size given.
        size: u32,
    },
    /// A slot geometry of a class count other than 2 or 3.
    #[error("a brick cache has 2 or 3 slot classes, not {classes}")]
    InvalidClasses {
        /// The count given.
        classes: u32,
    },
    /// `bytes_per_texel` is zero.
    #[error("bytes per texel must be positive")]
    ZeroBytesPerTexel,
    /// Not even one slot fits within the device's 3D image dimension limit.
    #[error(
        "a cache slot needs {slot_edge} texels per axis (rounded up to a power of two) but \
         maxImageDimension3D is {max_dim_3d}"
    )]
    SlotExceedsMaxDimension {
        /// Slot edge `n + 2`.
        slot_edge: u32,
        /// The device limit given.
        max_dim_3d: u32,
    },
    /// Not even one slot fits in the byte budget.
    #[error(
        "cache budget of {byte_budget} bytes is below the smallest cache holding one slot \
         ({extent:?} texels, {needed_bytes} bytes)"
    )]
    BudgetBelowOneSlot {
        /// The smallest cache extent that holds one slot.
        extent: [u32; 3],
        /// Its size in bytes.
        needed_bytes: u128,
        /// The budget given.
        byte_budget: u64,
    },
    /// A cache extent axis is not a power of two or is smaller than one slot.
    #[error("cache extent {extent:?} must be powers of two of at least one slot ({slot_edge})")]
    InvalidExtent {
        /// The extent given.
        extent: [u32; 3],
        /// Slot edge `n + 2`.
        slot_edge: u32,
    },
    /// The cache has more slots than a `u32` slot index (below [`EMPTY`]) can address.
    #[error("cache has {slots} slots; slot indices must stay below u32::MAX")]
    TooManySlots {
        /// The slot count.
        slots: u64,
    },
    /// The brick grid has more bricks than a `u32` brick index (below [`EMPTY`]) can address.
    #[error("brick grid has {bricks} bricks; brick indices must stay below u32::MAX")]
    TooManyBricks {
        /// The brick count.
        bricks: usize,
    },
    /// The brick grid and the cache geometry disagree on the brick size.
    #[error("brick grid uses brick size {grid} but the cache geometry {cache}")]
    BrickSizeMismatch {
        /// Brick size of the grid.
        grid: u32,
        /// Brick size of the cache geometry.
        cache: u32,
    },
    /// The wanted-level vector does not have one entry per brick.
    #[error("wanted levels hold {actual} entries but the brick grid has {expected} bricks")]
    WrongLength {
        /// Bricks in the grid.
        expected: usize,
        /// Entries given.
        actual: usize,
    },
    /// The plan needs more slots than the cache has; the LOD selector must demote or cull first.
    #[error(
        "residency plan needs {} slots ({hi} hi-res bricks + ceil({lo} low-res bricks / 8)) but \
         the cache has {slots}; demote or cull bricks before updating",
        .hi + .lo.div_ceil(8)
    )]
    OverBudget {
        /// Hi-res bricks wanted.
        hi: usize,
        /// Low-res bricks wanted.
        lo: usize,
        /// Slots available.
        slots: usize,
    },
    /// Compaction could not free enough whole slots although the count rule holds. This is an
    /// internal invariant violation (a bug); the cache state is left unchanged.
    #[error(
        "internal error: compaction could not free {needed} whole slots ({free} free); cache \
         state left unchanged"
    )]
    CompactionFailed {
        /// Whole slots needed.
        needed: usize,
        /// Whole slots free.
        free: usize,
    },
}
