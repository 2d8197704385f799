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
//! through low-res bricks, tricubic B-spline reconstruction (against the tricubic field at 8
//! samples/voxel), and every knob again shaded (fewer settings each). Written as Markdown, CSV
//! and JSON, with two charts (PNG and SVG): error against frame time (unshaded and shaded rows),
//! and the seam measure against frame time, one line per knob. Real-data scenes over an orbit:
//! [`crate::scenes`].

mod output;

pub use output::KNOB_NOTES;
pub(crate) use output::{family_series, seams_chart};

use crate::junction::JunctionScene;
use crate::metrics::gradient::gradient_rmse;
use crate::metrics::pixel::{psnr, rmse};
use crate::metrics::seam::{seam_lines, seam_measure, SeamLines, SeamMeasure};
use crate::metrics::ssim::ssim;
use crate::metrics::{Frame, MetricError};
use crate::plot::PlotError;
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
use mixvol::scene::{Camera, ClipPlanes, Reconstruction, RenderSettings, Shading, Transition};
use mixvol::volume::Volume;
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
    /// Reading a report file back failed (missing, or not what the report writes).
    #[error("reading {path}: {message}")]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
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

/// The families of the report in chart order (colours: [`family_colour`]).
pub const FAMILIES: [&str; 18] = [
    "samples per voxel",
    "transition",
    "transition, shaded",
    "LOD budget",
    "early termination",
    "pre-integration",
    "extinction sampling",
    "downsampling filter",
    "coarse low-res steps",
    "samples per voxel, shaded",
    "LOD budget, shaded",
    "tricubic",
    "early termination, shaded",
    "pre-integration, shaded",
    "extinction sampling, shaded",
    "tricubic, shaded",
    "downsampling filter, shaded",
    "coarse low-res steps, shaded",
];

/// The chart colour of a family: that of its unshaded knob, so a knob keeps its colour in the
/// shaded panels.
pub fn family_colour(family: &str) -> [u8; 3] {
    let base = family.strip_suffix(", shaded").unwrap_or(family);
    let index = FAMILIES[..12].iter().position(|f| *f == base).unwrap_or(0);
    // Families 9 and 10 are shaded ones; 11 (tricubic) takes the colour slot 9 leaves free.
    crate::plot::PALETTE[if index == 11 { 9 } else { index }]
}

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

/// The transition rows of the junction close-up `j` seen through `tf`: smooth against
/// discontinuous at the same residency, unshaded and shaded, `frames` timed frames each.
pub fn transition_rows(
    ctx: &GpuContext,
    tf: &TransferFunction,
    j: &JunctionScene,
    frames: u32,
) -> Result<Vec<ReportRow>> {
    let junction = MixedScene::new(ctx, tf, j.volume()?, j.brick_size, j.camera(), j.size)?;
    let mut rows = Vec::new();
    for (family, shaded) in [(FAMILIES[1], false), (FAMILIES[2], true)] {
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            rows.push(junction.row(
                ctx,
                tf,
                frames,
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
    Ok(rows)
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
    // The tricubic rows' references: the B-spline field at 8 samples/voxel (the reconstruction
    // changes the field itself; its own converged image is what a step can approach).
    let tricubic_reference = {
        let mut render = |lit: RenderSettings| -> Result<Vec<Vec4>> {
            let settings = RenderSettings {
                reconstruction: Reconstruction::TricubicBSpline,
                samples_per_voxel: 8.0,
                early_termination: 1.0,
                ..lit
            };
            Ok(single
                .render(&options.camera, &settings, size, size)?
                .pixels)
        };
        let [plain, lit] = plain_and_lit();
        [render(plain)?, render(lit)?]
    };
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
        let shaded = settings.shading.is_some();
        let reference = if settings.reconstruction == Reconstruction::TricubicBSpline {
            &tricubic_reference[usize::from(shaded)]
        } else {
            &overview.reference[usize::from(shaded)]
        };
        let m = metrics(size, &pixels, reference, None)?;
        Ok(ReportRow {
            family,
            label,
            setting,
            shaded,
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
    for spv in [0.5f32, 1.0, 2.0] {
        rows.push(single_row(
            FAMILIES[11],
            format!("{spv}"),
            format!("{spv} samples/voxel, tricubic B-spline (against the tricubic reference)"),
            RenderSettings {
                reconstruction: Reconstruction::TricubicBSpline,
                ..at(spv)
            },
        )?);
    }
    if let Some(j) = &options.junction {
        rows.extend(transition_rows(ctx, tf, j, options.frames)?);
    }
    let overview_row = |family: &'static str,
                        label: String,
                        setting: String,
                        fraction: f64,
                        filter: DownsampleFilter,
                        coarse_low_res_steps: bool,
                        shaded: bool|
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
                shaded,
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
            false,
        )?);
    }
    // Shaded rows (Blinn-Phong, against the shaded reference): shading turns the field's
    // gradient into colour, so it shows what the step and the LOD cost in normals.
    for spv in [0.5f32, 1.0, 2.0] {
        rows.push(single_row(
            FAMILIES[9],
            format!("{spv}"),
            format!("{spv} samples/voxel, single resolution, shaded"),
            RenderSettings {
                shading: Some(Shading::default()),
                ..at(spv)
            },
        )?);
    }
    for fraction in [1.0, 0.5, 0.0] {
        rows.push(overview_row(
            FAMILIES[10],
            percent(fraction),
            format!(
                "{} of bricks hi-res, smooth, 1 sample/voxel, shaded",
                percent(fraction)
            ),
            fraction,
            DownsampleFilter::Mean2,
            false,
            true,
        )?);
    }
    // The other knobs shaded, fewer settings each (shaded frames cost 2-4x), against the shaded
    // reference and the shaded rows without the knob.
    let lit = |settings: RenderSettings| RenderSettings {
        shading: Some(Shading::default()),
        ..settings
    };
    for threshold in [0.8f32, 1.0] {
        rows.push(single_row(
            FAMILIES[12],
            format!("{threshold}"),
            format!("early termination at opacity {threshold}, 1 sample/voxel, shaded"),
            lit(RenderSettings {
                early_termination: threshold,
                ..at(1.0)
            }),
        )?);
    }
    for spv in [0.5f32, 1.0] {
        rows.push(single_row(
            FAMILIES[13],
            format!("{spv}"),
            format!("{spv} samples/voxel, pre-integrated, shaded"),
            lit(RenderSettings {
                preintegrated: true,
                ..at(spv)
            }),
        )?);
    }
    rows.push(single_row(
        FAMILIES[14],
        "1".into(),
        "1 samples/voxel, extinction-based, shaded".into(),
        lit(RenderSettings {
            sampling_model: SamplingModel::Extinction,
            ..at(1.0)
        }),
    )?);
    rows.push(single_row(
        FAMILIES[15],
        "1".into(),
        "1 samples/voxel, tricubic B-spline (against the tricubic reference), shaded".into(),
        lit(RenderSettings {
            reconstruction: Reconstruction::TricubicBSpline,
            ..at(1.0)
        }),
    )?);
    drop(single);
    for (label, filter) in [
        ("mean", DownsampleFilter::Mean2),
        ("LaMar", DownsampleFilter::LaMarSubsample),
        ("box4", DownsampleFilter::Box4),
        ("13/19", DownsampleFilter::BSpline4),
    ] {
        rows.push(overview_row(
            FAMILIES[16],
            label.into(),
            format!(
                "{filter:?} low-res level, 25% of bricks hi-res, smooth, 1 sample/voxel, shaded"
            ),
            0.25,
            filter,
            false,
            true,
        )?);
    }
    for fraction in [0.5, 0.0] {
        rows.push(overview_row(
            FAMILIES[17],
            percent(fraction),
            format!(
                "{} of bricks hi-res, LaMar's coarse low-res steps, smooth, 1 sample/voxel, shaded",
                percent(fraction)
            ),
            fraction,
            DownsampleFilter::Mean2,
            true,
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
    /// samples-per-voxel row of its rate, unshaded or shaded, for early termination,
    /// pre-integration, extinction and tricubic; the mean filter for the downsampling filters;
    /// the LOD row of its residency for coarse low-res steps); `None` for the other families.
    pub fn baseline(&self, r: &ReportRow) -> Option<&ReportRow> {
        let f = FAMILIES;
        let spv = |family: &str, s: &str| self.row(family, &format!("{s} samples/voxel"));
        let same_label = |family: &str, label: &str| {
            self.rows
                .iter()
                .find(|b| b.family == family && b.label == label)
        };
        match r.family {
            x if x == f[4] => spv(f[0], "1"),
            x if x == f[12] => spv(f[9], "1"),
            x if x == f[5] || x == f[6] || x == f[11] => spv(f[0], &r.label),
            x if x == f[13] || x == f[14] || x == f[15] => spv(f[9], &r.label),
            x if (x == f[7] || x == f[16]) && r.label != "mean" => same_label(x, "mean"),
            x if x == f[8] => same_label(f[3], &r.label),
            x if x == f[17] => same_label(f[10], &r.label),
            _ => None,
        }
    }
}
