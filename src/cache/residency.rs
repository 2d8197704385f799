//! [`BrickCache`]: slot allocation, residency updates with stable placement, split/merge,
//! compaction, and the tables derived from the residency. The rules are in the module docs of
//! [`crate::cache`].

use super::tables::{brick_neighbour_bits, layout_entry, EMPTY};
use super::{CacheError, CacheGeometry, Residency};
use crate::bricks::{BrickGrid, Level, SUB_SLOTS_PER_SLOT};
use slotmap::{new_key_type, SlotMap};
use std::cmp::Reverse;
use std::collections::BTreeSet;

new_key_type! {
    /// Key of a live slot allocation (generation-checked, so a reused slot index gets a new key).
    struct AllocationKey;
}

const SUBS: usize = SUB_SLOTS_PER_SLOT as usize;

/// What an allocated slot holds.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Contents {
    /// One hi-res brick.
    Whole(u32),
    /// Eight sub-slots, each a low-res brick or [`EMPTY`]; at least one is occupied.
    Split([u32; SUBS]),
}

/// A live slot allocation.
#[derive(Clone, Debug)]
struct Allocation {
    slot: u32,
    contents: Contents,
}

/// The mutable residency state; cloned for each update so a failed update changes nothing.
#[derive(Clone, Debug)]
struct State {
    /// Live allocations.
    allocations: SlotMap<AllocationKey, Allocation>,
    /// Per usable slot index: the allocation occupying it.
    slot_keys: Vec<Option<AllocationKey>>,
    /// Free whole slots (neither hi-res nor split), lowest index allocated first.
    free: BTreeSet<u32>,
    /// Per brick: where it lives.
    residency: Vec<Residency>,
}

/// One brick to write into the cache image.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BrickUpload {
    /// Linear brick index.
    pub brick: u32,
    /// The level to pack (`Hi` or `Lo`, never `Absent`).
    pub level: Level,
    /// Destination texel origin in the cache image.
    pub dst_origin: [u32; 3],
    /// Texels per axis: `S^3` for `Hi`, `(n/2+1)^3` for `Lo`.
    pub extent: [u32; 3],
}

/// The result of [`BrickCache::update`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CacheUpdate {
    /// Bricks to pack and write, in ascending brick order: bricks newly resident or at a new
    /// level, low-res bricks moved by compaction, and hi-res bricks whose border needs restoring.
    pub uploads: Vec<BrickUpload>,
    /// Bricks that were resident and are now absent, ascending.
    pub evicted: Vec<u32>,
    /// Low-res bricks that kept their level but were moved by compaction (each also in
    /// `uploads`), ascending.
    pub moved: Vec<u32>,
    /// Hi-res bricks that stayed in place but lost a low-res neighbour, so their fixed-up border
    /// is stale; re-uploaded (each also in `uploads`), ascending.
    pub restored_borders: Vec<u32>,
    /// True when any brick's residency changed: the layout, neighbour and reverse tables and the
    /// fixup list must be re-uploaded and the fixup pass rerun.
    pub tables_changed: bool,
}

impl CacheUpdate {
    /// True when nothing has to be uploaded or rebuilt.
    pub fn is_empty(&self) -> bool {
        !self.tables_changed && self.uploads.is_empty()
    }
}

/// The residency model of the brick cache: which brick lives in which slot / sub-slot.
///
/// See the [module documentation](crate::cache) for the allocation design and the update rules.
#[derive(Clone, Debug)]
pub struct BrickCache {
    grid: BrickGrid,
    geometry: CacheGeometry,
    capacity: u32,
    state: State,
}

impl BrickCache {
    /// An empty cache for the bricks of `grid`, using every slot of `geometry`.
    pub fn new(grid: BrickGrid, geometry: CacheGeometry) -> Result<Self, CacheError> {
        Self::with_slot_limit(grid, geometry, u32::MAX)
    }

    /// An empty cache that uses only the first `max_slots` slots of `geometry` (all of them when
    /// `max_slots >= geometry.slot_count()`); handy to model memory pressure on a small image.
    pub fn with_slot_limit(
        grid: BrickGrid,
        geometry: CacheGeometry,
        max_slots: u32,
    ) -> Result<Self, CacheError> {
        if grid.brick_size() != geometry.brick_size() {
            return Err(CacheError::BrickSizeMismatch {
                grid: grid.brick_size(),
                cache: geometry.brick_size(),
            });
        }
        let bricks = grid.brick_count();
        if bricks >= EMPTY as usize {
            return Err(CacheError::TooManyBricks { bricks });
        }
        let capacity = max_slots.min(geometry.slot_count());
        Ok(Self {
            grid,
            geometry,
            capacity,
            state: State::empty(capacity, bricks),
        })
    }

    /// The brick grid.
    pub fn grid(&self) -> &BrickGrid {
        &self.grid
    }

    /// The cache geometry.
    pub fn geometry(&self) -> &CacheGeometry {
        &self.geometry
    }

    /// Usable slots.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Free whole slots.
    pub fn free_slot_count(&self) -> usize {
        self.state.free.len()
    }

    /// Slots split into sub-slots.
    pub fn split_slot_count(&self) -> usize {
        self.state
            .allocations
            .values()
            .filter(|a| matches!(a.contents, Contents::Split(_)))
            .count()
    }

    /// Where brick `brick` lives (`Absent` for indices outside the grid).
    pub fn residency(&self, brick: u32) -> Residency {
        self.state
            .residency
            .get(brick as usize)
            .copied()
            .unwrap_or_default()
    }

    /// Residency of every brick, by linear brick index.
    pub fn residencies(&self) -> &[Residency] {
        &self.state.residency
    }

    /// Current level of every brick, by linear brick index.
    pub fn levels(&self) -> Vec<Level> {
        self.state.residency.iter().map(|r| r.level()).collect()
    }

    /// The slots a plan with `hi` hi-res and `lo` low-res bricks needs: `hi + ceil(lo / 8)`.
    pub fn slots_needed(hi: usize, lo: usize) -> usize {
        hi + lo.div_ceil(SUBS)
    }

    /// Makes every brick absent (e.g. after the cache image was recreated); the next update
    /// uploads everything it places.
    pub fn clear(&mut self) {
        self.state = State::empty(self.capacity, self.grid.brick_count());
    }

    /// Moves the cache to the levels `wanted` (one per brick, linear brick index) and returns
    /// what must be uploaded. See the [module documentation](crate::cache) for the rules.
    ///
    /// Errors (cache unchanged): [`CacheError::WrongLength`] when `wanted` does not have one entry
    /// per brick, and [`CacheError::OverBudget`] when `#Hi + ceil(#Lo / 8)` exceeds
    /// [`BrickCache::capacity`].
    pub fn update(&mut self, wanted: &[Level]) -> Result<CacheUpdate, CacheError> {
        let bricks = self.state.residency.len();
        if wanted.len() != bricks {
            return Err(CacheError::WrongLength {
                expected: bricks,
                actual: wanted.len(),
            });
        }
        let hi = wanted.iter().filter(|&&l| l == Level::Hi).count();
        let lo = wanted.iter().filter(|&&l| l == Level::Lo).count();
        let slots = self.capacity as usize;
        if Self::slots_needed(hi, lo) > slots {
            return Err(CacheError::OverBudget { hi, lo, slots });
        }

        let mut next = self.state.clone();
        for (brick, &level) in wanted.iter().enumerate() {
            if next.residency[brick].level() != level {
                next.release(brick as u32);
            }
        }
        let absent_with = |next: &State, level: Level| -> Vec<u32> {
            (0..bricks as u32)
                .filter(|&b| {
                    wanted[b as usize] == level && next.residency[b as usize] == Residency::Absent
                })
                .collect()
        };
        let new_hi = absent_with(&next, Level::Hi);
        let new_lo = absent_with(&next, Level::Lo);

        let placed = next.fill_split_slots(&new_lo);
        let rest = &new_lo[placed..];
        let needed = new_hi.len() + rest.len().div_ceil(SUBS);
        next.compact(needed)?;
        for &brick in &new_hi {
            let slot = next.take_free_slot(needed)?;
            next.place_hi(brick, slot);
        }
        for chunk in rest.chunks(SUBS) {
            let slot = next.take_free_slot(needed)?;
            let key = next.allocations.insert(Allocation {
                slot,
                contents: Contents::Split([EMPTY; SUBS]),
            });
            next.slot_keys[slot as usize] = Some(key);
            for (sub, &brick) in chunk.iter().enumerate() {
                next.place_lo(brick, key, sub);
            }
        }

        let update = self.diff(&next.residency, wanted);
        self.state = next;
        Ok(update)
    }

    /// The update from the current residency to `new` (with levels `wanted`).
    fn diff(&self, new: &[Residency], wanted: &[Level]) -> CacheUpdate {
        let old = &self.state.residency;
        let old_level = |i: usize| old[i].level();
        let new_level = |i: usize| wanted[i];
        let mut update = CacheUpdate::default();
        for (i, (&before, &after)) in old.iter().zip(new).enumerate() {
            let brick = i as u32;
            let mut upload = before != after;
            if before != after {
                update.tables_changed = true;
                if after == Residency::Absent {
                    update.evicted.push(brick);
                } else if before.level() == after.level() {
                    update.moved.push(brick);
                }
            } else if after.level() == Level::Hi {
                let coords = self.grid.brick_coords(i);
                let lost = brick_neighbour_bits(&self.grid, coords, old_level)
                    & !brick_neighbour_bits(&self.grid, coords, new_level);
                if lost != 0 {
                    update.restored_borders.push(brick);
                    upload = true;
                }
            }
            if let (true, Some((origin, extent))) = (upload, self.geometry.texel_box(after)) {
                update.uploads.push(BrickUpload {
                    brick,
                    level: after.level(),
                    dst_origin: origin.to_array(),
                    extent: extent.to_array(),
                });
            }
        }
        update
    }

    /// Layout table, one `(t_x, t_y, t_z, t_w)` per brick in texel units (see
    /// [`layout_entry`]).
    pub fn layout_table(&self) -> Vec<[f32; 4]> {
        self.state
            .residency
            .iter()
            .enumerate()
            .map(|(i, &r)| layout_entry(&self.geometry, self.grid.brick_coords(i), r))
            .collect()
    }

    /// Neighbour bits, one per brick: for `Hi` bricks, bit `k` set when the neighbour at
    /// [`super::neighbour_offset`]`(k)` is inside the grid and `Lo`; zero otherwise.
    pub fn neighbour_bits(&self) -> Vec<u32> {
        let level = |i: usize| self.state.residency[i].level();
        self.grid
            .bricks()
            .map(|b| brick_neighbour_bits(&self.grid, b, level))
            .collect()
    }

    /// Reverse table, eight entries per slot of the geometry (all slots, also those beyond the
    /// capacity): a hi-res slot holds its brick in entry 0 and [`EMPTY`] in entries 1..8; a split
    /// slot holds the low-res brick of sub-slot `j` (or `EMPTY`) in entry `j`; a free slot is all
    /// `EMPTY`.
    pub fn reverse_table(&self) -> Vec<[u32; SUBS]> {
        let mut table = vec![[EMPTY; SUBS]; self.geometry.slot_count() as usize];
        for allocation in self.state.allocations.values() {
            let entry = &mut table[allocation.slot as usize];
            match allocation.contents {
                Contents::Whole(brick) => entry[0] = brick,
                Contents::Split(bricks) => *entry = bricks,
            }
        }
        table
    }

    /// Marks in `stale` (one flag per brick) the hi-res bricks whose fixed-up border `update`
    /// made stale, given the levels `before` it: every brick `update` uploads (a new, re-levelled,
    /// moved or border-restored brick arrives with raw borders), and every brick among the 26
    /// neighbours of a brick that became low-res (its border must now take that brick's
    /// low-res samples). A low-res brick that was only moved keeps its samples, and a lost
    /// low-res neighbour is a border restore (an upload), so nothing else is stale. Flags already
    /// set stay set (a host may stage several updates before the fixup runs).
    pub fn mark_stale_borders(&self, update: &CacheUpdate, before: &[Level], stale: &mut [bool]) {
        let size = self.grid.bricks_per_axis().as_ivec3();
        for upload in &update.uploads {
            let brick = upload.brick as usize;
            if let Some(flag) = stale.get_mut(brick) {
                *flag = true;
            }
            if upload.level != Level::Lo || before.get(brick) == Some(&Level::Lo) {
                continue;
            }
            let at = self.grid.brick_coords(brick).as_ivec3();
            for k in 0..super::tables::NEIGHBOUR_COUNT {
                let nb = at + super::tables::neighbour_offset(k);
                if nb.cmpge(glam::IVec3::ZERO).all() && nb.cmplt(size).all() {
                    if let Some(flag) = stale.get_mut(self.grid.linear_index(nb.as_uvec3())) {
                        *flag = true;
                    }
                }
            }
        }
    }

    /// The fixup dispatch list restricted to the bricks flagged in `stale`
    /// ([`BrickCache::mark_stale_borders`]): slot indices (ascending) of the flagged hi-res
    /// bricks with any neighbour bit set. The fixup is idempotent, so running it over these
    /// alone leaves the cache as [`BrickCache::fixup_slots`] would.
    pub fn stale_fixup_slots(&self, stale: &[bool]) -> Vec<u32> {
        let bits = self.neighbour_bits();
        let mut slots: Vec<u32> = self
            .state
            .residency
            .iter()
            .zip(&bits)
            .zip(stale)
            .filter_map(|((r, &b), &flag)| match r {
                Residency::Hi { slot } if b != 0 && flag => Some(*slot),
                _ => None,
            })
            .collect();
        slots.sort_unstable();
        slots
    }

    /// The fixup dispatch list: slot indices (ascending) of the hi-res bricks with any neighbour
    /// bit set.
    pub fn fixup_slots(&self) -> Vec<u32> {
        let bits = self.neighbour_bits();
        let mut slots: Vec<u32> = self
            .state
            .residency
            .iter()
            .zip(&bits)
            .filter_map(|(r, &b)| match r {
                Residency::Hi { slot } if b != 0 => Some(*slot),
                _ => None,
            })
            .collect();
        slots.sort_unstable();
        slots
    }
}

impl State {
    /// All slots free, all bricks absent.
    fn empty(capacity: u32, bricks: usize) -> Self {
        Self {
            allocations: SlotMap::with_key(),
            slot_keys: vec![None; capacity as usize],
            free: (0..capacity).collect(),
            residency: vec![Residency::Absent; bricks],
        }
    }

    /// Frees the storage of `brick` and makes it absent; an emptied split slot merges back into
    /// a free whole slot.
    fn release(&mut self, brick: u32) {
        let residency = std::mem::take(&mut self.residency[brick as usize]);
        let Some(slot) = residency.slot() else {
            return;
        };
        let Some(key) = self.slot_keys[slot as usize] else {
            return;
        };
        let now_free = match (residency, self.allocations.get_mut(key)) {
            (Residency::Hi { .. }, _) => true,
            (
                Residency::Lo { sub_slot, .. },
                Some(Allocation {
                    contents: Contents::Split(bricks),
                    ..
                }),
            ) => {
                bricks[sub_slot as usize] = EMPTY;
                bricks.iter().all(|&b| b == EMPTY)
            }
            _ => false,
        };
        if now_free {
            self.allocations.remove(key);
            self.slot_keys[slot as usize] = None;
            self.free.insert(slot);
        }
    }

    /// Puts hi-res `brick` into the free whole slot `slot`.
    fn place_hi(&mut self, brick: u32, slot: u32) {
        let key = self.allocations.insert(Allocation {
            slot,
            contents: Contents::Whole(brick),
        });
        self.slot_keys[slot as usize] = Some(key);
        self.residency[brick as usize] = Residency::Hi { slot };
    }

    /// Puts low-res `brick` into free sub-slot `sub` of the split allocation `key`.
    fn place_lo(&mut self, brick: u32, key: AllocationKey, sub: usize) {
        if let Some(Allocation {
            slot,
            contents: Contents::Split(bricks),
        }) = self.allocations.get_mut(key)
        {
            bricks[sub] = brick;
            self.residency[brick as usize] = Residency::Lo {
                slot: *slot,
                sub_slot: sub as u32,
            };
        }
    }

    /// Split allocations with free sub-slots as `(occupied, slot, key)`, fullest first, then by
    /// slot index.
    fn partial_split_slots(&self) -> Vec<(usize, u32, AllocationKey)> {
        let mut partial: Vec<_> = self
            .allocations
            .iter()
            .filter_map(|(key, a)| match &a.contents {
                Contents::Split(bricks) => Some((occupied(bricks), a.slot, key)),
                Contents::Whole(_) => None,
            })
            .filter(|&(occ, _, _)| occ < SUBS)
            .collect();
        partial.sort_unstable_by_key(|&(occ, slot, _)| (Reverse(occ), slot));
        partial
    }

    /// First free sub-slot of split allocation `key`.
    fn free_sub_slot(&self, key: AllocationKey) -> Option<usize> {
        match &self.allocations.get(key)?.contents {
            Contents::Split(bricks) => bricks.iter().position(|&b| b == EMPTY),
            Contents::Whole(_) => None,
        }
    }

    /// Places the leading bricks of `bricks` (low-res, absent) into free sub-slots of existing
    /// split slots, fullest slot first; returns how many were placed.
    fn fill_split_slots(&mut self, bricks: &[u32]) -> usize {
        let mut placed = 0;
        for (_, _, key) in self.partial_split_slots() {
            while placed < bricks.len() {
                let Some(sub) = self.free_sub_slot(key) else {
                    break;
                };
                self.place_lo(bricks[placed], key, sub);
                placed += 1;
            }
        }
        placed
    }

    /// Evacuates the least occupied split slots into free sub-slots of the other split slots until
    /// at least `needed` whole slots are free (see the module docs).
    fn compact(&mut self, needed: usize) -> Result<(), CacheError> {
        while self.free.len() < needed {
            let failed = CacheError::CompactionFailed {
                needed,
                free: self.free.len(),
            };
            let splits = self.partial_split_slots();
            // Least occupied; among equals the highest slot, so low slots stay in use.
            let Some(&(occ, source_slot, source)) = splits
                .iter()
                .min_by_key(|&&(occ, slot, _)| (occ, Reverse(slot)))
            else {
                return Err(failed);
            };
            let room: usize = splits
                .iter()
                .filter(|&&(_, slot, _)| slot != source_slot)
                .map(|&(o, _, _)| SUBS - o)
                .sum();
            if room < occ {
                return Err(failed);
            }
            let Some(Allocation {
                contents: Contents::Split(bricks),
                ..
            }) = self.allocations.get(source).cloned()
            else {
                return Err(failed);
            };
            let targets: Vec<AllocationKey> = splits
                .iter()
                .filter(|&&(_, slot, _)| slot != source_slot)
                .map(|&(_, _, key)| key)
                .collect();
            let free_before = self.free.len();
            let mut target = targets.iter().copied();
            let mut current = target.next();
            for brick in bricks.into_iter().filter(|&b| b != EMPTY) {
                let (key, sub) = loop {
                    let key = current.ok_or(failed.clone())?;
                    match self.free_sub_slot(key) {
                        Some(sub) => break (key, sub),
                        None => current = target.next(),
                    }
                };
                self.release(brick);
                self.place_lo(brick, key, sub);
            }
            // The evacuated slot must have merged back; never loop without progress.
            if self.free.len() <= free_before {
                return Err(failed);
            }
        }
        Ok(())
    }

    /// Takes the lowest free whole slot.
    fn take_free_slot(&mut self, needed: usize) -> Result<u32, CacheError> {
        self.free
            .pop_first()
            .ok_or(CacheError::CompactionFailed { needed, free: 0 })
    }
}

/// Occupied sub-slots of a split slot.
fn occupied(bricks: &[u32; SUBS]) -> usize {
    bricks.iter().filter(|&&b| b != EMPTY).count()
}

#[cfg(test)]
mod tests {
    use super::super::tables::compute_neighbour_bits;
    use super::*;
    use glam::{UVec3, Vec3};
    use std::collections::BTreeMap;

    /// Only the bricks whose border a change made stale are fixed up again: the uploaded ones and
    /// the hi-res neighbours of a brick that became low-res; a far hi-res brick is left alone,
    /// and a second update before the fixup keeps the first one's flags.
    #[test]
    fn stale_borders_are_the_uploads_and_the_neighbours_of_new_low_res_bricks() {
        let grid = BrickGrid::new(UVec3::new(16, 4, 4), 4).unwrap();
        let geometry = CacheGeometry::new(4, UVec3::splat(32)).unwrap();
        let mut cache = BrickCache::new(grid, geometry).unwrap();
        let hi = vec![Level::Hi; 4];
        let first = cache.update(&hi).unwrap();
        let mut stale = vec![false; 4];
        cache.mark_stale_borders(&first, &[Level::Absent; 4], &mut stale);
        assert_eq!(stale, [true; 4], "a first upload makes every border stale");
        assert!(
            cache.stale_fixup_slots(&stale).is_empty(),
            "no low-res neighbour yet"
        );
        // Brick 3 becomes low-res: brick 2 next to it must take its samples; 0 and 1 must not.
        let mut stale = vec![false; 4];
        let levels = [Level::Hi, Level::Hi, Level::Hi, Level::Lo];
        let update = cache.update(&levels).unwrap();
        cache.mark_stale_borders(&update, &hi, &mut stale);
        assert_eq!(stale, [false, false, true, true]);
        let slot_of = |cache: &BrickCache, b: usize| match cache.residencies()[b] {
            Residency::Hi { slot } => slot,
            r => panic!("brick {b}: {r:?}"),
        };
        assert_eq!(cache.stale_fixup_slots(&stale), vec![slot_of(&cache, 2)]);
        assert_eq!(cache.fixup_slots(), vec![slot_of(&cache, 2)]);
        // Brick 0 becomes low-res too, before a fixup ran: 1 joins, 2 stays flagged.
        let update = cache
            .update(&[Level::Lo, Level::Hi, Level::Hi, Level::Lo])
            .unwrap();
        cache.mark_stale_borders(&update, &levels, &mut stale);
        let mut expected = vec![slot_of(&cache, 1), slot_of(&cache, 2)];
        expected.sort_unstable();
        assert_eq!(cache.stale_fixup_slots(&stale), expected);
    }

    /// Xorshift64 for reproducible randomized tests.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        fn below(&mut self, m: u64) -> u64 {
            self.next() % m
        }

        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// n = 4 (slot edge 6), a 64^3 cache (10^3 slots), a 5x4x3 brick grid.
    fn cache_5x4x3(max_slots: u32) -> BrickCache {
        let grid = BrickGrid::new(UVec3::new(20, 16, 12), 4).unwrap();
        let geometry = CacheGeometry::new(4, UVec3::splat(64)).unwrap();
        BrickCache::with_slot_limit(grid, geometry, max_slots).unwrap()
    }

    fn levels_with(count: usize, set: &[(usize, Level)]) -> Vec<Level> {
        let mut levels = vec![Level::Absent; count];
        for &(i, l) in set {
            levels[i] = l;
        }
        levels
    }

    /// Checks the internal bookkeeping and the public invariants: every usable slot is free,
    /// hi-res or split (exactly one), residency matches the allocations, texel boxes are disjoint
    /// and inside the cache, and the reverse table lists every resident brick exactly once.
    fn check_consistency(cache: &BrickCache) {
        let state = &cache.state;
        let g = cache.geometry();
        assert_eq!(
            state.free.len() + state.allocations.len(),
            cache.capacity() as usize,
            "every usable slot is free or allocated"
        );
        for (key, a) in &state.allocations {
            assert!(a.slot < cache.capacity());
            assert!(
                !state.free.contains(&a.slot),
                "slot {} free and used",
                a.slot
            );
            assert_eq!(state.slot_keys[a.slot as usize], Some(key));
            match a.contents {
                Contents::Whole(b) => {
                    assert_eq!(state.residency[b as usize], Residency::Hi { slot: a.slot })
                }
                Contents::Split(bricks) => {
                    assert!(
                        occupied(&bricks) > 0,
                        "empty split slot {} not merged",
                        a.slot
                    );
                    for (j, &b) in bricks.iter().enumerate() {
                        if b != EMPTY {
                            assert_eq!(
                                state.residency[b as usize],
                                Residency::Lo {
                                    slot: a.slot,
                                    sub_slot: j as u32
                                }
                            );
                        }
                    }
                }
            }
        }
        // Disjoint texel boxes inside the cache extent.
        let boxes: Vec<(usize, UVec3, UVec3)> = state
            .residency
            .iter()
            .enumerate()
            .filter_map(|(i, &r)| g.texel_box(r).map(|(o, e)| (i, o, e)))
            .collect();
        for &(i, o, e) in &boxes {
            assert!(
                (o + e).cmple(g.extent()).all(),
                "brick {i} outside the cache"
            );
        }
        for (x, &(i, oi, ei)) in boxes.iter().enumerate() {
            for &(j, oj, ej) in &boxes[x + 1..] {
                let overlap = oi.cmplt(oj + ej).all() && oj.cmplt(oi + ei).all();
                assert!(!overlap, "bricks {i} and {j} overlap");
            }
        }
        // Reverse table: every resident brick exactly once, at its slot / sub-slot.
        let reverse = cache.reverse_table();
        assert_eq!(reverse.len(), g.slot_count() as usize);
        let mut seen = BTreeMap::new();
        for (slot, entry) in reverse.iter().enumerate() {
            for (j, &b) in entry.iter().enumerate() {
                if b != EMPTY {
                    assert!(
                        seen.insert(b, (slot as u32, j as u32)).is_none(),
                        "{b} twice"
                    );
                }
            }
        }
        for (i, &r) in state.residency.iter().enumerate() {
            let found = seen.get(&(i as u32)).copied();
            match r {
                Residency::Absent => assert_eq!(found, None),
                Residency::Hi { slot } => {
                    assert_eq!(found, Some((slot, 0)));
                    assert!(reverse[slot as usize][1..].iter().all(|&e| e == EMPTY));
                }
                Residency::Lo { slot, sub_slot } => assert_eq!(found, Some((slot, sub_slot))),
            }
        }
        // Layout: the brick centre maps into the brick's own texel box; absent entries are zero.
        let layout = cache.layout_table();
        let n = g.brick_size() as f32;
        for (i, &r) in state.residency.iter().enumerate() {
            let e = layout[i];
            match g.texel_box(r) {
                None => assert_eq!(e, [0.0; 4]),
                Some((o, ext)) => {
                    let centre = (cache.grid().brick_coords(i).as_vec3() + 0.5) * n;
                    let tex = centre * e[3] + Vec3::new(e[0], e[1], e[2]);
                    assert!(
                        tex.cmpgt(o.as_vec3()).all() && tex.cmplt((o + ext).as_vec3()).all(),
                        "brick {i}: centre -> {tex} outside {o} + {ext}"
                    );
                }
            }
        }
    }

    #[test]
    fn same_plan_twice_uploads_nothing_and_one_change_uploads_one_brick() {
        let mut cache = cache_5x4x3(40);
        let mut wanted = vec![Level::Absent; 60];
        for (i, w) in wanted.iter_mut().enumerate() {
            *w = [Level::Hi, Level::Lo, Level::Absent, Level::Lo][i % 4];
        }
        let first = cache.update(&wanted).unwrap();
        assert_eq!(first.uploads.len(), 45);
        assert!(first.tables_changed);
        check_consistency(&cache);
        let before = cache.residencies().to_vec();
        let second = cache.update(&wanted).unwrap();
        assert!(second.is_empty(), "{second:?}");
        assert_eq!(cache.residencies(), &before[..]);

        // Absent -> Lo for one brick: exactly that brick is uploaded, nobody else moves.
        wanted[2] = Level::Lo;
        let third = cache.update(&wanted).unwrap();
        assert_eq!(third.uploads.len(), 1);
        assert_eq!(third.uploads[0].brick, 2);
        assert_eq!(third.uploads[0].level, Level::Lo);
        assert_eq!(third.uploads[0].extent, [3; 3]);
        assert!(third.evicted.is_empty() && third.moved.is_empty());
        for (i, (&a, &b)) in before.iter().zip(cache.residencies()).enumerate() {
            if i != 2 {
                assert_eq!(a, b, "brick {i} moved");
            }
        }
        // Hi -> Absent: an eviction, nothing to upload.
        wanted[0] = Level::Absent;
        let fourth = cache.update(&wanted).unwrap();
        assert!(fourth.uploads.is_empty());
        assert_eq!(fourth.evicted, vec![0]);
        assert!(fourth.tables_changed);
        check_consistency(&cache);
    }

    #[test]
    fn nine_low_res_bricks_use_two_slots_and_merge_back() {
        let mut cache = cache_5x4x3(10);
        let wanted = levels_with(60, &(0..9).map(|i| (i, Level::Lo)).collect::<Vec<_>>());
        let update = cache.update(&wanted).unwrap();
        assert_eq!(update.uploads.len(), 9);
        assert_eq!(cache.split_slot_count(), 2);
        assert_eq!(cache.free_slot_count(), 8);
        check_consistency(&cache);
        // Adding a tenth fills the partial split slot instead of splitting another.
        let mut wanted10 = wanted.clone();
        wanted10[20] = Level::Lo;
        cache.update(&wanted10).unwrap();
        assert_eq!(cache.split_slot_count(), 2);
        assert_eq!(cache.residency(20).slot(), cache.residency(8).slot());
        // Removing all but brick 8 and 20 merges the first split slot back.
        let kept = levels_with(60, &[(8, Level::Lo), (20, Level::Lo)]);
        let update = cache.update(&kept).unwrap();
        assert_eq!(update.evicted, (0..8).collect::<Vec<_>>());
        assert!(update.uploads.is_empty());
        assert_eq!(cache.split_slot_count(), 1);
        assert_eq!(cache.free_slot_count(), 9);
        check_consistency(&cache);
        let update = cache.update(&[Level::Absent; 60]).unwrap();
        assert_eq!(update.evicted, vec![8, 20]);
        assert_eq!(cache.split_slot_count(), 0);
        assert_eq!(cache.free_slot_count(), 10);
        check_consistency(&cache);
    }

    #[test]
    fn hi_res_bricks_take_whole_slots_and_switching_level_reuploads() {
        let mut cache = cache_5x4x3(4);
        let wanted = levels_with(60, &[(0, Level::Hi), (59, Level::Hi), (30, Level::Lo)]);
        let update = cache.update(&wanted).unwrap();
        assert_eq!(cache.residency(0), Residency::Hi { slot: 0 });
        assert_eq!(cache.residency(59), Residency::Hi { slot: 1 });
        assert_eq!(
            cache.residency(30),
            Residency::Lo {
                slot: 2,
                sub_slot: 0
            }
        );
        let hi = update.uploads.iter().find(|u| u.brick == 59).unwrap();
        assert_eq!(hi.dst_origin, [6, 0, 0]);
        assert_eq!(hi.extent, [6; 3]);
        // Brick 59 goes Lo: re-uploaded into the existing split slot, its whole slot is freed.
        let wanted = levels_with(60, &[(0, Level::Hi), (59, Level::Lo), (30, Level::Lo)]);
        let update = cache.update(&wanted).unwrap();
        assert_eq!(update.uploads.len(), 1);
        assert_eq!(update.uploads[0].brick, 59);
        assert_eq!(update.uploads[0].level, Level::Lo);
        assert_eq!(update.uploads[0].dst_origin, [15, 0, 0]); // slot 2, sub-slot 1
        assert_eq!(cache.free_slot_count(), 2);
        check_consistency(&cache);
    }

    /// Fragmented sub-slots: four split slots at (3, 3, 3, 1) occupancy hold 10 low-res bricks,
    /// which need only two; two new hi-res bricks force two evacuations.
    #[test]
    fn compaction_frees_whole_slots_from_fragmented_split_slots() {
        let mut cache = cache_5x4x3(4);
        let all_lo: Vec<(usize, Level)> = (0..25).map(|i| (i, Level::Lo)).collect();
        cache.update(&levels_with(60, &all_lo)).unwrap();
        assert_eq!(cache.split_slot_count(), 4);
        assert_eq!(cache.free_slot_count(), 0);
        // Keep 3 bricks of each of the first three split slots and the single one in the fourth.
        let kept: Vec<usize> = vec![0, 1, 2, 8, 9, 10, 16, 17, 18, 24];
        let mut plan: Vec<(usize, Level)> = kept.iter().map(|&i| (i, Level::Lo)).collect();
        plan.extend([(40, Level::Hi), (41, Level::Hi)]);
        let before = cache.residencies().to_vec();
        let update = cache.update(&levels_with(60, &plan)).unwrap();
        check_consistency(&cache);
        assert_eq!(cache.split_slot_count(), 2);
        assert_eq!(cache.free_slot_count(), 0);
        assert!(matches!(cache.residency(40), Residency::Hi { .. }));
        assert!(matches!(cache.residency(41), Residency::Hi { .. }));
        // Evacuated: slot 3 (one brick), then the highest of the 3-occupied slots (slot 2).
        assert_eq!(update.moved, vec![16, 17, 18, 24]);
        for &b in &kept {
            let moved = before[b] != cache.residency(b as u32);
            assert_eq!(moved, update.moved.contains(&(b as u32)), "brick {b}");
        }
        let uploaded: Vec<u32> = update.uploads.iter().map(|u| u.brick).collect();
        assert_eq!(uploaded, vec![16, 17, 18, 24, 40, 41]);
        // The moved bricks went into slot 0 (fullest first, ties by slot index).
        for b in [16, 17, 18, 24] {
            assert_eq!(cache.residency(b).slot(), Some(0));
        }
    }

    #[test]
    fn over_budget_is_an_error_and_changes_nothing() {
        let mut cache = cache_5x4x3(3);
        let ok = levels_with(60, &[(0, Level::Hi), (1, Level::Lo)]);
        cache.update(&ok).unwrap();
        let before = cache.residencies().to_vec();
        // 3 Hi + 1 Lo = 4 slots > 3.
        let too_many = levels_with(
            60,
            &[
                (0, Level::Hi),
                (1, Level::Lo),
                (2, Level::Hi),
                (3, Level::Hi),
            ],
        );
        let err = cache.update(&too_many).unwrap_err();
        assert_eq!(
            err,
            CacheError::OverBudget {
                hi: 3,
                lo: 1,
                slots: 3
            }
        );
        let msg = err.to_string();
        assert!(
            msg.contains("needs 4 slots") && msg.contains("has 3"),
            "{msg}"
        );
        assert_eq!(cache.residencies(), &before[..]);
        // 17 Lo = 3 slots fits exactly; 25 Lo does not.
        let lo17: Vec<_> = (0..17).map(|i| (i, Level::Lo)).collect();
        assert!(cache.update(&levels_with(60, &lo17)).is_ok());
        let lo25: Vec<_> = (0..25).map(|i| (i, Level::Lo)).collect();
        assert!(matches!(
            cache.update(&levels_with(60, &lo25)),
            Err(CacheError::OverBudget { .. })
        ));
        assert!(matches!(
            cache.update(&[Level::Hi; 3]),
            Err(CacheError::WrongLength {
                expected: 60,
                actual: 3
            })
        ));
        check_consistency(&cache);
    }

    /// A hi-res brick that loses a low-res neighbour is re-uploaded: the fixup wrote low-res
    /// values into its border, and only an upload restores the duplicated voxels.
    #[test]
    fn losing_a_low_res_neighbour_restores_the_border() {
        let mut cache = cache_5x4x3(10);
        // Brick 0 = (0,0,0) Hi; brick 1 = (1,0,0) Lo (face neighbour); brick 6 = (1,1,0) Lo.
        let mut wanted = levels_with(60, &[(0, Level::Hi), (1, Level::Lo), (6, Level::Lo)]);
        cache.update(&wanted).unwrap();
        assert_eq!(cache.fixup_slots(), vec![0]);
        // Brick 6 becomes Hi: brick 0 loses its corner-edge neighbour bit.
        wanted[6] = Level::Hi;
        let update = cache.update(&wanted).unwrap();
        assert_eq!(update.restored_borders, vec![0]);
        let uploaded: Vec<u32> = update.uploads.iter().map(|u| u.brick).collect();
        assert_eq!(uploaded, vec![0, 6]);
        assert_eq!(cache.fixup_slots().len(), 2);
        // A new low-res neighbour only needs the fixup, no upload of brick 0.
        wanted[5] = Level::Lo;
        let update = cache.update(&wanted).unwrap();
        let uploaded: Vec<u32> = update.uploads.iter().map(|u| u.brick).collect();
        assert_eq!(uploaded, vec![5]);
        assert!(update.restored_borders.is_empty());
        check_consistency(&cache);
    }

    #[test]
    fn tables_match_the_residency() {
        let mut cache = cache_5x4x3(10);
        let wanted = levels_with(60, &[(0, Level::Hi), (1, Level::Lo), (7, Level::Hi)]);
        cache.update(&wanted).unwrap();
        let bits = cache.neighbour_bits();
        assert_eq!(bits, compute_neighbour_bits(cache.grid(), &wanted));
        // Brick 0 (0,0,0) sees Lo (1,0,0) at d=(1,0,0): bit 13. Brick 7 = (2,1,0) sees it at
        // d = (-1,-1,0): idx 0 + 0 + 9 = 9 -> bit 9.
        assert_eq!(bits[0], 1 << 13);
        assert_eq!(bits[7], 1 << 9);
        assert_eq!(cache.fixup_slots(), vec![0, 1]);
        let reverse = cache.reverse_table();
        assert_eq!(reverse.len(), 1000);
        assert_eq!(
            reverse[0],
            [0, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY]
        );
        assert_eq!(
            reverse[1],
            [7, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY]
        );
        assert_eq!(
            reverse[2],
            [1, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY]
        );
        assert_eq!(reverse[3], [EMPTY; 8]);
        // Layout of brick 1 = (1,0,0) Lo in slot 2 sub-slot 0: origin (12,0,0); t = o + 0.5 - 2b.
        assert_eq!(cache.layout_table()[1], [10.5, 0.5, 0.5, 0.5]);
        check_consistency(&cache);
        cache.clear();
        assert!(cache.residencies().iter().all(|&r| r == Residency::Absent));
        assert_eq!(cache.update(&wanted).unwrap().uploads.len(), 3);
    }

    #[test]
    fn mismatched_brick_size_is_rejected() {
        let grid = BrickGrid::new(UVec3::splat(16), 8).unwrap();
        let geometry = CacheGeometry::new(4, UVec3::splat(32)).unwrap();
        assert_eq!(
            BrickCache::new(grid, geometry).unwrap_err(),
            CacheError::BrickSizeMismatch { grid: 8, cache: 4 }
        );
    }

    /// Random demotions (Hi -> Lo, then Lo -> Absent) until `#Hi + ceil(#Lo / 8) <= capacity`.
    fn demote_until_fits(plan: &mut [Level], capacity: usize, rng: &mut Rng) {
        loop {
            let hi: Vec<usize> = (0..plan.len()).filter(|&i| plan[i] == Level::Hi).collect();
            let lo: Vec<usize> = (0..plan.len()).filter(|&i| plan[i] == Level::Lo).collect();
            if BrickCache::slots_needed(hi.len(), lo.len()) <= capacity {
                return;
            }
            if hi.is_empty() {
                plan[lo[rng.below(lo.len() as u64) as usize]] = Level::Absent;
            } else {
                plan[hi[rng.below(hi.len() as u64) as usize]] = Level::Lo;
            }
        }
    }

    /// 200 random plans over a 5x4x3 grid in runs with random capacities: errors exactly when the
    /// count rule fails (state unchanged), otherwise a consistent non-overlapping assignment with
    /// the wanted levels, hi-res bricks that kept their level never move, and the uploads are
    /// exactly the changed / moved bricks plus border restores.
    #[test]
    fn randomized_plans_keep_every_invariant() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let mut compactions = 0;
        let mut errors = 0;
        for _run in 0..10 {
            let capacity = 1 + rng.below(40) as u32;
            let mut cache = cache_5x4x3(capacity);
            let mut wanted = vec![Level::Absent; 60];
            for _step in 0..20 {
                if rng.below(2) == 0 {
                    // A fresh plan with random level probabilities.
                    let (p_hi, p_lo) = (rng.unit() * 0.6, rng.unit());
                    for w in wanted.iter_mut() {
                        let u = rng.unit();
                        *w = if u < p_hi {
                            Level::Hi
                        } else if u < p_hi + (1.0 - p_hi) * p_lo {
                            Level::Lo
                        } else {
                            Level::Absent
                        };
                    }
                } else {
                    // A few local changes to the current levels.
                    wanted = cache.levels();
                    for _ in 0..1 + rng.below(6) {
                        let i = rng.below(60) as usize;
                        wanted[i] = [Level::Hi, Level::Lo, Level::Absent][rng.below(3) as usize];
                    }
                }
                if rng.below(4) != 0 {
                    // Mostly demote like a LOD selector would (Hi -> Lo, then Lo -> Absent) until
                    // the plan fits; the rest stays over budget to exercise the error.
                    demote_until_fits(&mut wanted, capacity as usize, &mut rng);
                }
                let hi = wanted.iter().filter(|&&l| l == Level::Hi).count();
                let lo = wanted.iter().filter(|&&l| l == Level::Lo).count();
                let fits = hi + lo.div_ceil(8) <= capacity as usize;
                let before = cache.residencies().to_vec();
                let result = cache.update(&wanted);
                let update = match result {
                    Err(CacheError::OverBudget { .. }) if !fits => {
                        errors += 1;
                        assert_eq!(cache.residencies(), &before[..]);
                        continue;
                    }
                    Err(e) => panic!("unexpected error {e} (fits = {fits})"),
                    Ok(u) => {
                        assert!(fits, "accepted an over-budget plan");
                        u
                    }
                };
                check_consistency(&cache);
                assert_eq!(cache.levels(), wanted);
                let old_levels: Vec<Level> = before.iter().map(|r| r.level()).collect();
                let old_bits = compute_neighbour_bits(cache.grid(), &old_levels);
                let new_bits = compute_neighbour_bits(cache.grid(), &wanted);
                let mut expected_uploads = Vec::new();
                let mut expected_moved = Vec::new();
                let mut expected_evicted = Vec::new();
                for i in 0..60 {
                    let (a, b) = (before[i], cache.residency(i as u32));
                    if a.level() == Level::Hi && b.level() == Level::Hi {
                        assert_eq!(a, b, "hi-res brick {i} moved");
                    }
                    if a != b && a.level() == b.level() {
                        expected_moved.push(i as u32);
                    }
                    if a.level().is_resident() && b == Residency::Absent {
                        expected_evicted.push(i as u32);
                    }
                    let restore =
                        a == b && b.level() == Level::Hi && old_bits[i] & !new_bits[i] != 0;
                    if b.level().is_resident() && (a != b || restore) {
                        let (o, e) = cache.geometry().texel_box(b).unwrap();
                        expected_uploads.push(BrickUpload {
                            brick: i as u32,
                            level: b.level(),
                            dst_origin: o.to_array(),
                            extent: e.to_array(),
                        });
                    }
                }
                assert_eq!(update.uploads, expected_uploads);
                assert_eq!(update.moved, expected_moved);
                assert_eq!(update.evicted, expected_evicted);
                assert_eq!(update.tables_changed, before != cache.residencies());
                if !update.moved.is_empty() {
                    // Compaction only happens to make room for new hi-res bricks, and stops as
                    // soon as enough whole slots are free.
                    compactions += 1;
                    assert!((0..60).any(|i| wanted[i] == Level::Hi && old_levels[i] != Level::Hi));
                    assert_eq!(cache.free_slot_count(), 0);
                }
            }
        }
        assert!(errors > 5, "only {errors} over-budget plans");
        assert!(compactions > 5, "only {compactions} compactions exercised");
    }
}
