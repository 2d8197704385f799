//! The storage a [`ZarrLocation`] is read through: zarrs' filesystem store for a folder, and for
//! `s3://` / `http(s)://` an [`object_store`](zarrs_object_store::object_store) client (through
//! zarrs' `zarrs_object_store` adapter) driven synchronously by a current-thread tokio runtime. Every
//! location gives the same `Arc<dyn ReadableStorageTraits>`, so the chunk and metadata code is
//! shared line for line.
//!
//! Why object_store (through zarrs' own `zarrs_object_store` adapter) rather than opendal: one
//! kept client (Apache Arrow's) serves both S3-compatible stores and plain HTTP with Range
//! requests, it reads the usual AWS environment variables itself, and its per-request timeouts
//! and bounded retries with exponential backoff are explicit options ([`RemoteOptions`]).

use super::ZarrLocation;
use crate::volume::VolumeError;
use futures::StreamExt;
use std::sync::Arc;
use std::time::Duration;
use zarrs::filesystem::FilesystemStore;
use zarrs::storage::byte_range::{ByteRange, ByteRangeIterator};
use zarrs::storage::{
    AsyncReadableStorageTraits, Bytes, MaybeBytes, MaybeBytesIterator, ReadableStorageTraits,
    StorageError, StoreKey,
};
use zarrs_object_store::object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use zarrs_object_store::object_store::http::HttpBuilder;
use zarrs_object_store::object_store::path::Path as ObjectPath;
use zarrs_object_store::object_store::prefix::PrefixStore;
use zarrs_object_store::object_store::{
    BackoffConfig, ClientOptions, Error as ObjectStoreError, ObjectStore, ObjectStoreExt,
    RetryConfig,
};
use zarrs_object_store::AsyncObjectStore;

/// The storage every location is read through.
pub(super) type Storage = Arc<dyn ReadableStorageTraits>;

/// How remote objects are fetched: timeouts and retries (set explicitly, never left to the
/// client's defaults), and S3 settings that override the environment.
///
/// A request (connect to the last body byte) that does not finish within `timeout` fails; a
/// failed request (timeout, connection error, truncated body, HTTP 5xx or 429) is retried up to
/// `max_retries` times with exponential backoff from `init_backoff` (doubling, at most
/// `max_backoff`), and never after `retry_timeout` from the first try. So a stalled or failing
/// server costs at most about `(max_retries + 1) * timeout` plus the backoff per object before a
/// [`VolumeError::Remote`] naming the object. HTTP 404 is not retried: a missing chunk is the
/// fill value, a missing metadata document an error.
#[derive(Clone, Debug, PartialEq)]
pub struct RemoteOptions {
    /// Limit on one request, from connecting to the end of the body. Default 30 s
    /// (`MIXVOL_REMOTE_TIMEOUT_MS`).
    pub timeout: Duration,
    /// Limit on connecting. Default 5 s (`MIXVOL_REMOTE_CONNECT_TIMEOUT_MS`).
    pub connect_timeout: Duration,
    /// Retries after the first try. Default 3 (`MIXVOL_REMOTE_RETRIES`).
    pub max_retries: usize,
    /// No retry starts later than this after the first try. Default 120 s.
    pub retry_timeout: Duration,
    /// The first backoff. Default 100 ms.
    pub init_backoff: Duration,
    /// The largest backoff. Default 2 s.
    pub max_backoff: Duration,
    /// S3 settings applied after the `AWS_*` environment variables, as `(key, value)` with the
    /// variables' names in lower case (`aws_endpoint_url`, `aws_region`, `aws_access_key_id`,
    /// `aws_secret_access_key`, `aws_allow_http`, `aws_skip_signature`, ...). Empty by default.
    pub s3_config: Vec<(String, String)>,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(30),
            connect_timeout: Duration::from_secs(5),
            max_retries: 3,
            retry_timeout: Duration::from_secs(120),
            init_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(2),
            s3_config: Vec::new(),
        }
    }
}

impl RemoteOptions {
    /// The defaults, with `timeout`, `connect_timeout` and `max_retries` taken from
    /// `MIXVOL_REMOTE_TIMEOUT_MS`, `MIXVOL_REMOTE_CONNECT_TIMEOUT_MS` and `MIXVOL_REMOTE_RETRIES`
    /// where set. A value that is not a whole number (or a zero timeout) is a
    /// [`VolumeError::Environment`] naming the variable.
    pub fn from_env() -> Result<Self, VolumeError> {
        let mut options = Self::default();
        let refuse = |name: &str, value: String, expected: &str| VolumeError::Environment {
            name: name.to_string(),
            value,
            expected: expected.to_string(),
        };
        let var = |name: &str| -> Result<Option<u64>, VolumeError> {
            match std::env::var(name) {
                Err(_) => Ok(None),
                Ok(text) => text
                    .trim()
                    .parse::<u64>()
                    .map(Some)
                    .map_err(|_| refuse(name, text, "expected a whole number")),
            }
        };
        let millis = |name: &str| -> Result<Option<Duration>, VolumeError> {
            match var(name)? {
                Some(0) => Err(refuse(name, "0".into(), "a timeout must be at least 1 ms")),
                v => Ok(v.map(Duration::from_millis)),
            }
        };
        if let Some(t) = millis("MIXVOL_REMOTE_TIMEOUT_MS")? {
            options.timeout = t;
        }
        if let Some(t) = millis("MIXVOL_REMOTE_CONNECT_TIMEOUT_MS")? {
            options.connect_timeout = t;
        }
        if let Some(n) = var("MIXVOL_REMOTE_RETRIES")? {
            options.max_retries = usize::try_from(n).unwrap_or(usize::MAX);
        }
        Ok(options)
    }

    fn client_options(&self) -> ClientOptions {
        ClientOptions::new()
            .with_timeout(self.timeout)
            .with_connect_timeout(self.connect_timeout)
    }

    fn retry(&self) -> RetryConfig {
        RetryConfig {
            backoff: BackoffConfig {
                init_backoff: self.init_backoff,
                max_backoff: self.max_backoff,
                base: 2.0,
            },
            max_retries: self.max_retries,
            retry_timeout: self.retry_timeout,
        }
    }
}

/// A remote object store read synchronously: object_store's futures run to completion on one
/// current-thread tokio runtime (timer and IO drivers on) owned by the store. Like zarrs_storage's
/// `AsyncToSyncStorageAdapter`, but a whole-object `get` is one GET, where the adapter turns it
/// into a HEAD (for the size) and a ranged GET: half the round trips per chunk; and its errors
/// keep their causes.
struct RemoteStorage {
    /// The client, for whole-object reads (with the full error chain in messages).
    client: Arc<dyn ObjectStore>,
    /// The same client through zarrs' adapter, for sizes and partial reads.
    store: AsyncObjectStore<Arc<dyn ObjectStore>>,
    runtime: tokio::runtime::Runtime,
}

/// An object_store error with its causes (`request or response body error: operation timed
/// out`), where zarrs' adapter keeps only the first line.
fn error_chain(e: &dyn std::error::Error) -> StorageError {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let line = c.to_string();
        if !text.contains(&line) {
            text.push_str(": ");
            text.push_str(&line);
        }
        cause = c.source();
    }
    StorageError::Other(text)
}

impl ReadableStorageTraits for RemoteStorage {
    fn get(&self, key: &StoreKey) -> Result<MaybeBytes, StorageError> {
        let path = ObjectPath::from(key.as_str());
        self.runtime.block_on(async {
            match self.client.get(&path).await {
                Ok(found) => found.bytes().await.map(Some).map_err(|e| error_chain(&e)),
                Err(ObjectStoreError::NotFound { .. }) => Ok(None),
                Err(e) => Err(error_chain(&e)),
            }
        })
    }

    fn get_partial_many<'a>(
        &'a self,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        let byte_ranges: Vec<ByteRange> = byte_ranges.collect();
        let absolute: Option<Vec<std::ops::Range<u64>>> = byte_ranges
            .iter()
            .map(|range| match *range {
                ByteRange::FromStart(offset, Some(len)) => Some(offset..offset + len),
                _ => None,
            })
            .collect();
        if let Some(absolute) = absolute {
            // Every offset and length known: ranged GETs straight away. zarrs' adapter asks for
            // the object's size first (a HEAD per read), which doubled the requests of a level
            // store's stored-brick reads (review H3).
            let path = ObjectPath::from(key.as_str());
            return self.runtime.block_on(async {
                match self.client.get_ranges(&path, &absolute).await {
                    Ok(parts) => {
                        let checked: Vec<Result<Bytes, StorageError>> =
                            std::iter::zip(&absolute, parts)
                                .map(|(range, bytes)| {
                                    let want = range.end - range.start;
                                    if bytes.len() as u64 == want {
                                        Ok(bytes)
                                    } else {
                                        Err(StorageError::Other(format!(
                                            "asked for {want} bytes at {}, got {}",
                                            range.start,
                                            bytes.len()
                                        )))
                                    }
                                })
                                .collect();
                        Ok(Some(Box::new(checked.into_iter()) as _))
                    }
                    Err(ObjectStoreError::NotFound { .. }) => Ok(None),
                    Err(e) => Err(error_chain(&e)),
                }
            });
        }
        let parts = self.runtime.block_on(
            self.store
                .get_partial_many(key, Box::new(byte_ranges.into_iter())),
        )?;
        Ok(match parts {
            Some(parts) => {
                let parts: Vec<_> = self.runtime.block_on(parts.collect::<Vec<_>>());
                Some(Box::new(parts.into_iter()))
            }
            None => None,
        })
    }

    fn size_key(&self, key: &StoreKey) -> Result<Option<u64>, StorageError> {
        self.runtime.block_on(self.store.size_key(key))
    }

    fn supports_get_partial(&self) -> bool {
        true
    }
}

/// Opens the storage of `location`: a local folder (which must exist and be a folder) or a
/// remote object store configured by `options` and, for S3, the environment.
pub(super) fn open_storage(
    location: &ZarrLocation,
    options: &RemoteOptions,
) -> Result<Storage, VolumeError> {
    let remote_err = |message: String| VolumeError::Remote {
        url: location.to_string(),
        message,
    };
    if location.is_remote() {
        // reqwest is built without a TLS crypto provider of its own (see Cargo.toml), and
        // object_store builds its client in `build()`: rustls' ring provider becomes the process
        // default first, unless one is installed already.
        let _ = rustls::crypto::ring::default_provider().install_default();
    }
    let store: Arc<dyn ObjectStore> = match location {
        ZarrLocation::Local(root) => {
            let store = FilesystemStore::new(root).map_err(|e| VolumeError::Io {
                path: root.clone(),
                source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()),
            })?;
            return Ok(Arc::new(store));
        }
        ZarrLocation::S3 { bucket, prefix } => {
            let mut builder = AmazonS3Builder::new()
                .with_client_options(options.client_options())
                .with_retry(options.retry());
            // As AmazonS3Builder::from_env, after the client options (which would replace the
            // environment's AWS_ALLOW_HTTP).
            for (key, value) in std::env::vars_os() {
                if let (Some(key), Some(value)) = (key.to_str(), value.to_str()) {
                    if let Some(k) = key
                        .strip_prefix("AWS_")
                        .and_then(|_| key.to_ascii_lowercase().parse::<AmazonS3ConfigKey>().ok())
                    {
                        builder = builder.with_config(k, value);
                    }
                }
            }
            for (key, value) in &options.s3_config {
                let k = key.parse::<AmazonS3ConfigKey>().map_err(|e| {
                    VolumeError::InvalidParameter(format!("S3 setting `{key}`: {e}"))
                })?;
                builder = builder.with_config(k, value);
            }
            let s3 = builder
                .with_bucket_name(bucket)
                .build()
                .map_err(|e| remote_err(format!("cannot configure the S3 client: {e}")))?;
            if prefix.is_empty() {
                Arc::new(s3)
            } else {
                Arc::new(PrefixStore::new(s3, prefix.as_str()))
            }
        }
        ZarrLocation::Http { url } => {
            let client = options
                .client_options()
                .with_allow_http(url.starts_with("http://"));
            Arc::new(
                HttpBuilder::new()
                    .with_url(url)
                    .with_client_options(client)
                    .with_retry(options.retry())
                    .build()
                    .map_err(|e| remote_err(format!("cannot configure the HTTP client: {e}")))?,
            )
        }
    };
    if tokio::runtime::Handle::try_current().is_ok() {
        return Err(remote_err(
            "remote Zarr stores are read synchronously and cannot be opened from inside an \
             async (tokio) runtime: open it from a plain thread"
                .into(),
        ));
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .enable_time()
        .build()
        .map_err(|e| remote_err(format!("cannot start the IO runtime: {e}")))?;
    Ok(Arc::new(RemoteStorage {
        client: store.clone(),
        store: AsyncObjectStore::new(store),
        runtime,
    }))
}

/// One object (a file) in a local folder or an object store, read by byte ranges: what a level
/// store on S3 or behind HTTP is read through (`store::LevelStore::open_remote`), with
/// the timeouts and retries of [`RemoteOptions`].
pub struct RemoteObject {
    storage: Storage,
    key: StoreKey,
    url: String,
}

impl std::fmt::Debug for RemoteObject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteObject")
            .field("url", &self.url)
            .finish()
    }
}

impl RemoteObject {
    /// Opens the object `url` (`s3://BUCKET/PATH/FILE`, `http(s)://HOST/PATH/FILE`): its folder
    /// as a location, the file name as the key. Errors: a URL that does not parse or has no file
    /// name, a client that cannot be configured.
    pub fn open(url: &str, options: &RemoteOptions) -> Result<Self, VolumeError> {
        let bad = |message: &str| VolumeError::InvalidLocation {
            location: url.to_string(),
            message: message.to_string(),
        };
        let (folder, name) = url
            .trim_end_matches('/')
            .rsplit_once('/')
            .filter(|(folder, name)| !name.is_empty() && folder.contains("://"))
            .ok_or_else(|| bad("expected a URL naming a file"))?;
        let location = ZarrLocation::parse(folder)?;
        let key = StoreKey::new(name).map_err(|e| bad(&format!("not an object name ({e})")))?;
        Ok(Self {
            storage: open_storage(&location, options)?,
            key,
            url: url.to_string(),
        })
    }

    /// The object's URL.
    pub fn url(&self) -> &str {
        &self.url
    }

    fn error(&self, message: String) -> VolumeError {
        VolumeError::Remote {
            url: self.url.clone(),
            message,
        }
    }

    /// The object's size in bytes. Errors: it does not exist, or the request fails.
    pub fn size(&self) -> Result<u64, VolumeError> {
        self.storage
            .size_key(&self.key)
            .map_err(|e| self.error(e.to_string()))?
            .ok_or_else(|| self.error("not found".into()))
    }

    /// Fills `buf` with the object's bytes from `offset` (one range request). Errors: the object
    /// is missing, the request fails, or fewer bytes come back.
    pub fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> Result<(), VolumeError> {
        if buf.is_empty() {
            return Ok(());
        }
        let bytes = self
            .storage
            .get_partial(
                &self.key,
                ByteRange::FromStart(offset, Some(buf.len() as u64)),
            )
            .map_err(|e| self.error(e.to_string()))?
            .ok_or_else(|| self.error("not found".into()))?;
        if bytes.len() != buf.len() {
            return Err(self.error(format!(
                "asked for {} bytes at {offset}, got {}",
                buf.len(),
                bytes.len()
            )));
        }
        buf.copy_from_slice(&bytes);
        Ok(())
    }
}
