//! A level store read from where it lives (issue 19, item 4: the store carries every level, on
//! disk or in object storage): `LevelStore::open_remote` over HTTP (tests/servers/range_server.py
//! on loopback) and S3 (moto's server) reads the same header, table and stored bricks as the
//! local file, one range request per stored brick; a missing object and a damaged brick are
//! errors naming the URL.

mod remote_util;

use glam::UVec3;
use mixvol::bricks::DownsampleFilter;
use mixvol::cache::{block_bricks, stored_bricks_per_axis};
use mixvol::store::{write_level_store, LevelStore, LevelStreamConfig, LevelStreamer, StoreError};
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

/// A level store of Marschner-Lobb at `dims` in `scalar` written as `v.mvl` in `dir`, and the
/// file opened.
fn local_store(dir: &TempDir, dims: UVec3, scalar: ScalarType) -> (std::path::PathBuf, LevelStore) {
    let volume = SyntheticField::MarschnerLobb
        .generate(dims, scalar)
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
    (path, local)
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
    let (path, local) = local_store(&dir, UVec3::new(40, 24, 32), ScalarType::U16);

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

/// Review H3: a remote level store under faults and through the background reader.
/// - one range request per stored brick (the header and table are read once, at open);
/// - a first request answered 500 is retried (`RemoteOptions::max_retries`): the store opens and
///   reads as the local file;
/// - a stalled server fails within the timeout and a body cut short fails as a remote error
///   naming the URL, not as a corrupt brick;
/// - a `LevelStreamer` with 4 loaders over the remote store reads every stored brick, and over
///   one whose stored brick is damaged counts that failure and names the URL.
#[test]
fn a_remote_level_store_under_faults_and_through_the_streamer() {
    let dir = TempDir::new("level-store-faults");
    let (path, local) = local_store(&dir, UVec3::new(32, 24, 16), ScalarType::U8);
    let server = range_server(&dir.0);
    let stored = every_stored(&local);

    // One range request per stored brick once open.
    let url = format!("{}/ok/v.mvl", server.base());
    let remote = LevelStore::open_remote(&url, &RemoteOptions::default()).unwrap();
    let before = request_count(&server, "/ok/v.mvl");
    for &(level, first) in &stored {
        remote.read_stored_bytes(level, first).unwrap();
    }
    let per_brick = request_count(&server, "/ok/v.mvl") - before;
    assert_eq!(
        per_brick,
        stored.len() as u64,
        "{per_brick} requests for {} stored bricks",
        stored.len()
    );

    // The first request answered 500: retried, and the store reads as the file.
    let flaky = format!("{}/500once/v.mvl", server.base());
    let remote = LevelStore::open_remote(&flaky, &quick(2, 5000)).unwrap();
    assert_same_store(&remote, &local);

    // A stalled server: a remote error naming the URL within the timeout.
    let stalled = format!("{}/stall/v.mvl", server.base());
    let start = std::time::Instant::now();
    match LevelStore::open_remote(&stalled, &quick(1, 300)) {
        Err(e @ StoreError::Remote { .. }) => assert!(e.to_string().contains(&stalled), "{e}"),
        other => panic!("expected a remote error, got {other:?}"),
    }
    assert!(start.elapsed() < std::time::Duration::from_secs(10));
    // Bodies cut in half: a remote error naming the URL, not a checksum error.
    let cut = format!("{}/truncate/v.mvl", server.base());
    match LevelStore::open_remote(&cut, &quick(1, 2000)) {
        Err(e @ StoreError::Remote { .. }) => assert!(e.to_string().contains(&cut), "{e}"),
        other => panic!("expected a remote error, got {other:?}"),
    }

    // The background reader over the remote store: every stored brick read, none failed.
    let remote =
        std::sync::Arc::new(LevelStore::open_remote(&url, &RemoteOptions::default()).unwrap());
    let grid = remote.grid();
    let keys: Vec<(u32, usize)> = stored
        .iter()
        .map(|&(level, first)| (level, grid.linear_index(first)))
        .collect();
    let streamer = LevelStreamer::new(remote.clone(), LevelStreamConfig::default()).unwrap();
    streamer.request(&keys);
    assert!(streamer.wait_idle(std::time::Duration::from_secs(60)));
    let stats = streamer.stats();
    assert_eq!(stats.loads, keys.len() as u64, "{stats:?}");
    assert_eq!(stats.failures, 0, "{stats:?}");
    for &(level, first) in &keys {
        let bytes = streamer.get((level, first)).expect("in RAM").unwrap();
        let at = grid.brick_coords(first);
        assert_eq!(&bytes[..], &local.read_stored_bytes(level, at).unwrap()[..]);
    }
    drop(streamer);

    // A damaged stored brick: the reader counts the failure and names the URL.
    let data = local.header().data_offset as usize;
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[data + 7] ^= 0x10;
    std::fs::write(dir.0.join("bad.mvl"), &bytes).unwrap();
    let bad_url = format!("{}/ok/bad.mvl", server.base());
    let bad =
        std::sync::Arc::new(LevelStore::open_remote(&bad_url, &RemoteOptions::default()).unwrap());
    let streamer = LevelStreamer::new(bad, LevelStreamConfig::default()).unwrap();
    streamer.request(&keys);
    assert!(streamer.wait_idle(std::time::Duration::from_secs(60)));
    let stats = streamer.stats();
    assert_eq!(stats.failures, 1, "{stats:?}");
    let first = streamer.first_failure().expect("a failure");
    assert!(first.to_string().contains(&bad_url), "{first}");
    assert!(matches!(
        streamer.get((0, 0)),
        Some(Err(ref e)) if matches!(**e, StoreError::StoredBrickChecksum { level: 0, .. })
    ));
}
