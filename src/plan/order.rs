//! The orders the planner ranks bricks by: f32 keys for radix passes, the stable radix sort of
//! the order by error, and the importance order (error, then box distance, then index) with
//! distances computed on demand.

use std::cmp::Ordering;

/// Buckets of one radix digit (11 bits).
pub(super) const BUCKETS: usize = 1 << 11;

/// Per-digit counts of the three 11-bit digits of 32-bit keys (bits 0-10, 11-21, 22-31).
pub(super) type Histograms = [[u32; BUCKETS]; 3];

/// A key whose ascending order is the descending [`f32::total_cmp`] order of `v`.
#[inline]
pub(super) fn descending_key(v: f32) -> u32 {
    let bits = v.to_bits();
    // Negative: all bits flipped; positive: the sign bit set.
    let flip = ((bits as i32) >> 31) as u32 | 0x8000_0000;
    !(bits ^ flip)
}

/// The value whose [`descending_key`] is `key` (its inverse: the same bits back).
#[inline]
pub(super) fn value_of_descending_key(key: u32) -> f32 {
    let x = !key;
    // `x` has its sign bit set for a value without one (see `descending_key`).
    let flip = !(((x as i32) >> 31) as u32) | 0x8000_0000;
    f32::from_bits(x ^ flip)
}

/// Adds the key `k` to the counts (`add` = 1) or leaves them alone (`add` = 0), without a
/// branch.
#[inline]
fn count_key(hist: &mut Histograms, k: u32, add: u32) {
    let k = k as usize;
    hist[0][k & (BUCKETS - 1)] += add;
    hist[1][(k >> 11) & (BUCKETS - 1)] += add;
    hist[2][k >> 22] += add;
}

/// The entries of the order by error being written, one per active brick in brick order, with
/// the counts of their keys' radix digits.
pub(super) struct OrderKeys {
    hist: Histograms,
    len: usize,
}

impl OrderKeys {
    /// No entries yet; `by_error` must hold one entry per brick (every entry up to the last
    /// active brick's is written by [`OrderKeys::push`]).
    pub(super) fn new() -> Self {
        Self {
            hist: [[0; BUCKETS]; 3],
            len: 0,
        }
    }

    /// Brick `i` with radix key `key` and entry `entry`: written at the next free place, which
    /// only an active brick takes (branch-free).
    #[inline]
    pub(super) fn push(&mut self, by_error: &mut [u64], key: u32, entry: u64, active: bool) {
        count_key(&mut self.hist, key, u32::from(active));
        by_error[self.len] = entry;
        self.len += usize::from(active);
    }

    /// Truncates `by_error` to the entries written and sorts it by key (stably).
    pub(super) fn sort(mut self, by_error: &mut Vec<u64>, scratch: &mut Vec<u64>) {
        by_error.truncate(self.len);
        radix_sort_by_high_word(by_error, scratch, &mut self.hist);
    }
}

/// Sorts `v` by the upper 32 bits of its entries, stably (an LSD radix sort, three passes of 11
/// bits; a pass whose digit is the same for every entry is skipped). `hist` holds the counts
/// of the upper words of `v` ([`count_key`]), gathered while `v` was filled.
fn radix_sort_by_high_word(v: &mut Vec<u64>, scratch: &mut Vec<u64>, hist: &mut Histograms) {
    let len = v.len() as u32;
    // Every entry is written by a pass before it is read.
    scratch.resize(v.len(), 0);
    for (pass, counts) in hist.iter_mut().enumerate() {
        if counts.contains(&len) {
            continue;
        }
        let mut offset = 0;
        for c in counts.iter_mut() {
            let n = *c;
            *c = offset;
            offset += n;
        }
        let shift = 32 + 11 * pass;
        for &x in v.iter() {
            let d = (x >> shift) as usize & (BUCKETS - 1);
            scratch[counts[d] as usize] = x;
            counts[d] += 1;
        }
        std::mem::swap(v, scratch);
    }
}

/// Box distances from the eye, computed on demand from the per-axis squared components (one
/// per brick slab along x, y and z; bricks in x-fastest order) with the same floating-point
/// operations as the errors were, so the same values.
#[derive(Copy, Clone)]
pub(super) struct Distances<'a> {
    x: &'a [f32],
    y: &'a [f32],
    z: &'a [f32],
}

impl<'a> Distances<'a> {
    /// The distances of the components `axis_sq` (x, y, z).
    pub(super) fn new(axis_sq: &'a [Vec<f32>; 3]) -> Self {
        Self {
            x: &axis_sq[0],
            y: &axis_sq[1],
            z: &axis_sq[2],
        }
    }

    /// The box distance of brick `i`.
    #[inline]
    pub(super) fn get(&self, i: u32) -> f32 {
        let i = i as usize;
        let (nx, ny) = (self.x.len(), self.y.len());
        let (x, row) = (i % nx, i / nx);
        ((self.x[x] + self.y[row % ny]) + self.z[row / ny]).sqrt()
    }
}

/// Importance order, most important first: larger error, then smaller distance, then lower index.
pub(super) fn more_important(error: &[f32], distance: Distances<'_>, a: u32, b: u32) -> Ordering {
    error[b as usize]
        .total_cmp(&error[a as usize])
        .then_with(|| distance.get(a).total_cmp(&distance.get(b)))
        .then(a.cmp(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_descending_key_orders_descending_and_inverts() {
        let values = [
            f32::NEG_INFINITY,
            -3.5,
            -f32::MIN_POSITIVE,
            -0.0,
            0.0,
            1e-40,
            0.25,
            7.0,
            f32::MAX,
            f32::INFINITY,
        ];
        for w in values.windows(2) {
            assert!(descending_key(w[0]) > descending_key(w[1]), "{w:?}");
        }
        for v in values.iter().copied().chain([f32::NAN, -f32::NAN]) {
            let back = value_of_descending_key(descending_key(v));
            assert_eq!(back.to_bits(), v.to_bits(), "{v}");
        }
    }
}
