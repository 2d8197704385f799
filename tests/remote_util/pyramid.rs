//! The two-level OME-Zarr pyramid that ome-zarr-py writes (tests/fixtures/write_stream_pyramid.py):
//! its values recomputed here on their own, and its level-1 coordinates read from its zarr.json
//! with serde_json (not the loader). Shared by tests/remote_stream.rs and tests/zarr_levels.rs.
#![allow(dead_code)]

use std::path::Path;

/// The pyramid image's level-0 dims (x, y, z).
pub const PDIMS: [u32; 3] = [64, 32, 32];
/// Its chunk edge.
pub const PCHUNK: u32 = 16;

/// The level-0 value at (x, y, z) of tests/fixtures/write_stream_pyramid.py.
pub fn pyramid_level0(x: u32, y: u32, z: u32) -> u16 {
    (1000 + 40 * x + 300 * y + 500 * z + 60 * ((x * y + 3 * y * z) % 41)) as u16
}

/// The level-1 value at (x, y, z): the mean of the 2x2x2 block, rounded half up.
pub fn pyramid_level1(x: u32, y: u32, z: u32) -> u16 {
    let mut sum = 0u32;
    for c in 0..8 {
        sum += u32::from(pyramid_level0(
            2 * x + (c & 1),
            2 * y + ((c >> 1) & 1),
            2 * z + ((c >> 2) & 1),
        ));
    }
    ((sum + 4) / 8) as u16
}

/// The folder holding pyr.zarr (written once by ome-zarr-py).
pub fn pyramid_fixture() -> &'static Path {
    static DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        super::python_env::write_fixtures(
            "write_stream_pyramid.py",
            "stream-pyramid",
            "scripts/requirements-zarr.txt",
        )
    })
}

/// Per axis (x, y, z), the level-1 index coordinate of level-0 index coordinate `i`:
/// `(t0 - t1 + s0 * i) / s1`, from the scale and translation of both datasets in the root
/// zarr.json (read here with serde_json, not the loader).
pub fn level1_mapping(root: &Path) -> [(f64, f64); 3] {
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("zarr.json")).unwrap()).unwrap();
    let datasets = &doc["attributes"]["ome"]["multiscales"][0]["datasets"];
    let transform = |level: usize, kind: &str| -> Vec<f64> {
        let list = datasets[level]["coordinateTransformations"]
            .as_array()
            .unwrap();
        let t = list.iter().find(|t| t["type"] == kind).unwrap();
        t[kind]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    let (s0, t0) = (transform(0, "scale"), transform(0, "translation"));
    let (s1, t1) = (transform(1, "scale"), transform(1, "translation"));
    // Array axes z, y, x; volume axes x, y, z.
    [2, 1, 0].map(|a| (s0[a] / s1[a], (t0[a] - t1[a]) / s1[a]))
}

/// Trilinear interpolation of level 1 (u16 units) at level-1 index coordinates `u`, clamped.
pub fn level1_trilinear(u: [f64; 3]) -> f64 {
    let d1 = [PDIMS[0] / 2, PDIMS[1] / 2, PDIMS[2] / 2];
    let u = [0, 1, 2].map(|a| u[a].clamp(0.0, f64::from(d1[a] - 1)));
    let i0 = [0, 1, 2].map(|a| u[a].floor() as u32);
    let t = [0, 1, 2].map(|a| u[a] - f64::from(i0[a]));
    let mut sum = 0.0;
    for c in 0..8u32 {
        let mut w = 1.0;
        let mut p = [0u32; 3];
        for a in 0..3 {
            let up = (c >> a) & 1 == 1;
            p[a] = if up {
                (i0[a] + 1).min(d1[a] - 1)
            } else {
                i0[a]
            };
            w *= if up { t[a] } else { 1.0 - t[a] };
        }
        sum += w * f64::from(pyramid_level1(p[0], p[1], p[2]));
    }
    sum
}
