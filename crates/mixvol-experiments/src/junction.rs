//! The scene of the accuracy report's transition rows: a close-up of an edge-on junction
//! between low-res and hi-res bricks, where a seam is an image jump the measure can see.
//!
//! Why not the report's overview. Seen from outside at about one voxel per pixel, the two
//! transitions differ by less than a pixel: the smooth one ramps over half a hi-res voxel, and a
//! face crossed at an angle integrates into a continuous image either way (see
//! [`crate::metrics::seam`]). Measured on the 48 px overview: the seam measure of smooth and
//! discontinuous agreed to 0.1-0.4%. Here the face between the halves (world `x = 0`, the
//! volume's middle) holds the view direction, so every ray stays on one side of it and the
//! image jumps on its projected line (the image's middle column) by the whole difference
//! between the two reconstructions, and the view is magnified to several pixels per voxel so
//! that the smooth ramp spans pixels.

use crate::accuracy::Result;
use glam::{UVec3, Vec3, Vec4};
use image::imageops::FilterType;
use image::Rgba;
use mixvol::bricks::{BrickGrid, Level};
use mixvol::embed::MixedConfig;
use mixvol::gpu::GpuContext;
use mixvol::optics::TransferFunction;
use mixvol::renderer::{pixels_to_rgba8, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Shading, Transition};
use mixvol::volume::{ScalarType, SyntheticField, Volume};
use std::sync::Arc;

/// The junction close-up: volume, bricks, image and magnification.
#[derive(Clone, Debug, PartialEq)]
pub struct JunctionScene {
    /// Edge of the cubic Marschner-Lobb volume (f32: lavapipe filters 8-bit textures in 8-bit
    /// fixed point, which terraces a magnified view).
    pub volume_size: u32,
    /// Brick edge in voxels.
    pub brick_size: u32,
    /// Image width and height in pixels.
    pub size: u32,
    /// Voxels across the image (`size / width_voxels` pixels per voxel).
    pub width_voxels: f32,
    /// The volume the junction is cut into; `None`: Marschner-Lobb of `volume_size` (f32). A
    /// real volume ([`Self::in_volume`]) keeps its own dims and type.
    pub given: Option<Arc<Volume>>,
}

impl JunctionScene {
    /// The quick scene: 64^3 in bricks of 8 (Marschner-Lobb has detail at the brick scale
    /// there), 64 x 64 pixels over 4 voxels, 16 pixels per voxel: the smooth ramp (half a
    /// voxel) spans 8 pixels. Measured (lavapipe): at 8 pixels per voxel the smooth rows' seam
    /// max is 0.019 unshaded (the ramp's curvature, 0.0045 at 16), against 0.025 discontinuous.
    pub fn quick() -> Self {
        Self {
            volume_size: 64,
            brick_size: 8,
            size: 64,
            width_voxels: 4.0,
            given: None,
        }
    }

    /// The close-up of the full report on the junction cut into `volume` (a real scene): the
    /// bricks below the middle brick column in x low-res, seen edge-on as in [`Self::full`],
    /// bricks of `brick_size`.
    pub fn in_volume(volume: Arc<Volume>, brick_size: u32) -> Self {
        Self {
            volume_size: volume.dims().max_element(),
            brick_size,
            given: Some(volume),
            ..Self::full()
        }
    }

    /// The full report's scene: the quick one at 128 x 128 pixels over 8 voxels (16 pixels per
    /// voxel, a taller strip of the junction).
    pub fn full() -> Self {
        Self {
            size: 128,
            width_voxels: 8.0,
            ..Self::quick()
        }
    }

    /// The volume: the given one, or Marschner-Lobb, f32.
    pub fn volume(&self) -> Result<Arc<Volume>> {
        if let Some(v) = &self.given {
            return Ok(v.clone());
        }
        Ok(Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::splat(self.volume_size), ScalarType::F32)
                .map_err(mixvol::Error::from)?,
        ))
    }

    /// The levels: bricks below the middle in x low-res, the others hi-res (identical for both
    /// transitions).
    pub fn levels(grid: &BrickGrid) -> Vec<Level> {
        let half = grid.bricks_per_axis().x / 2;
        (0..grid.brick_count())
            .map(|i| {
                if grid.brick_coords(i).x >= half {
                    Level::Hi
                } else {
                    Level::Lo
                }
            })
            .collect()
    }

    /// The camera: orthographic, looking down -z at the junction plane (the face below which
    /// [`Self::levels`] makes bricks low-res: world `x = 0` for Marschner-Lobb) from outside
    /// the volume, `width_voxels` voxels tall, centred at `y = 0.1` (off the field's axis, where
    /// the Marschner-Lobb rings cross the plane; inside the head for the real scenes).
    pub fn camera(&self) -> Camera {
        let (x, voxel) = match &self.given {
            Some(v) => {
                let (lo, hi) = mixvol::scene::volume_box(v.dims(), v.spacing());
                let d = v.dims().x as f32;
                let plane = (v.dims().x.div_ceil(self.brick_size) / 2 * self.brick_size) as f32;
                (lo.x + (hi.x - lo.x) * plane / d, (hi.x - lo.x) / d)
            }
            None => (0.0, 1.0 / self.volume_size as f32),
        };
        Camera::orthographic(
            Vec3::new(x, 0.1, 2.0),
            Vec3::new(x, 0.1, 0.0),
            self.width_voxels * voxel,
        )
    }
}

/// The file name `mixvol report` writes [`figure`] under, next to the report.
pub const JUNCTION_FIGURE: &str = "junction.png";

/// Pixels per frame pixel in [`figure`].
pub const FIGURE_ZOOM: u32 = 2;

/// The figure of the junction (`docs/report/junction.png`): one row unshaded, one shaded; in each
/// the smooth frame, the discontinuous frame (the low-res half on the left of both) and their
/// difference amplified four times, every pixel drawn as a [`FIGURE_ZOOM`]-pixel square.
pub fn figure(
    ctx: &GpuContext,
    tf: &TransferFunction,
    scene: &JunctionScene,
) -> Result<image::RgbaImage> {
    let volume = scene.volume()?;
    let grid = BrickGrid::new(volume.dims(), scene.brick_size)?;
    let levels = JunctionScene::levels(&grid);
    let camera = scene.camera();
    let s = scene.size;
    let (z, gap) = (FIGURE_ZOOM, 4);
    let cell = s * z + gap;
    let mut out = image::RgbaImage::from_pixel(3 * cell - gap, 2 * cell - gap, Rgba([255; 4]));
    for (row, shading) in [None, Some(Shading::default())].into_iter().enumerate() {
        let settings = RenderSettings {
            shading,
            ..RenderSettings::default()
        };
        let mut frames = Vec::new();
        for transition in [Transition::Smooth, Transition::Discontinuous] {
            let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float)?;
            renderer.set_transfer_function(tf)?;
            renderer.set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config: MixedConfig {
                    brick_size: scene.brick_size,
                    transition,
                    ..MixedConfig::default()
                },
            })?;
            renderer.set_levels(&levels)?;
            frames.push(renderer.render(&camera, &settings, s, s)?.pixels);
        }
        let difference: Vec<Vec4> = frames[0]
            .iter()
            .zip(&frames[1])
            .map(|(a, b)| ((*a - *b).abs() * 4.0).truncate().extend(1.0))
            .collect();
        for (column, pixels) in [&frames[0], &frames[1], &difference]
            .into_iter()
            .enumerate()
        {
            let img = pixels_to_rgba8(pixels, s, s, Vec3::splat(0.08));
            let big = image::imageops::resize(&img, s * z, s * z, FilterType::Nearest);
            image::imageops::overlay(
                &mut out,
                &big,
                i64::from(column as u32 * cell),
                i64::from(row as u32 * cell),
            );
        }
    }
    Ok(out)
}
