//! The validation harness itself: it must catch a real error (so a clean run means something),
//! shut down with zero live allocations, and reject a missing device with a typed error.

mod common;

use ash::vk;
use mixvol::gpu::{ContextDesc, GpuContext, Severity};
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol::Error;

#[test]
fn messenger_records_a_deliberate_validation_error() {
    let ctx = common::validated_context();
    let log = ctx.message_log();
    // A zero-sized buffer violates VUID-VkBufferCreateInfo-size-00912.
    let info = vk::BufferCreateInfo::default()
        .size(0)
        .usage(vk::BufferUsageFlags::TRANSFER_SRC);
    // SAFETY: deliberately invalid create info; the layer reports it before the driver sees it
    // and any handle returned is destroyed right away.
    unsafe {
        if let Ok(buffer) = ctx.device().create_buffer(&info, None) {
            ctx.device().destroy_buffer(buffer, None);
        }
    }
    drop(ctx);
    let errors: Vec<_> = log
        .warnings_and_errors()
        .into_iter()
        .filter(|m| m.severity == Severity::Error)
        .collect();
    assert!(
        errors
            .iter()
            .any(|m| m.id_name.contains("VkBufferCreateInfo-size")),
        "expected the size-0 buffer to be reported, got {errors:?}"
    );
}

#[test]
fn a_full_render_is_validation_clean_and_frees_every_allocation() {
    let ctx = common::validated_context();
    assert!(
        ctx.info().synchronization_validation,
        "the installed layer offers VK_EXT_validation_features; sync validation must be on"
    );
    {
        let volume = SyntheticField::Sphere
            .generate(glam::UVec3::splat(24), ScalarType::U8)
            .unwrap();
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).unwrap();
        renderer.set_source(VolumeSource::Volume(&volume)).unwrap();
        assert!(ctx.live_allocation_count() > 0);
        let frame = renderer
            .render(&Camera::default_view(), &RenderSettings::default(), 32, 32)
            .unwrap();
        // Resizing recreates the target; a second volume replaces the first.
        renderer
            .render(&Camera::default_view(), &RenderSettings::default(), 40, 24)
            .unwrap();
        renderer.set_source(VolumeSource::Volume(&volume)).unwrap();
        assert!(
            frame.pixels.iter().any(|p| p.w > 0.0),
            "the sphere must be visible"
        );
    }
    common::finish(ctx);
}

#[test]
fn missing_device_is_a_typed_error() {
    let err = GpuContext::new(&ContextDesc {
        validation: true,
        device_name: Some("no-such-device-anywhere".into()),
    })
    .unwrap_err();
    assert!(matches!(err, Error::Unsupported(_)), "{err}");
}

#[test]
fn render_before_volume_and_zero_viewport_are_errors() {
    let ctx = common::validated_context();
    {
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba8Unorm).unwrap();
        let err = renderer
            .render(&Camera::default_view(), &RenderSettings::default(), 8, 8)
            .unwrap_err();
        assert!(matches!(err, Error::InvalidInput(_)), "{err}");
        let volume = SyntheticField::Wall
            .generate(glam::UVec3::splat(8), ScalarType::U8)
            .unwrap();
        renderer.set_source(VolumeSource::Volume(&volume)).unwrap();
        let err = renderer
            .render(&Camera::default_view(), &RenderSettings::default(), 0, 8)
            .unwrap_err();
        assert!(matches!(err, Error::InvalidInput(_)), "{err}");
    }
    common::finish(ctx);
}
