//! Runs the embedding example host and checks depth-correct compositing analytically: where the
//! host's opaque quad (plane z = 0, left half of the image) is in front of the back half of the
//! volume, rays stop at it and the volume (16 voxels of it) composites over the quad; elsewhere
//! the whole 32-voxel path composites over the background.

#[path = "../examples/embed_host.rs"]
mod embed_host;

fn channel_close(actual: u8, expected: f32) -> bool {
    (actual as f32 - expected * 255.0).abs() <= 2.5
}

#[test]
fn volume_composites_over_host_geometry_and_stops_at_its_depth() {
    let report = embed_host::run().expect("host runs");
    assert_eq!(
        report.validation_problems, 0,
        "validation: {:#?}",
        report.messages
    );
    let size = embed_host::SIZE;
    let px = |x: u32, y: u32| report.pixels[(y * size + x) as usize];
    // The volume box spans x, y in [-0.5, 0.5]; the image shows [-0.6, 0.6]: pixel 16 is at
    // x = -0.3 (quad, inside the volume), pixel 48 at x = +0.3 (volume only), row 32 at y ~ 0.
    let with_quad = embed_host::expected(16.0, embed_host::QUAD_COLOR);
    let without = embed_host::expected(32.0, embed_host::BACKGROUND);
    for (x, y, e) in [
        (16, 32, with_quad),
        (20, 20, with_quad),
        (48, 32, without),
        (44, 44, without),
    ] {
        let p = px(x, y);
        for c in 0..3 {
            assert!(
                channel_close(p[c], e[c]),
                "pixel ({x},{y}) channel {c}: {} vs expected {}",
                p[c],
                e[c] * 255.0
            );
        }
    }
    // Outside the volume box but on the quad: the quad's own colour (x = -0.65 is outside the
    // box, inside the quad).
    let q = px(1, 32);
    for c in 0..3 {
        assert!(
            channel_close(q[c], embed_host::QUAD_COLOR[c]),
            "quad pixel {q:?}"
        );
    }
    // Without depth the left pixels would show the full 32-voxel path: make sure they differ.
    let full_over_quad = embed_host::expected(32.0, embed_host::QUAD_COLOR);
    assert!(
        !channel_close(px(16, 32)[1], full_over_quad[1]),
        "rays did not stop at the depth"
    );
}
