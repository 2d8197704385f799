//! The separable downsampling filters ([`DownsampleFilter`]: the taps `(offset, weight)` that make
//! the low-res sample at `2k`) and their taps along one axis ([`AxisTaps`]): for every low-res
//! sample `k` of the axis, the clamped hi-res indices its filter taps read (`DESIGN.md` §1,
//! [`super::filters`]).
//!
//! One table serves the reference ([`super::low_res_block`]) and the kernel
//! ([`super::kernel`]), so both read exactly the same voxels for every sample.

use std::ops::Range;

/// A separable downsampling filter producing the low-res sample at position `2k`.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub enum DownsampleFilter {
    /// Mean of hi-res indices `2k-1` and `2k` per axis (the 2x2x2 mean of Beyer et al. §3.1),
    /// i.e. the two voxels at `2k ∓ 0.5`. Reproduces linear functions exactly.
    #[default]
    Mean2,
    /// LaMar et al. 1999 subsampling `B_k = A_{2k}`: the single voxel of index `2k` (position
    /// `2k + 0.5`), no averaging. The sample is therefore biased by half a hi-res voxel towards `+`
    /// on each axis: a linear ramp `f(p)` comes out as `f(2k + 0.5)` at position `2k`.
    LaMarSubsample,
    /// Kraus' 4-tap box `1/4 (1 1 1 1)` over indices `2k-2 ..= 2k+1`, the best 4-tap compromise for
    /// trilinear reconstruction. Reproduces linear functions exactly.
    Box4,
    /// Kraus' `1/64 (13 19 19 13)` over indices `2k-2 ..= 2k+1`, matched to quadratic B-spline
    /// reconstruction. Reproduces linear functions exactly.
    BSpline4,
}

const MEAN2_TAPS: [(i64, f32); 2] = [(-1, 0.5), (0, 0.5)];
const LAMAR_TAPS: [(i64, f32); 1] = [(0, 1.0)];
const BOX4_TAPS: [(i64, f32); 4] = [(-2, 0.25), (-1, 0.25), (0, 0.25), (1, 0.25)];
const BSPLINE4_TAPS: [(i64, f32); 4] = [
    (-2, 13.0 / 64.0),
    (-1, 19.0 / 64.0),
    (0, 19.0 / 64.0),
    (1, 13.0 / 64.0),
];

impl DownsampleFilter {
    /// Every filter, for tests and option lists.
    pub const ALL: [DownsampleFilter; 4] = [
        DownsampleFilter::Mean2,
        DownsampleFilter::LaMarSubsample,
        DownsampleFilter::Box4,
        DownsampleFilter::BSpline4,
    ];

    /// The 1D taps `(offset from index 2k, weight)`; the weights sum to one.
    pub fn taps(self) -> &'static [(i64, f32)] {
        match self {
            DownsampleFilter::Mean2 => &MEAN2_TAPS,
            DownsampleFilter::LaMarSubsample => &LAMAR_TAPS,
            DownsampleFilter::Box4 => &BOX4_TAPS,
            DownsampleFilter::BSpline4 => &BSPLINE4_TAPS,
        }
    }

    /// Parses `mean2`, `lamar`, `box4` or `bspline4` (case-insensitive).
    pub fn parse(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "mean2" | "mean" | "box2" => Some(DownsampleFilter::Mean2),
            "lamar" | "subsample" | "lamar-subsample" => Some(DownsampleFilter::LaMarSubsample),
            "box4" => Some(DownsampleFilter::Box4),
            "bspline4" | "bspline" => Some(DownsampleFilter::BSpline4),
            _ => None,
        }
    }
}

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
