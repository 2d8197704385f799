//! `mixvol render --zarr-level N` renders that level of a multiscale OME-Zarr image; a level the
//! image lacks is an error naming the metadata field, and the flag on a non-Zarr volume is
//! refused. The image is written by hand here (OME-Zarr 0.4 on Zarr v2, one uncompressed chunk
//! per array); the loader itself is tested in the library's `tests/zarr.rs`.

use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh temporary folder for this test.
fn temp_dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mixvol-cli-zarr-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A u8 Zarr v2 array of `shape` (z, y, x) in one raw chunk, voxel values from `value`.
fn write_array(dir: &Path, shape: [u64; 3], value: impl Fn(u64, u64, u64) -> u8) {
    std::fs::create_dir_all(dir).unwrap();
    let meta = json!({
        "zarr_format": 2, "shape": shape, "chunks": shape, "dtype": "|u1",
        "compressor": null, "fill_value": 0, "order": "C", "filters": null,
    });
    std::fs::write(dir.join(".zarray"), meta.to_string()).unwrap();
    let mut bytes = Vec::new();
    for z in 0..shape[0] {
        for y in 0..shape[1] {
            for x in 0..shape[2] {
                bytes.push(value(z, y, x));
            }
        }
    }
    std::fs::write(dir.join("0.0.0"), bytes).unwrap();
}

fn render(root: &Path, png: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .arg("render")
        .arg("--volume")
        .arg(root)
        .args([
            "--width", "16", "--height", "16", "--frames", "1", "--output",
        ])
        .arg(png)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn cli_renders_the_chosen_zarr_level() {
    let dir = temp_dir();
    let root = dir.join("two.zarr");
    let ramp = |z: u64, y: u64, x: u64| (z * 40 + y * 7 + x * 3) as u8;
    write_array(&root.join("s0"), [8, 12, 16], ramp);
    write_array(&root.join("s1"), [4, 6, 8], ramp);
    let axes: Vec<_> = ["z", "y", "x"]
        .iter()
        .map(|n| json!({"name": n, "type": "space", "unit": "micrometer"}))
        .collect();
    let dataset = |path: &str, s: f64| json!({"path": path, "coordinateTransformations": [{"type": "scale", "scale": [s, s, s]}]});
    let multiscale = json!({
        "version": "0.4", "axes": axes,
        "datasets": [dataset("s0", 1.0), dataset("s1", 2.0)],
    });
    std::fs::write(root.join(".zgroup"), json!({"zarr_format": 2}).to_string()).unwrap();
    std::fs::write(
        root.join(".zattrs"),
        json!({ "multiscales": [multiscale] }).to_string(),
    )
    .unwrap();
    let png = dir.join("out.png");

    let finest = render(&root, &png, &[]);
    assert!(finest.status.success(), "{finest:?}");
    assert!(String::from_utf8_lossy(&finest.stdout).contains("16x12x8"));
    let coarse = render(&root, &png, &["--zarr-level", "1"]);
    assert!(coarse.status.success(), "{coarse:?}");
    assert!(String::from_utf8_lossy(&coarse.stdout).contains("8x6x4"));
    let missing = render(&root, &png, &["--zarr-level", "2"]);
    assert!(!missing.status.success());
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(
        err.contains("datasets") && err.contains("2 levels"),
        "{err}"
    );
    let not_zarr = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["render", "--volume", "ml", "--zarr-level", "1"])
        .output()
        .unwrap();
    assert!(!not_zarr.status.success());
    assert!(String::from_utf8_lossy(&not_zarr.stderr).contains("--zarr-level"));
    std::fs::remove_dir_all(&dir).ok();
}

/// The number right after `key` in `text`.
fn number_after(text: &str, key: &str) -> f64 {
    let start = text
        .find(key)
        .unwrap_or_else(|| panic!("no '{key}' in:\n{text}"))
        + key.len();
    let rest = text[start..].trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .unwrap_or(rest.len());
    rest[..end].parse().unwrap()
}

/// `render --stream --levels camera` draws a multiscale image at every level through the
/// three-level cache without converting it: vertex levels past level 0 are read from image
/// level 1, the stored bricks stream in the background, and the frame matches the CPU
/// reference over the same levels under the validation layers. `--zarr-level 1` draws the
/// image from its level 1 down the same way.
#[test]
fn cli_streams_a_pyramid_at_every_level() {
    // Its own folder: temp_dir() clears the other test's.
    let dir = std::env::temp_dir().join(format!("mixvol-cli-pyramid-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let root = dir.join("pyr.zarr");
    // A smooth ramp: lavapipe filters 8-bit textures with 8-bit weights, so steep data would
    // measure its rounding rather than the levels.
    let value = |z: u64, y: u64, x: u64| (x * 3 + y * 2 + z * 2 + 30) as u8;
    write_array(&root.join("s0"), [32, 24, 32], value);
    // Level 1 subsamples level 0 (OME-Zarr scale 2, no translation).
    write_array(&root.join("s1"), [16, 12, 16], |z, y, x| {
        value(2 * z, 2 * y, 2 * x)
    });
    let axes: Vec<_> = ["z", "y", "x"]
        .iter()
        .map(|n| json!({"name": n, "type": "space"}))
        .collect();
    let dataset = |path: &str, s: f64| json!({"path": path, "coordinateTransformations": [{"type": "scale", "scale": [s, s, s]}]});
    let multiscale = json!({
        "version": "0.4", "axes": axes,
        "datasets": [dataset("s0", 1.0), dataset("s1", 2.0)],
    });
    std::fs::write(root.join(".zgroup"), json!({"zarr_format": 2}).to_string()).unwrap();
    std::fs::write(
        root.join(".zattrs"),
        json!({ "multiscales": [multiscale] }).to_string(),
    )
    .unwrap();
    let png = dir.join("out.png");
    let args = [
        "--stream",
        "--levels",
        "camera",
        "--brick-size",
        "8",
        "--voxel-px",
        "3",
        "--compare",
        "--validation",
    ];
    let out = render(&root, &png, &args);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("at every level: vertex levels 0..5 read from image levels [0, 1, 1, 1, 1]"),
        "{text}"
    );
    assert!(text.contains("from the image's pyramid"), "{text}");
    let stream = text
        .lines()
        .find(|l| l.starts_with("level stream:"))
        .unwrap_or_else(|| panic!("no level stream line:\n{text}"));
    assert!(number_after(stream, "level stream:") > 0.0, "{text}");
    assert!(stream.contains(" 0 failed"), "{text}");
    assert!(
        number_after(&text, "max per-channel difference") < 0.06,
        "{text}"
    );
    assert!(number_after(&text, "mean") < 4e-3, "{text}");
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");

    // `--levels camera` is what `--stream` does anyway; `--zarr-level 1` draws from level 1
    // down: its voxels are level 0's stored bricks, every coarser vertex level reads it too.
    let from_level_1 = [
        "--stream",
        "--zarr-level",
        "1",
        "--brick-size",
        "4",
        "--voxel-px",
        "3",
        "--compare",
        "--validation",
    ];
    let out = render(&root, &png, &from_level_1);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("16x12x16"), "{text}");
    assert!(text.contains("read from image levels [1, 1, 1]"), "{text}");
    assert!(text.contains("level 1 down"), "{text}");
    assert!(
        number_after(&text, "max per-channel difference") < 0.06,
        "{text}"
    );
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    let two_level = render(&root, &png, &["--stream", "--levels", "all-hi"]);
    assert!(!two_level.status.success());
    assert!(String::from_utf8_lossy(&two_level.stderr).contains("two-level pattern"));
    std::fs::remove_dir_all(&dir).ok();
}
