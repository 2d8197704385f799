//! Headerless raw volume files: loading (any endianness, optional header to skip) and saving
//! (little-endian, no header).
use super::{checked_voxel_count, ScalarType, Volume, VolumeError, VoxelData};
use glam::{UVec3, Vec3};
use std::io::{self, ErrorKind, Read, Seek, SeekFrom};
use std::path::Path;

/// Describes a headerless raw file.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct RawDescriptor {
    /// Voxel counts.
    pub dims: UVec3,
    /// Scalar type of the voxels.
    pub scalar: ScalarType,
    /// Voxel spacing.
    pub spacing: Vec3,
    /// Bytes to skip at the start of the file.
    pub header_bytes: u64,
    /// True when multi-byte values are big-endian.
    pub big_endian: bool,
}

/// Loads a raw volume file: `header_bytes` skipped, then `dims` voxels of `scalar` in storage
/// order (x fastest), little-endian unless `big_endian`.
///
/// Dimensions and sizes are checked before anything is allocated or read: zero axes give
/// [`VolumeError::ZeroDimension`], sizes that overflow give [`VolumeError::SizeOverflow`], and a
/// file whose length is not exactly `header_bytes + voxels * size` (shorter or longer) gives
/// [`VolumeError::FileSizeMismatch`]. IO failures, including a missing path or a directory, give
/// [`VolumeError::Io`]; non-finite f32 voxels give [`VolumeError::NonFinite`].
pub fn load_raw(path: &Path, desc: &RawDescriptor) -> Result<Volume, VolumeError> {
    let (count, data_bytes, expected) = raw_sizes(path, desc)?;
    let io_err = |source: io::Error| VolumeError::Io {
        path: path.to_path_buf(),
        source,
    };
    let (mut file, len) = super::open_regular_file(path)?;
    if len != expected {
        return Err(VolumeError::FileSizeMismatch {
            path: path.to_path_buf(),
            dims: desc.dims.to_array(),
            scalar: desc.scalar,
            header: desc.header_bytes,
            expected,
            actual: len,
        });
    }
    super::memory::check_host_bytes(
        &format!(
            "{} ({}x{}x{} {:?})",
            path.display(),
            desc.dims.x,
            desc.dims.y,
            desc.dims.z,
            desc.scalar
        ),
        data_bytes,
    )?;
    file.seek(SeekFrom::Start(desc.header_bytes))
        .map_err(io_err)?;

    let data = match desc.scalar {
        ScalarType::U8 => VoxelData::U8(read_values(&mut file, count).map_err(io_err)?),
        ScalarType::U16 => {
            let mut v: Vec<u16> = read_values(&mut file, count).map_err(io_err)?;
            let convert = if desc.big_endian {
                u16::from_be
            } else {
                u16::from_le
            };
            v.iter_mut().for_each(|x| *x = convert(*x));
            VoxelData::U16(v)
        }
        ScalarType::F32 => {
            let v: Vec<u32> = read_values(&mut file, count).map_err(io_err)?;
            let convert = if desc.big_endian {
                u32::from_be
            } else {
                u32::from_le
            };
            VoxelData::F32(v.into_iter().map(|x| f32::from_bits(convert(x))).collect())
        }
    };
    Volume::new(desc.dims, desc.spacing, data).map_err(|e| e.in_file(path))
}

/// Reads exactly `count` values of `T` in native byte order. The buffer is reserved fallibly, so
/// a size the allocator refuses is an `OutOfMemory` error rather than an abort.
fn read_values<T: bytemuck::Pod>(reader: &mut impl Read, count: usize) -> io::Result<Vec<T>> {
    let mut values = Vec::new();
    values
        .try_reserve_exact(count)
        .map_err(|_| io::Error::from(ErrorKind::OutOfMemory))?;
    values.resize(count, T::zeroed());
    reader.read_exact(bytemuck::cast_slice_mut(&mut values))?;
    Ok(values)
}

/// `(voxels, data bytes, expected file length)` of headerless raw data described by `desc`: a
/// zero axis, an overflowing size ([`VolumeError::SizeOverflow`]) or a header that overflows
/// the length ([`VolumeError::HeaderTooLarge`]) are errors. Shared by [`load_raw`] and the raw
/// slab reader, so both refuse the same inputs with the same words.
pub(crate) fn raw_sizes(
    path: &Path,
    desc: &RawDescriptor,
) -> Result<(usize, u64, u64), VolumeError> {
    let count = checked_voxel_count(desc.dims)?;
    let overflow = || VolumeError::SizeOverflow {
        dims: desc.dims.to_array(),
    };
    let data_bytes = u64::try_from(count)
        .ok()
        .and_then(|n| n.checked_mul(desc.scalar.size_bytes() as u64))
        .ok_or_else(overflow)?;
    let expected =
        data_bytes
            .checked_add(desc.header_bytes)
            .ok_or_else(|| VolumeError::HeaderTooLarge {
                path: path.to_path_buf(),
                header: desc.header_bytes,
                data: data_bytes,
            })?;

    Ok((count, data_bytes, expected))
}

/// Writes `volume`'s voxels as a headerless little-endian raw file (storage order, x fastest)
/// at `path`, atomically ([`crate::output`]: a failed write leaves any previous file intact).
/// Dims, type and spacing are not stored; describe them with a [`RawDescriptor`] to load the
/// file back. Failures give [`VolumeError::Write`].
pub fn save_raw(volume: &Volume, path: &Path) -> Result<(), VolumeError> {
    let write = || -> io::Result<()> {
        crate::output::write_atomically_with(path, |w| match volume.data() {
            VoxelData::U8(v) => w.write_all(v),
            VoxelData::U16(v) => v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes())),
            VoxelData::F32(v) => v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes())),
        })
    };
    write().map_err(|source| VolumeError::Write {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::marschner_lobb;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A unique temporary file path, removed on drop.
    struct TempFile(PathBuf);

    impl TempFile {
        fn new(tag: &str) -> Self {
            static NEXT: AtomicUsize = AtomicUsize::new(0);
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let name = format!("mixvol-loader-{}-{n}-{tag}.raw", std::process::id());
            Self(std::env::temp_dir().join(name))
        }

        fn with_bytes(tag: &str, bytes: &[u8]) -> Self {
            let f = Self::new(tag);
            std::fs::write(&f.0, bytes).unwrap();
            f
        }
    }

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn desc(dims: [u32; 3], scalar: ScalarType) -> RawDescriptor {
        RawDescriptor {
            dims: UVec3::from_array(dims),
            scalar,
            spacing: Vec3::ONE,
            header_bytes: 0,
            big_endian: false,
        }
    }

    #[test]
    fn round_trip_all_types() {
        let dims = UVec3::new(7, 5, 3);
        for scalar in [ScalarType::U8, ScalarType::U16, ScalarType::F32] {
            let original = marschner_lobb(dims, scalar).unwrap();
            let f = TempFile::new("roundtrip");
            save_raw(&original, &f.0).unwrap();
            let len = std::fs::metadata(&f.0).unwrap().len();
            assert_eq!(len, (7 * 5 * 3 * scalar.size_bytes()) as u64);
            let d = RawDescriptor {
                spacing: Vec3::new(2.0, 1.0, 0.5),
                ..desc(dims.to_array(), scalar)
            };
            let loaded = load_raw(&f.0, &d).unwrap();
            assert_eq!(loaded.dims(), dims);
            assert_eq!(loaded.spacing(), Vec3::new(2.0, 1.0, 0.5));
            assert_eq!(loaded.data(), original.data());
        }
    }

    #[test]
    fn save_is_little_endian() {
        let v = Volume::new(
            UVec3::new(2, 1, 1),
            Vec3::ONE,
            VoxelData::U16(vec![0x0102, 7]),
        );
        let f = TempFile::new("le");
        save_raw(&v.unwrap(), &f.0).unwrap();
        assert_eq!(std::fs::read(&f.0).unwrap(), [0x02, 0x01, 7, 0]);
    }

    #[test]
    fn big_endian_u16_and_f32() {
        let f = TempFile::with_bytes("be16", &[0x01, 0x02, 0xff, 0x00, 0x00, 0x03]);
        let d = RawDescriptor {
            big_endian: true,
            ..desc([3, 1, 1], ScalarType::U16)
        };
        let v = load_raw(&f.0, &d).unwrap();
        assert_eq!(v.data(), &VoxelData::U16(vec![0x0102, 0xff00, 0x0003]));
        // The same bytes read little-endian differ.
        let v = load_raw(&f.0, &desc([3, 1, 1], ScalarType::U16)).unwrap();
        assert_eq!(v.data(), &VoxelData::U16(vec![0x0201, 0x00ff, 0x0300]));

        let mut bytes = 1.5f32.to_be_bytes().to_vec();
        bytes.extend_from_slice(&(-0.25f32).to_be_bytes());
        let f = TempFile::with_bytes("be32", &bytes);
        let d = RawDescriptor {
            big_endian: true,
            ..desc([1, 2, 1], ScalarType::F32)
        };
        let v = load_raw(&f.0, &d).unwrap();
        assert_eq!(v.data(), &VoxelData::F32(vec![1.5, -0.25]));
    }

    #[test]
    fn header_bytes_are_skipped() {
        let mut bytes = vec![0xAA; 7];
        bytes.extend_from_slice(&[1, 2, 3, 4, 5, 6]);
        let f = TempFile::with_bytes("header", &bytes);
        let d = RawDescriptor {
            header_bytes: 7,
            ..desc([3, 2, 1], ScalarType::U8)
        };
        let v = load_raw(&f.0, &d).unwrap();
        assert_eq!(v.data(), &VoxelData::U8(vec![1, 2, 3, 4, 5, 6]));
        assert_eq!(v.value(2, 1, 0), 6.0 / 255.0);
        // Without the header setting, the file is 7 bytes too long.
        let err = load_raw(&f.0, &desc([3, 2, 1], ScalarType::U8)).unwrap_err();
        assert!(matches!(
            err,
            VolumeError::FileSizeMismatch {
                expected: 6,
                actual: 13,
                ..
            }
        ));
    }

    #[test]
    fn wrong_file_size_rejected() {
        let d = desc([2, 2, 2], ScalarType::U16);
        for (tag, len) in [("short", 15), ("long", 17), ("empty", 0)] {
            let f = TempFile::with_bytes(tag, &vec![0; len]);
            match load_raw(&f.0, &d) {
                Err(VolumeError::FileSizeMismatch {
                    path,
                    expected,
                    actual,
                    header,
                    scalar,
                    dims,
                }) => {
                    assert_eq!(path, f.0);
                    assert_eq!((expected, actual), (16, len as u64));
                    assert_eq!((header, scalar, dims), (0, ScalarType::U16, [2, 2, 2]));
                }
                other => panic!("{tag}: expected FileSizeMismatch, got {other:?}"),
            }
        }
        // The header counts towards the expected size.
        let f = TempFile::with_bytes("hdr-short", &[0; 16]);
        let d = RawDescriptor {
            header_bytes: 4,
            ..d
        };
        assert!(matches!(
            load_raw(&f.0, &d),
            Err(VolumeError::FileSizeMismatch {
                expected: 20,
                actual: 16,
                header: 4,
                ..
            })
        ));
    }

    #[test]
    fn missing_file_and_directory_are_io_errors() {
        let missing = TempFile::new("missing");
        match load_raw(&missing.0, &desc([1, 1, 1], ScalarType::U8)) {
            Err(VolumeError::Io { path, source }) => {
                assert_eq!(path, missing.0);
                assert_eq!(source.kind(), ErrorKind::NotFound);
            }
            other => panic!("expected Io, got {other:?}"),
        }
        let dir = std::env::temp_dir();
        match load_raw(&dir, &desc([1, 1, 1], ScalarType::U8)) {
            Err(VolumeError::Io { path, .. }) => assert_eq!(path, dir),
            other => panic!("expected Io, got {other:?}"),
        }
    }

    #[test]
    fn save_to_directory_is_write_error() {
        let v = marschner_lobb(UVec3::splat(2), ScalarType::U8).unwrap();
        let dir = std::env::temp_dir();
        assert!(matches!(
            save_raw(&v, &dir),
            Err(VolumeError::Write { path, .. }) if path == dir
        ));
    }

    #[test]
    fn bad_dims_rejected_before_reading() {
        // The file does not exist: dims are checked before the path is touched.
        let missing = TempFile::new("never-read");
        assert!(matches!(
            load_raw(&missing.0, &desc([4, 4, 0], ScalarType::U8)),
            Err(VolumeError::ZeroDimension { axis: 'z', .. })
        ));
        assert!(matches!(
            load_raw(&missing.0, &desc([0, 4, 4], ScalarType::F32)),
            Err(VolumeError::ZeroDimension { axis: 'x', .. })
        ));
        let huge = [4_000_000_000; 3];
        assert!(matches!(
            load_raw(&missing.0, &desc(huge, ScalarType::U16)),
            Err(VolumeError::SizeOverflow { dims }) if dims == huge
        ));
        // Voxel bytes fit, but adding the header overflows u64: the header size is blamed, not
        // the dims (issue 16 item 9).
        let d = RawDescriptor {
            header_bytes: u64::MAX,
            ..desc([16, 16, 16], ScalarType::F32)
        };
        assert!(matches!(
            load_raw(&missing.0, &d),
            Err(VolumeError::HeaderTooLarge {
                header: u64::MAX,
                data: 16384,
                ..
            })
        ));
    }

    #[test]
    fn non_finite_f32_rejected_with_voxel() {
        // dims 3 x 4 x 2; NaN at (1, 2, 1) = index 1 + 3 * (2 + 4 * 1) = 19.
        let mut values = [0.5f32; 24];
        values[19] = f32::NAN;
        values[23] = f32::INFINITY;
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let f = TempFile::with_bytes("nan", &bytes);
        match load_raw(&f.0, &desc([3, 4, 2], ScalarType::F32)) {
            Err(VolumeError::NonFinite {
                file,
                index,
                x,
                y,
                z,
                value,
            }) => {
                assert_eq!(file.as_deref(), Some(f.0.as_path()));
                assert_eq!((index, x, y, z), (19, 1, 2, 1));
                assert!(value.is_nan());
            }
            other => panic!("expected NonFinite, got {other:?}"),
        }
        let bytes: Vec<u8> = [0.0f32, f32::NEG_INFINITY]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = TempFile::with_bytes("inf", &bytes);
        assert!(matches!(
            load_raw(&f.0, &desc([2, 1, 1], ScalarType::F32)),
            Err(VolumeError::NonFinite { index: 1, x: 1, y: 0, z: 0, value, .. })
                if value == f32::NEG_INFINITY
        ));
    }
}
