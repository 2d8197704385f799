//! `mixvol render` and `mixvol convert` on TIFF stacks written by tifffile (the library's
//! tests/fixtures/write_tiff_fixtures.py, run in the venv of scripts/python-env.sh): the MNI152
//! template as a multi-page LZW TIFF and as a tiled Deflate OME-TIFF renders the same image as
//! its NIfTI file (lavapipe, validation on), converts page by page into the same brick store as
//! the NIfTI volume, and `--tiff-channel` picks an OME-TIFF's channel (or is refused by name).

#[path = "../../../tests/python_env/mod.rs"]
mod python_env;

use mixvol::bricks::DownsampleFilter;
use mixvol::store::write_level_store;
use mixvol::volume::load_volume;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_tiff_fixtures.py",
            "tifffile-fixtures-cli",
            "scripts/requirements-tiff.txt",
        )
    })
}

fn mni_nifti() -> PathBuf {
    let dir = std::env::var("MIXVOL_DATA_DIR")
        .map(|d| python_env::repo_root().join(d))
        .unwrap_or_else(|_| python_env::repo_root().join("target/datasets"));
    let nii = dir.join("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii");
    assert!(
        nii.is_file(),
        "{} missing: run scripts/fetch-datasets.sh (scripts/test.sh does)",
        nii.display()
    );
    nii
}

fn mixvol(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(args)
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Renders `volume` (with `extra` flags) to a PNG and returns its RGBA pixels.
fn render(volume: &Path, tag: &str, extra: &[&str]) -> Vec<u8> {
    let png = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("tiff-cli-{tag}.png"));
    let mut args = vec![
        "render",
        "--frames",
        "1",
        "--width",
        "48",
        "--height",
        "48",
        "--validation",
        "--tf",
        "grey",
        "--volume",
        volume.to_str().unwrap(),
        "--output",
        png.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = mixvol(&args);
    assert!(out.status.success(), "{tag}: {}", text(&out));
    image::open(&png)
        .unwrap_or_else(|e| panic!("{}: {e}", png.display()))
        .to_rgba8()
        .into_raw()
}

#[test]
fn a_tiff_stack_renders_the_same_image_as_its_nifti_file() {
    let reference = render(&mni_nifti(), "mni-nii", &[]);
    // Not a blank frame: the head is there.
    let lit = reference.chunks_exact(4).filter(|p| p[0] > 20).count();
    assert!(lit > 48 * 48 / 10, "only {lit} lit pixels");
    for name in ["mni.tif", "mni.ome.tif"] {
        let got = render(&fixtures().join(name), name, &[]);
        assert!(
            got == reference,
            "{name}: the render differs from the NIfTI one"
        );
    }
}

#[test]
fn convert_streams_a_tiff_stack_into_the_store_of_the_same_volume() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("tiff-cli-convert");
    std::fs::create_dir_all(&dir).unwrap();
    let ours = dir.join("mni-tif.mvl");
    let theirs = dir.join("mni-nii.mvl");
    let _ = std::fs::remove_file(&ours);
    let tif = fixtures().join("mni.tif");
    let out = mixvol(&[
        "convert",
        tif.to_str().unwrap(),
        ours.to_str().unwrap(),
        "--brick-size",
        "16",
        "--ram-budget-mb",
        "8",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("Tiff"),
        "{}",
        text(&out)
    );
    let volume = load_volume(&mni_nifti()).unwrap();
    write_level_store(
        &theirs,
        &volume,
        16,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    assert!(
        std::fs::read(&ours).unwrap() == std::fs::read(&theirs).unwrap(),
        "the store converted from the TIFF stack differs from the NIfTI volume's"
    );
}

#[test]
fn tiff_channel_flags_pick_a_channel_or_are_refused_by_name() {
    let ome = fixtures().join("tczyx.ome.tif");
    let window = ["--window", "0,0.2"];
    let c0 = render(&ome, "c0", &window);
    let c2 = render(
        &ome,
        "c2",
        &[&window[..], &["--tiff-channel", "2"]].concat(),
    );
    assert!(c0 != c2, "channel 2 renders as channel 0");
    let c0_again = render(
        &ome,
        "c0-flag",
        &[&window[..], &["--tiff-channel", "0"]].concat(),
    );
    assert!(c0 == c0_again);
    let out = mixvol(&[
        "render",
        "--volume",
        ome.to_str().unwrap(),
        "--tiff-channel",
        "3",
        "--output",
        "/dev/null",
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("SizeC"), "{}", text(&out));
    let out = mixvol(&[
        "render",
        "--volume",
        mni_nifti().to_str().unwrap(),
        "--tiff-time",
        "1",
    ]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("TIFF stacks"),
        "{}",
        text(&out)
    );
}

#[test]
fn convert_of_a_stack_larger_than_the_budget_has_bounded_peak_rss() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("tiff-cli-rss");
    std::fs::create_dir_all(&dir).unwrap();
    let store = dir.join("big.mvl");
    let stats = dir.join("stats.json");
    let input = fixtures().join("big_zlib.tif");
    let out = mixvol(&[
        "convert",
        input.to_str().unwrap(),
        store.to_str().unwrap(),
        "--force",
        // Bricks of 16: the level writer holds a window of 16 + 12 level-0 planes as f32
        // (28 MiB) and the store's table.
        "--brick-size",
        "16",
        "--ram-budget-mb",
        "40",
        "--stats-json",
        stats.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("512x512x192"),
        "{}",
        text(&out)
    );
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let peak = s["peak_rss_bytes"].as_u64().expect("peak RSS measured");
    let voxel_bytes = 512 * 512 * 192 * 2u64;
    // The process's own baseline: a convert of 8^3 voxels.
    let tiny = dir.join("tiny.json");
    let out = mixvol(&[
        "convert",
        "ml",
        dir.join("tiny.mvl").to_str().unwrap(),
        "--force",
        "--dims",
        "8,8,8",
        "--brick-size",
        "8",
        "--stats-json",
        tiny.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&tiny).unwrap()).unwrap();
    let baseline = t["peak_rss_bytes"].as_u64().unwrap();
    // The voxels are 96 MiB: the process holds its baseline and the budget at most.
    assert!(
        peak < baseline + (40 << 20) && peak < voxel_bytes * 3 / 5,
        "peak RSS {peak} bytes (baseline {baseline}) for {voxel_bytes} bytes of voxels under \
         a 40 MiB budget"
    );
    let opened = mixvol::store::LevelStore::open(&store).unwrap();
    assert_eq!(opened.header().dims.to_array(), [512, 512, 192]);
    drop(opened);
    let _ = std::fs::remove_dir_all(&dir);
}
