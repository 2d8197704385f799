//! Level-of-detail selection for flat two-level bricking (Beyer et al. 2008, §3): every brick that
//! survives culling is drawn at least low-res, and a screen-space error ranking decides which
//! bricks get the hi-res slots the cache budget allows.
//!
//! # Cache constraint
//!
//! A `Hi` brick fills one cache slot, a split slot holds eight `Lo` bricks
//! (`docs/cache-layout.md`), so an assignment with `h` hi-res and `l` low-res bricks needs
//! `h + ceil(l / 8)` slots ([`slots_needed`]).
//!
//! # Screen-space error
//!
//! Drawing a brick low-res instead of hi-res doubles its voxel size. [`screen_space_error`]
//! estimates what that costs on screen as the projected size in pixels of one low-res voxel,
//! `2 v / d * H / (2 tan(fov_y / 2))` (`v` the largest world-space side of a hi-res voxel, `d`
//! the distance from the eye to the nearest point of the brick's box, `H` the image height;
//! orthographic: `2 v * H / height`), times a data term, the brick's value range `max - min`: a
//! brick whose values are all equal is reproduced exactly by its low-res level and gains nothing.
//!
//! # LaMar et al. 1999 selection filters
//!
//! LaMar, Hamann and Joy ("Multiresolution techniques for interactive texture-based volume
//! visualization", §4.1) select a tile of their octree (a fixed voxel count per tile, so a
//! parent tile has twice the extent of a child) with one of two filters, both offered here as
//! options ([`DistanceFilter`], [`FovFilter`]) that force bricks to `Lo`:
//!
//! - **Distance**: a tile is selected "if the distance from the viewpoint to the center of the
//!   tile is greater than the diagonal length of the tile". A `Lo` brick has the resolution of
//!   LaMar's parent tile, whose diagonal is twice the brick's; the equivalent flat-brick rule is
//!   "`Lo` when the eye is farther than `2 x` the brick diagonal from the brick centre" (the
//!   factor is a parameter, [`DistanceFilter::LAMAR`] uses 2).
//! - **Field of view**: a tile is selected "if it intersects the view frustum and the projected
//!   angle of the tile is less than half the view frustum's field-of-view angle"; tiles outside
//!   the frustum are ignored. With flat bricking every active brick stays at least `Lo` (the
//!   frustum test is conservative and the camera may move), so here a brick goes `Lo` when its
//!   box is outside the frustum, or when the angle its low-res tile subtends (a sphere of radius
//!   one brick diagonal around the brick centre, LaMar's parent tile) is less than
//!   `angle_fraction x fov_y` ([`FovFilter::LAMAR`]: 1/2; [`FovFilter::FRUSTUM_ONLY`]: 0 keeps
//!   only the frustum test). For an orthographic view the angle ratio becomes the ratio of the
//!   tile's diameter to the visible height.
//!
//! Bricks a filter forces to `Lo` are not ranked; the others compete for the remaining slots.
//!
//! # Neighbour-level rule
//!
//! Beyer et al. require face-, edge- and corner-adjacent bricks to differ by at most one level so
//! that the transition fixup only ever blends two adjacent levels. With two levels (`Hi` = 0, `Lo`
//! = 1) every assignment satisfies it trivially; [`check_level_rule`] verifies it for any
//! assignment so that it keeps being checked once more levels exist.
//!
//! The output is one [`Level`] ([`crate::bricks::Level`], what the cache stores) per brick.

use super::error::LodError;
use super::geometry::{BrickGeometry, LodView, ViewProjection};
use crate::bricks::{BrickGrid, Level, ValueRange, SUB_SLOTS_PER_SLOT};
use glam::{IVec3, Vec3};
use std::cmp::Ordering;

/// The level number of `level` (0 = finest: `Hi` = 0, `Lo` = 1), `None` for
/// [`Level::Absent`]; what [`check_level_rule`] compares.
pub fn level_number(level: Level) -> Option<u32> {
    match level {
        Level::Hi => Some(0),
        Level::Lo => Some(1),
        Level::Absent => None,
    }
}

/// Slots needed by `hi` hi-res and `lo` low-res bricks: `hi + ceil(lo / 8)`.
pub fn slots_needed(hi: usize, lo: usize) -> usize {
    hi + lo.div_ceil(SUB_SLOTS_PER_SLOT as usize)
}

/// The largest number `h <= candidates` of `active` bricks that can be hi-res with the rest
/// low-res in `slots` slots (`h + ceil((active - h) / 8) <= slots`), or `None` when even all-low-res
/// does not fit. `candidates` is clamped to `active`.
pub fn max_hi_bricks(active: usize, candidates: usize, slots: usize) -> Option<usize> {
    let fits = |h: usize| slots_needed(h, active - h) <= slots;
    if !fits(0) {
        return None;
    }
    // slots_needed(h, active - h) never decreases with h: binary search the last h that fits.
    let (mut lo, mut hi) = (0, candidates.min(active));
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if fits(mid) {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    Some(lo)
}

/// LaMar's distance filter: bricks whose centre is farther from the eye than
/// `diagonal_factor` times their world-space diagonal are drawn low-res.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DistanceFilter {
    /// Multiple of the brick diagonal beyond which a brick goes low-res (finite, >= 0).
    pub diagonal_factor: f32,
}

impl DistanceFilter {
    /// LaMar's criterion for the tile with the resolution of a `Lo` brick (twice the brick's
    /// diagonal).
    pub const LAMAR: Self = Self {
        diagonal_factor: 2.0,
    };
}

/// LaMar's field-of-view filter: bricks outside the view frustum, or whose low-res tile subtends
/// less than `angle_fraction x fov_y`, are drawn low-res.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct FovFilter {
    /// Fraction of the vertical field of view below which a brick goes low-res (finite, >= 0).
    pub angle_fraction: f32,
}

impl FovFilter {
    /// LaMar's criterion: projected angle below half the field of view.
    pub const LAMAR: Self = Self {
        angle_fraction: 0.5,
    };
    /// Only the frustum test: bricks outside the view frustum go low-res.
    pub const FRUSTUM_ONLY: Self = Self {
        angle_fraction: 0.0,
    };
}

/// Settings of one selection.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SelectionOptions {
    /// Cache slots available.
    pub slots: usize,
    /// Optional LaMar distance filter.
    pub distance_filter: Option<DistanceFilter>,
    /// Optional LaMar field-of-view filter.
    pub fov_filter: Option<FovFilter>,
}

impl SelectionOptions {
    /// Budget-driven selection into `slots` slots without the LaMar filters.
    pub fn with_slots(slots: usize) -> Self {
        Self {
            slots,
            distance_filter: None,
            fov_filter: None,
        }
    }
}

/// Counts of one selection.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct SelectionSummary {
    /// Active (not culled) bricks.
    pub active: usize,
    /// Active bricks a LaMar filter forced to `Lo`.
    pub filtered: usize,
    /// Bricks selected `Hi`.
    pub hi: usize,
    /// Bricks selected `Lo`.
    pub lo: usize,
    /// Slots the selection needs, `hi + ceil(lo / 8)`.
    pub slots_used: usize,
}

/// Screen-space error of drawing the brick with world-space box `[min, max]` and value range
/// `range` low-res: the projected size in pixels of a low-res voxel (two hi-res voxels) at the
/// box's nearest point, times `range.max - range.min`. The distance is clamped below to one
/// low-res voxel so that an eye inside the brick gives a large finite error. A NaN range end
/// gives `+inf` (rank first, conservative); an empty or zero-width range gives 0.
pub fn screen_space_error(
    geometry: &BrickGeometry,
    view: &LodView,
    min: Vec3,
    max: Vec3,
    range: ValueRange,
) -> f32 {
    let lo_voxel = 2.0 * geometry.voxel_size().max_element();
    let pixels =
        lo_voxel * view.pixels_per_world_unit(box_distance(view.eye(), min, max).max(lo_voxel));
    let width = range.max - range.min;
    if width.is_nan() {
        f32::INFINITY
    } else if width > 0.0 {
        pixels * width
    } else {
        0.0
    }
}

/// Distance from `p` to the nearest point of the box `[min, max]` (0 inside).
fn box_distance(p: Vec3, min: Vec3, max: Vec3) -> f32 {
    (min - p).max(p - max).max(Vec3::ZERO).length()
}

/// Pre-validated filter state for the per-brick loop.
struct Filters {
    eye: Vec3,
    distance_factor: Option<f32>,
    fov_fraction: Option<f32>,
    view: LodView,
}

impl Filters {
    fn new(view: &LodView, options: &SelectionOptions) -> Result<Self, LodError> {
        let check = |filter: &'static str, value: f32| {
            if value.is_finite() && value >= 0.0 {
                Ok(value)
            } else {
                Err(LodError::InvalidFilter { filter, value })
            }
        };
        Ok(Self {
            eye: view.eye(),
            distance_factor: options
                .distance_filter
                .map(|f| check("distance", f.diagonal_factor))
                .transpose()?,
            fov_fraction: options
                .fov_filter
                .map(|f| check("field-of-view", f.angle_fraction))
                .transpose()?,
            view: *view,
        })
    }

    /// True when a filter forces the brick with box `[min, max]` to `Lo`.
    fn forces_lo(&self, min: Vec3, max: Vec3) -> bool {
        let centre = 0.5 * (min + max);
        let diagonal = (max - min).length();
        let distance = self.eye.distance(centre);
        if let Some(factor) = self.distance_factor {
            if distance > factor * diagonal {
                return true;
            }
        }
        if let Some(fraction) = self.fov_fraction {
            if self.view.box_outside_frustum(min, max) {
                return true;
            }
            // The low-res tile: a sphere of radius one brick diagonal (LaMar's parent tile).
            let radius = diagonal;
            let subtended = match self.view.projection() {
                ViewProjection::Perspective { fov_y, .. } => {
                    let angle = if distance <= radius {
                        std::f32::consts::PI
                    } else {
                        2.0 * (radius / distance).asin()
                    };
                    angle / fov_y
                }
                ViewProjection::Orthographic { height } => 2.0 * radius / height,
            };
            if subtended < fraction {
                return true;
            }
        }
        false
    }
}

/// Ranking order: larger error first, ties by smaller brick index (deterministic).
fn rank_order(a: &(f32, u32), b: &(f32, u32)) -> Ordering {
    b.0.total_cmp(&a.0).then(a.1.cmp(&b.1))
}

/// Reusable budget-driven level selection; keeps its ranking buffer between frames so that a
/// selection allocates nothing once warmed up.
#[derive(Clone, Debug, Default)]
pub struct LodSelector {
    ranked: Vec<(f32, u32)>,
}

impl LodSelector {
    /// An empty selector.
    pub fn new() -> Self {
        Self::default()
    }

    /// Selects a level for every brick of `geometry` into `levels` (cleared first, indexed by
    /// linear brick index):
    ///
    /// 1. bricks with `active[i] == false` are [`Level::Absent`];
    /// 2. every active brick is at least [`Level::Lo`]; it fails with
    ///    [`LodError::BudgetTooSmall`] when `ceil(active / 8) > slots`;
    /// 3. active bricks not forced to `Lo` by a LaMar filter are ranked by
    ///    [`screen_space_error`] (ties: lower index first), and the top `h` become [`Level::Hi`]
    ///    with `h` the largest count that satisfies `h + ceil((active - h) / 8) <= slots`.
    ///
    /// A brick with a zero-width range has error 0 and every brick with a positive range ranks
    /// above it (positive errors are kept >= `f32::MIN_POSITIVE`). Runs in O(bricks) expected
    /// time (one `select_nth_unstable_by`).
    pub fn select_into(
        &mut self,
        geometry: &BrickGeometry,
        view: &LodView,
        ranges: &[ValueRange],
        active: &[bool],
        options: &SelectionOptions,
        levels: &mut Vec<Level>,
    ) -> Result<SelectionSummary, LodError> {
        let expected = geometry.grid().brick_count();
        for (what, actual) in [
            ("value ranges", ranges.len()),
            ("active mask", active.len()),
        ] {
            if actual != expected {
                return Err(LodError::LengthMismatch {
                    what,
                    expected,
                    actual,
                });
            }
        }
        let active_count = active.iter().filter(|&&a| a).count();
        let needed = active_count.div_ceil(SUB_SLOTS_PER_SLOT as usize);
        if needed > options.slots {
            return Err(LodError::BudgetTooSmall {
                active: active_count,
                needed,
                slots: options.slots,
            });
        }
        let filters = Filters::new(view, options)?;

        levels.clear();
        levels.extend(
            active
                .iter()
                .map(|&a| if a { Level::Lo } else { Level::Absent }),
        );
        self.ranked.clear();
        geometry.for_each_brick_box(|index, min, max| {
            if !active[index] || filters.forces_lo(min, max) {
                return;
            }
            let error = screen_space_error(geometry, view, min, max, ranges[index]);
            let key = if error > 0.0 {
                error.max(f32::MIN_POSITIVE)
            } else {
                0.0
            };
            self.ranked.push((key, index as u32));
        });

        let candidates = self.ranked.len();
        let hi = max_hi_bricks(active_count, candidates, options.slots)
            .expect("all-low-res fits: checked above");
        if hi > 0 {
            if hi < candidates {
                self.ranked.select_nth_unstable_by(hi - 1, rank_order);
            }
            for &(_, index) in &self.ranked[..hi] {
                levels[index as usize] = Level::Hi;
            }
        }
        let lo = active_count - hi;
        Ok(SelectionSummary {
            active: active_count,
            filtered: active_count - candidates,
            hi,
            lo,
            slots_used: slots_needed(hi, lo),
        })
    }
}

/// One-shot form of [`LodSelector::select_into`]: the level of every brick.
pub fn select_levels(
    geometry: &BrickGeometry,
    view: &LodView,
    ranges: &[ValueRange],
    active: &[bool],
    options: &SelectionOptions,
) -> Result<Vec<Level>, LodError> {
    let mut levels = Vec::new();
    LodSelector::new().select_into(geometry, view, ranges, active, options, &mut levels)?;
    Ok(levels)
}

/// True when face-, edge- and corner-adjacent drawn bricks differ by at most one level
/// ([`Level::Absent`] bricks are not drawn and impose nothing). Trivially true for the two levels
/// of [`Level`]; false when `levels` does not hold one entry per brick of `grid`.
pub fn check_level_rule(levels: &[Level], grid: &BrickGrid) -> bool {
    levels.len() == grid.brick_count() && check_level_rule_with(grid, |i| level_number(levels[i]))
}

/// [`check_level_rule`] for any number of levels: `level_of(i)` is the level number of brick `i`
/// (linear index), `None` for a brick that is not drawn.
pub fn check_level_rule_with(grid: &BrickGrid, level_of: impl Fn(usize) -> Option<u32>) -> bool {
    // Each unordered neighbour pair once: the 13 offsets after (0, 0, 0) in z-major order.
    let offsets: Vec<IVec3> = (-1..=1)
        .flat_map(|z| (-1..=1).flat_map(move |y| (-1..=1).map(move |x| IVec3::new(x, y, z))))
        .filter(|d| (d.z, d.y, d.x) > (0, 0, 0))
        .collect();
    let per_axis = grid.bricks_per_axis().as_ivec3();
    grid.bricks().enumerate().all(|(index, brick)| {
        let Some(level) = level_of(index) else {
            return true;
        };
        offsets.iter().all(|&d| {
            let n = brick.as_ivec3() + d;
            if n.min_element() < 0 || n.cmpge(per_axis).any() {
                return true;
            }
            level_of(grid.linear_index(n.as_uvec3())).is_none_or(|other| level.abs_diff(other) <= 1)
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Camera;
    use glam::UVec3;

    fn range(min: f32, max: f32) -> ValueRange {
        ValueRange { min, max }
    }

    /// Deterministic pseudo-random numbers in [0, 1) (xorshift64).
    fn rng(seed: u64) -> impl FnMut() -> f32 {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// A row of `count` bricks of 8 voxels along x (world x from -0.5 to 0.5), viewed by a
    /// camera on the -x side looking along +x.
    fn row(count: u32) -> (BrickGeometry, LodView) {
        let grid = BrickGrid::new(UVec3::new(8 * count, 8, 8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let camera = Camera::perspective(Vec3::new(-1.5, 0.0, 0.0), Vec3::ZERO, 40.0);
        (geometry, LodView::new(&camera, 256, 256).unwrap())
    }

    fn count(levels: &[Level], level: Level) -> usize {
        levels.iter().filter(|&&l| l == level).count()
    }

    #[test]
    fn max_hi_bricks_matches_a_direct_search() {
        for active in 0usize..40 {
            for candidates in [0, active / 2, active] {
                for slots in 0..45 {
                    let direct = if active.div_ceil(8) > slots {
                        None
                    } else {
                        (0..=candidates)
                            .rev()
                            .find(|&h| h + (active - h).div_ceil(8) <= slots)
                    };
                    assert_eq!(
                        max_hi_bricks(active, candidates, slots),
                        direct,
                        "active {active} candidates {candidates} slots {slots}"
                    );
                }
            }
        }
        assert_eq!(slots_needed(3, 9), 5);
        assert_eq!(slots_needed(0, 8), 1);
    }

    #[test]
    fn budget_is_respected_exactly_and_filled() {
        let grid = BrickGrid::new(UVec3::new(64, 48, 40), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::new(1.0, 1.0, 1.5)).unwrap();
        let camera = Camera::perspective(Vec3::new(1.2, 0.9, 1.6), Vec3::ZERO, 35.0);
        let view = LodView::new(&camera, 320, 240).unwrap();
        let mut next = rng(5);
        let n = grid.brick_count();
        let ranges: Vec<_> = (0..n)
            .map(|_| {
                let a = next();
                range(a, a + if next() < 0.2 { 0.0 } else { next() * 0.3 })
            })
            .collect();
        let active: Vec<bool> = (0..n).map(|_| next() < 0.7).collect();
        let active_count = active.iter().filter(|&&a| a).count();
        let mut selector = LodSelector::new();
        let mut levels = Vec::new();
        for slots in [
            active_count.div_ceil(8),
            50,
            123,
            200,
            active_count - 1,
            active_count,
            n + 5,
        ] {
            let options = SelectionOptions::with_slots(slots);
            let summary = selector
                .select_into(&geometry, &view, &ranges, &active, &options, &mut levels)
                .unwrap();
            let (hi, lo) = (count(&levels, Level::Hi), count(&levels, Level::Lo));
            assert_eq!(hi + lo, active_count);
            assert!(
                slots_needed(hi, lo) <= slots,
                "slots {slots}: {hi} hi {lo} lo"
            );
            // One more Hi would not fit (unless all active bricks are already Hi).
            assert!(hi == active_count || slots_needed(hi + 1, lo - 1) > slots);
            assert_eq!(
                summary,
                SelectionSummary {
                    active: active_count,
                    filtered: 0,
                    hi,
                    lo,
                    slots_used: slots_needed(hi, lo)
                }
            );
            assert_eq!(
                levels,
                select_levels(&geometry, &view, &ranges, &active, &options).unwrap()
            );
        }
    }

    #[test]
    fn nearer_bricks_win_at_equal_range() {
        let (geometry, view) = row(8);
        let ranges = vec![range(0.2, 0.7); 8];
        let active = vec![true; 8];
        // 8 active: all-Lo needs 1 slot; h Hi need h + ceil((8 - h) / 8) slots.
        for slots in 1..=8 {
            let levels = select_levels(
                &geometry,
                &view,
                &ranges,
                &active,
                &SelectionOptions::with_slots(slots),
            )
            .unwrap();
            let hi = max_hi_bricks(8, 8, slots).unwrap();
            // The camera is on the -x side: the first `hi` bricks are the nearest.
            for (i, level) in levels.iter().enumerate() {
                let expected = if i < hi { Level::Hi } else { Level::Lo };
                assert_eq!(*level, expected, "slots {slots} brick {i}: {levels:?}");
            }
        }
        // A larger range beats a nearer brick with a much smaller one.
        let mut ranges = vec![range(0.2, 0.2001); 8];
        ranges[7] = range(0.0, 1.0);
        let levels = select_levels(
            &geometry,
            &view,
            &ranges,
            &active,
            &SelectionOptions::with_slots(2),
        )
        .unwrap();
        assert_eq!(levels[7], Level::Hi);
        assert_eq!(count(&levels, Level::Hi), 1);
    }

    #[test]
    fn zero_range_bricks_are_promoted_only_after_all_others() {
        let (geometry, view) = row(16);
        // The near half is constant, the far half varies a little.
        let ranges: Vec<_> = (0..16)
            .map(|i| {
                if i < 8 {
                    range(0.5, 0.5)
                } else {
                    range(0.5, 0.5 + 1e-6)
                }
            })
            .collect();
        let active = vec![true; 16];
        for slots in 2..=16 {
            let levels = select_levels(
                &geometry,
                &view,
                &ranges,
                &active,
                &SelectionOptions::with_slots(slots),
            )
            .unwrap();
            let hi = count(&levels, Level::Hi);
            let varying_hi = levels[8..].iter().filter(|&&l| l == Level::Hi).count();
            assert_eq!(varying_hi, hi.min(8), "slots {slots}: {levels:?}");
        }
    }

    #[test]
    fn culled_bricks_stay_absent() {
        let (geometry, view) = row(8);
        let ranges = vec![range(0.0, 1.0); 8];
        let active = [true, false, true, false, false, true, true, false];
        let levels = select_levels(
            &geometry,
            &view,
            &ranges,
            &active,
            &SelectionOptions::with_slots(100),
        )
        .unwrap();
        for (level, &a) in levels.iter().zip(&active) {
            assert_eq!(*level == Level::Absent, !a);
        }
        assert_eq!(count(&levels, Level::Hi), 4);
        // Nothing active: nothing needed, even with no slots.
        let none = select_levels(
            &geometry,
            &view,
            &ranges,
            &[false; 8],
            &SelectionOptions::with_slots(0),
        )
        .unwrap();
        assert_eq!(none, vec![Level::Absent; 8]);
    }

    #[test]
    fn impossible_budget_is_a_typed_error() {
        let grid = BrickGrid::new(UVec3::splat(40), 4).unwrap(); // 1000 bricks
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let view = LodView::new(&Camera::default_view(), 64, 64).unwrap();
        let ranges = vec![range(0.0, 1.0); 1000];
        let active = vec![true; 1000];
        let result = select_levels(
            &geometry,
            &view,
            &ranges,
            &active,
            &SelectionOptions::with_slots(124),
        );
        assert_eq!(
            result,
            Err(LodError::BudgetTooSmall {
                active: 1000,
                needed: 125,
                slots: 124
            })
        );
        let levels = select_levels(
            &geometry,
            &view,
            &ranges,
            &active,
            &SelectionOptions::with_slots(125),
        )
        .unwrap();
        assert_eq!(count(&levels, Level::Lo), 1000);
        assert!(matches!(
            select_levels(
                &geometry,
                &view,
                &ranges[..5],
                &active,
                &SelectionOptions::with_slots(125)
            ),
            Err(LodError::LengthMismatch { .. })
        ));
    }

    #[test]
    fn screen_space_error_follows_the_formula() {
        // One brick of 8^3 voxels: world box [-0.5, 0.5]^3, voxel 1/8, low-res voxel 1/4.
        let grid = BrickGrid::new(UVec3::splat(8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let camera = Camera::perspective(Vec3::new(0.0, 0.0, 2.5), Vec3::ZERO, 60.0);
        let view = LodView::new(&camera, 100, 200).unwrap();
        let (min, max) = geometry.brick_box(UVec3::ZERO);
        let error = screen_space_error(&geometry, &view, min, max, range(0.25, 0.75));
        // Nearest point at distance 2; 200 / (2 tan 30deg) pixels per unit at distance 1.
        let expected = 0.25 / 2.0 * 200.0 / (2.0 * 30f32.to_radians().tan()) * 0.5;
        assert!(
            (error - expected).abs() < 1e-4 * expected,
            "{error} vs {expected}"
        );
        assert_eq!(
            screen_space_error(&geometry, &view, min, max, range(0.3, 0.3)),
            0.0
        );
        assert_eq!(
            screen_space_error(&geometry, &view, min, max, range(f32::NAN, 0.3)),
            f32::INFINITY
        );
        // Orthographic: independent of distance.
        let ortho = Camera::orthographic(Vec3::new(0.0, 0.0, 9.0), Vec3::ZERO, 2.0);
        let view = LodView::new(&ortho, 100, 200).unwrap();
        let error = screen_space_error(&geometry, &view, min, max, range(0.0, 1.0));
        assert!((error - 0.25 * 100.0).abs() < 1e-4);
        // Eye inside the brick: large but finite.
        let inside = Camera::perspective(Vec3::new(0.0, 0.0, 0.1), Vec3::ZERO, 60.0);
        let view = LodView::new(&inside, 100, 200).unwrap();
        let error = screen_space_error(&geometry, &view, min, max, range(0.0, 1.0));
        assert!(error.is_finite() && error > 100.0);
    }

    #[test]
    fn distance_filter_forces_far_bricks_low_res() {
        // 8 bricks of 8 voxels along x: each brick is a cube of side 0.125 (diagonal 0.2165).
        // Brick i has its centre at x = -0.5 + 0.125 (i + 0.5); the eye is at x = -1.5, so the
        // distances are 1.0625 + 0.125 i.
        let (geometry, view) = row(8);
        let ranges = vec![range(0.0, 1.0); 8];
        let active = vec![true; 8];
        let mut options = SelectionOptions::with_slots(100);
        // LaMar's factor 2: threshold 0.433, every brick is farther.
        options.distance_filter = Some(DistanceFilter::LAMAR);
        let levels = select_levels(&geometry, &view, &ranges, &active, &options).unwrap();
        assert_eq!(levels, [Level::Lo; 8]);
        // Factor 8: threshold 1.732 between bricks 5 (1.6875) and 6 (1.8125).
        options.distance_filter = Some(DistanceFilter {
            diagonal_factor: 8.0,
        });
        let mut selector = LodSelector::new();
        let mut levels = Vec::new();
        let summary = selector
            .select_into(&geometry, &view, &ranges, &active, &options, &mut levels)
            .unwrap();
        let mut expected = [Level::Hi; 8];
        expected[6..].fill(Level::Lo);
        assert_eq!(levels, expected);
        assert_eq!(summary.filtered, 2);
        // Factor 5: threshold 1.083, only brick 0 (1.0625) stays eligible.
        options.distance_filter = Some(DistanceFilter {
            diagonal_factor: 5.0,
        });
        let levels = select_levels(&geometry, &view, &ranges, &active, &options).unwrap();
        let mut expected = [Level::Lo; 8];
        expected[0] = Level::Hi;
        assert_eq!(levels, expected);
        // The filter only restricts: a small budget still limits the eligible bricks.
        options.distance_filter = Some(DistanceFilter {
            diagonal_factor: 8.0,
        });
        options.slots = 3; // 2 Hi + 6 Lo
        let levels = select_levels(&geometry, &view, &ranges, &active, &options).unwrap();
        let mut expected = [Level::Lo; 8];
        expected[..2].fill(Level::Hi);
        assert_eq!(levels, expected);
        options.distance_filter = Some(DistanceFilter {
            diagonal_factor: -1.0,
        });
        assert!(matches!(
            select_levels(&geometry, &view, &ranges, &active, &options),
            Err(LodError::InvalidFilter { .. })
        ));
    }

    #[test]
    fn fov_filter_forces_bricks_outside_the_frustum_and_small_ones_low_res() {
        // 4 x 1 x 1 bricks of 8 voxels: cubes of side 0.25 (diagonal 0.433), x slabs
        // [-0.5, -0.25], ..., [0.25, 0.5]; y, z in [-0.125, 0.125].
        let grid = BrickGrid::new(UVec3::new(32, 8, 8), 8).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
        let ranges = vec![range(0.0, 1.0); 4];
        let active = vec![true; 4];
        let mut options = SelectionOptions::with_slots(100);
        options.fov_filter = Some(FovFilter::FRUSTUM_ONLY);
        let select = |camera: Camera, options: &SelectionOptions| {
            let view = LodView::new(&camera, 100, 100).unwrap();
            select_levels(&geometry, &view, &ranges, &active, options).unwrap()
        };
        // At z = 1 looking along -z at x = 0.42 with 16 degrees: the frustum spans x in
        // [0.297, 0.543] at the box front (z = 0.125) and [0.262, 0.578] at the back, so only
        // the last slab is in view.
        let narrow =
            Camera::perspective(Vec3::new(0.42, 0.0, 1.0), Vec3::new(0.42, 0.0, 0.0), 16.0);
        assert_eq!(
            select(narrow, &options),
            [Level::Lo, Level::Lo, Level::Lo, Level::Hi]
        );
        // Aimed at x = 0.375 with 20 degrees: [0.176, 0.574] at the back touches slab 2.
        let narrow =
            Camera::perspective(Vec3::new(0.375, 0.0, 1.0), Vec3::new(0.375, 0.0, 0.0), 20.0);
        assert_eq!(
            select(narrow, &options),
            [Level::Lo, Level::Lo, Level::Hi, Level::Hi]
        );
        // Eye inside slab 2 looking along +x: slabs 0 and 1 lie behind the near plane.
        let inside = Camera::perspective(Vec3::new(0.1, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), 60.0);
        assert_eq!(
            select(inside, &options),
            [Level::Lo, Level::Lo, Level::Hi, Level::Hi]
        );
        // Orthographic, 0.2 units tall and wide around x = -0.375: only slab 0 is in view.
        let ortho = Camera::orthographic(
            Vec3::new(-0.375, 0.0, 1.0),
            Vec3::new(-0.375, 0.0, 0.0),
            0.2,
        );
        assert_eq!(
            select(ortho, &options),
            [Level::Hi, Level::Lo, Level::Lo, Level::Lo]
        );

        // 60 degrees from x = 0.375: all four slabs are in the frustum. The low-res tile (radius
        // one diagonal, 0.433) of brick i, at distance 1.25, 1.118, 1.031, 1.0, subtends
        // 40.5, 45.6, 49.7, 51.3 degrees: 0.676, 0.760, 0.828, 0.855 of the field of view.
        let wide =
            Camera::perspective(Vec3::new(0.375, 0.0, 1.0), Vec3::new(0.375, 0.0, 0.0), 60.0);
        assert_eq!(select(wide, &options), [Level::Hi; 4]);
        options.fov_filter = Some(FovFilter {
            angle_fraction: 0.8,
        });
        assert_eq!(
            select(wide, &options),
            [Level::Lo, Level::Lo, Level::Hi, Level::Hi]
        );
        options.fov_filter = Some(FovFilter::LAMAR);
        assert_eq!(select(wide, &options), [Level::Hi; 4]);
        options.fov_filter = Some(FovFilter {
            angle_fraction: 0.9,
        });
        assert_eq!(select(wide, &options), [Level::Lo; 4]);
        options.fov_filter = Some(FovFilter {
            angle_fraction: f32::NAN,
        });
        let view = LodView::new(&wide, 100, 100).unwrap();
        assert!(matches!(
            select_levels(&geometry, &view, &ranges, &active, &options),
            Err(LodError::InvalidFilter { .. })
        ));
    }

    #[test]
    fn level_rule_holds_for_two_levels_and_is_checked_for_more() {
        let grid = BrickGrid::new(UVec3::new(12, 8, 8), 4).unwrap(); // 3 x 2 x 2 bricks
        let n = grid.brick_count();
        let mut next = rng(11);
        for _ in 0..50 {
            let levels: Vec<Level> = (0..n)
                .map(|_| [Level::Hi, Level::Lo, Level::Absent][(next() * 3.0) as usize % 3])
                .collect();
            assert!(check_level_rule(&levels, &grid));
        }
        assert!(!check_level_rule(&[Level::Hi; 3], &grid), "length mismatch");
        // Three levels: 0 and 2 at corner neighbours (0,0,0) and (1,1,1) break the rule ...
        let corner = grid.linear_index(UVec3::new(1, 1, 1));
        let levels = |i: usize| {
            Some(if i == 0 {
                0
            } else if i == corner {
                2
            } else {
                1
            })
        };
        assert!(!check_level_rule_with(&grid, levels));
        // ... unless one of them is not drawn, or they are not adjacent.
        assert!(check_level_rule_with(&grid, |i| if i == corner {
            None
        } else {
            levels(i).map(|l| l.min(1))
        }));
        let far = grid.linear_index(UVec3::new(2, 1, 1));
        assert!(check_level_rule_with(&grid, |i| Some(if i == 0 {
            0
        } else if i == far {
            2
        } else {
            1
        })));
        assert!(!check_level_rule_with(&grid, |i| Some(if i == 0 {
            0
        } else if i == 1 {
            2
        } else {
            1
        })));
        let edge = grid.linear_index(UVec3::new(2, 1, 0));
        let next_to_edge = grid.linear_index(UVec3::new(1, 0, 1));
        assert!(!check_level_rule_with(&grid, |i| Some(if i == edge {
            3
        } else if i == next_to_edge {
            1
        } else {
            2
        })));
    }
}
