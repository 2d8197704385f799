//! The preprocessed on-disk brick store and background brick streaming (out-of-core rendering).
//!
//! A volume too large for RAM (or for the GPU brick cache) is preprocessed once into a single
//! versioned file ([`format`](mod@format), documented byte by byte in `docs/brick-store.md`)
//! that holds, per brick, the packed hi-res brick (`(n+2)^3` texels with the duplicated border),
//! the packed low-res brick (`(n/2+1)^3` texels) in the storage format, and the conservative
//! per-brick min/max. At render time only the bricks the renderer currently wants are in RAM:
//!
//! - [`write_store`] builds the file from a *voxel producer* (`sample(voxel) -> f32`) on all cores
//!   with bounded memory: no step ever needs the whole volume in RAM. [`write_store_from_volume`]
//!   does the same for an in-memory [`Volume`](crate::volume::Volume); its bytes are identical to
//!   [`pack_hi_res_brick`](crate::bricks::pack_hi_res_brick) /
//!   [`pack_low_res_brick`](crate::bricks::pack_low_res_brick) +
//!   [`quantize_to`](crate::bricks::quantize_to), and its ranges to
//!   [`brick_value_ranges_for_storage`](crate::bricks::brick_value_ranges_for_storage).
//! - [`write_store_from_slabs`] writes the same bytes from a volume *file* read slab by slab
//!   ([`crate::volume::SlabReader`]) under a RAM budget, never holding the whole volume.
//! - [`BrickStore`] opens and validates a store file, keeps the small tables (offsets, min/max) in
//!   RAM and reads one brick level with one positioned read ([`BrickStore::read_brick`]).
//! - [`BrickStreamer`] loads the bricks a renderer asks for on a background thread, in priority
//!   order, into an LRU RAM cache bounded by a byte budget; it never blocks the caller on disk.
//!   It reads through a [`BrickBackend`]: a [`BrickStore`], or an OME-Zarr image packed from its
//!   chunks (`stream::ZarrBricks`).
//! - The streamer is a [`BrickSource`](crate::bricks::BrickSource), what a renderer packs bricks
//!   from (the in-memory sources live beside the bricks, in [`crate::bricks::source`]);
//!   [`fallback_levels`](crate::bricks::fallback_levels) turns the levels the LOD selector wants
//!   into levels whose bytes are available right now (a missing hi-res brick falls back to its
//!   low-res version), so the renderer never waits for the disk.

pub mod backend;
pub mod format;
pub mod levels;
pub mod reader;
pub mod slab_writer;
pub mod streamer;
pub mod upgrade;
pub mod writer;

pub use backend::BrickBackend;
pub use format::{StoreHeader, FORMAT_VERSION, HEADER_SIZE, MAGIC};
pub use levels::{
    default_store_levels, level_slab_bytes, write_level_store, write_level_store_from_slabs,
    LevelBackend, LevelStore, LevelStoreHeader, LevelStreamConfig, LevelStreamStats, LevelStreamer,
    LevelWriteSummary, StoredKey,
};
pub use reader::BrickStore;
pub use slab_writer::{plan_slab_write, slab_store_desc, write_store_from_slabs, SlabPlan};
pub use streamer::{BrickStreamer, StreamStats, StreamerConfig};
pub use upgrade::BrickStoreSlabs;
pub use writer::{
    write_store, write_store_from_volume, write_store_from_volume_with_progress,
    write_store_with_threads, StoreDesc, WriteSummary,
};

use std::path::PathBuf;

/// What a [`StoreError::Io`] or [`StoreError::Format`] names the file as.
pub const BRICK_STORE: &str = "brick store";
/// What a [`StoreError::Io`] or [`StoreError::Format`] names a level store as (review D22: its
/// errors said "brick store").
pub const LEVEL_STORE: &str = "level store";

/// Errors from writing, opening, reading and streaming brick and level stores.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The operating system refused an operation on the store file.
    #[error("{kind} {path}: {action}: {source}")]
    Io {
        /// The kind of store ([`BRICK_STORE`], [`LEVEL_STORE`]).
        kind: &'static str,
        /// The store file.
        path: PathBuf,
        /// What was being done (`open`, `read header`, `write bricks`, ...).
        action: &'static str,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a valid store: a field of the header or of a table is wrong.
    #[error("{kind} {path}: field `{field}`: {message}")]
    Format {
        /// The kind of store ([`BRICK_STORE`], [`LEVEL_STORE`]).
        kind: &'static str,
        /// The store file.
        path: PathBuf,
        /// The field at fault, as `docs/brick-store.md` names it (`magic`, `version`, `dims`,
        /// `brick_count`, `file_size`, `table_checksum`, `value_ranges`, `offsets`, ...).
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A [`StoreDesc`] (or the volume it came from) cannot be written as a store.
    #[error("invalid store description: `{field}`: {message}")]
    InvalidDesc {
        /// The description field at fault (`dims`, `brick_size`, `spacing`).
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The voxel producer returned a NaN or infinite value for an `F32` store.
    #[error("sample({voxel:?}) returned {value}; f32 stores need finite values")]
    NonFiniteSample {
        /// The voxel asked for.
        voxel: [i32; 3],
        /// The value returned.
        value: f32,
    },
    /// A brick index outside the grid.
    #[error("brick {brick} is outside the store's {count} bricks")]
    BrickOutOfRange {
        /// The index given.
        brick: u32,
        /// Bricks in the store.
        count: u32,
    },
    /// A brick level's bytes do not match the CRC-32 the store recorded for them: the file was
    /// altered or damaged after it was written.
    #[error(
        "{path}: brick {brick} level {level:?} is corrupt: its bytes hash to CRC-32 {computed:#010x} \
         but the store recorded {stored:#010x} (convert the source again)"
    )]
    BrickChecksum {
        /// The store file.
        path: PathBuf,
        /// The brick.
        brick: u32,
        /// The level.
        level: crate::bricks::Level,
        /// The CRC-32 the store recorded.
        stored: u32,
        /// The CRC-32 of the bytes read.
        computed: u32,
    },
    /// A stored brick of a level store does not match the CRC-32 the store recorded for it.
    #[error(
        "{path}: stored brick {entry} (level {level}) is corrupt: its bytes hash to CRC-32 \
         {computed:#010x} but the store recorded {stored:#010x} (write the store again)"
    )]
    StoredBrickChecksum {
        /// The store file.
        path: PathBuf,
        /// The level.
        level: u32,
        /// Index of the stored brick in the table.
        entry: usize,
        /// The CRC-32 the store recorded.
        stored: u32,
        /// The CRC-32 of the bytes read.
        computed: u32,
    },
    /// A level or brick outside a level store.
    #[error(
        "level {level} brick {brick:?} is outside the store's {levels} levels of {bricks:?} bricks"
    )]
    LevelOutOfRange {
        /// The level asked for.
        level: u32,
        /// The brick asked for.
        brick: [u32; 3],
        /// Levels in the store.
        levels: u32,
        /// Bricks per axis.
        bricks: [u32; 3],
    },
    /// `Level::Absent` was asked for; only `Hi` and `Lo` have bytes.
    #[error("brick {brick}: level Absent has no bytes")]
    AbsentLevel {
        /// The brick index given.
        brick: u32,
    },
    /// A request for a remote level store failed (after the retries of
    /// [`crate::volume::formats::RemoteOptions`]): the error names the object's URL.
    #[error("level store {url}: {action}: {source}")]
    Remote {
        /// The store's URL.
        url: String,
        /// What was being read.
        action: &'static str,
        /// What the object store said.
        source: Box<crate::volume::VolumeError>,
    },
    /// Reading the input volume failed (truncated or corrupt data, a non-finite value, an OS
    /// error); the error names the file and the field.
    #[error("reading the input volume: {0}")]
    Input(#[from] crate::volume::VolumeError),
    /// The RAM budget of a slab write cannot hold what the write needs.
    #[error("RAM budget of {budget} bytes is too small: {needed} bytes needed for {message}")]
    RamBudget {
        /// Bytes the write needs at least.
        needed: u64,
        /// The budget given (0 when the allocator refused).
        budget: u64,
        /// What the bytes are for.
        message: String,
    },
    /// The streamer's loader thread could not be started.
    #[error("cannot start the brick loader thread: {0}")]
    Thread(#[source] std::io::Error),
    /// A level backend other than a store file (an OME-Zarr pyramid) could not deliver a stored
    /// brick, or its stored bricks do not make up its levels.
    #[error("{backend}: {source}")]
    Backend {
        /// What was read ([`LevelBackend::name`]: a path or URL).
        backend: String,
        /// The backend's own error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A stored brick whose background read failed earlier ([`LevelStreamer`] keeps the error
    /// until [`LevelStreamer::clear_failures`]).
    #[error("level {level}, stored brick of brick {first}: its read failed earlier: {source}")]
    EarlierReadFailed {
        /// The level.
        level: u32,
        /// Linear index of the stored brick's first brick.
        first: usize,
        /// The error of that read.
        #[source]
        source: std::sync::Arc<StoreError>,
    },
}
