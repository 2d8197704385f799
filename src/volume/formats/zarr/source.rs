//! [`ZarrSource`]: an opened [`ZarrLocation`]: its storage (shared by zarrs for chunks and
//! array metadata), and the probing and bounded reading of the metadata documents the loader
//! parses itself.

use super::remote::{open_storage, Storage};
use super::{format_err, io_err, read_metadata, RemoteOptions, ZarrLocation, MAX_HEADER_BYTES};
use crate::volume::VolumeError;
use std::path::PathBuf;
use zarrs::storage::{StorageError, StoreKey};

/// A location opened for reading.
pub(super) struct ZarrSource {
    pub(super) location: ZarrLocation,
    pub(super) storage: Storage,
}

impl ZarrSource {
    /// Opens `location` (a local one must be an existing folder) without reading anything
    /// remote.
    pub(super) fn open(
        location: &ZarrLocation,
        options: &RemoteOptions,
    ) -> Result<Self, VolumeError> {
        if let ZarrLocation::Local(root) = location {
            let meta = std::fs::metadata(root).map_err(io_err(root))?;
            if !meta.is_dir() {
                return Err(format_err(
                    root,
                    "zarr_format",
                    "an OME-Zarr image is a folder (holding zarr.json or .zattrs)",
                ));
            }
        }
        Ok(Self {
            location: location.clone(),
            storage: open_storage(location, options)?,
        })
    }

    /// The name errors give the object at `key`.
    pub(super) fn name(&self, key: &str) -> PathBuf {
        self.location.object_name(key)
    }

    /// Whether the metadata document `key` exists (a regular file; a remote object).
    pub(super) fn exists(&self, key: &str) -> Result<bool, VolumeError> {
        match &self.location {
            ZarrLocation::Local(_) => Ok(self.name(key).is_file()),
            _ => Ok(self
                .storage
                .size_key(&self.key(key)?)
                .map_err(|e| storage_err(&self.name(key), &e))?
                .is_some()),
        }
    }

    /// Reads the metadata document `key`, of at most [`MAX_HEADER_BYTES`]. A missing document is
    /// a [`VolumeError::Io`] (not found) naming it.
    pub(super) fn read_doc(&self, key: &str) -> Result<Vec<u8>, VolumeError> {
        self.find_doc(key)?.ok_or_else(|| VolumeError::Io {
            path: self.name(key),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such object"),
        })
    }

    /// Reads the metadata document `key` if it exists (a regular file; a remote object), of at
    /// most [`MAX_HEADER_BYTES`]: remotely a HEAD, then a GET (refused when the size is over).
    pub(super) fn find_doc(&self, key: &str) -> Result<Option<Vec<u8>>, VolumeError> {
        let name = self.name(key);
        if self.location.local_path().is_some() {
            // Through the file reader, which refuses FIFOs and devices before opening them.
            return if name.is_file() {
                read_metadata(&name).map(Some)
            } else {
                Ok(None)
            };
        }
        let store_key = self.key(key)?;
        let too_big = |len: u64| {
            format_err(
                &name,
                "json",
                format!("the metadata is {len} bytes; at most {MAX_HEADER_BYTES} are read"),
            )
        };
        let Some(len) = self
            .storage
            .size_key(&store_key)
            .map_err(|e| storage_err(&name, &e))?
        else {
            return Ok(None);
        };
        if len > MAX_HEADER_BYTES {
            return Err(too_big(len));
        }
        let bytes = self
            .storage
            .get(&store_key)
            .map_err(|e| storage_err(&name, &e))?;
        match bytes {
            Some(b) if b.len() as u64 > MAX_HEADER_BYTES => Err(too_big(b.len() as u64)),
            b => Ok(b.map(|b| b.to_vec())),
        }
    }

    fn key(&self, key: &str) -> Result<StoreKey, VolumeError> {
        StoreKey::new(key).map_err(|e| format_err(&self.name(key), "path", e.to_string()))
    }
}

/// A storage failure on the object `name`: an IO error (local files) or a failed fetch.
pub(super) fn storage_err(name: &std::path::Path, e: &StorageError) -> VolumeError {
    match e {
        StorageError::IOError(io) => VolumeError::Io {
            path: name.to_path_buf(),
            source: std::io::Error::new(io.kind(), io.to_string()),
        },
        other => VolumeError::Remote {
            url: name.display().to_string(),
            message: other.to_string(),
        },
    }
}
