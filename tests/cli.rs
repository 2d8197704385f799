//! The command-line interface: help, bad input, and a real render checked for content.

use std::process::Command;

fn mixvol() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
}

#[test]
fn help_explains_every_render_flag() {
    let out = mixvol().args(["render", "--help"]).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--volume",
        "--dims",
        "--scalar",
        "--spacing",
        "--tf",
        "--projection",
        "--eye",
        "--target",
        "--fov",
        "--width",
        "--height",
        "--samples-per-voxel",
        "--early-termination",
        "--output",
        "--validation",
        "--frames",
    ] {
        assert!(text.contains(flag), "help lacks {flag}:\n{text}");
    }
}

#[test]
fn missing_raw_file_is_a_clear_error() {
    let out = mixvol()
        .args([
            "render",
            "--volume",
            "/no/such/volume.raw",
            "--dims",
            "4,4,4",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/no/such/volume.raw"), "{err}");
}

#[test]
fn wrong_raw_size_names_expected_and_actual_bytes() {
    let path = std::env::temp_dir().join(format!("mixvol-cli-{}.raw", std::process::id()));
    std::fs::write(&path, vec![7u8; 60]).unwrap();
    let out = mixvol()
        .args([
            "render",
            "--volume",
            path.to_str().unwrap(),
            "--dims",
            "4,4,4",
        ])
        .output()
        .unwrap();
    std::fs::remove_file(&path).ok();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("60") && err.contains("64"), "{err}");
}

#[test]
fn bad_flag_values_are_rejected_with_the_reason() {
    let out = mixvol().args(["render", "--dims", "4,4"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("x,y,z"));
    let out = mixvol().args(["render", "--tf", "nope"]).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("grey"));
}

#[test]
fn render_writes_a_png_with_the_volume_in_it_and_prints_timing() {
    let dir = std::env::temp_dir().join(format!("mixvol-cli-render-{}", std::process::id()));
    let png = dir.join("sub/out.png");
    let out = mixvol()
        .args([
            "render",
            "--volume",
            "sphere",
            "--dims",
            "32,32,32",
            "--tf",
            "grey",
            "--width",
            "48",
            "--height",
            "40",
            "--frames",
            "2",
            "--validation",
            "--output",
        ])
        .arg(&png)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("frame timing"), "{stdout}");
    assert!(stdout.contains("validation: 0 warnings/errors"), "{stdout}");
    let img = image::open(&png).unwrap().to_rgba8();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(img.dimensions(), (48, 40));
    let corner = img.get_pixel(0, 0).0;
    let centre = img.get_pixel(24, 20).0;
    // The corner shows the background (0.08 * 255 = 20); the centre shows the grey sphere.
    assert_eq!(corner[0], 20);
    assert!(
        centre[0] > corner[0] + 30,
        "centre {centre:?} corner {corner:?}"
    );
}
