//! The accuracy-versus-time report: renders one scene under the settings that trade accuracy for
//! time, each against a high-quality reference render (full resolution, 8 samples per voxel, no
//! early ray termination, shaded when the row is), and records GPU frame time, cache memory and the image metrics of
//! [`crate::metrics`]: RMSE and PSNR, the gradient error, SSIM and the seam measure (the image
//! jump across the projected faces where the brick level changes, beyond the jump of the
//! full-resolution frame at the row's own settings there: against the 8 samples/voxel reference
//! the 1 sample/voxel wood-grain would count as seams; measured in quick mode, the
//! single-resolution 1 sample/voxel frame then scores a seam max of 0.49 on the same lines, the
//! mixed rows 0.54).
//!
//! Rows: samples per voxel (single resolution), smooth against discontinuous transitions at the
//! same residency unshaded and shaded (shading amplifies seams, Beyer et al. Fig. 8) on the
//! close-up of an edge-on junction of [`crate::junction`] (where a seam is an image jump; on the
//! overview the two transitions' seam measures agree to 0.4%), the LOD budget, early ray
//! termination, pre-integration and extinction-based sampling (single resolution, against the
//! same step without them), the downsampling filter of the low-res level (mean, LaMar's
//! subsampling, Kraus' 4-tap box and 13/19/19/13, at one residency) and LaMar's coarse steps
//! through low-res bricks. Written as Markdown, CSV and JSON, with two charts (PNG and SVG):
//! error against frame time, and the seam measure against frame time, one line per knob.
//! Not measured yet: tricubic reconstruction (its reference would have to be tricubic too),
//! shaded rows of the knobs other than the transition, and real-data scenes over an orbit.

use crate::junction::JunctionScene;
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
use mixvol::optics::SamplingModel;
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
    /// The scene of the transition rows (smooth against discontinuous); `None` leaves them out
    /// (the orbit of [`crate::scenes`] measures them once, not per view).
    pub junction: Option<JunctionScene>,
    /// What the volume is, in words (the report's scene line).
    pub volume_name: String,
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
            junction: Some(JunctionScene::quick()),
            volume_name: "Marschner-Lobb".into(),
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
    camera: &Camera,
    size: u32,
    frames: u32,
    settings: &RenderSettings,
) -> Result<(f64, Vec<Vec4>)> {
    renderer.render(camera, settings, size, size)?;
    let mut times = Vec::new();
    let mut last = Vec::new();
    for _ in 0..frames.max(1) {
        let frame = renderer.render(camera, settings, size, size)?;
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
pub const FAMILIES: [&str; 9] = [
    "samples per voxel",
    "transition",
    "transition, shaded",
    "LOD budget",
    "early termination",
    "pre-integration",
    "extinction sampling",
    "downsampling filter",
    "coarse low-res steps",
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
    levels: Vec<Level>,
    transition: Transition,
    filter: DownsampleFilter,
    coarse_low_res_steps: bool,
    shaded: bool,
}

/// What the mixed-resolution rows of one scene share: the volume in bricks, the view, and the
/// single-resolution frames they are measured against.
struct MixedScene {
    volume: Arc<Volume>,
    grid: BrickGrid,
    geometry: BrickGeometry,
    brick_size: u32,
    camera: Camera,
    size: u32,
    /// 8 samples/voxel without early termination, unshaded and shaded: the error metrics'
    /// references.
    reference: [Vec<Vec4>; 2],
    /// 1 sample/voxel (the rows' own rate), unshaded and shaded: the seam measure's.
    full_resolution: [Vec<Vec4>; 2],
}

fn plain_and_lit() -> [RenderSettings; 2] {
    [
        RenderSettings::default(),
        RenderSettings {
            shading: Some(Shading::default()),
            ..RenderSettings::default()
        },
    ]
}

impl MixedScene {
    fn new(
        ctx: &GpuContext,
        tf: &TransferFunction,
        volume: Arc<Volume>,
        brick_size: u32,
        camera: Camera,
        size: u32,
    ) -> Result<Self> {
        let mut single = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
        single.set_transfer_function(tf)?;
        single.set_source(VolumeSource::Volume(&volume))?;
        // The 8 samples/voxel references run every ray to its end (no early termination: the
        // early termination rows are measured against them too); the 1 sample/voxel
        // full-resolution frames keep the rows' own settings.
        let mut render_at = |settings: &RenderSettings, spv: f32| -> Result<Vec<Vec4>> {
            let settings = RenderSettings {
                samples_per_voxel: spv,
                early_termination: if spv > 1.0 {
                    1.0
                } else {
                    settings.early_termination
                },
                ..*settings
            };
            Ok(single.render(&camera, &settings, size, size)?.pixels)
        };
        let [plain, lit] = plain_and_lit();
        let reference = [render_at(&plain, 8.0)?, render_at(&lit, 8.0)?];
        let full_resolution = [render_at(&plain, 1.0)?, render_at(&lit, 1.0)?];
        let grid = BrickGrid::new(volume.dims(), brick_size)?;
        let geometry = BrickGeometry::new(grid, volume.spacing())?;
        Ok(Self {
            volume,
            grid,
            geometry,
            brick_size,
            camera,
            size,
            reference,
            full_resolution,
        })
    }

    /// The row of setting `s`, `frames` timed frames.
    fn row(
        &self,
        ctx: &GpuContext,
        tf: &TransferFunction,
        frames: u32,
        s: MixedSetting,
    ) -> Result<ReportRow> {
        let size = self.size;
        let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
        renderer.set_transfer_function(tf)?;
        renderer.set_source(VolumeSource::Mixed {
            volume: self.volume.clone(),
            config: MixedConfig {
                brick_size: self.brick_size,
                transition: s.transition,
                filter: s.filter,
                ..MixedConfig::default()
            },
        })?;
        let report = renderer.set_levels(&s.levels)?;
        let lit = usize::from(s.shaded);
        let settings = RenderSettings {
            coarse_low_res_steps: s.coarse_low_res_steps,
            ..plain_and_lit()[lit]
        };
        let (ms, pixels) = timed(&mut renderer, &self.camera, size, frames, &settings)?;
        let lines = seam_lines(&self.geometry, &s.levels, &self.camera, size, size)?;
        let seam = SeamInput {
            full_resolution: &self.full_resolution[lit],
            lines: &lines,
        };
        let m = metrics(size, &pixels, &self.reference[lit], Some(seam))?;
        let active = report.hi_bricks + report.lo_bricks;
        let n = self.brick_size as u64;
        let texel = self.volume.scalar_type().size_bytes() as u64;
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
    }
}

/// Renders the report for `volume` seen through `tf` (the transition rows on their own scene,
/// [`ReportOptions::junction`], through the same `tf`).
pub fn accuracy_report(
    ctx: &GpuContext,
    volume: Arc<Volume>,
    tf: &TransferFunction,
    options: &ReportOptions,
) -> Result<Report> {
    let size = options.size;
    let overview = MixedScene::new(
        ctx,
        tf,
        volume.clone(),
        options.brick_size,
        options.camera,
        size,
    )?;
    let mut single = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
    single.set_transfer_function(tf)?;
    single.set_source(VolumeSource::Volume(&volume))?;
    let volume_bytes = volume.data().as_bytes().len() as u64;
    let mut rows = Vec::new();
    let mut single_row = |family: &'static str,
                          label: String,
                          setting: String,
                          settings: RenderSettings|
     -> Result<ReportRow> {
        let (ms, pixels) = timed(
            &mut single,
            &options.camera,
            size,
            options.frames,
            &settings,
        )?;
        let m = metrics(size, &pixels, &overview.reference[0], None)?;
        Ok(ReportRow {
            family,
            label,
            setting,
            shaded: false,
            frame_ms: ms,
            rmse: m.rmse,
            psnr_db: psnr(m.rmse),
            gradient_rmse: m.gradient_rmse,
            ssim: m.ssim,
            seam: m.seam,
            resident_bytes: volume_bytes,
            hi_fraction: 1.0,
        })
    };
    let at = |spv: f32| RenderSettings {
        samples_per_voxel: spv,
        ..RenderSettings::default()
    };
    for spv in [0.5f32, 1.0, 2.0, 4.0] {
        rows.push(single_row(
            FAMILIES[0],
            format!("{spv}"),
            format!("{spv} samples/voxel, single resolution"),
            at(spv),
        )?);
    }
    for threshold in [0.8f32, 0.9, 0.95, 1.0] {
        rows.push(single_row(
            FAMILIES[4],
            format!("{threshold}"),
            format!("early termination at opacity {threshold}, 1 sample/voxel"),
            RenderSettings {
                early_termination: threshold,
                ..at(1.0)
            },
        )?);
    }
    for spv in [0.5f32, 1.0, 2.0] {
        rows.push(single_row(
            FAMILIES[5],
            format!("{spv}"),
            format!("{spv} samples/voxel, pre-integrated"),
            RenderSettings {
                preintegrated: true,
                ..at(spv)
            },
        )?);
    }
    for spv in [0.5f32, 1.0, 2.0] {
        rows.push(single_row(
            FAMILIES[6],
            format!("{spv}"),
            format!("{spv} samples/voxel, extinction-based"),
            RenderSettings {
                sampling_model: SamplingModel::Extinction,
                ..at(spv)
            },
        )?);
    }
    drop(single);
    if let Some(j) = &options.junction {
        let junction = MixedScene::new(
            ctx,
            tf,
            Arc::new(j.volume()?),
            j.brick_size,
            j.camera(),
            j.size,
        )?;
        for (family, shaded) in [(FAMILIES[1], false), (FAMILIES[2], true)] {
            for transition in [Transition::Smooth, Transition::Discontinuous] {
                rows.push(junction.row(
                    ctx,
                    tf,
                    options.frames,
                    MixedSetting {
                        family,
                        label: format!("{transition:?}").to_lowercase(),
                        setting: format!(
                            "{transition:?}, junction close-up (x < middle low-res), 1 sample/voxel{}",
                            if shaded { ", shaded" } else { "" }
                        ),
                        levels: JunctionScene::levels(&junction.grid),
                        transition,
                        filter: DownsampleFilter::Mean2,
                        coarse_low_res_steps: false,
                        shaded,
                    },
                )?);
            }
        }
    }
    let overview_row = |family: &'static str,
                        label: String,
                        setting: String,
                        fraction: f64,
                        filter: DownsampleFilter,
                        coarse_low_res_steps: bool|
     -> Result<ReportRow> {
        let levels =
            levels_for_fraction(&volume, &overview.grid, tf, &options.camera, size, fraction)?;
        overview.row(
            ctx,
            tf,
            options.frames,
            MixedSetting {
                family,
                label,
                setting,
                levels,
                transition: Transition::Smooth,
                filter,
                coarse_low_res_steps,
                shaded: false,
            },
        )
    };
    let percent = |f: f64| format!("{:.0}%", f * 100.0);
    for fraction in [1.0, 0.5, 0.25, 0.0] {
        rows.push(overview_row(
            FAMILIES[3],
            percent(fraction),
            format!(
                "{} of bricks hi-res, smooth, 1 sample/voxel",
                percent(fraction)
            ),
            fraction,
            DownsampleFilter::Mean2,
            false,
        )?);
    }
    for (label, filter) in [
        ("mean", DownsampleFilter::Mean2),
        ("LaMar", DownsampleFilter::LaMarSubsample),
        ("box4", DownsampleFilter::Box4),
        ("13/19", DownsampleFilter::BSpline4),
    ] {
        rows.push(overview_row(
            FAMILIES[7],
            label.into(),
            format!("{filter:?} low-res level, 25% of bricks hi-res, smooth, 1 sample/voxel"),
            0.25,
            filter,
            false,
        )?);
    }
    for fraction in [0.5, 0.25, 0.0] {
        rows.push(overview_row(
            FAMILIES[8],
            percent(fraction),
            format!(
                "{} of bricks hi-res, LaMar's coarse low-res steps, smooth, 1 sample/voxel",
                percent(fraction)
            ),
            fraction,
            DownsampleFilter::Mean2,
            true,
        )?);
    }
    let info = ctx.info();
    let d = volume.dims();
    Ok(Report {
        device: format!("{} ({:?})", info.name, info.device_type),
        scene: format!(
            "{}x{}x{} {:?} {} volume, {}x{} image, bricks {}^3, one camera; {}reference: single resolution at 8 samples/voxel without early termination (shaded for shaded rows)",
            d.x, d.y, d.z, volume.scalar_type(), options.volume_name, size, size, options.brick_size,
            options.junction.as_ref().map_or(String::new(), |j| format!(
                "transition rows: {}^3 F32 Marschner-Lobb in bricks {}^3, orthographic close-up of the junction plane x = 0 seen edge-on (bricks below the middle low-res), {}x{} image over {} voxels ({:.0} px/voxel); ",
                j.volume_size, j.brick_size, j.size, j.size, j.width_voxels,
                j.size as f32 / j.width_voxels
            )),
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

    /// The row a knob's row is compared with: the same settings without the knob (the
    /// samples-per-voxel row of its rate for early termination, pre-integration and extinction,
    /// the mean filter for the downsampling filters, the LOD row of its residency for coarse
    /// low-res steps); `None` for the other families.
    pub fn baseline(&self, r: &ReportRow) -> Option<&ReportRow> {
        let spv = |s: &str| self.row(FAMILIES[0], &format!("{s} samples/voxel"));
        match r.family {
            f if f == FAMILIES[4] => spv("1"),
            f if f == FAMILIES[5] || f == FAMILIES[6] => spv(&r.label),
            f if f == FAMILIES[7] && r.label != "mean" => self
                .rows
                .iter()
                .find(|b| b.family == f && b.label == "mean"),
            f if f == FAMILIES[8] => self
                .rows
                .iter()
                .find(|b| b.family == FAMILIES[3] && b.label == r.label),
            _ => None,
        }
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
        out.push_str("- Metrics (`crates/mixvol-experiments/src/metrics/`): RMSE and PSNR of premultiplied RGBA; *grad RMSE*: RMS error of the image's horizontal and vertical finite differences against the reference's; *SSIM*: mean SSIM over 8x8 windows (`image-compare`), 1 = identical; *seam max / mean*: along the projected edges of every face between a hi-res and a low-res brick (every half pixel), each side extrapolated linearly to the line from bilinear samples 0.5 and 1.5 pixels from it, `J` the largest RGBA difference of the two extrapolations (a step of height h scores h, a continuous kink 0), and the seam the excess `max(0, J - J_ref)` over `J_ref` of the full-resolution frame of the same settings (single resolution, 1 sample/voxel, shaded for shaded rows: so what both share is not counted as a seam); *jump max*: the largest `J` of this frame / of the full-resolution frame there. Rows without a level change have no seam lines (0).\n");
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
        out.push_str("\nCharts (PNG and SVG): `accuracy-vs-time`: RMSE (left) and gradient RMSE (right) against frame time; `seams-vs-time`: the seam measure's max (left) and mean (right) against frame time, for the knobs with a level change. One line per knob joining its settings, each point labelled with its setting.\n");
        out
    }

    /// One series per family; with `seams_only`, only the families with seam lines (a level
    /// change somewhere), the others being 0 on the seam chart.
    fn series(&self, y: impl Fn(&ReportRow) -> f64, seams_only: bool) -> Vec<Series> {
        FAMILIES
            .iter()
            .zip(PALETTE)
            .filter(|(family, _)| {
                !seams_only
                    || self
                        .rows
                        .iter()
                        .any(|r| r.family == **family && r.seam.faces > 0)
            })
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
        let panel =
            |title: &str, y_label: &str, y: &dyn Fn(&ReportRow) -> f64, seams: bool| Panel {
                title: title.into(),
                x_label: x.clone(),
                y_label: y_label.into(),
                y_range: None,
                series: self.series(y, seams),
                legend_left: false,
            };
        [
            (
                "accuracy-vs-time",
                Chart {
                    title: "Error against the 8 samples/voxel reference vs frame time".into(),
                    panels: vec![
                        panel(
                            "Image error",
                            "RMSE of premultiplied RGBA (0-1)",
                            &|r| r.rmse,
                            false,
                        ),
                        panel(
                            "Gradient error",
                            "RMSE of image finite differences (0-1)",
                            &|r| r.gradient_rmse,
                            false,
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
                            true,
                        ),
                        panel(
                            "Mean excess jump",
                            "max(0, J - J_ref), mean along seam lines (0-1)",
                            &|r| r.seam.mean_excess,
                            true,
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
