//! CPU cost of per-frame brick culling and level-of-detail selection (`mixvol::lod`) against the
//! brick count: synthetic per-brick value ranges on cubic grids of 32^3-voxel bricks, culled by
//! the `fire` transfer function and one clip plane, then selected into a cache holding a quarter
//! of the active bricks hi-res.
//!
//! Run: `cargo bench --bench lod` (set MIXVOL_BENCH_RUNS to change the run count). Prints a
//! Markdown table of median times.

use glam::{UVec3, Vec3};
use mixvol::bricks::{BrickGrid, ValueRange};
use mixvol::lod::{
    cull_bricks_into, BrickGeometry, CullParams, LodSelector, LodView, SelectionOptions,
    TfCullTable, ValueCulling,
};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::Camera;
use mixvol::scene::{ClipPlane, ClipPlanes};
use std::hint::black_box;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Smooth-ish ranges: a radial field around the centre plus a small per-brick spread, so that
/// the `fire` shell around 0.5 culls a realistic share of the bricks.
fn synthetic_ranges(grid: &BrickGrid) -> Vec<ValueRange> {
    let per_axis = grid.bricks_per_axis().as_vec3();
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    grid.bricks()
        .map(|b| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let jitter = (state >> 40) as f32 / (1u64 << 24) as f32;
            let p = (b.as_vec3() + Vec3::splat(0.5)) / per_axis - Vec3::splat(0.5);
            let centre = 1.0 - 1.4 * p.length();
            let half = 0.02 + 0.08 * jitter;
            ValueRange {
                min: (centre - half).clamp(0.0, 1.0),
                max: (centre + half).clamp(0.0, 1.0),
            }
        })
        .collect()
}

fn main() {
    let runs = std::env::var("MIXVOL_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(11usize)
        .max(1);
    let tf = TransferFunction::preset(TfPreset::Fire);
    let camera = Camera::perspective(Vec3::new(1.2, 0.9, 1.6), Vec3::ZERO, 35.0);
    let view = LodView::new(&camera, 1920, 1080).expect("valid view");
    let clip = ClipPlanes::new(&[ClipPlane::new(Vec3::new(-1.0, 0.0, 0.0), 0.3)])
        .expect("one finite plane");

    println!(
        "# mixvol::lod culling + selection, 32^3-voxel bricks, 1920x1080, median of {runs} runs"
    );
    println!("| bricks | grid | active | hi | lo | slots | culling µs | selection µs |");
    println!("|---:|---|---:|---:|---:|---:|---:|---:|");
    for side in [16u32, 32, 47] {
        let grid = BrickGrid::new(UVec3::splat(side * 32), 32).expect("valid grid");
        let geometry = BrickGeometry::new(grid, Vec3::ONE).expect("valid spacing");
        let ranges = synthetic_ranges(&grid);
        let mut active = Vec::new();
        let mut levels = Vec::new();
        let mut selector = LodSelector::new();
        let mut cull_us = Vec::new();
        let mut select_us = Vec::new();
        let mut summary = None;
        let mut slots = 0;
        for run in 0..=runs {
            let t = Instant::now();
            let params = CullParams {
                value: ValueCulling::TransferFunction(
                    TfCullTable::new(&tf, (0.0, 1.0)).expect("valid window"),
                ),
                clip,
            };
            cull_bricks_into(&geometry, black_box(&ranges), &params, &mut active)
                .expect("one range per brick");
            let cull = t.elapsed().as_secs_f64() * 1e6;

            let active_count = active.iter().filter(|&&a| a).count();
            slots = (active_count / 4).max(active_count.div_ceil(8));
            let options = SelectionOptions::with_slots(slots);
            let t = Instant::now();
            let s = selector
                .select_into(
                    &geometry,
                    &view,
                    &ranges,
                    black_box(&active),
                    &options,
                    &mut levels,
                )
                .expect("budget fits");
            let select = t.elapsed().as_secs_f64() * 1e6;
            black_box(&levels);
            if run > 0 {
                // Run 0 warms caches and the selector's buffer.
                cull_us.push(cull);
                select_us.push(select);
            }
            summary = Some(s);
        }
        let s = summary.expect("runs >= 1");
        println!(
            "| {} | {side}^3 | {} | {} | {} | {slots} | {:.0} | {:.0} |",
            grid.brick_count(),
            s.active,
            s.hi,
            s.lo,
            median(cull_us),
            median(select_us)
        );
    }
}
