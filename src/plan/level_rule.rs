//! The rule of a level cut (a brick at most one level coarser than any of its 26 neighbours)
//! kept by refining, for [`super::LevelChooser`] (its step 3): one pass of a 3x3x3 minimum filter
//! over the bricks' levels, then the neighbours of every brick lowered, in turn; a block
//! (level 3 and up) is split whole, each node on the way down.
use crate::cache::block_bricks;
use glam::UVec3;

/// The rule keeper's buffers, kept between cuts (no allocation once grown to the grid).
#[derive(Debug, Default)]
pub(super) struct RuleKeeper {
    /// Scratch for the 3x3x3 minimum filter.
    filtered: [Vec<u8>; 2],
    /// Bricks whose level was lowered, their neighbours still to check.
    lowered: Vec<u32>,
}

impl RuleKeeper {
    /// Refines every node of the cut `level` (one entry per brick of a grid of `bricks` per
    /// axis) that breaks the rule (a brick more than one level coarser
    /// than a neighbour) down to the level its finest neighbour allows, splitting blocks whole,
    /// until no brick breaks it: one pass of a 3x3x3 minimum filter, then the neighbours of
    /// every brick lowered, in turn.
    pub(super) fn keep(&mut self, bricks: UVec3, level: &mut [u8]) {
        self.neighbour_minimum(bricks, level);
        self.lowered.clear();
        for i in 0..level.len() {
            let allowed = self.filtered[0][i].saturating_add(1);
            if level[i] > allowed {
                self.lower(bricks, level, i, allowed);
            }
        }
        while let Some(i) = self.lowered.pop() {
            let brick = brick_at(bricks, i as usize);
            let allowed = level[i as usize] + 1;
            let first = brick.saturating_sub(UVec3::ONE);
            let end = (brick + UVec3::splat(2)).min(bricks);
            for n in bricks_in(first, end) {
                let j = linear(bricks, n);
                if level[j] > allowed {
                    self.lower(bricks, level, j, allowed);
                }
            }
        }
    }

    /// Lowers the node of the cut `cut` holding brick `i` to `level`: a block is split (each node on the way
    /// holding the brick split in turn, its bricks one level finer), a brick refined in place.
    /// Every brick lowered joins `self.lowered`.
    fn lower(&mut self, bricks: UVec3, cut: &mut [u8], i: usize, level: u8) {
        let brick = brick_at(bricks, i);
        let from = cut[i];
        for k in (u32::from(level.max(2)) + 1..=u32::from(from)).rev() {
            let size = block_bricks(k);
            let origin = brick / size * size;
            let end = (origin + UVec3::splat(size)).min(bricks);
            for z in origin.z..end.z {
                for y in origin.y..end.y {
                    let row = linear(bricks, UVec3::new(origin.x, y, z));
                    let run = &mut cut[row..row + (end.x - origin.x) as usize];
                    for (j, l) in (row..).zip(run) {
                        if *l > k as u8 - 1 {
                            *l = k as u8 - 1;
                            self.lowered.push(j as u32);
                        }
                    }
                }
            }
        }
        if cut[i] > level {
            cut[i] = level;
            self.lowered.push(i as u32);
        }
    }

    /// `self.filtered[0]`: the smallest level of `level` in every brick's 3x3x3 neighbourhood (itself
    /// included), one axis at a time.
    fn neighbour_minimum(&mut self, bricks: UVec3, level: &[u8]) {
        let count = level.len();
        let [out, scratch] = &mut self.filtered;
        out.resize(count, 0);
        scratch.resize(count, 0);
        let (nx, ny, nz) = (bricks.x as usize, bricks.y as usize, bricks.z as usize);
        for (src, dst) in level.chunks(nx).zip(scratch.chunks_mut(nx)) {
            for x in 0..nx {
                let lo = x.saturating_sub(1);
                let hi = (x + 1).min(nx - 1);
                dst[x] = src[lo].min(src[x]).min(src[hi]);
            }
        }
        min_along(scratch, out, nx, ny);
        min_along(out, scratch, nx * ny, nz);
        std::mem::swap(out, scratch);
    }
}

/// `dst`: the smallest of each cell of `src` and its two neighbours `stride` apart, along an
/// axis of `n` cells (the data a sequence of blocks of `n * stride` cells).
fn min_along(src: &[u8], dst: &mut [u8], stride: usize, n: usize) {
    for (src, dst) in src.chunks(stride * n).zip(dst.chunks_mut(stride * n)) {
        for j in 0..n {
            let lo = &src[j.saturating_sub(1) * stride..][..stride];
            let mid = &src[j * stride..][..stride];
            let hi = &src[(j + 1).min(n - 1) * stride..][..stride];
            for (((d, &a), &b), &c) in dst[j * stride..][..stride]
                .iter_mut()
                .zip(lo)
                .zip(mid)
                .zip(hi)
            {
                *d = a.min(b).min(c);
            }
        }
    }
}

/// The brick of linear index `i` in a grid of `bricks` per axis (x fastest).
pub(super) fn brick_at(bricks: UVec3, i: usize) -> UVec3 {
    let (x, yz) = (i as u32 % bricks.x, i as u32 / bricks.x);
    UVec3::new(x, yz % bricks.y, yz / bricks.y)
}

/// The linear index of `b` in a grid of `size` per axis (x fastest).
pub(super) fn linear(size: UVec3, b: UVec3) -> usize {
    (b.x + size.x * (b.y + size.y * b.z)) as usize
}

/// The bricks `first..end` (z, y, x order).
pub(super) fn bricks_in(first: UVec3, end: UVec3) -> impl Iterator<Item = UVec3> {
    (first.z..end.z).flat_map(move |z| {
        (first.y..end.y).flat_map(move |y| (first.x..end.x).map(move |x| UVec3::new(x, y, z)))
    })
}
