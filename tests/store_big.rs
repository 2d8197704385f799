//! Out-of-core: a volume far larger than the RAM budget is written brick by brick from an
//! analytic field, then streamed under a 64 MiB budget while the process's peak RSS (VmHWM) is
//! checked. VmHWM is process-wide, so this file holds a single test.
//!
//! The edge length defaults to 1024 (a 1.35 GiB store); `MIXVOL_STORE_BIG_DIM` overrides it with
//! a larger one. Smaller ones are refused (the test fails saying so): below 1024 the store is no
//! longer 8 times the RAM budget, the views no longer exceed it and nothing is evicted, so the
//! out-of-core test would silently become an in-core one.

use glam::{IVec3, UVec3, Vec3};
use mixvol::bricks::{
    fallback_levels, request_plan, BrickSource, DownsampleFilter, Level, ValueRange,
};
use mixvol::store::{write_store, BrickStore, BrickStreamer, StoreDesc, StreamerConfig};
use mixvol::volume::ScalarType;
use std::path::PathBuf;
use std::time::{Duration, Instant};

const BRICK: u32 = 32;
const RAM_BUDGET: usize = 64 << 20;
/// Memory beyond the streamer's budget the test allows: the writer's per-thread chunk buffers
/// (about 2.5 x 8 MiB per thread, 2 threads here), thread stacks, the store's tables and
/// allocator slack.
const ALLOWANCE: u64 = 48 << 20;

/// `VmHWM` (peak RSS) of this process in bytes.
fn vm_hwm() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

/// The analytic field as separable tables: `f = x(x) + y(y) + z(z) + u(x) * w(y)`, in [0.04, 0.96].
struct Field {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    u: Vec<f32>,
    w: Vec<f32>,
}

impl Field {
    fn new(d: u32) -> Self {
        let table = |f: &dyn Fn(f32) -> f32| (0..d).map(|i| f(i as f32)).collect::<Vec<f32>>();
        let tau = std::f32::consts::TAU;
        Self {
            x: table(&|i| 0.5 + 0.2 * (tau * i / 97.0).sin()),
            y: table(&|i| 0.1 * (tau * i / 61.0 + 0.3).sin()),
            z: table(&|i| 0.08 * (tau * i / 127.0).cos()),
            u: table(&|i| 0.3 * (tau * i / 53.0).cos()),
            w: table(&|i| 0.25 * (tau * i / 71.0).sin()),
        }
    }

    fn value(&self, p: IVec3) -> f32 {
        let (x, y, z) = (p.x as usize, p.y as usize, p.z as usize);
        self.x[x] + self.y[y] + self.z[z] + self.u[x] * self.w[y]
    }

    /// The stored (u8-quantised) value of voxel `p`, clamped to the volume.
    fn stored(&self, p: IVec3, d: i32) -> f32 {
        let q = (self
            .value(p.clamp(IVec3::ZERO, IVec3::splat(d - 1)))
            .clamp(0.0, 1.0)
            * 255.0)
            .round();
        q / 255.0
    }
}

/// The expected hi-res brick bytes by direct evaluation.
fn expected_hi(field: &Field, d: i32, brick: UVec3) -> Vec<u8> {
    let n = BRICK as i32;
    let e = n + 2;
    let first = brick.as_ivec3() * n - IVec3::ONE;
    let mut out = Vec::new();
    for z in 0..e {
        for y in 0..e {
            for x in 0..e {
                out.push((field.stored(first + IVec3::new(x, y, z), d) * 255.0).round() as u8);
            }
        }
    }
    out
}

/// The expected Mean2 low-res brick bytes by direct evaluation: sample `k` averages voxels
/// `2k-1, 2k` per axis (clamped, `k` clamped to `ceil(d/2)`), separably x, y, z in `f64`, rounded
/// to `f32` after each axis.
fn expected_lo(field: &Field, d: i32, brick: UVec3) -> Vec<u8> {
    let n = BRICK as i32;
    let e = n / 2 + 1;
    let kmax = (d + 1) / 2;
    let pair = |k: i32| {
        let k = k.clamp(0, kmax);
        [2 * k - 1, 2 * k]
    };
    let mean = |a: f32, b: f32| (0.5 * f64::from(a) + 0.5 * f64::from(b)) as f32;
    let k0 = brick.as_ivec3() * (n / 2);
    let mut out = Vec::new();
    for jz in 0..e {
        for jy in 0..e {
            for jx in 0..e {
                let k = k0 + IVec3::new(jx, jy, jz);
                let [x0, x1] = pair(k.x);
                let [y0, y1] = pair(k.y);
                let [z0, z1] = pair(k.z);
                let along_x = |y, z| {
                    mean(
                        field.stored(IVec3::new(x0, y, z), d),
                        field.stored(IVec3::new(x1, y, z), d),
                    )
                };
                let along_y = |z| mean(along_x(y0, z), along_x(y1, z));
                let v = mean(along_y(z0), along_y(z1));
                out.push((v.clamp(0.0, 1.0) * 255.0).round() as u8);
            }
        }
    }
    out
}

/// Removes the (large) store file however the test ends.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The smallest edge length for which the store is over 8 x the RAM budget, the views exceed it
/// and the streamer has to evict (the default).
const MIN_DIM: u32 = 1024;

/// The edge length from `MIXVOL_STORE_BIG_DIM` (`None`: unset): the default [`MIN_DIM`], or a
/// larger one; a smaller or unparsable one panics with the reason.
fn big_dim(var: Option<&str>) -> u32 {
    let Some(text) = var else {
        return MIN_DIM;
    };
    let dim: u32 = text.trim().parse().unwrap_or_else(|_| {
        panic!("MIXVOL_STORE_BIG_DIM={text:?} is not an edge length (unset it for {MIN_DIM})")
    });
    assert!(
        dim >= MIN_DIM,
        "MIXVOL_STORE_BIG_DIM={dim} is refused: below {MIN_DIM} the store is not 8 x the \
         {} MiB RAM budget, the views do not exceed it and nothing is evicted, so the test \
         would not test out-of-core streaming (unset it, or use {MIN_DIM} or more)",
        RAM_BUDGET >> 20
    );
    dim
}

#[test]
fn out_of_core_volume_streams_within_the_ram_budget() {
    let baseline = vm_hwm();
    let dim = big_dim(std::env::var("MIXVOL_STORE_BIG_DIM").ok().as_deref());
    let d = dim as i32;
    let field = Field::new(dim);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("store-tests");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("big-{dim}-{}.mvbs", std::process::id()));
    let _cleanup = RemoveOnDrop(path.clone());
    let desc = StoreDesc {
        dims: UVec3::splat(dim),
        brick_size: BRICK,
        scalar: ScalarType::U8,
        spacing: Vec3::ONE,
        filter: DownsampleFilter::Mean2,
    };

    // 1. Write brick by brick: never the whole volume in RAM.
    let sample = |p: IVec3| field.value(p);
    let summary = write_store(&path, desc, &sample, &mut |_, _| {}).unwrap();
    let after_write = vm_hwm();
    let file_size = summary.header.file_size;
    eprintln!(
        "wrote {dim}^3 u8 (n = {BRICK}): {} bricks, {:.2} GiB in {:.1} s on {} threads = {:.0} MB/s; \
         VmHWM {:.1} MiB (baseline {:.1} MiB)",
        summary.header.brick_count,
        file_size as f64 / (1u64 << 30) as f64,
        summary.elapsed.as_secs_f64(),
        summary.threads,
        summary.bytes_per_second() / 1e6,
        after_write as f64 / (1 << 20) as f64,
        baseline as f64 / (1 << 20) as f64,
    );
    assert!(
        after_write <= baseline + ALLOWANCE,
        "writing needed {} MiB over the baseline",
        (after_write - baseline) >> 20
    );

    // 2. Open and check bricks against the analytic field.
    let store = BrickStore::open(&path).unwrap();
    let grid = store.grid();
    let b = grid.bricks_per_axis();
    assert!(
        file_size as usize > 8 * RAM_BUDGET,
        "the store ({file_size} bytes) must be over 8 x the RAM budget"
    );
    let samples = [
        UVec3::ZERO,
        b - UVec3::ONE,
        b / 2,
        UVec3::new(1, b.y - 1, 2.min(b.z - 1)),
    ];
    for brick in samples {
        let i = grid.linear_index(brick) as u32;
        assert_eq!(
            store.read_brick(i, Level::Hi).unwrap(),
            expected_hi(&field, d, brick),
            "hi {brick}"
        );
        assert_eq!(
            store.read_brick(i, Level::Lo).unwrap(),
            expected_lo(&field, d, brick),
            "lo {brick}"
        );
    }
    assert!(store.value_range().min >= 0.03 && store.value_range().max <= 0.97);
    // Positioned-read throughput of random hi-res bricks. The file was just written, so it is in
    // the page cache; with MIXVOL_STORE_COLD=1 the test first syncs it and drops its cached pages
    // (`dd iflag=nocache count=0`, this file only) to measure reads from the disk as well.
    let reads = 2000.min(grid.brick_count() as u32);
    let mut buffer = vec![0u8; store.level_bytes(Level::Hi)];
    let mut measure = |label: &str| {
        let start = Instant::now();
        for r in 0..reads {
            let i = (r as u64 * 2_654_435_761 % grid.brick_count() as u64) as u32;
            store.read_brick_into(i, Level::Hi, &mut buffer).unwrap();
        }
        let t = start.elapsed();
        eprintln!(
            "read {reads} random hi-res bricks ({label}): {:.0} MB/s ({:.1} us per brick)",
            reads as f64 * buffer.len() as f64 / t.as_secs_f64() / 1e6,
            t.as_secs_f64() * 1e6 / reads as f64
        );
    };
    if std::env::var_os("MIXVOL_STORE_COLD").is_some() {
        std::fs::File::open(&path).unwrap().sync_all().unwrap();
        let dropped = std::process::Command::new("dd")
            .arg(format!("if={}", path.display()))
            .args(["iflag=nocache", "count=0", "status=none"])
            .status()
            .is_ok_and(|s| s.success());
        assert!(dropped, "dd could not drop the page cache of the store");
        measure("cold: page cache dropped");
    }
    measure("page cache warm");
    drop(buffer);
    drop(store);

    // 3. Stream three views under the RAM budget.
    let streamer = BrickStreamer::open(
        &path,
        StreamerConfig {
            ram_budget_bytes: RAM_BUDGET,
            record_load_order: false,
        },
    )
    .unwrap();
    let count = grid.brick_count();
    let centre = |i: usize| (grid.brick_coords(i).as_vec3() + 0.5) * BRICK as f32;
    let extent = dim as f32;
    for (view, eye) in [
        Vec3::new(0.2, 0.3, 0.4),
        Vec3::new(0.8, 0.5, 0.5),
        Vec3::new(0.45, 0.65, 0.35),
    ]
    .into_iter()
    .enumerate()
    {
        let eye = eye * extent;
        // Hi near the eye, Lo further out, culled beyond: about 100 MB wanted, over the budget.
        let distance: Vec<f32> = (0..count).map(|i| centre(i).distance(eye)).collect();
        let wanted: Vec<Level> = distance
            .iter()
            .map(|&r| {
                if r < 0.18 * extent {
                    Level::Hi
                } else if r < 0.45 * extent {
                    Level::Lo
                } else {
                    Level::Absent
                }
            })
            .collect();
        let priority: Vec<f32> = distance.iter().map(|r| -r).collect();
        let plan = request_plan(&wanted, &priority);
        let t = Instant::now();
        streamer.request(&plan).unwrap();
        let request_time = t.elapsed();
        // A hang guard for "request never reads the disk" (it takes 0.4-10 ms idle; reading the
        // wanted levels would take seconds), generous for a busy machine.
        assert!(request_time < Duration::from_secs(2), "request blocked");
        let start = Instant::now();
        assert!(
            streamer.wait_settled(Duration::from_secs(30)),
            "view {view} did not settle"
        );
        let stats = streamer.stats();
        let wanted_bytes: usize = plan
            .iter()
            .map(|&(_, level, _)| streamer.store().level_bytes(level))
            .sum();
        let levels = fallback_levels(&wanted, &streamer);
        let shown = |l: Level| levels.iter().filter(|&&x| x == l).count();
        eprintln!(
            "view {view}: request() {:.2} ms; wanted {} levels ({:.1} MiB), resident {} ({:.1} MiB), peak {:.1} MiB, \
             loads {} ({:.0} MB/s), evictions {}, settled in {:.2} s; drawn hi {} lo {} absent-but-wanted {}",
            request_time.as_secs_f64() * 1e3,
            stats.wanted_levels,
            wanted_bytes as f64 / (1 << 20) as f64,
            stats.wanted_resident,
            stats.resident_bytes as f64 / (1 << 20) as f64,
            stats.peak_bytes as f64 / (1 << 20) as f64,
            stats.loads,
            stats.bytes_read as f64 / stats.read_time.as_secs_f64().max(1e-9) / 1e6,
            stats.evictions,
            start.elapsed().as_secs_f64(),
            shown(Level::Hi),
            shown(Level::Lo),
            wanted.iter().zip(&levels).filter(|(w, l)| **w != Level::Absent && **l == Level::Absent).count(),
        );
        assert!(stats.peak_bytes <= RAM_BUDGET, "{stats:?}");
        assert!(stats.resident_bytes <= RAM_BUDGET, "{stats:?}");
        assert!(
            wanted_bytes > RAM_BUDGET,
            "view {view}: the views must exceed the budget ({wanted_bytes} bytes wanted)"
        );
        // The resident prefix is the plan's: every wanted level up to the first missing one.
        let first_missing = plan
            .iter()
            .position(|&(b, l, _)| !streamer.is_loaded(b, l))
            .unwrap_or(plan.len());
        assert_eq!(first_missing, stats.wanted_resident, "view {view}");
        // Fallback never draws a level whose bytes are missing.
        for (i, &level) in levels.iter().enumerate() {
            if level != Level::Absent {
                let bytes = streamer.brick_bytes(i as u32, level).unwrap().unwrap();
                assert_eq!(bytes.len(), streamer.store().level_bytes(level));
            }
        }
        let peak = vm_hwm();
        assert!(
            peak <= baseline + RAM_BUDGET as u64 + ALLOWANCE,
            "VmHWM {} MiB exceeds baseline {} MiB + budget {} MiB + allowance {} MiB",
            peak >> 20,
            baseline >> 20,
            RAM_BUDGET >> 20,
            ALLOWANCE >> 20
        );
    }
    // Spot-check streamed bytes against the field.
    let some_hi = streamer
        .resident()
        .into_iter()
        .find(|k| k.1 == Level::Hi)
        .expect("some hi-res brick is resident");
    assert_eq!(
        &*streamer.brick_bytes(some_hi.0, Level::Hi).unwrap().unwrap(),
        &expected_hi(&field, d, grid.brick_coords(some_hi.0 as usize))[..]
    );
    assert!(
        streamer.stats().evictions > 0,
        "nothing was evicted: {:?}",
        streamer.stats()
    );
    let value_range: ValueRange = streamer.value_range();
    assert!(value_range.max > value_range.min);
    drop(streamer);
    let peak = vm_hwm();
    eprintln!(
        "peak RSS (VmHWM) {:.1} MiB = baseline {:.1} MiB + {:.1} MiB (budget {} MiB + allowance {} MiB)",
        peak as f64 / (1 << 20) as f64,
        baseline as f64 / (1 << 20) as f64,
        (peak - baseline) as f64 / (1 << 20) as f64,
        RAM_BUDGET >> 20,
        ALLOWANCE >> 20
    );
}
