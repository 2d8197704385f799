//! An OME-Zarr pyramid drawn at all its levels without converting it (issue 19, item 4):
//! `stream::ZarrLevels` reads the stored bricks of every vertex level from the image's own
//! pyramid levels, local or over HTTP (tests/servers/range_server.py on loopback), and a
//! `VolumeSource::LevelStream` over it draws the camera's levels, matching the CPU reference
//! over those stored bricks, under the validation layers.
//!
//! The image is the two-level uint16 pyramid ome-zarr-py writes
//! (tests/fixtures/write_stream_pyramid.py): level 0 of 64x32x32 voxels, level 1 their 2x2x2
//! means with ome-zarr-py's scale and translation. Its values are recomputed here on their own
//! (`remote_util::pyramid`), and level 1's coordinates are read from zarr.json with serde_json.

mod common;
mod remote_util;

use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::{BrickGrid, DownsampleFilter};
use mixvol::cache::{
    block_bricks, stored_brick_edge, stored_bricks_per_axis, stored_first_sample, SlotGeometry,
};
use mixvol::pyramid::{LevelGrid, SamplePlacement};
use mixvol::reference::{self, LevelField, LevelReferenceCache};
use mixvol::renderer::{MixedConfig, Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::{LevelBackend, LevelStreamConfig, LevelStreamer};
use mixvol::stream::{StreamError, ZarrLevels, ZarrLevelsConfig};
use mixvol::volume::formats::{RemoteOptions, ZarrLocation};
use mixvol::volume::ScalarType;
use remote_util::pyramid::*;
use remote_util::*;
use std::sync::Arc;
use std::time::Duration;

const N: u32 = 8;
const W: u32 = 48;

fn config() -> ZarrLevelsConfig {
    ZarrLevelsConfig {
        brick_size: N,
        concurrency: 4,
        ..ZarrLevelsConfig::default()
    }
}

fn open(location: &str) -> ZarrLevels {
    ZarrLevels::open(
        &ZarrLocation::parse(location).unwrap(),
        &RemoteOptions::default(),
        config(),
    )
    .unwrap()
}

/// Every stored brick's first brick at `level`.
fn stored(grid: &BrickGrid, level: u32) -> Vec<UVec3> {
    let s = stored_bricks_per_axis(grid.bricks_per_axis(), level);
    let mut out = Vec::new();
    for z in 0..s.z {
        for y in 0..s.y {
            for x in 0..s.x {
                out.push(UVec3::new(x, y, z) * block_bricks(level));
            }
        }
    }
    out
}

fn u16s(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .map(|c| u16::from_ne_bytes([c[0], c[1]]))
        .collect()
}

/// Level 0's stored bricks are the image's voxels (borders clamped); every coarser vertex
/// level is image level 1 interpolated trilinearly at the vertex positions `2^k j - 1/2`
/// (mapped through the OME-Zarr transforms; past the image's pyramid, level 1 still); the same
/// bytes come over HTTP; a float image without a value range and too many levels are refused.
#[test]
fn zarr_levels_are_the_image_levels_at_vertex_positions() {
    let dir = pyramid_fixture();
    let root = dir.join("pyr.zarr");
    let levels = open(root.to_str().unwrap());
    let grid = levels.grid();
    assert_eq!(grid.dims(), UVec3::from(PDIMS));
    assert_eq!(grid.bricks_per_axis(), UVec3::new(8, 4, 4));
    // Levels 0-2 and block levels 3-5 (a block of 8 bricks covers the longest axis).
    assert_eq!(levels.level_count(), 6);
    assert_eq!(levels.image_levels(), &[0, 1, 1, 1, 1, 1]);
    assert_eq!(levels.scalar(), ScalarType::U16);
    assert_eq!(levels.stored_range(1, UVec3::ZERO), None);

    let dims = UVec3::from(PDIMS).as_ivec3();
    for first in stored(&grid, 0) {
        let texels = u16s(&levels.read_stored_bytes(0, first).unwrap());
        let start = stored_first_sample(first, N, 0);
        let edge = stored_brick_edge(N, 0) as i32;
        for (t, &got) in texels.iter().enumerate() {
            let t = t as i32;
            let v = (start + glam::IVec3::new(t % edge, t / edge % edge, t / (edge * edge)))
                .clamp(glam::IVec3::ZERO, dims - 1);
            let want = pyramid_level0(v.x as u32, v.y as u32, v.z as u32);
            assert_eq!(got, want, "level 0 brick {first} texel {t}");
        }
    }
    let mapping = level1_mapping(&root);
    let mut checked = 0;
    for level in 1..6 {
        let last =
            LevelGrid::covering_dims(level, SamplePlacement::Vertex, grid.dims()).as_ivec3() - 1;
        let edge = stored_brick_edge(N, level) as i32;
        for first in stored(&grid, level) {
            let texels = u16s(&levels.read_stored_bytes(level, first).unwrap());
            let start = stored_first_sample(first, N, level);
            for (t, &got) in texels.iter().enumerate() {
                let t = t as i32;
                let j = (start + glam::IVec3::new(t % edge, t / edge % edge, t / (edge * edge)))
                    .clamp(glam::IVec3::ZERO, last);
                let i = [j.x, j.y, j.z].map(|c| f64::from((1 << level) * c) - 0.5);
                let u = [0, 1, 2].map(|a| mapping[a].0 * i[a] + mapping[a].1);
                let want = level1_trilinear(u);
                assert!(
                    (f64::from(got) - want).abs() <= 0.51,
                    "level {level} brick {first} texel {t}: {got} against {want}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000, "{checked} samples checked");

    // The same stored bricks over HTTP.
    let server = range_server(dir);
    let remote = open(&format!("{}/ok/pyr.zarr", server.base()));
    for level in 0..6 {
        for first in stored(&grid, level).into_iter().step_by(3) {
            assert_eq!(
                remote.read_stored_bytes(level, first).unwrap(),
                levels.read_stored_bytes(level, first).unwrap(),
                "level {level} brick {first} over HTTP"
            );
        }
    }
    assert!(remote.bytes_fetched() > 0);

    let refused = |config: ZarrLevelsConfig, field: &str| match ZarrLevels::open(
        &ZarrLocation::parse(root.to_str().unwrap()).unwrap(),
        &RemoteOptions::default(),
        config,
    ) {
        Err(StreamError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
        other => panic!("expected a refusal naming {field}, got {other:?}"),
    };
    refused(
        ZarrLevelsConfig {
            levels: Some(7),
            brick_size: 4,
            ..config()
        },
        "levels",
    );
    refused(
        ZarrLevelsConfig {
            brick_size: 0,
            ..config()
        },
        "brick_size",
    );
}

fn camera() -> Camera {
    Camera::perspective(Vec3::new(0.9, 0.7, 1.3), Vec3::ZERO, 40.0)
}

fn settings() -> RenderSettings {
    RenderSettings {
        samples_per_voxel: 1.5,
        ..RenderSettings::default()
    }
}

/// The CPU reference of `renderer`'s current levels over every stored brick of `backend`.
fn reference_frame(renderer: &Renderer, backend: &dyn LevelBackend) -> Vec<Vec4> {
    let grids = backend.read_grids().unwrap();
    let levels = renderer.brick_levels().unwrap().to_vec();
    let field = LevelField::new(&backend.grid(), &grids, &levels).unwrap();
    let geometry = SlotGeometry::new(N, 3, UVec3::splat(128)).unwrap();
    let cpu = LevelReferenceCache::build_stored_as(
        &field,
        &geometry,
        Transition::Smooth,
        backend.scalar(),
    )
    .unwrap();
    let params = renderer.params(&camera(), &settings(), W, W).unwrap();
    let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
    reference::render_mixed(&cpu.view(), Transition::Smooth, &tf, &params)
}

/// The pyramid over HTTP, streamed in the background, drawn at the camera's levels: the first
/// plan finds nothing in RAM and keeps the coarsest level; once the reader catches up the
/// camera's mix of levels (at least two, some read from image level 1) is drawn, and the frame
/// matches the CPU reference over the stored bricks, with no stored brick read on the render
/// thread after attaching.
#[test]
fn a_remote_pyramid_streams_at_the_cameras_levels_and_matches_the_reference() {
    let ctx = common::validated_context();
    {
        let server = range_server(pyramid_fixture());
        let backend = Arc::new(open(&format!("{}/ok/pyr.zarr", server.base())));
        let streamer =
            Arc::new(LevelStreamer::new(backend.clone(), LevelStreamConfig::default()).unwrap());
        let tf = mixvol::optics::TransferFunction::preset(mixvol::optics::TfPreset::Bands);
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer.set_transfer_function(&tf).unwrap();
        renderer
            .set_source(VolumeSource::LevelStream {
                streamer: streamer.clone(),
                levels: &[],
                config: MixedConfig {
                    brick_size: N,
                    filter: DownsampleFilter::Mean2,
                    cache_budget_bytes: 16 << 20,
                    transition: Transition::Smooth,
                    max_levels: 0,
                },
            })
            .unwrap();
        let coarsest = renderer.brick_levels().unwrap().to_vec();
        assert!(coarsest.iter().all(|l| *l == Some(5)));
        let at_attach = streamer.stats().blocking_reads;
        let first = common::step_levels(&mut renderer, &camera(), &settings(), W, W, 3.0).unwrap();
        assert_eq!(renderer.brick_levels().unwrap(), &coarsest[..]);
        assert!(first.waiting > 0);
        let mut steps = 0;
        loop {
            assert!(streamer.wait_idle(Duration::from_secs(60)));
            let choice =
                common::step_levels(&mut renderer, &camera(), &settings(), W, W, 3.0).unwrap();
            steps += 1;
            if choice.waiting == 0 {
                break;
            }
            assert!(steps < 16, "the streamed pyramid converges");
        }
        let drawn = renderer.brick_levels().unwrap().to_vec();
        let distinct: std::collections::BTreeSet<u32> = drawn.iter().flatten().copied().collect();
        assert!(distinct.len() >= 2, "the camera mixes levels: {distinct:?}");
        assert!(distinct.iter().any(|&l| l >= 1), "{distinct:?}");
        let stats = streamer.stats();
        assert_eq!(stats.blocking_reads, at_attach, "{stats:?}");
        assert_eq!(stats.failures, 0);
        let frame = renderer.render(&camera(), &settings(), W, W).unwrap();
        let expected = reference_frame(&renderer, &*backend);
        let d = common::diff(&frame.pixels, &expected, 1.0 / 255.0);
        eprintln!("pyramid against the reference: {d:?}");
        assert!(
            d.mean < 1e-3 && d.max < 6.0 / 255.0 && d.large_fraction < 0.005,
            "GPU frame against the CPU reference: {d:?}"
        );
        let covered = expected.iter().filter(|p| p.w > 0.05).count();
        assert!(covered > expected.len() / 10, "the frame shows the volume");
        drop(renderer);
        drop(streamer);
    }
    common::finish(ctx);
}
