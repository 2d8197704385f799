//! A level's samples on disk, plane by plane: what lets [`super::write_level_store_from_slabs`]
//! build every level above 0 without holding one in RAM. Each level is written once, z plane
//! after z plane (f32, little-endian, x fastest), into a temporary file next to the store, and
//! read back in order through a sliding window of planes; the file is removed when its
//! [`PlaneFile`] is dropped.

use crate::pyramid::{downsample_sum, downsample_taps, LevelGrid, SamplePlacement};
use crate::store::StoreError;
use crate::store::LEVEL_STORE;
use glam::{IVec3, UVec3};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// One level's samples in a temporary file (removed on drop).
pub(super) struct PlaneFile {
    path: PathBuf,
    /// The level.
    pub(super) level: u32,
    /// Samples per axis.
    pub(super) dims: UVec3,
}

impl Drop for PlaneFile {
    fn drop(&mut self) {
        // A temporary file: nothing to do if it is already gone.
        let _ = std::fs::remove_file(&self.path);
    }
}

fn io(path: &Path, action: &'static str) -> impl FnOnce(std::io::Error) -> StoreError {
    let path = path.to_path_buf();
    move |source| StoreError::Io {
        kind: LEVEL_STORE,
        path,
        action,
        source,
    }
}

/// Writes a level's planes in order.
pub(super) struct PlaneFileWriter {
    file: PlaneFile,
    out: BufWriter<File>,
    planes: u32,
}

impl PlaneFileWriter {
    /// Creates the temporary file of `level` (samples `dims`) at `path`.
    pub(super) fn create(path: PathBuf, level: u32, dims: UVec3) -> Result<Self, StoreError> {
        // Exclusively: never a file or a link that was there.
        let out = File::create_new(&path).map_err(io(&path, "create a temporary level file"))?;
        Ok(Self {
            file: PlaneFile { path, level, dims },
            out: BufWriter::with_capacity(1 << 20, out),
            planes: 0,
        })
    }

    /// Appends the next z plane (`dims.x * dims.y` samples).
    pub(super) fn push(&mut self, plane: &[f32]) -> Result<(), StoreError> {
        let mut bytes = Vec::with_capacity(plane.len() * 4);
        for v in plane {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        self.out
            .write_all(&bytes)
            .map_err(io(&self.file.path, "write a temporary level file"))?;
        self.planes += 1;
        Ok(())
    }

    /// Flushes the file once every plane is in.
    pub(super) fn finish(mut self) -> Result<PlaneFile, StoreError> {
        if self.planes != self.file.dims.z {
            return Err(StoreError::InvalidDesc {
                field: "dims",
                message: format!(
                    "level {} got {} planes of {}",
                    self.file.level, self.planes, self.file.dims.z
                ),
            });
        }
        self.out
            .flush()
            .map_err(io(&self.file.path, "write a temporary level file"))?;
        Ok(self.file)
    }
}

/// A sliding window over a [`PlaneFile`]'s planes, read in order.
pub(super) struct PlaneWindow<'a> {
    file: &'a PlaneFile,
    input: BufReader<File>,
    /// Planes `first..first + window.len()`.
    window: VecDeque<Vec<f32>>,
    first: u32,
    read: u32,
}

impl<'a> PlaneWindow<'a> {
    /// Opens `file` for reading from its first plane.
    pub(super) fn open(file: &'a PlaneFile) -> Result<Self, StoreError> {
        let input =
            File::open(&file.path).map_err(io(&file.path, "open a temporary level file"))?;
        Ok(Self {
            file,
            input: BufReader::with_capacity(1 << 20, input),
            window: VecDeque::new(),
            first: 0,
            read: 0,
        })
    }

    /// Holds planes `from..=to` (clamped to the level), reading forward and dropping the
    /// planes before `from`. Calls must not move backwards.
    pub(super) fn hold(&mut self, from: i32, to: i32) -> Result<(), StoreError> {
        let last = self.file.dims.z as i32 - 1;
        let (from, to) = (from.clamp(0, last) as u32, to.clamp(0, last) as u32);
        let plane = self.file.dims.x as usize * self.file.dims.y as usize;
        let mut bytes = vec![0u8; plane * 4];
        while self.read <= to {
            self.input
                .read_exact(&mut bytes)
                .map_err(io(&self.file.path, "read a temporary level file"))?;
            let values = bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            self.window.push_back(values);
            self.read += 1;
        }
        while self.first < from && self.window.len() > 1 {
            self.window.pop_front();
            self.first += 1;
        }
        Ok(())
    }

    /// Sample `k`, clamped to the level (its plane must be held): [`LevelGrid::value`].
    pub(super) fn value(&self, k: IVec3) -> f32 {
        let dims = self.file.dims;
        let c = k
            .clamp(IVec3::ZERO, dims.as_ivec3() - IVec3::ONE)
            .as_uvec3();
        self.window[(c.z - self.first) as usize][(c.x + dims.x * c.y) as usize]
    }
}

/// The next coarser vertex level of `file`'s (a vertex level covering a volume of `volume`
/// voxels) into a new temporary file at `path`, plane by plane: each sample through
/// `downsample_sum`, as [`LevelGrid::downsampled`] forms it, so the samples are bit for bit
/// its own.
pub(super) fn downsample_file(
    file: &PlaneFile,
    volume: UVec3,
    path: PathBuf,
) -> Result<PlaneFile, StoreError> {
    let level = file.level + 1;
    let dims = LevelGrid::covering_dims(level, SamplePlacement::Vertex, volume);
    let spacing = (1u32 << file.level.min(30)) as f32;
    let taps =
        |j: i32| downsample_taps(spacing, SamplePlacement::Vertex, SamplePlacement::Vertex, j);
    let taps_x: Vec<Vec<(i32, f32)>> = (0..dims.x as i32).map(taps).collect();
    let mut window = PlaneWindow::open(file)?;
    let mut out = PlaneFileWriter::create(path, level, dims)?;
    let mut plane = Vec::with_capacity(dims.x as usize * dims.y as usize);
    for z in 0..dims.z as i32 {
        let tz = taps(z);
        let (lo, hi) = tz
            .iter()
            .fold((i32::MAX, i32::MIN), |(a, b), &(k, _)| (a.min(k), b.max(k)));
        window.hold(lo, hi)?;
        plane.clear();
        for y in 0..dims.y as i32 {
            let ty = taps(y);
            for tx in &taps_x {
                plane.push(downsample_sum(&tz, &ty, tx, |k| window.value(k)));
            }
        }
        out.push(&plane)?;
    }
    out.finish()
}
