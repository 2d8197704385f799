//! The planner's `Hi` selection: the `h` best-ranked candidates, found by merging two runs of
//! the order by error (the bricks wanted `Hi` last frame, whose ranking key is their error
//! times `1 + m`, and the others) instead of ranking every brick.
//!
//! The ranking is step 3 of the [planner](super): ranking key descending, a brick wanted `Hi`
//! last frame first on equal keys, then importance ([`more_important`]). The order by error
//! lists the kept bricks by descending error, equal errors in brick order, with NaN errors last
//! ([`request_key`]). Within each of the two runs the ranking key falls as the error falls
//! (multiplying by `1 + m` keeps the order), so the best remaining candidate is at the head of
//! one of the two runs, and only the bricks before the selection's boundary are visited. Bricks
//! of equal ranking key within one run (consecutive in it) are taken whole, or, at the
//! boundary, the most important of them. NaN errors, which rank by their bits (a positive NaN
//! before every number, a negative one after), are ranked among themselves by sorting.
//!
//! Each entry of the order carries its brick's error (its key is a bijection of the error's
//! bits) and a bit saying whether the brick was wanted `Hi` last frame ([`order_entry`]), so
//! the merge reads the order alone, front to back, instead of looking up two per-brick arrays at
//! random for every brick it visits.

use super::order::{descending_key, more_important, value_of_descending_key, Distances};
use crate::bricks::Level;
use std::cmp::Ordering;

/// The key of brick errors in the order by error (ascending key = descending error): NaN last,
/// after every number.
#[inline]
pub(super) fn request_key(e: f32) -> u32 {
    if e.is_nan() {
        u32::MAX
    } else {
        descending_key(e)
    }
}

/// The bit of an entry of the order by error that says the brick was wanted `Hi` last frame.
const WAS_HI: u64 = 1 << 31;

/// An entry of the order by error: `key << 32`, bit 31 set when the brick was wanted `Hi`
/// last frame (so that the selection reads the order alone, not the per-brick arrays), and the
/// brick (below 2^31) in the low bits. Sorted by the upper word, the entries are in the order
/// by error.
#[inline]
pub(super) fn order_entry(key: u32, brick: u32, was_hi: bool) -> u64 {
    debug_assert!(u64::from(brick) < WAS_HI);
    (u64::from(key) << 32) | (u64::from(was_hi) << 31) | u64::from(brick)
}

/// The brick of an entry of the order by error.
#[inline]
pub(super) fn entry_brick(entry: u64) -> u32 {
    (entry & (WAS_HI - 1)) as u32
}

/// Whether an entry's brick was wanted `Hi` last frame.
#[inline]
pub(super) fn entry_was_hi(entry: u64) -> bool {
    entry & WAS_HI != 0
}

/// Sets the `WAS_HI` bit of every entry from `prev_wanted` (for an order kept from the last
/// frame, whose wanted levels have changed since).
pub(super) fn refresh_was_hi(by_error: &mut [u64], prev_wanted: &[Level]) {
    for entry in by_error {
        let was_hi = prev_wanted[entry_brick(*entry) as usize] == Level::Hi;
        *entry = (*entry & !WAS_HI) | (u64::from(was_hi) << 31);
    }
}

/// The error of an entry whose key is not NaN's (`u32::MAX`): the same bits as the brick's.
#[inline]
fn entry_error(entry: u64) -> f32 {
    value_of_descending_key((entry >> 32) as u32)
}

/// What the selection reads.
#[derive(Copy, Clone)]
pub(super) struct Ranking<'a> {
    /// The kept bricks by descending error ([`order_entry`] of their [`request_key`]),
    /// ascending.
    pub by_error: &'a [u64],
    /// Per brick, the screen-space error.
    pub error: &'a [f32],
    /// Per brick, the box distance (for importance).
    pub distance: Distances<'a>,
    /// Per brick, last frame's wanted level.
    pub prev_wanted: &'a [Level],
    /// `1 + m`: what a brick wanted `Hi` last frame has its error multiplied by.
    pub boost: f32,
}

impl Ranking<'_> {
    fn was_hi(&self, i: u32) -> bool {
        self.prev_wanted[i as usize] == Level::Hi
    }

    /// The ranking key of brick `i` (smaller first), as a radix key of the boosted error.
    #[inline]
    fn key(&self, i: u32) -> u32 {
        self.key_of(self.error[i as usize], self.was_hi(i))
    }

    /// The ranking key of a brick of error `e` that was or was not wanted `Hi` last frame.
    #[inline]
    fn key_of(&self, e: f32, was_hi: bool) -> u32 {
        let e = if was_hi { e * self.boost } else { e };
        descending_key(e).min(u32::MAX - 1)
    }

    /// The full ranking order, best first.
    fn order(&self, a: u32, b: u32) -> Ordering {
        self.key(a)
            .cmp(&self.key(b))
            .then(self.was_hi(b).cmp(&self.was_hi(a)))
            .then_with(|| more_important(self.error, self.distance, a, b))
    }
}

/// Scratch buffers of the selection, kept between frames.
#[derive(Clone, Debug, Default)]
pub(super) struct SelectScratch {
    /// Bricks of one ranking key, at the boundary.
    group: Vec<u32>,
    /// Candidates with a NaN error.
    nan: Vec<u32>,
}

/// One of the two runs of the order by error (the candidates wanted `Hi` last frame, or the
/// others), visited from the best: its head and where to look for the next.
struct Run {
    was_hi: bool,
    /// The best candidate not taken yet, with its ranking key.
    head: Option<(u32, u32)>,
    /// Position in the order by error after the head's.
    next: usize,
}

impl Run {
    /// The run of the candidates with `was_hi`, at its first candidate.
    fn new(
        was_hi: bool,
        ranking: &Ranking<'_>,
        finite: &[u64],
        is_candidate: &impl Fn(f32, bool) -> bool,
    ) -> Self {
        let mut run = Self {
            was_hi,
            head: None,
            next: 0,
        };
        run.advance(ranking, finite, is_candidate);
        run
    }

    /// Moves the head to the next candidate of this run.
    #[inline]
    fn advance(
        &mut self,
        ranking: &Ranking<'_>,
        finite: &[u64],
        is_candidate: &impl Fn(f32, bool) -> bool,
    ) {
        // Reads the order alone: the brick, its `WAS_HI` bit and (from the key) its error.
        while let Some(&entry) = finite.get(self.next) {
            self.next += 1;
            if entry_was_hi(entry) == self.was_hi {
                let e = entry_error(entry);
                if is_candidate(e, self.was_hi) {
                    self.head = Some((entry_brick(entry), ranking.key_of(e, self.was_hi)));
                    return;
                }
            }
        }
        self.head = None;
    }
}

/// Sets `wanted[i] = Hi` for the `h` best-ranked candidates (see the [module docs](self));
/// `is_candidate(error, was_hi)` says which kept bricks may be `Hi`. Returns how many were set
/// (`h`, or fewer when there are fewer candidates).
pub(super) fn select_hi(
    ranking: Ranking<'_>,
    h: usize,
    is_candidate: impl Fn(f32, bool) -> bool,
    scratch: &mut SelectScratch,
    wanted: &mut [Level],
) -> usize {
    let by_error = ranking.by_error;
    // NaN errors are last in the order by error.
    let finite_len = by_error.partition_point(|&k| (k >> 32) as u32 != u32::MAX);
    let (finite, nans) = by_error.split_at(finite_len);
    let SelectScratch { group, nan } = scratch;
    nan.clear();
    nan.extend(
        nans.iter()
            .map(|&k| entry_brick(k))
            .filter(|&i| is_candidate(ranking.error[i as usize], ranking.was_hi(i))),
    );
    nan.sort_unstable_by(|&a, &b| ranking.order(a, b));
    // Positive NaNs rank before every number, negative ones after.
    let split = nan.partition_point(|&i| ranking.error[i as usize].is_sign_positive());
    let mut remaining = h;
    mark_hi(&nan[..split], &mut remaining, wanted);
    let mut runs = [
        Run::new(true, &ranking, finite, &is_candidate),
        Run::new(false, &ranking, finite, &is_candidate),
    ];
    while remaining > 0 {
        // The smaller key; the run wanted `Hi` last frame on equal keys.
        let r = match (runs[0].head, runs[1].head) {
            (Some((_, a)), Some((_, b))) => usize::from(b < a),
            (Some(_), None) => 0,
            (None, Some(_)) => 1,
            (None, None) => break,
        };
        let run = &mut runs[r];
        let Some((first, key)) = run.head else {
            break;
        };
        run.advance(&ranking, finite, &is_candidate);
        if run.head.is_none_or(|(_, k)| k != key) {
            // The only brick of its key in its run (the common case).
            wanted[first as usize] = Level::Hi;
            remaining -= 1;
            continue;
        }
        // The run's bricks of this key (consecutive in the run).
        group.clear();
        group.push(first);
        while let Some((i, k)) = run.head {
            if k != key {
                break;
            }
            group.push(i);
            run.advance(&ranking, finite, &is_candidate);
        }
        if group.len() > remaining {
            group.select_nth_unstable_by(remaining, |&a, &b| {
                more_important(ranking.error, ranking.distance, a, b)
            });
        }
        mark_hi(group, &mut remaining, wanted);
    }
    mark_hi(&nan[split..], &mut remaining, wanted);
    h - remaining
}

/// Sets the first `remaining` of `bricks` `Hi`, counting them off `remaining`.
#[inline]
fn mark_hi(bricks: &[u32], remaining: &mut usize, wanted: &mut [Level]) {
    let take = bricks.len().min(*remaining);
    for &i in &bricks[..take] {
        wanted[i as usize] = Level::Hi;
    }
    *remaining -= take;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `Hi` set by brute force: every candidate sorted by the ranking order, the first `h`.
    fn brute_force(
        ranking: &Ranking<'_>,
        h: usize,
        is_candidate: &impl Fn(f32, bool) -> bool,
    ) -> Vec<bool> {
        let mut all: Vec<u32> = ranking
            .by_error
            .iter()
            .map(|&k| entry_brick(k))
            .filter(|&i| is_candidate(ranking.error[i as usize], ranking.was_hi(i)))
            .collect();
        all.sort_by(|&a, &b| ranking.order(a, b));
        let mut hi = vec![false; ranking.error.len()];
        for &i in all.iter().take(h) {
            hi[i as usize] = true;
        }
        hi
    }

    #[test]
    fn the_merge_selects_what_a_full_sort_of_the_ranking_selects() {
        let mut next = crate::plan::tests::xorshift(0x2545_F491_4F6C_DD1Du64);
        let mut scratch = SelectScratch::default();
        for case in 0..400 {
            let n = 1 + (next() % 300) as usize;
            // A few distinct errors (ties), NaNs of both signs, zeros and infinities.
            let error: Vec<f32> = (0..n)
                .map(|_| match next() % 16 {
                    0 => f32::NAN,
                    1 => -f32::NAN,
                    2 => 0.0,
                    3 => f32::INFINITY,
                    4..=8 => (next() % 6) as f32 * 0.5,
                    _ => (next() % 10_000) as f32 / 97.0,
                })
                .collect();
            let prev_wanted: Vec<Level> = (0..n)
                .map(|_| [Level::Hi, Level::Lo, Level::Absent][(next() % 3) as usize])
                .collect();
            // The kept bricks (about 3 in 4) by descending error, NaN last, equal in brick order.
            let mut by_error: Vec<u64> = (0..n as u32)
                .filter(|_| !next().is_multiple_of(4))
                .map(|i| {
                    let was_hi = prev_wanted[i as usize] == Level::Hi;
                    order_entry(request_key(error[i as usize]), i, was_hi)
                })
                .collect();
            by_error.sort_unstable();
            let sq: [Vec<f32>; 3] = [
                (0..n).map(|_| (next() % 4) as f32).collect(),
                vec![0.0],
                vec![0.0],
            ];
            let ranking = Ranking {
                by_error: &by_error,
                error: &error,
                distance: Distances::new(&sq),
                prev_wanted: &prev_wanted,
                boost: [1.0, 1.1, 1.5][case % 3],
            };
            let threshold = [0.0, 10.0][case % 2];
            let is_candidate = |e: f32, was_hi: bool| {
                threshold == 0.0
                    || e > threshold * 1.1
                    || (was_hi && e > threshold / 1.1)
                    || e.is_nan()
            };
            let h = (next() % (by_error.len() as u64 + 2)) as usize;
            let mut wanted = vec![Level::Lo; n];
            let set = select_hi(ranking, h, is_candidate, &mut scratch, &mut wanted);
            let expected = brute_force(&ranking, h, &is_candidate);
            let got: Vec<bool> = wanted.iter().map(|&l| l == Level::Hi).collect();
            assert_eq!(got, expected, "case {case}: n {n}, h {h}");
            assert_eq!(set, expected.iter().filter(|&&b| b).count(), "case {case}");
        }
    }
}
