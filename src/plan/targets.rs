//! The planner's per-brick target pass: the target of every brick (the best loaded level at or
//! below the wanted one, see step 4 of the [planner](super)), and the lists of changes staging
//! works through, in one pass over the bricks.

use super::loaded::Loaded;
use crate::bricks::{Level, LoadedLevels};

/// The per-brick state the pass reads and fills (one entry per brick each).
pub(super) struct Bricks<'a> {
    /// Last frame's wanted levels.
    pub prev_wanted: &'a [Level],
    /// This frame's wanted levels.
    pub wanted: &'a [Level],
    /// Screen-space errors.
    pub error: &'a [f32],
    /// Drawn levels, in: the last frame's; out: `Absent` where the target is `Absent`.
    pub draw: &'a mut [Level],
    /// Out: the targets (`Absent` for the bricks in `keep_hi`, decided later).
    pub target: &'a mut [Level],
}

/// The changes found, each in brick order (appended to; the caller clears them).
pub(super) struct Changes<'a> {
    /// Wanted `Lo`, drawn `Hi`, `Lo` not loaded but `Hi` loaded: may keep `Hi`.
    pub keep_hi: &'a mut Vec<u32>,
    /// Drawn `Hi`, target `Lo`.
    pub coarsen: &'a mut Vec<u32>,
    /// Drawn `Absent`, target resident.
    pub holes: &'a mut Vec<u32>,
    /// Drawn `Lo`, target `Hi`.
    pub refine: &'a mut Vec<u32>,
}

/// The counts of the pass.
#[derive(Copy, Clone, Debug, Default)]
pub(super) struct Counts {
    pub target_hi: usize,
    pub target_lo: usize,
    /// Drawn levels after the pass (bricks targeted `Absent` are drawn `Absent`).
    pub drawn_hi: usize,
    pub drawn_lo: usize,
    /// Bricks (not in `keep_hi`) whose drawn level differs from the target.
    pub deferred: usize,
    /// Bricks whose target differs from their wanted level.
    pub waiting: usize,
    /// The largest error of a brick drawn and targeted `Lo` (not in `keep_hi`), at least 0.
    pub max_lo_error: f32,
    /// Whether a wanted level differs from the last frame's.
    pub wanted_changed: bool,
}

/// Fills the targets of the wanted levels and collects the changes, in one pass over the
/// bricks. A brick drawn at its wanted level with that level loaded (or with both `Absent`) is
/// *settled*: nothing to stage. The counts of the levels are taken afterwards from the level
/// bytes (`count_levels`).
///
/// When `loaded` holds the loaded levels of every brick as bytes, the pass decides every brick
/// from its bytes without branches, in blocks of [`BLOCK`] the compiler vectorizes
/// ([`decide_lane`], the rule of [`decide`] as byte operations), and walks only the blocks with
/// a change to append to the lists. Otherwise (a closure) the targets start as a copy of the
/// wanted levels, `is_loaded` is asked about the wanted level of every wanted brick first, and
/// then only as the fallback rules need, a settled brick skipped with two byte comparisons and
/// one call.
pub(super) fn targets(bricks: Bricks<'_>, changes: Changes<'_>, loaded: &impl Loaded) -> Counts {
    let Bricks {
        prev_wanted,
        wanted,
        error,
        draw,
        target,
    } = bricks;
    let mut c = Counts::default();
    let count = wanted.len();
    let (target, draw, error) = (&mut target[..count], &mut draw[..count], &error[..count]);
    c.wanted_changed = level_bytes(wanted) != level_bytes(&prev_wanted[..count]);
    let mut pass = Pass {
        changes,
        waiting: 0,
        deferred: 0,
    };
    match loaded.bits(count) {
        Some(bits) => pass.over_bits(wanted, draw, target, bits),
        None => {
            target.copy_from_slice(wanted);
            pass.asking(wanted, draw, target, loaded);
        }
    }
    (c.waiting, c.deferred) = (pass.waiting, pass.deferred);
    (c.target_hi, c.target_lo) = count_levels(target);
    (c.drawn_hi, c.drawn_lo) = count_levels(draw);
    c.max_lo_error = max_lo_error(draw, target, error);
    c
}

/// Bricks per block of the pass over loaded-level bytes.
const BLOCK: usize = 32;

/// What the pass does with one brick that is not settled.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
struct Decision {
    /// The target (`Absent` for a brick that may keep `Hi`).
    to: Level,
    /// The drawn level after the pass.
    draw: Level,
    /// The list the brick joins.
    change: Change,
    /// The target differs from the wanted level.
    waiting: bool,
    /// The drawn level differs from the target (not counted for a brick that may keep `Hi`).
    deferred: bool,
}

/// The change lists of [`Changes`], and none.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
enum Change {
    None,
    KeepHi,
    Coarsen,
    Hole,
    Refine,
}

/// The rule for a brick that is not settled, wanted `w` and drawn `drawn`; `first` says whether
/// `w` is loaded (false for `Absent`), `is_loaded` answers for the other levels, asked only as
/// the rule needs.
#[inline(always)]
fn decide(w: Level, drawn: Level, first: bool, is_loaded: impl Fn(Level) -> bool) -> Decision {
    let mut keep = false;
    let to = match w {
        Level::Absent => Level::Absent,
        _ if first => w,
        Level::Hi if is_loaded(Level::Lo) => Level::Lo,
        Level::Lo if drawn == Level::Hi && is_loaded(Level::Hi) => {
            keep = true;
            Level::Absent
        }
        _ => Level::Absent,
    };
    let (draw, change) = match (drawn, to) {
        _ if keep => (drawn, Change::KeepHi),
        (_, Level::Absent) => (Level::Absent, Change::None),
        (Level::Hi, Level::Lo) => (drawn, Change::Coarsen),
        (Level::Absent, _) => (drawn, Change::Hole),
        (Level::Lo, Level::Hi) => (drawn, Change::Refine),
        _ => (drawn, Change::None),
    };
    Decision {
        to,
        draw,
        change,
        waiting: to != w,
        deferred: !keep && draw != to,
    }
}

/// What the pass does with one brick, computed without branches from its bytes (for the
/// compiler to vectorize over a block); the same as [`decide`] for a brick that is not settled,
/// and for a settled one its levels unchanged.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
struct Lane {
    to: Level,
    draw: Level,
    /// The brick joins a change list ([`change_of`] says which).
    change: bool,
    waiting: bool,
    deferred: bool,
}

/// The bit of `Hi` and of `Lo` in [`LoadedLevels::bits`].
const HI_BIT: u8 = LoadedLevels::NONE.with(Level::Hi, true).bits_of();
const LO_BIT: u8 = LoadedLevels::NONE.with(Level::Lo, true).bits_of();

/// [`Lane`] for a brick wanted `w`, drawn `drawn`, with the loaded levels `bits`.
#[inline(always)]
fn decide_lane(w: Level, drawn: Level, bits: u8) -> Lane {
    let (hi_loaded, lo_loaded) = (bits & HI_BIT != 0, bits & LO_BIT != 0);
    let (w_hi, w_lo) = (w == Level::Hi, w == Level::Lo);
    // The wanted level is loaded (never for `Absent`).
    let first = (w_hi & hi_loaded) | (w_lo & lo_loaded);
    let fall_to_lo = w_hi & !hi_loaded & lo_loaded;
    let keep = w_lo & !lo_loaded & (drawn == Level::Hi) & hi_loaded;
    let to = select(first, w, select(fall_to_lo, Level::Lo, Level::Absent));
    let draw = select((to == Level::Absent) & !keep, Level::Absent, drawn);
    Lane {
        to,
        draw,
        change: keep | ((to != Level::Absent) & (drawn != to)),
        waiting: to != w,
        deferred: !keep & (draw != to),
    }
}

/// [`decide_lane`] for the bricks of one block (at most 255), the targets and drawn levels
/// written; returns the counts of waiting and deferred bricks (byte counters, so that the lanes
/// stay bytes wide) and whether a brick joins a change list.
#[inline(always)]
fn decide_block(
    wanted: &[Level],
    draw: &mut [Level],
    target: &mut [Level],
    bits: &[u8],
) -> (u8, u8, bool) {
    let (mut waiting, mut deferred, mut changed) = (0u8, 0u8, false);
    let n = wanted.len();
    let (draw, target, bits) = (&mut draw[..n], &mut target[..n], &bits[..n]);
    for j in 0..n {
        let lane = decide_lane(wanted[j], draw[j], bits[j]);
        (target[j], draw[j]) = (lane.to, lane.draw);
        waiting += u8::from(lane.waiting);
        deferred += u8::from(lane.deferred);
        changed |= lane.change;
    }
    (waiting, deferred, changed)
}

/// `a` when `c`, else `b`.
#[inline(always)]
fn select(c: bool, a: Level, b: Level) -> Level {
    if c {
        a
    } else {
        b
    }
}

/// The list of a brick after [`decide_lane`], from its target `to` and drawn level `draw`: a
/// brick that keeps its `Hi` level is targeted `Absent` and drawn `Hi`; one targeted `Absent`
/// otherwise is drawn `Absent`.
fn change_of(to: Level, draw: Level) -> Change {
    match (draw, to) {
        (Level::Hi, Level::Absent) => Change::KeepHi,
        (Level::Hi, Level::Lo) => Change::Coarsen,
        (Level::Absent, Level::Hi | Level::Lo) => Change::Hole,
        (Level::Lo, Level::Hi) => Change::Refine,
        _ => Change::None,
    }
}

/// The outputs of the pass other than the levels.
struct Pass<'a> {
    changes: Changes<'a>,
    waiting: usize,
    deferred: usize,
}

impl Pass<'_> {
    /// Records a decision for brick `b`.
    #[inline(always)]
    fn apply(&mut self, b: u32, d: Decision, draw: &mut Level, target: &mut Level) {
        *target = d.to;
        *draw = d.draw;
        self.waiting += usize::from(d.waiting);
        self.deferred += usize::from(d.deferred);
        self.push(b, d.change);
    }

    /// Appends brick `b` to the list of `change`.
    #[inline(always)]
    fn push(&mut self, b: u32, change: Change) {
        let list = match change {
            Change::None => return,
            Change::KeepHi => &mut *self.changes.keep_hi,
            Change::Coarsen => &mut *self.changes.coarsen,
            Change::Hole => &mut *self.changes.holes,
            Change::Refine => &mut *self.changes.refine,
        };
        list.push(b);
    }

    /// The pass over loaded-level bytes (`bits`, one per brick): every block of [`BLOCK`]
    /// bricks decided lane by lane without branches ([`decide_lane`]), then, in a block with a
    /// change, its bricks appended to the lists.
    fn over_bits(
        &mut self,
        wanted: &[Level],
        draw: &mut [Level],
        target: &mut [Level],
        bits: &[u8],
    ) {
        let count = wanted.len();
        let (draw, target, bits) = (&mut draw[..count], &mut target[..count], &bits[..count]);
        let mut start = 0;
        while start < count {
            let end = (start + BLOCK).min(count);
            let (w, d, t, l) = (
                &wanted[start..end],
                &mut draw[start..end],
                &mut target[start..end],
                &bits[start..end],
            );
            let (waiting, deferred, changed) = if let (Ok(w), Ok(d), Ok(t), Ok(l)) = (
                <&[Level; BLOCK]>::try_from(w),
                <&mut [Level; BLOCK]>::try_from(&mut *d),
                <&mut [Level; BLOCK]>::try_from(&mut *t),
                <&[u8; BLOCK]>::try_from(l),
            ) {
                // A whole block: fixed bounds, so that the lanes vectorize.
                decide_block(w, d, t, l)
            } else {
                decide_block(w, d, t, l)
            };
            self.waiting += usize::from(waiting);
            self.deferred += usize::from(deferred);
            if changed {
                for (j, (&to, &drawn)) in t.iter().zip(d.iter()).enumerate() {
                    self.push(start as u32 + j as u32, change_of(to, drawn));
                }
            }
            start = end;
        }
    }

    /// The pass asking `loaded` brick by brick.
    fn asking(
        &mut self,
        wanted: &[Level],
        draw: &mut [Level],
        target: &mut [Level],
        loaded: &impl Loaded,
    ) {
        // Indexed (the lengths checked once) rather than zipped: the zipped loop compiled to
        // several times the instructions.
        let count = wanted.len();
        let (draw, target) = (&mut draw[..count], &mut target[..count]);
        for i in 0..count {
            let (w, drawn) = (wanted[i], draw[i]);
            let b = i as u32;
            let first = if w == drawn {
                // Drawn at the wanted level (or both `Absent`): settled when it is loaded.
                if w == Level::Absent || loaded.is_loaded(b, w) {
                    continue;
                }
                false
            } else {
                w != Level::Absent && loaded.is_loaded(b, w)
            };
            let d = decide(w, drawn, first, |l| loaded.is_loaded(b, l));
            self.apply(b, d, &mut draw[i], &mut target[i]);
        }
    }
}

/// The levels as their bytes (`Level` is `repr(u8)`).
fn level_bytes(levels: &[Level]) -> &[u8] {
    bytemuck::cast_slice(levels)
}

/// How many of `levels` are `Hi` and how many `Lo`, counted over the bytes in blocks the
/// compiler can vectorize.
fn count_levels(levels: &[Level]) -> (usize, usize) {
    const HI: u8 = Level::Hi as u8;
    const LO: u8 = Level::Lo as u8;
    let bytes = level_bytes(levels);
    let (mut hi, mut lo) = (0usize, 0usize);
    // Blocks of at most 255 bytes, so that the per-lane byte counters cannot overflow.
    for block in bytes.chunks(255) {
        let (mut h, mut l) = (0u8, 0u8);
        for &b in block {
            h += u8::from(b == HI);
            l += u8::from(b == LO);
        }
        hi += usize::from(h);
        lo += usize::from(l);
    }
    (hi, lo)
}

/// The largest error of a brick drawn and targeted `Lo`, at least 0, NaN ignored. For errors
/// that are not negative (and not NaN) the order of the bit patterns is the order of the values,
/// so the maximum is taken over the bits, which the compiler can vectorize; negative values and
/// NaNs (bit patterns above that of `+inf`) are left out, as `max` with 0 would leave them.
fn max_lo_error(draw: &[Level], target: &[Level], error: &[f32]) -> f32 {
    const INF: u32 = 0x7F80_0000;
    const LO: u8 = Level::Lo as u8;
    let (draw, target) = (level_bytes(draw), level_bytes(target));
    // The bits of the counted errors are at most those of `+inf`, below 2^31: compared as
    // `i32`, which the baseline x86-64 vector instructions can do.
    let counted = |e: f32, d: u8, t: u8| {
        let bits = e.to_bits();
        let mask = 0u32.wrapping_sub(u32::from((d == LO) & (t == LO) & (bits <= INF)));
        (bits & mask) as i32
    };
    const LANES: usize = 16;
    let mut lanes = [0i32; LANES];
    let blocks = error
        .chunks_exact(LANES)
        .zip(draw.chunks_exact(LANES))
        .zip(target.chunks_exact(LANES));
    for ((e, d), t) in blocks {
        for j in 0..LANES {
            lanes[j] = lanes[j].max(counted(e[j], d[j], t[j]));
        }
    }
    let tail = error.len() / LANES * LANES;
    let rest = error[tail..]
        .iter()
        .zip(&draw[tail.min(draw.len())..])
        .zip(&target[tail.min(target.len())..])
        .map(|((&e, &d), &t)| counted(e, d, t));
    let max = lanes.into_iter().chain(rest).max().unwrap_or(0) as u32;
    f32::from_bits(max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::loaded::{Asked, PerBrick};

    const LEVELS: [Level; 3] = [Level::Hi, Level::Lo, Level::Absent];

    /// Everything the pass writes.
    #[derive(Debug, PartialEq)]
    struct Outcome {
        target: Vec<Level>,
        draw: Vec<Level>,
        lists: [Vec<u32>; 4],
        counts: (usize, usize, usize, usize, usize, usize, u32, bool),
    }

    fn run(
        wanted: &[Level],
        prev_wanted: &[Level],
        drawn: &[Level],
        error: &[f32],
        loaded: &impl Loaded,
    ) -> Outcome {
        let mut draw = drawn.to_vec();
        let mut target = vec![Level::Hi; wanted.len()];
        let mut lists: [Vec<u32>; 4] = Default::default();
        let [keep_hi, coarsen, holes, refine] = &mut lists;
        let c = targets(
            Bricks {
                prev_wanted,
                wanted,
                error,
                draw: &mut draw,
                target: &mut target,
            },
            Changes {
                keep_hi,
                coarsen,
                holes,
                refine,
            },
            loaded,
        );
        Outcome {
            target,
            draw,
            lists,
            counts: (
                c.target_hi,
                c.target_lo,
                c.drawn_hi,
                c.drawn_lo,
                c.deferred,
                c.waiting,
                c.max_lo_error.to_bits(),
                c.wanted_changed,
            ),
        }
    }

    /// The loaded levels with bits `b` (bit 0 `Hi`, bit 1 `Lo`).
    fn levels_of(b: u64) -> LoadedLevels {
        LoadedLevels::NONE
            .with(Level::Hi, b & 1 != 0)
            .with(Level::Lo, b & 2 != 0)
    }

    #[test]
    fn the_pass_over_bytes_decides_every_state_as_asking_does() {
        // Every (wanted, drawn, loaded) state, in a whole block and in the tail, between random
        // states; then random arrays of several lengths. Both queries give the same outcome.
        let mut next = crate::plan::tests::xorshift(0x2545_F491_4F6C_DD1D);
        let mut states: Vec<(Level, Level, LoadedLevels)> = Vec::new();
        for w in LEVELS {
            for d in LEVELS {
                for b in 0..4 {
                    states.push((w, d, levels_of(b)));
                }
            }
        }
        let random_state = |next: &mut dyn FnMut() -> u64| {
            (
                LEVELS[(next() % 3) as usize],
                LEVELS[(next() % 3) as usize],
                levels_of(next() % 4),
            )
        };
        // The 36 states in two whole blocks (with random states after them), and each alone
        // (a tail shorter than a block).
        let mut cases: Vec<Vec<(Level, Level, LoadedLevels)>> =
            states.iter().map(|&s| vec![s]).collect();
        let mut blocks = states.clone();
        blocks.extend((states.len()..2 * BLOCK).map(|_| random_state(&mut next)));
        cases.push(blocks);
        for len in [1, 31, 32, 33, 100, 1000] {
            cases.push((0..len).map(|_| random_state(&mut next)).collect());
        }
        // Mostly settled, as in a planned frame: a few changes in long runs.
        cases.push(
            (0..2000)
                .map(|i| {
                    if i % 97 == 5 {
                        random_state(&mut next)
                    } else {
                        (Level::Lo, Level::Lo, LoadedLevels::BOTH)
                    }
                })
                .collect(),
        );
        for case in &cases {
            let wanted: Vec<Level> = case.iter().map(|s| s.0).collect();
            let drawn: Vec<Level> = case.iter().map(|s| s.1).collect();
            let loaded: Vec<LoadedLevels> = case.iter().map(|s| s.2).collect();
            let prev: Vec<Level> = wanted
                .iter()
                .map(|&w| {
                    if next().is_multiple_of(5) {
                        Level::Absent
                    } else {
                        w
                    }
                })
                .collect();
            let error: Vec<f32> = (0..case.len()).map(|_| (next() % 1000) as f32).collect();
            let asked = Asked(|b: u32, l: Level| loaded[b as usize].contains(l));
            assert!(PerBrick(&loaded).bits(case.len()).is_some());
            let from_bytes = run(&wanted, &prev, &drawn, &error, &PerBrick(&loaded));
            let by_asking = run(&wanted, &prev, &drawn, &error, &asked);
            assert_eq!(from_bytes, by_asking, "{} bricks", case.len());
        }
    }

    #[test]
    fn the_pass_over_bytes_applies_the_fallback_rules() {
        // The rules stated in the module documentation, brick by brick, from the bytes path.
        use Level::{Absent, Hi, Lo};
        let hi_only = levels_of(1);
        let lo_only = levels_of(2);
        #[rustfmt::skip]
        let cases = [
            // wanted, drawn, loaded, target, drawn after, list (0 keep Hi, 1 coarsen, 2 hole, 3 refine)
            (Hi, Lo, lo_only, Lo, Lo, None),           // falls back to Lo, already drawn
            (Hi, Lo, LoadedLevels::BOTH, Hi, Lo, Some(3)), // refine
            (Hi, Absent, lo_only, Lo, Absent, Some(2)),   // a hole filled Lo
            (Lo, Hi, hi_only, Absent, Hi, Some(0)),   // zooming out keeps Hi (decided later)
            (Lo, Hi, LoadedLevels::BOTH, Lo, Hi, Some(1)), // coarsen
            (Lo, Lo, hi_only, Absent, Absent, None),  // Lo dropped from the source: not drawn
            (Hi, Hi, LoadedLevels::NONE, Absent, Absent, None),
            (Absent, Hi, LoadedLevels::BOTH, Absent, Absent, None), // culled
            (Hi, Hi, hi_only, Hi, Hi, None),          // settled
        ];
        for (i, &(w, d, l, to, after, list)) in cases.iter().enumerate() {
            // The brick at position 40, the others settled `Lo`.
            let mut wanted = vec![Lo; 70];
            let mut drawn = vec![Lo; 70];
            let mut loaded = vec![LoadedLevels::BOTH; 70];
            (wanted[40], drawn[40], loaded[40]) = (w, d, l);
            let error = vec![1.0; 70];
            let out = run(&wanted, &wanted, &drawn, &error, &PerBrick(&loaded));
            assert_eq!((out.target[40], out.draw[40]), (to, after), "case {i}");
            for (k, l) in out.lists.iter().enumerate() {
                let expected: &[u32] = if list == Some(k) { &[40] } else { &[] };
                assert_eq!(l, expected, "case {i}, list {k}");
            }
            let waiting = usize::from(to != w);
            assert_eq!(out.counts.5, waiting, "case {i}: waiting");
        }
    }
}
