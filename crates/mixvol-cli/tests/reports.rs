//! The report subcommands write their files (the reports' contents are tested in
//! `mixvol-experiments`).

use std::process::Command;

/// `mixvol kraus` writes the Markdown, CSV and chart.
#[test]
fn command_writes_report_files() {
    let dir = std::env::temp_dir().join(format!("mixvol-kraus-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["kraus", "--output-dir"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(dir.join("kraus.md")).unwrap();
    assert!(md.contains("tau_max = 8") && md.contains("one-voxel-thick wall"));
    let csv = std::fs::read_to_string(dir.join("kraus.csv")).unwrap();
    assert!(csv.starts_with("experiment,model,tau,d,"));
    assert!(csv.lines().count() > 200);
    let png = image::open(dir.join("kraus.png")).unwrap().to_rgb8();
    assert!(png.width() >= 640 && png.height() >= 300);
    // The chart holds the four tau colours.
    for colour in &mixvol_experiments::plot::PALETTE[..4] {
        assert!(png.pixels().any(|p| p.0 == *colour), "{colour:?} missing");
    }
    let svg = std::fs::read_to_string(dir.join("kraus.svg")).unwrap();
    assert!(svg.contains("sampling distance d = d0"));
    std::fs::remove_dir_all(&dir).ok();
}

/// `mixvol report --quick` writes every file of the accuracy report and the junction figure,
/// and runs no orbit.
#[test]
fn quick_accuracy_report_writes_its_files() {
    let dir = std::env::temp_dir().join(format!("mixvol-accuracy-cli-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(["report", "--quick", "--output-dir"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in mixvol_experiments::accuracy::REPORT_FILES {
        assert!(dir.join(name).is_file(), "{name} missing");
    }
    let md = std::fs::read_to_string(dir.join("accuracy-vs-time.md")).unwrap();
    assert!(md.contains("`cargo run --release -- report --quick`"));
    assert!(md.contains("| transition, shaded | Smooth"));
    assert!(md.contains("| early termination |") && md.contains("| downsampling filter |"));
    let figure = image::open(dir.join(mixvol_experiments::junction::JUNCTION_FIGURE)).unwrap();
    assert!(figure.width() > figure.height() && figure.height() > 200);
    // The orbit over scenes belongs to the full report only.
    for name in mixvol_experiments::scenes::SCENE_FILES {
        assert!(!dir.join(name).exists(), "{name} written by --quick");
    }
    std::fs::remove_dir_all(&dir).ok();
}
