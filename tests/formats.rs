//! Volume file formats (CPU only): NIfTI-1, NRRD, JSON sidecar + raw, VolPack `.den`.
//!
//! Small files of every format are written by hand into a temporary folder and loaded back (every
//! stored type, both byte orders, raw and gzip); malformed files must give the typed
//! `VolumeError::Format` naming the file and the field at fault. The last tests read the real
//! volumes that `scripts/fetch-datasets.sh` downloads into `$MIXVOL_DATA_DIR` (default
//! `target/datasets`); they fail, never skip, when those files are missing.
use flate2::write::GzEncoder;
use flate2::Compression;
use glam::{UVec3, Vec3};
use mixvol::volume::formats::{
    parse_den_header, parse_nifti_header, parse_nrrd_header, parse_sidecar, Encoding, I16_OFFSET,
    MAX_VOLUME_BYTES,
};
use mixvol::volume::{
    load_den, load_nifti, load_nrrd, load_sidecar, load_volume, load_volume_with_meta, FileFormat,
    LoadedVolume, StoredType, VolumeError, VoxelData,
};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

// ---------------------------------------------------------------------------------------------
// Helpers

/// A unique temporary folder, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("mixvol-formats-{}-{n}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Asserts a `Format` error on `path` and `field`; returns the message.
#[track_caller]
fn expect_format<T: std::fmt::Debug>(
    result: Result<T, VolumeError>,
    path: &Path,
    field: &str,
) -> String {
    match result {
        Err(VolumeError::Format {
            path: p,
            field: f,
            message,
        }) => {
            assert_eq!(p, path, "wrong path in error: {message}");
            assert_eq!(f, field, "wrong field in error: {message}");
            // The Display form names the file and the field.
            let shown = VolumeError::Format {
                path: p.clone(),
                field: f.clone(),
                message: message.clone(),
            }
            .to_string();
            assert!(shown.contains(&*p.to_string_lossy()) && shown.contains(&f));
            message
        }
        other => panic!("expected a Format error on `{field}`, got {other:?}"),
    }
}

fn dims_of(r: Result<LoadedVolume, VolumeError>) -> Result<UVec3, VolumeError> {
    r.map(|l| l.volume.dims())
}

const ALL_TYPES: [StoredType; 8] = [
    StoredType::U8,
    StoredType::I8,
    StoredType::U16,
    StoredType::I16,
    StoredType::U32,
    StoredType::I32,
    StoredType::F32,
    StoredType::F64,
];

/// Twelve test values per stored type, covering each type's extremes.
fn values(t: StoredType) -> Vec<f64> {
    let v: &[f64] = match t {
        StoredType::U8 => &[0., 1., 2., 100., 127., 128., 200., 254., 255., 3., 4., 5.],
        StoredType::I8 => &[-128., -127., -1., 0., 1., 64., 127., -64., 2., 3., 4., 5.],
        StoredType::U16 => &[
            0., 1., 258., 32767., 32768., 65534., 65535., 7., 8., 9., 10., 11.,
        ],
        StoredType::I16 => &[
            -32768., -1000., -1., 0., 1., 1000., 32767., 258., -258., 3., 4., 5.,
        ],
        StoredType::U32 => &[0., 1., 70000., 16777216., 5., 6., 7., 8., 9., 10., 11., 12.],
        StoredType::I32 => &[-5., 0., 123456., -16777216., 1., 2., 3., 4., 5., 6., 7., 8.],
        StoredType::F32 => &[
            -1.5, 0.25, 3.0e5, 0.0, -0.0, 1e-3, 2.5, 7., 8., 9., 10., 11.,
        ],
        StoredType::F64 => &[
            -2.5, 1e-3, 12345.678, 0.1, 1e30, -1e-30, 3., 4., 5., 6., 7., 8.,
        ],
    };
    v.to_vec()
}

fn encode(t: StoredType, values: &[f64], big: bool) -> Vec<u8> {
    let mut out = Vec::new();
    macro_rules! put {
        ($x:expr) => {
            if big {
                out.extend_from_slice(&$x.to_be_bytes())
            } else {
                out.extend_from_slice(&$x.to_le_bytes())
            }
        };
    }
    for &v in values {
        match t {
            StoredType::U8 => put!(v as u8),
            StoredType::I8 => put!(v as i8),
            StoredType::U16 => put!(v as u16),
            StoredType::I16 => put!(v as i16),
            StoredType::U32 => put!(v as u32),
            StoredType::I32 => put!(v as i32),
            StoredType::F32 => put!(v as f32),
            StoredType::F64 => put!(v),
        }
    }
    out
}

/// What the loaders must produce for `values` of type `t` (the documented mapping).
fn expected(t: StoredType, values: &[f64]) -> VoxelData {
    match t {
        StoredType::U8 => VoxelData::U8(values.iter().map(|&v| v as u8).collect()),
        StoredType::I8 => VoxelData::U8(values.iter().map(|&v| (v + 128.0) as u8).collect()),
        StoredType::U16 => VoxelData::U16(values.iter().map(|&v| v as u16).collect()),
        StoredType::I16 => VoxelData::U16(
            values
                .iter()
                .map(|&v| (v + f64::from(I16_OFFSET)) as u16)
                .collect(),
        ),
        _ => VoxelData::F32(values.iter().map(|&v| v as f32).collect()),
    }
}

const DIMS: [u64; 3] = [3, 2, 2];

// ---------------------------------------------------------------------------------------------
// NIfTI-1 writer (hand-built 348-byte header + 4 extension bytes + data)

#[derive(Clone)]
struct Nifti {
    dim: [i16; 8],
    datatype: i16,
    bitpix: i16,
    pixdim: [f32; 8],
    vox_offset: f32,
    big: bool,
    sizeof_hdr: i32,
    magic: [u8; 4],
    qform: Option<([f32; 3], [f32; 3])>,
    sform: Option<[[f32; 4]; 3]>,
    scl: (f32, f32),
}

impl Nifti {
    fn new(t: StoredType) -> Self {
        let (datatype, bits) = match t {
            StoredType::U8 => (2, 8),
            StoredType::I16 => (4, 16),
            StoredType::I32 => (8, 32),
            StoredType::F32 => (16, 32),
            StoredType::F64 => (64, 64),
            StoredType::I8 => (256, 8),
            StoredType::U16 => (512, 16),
            StoredType::U32 => (768, 32),
        };
        Self {
            dim: [
                3,
                DIMS[0] as i16,
                DIMS[1] as i16,
                DIMS[2] as i16,
                1,
                1,
                1,
                1,
            ],
            datatype,
            bitpix: bits,
            pixdim: [1.0, 0.5, 1.0, 2.5, 1.0, 1.0, 1.0, 1.0],
            vox_offset: 352.0,
            big: false,
            sizeof_hdr: 348,
            magic: *b"n+1\0",
            qform: None,
            sform: None,
            scl: (0.0, 0.0),
        }
    }

    fn header(&self) -> Vec<u8> {
        let mut h = vec![0u8; 348];
        let big = self.big;
        let mut put = |at: usize, bytes: &[u8]| h[at..at + bytes.len()].copy_from_slice(bytes);
        macro_rules! num {
            ($x:expr) => {
                if big {
                    $x.to_be_bytes()
                } else {
                    $x.to_le_bytes()
                }
            };
        }
        put(0, &num!(self.sizeof_hdr));
        put(38, b"r");
        for (i, d) in self.dim.iter().enumerate() {
            put(40 + 2 * i, &num!(*d));
        }
        put(70, &num!(self.datatype));
        put(72, &num!(self.bitpix));
        for (i, p) in self.pixdim.iter().enumerate() {
            put(76 + 4 * i, &num!(*p));
        }
        put(108, &num!(self.vox_offset));
        put(112, &num!(self.scl.0));
        put(116, &num!(self.scl.1));
        put(123, &[2]); // xyzt_units: mm
        if let Some((q, offset)) = self.qform {
            put(252, &num!(1i16));
            for (i, v) in q.iter().chain(&offset).enumerate() {
                put(256 + 4 * i, &num!(*v));
            }
        }
        if let Some(rows) = self.sform {
            put(254, &num!(2i16));
            for (r, row) in rows.iter().enumerate() {
                for (c, v) in row.iter().enumerate() {
                    put(280 + 16 * r + 4 * c, &num!(*v));
                }
            }
        }
        put(344, &self.magic);
        h
    }

    /// Header, 4 zero extension bytes, padding up to `vox_offset`, then `data`.
    fn file(&self, data: &[u8]) -> Vec<u8> {
        let mut f = self.header();
        let off = if self.vox_offset.is_finite() && self.vox_offset >= 352.0 {
            self.vox_offset as usize
        } else {
            352
        };
        f.resize(off, 0);
        f.extend_from_slice(data);
        f
    }
}

// ---------------------------------------------------------------------------------------------
// NIfTI-1

#[test]
fn nifti_every_type_both_byte_orders() {
    let dir = TempDir::new("nii-types");
    for t in ALL_TYPES {
        for big in [false, true] {
            let vals = values(t);
            let n = Nifti {
                big,
                ..Nifti::new(t)
            };
            let p = dir.write(
                &format!("{}-{big}.nii", t.name()),
                &n.file(&encode(t, &vals, big)),
            );
            let loaded = load_volume_with_meta(&p).unwrap_or_else(|e| panic!("{t:?}: {e}"));
            let v = &loaded.volume;
            assert_eq!(v.dims(), UVec3::new(3, 2, 2));
            assert_eq!(
                v.spacing(),
                Vec3::new(0.5, 1.0, 2.5),
                "pixdim gives the spacing"
            );
            assert_eq!(v.data(), &expected(t, &vals), "{t:?} big={big}");
            assert_eq!(v.scalar_type(), t.volume_scalar());
            assert_eq!(loaded.meta.stored, t);
            assert_eq!(loaded.meta.big_endian, big);
            assert_eq!(loaded.meta.format, FileFormat::Nifti);
            assert_eq!(load_volume(&p).unwrap(), loaded.volume);
        }
    }
}

#[test]
fn nifti_gz_and_gzip_sniffing() {
    let dir = TempDir::new("nii-gz");
    for t in [StoredType::U8, StoredType::I16, StoredType::F32] {
        let vals = values(t);
        let file = Nifti::new(t).file(&encode(t, &vals, false));
        let gz = dir.write(&format!("{}.nii.gz", t.name()), &gzip(&file));
        let v = load_volume(&gz).unwrap();
        assert_eq!(v.data(), &expected(t, &vals));
        assert_eq!(v.spacing(), Vec3::new(0.5, 1.0, 2.5));
        // A gzip stream named .nii is still recognised by its magic bytes.
        let misnamed = dir.write(&format!("{}-gz.nii", t.name()), &gzip(&file));
        assert_eq!(load_volume(&misnamed).unwrap(), v);
    }
}

#[test]
fn nifti_larger_vox_offset_and_fewer_axes() {
    let dir = TempDir::new("nii-offset");
    let vals = values(StoredType::U8);
    let n = Nifti {
        vox_offset: 400.0,
        ..Nifti::new(StoredType::U8)
    };
    let p = dir.write("off.nii", &n.file(&encode(StoredType::U8, &vals, false)));
    assert_eq!(
        load_volume(&p).unwrap().data(),
        &expected(StoredType::U8, &vals)
    );
    // dim[0] = 2: a single slice; the third axis has one voxel and spacing 1.
    let n = Nifti {
        dim: [2, 4, 3, 9, 9, 9, 9, 9],
        ..Nifti::new(StoredType::U8)
    };
    let p = dir.write("2d.nii", &n.file(&[7u8; 12]));
    let v = load_volume(&p).unwrap();
    assert_eq!(v.dims(), UVec3::new(4, 3, 1));
    assert_eq!(v.spacing(), Vec3::new(0.5, 1.0, 1.0));
    // A 4-D file with one frame is a 3-D volume.
    let n = Nifti {
        dim: [4, 3, 2, 2, 1, 1, 1, 1],
        ..Nifti::new(StoredType::U8)
    };
    let p = dir.write("4d1.nii", &n.file(&[1u8; 12]));
    assert_eq!(load_volume(&p).unwrap().dims(), UVec3::new(3, 2, 2));
}

#[test]
fn nifti_orientation_and_scaling_in_meta() {
    let dir = TempDir::new("nii-orient");
    let data = [5u8; 12];
    // sform with a flipped x axis (LAS-like storage): spacing still from pixdim.
    let n = Nifti {
        sform: Some([
            [-0.5, 0.0, 0.0, 90.0],
            [0.0, 1.0, 0.0, -126.0],
            [0.0, 0.0, 2.5, -72.0],
        ]),
        scl: (2.0, -1024.0),
        ..Nifti::new(StoredType::U8)
    };
    let p = dir.write("sform.nii", &n.file(&data));
    let l = load_nifti(&p).unwrap();
    assert_eq!(l.volume.spacing(), Vec3::new(0.5, 1.0, 2.5));
    // The voxels are reordered to RAS+ (x reversed): the directions left are the identity and
    // the origin is the world position of the new voxel 0, the file's last along x.
    assert_eq!(
        l.meta.directions,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    );
    assert_eq!(l.meta.origin, [90.0 - 0.5 * 2.0, -126.0, -72.0]);
    assert_eq!(l.meta.flipped(), [false; 3]);
    let r = l.meta.reorientation.clone().unwrap();
    assert_eq!(r.file_code(), "LAS");
    assert_eq!(r.flipped, [true, false, false]);
    // scl_slope / scl_inter applied: f32 physical values 2 * 5 - 1024.
    assert_eq!((l.meta.scale_slope, l.meta.scale_inter), (2.0, -1024.0));
    assert!(l.meta.scale_applied);
    assert_eq!(l.volume.data(), &VoxelData::F32(vec![-1014.0; 12]));

    // qform: 180 degrees about z (b=c=0, d=1) with qfac -1 flips x, y and z.
    let mut pixdim = Nifti::new(StoredType::U8).pixdim;
    pixdim[0] = -1.0;
    let n = Nifti {
        qform: Some(([0.0, 0.0, 1.0], [1.0, 2.0, 3.0])),
        pixdim,
        ..Nifti::new(StoredType::U8)
    };
    let p = dir.write("qform.nii", &n.file(&data));
    let l = load_nifti(&p).unwrap();
    let r = l.meta.reorientation.clone().unwrap();
    assert_eq!(r.file_code(), "LPI");
    assert_eq!(r.flipped, [true; 3]);
    let d = l.meta.directions;
    let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(close(d[0], [1.0, 0.0, 0.0]), "{d:?}");
    assert!(close(d[1], [0.0, 1.0, 0.0]), "{d:?}");
    assert!(close(d[2], [0.0, 0.0, 1.0]), "{d:?}");
    assert!(
        close(l.meta.origin, [1.0 - 0.5 * 2.0, 2.0 - 1.0, 3.0 - 2.5]),
        "{:?}",
        l.meta.origin
    );
    assert_eq!(l.meta.flipped(), [false; 3]);
    assert_eq!(l.volume.spacing(), Vec3::new(0.5, 1.0, 2.5));
    // No transform at all: identity.
    let p = dir.write("none.nii", &Nifti::new(StoredType::U8).file(&data));
    let l = load_nifti(&p).unwrap();
    assert_eq!(l.meta.flipped(), [false; 3]);
    assert_eq!((l.meta.scale_slope, l.meta.scale_inter), (1.0, 0.0));
}

#[test]
fn i16_offset_and_window_mapping() {
    let dir = TempDir::new("i16-window");
    let vals = [-1000.0, 400.0, -32768.0, 32767.0];
    let n = Nifti {
        dim: [3, 4, 1, 1, 1, 1, 1, 1],
        ..Nifti::new(StoredType::I16)
    };
    let p = dir.write("ct.nii", &n.file(&encode(StoredType::I16, &vals, false)));
    let l = load_volume_with_meta(&p).unwrap();
    assert_eq!(
        l.volume.data(),
        &VoxelData::U16(vec![31768, 33168, 0, 65535])
    );
    // A window given in file units maps to exactly the normalised values the renderer sees.
    for (x, &s) in vals.iter().enumerate() {
        assert_eq!(l.meta.normalized(s), l.volume.value(x as u32, 0, 0));
    }
    assert_eq!(l.meta.stored.value_offset(), 32768);
}

#[test]
fn nifti_malformed_headers_name_the_field() {
    let dir = TempDir::new("nii-bad");
    let t = StoredType::U8;
    let data = encode(t, &values(t), false);
    let base = Nifti::new(t);
    let cases: Vec<(&str, Nifti, &str)> = vec![
        (
            "dim0",
            Nifti {
                dim: [0, 3, 2, 2, 1, 1, 1, 1],
                ..base.clone()
            },
            "dim[0]",
        ),
        (
            "dim0big",
            Nifti {
                dim: [8, 3, 2, 2, 1, 1, 1, 1],
                ..base.clone()
            },
            "dim[0]",
        ),
        (
            "dim2",
            Nifti {
                dim: [3, 3, 0, 2, 1, 1, 1, 1],
                ..base.clone()
            },
            "dim[2]",
        ),
        (
            "dim3neg",
            Nifti {
                dim: [3, 3, 2, -2, 1, 1, 1, 1],
                ..base.clone()
            },
            "dim[3]",
        ),
        (
            "dim4",
            Nifti {
                dim: [4, 3, 2, 2, 2, 1, 1, 1],
                ..base.clone()
            },
            "dim[4]",
        ),
        (
            "datatype",
            Nifti {
                datatype: 32,
                bitpix: 64,
                ..base.clone()
            },
            "datatype",
        ),
        (
            "bitpix",
            Nifti {
                bitpix: 16,
                ..base.clone()
            },
            "bitpix",
        ),
        (
            "pixdim",
            {
                let mut n = base.clone();
                n.pixdim[2] = 0.0;
                n
            },
            "pixdim[2]",
        ),
        (
            "pixdimnan",
            {
                let mut n = base.clone();
                n.pixdim[3] = f32::NAN;
                n
            },
            "pixdim[3]",
        ),
        (
            "voxoff",
            Nifti {
                vox_offset: 100.0,
                ..base.clone()
            },
            "vox_offset",
        ),
        (
            "voxfrac",
            Nifti {
                vox_offset: 352.5,
                ..base.clone()
            },
            "vox_offset",
        ),
        (
            "voxinf",
            Nifti {
                vox_offset: f32::INFINITY,
                ..base.clone()
            },
            "vox_offset",
        ),
        (
            "ni1",
            Nifti {
                magic: *b"ni1\0",
                ..base.clone()
            },
            "magic",
        ),
        (
            "magic",
            Nifti {
                magic: *b"abcd",
                ..base.clone()
            },
            "magic",
        ),
        (
            "sizeof",
            Nifti {
                sizeof_hdr: 100,
                ..base.clone()
            },
            "sizeof_hdr",
        ),
        (
            "nifti2",
            Nifti {
                sizeof_hdr: 540,
                ..base.clone()
            },
            // Read as NIfTI-2 now, whose magic ("n+2") this NIfTI-1 header lacks.
            "magic",
        ),
    ];
    for (tag, n, field) in cases {
        let p = dir.write(&format!("{tag}.nii"), &n.file(&data));
        let msg = expect_format(dims_of(load_nifti(&p)), &p, field);
        assert!(!msg.is_empty(), "{tag}");
        // The byte parser agrees with the loader.
        expect_format(parse_nifti_header(&p, &n.file(&data)), &p, field);
    }
    // Truncated header.
    let p = dir.write("short.nii", &base.header()[..100]);
    expect_format(dims_of(load_nifti(&p)), &p, "header");
}

#[test]
fn nifti_data_size_mismatches() {
    let dir = TempDir::new("nii-size");
    let t = StoredType::U16;
    let file = Nifti::new(t).file(&encode(t, &values(t), false));
    let short = dir.write("short.nii", &file[..file.len() - 1]);
    let msg = expect_format(dims_of(load_nifti(&short)), &short, "dim");
    assert!(msg.contains("too short"), "{msg}");
    let mut longer = file.clone();
    longer.push(0);
    let long = dir.write("long.nii", &longer);
    let msg = expect_format(dims_of(load_nifti(&long)), &long, "dim");
    assert!(msg.contains("too long"), "{msg}");
    // gzip: decoded stream too short / too long / cut off.
    let gz_short = dir.write("short.nii.gz", &gzip(&file[..file.len() - 2]));
    expect_format(dims_of(load_nifti(&gz_short)), &gz_short, "dim");
    let gz_long = dir.write("long.nii.gz", &gzip(&longer));
    expect_format(dims_of(load_nifti(&gz_long)), &gz_long, "dim");
    let full = gzip(&file);
    let cut = dir.write("cut.nii.gz", &full[..full.len() - 12]);
    expect_format(dims_of(load_nifti(&cut)), &cut, "dim");
    // Corrupt deflate data after an intact header (incompressible voxels, so the header is
    // encoded in the first few hundred bytes of the stream and the damage comes later).
    let mut noise = 12345u32;
    let voxels: Vec<u8> = (0..16 * 16 * 16)
        .map(|_| {
            noise = noise.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (noise >> 24) as u8
        })
        .collect();
    let n = Nifti {
        dim: [3, 16, 16, 16, 1, 1, 1, 1],
        ..Nifti::new(StoredType::U8)
    };
    let mut corrupt = gzip(&n.file(&voxels));
    let from = corrupt.len() * 2 / 3;
    corrupt[from..].iter_mut().for_each(|b| *b = 0xff);
    let bad = dir.write("corrupt.nii.gz", &corrupt);
    let ok = dir.write("intact.nii.gz", &gzip(&n.file(&voxels)));
    assert_eq!(load_volume(&ok).unwrap().data(), &VoxelData::U8(voxels));
    match load_nifti(&bad) {
        Err(VolumeError::Format { path, field, .. }) => {
            assert_eq!(path, bad);
            assert!(field == "encoding" || field == "dim", "{field}");
        }
        other => panic!("expected a Format error, got {other:?}"),
    }
}

#[test]
fn nifti_absurd_dims_refused_before_allocating() {
    let dir = TempDir::new("nii-absurd");
    // 32767^3 doubles = 281 TB: refused from the header alone, the file holds no data.
    let n = Nifti {
        dim: [3, 32767, 32767, 32767, 1, 1, 1, 1],
        ..Nifti::new(StoredType::F64)
    };
    let p = dir.write("absurd.nii", &n.file(&[]));
    let start = Instant::now();
    let msg = expect_format(dims_of(load_nifti(&p)), &p, "dim");
    assert!(msg.contains("GiB"), "{msg}");
    let gz = dir.write("absurd.nii.gz", &gzip(&n.file(&[])));
    expect_format(dims_of(load_nifti(&gz)), &gz, "dim");
    assert!(start.elapsed().as_secs() < 5);
}

#[test]
fn nifti_non_finite_floats_rejected() {
    let dir = TempDir::new("nii-nan");
    let mut vals = values(StoredType::F32);
    vals[5] = f64::NAN;
    let n = Nifti::new(StoredType::F32);
    let p = dir.write("nan.nii", &n.file(&encode(StoredType::F32, &vals, false)));
    assert!(matches!(
        load_volume(&p),
        Err(VolumeError::NonFinite { index: 5, .. })
    ));
    // f64 beyond the f32 range becomes infinite: rejected too.
    let mut vals = values(StoredType::F64);
    vals[0] = 1e300;
    let p = dir.write(
        "big.nii",
        &Nifti::new(StoredType::F64).file(&encode(StoredType::F64, &vals, false)),
    );
    assert!(matches!(
        load_volume(&p),
        Err(VolumeError::NonFinite { index: 0, .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// NRRD

fn nrrd_type(t: StoredType) -> &'static str {
    match t {
        StoredType::U8 => "uchar",
        StoredType::I8 => "signed char",
        StoredType::U16 => "unsigned short",
        StoredType::I16 => "short",
        StoredType::U32 => "uint",
        StoredType::I32 => "int32_t",
        StoredType::F32 => "float",
        StoredType::F64 => "double",
    }
}

fn nrrd_header(t: StoredType, encoding: &str, big: bool, extra: &str) -> String {
    format!(
        "NRRD0004\n# Complete NRRD file format specification at:\n\
         type: {}\ndimension: 3\nsizes: {} {} {}\nencoding: {encoding}\nendian: {}\n\
         kinds: domain domain domain\nmodality:=MR\n{extra}",
        nrrd_type(t),
        DIMS[0],
        DIMS[1],
        DIMS[2],
        if big { "big" } else { "little" },
    )
}

#[test]
fn nrrd_attached_raw_and_gzip_every_type() {
    let dir = TempDir::new("nrrd-types");
    for t in ALL_TYPES {
        for big in [false, true] {
            for encoding in ["raw", "gzip"] {
                let vals = values(t);
                let mut bytes =
                    nrrd_header(t, encoding, big, "spacings: 0.5 1 2.5\n\n").into_bytes();
                let data = encode(t, &vals, big);
                bytes.extend(if encoding == "gzip" {
                    gzip(&data)
                } else {
                    data
                });
                let p = dir.write(&format!("{}-{big}-{encoding}.nrrd", t.name()), &bytes);
                let l = load_volume_with_meta(&p).unwrap_or_else(|e| panic!("{t:?}: {e}"));
                assert_eq!(l.volume.dims(), UVec3::new(3, 2, 2));
                assert_eq!(
                    l.volume.data(),
                    &expected(t, &vals),
                    "{t:?} {big} {encoding}"
                );
                assert_eq!(l.volume.spacing(), Vec3::new(0.5, 1.0, 2.5));
                assert_eq!((l.meta.stored, l.meta.big_endian), (t, big));
                assert_eq!(l.meta.format, FileFormat::Nrrd);
            }
        }
    }
}

#[test]
fn nrrd_detached_headers() {
    let dir = TempDir::new("nrrd-detached");
    let t = StoredType::I16;
    let vals = values(t);
    let data = encode(t, &vals, true);
    dir.write("vol.raw", &data);
    dir.write("vol.raw.gz", &gzip(&data));
    let sub = dir.0.join("sub");
    std::fs::create_dir_all(&sub).unwrap();
    std::fs::write(sub.join("vol.raw"), &data).unwrap();
    for (name, encoding, file) in [
        ("a.nhdr", "raw", "vol.raw"),
        ("b.nhdr", "gzip", "vol.raw.gz"),
        ("c.nhdr", "raw", "sub/vol.raw"),
    ] {
        let h = nrrd_header(t, encoding, true, &format!("data file: {file}\n"));
        let p = dir.write(name, h.as_bytes());
        let v = load_volume(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(v.data(), &expected(t, &vals), "{name}");
    }
    // A .nrrd file may also point at detached data (NRRD0005 `datafile` spelling, CRLF lines).
    let h = nrrd_header(t, "raw", true, "datafile: vol.raw\n\n").replace('\n', "\r\n");
    let p = dir.write("d.nrrd", h.as_bytes());
    assert_eq!(load_volume(&p).unwrap().data(), &expected(t, &vals));
    // An absolute data file path.
    let abs = dir.0.join("vol.raw");
    let h = nrrd_header(t, "raw", true, &format!("data file: {}\n", abs.display()));
    let p = dir.write("e.nhdr", h.as_bytes());
    assert_eq!(load_volume(&p).unwrap().data(), &expected(t, &vals));
    // The data file is missing: an IO error naming it.
    let h = nrrd_header(t, "raw", true, "data file: nowhere.raw\n");
    let p = dir.write("f.nhdr", h.as_bytes());
    match load_volume(&p) {
        Err(VolumeError::Io { path, .. }) => assert!(path.ends_with("nowhere.raw")),
        other => panic!("expected Io, got {other:?}"),
    }
}

#[test]
fn nrrd_skips_and_space_directions() {
    let dir = TempDir::new("nrrd-skip");
    let t = StoredType::U8;
    let vals = values(t);
    let data = encode(t, &vals, false);
    // line skip 2, then byte skip 3, in the detached raw file.
    let mut raw = b"line one\nline two\nabc".to_vec();
    raw.extend_from_slice(&data);
    dir.write("skip.raw", &raw);
    let h = nrrd_header(
        t,
        "raw",
        false,
        "data file: skip.raw\nline skip: 2\nbyte skip: 3\n",
    );
    let p = dir.write("skip.nhdr", h.as_bytes());
    assert_eq!(load_volume(&p).unwrap().data(), &expected(t, &vals));
    // byte skip -1: the data is the end of the file.
    let h = nrrd_header(t, "raw", false, "data file: skip.raw\nbyte skip: -1\n");
    let p = dir.write("tail.nhdr", h.as_bytes());
    assert_eq!(load_volume(&p).unwrap().data(), &expected(t, &vals));
    // gzip: byte skip applies to the decoded stream.
    let mut padded = vec![9u8; 5];
    padded.extend_from_slice(&data);
    dir.write("skip.gz", &gzip(&padded));
    let h = nrrd_header(t, "gzip", false, "data file: skip.gz\nbyte skip: 5\n");
    let p = dir.write("gzskip.nhdr", h.as_bytes());
    assert_eq!(load_volume(&p).unwrap().data(), &expected(t, &vals));

    // space directions: spacing from their norms; a flipped y axis is reported, data kept.
    let extra =
        "space: left-posterior-superior\nspace directions: (0.5,0,0) (0,-1.5,0) (0, 0, 3)\n\
                 space origin: (10,20,30)\nspace units: \"mm\" \"mm\" \"mm\"\n\n";
    let mut bytes = nrrd_header(t, "raw", false, extra).into_bytes();
    bytes.extend_from_slice(&data);
    let p = dir.write("dirs.nrrd", &bytes);
    let l = load_nrrd(&p).unwrap();
    assert_eq!(l.volume.spacing(), Vec3::new(0.5, 1.5, 3.0));
    // The renderer sizes the volume box by dims * spacing: anisotropic voxels keep their aspect.
    assert_eq!(l.volume.physical_extent(), Vec3::new(1.5, 3.0, 6.0));
    let (lo, hi) = mixvol::scene::volume_box(l.volume.dims(), l.volume.spacing());
    assert_eq!(hi - lo, Vec3::new(0.25, 0.5, 1.0));
    assert_eq!(
        l.meta.directions,
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]
    );
    assert_eq!(l.meta.flipped(), [false, true, false]);
    assert_eq!(l.meta.origin, [10.0, 20.0, 30.0]);
    assert_eq!(l.volume.data(), &expected(t, &vals));
    // Single-byte types need no endian field; nan spacings mean 1.
    let mut bytes = b"NRRD0001\ntype: uint8\ndimension: 3\nsizes: 3 2 2\nencoding: raw\nspacings: nan 2 nan\n\n".to_vec();
    bytes.extend_from_slice(&data);
    let p = dir.write("noendian.nrrd", &bytes);
    assert_eq!(load_volume(&p).unwrap().spacing(), Vec3::new(1.0, 2.0, 1.0));
}

#[test]
fn nrrd_malformed_headers_name_the_field() {
    let dir = TempDir::new("nrrd-bad");
    let t = StoredType::U16;
    let data = encode(t, &values(t), false);
    let good = nrrd_header(t, "raw", false, "");
    let cases: Vec<(&str, String, &str)> = vec![
        ("magic", good.replace("NRRD0004", "NRRD0009"), "magic"),
        ("notnrrd", "P6\n3 2\n255\n".into(), "magic"),
        ("type", good.replace("unsigned short", "long long"), "type"),
        ("notype", good.replace("type: unsigned short\n", ""), "type"),
        (
            "dimension",
            good.replace("dimension: 3", "dimension: 4"),
            "dimension",
        ),
        (
            "nodimension",
            good.replace("dimension: 3\n", ""),
            "dimension",
        ),
        (
            "sizes2",
            good.replace("sizes: 3 2 2", "sizes: 3 2"),
            "sizes",
        ),
        (
            "sizesword",
            good.replace("sizes: 3 2 2", "sizes: 3 two 2"),
            "sizes",
        ),
        (
            "sizes0",
            good.replace("sizes: 3 2 2", "sizes: 3 0 2"),
            "sizes",
        ),
        (
            "sizesbig",
            good.replace("sizes: 3 2 2", "sizes: 5000000000 1 1"),
            "sizes",
        ),
        (
            "encoding",
            good.replace("encoding: raw", "encoding: bzip2"),
            "encoding",
        ),
        (
            "noencoding",
            good.replace("encoding: raw\n", ""),
            "encoding",
        ),
        (
            "endian",
            good.replace("endian: little", "endian: middle"),
            "endian",
        ),
        ("noendian", good.replace("endian: little\n", ""), "endian"),
        ("twice", format!("{good}type: float\n"), "type"),
        ("spacings", format!("{good}spacings: 1 0 1\n"), "spacings"),
        ("spacings2", format!("{good}spacings: 1 1\n"), "spacings"),
        (
            "dirnone",
            format!("{good}space directions: none (0,1,0) (0,0,1)\n"),
            "space directions",
        ),
        (
            "dirzero",
            format!("{good}space directions: (0,0,0) (0,1,0) (0,0,1)\n"),
            "space directions",
        ),
        (
            "dirsyntax",
            format!("{good}space directions: (1,0,0 (0,1,0) (0,0,1)\n"),
            "space directions",
        ),
        (
            "dirnan",
            format!("{good}space directions: (nan,0,0) (0,1,0) (0,0,1)\n"),
            "space directions",
        ),
        (
            "origin",
            format!("{good}space origin: 1 2 3\n"),
            "space origin",
        ),
        ("list", format!("{good}data file: LIST\n"), "data file"),
        (
            "series",
            format!("{good}data file: slice%03d.raw 1 10 1\n"),
            "data file",
        ),
        ("byteskip", format!("{good}byte skip: -2\n"), "byte skip"),
        ("lineskip", format!("{good}line skip: -1\n"), "line skip"),
        (
            "garbage",
            format!("{good}this line has no colon\n"),
            "header",
        ),
    ];
    for (tag, header, field) in cases {
        let mut bytes = format!("{header}\n").into_bytes();
        bytes.extend_from_slice(&data);
        let p = dir.write(&format!("{tag}.nrrd"), &bytes);
        expect_format(dims_of(load_nrrd(&p)), &p, field);
        expect_format(parse_nrrd_header(&p, &bytes), &p, field);
    }
    // gzip with byte skip -1.
    let h = nrrd_header(t, "gzip", false, "byte skip: -1\n\n");
    let p = dir.write("gzskip.nrrd", h.as_bytes());
    expect_format(dims_of(load_nrrd(&p)), &p, "byte skip");
    // A detached header (no blank line) without a data file.
    let p = dir.write("nodata.nhdr", good.as_bytes());
    expect_format(dims_of(load_nrrd(&p)), &p, "data file");
    // Line skip past the end of the data file.
    dir.write("two.raw", b"a\nb\n");
    let h = nrrd_header(t, "raw", false, "data file: two.raw\nline skip: 3\n");
    let p = dir.write("lines.nhdr", h.as_bytes());
    expect_format(dims_of(load_nrrd(&p)), &p, "line skip");
    // Non-UTF-8 header line.
    let mut bytes = b"NRRD0004\ntype: \xff\xfe\n\n".to_vec();
    bytes.extend_from_slice(&data);
    let p = dir.write("utf8.nrrd", &bytes);
    expect_format(dims_of(load_nrrd(&p)), &p, "header");
}

#[test]
fn nrrd_data_size_mismatches() {
    let dir = TempDir::new("nrrd-size");
    let t = StoredType::F32;
    let data = encode(t, &values(t), true);
    let header = nrrd_header(t, "raw", true, "\n");
    for (tag, cut, grow, what) in [("short", 1, 0, "too short"), ("long", 0, 3, "too long")] {
        let mut bytes = header.clone().into_bytes();
        bytes.extend_from_slice(&data[..data.len() - cut]);
        bytes.extend(std::iter::repeat_n(0u8, grow));
        let p = dir.write(&format!("{tag}.nrrd"), &bytes);
        let msg = expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
        assert!(msg.contains(what), "{msg}");
    }
    // gzip decoding to too little / too much.
    let gz = nrrd_header(t, "gzip", true, "\n");
    for (tag, payload) in [
        ("gzshort", gzip(&data[..data.len() - 4])),
        ("gzlong", gzip(&[&data[..], &[1, 2, 3, 4]].concat())),
    ] {
        let mut bytes = gz.clone().into_bytes();
        bytes.extend(payload);
        let p = dir.write(&format!("{tag}.nrrd"), &bytes);
        expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    }
    // Not gzip at all.
    let mut bytes = gz.into_bytes();
    bytes.extend_from_slice(&data);
    let p = dir.write("notgz.nrrd", &bytes);
    expect_format(dims_of(load_nrrd(&p)), &p, "encoding");
    // Detached data file too short.
    dir.write("short.raw", &data[..7]);
    let h = nrrd_header(t, "raw", true, "data file: short.raw\n");
    let p = dir.write("short.nhdr", h.as_bytes());
    let msg = expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    assert!(msg.contains("short.raw"), "{msg}");
    // byte skip -1 with too little data.
    let h = nrrd_header(t, "raw", true, "data file: short.raw\nbyte skip: -1\n");
    let p = dir.write("tail.nhdr", h.as_bytes());
    expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
}

#[test]
fn absurd_sizes_refused_before_allocating() {
    let dir = TempDir::new("absurd");
    let start = Instant::now();
    // 100000^3 voxels: refused from the header; the data file does not even exist.
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n\
             data file: missing.raw\n";
    let p = dir.write("absurd.nhdr", h.as_bytes());
    let msg = expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    assert!(msg.contains("GiB"), "{msg}");
    // Product overflowing u64.
    let h = h.replace("100000 100000 100000", "4294967295 4294967295 4294967295");
    let p = dir.write("overflow.nhdr", h.as_bytes());
    expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    let j = r#"{"dims": [100000, 100000, 100000], "type": "u16", "endianness": "little"}"#;
    let p = dir.write("absurd.json", j.as_bytes());
    expect_format(dims_of(load_sidecar(&p)), &p, "dims");

    // A lying header on a gzip stream: it claims the largest volume allowed (16 GiB) but the
    // stream holds 1 KiB. The buffer grows with the decoded data, so this fails at once with
    // the size error instead of allocating 16 GiB.
    let side = 2048u64; // 2048^3 * 2 bytes = 16 GiB
    assert_eq!(side * side * side * 2, MAX_VOLUME_BYTES);
    let mut bytes = format!(
        "NRRD0004\ntype: ushort\ndimension: 3\nsizes: {side} {side} {side}\nencoding: gzip\n\
         endian: little\n\n"
    )
    .into_bytes();
    bytes.extend(gzip(&[0u8; 1024]));
    let p = dir.write("liar.nrrd", &bytes);
    let msg = expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    assert!(msg.contains("1024"), "{msg}");

    // A gzip bomb (64 MiB of zeros in ~64 KiB) under a header describing 64 voxels: decoding
    // stops at the described size + 1 byte.
    let bomb = gzip(&vec![0u8; 64 << 20]);
    assert!(bomb.len() < 1 << 20);
    let mut bytes =
        b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: gzip\n\n".to_vec();
    bytes.extend(bomb);
    let p = dir.write("bomb.nrrd", &bytes);
    let msg = expect_format(dims_of(load_nrrd(&p)), &p, "sizes");
    assert!(msg.contains("more than"), "{msg}");
    assert!(start.elapsed().as_secs() < 10, "took {:?}", start.elapsed());
}

// ---------------------------------------------------------------------------------------------
// JSON sidecar + raw

fn sidecar_json(t: StoredType, big: bool, extra: &str) -> String {
    format!(
        r#"{{"dims": [3, 2, 2], "type": "{}", "endianness": "{}", "spacing": [1, 1, 3.5]{extra}}}"#,
        t.name(),
        if big { "big" } else { "little" }
    )
}

#[test]
fn sidecar_every_type_and_dispatch() {
    let dir = TempDir::new("sidecar");
    for t in ALL_TYPES {
        for big in [false, true] {
            let vals = values(t);
            let stem = format!("{}-{big}", t.name());
            dir.write(&format!("{stem}.raw"), &encode(t, &vals, big));
            let json = dir.write(&format!("{stem}.json"), sidecar_json(t, big, "").as_bytes());
            let l = load_volume_with_meta(&json).unwrap_or_else(|e| panic!("{t:?}: {e}"));
            assert_eq!(l.volume.data(), &expected(t, &vals));
            assert_eq!(l.volume.spacing(), Vec3::new(1.0, 1.0, 3.5));
            assert_eq!((l.meta.stored, l.meta.big_endian), (t, big));
            assert_eq!(l.meta.format, FileFormat::Sidecar);
            // Loading the .raw finds its sibling sidecar.
            let raw = dir.0.join(format!("{stem}.raw"));
            assert_eq!(load_volume(&raw).unwrap(), l.volume);
        }
    }
    // NAME.raw.json is found too, and its default data file is NAME.raw.
    let t = StoredType::U8;
    let vals = values(t);
    let raw = dir.write("other.raw", &encode(t, &vals, false));
    dir.write("other.raw.json", br#"{"dims": [3, 2, 2], "type": "uint8"}"#);
    let v = load_volume(&raw).unwrap();
    assert_eq!(v.data(), &expected(t, &vals));
    assert_eq!(v.spacing(), Vec3::ONE);
    // Explicit data file, header bytes and gzip encoding.
    let t = StoredType::I16;
    let vals = values(t);
    let mut with_header = vec![0xAB; 10];
    with_header.extend(encode(t, &vals, true));
    dir.write("payload.bin", &with_header);
    dir.write("payload.bin.gz", &gzip(&with_header));
    for (name, extra) in [
        (
            "explicit.json",
            r#", "data": "payload.bin", "header_bytes": 10"#,
        ),
        (
            "gz.json",
            r#", "data": "payload.bin.gz", "header_bytes": 10, "encoding": "gzip""#,
        ),
    ] {
        let json = dir.write(name, sidecar_json(t, true, extra).as_bytes());
        assert_eq!(
            load_volume(&json).unwrap().data(),
            &expected(t, &vals),
            "{name}"
        );
    }
}

#[test]
fn sidecar_errors_name_the_key() {
    let dir = TempDir::new("sidecar-bad");
    let t = StoredType::U16;
    dir.write("vol.raw", &encode(t, &values(t), false));
    // (tag, sidecar text, field, whether parsing alone already fails)
    let cases: Vec<(&str, String, &str, bool)> = vec![
        (
            "nodims",
            r#"{"type": "u16", "endianness": "little"}"#.into(),
            "dims",
            true,
        ),
        (
            "dims2",
            r#"{"dims": [3, 2], "type": "u16", "endianness": "little"}"#.into(),
            "dims",
            true,
        ),
        (
            "dimsneg",
            r#"{"dims": [3, -2, 2], "type": "u16", "endianness": "little"}"#.into(),
            "dims",
            true,
        ),
        (
            "dims0",
            r#"{"dims": [3, 0, 2], "type": "u16", "endianness": "little"}"#.into(),
            "dims",
            true,
        ),
        (
            "notype",
            r#"{"dims": [3, 2, 2], "endianness": "little"}"#.into(),
            "type",
            true,
        ),
        (
            "type",
            sidecar_json(t, false, "").replace("u16", "complex64"),
            "type",
            true,
        ),
        (
            "typenum",
            r#"{"dims": [3, 2, 2], "type": 16, "endianness": "little"}"#.into(),
            "type",
            true,
        ),
        (
            "noendian",
            r#"{"dims": [3, 2, 2], "type": "u16"}"#.into(),
            "endianness",
            true,
        ),
        (
            "endian",
            sidecar_json(t, false, "").replace("little", "pdp"),
            "endianness",
            true,
        ),
        (
            "spacing",
            sidecar_json(t, false, "").replace("3.5", "-1"),
            "spacing",
            true,
        ),
        (
            "spacing0",
            sidecar_json(t, false, "").replace("3.5", "0"),
            "spacing",
            true,
        ),
        (
            "unknown",
            sidecar_json(t, false, r#", "spacings": [1, 1, 1]"#),
            "spacings",
            true,
        ),
        (
            "encoding",
            sidecar_json(t, false, r#", "encoding": "zstd""#),
            "encoding",
            true,
        ),
        (
            "header",
            sidecar_json(t, false, r#", "header_bytes": -4"#),
            "header_bytes",
            true,
        ),
        (
            "data",
            sidecar_json(t, false, r#", "data": 7"#),
            "data",
            true,
        ),
        ("json", "{\"dims\": [3, 2, 2],".into(), "json", true),
        ("array", "[1, 2, 3]".into(), "json", true),
        // The data does not match: the sidecar says 3x2x3 but vol.raw holds 3x2x2.
        (
            "size",
            sidecar_json(t, false, "").replace("[3, 2, 2]", "[3, 2, 3]"),
            "dims",
            false,
        ),
    ];
    for (tag, text, field, parse_fails) in cases {
        // Point every object at vol.raw unless it names its own data.
        let text = if text.starts_with('{') && !text.contains("\"data\"") {
            text.replacen('{', r#"{"data": "vol.raw", "#, 1)
        } else {
            text
        };
        let json = dir.write(&format!("{tag}.json"), text.as_bytes());
        expect_format(dims_of(load_sidecar(&json)), &json, field);
        let parsed = parse_sidecar(&json, text.as_bytes());
        if parse_fails {
            expect_format(parsed, &json, field);
        } else {
            assert!(parsed.is_ok(), "{tag}");
        }
    }
    // A .raw without any sidecar, and a sidecar that describes another file.
    let lonely = dir.write("lonely.raw", &[0; 12]);
    expect_format(load_volume(&lonely), &lonely, "extension");
    let raw = dir.write("mine.raw", &[0; 12]);
    let json = dir.write(
        "mine.json",
        br#"{"dims": [3, 2, 2], "type": "u8", "data": "vol.raw"}"#,
    );
    expect_format(load_volume(&raw), &json, "data");
    // Missing data file: an IO error naming it.
    let json = dir.write("gone.json", br#"{"dims": [3, 2, 2], "type": "u8"}"#);
    match load_volume(&json) {
        Err(VolumeError::Io { path, .. }) => assert!(path.ends_with("gone.raw")),
        other => panic!("expected Io, got {other:?}"),
    }
    // Encoding enum round trip through the parser.
    let sc = parse_sidecar(
        Path::new("x.json"),
        br#"{"dims": [1, 1, 1], "type": "f64", "endianness": "big", "encoding": "gzip"}"#,
    )
    .unwrap();
    assert_eq!(
        (sc.encoding, sc.stored, sc.big_endian),
        (Encoding::Gzip, StoredType::F64, true)
    );
}

// ---------------------------------------------------------------------------------------------
// VolPack .den

fn den_file(dims: [i16; 3], map_length: i32, big: bool, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let short = |v: i16, out: &mut Vec<u8>| {
        out.extend_from_slice(&if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        })
    };
    short(1, &mut out);
    for _ in 0..3 {
        // orig, extr, map: min, max, len
        for v in [0, 0, 0] {
            short(v, &mut out);
        }
        for d in dims {
            short(d - 1, &mut out);
        }
        for d in dims {
            short(d, &mut out);
        }
    }
    short(0, &mut out); // map_warps
    out.extend_from_slice(&if big {
        map_length.to_be_bytes()
    } else {
        map_length.to_le_bytes()
    });
    assert_eq!(out.len(), 62);
    out.extend_from_slice(data);
    out
}

#[test]
fn den_both_byte_orders_and_errors() {
    let dir = TempDir::new("den");
    let data: Vec<u8> = (0..24).collect();
    for big in [false, true] {
        let p = dir.write(&format!("v{big}.den"), &den_file([4, 3, 2], 24, big, &data));
        let l = load_volume_with_meta(&p).unwrap();
        assert_eq!(l.volume.dims(), UVec3::new(4, 3, 2));
        assert_eq!(l.volume.spacing(), Vec3::ONE);
        assert_eq!(l.volume.data(), &VoxelData::U8(data.clone()));
        assert_eq!((l.meta.format, l.meta.big_endian), (FileFormat::Den, big));
        let h = parse_den_header(&p, &den_file([4, 3, 2], 24, big, &[])).unwrap();
        assert_eq!((h.dims, h.map_length), ([4, 3, 2], 24));
    }
    let mut bad_version = den_file([4, 3, 2], 24, false, &data);
    bad_version[0] = 2;
    let cases = [
        ("version", bad_version, "map_version"),
        (
            "length",
            den_file([4, 3, 2], 25, false, &data),
            "map_length",
        ),
        (
            "lenneg",
            den_file([4, 3, 2], -24, false, &data),
            "map_length",
        ),
        ("len0", den_file([4, 0, 2], 0, false, &data), "map_len[1]"),
        (
            "short",
            den_file([4, 3, 2], 24, false, &data[..23]),
            "map_length",
        ),
        (
            "long",
            den_file([4, 3, 2], 24, true, &[&data[..], &[0]].concat()),
            "map_length",
        ),
        (
            "header",
            den_file([4, 3, 2], 24, false, &[])[..40].to_vec(),
            "header",
        ),
    ];
    for (tag, bytes, field) in cases {
        let p = dir.write(&format!("{tag}.den"), &bytes);
        expect_format(dims_of(load_den(&p)), &p, field);
    }
}

#[test]
fn unknown_extension_and_missing_files() {
    let dir = TempDir::new("dispatch");
    let p = dir.write("volume.xyz", b"hello");
    expect_format(load_volume(&p), &p, "extension");
    let p = dir.0.join("absent.nii");
    assert!(matches!(load_volume(&p), Err(VolumeError::Io { .. })));
    assert!(matches!(
        load_volume(&dir.0.join("absent.nrrd")),
        Err(VolumeError::Io { .. })
    ));
    // A directory named like a volume.
    let d = dir.0.join("folder.nii");
    std::fs::create_dir_all(&d).unwrap();
    assert!(matches!(load_volume(&d), Err(VolumeError::Io { .. })));
    assert_eq!(
        FileFormat::from_path(Path::new("a/B.NII.GZ")),
        Some(FileFormat::Nifti)
    );
    assert_eq!(
        FileFormat::from_path(Path::new("x.nhdr")),
        Some(FileFormat::Nrrd)
    );
    assert_eq!(FileFormat::from_path(Path::new(".nii")), None);
}

/// A small deterministic fuzz pass over every header parser (the cargo-fuzz targets in `fuzz/`
/// do this at scale): mutated valid headers and random bytes must give `Ok` or a typed error,
/// never a panic.
#[test]
fn header_parsers_survive_mutated_input() {
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let nifti = Nifti {
        sform: Some([
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ]),
        qform: Some(([0.1, 0.2, 0.3], [0.0; 3])),
        ..Nifti::new(StoredType::I16)
    }
    .header();
    let nrrd = nrrd_header(
        StoredType::F32,
        "gzip",
        true,
        "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (1,2,3)\nbyte skip: 4\n\n",
    )
    .into_bytes();
    let json = sidecar_json(
        StoredType::I16,
        false,
        r#", "header_bytes": 3, "data": "a.raw""#,
    )
    .into_bytes();
    let den = den_file([4, 3, 2], 24, false, &[]);
    let path = Path::new("fuzz");
    for seed_bytes in [&nifti, &nrrd, &json, &den] {
        for round in 0..3000 {
            let mut b = seed_bytes.clone();
            let edits = 1 + next() % 8;
            for _ in 0..edits {
                let r = next();
                match r % 4 {
                    0 if !b.is_empty() => {
                        let i = (r >> 8) as usize % b.len();
                        b[i] = (r >> 32) as u8;
                    }
                    1 if !b.is_empty() => {
                        let i = (r >> 8) as usize % b.len();
                        b.truncate(i);
                    }
                    2 => {
                        let i = (r >> 8) as usize % (b.len() + 1);
                        b.insert(i, b"\n:( ),-1 9e999"[(r >> 40) as usize % 13]);
                    }
                    _ => {
                        if round % 50 == 0 {
                            b = (0..(r % 400)).map(|_| next() as u8).collect();
                        }
                    }
                }
            }
            let _ = parse_nifti_header(path, &b);
            let _ = parse_nrrd_header(path, &b);
            let _ = parse_sidecar(path, &b);
            let _ = parse_den_header(path, &b);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Real datasets (fetched by scripts/fetch-datasets.sh; never skipped)

fn dataset(name: &str) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::var_os("MIXVOL_DATA_DIR")
        .map(|d| root.join(d))
        .unwrap_or_else(|| root.join("target/datasets"));
    let p = dir.join(name);
    assert!(
        p.is_file(),
        "dataset {} is missing: run scripts/fetch-datasets.sh first (scripts/test.sh does); \
         set MIXVOL_DATA_DIR if the datasets live elsewhere",
        p.display()
    );
    p
}

fn byte_sum(v: &VoxelData) -> u64 {
    match v {
        VoxelData::U8(b) => b.iter().map(|&x| u64::from(x)).sum(),
        other => panic!("expected u8 data, got {:?}", other.scalar_type()),
    }
}

#[test]
fn real_mni152_2009_t1_template() {
    let gz = dataset("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz");
    let l = load_volume_with_meta(&gz).unwrap();
    let v = &l.volume;
    assert_eq!(v.dims(), UVec3::new(197, 233, 189));
    assert_eq!(v.spacing(), Vec3::ONE, "1 mm isotropic");
    assert_eq!(l.meta.stored, StoredType::U8);
    assert_eq!(l.meta.format, FileFormat::Nifti);
    assert_eq!(l.meta.flipped(), [false; 3], "stored RAS");
    assert_eq!(l.meta.origin, [-98.0, -134.0, -72.0]);
    assert_eq!(byte_sum(v.data()), 333_468_829);
    assert_eq!(v.value(0, 0, 0), 0.0, "background outside the head");
    assert_eq!(
        v.value(98, 116, 94),
        198.0 / 255.0,
        "white matter near the centre"
    );
    // The uncompressed copy the fetch script writes loads identically.
    let nii = dataset("mni_icbm152_t1_tal_nlin_sym_09a_converted.nii");
    assert_eq!(&load_volume(&nii).unwrap(), v);
}

#[test]
fn real_volpack_brainsmall() {
    let den = dataset("brainsmall.den");
    let l = load_volume_with_meta(&den).unwrap();
    let v = &l.volume;
    assert_eq!(v.dims(), UVec3::new(128, 128, 84));
    assert_eq!(v.scalar_type(), mixvol::volume::ScalarType::U8);
    assert!(!l.meta.big_endian);
    assert_eq!(byte_sum(v.data()), 19_284_185);
    assert_eq!(v.value(64, 64, 42), 65.0 / 255.0);
    let h = parse_den_header(&den, &std::fs::read(&den).unwrap()[..62]).unwrap();
    assert_eq!(h.map_warps, 3);
    // The detached NRRD header the fetch script writes reads the same bytes (byte skip 62).
    let nhdr = dataset("brainsmall.nhdr");
    assert_eq!(&load_volume(&nhdr).unwrap(), v);
}
