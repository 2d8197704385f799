//! The planner's fallbacks when the source lacks a level (zooming out with only hi-res bytes
//! loaded, slot pressure on kept levels) and its fast paths against straightforward reference
//! computations.

use super::*;

/// Hi loaded for every brick, Lo for none.
fn only_hi_loaded(_: u32, level: Level) -> bool {
    level == Level::Hi
}

/// Threshold 1 over a row of 8: from x = -1.5 every brick wants Hi, from x = -100 none does.
fn near_and_far() -> (BrickGeometry, LodView, LodView, ResidencyPlanner) {
    let (geometry, near) = row(8);
    let far = LodView::new(
        &Camera::perspective(Vec3::new(-100.0, 0.0, 0.0), Vec3::ZERO, 40.0),
        256,
        256,
    )
    .unwrap();
    let planner = ResidencyPlanner::new(PlanOptions {
        error_threshold: 1.0,
        hysteresis: 0.1,
    });
    (geometry, near, far, planner)
}

#[test]
fn zooming_out_keeps_drawing_hi_while_lo_is_not_loaded() {
    // A brick drawn Hi that the view now wants Lo, with only its Hi bytes loaded, stays drawn Hi
    // (no hole) and counts as waiting for the source; once Lo is loaded it coarsens.
    let (geometry, near, far, mut planner) = near_and_far();
    let ranges = vec![range(0.0, 1.0); 8];
    let input = frame(&geometry, &near, &ranges, &NO_CULLING, budget(8, 8 * HI8));
    assert_eq!(
        planner.plan_frame(&input, all_loaded).unwrap().draw,
        vec![Level::Hi; 8]
    );
    let input = frame(&geometry, &far, &ranges, &NO_CULLING, budget(8, 3 * LO8));
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, only_hi_loaded).unwrap();
    check_frame(&input, &prev, plan, &only_hi_loaded);
    assert_eq!(plan.wanted, vec![Level::Lo; 8]);
    assert_eq!(plan.draw, vec![Level::Hi; 8], "no brick disappears");
    assert!(plan.uploads.is_empty());
    assert_eq!(plan.report.waiting_for_source, 8);
    assert_eq!(plan.report.drawn_absent, 0);
    assert_eq!(plan.report.deferred, 0);
    // The kept Hi levels stay requested (after the wanted Lo levels).
    let hi_requested = plan.requests.iter().filter(|r| r.1 == Level::Hi).count();
    assert_eq!(hi_requested, 8);
    // Lo arrives: three coarsenings a frame, least important (farthest) first.
    let prev = plan.draw.clone();
    let plan = planner.plan_frame(&input, all_loaded).unwrap();
    check_frame(&input, &prev, plan, &all_loaded);
    let mut expected = vec![Level::Hi; 8];
    expected[5..].fill(Level::Lo);
    assert_eq!(plan.draw, expected);
    assert_eq!(plan.report.waiting_for_source, 0);
    // A pending coarsening (drawn Hi, wanted Lo) whose Lo level is evicted again stays Hi too.
    let prev = plan.draw.clone();
    let plan = planner.plan_frame(&input, only_hi_loaded).unwrap();
    check_frame(&input, &prev, plan, &only_hi_loaded);
    let mut expected = vec![Level::Hi; 8];
    expected[5..].fill(Level::Absent);
    assert_eq!(plan.draw, expected);
    assert_eq!(plan.report.drawn_absent, 3);
    assert_eq!(plan.report.waiting_for_source, 8);
    // With neither level loaded there is nothing to keep: the bricks are absent.
    let prev = plan.draw.clone();
    let nothing = |_: u32, _: Level| false;
    let plan = planner.plan_frame(&input, nothing).unwrap();
    check_frame(&input, &prev, plan, &nothing);
    assert_eq!(plan.draw, vec![Level::Absent; 8]);
}

#[test]
fn kept_hi_levels_give_way_to_slot_pressure() {
    // Zooming out with only Hi loaded and 3 slots: the wanted levels (8 Lo) need one slot, so
    // three kept Hi bricks fit, the most important (nearest) ones; the others are absent.
    let (geometry, near, far, mut planner) = near_and_far();
    let ranges = vec![range(0.0, 1.0); 8];
    let input = frame(&geometry, &near, &ranges, &NO_CULLING, budget(8, 8 * HI8));
    planner.plan_frame(&input, all_loaded).unwrap();
    let input = frame(&geometry, &far, &ranges, &NO_CULLING, budget(3, 10 * HI8));
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, only_hi_loaded).unwrap();
    check_frame(&input, &prev, plan, &only_hi_loaded);
    use Level::{Absent as A, Hi as H, Lo as L};
    assert_eq!(plan.draw, [H, H, H, A, A, A, A, A]);
    assert_eq!(plan.report.slots_used, 3);
    assert_eq!(plan.report.waiting_for_source, 8);
    assert_eq!(plan.report.drawn_absent, 5);
    // Lo loaded for the far half: those targets take one slot, two kept Hi bricks still fit.
    let far_lo = |b: u32, l: Level| l == Level::Hi || (l == Level::Lo && b >= 4);
    let mut planner = near_and_far().3;
    let input_near = frame(&geometry, &near, &ranges, &NO_CULLING, budget(8, 8 * HI8));
    planner.plan_frame(&input_near, all_loaded).unwrap();
    let prev = planner.last_plan().draw.clone();
    let plan = planner.plan_frame(&input, far_lo).unwrap();
    check_frame(&input, &prev, plan, &far_lo);
    assert_eq!(plan.draw, [H, H, A, A, L, L, L, L]);
    assert_eq!(plan.report.waiting_for_source, 4);
    assert_eq!(plan.report.slots_used, 3);
}

/// The wanted levels as the planner documents them, by full sorts: culling, dropping all but the
/// `8 x slots` most important, then the `h` best-ranked candidates `Hi`.
fn reference_wanted(
    frame: &FrameInput<'_>,
    options: PlanOptions,
    error: &[f32],
    distance: &[f32],
    prev_wanted: &[Level],
) -> Vec<Level> {
    let bricks = frame.geometry.grid().brick_count();
    let active = cull_bricks(frame.geometry, frame.ranges, frame.cull).unwrap();
    let importance = |a: &u32, b: &u32| {
        let (a, b) = (*a as usize, *b as usize);
        error[b]
            .total_cmp(&error[a])
            .then(distance[a].total_cmp(&distance[b]))
            .then(a.cmp(&b))
    };
    let mut kept: Vec<u32> = (0..bricks as u32).filter(|&i| active[i as usize]).collect();
    kept.sort_by(importance);
    kept.truncate(frame.budget.slots * SUB_SLOTS_PER_SLOT as usize);
    let boost = 1.0 + options.hysteresis;
    let t = options.error_threshold;
    let was_hi = |i: u32| prev_wanted.get(i as usize) == Some(&Level::Hi);
    let mut ranked: Vec<u32> = kept
        .iter()
        .copied()
        .filter(|&i| {
            let e = error[i as usize];
            t == 0.0 || e > t * boost || (was_hi(i) && e > t / boost) || e.is_nan()
        })
        .collect();
    let key = |i: u32| {
        let e = error[i as usize];
        if was_hi(i) {
            e * boost
        } else {
            e
        }
    };
    ranked.sort_by(|&a, &b| {
        key(b)
            .total_cmp(&key(a))
            .then(was_hi(b).cmp(&was_hi(a)))
            .then_with(|| importance(&a, &b))
    });
    let hi = max_hi_bricks(kept.len(), ranked.len(), frame.budget.slots).unwrap_or(0);
    let mut wanted = vec![Level::Absent; bricks];
    for &i in &kept {
        wanted[i as usize] = Level::Lo;
    }
    for &i in &ranked[..hi] {
        wanted[i as usize] = Level::Hi;
    }
    wanted
}

#[test]
fn the_fast_paths_match_reference_computations() {
    // Errors and distances (per-axis sums) against `screen_space_error` and the box distance,
    // the radix-selected wanted levels against full sorts, the radix-sorted requests against
    // `request_plan`, the RAM cut against a running sum, and the incrementally kept report
    // counts against a recount. Value ranges come from a small set and some eyes sit on the
    // grid's symmetry axis, so equal errors (ties) occur.
    for seed in 0..16u64 {
        let mut rng = Rng::new(seed + 300);
        let n = [4, 8][rng.below(2)];
        let dims = UVec3::new(
            (2 + rng.below(10)) as u32 * n,
            (1 + rng.below(8)) as u32 * n,
            (1 + rng.below(6)) as u32 * n - rng.below(2) as u32,
        );
        let grid = BrickGrid::new(dims, n).unwrap();
        let geometry = BrickGeometry::new(grid, Vec3::new(1.0, 0.5 + rng.f32(), 1.0)).unwrap();
        let bricks = grid.brick_count();
        let widths = [0.0, 0.25, 0.5, 0.5, 1.0];
        let ranges: Vec<_> = (0..bricks)
            .map(|_| match rng.below(12) {
                0 => ValueRange::EMPTY,
                _ => range(0.25, 0.25 + widths[rng.below(widths.len())]),
            })
            .collect();
        let cull = if rng.below(3) == 0 {
            CullParams {
                value: ValueCulling::IsoValue(0.4),
                clip: ClipPlanes::NONE,
            }
        } else {
            NO_CULLING
        };
        let options = PlanOptions {
            error_threshold: [0.0, 0.0, 1.0, 4.0][rng.below(4)],
            hysteresis: [0.0, 0.1, 0.3][rng.below(3)],
        };
        let mut planner = ResidencyPlanner::new(options);
        let salt = rng.next_u64();
        for f in 0..12u64 {
            let eye = if rng.below(2) == 0 {
                Vec3::new(0.0, 0.0, 1.0 + 2.0 * rng.f32())
            } else {
                Vec3::new(rng.f32() * 3.0 - 1.5, rng.f32() * 3.0 - 1.5, 1.5)
            };
            let camera = if rng.below(4) == 0 {
                Camera::orthographic(eye, Vec3::ZERO, 0.5 + rng.f32())
            } else {
                Camera::perspective(eye, Vec3::ZERO, 30.0 + rng.f32() * 40.0)
            };
            let view = LodView::new(&camera, 200, 150).unwrap();
            let hi_bytes = upload_bytes(Level::Hi, n, 1);
            let b = PlanBudget {
                slots: rng.below(bricks + 4),
                upload_bytes_per_frame: rng.below(8) as u64 * hi_bytes,
                bytes_per_texel: 1,
                ram_bytes: (rng.below(2) == 0).then(|| rng.below(bricks) as u64 * hi_bytes),
            };
            let loaded = move |brick: u32, level: Level| {
                let h = (u64::from(brick) ^ ((f / 4) << 32) ^ salt)
                    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    .wrapping_mul(if level == Level::Hi { 3 } else { 5 });
                level.is_resident() && (h >> 61) < 6
            };
            let input = frame(&geometry, &view, &ranges, &cull, b);
            let prev_wanted = planner.last_plan().wanted.clone();
            let prev_draw = match planner.last_plan().draw.len() {
                0 => vec![Level::Absent; bricks],
                _ => planner.last_plan().draw.clone(),
            };
            planner.plan_frame(&input, loaded).unwrap();
            let plan = planner.last_plan();
            check_frame(&input, &prev_draw, plan, &loaded);
            let work = &planner.work;
            let active = cull_bricks(&geometry, &ranges, &cull).unwrap();
            let distances = Distances::new(&work.axis_sq);
            let distance: Vec<f32> = (0..bricks as u32).map(|i| distances.get(i)).collect();
            for i in 0..bricks {
                if !active[i] {
                    continue;
                }
                let (min, max) = geometry.brick_box(grid.brick_coords(i));
                let e = screen_space_error(&geometry, &view, min, max, ranges[i]);
                assert_eq!(
                    work.error[i].to_bits(),
                    e.to_bits(),
                    "seed {seed} brick {i}"
                );
                let d = box_distance(view.eye(), min, max);
                assert_eq!(distance[i].to_bits(), d.to_bits());
            }
            let wanted =
                reference_wanted(&input, options, &work.error, &distance, &{ prev_wanted });
            assert_eq!(plan.wanted, wanted, "seed {seed} frame {f}");
            // Requests: `request_plan`, then what is drawn Hi but not wanted Hi, cut to the RAM.
            let mut expected: Vec<(u32, Level)> = request_plan(&plan.wanted, &work.error)
                .into_iter()
                .map(|(i, l, _)| (i, l))
                .collect();
            expected.extend(
                (0..bricks as u32)
                    .filter(|&i| {
                        plan.draw[i as usize] == Level::Hi && plan.wanted[i as usize] != Level::Hi
                    })
                    .map(|i| (i, Level::Hi)),
            );
            let mut bytes = 0u64;
            let fit = expected
                .iter()
                .take_while(|&&(_, l)| {
                    bytes += upload_bytes(l, n, 1);
                    b.ram_bytes.is_none_or(|ram| bytes <= ram)
                })
                .count();
            let got: Vec<(u32, Level)> = plan.requests.iter().map(|&(i, l, _)| (i, l)).collect();
            assert_eq!(got, expected[..fit], "seed {seed} frame {f}");
            let r = &plan.report;
            assert_eq!(r.requests_cut, expected.len() - fit);
            let fit_bytes: u64 = expected[..fit]
                .iter()
                .map(|&(_, l)| upload_bytes(l, n, 1))
                .sum();
            assert_eq!(r.request_bytes, fit_bytes);
            for (pos, req) in plan.requests.iter().enumerate() {
                assert_eq!(req.2, (fit - pos) as f32);
            }
            // The report against a recount.
            assert_eq!(r.drawn_hi, count(&plan.draw, Level::Hi));
            assert_eq!(r.drawn_lo, count(&plan.draw, Level::Lo));
            let deferred = (0..bricks)
                .filter(|&i| plan.draw[i] != work.target[i])
                .count();
            assert_eq!(r.deferred, deferred);
            let waiting = (0..bricks)
                .filter(|&i| plan.wanted[i] != work.target[i])
                .count();
            assert_eq!(r.waiting_for_source, waiting);
            let max_lo = (0..bricks)
                .filter(|&i| plan.draw[i] == Level::Lo)
                .fold(0.0f32, |m, i| m.max(work.error[i]));
            assert_eq!(r.max_drawn_error, max_lo);
            // Targets: the loaded fallback, or a kept Hi level (drawn Hi before, wanted Lo).
            for (i, &before) in prev_draw.iter().enumerate() {
                let (w, t, bi) = (plan.wanted[i], work.target[i], i as u32);
                let fallback = match w {
                    Level::Hi if loaded(bi, Level::Hi) => Level::Hi,
                    Level::Hi | Level::Lo if loaded(bi, Level::Lo) => Level::Lo,
                    _ => Level::Absent,
                };
                if t != fallback {
                    assert_eq!((w, fallback, t), (Level::Lo, Level::Absent, Level::Hi));
                    assert_eq!(before, Level::Hi);
                    assert!(loaded(bi, Level::Hi));
                }
            }
        }
    }
}
