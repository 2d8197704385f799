//! `mixvol junction`: a close-up of a hi-res / low-res brick junction, discontinuous and smooth
//! side by side, to see what the C0 transition removes.

use crate::args::{JunctionArgs, LevelsArg};
use crate::files::create_parent;
use crate::levels::level_pattern;
use crate::render::check_validation;
use glam::{UVec3, Vec3};
use mixvol::bricks::BrickGrid;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::TransferFunction;
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol::{Error, Result};
use std::sync::Arc;

/// A close-up of a plane junction (bricks with x < 32 low-res) in a 64^3 Marschner-Lobb volume,
/// discontinuous on the left, smooth on the right.
pub fn junction(args: &JunctionArgs) -> Result<()> {
    if args.size == 0 {
        return Err(Error::InvalidInput("--size must be positive".into()));
    }
    // f32: 8-bit textures are filtered in 8-bit fixed point on lavapipe, which terraces a zoom.
    let volume =
        Arc::new(SyntheticField::MarschnerLobb.generate(UVec3::splat(64), ScalarType::F32)?);
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: None,
    })?;
    // Contour stripes: a jump in the field breaks the stripes at the junction.
    let stripes: Vec<(f32, glam::Vec4)> = (0..=40)
        .map(|i| {
            let s = i as f32 / 40.0;
            let c = if i % 2 == 0 {
                glam::Vec4::new(0.95, 0.85, 0.3, 1.0)
            } else {
                glam::Vec4::new(0.1, 0.25, 0.6, 1.0)
            };
            (s, c)
        })
        .collect();
    let tf = TransferFunction::from_control_points(&stripes)?;
    let grid = BrickGrid::new(volume.dims(), 16)?;
    let levels = level_pattern(&grid, LevelsArg::Half)?;
    // Looking down -z at the junction plane x = 0 (world), 8 voxels wide, through a slab two
    // voxels thick (near/far clip) so the image shows the field itself, like a slice.
    let camera = Camera {
        near: 2.0 - 1.0 / 64.0,
        far: 2.0 + 1.0 / 64.0,
        ..Camera::orthographic(
            Vec3::new(0.0, 0.1, 2.0),
            Vec3::new(0.0, 0.1, 0.0),
            8.0 / 64.0,
        )
    };
    let settings = RenderSettings {
        samples_per_voxel: 4.0,
        ..RenderSettings::default()
    };
    let mut halves = Vec::new();
    for transition in [Transition::Discontinuous, Transition::Smooth] {
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm)?;
        renderer.set_transfer_function(&tf)?;
        // Levels 0 and 1 through the two-level slot classes.
        renderer.set_source(VolumeSource::Levels {
            volume: volume.clone(),
            levels: &levels,
            config: MixedConfig {
                brick_size: 16,
                transition,
                max_levels: 2,
                ..MixedConfig::default()
            },
        })?;
        let frame = renderer.render(&camera, &settings, args.size, args.size)?;
        halves.push(frame.to_rgba8(Vec3::splat(0.08)));
    }
    let gap = 4;
    let mut out = image::RgbaImage::from_pixel(
        2 * args.size + gap,
        args.size,
        image::Rgba([255, 255, 255, 255]),
    );
    image::imageops::overlay(&mut out, &halves[0], 0, 0);
    image::imageops::overlay(&mut out, &halves[1], i64::from(args.size + gap), 0);
    create_parent(&args.output)?;
    mixvol::renderer::save_png(&out, &args.output)?;
    println!(
        "wrote {}: low-res bricks left of the centre line, hi-res right; discontinuous (left image) vs smooth (right image)",
        args.output.display()
    );
    let log = ctx.message_log();
    drop(ctx);
    if args.validation {
        check_validation(&log, false)?;
    }
    Ok(())
}
