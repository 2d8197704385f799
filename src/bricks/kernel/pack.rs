//! The body of [`super::BrickKernel::pack_window`] for one voxel type `S`, storage type `D` and
//! tap count `T`.

use super::rows::{combine_rows, filter_row, Weights};
use super::texel::{copy_clamped_row, Texel};
use super::{AxisNeeds, BrickBox, LowResBlock, Scratch};
use crate::bricks::taps::AxisTaps;
use crate::bricks::taps::DownsampleFilter;
use crate::bricks::{include_stored, BrickGrid, ValueRange};
use crate::volume::ScalarType;
use std::ops::Range;

/// The typed outputs of one call (checked for length and type by the caller).
pub(super) struct Outputs<'a, D> {
    pub(super) hi: Option<&'a mut [D]>,
    pub(super) lo: Option<&'a mut [D]>,
    pub(super) ranges: Option<&'a mut [ValueRange]>,
}

/// One call: the grid, the window (`src`, whose voxel `origin + (x, y, z)` is
/// `src[x + extent[0] * (y + extent[1] * z)]`) and what to read along each axis.
pub(super) struct Job<'a, S> {
    pub(super) grid: &'a BrickGrid,
    pub(super) storage: ScalarType,
    pub(super) axes: &'a [AxisTaps; 3],
    pub(super) src: &'a [S],
    pub(super) origin: [usize; 3],
    pub(super) extent: [usize; 3],
    pub(super) bricks: &'a BrickBox,
    pub(super) needs: &'a [AxisNeeds; 3],
}

impl<S: Texel> Job<'_, S> {
    /// The window row of voxels `(.., hy, hz)`.
    #[inline]
    fn row(&self, hy: usize, hz: usize) -> &[S] {
        let [_, ey, ez] = self.extent;
        let (y, z) = (hy - self.origin[1], hz - self.origin[2]);
        debug_assert!(y < ey && z < ez);
        &self.src[(z * ey + y) * self.extent[0]..][..self.extent[0]]
    }

    /// Phase 1 reads each window row once: it cuts the row into the hi-res bricks, folds it into
    /// the column min / max of its brick rows and filters it along x; the y pass follows per
    /// plane and the z pass at the end. Phase 2 cuts the low-res bricks from the filtered block
    /// and finishes the ranges.
    pub(super) fn run<D: Texel, const T: usize>(
        &self,
        filter: DownsampleFilter,
        scratch: &mut Scratch,
        block: &mut LowResBlock,
        mut out: Outputs<'_, D>,
    ) {
        let taps = filter.taps();
        let w = Weights::<T>::new(std::array::from_fn(|t| taps[t].1), S::UNORM);
        let n = self.grid.brick_size() as usize;
        let he = n + 2;
        let hi_len = he * he * he;
        let dims = self.grid.dims().to_array().map(|c| c as usize);
        let b0 = self.bricks.start.to_array().map(|c| c as usize);
        let b1 = self.bricks.end.to_array().map(|c| c as usize);
        let nb = [b1[0] - b0[0], b1[1] - b0[1], b1[2] - b0[2]];
        let [kx, ky, kz] = [0, 1, 2].map(|a| self.needs[a].ks.clone());
        let (nx, ny, nz) = (kx.len(), ky.len(), kz.len());
        let with_level = nx * ny * nz > 0;
        let (ty, tz) = (&self.needs[1].taps, &self.needs[2].taps);
        let hx = self.needs[0].hi.clone();
        let want_ranges = out.ranges.is_some();

        block.k_start = [kx.start, ky.start, kz.start];
        block.dims = [nx, ny, nz];
        block.values.clear();
        block.values.resize(nx * ny * nz, 0.0);
        let Scratch {
            split,
            x_rows,
            xy_rows,
            needed,
            lo_min,
            lo_max,
        } = scratch;
        x_rows.resize(ty.len() * nx, 0.0);
        xy_rows.resize(tz.len() * ny * nx, 0.0);
        for (a, needed) in needed.iter_mut().enumerate() {
            let span = &self.needs[a].taps;
            needed.clear();
            needed.resize(span.len(), false);
            for k in self.needs[a].ks.clone() {
                for &i in self.axes[a].row(k) {
                    needed[i - span.start] = true;
                }
            }
        }
        // Column min / max of the hi-res windows, per brick row (by, bz) of the box.
        let brick_rows = nb[1] * nb[2];
        let columns = if want_ranges {
            brick_rows * hx.len()
        } else {
            0
        };
        let mut hi_min = vec![S::HIGHEST; columns];
        let mut hi_max = vec![S::LOWEST; columns];

        // The hi-res window of brick b along an axis of d voxels.
        let hi_window = |b: usize, d: usize| (n * b).saturating_sub(1)..(n * b + n + 1).min(d);
        // Texel layers of brick b that hold voxel layer h (several at a clamped face).
        let layers = |h: usize, b: usize, d: usize| -> Range<usize> {
            let base = (n * b) as i64 - 1;
            let first = if h == 0 { 0 } else { h as i64 - base };
            let last = if h == d - 1 {
                he as i64 - 1
            } else {
                h as i64 - base
            };
            first.max(0) as usize..(last + 1).clamp(0, he as i64) as usize
        };
        let read = self.needs.clone().map(|a| a.read());
        for hz in read[2].clone() {
            let z_level = with_level && tz.contains(&hz) && needed[2][hz - tz.start];
            let z_hi = self.needs[2].hi.contains(&hz);
            for hy in read[1].clone() {
                let y_level = z_level && ty.contains(&hy) && needed[1][hy - ty.start];
                let y_hi = z_hi && self.needs[1].hi.contains(&hy);
                if !(y_level || y_hi) {
                    continue;
                }
                let row = self.row(hy, hz);
                if y_hi {
                    for bz in b0[2]..b1[2] {
                        if !hi_window(bz, dims[2]).contains(&hz) {
                            continue;
                        }
                        for by in b0[1]..b1[1] {
                            if !hi_window(by, dims[1]).contains(&hy) {
                                continue;
                            }
                            let r = (bz - b0[2]) * nb[1] + (by - b0[1]);
                            if let Some(hi) = out.hi.as_deref_mut() {
                                let bricks = &mut hi[r * nb[0] * hi_len..][..nb[0] * hi_len];
                                for tz in layers(hz, bz, dims[2]) {
                                    for ty in layers(hy, by, dims[1]) {
                                        let texels = (tz * he + ty) * he;
                                        for (i, brick) in
                                            bricks.chunks_exact_mut(hi_len).enumerate()
                                        {
                                            let start = (n * (b0[0] + i)) as i64
                                                - 1
                                                - self.origin[0] as i64;
                                            let dst = &mut brick[texels..][..he];
                                            copy_clamped_row(row, start, dst);
                                        }
                                    }
                                }
                            }
                            if want_ranges {
                                let cols = r * hx.len()..(r + 1) * hx.len();
                                let values =
                                    &row[hx.start - self.origin[0]..hx.end - self.origin[0]];
                                S::fold_columns(
                                    &mut hi_min[cols.clone()],
                                    &mut hi_max[cols],
                                    values,
                                );
                            }
                        }
                    }
                }
                if y_level {
                    let x_row = &mut x_rows[(hy - ty.start) * nx..][..nx];
                    filter_row(
                        row,
                        self.origin[0],
                        split,
                        &self.axes[0],
                        kx.clone(),
                        &w,
                        x_row,
                    );
                }
            }
            if z_level {
                let plane = &mut xy_rows[(hz - tz.start) * ny * nx..][..ny * nx];
                for (k, out) in ky.clone().zip(plane.chunks_exact_mut(nx)) {
                    let rows = self.axes[1]
                        .fixed::<T>(k)
                        .map(|hy| &x_rows[(hy - ty.start) * nx..][..nx]);
                    combine_rows(rows, &w, out);
                }
            }
        }
        if with_level {
            for (k, plane) in kz.clone().zip(block.values.chunks_exact_mut(ny * nx)) {
                let taps = self.axes[2].fixed::<T>(k);
                for (j, out) in plane.chunks_exact_mut(nx).enumerate() {
                    let rows = taps.map(|hz| &xy_rows[((hz - tz.start) * ny + j) * nx..][..nx]);
                    combine_rows(rows, &w, out);
                }
            }
        }

        let half = n / 2;
        let kmax = [0, 1, 2].map(|a| self.axes[a].kmax());
        let values = &block.values[..];
        if let Some(lo) = out.lo {
            let le = half + 1;
            let lo_len = le * le * le;
            for bz in b0[2]..b1[2] {
                for by in b0[1]..b1[1] {
                    let r = (bz - b0[2]) * nb[1] + (by - b0[1]);
                    let bricks = &mut lo[r * nb[0] * lo_len..][..nb[0] * lo_len];
                    // Texel j holds low-res sample n*b/2 + j, clamped.
                    for tz in 0..le {
                        let z = (half * bz + tz).min(kmax[2]) - kz.start;
                        for ty in 0..le {
                            let y = (half * by + ty).min(kmax[1]) - ky.start;
                            let block_row = &values[(z * ny + y) * nx..][..nx];
                            let texels = (tz * le + ty) * le;
                            for (i, brick) in bricks.chunks_exact_mut(lo_len).enumerate() {
                                let start = (half * (b0[0] + i) - kx.start) as i64;
                                copy_clamped_row(block_row, start, &mut brick[texels..][..le]);
                            }
                        }
                    }
                }
            }
        }
        let Some(ranges) = out.ranges else {
            return;
        };
        // The low-res range window of brick b: samples n*b/2 - 1 ..= n*b/2 + n/2 + 1, clamped.
        let lo_window = |b: usize, a: usize| {
            (half * b).saturating_sub(1)..(half * b + half + 2).min(kmax[a] + 1)
        };
        let none = (f32::HIGHEST, f32::LOWEST);
        for bz in b0[2]..b1[2] {
            for by in b0[1]..b1[1] {
                let r = (bz - b0[2]) * nb[1] + (by - b0[1]);
                lo_min.clear();
                lo_min.resize(nx, f32::HIGHEST);
                lo_max.clear();
                lo_max.resize(nx, f32::LOWEST);
                for z in lo_window(bz, 2) {
                    for y in lo_window(by, 1) {
                        let block_row =
                            &values[((z - kz.start) * ny + (y - ky.start)) * nx..][..nx];
                        f32::fold_columns(lo_min, lo_max, block_row);
                    }
                }
                let (hi_min, hi_max) = (&hi_min[r * hx.len()..], &hi_max[r * hx.len()..]);
                for (i, range) in ranges[r * nb[0]..][..nb[0]].iter_mut().enumerate() {
                    let bx = b0[0] + i;
                    let ks = lo_window(bx, 0);
                    let ks = ks.start - kx.start..ks.end - kx.start;
                    let (lmin, _) = f32::min_max(&lo_min[ks.clone()], none);
                    let (_, lmax) = f32::min_max(&lo_max[ks], none);
                    let xs = hi_window(bx, dims[0]);
                    let xs = xs.start - hx.start..xs.end - hx.start;
                    let (vmin, _) = S::min_max(&hi_min[xs.clone()], (S::HIGHEST, S::LOWEST));
                    let (_, vmax) = S::min_max(&hi_max[xs], (S::HIGHEST, S::LOWEST));
                    let mut stored = ValueRange::EMPTY;
                    for value in [vmin.normalized(), vmax.normalized(), lmin, lmax] {
                        include_stored(&mut stored, value, self.storage);
                    }
                    *range = stored;
                }
            }
        }
    }
}
