//! Texel types of the kernel: how a voxel normalises, how a normalised value quantises to a
//! storage texel, and the row copies that cut packed bricks (clamp-to-edge, converting on the fly).
//!
//! Every conversion here is the reference's bit for bit: [`Texel::normalized`] is
//! [`VoxelData::normalized`](crate::volume::VoxelData::normalized) and [`Texel::from_normalized`]
//! is [`quantize_to`](crate::bricks::quantize_to) (tested in this module).

use super::TexelsMut;
use std::any::TypeId;
use std::ops::Range;

/// A voxel / texel type: how it normalises, quantises and orders.
pub(crate) trait Texel: bytemuck::Pod + Send + Sync + 'static {
    /// Larger than or equal to every value (identity of `min_of`).
    const HIGHEST: Self;
    /// Smaller than or equal to every value (identity of `max_of`).
    const LOWEST: Self;
    /// True for UNORM types: normalised values are `0` or at least `1 / 65535`.
    const UNORM: bool;
    /// The normalised value, exactly as
    /// [`VoxelData::normalized`](crate::volume::VoxelData::normalized) computes it.
    fn normalized(self) -> f32;
    /// The texel storing normalised `v`, exactly as [`crate::bricks::quantize_to`] computes it.
    fn from_normalized(v: f32) -> Self;
    /// `(min, max)` of `values` and `init` (finite values only for `f32`).
    fn min_max(values: &[Self], init: (Self, Self)) -> (Self, Self);
    /// Column-wise `lo[i] = min(lo[i], values[i])`, `hi[i] = max(hi[i], values[i])`.
    fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]);
    /// The texels of `texels` when they are of this type.
    fn of_texels(texels: TexelsMut<'_>) -> Option<&mut [Self]>;
    /// `texels` as [`TexelsMut`].
    fn texels(texels: &mut [Self]) -> TexelsMut<'_>;
}

/// The UNORM texel types differ only in their maximum; one definition serves both.
macro_rules! unorm_texel {
    ($t:ty, $max:expr, $variant:ident) => {
        impl Texel for $t {
            const HIGHEST: Self = <$t>::MAX;
            const LOWEST: Self = 0;
            const UNORM: bool = true;
            #[inline]
            fn normalized(self) -> f32 {
                f32::from(self) / $max
            }
            #[inline]
            fn from_normalized(v: f32) -> Self {
                unorm_round(v, $max) as $t
            }
            #[inline]
            fn min_max(values: &[Self], (mut lo, mut hi): (Self, Self)) -> (Self, Self) {
                // A plain reduction: the compiler vectorises it.
                for &v in values {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                (lo, hi)
            }
            #[inline]
            fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]) {
                for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(values) {
                    *l = (*l).min(v);
                    *h = (*h).max(v);
                }
            }
            fn of_texels(texels: TexelsMut<'_>) -> Option<&mut [Self]> {
                match texels {
                    TexelsMut::$variant(v) => Some(v),
                    _ => None,
                }
            }
            fn texels(texels: &mut [Self]) -> TexelsMut<'_> {
                TexelsMut::$variant(texels)
            }
        }
    };
}

unorm_texel!(u8, 255.0, U8);
unorm_texel!(u16, 65535.0, U16);

impl Texel for f32 {
    const HIGHEST: Self = f32::INFINITY;
    const LOWEST: Self = f32::NEG_INFINITY;
    const UNORM: bool = false;
    #[inline]
    fn normalized(self) -> f32 {
        self
    }
    #[inline]
    fn from_normalized(v: f32) -> Self {
        v
    }
    #[inline]
    fn min_max(values: &[Self], init: (Self, Self)) -> (Self, Self) {
        // Reduce order-preserving integer keys, which vectorises (float min / max reductions do
        // not without fast-math). Volumes and low-res levels hold finite values only.
        let (mut lo, mut hi) = (f32_key(init.0), f32_key(init.1));
        for &v in values {
            let key = f32_key(v);
            lo = lo.min(key);
            hi = hi.max(key);
        }
        (f32_from_key(lo), f32_from_key(hi))
    }
    #[inline]
    fn fold_columns(lo: &mut [Self], hi: &mut [Self], values: &[Self]) {
        // Plain comparisons: element-wise, so they vectorise (finite values only).
        for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(values) {
            *l = if v < *l { v } else { *l };
            *h = if v > *h { v } else { *h };
        }
    }
    fn of_texels(texels: TexelsMut<'_>) -> Option<&mut [Self]> {
        match texels {
            TexelsMut::F32(v) => Some(v),
            _ => None,
        }
    }
    fn texels(texels: &mut [Self]) -> TexelsMut<'_> {
        TexelsMut::F32(texels)
    }
}

/// An `i32` ordered like the (non-NaN) `f32` `v`: negative values get their magnitude bits
/// flipped, so the total order of the keys is the order of the values (`-0.0` just below `0.0`).
#[inline]
fn f32_key(v: f32) -> i32 {
    let bits = v.to_bits() as i32;
    bits ^ ((bits >> 31) & 0x7FFF_FFFF)
}

/// The inverse of [`f32_key`].
#[inline]
fn f32_from_key(key: i32) -> f32 {
    f32::from_bits((key ^ ((key >> 31) & 0x7FFF_FFFF)) as u32)
}

/// `(v.clamp(0.0, 1.0) * max).round()` as an integer (NaN gives 0), exactly as
/// [`crate::bricks::quantize_to`] computes it, for `max <= 65535`, in operations that vectorise (no
/// saturating float-to-int cast):
///
/// - after the clamp, `x = v * max` is the same `f32` product in `[0, max]`;
/// - `y = x + 2^23` rounds `x` to the nearest integer, ties to even (the `f32` spacing in
///   `[2^23, 2^24)` is 1), and the low mantissa bits of `y` are that integer `r`;
/// - `x - r` is exact (Sterbenz), and equals `0.5` exactly when `x` was a tie that went down to an
///   even `r`: `f32::round` rounds ties away from zero, so add one there.
#[inline]
fn unorm_round(v: f32, max: f32) -> u32 {
    const TWO_POW_23: f32 = 8_388_608.0;
    let v = if v > 0.0 { v } else { 0.0 }; // also maps NaN (and -0.0) to 0
    let v = if v < 1.0 { v } else { 1.0 };
    let x = v * max;
    let y = x + TWO_POW_23;
    let nearest_even = y.to_bits() - TWO_POW_23.to_bits();
    let tie_down = x - (y - TWO_POW_23) == 0.5;
    nearest_even + u32::from(tie_down)
}

/// Converts `src` to `dst` texel by texel (normalise, then quantise); a plain copy when both
/// types are the same (the conversion is the identity then).
#[inline(always)]
pub(crate) fn convert_into<S: Texel, D: Texel>(src: &[S], dst: &mut [D]) {
    if TypeId::of::<S>() == TypeId::of::<D>() {
        dst.copy_from_slice(bytemuck::cast_slice(src));
    } else {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = D::from_normalized(s.normalized());
        }
    }
}

/// One converted texel.
#[inline(always)]
fn convert_one<S: Texel, D: Texel>(s: S) -> D {
    let mut one = [D::zeroed()];
    convert_into(&[s], &mut one);
    one[0]
}

/// [`convert_into`] for the short rows of packed bricks: the usual row lengths (`n + 2` and
/// `n/2 + 1` for `n` = 8, 16, 32, 64) get a copy of constant length, which compiles to a few
/// vector moves instead of a `memcpy` call.
#[inline(always)]
fn convert_short<S: Texel, D: Texel>(src: &[S], dst: &mut [D]) {
    #[inline(always)]
    fn fixed<S: Texel, D: Texel, const N: usize>(src: &[S], dst: &mut [D]) -> bool {
        match (<&[S; N]>::try_from(src), <&mut [D; N]>::try_from(dst)) {
            (Ok(src), Ok(dst)) => {
                convert_into(src, dst);
                true
            }
            _ => false,
        }
    }
    let done = match dst.len() {
        9 => fixed::<S, D, 9>(src, dst),
        10 => fixed::<S, D, 10>(src, dst),
        17 => fixed::<S, D, 17>(src, dst),
        18 => fixed::<S, D, 18>(src, dst),
        33 => fixed::<S, D, 33>(src, dst),
        34 => fixed::<S, D, 34>(src, dst),
        65 => fixed::<S, D, 65>(src, dst),
        66 => fixed::<S, D, 66>(src, dst),
        _ => false,
    };
    if !done {
        convert_into(src, dst);
    }
}

/// Fills `dst` with the texels `row[clamp(start + t, 0, len - 1)]`, converted; returns the range
/// of `row` indices that was copied without clamping (it contains every index read).
#[inline(always)]
pub(crate) fn copy_clamped_row<S: Texel, D: Texel>(
    row: &[S],
    start: i64,
    dst: &mut [D],
) -> Range<usize> {
    let len = dst.len() as i64;
    let last = row.len() as i64 - 1;
    let left = (-start).clamp(0, len) as usize;
    let mid_end = (last + 1 - start).clamp(left as i64, len) as usize;
    let first = (start + left as i64) as usize;
    let copied = first..first + (mid_end - left);
    convert_short(&row[copied.clone()], &mut dst[left..mid_end]);
    if left > 0 {
        dst[..left].fill(convert_one(row[0]));
    }
    if mid_end < dst.len() {
        dst[mid_end..].fill(convert_one(row[last as usize]));
    }
    copied
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::quantize_to;
    use crate::bricks::tests::pseudo_random;
    use crate::volume::{ScalarType, VoxelData};

    #[test]
    fn fast_quantisation_equals_quantize_to() {
        let mut values = vec![
            f32::NAN,
            -0.0,
            0.0,
            -1.0,
            2.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            1.0,
            0.5,
            1.0 - f32::EPSILON,
        ];
        let next = |v: f32, d: i32| f32::from_bits(v.to_bits().wrapping_add_signed(d));
        for (levels, count) in [(65535.0_f32, 65535u32), (255.0, 255)] {
            for k in 0..=count {
                let tie = (k as f32 + 0.5) / levels;
                values.extend((-2..=2).map(|d| next(tie, d)));
            }
        }
        // A stride through every bit pattern of [0, 1].
        values.extend((0..=1.0_f32.to_bits()).step_by(1009).map(f32::from_bits));
        values.extend(pseudo_random(100_000, 9).iter().map(|v| v * 1.2 - 0.1));
        let ties = values
            .iter()
            .filter(|&&v| (v * 65535.0).fract() == 0.5 && v < 1.0)
            .count();
        assert!(ties > 1000, "only {ties} exact ties exercised");
        let words = quantize_to(&values, ScalarType::U16);
        let bytes = quantize_to(&values, ScalarType::U8);
        for (i, &v) in values.iter().enumerate() {
            let word = u16::from_ne_bytes([words[2 * i], words[2 * i + 1]]);
            assert_eq!(u16::from_normalized(v), word, "{v:e} ({:#x})", v.to_bits());
            assert_eq!(
                u8::from_normalized(v),
                bytes[i],
                "{v:e} ({:#x})",
                v.to_bits()
            );
        }
    }

    #[test]
    fn fast_unorm_matches_quantize_to_bit_for_bit() {
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            2.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
        ];
        for levels in [255.0_f32, 65535.0] {
            for k in 0..=levels as u32 {
                for x in [k as f32 - 0.5, k as f32 + 0.5, k as f32] {
                    let v = x / levels;
                    // The neighbouring floats (v is positive or zero here).
                    let b = v.to_bits();
                    values.extend([v, f32::from_bits(b + 1), f32::from_bits(b.max(1) - 1)]);
                }
            }
        }
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        for _ in 0..1_000_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            values.push(f32::from_bits(state as u32 & 0x3FFF_FFFF));
        }
        let u8s = quantize_to(&values, ScalarType::U8);
        let u16s = quantize_to(&values, ScalarType::U16);
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(u8::from_normalized(v), u8s[i], "u8 {v:e}");
            let w = u16::from_ne_bytes([u16s[2 * i], u16s[2 * i + 1]]);
            assert_eq!(u16::from_normalized(v), w, "u16 {v:e}");
        }
    }

    #[test]
    fn same_type_copy_equals_normalise_then_quantise() {
        // The verbatim-copy path relies on quantise(normalise(v)) == v on the storage grid.
        for v in 0..=u16::MAX {
            assert_eq!(u16::from_normalized(v.normalized()), v);
            let packed = quantize_to(&[VoxelData::U16(vec![v]).normalized(0)], ScalarType::U16);
            assert_eq!(packed, v.to_ne_bytes());
        }
        for v in 0..=u8::MAX {
            assert_eq!(u8::from_normalized(v.normalized()), v);
        }
        let mut out = [0u8; 7];
        let range = copy_clamped_row(&[10u8, 20, 30], -2, &mut out);
        assert_eq!(out, [10, 10, 10, 20, 30, 30, 30]);
        assert_eq!(range, 0..3);
        let mut out = [0u8; 3];
        assert_eq!(copy_clamped_row(&[1u8, 2, 3, 4, 5], 1, &mut out), 1..4);
        assert_eq!(out, [2, 3, 4]);
    }
}
