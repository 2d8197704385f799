//! Brick-cache residency churn after small camera moves (CPU only): how many bricks a
//! `BrickCache::update` re-uploads when the view changes slightly, against how many are resident.
//!
//! Setup: a Marschner-Lobb volume (u16, default 256^3) in bricks of n = 16, culled by the `fire`
//! transfer function, LOD-selected for a 1920x1080 perspective view into a cache whose slot
//! budget holds only a quarter of the active bricks hi-res (so demotion happens). Two views: an
//! overview with the whole volume in view (budget-driven selection), and a close-up that sees
//! part of the volume, with LaMar's frustum filter (`FovFilter::FRUSTUM_ONLY`) on top. The cache
//! is warmed at camera A; each row starts from that warm cache, moves the camera, selects again
//! and updates. Sequences (`x N`) apply the move N times in a row and report the per-step mean.
//! Timings: one step from camera A, selection (`LodSelector::select_into`) and
//! `BrickCache::update` separately.
//!
//! Run: `cargo bench --bench residency`. Environment: `MIXVOL_BENCH_DIM` (volume edge, default
//! 256), `MIXVOL_BENCH_RUNS` (timed repeats, default 21; medians reported). Prints Markdown
//! tables.

use glam::{Quat, UVec3, Vec3};
use mixvol::bricks::{build_bricks, BrickGrid, DownsampleFilter, Level};
use mixvol::cache::{BrickCache, CacheGeometry, CacheUpdate};
use mixvol::lod::{
    cull_bricks, slots_needed, BrickGeometry, CullParams, FovFilter, LodSelector, LodView,
    SelectionOptions, TfCullTable,
};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::Camera;
use mixvol::volume::{marschner_lobb, ScalarType};
use std::hint::black_box;
use std::time::Instant;

const BRICK_SIZE: u32 = 16;
const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
/// Share of the active bricks the slot budget can hold hi-res (the rest low-res).
const HI_SHARE: f64 = 0.25;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// A camera move applied to a camera.
#[derive(Copy, Clone)]
enum Move {
    /// Orbit the eye around the target about +y by this many degrees.
    Orbit(f32),
    /// Move the eye towards the target by this fraction of the distance.
    Dolly(f32),
    /// Shift eye and target sideways by this fraction of the distance.
    Pan(f32),
}

impl Move {
    fn apply(self, camera: &Camera) -> Camera {
        let mut c = *camera;
        let offset = c.eye - c.target;
        match self {
            Move::Orbit(degrees) => {
                c.eye = c.target + Quat::from_rotation_y(degrees.to_radians()) * offset;
            }
            Move::Dolly(fraction) => c.eye = c.target + offset * (1.0 - fraction),
            Move::Pan(fraction) => {
                let right = (-offset).cross(c.up).normalize();
                let shift = right * offset.length() * fraction;
                c.eye += shift;
                c.target += shift;
            }
        }
        c
    }

    fn name(self) -> String {
        match self {
            Move::Orbit(d) => format!("orbit {d}°"),
            Move::Dolly(f) => format!("dolly {}% closer", f * 100.0),
            Move::Pan(f) => format!("pan {}% sideways", f * 100.0),
        }
    }
}

/// Everything a selection needs, fixed for the run.
struct Scene {
    geometry: BrickGeometry,
    ranges: Vec<mixvol::bricks::ValueRange>,
    active: Vec<bool>,
    options: SelectionOptions,
}

impl Scene {
    fn select(&self, selector: &mut LodSelector, camera: &Camera, levels: &mut Vec<Level>) {
        let view = LodView::new(camera, WIDTH, HEIGHT).expect("valid view");
        selector
            .select_into(
                &self.geometry,
                &view,
                &self.ranges,
                &self.active,
                &self.options,
                levels,
            )
            .expect("budget holds all-low-res");
    }
}

/// Counts of one update.
#[derive(Default, Clone, Copy)]
struct Churn {
    resident: usize,
    hi: usize,
    uploads: usize,
    lo_to_hi: usize,
    hi_to_lo: usize,
    new: usize,
    evicted: usize,
    moved: usize,
    restored: usize,
    upload_texels: u64,
}

impl Churn {
    fn of(before: &[Level], after: &[Level], update: &CacheUpdate) -> Self {
        let mut c = Churn {
            uploads: update.uploads.len(),
            evicted: update.evicted.len(),
            moved: update.moved.len(),
            restored: update.restored_borders.len(),
            upload_texels: update
                .uploads
                .iter()
                .map(|u| u.extent.iter().map(|&e| u64::from(e)).product::<u64>())
                .sum(),
            ..Churn::default()
        };
        for (&b, &a) in before.iter().zip(after) {
            c.resident += usize::from(a.is_resident());
            c.hi += usize::from(a == Level::Hi);
            match (b, a) {
                (Level::Lo, Level::Hi) => c.lo_to_hi += 1,
                (Level::Hi, Level::Lo) => c.hi_to_lo += 1,
                (Level::Absent, Level::Hi | Level::Lo) => c.new += 1,
                _ => {}
            }
        }
        c
    }

    fn add(&mut self, o: &Churn) {
        self.resident += o.resident;
        self.hi += o.hi;
        self.uploads += o.uploads;
        self.lo_to_hi += o.lo_to_hi;
        self.hi_to_lo += o.hi_to_lo;
        self.new += o.new;
        self.evicted += o.evicted;
        self.moved += o.moved;
        self.restored += o.restored;
        self.upload_texels += o.upload_texels;
    }
}

fn main() {
    let dim = env_usize("MIXVOL_BENCH_DIM", 256).max(BRICK_SIZE as usize) as u32;
    let runs = env_usize("MIXVOL_BENCH_RUNS", 21).max(1);
    let volume = marschner_lobb(UVec3::splat(dim), ScalarType::U16).expect("valid volume");
    let grid = BrickGrid::new(volume.dims(), BRICK_SIZE).expect("valid grid");
    let store =
        build_bricks(&volume, &grid, DownsampleFilter::Mean2, ScalarType::U16).expect("bricks");
    let geometry = BrickGeometry::new(grid, volume.spacing()).expect("valid spacing");
    let tf = TransferFunction::preset(TfPreset::Fire);
    let params = CullParams::transfer_function(TfCullTable::new(&tf, (0.0, 1.0)).expect("window"));
    let ranges = store.value_ranges().to_vec();
    let active = cull_bricks(&geometry, &ranges, &params).expect("culls");
    let active_count = active.iter().filter(|&&a| a).count();
    let hi_budget = (active_count as f64 * HI_SHARE) as usize;
    let slots = slots_needed(hi_budget, active_count - hi_budget);
    let cache_geometry =
        CacheGeometry::choose(BRICK_SIZE, 2, 1 << 30, 2048, slots as u32).expect("cache fits");
    println!(
        "# BrickCache residency after small camera moves: {dim}^3 u16 Marschner-Lobb, n = \
         {BRICK_SIZE}, {} bricks, {active_count} active (fire TF), {slots} slots (≈{:.0}% of the \
         active bricks hi-res), {WIDTH}x{HEIGHT}, medians of {runs} timings",
        grid.brick_count(),
        HI_SHARE * 100.0,
    );
    let overview = Camera::perspective(Vec3::new(1.2, 0.9, 1.6), Vec3::ZERO, 35.0);
    let close_up = Camera::perspective(Vec3::new(0.45, 0.3, 0.75), Vec3::new(0.1, 0.0, 0.0), 35.0);
    let budget_only = SelectionOptions::with_slots(slots);
    let frustum = SelectionOptions {
        fov_filter: Some(FovFilter::FRUSTUM_ONLY),
        ..budget_only
    };
    for (title, camera, options) in [
        (
            "overview (whole volume in view), budget-driven selection",
            overview,
            budget_only,
        ),
        (
            "close-up (part of the volume in view), budget + frustum filter",
            close_up,
            frustum,
        ),
    ] {
        let scene = Scene {
            geometry,
            ranges: ranges.clone(),
            active: active.clone(),
            options,
        };
        let cache = BrickCache::with_slot_limit(grid, cache_geometry, slots as u32).expect("cache");
        run_view(title, &scene, camera, cache, runs);
    }
}

/// Warms `cache` at `camera_a`, then prints one table row per camera move.
fn run_view(title: &str, scene: &Scene, camera_a: Camera, mut warm: BrickCache, runs: usize) {
    let mut selector = LodSelector::new();
    let mut levels_a = Vec::new();
    scene.select(&mut selector, &camera_a, &mut levels_a);
    let first = warm.update(&levels_a).expect("fits");
    let bytes_per_texel = 2u64;
    println!();
    println!(
        "## {title}: camera A at distance {:.2}; warm-up uploads {} bricks from empty ({:.1} MB)",
        (camera_a.eye - camera_a.target).length(),
        first.uploads.len(),
        first
            .uploads
            .iter()
            .map(|u| u.extent.iter().map(|&e| u64::from(e)).product::<u64>())
            .sum::<u64>() as f64
            * bytes_per_texel as f64
            / 1e6
    );
    println!();
    println!(
        "| move | resident (hi + lo) | re-uploaded | lo→hi | hi→lo | newly resident | evicted | \
         moved by compaction | border restores | re-uploaded / resident | upload MB | select µs | \
         update µs |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");

    let cases: Vec<(Move, usize)> = vec![
        (Move::Orbit(1.0), 1),
        (Move::Orbit(2.0), 1),
        (Move::Orbit(2.0), 10),
        (Move::Dolly(0.01), 1),
        (Move::Dolly(0.01), 10),
        (Move::Pan(0.01), 1),
        (Move::Orbit(10.0), 1),
        (Move::Orbit(45.0), 1),
    ];
    let mut levels = Vec::new();
    for (step, count) in cases {
        // Counts: apply the move `count` times from camera A, starting from the warm cache.
        let mut cache = warm.clone();
        let mut camera = camera_a;
        let mut before = levels_a.clone();
        let mut total = Churn::default();
        for _ in 0..count {
            camera = step.apply(&camera);
            scene.select(&mut selector, &camera, &mut levels);
            let update = cache.update(&levels).expect("selection fits the cache");
            total.add(&Churn::of(&before, &levels, &update));
            before.clone_from(&levels);
        }
        // Timing: one step from camera A (selection, then update of a fresh warm clone).
        let moved = step.apply(&camera_a);
        let mut select_s = Vec::with_capacity(runs);
        let mut update_s = Vec::with_capacity(runs);
        for _ in 0..runs {
            let mut cache = warm.clone();
            let t = Instant::now();
            scene.select(&mut selector, black_box(&moved), &mut levels);
            select_s.push(t.elapsed().as_secs_f64());
            let t = Instant::now();
            let update = cache.update(black_box(&levels)).expect("fits");
            update_s.push(t.elapsed().as_secs_f64());
            black_box(update);
        }
        let per = |v: usize| v as f64 / count as f64;
        let name = if count > 1 {
            format!("{} x {count} (mean per step)", step.name())
        } else {
            step.name()
        };
        println!(
            "| {name} | {:.0} ({:.0} + {:.0}) | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | \
             {:.1} | {:.2}% | {:.2} | {:.0} | {:.0} |",
            per(total.resident),
            per(total.hi),
            per(total.resident - total.hi),
            per(total.uploads),
            per(total.lo_to_hi),
            per(total.hi_to_lo),
            per(total.new),
            per(total.evicted),
            per(total.moved),
            per(total.restored),
            100.0 * total.uploads as f64 / total.resident.max(1) as f64,
            total.upload_texels as f64 * bytes_per_texel as f64 / 1e6 / count as f64,
            median(select_s) * 1e6,
            median(update_s) * 1e6,
        );
    }
}
