//! Background streaming of brick levels from a [`BrickStore`] (or any [`BrickBackend`], e.g. an
//! OME-Zarr image: `stream::ZarrBricks`) into a RAM cache with a byte budget.
//!
//! # Policy
//!
//! - **Wanted set.** [`BrickStreamer::request`] replaces the wanted set with a list of
//!   `(brick, level, priority)`, ordered by descending priority (stable: equal priorities keep the
//!   caller's order; NaN counts as lowest; duplicates keep their highest priority). The caller
//!   computes the priority (LOD error, tie-broken by distance; [`crate::bricks::request_plan`] builds a
//!   request from wanted levels). It never blocks on disk: it only takes a short lock.
//! - **Loading.** One background thread loads the wanted levels that are not in RAM, strictly in
//!   priority order, one positioned read each, without holding the lock during the read.
//! - **Budget.** The bytes of all cached levels plus the one being read never exceed the RAM
//!   budget ([`StreamerConfig::ram_budget_bytes`]; texel bytes, per-entry bookkeeping of a few
//!   dozen bytes is not counted). Before a read the loader reserves its bytes, evicting:
//!   1. cached levels that are *not wanted*, least recently used first (a level is used when it
//!      is loaded and whenever [`BrickSource::brick_bytes`] returns it);
//!   2. then, only if that is not enough, wanted levels of *lower priority* than the one to load,
//!      lowest priority first.
//!
//!   Wanted levels of higher priority are never evicted for a load. If the next level cannot be
//!   made to fit, the loader stops there (it does not skip ahead to smaller, lower-priority
//!   levels) until the next request, budget change or [`BrickStreamer::clear_failures`]: the
//!   result is that the highest-priority prefix of the wanted set that fits the budget is
//!   resident, and it stays resident (no thrashing) while the request is unchanged. Levels that
//!   stop being wanted stay cached (and can be returned) until their room is needed.
//! - **Pins.** A level that [`BrickSource::brick_bytes`] or [`BrickSource::is_loaded`] reported
//!   present stays cached until the next [`BrickStreamer::request`] (which releases all pins;
//!   an unchanged request too). So within a frame — request, then
//!   [`fallback_levels`](crate::bricks::fallback_levels), then the cache update and its uploads — every
//!   level the fallback chose still has its bytes when the upload asks for them. Pinned levels
//!   count against the budget like any other; the loader waits rather than evict them.
//!   [`BrickSource::loaded_levels`] (one call for every brick, what the residency planner asks
//!   each frame) holds every cached level so, until the next request, without pinning each.
//! - **Lowering the budget** ([`BrickStreamer::set_ram_budget`]) evicts at once, in the same
//!   order and then pinned levels too; only a read already in flight can then push the total over
//!   the new budget, once.
//! - **Failures.** A level whose read fails is not retried: [`BrickSource::brick_bytes`] returns
//!   [`SourceError::Load`] for it until [`BrickStreamer::clear_failures`].
//! - **Shutdown.** Dropping the streamer stops the loader (after the read in flight, if any) and
//!   joins it.
//!
//! Bytes handed out are `Arc<[u8]>` clones: a level evicted while a caller still holds its `Arc`
//! stays allocated until the caller drops it (the budget counts the cache's own references).

use super::{BrickBackend, BrickStore, StoreError};
use crate::bricks::{
    BrickGrid, BrickSource, DownsampleFilter, Level, LoadedLevels, SourceError, ValueRange,
};
use crate::volume::ScalarType;
use glam::Vec3;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A brick level: `(linear brick index, level)`.
type Key = (u32, Level);

/// How a [`BrickStreamer`] runs.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct StreamerConfig {
    /// Most bytes of brick texels held in RAM (cached levels plus the read in flight).
    pub ram_budget_bytes: usize,
    /// Record every completed load in order (see [`BrickStreamer::loaded_order`]); for tests and
    /// diagnostics, the record grows with every load.
    pub record_load_order: bool,
}

impl Default for StreamerConfig {
    fn default() -> Self {
        Self {
            ram_budget_bytes: 512 << 20,
            record_load_order: false,
        }
    }
}

/// A snapshot of the streamer's counters.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StreamStats {
    /// The current RAM budget.
    pub ram_budget_bytes: usize,
    /// Bytes of cached levels plus the read in flight.
    pub resident_bytes: usize,
    /// Largest `resident_bytes` ever reached.
    pub peak_bytes: usize,
    /// Cached levels.
    pub resident_levels: usize,
    /// Levels in the wanted set.
    pub wanted_levels: usize,
    /// Wanted levels that are cached.
    pub wanted_resident: usize,
    /// Completed loads.
    pub loads: u64,
    /// Levels evicted to make room.
    pub evictions: u64,
    /// Bytes read from the store.
    pub bytes_read: u64,
    /// Time spent in reads.
    pub read_time: Duration,
    /// Levels whose read failed.
    pub failures: usize,
}

/// A cached level.
struct Entry {
    bytes: Arc<[u8]>,
    /// Last use, for the LRU order of unwanted levels.
    tick: u64,
    /// Returned to a caller since the latest request: not evictable until the next one.
    pinned: bool,
}

/// Everything behind the lock.
///
/// Cached levels are partitioned into three groups, so that choosing a victim and checking
/// whether a level can be made to fit cost `O(log n)` per evicted level:
/// - `pinned`: returned by [`BrickSource::brick_bytes`] / [`BrickSource::is_loaded`] since the
///   latest request (never evicted for a load);
/// - `wanted_free`: unpinned wanted levels, by rank;
/// - `unwanted_lru`: unpinned unwanted levels, by last use.
struct State {
    /// Wanted levels in priority order.
    wanted: Vec<Key>,
    /// Position of each wanted level in `wanted`.
    rank: HashMap<Key, usize>,
    /// Every wanted level before `cursor` is cached or failed.
    cursor: usize,
    cache: HashMap<Key, Entry>,
    /// Ranks of the unpinned cached wanted levels.
    wanted_free: BTreeSet<usize>,
    /// Unpinned cached unwanted levels by last use.
    unwanted_lru: BTreeMap<u64, Key>,
    /// Bytes of the levels in `unwanted_lru`.
    unwanted_free_bytes: usize,
    /// Pinned cached levels.
    pinned: Vec<Key>,
    /// Every cached level is held (as if pinned) until the next request: set when
    /// [`BrickSource::loaded_levels`] reported them.
    all_held: bool,
    tick: u64,
    /// Bytes of cached levels plus the read in flight.
    used: usize,
    peak: usize,
    budget: usize,
    in_flight: Option<Key>,
    failed: HashMap<Key, Arc<dyn std::error::Error + Send + Sync>>,
    shutdown: bool,
    loads: u64,
    evictions: u64,
    bytes_read: u64,
    read_time: Duration,
    order: Option<Vec<Key>>,
}

impl State {
    fn new(budget: usize, record: bool) -> Self {
        Self {
            wanted: Vec::new(),
            rank: HashMap::new(),
            cursor: 0,
            cache: HashMap::new(),
            wanted_free: BTreeSet::new(),
            unwanted_lru: BTreeMap::new(),
            unwanted_free_bytes: 0,
            pinned: Vec::new(),
            all_held: false,
            tick: 0,
            used: 0,
            peak: 0,
            budget,
            in_flight: None,
            failed: HashMap::new(),
            shutdown: false,
            loads: 0,
            evictions: 0,
            bytes_read: 0,
            read_time: Duration::ZERO,
            order: record.then(Vec::new),
        }
    }

    /// Puts an unpinned cached level into its free group.
    fn file_free(&mut self, key: Key) {
        let entry = &self.cache[&key];
        match self.rank.get(&key) {
            Some(&r) => {
                self.wanted_free.insert(r);
            }
            None => {
                self.unwanted_lru.insert(entry.tick, key);
                self.unwanted_free_bytes += entry.bytes.len();
            }
        }
    }

    /// Takes an unpinned cached level out of its free group.
    fn unfile_free(&mut self, key: Key) {
        let entry = &self.cache[&key];
        match self.rank.get(&key) {
            Some(r) => {
                self.wanted_free.remove(r);
            }
            None => {
                self.unwanted_lru.remove(&entry.tick);
                self.unwanted_free_bytes -= entry.bytes.len();
            }
        }
    }

    /// Releases every pin (a new request starts a new frame).
    fn unpin_all(&mut self) {
        self.all_held = false;
        for key in std::mem::take(&mut self.pinned) {
            if let Some(entry) = self.cache.get_mut(&key) {
                entry.pinned = false;
                self.file_free(key);
            }
        }
    }

    /// Installs a new wanted set and re-files the cache; returns the old set (to drop unlocked).
    fn set_wanted(
        &mut self,
        wanted: Vec<Key>,
        rank: HashMap<Key, usize>,
    ) -> (Vec<Key>, HashMap<Key, usize>) {
        self.unpin_all();
        let old = (
            std::mem::replace(&mut self.wanted, wanted),
            std::mem::replace(&mut self.rank, rank),
        );
        self.cursor = 0;
        self.wanted_free.clear();
        self.unwanted_lru.clear();
        self.unwanted_free_bytes = 0;
        let keys: Vec<Key> = self.cache.keys().copied().collect();
        for key in keys {
            self.file_free(key);
        }
        old
    }

    /// Marks `key` used now, pins it until the next request and returns its bytes.
    fn touch(&mut self, key: Key) -> Option<Arc<[u8]>> {
        let pinned = self.cache.get(&key)?.pinned;
        if !pinned {
            self.unfile_free(key);
            self.pinned.push(key);
        }
        self.tick += 1;
        let entry = self.cache.get_mut(&key)?;
        entry.tick = self.tick;
        entry.pinned = true;
        Some(entry.bytes.clone())
    }

    fn insert(&mut self, key: Key, bytes: Arc<[u8]>) {
        self.tick += 1;
        let old = self.cache.insert(
            key,
            Entry {
                bytes,
                tick: self.tick,
                pinned: false,
            },
        );
        debug_assert!(old.is_none(), "a level is loaded once");
        self.file_free(key);
    }

    fn evict(&mut self, key: Key) {
        let Some(entry) = self.cache.get(&key) else {
            return;
        };
        if entry.pinned {
            self.pinned.retain(|k| *k != key);
        } else {
            self.unfile_free(key);
        }
        if let Some(entry) = self.cache.remove(&key) {
            self.used -= entry.bytes.len();
            self.evictions += 1;
        }
    }

    /// The next victim for a load of rank `rank`: the least recently used unpinned unwanted
    /// level, else the lowest-priority unpinned wanted level ranked after `rank` (`None` allows
    /// unwanted levels only).
    fn victim(&self, rank: Option<usize>) -> Option<Key> {
        if self.all_held {
            return None;
        }
        if let Some((_, &key)) = self.unwanted_lru.first_key_value() {
            return Some(key);
        }
        let r = *self.wanted_free.range(rank? + 1..).next_back()?;
        Some(self.wanted[r])
    }

    /// True when `extra` more bytes can be made to fit by evicting [`State::victim`]s.
    fn can_fit(&self, extra: usize, rank: usize) -> bool {
        if extra > self.budget {
            return false;
        }
        if self.all_held {
            return self.used + extra <= self.budget;
        }
        if self.used + extra <= self.budget + self.unwanted_free_bytes {
            return true;
        }
        let mut deficit = self.used + extra - self.budget - self.unwanted_free_bytes;
        // Lowest priority first, exactly the order make_room evicts in: stops as soon as enough.
        for &r in self.wanted_free.range(rank + 1..).rev() {
            let len = self.cache[&self.wanted[r]].bytes.len();
            match deficit.checked_sub(len) {
                Some(0) | None => return true,
                Some(rest) => deficit = rest,
            }
        }
        false
    }

    /// Evicts (see [`State::victim`]) until `extra` more bytes fit the budget or nothing is left
    /// to evict; true when they fit.
    fn make_room(&mut self, extra: usize, rank: Option<usize>) -> bool {
        while self.used + extra > self.budget {
            match self.victim(rank) {
                Some(key) => self.evict(key),
                None => return false,
            }
        }
        true
    }

    /// The next wanted level to load (always the one at `cursor`), if it can be made to fit.
    fn next_job(&mut self, level_bytes: impl Fn(Level) -> usize) -> Option<(Key, usize)> {
        if self.in_flight.is_some() {
            return None;
        }
        while let Some(key) = self.wanted.get(self.cursor) {
            if self.cache.contains_key(key) || self.failed.contains_key(key) {
                self.cursor += 1;
            } else {
                break;
            }
        }
        let key = *self.wanted.get(self.cursor)?;
        let size = level_bytes(key.1);
        self.can_fit(size, self.cursor).then_some((key, size))
    }

    /// Cached wanted levels.
    fn wanted_resident(&self) -> usize {
        self.wanted_free.len()
            + self
                .pinned
                .iter()
                .filter(|k| self.rank.contains_key(k))
                .count()
    }
}

/// What the loader thread and the handle share.
struct Shared<B> {
    store: B,
    state: Mutex<State>,
    /// Signalled when there may be work (request, budget change, shutdown).
    work: Condvar,
    /// Signalled after every load and whenever the loader goes idle.
    progress: Condvar,
}

impl<B> Shared<B> {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Streams brick levels of a [`BrickStore`] on a background thread into a budgeted RAM cache, in
/// the priority order of the latest [`BrickStreamer::request`] (policy in the
/// [module docs](self)); a [`BrickSource`] whose [`BrickSource::brick_bytes`] never blocks.
pub struct BrickStreamer<B: BrickBackend = BrickStore> {
    shared: Arc<Shared<B>>,
    thread: Option<JoinHandle<()>>,
}

impl<B: BrickBackend> std::fmt::Debug for BrickStreamer<B> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BrickStreamer")
            .field("backend", &self.shared.store.name())
            .field("stats", &self.stats())
            .finish()
    }
}

impl BrickStreamer<BrickStore> {
    /// Opens the store at `path` and starts streaming from it.
    pub fn open(path: impl AsRef<Path>, config: StreamerConfig) -> Result<Self, StoreError> {
        Self::new(BrickStore::open(path)?, config)
    }
}

impl<B: BrickBackend> BrickStreamer<B> {
    /// Starts streaming from `store` (a [`BrickStore`] or another [`BrickBackend`]) with an empty
    /// wanted set.
    pub fn new(store: B, config: StreamerConfig) -> Result<Self, StoreError> {
        let shared = Arc::new(Shared {
            store,
            state: Mutex::new(State::new(
                config.ram_budget_bytes,
                config.record_load_order,
            )),
            work: Condvar::new(),
            progress: Condvar::new(),
        });
        let loader = shared.clone();
        let thread = std::thread::Builder::new()
            .name("mixvol-brick-loader".into())
            .spawn(move || load_loop(&loader))
            .map_err(StoreError::Thread)?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// The backend streamed from (the store).
    pub fn store(&self) -> &B {
        &self.shared.store
    }

    /// Replaces the wanted set with `wanted` (`(brick, level, priority)`, higher priority loads
    /// first; see the [module docs](self)). `Level::Absent` entries are ignored. Never blocks on
    /// disk. Errors (and changes nothing) when a brick index is outside the grid.
    pub fn request(&self, wanted: &[(u32, Level, f32)]) -> Result<(), StoreError> {
        let count = self.shared.store.grid().brick_count() as u32;
        if let Some(&(brick, ..)) = wanted.iter().find(|(b, ..)| *b >= count) {
            return Err(StoreError::BrickOutOfRange { brick, count });
        }
        let key_priority = |p: f32| if p.is_nan() { f32::NEG_INFINITY } else { p };
        let mut sorted: Vec<(u32, Level, f32)> = wanted
            .iter()
            .copied()
            .filter(|&(_, level, _)| level != Level::Absent)
            .collect();
        // A planner's list is in priority order already: only check that.
        let in_order = sorted
            .windows(2)
            .all(|w| key_priority(w[0].2) >= key_priority(w[1].2));
        if !in_order {
            sorted.sort_by(|a, b| key_priority(b.2).total_cmp(&key_priority(a.2)));
        }
        // The first of each (brick, level), marked in a bit per brick and level.
        let bit = |brick: u32, level: Level| brick as usize * 2 + usize::from(level == Level::Lo);
        let mut seen = vec![0u64; (count as usize * 2).div_ceil(64)];
        let mut order = Vec::with_capacity(sorted.len());
        for (brick, level, _) in sorted {
            let b = bit(brick, level);
            let (word, mask) = (b / 64, 1u64 << (b % 64));
            if seen[word] & mask == 0 {
                seen[word] |= mask;
                order.push((brick, level));
            }
        }
        let old = {
            let mut state = self.shared.lock();
            if state.wanted == order {
                // Unchanged (a renderer typically asks every frame): only release the pins.
                state.unpin_all();
                drop(state);
                self.shared.work.notify_all();
                return Ok(());
            }
            drop(state);
            // Ranked outside the lock.
            let rank: HashMap<Key, usize> =
                order.iter().enumerate().map(|(r, &k)| (k, r)).collect();
            self.shared.lock().set_wanted(order, rank)
        };
        self.shared.work.notify_all();
        drop(old);
        Ok(())
    }

    /// Changes the RAM budget; a lower budget evicts at once (see the [module docs](self)).
    pub fn set_ram_budget(&self, bytes: usize) {
        {
            let mut state = self.shared.lock();
            state.budget = bytes;
            state.cursor = 0;
            state.make_room(0, None);
            // Still over budget: give up wanted levels from the lowest priority up, then pinned
            // levels (the caller asked for less memory now).
            while state.used > state.budget {
                let key = match state.wanted_free.last() {
                    Some(&r) => state.wanted[r],
                    None => match state.pinned.last() {
                        Some(&key) => key,
                        None => break,
                    },
                };
                state.evict(key);
            }
        }
        self.shared.work.notify_all();
    }

    /// Forgets failed loads so that they are retried while wanted.
    pub fn clear_failures(&self) {
        {
            let mut state = self.shared.lock();
            state.failed.clear();
            state.cursor = 0;
        }
        self.shared.work.notify_all();
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> StreamStats {
        let state = self.shared.lock();
        StreamStats {
            ram_budget_bytes: state.budget,
            resident_bytes: state.used,
            peak_bytes: state.peak,
            resident_levels: state.cache.len(),
            wanted_levels: state.wanted.len(),
            wanted_resident: state.wanted_resident(),
            loads: state.loads,
            evictions: state.evictions,
            bytes_read: state.bytes_read,
            read_time: state.read_time,
            failures: state.failed.len(),
        }
    }

    /// Every completed load so far, in order, when [`StreamerConfig::record_load_order`] is set
    /// (empty otherwise).
    pub fn loaded_order(&self) -> Vec<(u32, Level)> {
        self.shared.lock().order.clone().unwrap_or_default()
    }

    /// The cached levels, in no particular order.
    pub fn resident(&self) -> Vec<(u32, Level)> {
        self.shared.lock().cache.keys().copied().collect()
    }

    /// True when the loader has nothing to do for the current request: every wanted level is
    /// cached or failed, or the next one does not fit the budget.
    pub fn is_settled(&self) -> bool {
        let store = &self.shared.store;
        let mut state = self.shared.lock();
        state.in_flight.is_none() && state.next_job(|l| store.level_bytes(l)).is_none()
    }

    /// Blocks until [`BrickStreamer::is_settled`] or `timeout`; true when settled. For tools and
    /// tests: a renderer never needs to wait.
    pub fn wait_settled(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let store = &self.shared.store;
        let mut state = self.shared.lock();
        loop {
            if state.in_flight.is_none() && state.next_job(|l| store.level_bytes(l)).is_none() {
                return true;
            }
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            state = self
                .shared
                .progress
                .wait_timeout(state, deadline - now)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }
}

impl<B: BrickBackend> BrickSource for BrickStreamer<B> {
    fn grid(&self) -> BrickGrid {
        self.shared.store.grid()
    }

    fn scalar(&self) -> ScalarType {
        self.shared.store.scalar()
    }

    fn filter(&self) -> DownsampleFilter {
        self.shared.store.filter()
    }

    fn spacing(&self) -> Vec3 {
        self.shared.store.spacing()
    }

    fn value_ranges(&self) -> &[ValueRange] {
        self.shared.store.value_ranges()
    }

    fn learned_value_ranges(&self) -> Option<Arc<[ValueRange]>> {
        self.shared.store.learned_value_ranges()
    }

    fn value_range(&self) -> ValueRange {
        self.shared.store.value_range()
    }

    fn brick_bytes(&self, brick: u32, level: Level) -> Result<Option<Arc<[u8]>>, SourceError> {
        let count = self.shared.store.grid().brick_count() as u32;
        if brick >= count {
            return Err(SourceError::BrickOutOfRange { brick, count });
        }
        if level == Level::Absent {
            return Err(SourceError::AbsentLevel { brick });
        }
        let mut state = self.shared.lock();
        if let Some(bytes) = state.touch((brick, level)) {
            return Ok(Some(bytes));
        }
        match state.failed.get(&(brick, level)) {
            Some(e) => Err(SourceError::Load {
                brick,
                level,
                source: e.clone(),
            }),
            None => Ok(None),
        }
    }

    fn is_loaded(&self, brick: u32, level: Level) -> bool {
        let mut state = self.shared.lock();
        state.touch((brick, level)).is_some()
    }

    /// One lock for every brick (rather than one [`BrickSource::is_loaded`] call, lock and pin
    /// per brick and level): every cached level is held until the next request.
    fn loaded_levels(&self, loaded: &mut Vec<LoadedLevels>) {
        let count = self.shared.store.grid().brick_count();
        loaded.clear();
        loaded.resize(count, LoadedLevels::NONE);
        let mut state = self.shared.lock();
        state.all_held = true;
        for &(brick, level) in state.cache.keys() {
            if let Some(l) = loaded.get_mut(brick as usize) {
                *l = l.with(level, true);
            }
        }
    }

    fn request_levels(&self, requests: &[(u32, Level, f32)]) -> Result<(), SourceError> {
        self.request(requests).map_err(|e| match e {
            StoreError::BrickOutOfRange { brick, count } => {
                SourceError::BrickOutOfRange { brick, count }
            }
            other => SourceError::InvalidInput {
                field: "requests",
                message: other.to_string(),
            },
        })
    }
}

impl<B: BrickBackend> Drop for BrickStreamer<B> {
    fn drop(&mut self) {
        self.shared.lock().shutdown = true;
        self.shared.work.notify_all();
        if let Some(thread) = self.thread.take() {
            // A panicked loader has nothing left to clean up.
            let _ = thread.join();
        }
    }
}

/// The loader thread: pick the next level under the lock, read it without the lock, insert it.
fn load_loop<B: BrickBackend>(shared: &Shared<B>) {
    let store = &shared.store;
    let mut state = shared.lock();
    loop {
        if state.shutdown {
            return;
        }
        let Some((key, size)) = state.next_job(|l| store.level_bytes(l)) else {
            shared.progress.notify_all();
            state = shared.work.wait(state).unwrap_or_else(|p| p.into_inner());
            continue;
        };
        let rank = state.cursor;
        if !state.make_room(size, Some(rank)) {
            // Unreachable (next_job checked the same victims); never exceed the budget anyway.
            debug_assert!(false, "next_job checked that the level fits");
            state = shared.work.wait(state).unwrap_or_else(|p| p.into_inner());
            continue;
        }
        state.used += size;
        state.peak = state.peak.max(state.used);
        state.in_flight = Some(key);
        drop(state);

        let start = Instant::now();
        let result = read_shared(store, key);
        let elapsed = start.elapsed();

        state = shared.lock();
        state.in_flight = None;
        state.read_time += elapsed;
        match result {
            Ok(bytes) => {
                state.loads += 1;
                state.bytes_read += size as u64;
                if let Some(order) = &mut state.order {
                    order.push(key);
                }
                state.insert(key, bytes);
                // Only a budget lowered during the read can leave us over it.
                if state.used > state.budget {
                    state.make_room(0, None);
                }
            }
            Err(e) => {
                state.used -= size;
                log::warn!("{}: {e}", store.name());
                state.failed.insert(key, Arc::new(e));
            }
        }
        shared.progress.notify_all();
    }
}

/// Reads one level into a freshly allocated shared buffer (one allocation, no copy).
fn read_shared<B: BrickBackend>(store: &B, (brick, level): Key) -> Result<Arc<[u8]>, B::Error> {
    let mut bytes: Arc<[u8]> = std::iter::repeat_n(0u8, store.level_bytes(level)).collect();
    let buffer = Arc::get_mut(&mut bytes).expect("a fresh Arc is unique");
    store.read_brick_into(brick, level, buffer)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(len: usize) -> Arc<[u8]> {
        vec![0u8; len].into()
    }

    /// A state with `keys` cached (100 bytes each) and wanted in that order.
    fn state_with(budget: usize, keys: &[Key]) -> State {
        let mut state = State::new(budget, false);
        for &key in keys {
            state.insert(key, bytes(100));
            state.used += 100;
        }
        let rank = keys.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        state.set_wanted(keys.to_vec(), rank);
        state
    }

    #[test]
    fn pinned_levels_are_not_evicted_until_the_next_request() {
        let keys: Vec<Key> = (0..4).map(|b| (b, Level::Hi)).collect();
        let mut state = state_with(400, &keys);
        // A new top-priority level wants room: the lowest-priority wanted level (3) would go, but
        // the renderer just used it.
        let mut wanted = vec![(9, Level::Hi)];
        wanted.extend(&keys);
        let rank = wanted.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        state.set_wanted(wanted.clone(), rank);
        assert!(state.touch((3, Level::Hi)).is_some());
        assert_eq!(state.victim(Some(0)), Some((2, Level::Hi)));
        assert!(state.can_fit(100, 0));
        // With 1 and 2 pinned as well, only 0 is left... which is ranked above nothing: it goes.
        state.touch((1, Level::Hi));
        state.touch((2, Level::Hi));
        assert_eq!(state.victim(Some(0)), Some((0, Level::Hi)));
        state.touch((0, Level::Hi));
        assert_eq!(state.victim(Some(0)), None);
        assert!(!state.can_fit(100, 0));
        assert_eq!(
            state.next_job(|_| 100),
            None,
            "waits instead of evicting pins"
        );
        // The next request releases the pins.
        state.unpin_all();
        assert_eq!(state.next_job(|_| 100), Some(((9, Level::Hi), 100)));
        assert!(state.make_room(100, Some(0)));
        assert!(!state.cache.contains_key(&(3, Level::Hi)));
    }

    #[test]
    fn levels_reported_loaded_are_held_until_the_next_request() {
        let keys: Vec<Key> = (0..4).map(|b| (b, Level::Lo)).collect();
        let mut state = state_with(400, &keys);
        state.touch((0, Level::Lo));
        state.unpin_all();
        let mut wanted = vec![(9, Level::Hi)];
        wanted.extend(&keys[..2]);
        let rank = wanted.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        state.set_wanted(wanted, rank);
        // Unheld, 3 (unwanted, least recently used) would make room for the new level.
        assert_eq!(state.victim(Some(0)), Some((2, Level::Lo)));
        assert!(state.can_fit(100, 0));
        // Reported loaded (what `loaded_levels` does): nothing goes until the next request.
        state.all_held = true;
        assert_eq!(state.victim(Some(0)), None);
        assert!(!state.can_fit(100, 0));
        assert!(!state.make_room(100, Some(0)));
        assert_eq!(state.next_job(|_| 100), None, "waits instead of evicting");
        assert_eq!(state.cache.len(), 4);
        state.unpin_all();
        assert_eq!(state.next_job(|_| 100), Some(((9, Level::Hi), 100)));
        assert!(state.make_room(100, Some(0)));
        assert_eq!(state.cache.len(), 3);
    }

    #[test]
    fn unwanted_levels_go_first_in_lru_order_and_feasibility_matches_eviction() {
        let keys: Vec<Key> = (0..6).map(|b| (b, Level::Lo)).collect();
        let mut state = state_with(600, &keys);
        state.touch((0, Level::Lo));
        state.touch((1, Level::Lo));
        state.unpin_all();
        // Only 4 and 5 stay wanted; 2, 3 are older than 0, 1.
        let wanted = vec![(5, Level::Lo), (4, Level::Lo), (7, Level::Lo)];
        let rank = wanted.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        state.set_wanted(wanted, rank);
        let mut order = Vec::new();
        while let Some(key) = state.victim(Some(2)) {
            order.push(key.0);
            state.evict(key);
        }
        assert_eq!(order, vec![2, 3, 0, 1]);
        assert_eq!(state.used, 200);
        assert!(state.can_fit(400, 2));
        assert!(!state.can_fit(401, 2));
        assert!(!state.can_fit(601, 2));
    }
}
