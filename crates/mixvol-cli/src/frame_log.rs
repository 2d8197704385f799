//! The per-frame log of `render` and `bench` along a camera path: GPU upload, fixup and
//! ray-cast times, CPU frame and planner time, what was uploaded, what is resident, how full
//! the budgets are, and the worst screen-space error; written as CSV and JSON (each
//! atomically: a temporary name, then renamed).

use crate::files::write_text;
use mixvol::renderer::Frame;
use mixvol::{Error, Result};
use serde::Serialize;
use std::path::Path;

/// One frame's row.
#[derive(Serialize, Clone, Debug, Default, PartialEq)]
pub struct FrameRow {
    /// Frame index along the path.
    pub frame: usize,
    /// GPU time of the uploads recorded with the frame (ms; empty where not measured).
    pub gpu_upload_ms: Option<f64>,
    /// GPU time of the fixup (ms).
    pub gpu_fixup_ms: Option<f64>,
    /// GPU time of the ray-cast (ms).
    pub gpu_raycast_ms: Option<f64>,
    /// CPU wall time of the frame, planning to read-back (ms).
    pub cpu_frame_ms: f64,
    /// CPU time of the planner (ms).
    pub plan_ms: f64,
    /// Bricks copied into the cache (level changes, moves and border restores).
    pub uploaded_bricks: usize,
    /// Megabytes copied into the cache.
    pub uploaded_mb: f64,
    /// Megabytes of level changes against the per-frame upload budget.
    pub upload_budget_mb: f64,
    /// Bricks drawn at each level, level 0 (full resolution) first
    /// (`mixvol::renderer::FrameReport::per_level`: `Hi` and `Lo` of a two-level scene, every
    /// level of a level source; CSV columns `resident_l0`, ...).
    pub resident: Vec<usize>,
    /// Bricks drawn absent although the view wants them (not loaded yet, or deferred).
    pub absent_wanted: usize,
    /// Bricks culled (transfer function, iso value, clip planes).
    pub culled: usize,
    /// Bricks dropped because even all-low-res did not fit the cache.
    pub dropped: usize,
    /// Bricks not drawn at the level the view wants: not loaded yet, or waiting for the upload
    /// budget of a later frame.
    pub waiting: usize,
    /// Level changes deferred to later frames by the upload budget.
    pub deferred: usize,
    /// Cache slots used / slots in the cache.
    pub budget_fill: f64,
    /// Megabytes of the GPU cache image.
    pub cache_mb: f64,
    /// Megabytes of GPU memory allocated by the renderer after the frame.
    pub gpu_allocated_mb: f64,
    /// Largest screen-space error of a brick drawn low-res (pixels x value range; a level
    /// source: the largest voxel on screen, in pixels, at the levels the view wants).
    pub worst_error: f32,
    /// Bricks whose load failed in the source (drawn at a fallback).
    pub source_errors: usize,
}

impl FrameRow {
    /// The row of `frame` (index `index`) with `gpu_allocated_bytes` allocated after it.
    pub fn of(index: usize, frame: &Frame, gpu_allocated_bytes: u64) -> Self {
        let t = frame.timing;
        let mut row = FrameRow {
            frame: index,
            gpu_upload_ms: t.gpu_upload_ms,
            gpu_fixup_ms: t.gpu_fixup_ms,
            gpu_raycast_ms: t.gpu_raycast_ms,
            cpu_frame_ms: t.cpu_frame_ms,
            gpu_allocated_mb: gpu_allocated_bytes as f64 / 1e6,
            ..FrameRow::default()
        };
        if let Some(r) = &frame.residency {
            let p = &r.plan;
            row.plan_ms = r.plan_ms;
            row.uploaded_bricks = r.residency.uploaded_bricks;
            row.uploaded_mb = r.residency.uploaded_bytes as f64 / 1e6;
            row.upload_budget_mb = p.upload_budget as f64 / 1e6;
            row.resident = r.per_level.iter().map(|l| l.drawn).collect();
            row.absent_wanted = p.drawn_absent;
            row.culled = p.culled;
            row.dropped = p.dropped;
            row.waiting = r.waiting;
            row.deferred = p.deferred;
            row.budget_fill = if p.slot_budget == 0 {
                0.0
            } else {
                p.slots_used as f64 / p.slot_budget as f64
            };
            row.cache_mb = r.cache_bytes as f64 / 1e6;
            row.worst_error = p.max_drawn_error;
            row.source_errors = r.source_errors;
        }
        row
    }
}

/// The CSV columns before the residency per level.
const CSV_HEAD: &str = "frame,gpu_upload_ms,gpu_fixup_ms,gpu_raycast_ms,cpu_frame_ms,plan_ms,\
uploaded_bricks,uploaded_mb,upload_budget_mb";

/// The CSV columns after it.
const CSV_TAIL: &str = "absent_wanted,culled,dropped,waiting,deferred,budget_fill,cache_mb,\
gpu_allocated_mb,worst_error,source_errors";

fn opt(v: Option<f64>) -> String {
    v.map(|v| format!("{v:.4}")).unwrap_or_default()
}

/// The rows as CSV text (header first; empty cells where a GPU time was not measured; one
/// `resident_lK` column per level any row draws, 0 where a row draws fewer levels).
pub fn to_csv(rows: &[FrameRow]) -> String {
    let levels = rows
        .iter()
        .map(|r| r.resident.len())
        .max()
        .unwrap_or(0)
        .max(1);
    let mut out = String::from(CSV_HEAD);
    for level in 0..levels {
        out.push_str(&format!(",resident_l{level}"));
    }
    out.push(',');
    out.push_str(CSV_TAIL);
    out.push('\n');
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{:.4},{:.4},{},{:.4},{:.4},",
            r.frame,
            opt(r.gpu_upload_ms),
            opt(r.gpu_fixup_ms),
            opt(r.gpu_raycast_ms),
            r.cpu_frame_ms,
            r.plan_ms,
            r.uploaded_bricks,
            r.uploaded_mb,
            r.upload_budget_mb,
        ));
        for level in 0..levels {
            out.push_str(&format!("{},", r.resident.get(level).copied().unwrap_or(0)));
        }
        out.push_str(&format!(
            "{},{},{},{},{},{:.4},{:.4},{:.4},{:.6},{}\n",
            r.absent_wanted,
            r.culled,
            r.dropped,
            r.waiting,
            r.deferred,
            r.budget_fill,
            r.cache_mb,
            r.gpu_allocated_mb,
            r.worst_error,
            r.source_errors
        ));
    }
    out
}

/// Writes the rows as `csv_path` and, next to it, the same stem with `.json`.
pub fn write_log(csv_path: &Path, rows: &[FrameRow]) -> Result<()> {
    write_text("the frame log", csv_path, &to_csv(rows))?;
    let json_path = csv_path.with_extension("json");
    let json = serde_json::to_string_pretty(rows).map_err(|e| Error::FileWrite {
        what: "the frame log".into(),
        path: json_path.clone(),
        message: e.to_string(),
    })?;
    write_text("the frame log", &json_path, &json)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_rows_have_one_cell_per_header_field() {
        let rows = vec![
            FrameRow {
                frame: 3,
                gpu_raycast_ms: Some(1.5),
                resident: vec![7, 2],
                ..FrameRow::default()
            };
            2
        ];
        let csv = to_csv(&rows);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        let fields = lines[0].split(',').count();
        for line in &lines[1..] {
            assert_eq!(line.split(',').count(), fields, "{line}");
        }
        let cells: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(cells[0], "3");
        assert_eq!(cells[1], "", "an unmeasured GPU time is an empty cell");
        assert_eq!(cells[3], "1.5000");
        assert_eq!(cells[9], "7");
        assert_eq!(
            &lines[0].split(',').collect::<Vec<_>>()[9..11],
            ["resident_l0", "resident_l1"]
        );
    }
}
