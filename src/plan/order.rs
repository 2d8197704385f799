//! The orders the planner ranks bricks by: f32 keys for radix passes, the sort of the order by
//! error (by the top digit, then bucket by bucket), and the importance order (error, then box
//! distance, then index) with distances computed on demand.

use std::cmp::Ordering;

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

/// Where the top digit of a 32-bit key starts: the first pass sorts by bits 22-31.
const TOP_SHIFT: u32 = 22;
/// Buckets of the top digit (10 bits).
const TOP_BUCKETS: usize = 1 << (32 - TOP_SHIFT);
/// Bits of each of the two digits below the top one (bits 0-10 and 11-21).
const LOW_BITS: u32 = 11;
/// Buckets of a digit below the top one.
const LOW_BUCKETS: usize = 1 << LOW_BITS;
/// A top bucket of at most this many entries is sorted by comparison (a radix pass over it
/// would cost more in clearing and summing its counts than in moving its entries).
const SMALL_BUCKET: usize = 256;

/// The bit of an entry that [`OrderKeys::sort`] leaves out of its order (the order by error
/// keeps a flag there, [`super::select::order_entry`]).
const FLAG_BIT: u64 = 1 << 31;

/// The entries of the order by error being written, one per active brick in brick order, with
/// the counts of their keys' top digits.
pub(super) struct OrderKeys {
    top: [u32; TOP_BUCKETS],
    len: usize,
}

impl OrderKeys {
    /// No entries yet; the slice [`OrderKeys::push`] writes into must hold one entry per brick
    /// (every entry up to the last active brick's is written).
    pub(super) fn new() -> Self {
        Self {
            top: [0; TOP_BUCKETS],
            len: 0,
        }
    }

    /// An entry with radix key `key` (its upper word): written at the next free place, which
    /// only an active brick takes (branch-free).
    #[inline]
    pub(super) fn push(&mut self, by_error: &mut [u64], key: u32, entry: u64, active: bool) {
        self.top[(key >> TOP_SHIFT) as usize] += u32::from(active);
        by_error[self.len] = entry;
        self.len += usize::from(active);
    }

    /// Truncates `by_error` to the entries written and sorts them by their upper word, then
    /// their lower 31 bits (bit 31 left out). Entries pushed in ascending order of their lower
    /// 31 bits (brick order) are so sorted stably by key.
    pub(super) fn sort(self, by_error: &mut Vec<u64>, scratch: &mut Vec<u64>) {
        by_error.truncate(self.len);
        sort_by_high_word(by_error, scratch, &self.top);
    }
}

/// Sorts `v` by the upper 32 bits of its entries, then by their lower 31 bits (bit 31 left
/// out); entries in ascending order of the lower 31 bits are so sorted stably by the upper
/// word. `top` holds the counts of the top digits (bits 22-31 of the upper words) of `v`.
///
/// One pass distributes the entries by their top digit (few buckets: the errors of one frame
/// span a few binades), then each bucket, small enough to stay in the caches, is sorted on its
/// own: by comparison when small, else by two stable radix passes of 11 bits (a pass whose
/// digit is the same for every entry of the bucket is skipped). A least-significant-digit sort
/// of the whole order distributes it by a low digit first, writing to 2048 places spread over
/// all of it, which missed the first-level cache at nearly every entry.
fn sort_by_high_word(v: &mut Vec<u64>, scratch: &mut Vec<u64>, top: &[u32; TOP_BUCKETS]) {
    // Every entry is written by the first pass before it is read.
    scratch.resize(v.len(), 0);
    let mut start = [0u32; TOP_BUCKETS];
    let mut offset = 0;
    for (s, &n) in start.iter_mut().zip(top) {
        *s = offset;
        offset += n;
    }
    let mut next = start;
    for &x in v.iter() {
        let d = (x >> (32 + TOP_SHIFT)) as usize;
        scratch[next[d] as usize] = x;
        next[d] += 1;
    }
    let mut hist = [[0u32; LOW_BUCKETS]; 2];
    for (&s, &n) in start.iter().zip(top) {
        if n > 1 {
            let range = s as usize..(s + n) as usize;
            sort_bucket(&mut scratch[range.clone()], &mut v[range], &mut hist);
        }
    }
    std::mem::swap(v, scratch);
}

/// Sorts `bucket` (entries of one top digit) by the lower 22 bits of their upper words, then
/// their lower 31 bits; `aux` (as long) is scratch.
fn sort_bucket(bucket: &mut [u64], aux: &mut [u64], hist: &mut [[u32; LOW_BUCKETS]; 2]) {
    if bucket.len() <= SMALL_BUCKET {
        bucket.sort_unstable_by_key(|&x| x & !FLAG_BIT);
        return;
    }
    for h in hist.iter_mut() {
        h.fill(0);
    }
    for &x in bucket.iter() {
        let k = (x >> 32) as usize;
        hist[0][k & (LOW_BUCKETS - 1)] += 1;
        hist[1][(k >> LOW_BITS) & (LOW_BUCKETS - 1)] += 1;
    }
    let len = bucket.len() as u32;
    let (mut from, mut to) = (bucket, aux);
    let mut in_bucket = true;
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
        let shift = 32 + LOW_BITS * pass as u32;
        for &x in from.iter() {
            let d = (x >> shift) as usize & (LOW_BUCKETS - 1);
            to[counts[d] as usize] = x;
            counts[d] += 1;
        }
        std::mem::swap(&mut from, &mut to);
        in_bucket = !in_bucket;
    }
    if !in_bucket {
        // The sorted entries are in `aux` (one pass ran): back into the bucket.
        to.copy_from_slice(from);
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

    /// Sorts entries built from `keys` (brick `i` gets `keys[i]`, its flag bit from `i`) with
    /// [`OrderKeys`] and checks the result against a stable sort of the same entries by key.
    fn check_sort(keys: &[u32], active_every: usize) {
        let mut order = OrderKeys::new();
        // Stale contents past the entries and in the scratch: what is read must be written.
        let mut v = vec![7u64; keys.len()];
        let mut expected = Vec::new();
        for (i, &k) in keys.iter().enumerate() {
            let entry = (u64::from(k) << 32) | (((i % 3 == 0) as u64) << 31) | i as u64;
            let active = i % active_every != 1;
            order.push(&mut v, k, entry, active);
            if active {
                expected.push(entry);
            }
        }
        let mut scratch = vec![9u64; 5];
        order.sort(&mut v, &mut scratch);
        expected.sort_by_key(|&x| x >> 32);
        assert_eq!(v.len(), expected.len());
        assert!(v == expected, "{} keys", keys.len());
    }

    #[test]
    fn the_order_sort_matches_a_stable_sort_for_every_bucket_shape() {
        let mut next = crate::plan::tests::xorshift(0x9E37_79B9_7F4A_7C15u64);
        // Every key in one top bucket (both radix passes), one bucket with the low digits
        // varying only (one pass), many small buckets (comparison), ties and NaN (`u32::MAX`).
        let one_bucket: Vec<u32> = (0..5000)
            .map(|_| (7 << 22) | (next() as u32 >> 10))
            .collect();
        let low_only: Vec<u32> = (0..3000)
            .map(|_| (3 << 22) | (next() as u32 & 0x7FF))
            .collect();
        let spread: Vec<u32> = (0..20_000).map(|_| next() as u32).collect();
        let ties: Vec<u32> = (0..4000)
            .map(|_| match next() % 4 {
                0 => u32::MAX,
                1 => 5 << 22,
                _ => (5 << 22) | (next() % 64) as u32,
            })
            .collect();
        let errors: Vec<u32> = (0..30_000)
            .map(|_| descending_key((next() % 1_000_000) as f32 / 7.0 + 0.5))
            .collect();
        for keys in [&one_bucket, &low_only, &spread, &ties, &errors] {
            for active_every in [1, 2, 5] {
                check_sort(keys, active_every);
            }
        }
        check_sort(&[], 1);
        check_sort(&[42], 1);
    }

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
