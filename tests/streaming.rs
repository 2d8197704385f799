//! Rendering from a brick store streamed from disk: identical to the in-core renderer when every
//! wanted brick is loaded, and never blocking (falling back to low-res or absent) when the RAM
//! budget holds only part of them.

mod common;

use glam::UVec3;
use mixvol::bricks::{request_plan, DownsampleFilter, Level};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::Transition;
use mixvol::scene::{Camera, RenderSettings};
use mixvol::store::{write_store_from_volume, BrickStreamer, StreamerConfig};
use mixvol::volume::{ScalarType, SyntheticField};
use std::sync::Arc;
use std::time::Duration;

const N: u32 = 8;

fn config() -> MixedConfig {
    MixedConfig {
        brick_size: N,
        filter: DownsampleFilter::Mean2,
        cache_budget_bytes: 16 << 20,
        transition: Transition::Smooth,
        max_levels: 0,
    }
}

#[test]
fn streamed_bricks_render_like_in_core_bricks_and_missing_ones_fall_back() {
    let ctx = common::validated_context();
    let path = std::env::temp_dir().join(format!("mixvol-streaming-{}.mvbs", std::process::id()));
    {
        let volume = Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::splat(48), ScalarType::U8)
                .unwrap(),
        );
        write_store_from_volume(&path, &volume, N, DownsampleFilter::Mean2).unwrap();
        let count = 6 * 6 * 6;
        let checker: Vec<Level> = (0..count)
            .map(|i: usize| {
                if (i % 6 + (i / 6) % 6 + i / 36).is_multiple_of(2) {
                    Level::Hi
                } else {
                    Level::Lo
                }
            })
            .collect();
        let camera = Camera::default_view();
        let settings = RenderSettings::default();
        let render_in_core = |levels: &[Level]| {
            let mut r = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
            r.set_source(VolumeSource::Mixed {
                volume: volume.clone(),
                config: config(),
            })
            .unwrap();
            r.set_levels(levels).unwrap();
            r.render(&camera, &settings, 48, 48).unwrap().pixels
        };

        // Enough RAM for everything: identical images.
        let streamer = Arc::new(
            BrickStreamer::open(
                &path,
                StreamerConfig {
                    ram_budget_bytes: 64 << 20,
                    record_load_order: false,
                },
            )
            .unwrap(),
        );
        let priorities = vec![1.0f32; count];
        streamer
            .request(&request_plan(&checker, &priorities))
            .unwrap();
        assert!(
            streamer.wait_settled(Duration::from_secs(30)),
            "streamer did not settle"
        );
        let mut streamed = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        streamed
            .set_source(VolumeSource::Bricks {
                source: streamer.clone(),
                config: config(),
            })
            .unwrap();
        let report = streamed.set_levels(&checker).unwrap();
        assert_eq!(report.fallback_bricks, 0);
        let a = streamed.render(&camera, &settings, 48, 48).unwrap().pixels;
        assert_eq!(
            a,
            render_in_core(&checker),
            "streamed and in-core bricks must render identically"
        );
        drop(streamed);

        // A RAM budget for the low-res levels and a few hi-res bricks: asking for all hi-res
        // returns at once with fallbacks, and renders exactly what the fallback plan says.
        let lo_bytes = count * ((N / 2 + 1).pow(3) as usize);
        let hi_bytes = ((N + 2).pow(3)) as usize;
        let small = Arc::new(
            BrickStreamer::open(
                &path,
                StreamerConfig {
                    ram_budget_bytes: lo_bytes + 20 * hi_bytes,
                    record_load_order: false,
                },
            )
            .unwrap(),
        );
        let all_hi = vec![Level::Hi; count];
        small.request(&request_plan(&all_hi, &priorities)).unwrap();
        assert!(
            small.wait_settled(Duration::from_secs(30)),
            "streamer did not settle"
        );
        let mut partial = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        partial
            .set_source(VolumeSource::Bricks {
                source: small.clone(),
                config: config(),
            })
            .unwrap();
        let report = partial.set_levels(&all_hi).unwrap();
        assert!(
            report.fallback_bricks > 0 && report.hi_bricks <= 20,
            "{report:?}"
        );
        assert_eq!(
            report.hi_bricks + report.fallback_bricks,
            count,
            "{report:?}"
        );
        let applied = partial.brick_cache().unwrap().levels();
        let b = partial.render(&camera, &settings, 48, 48).unwrap().pixels;
        assert_eq!(
            b,
            render_in_core(&applied),
            "fallback plan renders like the same plan in core"
        );
        assert!(small.stats().peak_bytes <= lo_bytes + 20 * hi_bytes);
    }
    std::fs::remove_file(&path).ok();
    common::finish(ctx);
}
