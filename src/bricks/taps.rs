//! The taps of the separable downsampling filter along one axis: for every low-res sample `k` of
//! the axis, the clamped hi-res indices its filter taps read (`DESIGN.md` §1, [`super::filters`]).
//!
//! One table serves the reference ([`super::low_res_block`]) and the kernel
//! ([`super::kernel`]), so both read exactly the same voxels for every sample.

use super::filters::DownsampleFilter;
use std::ops::Range;

/// The taps of one axis of the separable filter, for the low-res samples `0..=K` of an axis of
/// `d` voxels (`K = ceil(d / 2)`).
#[derive(Clone, Debug)]
pub(crate) struct AxisTaps {
    /// Taps per sample.
    taps: usize,
    /// Per sample `k`, the clamped hi-res index `clamp(2k + offset, 0, d - 1)` of each tap, in tap
    /// order (`taps` entries per sample).
    index: Vec<usize>,
    /// Samples whose taps are the unclamped consecutive indices `2k + first_offset + t`.
    interior: Range<usize>,
    /// Offset of the first tap from `2k`.
    first_offset: i64,
}

impl AxisTaps {
    /// The taps of `filter` along an axis of `d` voxels (`d >= 1`).
    pub(crate) fn new(d: u32, filter: DownsampleFilter) -> Self {
        let offsets: Vec<i64> = filter.taps().iter().map(|&(o, _)| o).collect();
        let taps = offsets.len();
        let last = i64::from(d.max(1)) - 1;
        let kmax = i64::from(d.div_ceil(2));
        let index = (0..=kmax)
            .flat_map(|k| {
                offsets
                    .iter()
                    .map(move |&o| (2 * k + o).clamp(0, last) as usize)
            })
            .collect();
        let consecutive = offsets.windows(2).all(|w| w[1] == w[0] + 1);
        let (first, final_) = (offsets[0], offsets[taps - 1]);
        // 2k + first >= 0 and 2k + final <= last.
        let k_lo = ((-first).max(0) + 1) / 2;
        let k_hi = ((last - final_).div_euclid(2) + 1).clamp(0, kmax + 1);
        let interior = if consecutive && k_lo < k_hi {
            k_lo as usize..k_hi as usize
        } else {
            0..0
        };
        Self {
            taps,
            index,
            interior,
            first_offset: first,
        }
    }

    /// The largest low-res index `K` of the axis.
    pub(crate) fn kmax(&self) -> usize {
        self.index.len() / self.taps - 1
    }

    /// The hi-res indices read by sample `k` (`k <= K`), in tap order.
    #[inline]
    pub(crate) fn row(&self, k: usize) -> &[usize] {
        &self.index[k * self.taps..(k + 1) * self.taps]
    }

    /// [`AxisTaps::row`] as an array of the filter's `T` taps.
    #[inline]
    pub(crate) fn fixed<const T: usize>(&self, k: usize) -> [usize; T] {
        let row = self.row(k);
        std::array::from_fn(|t| row[t])
    }

    /// Samples whose taps read the consecutive unclamped indices `2k + first_offset() + t`.
    pub(crate) fn interior(&self) -> Range<usize> {
        self.interior.clone()
    }

    /// Offset of the first tap from `2k`.
    pub(crate) fn first_offset(&self) -> i64 {
        self.first_offset
    }

    /// The hi-res indices `lo..hi` the taps of the samples `ks` read (empty for empty `ks`).
    pub(crate) fn span(&self, ks: &Range<usize>) -> Range<usize> {
        if ks.is_empty() {
            return 0..0;
        }
        let taps = &self.index[ks.start * self.taps..ks.end * self.taps];
        let lo = taps.iter().copied().min().unwrap_or(0);
        let hi = taps.iter().copied().max().map_or(lo, |i| i + 1);
        lo..hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taps_are_clamped_and_the_interior_is_unclamped() {
        for filter in DownsampleFilter::ALL {
            for d in [1u32, 2, 3, 7, 16, 33] {
                let axis = AxisTaps::new(d, filter);
                assert_eq!(axis.kmax(), d.div_ceil(2) as usize);
                for k in 0..=axis.kmax() {
                    let expected: Vec<usize> = filter
                        .taps()
                        .iter()
                        .map(|&(o, _)| (2 * k as i64 + o).clamp(0, i64::from(d) - 1) as usize)
                        .collect();
                    assert_eq!(axis.row(k), &expected[..], "{filter:?} d {d} k {k}");
                    if axis.interior().contains(&k) {
                        for (t, &i) in axis.row(k).iter().enumerate() {
                            let unclamped = 2 * k as i64 + axis.first_offset() + t as i64;
                            assert_eq!(i as i64, unclamped, "{filter:?} d {d} k {k}");
                        }
                    }
                }
                let all = 0..axis.kmax() + 1;
                assert_eq!(axis.span(&all), 0..d as usize, "{filter:?} d {d}");
                assert_eq!(axis.span(&(1..1)), 0..0);
            }
        }
    }
}
