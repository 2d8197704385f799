//! `mixvol render` on NIfTI files: it prints how the voxels were reordered to RAS+ and the window
//! in the file's units (HU for a CT), and `mixvol convert` refuses a file it would read in a
//! different order from the loader.
use std::path::{Path, PathBuf};
use std::process::Command;

fn mixvol() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("nifti-orientation");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A NIfTI-1 file of `dims` (datatype 2 u8 or 4 i16), with an sform (`srow`, code 1) when given
/// and `scl` = (slope, inter).
fn nifti(
    dims: [i16; 3],
    datatype: i16,
    srow: Option<[[f32; 4]; 3]>,
    scl: (f32, f32),
    data: &[u8],
) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let mut put = |at: usize, bytes: &[u8]| h[at..at + bytes.len()].copy_from_slice(bytes);
    put(0, &348i32.to_le_bytes());
    for (i, d) in [3, dims[0], dims[1], dims[2], 1, 1, 1, 1]
        .iter()
        .enumerate()
    {
        put(40 + 2 * i, &d.to_le_bytes());
    }
    put(70, &datatype.to_le_bytes());
    put(72, &(if datatype == 2 { 8i16 } else { 16 }).to_le_bytes());
    for (i, p) in [1.0f32; 8].iter().enumerate() {
        put(76 + 4 * i, &p.to_le_bytes());
    }
    put(108, &352.0f32.to_le_bytes());
    put(112, &scl.0.to_le_bytes());
    put(116, &scl.1.to_le_bytes());
    if let Some(rows) = srow {
        put(254, &1i16.to_le_bytes());
        for (r, row) in rows.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                put(280 + 16 * r + 4 * c, &v.to_le_bytes());
            }
        }
    }
    put(344, b"n+1\0");
    h.extend_from_slice(data);
    h
}

const N: i16 = 16;

/// A ball of value 200 in a u8 grid, off-centre along x.
fn ball() -> Vec<u8> {
    let n = N as i32;
    let mut v = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let d = (x - 4) * (x - 4) + (y - 8) * (y - 8) + (z - 8) * (z - 8);
                v.push(if d < 12 { 200 } else { 10 });
            }
        }
    }
    v
}

/// CT-like i16 values: -1000 (air) around a block of 40 (soft tissue) with a core of 1200.
fn ct(offset: i16) -> Vec<u8> {
    let n = N as i32;
    let mut v = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let inside = |a: i32| (4..12).contains(&a);
                let core = |a: i32| (6..10).contains(&a);
                let hu: i16 = if core(x) && core(y) && core(z) {
                    1200
                } else if inside(x) && inside(y) && inside(z) {
                    40
                } else {
                    -1000
                };
                v.extend_from_slice(&(hu - offset).to_le_bytes());
            }
        }
    }
    v
}

fn render(volume: &Path, extra: &[&str]) -> String {
    let png = volume.with_extension("png");
    let out = mixvol()
        .args([
            "render",
            "--frames",
            "1",
            "--width",
            "32",
            "--height",
            "32",
            "--validation",
        ])
        .args(extra)
        .arg("--volume")
        .arg(volume)
        .arg("--output")
        .arg(&png)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// The RGBA bytes of the PNG `render` wrote for `volume`.
fn png(volume: &Path) -> Vec<u8> {
    image::open(volume.with_extension("png"))
        .unwrap()
        .to_rgba8()
        .into_raw()
}

/// The two numbers of the line starting with `prefix` after its `[`.
fn numbers_after(text: &str, marker: &str) -> [f64; 2] {
    let at = text
        .find(marker)
        .unwrap_or_else(|| panic!("no {marker:?} in {text}"));
    let rest = &text[at + marker.len()..];
    let inner = &rest[..rest.find(']').unwrap()];
    let v: Vec<f64> = inner
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    [v[0], v[1]]
}

#[test]
fn render_prints_the_orientation_of_a_las_file() {
    let las = tmp("las.nii");
    let x_left = [-1.0, 0.0, 0.0, 15.0];
    std::fs::write(
        &las,
        nifti(
            [N; 3],
            2,
            Some([x_left, [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]),
            (1.0, 0.0),
            &ball(),
        ),
    )
    .unwrap();
    let stdout = render(&las, &[]);
    assert!(
        stdout.contains(
            "orientation: LAS -> RAS (flipped x), from the sform (RAS+ world: +x right, +y \
             anterior, +z superior)"
        ),
        "{stdout}"
    );
    // No transform: said so.
    let plain = tmp("plain.nii");
    std::fs::write(&plain, nifti([N; 3], 2, None, (1.0, 0.0), &ball())).unwrap();
    let stdout = render(&plain, &[]);
    assert!(
        stdout.contains("orientation: RAS -> RAS (no reordering), no sform or qform"),
        "{stdout}"
    );
    // An oblique sform: the residual rotation is applied by default, not with --axis-aligned.
    let (c, s) = (20f32.to_radians().cos(), 20f32.to_radians().sin());
    let oblique = tmp("oblique.nii");
    std::fs::write(
        &oblique,
        nifti(
            [N; 3],
            2,
            Some([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]),
            (1.0, 0.0),
            &ball(),
        ),
    )
    .unwrap();
    let stdout = render(&oblique, &[]);
    assert!(
        stdout.contains(
            "residual oblique rotation of 20.00 deg applied (rendered in RAS+ patient space"
        ),
        "{stdout}"
    );
    let rotated = png(&oblique);
    let stdout = render(&oblique, &["--axis-aligned"]);
    assert!(
        stdout.contains(
            "residual oblique rotation of 20.00 deg NOT applied (--axis-aligned: rendered \
             axis-aligned)"
        ),
        "{stdout}"
    );
    let axis_aligned = png(&oblique);
    // Axis-aligned, the oblique file draws as the same voxels without a transform; rotated, it
    // draws as them seen by the camera turned by -20 degrees about z (R^T of eye, target, up).
    assert_eq!(
        axis_aligned,
        png(&plain),
        "--axis-aligned draws the voxels unrotated"
    );
    let turn = |v: [f32; 3]| [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]];
    let text = |v: [f32; 3]| format!("{:.7},{:.7},{:.7}", v[0], v[1], v[2]);
    let (eye, up) = (turn([1.0, 1.3, 1.4]), turn([0.0, 1.0, 0.0]));
    render(&plain, &["--eye", &text(eye), "--up", &text(up)]);
    let expected = png(&plain);
    let largest = |a: &[u8], b: &[u8]| a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
    assert!(
        largest(&rotated, &expected) <= 6,
        "the rotated render is the camera turned the other way"
    );
    assert!(
        largest(&axis_aligned, &expected) > 40,
        "the rotation shows in the image"
    );

    // convert reads slabs in file order: it refuses the LAS file rather than store it mirrored.
    let out = mixvol()
        .arg("convert")
        .arg(&las)
        .arg(tmp("las.mvl"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("orientation") && stderr.contains("LAS"),
        "{stderr}"
    );
}

#[test]
fn preset_ct_windows_in_hounsfield_units() {
    // Scaled: stored HU + 1024 with scl_inter -1024; the volume holds HU, so does the window.
    let scaled = tmp("ct_scaled.nii");
    std::fs::write(&scaled, nifti([N; 3], 4, None, (1.0, -1024.0), &ct(-1024))).unwrap();
    let stdout = render(&scaled, &["--preset", "ct"]);
    assert!(stdout.contains("scl_slope 1 / scl_inter -1024"), "{stdout}");
    let [lo, hi] = numbers_after(&stdout, "window: [");
    assert!(
        (-1000.0..=1200.0).contains(&lo) && lo < hi && hi <= 1200.0,
        "{stdout}"
    );
    // An explicit window is in HU too.
    let stdout = render(&scaled, &["--preset", "ct", "--window=-1000,1200"]);
    assert_eq!(
        numbers_after(&stdout, "window: ["),
        [-1000.0, 1200.0],
        "{stdout}"
    );

    // Unscaled i16: kept as u16 + 32768; the window is printed in HU as well.
    let signed = tmp("ct_signed.nii");
    std::fs::write(&signed, nifti([N; 3], 4, None, (0.0, 0.0), &ct(0))).unwrap();
    let stdout = render(&signed, &["--preset", "ct"]);
    let [lo, hi] = numbers_after(&stdout, ") = [");
    assert!(
        (-1000.5..=1200.5).contains(&lo) && lo < hi && hi <= 1200.5,
        "{stdout}"
    );
    assert!(
        stdout.contains("in file units (i16 stored + 32768"),
        "{stdout}"
    );
}
