//! The plan is a pure function of the inputs and the previous frames: these digests of every
//! frame's full output (drawn and wanted levels, uploads, requests and the report) along
//! randomized camera paths were recorded from the planner before its speed-ups of 2026-12-02,
//! so any change to what it plans fails here. Paths mix still frames (the same view again),
//! orbits, dollies and jumps, with the loaded set, budgets (including dropping and a RAM cut),
//! options, value ranges and host overrides (`set_drawn`, `reset`) changing along the way.

use super::*;
use glam::Quat;

/// FNV-1a over 64-bit words.
struct Digest(u64);

impl Digest {
    fn word(&mut self, w: u64) {
        for b in w.to_le_bytes() {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01B3);
        }
    }

    fn level(&mut self, l: Level) {
        self.word(match l {
            Level::Hi => 1,
            Level::Lo => 2,
            Level::Absent => 3,
        });
    }

    fn plan(&mut self, plan: &FramePlan) {
        for s in [&plan.draw, &plan.wanted] {
            self.word(s.len() as u64);
            for &l in s.iter() {
                self.level(l);
            }
        }
        self.word(plan.uploads.len() as u64);
        for &(i, l) in &plan.uploads {
            self.word(u64::from(i));
            self.level(l);
        }
        self.word(plan.requests.len() as u64);
        for &(i, l, p) in &plan.requests {
            self.word(u64::from(i));
            self.level(l);
            self.word(u64::from(p.to_bits()));
        }
        let r = &plan.report;
        for v in [
            r.bricks,
            r.culled,
            r.dropped,
            r.wanted_hi,
            r.wanted_lo,
            r.drawn_hi,
            r.drawn_lo,
            r.drawn_absent,
            r.waiting_for_source,
            r.deferred,
            r.slots_used,
            r.slot_budget,
            r.requests_cut,
        ] {
            self.word(v as u64);
        }
        self.word(r.upload_bytes);
        self.word(r.upload_budget);
        self.word(r.request_bytes);
        self.word(u64::from(r.max_drawn_error.to_bits()));
    }
}

/// The digest of one randomized path of 120 frames.
fn path_digest(seed: u64) -> u64 {
    let mut rng = Rng::new(seed + 7000);
    let n = [4, 8, 16][rng.below(3)];
    let dims = UVec3::new(
        (2 + rng.below(16)) as u32 * n - rng.below(3) as u32,
        (1 + rng.below(14)) as u32 * n,
        (1 + rng.below(10)) as u32 * n,
    );
    let grid = BrickGrid::new(dims, n).unwrap();
    let spacing = Vec3::new(1.0, 0.5 + rng.f32(), 0.5 + rng.f32());
    let geometry = BrickGeometry::new(grid, spacing).unwrap();
    let bricks = grid.brick_count();
    let random_ranges = |rng: &mut Rng| -> Vec<ValueRange> {
        (0..bricks)
            .map(|_| match rng.below(12) {
                0 => ValueRange::EMPTY,
                // Equal widths: equal errors at equal distances, so the ties are exercised.
                1 | 2 => range(0.4, 0.6),
                3 => range(f32::NAN, 0.5),
                _ => {
                    let a = rng.f32();
                    range(a, a + rng.f32() * 0.5)
                }
            })
            .collect()
    };
    let mut ranges = random_ranges(&mut rng);
    let cull = match rng.below(3) {
        0 => CullParams {
            value: ValueCulling::IsoValue(0.5),
            clip: ClipPlanes::NONE,
        },
        1 => CullParams::transfer_function(
            TfCullTable::new(&TransferFunction::preset(TfPreset::Fire), (0.0, 1.0)).unwrap(),
        ),
        _ => NO_CULLING,
    };
    let options = PlanOptions {
        error_threshold: [0.0, 0.0, 1.0, 5.0][rng.below(4)],
        hysteresis: [0.0, 0.1, 0.3][rng.below(3)],
    };
    let mut planner = ResidencyPlanner::new(options);
    let mut digest = Digest(0xCBF2_9CE4_8422_2325);
    let hi_cost = upload_bytes(Level::Hi, n, 2);
    let mut eye = Vec3::new(rng.f32() * 4.0 - 2.0, rng.f32() * 4.0 - 2.0, 2.0);
    let mut target = Vec3::ZERO;
    let mut budget = PlanBudget {
        slots: bricks / 4 + 1,
        upload_bytes_per_frame: 8 * hi_cost,
        bytes_per_texel: 2,
        ram_bytes: None,
    };
    let (mut width, mut height) = (320u32, 240u32);
    let mut ortho = false;
    let salt = rng.next_u64();
    let mut epoch = 0u64;
    for _ in 0..120 {
        // The camera: still (often, several frames in a row), orbit, dolly or a jump.
        match rng.below(10) {
            0..=3 => {}
            4 | 5 => eye = target + Quat::from_rotation_y(0.02) * (eye - target),
            6 | 7 => eye = target + (eye - target) * 0.97,
            8 => eye = target + (eye - target) * 1.05,
            _ => {
                eye = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5) * 5.0;
                target = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5) * 0.3;
            }
        }
        // Now and then: budgets, viewport, projection, loaded set, ranges, host overrides.
        match rng.below(24) {
            0 => budget.slots = rng.below(bricks + 6),
            1 => budget.upload_bytes_per_frame = rng.below(16) as u64 * hi_cost / 2,
            2 => budget.ram_bytes = (rng.below(2) == 0).then(|| rng.below(1 << 22) as u64),
            3 => (width, height) = (64 + rng.below(600) as u32, 64 + rng.below(400) as u32),
            4 => ortho = !ortho,
            5..=7 => epoch += 1,
            8 => ranges = random_ranges(&mut rng),
            9 => {
                let drawn: Vec<Level> = planner
                    .last_plan()
                    .draw
                    .iter()
                    .map(|&l| if rng.below(8) == 0 { Level::Absent } else { l })
                    .collect();
                planner.set_drawn(&drawn);
            }
            10 => planner.reset(),
            _ => {}
        }
        let camera = if ortho {
            Camera::orthographic(eye, target, 1.5)
        } else {
            Camera::perspective(eye, target, 40.0)
        };
        let Ok(view) = LodView::new(&camera, width, height) else {
            continue;
        };
        let loaded = move |brick: u32, level: Level| {
            let h = (u64::from(brick) ^ (epoch << 32) ^ salt)
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .rotate_left(17)
                .wrapping_mul(if level == Level::Hi { 3 } else { 5 });
            level.is_resident() && (h >> 60) < if level == Level::Hi { 12 } else { 15 }
        };
        let input = frame(&geometry, &view, &ranges, &cull, budget);
        let plan = planner.plan_frame(&input, loaded).unwrap();
        digest.plan(plan);
    }
    digest.0
}

/// Recorded from the planner at f938c94 (before the speed-ups).
const RECORDED: [u64; 16] = [
    0xd618a9f79c9d1500,
    0x5582f69cc5ced191,
    0x754a47f28e23b09d,
    0x89fb5aff21cd0c03,
    0x748690f4f8220a6a,
    0x89357142b81b9e4c,
    0xdf9634eb0d78e451,
    0x0bbf329a3eec2b9a,
    0x09089f1bd296b4f8,
    0x018d422fb95ecfc8,
    0xf0c61cb258bcc1b5,
    0xddfba9e8e80b6ce2,
    0x77d0d9ad36f3475c,
    0x922095c295e3167c,
    0xe336314bd2cd226b,
    0x4b0f104ba44d4931,
];

#[test]
fn plans_match_the_recorded_outputs_along_randomized_paths() {
    let digests: Vec<u64> = (0..RECORDED.len() as u64).map(path_digest).collect();
    assert_eq!(digests, RECORDED, "recorded: {digests:#x?}");
}
