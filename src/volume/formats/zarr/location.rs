//! [`ZarrLocation`]: where an OME-Zarr image lives (a local folder, an S3 bucket prefix or an
//! HTTP(S) base URL), parsed from what a user typed, with the names errors give its objects.

use crate::volume::VolumeError;
use std::fmt;
use std::path::{Path, PathBuf};

/// Where an OME-Zarr image (or plain Zarr array) is: its root folder, or the root of its keys in
/// an object store.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ZarrLocation {
    /// A local folder (`image.zarr`, `/data/image.ome.zarr`, or a `file://` URL).
    Local(PathBuf),
    /// `s3://BUCKET/PREFIX` on an S3-compatible object store: endpoint, region and credentials
    /// come from the usual AWS environment variables (see
    /// [`RemoteOptions`](super::RemoteOptions)).
    S3 {
        /// The bucket (the URL's host).
        bucket: String,
        /// The key prefix of the image's root inside the bucket, without leading or trailing
        /// `/` (empty: the bucket's root).
        prefix: String,
    },
    /// `http://HOST/PATH` or `https://HOST/PATH`: objects are fetched with GET (Range requests
    /// for partial reads) under this base URL.
    Http {
        /// The base URL, without a trailing `/`.
        url: String,
    },
}

/// What a location may be, for messages.
const EXPECTED: &str = "expected a local folder, s3://BUCKET/PATH.zarr or http(s)://HOST/PATH.zarr";

impl ZarrLocation {
    /// True when `text` starts with a URL scheme (`LETTERS://`): it is then parsed as a URL by
    /// [`ZarrLocation::parse`], never looked up as a local file.
    pub fn is_url(text: &str) -> bool {
        text.split_once("://").is_some_and(|(scheme, _)| {
            scheme.len() >= 2
                && scheme.starts_with(|c: char| c.is_ascii_alphabetic())
                && scheme
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
        })
    }

    /// Parses what a user typed: a URL (see [`ZarrLocation::is_url`]) with scheme `s3`, `http`,
    /// `https` or `file`, else a local path. A URL with another scheme, no host (bucket), a
    /// query, a fragment, credentials in it, or that does not parse is a
    /// [`VolumeError::InvalidLocation`] naming it and what was expected.
    pub fn parse(text: &str) -> Result<Self, VolumeError> {
        if !Self::is_url(text) {
            return Ok(Self::Local(PathBuf::from(text)));
        }
        let bad = |message: String| VolumeError::InvalidLocation {
            location: text.to_string(),
            message,
        };
        let url = url::Url::parse(text).map_err(|e| bad(format!("not a valid URL ({e})")))?;
        if url.query().is_some() || url.fragment().is_some() {
            return Err(bad(
                "a query (?...) or fragment (#...) is not part of a Zarr location".into(),
            ));
        }
        if !url.username().is_empty() || url.password().is_some() {
            return Err(bad(
                "credentials in the URL are refused: give them in the environment \
                 (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY)"
                    .into(),
            ));
        }
        let path = url.path().trim_matches('/');
        match url.scheme() {
            "s3" => {
                let bucket = url.host_str().unwrap_or_default();
                if bucket.is_empty() {
                    return Err(bad(format!("no bucket: {EXPECTED}")));
                }
                if url.port().is_some() {
                    return Err(bad(
                        "an s3:// URL names a bucket, not a server: give the endpoint in \
                         AWS_ENDPOINT_URL"
                            .into(),
                    ));
                }
                Ok(Self::S3 {
                    bucket: bucket.to_string(),
                    prefix: path.to_string(),
                })
            }
            "http" | "https" => {
                if url.host_str().is_none_or(str::is_empty) {
                    return Err(bad(format!("no host: {EXPECTED}")));
                }
                let mut base = url.clone();
                base.set_path(path);
                Ok(Self::Http {
                    url: base.as_str().trim_end_matches('/').to_string(),
                })
            }
            "file" => url
                .to_file_path()
                .map(Self::Local)
                .map_err(|()| bad("a file:// URL must hold an absolute local path".into())),
            other => Err(bad(format!("unsupported scheme `{other}`: {EXPECTED}"))),
        }
    }

    /// True for S3 and HTTP(S) locations.
    pub fn is_remote(&self) -> bool {
        !matches!(self, Self::Local(_))
    }

    /// The local folder, for a local location.
    pub fn local_path(&self) -> Option<&Path> {
        match self {
            Self::Local(p) => Some(p),
            _ => None,
        }
    }

    /// The name errors give the root: the folder, or the URL (`s3://bucket/prefix`,
    /// `http://host/path`), as a path.
    pub fn root_name(&self) -> PathBuf {
        match self {
            Self::Local(p) => p.clone(),
            remote => PathBuf::from(remote.to_string()),
        }
    }

    /// The name errors give the object at `key` (a Zarr store key such as `0/zarr.json` or
    /// `0/c/1/2/3`): the file below the folder, or the object's URL.
    pub fn object_name(&self, key: &str) -> PathBuf {
        match self {
            Self::Local(p) => key
                .split('/')
                .filter(|s| !s.is_empty())
                .fold(p.clone(), |p, s| p.join(s)),
            remote => PathBuf::from(format!("{remote}/{}", key.trim_start_matches('/'))),
        }
    }
}

impl fmt::Display for ZarrLocation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Local(p) => write!(f, "{}", p.display()),
            Self::S3 { bucket, prefix } if prefix.is_empty() => write!(f, "s3://{bucket}"),
            Self::S3 { bucket, prefix } => write!(f, "s3://{bucket}/{prefix}"),
            Self::Http { url } => f.write_str(url),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn invalid(text: &str) -> String {
        match ZarrLocation::parse(text) {
            Err(VolumeError::InvalidLocation { location, message }) => {
                assert_eq!(location, text);
                message
            }
            other => panic!("{text}: expected InvalidLocation, got {other:?}"),
        }
    }

    #[test]
    fn parses_local_s3_http_and_file() {
        assert_eq!(
            ZarrLocation::parse("data/image.zarr").unwrap(),
            ZarrLocation::Local("data/image.zarr".into())
        );
        // A Windows drive or a colon in a name is not a URL.
        assert!(!ZarrLocation::is_url("C:\\data\\x.zarr"));
        assert!(!ZarrLocation::is_url("a:b.zarr"));
        assert!(!ZarrLocation::is_url("://x"));
        let s3 = ZarrLocation::parse("s3://bucket/some/image.zarr/").unwrap();
        assert_eq!(
            s3,
            ZarrLocation::S3 {
                bucket: "bucket".into(),
                prefix: "some/image.zarr".into()
            }
        );
        assert_eq!(s3.to_string(), "s3://bucket/some/image.zarr");
        assert_eq!(
            s3.object_name("0/zarr.json"),
            PathBuf::from("s3://bucket/some/image.zarr/0/zarr.json")
        );
        assert_eq!(
            ZarrLocation::parse("s3://bucket").unwrap().to_string(),
            "s3://bucket"
        );
        let http = ZarrLocation::parse("http://127.0.0.1:8080/a/image.zarr/").unwrap();
        assert_eq!(
            http,
            ZarrLocation::Http {
                url: "http://127.0.0.1:8080/a/image.zarr".into()
            }
        );
        assert!(http.is_remote());
        assert_eq!(
            http.object_name(".zattrs"),
            PathBuf::from("http://127.0.0.1:8080/a/image.zarr/.zattrs")
        );
        assert_eq!(
            ZarrLocation::parse("file:///data/x.zarr").unwrap(),
            ZarrLocation::Local("/data/x.zarr".into())
        );
        let local = ZarrLocation::Local("/d/x.zarr".into());
        assert_eq!(
            local.object_name("0/c/1/2"),
            PathBuf::from("/d/x.zarr/0/c/1/2")
        );
    }

    #[test]
    fn bad_urls_name_the_url_and_what_was_expected() {
        assert!(invalid("ftp://host/x.zarr").contains("unsupported scheme `ftp`"));
        assert!(invalid("ftp://host/x.zarr").contains("s3://BUCKET/PATH.zarr"));
        assert!(invalid("s3:///x.zarr").contains("no bucket"));
        assert!(invalid("s3://bucket:9000/x.zarr").contains("AWS_ENDPOINT_URL"));
        assert!(invalid("http://h/x.zarr?v=1").contains("query"));
        assert!(invalid("https://user:pw@h/x.zarr").contains("credentials"));
        assert!(invalid("http://[::1/x.zarr").contains("not a valid URL"));
    }
}
