//! Brick culling: which bricks can contribute to the image at all.
//!
//! Three tests, each O(1) per brick, combined by [`cull_bricks`]:
//!
//! - **Transfer-function culling** ([`TfCullTable`]): a brick whose values all map to
//!   transparent transfer-function entries is invisible. A prefix count over the entries with
//!   non-zero opacity answers "is any entry in `a..=b` visible?" with two loads.
//! - **Iso-value culling** ([`iso_active`]): for iso-surface rendering a brick matters only when
//!   its value range contains the iso-value.
//! - **Clip planes** ([`ClipPlanes`], defined with the scene): a brick whose world-space box lies entirely on the clipped
//!   side of a plane is removed.
//!
//! Brick value ranges are the conservative per-brick min/max of [`crate::bricks`]
//! ([`ValueRange`]), which already bound every value trilinear filtering, the low-res level and
//! the smooth-transition fixup can produce inside the brick.

use super::error::LodError;
use super::geometry::BrickGeometry;
use crate::bricks::ValueRange;
use crate::optics::{TransferFunction, TF_SIZE};
use crate::scene::ClipPlanes;

/// Transfer-function culling table for one transfer function and value window.
///
/// Value `v` maps to the TF position `s = clamp((v - lo) * inv_range, 0, 1)` exactly as
/// [`crate::optics::classify`] computes it, and the lookup at `x = s * (N - 1)` interpolates
/// linearly between entries `floor(x)` and `floor(x) + 1` ([`TransferFunction::lookup`]). A brick
/// with values in `[min, max]` (a monotone map, so positions `[s_min, s_max]`) can therefore read
/// exactly the entries `floor(s_min * (N - 1)) ..= ceil(s_max * (N - 1))`, and it is *active* iff
/// one of them has opacity > 0. Values outside the window clamp to the end entries.
///
/// `prefix[i]` counts the entries `0..i` with non-zero opacity, so the test is
/// `prefix[last + 1] - prefix[first] > 0`: O(1) per brick after an O(N) build per TF and window.
#[derive(Clone, Debug, PartialEq)]
pub struct TfCullTable {
    prefix: Vec<u32>,
    window_lo: f32,
    window_inv_range: f32,
}

impl TfCullTable {
    /// Builds the table for `tf` seen through the value window `(lo, hi)`: values `lo` and `hi`
    /// map to TF positions 0 and 1. An empty window (`hi <= lo`) maps every value to position 0,
    /// as [`crate::scene::RaycastParams`] does.
    pub fn new(tf: &TransferFunction, window: (f32, f32)) -> Result<Self, LodError> {
        let (lo, hi) = window;
        let inv_range = if hi > lo { 1.0 / (hi - lo) } else { 0.0 };
        if !hi.is_finite() {
            return Err(LodError::InvalidWindow { lo, inv_range });
        }
        Self::with_inverse_range(tf, lo, inv_range)
    }

    /// Builds the table from the window as the GPU receives it (`RaycastParams::tf_window.xy`):
    /// `window_lo` and `window_inv_range = 1 / (hi - lo)` (0 for an empty window). Both must be
    /// finite and the inverse range non-negative.
    pub fn with_inverse_range(
        tf: &TransferFunction,
        window_lo: f32,
        window_inv_range: f32,
    ) -> Result<Self, LodError> {
        if !(window_lo.is_finite() && window_inv_range.is_finite() && window_inv_range >= 0.0) {
            return Err(LodError::InvalidWindow {
                lo: window_lo,
                inv_range: window_inv_range,
            });
        }
        let mut prefix = Vec::with_capacity(TF_SIZE + 1);
        let mut count = 0u32;
        prefix.push(0);
        for entry in tf.entries() {
            count += u32::from(entry.w > 0.0);
            prefix.push(count);
        }
        Ok(Self {
            prefix,
            window_lo,
            window_inv_range,
        })
    }

    /// Number of transfer-function entries (`N`).
    pub fn entry_count(&self) -> usize {
        self.prefix.len() - 1
    }

    /// TF position of `value`, as [`crate::optics::classify`] computes it.
    pub fn position(&self, value: f32) -> f32 {
        ((value - self.window_lo) * self.window_inv_range).clamp(0.0, 1.0)
    }

    /// The entries `first ..= last` a sample with a value in `range` can read, or `None` for an
    /// empty range (`min > max`). A range with a NaN end reads every entry (conservative).
    #[inline]
    pub fn entry_span(&self, range: ValueRange) -> Option<(usize, usize)> {
        let last_entry = self.entry_count() - 1;
        if range.min.is_nan() || range.max.is_nan() {
            return Some((0, last_entry));
        }
        if range.min > range.max {
            return None;
        }
        let scale = last_entry as f32;
        // x >= 0, so truncation is floor; ceil adds one unless x is integral (no libm calls).
        let x_min = self.position(range.min) * scale;
        let x_max = self.position(range.max) * scale;
        // Both lie in [0, N - 1]: the i32 conversion is exact and a single instruction.
        let first = x_min as i32 as usize;
        let truncated = x_max as i32;
        let last = (truncated + i32::from((truncated as f32) < x_max)) as usize;
        Some((first.min(last_entry), last.min(last_entry)))
    }

    /// Number of entries with non-zero opacity among `first ..= last` (indices clamped to the
    /// table; 0 when `first > last`).
    pub fn visible_entries(&self, first: usize, last: usize) -> u32 {
        let last = last.min(self.entry_count() - 1);
        if first > last {
            return 0;
        }
        self.prefix[last + 1] - self.prefix[first]
    }

    /// True when a brick with values in `range` can produce a sample with non-zero opacity.
    #[inline]
    pub fn is_active(&self, range: ValueRange) -> bool {
        self.entry_span(range)
            .is_some_and(|(first, last)| self.visible_entries(first, last) > 0)
    }
}

/// Iso-value culling: a brick can hold the iso-surface `value == iso` only when
/// `min <= iso <= max`.
pub fn iso_active(range: ValueRange, iso: f32) -> bool {
    range.min <= iso && iso <= range.max
}

/// Which value-based test decides whether a brick is visible.
#[derive(Clone, Debug, PartialEq)]
pub enum ValueCulling {
    /// Keep every brick whose value range is non-empty.
    None,
    /// Direct volume rendering: keep bricks that can read a non-transparent TF entry.
    TransferFunction(TfCullTable),
    /// Iso-surface rendering: keep bricks whose range contains the iso-value.
    IsoValue(f32),
}

/// All culling criteria for one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct CullParams {
    /// The value-based test.
    pub value: ValueCulling,
    /// The clip planes.
    pub clip: ClipPlanes,
}

impl CullParams {
    /// Culling by the transfer function only.
    pub fn transfer_function(table: TfCullTable) -> Self {
        Self {
            value: ValueCulling::TransferFunction(table),
            clip: ClipPlanes::NONE,
        }
    }
}

/// Culls every brick of `geometry`: `active[i]` is true when brick `i` (linear index) passes the
/// value test on `ranges[i]` and no clip plane removes its box. `ranges` holds one entry per
/// brick, as [`crate::bricks::brick_value_ranges`] returns them. Empty ranges are always culled.
pub fn cull_bricks(
    geometry: &BrickGeometry,
    ranges: &[ValueRange],
    params: &CullParams,
) -> Result<Vec<bool>, LodError> {
    let mut active = Vec::new();
    cull_bricks_into(geometry, ranges, params, &mut active)?;
    Ok(active)
}

/// As [`cull_bricks`], writing into `active` (cleared first) to reuse its allocation.
pub fn cull_bricks_into(
    geometry: &BrickGeometry,
    ranges: &[ValueRange],
    params: &CullParams,
    active: &mut Vec<bool>,
) -> Result<(), LodError> {
    let expected = geometry.grid().brick_count();
    if ranges.len() != expected {
        return Err(LodError::LengthMismatch {
            what: "value ranges",
            expected,
            actual: ranges.len(),
        });
    }
    if let ValueCulling::IsoValue(iso) = params.value {
        if !iso.is_finite() {
            return Err(LodError::InvalidIsoValue { iso });
        }
    }
    active.clear();
    match &params.value {
        ValueCulling::None => active.extend(ranges.iter().map(|r| !r.is_empty())),
        ValueCulling::TransferFunction(table) => {
            active.extend(ranges.iter().map(|&r| table.is_active(r)));
        }
        // NaN ends compare false: keep such a brick (conservative).
        ValueCulling::IsoValue(iso) => active.extend(
            ranges
                .iter()
                .map(|&r| iso_active(r, *iso) || r.min.is_nan() || r.max.is_nan()),
        ),
    }
    if !params.clip.planes().is_empty() {
        geometry.for_each_brick_box(|index, min, max| {
            if active[index] && params.clip.box_clipped(min, max) {
                active[index] = false;
            }
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bricks::BrickGrid;
    use crate::optics::{classify, TfPreset};
    use crate::scene::{ClipPlane, ClipPlaneError};
    use glam::Vec3;
    use glam::{UVec3, Vec4};

    /// Deterministic pseudo-random numbers in [0, 1) (xorshift64).
    struct Rng(u64);

    impl Rng {
        fn new(seed: u64) -> Self {
            Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
        }
        fn next_f32(&mut self) -> f32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
        fn below(&mut self, n: usize) -> usize {
            ((self.next_f32() * n as f32) as usize).min(n - 1)
        }
    }

    fn range(min: f32, max: f32) -> ValueRange {
        ValueRange { min, max }
    }

    /// A TF whose opacity is non-zero exactly at `visible` entries.
    fn tf_with_visible(visible: &[usize]) -> TransferFunction {
        let mut entries = vec![Vec4::new(0.3, 0.6, 0.9, 0.0); TF_SIZE];
        for &i in visible {
            entries[i].w = 0.5;
        }
        TransferFunction::from_entries(entries).unwrap()
    }

    /// Random sparse TFs: a few opaque runs and single entries, sometimes none at all.
    fn random_tf(rng: &mut Rng) -> TransferFunction {
        let mut visible = Vec::new();
        let runs = rng.below(4);
        for _ in 0..runs {
            let start = rng.below(TF_SIZE);
            let max_len = if rng.next_f32() < 0.5 { 2 } else { 40 };
            let len = 1 + rng.below(max_len);
            visible.extend(start..(start + len).min(TF_SIZE));
        }
        tf_with_visible(&visible)
    }

    /// The specification, checked entry by entry: entry `i` is read by a sample at `x` when
    /// `|x - i| < 1` (it gets weight `1 - |x - i| > 0`) or `x == i`; over `[x_min, x_max]` that is
    /// `x_min < i + 1 && x_max > i - 1`.
    fn brute_force_active(tf: &TransferFunction, lo: f32, inv: f32, r: ValueRange) -> bool {
        if r.min > r.max {
            return false;
        }
        let scale = (TF_SIZE - 1) as f32;
        let x_min = ((r.min - lo) * inv).clamp(0.0, 1.0) * scale;
        let x_max = ((r.max - lo) * inv).clamp(0.0, 1.0) * scale;
        tf.entries().iter().enumerate().any(|(i, e)| {
            let i = i as f32;
            e.w > 0.0 && x_min < i + 1.0 && x_max > i - 1.0
        })
    }

    #[test]
    fn prefix_table_matches_brute_force_on_random_ranges_and_tfs() {
        let mut rng = Rng::new(42);
        let mut active_seen = 0;
        let mut culled_seen = 0;
        for _ in 0..200 {
            let tf = random_tf(&mut rng);
            // Windows inside, around and beyond [0, 1], plus the empty window.
            let lo = rng.next_f32() * 1.2 - 0.3;
            let hi = if rng.next_f32() < 0.1 {
                lo
            } else {
                lo + 0.05 + rng.next_f32()
            };
            let table = TfCullTable::new(&tf, (lo, hi)).unwrap();
            let inv = if hi > lo { 1.0 / (hi - lo) } else { 0.0 };
            for _ in 0..200 {
                let a = rng.next_f32() * 1.6 - 0.3;
                // Mostly narrow ranges (the interesting case), some wide, some degenerate.
                let w = match rng.below(3) {
                    0 => 0.0,
                    1 => rng.next_f32() * 0.02,
                    _ => rng.next_f32(),
                };
                let r = range(a, a + w);
                let expected = brute_force_active(&tf, lo, inv, r);
                assert_eq!(
                    table.is_active(r),
                    expected,
                    "window ({lo}, {hi}) range {r:?}"
                );
                if expected {
                    active_seen += 1;
                } else {
                    culled_seen += 1;
                }
            }
            // Ranges whose ends map exactly onto entry centres: ceil/floor must not widen them.
            for _ in 0..20 {
                let i = rng.below(TF_SIZE) as f32;
                let v = if inv > 0.0 {
                    lo + i / (TF_SIZE - 1) as f32 / inv
                } else {
                    lo
                };
                let r = range(v, v);
                assert_eq!(
                    table.is_active(r),
                    brute_force_active(&tf, lo, inv, r),
                    "{r:?}"
                );
            }
        }
        assert!(
            active_seen > 1000 && culled_seen > 1000,
            "{active_seen} / {culled_seen}"
        );
    }

    #[test]
    fn exact_entry_centres_read_one_entry_and_neighbours_are_touched_otherwise() {
        let scale = (TF_SIZE - 1) as f32;
        let tf = tf_with_visible(&[100]);
        let table = TfCullTable::new(&tf, (0.0, 1.0)).unwrap();
        // A value exactly at the centre of entry 99 or 101 reads only that entry.
        assert!(!table.is_active(range(99.0 / scale, 99.0 / scale)));
        assert!(!table.is_active(range(101.0 / scale, 101.0 / scale)));
        assert!(table.is_active(range(100.0 / scale, 100.0 / scale)));
        // Just past a neighbour's centre, towards 100: interpolation reads entry 100.
        assert!(table.is_active(range(99.5 / scale, 99.5 / scale)));
        assert!(table.is_active(range(100.5 / scale, 100.5 / scale)));
        // A range spanning entry 100 without an end near it.
        assert!(table.is_active(range(0.1, 0.9)));
        assert!(!table.is_active(range(0.0, 98.0 / scale)));
        assert!(!table.is_active(range(102.0 / scale, 1.0)));
        assert_eq!(table.entry_span(range(0.5, 0.25)), None);
        assert!(!table.is_active(ValueRange::EMPTY));
    }

    #[test]
    fn values_outside_the_window_clamp_to_the_end_entries() {
        let window = (0.25, 0.75);
        let first_only = TfCullTable::new(&tf_with_visible(&[0]), window).unwrap();
        let second_only = TfCullTable::new(&tf_with_visible(&[1]), window).unwrap();
        let last_only = TfCullTable::new(&tf_with_visible(&[TF_SIZE - 1]), window).unwrap();
        let below = range(-5.0, 0.2);
        let above = range(0.8, 7.0);
        assert!(first_only.is_active(below));
        assert!(
            !second_only.is_active(below),
            "clamped to s = 0 reads entry 0 only"
        );
        assert!(!last_only.is_active(below));
        assert!(last_only.is_active(above));
        assert!(!first_only.is_active(above));
        assert_eq!(first_only.entry_span(below), Some((0, 0)));
        assert_eq!(
            first_only.entry_span(above),
            Some((TF_SIZE - 1, TF_SIZE - 1))
        );
        // Straddling the window reads everything.
        assert_eq!(
            first_only.entry_span(range(-1.0, 2.0)),
            Some((0, TF_SIZE - 1))
        );
        // An empty window maps everything to entry 0, as the ray-caster does.
        let empty = TfCullTable::new(&tf_with_visible(&[0]), (0.5, 0.5)).unwrap();
        assert!(empty.is_active(range(0.9, 1.0)));
        let empty = TfCullTable::new(&tf_with_visible(&[1]), (0.5, 0.5)).unwrap();
        assert!(!empty.is_active(range(0.0, 1.0)));
    }

    /// The property the renderer relies on: if any value in the range classifies to non-zero
    /// opacity, the brick is active.
    #[test]
    fn culling_is_conservative_for_classify() {
        let mut rng = Rng::new(7);
        for preset in [TfPreset::Fire, TfPreset::Bands, TfPreset::Grey] {
            let tf = TransferFunction::preset(preset);
            for window in [(0.0, 1.0), (0.3, 0.6), (0.45, 0.55)] {
                let table = TfCullTable::new(&tf, window).unwrap();
                let inv = 1.0 / (window.1 - window.0);
                for _ in 0..300 {
                    let a = rng.next_f32();
                    let r = range(a, (a + rng.next_f32() * 0.05).min(1.0));
                    let visible = (0..=64).any(|k| {
                        let v = r.min + (r.max - r.min) * k as f32 / 64.0;
                        classify(&tf, window.0, inv, v).w > 0.0
                    });
                    if visible {
                        assert!(table.is_active(r), "{preset:?} {window:?} {r:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn bad_windows_are_rejected() {
        let tf = TransferFunction::preset(TfPreset::Grey);
        assert!(matches!(
            TfCullTable::new(&tf, (f32::NAN, 1.0)),
            Err(LodError::InvalidWindow { .. })
        ));
        assert!(TfCullTable::new(&tf, (0.0, f32::INFINITY)).is_err());
        assert!(
            TfCullTable::new(&tf, (0.0, 1e-45)).is_err(),
            "1/(hi-lo) overflows"
        );
        assert!(TfCullTable::with_inverse_range(&tf, 0.0, -1.0).is_err());
        assert!(TfCullTable::with_inverse_range(&tf, 0.0, 2.0).is_ok());
    }

    #[test]
    fn iso_culling_keeps_ranges_containing_the_iso_value() {
        assert!(iso_active(range(0.2, 0.6), 0.5));
        assert!(iso_active(range(0.5, 0.5), 0.5));
        assert!(iso_active(range(0.2, 0.5), 0.5));
        assert!(!iso_active(range(0.2, 0.49), 0.5));
        assert!(!iso_active(range(0.51, 0.9), 0.5));
        assert!(!iso_active(ValueRange::EMPTY, 0.5));
    }

    /// All eight corners, the definition the positive-vertex shortcut must match.
    fn all_corners_clipped(plane: &ClipPlane, min: Vec3, max: Vec3) -> bool {
        (0..8).all(|c| {
            let p = Vec3::new(
                if c & 1 == 0 { min.x } else { max.x },
                if c & 2 == 0 { min.y } else { max.y },
                if c & 4 == 0 { min.z } else { max.z },
            );
            plane.signed_distance(p) < 0.0
        })
    }

    #[test]
    fn clip_planes_cull_boxes_entirely_on_the_clipped_side() {
        // Keep x >= 0.
        let keep_pos_x = ClipPlane::new(Vec3::X, 0.0);
        let (lo, hi) = (Vec3::splat(-0.5), Vec3::splat(-0.1));
        assert!(keep_pos_x.box_clipped(lo, hi));
        // Straddling, and touching the plane (corner at n.p + d = 0), are kept.
        assert!(!keep_pos_x.box_clipped(Vec3::splat(-0.5), Vec3::splat(0.1)));
        assert!(!keep_pos_x.box_clipped(Vec3::new(-0.5, 0.0, 0.0), Vec3::new(0.0, 1.0, 1.0)));
        assert!(!keep_pos_x.box_clipped(Vec3::splat(0.1), Vec3::splat(0.5)));
        // Oblique plane x + y + z >= 1: the unit box's far corner (1,1,1) is kept.
        let oblique = ClipPlane::new(Vec3::ONE, -1.0);
        assert!(!oblique.box_clipped(Vec3::ZERO, Vec3::ONE));
        assert!(oblique.box_clipped(Vec3::ZERO, Vec3::splat(0.3)));
        // Negative normal: keep z <= 0.25.
        let keep_low_z = ClipPlane::new(-Vec3::Z, 0.25);
        assert!(keep_low_z.box_clipped(Vec3::new(0.0, 0.0, 0.3), Vec3::ONE));
        assert!(!keep_low_z.box_clipped(Vec3::new(0.0, 0.0, 0.2), Vec3::ONE));

        let mut rng = Rng::new(3);
        for _ in 0..2000 {
            let v = |rng: &mut Rng| {
                Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - Vec3::ONE
            };
            let plane = ClipPlane::new(v(&mut rng), rng.next_f32() - 0.5);
            let (a, b) = (v(&mut rng), v(&mut rng));
            let (min, max) = (a.min(b), a.max(b));
            assert_eq!(
                plane.box_clipped(min, max),
                all_corners_clipped(&plane, min, max),
                "{plane:?} {min} {max}"
            );
        }
    }

    #[test]
    fn any_one_plane_culls_and_more_than_six_is_an_error() {
        let planes = ClipPlanes::new(&[
            ClipPlane::new(Vec3::X, 0.5),  // keep x >= -0.5
            ClipPlane::new(-Vec3::Y, 0.0), // keep y <= 0
        ])
        .unwrap();
        assert_eq!(planes.planes().len(), 2);
        assert!(!planes.box_clipped(Vec3::splat(-0.4), Vec3::splat(-0.1)));
        assert!(planes.box_clipped(Vec3::new(-0.4, 0.1, -0.4), Vec3::new(-0.1, 0.3, -0.1)));
        assert!(planes.box_clipped(Vec3::new(-0.9, -0.4, 0.0), Vec3::new(-0.6, -0.1, 0.1)));
        assert!(!ClipPlanes::NONE.box_clipped(Vec3::ZERO, Vec3::ONE));

        let six = [ClipPlane::new(Vec3::X, 0.0); 6];
        assert!(ClipPlanes::new(&six).is_ok());
        let seven = [ClipPlane::new(Vec3::X, 0.0); 7];
        assert_eq!(
            ClipPlanes::new(&seven),
            Err(ClipPlaneError::TooMany { count: 7 })
        );
        let bad = [ClipPlane::new(Vec3::X, 0.0), ClipPlane::new(Vec3::NAN, 0.0)];
        assert_eq!(
            ClipPlanes::new(&bad),
            Err(ClipPlaneError::NonFinite { index: 1 })
        );
    }

    #[test]
    fn cull_bricks_combines_value_test_and_clip_planes() {
        // 4 x 1 x 1 bricks of 8 voxels: world x from -0.5 to 0.5 in steps of 0.25.
        let grid = BrickGrid::new(UVec3::new(32, 8, 8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let ranges = [
            range(0.0, 0.1),
            range(0.4, 0.6),
            range(0.45, 0.5),
            ValueRange::EMPTY,
        ];
        let iso = CullParams {
            value: ValueCulling::IsoValue(0.5),
            clip: ClipPlanes::NONE,
        };
        assert_eq!(
            cull_bricks(&geometry, &ranges, &iso).unwrap(),
            [false, true, true, false]
        );
        // Keep x <= 0.1: brick 2 spans [0, 0.25] (kept), brick 3 [0.25, 0.5] (clipped).
        let clip = ClipPlanes::new(&[ClipPlane::new(-Vec3::X, 0.1)]).unwrap();
        let none = CullParams {
            value: ValueCulling::None,
            clip,
        };
        let all = [range(0.0, 1.0); 4];
        assert_eq!(
            cull_bricks(&geometry, &all, &none).unwrap(),
            [true, true, true, false]
        );
        let tf = tf_with_visible(&[TF_SIZE - 1]);
        let by_tf = CullParams::transfer_function(TfCullTable::new(&tf, (0.0, 1.0)).unwrap());
        assert_eq!(
            cull_bricks(
                &geometry,
                &[
                    range(0.0, 1.0),
                    range(0.0, 0.5),
                    range(0.99, 0.99),
                    range(2.0, 3.0)
                ],
                &by_tf
            )
            .unwrap(),
            [true, false, false, true]
        );
        assert_eq!(
            cull_bricks(&geometry, &ranges[..3], &iso),
            Err(LodError::LengthMismatch {
                what: "value ranges",
                expected: 4,
                actual: 3
            })
        );
        let bad_iso = CullParams {
            value: ValueCulling::IsoValue(f32::NAN),
            clip: ClipPlanes::NONE,
        };
        assert!(matches!(
            cull_bricks(&geometry, &ranges, &bad_iso),
            Err(LodError::InvalidIsoValue { .. })
        ));
    }
}
