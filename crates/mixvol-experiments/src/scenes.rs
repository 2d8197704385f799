//! The accuracy report over several scenes, each seen from an orbit of views: the rows of
//! [`crate::accuracy`] (without the transition rows, which need their edge-on close-up and are
//! measured once there) per view, summarised per setting as the mean and the worst over the
//! views, and the transition rows once per scene on a close-up of a junction cut into the
//! scene's own volume ([`JunctionScene::in_volume`]; one view, so mean = worst). Written as
//! `scenes.md`, `scenes.csv`, `scenes.json` and per scene a chart `scene-NAME.{png,svg}` of the
//! mean RMSE over the views against the mean frame time, unshaded rows (left) and shaded rows
//! (right), log scale, one line per knob, and a chart `scene-NAME-seams.{png,svg}` of the seam
//! measure (max and mean along the seam lines, mean over the views) against the mean frame
//! time, one line per knob with seams. [`summaries_from_json`] reads `scenes.json` back, so
//! that the charts can be redrawn without measuring again.

use crate::accuracy::{
    accuracy_report, family_series, report_camera, seams_chart, transition_rows, Report,
    ReportError, ReportOptions, ReportRow, Result, FAMILIES,
};
use crate::junction::JunctionScene;
use crate::plot::{Chart, Panel};
use glam::{Quat, Vec3};
use mixvol::gpu::GpuContext;
use mixvol::optics::TransferFunction;
use mixvol::scene::Camera;
use mixvol::volume::Volume;
use std::path::Path;
use std::sync::Arc;

/// One scene of the orbit: a volume and the transfer function it is seen through.
#[derive(Clone, Debug)]
pub struct OrbitScene {
    /// Short name (file names: `scene-NAME.png`), lower case, no spaces.
    pub name: String,
    /// What it is, in words.
    pub description: String,
    /// The volume.
    pub volume: Arc<Volume>,
    /// Its transfer function.
    pub tf: TransferFunction,
    /// The close-up of the transition rows; `None` leaves them out.
    pub junction: Option<JunctionScene>,
}

/// `views` cameras around the volume: the report's camera turned about the vertical axis in
/// equal steps (the first is [`report_camera`]).
pub fn orbit_cameras(views: u32) -> Vec<Camera> {
    let base = report_camera();
    (0..views.max(1))
        .map(|k| {
            let turn =
                Quat::from_rotation_y(std::f32::consts::TAU * k as f32 / views.max(1) as f32);
            Camera {
                eye: turn * base.eye,
                target: Vec3::ZERO,
                ..base
            }
        })
        .collect()
}

/// One setting summarised over the views.
#[derive(Clone, Debug, PartialEq)]
pub struct OrbitRow {
    /// The knob (as in [`crate::accuracy::ReportRow::family`]).
    pub family: &'static str,
    /// The setting in a word or two.
    pub label: String,
    /// The setting, in words.
    pub setting: String,
    /// Mean frame time over the views, ms.
    pub frame_ms_mean: f64,
    /// Mean and largest RMSE over the views.
    pub rmse: (f64, f64),
    /// Mean and largest gradient RMSE over the views.
    pub gradient_rmse: (f64, f64),
    /// Mean and smallest SSIM over the views.
    pub ssim: (f64, f64),
    /// Mean and largest seam max over the views.
    pub seam_max: (f64, f64),
    /// Mean and largest seam mean over the views.
    pub seam_mean: (f64, f64),
}

/// The orbit report of one scene.
#[derive(Clone, Debug)]
pub struct SceneSummary {
    /// The scene's name.
    pub name: String,
    /// The scene line of its first view's report (volume, image, bricks).
    pub description: String,
    /// Views rendered.
    pub views: usize,
    /// One row per setting.
    pub rows: Vec<OrbitRow>,
}

/// Renders every scene from `views` orbit cameras with `options` (its camera and junction are
/// replaced) and summarises each setting over the views.
pub fn orbit_report(
    ctx: &GpuContext,
    scenes: &[OrbitScene],
    options: &ReportOptions,
    views: u32,
) -> Result<Vec<SceneSummary>> {
    scenes
        .iter()
        .map(|scene| {
            let reports = view_reports(ctx, scene, options, views)?;
            let mut summary = summarise(&scene.name, &reports);
            if let Some(j) = &scene.junction {
                let rows = transition_rows(ctx, &scene.tf, j, options.frames)?;
                summary.rows.extend(rows.iter().map(|r| summarise_rows(&[r])));
                summary.description.push_str(&format!(
                    "; transition rows (one view): orthographic close-up of the face between brick columns {} and {} in x seen edge-on, bricks {}^3 below it low-res, {}x{} image over {} voxels",
                    j.volume()?.dims().x.div_ceil(j.brick_size) / 2 - 1,
                    j.volume()?.dims().x.div_ceil(j.brick_size) / 2,
                    j.brick_size, j.size, j.size, j.width_voxels
                ));
            }
            Ok(summary)
        })
        .collect()
}

/// The report of `scene` from each of `views` orbit cameras ([`orbit_cameras`]), without the
/// transition rows.
pub fn view_reports(
    ctx: &GpuContext,
    scene: &OrbitScene,
    options: &ReportOptions,
    views: u32,
) -> Result<Vec<Report>> {
    orbit_cameras(views)
        .into_iter()
        .map(|camera| {
            let opts = ReportOptions {
                camera,
                junction: None,
                volume_name: scene.description.clone(),
                ..options.clone()
            };
            accuracy_report(ctx, scene.volume.clone(), &scene.tf, &opts)
        })
        .collect()
}

/// The mean and the worst over `reports` (one per view) of every row of the first, matched by
/// family and setting; an empty summary without reports.
pub fn summarise(name: &str, reports: &[Report]) -> SceneSummary {
    let Some(first) = reports.first() else {
        return SceneSummary {
            name: name.into(),
            description: String::new(),
            views: 0,
            rows: Vec::new(),
        };
    };
    let rows = first
        .rows
        .iter()
        .map(|row| {
            // The same setting in every view's report (a report lacking it is left out).
            let all: Vec<_> = reports
                .iter()
                .filter_map(|r| {
                    r.rows
                        .iter()
                        .find(|x| x.family == row.family && x.setting == row.setting)
                })
                .collect();
            summarise_rows(&all)
        })
        .collect();
    SceneSummary {
        name: name.into(),
        description: first.scene.replace(", one camera", ""),
        views: reports.len(),
        rows,
    }
}

/// One setting's rows (one per view, at least one) as their mean and worst.
fn summarise_rows(all: &[&ReportRow]) -> OrbitRow {
    let n = all.len() as f64;
    let mean = |f: &dyn Fn(&ReportRow) -> f64| all.iter().map(|r| f(r)).sum::<f64>() / n;
    let max =
        |f: &dyn Fn(&ReportRow) -> f64| all.iter().map(|r| f(r)).fold(f64::NEG_INFINITY, f64::max);
    let min =
        |f: &dyn Fn(&ReportRow) -> f64| all.iter().map(|r| f(r)).fold(f64::INFINITY, f64::min);
    OrbitRow {
        family: all[0].family,
        label: all[0].label.clone(),
        setting: all[0].setting.clone(),
        frame_ms_mean: mean(&|r| r.frame_ms),
        rmse: (mean(&|r| r.rmse), max(&|r| r.rmse)),
        gradient_rmse: (mean(&|r| r.gradient_rmse), max(&|r| r.gradient_rmse)),
        ssim: (mean(&|r| r.ssim), min(&|r| r.ssim)),
        seam_max: (mean(&|r| r.seam.max_excess), max(&|r| r.seam.max_excess)),
        seam_mean: (mean(&|r| r.seam.mean_excess), max(&|r| r.seam.mean_excess)),
    }
}

/// The files [`write()`] writes besides one chart per scene.
pub const SCENE_FILES: [&str; 3] = ["scenes.md", "scenes.csv", "scenes.json"];

/// The summaries as Markdown (`when` and `command` go into the header).
pub fn to_markdown(summaries: &[SceneSummary], when: &str, command: &str) -> String {
    let mut out = String::from("# Accuracy versus time over scenes and views\n\n");
    out.push_str(&format!(
        "- Measured: {when}\n- Regenerate: `{command}`\n- Every scene is rendered from an orbit of views (the report's camera turned about the vertical axis in equal steps); each cell is the mean over the views and, after the slash, the worst (largest error, smallest SSIM); the transition rows are measured once per scene on a close-up of a junction in the scene's own volume (below). Metrics and rows as in `accuracy-vs-time.md`. Frame time is CPU time on lavapipe: compare rows, not absolute numbers.\n- Charts per scene (PNG and SVG): `scene-NAME`: mean RMSE over the views against mean frame time, unshaded rows (left) and shaded rows (right, dashed), log scale (the transition rows are left out); `scene-NAME-seams`: the seam measure `max(0, J - J_ref)`, its max (left) and mean (right) along the seam lines, each the mean over the views, against mean frame time, log scale, one line per knob with a non-zero seam figure, shaded knobs dashed; the transition rows' frame time is that of their 128x128 close-up, not comparable with the other rows'. One line per knob joining its settings, each point labelled with its setting.\n"
    ));
    out.push_str(crate::accuracy::KNOB_NOTES);
    for s in summaries {
        out.push_str(&format!(
            "\n## {}\n\n- {} views; {}\n- Charts: `scene-{}.png` / `.svg` (error), `scene-{}-seams.png` / `.svg` (seams)\n\n| knob | setting | frame ms (mean) | RMSE mean / worst | grad RMSE mean / worst | SSIM mean / worst | seam max mean / worst | seam mean mean / worst |\n|---|---|---|---|---|---|---|---|\n",
            s.name, s.views, s.description, s.name, s.name
        ));
        for r in &s.rows {
            out.push_str(&format!(
                "| {} | {} | {:.2} | {:.5} / {:.5} | {:.5} / {:.5} | {:.4} / {:.4} | {:.4} / {:.4} | {:.5} / {:.5} |\n",
                r.family, r.setting, r.frame_ms_mean, r.rmse.0, r.rmse.1, r.gradient_rmse.0,
                r.gradient_rmse.1, r.ssim.0, r.ssim.1, r.seam_max.0, r.seam_max.1,
                r.seam_mean.0, r.seam_mean.1
            ));
        }
    }
    out
}

/// The summaries as CSV with a header line.
pub fn to_csv(summaries: &[SceneSummary]) -> String {
    let mut out = String::from("scene,views,family,setting,frame_ms_mean,rmse_mean,rmse_worst,gradient_rmse_mean,gradient_rmse_worst,ssim_mean,ssim_worst,seam_max_mean,seam_max_worst,seam_mean_mean,seam_mean_worst\n");
    for s in summaries {
        for r in &s.rows {
            out.push_str(&format!(
                "{},{},\"{}\",\"{}\",{:.4},{:.6},{:.6},{:.6},{:.6},{:.5},{:.5},{:.5},{:.5},{:.6},{:.6}\n",
                s.name,
                s.views,
                r.family,
                r.setting,
                r.frame_ms_mean,
                r.rmse.0,
                r.rmse.1,
                r.gradient_rmse.0,
                r.gradient_rmse.1,
                r.ssim.0,
                r.ssim.1,
                r.seam_max.0,
                r.seam_max.1,
                r.seam_mean.0,
                r.seam_mean.1
            ));
        }
    }
    out
}

/// The summaries as JSON: one object per scene with its rows.
pub fn to_json(summaries: &[SceneSummary]) -> serde_json::Value {
    let pair = |p: (f64, f64)| serde_json::json!({ "mean": p.0, "worst": p.1 });
    serde_json::Value::Array(
        summaries
            .iter()
            .map(|s| {
                serde_json::json!({
                    "scene": s.name,
                    "description": s.description,
                    "views": s.views,
                    "rows": s.rows.iter().map(|r| serde_json::json!({
                        "family": r.family,
                        "label": r.label,
                        "setting": r.setting,
                        "frame_ms_mean": r.frame_ms_mean,
                        "rmse": pair(r.rmse),
                        "gradient_rmse": pair(r.gradient_rmse),
                        "ssim": pair(r.ssim),
                        "seam_max": pair(r.seam_max),
                        "seam_mean": pair(r.seam_mean),
                    })).collect::<Vec<_>>(),
                })
            })
            .collect(),
    )
}

/// The chart of one scene: mean RMSE over the views against mean frame time, unshaded rows
/// (left) and shaded rows (right), log scale (the transition rows, one view, are left out:
/// their seams are in the table).
pub fn chart(s: &SceneSummary) -> Chart {
    let series = |shaded: bool| {
        family_series(
            &s.rows,
            |f| f.ends_with("shaded") == shaded && f != FAMILIES[1] && f != FAMILIES[2],
            |r| r.family,
            |r| (r.frame_ms_mean, r.rmse.0),
            |r| r.label.clone(),
        )
    };
    let panel = |title: &str, shaded: bool| Panel {
        title: title.into(),
        x_label: "frame time (ms, mean over views)".into(),
        y_label: "RMSE of premultiplied RGBA (0-1, log scale)".into(),
        y_range: None,
        series: series(shaded),
        legend_left: false,
        log_y: true,
    };
    Chart {
        title: format!(
            "{}: mean error vs frame time over {} views",
            s.name, s.views
        ),
        panels: vec![
            panel("Unshaded rows", false),
            panel("Shaded rows (Blinn-Phong)", true),
        ],
        panel_size: (560, 460),
    }
}

/// The seam chart of one scene: the seam measure's max (left) and mean (right) along the seam
/// lines, each the mean over the views, against the mean frame time, log scale, one line per
/// knob with a non-zero seam figure (LOD budget, downsampling filter, coarse low-res steps and
/// the transition rows, whose frame time is that of their close-up), shaded knobs dashed.
pub fn seam_chart(s: &SceneSummary) -> Chart {
    let has_seams = |f: &str| {
        s.rows
            .iter()
            .any(|r| r.family == f && (r.seam_max.0 > 0.0 || r.seam_mean.0 > 0.0))
    };
    let series = |y: &dyn Fn(&OrbitRow) -> f64| {
        family_series(
            &s.rows,
            has_seams,
            |r| r.family,
            |r| (r.frame_ms_mean, y(r)),
            |r| r.label.clone(),
        )
    };
    seams_chart(
        format!(
            "{}: seams at level changes vs frame time, mean over {} views",
            s.name, s.views
        ),
        "frame time (ms, mean over views)",
        series(&|r| r.seam_max.0),
        series(&|r| r.seam_mean.0),
    )
}

/// The summaries [`to_json`] wrote, read back from its JSON (`path` names the file in errors).
pub fn summaries_from_json(json: &serde_json::Value, path: &Path) -> Result<Vec<SceneSummary>> {
    let bad = |what: String| ReportError::Read {
        path: path.to_path_buf(),
        message: what,
    };
    let text = |v: &serde_json::Value, key: &str| {
        v.get(key)
            .and_then(|x| x.as_str())
            .map(str::to_string)
            .ok_or_else(|| bad(format!("expected a string `{key}` in {v}")))
    };
    let number = |v: &serde_json::Value, key: &str| {
        v.get(key)
            .and_then(|x| x.as_f64())
            .ok_or_else(|| bad(format!("expected a number `{key}` in {v}")))
    };
    let pair = |v: &serde_json::Value, key: &str| -> Result<(f64, f64)> {
        let p = v
            .get(key)
            .ok_or_else(|| bad(format!("expected an object `{key}` in {v}")))?;
        Ok((number(p, "mean")?, number(p, "worst")?))
    };
    json.as_array()
        .ok_or_else(|| bad("expected an array of scenes".into()))?
        .iter()
        .map(|scene| {
            let rows = scene
                .get("rows")
                .and_then(|r| r.as_array())
                .ok_or_else(|| bad(format!("expected an array `rows` in scene {scene}")))?
                .iter()
                .map(|r| {
                    let family = text(r, "family")?;
                    Ok(OrbitRow {
                        family: FAMILIES
                            .iter()
                            .find(|f| **f == family)
                            .ok_or_else(|| bad(format!("unknown knob `{family}`")))?,
                        label: text(r, "label")?,
                        setting: text(r, "setting")?,
                        frame_ms_mean: number(r, "frame_ms_mean")?,
                        rmse: pair(r, "rmse")?,
                        gradient_rmse: pair(r, "gradient_rmse")?,
                        ssim: pair(r, "ssim")?,
                        seam_max: pair(r, "seam_max")?,
                        seam_mean: pair(r, "seam_mean")?,
                    })
                })
                .collect::<Result<Vec<_>>>()?;
            Ok(SceneSummary {
                name: text(scene, "scene")?,
                description: text(scene, "description")?,
                views: scene
                    .get("views")
                    .and_then(|v| v.as_u64())
                    .ok_or_else(|| bad(format!("expected a count `views` in scene {scene}")))?
                    as usize,
                rows,
            })
        })
        .collect()
}

/// Writes `scene-NAME.{png,svg}` and `scene-NAME-seams.{png,svg}` per scene into `dir`.
pub fn write_charts(summaries: &[SceneSummary], dir: &Path) -> Result<()> {
    for s in summaries {
        chart(s).write(dir, &format!("scene-{}", s.name))?;
        seam_chart(s).write(dir, &format!("scene-{}-seams", s.name))?;
    }
    Ok(())
}

/// Writes [`SCENE_FILES`] and the charts of [`write_charts`] into `dir`.
pub fn write(summaries: &[SceneSummary], dir: &Path, when: &str, command: &str) -> Result<()> {
    let io = |path: &Path, e: &dyn std::fmt::Display| ReportError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, &e))?;
    for (name, text) in [
        (SCENE_FILES[0], to_markdown(summaries, when, command)),
        (SCENE_FILES[1], to_csv(summaries)),
        (SCENE_FILES[2], format!("{:#}\n", to_json(summaries))),
    ] {
        let path = dir.join(name);
        mixvol::output::write_file_atomically(&path, text.as_bytes()).map_err(|e| io(&path, &e))?;
    }
    write_charts(summaries, dir)
}
