//! The arithmetic of the separable filter on rows: the x pass over a source row and the y / z
//! passes combining filtered rows.
//!
//! The arithmetic is the reference's ([`crate::bricks::low_res_block`]): `f64` accumulation from
//! 0 in tap order, rounded to `f32` after each axis, or `f32` where that provably gives the same
//! bits (see [`Weights::new`]).

use super::texel::Texel;
use crate::bricks::taps::AxisTaps;
use std::ops::Range;

/// The filter weights of one axis, and how to accumulate them.
pub(super) struct Weights<const T: usize> {
    f64: [f64; T],
    f32: [f32; T],
    /// Accumulating in `f32` gives the reference's `f64`-then-`f32` result bit for bit.
    exact_in_f32: bool,
}

impl<const T: usize> Weights<T> {
    /// The weights of `taps` for a source whose normalised values are UNORM (`unorm`) or
    /// arbitrary finite `f32`.
    ///
    /// The reference accumulates `sum w_t v_t` in `f64` (from 0.0, in tap order) and rounds the sum
    /// to `f32`. With one tap of weight 1 that is `v` itself; with two taps of weight 1/2 it is
    /// `RN32(RN64(a/2 + b/2))` with `a/2`, `b/2` exact, and rounding a sum of two `f32` values
    /// through `f64` first is innocuous (53 >= 2 * 24 + 2), so it equals the `f32` sum
    /// `a * 0.5 + b * 0.5` as long as the halves do not underflow, which holds for UNORM inputs
    /// (nonzero values are at least `2^-16`, and averages stay above `2^-18` after three
    /// passes) and their averages. Every other case keeps `f64`.
    pub(super) fn new(taps: [f32; T], unorm: bool) -> Self {
        let mean_of_two = T == 2 && taps.iter().all(|&w| w == 0.5);
        let single = T == 1 && taps[0] == 1.0;
        Self {
            f64: taps.map(f64::from),
            f32: taps,
            exact_in_f32: unorm && (mean_of_two || single),
        }
    }
}

/// Row buffers of the x pass: the normalised row split into even and odd indices.
#[derive(Clone, Debug, Default)]
pub(super) struct RowSplit {
    even: Vec<f32>,
    odd: Vec<f32>,
}

impl RowSplit {
    /// Normalises `row` into the even / odd halves.
    #[inline]
    fn load<S: Texel>(&mut self, row: &[S]) {
        self.even.resize(row.len().div_ceil(2), 0.0);
        self.odd.resize(row.len() / 2, 0.0);
        let pairs = row.chunks_exact(2);
        if let [last] = pairs.remainder() {
            self.even[row.len() / 2] = last.normalized();
        }
        for ((e, o), pair) in self.even.iter_mut().zip(self.odd.iter_mut()).zip(pairs) {
            *e = pair[0].normalized();
            *o = pair[1].normalized();
        }
    }
}

/// Filters one hi-res source row along x into `out`, one value per low-res sample of `ks`
/// (`out[i]` is sample `ks.start + i`). `row[i]` is hi-res index `origin + i`, and the row holds
/// every index the taps of `ks` read.
///
/// Clamped index tables at the border; inside, either one fused pass over the source (`f32`-exact
/// filters with at most two taps) or contiguous slices of the row split into even / odd indices.
#[inline]
#[allow(clippy::too_many_arguments)] // reason: one row, its place and the filter, all needed.
pub(super) fn filter_row<S: Texel, const T: usize>(
    row: &[S],
    origin: usize,
    split: &mut RowSplit,
    taps: &AxisTaps,
    ks: Range<usize>,
    w: &Weights<T>,
    out: &mut [f32],
) {
    let interior = taps.interior();
    let inner = interior.start.clamp(ks.start, ks.end)..interior.end.clamp(ks.start, ks.end);
    let inner = if inner.is_empty() {
        ks.start..ks.start
    } else {
        inner
    };
    for k in (ks.start..inner.start).chain(inner.end..ks.end) {
        let mut acc = 0.0_f64;
        for (&wt, &i) in w.f64.iter().zip(taps.row(k)) {
            acc += wt * f64::from(row[i - origin].normalized());
        }
        out[k - ks.start] = acc as f32;
    }
    if inner.is_empty() {
        return;
    }
    // Tap t of sample k reads row index 2k + first_offset + t - origin.
    let first = (2 * inner.start as i64 + taps.first_offset() - origin as i64) as usize;
    let out = &mut out[inner.start - ks.start..inner.end - ks.start];
    if w.exact_in_f32 && T == 1 {
        for (o, v) in out.iter_mut().zip(row[first..].iter().step_by(2)) {
            *o = 0.0 + w.f32[0] * v.normalized();
        }
    } else if w.exact_in_f32 && T == 2 {
        // Interior samples have both taps inside the row, so the pairs are complete.
        for (o, pair) in out.iter_mut().zip(row[first..].chunks_exact(2)) {
            *o = 0.0 + w.f32[0] * pair[0].normalized() + w.f32[T - 1] * pair[1].normalized();
        }
    } else {
        split.load(row);
        // Tap t reads half (first + t) mod 2 of the split row at position (first + t) div 2 + i.
        let rows: [&[f32]; T] = std::array::from_fn(|t| {
            let index = first + t;
            let half = if index.is_multiple_of(2) {
                &split.even
            } else {
                &split.odd
            };
            &half[index / 2..]
        });
        combine_rows(rows, w, out);
    }
}

/// `out[i] = sum_t w[t] * rows[t][i]`, accumulated in tap order from 0 in `f64` and rounded to
/// `f32` (the reference's arithmetic), or in `f32` where that is provably the same
/// ([`Weights::new`]). Every row must hold at least `out.len()` values.
#[inline]
pub(super) fn combine_rows<const T: usize>(rows: [&[f32]; T], w: &Weights<T>, out: &mut [f32]) {
    let len = out.len();
    let rows = rows.map(|r| &r[..len]);
    if w.exact_in_f32 {
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0_f32;
            for (r, &wt) in rows.iter().zip(&w.f32) {
                acc += wt * r[i];
            }
            *o = acc;
        }
    } else {
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0_f64;
            for (r, &wt) in rows.iter().zip(&w.f64) {
                acc += wt * f64::from(r[i]);
            }
            *o = acc as f32;
        }
    }
}
