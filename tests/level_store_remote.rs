//! A level store read from where it lives (issue 19, item 4: the store carries every level, on
//! disk or in object storage): `LevelStore::open_remote` over HTTP (tests/servers/range_server.py
//! on loopback) and S3 (moto's server) reads the same header, table and stored bricks as the
//! local file, one range request per stored brick; a missing object and a damaged brick are
//! errors naming the URL.

mod remote_util;

use glam::UVec3;
use mixvol::bricks::DownsampleFilter;
use mixvol::cache::{block_bricks, stored_bricks_per_axis};
use mixvol::store::{write_level_store, LevelStore, StoreError};
use mixvol::volume::formats::RemoteOptions;
use mixvol::volume::{ScalarType, SyntheticField};
use remote_util::*;

const N: u32 = 8;

/// Every stored brick's first brick, level by level.
fn every_stored(store: &LevelStore) -> Vec<(u32, UVec3)> {
    let bricks = store.grid().bricks_per_axis();
    let mut out = Vec::new();
    for level in 0..store.level_count() {
        let s = stored_bricks_per_axis(bricks, level);
        for z in 0..s.z {
            for y in 0..s.y {
                for x in 0..s.x {
                    out.push((level, UVec3::new(x, y, z) * block_bricks(level)));
                }
            }
        }
    }
    out
}

fn assert_same_store(remote: &LevelStore, local: &LevelStore) {
    assert_eq!(remote.header(), local.header());
    for (level, first) in every_stored(local) {
        assert_eq!(
            remote.read_stored_bytes(level, first).unwrap(),
            local.read_stored_bytes(level, first).unwrap(),
            "level {level} brick {first}"
        );
        assert_eq!(
            remote.stored_range(level, first).unwrap(),
            local.stored_range(level, first).unwrap()
        );
    }
}

#[test]
fn a_remote_level_store_reads_as_the_local_file() {
    let dir = TempDir::new("level-store");
    let volume = SyntheticField::MarschnerLobb
        .generate(UVec3::new(40, 24, 32), ScalarType::U16)
        .unwrap();
    let path = dir.0.join("v.mvl");
    write_level_store(
        &path,
        &volume,
        N,
        None,
        DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    let local = LevelStore::open(&path).unwrap();

    // Over HTTP with range requests.
    let server = range_server(&dir.0);
    let url = format!("{}/ok/v.mvl", server.base());
    let remote = LevelStore::open_remote(&url, &RemoteOptions::default()).unwrap();
    assert_same_store(&remote, &local);
    assert_eq!(remote.path().to_str(), Some(url.as_str()));

    // On S3.
    let moto = moto_server();
    s3_upload(&moto, &dir.0, "levels", "stores");
    let s3 = LevelStore::open_remote("s3://levels/stores/v.mvl", &moto_options(&moto)).unwrap();
    assert_same_store(&s3, &local);

    // A missing object names its URL.
    let missing = format!("{}/ok/none.mvl", server.base());
    match LevelStore::open_remote(&missing, &RemoteOptions::default()) {
        Err(e @ StoreError::Remote { .. }) => assert!(e.to_string().contains(&missing), "{e}"),
        other => panic!("expected a remote error, got {other:?}"),
    }
    // A damaged stored brick fails its CRC, naming the URL.
    let data = local.header().data_offset as usize;
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[data + 7] ^= 0x10;
    std::fs::write(dir.0.join("bad.mvl"), &bytes).unwrap();
    let bad_url = format!("{}/ok/bad.mvl", server.base());
    let bad = LevelStore::open_remote(&bad_url, &RemoteOptions::default()).unwrap();
    match bad.read_stored_bytes(0, UVec3::ZERO) {
        Err(e @ StoreError::StoredBrickChecksum { level: 0, .. }) => {
            assert!(e.to_string().contains(&bad_url), "{e}")
        }
        other => panic!("expected a checksum error, got {other:?}"),
    }
    // A URL that names no file is refused.
    assert!(LevelStore::open_remote("s3://levels", &moto_options(&moto)).is_err());
}
