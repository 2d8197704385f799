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
    // An unknown preset is a usage error: refused while parsing the arguments (clap's exit code
    // 2, not the 1 of a failed command), naming the value and the presets.
    let out = mixvol().args(["render", "--tf", "nope"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "--tf nope accepted: {err}");
    assert_eq!(out.status.code(), Some(2), "--tf nope: {err}");
    assert!(err.contains("nope") && err.contains("grey"), "{err}");
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

#[test]
fn junction_image_shows_the_jump_only_in_discontinuous_mode() {
    let dir = std::env::temp_dir().join(format!("mixvol-cli-junction-{}", std::process::id()));
    let png = dir.join("junction.png");
    let size = 96u32;
    let out = mixvol()
        .args([
            "junction",
            "--validation",
            "--size",
            &size.to_string(),
            "--output",
        ])
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&png).unwrap().to_rgba8();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(img.dimensions(), (2 * size + 4, size));
    // The junction is the centre column of each half. Largest colour step between neighbouring
    // pixels across it, against the largest step anywhere else in the same half.
    let step = |x0: u32, x: u32, y: u32| -> i32 {
        let a = img.get_pixel(x0 + x, y).0;
        let b = img.get_pixel(x0 + x + 1, y).0;
        (0..3).map(|c| (a[c] as i32 - b[c] as i32).abs()).sum()
    };
    let at_junction = |x0: u32| (0..size).map(|y| step(x0, size / 2 - 1, y)).max().unwrap();
    let elsewhere = |x0: u32| {
        (0..size)
            .flat_map(|y| {
                (0..size - 1)
                    .filter(|x| x.abs_diff(size / 2 - 1) > 8)
                    .map(move |x| (x, y))
            })
            .map(|(x, y)| step(x0, x, y))
            .max()
            .unwrap()
    };
    let (disc_jump, disc_other) = (at_junction(0), elsewhere(0));
    let (smooth_jump, _) = (at_junction(size + 4), elsewhere(size + 4));
    assert!(
        disc_jump > disc_other,
        "discontinuous: junction step {disc_jump} vs elsewhere {disc_other}"
    );
    assert!(
        smooth_jump * 2 < disc_jump,
        "smooth junction step {smooth_jump} vs discontinuous {disc_jump}"
    );
}

#[test]
fn bench_reports_every_pass_as_a_table_and_json() {
    let out = mixvol()
        .args([
            "bench",
            "--volume",
            "sphere",
            "--dims",
            "32,32,32",
            "--levels",
            "checker",
            "--brick-size",
            "8",
            "--churn",
            "--frames",
            "3",
            "--width",
            "32",
            "--height",
            "32",
            "--json",
            "-",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for pass in [
        "upload (gpu)",
        "fixup (gpu)",
        "ray-cast (gpu)",
        "frame (cpu)",
    ] {
        assert!(
            stdout.contains(&format!("| {pass} | 3 |")),
            "{pass} missing:\n{stdout}"
        );
    }
    let json = stdout
        .lines()
        .find(|l| l.starts_with('{'))
        .expect("a JSON line");
    assert!(
        json.contains("\"frames\":3") && json.contains("\"pass\":\"ray-cast (gpu)\",\"samples\":3"),
        "{json}"
    );
    assert!(json.ends_with("]}"), "{json}");
}

#[test]
fn renders_the_real_mri_template_with_the_mri_preset_and_auto_window() {
    let dir = std::env::var("MIXVOL_DATA_DIR")
        .unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/../../target/datasets").into());
    let nii = std::path::Path::new(&dir).join("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz");
    assert!(
        nii.exists(),
        "{} missing: run scripts/fetch-datasets.sh (scripts/test.sh does)",
        nii.display()
    );
    let png = std::env::temp_dir().join(format!("mixvol-cli-mni-{}.png", std::process::id()));
    let out = mixvol()
        .args([
            "render",
            "--preset",
            "mri",
            "--frames",
            "1",
            "--width",
            "48",
            "--height",
            "48",
            "--validation",
            "--volume",
        ])
        .arg(&nii)
        .arg("--output")
        .arg(&png)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("volume:") && stdout.contains("197x233x189"),
        "{stdout}"
    );
    assert!(stdout.contains("window: ["), "{stdout}");
    let img = image::open(&png).unwrap().to_rgba8();
    std::fs::remove_file(&png).ok();
    // The brain fills the middle of the frame; the corner is background.
    let centre = img.get_pixel(24, 24).0;
    let corner = img.get_pixel(0, 0).0;
    assert!(
        centre[0] > corner[0] + 60,
        "centre {centre:?} corner {corner:?}"
    );
}
