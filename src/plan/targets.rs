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
/// only as the fallback rules need. The common case (a brick drawn at its wanted level, which
/// is loaded) takes a short branch-light path.
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
    // Bricks drawn and targeted at their wanted level; `hi` of them `Hi`.
    let (mut settled, mut settled_hi) = (0usize, 0usize);
    let mut max_lo = 0.0f32;
    // Indexed (the lengths checked once) rather than zipped: the zipped loop compiled to
    // several times the instructions.
    let count = wanted.len();
    let (target, draw, error) = (&mut target[..count], &mut draw[..count], &error[..count]);
    let prev_wanted = &prev_wanted[..count];
    let mut changed = 0u8;
    for i in 0..count {
        let (w, e) = (wanted[i], error[i]);
        changed |= u8::from(w != prev_wanted[i]);
        let (t, d) = (&mut target[i], &mut draw[i]);
        let b = i as u32;
        let drawn = *d;
        let first = w != Level::Absent && is_loaded(b, w);
        if first && drawn == w {
            // Nothing to stage.
            *t = w;
            let hi = w == Level::Hi;
            settled += 1;
            settled_hi += usize::from(hi);
            // As `max`, NaN ignored.
            let e = if hi { 0.0 } else { e };
            if e > max_lo {
                max_lo = e;
            }
            continue;
        }
        if w == Level::Absent && drawn == Level::Absent {
            *t = Level::Absent;
            continue;
        }
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
        *t = to;
        c.waiting += usize::from(to != w);
        match (drawn, to) {
            _ if keep => keep_hi.push(b),
            (_, Level::Absent) => *d = Level::Absent,
            (Level::Hi, Level::Lo) => coarsen.push(b),
            (Level::Absent, _) => holes.push(b),
            (Level::Lo, Level::Hi) => refine.push(b),
            _ => {}
        }
        match to {
            Level::Hi => c.target_hi += 1,
            Level::Lo => c.target_lo += 1,
            Level::Absent => {}
        }
        match *d {
            Level::Hi => c.drawn_hi += 1,
            Level::Lo => c.drawn_lo += 1,
            Level::Absent => {}
        }
        if !keep {
            c.deferred += usize::from(*d != to);
            if (*d, to) == (Level::Lo, Level::Lo) {
                max_lo = max_lo.max(e);
            }
        }
    }
    c.max_lo_error = max_lo;
    c.wanted_changed = changed != 0;
    c.target_hi += settled_hi;
    c.target_lo += settled - settled_hi;
    c.drawn_hi += settled_hi;
    c.drawn_lo += settled - settled_hi;
    c
}
