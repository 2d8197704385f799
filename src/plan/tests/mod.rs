use super::*;
use crate::bricks::{BrickGrid, SUB_SLOTS_PER_SLOT};
use crate::cache::CacheGeometry;
use crate::lod::{check_level_rule, level_number};
use crate::optics::TfPreset;
use crate::scene::{Camera, ClipPlane, ClipPlanes};
use glam::{UVec3, Vec4};

/// Deterministic pseudo-random numbers (xorshift64).
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

fn range(min: f32, max: f32) -> ValueRange {
    ValueRange { min, max }
}

const NO_CULLING: CullParams = CullParams {
    value: ValueCulling::None,
    clip: ClipPlanes::NONE,
};

/// A row of `count` bricks of 8 voxels along x, seen from the -x side looking along +x: brick 0
/// is the nearest.
fn row(count: u32) -> (BrickGeometry, LodView) {
    let grid = BrickGrid::new(UVec3::new(8 * count, 8, 8), 8).unwrap();
    let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
    let camera = Camera::perspective(Vec3::new(-1.5, 0.0, 0.0), Vec3::ZERO, 40.0);
    (geometry, LodView::new(&camera, 256, 256).unwrap())
}

fn budget(slots: usize, upload_bytes_per_frame: u64) -> PlanBudget {
    PlanBudget {
        slots,
        upload_bytes_per_frame,
        bytes_per_texel: 1,
        ram_bytes: None,
    }
}

fn all_loaded(_: u32, _: Level) -> bool {
    true
}

/// Hi and Lo upload bytes of 8-voxel bricks at one byte per texel.
const HI8: u64 = 1000;
const LO8: u64 = 125;

fn slots_of(levels: &[Level]) -> usize {
    let hi = levels.iter().filter(|&&l| l == Level::Hi).count();
    let lo = levels.iter().filter(|&&l| l == Level::Lo).count();
    slots_needed(hi, lo)
}

fn count(levels: &[Level], level: Level) -> usize {
    levels.iter().filter(|&&l| l == level).count()
}

/// Rules 1, 2 and 5 and the bookkeeping of one frame, given the previous frame's drawn levels.
fn check_frame(
    frame: &FrameInput<'_>,
    prev_draw: &[Level],
    plan: &FramePlan,
    is_loaded: &dyn Fn(u32, Level) -> bool,
) {
    let b = frame.budget;
    let n = frame.geometry.grid().brick_size();
    let bricks = frame.geometry.grid().brick_count();
    let r = &plan.report;
    assert_eq!(plan.draw.len(), bricks);
    assert_eq!(plan.wanted.len(), bricks);
    // Rule 1: slots and upload bytes.
    assert!(slots_of(&plan.draw) <= b.slots, "{r:?}");
    assert!(slots_of(&plan.wanted) <= b.slots, "{r:?}");
    assert_eq!(r.slots_used, slots_of(&plan.draw));
    let uploaded: u64 = plan
        .uploads
        .iter()
        .map(|&(_, l)| upload_bytes(l, n, b.bytes_per_texel))
        .sum();
    assert_eq!(uploaded, r.upload_bytes);
    assert!(uploaded <= b.upload_bytes_per_frame, "{r:?}");
    // The uploads are exactly the changes to a resident level, each of a loaded level.
    let mut changed: Vec<(u32, Level)> = (0..bricks)
        .filter(|&i| plan.draw[i] != prev_draw[i] && plan.draw[i].is_resident())
        .map(|i| (i as u32, plan.draw[i]))
        .collect();
    let mut listed = plan.uploads.clone();
    changed.sort_by_key(|&(i, _)| i);
    listed.sort_by_key(|&(i, _)| i);
    assert_eq!(changed, listed);
    for &(i, l) in &plan.uploads {
        assert!(
            is_loaded(i, l),
            "brick {i} uploaded at {l:?} but not loaded"
        );
    }
    // Rule 2: the neighbour rule.
    assert!(check_level_rule(&plan.draw, frame.geometry.grid()));
    // Rule 5: culling, dropping, and never drawing finer than wanted.
    let active = cull_bricks(frame.geometry, frame.ranges, frame.cull).unwrap();
    let active_count = active.iter().filter(|&&a| a).count();
    let capacity = b.slots * SUB_SLOTS_PER_SLOT as usize;
    assert_eq!(r.culled, bricks - active_count);
    assert_eq!(r.dropped, active_count.saturating_sub(capacity));
    assert_eq!(r.wanted_hi + r.wanted_lo, active_count - r.dropped);
    for (i, &a) in active.iter().enumerate() {
        if !a {
            assert_eq!(plan.wanted[i], Level::Absent);
            assert_eq!(plan.draw[i], Level::Absent);
        }
        if plan.wanted[i] == Level::Absent {
            assert_eq!(plan.draw[i], Level::Absent, "brick {i}");
        }
    }
    assert_eq!(
        r.drawn_hi + r.drawn_lo + r.drawn_absent,
        r.wanted_hi + r.wanted_lo
    );
}

use crate::lod::cull_bricks;

fn frame<'a>(
    geometry: &'a BrickGeometry,
    view: &'a LodView,
    ranges: &'a [ValueRange],
    cull: &'a CullParams,
    budget: PlanBudget,
) -> FrameInput<'a> {
    FrameInput {
        geometry,
        view,
        ranges,
        ranges_generation: None,
        cull,
        budget,
    }
}

#[test]
fn upload_budget_stages_the_most_important_changes_first() {
    // Rule 1 (upload bytes): from nothing, 8 bricks all wanted Hi, 3 Hi uploads per frame.
    let (geometry, view) = row(8);
    let ranges = vec![range(0.0, 1.0); 8];
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let mut prev = vec![Level::Absent; 8];
    let mut hi_frames = Vec::new();
    for _ in 0..5 {
        let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(8, 3 * HI8));
        let plan = planner.plan_frame(&input, all_loaded).unwrap();
        check_frame(&input, &prev, plan, &all_loaded);
        assert_eq!(plan.wanted, vec![Level::Hi; 8]);
        hi_frames.push(count(&plan.draw, Level::Hi));
        // The nearest bricks come first: the Hi bricks are always a prefix of the row.
        let hi = count(&plan.draw, Level::Hi);
        assert!(plan.draw[..hi].iter().all(|&l| l == Level::Hi));
        assert!(plan.draw[hi..].iter().all(|&l| l == Level::Absent));
        prev = plan.draw.clone();
    }
    assert_eq!(hi_frames, [3, 6, 8, 8, 8]);
    assert!(planner.last_plan().report.is_settled());

    // A budget of 3 Hi and 5 Lo: the holes whose Hi upload does not fit are filled low-res first.
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(
        &geometry,
        &view,
        &ranges,
        &NO_CULLING,
        budget(8, 3 * HI8 + 5 * LO8),
    );
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &[Level::Absent; 8], plan, &all_loaded);
    let mut expected = vec![Level::Lo; 8];
    expected[..3].fill(Level::Hi);
    assert_eq!(plan.draw, expected);
    assert_eq!(plan.report.deferred, 5);
    assert_eq!(plan.report.upload_bytes, 3 * HI8 + 5 * LO8);
    // The next frame refines the nearest low-res bricks first.
    let prev = plan.draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    let mut expected = vec![Level::Lo; 8];
    expected[..6].fill(Level::Hi);
    assert_eq!(plan.draw, expected);
}

#[test]
fn a_shrinking_slot_budget_holds_on_the_same_frame() {
    // Rule 1 (slots): all Hi in 8 slots, then 3 slots with uploads for two Lo bricks a frame.
    let (geometry, view) = row(8);
    let ranges = vec![range(0.0, 1.0); 8];
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(8, 8 * HI8));
    assert_eq!(
        planner.plan_frame(&input, all_loaded).unwrap().draw,
        vec![Level::Hi; 8]
    );
    let mut prev = vec![Level::Hi; 8];
    let small = frame(&geometry, &view, &ranges, &NO_CULLING, budget(3, 2 * LO8));
    let plan = planner.plan_frame(&small, all_loaded).unwrap();
    check_frame(&small, &prev, plan, &all_loaded);
    // Wanted: 2 Hi + 6 Lo = 3 slots. The two least important pending coarsenings got their Lo
    // upload; the next four could not be paid and are absent for now.
    let mut wanted = vec![Level::Lo; 8];
    wanted[..2].fill(Level::Hi);
    assert_eq!(plan.wanted, wanted);
    assert_eq!(
        plan.draw,
        [
            Level::Hi,
            Level::Hi,
            Level::Absent,
            Level::Absent,
            Level::Absent,
            Level::Absent,
            Level::Lo,
            Level::Lo
        ]
    );
    assert_eq!(plan.report.drawn_absent, 4);
    // Two holes a frame, most important first.
    for expected_absent in [2, 0, 0] {
        prev = planner.last_plan().draw.clone();
        let plan = planner.plan_frame(&small, all_loaded).unwrap();
        check_frame(&small, &prev, plan, &all_loaded);
        assert_eq!(plan.report.drawn_absent, expected_absent);
    }
    assert_eq!(planner.last_plan().draw, wanted);
    assert!(planner.last_plan().report.is_settled());
}

#[test]
fn a_still_camera_converges_within_a_bound_and_then_uploads_nothing() {
    // Rule 3: repeated frames with the same view and tight budgets.
    let grid = BrickGrid::new(UVec3::new(64, 48, 40), 8).unwrap(); // 8 x 6 x 5 = 240 bricks
    let geometry = BrickGeometry::new(grid, Vec3::new(1.0, 1.0, 1.5)).unwrap();
    let view = LodView::new(&Camera::default_view(), 320, 240).unwrap();
    let mut rng = Rng::new(3);
    let ranges: Vec<_> = (0..240)
        .map(|_| {
            let a = rng.f32();
            range(a, a + if rng.f32() < 0.2 { 0.0 } else { rng.f32() })
        })
        .collect();
    for (slots, upload, threshold) in [
        (40, 4 * HI8, 0.0),
        (100, 3 * HI8, 2.0),
        (30, HI8 + 2 * LO8, 0.0),
    ] {
        let mut planner = ResidencyPlanner::new(PlanOptions {
            error_threshold: threshold,
            hysteresis: 0.1,
        });
        let input = frame(
            &geometry,
            &view,
            &ranges,
            &NO_CULLING,
            budget(slots, upload),
        );
        let mut prev = vec![Level::Absent; 240];
        let mut settled_at = None;
        for f in 0..200 {
            let plan = planner.plan_frame(&input, all_loaded).unwrap();
            check_frame(&input, &prev, plan, &all_loaded);
            if f > 0 && plan.report.is_settled() && plan.draw == prev {
                settled_at = Some(f);
                break;
            }
            prev = plan.draw.clone();
        }
        let settled_at = settled_at.expect("the plan never settled");
        let last = planner.last_plan().clone();
        // Bound: every frame but the last stages at least `upload - HI8` bytes while changes
        // remain, and reaching the target from nothing costs at most this.
        // (a skipped change costs at most HI8 + LO8 with the coarsening that makes room).
        let total = last.report.wanted_hi as u64 * (HI8 + LO8) + 240 * LO8;
        let bound = 2 + total.div_ceil(upload - HI8 - LO8) as usize;
        assert!(
            settled_at <= bound,
            "settled at {settled_at}, bound {bound}"
        );
        assert_eq!(
            last.draw, last.wanted,
            "a still camera ends at the wanted levels"
        );
        for _ in 0..20 {
            let plan = planner.plan_frame(&input, all_loaded).unwrap();
            assert!(plan.uploads.is_empty());
            assert_eq!(plan.draw, last.draw);
            assert_eq!(plan.wanted, last.wanted);
        }
    }
}

#[test]
fn hysteresis_keeps_two_near_equal_bricks_from_swapping() {
    // Rule 3: the eye jitters by +-0.01 in x over a row of 4 bricks; bricks 1 and 2 swap being
    // the nearest, and only one Hi brick fits (1 + ceil(3 / 8) = 2 slots).
    let grid = BrickGrid::new(UVec3::new(32, 8, 8), 8).unwrap();
    let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
    let ranges = vec![range(0.0, 1.0); 4];
    let view_at = |x: f32| {
        let camera = Camera::perspective(Vec3::new(x, 0.0, 1.0), Vec3::new(x, 0.0, 0.0), 60.0);
        LodView::new(&camera, 256, 256).unwrap()
    };
    let views = [view_at(0.01), view_at(-0.01)];
    let run = |hysteresis: f32| {
        let mut planner = ResidencyPlanner::new(PlanOptions {
            error_threshold: 0.0,
            hysteresis,
        });
        let mut uploads_after_warm_up = 0;
        for f in 0..20 {
            let input = frame(
                &geometry,
                &views[f % 2],
                &ranges,
                &NO_CULLING,
                budget(2, 10 * HI8),
            );
            let plan = planner.plan_frame(&input, all_loaded).unwrap();
            assert_eq!(count(&plan.draw, Level::Hi), 1);
            if f >= 2 {
                uploads_after_warm_up += plan.uploads.len();
            }
        }
        uploads_after_warm_up
    };
    assert_eq!(run(0.1), 0, "with hysteresis the plan stays put");
    assert!(run(0.0) >= 18, "without it the Hi level swaps every frame");
}

#[test]
fn dolly_in_never_coarsens_a_brick_whose_distance_shrank() {
    // Rule 4. Property tested: with a slot budget that does not bind (slots >= bricks), an error
    // threshold and an upload budget of 12 Hi bricks a frame, for every frame f > 0 and every
    // brick whose box distance from the eye did not grow from frame f - 1 to f, the drawn level
    // at f is not coarser than at f - 1 (Absent counts as the coarsest). The paths are straight
    // lines, along which a box distance, once growing, keeps growing (see the module docs).
    let grid = BrickGrid::new(UVec3::splat(32), 4).unwrap(); // 512 bricks
    let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
    let mut rng = Rng::new(17);
    let ranges: Vec<_> = (0..512)
        .map(|_| {
            let a = rng.f32() * 0.5;
            range(a, a + rng.f32() * 0.5)
        })
        .collect();
    let bricks: Vec<(Vec3, Vec3)> = (0..512)
        .map(|i| geometry.brick_box(grid.brick_coords(i)))
        .collect();
    let coarseness = |l: Level| level_number(l).unwrap_or(2);
    for (start, goal) in [
        (Vec3::new(2.5, 1.0, 1.8), Vec3::new(0.1, -0.05, 0.1)),
        (Vec3::new(-0.2, 2.8, 0.3), Vec3::new(-0.3, -0.4, 0.2)),
    ] {
        let mut planner = ResidencyPlanner::new(PlanOptions {
            error_threshold: 4.0,
            hysteresis: 0.15,
        });
        let mut prev: Option<(Vec<Level>, Vec<f32>)> = None;
        let mut refined = 0;
        for f in 0..40 {
            let eye = start.lerp(goal, f as f32 / 40.0);
            let camera = Camera::perspective(eye, goal + (goal - start), 45.0);
            let view = LodView::new(&camera, 256, 256).unwrap();
            let distance: Vec<f32> = bricks
                .iter()
                .map(|&(min, max)| box_distance(eye, min, max))
                .collect();
            let input = frame(
                &geometry,
                &view,
                &ranges,
                &NO_CULLING,
                budget(512, 12 * upload_bytes(Level::Hi, 4, 1)),
            );
            let plan = planner.plan_frame(&input, all_loaded).unwrap();
            if let Some((draw, dist)) = &prev {
                check_frame(&input, draw, plan, &all_loaded);
                for i in 0..512 {
                    if distance[i] <= dist[i] {
                        assert!(
                            coarseness(plan.draw[i]) <= coarseness(draw[i]),
                            "frame {f} brick {i}: {:?} -> {:?}",
                            draw[i],
                            plan.draw[i]
                        );
                    }
                    refined += usize::from(draw[i] == Level::Lo && plan.draw[i] == Level::Hi);
                }
            }
            prev = Some((plan.draw.clone(), distance));
        }
        let last = planner.last_plan();
        assert!(refined > 20, "the path refines bricks ({refined})");
        assert!(last.report.drawn_lo > 0, "and leaves some low-res");
    }
}

#[test]
fn a_budget_below_all_low_res_drops_the_least_important() {
    // Rule 5: 16 bricks, 1 slot holds 8 low-res bricks: the 8 farthest are dropped, no error.
    let (geometry, view) = row(16);
    let mut ranges = vec![range(0.0, 1.0); 16];
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(1, 100 * HI8));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &[Level::Absent; 16], plan, &all_loaded);
    assert_eq!(plan.report.dropped, 8);
    let mut expected = vec![Level::Absent; 16];
    expected[..8].fill(Level::Lo);
    assert_eq!(plan.draw, expected);
    assert_eq!(plan.wanted, expected);
    // Importance is the error first: a far brick with a wide range beats a near constant one.
    ranges[0] = range(0.5, 0.5);
    ranges[15] = range(0.0, 1.0);
    ranges[1..15].fill(range(0.0, 0.5));
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(1, 100 * HI8));
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    assert_eq!(plan.draw[15], Level::Lo);
    assert_eq!(plan.draw[0], Level::Absent);
    // No slots at all: everything dropped, still a plan.
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(0, 100 * HI8));
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    assert_eq!(plan.report.dropped, 16);
    assert_eq!(plan.draw, vec![Level::Absent; 16]);
}

#[test]
fn unloaded_levels_fall_back_and_are_requested_in_order() {
    let (geometry, view) = row(8);
    let ranges = vec![range(0.0, 1.0); 8];
    // Hi is loaded for even bricks only; Lo for all but brick 3.
    let loaded = |b: u32, l: Level| match l {
        Level::Hi => b.is_multiple_of(2),
        Level::Lo => b != 3,
        Level::Absent => false,
    };
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(8, 100 * HI8));
    let plan = planner.plan_frame(&input, loaded).unwrap();
    check_frame(&input, &[Level::Absent; 8], plan, &loaded);
    assert_eq!(plan.wanted, vec![Level::Hi; 8]);
    use Level::{Absent as A, Hi as H, Lo as L};
    assert_eq!(plan.draw, [H, L, H, A, H, L, H, L]);
    assert_eq!(plan.report.waiting_for_source, 4);
    assert_eq!(plan.report.drawn_absent, 1);
    // Lo levels first, then Hi, nearest (largest error) first; ranks as priorities.
    let expected: Vec<(u32, Level)> = (0..8)
        .map(|i| (i, L))
        .chain((0..8).map(|i| (i, H)))
        .collect();
    let got: Vec<(u32, Level)> = plan.requests.iter().map(|&(b, l, _)| (b, l)).collect();
    assert_eq!(got, expected);
    assert_eq!(plan.requests[0].2, 16.0);
    assert_eq!(plan.requests[15].2, 1.0);
    assert_eq!(plan.report.request_bytes, 8 * HI8 + 8 * LO8);
    // A RAM budget cuts the list to the prefix that fits: all Lo and two Hi levels.
    let mut b = budget(8, 100 * HI8);
    b.ram_bytes = Some(8 * LO8 + 2 * HI8 + 999);
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, b);
    let plan = planner.plan_frame(&input, loaded).unwrap();
    assert_eq!(plan.requests.len(), 10);
    assert_eq!(plan.report.requests_cut, 6);
    assert_eq!(plan.report.request_bytes, 8 * LO8 + 2 * HI8);
    // Once everything is loaded the fallbacks are refined.
    let prev = plan.draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    assert_eq!(plan.draw, vec![H; 8]);
    assert_eq!(plan.report.waiting_for_source, 0);
}

#[test]
fn pending_coarsenings_keep_their_hi_bytes_requested() {
    // Threshold 1: seen from x = -1.5 every brick's error (about 11 / distance) wants Hi, from
    // x = -100 none does. Without upload budget the coarsenings stay pending: the bricks stay
    // drawn Hi and their Hi levels stay requested after the wanted levels.
    let (geometry, near) = row(8);
    let far = LodView::new(
        &Camera::perspective(Vec3::new(-100.0, 0.0, 0.0), Vec3::ZERO, 40.0),
        256,
        256,
    )
    .unwrap();
    let ranges = vec![range(0.0, 1.0); 8];
    let mut planner = ResidencyPlanner::new(PlanOptions {
        error_threshold: 1.0,
        hysteresis: 0.1,
    });
    let input = frame(&geometry, &near, &ranges, &NO_CULLING, budget(8, 8 * HI8));
    assert_eq!(
        planner.plan_frame(&input, all_loaded).unwrap().draw,
        vec![Level::Hi; 8]
    );
    let input = frame(&geometry, &far, &ranges, &NO_CULLING, budget(8, 0));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    assert_eq!(plan.wanted, vec![Level::Lo; 8]);
    assert_eq!(plan.draw, vec![Level::Hi; 8]);
    assert!(plan.uploads.is_empty());
    assert_eq!(plan.report.deferred, 8);
    let got: Vec<(u32, Level)> = plan.requests.iter().map(|&(b, l, _)| (b, l)).collect();
    let expected: Vec<(u32, Level)> = (0..8)
        .map(|i| (i, Level::Lo))
        .chain((0..8).map(|i| (i, Level::Hi)))
        .collect();
    assert_eq!(got, expected);
    assert_eq!(plan.requests[15].2, 1.0);
    // Three coarsenings a frame, least important (farthest) first.
    let input = frame(&geometry, &far, &ranges, &NO_CULLING, budget(8, 3 * LO8));
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    let mut expected = vec![Level::Hi; 8];
    expected[5..].fill(Level::Lo);
    assert_eq!(plan.draw, expected);
    let hi_requested: Vec<u32> = plan
        .requests
        .iter()
        .filter(|r| r.1 == Level::Hi)
        .map(|r| r.0)
        .collect();
    assert_eq!(hi_requested, [0, 1, 2, 3, 4]);
}

#[test]
fn culling_follows_the_render_settings() {
    let (geometry, view) = row(8);
    let ranges: Vec<_> = (0..8)
        .map(|i| range(i as f32 / 8.0, (i as f32 + 0.9) / 8.0))
        .collect();
    let tf = TransferFunction::preset(TfPreset::ConstantWhite);
    // Iso-surface at 0.3: only brick 2 ([0.25, 0.36]) holds it.
    let iso = RenderSettings {
        mode: RenderMode::Iso {
            value: 0.3,
            colour: Vec3::ONE,
        },
        ..RenderSettings::default()
    };
    let cull = cull_params(&iso, &tf, (0.0, 1.0)).unwrap();
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(&geometry, &view, &ranges, &cull, budget(8, 100 * HI8));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    assert_eq!(plan.report.culled, 7);
    assert_eq!(plan.draw[2], Level::Hi);
    assert_eq!(count(&plan.draw, Level::Absent), 7);
    // DVR with a TF transparent below 0.5 culls the bricks below it.
    let mut entries = vec![Vec4::ZERO; crate::optics::TF_SIZE];
    for e in &mut entries[crate::optics::TF_SIZE / 2 + 8..] {
        *e = Vec4::splat(0.5);
    }
    let upper = TransferFunction::from_entries(entries).unwrap();
    let dvr = RenderSettings::default();
    let cull = cull_params(&dvr, &upper, (0.0, 1.0)).unwrap();
    assert!(matches!(cull.value, ValueCulling::TransferFunction(_)));
    let input = frame(&geometry, &view, &ranges, &cull, budget(8, 100 * HI8));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    assert_eq!(plan.report.culled, 4);
    assert!(plan.draw[..4].iter().all(|&l| l == Level::Absent));
    // MIP keeps every brick; a clip plane x >= 0 removes the near half.
    let mip = RenderSettings {
        mode: RenderMode::Mip,
        clip_planes: ClipPlanes::new(&[ClipPlane::new(Vec3::X, -0.01)]).unwrap(),
        ..RenderSettings::default()
    };
    let cull = cull_params(&mip, &upper, (0.0, 1.0)).unwrap();
    assert_eq!(cull.value, ValueCulling::None);
    let input = frame(&geometry, &view, &ranges, &cull, budget(8, 100 * HI8));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    assert_eq!(plan.report.culled, 4);
    assert!(plan.draw[4..].iter().all(|&l| l == Level::Hi));
    assert!(matches!(
        cull_params(&dvr, &tf, (0.0, f32::INFINITY)),
        Err(LodError::InvalidWindow { .. })
    ));
}

#[test]
fn bad_inputs_are_typed_errors_and_keep_the_previous_plan() {
    let (geometry, view) = row(8);
    let ranges = vec![range(0.0, 1.0); 8];
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(8, 100 * HI8));
    let good = planner.plan_frame(&input, all_loaded).unwrap().clone();
    let mut zero = budget(8, 0);
    zero.bytes_per_texel = 0;
    let input = frame(&geometry, &view, &ranges, &NO_CULLING, zero);
    assert!(matches!(
        planner.plan_frame(&input, all_loaded),
        Err(PlanError::InvalidInput {
            field: "bytes_per_texel",
            ..
        })
    ));
    let input = frame(&geometry, &view, &ranges[..5], &NO_CULLING, budget(8, 0));
    assert!(matches!(
        planner.plan_frame(&input, all_loaded),
        Err(PlanError::Lod(LodError::LengthMismatch { .. }))
    ));
    let nan_iso = CullParams {
        value: ValueCulling::IsoValue(f32::NAN),
        clip: ClipPlanes::NONE,
    };
    let input = frame(&geometry, &view, &ranges, &nan_iso, budget(8, 0));
    assert!(planner.plan_frame(&input, all_loaded).is_err());
    assert_eq!(planner.last_plan(), &good);
    for options in [
        PlanOptions {
            error_threshold: f32::NAN,
            hysteresis: 0.1,
        },
        PlanOptions {
            error_threshold: 1.0,
            hysteresis: -0.5,
        },
    ] {
        let mut planner = ResidencyPlanner::new(options);
        let input = frame(&geometry, &view, &ranges, &NO_CULLING, budget(8, 0));
        let err = planner.plan_frame(&input, all_loaded).unwrap_err();
        assert!(matches!(err, PlanError::InvalidInput { .. }));
        assert!(matches!(
            crate::Error::from(err),
            crate::Error::Plan(PlanError::InvalidInput { .. })
        ));
    }
    // A different grid starts from nothing resident.
    let (geometry4, view4) = row(4);
    let input = frame(&geometry4, &view4, &ranges[..4], &NO_CULLING, budget(8, 0));
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    assert_eq!(plan.draw, vec![Level::Absent; 4]);
    assert_eq!(plan.report.drawn_absent, 4);
}

#[test]
fn byte_helpers() {
    assert_eq!(upload_bytes(Level::Hi, 32, 2), 34 * 34 * 34 * 2);
    assert_eq!(upload_bytes(Level::Lo, 32, 4), 17 * 17 * 17 * 4);
    assert_eq!(upload_bytes(Level::Absent, 32, 4), 0);
    // 128^3 texels hold 3^3 slots of 34^3.
    assert_eq!(
        PlanBudget::slots_in_bytes(32, 1, 128 * 128 * 128, 2048).unwrap(),
        27
    );
    assert!(matches!(
        PlanBudget::slots_in_bytes(32, 1, 10, 2048),
        Err(PlanError::Cache(_))
    ));
    let cache = CacheGeometry::new(8, UVec3::splat(64)).unwrap();
    assert_eq!(PlanBudget::for_cache(&cache, 2, 7).slots, 216);
}

#[test]
fn randomized_paths_and_budgets_keep_rules_1_2_and_5() {
    for seed in 0..24u64 {
        let mut rng = Rng::new(seed + 100);
        let n = [4, 8][rng.below(2)];
        let dims = UVec3::new(
            (1 + rng.below(12)) as u32 * n - rng.below(3) as u32,
            (1 + rng.below(10)) as u32 * n,
            (1 + rng.below(8)) as u32 * n,
        );
        let grid = BrickGrid::new(dims, n).unwrap();
        let spacing = Vec3::new(1.0, 0.5 + rng.f32(), 0.5 + rng.f32());
        let geometry = BrickGeometry::new(grid, spacing).unwrap();
        let bricks = grid.brick_count();
        let ranges: Vec<_> = (0..bricks)
            .map(|_| match rng.below(10) {
                0 => ValueRange::EMPTY,
                1 => range(0.4, 0.4),
                _ => {
                    let a = rng.f32();
                    range(a, a + rng.f32() * 0.5)
                }
            })
            .collect();
        let cull = if rng.below(3) == 0 {
            CullParams {
                value: ValueCulling::IsoValue(0.5),
                clip: ClipPlanes::NONE,
            }
        } else {
            NO_CULLING
        };
        let options = PlanOptions {
            error_threshold: [0.0, 1.0, 5.0][rng.below(3)],
            hysteresis: [0.0, 0.1, 0.3][rng.below(3)],
        };
        let mut planner = ResidencyPlanner::new(options);
        let mut prev = vec![Level::Absent; bricks];
        let mut eye = Vec3::new(rng.f32() * 4.0 - 2.0, rng.f32() * 4.0 - 2.0, 2.0);
        let salt = rng.next_u64();
        for f in 0..20u64 {
            eye += Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5) * 0.4;
            let target = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5) * 0.3;
            let camera = if rng.below(5) == 0 {
                Camera::orthographic(eye, target, 0.5 + rng.f32())
            } else {
                Camera::perspective(eye, target, 20.0 + rng.f32() * 60.0)
            };
            let Ok(view) = LodView::new(
                &camera,
                64 + rng.below(400) as u32,
                64 + rng.below(300) as u32,
            ) else {
                continue;
            };
            let b = PlanBudget {
                slots: rng.below(bricks + 6),
                upload_bytes_per_frame: (rng.below(12) as u64) * upload_bytes(Level::Hi, n, 2) / 2,
                bytes_per_texel: 2,
                ram_bytes: (rng.below(2) == 0).then(|| rng.below(1 << 20) as u64),
            };
            // What the source has loaded changes every few frames.
            let epoch = f / 3;
            let loaded = move |brick: u32, level: Level| {
                let h = (u64::from(brick) ^ (epoch << 32) ^ salt)
                    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    .rotate_left(17)
                    .wrapping_mul(if level == Level::Hi { 3 } else { 5 });
                level.is_resident() && (h >> 60) < if level == Level::Hi { 11 } else { 14 }
            };
            let input = frame(&geometry, &view, &ranges, &cull, b);
            let plan = planner.plan_frame(&input, loaded).unwrap();
            check_frame(&input, &prev, plan, &loaded);
            if let Some(ram) = b.ram_bytes {
                assert!(plan.report.request_bytes <= ram);
            }
            prev = plan.draw.clone();
        }
    }
}

#[test]
fn a_hundred_thousand_bricks() {
    // 47^3 = 103 823 bricks: a few frames of a moving camera, rules checked on each.
    let grid = BrickGrid::new(UVec3::splat(47 * 4), 4).unwrap();
    let geometry = BrickGeometry::new(grid, Vec3::ONE).unwrap();
    let bricks = grid.brick_count();
    let mut rng = Rng::new(9);
    let ranges: Vec<_> = (0..bricks)
        .map(|_| {
            let a = rng.f32();
            range(a, a + rng.f32() * 0.3)
        })
        .collect();
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let mut prev = vec![Level::Absent; bricks];
    for f in 0..4 {
        let eye = Vec3::new(1.6 - 0.2 * f as f32, 0.9, 1.4);
        let view = LodView::new(&Camera::perspective(eye, Vec3::ZERO, 40.0), 1920, 1080).unwrap();
        let input = frame(
            &geometry,
            &view,
            &ranges,
            &NO_CULLING,
            budget(20_000, 4000 * upload_bytes(Level::Hi, 4, 1)),
        );
        let plan = planner.plan_frame(&input, all_loaded).unwrap();
        check_frame(&input, &prev, plan, &all_loaded);
        prev = plan.draw.clone();
    }
    // Timings live in `cargo bench --bench planner`.
}

mod fallback;
mod frozen;
mod source;

/// A xorshift64 generator from `seed`, for the planner's randomized tests.
pub(super) fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}

#[test]
fn a_kept_ranges_generation_skips_the_comparison_and_a_new_one_culls_again() {
    // Iso-surface at 0.3: of the ranges below only brick 2 holds it.
    let (geometry, view) = row(8);
    let ranges: Vec<_> = (0..8)
        .map(|i| range(i as f32 / 8.0, (i as f32 + 0.9) / 8.0))
        .collect();
    let iso = RenderSettings {
        mode: RenderMode::Iso {
            value: 0.3,
            colour: Vec3::ONE,
        },
        ..RenderSettings::default()
    };
    let tf = TransferFunction::preset(TfPreset::ConstantWhite);
    let cull = cull_params(&iso, &tf, (0.0, 1.0)).unwrap();
    // Brick 5 now holds the iso-value too.
    let mut widened = ranges.clone();
    widened[5] = range(0.0, 1.0);
    let culled = |planner: &mut ResidencyPlanner, ranges: &[ValueRange], generation| {
        let input = FrameInput {
            ranges_generation: generation,
            ..frame(&geometry, &view, ranges, &cull, budget(8, 100 * HI8))
        };
        planner
            .plan_frame(&input, all_loaded)
            .unwrap()
            .report
            .culled
    };
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    assert_eq!(culled(&mut planner, &ranges, Some(1)), 7);
    // The caller said the ranges did not change: the last culling holds.
    assert_eq!(culled(&mut planner, &widened, Some(1)), 7);
    // A new generation, or none, compares and culls again.
    assert_eq!(culled(&mut planner, &widened, Some(2)), 6);
    assert_eq!(culled(&mut planner, &ranges, None), 7);
    assert_eq!(culled(&mut planner, &widened, None), 6);
    // A generation equal to the last one but another count of ranges is not trusted.
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    assert_eq!(culled(&mut planner, &ranges, Some(3)), 7);
    assert!(matches!(
        planner.plan_frame(
            &FrameInput {
                ranges_generation: Some(3),
                ..frame(&geometry, &view, &ranges[..7], &cull, budget(8, 100 * HI8))
            },
            all_loaded
        ),
        Err(PlanError::Lod(_))
    ));
}
