//! [`ChunkCache`]: decoded Zarr chunks in RAM under a byte budget (least recently used evicted
//! first), fetched concurrently (bounded) when missing, with failed chunks remembered.

use super::StreamError;
use crate::volume::formats::{ZarrChunk, ZarrChunks};
use crate::volume::VolumeError;
use glam::UVec3;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

/// Counters of a [`ChunkCache`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChunkCacheStats {
    /// The budget, decoded bytes.
    pub budget_bytes: usize,
    /// Decoded bytes of the cached chunks.
    pub resident_bytes: usize,
    /// Largest `resident_bytes` reached.
    pub peak_bytes: usize,
    /// Cached chunks.
    pub resident_chunks: usize,
    /// Chunk look-ups answered from the cache.
    pub hits: u64,
    /// Chunks read from the source (missing ones, the fill value, included).
    pub fetches: u64,
    /// Of those, chunks that do not exist (read as the fill value, no bytes fetched).
    pub absent_chunks: u64,
    /// Chunks evicted.
    pub evictions: u64,
    /// Chunks whose fetch or decode failed (remembered, not fetched again).
    pub failed_chunks: usize,
}

#[derive(Default)]
struct State {
    map: HashMap<[u32; 3], (Arc<ZarrChunk>, u64)>,
    lru: BTreeMap<u64, [u32; 3]>,
    failed: HashMap<[u32; 3], Arc<VolumeError>>,
    tick: u64,
    stats: ChunkCacheStats,
}

impl State {
    fn touch(&mut self, key: [u32; 3]) -> Option<Arc<ZarrChunk>> {
        let tick = self.tick + 1;
        let (chunk, old) = self.map.get_mut(&key)?;
        let chunk = chunk.clone();
        self.lru.remove(old);
        *old = tick;
        self.tick = tick;
        self.lru.insert(tick, key);
        Some(chunk)
    }

    fn insert(&mut self, key: [u32; 3], chunk: Arc<ZarrChunk>) {
        let bytes = chunk.decoded_bytes();
        let budget = self.stats.budget_bytes;
        // Room first (least recently used out); a chunk larger than the whole budget is not kept.
        while self.stats.resident_bytes + bytes > budget {
            let Some((_, victim)) = self.lru.pop_first() else {
                break;
            };
            if let Some((c, _)) = self.map.remove(&victim) {
                self.stats.resident_bytes -= c.decoded_bytes();
                self.stats.evictions += 1;
            }
        }
        if self.stats.resident_bytes + bytes > budget {
            return;
        }
        self.tick += 1;
        self.lru.insert(self.tick, key);
        self.map.insert(key, (chunk, self.tick));
        self.stats.resident_bytes += bytes;
        self.stats.peak_bytes = self.stats.peak_bytes.max(self.stats.resident_bytes);
    }
}

/// Decoded chunks under a RAM budget. The chunks one call of [`ChunkCache::get_many`] returns
/// are held by the caller (`Arc`) until it drops them, so at most the budget plus the chunks of
/// one brick window are in RAM.
pub struct ChunkCache {
    state: Mutex<State>,
    concurrency: usize,
}

impl ChunkCache {
    /// An empty cache of `budget_bytes` decoded bytes, fetching at most `concurrency` chunks at
    /// once (at least 1).
    pub fn new(budget_bytes: usize, concurrency: usize) -> Self {
        let state = State {
            stats: ChunkCacheStats {
                budget_bytes,
                ..ChunkCacheStats::default()
            },
            ..State::default()
        };
        Self {
            state: Mutex::new(state),
            concurrency: concurrency.max(1),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> ChunkCacheStats {
        let state = self.lock();
        ChunkCacheStats {
            resident_chunks: state.map.len(),
            failed_chunks: state.failed.len(),
            ..state.stats.clone()
        }
    }

    /// Forgets the failed chunks (they are fetched again when next needed).
    pub fn clear_failures(&self) {
        self.lock().failed.clear();
    }

    /// The chunks `wanted` (chunk coordinates), in that order: cached ones at once, the others
    /// fetched from `source` by at most `concurrency` threads at once. The first chunk (in
    /// `wanted` order) that failed, now or before, is a [`StreamError::Chunk`] naming it.
    pub fn get_many(
        &self,
        source: &ZarrChunks,
        wanted: &[UVec3],
    ) -> Result<Vec<Arc<ZarrChunk>>, StreamError> {
        self.get_each(source, wanted).into_iter().collect()
    }

    /// Like [`ChunkCache::get_many`], but one result per chunk of `wanted`: every chunk that
    /// failed (now or before) is its own [`StreamError::Chunk`], and the others are returned
    /// (a chunk known to have failed is not fetched again; the others all are).
    pub fn get_each(
        &self,
        source: &ZarrChunks,
        wanted: &[UVec3],
    ) -> Vec<Result<Arc<ZarrChunk>, StreamError>> {
        let mut got: Vec<Option<Result<Arc<ZarrChunk>, StreamError>>> =
            (0..wanted.len()).map(|_| None).collect();
        let mut missing = Vec::new();
        {
            let mut state = self.lock();
            for (i, c) in wanted.iter().enumerate() {
                let key = c.to_array();
                if let Some(e) = state.failed.get(&key) {
                    got[i] = Some(Err(chunk_error(source, *c, e.clone())));
                    continue;
                }
                match state.touch(key) {
                    Some(chunk) => {
                        state.stats.hits += 1;
                        got[i] = Some(Ok(chunk));
                    }
                    None => missing.push(i),
                }
            }
        }
        let results = fetch_concurrently(source, wanted, &missing, self.concurrency);
        {
            let mut state = self.lock();
            for (&i, result) in missing.iter().zip(results) {
                let key = wanted[i].to_array();
                got[i] = Some(match result {
                    Ok(chunk) => {
                        state.stats.fetches += 1;
                        if chunk.stored_bytes == 0 {
                            state.stats.absent_chunks += 1;
                        }
                        let chunk = Arc::new(chunk);
                        state.insert(key, chunk.clone());
                        Ok(chunk)
                    }
                    Err(e) => {
                        let e = Arc::new(e);
                        state.failed.insert(key, e.clone());
                        Err(chunk_error(source, wanted[i], e))
                    }
                });
            }
        }
        got.into_iter()
            .zip(wanted)
            .map(|(r, c)| {
                r.unwrap_or_else(|| {
                    Err(chunk_error(
                        source,
                        *c,
                        Arc::new(VolumeError::InvalidParameter(
                            "a chunk was neither cached nor fetched".into(),
                        )),
                    ))
                })
            })
            .collect()
    }
}

/// The typed error of a failed chunk.
fn chunk_error(source: &ZarrChunks, chunk: UVec3, e: Arc<VolumeError>) -> StreamError {
    StreamError::Chunk {
        chunk: chunk.to_array(),
        object: source.chunk_name(chunk).display().to_string(),
        source: e,
    }
}

/// Reads `wanted[i]` for every `i` in `which` on up to `concurrency` scoped threads (the caller's
/// thread alone when one is enough); results in `which` order.
pub(super) fn fetch_concurrently(
    source: &ZarrChunks,
    wanted: &[UVec3],
    which: &[usize],
    concurrency: usize,
) -> Vec<Result<ZarrChunk, VolumeError>> {
    let workers = concurrency.max(1).min(which.len());
    if workers <= 1 {
        return which
            .iter()
            .map(|&i| source.read_chunk(wanted[i]))
            .collect();
    }
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<Result<ZarrChunk, VolumeError>>>> =
        which.iter().map(|_| Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(&i) = which.get(k) else {
                    break;
                };
                let result = source.read_chunk(wanted[i]);
                *slots[k].lock().unwrap_or_else(|p| p.into_inner()) = Some(result);
            });
        }
    });
    slots
        .into_iter()
        .map(|s| {
            s.into_inner()
                .unwrap_or_else(|p| p.into_inner())
                .unwrap_or_else(|| {
                    Err(VolumeError::InvalidParameter(
                        "a chunk fetch thread stopped".into(),
                    ))
                })
        })
        .collect()
}
