//! The accuracy-versus-time report: renders one scene under the settings that trade accuracy for
//! time, each against a high-quality reference render (full resolution, 8 samples per voxel), and
//! records GPU frame time, image error (RMSE, PSNR) and cache memory. Written as Markdown, CSV
//! and a PNG chart (frame time against PSNR). Settings that later issues add (tricubic
//! reconstruction, extinction-based sampling, shading, pre-integration) join the list as they land.

use crate::chart::draw_text;
use glam::Vec4;
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
use mixvol::scene::Transition;
use mixvol::scene::{Camera, ClipPlanes, RenderSettings};
use mixvol::volume::Volume;
use mixvol::Result;
use std::sync::Arc;

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

/// One setting's measurements.
#[derive(Clone, Debug, PartialEq)]
pub struct ReportRow {
    /// Which knob this row turns (`samples per voxel`, `transition`, `LOD budget`).
    pub family: &'static str,
    /// The setting, in words.
    pub setting: String,
    /// Median GPU ray-cast time in milliseconds (CPU frame time where the queue has no
    /// timestamps).
    pub frame_ms: f64,
    /// Root-mean-square error of premultiplied RGBA against the reference, in [0, 1].
    pub rmse: f64,
    /// Peak signal-to-noise ratio in dB (infinite for an exact match).
    pub psnr_db: f64,
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

fn rmse(a: &[Vec4], b: &[Vec4]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from((*x - *y).length_squared()))
        .sum();
    (sum / (4 * a.len()) as f64).sqrt()
}

fn psnr(rmse: f64) -> f64 {
    if rmse > 0.0 {
        20.0 * (1.0 / rmse).log10()
    } else {
        f64::INFINITY
    }
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

/// Renders the report for `volume` seen through `tf`.
pub fn accuracy_report(
    ctx: &GpuContext,
    volume: Arc<Volume>,
    tf: &TransferFunction,
    options: &ReportOptions,
) -> Result<Report> {
    let mut single = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
    single.set_transfer_function(tf)?;
    single.set_source(VolumeSource::Volume(&volume))?;
    let fine = RenderSettings {
        samples_per_voxel: 8.0,
        ..RenderSettings::default()
    };
    let reference = single
        .render(&options.camera, &fine, options.size, options.size)?
        .pixels;
    let volume_bytes = volume.data().as_bytes().len() as u64;
    let mut rows = Vec::new();
    for spv in [0.5f32, 1.0, 2.0, 4.0] {
        let settings = RenderSettings {
            samples_per_voxel: spv,
            ..RenderSettings::default()
        };
        let (ms, pixels) = timed(&mut single, options, &settings)?;
        let e = rmse(&pixels, &reference);
        rows.push(ReportRow {
            family: "samples per voxel",
            setting: format!("{spv} samples/voxel, single resolution"),
            frame_ms: ms,
            rmse: e,
            psnr_db: psnr(e),
            resident_bytes: volume_bytes,
            hi_fraction: 1.0,
        });
    }
    drop(single);
    let grid = BrickGrid::new(volume.dims(), options.brick_size)?;
    let n = options.brick_size as u64;
    let texel = volume.scalar_type().size_bytes() as u64;
    let settings = RenderSettings::default();
    let mixed_row = |family: &'static str,
                     setting: String,
                     fraction: f64,
                     transition: Transition|
     -> Result<ReportRow> {
        let levels =
            levels_for_fraction(&volume, &grid, tf, &options.camera, options.size, fraction)?;
        let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
        renderer.set_transfer_function(tf)?;
        renderer.set_source(VolumeSource::Mixed {
            volume: volume.clone(),
            config: MixedConfig {
                brick_size: options.brick_size,
                transition,
                ..MixedConfig::default()
            },
        })?;
        let report = renderer.set_levels(&levels)?;
        let (ms, pixels) = timed(&mut renderer, options, &settings)?;
        let e = rmse(&pixels, &reference);
        let active = report.hi_bricks + report.lo_bricks;
        Ok(ReportRow {
            family,
            setting,
            frame_ms: ms,
            rmse: e,
            psnr_db: psnr(e),
            resident_bytes: report.hi_bricks as u64 * (n + 2).pow(3) * texel
                + report.lo_bricks as u64 * (n / 2 + 1).pow(3) * texel,
            hi_fraction: if active == 0 {
                0.0
            } else {
                report.hi_bricks as f64 / active as f64
            },
        })
    };
    for transition in [Transition::Smooth, Transition::Discontinuous] {
        rows.push(mixed_row(
            "transition",
            format!("{transition:?}, half the bricks hi-res, 1 sample/voxel"),
            0.5,
            transition,
        )?);
    }
    for fraction in [1.0, 0.5, 0.25, 0.0] {
        rows.push(mixed_row(
            "LOD budget",
            format!(
                "{:.0}% of bricks hi-res, smooth, 1 sample/voxel",
                fraction * 100.0
            ),
            fraction,
            Transition::Smooth,
        )?);
    }
    let info = ctx.info();
    let d = volume.dims();
    Ok(Report {
        device: format!("{} ({:?})", info.name, info.device_type),
        scene: format!(
            "{}x{}x{} {:?} volume, {}x{} image, bricks {}^3, reference: single resolution at 8 samples/voxel",
            d.x, d.y, d.z, volume.scalar_type(), options.size, options.size, options.brick_size
        ),
        rows,
    })
}

impl Report {
    /// The rows as CSV with a header line.
    pub fn to_csv(&self) -> String {
        let mut out =
            String::from("family,setting,frame_ms,rmse,psnr_db,resident_bytes,hi_fraction\n");
        for r in &self.rows {
            out.push_str(&format!(
                "{},\"{}\",{:.4},{:.6},{:.2},{},{:.3}\n",
                r.family, r.setting, r.frame_ms, r.rmse, r.psnr_db, r.resident_bytes, r.hi_fraction
            ));
        }
        out
    }

    /// The report as Markdown: scene, device, date line supplied by the caller, and the table.
    pub fn to_markdown(&self, when: &str, command: &str) -> String {
        let mut out = String::from("# Accuracy versus time\n\n");
        out.push_str(&format!(
            "- Scene: {}\n- Device: {}\n- Measured: {when}\n- Regenerate: `{command}`\n",
            self.scene, self.device
        ));
        out.push_str("- Frame time is the median GPU ray-cast time (timestamps). On a CPU device (lavapipe) it is CPU time: compare rows, not absolute numbers.\n\n");
        out.push_str("| knob | setting | frame ms | RMSE | PSNR dB | resident MB | hi-res fraction |\n|---|---|---|---|---|---|---|\n");
        for r in &self.rows {
            out.push_str(&format!(
                "| {} | {} | {:.2} | {:.5} | {:.1} | {:.2} | {:.2} |\n",
                r.family,
                r.setting,
                r.frame_ms,
                r.rmse,
                r.psnr_db,
                r.resident_bytes as f64 / 1e6,
                r.hi_fraction
            ));
        }
        out.push_str("\nChart (`accuracy-vs-time.png`): frame time (x) against PSNR (y); blue = samples per voxel, green = transition (smooth, discontinuous), orange = LOD budget.\n");
        out
    }

    /// A scatter chart of frame time (x) against PSNR (y), one colour per knob, with tick labels.
    pub fn chart(&self) -> image::RgbImage {
        let (w, h, margin) = (640u32, 400u32, 48u32);
        let mut img = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
        let finite: Vec<&ReportRow> = self.rows.iter().filter(|r| r.psnr_db.is_finite()).collect();
        if finite.is_empty() {
            return img;
        }
        let max_ms = finite.iter().map(|r| r.frame_ms).fold(0.0, f64::max) * 1.1;
        let (min_db, max_db) = finite
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
                (a.min(r.psnr_db), b.max(r.psnr_db))
            });
        let (min_db, max_db) = ((min_db - 2.0).floor(), (max_db + 2.0).ceil());
        let to_px = |ms: f64, db: f64| {
            let x = margin as f64 + ms / max_ms * (w - 2 * margin) as f64;
            let y =
                (h - margin) as f64 - (db - min_db) / (max_db - min_db) * (h - 2 * margin) as f64;
            (x as i64, y as i64)
        };
        let black = image::Rgb([0, 0, 0]);
        for x in margin..w - margin {
            img.put_pixel(x, h - margin, black);
        }
        for y in margin..=h - margin {
            img.put_pixel(margin, y, black);
        }
        for i in 0..=4 {
            let ms = max_ms * i as f64 / 4.0;
            let (x, _) = to_px(ms, min_db);
            draw_text(
                &mut img,
                x - 8,
                (h - margin + 6) as i64,
                &format!("{ms:.0}"),
                black,
            );
            let db = min_db + (max_db - min_db) * i as f64 / 4.0;
            let (_, y) = to_px(0.0, db);
            draw_text(&mut img, 4, y - 4, &format!("{db:.0}"), black);
        }
        for r in finite {
            let colour = match r.family {
                "samples per voxel" => image::Rgb([30, 90, 220]),
                "transition" => image::Rgb([20, 160, 60]),
                _ => image::Rgb([240, 140, 20]),
            };
            let (cx, cy) = to_px(r.frame_ms, r.psnr_db);
            for dy in -4i64..=4 {
                for dx in -4i64..=4 {
                    if dx * dx + dy * dy <= 16 {
                        let (x, y) = (cx + dx, cy + dy);
                        if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
                            img.put_pixel(x as u32, y as u32, colour);
                        }
                    }
                }
            }
        }
        img
    }
}
