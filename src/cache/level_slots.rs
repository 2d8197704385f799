//! Which sub-slots of a three-level cache hold a stored brick: the allocator that lets a
//! residency change keep every brick that stays where it is (`levels::LevelResidency`).
//!
//! A slot holds stored bricks of one packing class only (level 0: one brick; level 1: eight;
//! level 2 and the block levels: sixty-four, `SlotGeometry::bricks_per_slot`). A sub-slot
//! is taken from a slot of its class that has room, else from an empty slot, lowest index first
//! (so allocation is deterministic); a slot whose last sub-slot is released is empty again.

use super::slot_geometry::{LevelSlot, SlotGeometry, THREE_LEVELS};
use std::collections::BTreeSet;

/// The occupancy of every slot of a three-level cache.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LevelSlots {
    /// Per slot: the packing class it holds, `None` when empty.
    classes: Vec<Option<u32>>,
    /// Per slot: the sub-slots in use (bit `i`: sub-slot `i`).
    used: Vec<u64>,
    /// Empty slots.
    free: BTreeSet<u32>,
    /// Per class: the slots of that class with a free sub-slot.
    partial: [BTreeSet<u32>; THREE_LEVELS as usize],
}

/// The packing class of `level`: 0, 1, or 2 for level 2 and past it.
fn class_of(level: u32) -> usize {
    level.min(THREE_LEVELS - 1) as usize
}

impl LevelSlots {
    /// `slot_count` empty slots.
    pub fn new(slot_count: u32) -> Self {
        Self {
            classes: vec![None; slot_count as usize],
            used: vec![0; slot_count as usize],
            free: (0..slot_count).collect(),
            partial: Default::default(),
        }
    }

    /// A free sub-slot for a stored brick of `level`, now taken; `None` when every slot of its
    /// class is full and no slot is empty.
    pub fn allocate(&mut self, level: u32) -> Option<LevelSlot> {
        let class = class_of(level);
        let capacity = SlotGeometry::bricks_per_slot(level);
        let slot = match self.partial[class].first() {
            Some(&slot) => slot,
            None => {
                let slot = self.free.pop_first()?;
                self.classes[slot as usize] = Some(class as u32);
                if capacity > 1 {
                    self.partial[class].insert(slot);
                }
                slot
            }
        };
        let used = &mut self.used[slot as usize];
        let index = (!*used).trailing_zeros();
        *used |= 1 << index;
        if used.count_ones() == capacity {
            self.partial[class].remove(&slot);
        }
        Some(LevelSlot { slot, level, index })
    }

    /// Takes `place` itself (as a packing placed it); false, changing nothing, when its slot
    /// holds another class, the sub-slot is taken or out of range.
    pub fn take(&mut self, place: LevelSlot) -> bool {
        let s = place.slot as usize;
        let class = class_of(place.level);
        let capacity = SlotGeometry::bricks_per_slot(place.level);
        if s >= self.used.len()
            || place.index >= capacity
            || self.classes[s].is_some_and(|c| c != class as u32)
            || self.used[s] & (1 << place.index) != 0
        {
            return false;
        }
        if self.classes[s].is_none() {
            self.free.remove(&place.slot);
            self.classes[s] = Some(class as u32);
        }
        self.used[s] |= 1 << place.index;
        if self.used[s].count_ones() < capacity {
            self.partial[class].insert(place.slot);
        } else {
            self.partial[class].remove(&place.slot);
        }
        true
    }

    /// Gives `place` back. A place not taken (or of another class than its slot's) is ignored.
    pub fn release(&mut self, place: LevelSlot) {
        let s = place.slot as usize;
        let class = class_of(place.level);
        if s >= self.used.len()
            || self.classes[s] != Some(class as u32)
            || place.index >= 64
            || self.used[s] & (1 << place.index) == 0
        {
            return;
        }
        self.used[s] &= !(1 << place.index);
        if self.used[s] == 0 {
            self.classes[s] = None;
            self.partial[class].remove(&place.slot);
            self.free.insert(place.slot);
        } else {
            self.partial[class].insert(place.slot);
        }
    }

    /// A partly filled slot of level 1 or of level 2 and past whose stored bricks the other
    /// partly filled slots of its class can take: of those, the one holding the fewest (ties:
    /// the lowest index). `None` when there is none.
    pub fn emptiable_slot(&self) -> Option<u32> {
        let mut best: Option<(u32, u32)> = None;
        for class in 1..THREE_LEVELS as usize {
            let capacity = SlotGeometry::bricks_per_slot(class as u32);
            let free: u32 = self.partial[class]
                .iter()
                .map(|&s| capacity - self.used[s as usize].count_ones())
                .sum();
            for &slot in &self.partial[class] {
                let used = self.used[slot as usize].count_ones();
                let room_elsewhere = free - (capacity - used);
                if room_elsewhere >= used && best.is_none_or(|(u, _)| used < u) {
                    best = Some((used, slot));
                }
            }
        }
        best.map(|(_, slot)| slot)
    }

    /// Slots holding at least one stored brick.
    pub fn slots_in_use(&self) -> u32 {
        (self.classes.len() - self.free.len()) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_slots_fill_a_slot_of_their_class_before_an_empty_one() {
        let mut slots = LevelSlots::new(3);
        let a = slots.allocate(1).unwrap();
        let b = slots.allocate(1).unwrap();
        assert_eq!((a.slot, a.index, b.slot, b.index), (0, 0, 0, 1));
        let hi = slots.allocate(0).unwrap();
        assert_eq!((hi.slot, hi.index), (1, 0));
        // Six more level-1 bricks fill slot 0; the ninth needs the last slot.
        for _ in 0..6 {
            assert_eq!(slots.allocate(1).unwrap().slot, 0);
        }
        assert_eq!(slots.allocate(1).unwrap().slot, 2);
        assert_eq!(slots.slots_in_use(), 3);
        assert_eq!(slots.allocate(0), None, "no empty slot left");
        assert_eq!(slots.allocate(3), None, "no slot of the level-2 class");
        // A released sub-slot is reused; a slot emptied becomes free for any class.
        slots.release(b);
        assert_eq!(slots.allocate(1), Some(b));
        slots.release(hi);
        assert_eq!(slots.slots_in_use(), 2);
        let deep = slots.allocate(4).unwrap();
        assert_eq!((deep.slot, deep.index, deep.level), (1, 0, 4));
        // Taking a place already taken, or in a slot of another class, fails.
        assert!(!slots.take(a));
        assert!(!slots.take(LevelSlot {
            slot: 0,
            level: 0,
            index: 0
        }));
        // Releasing twice, or with the wrong class, changes nothing.
        slots.release(deep);
        let before = slots.clone();
        slots.release(deep);
        slots.release(LevelSlot {
            slot: 0,
            level: 0,
            index: 0,
        });
        assert_eq!(slots, before);
    }

    #[test]
    fn taking_the_places_of_a_packing_leaves_the_same_free_sub_slots() {
        let mut packed = LevelSlots::new(4);
        let places: Vec<_> = [0, 1, 1, 3, 0]
            .iter()
            .map(|&l| packed.allocate(l).unwrap())
            .collect();
        let mut taken = LevelSlots::new(4);
        for p in places.iter().rev() {
            assert!(taken.take(*p));
        }
        assert_eq!(taken, packed);
        assert_eq!(taken.allocate(1), packed.allocate(1));
    }

    #[test]
    fn the_emptiest_slot_whose_bricks_fit_elsewhere_can_be_emptied() {
        let mut slots = LevelSlots::new(4);
        let ones: Vec<_> = (0..16).map(|_| slots.allocate(1).unwrap()).collect();
        assert_eq!(slots.emptiable_slot(), None, "full slots");
        // Slot 0 keeps 6 bricks, slot 1 keeps 2: slot 1's fit in slot 0's two free sub-slots.
        for p in ones
            .iter()
            .filter(|p| (p.slot == 0 && p.index >= 6) || (p.slot == 1 && p.index >= 2))
        {
            slots.release(*p);
        }
        assert_eq!(slots.emptiable_slot(), Some(1));
        // Slot 1 keeping 3 would not fit in the two free sub-slots of slot 0.
        assert!(slots.take(ones[10]));
        assert_eq!(slots.emptiable_slot(), None);
    }

    #[test]
    fn a_level_two_slot_takes_sixty_four_bricks_of_any_deeper_level() {
        let mut slots = LevelSlots::new(1);
        for i in 0..64 {
            let place = slots.allocate(2 + i % 3).unwrap();
            assert_eq!((place.slot, place.index), (0, i));
        }
        assert_eq!(slots.allocate(2), None);
    }
}
