//! Background reading of the stored bricks of every level (a level store, an OME-Zarr pyramid) ([`LevelStreamer`]), so that a camera
//! moving through a three-level source never waits on the disk.
//!
//! # Policy
//!
//! - **Wanted set.** [`LevelStreamer::request`] replaces the wanted set with a list of stored
//!   bricks `(level, first brick)`, highest priority first (duplicates keep their first place).
//!   It only takes a short lock. `renderer::Renderer::update` requests, in
//!   this order: the bricks of its next step towards the wanted plan, the stored bricks drawn
//!   now (a change of a coarser neighbour uploads them again), then the rest of the wanted plan.
//! - **Loading.** [`LevelStreamConfig::loaders`] background threads read the wanted bricks that
//!   are not in RAM, in priority order, each taking the next one no other loader reads
//!   ([`LevelBackend::read_stored_bytes`]: one CRC-checked positioned read or range request
//!   from a level store, the chunks of an OME-Zarr pyramid), without holding the lock during
//!   the read.
//! - **Budget.** The bytes of the cached bricks plus the ones being read never exceed
//!   [`LevelStreamConfig::ram_budget_bytes`]. Before a read a loader makes room by evicting
//!   first cached bricks that are not wanted, least recently used first, then wanted bricks of
//!   lower priority than the one to read, lowest first. Wanted bricks of higher priority are
//!   never evicted for a read: when the next brick cannot fit, the loaders stop until the next
//!   request, so the highest-priority prefix of the wanted set that fits is resident and stays
//!   so while the request is unchanged.
//! - **Failures.** A brick whose read fails (an I/O error, a CRC mismatch) is not read again
//!   until [`LevelStreamer::clear_failures`]; [`LevelStreamer::get`] returns its error.
//! - **Blocking reads.** [`LevelStreamer::read_now`] returns a brick from RAM, or reads it on
//!   the caller's thread when it is not there (attaching a source, a host-set plan, or a brick
//!   evicted under a tight budget); [`LevelStreamStats::blocking_reads`] counts those.
//! - **Shutdown.** Dropping the streamer stops the loaders after their reads in flight and joins
//!   them.

use super::LevelBackend;
use crate::store::StoreError;
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A stored brick: `(level, linear index of its first brick)`, as
/// `plan::step_towards` names it.
pub type StoredKey = (u32, usize);

/// How a [`LevelStreamer`] runs.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct LevelStreamConfig {
    /// Most bytes of stored bricks held in RAM (cached bricks plus the reads in flight). About
    /// the GPU cache's bytes plus one step's uploads keeps every drawn brick in RAM.
    pub ram_budget_bytes: usize,
    /// Loader threads, each with one read in flight (at least 1): an object store answers a
    /// request in tens of milliseconds, so several requests in flight keep it busy.
    pub loaders: usize,
}

impl Default for LevelStreamConfig {
    /// 512 MiB, 4 loaders.
    fn default() -> Self {
        Self {
            ram_budget_bytes: 512 << 20,
            loaders: 4,
        }
    }
}

/// A snapshot of a [`LevelStreamer`]'s counters.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelStreamStats {
    /// The RAM budget.
    pub ram_budget_bytes: usize,
    /// Bytes of cached bricks plus the read in flight.
    pub resident_bytes: usize,
    /// Largest `resident_bytes` reached.
    pub peak_bytes: usize,
    /// Cached stored bricks.
    pub resident_bricks: usize,
    /// Stored bricks in the wanted set.
    pub wanted_bricks: usize,
    /// Wanted stored bricks that are cached.
    pub wanted_resident: usize,
    /// Reads completed by the loaders.
    pub loads: u64,
    /// Bytes the loaders read.
    pub bytes_read: u64,
    /// Time the loaders spent reading (summed over the loaders).
    pub read_time: Duration,
    /// Bricks evicted to make room.
    pub evictions: u64,
    /// Reads done on a caller's thread ([`LevelStreamer::read_now`] missing RAM).
    pub blocking_reads: u64,
    /// Stored bricks whose read failed.
    pub failures: usize,
}

/// Everything behind the lock.
#[derive(Default)]
struct State {
    /// Wanted bricks in priority order.
    wanted: Vec<StoredKey>,
    /// Position of each wanted brick in `wanted`.
    rank: HashMap<StoredKey, usize>,
    /// Every wanted brick before `cursor` is cached or failed.
    cursor: usize,
    /// Cached bricks and their last use.
    cache: HashMap<StoredKey, (Arc<[u8]>, u64)>,
    /// Ranks of the cached wanted bricks.
    wanted_cached: BTreeSet<usize>,
    /// Cached unwanted bricks by last use.
    unwanted_lru: BTreeMap<u64, StoredKey>,
    failed: HashMap<StoredKey, Arc<StoreError>>,
    /// Bytes of the reads in flight.
    in_flight: usize,
    /// The stored bricks being read.
    reading: HashSet<StoredKey>,
    resident_bytes: usize,
    budget: usize,
    tick: u64,
    /// No read in flight, and nothing the loaders may read (all done, or the next brick does
    /// not fit).
    idle: bool,
    stop: bool,
    stats: LevelStreamStats,
}

impl State {
    fn touch(&mut self, key: StoredKey) {
        self.tick += 1;
        let tick = self.tick;
        if let Some(entry) = self.cache.get_mut(&key) {
            if !self.rank.contains_key(&key) {
                self.unwanted_lru.remove(&entry.1);
                self.unwanted_lru.insert(tick, key);
            }
            entry.1 = tick;
        }
    }

    fn evict(&mut self, key: StoredKey) {
        if let Some((bytes, tick)) = self.cache.remove(&key) {
            self.resident_bytes -= bytes.len();
            self.stats.evictions += 1;
            match self.rank.get(&key) {
                Some(rank) => {
                    self.wanted_cached.remove(rank);
                }
                None => {
                    self.unwanted_lru.remove(&tick);
                }
            }
        }
    }

    /// Makes room for `bytes` more for the wanted brick of rank `rank`; false if it cannot.
    fn make_room(&mut self, bytes: usize, rank: usize) -> bool {
        while self.resident_bytes + self.in_flight + bytes > self.budget {
            if let Some((_, &key)) = self.unwanted_lru.iter().next() {
                self.evict(key);
            } else if let Some(&last) = self.wanted_cached.iter().next_back() {
                if last <= rank {
                    return false;
                }
                self.evict(self.wanted[last]);
            } else {
                return false;
            }
        }
        true
    }
}

struct Shared {
    state: Mutex<State>,
    /// Wakes the loaders (a request, a budget change, a read done, shutdown) and waiters on idle.
    changed: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic on the loader thread while holding the lock cannot leave the counters
        // inconsistent with the cache in a way that matters more than stopping would.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Reads a [`LevelBackend`]'s stored bricks (a [`super::LevelStore`] file, an OME-Zarr pyramid)
/// on a background thread into a RAM cache with a byte budget (module docs for the policy).
/// Used by `VolumeSource::LevelStream`.
pub struct LevelStreamer {
    backend: Arc<dyn LevelBackend>,
    shared: Arc<Shared>,
    loaders: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for LevelStreamer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LevelStreamer")
            .field("backend", &self.backend.name())
            .field("stats", &self.stats())
            .finish()
    }
}

impl LevelStreamer {
    /// Starts a loader thread over `backend`. Errors: the thread cannot be spawned
    /// ([`StoreError::Thread`]).
    pub fn new(
        backend: Arc<dyn LevelBackend>,
        config: LevelStreamConfig,
    ) -> Result<Self, StoreError> {
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                budget: config.ram_budget_bytes,
                idle: true,
                ..State::default()
            }),
            changed: Condvar::new(),
        });
        let mut streamer = Self {
            backend,
            shared,
            loaders: Vec::new(),
        };
        for i in 0..config.loaders.max(1) {
            let backend = streamer.backend.clone();
            let shared = streamer.shared.clone();
            // On failure the streamer drops here and joins the loaders already started.
            let loader = std::thread::Builder::new()
                .name(format!("mixvol-level-streamer-{i}"))
                .spawn(move || load_loop(&*backend, &shared))
                .map_err(StoreError::Thread)?;
            streamer.loaders.push(loader);
        }
        Ok(streamer)
    }

    /// What the stored bricks are read from.
    pub fn backend(&self) -> &Arc<dyn LevelBackend> {
        &self.backend
    }

    /// Replaces the wanted set with `wanted`, highest priority first. Bricks no longer wanted
    /// stay cached until their room is needed. Never blocks on the disk.
    pub fn request(&self, wanted: &[StoredKey]) {
        let mut s = self.shared.lock();
        let old_rank = std::mem::take(&mut s.rank);
        let mut order = Vec::with_capacity(wanted.len());
        let mut rank = HashMap::with_capacity(wanted.len());
        for &key in wanted {
            if let std::collections::hash_map::Entry::Vacant(e) = rank.entry(key) {
                e.insert(order.len());
                order.push(key);
            }
        }
        // Rebuild the eviction orders for the new ranks.
        let mut wanted_cached = BTreeSet::new();
        let mut lru = std::mem::take(&mut s.unwanted_lru);
        for (key, (_, tick)) in &s.cache {
            match rank.get(key) {
                Some(&r) => {
                    if !old_rank.contains_key(key) {
                        lru.remove(tick);
                    }
                    wanted_cached.insert(r);
                }
                None => {
                    if old_rank.contains_key(key) {
                        lru.insert(*tick, *key);
                    }
                }
            }
        }
        s.unwanted_lru = lru;
        s.wanted_cached = wanted_cached;
        s.wanted = order;
        s.rank = rank;
        s.cursor = 0;
        s.idle = false;
        drop(s);
        self.shared.changed.notify_all();
    }

    /// The bytes of a cached stored brick (texels of the backend's scalar type, as
    /// [`LevelBackend::read_stored_bytes`] returns them), `Some(Err)` if its read failed,
    /// `None` if it is not in RAM. Never blocks on the disk.
    pub fn get(&self, key: StoredKey) -> Option<Result<Arc<[u8]>, Arc<StoreError>>> {
        let mut s = self.shared.lock();
        if let Some(e) = s.failed.get(&key) {
            return Some(Err(e.clone()));
        }
        let bytes = s.cache.get(&key)?.0.clone();
        s.touch(key);
        Some(Ok(bytes))
    }

    /// Whether the stored brick is in RAM.
    pub fn is_ready(&self, key: StoredKey) -> bool {
        self.shared.lock().cache.contains_key(&key)
    }

    /// The stored brick's bytes from RAM, else read now on this thread (counted in
    /// [`LevelStreamStats::blocking_reads`]; not cached). A brick whose background read failed
    /// returns that error.
    pub fn read_now(&self, key: StoredKey) -> Result<Arc<[u8]>, StoreError> {
        match self.get(key) {
            Some(Ok(bytes)) => return Ok(bytes),
            Some(Err(source)) => {
                return Err(StoreError::EarlierReadFailed {
                    level: key.0,
                    first: key.1,
                    source,
                })
            }
            None => {}
        }
        self.shared.lock().stats.blocking_reads += 1;
        let brick = self.backend.grid().brick_coords(key.1);
        Ok(self.backend.read_stored_bytes(key.0, brick)?.into())
    }

    /// Changes the RAM budget; a lower one evicts at once (unwanted bricks first, then wanted
    /// ones from the lowest priority up).
    pub fn set_ram_budget(&self, bytes: usize) {
        let mut s = self.shared.lock();
        s.budget = bytes;
        s.make_room(0, 0);
        s.cursor = 0;
        s.idle = false;
        drop(s);
        self.shared.changed.notify_all();
    }

    /// Forgets failed reads, so that they are tried again.
    pub fn clear_failures(&self) {
        let mut s = self.shared.lock();
        s.failed.clear();
        s.cursor = 0;
        s.idle = false;
        drop(s);
        self.shared.changed.notify_all();
    }

    /// Waits until the loader has nothing it may read (every wanted brick cached or failed, or
    /// the next one does not fit the budget), at most `timeout`. Returns whether it got there.
    pub fn wait_idle(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut s = self.shared.lock();
        while !s.idle {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            s = self
                .shared
                .changed
                .wait_timeout(s, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        true
    }

    /// The counters now.
    pub fn stats(&self) -> LevelStreamStats {
        let s = self.shared.lock();
        LevelStreamStats {
            ram_budget_bytes: s.budget,
            resident_bytes: s.resident_bytes + s.in_flight,
            resident_bricks: s.cache.len(),
            wanted_bricks: s.wanted.len(),
            wanted_resident: s.wanted_cached.len(),
            failures: s.failed.len(),
            ..s.stats.clone()
        }
    }

    /// The first failed read's error, if any (for messages).
    pub fn first_failure(&self) -> Option<Arc<StoreError>> {
        self.shared.lock().failed.values().next().cloned()
    }

    /// The stored bricks whose read failed (until [`LevelStreamer::clear_failures`]).
    pub fn failed_keys(&self) -> Vec<StoredKey> {
        self.shared.lock().failed.keys().copied().collect()
    }

    /// The stored bricks of `keys` that are not in RAM (for tests and reports).
    pub fn missing(&self, keys: &[StoredKey]) -> HashSet<StoredKey> {
        let s = self.shared.lock();
        keys.iter()
            .filter(|k| !s.cache.contains_key(k))
            .copied()
            .collect()
    }
}

impl Drop for LevelStreamer {
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.changed.notify_all();
        for loader in self.loaders.drain(..) {
            // A loader that panicked has nothing left to clean up.
            let _ = loader.join();
        }
    }
}

/// A loader thread: reads the next wanted brick (in priority order, not cached, failed or being
/// read by another loader) while it fits the budget.
fn load_loop(backend: &dyn LevelBackend, shared: &Shared) {
    let grid = backend.grid();
    let mut s = shared.lock();
    loop {
        if s.stop {
            return;
        }
        // Every wanted brick before the cursor is cached or failed.
        while s.cursor < s.wanted.len() {
            let key = s.wanted[s.cursor];
            if s.cache.contains_key(&key) || s.failed.contains_key(&key) {
                s.cursor += 1;
            } else {
                break;
            }
        }
        // The first one after it that no loader reads yet.
        let rank = (s.cursor..s.wanted.len()).find(|&r| {
            let key = s.wanted[r];
            !s.cache.contains_key(&key) && !s.failed.contains_key(&key) && !s.reading.contains(&key)
        });
        let fits = rank.is_some_and(|r| {
            let bytes = backend.stored_bytes(s.wanted[r].0);
            s.make_room(bytes, r)
        });
        let Some(key) = rank.filter(|_| fits).map(|r| s.wanted[r]) else {
            if s.reading.is_empty() {
                s.idle = true;
                shared.changed.notify_all();
            }
            s = shared.changed.wait(s).unwrap_or_else(|e| e.into_inner());
            continue;
        };
        let bytes = backend.stored_bytes(key.0);
        s.in_flight += bytes;
        s.reading.insert(key);
        s.stats.peak_bytes = s.stats.peak_bytes.max(s.resident_bytes + s.in_flight);
        drop(s);
        let start = Instant::now();
        let read = backend.read_stored_bytes(key.0, grid.brick_coords(key.1));
        let took = start.elapsed();
        s = shared.lock();
        s.in_flight -= bytes;
        s.reading.remove(&key);
        s.stats.read_time += took;
        match read {
            Ok(data) => {
                s.stats.loads += 1;
                s.stats.bytes_read += data.len() as u64;
                s.resident_bytes += data.len();
                s.tick += 1;
                let tick = s.tick;
                match s.rank.get(&key).copied() {
                    Some(r) => {
                        s.wanted_cached.insert(r);
                    }
                    None => {
                        s.unwanted_lru.insert(tick, key);
                    }
                }
                s.cache.insert(key, (data.into(), tick));
            }
            Err(e) => {
                s.failed.insert(key, Arc::new(e));
            }
        }
        // Others may wait for this read (the idle waiters, a loader short of room).
        shared.changed.notify_all();
    }
}
