//! Two-level brick stores written by earlier versions (`tests/fixtures/brick_stores/*.mvbs`,
//! written by the two-level store writer at 879d560 from synthetic fields of awkward
//! dimensions, bricks of 8) are upgraded to level stores (CPU only).
//!
//! `BrickStoreSlabs` must give back every voxel of the volume the store was written from,
//! exactly, in slabs of any thickness (the fields are regenerated here from their names and
//! dimensions; the stores hold no copy of that code); a level store written from those slabs
//! must hold the same stored bricks, at every level, as one written from the regenerated
//! volume; a damaged brick is a typed error naming the store, and a bad request is refused.
use glam::UVec3;
use mixvol::bricks::DownsampleFilter;
use mixvol::store::{
    write_level_store, write_level_store_from_slabs, BrickStore, BrickStoreSlabs, LevelStore,
};
use mixvol::volume::{ScalarType, SlabMut, SlabReader, SyntheticField, VolumeError, VoxelData};
use std::path::PathBuf;

/// The fixtures: file, field, scalar type, dimensions.
const FIXTURES: [(&str, &str, ScalarType, [u32; 3]); 3] = [
    ("ml_u8", "ml", ScalarType::U8, [20, 12, 9]),
    ("sphere_u16", "sphere", ScalarType::U16, [13, 17, 10]),
    ("ml_f32", "ml", ScalarType::F32, [9, 10, 17]),
];

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/brick_stores")
        .join(format!("{name}.mvbs"))
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mixvol-upgrade-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Reads the whole volume from `reader` in slabs of `planes` planes.
fn read_all(reader: &mut BrickStoreSlabs, planes: u32) -> VoxelData {
    let d = reader.dims();
    let plane = (d.x * d.y) as usize;
    let voxels = plane * d.z as usize;
    let mut data = match reader.scalar() {
        ScalarType::U8 => VoxelData::U8(vec![0; voxels]),
        ScalarType::U16 => VoxelData::U16(vec![0; voxels]),
        ScalarType::F32 => VoxelData::F32(vec![0.0; voxels]),
    };
    let mut z = 0;
    while z < d.z {
        let end = (z + planes).min(d.z);
        let out = SlabMut::of_range(&mut data, z as usize * plane..end as usize * plane).unwrap();
        reader.read_slab(z..end, out).unwrap();
        z = end;
    }
    data
}

#[test]
fn a_brick_store_reads_back_every_voxel_of_its_volume_in_slabs_of_any_thickness() {
    for (name, field, scalar, dims) in FIXTURES {
        let dims = UVec3::from_array(dims);
        let expected = SyntheticField::parse(field)
            .unwrap()
            .generate(dims, scalar)
            .unwrap();
        let mut reader = BrickStoreSlabs::new(BrickStore::open(fixture(name)).unwrap());
        assert_eq!(reader.dims(), dims, "{name}");
        assert_eq!(reader.scalar(), scalar, "{name}");
        for planes in [1, 3, 8, dims.z] {
            let data = read_all(&mut reader, planes);
            assert!(
                data == *expected.data(),
                "{name}: slabs of {planes} planes differ from the volume"
            );
        }
    }
}

#[test]
fn an_upgraded_store_holds_the_level_store_of_its_volume() {
    for (name, field, scalar, dims) in FIXTURES {
        let volume = SyntheticField::parse(field)
            .unwrap()
            .generate(UVec3::from_array(dims), scalar)
            .unwrap();
        let direct = temp(&format!("{name}-direct.mvl"));
        let upgraded = temp(&format!("{name}-upgraded.mvl"));
        let filter = DownsampleFilter::Mean2;
        write_level_store(&direct, &volume, 8, None, filter, &mut |_, _| {}).unwrap();
        let mut reader = BrickStoreSlabs::new(BrickStore::open(fixture(name)).unwrap());
        write_level_store_from_slabs(
            &upgraded,
            &mut reader,
            8,
            None,
            filter,
            64 << 20,
            &mut |_, _| {},
        )
        .unwrap();
        let (a, b) = (
            LevelStore::open(&direct).unwrap(),
            LevelStore::open(&upgraded).unwrap(),
        );
        assert_eq!(a.level_count(), b.level_count(), "{name}");
        assert!(a.level_count() >= 2, "{name}");
        let bricks = a.grid().bricks_per_axis();
        for level in 0..a.level_count() {
            let step = 1u32 << level;
            for z in (0..bricks.z).step_by(step as usize) {
                for y in (0..bricks.y).step_by(step as usize) {
                    for x in (0..bricks.x).step_by(step as usize) {
                        let brick = UVec3::new(x, y, z);
                        assert_eq!(
                            a.read_stored_bytes(level, brick).unwrap(),
                            b.read_stored_bytes(level, brick).unwrap(),
                            "{name}: level {level} brick {brick}"
                        );
                    }
                }
            }
        }
        std::fs::remove_file(direct).ok();
        std::fs::remove_file(upgraded).ok();
    }
}

#[test]
fn a_damaged_brick_or_a_bad_request_is_an_error_naming_the_store() {
    let copy = temp("damaged.mvbs");
    let mut bytes = std::fs::read(fixture("ml_u8")).unwrap();
    // Byte 100 of the data is a texel of brick 0's hi-res level (the first level stored),
    // which plane 0 reads.
    let store = BrickStore::open(fixture("ml_u8")).unwrap();
    let data = store.header().data_offset as usize;
    bytes[data + 100] ^= 0x5a;
    std::fs::write(&copy, &bytes).unwrap();
    let mut reader = BrickStoreSlabs::new(BrickStore::open(&copy).unwrap());
    let d = reader.dims();
    let mut plane = vec![0u8; (d.x * d.y) as usize];
    match reader.read_slab(0..1, SlabMut::U8(&mut plane)) {
        Err(VolumeError::Io { path, source }) => {
            assert_eq!(path, copy);
            assert!(
                source.to_string().contains("brick 0 level Hi is corrupt"),
                "{source}"
            );
        }
        other => panic!("expected a checksum error, got {other:?}"),
    }
    // Planes past the volume, and a slab of the wrong size, are refused by name.
    let mut reader = BrickStoreSlabs::new(store);
    let mut big = vec![0u8; (d.x * d.y) as usize * 2];
    for z in [d.z - 1..d.z + 1, 0..1] {
        match reader.read_slab(z, SlabMut::U8(&mut big)) {
            Err(VolumeError::SlabRequest { path, .. }) => assert_eq!(path, fixture("ml_u8")),
            other => panic!("expected a refused request, got {other:?}"),
        }
    }
    std::fs::remove_file(copy).ok();
}
