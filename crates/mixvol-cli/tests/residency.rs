//! `mixvol render` with camera-driven residency: a volume under `--gpu-budget-mb` checked
//! against the CPU reference, a turntable with its per-frame log, a brick store streamed under
//! a RAM budget smaller than the store drawing the same image as the volume in memory, and
//! keyframe files with errors that name the field.

use mixvol::bricks::DownsampleFilter;
use mixvol::store::write_level_store;
use mixvol::volume::{ScalarType, SyntheticField};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mixvol() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mixvol-residency-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn run(args: &[&str]) -> (Output, String) {
    let out = mixvol().args(args).output().unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out, text)
}

/// The number printed right after `key` in `text`.
fn number_after(text: &str, key: &str) -> f64 {
    let start = text
        .find(key)
        .unwrap_or_else(|| panic!("no '{key}' in:\n{text}"))
        + key.len();
    let rest = text[start..].trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .unwrap_or(rest.len());
    rest[..end]
        .parse()
        .unwrap_or_else(|e| panic!("'{}' after '{key}': {e}\n{text}", &rest[..end]))
}

/// `(hi, lo)` bricks drawn, from the residency line (`residency: [hi, lo] bricks drawn per
/// level, ...`).
fn drawn(text: &str) -> (usize, usize) {
    let line = text
        .lines()
        .find_map(|l| l.strip_prefix("residency: ["))
        .unwrap_or_else(|| panic!("no residency line in:\n{text}"));
    let counts: Vec<usize> = line[..line.find(']').unwrap()]
        .split(", ")
        .map(|c| c.parse().unwrap())
        .collect();
    assert_eq!(counts.len(), 2, "two levels: {line}");
    (counts[0], counts[1])
}

fn pixels(path: &Path) -> image::RgbaImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgba8()
}

/// Largest per-channel difference of two images of the same size.
fn max_difference(a: &image::RgbaImage, b: &image::RgbaImage) -> u8 {
    assert_eq!(a.dimensions(), b.dimensions());
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0)
}

/// Fraction of pixels that differ from the background by more than 8/255 in some channel.
fn covered(img: &image::RgbaImage, background: [u8; 3]) -> f64 {
    let n = img
        .pixels()
        .filter(|p| (0..3).any(|c| p.0[c].abs_diff(background[c]) > 8))
        .count();
    n as f64 / (img.width() * img.height()) as f64
}

const BACKGROUND: [u8; 3] = [20, 20, 26];

/// A `render --compare --validation` run's verdict: the frame within the CPU reference's
/// tolerances, validation-clean, and the PNG `png` showing the volume over a fifth of it.
/// The printed comparison of the GPU frame with the CPU reference, judged by the volume's
/// scalar type (review M8): an f32 volume at the library's tolerances (6/255 largest, 1e-3
/// mean; measured 2026-12-07: 0.5/255 and 4.8e-4, the PNG's rounding); u8 and u16 at the
/// bound measured 2026-12-01 for a u8 plan (0.045 largest, 2.5e-3 mean: lavapipe filters
/// 8-bit textures in 8-bit fixed point) with a margin.
fn assert_matches_reference(text: &str, png: &Path) {
    let max = number_after(text, "max per-channel difference");
    let mean = number_after(text, "mean");
    let is_f32 = text
        .lines()
        .find(|l| l.starts_with("volume:"))
        .is_some_and(|l| l.contains(" F32"));
    let (max_bound, mean_bound) = if is_f32 {
        (6.0 / 255.0, 1e-3)
    } else {
        (0.06, 4e-3)
    };
    assert!(
        max < max_bound,
        "GPU and CPU reference differ by {max} (bound {max_bound})\n{text}"
    );
    assert!(
        mean < mean_bound,
        "mean difference {mean} (bound {mean_bound})\n{text}"
    );
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    assert!(covered(&pixels(png), BACKGROUND) > 0.2, "{text}");
}

#[test]
fn a_volume_under_a_gpu_budget_mixes_levels_and_matches_the_cpu_reference() {
    let dir = temp_dir("budget");
    let png = dir.join("r.png");
    let (out, text) = run(&[
        "render",
        "--dims",
        "64,64,64",
        "--brick-size",
        "8",
        "--gpu-budget-mb",
        "0.2",
        "--width",
        "64",
        "--height",
        "64",
        "--frames",
        "1",
        "--compare",
        "--validation",
        "-o",
        png.to_str().unwrap(),
        // Two levels (the full-resolution one and the one below).
        "--level-count",
        "2",
    ]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("0 bricks still waiting"), "{text}");
    let (hi, lo) = drawn(&text);
    assert!(
        hi > 0 && lo > 0,
        "the budget should force a mix: {hi} hi, {lo} lo\n{text}"
    );
    // Measured 2026-12-01 on lavapipe: max 0.045, mean 2.5e-3 for this plan, and the same
    // (0.0445, 2.7e-3) with every brick hi-res: 64x64 images of Marschner-Lobb carry the
    // GPU's 8-bit filtering differences at the ridges; a misplaced brick costs far more.
    assert_matches_reference(&text, &png);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_staircase_of_five_levels_renders_through_the_three_level_cache() {
    let dir = temp_dir("staircase");
    let png = dir.join("s.png");
    let (out, text) = run(&[
        "render",
        "--dims",
        "128,128,128",
        "--brick-size",
        "8",
        "--levels",
        "staircase",
        "--width",
        "64",
        "--height",
        "64",
        "--compare",
        "--validation",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{text}");
    // 16^3 bricks: levels 0-4, the last two in blocks of 2^3 and 4^3 bricks.
    assert!(
        text.contains(
            "brick cache: 4096 bricks of 8^3 at levels 0..=4 ([1, 7, 56, 448, 3584] bricks per level)"
        ),
        "{text}"
    );
    // The tolerances of the two-level test above.
    assert_matches_reference(&text, &png);

    // The bench draws the staircase through the same level system (every pattern does), and
    // refuses to churn it (--churn swaps levels 0 and 1 of a two-level pattern).
    let bench = |extra: &[&str]| {
        let mut a = vec!["bench", "--dims", "32,32,32", "--brick-size", "8"];
        a.extend_from_slice(&["--levels", "staircase", "--frames", "2", "--width", "32"]);
        a.extend_from_slice(&["--height", "32", "--validation"]);
        a.extend_from_slice(extra);
        run(&a)
    };
    let (out, text) = bench(&[]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("| ray-cast (gpu) | 2 |"), "{text}");
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    let (out, text) = bench(&["--churn"]);
    assert!(!out.status.success(), "{text}");
    assert!(text.contains("not the staircase"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--weigh-by-value` weighs each brick's voxel size on screen by its value range (the
/// two-level planner's error): in a cache large enough for the one-pixel target, the same view
/// draws fewer bricks at level 0 (Marschner-Lobb's bricks span a fraction of its range), the
/// same bricks in all, and still matches the CPU reference.
#[test]
fn weighing_by_value_draws_narrow_bricks_coarser() {
    let dir = temp_dir("weigh_by_value");
    let per_level = |weigh: bool| {
        let png = dir.join(format!("w{weigh}.png"));
        let mut args = vec![
            "render",
            "--dims",
            "64,64,64",
            "--scalar",
            "f32",
            "--brick-size",
            "8",
            "--levels",
            "camera",
            // The three-level cache under the one GPU budget flag (64 MiB of it the cache).
            "--gpu-budget-mb",
            "72",
            "--width",
            "64",
            "--height",
            "64",
            "--compare",
            "--validation",
            "-o",
            png.to_str().unwrap(),
        ];
        if weigh {
            args.push("--weigh-by-value");
        }
        let (out, text) = run(&args);
        assert!(out.status.success(), "{text}");
        assert_matches_reference(&text, &png);
        let line = text
            .lines()
            .find_map(|l| l.strip_prefix("levels from the camera: ["))
            .unwrap_or_else(|| panic!("no levels line in:\n{text}"));
        let counts: Vec<u64> = line[..line.find(']').unwrap()]
            .split(", ")
            .map(|c| c.parse().unwrap())
            .collect();
        counts
    };
    let plain = per_level(false);
    let weighed = per_level(true);
    assert_eq!(
        plain.iter().sum::<u64>(),
        weighed.iter().sum::<u64>(),
        "{plain:?} {weighed:?}"
    );
    assert!(
        plain[0] > 0,
        "the one-pixel target draws level 0: {plain:?}"
    );
    assert!(
        weighed[0] < plain[0],
        "weighed by value, fewer bricks at level 0: {plain:?} -> {weighed:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn levels_chosen_from_the_camera_fit_the_cache_and_match_the_cpu_reference() {
    let dir = temp_dir("camera_levels");
    let png = dir.join("c.png");
    // 1 MiB of f32 texels (the cache holds the volume's scalar type): 125 slots of 12^3 for
    // 4096 bricks of 8^3, so the budget coarsens the plan past the one-pixel target.
    let (out, text) = run(&[
        "render",
        "--dims",
        "128,128,128",
        "--scalar",
        "f32",
        "--brick-size",
        "8",
        "--levels",
        "camera",
        // 1 MiB of cache (the budget less the upload staging).
        "--gpu-budget-mb",
        "2",
        "--upload-mb",
        "1",
        "--width",
        "64",
        "--height",
        "64",
        "--compare",
        "--validation",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("levels from the camera:"), "{text}");
    let voxel_px = number_after(&text, "drawn voxels at most");
    assert!(
        voxel_px > 1.0,
        "the budget should coarsen the plan: {voxel_px} px\n{text}"
    );
    assert_matches_reference(&text, &png);

    // An orbit chooses again at every view, validation-clean.
    let frames = dir.join("orbit");
    let (out, text) = run(&[
        "render",
        "--dims",
        "64,64,64",
        "--brick-size",
        "8",
        "--levels",
        "camera",
        // 1 MiB of cache (the budget less the upload staging).
        "--gpu-budget-mb",
        "2",
        "--upload-mb",
        "1",
        "--width",
        "32",
        "--height",
        "32",
        "--orbit",
        "4",
        "--frames-dir",
        frames.to_str().unwrap(),
        "--validation",
    ]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    assert!(frames.join("frame_0003.png").exists(), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `convert` writes a level store from a file read slab by slab, and
/// `render STORE` draws it through the three-level cache: at levels chosen from the camera (the
/// default) and at the staircase, each matching the CPU reference over the levels read back
/// from the store, validation-clean. Two-level options and a budget too small for the levels
/// are refused with the reason.
#[test]
fn a_level_store_renders_at_camera_levels_and_matches_the_cpu_reference() {
    let dir = temp_dir("level_store");
    let raw = dir.join("ml.raw");
    let volume = SyntheticField::MarschnerLobb
        .generate(glam::UVec3::splat(96), ScalarType::U8)
        .unwrap();
    std::fs::write(&raw, volume.data().as_bytes()).unwrap();
    let store = dir.join("ml.mvl");
    let convert = |extra: &[&str]| {
        let mut a = vec![
            "convert",
            raw.to_str().unwrap(),
            store.to_str().unwrap(),
            "--dims",
            "96,96,96",
            "--brick-size",
            "8",
        ];
        a.extend_from_slice(extra);
        run(&a)
    };
    let (out, text) = convert(&[]);
    assert!(out.status.success(), "{text}");
    // 12^3 bricks: levels 0-2 and block levels 3-6 (a block of 16 bricks covers 12).
    assert!(text.contains("bricks of 8): 7 levels"), "{text}");
    assert!(!dir.join("ml.mvl.partial").exists());
    // `render --volume STORE --compare --validation -o PNG` with `extra`: the output and the PNG.
    let compare = |name: &str, extra: &[&str]| {
        let png = dir.join(format!("{name}.png"));
        let mut a = vec![
            "render",
            "--volume",
            store.to_str().unwrap(),
            "--width",
            "64",
        ];
        a.extend_from_slice(&["--height", "64", "--compare", "--validation", "-o"]);
        a.push(png.to_str().unwrap());
        a.extend_from_slice(extra);
        let (out, text) = run(&a);
        assert!(out.status.success(), "{text}");
        assert_matches_reference(&text, &png);
        text
    };
    let text = compare("camera", &["--gpu-budget-mb", "2", "--upload-mb", "1"]);
    assert!(text.contains("(level store)"), "{text}");
    assert!(
        text.contains("levels chosen from the camera from 7 levels on disk"),
        "{text}"
    );
    assert!(text.contains("levels from the camera:"), "{text}");
    // The stored bricks come from the background reader; the render thread read only the
    // coarsest level, when the source was attached.
    let stream = text
        .lines()
        .find(|l| l.starts_with("level stream:"))
        .unwrap_or_else(|| panic!("no level stream line:\n{text}"));
    assert!(number_after(stream, "level stream:") > 10.0, "{text}");
    assert_eq!(number_after(stream, "ms),"), 1.0, "{text}");
    assert!(stream.contains(" 0 failed"), "{text}");
    // A small upload budget reaches the same choice in steps, and draws what the reference draws.
    // 0.05 MiB: just above the smallest budget, 27 level-0 stored bricks of 12^3 u8.
    let text = compare("steps", &["--gpu-budget-mb", "1.05", "--upload-mb", "0.05"]);
    assert!(number_after(&text, "level steps:") > 2.0, "{text}");
    assert!(text.contains("0 bricks still waiting"), "{text}");
    let text = compare("staircase", &["--levels", "staircase"]);
    assert!(text.contains("at levels 0..=4"), "{text}");

    // A two-level pattern is refused.
    let (out, text) = run(&[
        "render",
        "--volume",
        store.to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "16",
        "--levels",
        "checker",
    ]);
    assert!(!out.status.success(), "--levels checker is refused\n{text}");
    assert!(text.contains("is a two-level pattern"), "{text}");
    let (out, text) = convert(&[]);
    assert!(!out.status.success() && text.contains("exists"), "{text}");
    let (out, text) = convert(&["--force", "--ram-budget-mb", "1"]);
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("RAM budget of 1048576 bytes is too small"),
        "{text}"
    );
    assert!(store.exists(), "a refused convert leaves the old store");
    let (out, text) = run(&[
        "convert",
        raw.to_str().unwrap(),
        dir.join("four.mvl").to_str().unwrap(),
        "--dims",
        "96,96,96",
        "--brick-size",
        "8",
        "--level-count",
        "4",
    ]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("bricks of 8): 4 levels"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_orbit_writes_every_frame_and_a_per_frame_log() {
    let dir = temp_dir("orbit");
    let frames = dir.join("frames");
    let (out, text) = run(&[
        "render",
        "--dims",
        "48,48,48",
        "--brick-size",
        "8",
        // Levels from the camera; the upload cap holds the smallest step (27 level-0 bricks
        // of 12^3 u8).
        "--gpu-budget-mb",
        "0.13",
        "--upload-mb",
        "0.05",
        "--level-count",
        "2",
        "--width",
        "40",
        "--height",
        "32",
        "--orbit",
        "6",
        "--elevation",
        "25",
        "--validation",
        "--frames-dir",
        frames.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{text}");
    let images: Vec<_> = (0..6)
        .map(|i| pixels(&frames.join(format!("frame_{i:04}.png"))))
        .collect();
    assert!(!frames.join("frame_0006.png").exists());
    for img in &images {
        assert_eq!(img.dimensions(), (40, 32));
    }
    assert!(
        max_difference(&images[0], &images[3]) > 40,
        "half a turn later the image must change"
    );
    let csv = std::fs::read_to_string(frames.join("frames.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 7, "{csv}");
    let header: Vec<&str> = lines[0].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let cell = |row: usize, name: &str| -> f64 {
        lines[row + 1]
            .split(',')
            .nth(col(name))
            .unwrap()
            .parse()
            .unwrap()
    };
    let upload_limit = 0.05 * (1u64 << 20) as f64 / 1e6;
    for row in 0..6 {
        assert_eq!(cell(row, "frame") as usize, row);
        assert!(cell(row, "budget_fill") <= 1.0 + 1e-9, "{csv}");
        // The CSV rounds to 4 decimals.
        assert!(
            cell(row, "upload_budget_mb") <= upload_limit + 1e-4,
            "{csv}"
        );
    }
    assert!(
        cell(0, "uploaded_bricks") > 0.0,
        "the first frame uploads: {csv}"
    );
    // The upload budget spreads the first residency over several frames.
    assert!(cell(0, "waiting") > 0.0, "{csv}");
    for row in 0..6 {
        assert!(cell(row, "uploaded_mb") <= upload_limit + 1e-4, "{csv}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(frames.join("frames.json")).unwrap())
            .unwrap();
    assert_eq!(json.as_array().unwrap().len(), 6);
    assert_eq!(
        json[2]["resident"][0].as_f64().unwrap(),
        cell(2, "resident_l0")
    );
    assert_eq!(
        json[2]["resident"][1].as_f64().unwrap(),
        cell(2, "resident_l1")
    );
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_store_streamed_under_a_small_ram_budget_draws_what_the_volume_in_memory_draws() {
    let dir = temp_dir("store");
    let volume = SyntheticField::MarschnerLobb
        .generate(glam::UVec3::splat(64), ScalarType::U8)
        .unwrap();
    // A level store of two levels, and the volume in memory at two levels: the one system.
    let store = dir.join("ml.mvl");
    write_level_store(
        &store,
        &volume,
        16,
        Some(2),
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    let store_mb = std::fs::metadata(&store).unwrap().len() as f64 / (1u64 << 20) as f64;
    let common = [
        "--gpu-budget-mb",
        "0.6",
        "--width",
        "64",
        "--height",
        "64",
        "--frames",
        "1",
        "--validation",
    ];
    let in_memory = dir.join("memory.png");
    let mut args = vec!["render", "--dims", "64,64,64", "--brick-size", "16"];
    args.extend(["--level-count", "2"]);
    args.extend(common);
    args.extend(["-o", in_memory.to_str().unwrap()]);
    let (out, memory_text) = run(&args);
    assert!(out.status.success(), "{memory_text}");
    let ram = format!("{:.3}", store_mb * 0.6);
    let streamed = dir.join("streamed.png");
    let log = dir.join("log.csv");
    let mut args = vec![
        "render",
        "--volume",
        store.to_str().unwrap(),
        "--ram-budget-mb",
        &ram,
        "--frame-log",
        log.to_str().unwrap(),
    ];
    args.extend(common);
    args.extend(["-o", streamed.to_str().unwrap()]);
    let (out, store_text) = run(&args);
    assert!(out.status.success(), "{store_text}");
    assert!(store_text.contains("(level store)"), "{store_text}");
    assert!(
        store_text.contains("0 bricks still waiting"),
        "{store_text}"
    );
    assert!(store_text.contains("level stream:"), "{store_text}");
    let (hi, lo) = drawn(&store_text);
    assert!(hi > 0 && lo > 0, "{store_text}");
    assert_eq!(
        drawn(&memory_text),
        (hi, lo),
        "same plan\n{memory_text}\n{store_text}"
    );
    let (a, b) = (pixels(&in_memory), pixels(&streamed));
    assert!(covered(&a, BACKGROUND) > 0.2);
    assert!(
        max_difference(&a, &b) <= 1,
        "the streamed store draws the in-memory image"
    );
    assert!(std::fs::read_to_string(&log).unwrap().lines().count() == 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_camera_paths_and_budgets_are_refused_with_the_reason() {
    let dir = temp_dir("bad");
    let path = dir.join("path.json");
    std::fs::write(
        &path,
        r#"{"keyframes": [{"eye": [1, 1, 1]}, {"eye": [2, 2, 2], "up": [0, 0, 0]}]}"#,
    )
    .unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--path", path.to_str().unwrap()], "keyframes[1].up"),
        (vec!["--orbit", "0"], "--orbit 0"),
        (vec!["--gpu-budget-mb", "0"], "--gpu-budget-mb 0"),
        (
            vec!["--gpu-budget-mb", "1", "--upload-mb", "2"],
            "--upload-mb",
        ),
        // --upload-mb comes out of the one GPU budget, the default 256 MiB without the flag;
        // a plain volume has no brick cache to upload into.
        (
            vec!["--levels", "checker", "--upload-mb", "300"],
            "must stay below --gpu-budget-mb 256",
        ),
        (
            vec!["--upload-mb", "1"],
            "--upload-mb applies to the brick cache",
        ),
        (
            vec!["--orbit", "3", "--compare"],
            "--compare renders one view",
        ),
    ];
    for (extra, expected) in cases {
        let mut args = vec!["render", "--dims", "8,8,8", "-o", "/nonexistent/x.png"];
        args.extend(extra.iter().copied());
        let (out, text) = run(&args);
        assert!(!out.status.success(), "{args:?} succeeded:\n{text}");
        assert!(
            text.contains(expected),
            "{args:?}: no '{expected}' in\n{text}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Peak RSS ("peak RSS: X MB") printed by a command.
fn peak_rss_mb(text: &str) -> f64 {
    number_after(text, "peak RSS:")
}

/// Issue 14's out-of-core proof through the binary: a raw file converted into a store and the
/// store rendered, both under RAM budgets far below the data. The render's peak RSS stays
/// within the process's own baseline (a tiny render, measured here) plus the RAM and GPU
/// budgets plus a fixed slack, well below what reading the store whole would need.
#[test]
fn convert_then_render_a_volume_larger_than_the_ram_budget_in_bounded_memory() {
    let dir = temp_dir("outofcore");
    let raw = dir.join("ml.raw");
    let dims = glam::UVec3::new(512, 512, 256);
    let volume = SyntheticField::MarschnerLobb
        .generate(dims, ScalarType::U8)
        .unwrap();
    mixvol::volume::save_raw(&volume, &raw).unwrap();
    drop(volume);
    let store = dir.join("ml.mvl");
    // Levels 0 and 1, bricks of 16: the writer's window of level-0 planes (as f32) is 16 + 12
    // planes of 1 MiB.
    let (out, text) = run(&[
        "convert",
        raw.to_str().unwrap(),
        store.to_str().unwrap(),
        "--dims",
        "512,512,256",
        "--scalar",
        "u8",
        "--brick-size",
        "16",
        "--level-count",
        "2",
        "--ram-budget-mb",
        "40",
    ]);
    assert!(out.status.success(), "{text}");
    let store_mb = std::fs::metadata(&store).unwrap().len() as f64 / 1e6;
    assert!(store_mb > 80.0, "store of {store_mb} MB");
    let png = dir.join("r.png");
    let render = |volume: &str, ram: &str, gpu: &str| {
        run(&[
            "render",
            "--volume",
            volume,
            "--dims",
            "16,16,16",
            "--ram-budget-mb",
            ram,
            "--gpu-budget-mb",
            gpu,
            // Level-0 voxels are an eighth of a pixel here: ask for a tenth so that the cache
            // draws both levels.
            "--voxel-px",
            "0.1",
            "--width",
            "64",
            "--height",
            "64",
            "--frames",
            "1",
            "-o",
            png.to_str().unwrap(),
        ])
    };
    let (out, base_text) = render("ml", "1", "0.5");
    assert!(out.status.success(), "{base_text}");
    let baseline = peak_rss_mb(&base_text);
    let (out, text) = render(store.to_str().unwrap(), "24", "24");
    assert!(out.status.success(), "{text}");
    assert!(text.contains("(level store)"), "{text}");
    let (hi, lo) = drawn(&text);
    assert!(hi > 0 && lo > 0, "{text}");
    assert!(covered(&pixels(&png), BACKGROUND) > 0.2, "{text}");
    let peak = peak_rss_mb(&text);
    // RAM budget 24 MiB + what the renderer allocated on the device as it reports it (the
    // cache and staging within the 24 MiB GPU budget, the render target and its read-back
    // besides: lavapipe's memory is host memory) + 24 MB slack (allocator, thread stacks, the
    // stored bricks of one step in flight); reading the store whole would add its 144 MB.
    let gpu = number_after(&text, "gpu memory:");
    assert!(gpu > 0.0 && gpu < 40.0, "{text}");
    let bound = baseline + 25.2 + gpu + 24.0;
    assert!(
        peak < bound && peak < baseline + store_mb,
        "peak RSS {peak} MB > {bound} MB (baseline {baseline} MB, store {store_mb} MB)\n{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A level store whose level-0 bricks are damaged still renders: the background reader keeps
/// each CRC failure, the view steps onto what it could read and stops once nothing more can
/// move (it does not loop until the step limit), and the output names the failure.
#[test]
fn a_damaged_level_store_renders_what_it_can_read_and_names_the_failure() {
    let dir = temp_dir("damaged_level_store");
    let store = dir.join("ml.mvl");
    let (out, text) = run(&[
        "convert",
        "ml",
        store.to_str().unwrap(),
        "--dims",
        "64,64,64",
        "--brick-size",
        "8",
    ]);
    assert!(out.status.success(), "{text}");
    // Header: data_offset is the u64 at byte 76 (docs/brick-store.md); level 0's 512 stored
    // bricks of 12^3 u8 come first. One byte of every level-0 brick flipped.
    let mut bytes = std::fs::read(&store).unwrap();
    let data = u64::from_le_bytes(bytes[76..84].try_into().unwrap()) as usize;
    for brick in 0..512 {
        bytes[data + brick * 12 * 12 * 12 + 100] ^= 0x5a;
    }
    std::fs::write(&store, &bytes).unwrap();
    let start = std::time::Instant::now();
    let (out, text) = run(&[
        "render",
        "--volume",
        store.to_str().unwrap(),
        "--gpu-budget-mb",
        "3",
        "--upload-mb",
        "1",
        "--width",
        "64",
        "--height",
        "64",
        "--frames",
        "1",
        "--validation",
        "-o",
        dir.join("r.png").to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{text}");
    let stream = text
        .lines()
        .find(|l| l.starts_with("level stream:"))
        .unwrap_or_else(|| panic!("no level stream line:\n{text}"));
    assert!(
        number_after(stream, "on the render thread,") > 0.0,
        "{text}"
    );
    assert!(
        text.contains("first failed read:") && text.contains("CRC-32"),
        "{text}"
    );
    // The failures reach the frame's report and stderr (issue 42, item 5): the background
    // reader's failures count as well as the render thread's.
    assert!(text.contains("bricks failed to load (first:"), "{text}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("warning: ") && stderr.contains("CRC-32"),
        "{text}"
    );
    // The bricks whose reads failed still wait: the view stopped short of the camera's plan.
    assert!(
        text.contains("bricks still waiting") && !text.contains(" 0 bricks still waiting"),
        "{text}"
    );
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    // It stops once nothing can move (review M4): a step per level at most, not the 200-frame
    // limit; and the image shows what it could read.
    let steps = number_after(&text, "level steps:");
    assert!(steps <= 10.0, "{steps} steps: it kept stepping\n{text}");
    assert!(
        covered(&pixels(&dir.join("r.png")), BACKGROUND) > 0.2,
        "the image is mostly background\n{text}"
    );
    assert!(
        start.elapsed() < std::time::Duration::from_secs(60),
        "stopped stepping once nothing could move"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 36: a level store of two levels and one of seven drawn along an orbit from the camera
/// (`--levels camera`, the default) write a per-frame CSV with the residency per level
/// (`resident_l0`, `resident_l1`, ...) and the bytes each view uploaded, which never exceed
/// `--upload-mb`, for both level counts, under one `--gpu-budget-mb` (its cache the budget less
/// the upload staging); the two-level store draws levels 0 and 1 only, the seven-level one
/// more, and the drawn bricks never exceed the grid's.
#[test]
fn level_stores_log_residency_per_level_within_the_upload_cap() {
    let dir = temp_dir("level_csv");
    let raw = dir.join("ml.raw");
    let volume = SyntheticField::MarschnerLobb
        .generate(glam::UVec3::splat(96), ScalarType::U8)
        .unwrap();
    std::fs::write(&raw, volume.data().as_bytes()).unwrap();
    let upload_mb = 0.05;
    for (name, levels) in [("two", Some("2")), ("seven", None)] {
        let store = dir.join(format!("{name}.mvl"));
        let mut a = vec![
            "convert",
            raw.to_str().unwrap(),
            store.to_str().unwrap(),
            "--dims",
            "96,96,96",
            "--brick-size",
            "8",
        ];
        if let Some(l) = levels {
            a.extend_from_slice(&["--level-count", l]);
        }
        let (out, text) = run(&a);
        assert!(out.status.success(), "{text}");
        let frames = dir.join(format!("{name}-orbit"));
        let (out, text) = run(&[
            "render",
            "--volume",
            store.to_str().unwrap(),
            // One GPU budget for every level count: 1 MiB of cache, 0.05 of upload staging.
            "--gpu-budget-mb",
            "1.05",
            "--upload-mb",
            "0.05",
            "--width",
            "48",
            "--height",
            "48",
            "--orbit",
            "6",
            "--frames-dir",
            frames.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{name}: {text}");
        let csv = std::fs::read_to_string(frames.join("frames.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 7, "{name}: {csv}");
        let header: Vec<&str> = lines[0].split(',').collect();
        assert!(!header.contains(&"resident_hi"), "{csv}");
        let level_columns: Vec<usize> = (0..header.len())
            .filter(|&i| header[i].starts_with("resident_l"))
            .collect();
        let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
        let mut uploaded = 0.0;
        for line in &lines[1..] {
            let cells: Vec<f64> = line.split(',').map(|c| c.parse().unwrap_or(0.0)).collect();
            // MB (10^6 bytes) against MiB; the CSV rounds to 4 decimals.
            let cap = upload_mb * 1.048576 + 1e-4;
            assert!(
                cells[col("uploaded_mb")] <= cap,
                "{name}: over the cap: {csv}"
            );
            uploaded += cells[col("uploaded_mb")];
            let drawn: f64 = level_columns.iter().map(|&i| cells[i]).sum();
            assert!(
                drawn > 0.0 && drawn <= 1728.0,
                "{name}: {drawn} bricks: {csv}"
            );
            assert!(cells[col("budget_fill")] <= 1.0 + 1e-9, "{name}: {csv}");
            // The cache image takes what the GPU budget leaves after the upload staging.
            let cache = cells[col("cache_mb")] / 1.048576;
            assert!(
                cache > 0.5 && cache <= 1.0 + 1e-3,
                "{name}: {cache} MiB: {csv}"
            );
        }
        assert!(uploaded > 0.0, "{name}: the views upload: {csv}");
        match name {
            "two" => assert_eq!(level_columns.len(), 2, "{csv}"),
            _ => assert!(level_columns.len() >= 3, "{csv}"),
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 36: `bench` along a camera path takes levels chosen from the camera (it refused
/// every scene but the two-level ones): both transitions start from nothing drawn, every frame
/// uploads at most `--upload-mb`, the frames converge after the path, and the JSON says so.
#[test]
fn bench_along_a_path_takes_levels_from_the_camera() {
    let dir = temp_dir("level_path_bench");
    let json = dir.join("bench.json");
    let upload_mb = 0.05;
    let (out, text) = run(&[
        "bench",
        "--dims",
        "64,64,64",
        "--brick-size",
        "8",
        "--levels",
        "camera",
        "--gpu-budget-mb",
        "1.05",
        "--upload-mb",
        "0.05",
        "--width",
        "32",
        "--height",
        "32",
        "--orbit",
        "3",
        "--validation",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("validation: 0 warnings/errors"), "{text}");
    let value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let runs = value["transitions"].as_array().unwrap();
    assert_eq!(runs.len(), 2, "{value}");
    for run in runs {
        assert_eq!(run["frames"], 3, "{value}");
        // MB (10^6 bytes) per frame against MiB.
        let max = run["uploaded_mb_per_frame"]["max"].as_f64().unwrap();
        assert!(
            max > 0.0 && max <= upload_mb * 1.048576 + 1e-9,
            "{max} MB: {value}"
        );
        assert!(run["frames_to_converge"].as_u64().is_some(), "{value}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
