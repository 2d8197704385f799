//! Streaming an OME-Zarr image chunk by chunk through the planner (issue 15 item 3), against the
//! loopback servers of tests/remote_util (tests/servers/range_server.py with per-chunk fault
//! injection, moto's S3 server):
//!
//! - `streamed_bricks_are_the_in_memory_bricks_and_fetch_each_chunk_once`: every brick level
//!   packed from remote chunks (HTTP and S3) is byte-identical to the in-memory source over the
//!   loaded image (a missing chunk reads as the fill value), each chunk is requested once (the
//!   chunk cache), and the bytes fetched are exactly those of the chunks the levels read.
//! - `a_remote_render_through_the_planner_fetches_only_what_it_draws`: the offscreen renderer
//!   plans every frame over a remote image with the planner's request cut to a 24 KiB RAM budget
//!   (the bricks nearest the camera); every frame matches the CPU reference for that frame's
//!   residency, the bytes fetched are counted and are exactly the chunks of the levels loaded
//!   (each once, under half the image), both RAM budgets hold.
//! - `chunk_faults_are_typed_errors_naming_the_chunk_and_the_frame_still_renders`: HTTP 500 on
//!   one chunk (retried, then failed), a stalled response (timed out, no hang), a truncated body
//!   and a Content-Length beyond the body: the bricks the chunk feeds fail with
//!   `StreamError::Chunk` naming it (its coordinates and URL), the others load, the frame
//!   renders (those bricks absent: the image has no level 1 to fall back to, and a low-res
//!   brick derived from level 0 reads the same chunk) and matches the reference for its
//!   residency, the chunk is tried at most twice (then
//!   remembered), nothing hangs; a 500 on every chunk's first request is cured by the retry.
//! - `a_corrupt_local_chunk_is_a_typed_error_naming_it_and_other_bricks_load`: a chunk file cut
//!   short in a local image: both levels of a brick that reads it fail naming the chunk and its
//!   file, the chunk is remembered as failed, other bricks pack as from memory.
//! - `learned_value_ranges_cull_empty_bricks_before_their_hi_levels_load`: an image empty under
//!   the transfer function but for a blob in 8 of its 64 bricks, through the planner and
//!   renderer: after the low-res pass (the request cut to the low-res levels) the source knows
//!   every brick's exact range (bit for bit the in-memory source's), the next frames cull the 56
//!   empty bricks, only the 8 others load their hi-res level, and a chunk only empty bricks read
//!   is not fetched after the low-res pass; with the ranges hidden (the baseline) nothing is
//!   culled, the 62 hi-res levels the GPU cache holds load and that chunk is fetched again (the
//!   chunk cache holds two chunks; the figures are printed).
//! - `a_failed_chunk_falls_back_to_pyramid_level_1`: a two-level OME-Zarr written by
//!   ome-zarr-py (tests/fixtures/write_stream_pyramid.py) with one level-0 chunk served corrupt
//!   (then failing with HTTP 500): the low-res bricks that read it load, their texels whose
//!   filter taps meet the chunk are level 1 trilinearly resampled at the texel's position (the
//!   mapping from the multiscale's scale and translation, read from zarr.json here) within one
//!   u16 step, every other texel and every other brick is exact, neighbouring low-res bricks
//!   (fallen back or not) agree on their shared faces, only the clean bricks learn their exact
//!   value range; the hi-res levels fail naming
//!   the chunk, the degraded bricks are listed with that error and counted, level 1 is fetched
//!   only around it; through the planner and renderer no brick is drawn absent, the fed bricks
//!   are drawn low-res, the frame report names the chunk.

mod common;
mod remote_util;

use glam::{UVec3, Vec3, Vec4};
use mixvol::bricks::{
    BrickGrid, BrickSource, DownsampleFilter, Level, SourceError, ValueRange, VolumeBrickSource,
};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::reference::{self, ReferenceCache};
use mixvol::renderer::{MixedConfig, Renderer, ResidencyConfig, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings, Transition};
use mixvol::store::{BrickBackend, StreamerConfig};
use mixvol::stream::{
    open_zarr_source, StreamError, ZarrBrickSource, ZarrBricks, ZarrStreamConfig,
};
use mixvol::volume::formats::{RemoteOptions, ZarrLocation};
use mixvol::volume::{marschner_lobb_value, Volume};
use remote_util::pyramid::*;
use remote_util::*;
use std::collections::BTreeSet;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

const DIM: u64 = 64;
const CHUNK: u64 = 16;
const N: u32 = 8;
const FILL: u16 = 40_000;
/// Chunk (z, y, x) left out of the store: it reads as [`FILL`].
const MISSING: [u64; 3] = [3, 3, 3];
/// The chunk left out for the render tests: away from the corner they draw.
const FAR: [u64; 3] = [0, 0, 0];
const CHUNK_BYTES: u64 = CHUNK * CHUNK * CHUNK * 2;

fn spec(missing: [u64; 3]) -> ImageSpec {
    ImageSpec {
        shape: [DIM; 3],
        chunks: [CHUNK; 3],
        v3: true,
        missing: Some(missing),
        fill: FILL,
    }
}

/// A smooth u16 field (Marschner-Lobb), so that images compare with the reference tolerances.
fn smooth(x: u64, y: u64, z: u64) -> u16 {
    let c = Vec3::new(x as f32, y as f32, z as f32) + 0.5;
    let ml = marschner_lobb_value(2.0 * c / DIM as f32 - Vec3::ONE);
    ((0.15 + 0.7 * ml) * 65535.0).round() as u16
}

/// Writes the image, chunk `missing` (z, y, x) left out, into `dir/img.zarr`; returns its chunk
/// count and the loaded volume.
fn write_image(dir: &Path, missing: [u64; 3]) -> (usize, Volume) {
    let root = dir.join("img.zarr");
    let chunks = spec(missing).write_with(&root, smooth);
    let volume = mixvol::volume::load_zarr(&root).unwrap().volume;
    (chunks, volume)
}

fn stream_config(concurrency: usize) -> ZarrStreamConfig {
    ZarrStreamConfig {
        brick_size: N,
        filter: DownsampleFilter::Mean2,
        concurrency,
        chunk_cache_bytes: 1 << 20,
        value_range: None,
    }
}

fn at(url: &str) -> ZarrLocation {
    ZarrLocation::parse(url).unwrap()
}

#[test]
fn streamed_bricks_are_the_in_memory_bricks_and_fetch_each_chunk_once() {
    let dir = TempDir::new("stream-bricks");
    let (_, volume) = write_image(&dir.0, MISSING);
    let memory = VolumeBrickSource::new(Arc::new(volume), N, DownsampleFilter::Mean2).unwrap();
    let grid = memory.grid();
    let server = range_server(&dir.0);
    let moto = moto_server();
    s3_upload(&moto, &dir.0.join("img.zarr"), "stream", "img.zarr");
    let bricks: Vec<u32> = [[0, 0, 0], [3, 4, 5], [6, 6, 6], [7, 7, 7], [7, 6, 0]]
        .iter()
        .map(|&c| grid.linear_index(UVec3::from_array(c)) as u32)
        .collect();
    let sources = [
        (
            ZarrBricks::open(
                &at(&format!("{}/ok/img.zarr", server.base())),
                0,
                &quick(1, 5000),
                stream_config(4),
            )
            .unwrap(),
            true,
        ),
        (
            ZarrBricks::open(
                &at("s3://stream/img.zarr"),
                0,
                &moto_options(&moto),
                stream_config(1),
            )
            .unwrap(),
            false,
        ),
    ];
    for (zarr, http) in &sources {
        let mut chunks = BTreeSet::new();
        for &b in &bricks {
            for level in [Level::Hi, Level::Lo] {
                let streamed = zarr.read_brick(b, level).unwrap();
                let expected = memory.brick_bytes(b, level).unwrap().unwrap();
                assert_eq!(&streamed[..], &expected[..], "brick {b} {level:?}");
                chunks.extend(
                    zarr.chunks_for(b, level)
                        .unwrap()
                        .iter()
                        .map(|c| c.to_array()),
                );
            }
        }
        // The corner brick holds the missing chunk's fill value.
        let corner = zarr.read_brick(bricks[3], Level::Hi).unwrap();
        let values: &[u16] = bytemuck::cast_slice(&corner);
        assert!(values.contains(&FILL));
        // Each chunk once (the cache), the missing one for nothing.
        let missing = UVec3::new(MISSING[2] as u32, MISSING[1] as u32, MISSING[0] as u32);
        let present = chunks.iter().filter(|&&c| c != missing.to_array()).count() as u64;
        assert!(chunks.contains(&missing.to_array()));
        let stats = zarr.cache_stats();
        assert_eq!(stats.fetches as usize, chunks.len(), "{stats:?}");
        assert!(stats.hits > 0, "{stats:?}");
        assert_eq!(zarr.chunks().chunks_read() as usize, chunks.len());
        assert_eq!(zarr.chunks().bytes_fetched(), present * CHUNK_BYTES);
        assert!(chunks.len() < 64 / 2, "{} of 64 chunks", chunks.len());
        if *http {
            // Chunk (x, y, z) = (1, 2, 2) feeds brick (3, 4, 5) at both levels: one GET.
            assert_eq!(request_count(&server, "/ok/img.zarr/0/c/2/2/1"), 1);
        }
    }
}

/// Half the world-space box: spacing 0.5, 1, 2 (x, y, z), the longest side 1.
const HALF: Vec3 = Vec3::new(0.125, 0.25, 0.5);

fn corner_settings() -> RenderSettings {
    RenderSettings {
        samples_per_voxel: 1.5,
        ..RenderSettings::default()
    }
}

fn corner_camera() -> Camera {
    Camera::perspective(Vec3::new(0.7, 0.8, 1.4), 0.8 * HALF, 30.0)
}

const SIZE: u32 = 48;

/// A planned renderer over `source`; `ram_bytes` cuts the planner's requests (nearest bricks
/// first).
fn renderer_over(
    ctx: &mixvol::gpu::GpuContext,
    source: Arc<ZarrBrickSource>,
    ram_bytes: Option<u64>,
) -> Renderer {
    renderer_of(ctx, source, ram_bytes, N)
}

/// [`renderer_over`] with bricks of edge `n`.
fn renderer_of(
    ctx: &mixvol::gpu::GpuContext,
    source: Arc<dyn BrickSource>,
    ram_bytes: Option<u64>,
    n: u32,
) -> Renderer {
    let mut renderer = Renderer::new(ctx, TargetFormat::Rgba32Float).unwrap();
    renderer
        .set_transfer_function(&TransferFunction::preset(TfPreset::Bands))
        .unwrap();
    renderer.set_residency_config(ResidencyConfig {
        ram_bytes,
        ..ResidencyConfig::default()
    });
    renderer
        .set_source(VolumeSource::Bricks {
            source,
            config: MixedConfig {
                brick_size: n,
                filter: DownsampleFilter::Mean2,
                cache_budget_bytes: 1 << 20,
                transition: Transition::Smooth,
                max_levels: 0,
            },
        })
        .unwrap();
    assert!(renderer.is_planned());
    renderer
}

/// The image the CPU reference draws for `renderer`'s current residency, over `volume`.
fn reference_image(renderer: &Renderer, volume: &Volume, camera: &Camera) -> Vec<Vec4> {
    let cache = ReferenceCache::build(
        volume,
        DownsampleFilter::Mean2,
        renderer.brick_cache().unwrap(),
        volume.scalar_type(),
        Transition::Smooth,
    )
    .unwrap();
    let params = renderer
        .params(camera, &corner_settings(), SIZE, SIZE)
        .unwrap();
    reference::render_mixed(
        &cache.view(),
        Transition::Smooth,
        &TransferFunction::preset(TfPreset::Bands),
        &params,
    )
}

/// Renders until nothing waits for the source, or the source has loaded all it was asked for
/// and the frame changed nothing (at most `frames`), checking every frame against the
/// reference; returns the last frame's report.
fn render_until_settled(
    name: &str,
    renderer: &mut Renderer,
    source: &ZarrBrickSource,
    volume: &Volume,
    frames: usize,
) -> mixvol::embed::FrameReport {
    let camera = corner_camera();
    let settings = corner_settings();
    let mut last = None;
    for f in 0..frames {
        let frame = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
        let report = frame.residency.clone().expect("a planned frame");
        let expected = reference_image(renderer, volume, &camera);
        common::assert_frame_matches(&format!("{name}-{f:02}"), &frame, &expected);
        // Steady: nothing left to load, nothing changed this frame.
        let done = f > 0
            && (report.plan.waiting_for_source == 0
                || (source.is_settled() && report.residency.uploaded_bricks == 0));
        last = Some(report);
        if done {
            break;
        }
        assert!(
            source.wait_settled(Duration::from_secs(30)),
            "{name}: never settles"
        );
    }
    last.unwrap()
}

#[test]
fn a_remote_render_through_the_planner_fetches_only_what_it_draws() {
    let dir = TempDir::new("stream-render");
    // The missing chunk lies outside the corner: the frame never asks for it (the fill's jump
    // would also make the image too sensitive to sample positions for the tolerances).
    let (chunk_count, volume) = write_image(&dir.0, FAR);
    let server = range_server(&dir.0);
    let ctx = common::validated_context();
    {
        let source = Arc::new(
            open_zarr_source(
                &at(&format!("{}/ok/img.zarr", server.base())),
                0,
                &quick(1, 5000),
                stream_config(4),
                StreamerConfig {
                    ram_budget_bytes: 4 << 20,
                    record_load_order: false,
                },
            )
            .unwrap(),
        );
        // The planner's request is cut to 24 KiB of brick levels (96 of the 512 low-res bricks,
        // nearest the camera first).
        let mut renderer = renderer_over(&ctx, source.clone(), Some(24 << 10));
        let report = render_until_settled("stream-render", &mut renderer, &source, &volume, 12);
        assert_eq!(report.source_errors, 0, "{report:?}");
        // What the cut request holds is drawn; the rest waits (a low-res brick needs its
        // level-0 chunks, so low-res bricks fill the request before any hi-res one).
        assert!(report.plan.requests_cut > 0, "{report:?}");
        assert!(report.plan.drawn_lo >= 90, "{report:?}");
        assert_eq!(
            report.plan.drawn_lo + report.plan.drawn_hi,
            source.resident().len(),
            "{report:?}"
        );
        // Exactly the chunks of the levels loaded were fetched (nothing was evicted: the
        // streamer's budget holds them all), each once, and far less than the image.
        let zarr = source.store();
        let mut chunks = BTreeSet::new();
        for (brick, level) in source.resident() {
            chunks.extend(
                zarr.chunks_for(brick, level)
                    .unwrap()
                    .iter()
                    .map(|c| c.to_array()),
            );
        }
        assert_eq!(source.stats().evictions, 0);
        let far = [FAR[2] as u32, FAR[1] as u32, FAR[0] as u32];
        let present = chunks.iter().filter(|&&c| c != far).count() as u64;
        let fetched = zarr.chunks().bytes_fetched();
        let total = chunk_count as u64 * CHUNK_BYTES;
        assert_eq!(fetched, present * CHUNK_BYTES, "{chunks:?}");
        assert_eq!(zarr.cache_stats().fetches as usize, chunks.len());
        assert!(fetched * 2 < total, "{fetched} of {total} bytes fetched");
        let stats = source.stats();
        assert!(stats.peak_bytes <= 4 << 20, "{stats:?}");
        let cache = source.store().cache_stats();
        assert!(cache.peak_bytes <= cache.budget_bytes, "{cache:?}");
        drop(renderer);
    }
    common::finish(ctx);
}

/// The error `source` reports for `brick` at `level`, as the chunk it names.
fn chunk_error(source: &ZarrBrickSource, brick: u32, level: Level) -> ([u32; 3], String) {
    match source.brick_bytes(brick, level) {
        Err(SourceError::Load { source: e, .. }) => match e.downcast_ref::<StreamError>() {
            Some(StreamError::Brick { source: inner, .. }) => match &**inner {
                StreamError::Chunk { chunk, object, .. } => (*chunk, object.clone()),
                other => panic!("expected a chunk error, got {other}"),
            },
            _ => panic!("expected a StreamError, got {e}"),
        },
        other => panic!("expected a load error for brick {brick} {level:?}, got {other:?}"),
    }
}

#[test]
fn chunk_faults_are_typed_errors_naming_the_chunk_and_the_frame_still_renders() {
    let dir = TempDir::new("stream-faults");
    let (_, volume) = write_image(&dir.0, FAR);
    let server = range_server(&dir.0);
    let base = server.base();
    // Chunk (x, y, z) = (2, 3, 3): key 0/c/3/3/2. It feeds bricks 4..=6 along x, 6..=7 along
    // y and z (with borders and filter taps).
    let bad = UVec3::new(2, 3, 3);
    let key = "0/c/3/3/2";
    let ctx = common::validated_context();
    {
        for mode in ["500", "stall", "truncate", "longlen"] {
            let prefix = format!("{mode}@{}", key.replace('/', "~"));
            let url = format!("{base}/{prefix}/img.zarr");
            let start = Instant::now();
            let source = Arc::new(
                open_zarr_source(
                    &at(&url),
                    0,
                    &quick(1, 2000),
                    stream_config(4),
                    StreamerConfig {
                        ram_budget_bytes: 4 << 20,
                        record_load_order: false,
                    },
                )
                .unwrap(),
            );
            let mut renderer = renderer_over(&ctx, source.clone(), None);
            let report = render_until_settled(mode, &mut renderer, &source, &volume, 12);
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "{mode}: {:?}",
                start.elapsed()
            );
            assert!(report.source_errors > 0, "{mode}: {report:?}");
            let first = report.first_source_error.clone().unwrap_or_default();
            assert!(first.contains(&format!("{url}/{key}")), "{mode}: {first}");
            assert!(
                report.plan.drawn_hi + report.plan.drawn_lo > 0,
                "{report:?}"
            );
            let grid = source.grid();
            let fed = grid.linear_index(UVec3::new(5, 7, 7)) as u32;
            for level in [Level::Hi, Level::Lo] {
                let (chunk, object) = chunk_error(&source, fed, level);
                assert_eq!(chunk, bad.to_array(), "{mode}");
                assert_eq!(object, format!("{url}/{key}"), "{mode}");
            }
            // A corner brick that does not read the chunk loaded.
            let clean = grid.linear_index(UVec3::new(7, 6, 6)) as u32;
            assert!(
                !source
                    .store()
                    .chunks_for(clean, Level::Hi)
                    .unwrap()
                    .contains(&bad)
                    && source.is_loaded(clean, Level::Hi),
                "{mode}"
            );
            // Tried once and retried at most once, then remembered, not fetched again.
            let tries = request_count(&server, &format!("/{prefix}/img.zarr/{key}"));
            assert!((1..=2).contains(&tries), "{mode}: {tries} tries");
            drop(renderer);
        }
        // A 500 on every chunk's first request: the retry cures it, nothing fails.
        let url = format!("{base}/500once/img.zarr");
        let source = Arc::new(
            open_zarr_source(
                &at(&url),
                0,
                &quick(2, 5000),
                stream_config(4),
                StreamerConfig {
                    ram_budget_bytes: 4 << 20,
                    record_load_order: false,
                },
            )
            .unwrap(),
        );
        let mut renderer = renderer_over(&ctx, source.clone(), None);
        let report = render_until_settled("500once", &mut renderer, &source, &volume, 12);
        assert_eq!(report.source_errors, 0, "{report:?}");
        assert!(report.plan.drawn_hi > 0, "{report:?}");
        assert_eq!(request_count(&server, "/500once/img.zarr/0/c/2/2/2"), 2);
        drop(renderer);
    }
    common::finish(ctx);
}

#[test]
fn a_corrupt_local_chunk_is_a_typed_error_naming_it_and_other_bricks_load() {
    let dir = TempDir::new("stream-corrupt");
    let (_, volume) = write_image(&dir.0, FAR);
    // Chunk (x, y, z) = (1, 0, 0) cut to half its bytes: it does not decode.
    let file = dir.0.join("img.zarr/0/c/0/0/1");
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    let zarr = ZarrBricks::open(
        &ZarrLocation::Local(dir.0.join("img.zarr")),
        0,
        &RemoteOptions::default(),
        stream_config(2),
    )
    .unwrap();
    let grid = zarr.grid();
    let fed = grid.linear_index(UVec3::new(2, 0, 0)) as u32;
    for level in [Level::Hi, Level::Lo] {
        match zarr.read_brick(fed, level) {
            Err(StreamError::Brick { brick, source, .. }) => {
                assert_eq!(brick, fed);
                match *source {
                    StreamError::Chunk { chunk, object, .. } => {
                        assert_eq!(chunk, [1, 0, 0]);
                        assert_eq!(Path::new(&object), file);
                    }
                    other => panic!("expected a chunk error, got {other}"),
                }
            }
            other => panic!("expected a brick error, got {other:?}"),
        }
    }
    // Remembered: the corrupt chunk is read once, not once per brick level.
    assert_eq!(zarr.cache_stats().failed_chunks, 1);
    // A brick that does not read it is packed as from memory.
    let memory = VolumeBrickSource::new(Arc::new(volume), N, DownsampleFilter::Mean2).unwrap();
    let clean = grid.linear_index(UVec3::new(7, 7, 7)) as u32;
    assert_eq!(
        &zarr.read_brick(clean, Level::Hi).unwrap()[..],
        &memory.brick_bytes(clean, Level::Hi).unwrap().unwrap()[..]
    );
}

/// Brick edge of the pyramid tests.
const PN: u32 = 16;
/// The error inside a `StreamError::Brick`, or the error itself, as the chunk it names.
fn named_chunk(e: &StreamError) -> ([u32; 3], String) {
    match e {
        StreamError::Brick { source, .. } => named_chunk(source),
        StreamError::Chunk { chunk, object, .. } => (*chunk, object.clone()),
        other => panic!("expected a chunk error, got {other}"),
    }
}

#[test]
fn a_failed_chunk_falls_back_to_pyramid_level_1() {
    let dir = pyramid_fixture();
    let root = dir.join("pyr.zarr");
    let mapping = level1_mapping(&root);
    let server = range_server(dir);
    let dims = UVec3::from_array(PDIMS);
    let count = (dims.x * dims.y * dims.z) as usize;
    let values: Vec<u16> = (0..count as u32)
        .map(|i| pyramid_level0(i % dims.x, (i / dims.x) % dims.y, i / (dims.x * dims.y)))
        .collect();
    let volume = Volume::new(dims, Vec3::ONE, mixvol::volume::VoxelData::U16(values)).unwrap();
    let memory = VolumeBrickSource::new(Arc::new(volume), PN, DownsampleFilter::Mean2).unwrap();
    let grid = memory.grid();
    // Level-0 chunk (x, y, z) = (3, 0, 0): voxels x 48..64, y 0..16, z 0..16. The low-res (and
    // hi-res) levels of the bricks x = 2, 3 read it (brick 2's low-res taps reach voxel 48).
    let bad = UVec3::new(3, 0, 0);
    let key = "s0/c/0/0/3";
    let fed = |b: UVec3| b.x >= 2;
    let bad_lo = bad * PCHUNK;
    let bad_hi = bad_lo + UVec3::splat(PCHUNK);
    let config = ZarrStreamConfig {
        brick_size: PN,
        ..stream_config(4)
    };
    let taps: Vec<i64> = DownsampleFilter::Mean2.taps().iter().map(|t| t.0).collect();
    assert_eq!(taps, [-1, 0], "Mean2 averages voxels 2k - 1 and 2k");
    let e = PN / 2 + 1;
    let kmax = (dims + UVec3::ONE) / 2;
    for mode in ["corrupt", "500"] {
        let prefix = format!("{mode}@{}", key.replace('/', "~"));
        let url = format!("{}/{prefix}/pyr.zarr", server.base());
        let zarr = ZarrBricks::open(&at(&url), 0, &quick(1, 2000), config).unwrap();
        let mut replaced = 0;
        for brick in grid.bricks() {
            let b = grid.linear_index(brick) as u32;
            assert_eq!(
                zarr.chunks_for(b, Level::Lo).unwrap().contains(&bad),
                fed(brick),
                "{brick}"
            );
            let expected_lo = memory.brick_bytes(b, Level::Lo).unwrap().unwrap();
            let lo = zarr.read_brick(b, Level::Lo).unwrap();
            if !fed(brick) {
                assert_eq!(&lo[..], &expected_lo[..], "{mode}: clean brick {brick} Lo");
                let hi = zarr.read_brick(b, Level::Hi).unwrap();
                let expected_hi = memory.brick_bytes(b, Level::Hi).unwrap().unwrap();
                assert_eq!(&hi[..], &expected_hi[..], "{mode}: clean brick {brick} Hi");
                continue;
            }
            // A texel whose sample's taps (voxels 2k - 1, 2k per axis, clamped) meet the failed
            // chunk comes from level 1, resampled at its position; the others are level 0's.
            let got: &[u16] = bytemuck::cast_slice(&lo);
            let from_level0: &[u16] = bytemuck::cast_slice(&expected_lo);
            for z in 0..e {
                for y in 0..e {
                    for x in 0..e {
                        let j = UVec3::new(x, y, z);
                        let k = (brick * (PN / 2) + j).min(kmax);
                        let meets = (0..3).all(|a| {
                            let last = dims[a] as i64 - 1;
                            let first = (2 * k[a] as i64 - 1).clamp(0, last);
                            let end = (2 * k[a] as i64).clamp(0, last);
                            first < bad_hi[a] as i64 && bad_lo[a] as i64 <= end
                        });
                        let t = (x + e * (y + e * z)) as usize;
                        if meets {
                            let u = [0, 1, 2].map(|a| {
                                let (s, o) = mapping[a];
                                s * (2.0 * f64::from(k[a]) - 0.5) + o
                            });
                            let want = level1_trilinear(u).round();
                            assert!(
                                (f64::from(got[t]) - want).abs() <= 1.0,
                                "{mode}: brick {brick} texel {j}: {} from level 1, expected {want}",
                                got[t]
                            );
                            replaced += 1;
                        } else {
                            assert_eq!(got[t], from_level0[t], "{mode}: brick {brick} texel {j}");
                        }
                    }
                }
            }
            // The hi-res level fails, naming the chunk.
            match zarr.read_brick(b, Level::Hi) {
                Err(e) => assert_eq!(named_chunk(&e), (bad.to_array(), format!("{url}/{key}"))),
                Ok(_) => panic!("{mode}: brick {brick} Hi loaded from a failed chunk"),
            }
        }
        // The degraded bricks are recorded with the level-0 chunk's typed error, and counted.
        let degraded = zarr.degraded_bricks();
        let fed_bricks: Vec<u32> = grid
            .bricks()
            .filter(|&b| fed(b))
            .map(|b| grid.linear_index(b) as u32)
            .collect();
        assert_eq!(
            degraded.iter().map(|d| d.0).collect::<Vec<_>>(),
            fed_bricks,
            "{mode}"
        );
        for (_, e) in &degraded {
            assert!(matches!(**e, StreamError::Chunk { .. }), "{mode}: {e}");
            assert_eq!(named_chunk(e), (bad.to_array(), format!("{url}/{key}")));
        }
        // Only the bricks packed from level 0 alone learned their exact range.
        let learned = zarr.learned_value_ranges().unwrap();
        assert_eq!(zarr.learned_ranges(), grid.brick_count() - fed_bricks.len());
        for brick in grid.bricks() {
            let b = grid.linear_index(brick);
            let want = match fed(brick) {
                true => ValueRange { min: 0.0, max: 1.0 },
                false => memory.value_ranges()[b],
            };
            assert_eq!(learned[b], want, "{mode}: brick {brick}");
        }
        let stats = zarr.fallback_stats();
        assert_eq!(stats.level, Some(1), "{mode}: {stats:?}");
        assert_eq!(stats.bricks, fed_bricks.len(), "{mode}: {stats:?}");
        assert_eq!(stats.samples, replaced, "{mode}: {stats:?}");
        assert!(replaced > 0 && stats.bytes_fetched > 0, "{mode}: {stats:?}");
        // Level 1 is read only around the failed chunk: its chunk x = 1 (voxels 16..32).
        assert_eq!(stats.cache.fetches, 1, "{mode}: {stats:?}");
        // The failed chunk was tried once (and retried at most once), then remembered.
        let tries = request_count(&server, &format!("/{prefix}/pyr.zarr/{key}"));
        assert!((1..=2).contains(&tries), "{mode}: {tries} tries");
        // Neighbouring low-res bricks store the same samples on their shared face, whether
        // one, both or neither fell back (what keeps the low-res function one continuous
        // function): along x between bricks 1 | 2 (clean | fed) and 2 | 3 (both fed), and
        // along y and z between fed bricks.
        for (a, b, axis) in [
            ([1, 0, 0], [2, 0, 0], 0),
            ([2, 1, 1], [3, 1, 1], 0),
            ([2, 0, 1], [2, 1, 1], 1),
            ([3, 1, 0], [3, 1, 1], 2),
        ] {
            let read = |c: [u32; 3]| {
                let b = grid.linear_index(UVec3::from_array(c)) as u32;
                let bytes = zarr.read_brick(b, Level::Lo).unwrap();
                bytemuck::cast_slice::<u8, u16>(&bytes).to_vec()
            };
            let (lo, hi) = (read(a), read(b));
            for v in 0..e {
                for u in 0..e {
                    let mut on_lo = UVec3::new(u, v, u);
                    on_lo[(axis + 1) % 3] = u;
                    on_lo[(axis + 2) % 3] = v;
                    let mut on_hi = on_lo;
                    (on_lo[axis], on_hi[axis]) = (e - 1, 0);
                    let t = |p: UVec3| (p.x + e * (p.y + e * p.z)) as usize;
                    assert_eq!(lo[t(on_lo)], hi[t(on_hi)], "{mode}: face {a:?} | {b:?}");
                }
            }
        }
    }

    // Through the planner and the renderer: nothing in the failed chunk's region is drawn
    // absent, the bricks it feeds are drawn low-res, the frame names the chunk's error.
    let ctx = common::validated_context();
    {
        let url = format!(
            "{}/corrupt@{}/pyr.zarr",
            server.base(),
            key.replace('/', "~")
        );
        let source = Arc::new(
            open_zarr_source(
                &at(&url),
                0,
                &quick(1, 2000),
                config,
                StreamerConfig::default(),
            )
            .unwrap(),
        );
        let mut renderer = renderer_of(&ctx, source.clone(), None, PN);
        let camera = Camera::perspective(Vec3::new(0.9, 0.7, 1.6), Vec3::ZERO, 35.0);
        let settings = corner_settings();
        let mut report = None;
        for _ in 0..8 {
            renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
            let r = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
            let settled = source.wait_settled(Duration::from_secs(30));
            let r = r.residency.clone().expect("a planned frame");
            let done = settled && r.plan.is_settled() && r.plan.drawn_absent == 0;
            report = Some(r);
            if done {
                break;
            }
        }
        let report = report.unwrap();
        assert_eq!(report.plan.culled, 0, "{report:?}");
        assert_eq!(report.plan.drawn_absent, 0, "{report:?}");
        let levels = renderer.brick_cache().unwrap().levels();
        for brick in grid.bricks() {
            let want = if fed(brick) { Level::Lo } else { Level::Hi };
            assert_eq!(
                levels[grid.linear_index(brick)],
                want,
                "{brick}: {report:?}"
            );
        }
        assert!(report.source_errors > 0, "{report:?}");
        let first = report.first_source_error.clone().unwrap_or_default();
        assert!(first.contains(&format!("{url}/{key}")), "{first}");
        assert_eq!(source.store().fallback_stats().bricks, 8);
        drop(renderer);
    }
    common::finish(ctx);
}

/// A streamed source whose value ranges stay the conservative ones (what the pass saw before the
/// source learned ranges): the baseline of the culling test.
struct Conservative(Arc<ZarrBrickSource>);

impl BrickSource for Conservative {
    fn grid(&self) -> BrickGrid {
        self.0.grid()
    }
    fn scalar(&self) -> mixvol::volume::ScalarType {
        self.0.scalar()
    }
    fn filter(&self) -> DownsampleFilter {
        self.0.filter()
    }
    fn spacing(&self) -> Vec3 {
        self.0.spacing()
    }
    fn value_ranges(&self) -> &[ValueRange] {
        self.0.value_ranges()
    }
    fn value_range(&self) -> ValueRange {
        self.0.value_range()
    }
    fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError> {
        self.0.brick_bytes(brick, level)
    }
    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        self.0.is_loaded(brick, level)
    }
    fn request_levels(&self, requests: &[(u32, Level, f32)]) -> Result<(), SourceError> {
        self.0.request_levels(requests)
    }
}

#[test]
fn learned_value_ranges_cull_empty_bricks_before_their_hi_levels_load() {
    let dir = TempDir::new("stream-learn");
    let root = dir.0.join("img.zarr");
    // 64^3 u16 in 16^3 chunks, zero (transparent under Bands) but for a blob in voxels 12..28
    // per axis: 8 of the 64 bricks of 16^3 (2 per axis) read it.
    let spec = ImageSpec {
        shape: [DIM; 3],
        chunks: [CHUNK; 3],
        v3: true,
        missing: None,
        fill: 0,
    };
    let inside = |v: u64| (12..28).contains(&v);
    spec.write_with(&root, |x, y, z| {
        if inside(x) && inside(y) && inside(z) {
            30_000 + 500 * ((x + 2 * y + 3 * z) % 11) as u16
        } else {
            0
        }
    });
    let volume = mixvol::volume::load_zarr(&root).unwrap().volume;
    let memory = VolumeBrickSource::new(Arc::new(volume), PN, DownsampleFilter::Mean2).unwrap();
    let grid = memory.grid();
    let exact = memory.value_ranges().to_vec();
    let empty: Vec<bool> = exact.iter().map(|r| r.max == 0.0).collect();
    let full: Vec<u32> = (0..grid.brick_count() as u32)
        .filter(|&b| !empty[b as usize])
        .collect();
    assert_eq!(full.len(), 8, "{exact:?}");
    let server = range_server(&dir.0);
    let url = format!("{}/ok/img.zarr", server.base());
    // Chunk (3, 3, 3) is read by empty bricks only.
    let far = "/ok/img.zarr/0/c/3/3/3";
    let lo_bytes = grid.brick_count() as u64 * 9 * 9 * 9 * 2;
    let camera = Camera::perspective(Vec3::new(1.3, 1.1, 2.2), Vec3::ZERO, 35.0);
    let settings = corner_settings();
    let ctx = common::validated_context();
    {
        let mut figures = Vec::new();
        for learn in [true, false] {
            let before = request_count(&server, far);
            let source = Arc::new(
                open_zarr_source(
                    &at(&url),
                    0,
                    &quick(1, 5000),
                    ZarrStreamConfig {
                        brick_size: PN,
                        // Two chunks: the hi-res pass fetches again what it needs.
                        chunk_cache_bytes: 2 * CHUNK_BYTES as usize,
                        ..stream_config(4)
                    },
                    StreamerConfig {
                        ram_budget_bytes: 4 << 20,
                        record_load_order: true,
                    },
                )
                .unwrap(),
            );
            let shown: Arc<dyn BrickSource> = match learn {
                true => source.clone(),
                false => Arc::new(Conservative(source.clone())),
            };
            // The low-res pass: the request cut to the 64 Lo levels.
            let mut renderer = renderer_of(&ctx, shown, Some(lo_bytes), PN);
            renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
            assert!(source.wait_settled(Duration::from_secs(30)));
            let lo_pass = source.loaded_order();
            assert_eq!(lo_pass.len(), grid.brick_count(), "{lo_pass:?}");
            assert!(lo_pass.iter().all(|l| l.1 == Level::Lo), "{lo_pass:?}");
            let zarr = source.store();
            let lo_fetches = zarr.cache_stats().fetches;
            let far_lo = request_count(&server, far) - before;
            assert!(far_lo >= 1, "the Lo pass reads chunk (3, 3, 3)");
            // Every brick's exact range is known now, bit for bit the in-memory source's.
            assert_eq!(zarr.learned_ranges(), grid.brick_count());
            assert_eq!(&source.learned_value_ranges().unwrap()[..], &exact[..]);
            // Then without the cut, until settled.
            renderer.set_residency_config(ResidencyConfig::default());
            let mut report = None;
            for _ in 0..10 {
                let frame = renderer.render(&camera, &settings, SIZE, SIZE).unwrap();
                let r = frame.residency.clone().expect("a planned frame");
                let settled = source.wait_settled(Duration::from_secs(30));
                let done = settled && r.plan.is_settled() && r.plan.waiting_for_source == 0;
                report = Some(r);
                if done {
                    break;
                }
            }
            let report = report.unwrap();
            let hi: BTreeSet<u32> = source
                .loaded_order()
                .iter()
                .filter(|l| l.1 == Level::Hi)
                .map(|l| l.0)
                .collect();
            let far_all = request_count(&server, far) - before;
            let c = zarr.cache_stats();
            let s = source.stats();
            figures.push(format!(
                "learned ranges {learn}: culled {}, Hi loaded {}, chunk fetches {} (Lo pass {}), \
                 stored bytes fetched {}, packed bytes {}, chunk (3,3,3) requested {far_all}x \
                 ({far_lo}x in the Lo pass)",
                report.plan.culled,
                hi.len(),
                c.fetches,
                lo_fetches,
                zarr.chunks().bytes_fetched(),
                s.bytes_read
            ));
            if learn {
                // The empty bricks are culled, and their hi-res levels never load: no chunk
                // is fetched for them after the low-res pass.
                assert_eq!(
                    report.plan.culled,
                    grid.brick_count() - full.len(),
                    "{report:?}"
                );
                assert_eq!(report.plan.drawn_hi, full.len(), "{report:?}");
                assert_eq!(hi, full.iter().copied().collect(), "{report:?}");
                assert_eq!(far_all, far_lo, "chunk (3, 3, 3) fetched after the Lo pass");
            } else {
                assert_eq!(report.plan.culled, 0, "{report:?}");
                // As many hi-res levels as the 63 cache slots hold.
                assert_eq!(hi.len(), report.plan.drawn_hi, "{report:?}");
                assert!(hi.len() > 7 * full.len(), "{report:?}");
                assert!(far_all > far_lo, "{far_all} {far_lo}");
            }
            drop(renderer);
        }
        for f in &figures {
            eprintln!("{f}");
        }
    }
    common::finish(ctx);
}
