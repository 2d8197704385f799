//! Missing Zarr chunks cost memory only where they meet the array (issue 16: a 1x1x1 array with
//! 512x1024x1024 chunks took 1 GiB, the fill value being materialised at the full chunk size).
//!
//! This binary counts every heap allocation (a counting global allocator, so it holds this one
//! test and nothing runs beside it) and asserts the peak while loading such arrays, Zarr v2 and
//! v3, written by hand (metadata only: every chunk is missing). A full u16 chunk is exactly the
//! 1 GiB chunk limit, so it is accepted, and a loader that allocates it fails the bound by 64x.
use mixvol::volume::formats::zarr::{ZarrSlabs, MAX_CHUNK_BYTES};
use mixvol::volume::{load_zarr, VoxelData};
use mixvol::volume::{SlabMut, SlabReader};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(by: usize) {
    let now = CURRENT.fetch_add(by, Ordering::Relaxed) + by;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every call is forwarded to `System` unchanged; only the sizes are counted.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
            grew(new_size);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The most bytes a load of these tiny arrays may hold at once (metadata, zarrs' codec chains,
/// the volume): far below the 1 GiB of one full chunk.
const BOUND: usize = 16 << 20;

/// Runs `f` and returns its result and the peak heap bytes allocated during it, above what was
/// allocated before.
fn peak_during<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let r = f();
    (r, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

fn write(path: &Path, text: &str) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
}

#[test]
fn missing_chunks_larger_than_the_array_cost_no_chunk_sized_buffer() {
    // u16 chunks of 512 x 1024 x 1024: exactly the chunk limit, so not refused.
    assert_eq!(2 * 512 * 1024 * 1024, MAX_CHUNK_BYTES);
    let dir =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("zarr-fill-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let v3 = dir.join("v3.zarr");
    write(
        &v3.join("zarr.json"),
        r#"{"zarr_format": 3, "node_type": "array", "shape": [1, 1, 1], "data_type": "uint16",
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [512, 1024, 1024]}},
            "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
            "fill_value": 1234, "codecs": [{"name": "bytes", "configuration": {"endian": "little"}}]}"#,
    );
    let v2 = dir.join("v2.zarr");
    write(
        &v2.join(".zarray"),
        r#"{"zarr_format": 2, "shape": [3, 5, 7], "chunks": [512, 1024, 1024], "dtype": "<u2",
            "fill_value": 77, "order": "C", "filters": null, "compressor": null}"#,
    );

    let (v, peak) = peak_during(|| load_zarr(&v3).unwrap());
    assert_eq!(v.volume.dims().to_array(), [1, 1, 1]);
    assert!(matches!(v.volume.data(), VoxelData::U16(d) if d == &[1234]));
    // The loader says none of the chunks exists (review D7), for the caller to report.
    assert_eq!(v.meta.chunks_found, Some((0, 1)));
    assert!(
        peak < BOUND,
        "v3 1x1x1 load peaked at {peak} bytes (bound {BOUND})"
    );
    drop(v);

    let (v, peak) = peak_during(|| load_zarr(&v2).unwrap());
    assert_eq!(v.volume.dims().to_array(), [7, 5, 3]);
    assert!(
        matches!(v.volume.data(), VoxelData::U16(d) if d.len() == 105 && d.iter().all(|&x| x == 77))
    );
    assert!(
        peak < BOUND,
        "v2 7x5x3 load peaked at {peak} bytes (bound {BOUND})"
    );
    drop(v);

    // The slab reader shares the chunk reader.
    let (slab, peak) = peak_during(|| {
        let mut r = ZarrSlabs::open(&v2, 0).unwrap();
        let mut out = vec![0u16; 7 * 5];
        r.read_slab(1..2, SlabMut::U16(&mut out)).unwrap();
        out
    });
    assert!(slab.iter().all(|&x| x == 77), "{slab:?}");
    assert!(
        peak < BOUND,
        "v2 slab peaked at {peak} bytes (bound {BOUND})"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
