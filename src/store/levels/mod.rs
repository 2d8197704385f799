//! The level store: a volume's every level, as the three-level brick cache stores them, in one
//! checked file (issue 19, item 4). Where the two-level store ([`super::BrickStore`]) holds a
//! hi-res and a low-res brick per brick, a level store holds, per level `k`, one stored brick
//! per brick up to level 2 and one per aligned block of `block_bricks(k)^3` bricks past it
//! (`crate::cache::slot_geometry`), so a volume is drawn at any mix of levels without the
//! volume in RAM: `renderer::VolumeSource::LevelStore` packs each drawn brick straight
//! from the file.
//!
//! - [`write_level_store`] writes one from an in-memory volume (level by level, two levels in
//!   RAM at a time), into a fresh temporary file beside it (created exclusively), renamed into place once complete;
//!   [`write_level_store_from_slabs`] writes the same bytes from a volume file read in slabs
//!   (level 0 streamed, each coarser level built plane by plane in a temporary file: a few
//!   planes in RAM).
//! - [`LevelStore`] opens and checks one and reads stored bricks ([`LevelStore::read_stored`],
//!   CRC-checked) and their value ranges; [`LevelStreamer`] reads them on a background thread
//!   into a RAM cache under a byte budget, so that a moving camera does not wait on the disk.
//!
//! The format is specified in [`mod@format`] and, byte by byte, in `docs/brick-store.md`.

mod backend;
pub mod format;
mod plane_file;
mod reader;
mod slab_writer;
mod streamer;
mod writer;

pub use backend::LevelBackend;
pub use format::{LevelStoreHeader, LEVEL_FORMAT_VERSION, LEVEL_MAGIC};
pub use reader::LevelStore;
pub use slab_writer::{level_slab_bytes, write_level_store_from_slabs};
pub use streamer::{LevelStreamConfig, LevelStreamStats, LevelStreamer, StoredKey};
pub use writer::{default_store_levels, write_level_store, LevelWriteSummary};
