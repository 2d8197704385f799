//! The accuracy-versus-time report: renders one scene under the settings that trade accuracy for
//! time, each against a high-quality reference render (full resolution, 8 samples per voxel,
//! shaded when the row is), and records GPU frame time, cache memory and the image metrics of
//! [`crate::metrics`]: RMSE and PSNR, the gradient error, SSIM and the seam measure (the image
//! jump across the projected faces where the brick level changes, beyond the jump of the
//! full-resolution frame at the row's own settings there: against the 8 samples/voxel reference
//! the 1 sample/voxel wood-grain would count as seams; measured in quick mode, the
//! single-resolution 1 sample/voxel frame then scores a seam max of 0.49 on the same lines, the
//! mixed rows 0.54).
//!
//! Rows: samples per voxel (single resolution), smooth against discontinuous transitions at the
//! same residency (half the bricks hi-res) unshaded and shaded (shading amplifies seams, Beyer et
//! al. Fig. 8), and the LOD budget. Written as Markdown, CSV and JSON, with two charts (PNG and
//! SVG): error against frame time, and the seam measure against frame time, one line per knob.
//! Other knobs (filters, extinction, pre-integration, tricubic, coarse sampling, early
//! termination) and real-data scenes are not measured yet.

use crate::metrics::gradient::gradient_rmse;
use crate::metrics::pixel::{psnr, rmse};
use crate::metrics::seam::{seam_lines, seam_measure, SeamLines, SeamMeasure};
use crate::metrics::ssim::ssim;
use crate::metrics::{Frame, MetricError};
use crate::plot::{Chart, Panel, PlotError, Series, PALETTE};
use glam::{Vec3, Vec4};
use mixvol::bricks::Level;
use mixvol::bricks::{brick_value_ranges, BrickGrid, DownsampleFilter};
use mixvol::embed::MixedConfig;
use mixvol::gpu::GpuContext;
use mixvol::lod::{
    cull_bricks, select_levels, BrickGeometry, CullParams, LodView, SelectionOptions, TfCullTable,
    ValueCulling,
};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, ClipPlanes, RenderSettings, Shading, Transition};
use mixvol::volume::Volume;
use std::path::Path;
use std::sync::Arc;
use thiserror::Error;

/// Why the report failed.
#[derive(Debug, Error)]
pub enum ReportError {
    /// Rendering, level selection or volume handling failed.
    #[error(transparent)]
    Render(#[from] mixvol::Error),
    /// The brick grid refused its input.
    #[error(transparent)]
    Brick(#[from] mixvol::bricks::BrickError),
    /// The LOD selection refused its input.
    #[error(transparent)]
    Lod(#[from] mixvol::lod::LodError),
    /// A metric could not be computed.
    #[error(transparent)]
    Metric(#[from] MetricError),
    /// A chart could not be drawn or written.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// Writing a report file failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// The report's result type.
pub type Result<T> = std::result::Result<T, ReportError>;

/// Edge of the cubic volume of the quick report ([`ReportOptions::quick`]).
pub const QUICK_VOLUME_SIZE: u32 = 32;

/// The camera of the report: perspective, 35 degrees, from the front-right-top.
pub fn report_camera() -> Camera {
    Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0)
}

/// What the report renders.
#[derive(Clone, Debug)]
pub struct ReportOptions {
    /// Image width and height in pixels.
    pub size: u32,
    /// Timed frames per setting (the median is reported), after one warm-up.
    pub frames: u32,
    /// Brick size of the mixed-resolution settings.
    pub brick_size: u32,
    /// The camera.
    pub camera: Camera,
}

impl ReportOptions {
    /// The quick report, fast enough for the test suite on lavapipe: a 48 x 48 image of a
    /// [`QUICK_VOLUME_SIZE`]^3 volume in bricks of 8, one timed frame per row.
    pub fn quick() -> Self {
        Self {
            size: 48,
            frames: 1,
            brick_size: 8,
            camera: report_camera(),
        }
    }
}

/// One setting's measurements.
#[derive(Clone, Debug, PartialEq)]
pub struct ReportRow {
    /// Which knob this row turns (`samples per voxel`, `transition`, `transition, shaded`,
    /// `LOD budget`).
    pub family: &'static str,
    /// The setting in a word or two (the chart's point label).
    pub label: String,
    /// The setting, in words.
    pub setting: String,
    /// Blinn-Phong shading on (this row and its reference).
    pub shaded: bool,
    /// Median GPU ray-cast time in milliseconds (CPU frame time where the queue has no
    /// timestamps).
    pub frame_ms: f64,
    /// Root-mean-square error of premultiplied RGBA against the reference, in [0, 1].
    pub rmse: f64,
    /// Peak signal-to-noise ratio in dB (infinite for an exact match).
    pub psnr_db: f64,
    /// RMS error of the image's finite differences against the reference's.
    pub gradient_rmse: f64,
    /// Mean SSIM against the reference (1 = identical).
    pub ssim: f64,
    /// The seam measure along the projected edges of the Hi/Lo brick faces, against the
    /// full-resolution frame of the same settings (all zero for rows without a level change).
    pub seam: SeamMeasure,
    /// Bytes of volume data resident on the GPU (texture, or resident bricks in the cache).
    pub resident_bytes: u64,
    /// Fraction of active bricks at full resolution (1 for single-resolution rows).
    pub hi_fraction: f64,
}

/// The whole report.
#[derive(Clone, Debug)]
pub struct Report {
    /// Device name and type.
    pub device: String,
    /// Scene description.
    pub scene: String,
    /// The rows.
    pub rows: Vec<ReportRow>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn timed(
    renderer: &mut Renderer,
    options: &ReportOptions,
    settings: &RenderSettings,
) -> Result<(f64, Vec<Vec4>)> {
    renderer.render(&options.camera, settings, options.size, options.size)?;
    let mut times = Vec::new();
    let mut last = Vec::new();
    for _ in 0..options.frames.max(1) {
        let frame = renderer.render(&options.camera, settings, options.size, options.size)?;
        times.push(
            frame
                .timing
                .gpu_raycast_ms
                .unwrap_or(frame.timing.cpu_frame_ms),
        );
        last = frame.pixels;
    }
    Ok((median(times), last))
}

/// Levels that keep `fraction` of the active bricks at full resolution, chosen by the LOD
/// selector (largest screen-space error first); culled bricks are absent.
pub fn levels_for_fraction(
    volume: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    camera: &Camera,
    size: u32,
    fraction: f64,
) -> Result<Vec<Level>> {
    let ranges = brick_value_ranges(volume, grid, DownsampleFilter::Mean2)?;
    let geometry = BrickGeometry::new(*grid, volume.spacing())?;
    let window = if volume.scalar_type() == mixvol::volume::ScalarType::F32 {
        volume.value_range()
    } else {
        (0.0, 1.0)
    };
    let params = CullParams {
        value: ValueCulling::TransferFunction(TfCullTable::new(tf, window)?),
        clip: ClipPlanes::NONE,
    };
    let active = cull_bricks(&geometry, &ranges, &params)?;
    let count = active.iter().filter(|a| **a).count();
    let hi = ((count as f64) * fraction.clamp(0.0, 1.0)).round() as usize;
    let slots = hi + (count - hi).div_ceil(8);
    let view = LodView::new(camera, size, size)?;
    Ok(select_levels(
        &geometry,
        &view,
        &ranges,
        &active,
        &SelectionOptions {
            slots: slots.max(1),
            distance_filter: None,
            fov_filter: None,
        },
    )?)
}

/// The families of the report in chart order, with their colours.
pub const FAMILIES: [&str; 4] = [
    "samples per voxel",
    "transition",
    "transition, shaded",
    "LOD budget",
];

/// The image metrics of one frame.
struct Metrics {
    rmse: f64,
    gradient_rmse: f64,
    ssim: f64,
    seam: SeamMeasure,
}

/// The seam measure's inputs: the frame of the same settings at full resolution, and the lines.
struct SeamInput<'a> {
    full_resolution: &'a [Vec4],
    lines: &'a SeamLines,
}

fn metrics(
    size: u32,
    pixels: &[Vec4],
    reference: &[Vec4],
    seam: Option<SeamInput<'_>>,
) -> Result<Metrics> {
    let image = Frame::new(size, size, pixels)?;
    let reference = Frame::new(size, size, reference)?;
    let seam = match seam {
        Some(s) => seam_measure(&image, &Frame::new(size, size, s.full_resolution)?, s.lines)?,
        None => SeamMeasure::default(),
    };
    Ok(Metrics {
        rmse: rmse(&image, &reference)?,
        gradient_rmse: gradient_rmse(&image, &reference)?,
        ssim: ssim(&image, &reference)?,
        seam,
    })
}

/// A mixed-resolution row's setting.
struct MixedSetting {
    family: &'static str,
    label: String,
    setting: String,
    fraction: f64,
    transition: Transition,
    shaded: bool,
}

/// Renders the report for `volume` seen through `tf`.
pub fn accuracy_report(
    ctx: &GpuContext,
    volume: Arc<Volume>,
    tf: &TransferFunction,
    options: &ReportOptions,
) -> Result<Report> {
    let size = options.size;
    let plain = RenderSettings::default();
    let lit = RenderSettings {
        shading: Some(Shading::default()),
        ..RenderSettings::default()
    };
    let mut single = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
    single.set_transfer_function(tf)?;
    single.set_source(VolumeSource::Volume(&volume))?;
    let mut render_at = |settings: &RenderSettings, spv: f32| -> Result<Vec<Vec4>> {
        let settings = RenderSettings {
            samples_per_voxel: spv,
            ..*settings
        };
        Ok(single
            .render(&options.camera, &settings, size, size)?
            .pixels)
    };
    let reference_plain = render_at(&plain, 8.0)?;
    let reference_lit = render_at(&lit, 8.0)?;
    // The seam measure's full-resolution frames: the mixed rows' own settings, one texture.
    let full_plain = render_at(&plain, 1.0)?;
    let full_lit = render_at(&lit, 1.0)?;
    let grid = BrickGrid::new(volume.dims(), options.brick_size)?;
    let geometry = BrickGeometry::new(grid, volume.spacing())?;
    let volume_bytes = volume.data().as_bytes().len() as u64;
    let mut rows = Vec::new();
    for spv in [0.5f32, 1.0, 2.0, 4.0] {
        let settings = RenderSettings {
            samples_per_voxel: spv,
            ..plain
        };
        let (ms, pixels) = timed(&mut single, options, &settings)?;
        let m = metrics(size, &pixels, &reference_plain, None)?;
        rows.push(ReportRow {
            family: FAMILIES[0],
            label: format!("{spv}"),
            setting: format!("{spv} samples/voxel, single resolution"),
            shaded: false,
            frame_ms: ms,
            rmse: m.rmse,
            psnr_db: psnr(m.rmse),
            gradient_rmse: m.gradient_rmse,
            ssim: m.ssim,
            seam: m.seam,
            resident_bytes: volume_bytes,
            hi_fraction: 1.0,
        });
    }
    drop(single);
    let n = options.brick_size as u64;
    let texel = volume.scalar_type().size_bytes() as u64;
    let mixed_row = |s: MixedSetting| -> Result<ReportRow> {
        let levels = levels_for_fraction(&volume, &grid, tf, &options.camera, size, s.fraction)?;
        let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
        renderer.set_transfer_function(tf)?;
        renderer.set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config: MixedConfig {
                brick_size: options.brick_size,
                transition: s.transition,
                ..MixedConfig::default()
            },
        })?;
        let report = renderer.set_levels(&levels)?;
        let settings = if s.shaded { lit } else { plain };
        let (ms, pixels) = timed(&mut renderer, options, &settings)?;
        let lines = seam_lines(&geometry, &levels, &options.camera, size, size)?;
        let (reference, full_resolution) = if s.shaded {
            (&reference_lit, &full_lit)
        } else {
            (&reference_plain, &full_plain)
        };
        let seam = SeamInput {
            full_resolution,
            lines: &lines,
        };
        let m = metrics(size, &pixels, reference, Some(seam))?;
        let active = report.hi_bricks + report.lo_bricks;
        Ok(ReportRow {
            family: s.family,
            label: s.label,
            setting: s.setting,
            shaded: s.shaded,
            frame_ms: ms,
            rmse: m.rmse,
            psnr_db: psnr(m.rmse),
            gradient_rmse: m.gradient_rmse,
            ssim: m.ssim,
            seam: m.seam,
            resident_bytes: report.hi_bricks as u64 * (n + 2).pow(3) * texel
                + report.lo_bricks as u64 * (n / 2 + 1).pow(3) * texel,
            hi_fraction: if active == 0 {
                0.0
            } else {
                report.hi_bricks as f64 / active as f64
            },
        })
    };
    for (family, shaded) in [(FAMILIES[1], false), (FAMILIES[2], true)] {
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            rows.push(mixed_row(MixedSetting {
                family,
                label: format!("{transition:?}").to_lowercase(),
                setting: format!(
                    "{transition:?}, half the bricks hi-res, 1 sample/voxel{}",
                    if shaded { ", shaded" } else { "" }
                ),
                fraction: 0.5,
                transition,
                shaded,
            })?);
        }
    }
    for fraction in [1.0, 0.5, 0.25, 0.0] {
        rows.push(mixed_row(MixedSetting {
            family: FAMILIES[3],
            label: format!("{:.0}%", fraction * 100.0),
            setting: format!(
                "{:.0}% of bricks hi-res, smooth, 1 sample/voxel",
                fraction * 100.0
            ),
            fraction,
            transition: Transition::Smooth,
            shaded: false,
        })?);
    }
    let info = ctx.info();
    let d = volume.dims();
    Ok(Report {
        device: format!("{} ({:?})", info.name, info.device_type),
        scene: format!(
            "{}x{}x{} {:?} Marschner-Lobb volume, {}x{} image, bricks {}^3, one camera; reference: single resolution at 8 samples/voxel (shaded for shaded rows)",
            d.x, d.y, d.z, volume.scalar_type(), size, size, options.brick_size
        ),
        rows,
    })
}

/// The files [`Report::write`] writes, without the folder.
pub const REPORT_FILES: [&str; 7] = [
    "accuracy-vs-time.md",
    "accuracy-vs-time.csv",
    "accuracy-vs-time.json",
    "accuracy-vs-time.png",
    "accuracy-vs-time.svg",
    "seams-vs-time.png",
    "seams-vs-time.svg",
];

impl Report {
    /// The row whose setting starts with `prefix` in `family`, if any.
    pub fn row(&self, family: &str, prefix: &str) -> Option<&ReportRow> {
        self.rows
            .iter()
            .find(|r| r.family == family && r.setting.starts_with(prefix))
    }

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
        out.push_str("- Metrics (`crates/mixvol-experiments/src/metrics/`): RMSE and PSNR of premultiplied RGBA; *grad RMSE*: RMS error of the image's horizontal and vertical finite differences against the reference's; *SSIM*: mean SSIM over 8x8 windows (`image-compare`), 1 = identical; *seam max / mean*: along the projected edges of every face between a hi-res and a low-res brick (sampled every half pixel, 1 pixel to either side, bilinearly), the excess jump `max(0, J - J_ref)` with `J` the largest RGBA difference of the two sides in this frame and `J_ref` in the full-resolution frame of the same settings (single resolution, 1 sample/voxel, shaded for shaded rows: so sampling noise, which both share, is not counted as a seam); *jump max*: the largest `J` of this frame / of the full-resolution frame there. Rows without a level change have no seam lines (0).\n\n");
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
        out.push_str("\nRatios near 1 mean the metric does not tell the two apart on this scene: the smooth variant changes only the half-voxel band of hi-res bricks next to low-res ones, and at about one voxel per pixel the image difference it makes (measured: mean 0.003, max 0.3 at 48 px) is smaller than the jumps the low-res bricks' own error puts along the same lines.\n");
        out.push_str("\nCharts (PNG and SVG): `accuracy-vs-time`: RMSE (left) and gradient RMSE (right) against frame time; `seams-vs-time`: the seam measure's max (left) and mean (right) against frame time. One line per knob joining its settings, each point labelled with its setting.\n");
        out
    }

    fn series(&self, y: impl Fn(&ReportRow) -> f64) -> Vec<Series> {
        FAMILIES
            .iter()
            .zip(PALETTE)
            .map(|(family, colour)| {
                let rows: Vec<&ReportRow> =
                    self.rows.iter().filter(|r| r.family == *family).collect();
                Series {
                    name: (*family).to_string(),
                    colour,
                    dashed: family.ends_with("shaded"),
                    points: rows.iter().map(|r| (r.frame_ms, y(r))).collect(),
                    labels: rows.iter().map(|r| r.label.clone()).collect(),
                }
            })
            .filter(|s| !s.points.is_empty())
            .collect()
    }

    /// The two charts: `accuracy-vs-time` (RMSE and gradient RMSE against frame time) and
    /// `seams-vs-time` (the seam measure against frame time), one line per knob.
    pub fn charts(&self) -> [(&'static str, Chart); 2] {
        let x = "frame time (ms, median)".to_string();
        let panel = |title: &str, y_label: &str, y: &dyn Fn(&ReportRow) -> f64| Panel {
            title: title.into(),
            x_label: x.clone(),
            y_label: y_label.into(),
            y_range: None,
            series: self.series(y),
            legend_left: false,
        };
        [
            (
                "accuracy-vs-time",
                Chart {
                    title: "Error against the 8 samples/voxel reference vs frame time".into(),
                    panels: vec![
                        panel("Image error", "RMSE of premultiplied RGBA (0-1)", &|r| {
                            r.rmse
                        }),
                        panel(
                            "Gradient error",
                            "RMSE of image finite differences (0-1)",
                            &|r| r.gradient_rmse,
                        ),
                    ],
                    panel_size: (560, 420),
                },
            ),
            (
                "seams-vs-time",
                Chart {
                    title: "Seams at level changes vs frame time".into(),
                    panels: vec![
                        panel(
                            "Largest excess jump",
                            "max(0, J - J_ref), max along seam lines (0-1)",
                            &|r| r.seam.max_excess,
                        ),
                        panel(
                            "Mean excess jump",
                            "max(0, J - J_ref), mean along seam lines (0-1)",
                            &|r| r.seam.mean_excess,
                        ),
                    ],
                    panel_size: (560, 420),
                },
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
