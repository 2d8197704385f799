//! The accuracy report's outputs: Markdown, CSV, JSON and the two charts.

use super::{family_colour, Report, ReportError, ReportRow, Result, FAMILIES, REPORT_FILES};
use crate::plot::{Chart, Panel, Series};
use std::path::Path;

/// What the knob rows show and why, for both reports' Markdown (`accuracy-vs-time.md`,
/// `scenes.md`).
pub const KNOB_NOTES: &str = "- *Pre-integration* (Engel et al.) integrates the transfer function exactly between two samples, taking the field as linear between them; point sampling classifies the field at the sample. Samples lie in the middle of their steps, so a run of samples is a half step in front of its first sample, the segments between samples and a half step behind its last (until 2026-12-02 the first sample stood for a whole step and the last half step was lost: a half-step shift that cost every ray entering or leaving non-empty data, so that on 128^3 Marschner-Lobb, whose field is not empty at the box faces, pre-integration scored 1.1-1.5x the point-sampled RMSE; measured on the CPU reference, 64^3, 64x64, 1 sample/voxel: 0.0271 before the fix, 0.0172 after, point sampling 0.0277). Where it should help, a transfer function with features narrower than the field's change per step (Fire on Marschner-Lobb), it now beats point sampling at every step. On the MRI heads with the smooth MRI transfer function it does not: the transfer function is nearly linear over a step there, and what is left is the field's curvature between samples (the trilinear field along a ray is piecewise cubic, voxel-scale detail in MRI data), which the linear-between-samples assumption gets wrong by more than the midpoint rule of point sampling does (trapezoid against midpoint: both errors fall as the step squared, 3.5x and 4.2x from 1 to 2 samples/voxel here); measured on the CPU reference, VolPack head, 1 sample/voxel: 0.0024 pre-integrated against 0.0007 point sampled, and the pre-integrated image converges to the same reference (0.00004 at 8 samples/voxel). An honest property of the method, not a bug. Shaded, on 128^3 Marschner-Lobb it is ahead at 0.5 samples/voxel but behind at 1 (0.95x / 1.19x the point-sampled RMSE; ahead at both in the quick mode's 32^3): the shading takes the gradient at a segment's back sample, half a step off the middle of the segment it shades, where point sampling shades at the middle; shading with the mean of the front and back gradients (both in the ray state) would centre it (a likely cause, not verified; not done yet).\n- *Tricubic* (cubic B-spline) changes the field itself (it smooths: an approximating filter), so its rows are measured against the tricubic field at 8 samples/voxel: the smoother field is approached faster by a coarse step than the trilinear one by the same step, at about 2-4x the cost per sample (lavapipe).\n- *Extinction-based sampling* (Kraus et al.) is per sample exactly the opacity model (`1 - (1 - a)^d = 1 - exp(-tau d)` with `tau = -ln(1 - a)`); the two differ only between the transfer function's table entries and in pre-integration, so their rows agree to 4-5 digits.\n- *Early termination* at opacity t drops what lies behind opacity t: lower thresholds lose more (the baseline, the samples-per-voxel row, runs at the default threshold).\n";

impl Report {
    /// The rows as CSV with a header line.
    pub fn to_csv(&self) -> String {
        let mut out = String::from(
            "family,setting,shaded,frame_ms,rmse,psnr_db,gradient_rmse,ssim,seam_max,seam_mean,jump_max,reference_jump_max,seam_samples,seam_faces,resident_bytes,hi_fraction\n",
        );
        for r in &self.rows {
            out.push_str(&format!(
                "\"{}\",\"{}\",{},{:.4},{:.6},{:.2},{:.6},{:.5},{:.5},{:.6},{:.5},{:.5},{},{},{},{:.3}\n",
                r.family,
                r.setting,
                r.shaded,
                r.frame_ms,
                r.rmse,
                r.psnr_db,
                r.gradient_rmse,
                r.ssim,
                r.seam.max_excess,
                r.seam.mean_excess,
                r.seam.max_jump,
                r.seam.reference_max_jump,
                r.seam.samples,
                r.seam.faces,
                r.resident_bytes,
                r.hi_fraction
            ));
        }
        out
    }

    /// The report as JSON: device, scene and one object per row.
    pub fn to_json(&self) -> serde_json::Value {
        let finite = |v: f64| {
            if v.is_finite() {
                serde_json::json!(v)
            } else {
                serde_json::Value::Null
            }
        };
        serde_json::json!({
            "device": self.device,
            "scene": self.scene,
            "rows": self.rows.iter().map(|r| serde_json::json!({
                "family": r.family,
                "label": r.label,
                "setting": r.setting,
                "shaded": r.shaded,
                "frame_ms": r.frame_ms,
                "rmse": r.rmse,
                "psnr_db": finite(r.psnr_db),
                "gradient_rmse": r.gradient_rmse,
                "ssim": r.ssim,
                "seam": {
                    "faces": r.seam.faces,
                    "samples": r.seam.samples,
                    "max_excess": r.seam.max_excess,
                    "mean_excess": r.seam.mean_excess,
                    "max_jump": r.seam.max_jump,
                    "mean_jump": r.seam.mean_jump,
                    "reference_max_jump": r.seam.reference_max_jump,
                    "reference_mean_jump": r.seam.reference_mean_jump,
                },
                "resident_bytes": r.resident_bytes,
                "hi_fraction": r.hi_fraction,
            })).collect::<Vec<_>>(),
        })
    }

    /// The report as Markdown: scene, device, date line supplied by the caller, and the table.
    pub fn to_markdown(&self, when: &str, command: &str) -> String {
        let mut out = String::from("# Accuracy versus time\n\n");
        out.push_str(&format!(
            "- Scene: {}\n- Device: {}\n- Measured: {when}\n- Regenerate: `{command}`\n",
            self.scene, self.device
        ));
        out.push_str("- Frame time is the median GPU ray-cast time (timestamps). On a CPU device (lavapipe) it is CPU time: compare rows, not absolute numbers.\n");
        out.push_str("- Metrics (`crates/mixvol-experiments/src/metrics/`): RMSE and PSNR of premultiplied RGBA; *grad RMSE*: RMS error of the image's horizontal and vertical finite differences against the reference's; *SSIM*: mean SSIM over 8x8 windows (`image-compare`), 1 = identical; *seam max / mean*: along the projected edges of every face between a hi-res and a low-res brick (every half pixel), each side extrapolated linearly to the line from bilinear samples 0.5 and 1.5 pixels from it, `J` the largest RGBA difference of the two extrapolations (a step of height h scores h, a continuous kink 0), and the seam the excess `max(0, J - J_ref)` over `J_ref` of the full-resolution frame of the same settings (single resolution, 1 sample/voxel, shaded for shaded rows: so what both share is not counted as a seam); *jump max*: the largest `J` of this frame / of the full-resolution frame there. Rows without a level change have no seam lines (0).\n");
        out.push_str(KNOB_NOTES);
        out.push_str("- Transition rows: a close-up of a junction seen edge-on (its own scene, above). A face crossed by the rays at an angle integrates into a continuous image whether or not the field jumps on it, and at about a voxel per pixel the smooth transition's half-voxel ramp is sub-pixel: on the overview the two transitions' seam measures agreed to 0.4% (measured 2026-12-01). Here the rays run along the face, the image's middle column is the seam, and the ramp spans 8 pixels. `mixvol report` draws the close-up as `junction.png`: unshaded (top) and shaded (bottom), smooth, discontinuous and their difference (x4); the low-res half is on the left.\n\n");
        out.push_str("| knob | setting | frame ms | RMSE | PSNR dB | grad RMSE | SSIM | seam max | seam mean | jump max (frame / ref) | resident MB | hi-res fraction |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        for r in &self.rows {
            out.push_str(&format!(
                "| {} | {} | {:.2} | {:.5} | {:.1} | {:.5} | {:.4} | {:.4} | {:.5} | {:.3} / {:.3} | {:.2} | {:.2} |\n",
                r.family,
                r.setting,
                r.frame_ms,
                r.rmse,
                r.psnr_db,
                r.gradient_rmse,
                r.ssim,
                r.seam.max_excess,
                r.seam.mean_excess,
                r.seam.max_jump,
                r.seam.reference_max_jump,
                r.resident_bytes as f64 / 1e6,
                r.hi_fraction
            ));
        }
        out.push_str("\nSmooth against discontinuous at the same residency (discontinuous / smooth):\n\n| rows | RMSE | grad RMSE | seam max | seam mean | frame time |\n|---|---|---|---|---|---|\n");
        for family in [FAMILIES[1], FAMILIES[2]] {
            if let (Some(s), Some(d)) = (
                self.row(family, "Smooth"),
                self.row(family, "Discontinuous"),
            ) {
                let ratio = |a: f64, b: f64| {
                    if b > 0.0 {
                        format!("{:.3}", a / b)
                    } else {
                        "-".into()
                    }
                };
                out.push_str(&format!(
                    "| {family} | {} | {} | {} | {} | {} |\n",
                    ratio(d.rmse, s.rmse),
                    ratio(d.gradient_rmse, s.gradient_rmse),
                    ratio(d.seam.max_excess, s.seam.max_excess),
                    ratio(d.seam.mean_excess, s.seam.mean_excess),
                    ratio(d.frame_ms, s.frame_ms)
                ));
            }
        }
        out.push_str("\nA ratio far above 1 is the seam the smooth transition removes; RMSE and SSIM barely see it (one column of the image).\n");
        out.push_str("\nEach knob against its baseline, the same row without the knob (knob / baseline; RMSE below 1: closer to the reference):\n\n| knob | setting | baseline | RMSE | grad RMSE | frame time |\n|---|---|---|---|---|---|\n");
        for r in &self.rows {
            let Some(b) = self.baseline(r) else { continue };
            out.push_str(&format!(
                "| {} | {} | {} | {:.3} | {:.3} | {:.3} |\n",
                r.family,
                r.setting,
                b.setting,
                r.rmse / b.rmse,
                r.gradient_rmse / b.gradient_rmse,
                r.frame_ms / b.frame_ms
            ));
        }
        out.push_str("\nCharts (PNG and SVG): `accuracy-vs-time`: RMSE against frame time, unshaded rows (left) and shaded rows (right), log scale (gradient RMSE and SSIM are in the table); `seams-vs-time`: the seam measure's max (left) and mean (right) against frame time, for the knobs with a level change. One line per knob joining its settings, each point labelled with its setting.\n");
        out
    }

    /// One series per family; with `seams_only`, only the families with seam lines (a level
    /// change somewhere), the others being 0 on the seam chart; with `shaded`, only the shaded
    /// (`Some(true)`) or unshaded families.
    fn series(
        &self,
        y: impl Fn(&ReportRow) -> f64,
        seams_only: bool,
        shaded: Option<bool>,
    ) -> Vec<Series> {
        let has_seams = |f: &str| self.rows.iter().any(|r| r.family == f && r.seam.faces > 0);
        family_series(
            &self.rows,
            |f| {
                shaded.is_none_or(|lit| f.ends_with("shaded") == lit)
                    && (!seams_only || has_seams(f))
            },
            |r| r.family,
            |r| (r.frame_ms, y(r)),
            |r| r.label.clone(),
        )
    }

    /// The two charts: `accuracy-vs-time` (RMSE and gradient RMSE against frame time) and
    /// `seams-vs-time` (the seam measure against frame time), one line per knob.
    pub fn charts(&self) -> [(&'static str, Chart); 2] {
        let x = "frame time (ms, median)".to_string();
        let panel = |title: &str,
                     y_label: &str,
                     y: &dyn Fn(&ReportRow) -> f64,
                     seams: bool,
                     shaded: Option<bool>| Panel {
            title: title.into(),
            x_label: x.clone(),
            y_label: y_label.into(),
            y_range: None,
            series: self.series(y, seams, shaded),
            legend_left: false,
            log_y: true,
        };
        [
            (
                "accuracy-vs-time",
                Chart {
                    title: "Error against the 8 samples/voxel reference vs frame time".into(),
                    panels: vec![
                        panel(
                            "Unshaded rows",
                            "RMSE of premultiplied RGBA (0-1, log scale)",
                            &|r| r.rmse,
                            false,
                            Some(false),
                        ),
                        panel(
                            "Shaded rows (Blinn-Phong)",
                            "RMSE of premultiplied RGBA (0-1, log scale)",
                            &|r| r.rmse,
                            false,
                            Some(true),
                        ),
                    ],
                    panel_size: (560, 420),
                },
            ),
            (
                "seams-vs-time",
                seams_chart(
                    "Seams at level changes vs frame time".into(),
                    &x,
                    self.series(|r| r.seam.max_excess, true, None),
                    self.series(|r| r.seam.mean_excess, true, None),
                ),
            ),
        ]
    }

    /// Writes [`REPORT_FILES`] into `dir` (created if missing); `when` and `command` go into
    /// the Markdown.
    pub fn write(&self, dir: &Path, when: &str, command: &str) -> Result<()> {
        let io = |path: &Path, e: &dyn std::fmt::Display| ReportError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        std::fs::create_dir_all(dir).map_err(|e| io(dir, &e))?;
        for (name, text) in [
            (REPORT_FILES[0], self.to_markdown(when, command)),
            (REPORT_FILES[1], self.to_csv()),
            (REPORT_FILES[2], format!("{:#}\n", self.to_json())),
        ] {
            let path = dir.join(name);
            mixvol::output::write_file_atomically(&path, text.as_bytes())
                .map_err(|e| io(&path, &e))?;
        }
        for (stem, chart) in self.charts() {
            chart.write(dir, stem)?;
        }
        Ok(())
    }
}

/// One series per knob of [`FAMILIES`] (in that order) that `keep` accepts and `rows` has rows
/// of: its rows' points joined in row order, each labelled with its setting, in the knob's
/// colour, dashed for shaded knobs; shared by the single-scene and the orbit report's charts.
pub(crate) fn family_series<R>(
    rows: &[R],
    keep: impl Fn(&str) -> bool,
    family: impl Fn(&R) -> &str,
    point: impl Fn(&R) -> (f64, f64),
    label: impl Fn(&R) -> String,
) -> Vec<Series> {
    FAMILIES
        .iter()
        .filter(|f| keep(f))
        .map(|f| {
            let mine: Vec<&R> = rows.iter().filter(|r| family(r) == *f).collect();
            Series {
                name: (*f).to_string(),
                colour: family_colour(f),
                dashed: f.ends_with("shaded"),
                points: mine.iter().map(|r| point(r)).collect(),
                labels: mine.iter().map(|r| label(r)).collect(),
            }
        })
        .filter(|s| !s.points.is_empty())
        .collect()
}

/// The seam chart of both reports: the seam measure's max (left) and mean (right) along the
/// seam lines against frame time (x axis titled `x_label`), log scale, `max` and `mean` the
/// series of the two panels.
pub(crate) fn seams_chart(
    title: String,
    x_label: &str,
    max: Vec<Series>,
    mean: Vec<Series>,
) -> Chart {
    let panel = |title: &str, y_label: &str, series: Vec<Series>| Panel {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        y_range: None,
        series,
        legend_left: false,
        log_y: true,
    };
    Chart {
        title,
        panels: vec![
            panel(
                "Largest excess jump",
                "max(0, J - J_ref), max along seam lines (0-1, log)",
                max,
            ),
            panel(
                "Mean excess jump",
                "max(0, J - J_ref), mean along seam lines (0-1, log)",
                mean,
            ),
        ],
        panel_size: (560, 420),
    }
}
