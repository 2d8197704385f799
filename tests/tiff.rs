//! TIFF stacks written by tifffile (installed from PyPI by scripts/python-env.sh, which
//! scripts/test.sh runs and exports as `MIXVOL_PYTHON`): tests/fixtures/write_tiff_fixtures.py
//! writes plain stacks of every type, big-endian, BigTIFF, LZW / Deflate / PackBits / Zstd
//! pages, tiled pages, OME-TIFFs with physical sizes and with several channels and time points,
//! a folder of slices, wrong inputs, and the MNI152 template (fetched by
//! scripts/fetch-datasets.sh) as an OME-TIFF.
//!
//! Every voxel is checked against the formula the generator used (never the loader against
//! itself), or, for the MNI template, against the NIfTI load of the same data.
mod python_env;

use glam::{UVec3, Vec3};
use mixvol::volume::formats::{load_tiff_with, parse_ome_xml, TiffOptions, TiffSlabs};
use mixvol::volume::{
    load_volume, load_volume_with_meta, open_slabs, FileFormat, LoadedVolume, SlabMut, StoredType,
    Volume, VolumeError, VoxelData,
};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folder holding every fixture, written once per test binary.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        python_env::write_fixtures(
            "write_tiff_fixtures.py",
            "tifffile-fixtures",
            "scripts/requirements-tiff.txt",
        )
    })
}

const DIMS: [u32; 3] = [5, 4, 3];

/// The generator's anatomy.
fn f(x: u32, y: u32, z: u32) -> i64 {
    i64::from(x + 10 * y + 50 * z)
}

fn load(name: &str) -> LoadedVolume {
    let p = fixtures().join(name);
    load_volume_with_meta(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The volume's raw value at (x, y, z): u8 / u16 as integers, f32 as is.
fn raw(v: &Volume, x: u32, y: u32, z: u32) -> f64 {
    let i = v.index(x, y, z);
    match v.data() {
        VoxelData::U8(d) => f64::from(d[i]),
        VoxelData::U16(d) => f64::from(d[i]),
        VoxelData::F32(d) => f64::from(d[i]),
    }
}

/// Checks every voxel of `v` (dims `dims`) against `want`.
fn check_voxels(name: &str, v: &Volume, dims: [u32; 3], want: impl Fn(u32, u32, u32) -> f64) {
    assert_eq!(v.dims().to_array(), dims, "{name}: dims");
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                assert_eq!(
                    raw(v, x, y, z),
                    want(x, y, z),
                    "{name}: voxel ({x}, {y}, {z})"
                );
            }
        }
    }
}

/// The raw volume value of the generator's type `ty` at (x, y, z), mapped per the value table
/// (i8 + 128, i16 + 32768, 32-bit integers and f64 to f32).
fn mapped(ty: &str, x: u32, y: u32, z: u32) -> f64 {
    let v = f(x, y, z);
    match ty {
        "u8" => v as f64,
        "i8" => (v - 100 + 128) as f64,
        "u16" => (v * 300) as f64,
        "i16" => (v * 100 - 10000 + 32768) as f64,
        "u32" => (v * 100000) as f32 as f64,
        "i32" => (-v * 1000) as f32 as f64,
        "f32" => (v as f32 * 0.5 - 3.25) as f64,
        "f64" => (v as f64 / 3.0) as f32 as f64,
        _ => unreachable!("{ty}"),
    }
}

#[test]
fn every_type_loads_per_the_value_table() {
    use StoredType::*;
    for (ty, stored) in [
        ("u8", U8),
        ("i8", I8),
        ("u16", U16),
        ("i16", I16),
        ("u32", U32),
        ("i32", I32),
        ("f32", F32),
        ("f64", F64),
    ] {
        let name = format!("{ty}.tif");
        let l = load(&name);
        assert_eq!(l.meta.format, FileFormat::Tiff, "{name}");
        assert_eq!(l.meta.stored, stored, "{name}");
        assert_eq!(l.volume.scalar_type(), stored.volume_scalar(), "{name}");
        assert_eq!(l.volume.spacing(), Vec3::ONE, "{name}: plain TIFF spacing");
        assert!(!l.meta.big_endian, "{name}");
        check_voxels(&name, &l.volume, DIMS, |x, y, z| mapped(ty, x, y, z));
    }
}

#[test]
fn byte_orders_bigtiff_and_compressions_decode_the_same_voxels() {
    for (name, ty, big_endian) in [
        ("u16_be.tif", "u16", true),
        ("bigtiff.tif", "u16", false),
        ("bigtiff.btf", "i16", false),
        ("lzw.tif", "u16", false),
        ("zlib.tif", "f32", false),
        ("zlib_fp.tif", "f32", false),
        ("packbits.tif", "u8", false),
        ("zstd.tif", "i16", false),
    ] {
        let l = load(name);
        assert_eq!(l.meta.big_endian, big_endian, "{name}");
        check_voxels(name, &l.volume, DIMS, |x, y, z| mapped(ty, x, y, z));
    }
}

#[test]
fn tiled_pages_with_partial_edge_tiles() {
    for name in ["tiled.tif", "tiled_raw.tif"] {
        let l = load(name);
        check_voxels(name, &l.volume, [50, 40, 3], |x, y, z| {
            f64::from(x + 50 * y + 2000 * z)
        });
    }
}

#[test]
fn ome_tiff_physical_sizes_become_the_spacing() {
    let l = load("phys.ome.tif");
    // PhysicalSizeZ = 2000 nm = 2 µm; spacing is in micrometres.
    assert_eq!(l.volume.spacing(), Vec3::new(0.5, 0.25, 2.0));
    check_voxels("phys.ome.tif", &l.volume, DIMS, |x, y, z| {
        mapped("u16", x, y, z)
    });
}

#[test]
fn ome_tiff_channels_and_time_points_are_selected_by_dimension_order() {
    let path = fixtures().join("tczyx.ome.tif");
    let l = load("tczyx.ome.tif");
    assert_eq!(l.volume.spacing(), Vec3::new(1.5, 1.5, 3.0));
    check_voxels("tczyx c0 t0", &l.volume, DIMS, |x, y, z| f(x, y, z) as f64);
    for (c, t) in [(2, 1), (1, 0), (0, 1)] {
        let options = TiffOptions {
            channel: c,
            time: t,
            ..TiffOptions::default()
        };
        let l = load_tiff_with(&path, &options).unwrap();
        check_voxels(&format!("tczyx c{c} t{t}"), &l.volume, DIMS, |x, y, z| {
            (f(x, y, z) + 1000 * c as i64 + 5000 * t as i64) as f64
        });
    }
    // Channels interleaved between the z planes (DimensionOrder XYCZT).
    let zcyx = fixtures().join("zcyx.ome.tif");
    for c in 0..3u64 {
        let options = TiffOptions {
            channel: c,
            ..TiffOptions::default()
        };
        let l = load_tiff_with(&zcyx, &options).unwrap();
        check_voxels(&format!("zcyx c{c}"), &l.volume, DIMS, |x, y, z| {
            (f(x, y, z) + 1000 * c as i64) as f64
        });
    }
    // Out of range selections name the OME field; a plain TIFF has no channels.
    for (options, field) in [
        (
            TiffOptions {
                channel: 3,
                ..TiffOptions::default()
            },
            "SizeC",
        ),
        (
            TiffOptions {
                time: 2,
                ..TiffOptions::default()
            },
            "SizeT",
        ),
        (
            TiffOptions {
                image: 1,
                ..TiffOptions::default()
            },
            "Image",
        ),
    ] {
        match load_tiff_with(&path, &options) {
            Err(VolumeError::Format { field: got, .. }) => assert_eq!(got, field, "{options:?}"),
            other => panic!("{options:?}: expected a Format error on {field}, got {other:?}"),
        }
    }
    let plain = TiffOptions {
        channel: 1,
        ..TiffOptions::default()
    };
    match load_tiff_with(&fixtures().join("u8.tif"), &plain) {
        Err(VolumeError::Format { field, .. }) => assert_eq!(field, "SizeC"),
        other => panic!("expected a SizeC error, got {other:?}"),
    }
}

#[test]
fn the_ome_xml_of_the_file_parses_with_its_sizes_and_tiff_data() {
    let path = fixtures().join("tczyx.ome.tif");
    let slabs = TiffSlabs::open(&path, &TiffOptions::default()).unwrap();
    let px = slabs.info().ome.as_ref().expect("OME-XML");
    assert_eq!(px.size, [5, 4, 3, 3, 2]);
    assert_eq!(px.dimension_order.name(), "XYZCT");
    assert_eq!(px.tiff_data.len(), 1);
    assert_eq!(px.tiff_data[0].plane_count, Some(18));
    assert_eq!(slabs.info().pages, 18);
    // A document that is not OME is refused on the document.
    match parse_ome_xml(&path, b"<svg/>") {
        Err(VolumeError::Format { field, .. }) => assert_eq!(field, "OME-XML"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_folder_of_slices_stacks_in_natural_order() {
    let l = load("slices");
    assert_eq!(l.meta.format, FileFormat::Tiff);
    check_voxels("slices", &l.volume, [5, 4, 11], |x, y, z| {
        f64::from(x + 10 * y + 20 * z)
    });
    assert_eq!(
        FileFormat::detect(&fixtures().join("slices")),
        Some(FileFormat::Tiff)
    );
}

/// The error a wrong input gives, as (page, field, message); panics on another error.
fn page_error(name: &str) -> (PathBuf, u64, String, String) {
    match load_volume(&fixtures().join(name)) {
        Err(VolumeError::TiffPage {
            path,
            page,
            field,
            message,
        }) => (path, page, field, message),
        other => panic!("{name}: expected a TiffPage error, got {other:?}"),
    }
}

#[test]
fn wrong_inputs_give_typed_errors_naming_the_page_and_field() {
    let (_, page, field, message) = page_error("sizes.tif");
    assert_eq!((page, field.as_str()), (2, "ImageWidth"), "{message}");
    assert!(
        message.contains("6x4") && message.contains("page 0"),
        "{message}"
    );
    let (_, page, field, message) = page_error("types.tif");
    assert_eq!((page, field.as_str()), (1, "SampleFormat"), "{message}");
    assert!(
        message.contains("u16") && message.contains("u8"),
        "{message}"
    );
    let (_, page, field, message) = page_error("rgb.tif");
    assert_eq!(
        (page, field.as_str()),
        (0, "PhotometricInterpretation"),
        "{message}"
    );
    assert!(message.contains("RGB"), "{message}");
    let (_, page, field, message) = page_error("f16.tif");
    assert_eq!((page, field.as_str()), (0, "SampleFormat"), "{message}");
    // Cut inside the pixel data: the IFDs of pages 1 and 2 are gone, or a page's data ends.
    let (_, page, field, message) = page_error("truncated.tif");
    assert_eq!((page, field.as_str()), (1, "IFD"), "{message}");
    let (_, page, field, message) = page_error("truncated_page.tif");
    assert_eq!((page, field.as_str()), (0, "data"), "{message}");
    assert!(message.contains("truncated"), "{message}");
    let (path, page, field, message) = page_error("bad_slices");
    assert_eq!(path.file_name().unwrap(), "a2.tif");
    assert_eq!((page, field.as_str()), (1, "ImageLength"), "{message}");
    // Not a TIFF at all.
    let bogus = fixtures().join("bogus.tif");
    std::fs::write(&bogus, b"not a tiff file").unwrap();
    assert!(matches!(
        load_volume(&bogus),
        Err(VolumeError::TiffPage { page: 0, .. })
    ));
}

/// A buffer of `data`'s type and length holding no voxel of any fixture (0xAB bytes, -12345.0).
fn poisoned(data: &VoxelData) -> VoxelData {
    match data {
        VoxelData::U8(v) => VoxelData::U8(vec![0xAB; v.len()]),
        VoxelData::U16(v) => VoxelData::U16(vec![0xABAB; v.len()]),
        VoxelData::F32(v) => VoxelData::F32(vec![-12345.0; v.len()]),
    }
}

/// The first `count` voxels of `data`, normalised.
fn leading_voxels(data: &VoxelData, count: usize) -> Vec<f32> {
    (0..count).map(|i| data.normalized(i)).collect()
}

#[test]
fn slabs_stream_pages_in_any_order_and_match_the_load() {
    for name in ["tiled.tif", "i16.tif", "f64.tif", "tczyx.ome.tif", "slices"] {
        let path = fixtures().join(name);
        let whole = load_volume(&path).unwrap();
        let mut reader = open_slabs(&path, None).unwrap();
        assert_eq!(reader.dims(), whole.dims(), "{name}");
        assert_eq!(reader.spacing(), whole.spacing(), "{name}");
        assert!(!reader.forward_only());
        let d = reader.dims();
        let plane = (d.x * d.y) as usize;
        // Backwards, one plane at a time, then two planes at once, each into a poisoned buffer
        // (review M7: a read that writes nothing must fail).
        let mut got = poisoned(whole.data());
        for z in (0..d.z).rev() {
            let out =
                SlabMut::of_range(&mut got, z as usize * plane..(z as usize + 1) * plane).unwrap();
            reader.read_slab(z..z + 1, out).unwrap();
        }
        assert_eq!(&got, whole.data(), "{name}");
        if d.z >= 2 {
            got = poisoned(whole.data());
            let out = SlabMut::of_range(&mut got, 0..2 * plane).unwrap();
            reader.read_slab(0..2, out).unwrap();
            let two = 2 * plane;
            assert_eq!(
                leading_voxels(&got, two),
                leading_voxels(whole.data(), two),
                "{name}"
            );
        }
        reader.finish().unwrap();
        // A page (plus a page of scratch for converted types) and a small read buffer: far
        // less than the volume for real stacks.
        let stored = reader.meta().unwrap().stored.size_bytes() as u64;
        assert!(
            reader.scratch_bytes() <= 2 * plane as u64 * stored + (64 << 10),
            "{name}"
        );
    }
}

#[test]
fn the_mni_template_as_ome_tiff_matches_its_nifti_load_voxel_for_voxel() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::var_os("MIXVOL_DATA_DIR")
        .map(|d| root.join(d))
        .unwrap_or_else(|| root.join("target/datasets"));
    let nii = dir.join("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii");
    assert!(
        nii.is_file(),
        "{} missing: run scripts/fetch-datasets.sh (scripts/test.sh does)",
        nii.display()
    );
    let reference = load_volume(&nii).unwrap();
    assert_eq!(reference.dims(), UVec3::new(197, 233, 189));
    for name in ["mni.ome.tif", "mni.tif"] {
        let l = load(name);
        assert_eq!(l.meta.stored, StoredType::U8, "{name}");
        assert_eq!(l.volume.data(), reference.data(), "{name}: voxels");
        assert_eq!(l.volume.dims(), reference.dims(), "{name}");
    }
    // 1 mm physical sizes are 1000 µm.
    assert_eq!(load("mni.ome.tif").volume.spacing(), Vec3::splat(1000.0));
    let tiled = TiffSlabs::open(&fixtures().join("mni.ome.tif"), &TiffOptions::default()).unwrap();
    assert!(tiled.info().tiled);
    assert_eq!(tiled.info().compression, 8, "Deflate");
}

#[test]
fn hostile_ome_xml_gives_typed_errors() {
    let path = Path::new("hostile.ome.tif");
    let pixels = |attrs: &str, body: &str| {
        format!(
            r#"<?xml version="1.0"?><OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06"><Image ID="Image:0"><Pixels {attrs}>{body}</Pixels></Image></OME>"#
        )
    };
    let sizes = r#"SizeX="5" SizeY="4" SizeZ="3" SizeC="1" SizeT="1" Type="uint8""#;
    let cases: Vec<(String, &str)> = vec![
        ("<OME".into(), "OME-XML"),
        ("\u{feff}<notxml".into(), "OME-XML"),
        (
            r#"<!DOCTYPE OME [<!ENTITY a "aaaa">]><OME>&a;</OME>"#.into(),
            "OME-XML",
        ),
        (r#"<OME></OME>"#.into(), "Image"),
        (
            pixels(r#"SizeX="5" SizeY="4" SizeC="1" SizeT="1""#, ""),
            "SizeZ",
        ),
        (
            pixels(
                r#"SizeX="5" SizeY="4" SizeZ="18446744073709551616" SizeC="1" SizeT="1""#,
                "",
            ),
            "SizeZ",
        ),
        (
            pixels(&format!(r#"{sizes} DimensionOrder="XYZZT""#), ""),
            "DimensionOrder",
        ),
        (
            pixels(&format!(r#"{sizes} PhysicalSizeX="-1""#), ""),
            "PhysicalSizeX",
        ),
        (
            pixels(
                &format!(r#"{sizes} PhysicalSizeX="1e300" PhysicalSizeXUnit="km""#),
                "",
            ),
            "PhysicalSizeX",
        ),
        (
            pixels(
                &format!(r#"{sizes} PhysicalSizeZ="1" PhysicalSizeZUnit="pixel""#),
                "",
            ),
            "PhysicalSizeZUnit",
        ),
        (pixels(sizes, r#"<TiffData IFD="x"/>"#), "TiffData"),
    ];
    for (xml, field) in cases {
        match parse_ome_xml(path, xml.as_bytes()) {
            Err(VolumeError::Format { field: got, .. }) => assert_eq!(got, field, "{xml}"),
            other => panic!("{xml}: expected a Format error on {field}, got {other:?}"),
        }
    }
    // Huge sizes parse (they are only numbers) and plane look-ups overflow into typed errors or
    // land in another file's planes, never a panic.
    let xml = pixels(
        r#"SizeX="1" SizeY="1" SizeZ="18446744073709551615" SizeC="18446744073709551615" SizeT="2" DimensionOrder="XYZCT""#,
        r#"<TiffData IFD="18446744073709551615" PlaneCount="18446744073709551615"/><TiffData FirstZ="3"><UUID FileName="other.ome.tif">urn:uuid:1</UUID></TiffData>"#,
    );
    let ome = parse_ome_xml(path, xml.as_bytes()).unwrap();
    let px = &ome.images[0];
    assert!(matches!(
        px.ifd_of(path, [0, 0, 1]),
        Err(VolumeError::Format { .. })
    ));
    assert!(matches!(
        px.ifd_of(path, [5, 0, 0]),
        Err(VolumeError::Format { ref field, .. }) if field == "TiffData"
    ));
    assert!(px.ifd_of(path, [1, 0, 0]).is_err(), "IFD + 1 overflows");
    assert_eq!(px.ifd_of(path, [0, 0, 0]).unwrap(), Some(u64::MAX));
}

#[test]
fn imagej_hyperstacks_pick_channel_and_frame_with_their_voxel_size() {
    let path = fixtures().join("imagej.tif");
    let l = load("imagej.tif");
    assert_eq!(l.volume.spacing(), Vec3::new(0.5, 0.25, 2.0));
    check_voxels("imagej c0 t0", &l.volume, DIMS, |x, y, z| f(x, y, z) as f64);
    let slabs = TiffSlabs::open(&path, &TiffOptions::default()).unwrap();
    let ij = slabs.info().imagej.as_ref().expect("ImageJ description");
    assert_eq!((ij.channels, ij.slices, ij.frames), (2, 3, 2));
    for (c, t) in [(1, 0), (0, 1), (1, 1)] {
        let options = TiffOptions {
            channel: c,
            time: t,
            ..TiffOptions::default()
        };
        let l = load_tiff_with(&path, &options).unwrap();
        check_voxels(&format!("imagej c{c} t{t}"), &l.volume, DIMS, |x, y, z| {
            (f(x, y, z) + 1000 * c as i64 + 5000 * t as i64) as f64
        });
    }
    let options = TiffOptions {
        channel: 2,
        ..TiffOptions::default()
    };
    match load_tiff_with(&path, &options) {
        Err(VolumeError::Format { field, .. }) => assert_eq!(field, "channels"),
        other => panic!("expected a channels error, got {other:?}"),
    }
}
