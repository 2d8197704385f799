//! Loopback servers for the remote-store tests, started from the project's own scripts and the
//! Python environment `scripts/python-env.sh` creates (target/python-venv, or $MIXVOL_PYTHON): moto's
//! S3-compatible server and tests/servers/range_server.py (an HTTP server with Range requests
//! and fault injection). Each server runs on a free loopback port and is killed on drop. Also a
//! small hand-written OME-Zarr store (v2 + gzip, v3 + raw) with known voxel values.
#![allow(dead_code)]

pub mod pyramid;
#[path = "../python_env/mod.rs"]
pub mod python_env;

use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// The repository root.
pub fn repo() -> PathBuf {
    // This file is included by tests of the library and of crates/mixvol-cli.
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    if here.join("tests/servers/range_server.py").is_file() {
        here
    } else {
        here.join("../..")
    }
}

/// The Python of the test environment (see tests/python_env); panics with what to run when it
/// is missing.
pub fn python() -> PathBuf {
    python_env::python("moto and boto3")
}

/// A free loopback TCP port (bound and released: another process could take it in between,
/// which would make the server's start fail loudly, not silently).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A child process killed (and reaped) on drop.
pub struct Server {
    child: Child,
    /// Its loopback port.
    pub port: u16,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Server {
    /// `http://127.0.0.1:PORT`.
    pub fn base(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }
}

/// Starts tests/servers/range_server.py serving `root`.
pub fn range_server(root: &Path) -> Server {
    let mut child = Command::new(python())
        .arg(repo().join("tests/servers/range_server.py"))
        .arg(root)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start tests/servers/range_server.py");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port = line
        .trim()
        .strip_prefix("PORT ")
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("range_server.py printed {line:?}, expected PORT <n>"));
    Server { child, port }
}

/// Starts moto's S3 server (`python -m moto.server`) on a free port and waits until it answers.
pub fn moto_server() -> Server {
    let port = free_port();
    let child = Command::new(python())
        .args([
            "-m",
            "moto.server",
            "-H",
            "127.0.0.1",
            "-p",
            &port.to_string(),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start moto.server");
    let mut server = Server { child, port };
    let start = Instant::now();
    while http_get(port, "/").is_none() {
        if let Some(status) = server.child.try_wait().unwrap() {
            panic!("moto.server exited with {status} before answering on port {port}");
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "moto.server did not answer on port {port} within 60 s"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    server
}

/// The credentials and region the tests give moto (any values do).
pub const S3_ENV: [(&str, &str); 3] = [
    ("AWS_ACCESS_KEY_ID", "mixvol-test"),
    ("AWS_SECRET_ACCESS_KEY", "mixvol-test-secret"),
    ("AWS_DEFAULT_REGION", "us-east-1"),
];

/// Remote options that reach `moto` with the test credentials: the endpoint and credentials as
/// the AWS variables would give them, set through the options (which override the environment)
/// so that parallel tests share no settings.
pub fn moto_options(moto: &Server) -> mixvol::volume::formats::RemoteOptions {
    mixvol::volume::formats::RemoteOptions {
        s3_config: vec![
            ("aws_endpoint_url".into(), moto.base()),
            ("aws_allow_http".into(), "true".into()),
            ("aws_access_key_id".into(), S3_ENV[0].1.into()),
            ("aws_secret_access_key".into(), S3_ENV[1].1.into()),
            ("aws_region".into(), "us-east-1".into()),
        ],
        ..Default::default()
    }
}

/// Uploads `folder` to `s3://bucket/prefix` on the moto server with boto3
/// (tests/servers/s3_upload.py).
pub fn s3_upload(moto: &Server, folder: &Path, bucket: &str, prefix: &str) {
    let out = Command::new(python())
        .arg(repo().join("tests/servers/s3_upload.py"))
        .arg(moto.base())
        .arg(bucket)
        .arg(folder)
        .arg(prefix)
        .envs(S3_ENV)
        .output()
        .expect("run s3_upload.py");
    assert!(
        out.status.success(),
        "s3_upload.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A plain HTTP/1.0 GET on loopback: the body of a 200 answer, `None` when nothing answers.
pub fn http_get(port: u16, path: &str) -> Option<String> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n").ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let (head, body) = text.split_once("\r\n\r\n")?;
    head.starts_with("HTTP/1").then(|| body.to_string())
}

/// A raw HTTP/1.0 request on loopback with extra header lines: (status code, headers, body).
pub fn http_request(port: u16, method: &str, path: &str, headers: &str) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "{method} {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n{headers}\r\n"
    )
    .unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    (status, head, raw[split + 4..].to_vec())
}

/// Requests range_server.py has seen for `path` (`/MODE/...`).
pub fn request_count(server: &Server, path: &str) -> u64 {
    http_get(server.port, &format!("/_count{path}"))
        .and_then(|b| b.trim().parse().ok())
        .expect("range_server.py /_count")
}

/// A unique temporary folder, removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// A new empty folder named after `tag`.
    pub fn new(tag: &str) -> Self {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("mixvol-remote-{}-{n}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

fn write_json(path: &Path, value: &Value) {
    write(path, serde_json::to_string(value).unwrap().as_bytes());
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// The u16 value the test stores hold at voxel (x, y, z) (distinct per voxel).
pub fn value(x: u64, y: u64, z: u64) -> u16 {
    (1 + x + 37 * y + 1009 * z) as u16
}

/// A hand-written OME-Zarr image of u16 voxels: `shape` (z, y, x), `chunks` (z, y, x) that need
/// not divide it, chunk `missing` (z, y, x chunk indices) left out (it reads as `fill`).
pub struct ImageSpec {
    /// Array shape, z y x.
    pub shape: [u64; 3],
    /// Chunk shape, z y x.
    pub chunks: [u64; 3],
    /// Zarr v3 (raw chunks, OME 0.5) or v2 (gzip chunks, OME 0.4).
    pub v3: bool,
    /// A chunk not written.
    pub missing: Option<[u64; 3]>,
    /// The fill value.
    pub fill: u16,
}

impl ImageSpec {
    /// The chunk grid, z y x.
    pub fn grid(&self) -> [u64; 3] {
        [0, 1, 2].map(|a| self.shape[a].div_ceil(self.chunks[a]))
    }

    /// The value the loader must give at (x, y, z).
    pub fn expected(&self, x: u64, y: u64, z: u64) -> u16 {
        let c = [z / self.chunks[0], y / self.chunks[1], x / self.chunks[2]];
        if self.missing == Some(c) {
            self.fill
        } else {
            value(x, y, z)
        }
    }

    /// The store key of chunk (z, y, x) of level 0.
    pub fn chunk_key(&self, c: [u64; 3]) -> String {
        if self.v3 {
            format!("0/c/{}/{}/{}", c[0], c[1], c[2])
        } else {
            format!("0/{}.{}.{}", c[0], c[1], c[2])
        }
    }

    /// Writes the image (group metadata, level `0`) into `root`; returns the chunk count.
    pub fn write(&self, root: &Path) -> usize {
        self.write_with(root, value)
    }

    /// [`ImageSpec::write`] with the voxel values `f(x, y, z)` (what [`ImageSpec::expected`]
    /// assumes is [`value`]).
    pub fn write_with(&self, root: &Path, f: impl Fn(u64, u64, u64) -> u16) -> usize {
        let axes = json!([
            {"name": "z", "type": "space"}, {"name": "y", "type": "space"},
            {"name": "x", "type": "space"}
        ]);
        let ms = json!({
            "axes": axes,
            "datasets": [{"path": "0", "coordinateTransformations": [
                {"type": "scale", "scale": [2.0, 1.0, 0.5]}]}],
        });
        if self.v3 {
            write_json(
                &root.join("zarr.json"),
                &json!({"zarr_format": 3, "node_type": "group",
                        "attributes": {"ome": {"version": "0.5", "multiscales": [ms]}}}),
            );
            write_json(
                &root.join("0/zarr.json"),
                &json!({
                    "zarr_format": 3, "node_type": "array", "shape": self.shape,
                    "data_type": "uint16",
                    "chunk_grid": {"name": "regular",
                                   "configuration": {"chunk_shape": self.chunks}},
                    "chunk_key_encoding": {"name": "default",
                                           "configuration": {"separator": "/"}},
                    "fill_value": self.fill,
                    "codecs": [{"name": "bytes", "configuration": {"endian": "little"}}],
                    "attributes": {},
                }),
            );
        } else {
            write_json(&root.join(".zgroup"), &json!({"zarr_format": 2}));
            let ms = {
                let mut m = ms;
                m["version"] = json!("0.4");
                m
            };
            write_json(&root.join(".zattrs"), &json!({"multiscales": [ms]}));
            write_json(
                &root.join("0/.zarray"),
                &json!({
                    "zarr_format": 2, "shape": self.shape, "chunks": self.chunks,
                    "dtype": "<u2", "compressor": {"id": "gzip", "level": 1},
                    "fill_value": self.fill, "order": "C", "filters": null,
                    "dimension_separator": ".",
                }),
            );
        }
        let g = self.grid();
        let mut count = 0;
        for cz in 0..g[0] {
            for cy in 0..g[1] {
                for cx in 0..g[2] {
                    if self.missing == Some([cz, cy, cx]) {
                        continue;
                    }
                    let mut bytes = Vec::new();
                    let [sz, sy, sx] = self.chunks;
                    for z in cz * sz..(cz + 1) * sz {
                        for y in cy * sy..(cy + 1) * sy {
                            for x in cx * sx..(cx + 1) * sx {
                                // Padding outside the array: a value the reader must ignore.
                                let inside =
                                    z < self.shape[0] && y < self.shape[1] && x < self.shape[2];
                                let v = if inside { f(x, y, z) } else { 0xBEEF };
                                bytes.extend_from_slice(&v.to_le_bytes());
                            }
                        }
                    }
                    let bytes = if self.v3 { bytes } else { gzip(&bytes) };
                    write(&root.join(self.chunk_key([cz, cy, cx])), &bytes);
                    count += 1;
                }
            }
        }
        count
    }
}

/// Asserts every voxel of `volume` against `spec` (u16 data, x y z dims = the shape reversed).
pub fn check_volume(volume: &mixvol::volume::Volume, spec: &ImageSpec) {
    let [nz, ny, nx] = spec.shape;
    assert_eq!(volume.dims().to_array(), [nx as u32, ny as u32, nz as u32]);
    let mixvol::volume::VoxelData::U16(data) = volume.data() else {
        panic!("expected u16 voxels");
    };
    let mut i = 0;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                assert_eq!(
                    data[i],
                    spec.expected(x, y, z),
                    "voxel x={x} y={y} z={z} (index {i})"
                );
                i += 1;
            }
        }
    }
}

/// Short timeouts and quick retries, so that the fault tests end fast.
pub fn quick(retries: usize, timeout_ms: u64) -> mixvol::volume::formats::RemoteOptions {
    mixvol::volume::formats::RemoteOptions {
        timeout: Duration::from_millis(timeout_ms),
        connect_timeout: Duration::from_secs(2),
        max_retries: retries,
        retry_timeout: Duration::from_secs(30),
        init_backoff: Duration::from_millis(10),
        max_backoff: Duration::from_millis(50),
        s3_config: Vec::new(),
    }
}
