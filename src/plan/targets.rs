//! The planner's per-brick target pass: the target of every brick (the best loaded level at or
//! below the wanted one, see step 4 of the [planner](super)), and the lists of changes staging
//! works through, in one pass over the bricks.

use crate::bricks::Level;

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
/// bricks. `is_loaded` is asked about the wanted level of every wanted brick first, and then
/// only as the fallback rules need. The targets start as a copy of the wanted levels; the pass
/// skips, with two byte comparisons and one `is_loaded` call, a brick drawn at its wanted level
/// when that level is loaded (or when both are `Absent`): nothing to stage. The counts that
/// such bricks contribute to are taken afterwards from the level bytes (`count_levels`).
pub(super) fn targets(
    bricks: Bricks<'_>,
    changes: Changes<'_>,
    is_loaded: impl Fn(u32, Level) -> bool,
) -> Counts {
    let Bricks {
        prev_wanted,
        wanted,
        error,
        draw,
        target,
    } = bricks;
    let Changes {
        keep_hi,
        coarsen,
        holes,
        refine,
    } = changes;
    let mut c = Counts::default();
    let count = wanted.len();
    let (target, draw, error) = (&mut target[..count], &mut draw[..count], &error[..count]);
    target.copy_from_slice(wanted);
    c.wanted_changed = level_bytes(wanted) != level_bytes(&prev_wanted[..count]);
    // Indexed (the lengths checked once) rather than zipped: the zipped loop compiled to
    // several times the instructions.
    for i in 0..count {
        let (w, drawn) = (wanted[i], draw[i]);
        let b = i as u32;
        let first = if w == drawn {
            // Drawn at the wanted level (or both `Absent`): nothing to stage when it is loaded.
            if w == Level::Absent || is_loaded(b, w) {
                continue;
            }
            false
        } else {
            w != Level::Absent && is_loaded(b, w)
        };
        let mut keep = false;
        let to = match w {
            Level::Absent => Level::Absent,
            _ if first => w,
            Level::Hi if is_loaded(b, Level::Lo) => Level::Lo,
            Level::Lo if drawn == Level::Hi && is_loaded(b, Level::Hi) => {
                keep = true;
                Level::Absent
            }
            _ => Level::Absent,
        };
        target[i] = to;
        c.waiting += usize::from(to != w);
        let d = &mut draw[i];
        match (drawn, to) {
            _ if keep => keep_hi.push(b),
            (_, Level::Absent) => *d = Level::Absent,
            (Level::Hi, Level::Lo) => coarsen.push(b),
            (Level::Absent, _) => holes.push(b),
            (Level::Lo, Level::Hi) => refine.push(b),
            _ => {}
        }
        if !keep {
            c.deferred += usize::from(*d != to);
        }
    }
    (c.target_hi, c.target_lo) = count_levels(target);
    (c.drawn_hi, c.drawn_lo) = count_levels(draw);
    c.max_lo_error = max_lo_error(draw, target, error);
    c
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
