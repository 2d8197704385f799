//! DICOM series (src/volume/formats/dicom) against real files and real writers, through the venv
//! of scripts/python-env.sh (scripts/test.sh runs it and exports `MIXVOL_PYTHON`):
//! tests/fixtures/write_dicom_fixtures.py copies pydicom's own test files (CT, MR; RLE, JPEG 2000,
//! JPEG-LS, JPEG extended, deflated, big endian, implicit VR; a DICOMDIR over 3 patients) with
//! the volumes pydicom's pixel_array and nibabel's reorientation give for them, and writes the
//! MNI152 template (scripts/fetch-datasets.sh) as DICOM series in LPS axial and sagittal
//! orientations (uncompressed, JPEG 2000 lossless, JPEG-LS lossless and near-lossless, RLE with
//! a rescale to HU), file names shuffled.
//!
//! Every value is checked against what the generator computed or against the same volume loaded
//! from NIfTI (never the loader against itself, except for file-order invariance).
mod python_env;

use mixvol::volume::formats::{
    decode_dicom_slice, list_dicom_series, load_dicom, parse_dicom_slice, DicomError, DicomOptions,
    SeriesSelector, TransformSource,
};
use mixvol::volume::{
    load_volume_with_meta, FileFormat, LoadedVolume, StoredType, VolumeError, VoxelData,
};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folder holding every fixture, written once per test binary.
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

/// The DICOM error of a load that must fail with one.
fn dicom_error(result: Result<LoadedVolume, VolumeError>, what: &str) -> DicomError {
    match result {
        Err(VolumeError::Dicom(e)) => *e,
        Err(e) => panic!("{what}: not a DICOM series error: {e}"),
        Ok(l) => panic!("{what}: loaded {:?}", l.volume.dims()),
    }
}

fn load(path: &Path) -> LoadedVolume {
    load_volume_with_meta(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The voxels in file units: integer volumes less the stored type's offset, float volumes as
/// they are (physical values when the rescale was applied).
fn file_units(l: &LoadedVolume) -> Vec<f64> {
    let offset = f64::from(l.meta.stored.value_offset());
    match l.volume.data() {
        VoxelData::U8(v) => v.iter().map(|&x| f64::from(x) - offset).collect(),
        VoxelData::U16(v) => v.iter().map(|&x| f64::from(x) - offset).collect(),
        VoxelData::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
    }
}

struct Expected {
    dims: [u32; 3],
    spacing: [f64; 3],
    origin: [f64; 3],
    rescaled: bool,
    file_code: String,
    values: Vec<f64>,
}

fn expected(name: &str) -> Expected {
    let dir = fixtures().join("expected");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json"))).unwrap()).unwrap();
    let arr = |k: &str| -> Vec<f64> {
        json[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    let bytes = std::fs::read(dir.join(format!("{name}.f64"))).unwrap();
    let values = bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let d = arr("dims");
    Expected {
        dims: [d[0] as u32, d[1] as u32, d[2] as u32],
        spacing: arr("spacing").try_into().unwrap(),
        origin: arr("origin").try_into().unwrap(),
        rescaled: json["rescaled"].as_bool().unwrap(),
        file_code: json["file_code"].as_str().unwrap().to_string(),
        values,
    }
}

/// Checks a loaded volume against the generator's, values within `tolerance`; returns the
/// largest difference.
fn check(name: &str, l: &LoadedVolume, tolerance: f64) -> f64 {
    let e = expected(name);
    let v = &l.volume;
    assert_eq!(v.dims().to_array(), e.dims, "{name}: dims");
    for i in 0..3 {
        let s = f64::from(v.spacing()[i]);
        assert!(
            (s - e.spacing[i]).abs() < 1e-5,
            "{name}: spacing {:?} vs {:?}",
            v.spacing(),
            e.spacing
        );
        assert!(
            (l.meta.origin[i] - e.origin[i]).abs() < 1e-3,
            "{name}: origin {:?} vs {:?}",
            l.meta.origin,
            e.origin
        );
    }
    assert_eq!(l.meta.format, FileFormat::Dicom, "{name}");
    assert_eq!(l.meta.scale_applied, e.rescaled, "{name}: rescale applied");
    let r = l.meta.reorientation.as_ref().expect("a reorientation");
    if r.source == TransformSource::Dicom {
        assert_eq!(r.file_code(), e.file_code, "{name}: {}", r.describe());
    }
    let got = file_units(l);
    assert_eq!(got.len(), e.values.len(), "{name}");
    let mut worst = 0.0f64;
    for (i, (g, w)) in got.iter().zip(&e.values).enumerate() {
        let d = (g - w).abs();
        assert!(d <= tolerance, "{name}: voxel {i}: {g} vs pydicom's {w}");
        worst = worst.max(d);
    }
    worst
}

#[test]
fn pydicom_test_files_load_to_pydicoms_pixel_arrays() {
    let lossless = [
        "CT_small.dcm",
        "MR_small.dcm",
        "MR_small_RLE.dcm",
        "MR_small_bigendian.dcm",
        "MR_small_expb.dcm",
        "MR_small_implicit.dcm",
        "MR_small_jp2klossless.dcm",
        "MR_small_padded.dcm",
        "image_dfl.dcm",
        "rtdose_1frame.dcm",
    ];
    for name in lossless {
        let l = load(&fixtures().join("pydicom").join(name));
        check(name, &l, 0.0);
    }
    // The MR variants (RLE, JPEG 2000, JPEG-LS, big endian, implicit VR) hold the same pixels.
    let mr = load(&fixtures().join("pydicom/MR_small.dcm"));
    for name in [
        "MR_small_RLE.dcm",
        "MR_small_jp2klossless.dcm",
        "MR_small_jpeg_ls_lossless.dcm",
        "MR_small_bigendian.dcm",
    ] {
        assert_eq!(
            load(&fixtures().join("pydicom").join(name)).volume,
            mr.volume,
            "{name}"
        );
    }
    // CT: int16 with RescaleIntercept -1024 -> f32 HU; MR: int16 unscaled -> u16 + 32768.
    let ct = load(&fixtures().join("pydicom/CT_small.dcm"));
    assert!(ct.meta.scale_applied);
    assert_eq!((ct.meta.scale_slope, ct.meta.scale_inter), (1.0, -1024.0));
    assert_eq!(ct.meta.stored, StoredType::I16);
    assert_eq!(mr.meta.stored, StoredType::I16);
    assert!(!mr.meta.scale_applied);
    assert!(matches!(mr.volume.data(), VoxelData::U16(_)));
    // Lossy JPEG 2000 (a CT with a rescale, an NM image): the Rust port of OpenJPEG gives
    // exactly what pydicom's openjpeg plugin gives.
    for name in ["693_J2KI.dcm", "JPEG2000.dcm"] {
        let l = load(&fixtures().join("pydicom").join(name));
        check(name, &l, 0.0);
    }
    // JPEG-LS lossless (int16 MR) and near-lossless (8 and 16 bits): CharLS gives exactly what
    // pydicom's libjpeg plugin, another JPEG-LS implementation, gives.
    for (name, stored) in [
        ("MR_small_jpeg_ls_lossless.dcm", StoredType::I16),
        ("JPEGLSNearLossless_08.dcm", StoredType::U8),
        ("JPEGLSNearLossless_16.dcm", StoredType::U16),
    ] {
        let l = load(&fixtures().join("pydicom").join(name));
        check(name, &l, 0.0);
        assert_eq!(l.meta.stored, stored, "{name}");
    }
}

/// Asserts that decoding the file bytes `b` (of `p`) fails on PixelData with a message that
/// holds `fragment`.
fn refused_on_pixel_data(p: &Path, b: &[u8], fragment: &str) {
    match decode_dicom_slice(p, b) {
        Err(VolumeError::Format { field, message, .. }) => {
            assert!(field.starts_with("PixelData"), "{fragment}: {field}");
            assert!(message.contains(fragment), "{fragment}: {message}");
        }
        Err(e) => panic!("{fragment}: unexpected error {e}"),
        Ok(_) => panic!("{fragment}: decoded"),
    }
}

/// `bytes` with the JPEG-LS frame header (SOF55, FFF7) changed: `(i, value)` sets its byte `i`,
/// counted from the segment's length (Lf: 0-1, P: 2, Y: 3-4, X: 5-6, Nf: 7).
fn with_jpeg_ls_frame(bytes: &[u8], edits: &[(usize, u8)]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let at = b
        .windows(2)
        .position(|w| w == [0xFF, 0xF7])
        .expect("a SOF55 marker");
    for &(i, value) in edits {
        b[at + 2 + i] = value;
    }
    b
}

#[test]
fn jpeg_ls_frames_that_disagree_with_the_header_are_refused_before_decoding() {
    let p = fixtures().join("pydicom/MR_small_jpeg_ls_lossless.dcm");
    let bytes = std::fs::read(&p).unwrap();
    let (s, values) = decode_dicom_slice(&p, &bytes).unwrap();
    assert_eq!((s.columns, s.rows, s.bits_allocated), (64, 64, 16));
    assert_eq!(values.len(), 64 * 64);
    let cases: [(&str, &[(usize, u8)]); 4] = [
        // 65535 x 65535 16-bit samples: CharLS would allocate 8 GiB for this 6 KiB file.
        (
            "is 65535x65535 samples",
            &[(3, 0xFF), (4, 0xFF), (5, 0xFF), (6, 0xFF)],
        ),
        ("has 3 components", &[(1, 8 + 9), (7, 3)]),
        (
            "decode to 1 byte(s) each, but BitsAllocated is 16",
            &[(2, 8)],
        ),
        ("does not fit its 1 components", &[(1, 20)]),
    ];
    for (fragment, edits) in cases {
        refused_on_pixel_data(&p, &with_jpeg_ls_frame(&bytes, edits), fragment);
    }
}

#[test]
fn unsupported_files_are_refused_by_name() {
    let cases = [
        ("MR_truncated.dcm", "header", "unreadable DICOM file"),
        ("JPGExtended.dcm", "PixelData", "JPEG Extended"),
        ("rtdose.dcm", "NumberOfFrames", "multi-frame"),
        ("SC_rgb_small_odd.dcm", "SamplesPerPixel", "grey"),
        ("no_meta.dcm", "magic", "DICM"),
    ];
    for (name, want_field, fragment) in cases {
        let p = fixtures().join("pydicom").join(name);
        match load_volume_with_meta(&p) {
            Err(VolumeError::Format {
                path,
                field,
                message,
            }) => {
                assert_eq!(path, p, "{name}");
                assert!(
                    field.starts_with(want_field),
                    "{name}: field {field}: {message}"
                );
                assert!(message.contains(fragment), "{name}: {message}");
            }
            Err(e) => panic!("{name}: unexpected error {e}"),
            Ok(_) => panic!("{name}: loaded"),
        }
    }
}

#[test]
fn one_files_bytes_parse_into_its_slice_record() {
    let p = fixtures().join("pydicom/CT_small.dcm");
    let bytes = std::fs::read(&p).unwrap();
    let s = parse_dicom_slice(&p, &bytes).unwrap();
    assert_eq!(
        (s.rows, s.columns, s.bits_allocated, s.signed),
        (128, 128, 16, true)
    );
    assert_eq!(s.modality, "CT");
    assert_eq!((s.rescale_slope, s.rescale_intercept), (1.0, -1024.0));
    assert_eq!(s.transfer_syntax, "1.2.840.10008.1.2.1");
    assert!(s.position.is_some() && s.orientation.is_some());
    let (again, values) = decode_dicom_slice(&p, &bytes).unwrap();
    assert_eq!(again, s);
    assert_eq!(values.len(), 128 * 128);
    // pydicom's HU minus the intercept, in its row order, before any reorientation: compare the
    // sums (reordering keeps them).
    let e = expected("CT_small.dcm");
    let sum: f64 = values.iter().map(|&v| v as f64 - 1024.0).sum();
    assert_eq!(sum, e.values.iter().sum::<f64>());
    // Truncated bytes are an error, not a panic.
    for cut in [0, 100, 131, 132, 400, bytes.len() / 2, bytes.len() - 1] {
        assert!(
            decode_dicom_slice(&p, &bytes[..cut]).is_err(),
            "cut at {cut}"
        );
    }
}

fn dicomdir() -> PathBuf {
    fixtures().join("dicomdirtests")
}

#[test]
fn a_dicomdir_over_several_series_lists_them_and_a_number_or_uid_picks_one() {
    let ct5n_uid = "1.3.6.1.4.1.5962.1.1.0.0.0.1194734704.16302.0.6";
    for input in [dicomdir(), dicomdir().join("DICOMDIR")] {
        match dicom_error(load_volume_with_meta(&input), "DICOMDIR") {
            DicomError::SeveralSeries { folder, series } => {
                assert_eq!(folder, input);
                let ct5n = series
                    .iter()
                    .find(|s| s.uid == ct5n_uid)
                    .expect("CT5N listed");
                assert_eq!(ct5n.slices, 5);
                assert_eq!(ct5n.number, Some(5));
                assert_eq!(ct5n.description, "SmartScore - Gated 0.5 sec");
                assert_eq!(ct5n.modality, "CT");
                assert!(series.len() >= 9, "{series:?}");
                let text = DicomError::SeveralSeries { folder, series }.to_string();
                assert!(
                    text.contains(ct5n_uid) && text.contains("5 slices"),
                    "{text}"
                );
            }
            other => panic!("{other}"),
        }
    }
    assert!(list_dicom_series(&dicomdir())
        .unwrap()
        .iter()
        .any(|s| s.uid == ct5n_uid));
    // By number and by UID: the CT5N stack (5 slices, files in reverse position order).
    for selector in [
        SeriesSelector::Number(5),
        SeriesSelector::Uid(ct5n_uid.into()),
    ] {
        let options = DicomOptions {
            series: Some(selector),
            ..DicomOptions::default()
        };
        let l = load_dicom(&dicomdir(), &options).unwrap();
        check("CT5N", &l, 0.0);
    }
    // Series number 2 is shared (CT2 of one patient, MR2 of another): the UID must choose.
    let options = DicomOptions {
        series: Some(SeriesSelector::Number(2)),
        ..DicomOptions::default()
    };
    match dicom_error(load_dicom(&dicomdir(), &options), "series 2") {
        DicomError::SeriesNotFound { why, wanted, .. } => {
            assert_eq!(wanted, "2");
            assert!(why.contains("series have the number"), "{why}");
        }
        other => panic!("{other}"),
    }
    let options = DicomOptions {
        series: Some(SeriesSelector::Number(99)),
        ..DicomOptions::default()
    };
    assert!(matches!(
        dicom_error(load_dicom(&dicomdir(), &options), "series 99"),
        DicomError::SeriesNotFound { .. }
    ));
    // The TINY_ALPHA DICOMDIR references files without pixel data.
    assert!(matches!(
        dicom_error(
            load_volume_with_meta(&dicomdir().join("TINY_ALPHA")),
            "TINY_ALPHA"
        ),
        DicomError::NoImages { .. }
    ));
}

#[test]
fn irregular_spacing_and_mixed_orientations_are_refused() {
    // Real data: the CT2 series of patient 77654033 has slices at z -99.48, 103.02, 104.27,
    // 105.52: gaps of 202.5 and 1.25 mm.
    match dicom_error(
        load_volume_with_meta(&dicomdir().join("77654033/CT2")),
        "CT2",
    ) {
        DicomError::IrregularSpacing {
            first,
            second,
            gap,
            expected,
            first_index,
            ..
        } => {
            assert_eq!(first_index, 0);
            assert!(
                first.ends_with("17106") && second.ends_with("17136"),
                "{first:?} {second:?}"
            );
            assert!((gap - 202.5).abs() < 1e-3, "{gap}");
            assert!((expected - 1.25).abs() < 1e-3, "{expected}");
        }
        other => panic!("{other}"),
    }
    // The MNI series with slice 100 removed: a 2 mm gap among 1 mm gaps.
    let src = fixtures().join("mni_lps");
    let dst = fixtures().join("mni_lps_gap");
    let _ = std::fs::remove_dir_all(&dst);
    std::fs::create_dir_all(&dst).unwrap();
    let mut removed = None;
    for f in std::fs::read_dir(&src).unwrap() {
        let f = f.unwrap().path();
        let s = parse_dicom_slice(&f, &std::fs::read(&f).unwrap()).unwrap();
        if s.position.unwrap()[2] == -72.0 + 100.0 {
            removed = Some(f);
            continue;
        }
        std::fs::copy(&f, dst.join(f.file_name().unwrap())).unwrap();
    }
    assert!(removed.is_some());
    match dicom_error(load_volume_with_meta(&dst), "gap") {
        e @ DicomError::IrregularSpacing { .. } => {
            let DicomError::IrregularSpacing {
                gap,
                expected,
                first_index,
                ..
            } = &e
            else {
                unreachable!()
            };
            assert_eq!((*gap, *expected, *first_index), (2.0, 1.0, 99));
            assert!(e.to_string().contains("refused, not resampled"), "{e}");
        }
        other => panic!("{other}"),
    }
    // The MNI series with one slice copied under a second name (review M9: a copied file, or
    // two echoes at one position): refused, naming both files and the position, not loaded as
    // a longer volume.
    let dup = fixtures().join("mni_lps_duplicate");
    let _ = std::fs::remove_dir_all(&dup);
    std::fs::create_dir_all(&dup).unwrap();
    let mut copied = None;
    for f in std::fs::read_dir(&src).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, dup.join(f.file_name().unwrap())).unwrap();
        copied.get_or_insert(f);
    }
    let copied = copied.unwrap();
    let twin = dup.join("ZZ_copy.dcm");
    std::fs::copy(&copied, &twin).unwrap();
    match dicom_error(load_volume_with_meta(&dup), "duplicate") {
        e @ DicomError::DuplicatePosition { .. } => {
            let DicomError::DuplicatePosition { first, second, .. } = &e else {
                unreachable!()
            };
            let names = [first.file_name().unwrap(), second.file_name().unwrap()];
            assert!(
                names.contains(&twin.file_name().unwrap())
                    && names.contains(&copied.file_name().unwrap()),
                "{e}"
            );
        }
        other => panic!("{other}"),
    }
    // Without positions (review M9, D14): InstanceNumber orders the slices, numerically (1..n
    // in position order, file names shuffled: the same voxels as the positioned series); with
    // slices lacking it too, the series is refused, counting them.
    let by_number = load(&fixtures().join("mni_by_number"));
    let positioned = load(&src);
    assert_eq!(by_number.volume.dims(), positioned.volume.dims());
    // Per slice, the sum of its voxels (the positioned series is stored flipped within a slice
    // into RAS, not across slices: slice k holds the same voxels; string order of the numbers
    // would permute the slices).
    let slice_sums = |v: &mixvol::volume::Volume| -> Vec<f64> {
        let d = v.dims();
        (0..d.z)
            .map(|z| {
                let mut sum = 0.0f64;
                for y in 0..d.y {
                    for x in 0..d.x {
                        sum += f64::from(v.value(x, y, z));
                    }
                }
                sum
            })
            .collect()
    };
    let (a, b) = (
        slice_sums(&by_number.volume),
        slice_sums(&positioned.volume),
    );
    assert!(a == b, "ordered by InstanceNumber as by position");
    match dicom_error(
        load_volume_with_meta(&fixtures().join("mni_unordered")),
        "unordered",
    ) {
        e @ DicomError::Unordered {
            missing: 4,
            count: 4,
            ..
        } => {
            assert!(e.to_string().contains("cannot be ordered"), "{e}")
        }
        other => panic!("{other}"),
    }
    // Sheared by 0.5 mm per slice (a gantry tilt): refused, not loaded as a straight stack.
    match dicom_error(
        load_volume_with_meta(&fixtures().join("mni_sheared")),
        "sheared",
    ) {
        e @ DicomError::Sheared { .. } => assert!(e.to_string().contains("gantry tilt"), "{e}"),
        other => panic!("{other}"),
    }
    // The scout series of patient 98892001: two slices in different orientations.
    match dicom_error(
        load_volume_with_meta(&dicomdir().join("98892001/CT2N")),
        "CT2N",
    ) {
        DicomError::Inconsistent { field, .. } => {
            assert_eq!(field, "ImageOrientationPatient")
        }
        other => panic!("{other}"),
    }
}

fn mni_nifti() -> LoadedVolume {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::var_os("MIXVOL_DATA_DIR")
        .map(|d| root.join(d))
        .unwrap_or_else(|| root.join("target/datasets"));
    load(&dir.join("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"))
}

#[test]
fn series_written_from_the_mni_template_load_to_the_nifti_volume() {
    let nifti = mni_nifti();
    for (folder, code, flipped) in [
        ("mni_lps", "LPS", [true, true, false]),
        ("mni_sagittal", "PIR", [false, true, true]),
    ] {
        let l = load(&fixtures().join(folder));
        assert_eq!(l.volume.dims(), nifti.volume.dims(), "{folder}");
        assert_eq!(l.volume.spacing(), nifti.volume.spacing(), "{folder}");
        assert!(
            l.volume == nifti.volume,
            "{folder}: voxels differ from the NIfTI file's"
        );
        assert_eq!(l.meta.stored, StoredType::U8);
        for i in 0..3 {
            assert!(
                (l.meta.origin[i] - nifti.meta.origin[i]).abs() < 1e-6,
                "{folder}: {:?}",
                l.meta.origin
            );
        }
        let r = l.meta.reorientation.unwrap();
        assert_eq!(r.source, TransformSource::Dicom);
        assert_eq!(r.file_code(), code, "{folder}");
        assert_eq!(r.flipped, flipped, "{folder}: {}", r.describe());
        assert!(r.oblique_degrees < 1e-6);
    }
    // int16 + RescaleIntercept (RLE) against the same int16 values with scl_inter in NIfTI: both
    // f32 HU.
    let dicom = load(&fixtures().join("mni_ct"));
    let nii = load(&fixtures().join("mni_ct.nii"));
    assert!(dicom.meta.scale_applied && nii.meta.scale_applied);
    assert_eq!(dicom.meta.stored, StoredType::I16);
    assert!(dicom.volume == nii.volume, "HU voxels differ");
    let hu = dicom.volume.value(98, 116, 94);
    assert_eq!(hu, 198.0 * 8.0 - 1024.0, "white matter voxel in HU");
}

#[test]
fn jpeg_ls_series_load_to_the_uncompressed_volume() {
    // Lossless: uint8, and int16 with negative stored values and a rescale (two's complement
    // samples in the codestream, sign-extended from BitsStored).
    let nifti = mni_nifti();
    let lps = load(&fixtures().join("mni_lps"));
    let jls = load(&fixtures().join("mni_jpegls"));
    assert!(jls.volume == nifti.volume, "JPEG-LS voxels differ");
    assert_eq!(jls.meta.stored, StoredType::U8);
    assert_eq!(jls.meta.reorientation, lps.meta.reorientation);
    assert_eq!(jls.meta.origin, lps.meta.origin);
    let ct = load(&fixtures().join("mni_ct_jpegls"));
    let nii = load(&fixtures().join("mni_ct.nii"));
    assert_eq!(ct.meta.stored, StoredType::I16);
    assert!(ct.meta.scale_applied);
    assert!(ct.volume == nii.volume, "JPEG-LS HU voxels differ");
    assert_eq!(
        ct.volume.value(0, 0, 0),
        -1024.0,
        "background: stored -1000"
    );
    // Near-lossless with NEAR = 2: every voxel within 2 of the original, and not all equal.
    let near = load(&fixtures().join("mni_jpegls_near"));
    assert_eq!(near.volume.dims(), nifti.volume.dims());
    let (VoxelData::U8(a), VoxelData::U8(b)) = (near.volume.data(), nifti.volume.data()) else {
        panic!("uint8 volumes expected");
    };
    let worst = a.iter().zip(b).map(|(&x, &y)| x.abs_diff(y)).max().unwrap();
    let differ = a.iter().zip(b).filter(|(x, y)| x != y).count();
    assert!(worst <= 2, "error {worst} above NEAR = 2");
    assert!(differ > a.len() / 100, "{differ} voxels differ: not lossy?");
}

/// Copies the files of `src` into a fresh `dst` under new names from `rename`.
fn copy_renamed(src: &Path, dst: &Path, rename: impl Fn(usize, &Path) -> String) {
    let _ = std::fs::remove_dir_all(dst);
    std::fs::create_dir_all(dst).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(src)
        .unwrap()
        .map(|f| f.unwrap().path())
        .collect();
    files.sort();
    for (i, f) in files.iter().enumerate() {
        std::fs::copy(f, dst.join(rename(i, f))).unwrap();
    }
}

#[test]
fn the_file_order_does_not_change_the_volume() {
    let original = load(&fixtures().join("mni_lps"));
    let n = 189;
    // Reversed names, then names interleaved by a stride coprime with 189.
    let reversed = fixtures().join("mni_lps_reversed");
    copy_renamed(&fixtures().join("mni_lps"), &reversed, |i, _| {
        format!("{:04}", n - i)
    });
    let strided = fixtures().join("mni_lps_strided");
    copy_renamed(&fixtures().join("mni_lps"), &strided, |i, _| {
        format!("x{:04}.dcm", (i * 47) % n)
    });
    for dir in [reversed, strided] {
        let l = load(&dir);
        assert!(l.volume == original.volume, "{}", dir.display());
        assert_eq!(l.meta, original.meta, "{}", dir.display());
    }
}

#[test]
fn two_series_in_one_folder_are_listed_and_the_uid_chooses() {
    let both = fixtures().join("mni_two_series");
    copy_renamed(&fixtures().join("mni_lps"), &both, |i, _| {
        format!("a{i:04}")
    });
    for f in std::fs::read_dir(fixtures().join("mni_ct")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(
            &f,
            both.join(format!("b{}", f.file_name().unwrap().to_string_lossy())),
        )
        .unwrap();
    }
    let series = match dicom_error(load_volume_with_meta(&both), "two series") {
        DicomError::SeveralSeries { series, .. } => series,
        other => panic!("{other}"),
    };
    assert_eq!(series.len(), 2);
    assert!(series.iter().all(|s| s.slices == 189), "{series:?}");
    let ct = series.iter().find(|s| s.modality == "CT").unwrap();
    assert_eq!(ct.number, Some(7));
    assert_eq!(ct.description, "mni_ct");
    let by_uid = DicomOptions {
        series: Some(SeriesSelector::Uid(ct.uid.clone())),
        ..DicomOptions::default()
    };
    let by_number = DicomOptions {
        series: Some(SeriesSelector::Number(3)),
        ..DicomOptions::default()
    };
    let alone = load(&fixtures().join("mni_ct"));
    assert!(load_dicom(&both, &by_uid).unwrap().volume == alone.volume);
    assert!(load_dicom(&both, &by_number).unwrap().volume == mni_nifti().volume);
}

#[test]
fn mutated_files_give_errors_not_panics() {
    // The fuzz target's entry points on real files with bytes flipped (deterministic xorshift):
    // Ok or a typed error, never a panic.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for name in [
        "CT_small.dcm",
        "MR_small_RLE.dcm",
        "MR_small_jp2klossless.dcm",
        "MR_small_jpeg_ls_lossless.dcm",
        "image_dfl.dcm",
    ] {
        let p = fixtures().join("pydicom").join(name);
        let bytes = std::fs::read(&p).unwrap();
        let mut errors = 0;
        for _ in 0..80 {
            let mut b = bytes.clone();
            for _ in 0..1 + next() % 4 {
                // Mostly the header (the first 1.5 KiB), sometimes anywhere.
                let span = if next() % 4 == 0 {
                    b.len()
                } else {
                    b.len().min(1536)
                };
                let at = 132 + (next() as usize) % (span - 132);
                b[at] = next() as u8;
            }
            let _ = parse_dicom_slice(&p, &b);
            errors += usize::from(decode_dicom_slice(&p, &b).is_err());
        }
        assert!(errors > 0, "{name}: no mutation was refused");
    }
}

/// Issue 42, item 2 (review D2): a file of a series folder whose `DICM` magic is damaged, or
/// which is empty, is named in an error instead of dropped (the series would load a slice
/// short: at its end no spacing check can see the gap); the scheme of the names decides, so
/// extensionless numbered files are covered too. A file that is not DICOM and not named like
/// the slices (a README) is skipped, and the volume is the whole series.
#[test]
fn a_damaged_or_empty_slice_file_is_named_not_dropped() {
    let original = load(&fixtures().join("mni_lps"));
    let lost =
        |dir: &Path| match dicom_error(load_volume_with_meta(dir), &dir.display().to_string()) {
            DicomError::LostSlices {
                files, dicom_files, ..
            } => (files, dicom_files),
            other => panic!("{}: {other}", dir.display()),
        };
    // The last slice's magic with one bit flipped ("DICM" -> "DHCM").
    let damaged = fixtures().join("mni_lps_damaged_magic");
    copy_renamed(&fixtures().join("mni_lps"), &damaged, |_, f| {
        f.file_name().unwrap().to_string_lossy().into_owned()
    });
    let last = damaged.join("IM0188.dcm");
    let mut bytes = std::fs::read(&last).unwrap();
    assert_eq!(&bytes[128..132], b"DICM");
    bytes[129] ^= 0x01;
    std::fs::write(&last, &bytes).unwrap();
    assert_eq!(lost(&damaged), (vec![last.clone()], 188));
    let message = load_volume_with_meta(&damaged).err().unwrap().to_string();
    assert!(
        message.contains("IM0188.dcm") && message.contains("1 file named like"),
        "{message}"
    );
    // A slice emptied, in a series of extensionless numbered files.
    let numbered = fixtures().join("mni_lps_emptied");
    copy_renamed(&fixtures().join("mni_lps"), &numbered, |i, _| {
        format!("{i:05}")
    });
    let emptied = numbered.join("00100");
    std::fs::write(&emptied, b"").unwrap();
    assert_eq!(lost(&numbered), (vec![emptied], 188));
    // A README beside the slices is skipped: the whole series loads.
    let with_readme = fixtures().join("mni_lps_with_readme");
    copy_renamed(&fixtures().join("mni_lps"), &with_readme, |_, f| {
        f.file_name().unwrap().to_string_lossy().into_owned()
    });
    std::fs::write(with_readme.join("README.txt"), "exported by a scanner\n").unwrap();
    let l = load(&with_readme);
    assert!(l.volume == original.volume);
    assert_eq!(l.meta, original.meta);
}

/// `bytes` with words of the RLE header of its one frame replaced: `(i, value)` sets the 32-bit
/// word `i` (0: the segment count, 1-15: the segment offsets). The frame is the second item of
/// the encapsulated PixelData (the first is the basic offset table).
fn with_rle_header(bytes: &[u8], edits: &[(usize, u32)]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let tag = b
        .windows(4)
        .position(|w| w == [0xE0, 0x7F, 0x10, 0x00])
        .expect("a PixelData element");
    // Tag, "OB", 2 reserved bytes, undefined length; then the offset table's item.
    let table = tag + 12;
    assert_eq!(b[table..table + 4], [0xFE, 0xFF, 0x00, 0xE0]);
    let table_len = u32::from_le_bytes(b[table + 4..table + 8].try_into().unwrap()) as usize;
    let frame = table + 8 + table_len + 8;
    for &(i, value) in edits {
        b[frame + 4 * i..frame + 4 * i + 4].copy_from_slice(&value.to_le_bytes());
    }
    b
}

/// Issue 42, item 4 (review D5): an RLE frame whose header lists a garbage segment count (the
/// adapter would size its table from it first: 13 GB for 300 bytes) or segments outside the
/// frame is refused before it is decoded, with what was found; the intact file decodes to the
/// values pydicom gives (tested above).
#[test]
fn rle_frames_with_damaged_headers_are_refused_before_decoding() {
    let p = fixtures().join("pydicom/MR_small_RLE.dcm");
    let bytes = std::fs::read(&p).unwrap();
    let (s, values) = decode_dicom_slice(&p, &bytes).unwrap();
    assert_eq!((s.columns, s.rows, s.bits_allocated), (64, 64, 16));
    assert_eq!(values.len(), 64 * 64);
    assert!(decode_dicom_slice(&p, &with_rle_header(&bytes, &[])).is_ok());
    let cases: [(&str, &[(usize, u32)]); 4] = [
        ("lists 3294898289 segments", &[(0, 3_294_898_289)]),
        ("lists 3 segments", &[(0, 3)]),
        ("segment 2 at byte 4294901760", &[(2, 0xFFFF_0000)]),
        ("segment 1 at byte 0", &[(1, 0)]),
    ];
    for (fragment, edits) in cases {
        refused_on_pixel_data(&p, &with_rle_header(&bytes, edits), fragment);
    }
}
