//! Output files: a write that cannot succeed exits non-zero with the path and the reason, and
//! never replaces what is there (issue 16 item 1: `-o /dev/full` used to print "wrote").

use std::os::unix::fs::FileTypeExt;
use std::process::Command;

#[test]
fn a_png_to_a_device_is_refused_and_the_device_stays() {
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args([
            "render",
            "--dims",
            "16,16,16",
            "--width",
            "16",
            "--height",
            "16",
            "--frames",
            "1",
            "-o",
            "/dev/full",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stdout}\n{stderr}");
    assert!(!stdout.contains("wrote /dev/full"), "{stdout}");
    assert!(
        stderr.contains("/dev/full") && stderr.contains("not a regular file"),
        "{stderr}"
    );
    let meta = std::fs::metadata("/dev/full").unwrap();
    assert!(meta.file_type().is_char_device());
}

#[test]
fn a_frame_log_into_a_folder_path_fails_and_names_it() {
    let dir = std::env::temp_dir().join(format!("mixvol-outputs-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("log.csv")).unwrap();
    let png = dir.join("r.png");
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args([
            "render", "--dims", "16,16,16", "--width", "16", "--height", "16",
        ])
        .args(["--frames", "1", "--gpu-budget-mb", "1", "-o"])
        .arg(&png)
        .arg("--frame-log")
        .arg(dir.join("log.csv"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("log.csv"), "{stderr}");
    assert!(dir.join("log.csv").is_dir(), "the folder is left alone");
    // Only the PNG and the folder: no partial file left behind.
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 16 item 3: a synthetic volume beyond the host-memory limit is refused before any voxel
/// is computed (a 4096^3 f32 field used to run for minutes towards 256 GiB).
#[test]
fn a_synthetic_volume_beyond_the_memory_limit_is_refused_at_once() {
    let start = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["render", "--dims", "4096,4096,4096", "--scalar", "f32"])
        .args(["-o", "/nonexistent/x.png"])
        .env("MIXVOL_HOST_MEMORY_MB", "1024")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("274877906944 bytes") && stderr.contains("1073741824"),
        "names the request and the limit: {stderr}"
    );
    assert!(stderr.contains("MIXVOL_HOST_MEMORY_MB"), "{stderr}");
    // Refused before the work: far below the minutes generation took.
    assert!(start.elapsed().as_secs() < 20, "{:?}", start.elapsed());
}
