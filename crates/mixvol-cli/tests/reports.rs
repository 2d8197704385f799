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
    for colour in [[30, 90, 220], [20, 160, 60], [240, 140, 20], [200, 30, 30]] {
        assert!(png.pixels().any(|p| p.0 == colour), "{colour:?} missing");
    }
    std::fs::remove_dir_all(&dir).ok();
}
