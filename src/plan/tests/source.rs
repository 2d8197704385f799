//! Planning through a [`BrickSource`]: the plan settles on what `fallback_levels` makes of the
//! wanted levels, and one `loaded_levels` call per frame plans as asking `is_loaded` brick by
//! brick.

use super::*;

/// Asserts that two plans of frame `f` are the same, output by output.
fn assert_same_plan(a: &FramePlan, c: &FramePlan, f: u32) {
    assert_eq!(a.draw, c.draw, "frame {f}");
    assert_eq!(a.wanted, c.wanted, "frame {f}");
    assert_eq!(a.uploads, c.uploads, "frame {f}");
    assert_eq!(a.requests, c.requests, "frame {f}");
    assert_eq!(a.report, c.report, "frame {f}");
}

#[test]
fn planning_with_a_source_plans_as_with_its_is_loaded() {
    // A source with some levels not loaded (a pattern that changes every frame), which reports
    // them through the default `loaded_levels`: the plans of `plan_frame_with_source` and of
    // `plan_frame` asking `is_loaded` are the same, frame by frame.
    use crate::bricks::{DownsampleFilter, LoadedLevels, SourceError, VolumeBrickSource};
    use crate::volume::{marschner_lobb, ScalarType};
    use glam::Quat;
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::sync::Arc;
    struct Partial {
        inner: VolumeBrickSource,
        frame: AtomicU32,
    }
    impl BrickSource for Partial {
        fn grid(&self) -> BrickGrid {
            self.inner.grid()
        }
        fn scalar(&self) -> crate::volume::ScalarType {
            self.inner.scalar()
        }
        fn filter(&self) -> DownsampleFilter {
            self.inner.filter()
        }
        fn spacing(&self) -> Vec3 {
            self.inner.spacing()
        }
        fn value_ranges(&self) -> &[ValueRange] {
            self.inner.value_ranges()
        }
        fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError> {
            if !self.is_loaded(brick, level) {
                return Ok(None);
            }
            self.inner.brick_bytes(brick, level)
        }
        fn is_loaded(&self, brick: u32, level: Level) -> bool {
            let f = self.frame.load(Ordering::Relaxed);
            match level {
                Level::Hi => !(brick * 7 + f).is_multiple_of(5),
                Level::Lo => !(brick * 3 + f).is_multiple_of(4),
                Level::Absent => false,
            }
        }
    }
    let volume = marschner_lobb(UVec3::splat(32), ScalarType::U8).unwrap();
    let source = Partial {
        inner: VolumeBrickSource::new(Arc::new(volume), 4, DownsampleFilter::default()).unwrap(),
        frame: AtomicU32::new(0),
    };
    let grid = source.grid();
    let geometry = BrickGeometry::new(grid, source.spacing()).unwrap();
    let b = PlanBudget {
        slots: 60,
        upload_bytes_per_frame: 40 * upload_bytes(Level::Hi, 4, 1),
        bytes_per_texel: 1,
        ram_bytes: Some(300 * upload_bytes(Level::Lo, 4, 1)),
    };
    let settings = RenderSettings::default();
    let tf = TransferFunction::preset(TfPreset::Fire);
    let cull = cull_params(&settings, &tf, (0.0, 1.0)).unwrap();
    let mut with_source = ResidencyPlanner::new(PlanOptions::default());
    let mut with_closure = ResidencyPlanner::new(PlanOptions::default());
    let mut loaded = Vec::new();
    source.loaded_levels(&mut loaded);
    assert_eq!(loaded.len(), grid.brick_count());
    assert!(loaded.contains(&LoadedLevels::NONE) && loaded.contains(&LoadedLevels::BOTH));
    let mut camera = Camera::default_view();
    for f in 0..12 {
        source.frame.store(f, Ordering::Relaxed);
        camera.eye = Quat::from_rotation_y(0.2 * f as f32) * camera.eye;
        let view = LodView::new(&camera, 160, 120).unwrap();
        let input = frame(&geometry, &view, source.value_ranges(), &cull, b);
        let a = with_source
            .plan_frame_with_source(&input, &source)
            .unwrap()
            .clone();
        let c = with_closure
            .plan_frame(&input, |brick, level| source.is_loaded(brick, level))
            .unwrap();
        assert_same_plan(&a, c, f);
        assert!(
            a.report.waiting_for_source > 0,
            "frame {f}: some levels are missing"
        );
    }
}

#[test]
fn planning_with_loaded_levels_plans_as_asking_and_a_short_slice_has_nothing_past_its_end() {
    // Random loaded levels that change every frame, along a turning camera with a binding slot
    // and upload budget: `plan_frame_with_loaded` (the pass over bytes) and `plan_frame` (asking
    // brick by brick) give the same plans. A slice shorter than the grid plans as if the bricks
    // past its end had nothing loaded.
    use crate::bricks::LoadedLevels;
    use glam::Quat;
    let mut next = xorshift(0x5DEE_CE66_D1CE_4E5B);
    let count = 300u32;
    let (geometry, _) = row(count);
    let ranges: Vec<ValueRange> = (0..count)
        .map(|i| range(0.1 * (i % 7) as f32, 1.0))
        .collect();
    let cull = NO_CULLING;
    let b = budget(count as usize / 4, 12 * upload_bytes(Level::Hi, 8, 1));
    for short in [false, true] {
        let mut by_bytes = ResidencyPlanner::new(PlanOptions::default());
        let mut asking = ResidencyPlanner::new(PlanOptions::default());
        let mut loaded: Vec<LoadedLevels> = Vec::new();
        let mut camera = Camera::perspective(Vec3::new(0.1, 0.1, -0.4), Vec3::ZERO, 50.0);
        let mut changes = 0;
        for f in 0..40 {
            // Mostly loaded, with some levels of some bricks coming and going.
            loaded.resize(count as usize, LoadedLevels::BOTH);
            for l in loaded.iter_mut() {
                if next().is_multiple_of(6) {
                    let bits = next();
                    *l = LoadedLevels::NONE
                        .with(Level::Hi, bits & 1 != 0)
                        .with(Level::Lo, bits & 2 != 0);
                }
            }
            if short {
                loaded.truncate(count as usize - 37);
            }
            camera.eye = Quat::from_rotation_y(0.08) * camera.eye;
            let view = LodView::new(&camera, 320, 200).unwrap();
            let input = frame(&geometry, &view, &ranges, &cull, b);
            let a = by_bytes
                .plan_frame_with_loaded(&input, &loaded)
                .unwrap()
                .clone();
            let c = asking
                .plan_frame(&input, |brick, level| {
                    loaded
                        .get(brick as usize)
                        .is_some_and(|l| l.contains(level))
                })
                .unwrap();
            assert_same_plan(&a, c, f);
            changes += a.uploads.len();
            if short {
                assert!(
                    a.draw[count as usize - 37..]
                        .iter()
                        .all(|&d| d == Level::Absent),
                    "frame {f}: nothing loaded past the slice, nothing drawn"
                );
            }
        }
        assert!(
            changes > 40,
            "the plans changed along the path ({changes} uploads)"
        );
    }
}

#[test]
fn a_brick_source_drives_the_plan_like_fallback_levels() {
    // An in-memory source has every level loaded: once settled the drawn levels are what
    // `fallback_levels` makes of the wanted ones (here: the wanted levels themselves).
    use crate::bricks::{fallback_levels, DownsampleFilter, VolumeBrickSource};
    use crate::volume::{marschner_lobb, ScalarType};
    use std::sync::Arc;
    let volume = marschner_lobb(UVec3::splat(32), ScalarType::U16).unwrap();
    let source = VolumeBrickSource::new(Arc::new(volume), 8, DownsampleFilter::default()).unwrap();
    let grid = source.grid();
    let geometry = BrickGeometry::new(grid, source.spacing()).unwrap();
    let view = LodView::new(&Camera::default_view(), 200, 150).unwrap();
    let bytes_per_texel = PlanBudget::bytes_per_texel_of(&source);
    assert_eq!(bytes_per_texel, 2);
    let b = PlanBudget {
        slots: 20,
        upload_bytes_per_frame: 5 * upload_bytes(Level::Hi, 8, bytes_per_texel),
        bytes_per_texel,
        ram_bytes: None,
    };
    let settings = RenderSettings::default();
    let cull = cull_params(
        &settings,
        &TransferFunction::preset(TfPreset::Fire),
        (0.0, 1.0),
    )
    .unwrap();
    let input = frame(&geometry, &view, source.value_ranges(), &cull, b);
    let mut planner = ResidencyPlanner::new(PlanOptions::default());
    let loaded = |brick: u32, level: Level| source.is_loaded(brick, level);
    let mut prev = vec![Level::Absent; grid.brick_count()];
    for _ in 0..30 {
        let plan = planner.plan_frame_with_source(&input, &source).unwrap();
        check_frame(&input, &prev, plan, &loaded);
        prev = plan.draw.clone();
    }
    let plan = planner.last_plan();
    assert!(plan.report.is_settled());
    assert_eq!(plan.draw, fallback_levels(&plan.wanted, &source));
    assert_eq!(plan.report.waiting_for_source, 0);
    assert!(plan.report.drawn_hi > 0 && plan.report.slots_used <= 20);
    // Every upload's bytes come from the source at the size the plan counted.
    let (brick, level) = (0..grid.brick_count() as u32)
        .map(|i| (i, plan.draw[i as usize]))
        .find(|&(_, l)| l == Level::Hi)
        .unwrap();
    let bytes = source.brick_bytes(brick, level).unwrap().unwrap();
    assert_eq!(bytes.len() as u64, upload_bytes(level, 8, bytes_per_texel));
}
