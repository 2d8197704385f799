//! NIfTI files written by nibabel (installed from PyPI by scripts/python-env.sh, which
//! scripts/test.sh runs and exports as `MIXVOL_PYTHON`): tests/fixtures/write_nifti_fixtures.py
//! writes one anatomy stored RAS, LAS and PIR, with an sform (and a contradicting qform), with a
//! qform only, as NIfTI-1 and NIfTI-2, and value-scaled int16 / uint8 volumes.
//!
//! Every voxel is checked against the formula the generator used (never the loader against
//! itself): after reorientation each file loads to the RAS+ volume, with its spacing and origin.
//! On the GPU (lavapipe, validation on), the LAS file renders the same image as the RAS file, and
//! the LAS voxels in their own file order would not.
mod python_env;

mod common;

use glam::{UVec3, Vec3};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::renderer::{Renderer, TargetFormat, VolumeSource};
use mixvol::scene::{Camera, RenderSettings};
use mixvol::volume::formats::{parse_nifti_header, TransformSource};
use mixvol::volume::Volume;
use mixvol::volume::{
    load_volume_with_meta, open_slabs, FileFormat, LoadedVolume, ScalarType, StoredType,
    VolumeError, VoxelData,
};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folder holding every fixture, written once per test binary.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_nifti_fixtures.py",
            "nibabel-fixtures",
            "scripts/requirements-nifti.txt",
        )
    })
}

/// The RAS+ grid, spacing and origin of the generator's anatomy.
const SHAPE: [u32; 3] = [5, 4, 3];
const SPACING: [f32; 3] = [1.0, 2.0, 3.0];
const ORIGIN: [f64; 3] = [-7.0, 11.0, 5.0];

/// The generator's value at RAS+ voxel (x, y, z).
fn f(x: u32, y: u32, z: u32) -> u32 {
    x + 10 * y + 50 * z
}

fn load(name: &str) -> LoadedVolume {
    let p = fixtures().join(name);
    load_volume_with_meta(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Checks the loaded anatomy voxel by voxel against [`f`], with spacing, origin and the
/// reorientation recorded.
fn check_anatomy(name: &str, code: &str, source: TransformSource, version: u8) {
    let loaded = load(name);
    let v = &loaded.volume;
    assert_eq!(v.dims().to_array(), SHAPE, "{name}: dims");
    assert_eq!(v.spacing().to_array(), SPACING, "{name}: spacing");
    let VoxelData::U8(data) = v.data() else {
        panic!("{name}: expected u8 voxels, got {:?}", v.scalar_type());
    };
    for z in 0..SHAPE[2] {
        for y in 0..SHAPE[1] {
            for x in 0..SHAPE[0] {
                assert_eq!(
                    u32::from(data[v.index(x, y, z)]),
                    f(x, y, z),
                    "{name}: voxel ({x}, {y}, {z})"
                );
            }
        }
    }
    let r = loaded
        .meta
        .reorientation
        .as_ref()
        .expect("NIfTI reorientation");
    assert_eq!(r.file_code(), code, "{name}");
    assert_eq!(r.source, source, "{name}");
    assert!(r.oblique_degrees < 1e-6, "{name}: {r:?}");
    for (i, (o, want_o)) in loaded.meta.origin.iter().zip(ORIGIN).enumerate() {
        assert!(
            (o - want_o).abs() < 1e-9,
            "{name}: origin {:?}",
            loaded.meta.origin
        );
        for (j, d) in loaded.meta.directions[i].iter().enumerate() {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!(
                (d - want).abs() < 1e-9,
                "{name}: {:?}",
                loaded.meta.directions
            );
        }
    }
    assert_eq!(loaded.meta.flipped(), [false; 3], "{name}");
    let header = std::fs::read(fixtures().join(name)).unwrap();
    if !name.ends_with(".gz") {
        let info = parse_nifti_header(Path::new(name), &header).unwrap();
        assert_eq!(info.version, version, "{name}");
    }
}

#[test]
fn every_orientation_loads_to_the_ras_volume() {
    use TransformSource::{Qform, Sform};
    let cases: &[(&str, &str, TransformSource, u8)] = &[
        ("ras_sform.nii", "RAS", Sform, 1),
        ("ras_qform.nii", "RAS", Qform, 1),
        ("ras_n2.nii", "RAS", Sform, 2),
        ("las_sform.nii", "LAS", Sform, 1),
        ("las_sform.nii.gz", "LAS", Sform, 1),
        ("las_qform.nii", "LAS", Qform, 1),
        ("las_n2.nii", "LAS", Sform, 2),
        ("pir_sform.nii", "PIR", Sform, 1),
        ("pir_qform.nii", "PIR", Qform, 1),
        ("pir_n2.nii", "PIR", Sform, 2),
        ("pir_qform_n2.nii", "PIR", Qform, 2),
    ];
    for &(name, code, source, version) in cases {
        check_anatomy(name, code, source, version);
    }
    // LAS and RAS load to identical volumes; the LAS file's own voxel order differs.
    let (ras, las) = (load("ras_sform.nii"), load("las_sform.nii"));
    assert_eq!(ras.volume, las.volume);
    let r = las.meta.reorientation.unwrap();
    assert_eq!(r.flipped, [true, false, false]);
    assert!(
        r.describe().starts_with("LAS -> RAS (flipped x)"),
        "{}",
        r.describe()
    );
    let pir = load("pir_sform.nii").meta.reorientation.unwrap();
    assert_eq!(pir.permutation, [2, 0, 1]);
    assert_eq!(pir.flipped, [false, true, true]);
}

#[test]
fn the_slab_reader_refuses_what_it_would_read_differently() {
    // RAS, unscaled: slab reading agrees with the loader.
    assert!(open_slabs(&fixtures().join("ras_sform.nii"), None).is_ok());
    for name in ["las_sform.nii", "pir_qform.nii", "ct_scaled.nii"] {
        let p = fixtures().join(name);
        match open_slabs(&p, None) {
            Err(VolumeError::Format {
                path,
                field,
                message,
            }) => {
                assert_eq!(path, p);
                assert_eq!(field, "orientation", "{message}");
                println!("{name}: {message}");
            }
            Err(e) => panic!("{name}: wrong error {e}"),
            Ok(_) => panic!("{name}: opened for slab reading"),
        }
    }
}

#[test]
fn scl_slope_and_inter_give_physical_values() {
    // int16 with slope 1, inter -1024: f32 Hounsfield units.
    let ct = load("ct_scaled.nii");
    assert_eq!(ct.meta.stored, StoredType::I16);
    assert!(ct.meta.scale_applied);
    assert_eq!((ct.meta.scale_slope, ct.meta.scale_inter), (1.0, -1024.0));
    let VoxelData::F32(values) = ct.volume.data() else {
        panic!("expected f32, got {:?}", ct.volume.scalar_type())
    };
    let s = |x: u32, y: u32, z: u32| (24 * x + 100 * y + 500 * z) as f32;
    for z in 0..4 {
        for y in 0..5 {
            for x in 0..6 {
                assert_eq!(values[ct.volume.index(x, y, z)], s(x, y, z) - 1024.0);
            }
        }
    }
    // Windows are in HU: the value range is [-1024, 2020 - 1024].
    assert_eq!(ct.volume.value_range(), (-1024.0, 996.0));
    let (lo, hi) = ct.volume.auto_window();
    assert!(
        (-1024.0..=996.0).contains(&lo) && (lo..=996.0).contains(&hi),
        "{lo} {hi}"
    );
    assert_eq!(ct.meta.normalized(-1000.0), -1000.0);
    assert_eq!(ct.meta.file_value(-1000.0), -1000.0);

    // int16 unscaled: stored as u16 + 32768; file_value maps the normalised values back to HU.
    let signed = load("ct_signed.nii");
    assert_eq!(signed.meta.stored, StoredType::I16);
    assert!(!signed.meta.scale_applied);
    assert_eq!(signed.volume.scalar_type(), ScalarType::U16);
    for z in 0..4 {
        for y in 0..5 {
            for x in 0..6 {
                let n = signed.volume.value(x, y, z);
                let hu = signed.meta.file_value(n);
                assert!((hu - f64::from(s(x, y, z) - 1024.0)).abs() < 0.01, "{hu}");
            }
        }
    }
    let (lo, hi) = signed.volume.auto_window();
    let (lo_hu, hi_hu) = (signed.meta.file_value(lo), signed.meta.file_value(hi));
    assert!(
        (-1024.5..=996.5).contains(&lo_hu) && (lo_hu..=996.5).contains(&hi_hu),
        "{lo_hu} {hi_hu}"
    );

    // uint8 with slope 2, inter -10.
    let u8s = load("u8_scaled.nii");
    assert_eq!(u8s.meta.format, FileFormat::Nifti);
    let VoxelData::F32(values) = u8s.volume.data() else {
        panic!("expected f32")
    };
    for z in 0..SHAPE[2] {
        for y in 0..SHAPE[1] {
            for x in 0..SHAPE[0] {
                let want = 2.0 * f(x, y, z) as f32 - 10.0;
                assert_eq!(values[u8s.volume.index(x, y, z)], want);
            }
        }
    }
}

#[test]
fn las_renders_the_same_image_as_ras() {
    const SIZE: u32 = 64;
    let ras = load("ras_sform.nii").volume;
    let las = load("las_sform.nii").volume;
    // The LAS file's voxels in file order (no reorientation): file voxel (i, j, k) holds
    // f(4 - i, j, k), recomputed from the generator's formula.
    let [nx, ny, nz] = SHAPE;
    let mut raw = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                raw.push(f(nx - 1 - i, j, k) as u8);
            }
        }
    }
    let unreoriented = Volume::new(
        UVec3::from_array(SHAPE),
        Vec3::from_array(SPACING),
        VoxelData::U8(raw),
    )
    .unwrap();
    let settings = RenderSettings {
        value_window: Some((0.0, 0.55)),
        ..RenderSettings::default()
    };
    let camera = Camera::perspective(Vec3::new(1.1, 0.7, 1.5), Vec3::ZERO, 40.0);
    let ctx = common::validated_context();
    {
        let mut renderer = Renderer::new(&ctx, TargetFormat::Rgba32Float).unwrap();
        renderer
            .set_transfer_function(&TransferFunction::preset(TfPreset::Bands))
            .unwrap();
        let mut render = |v: &Volume| {
            renderer.set_source(VolumeSource::Volume(v)).unwrap();
            renderer
                .render(&camera, &settings, SIZE, SIZE)
                .unwrap()
                .pixels
        };
        let (a, b, c) = (render(&ras), render(&las), render(&unreoriented));
        let visible = a.iter().filter(|p| p.w > 0.05).count();
        assert!(
            visible > (SIZE * SIZE / 10) as usize,
            "{visible} visible pixels"
        );
        assert!(
            a == b,
            "LAS and RAS render differently: {:?}",
            common::diff(&a, &b, 1.0 / 255.0)
        );
        let d = common::diff(&a, &c, 1.0 / 255.0);
        eprintln!("RAS vs the LAS voxels un-reoriented: {d:?}");
        assert!(
            d.max > 0.03 && d.large_fraction > 0.1,
            "without the reorientation the LAS file should render mirrored: {d:?}"
        );
    }
    common::finish(ctx);
}

#[test]
fn broken_nifti2_headers_are_typed_errors_naming_the_field() {
    let good = std::fs::read(fixtures().join("ras_n2.nii")).unwrap();
    let p = Path::new("n2.nii");
    assert_eq!(parse_nifti_header(p, &good).unwrap().version, 2);
    let field_of = |bytes: &[u8]| match parse_nifti_header(p, bytes) {
        Err(VolumeError::Format { field, .. }) => field,
        other => panic!("expected a format error, got {other:?}"),
    };
    // Every truncation of the 540-byte header (past the magic) is a `header` error.
    for len in 12..540 {
        assert_eq!(field_of(&good[..len]), "header", "{len} bytes");
    }
    let with = |at: usize, bytes: &[u8]| {
        let mut h = good.clone();
        h[at..at + bytes.len()].copy_from_slice(bytes);
        h
    };
    assert_eq!(field_of(&with(4, b"ni2\0\r\n\x1a\n")), "magic");
    assert_eq!(field_of(&with(4, b"n+1\0")), "magic");
    assert_eq!(field_of(&with(12, &1i16.to_le_bytes())), "datatype");
    assert_eq!(field_of(&with(14, &9i16.to_le_bytes())), "bitpix");
    assert_eq!(field_of(&with(16, &9i64.to_le_bytes())), "dim[0]");
    assert_eq!(field_of(&with(24, &0i64.to_le_bytes())), "dim[1]");
    assert_eq!(field_of(&with(24, &(1i64 << 40).to_le_bytes())), "dim");
    assert_eq!(field_of(&with(112, &f64::NAN.to_le_bytes())), "pixdim[1]");
    assert_eq!(field_of(&with(168, &100i64.to_le_bytes())), "vox_offset");
}
