//! `mixvol render` on DICOM series (fixtures from tests/fixtures/write_dicom_fixtures.py, run in
//! the venv of scripts/python-env.sh): the MNI152 template written as an RLE int16 series with a
//! rescale to HU renders, with `--preset ct`, the same image and the same HU window as the same
//! values loaded from NIfTI; `--series` picks one series of a DICOMDIR, and without it the error
//! lists them.
#[path = "../../../tests/python_env/mod.rs"]
mod python_env;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_dicom_fixtures.py",
            "dicom-fixtures",
            "scripts/requirements-dicom.txt",
        )
    })
}

fn mixvol(volume: &Path, png: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args([
            "render",
            "--frames",
            "1",
            "--width",
            "48",
            "--height",
            "48",
            "--validation",
        ])
        .args(extra)
        .arg("--volume")
        .arg(volume)
        .arg("--output")
        .arg(png)
        .output()
        .unwrap()
}

fn render(volume: &Path, png: &Path, extra: &[&str]) -> String {
    let out = mixvol(volume, png, extra);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn line<'a>(text: &'a str, prefix: &str) -> &'a str {
    text.lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no line {prefix:?} in {text}"))
}

#[test]
fn a_dicom_series_renders_as_the_same_volume_from_nifti() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let (dicom_png, nifti_png) = (dir.join("mni_ct_dicom.png"), dir.join("mni_ct_nifti.png"));
    let dicom = render(&fixtures().join("mni_ct"), &dicom_png, &["--preset", "ct"]);
    let nifti = render(
        &fixtures().join("mni_ct.nii"),
        &nifti_png,
        &["--preset", "ct"],
    );
    assert!(
        line(&dicom, "window:").contains("RescaleSlope 1 / RescaleIntercept -24"),
        "{dicom}"
    );
    let window = |text: &str| {
        line(text, "window:")
            .split(" (")
            .next()
            .unwrap()
            .to_string()
    };
    assert_eq!(
        window(&dicom),
        window(&nifti),
        "HU windows\n{dicom}\n{nifti}"
    );
    let (a, b) = (
        image::open(&dicom_png).unwrap().to_rgba8(),
        image::open(&nifti_png).unwrap().to_rgba8(),
    );
    assert_eq!(a.dimensions(), b.dimensions());
    assert!(
        a.as_raw() == b.as_raw(),
        "the DICOM and NIfTI renders differ"
    );
    // Not a blank frame: the head is there.
    let centre = a.get_pixel(24, 24).0;
    let corner = a.get_pixel(0, 0).0;
    assert_ne!(centre, corner);
    assert!(
        line(&dicom, "orientation:").contains("LPS -> RAS (flipped x,y), from the DICOM"),
        "{dicom}"
    );
}

#[test]
fn series_chooses_one_series_of_a_dicomdir() {
    let dicomdir = fixtures().join("dicomdirtests");
    let png = Path::new(env!("CARGO_TARGET_TMPDIR")).join("ct5n.png");
    let out = mixvol(&dicomdir, &png, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("--series")
            && stderr.contains("SmartScore - Gated 0.5 sec")
            && stderr.contains("5 slices"),
        "{stderr}"
    );
    let stdout = render(&dicomdir, &png, &["--series", "5", "--preset", "ct"]);
    assert!(stdout.contains("16x16x5"), "{stdout}");
    let out = mixvol(&fixtures().join("mni_ct.nii"), &png, &["--series", "5"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--series applies to DICOM"));
}

fn convert(input: &Path, store: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .arg("convert")
        .arg(input)
        .arg(store)
        .args(["--brick-size", "16"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn convert_writes_a_dicom_series_as_the_store_of_the_same_volume_from_nifti() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("dicom-cli-convert");
    std::fs::create_dir_all(&dir).unwrap();
    let (ours, theirs, small) = (
        dir.join("mni-ct-dicom.mvl"),
        dir.join("mni-ct-nifti.mvl"),
        dir.join("too-small.mvl"),
    );
    for f in [&ours, &theirs, &small] {
        let _ = std::fs::remove_file(f);
    }
    let out = convert(
        &fixtures().join("mni_ct"),
        &ours,
        &["--ram-budget-mb", "64"],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("DICOM series"), "{stdout}");
    // The same values from NIfTI, bricked in memory (the NIfTI slab reader refuses a file
    // whose scl_slope / scl_inter must be applied).
    let volume = mixvol::volume::load_volume(&fixtures().join("mni_ct.nii")).unwrap();
    mixvol::store::write_level_store(
        &theirs,
        &volume,
        16,
        None,
        mixvol::bricks::DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    assert!(
        std::fs::read(&ours).unwrap() == std::fs::read(&theirs).unwrap(),
        "the store converted from the DICOM series differs from the NIfTI file's"
    );
    // The series is loaded whole (f32 HU, 197x233x189 x 4 bytes = 33 MiB): a budget below
    // that is refused from the headers, and no store is left.
    let out = convert(
        &fixtures().join("mni_ct"),
        &small,
        &["--ram-budget-mb", "8"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("DICOM series") && stderr.contains("loaded whole"),
        "{stderr}"
    );
    assert!(!small.exists() && !dir.join("too-small.mvl.partial").exists());
    // --series on another input is refused by name.
    let out = convert(&fixtures().join("mni_ct.nii"), &small, &["--series", "5"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--series applies to DICOM"));
}

/// Copies the files of `src` into a fresh `dst` under their names.
fn copy_folder(src: &Path, dst: &Path) {
    let _ = std::fs::remove_dir_all(dst);
    std::fs::create_dir_all(dst).unwrap();
    for f in std::fs::read_dir(src).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, dst.join(f.file_name().unwrap())).unwrap();
    }
}

/// Issue 42, item 2 (review D2): a file beside the slices that is not DICOM is skipped with a
/// warning on stderr naming it and the count; an emptied slice file is an error naming it
/// (exit 1), never a volume one slice short with exit 0.
#[test]
fn skipped_files_are_named_and_an_emptied_slice_is_refused() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let series = dir.join("mni_ct_with_readme");
    copy_folder(&fixtures().join("mni_ct"), &series);
    let slices = std::fs::read_dir(&series).unwrap().count();
    std::fs::write(series.join("README.txt"), "exported by a scanner\n").unwrap();
    let png = dir.join("mni_ct_with_readme.png");
    let out = mixvol(&series, &png, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let warning = format!(
        "1 of {} files skipped, not DICOM (no \"DICM\" after a 128-byte preamble): README.txt; \
         the series is read from the other {slices} files",
        slices + 1
    );
    assert!(stderr.contains(&warning), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains(&format!("x{slices} ")), "{stdout}");
    std::fs::write(series.join("IM0007.dcm"), b"").unwrap();
    let out = mixvol(&series, &png, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("IM0007.dcm") && stderr.contains("1 file named like the series' files"),
        "{stderr}"
    );
}
