//! The kernel against the reference functions, bit for bit, on boxes of every shape, from windows
//! cut out of the volume and from the whole volume.

use super::*;
use crate::bricks::tests::pseudo_random;
use crate::bricks::{
    brick_value_ranges_for_storage, low_res_level, pack_hi_res_brick, pack_low_res_brick,
    quantize_to, LowResLevel,
};
use glam::Vec3;

const STORAGES: [ScalarType; 3] = [ScalarType::U8, ScalarType::U16, ScalarType::F32];

fn volume_of(dims: UVec3, scalar: ScalarType, seed: u64) -> Volume {
    let count = (dims.x * dims.y * dims.z) as usize;
    let values = pseudo_random(count, seed);
    let data = match scalar {
        ScalarType::U8 => VoxelData::U8(values.iter().map(|v| (v * 256.0) as u8).collect()),
        ScalarType::U16 => VoxelData::U16(values.iter().map(|v| (v * 65536.0) as u16).collect()),
        // Not UNORM: exercises the f64 paths and ranges outside [0, 1].
        ScalarType::F32 => VoxelData::F32(values.iter().map(|v| v * 3.0 - 1.0).collect()),
    };
    Volume::new(dims, Vec3::ONE, data).unwrap()
}

fn zeroed(storage: ScalarType, len: usize) -> VoxelData {
    match storage {
        ScalarType::U8 => VoxelData::U8(vec![0; len]),
        ScalarType::U16 => VoxelData::U16(vec![0; len]),
        ScalarType::F32 => VoxelData::F32(vec![0.0; len]),
    }
}

/// The voxels `origin .. origin + extent` of `volume`, as a window buffer of its scalar type.
fn cut(volume: &Volume, origin: UVec3, extent: UVec3) -> VoxelData {
    let index = |x: u32, y: u32, z: u32| volume.index(origin.x + x, origin.y + y, origin.z + z);
    let coords = (0..extent.z)
        .flat_map(move |z| (0..extent.y).flat_map(move |y| (0..extent.x).map(move |x| (x, y, z))));
    match volume.data() {
        VoxelData::U8(v) => VoxelData::U8(coords.map(|(x, y, z)| v[index(x, y, z)]).collect()),
        VoxelData::U16(v) => VoxelData::U16(coords.map(|(x, y, z)| v[index(x, y, z)]).collect()),
        VoxelData::F32(v) => VoxelData::F32(coords.map(|(x, y, z)| v[index(x, y, z)]).collect()),
    }
}

/// The reference's bytes and ranges of every brick, and its level.
struct Reference {
    hi: Vec<Vec<u8>>,
    lo: Vec<Vec<u8>>,
    ranges: Vec<ValueRange>,
    level: LowResLevel,
}

impl Reference {
    fn new(
        volume: &Volume,
        grid: &BrickGrid,
        filter: DownsampleFilter,
        storage: ScalarType,
    ) -> Self {
        let pack = |values: Vec<f32>| quantize_to(&values, storage);
        Self {
            hi: grid
                .bricks()
                .map(|b| pack(pack_hi_res_brick(volume, grid, b).unwrap()))
                .collect(),
            lo: grid
                .bricks()
                .map(|b| pack(pack_low_res_brick(volume, grid, filter, b).unwrap()))
                .collect(),
            ranges: brick_value_ranges_for_storage(volume, grid, filter, storage).unwrap(),
            level: low_res_level(volume, filter),
        }
    }
}

/// Packs `bricks` with every output and compares each brick with the reference.
fn assert_box_matches_reference(
    kernel: &mut BrickKernel,
    reference: &Reference,
    window: &VoxelWindow<'_>,
    bricks: &BrickBox,
) {
    let grid = *kernel.grid();
    let (filter, storage) = (kernel.filter(), kernel.storage());
    let n = grid.brick_size();
    let count = bricks.count();
    let mut hi = zeroed(storage, count * (hi_res_brick_extent(n) as usize).pow(3));
    let mut lo = zeroed(storage, count * (low_res_brick_extent(n) as usize).pow(3));
    let mut ranges = vec![ValueRange::EMPTY; count];
    let out = PackOutputs {
        hi: Some(TexelsMut::of(&mut hi)),
        lo: Some(TexelsMut::of(&mut lo)),
        ranges: Some(&mut ranges),
        level: true,
    };
    kernel.pack_window(window, bricks, out).unwrap();
    let what = format!(
        "dims {} n {n} {filter:?} {:?} -> {storage:?}, box {bricks:?}, window at {}",
        grid.dims(),
        window.data.scalar_type(),
        window.origin()
    );
    let (hi_bytes, lo_bytes) = (hi.as_bytes(), lo.as_bytes());
    let hi_size = hi_bytes.len() / count;
    let lo_size = lo_bytes.len() / count;
    for (i, brick) in bricks.bricks().enumerate() {
        let index = grid.linear_index(brick);
        let got_hi = &hi_bytes[i * hi_size..][..hi_size];
        assert_eq!(got_hi, &reference.hi[index][..], "{what} hi {brick}");
        let got_lo = &lo_bytes[i * lo_size..][..lo_size];
        assert_eq!(got_lo, &reference.lo[index][..], "{what} lo {brick}");
        assert_eq!(ranges[i], reference.ranges[index], "{what} range {brick}");
    }
    // The samples computed on the way are the reference level's.
    let block = kernel.low_res_block();
    let [nx, ny, _] = block.dims;
    for (i, &v) in block.values.iter().enumerate() {
        let k = UVec3::new(
            (block.k_start[0] + i % nx) as u32,
            (block.k_start[1] + (i / nx) % ny) as u32,
            (block.k_start[2] + i / (nx * ny)) as u32,
        );
        let want = reference.level.value(k.as_ivec3());
        assert_eq!(v.to_bits(), want.to_bits(), "{what} level sample {k}");
    }
}

/// Every kind of box of a grid: single bricks, runs along x, a multi-row box, the whole grid.
fn boxes(grid: &BrickGrid) -> Vec<BrickBox> {
    let b = grid.bricks_per_axis();
    let mut boxes: Vec<BrickBox> = grid.bricks().map(BrickBox::single).collect();
    for z in 0..b.z {
        for y in 0..b.y {
            boxes.push(BrickBox::run(0..b.x, y, z));
            if b.x > 2 {
                boxes.push(BrickBox::run(1..b.x, y, z));
            }
        }
    }
    boxes.push(BrickBox {
        start: UVec3::ZERO,
        end: b,
    });
    boxes.push(BrickBox {
        start: b.saturating_sub(UVec3::splat(2)),
        end: b,
    });
    boxes
}

#[test]
fn every_box_matches_the_reference_from_windows_and_from_the_volume() {
    let cases = [
        (UVec3::new(37, 1, 23), 8),
        (UVec3::new(1, 1, 1), 4),
        (UVec3::new(13, 9, 6), 4),
        (UVec3::new(2, 3, 5), 2),
        (UVec3::new(19, 17, 9), 8),
        (UVec3::new(33, 7, 9), 32),
    ];
    for (case, &(dims, n)) in cases.iter().enumerate() {
        let grid = BrickGrid::new(dims, n).unwrap();
        for source in STORAGES {
            let volume = volume_of(dims, source, case as u64 + 11);
            for filter in DownsampleFilter::ALL {
                for storage in STORAGES {
                    let reference = Reference::new(&volume, &grid, filter, storage);
                    let mut kernel = BrickKernel::new(&grid, filter, storage);
                    for bricks in boxes(&grid) {
                        let whole = VoxelWindow::of_volume(&volume);
                        assert_box_matches_reference(&mut kernel, &reference, &whole, &bricks);
                        let (origin, extent) = kernel.window_for(&bricks).unwrap();
                        let data = cut(&volume, origin, extent);
                        let window = VoxelWindow::new(&data, origin, extent).unwrap();
                        assert_box_matches_reference(&mut kernel, &reference, &window, &bricks);
                    }
                }
            }
        }
    }
}

#[test]
fn each_output_alone_equals_the_full_call() {
    let dims = UVec3::new(21, 14, 10);
    let grid = BrickGrid::new(dims, 4).unwrap();
    let volume = volume_of(dims, ScalarType::U16, 5);
    for filter in DownsampleFilter::ALL {
        let mut kernel = BrickKernel::new(&grid, filter, ScalarType::U8);
        let bricks = BrickBox::run(1..5, 2, 1);
        let (origin, extent) = kernel.window_for(&bricks).unwrap();
        let data = cut(&volume, origin, extent);
        let window = VoxelWindow::new(&data, origin, extent).unwrap();
        let mut all = (
            vec![0u8; 4 * 216],
            vec![0u8; 4 * 27],
            vec![ValueRange::EMPTY; 4],
        );
        let out = PackOutputs {
            hi: Some(TexelsMut::U8(&mut all.0)),
            lo: Some(TexelsMut::U8(&mut all.1)),
            ranges: Some(&mut all.2),
            level: false,
        };
        kernel.pack_window(&window, &bricks, out).unwrap();
        let mut hi = vec![0u8; 4 * 216];
        let out = PackOutputs {
            hi: Some(TexelsMut::U8(&mut hi)),
            ..PackOutputs::default()
        };
        kernel.pack_window(&window, &bricks, out).unwrap();
        assert_eq!(hi, all.0, "{filter:?}");
        let mut lo = vec![0u8; 4 * 27];
        let out = PackOutputs {
            lo: Some(TexelsMut::U8(&mut lo)),
            ..PackOutputs::default()
        };
        kernel.pack_window(&window, &bricks, out).unwrap();
        assert_eq!(lo, all.1, "{filter:?}");
        let mut ranges = vec![ValueRange::EMPTY; 4];
        let out = PackOutputs {
            ranges: Some(&mut ranges),
            ..PackOutputs::default()
        };
        kernel.pack_window(&window, &bricks, out).unwrap();
        assert_eq!(ranges, all.2, "{filter:?}");
        // Nothing asked: nothing read, nothing computed.
        kernel
            .pack_window(&window, &bricks, PackOutputs::default())
            .unwrap();
        assert!(kernel.low_res_block().values.is_empty());
    }
}

#[test]
fn bad_boxes_windows_and_outputs_are_typed_errors() {
    let dims = UVec3::new(12, 8, 8);
    let grid = BrickGrid::new(dims, 4).unwrap();
    let volume = volume_of(dims, ScalarType::U8, 3);
    let whole = VoxelWindow::of_volume(&volume);
    let mut kernel = BrickKernel::new(&grid, DownsampleFilter::Box4, ScalarType::U8);
    for bricks in [
        BrickBox::single(UVec3::new(3, 0, 0)),
        BrickBox::run(2..2, 0, 0),
        BrickBox::run(0..4, 0, 0),
    ] {
        assert!(matches!(
            kernel.window_for(&bricks),
            Err(BrickError::BrickOutOfRange { .. })
        ));
        assert!(matches!(
            kernel.pack_window(&whole, &bricks, PackOutputs::default()),
            Err(BrickError::BrickOutOfRange { .. })
        ));
    }
    let bricks = BrickBox::single(UVec3::new(1, 1, 1));
    let (origin, extent) = kernel.window_for(&bricks).unwrap();
    // A window one voxel short along x misses a voxel the ranges read (the hi-res brick alone
    // does not need it).
    let short = extent - UVec3::X;
    let data = cut(&volume, origin, short);
    let window = VoxelWindow::new(&data, origin, short).unwrap();
    let mut hi = vec![0u8; 216];
    let out = PackOutputs {
        hi: Some(TexelsMut::U8(&mut hi)),
        ..PackOutputs::default()
    };
    kernel.pack_window(&window, &bricks, out).unwrap();
    let mut range = [ValueRange::EMPTY];
    let out = PackOutputs {
        ranges: Some(&mut range),
        ..PackOutputs::default()
    };
    assert!(matches!(
        kernel.pack_window(&window, &bricks, out),
        Err(BrickError::InvalidWindow { .. })
    ));
    assert!(matches!(
        VoxelWindow::new(&data, origin, extent),
        Err(BrickError::InvalidWindow { .. })
    ));
    // A window reaching past the volume.
    let data = VoxelData::U8(vec![0; 13 * 8 * 8]);
    let window = VoxelWindow::new(&data, UVec3::ZERO, UVec3::new(13, 8, 8)).unwrap();
    assert!(matches!(
        kernel.pack_window(&window, &bricks, PackOutputs::default()),
        Err(BrickError::InvalidWindow { .. })
    ));
    // Outputs of the wrong length or texel type.
    let mut short = vec![0u8; 215];
    let mut words = vec![0u16; 216];
    let mut ranges = vec![ValueRange::EMPTY; 2];
    for out in [
        PackOutputs {
            hi: Some(TexelsMut::U8(&mut short)),
            ..PackOutputs::default()
        },
        PackOutputs {
            hi: Some(TexelsMut::U16(&mut words)),
            ..PackOutputs::default()
        },
        PackOutputs {
            ranges: Some(&mut ranges),
            ..PackOutputs::default()
        },
    ] {
        assert!(matches!(
            kernel.pack_window(&whole, &bricks, out),
            Err(BrickError::OutputMismatch { .. })
        ));
    }
}
