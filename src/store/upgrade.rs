//! Reading a two-level brick store (`.mvbs`, written by `mixvol convert` before level stores
//! became the one format) back as a volume, slab by slab, so that `mixvol convert OLD NEW`
//! upgrades it to a level store without the original file.
//!
//! The store's level-0 ("hi") bricks hold every voxel of the volume exactly (the storage type's
//! values, a one-voxel border around each): [`BrickStoreSlabs`] cuts z planes out of them.
//! Its low-res bricks are not read; the level store builds its own coarser levels.

use super::BrickStore;
use crate::bricks::Level;
use crate::volume::formats::VolumeMeta;
use crate::volume::{ScalarType, SlabMut, SlabReader, VolumeError};
use glam::{UVec3, Vec3};
use std::ops::Range;
use std::path::Path;

/// A two-level brick store read as a volume in slabs of whole z planes ([module docs](self)).
///
/// Each slab reads, with one positioned read and its CRC-32 check, every hi-res brick it
/// crosses: a brick of edge `n` is read `ceil(n / planes)` times when slabs are `planes`
/// planes thick (4 times for bricks of 32 and the level writer's slabs of 8).
#[derive(Debug)]
pub struct BrickStoreSlabs {
    store: BrickStore,
    brick: Vec<u8>,
}

impl BrickStoreSlabs {
    /// Reads the voxels of `store`.
    pub fn new(store: BrickStore) -> Self {
        let bytes = store.level_bytes(Level::Hi);
        Self {
            store,
            brick: vec![0; bytes],
        }
    }

    /// The store read.
    pub fn store(&self) -> &BrickStore {
        &self.store
    }
}

/// Copies the voxels `[x0, x0 + width)` of row `(y, z)` of a stored hi-res brick (edge
/// `stored`, texels of `size` bytes, native-endian) into `out` at voxel `at`.
fn copy_row(
    brick: &[u8],
    stored: usize,
    size: usize,
    (y, z): (usize, usize),
    width: usize,
    out: &mut SlabMut<'_>,
    at: usize,
) {
    // Texel (x + 1, y + 1, z + 1) holds voxel (x, y, z) of the brick: one border texel a side.
    let first = ((z + 1) * stored + y + 1) * stored + 1;
    let bytes = &brick[first * size..(first + width) * size];
    match out {
        SlabMut::U8(v) => v[at..at + width].copy_from_slice(bytes),
        SlabMut::U16(v) => {
            for (o, b) in v[at..at + width].iter_mut().zip(bytes.chunks_exact(2)) {
                *o = u16::from_ne_bytes([b[0], b[1]]);
            }
        }
        SlabMut::F32(v) => {
            for (o, b) in v[at..at + width].iter_mut().zip(bytes.chunks_exact(4)) {
                *o = f32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
    }
}

impl SlabReader for BrickStoreSlabs {
    fn path(&self) -> &Path {
        self.store.path()
    }

    fn dims(&self) -> UVec3 {
        self.store.grid().dims()
    }

    fn scalar(&self) -> ScalarType {
        self.store.scalar()
    }

    fn spacing(&self) -> Vec3 {
        self.store.spacing()
    }

    fn meta(&self) -> Option<&VolumeMeta> {
        None
    }

    fn forward_only(&self) -> bool {
        false
    }

    fn scratch_bytes(&self) -> u64 {
        self.brick.len() as u64
    }

    fn read_slab(&mut self, z: Range<u32>, mut out: SlabMut<'_>) -> Result<(), VolumeError> {
        let grid = self.store.grid();
        let dims = grid.dims();
        let plane =
            crate::volume::slabs::check_request(self.path(), dims, self.scalar(), &z, &out)?;
        let n = grid.brick_size();
        let stored = n as usize + 2;
        let size = self.scalar().size_bytes();
        let bricks = grid.bricks_per_axis();
        if z.is_empty() {
            return Ok(());
        }
        for bz in z.start / n..=(z.end - 1) / n {
            let zs = (z.start.max(bz * n), z.end.min((bz + 1) * n));
            for by in 0..bricks.y {
                let rows = n.min(dims.y - by * n);
                for bx in 0..bricks.x {
                    let width = n.min(dims.x - bx * n) as usize;
                    let index = grid.linear_index(UVec3::new(bx, by, bz)) as u32;
                    self.store
                        .read_brick_into(index, Level::Hi, &mut self.brick)
                        .map_err(|e| VolumeError::Io {
                            path: self.store.path().to_path_buf(),
                            source: std::io::Error::other(e),
                        })?;
                    for vz in zs.0..zs.1 {
                        for row in 0..rows {
                            let vy = by * n + row;
                            let at = (vz - z.start) as usize * plane
                                + vy as usize * dims.x as usize
                                + (bx * n) as usize;
                            let local = (row as usize, (vz - bz * n) as usize);
                            copy_row(&self.brick, stored, size, local, width, &mut out, at);
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), VolumeError> {
        Ok(())
    }
}
