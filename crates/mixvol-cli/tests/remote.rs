//! `mixvol convert` and `mixvol render` on remote OME-Zarr images: `http://` from
//! tests/servers/range_server.py and `s3://` from moto's server, both on loopback, started here
//! (the library's tests/remote_util; the Python environment comes from scripts/test.sh). A
//! remote convert writes the same brick store, byte for byte, as converting the folder; the
//! S3 endpoint and credentials reach the binary through the usual AWS environment variables;
//! MIXVOL_REMOTE_TIMEOUT_MS / MIXVOL_REMOTE_RETRIES bound a stalled server; a bad URL is refused
//! by name.

#[path = "../../../tests/remote_util/mod.rs"]
mod remote_util;

use remote_util::*;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn spec() -> ImageSpec {
    ImageSpec {
        shape: [20, 18, 21],
        chunks: [8, 8, 8],
        v3: true,
        missing: Some([1, 1, 1]),
        fill: 3,
    }
}

fn mixvol(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mixvol"))
        .args(args)
        .envs(env.iter().copied())
        .output()
        .unwrap()
}

fn convert(input: &str, store: &Path, env: &[(&str, &str)]) -> Output {
    mixvol(
        &[
            "convert",
            input,
            store.to_str().unwrap(),
            "--brick-size",
            "8",
        ],
        env,
    )
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "mixvol failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // stdout, then stderr (warnings).
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

#[test]
fn convert_and_render_from_http_equal_the_local_folder() {
    let dir = TempDir::new("cli-http");
    let image = dir.0.join("img.zarr");
    spec().write(&image);
    let server = range_server(&dir.0);
    let url = format!("{}/ok/img.zarr", server.base());

    let local = dir.0.join("local.store");
    ok(&convert(image.to_str().unwrap(), &local, &[]));
    let remote = dir.0.join("remote.store");
    let text = ok(&convert(&url, &remote, &[]));
    assert!(text.contains(&url), "the summary names the URL: {text}");
    assert_eq!(
        std::fs::read(&remote).unwrap(),
        std::fs::read(&local).unwrap(),
        "the store converted over HTTP differs from the local one"
    );

    let png = dir.0.join("out.png");
    let out = mixvol(
        &[
            "render",
            "--volume",
            &url,
            "--width",
            "16",
            "--height",
            "16",
            "--frames",
            "1",
            "--output",
            png.to_str().unwrap(),
        ],
        &[],
    );
    assert!(ok(&out).contains("21x18x20"));
    assert!(png.is_file());
}

#[test]
fn convert_from_s3_with_the_aws_environment_variables() {
    let dir = TempDir::new("cli-s3");
    let image = dir.0.join("img.zarr");
    spec().write(&image);
    let moto = moto_server();
    s3_upload(&moto, &image, "bucket", "deep/path/img.zarr");
    let endpoint = moto.base();
    let mut env: Vec<(&str, &str)> = S3_ENV.to_vec();
    env.extend([
        ("AWS_ENDPOINT_URL", endpoint.as_str()),
        ("AWS_ALLOW_HTTP", "true"),
    ]);

    let local = dir.0.join("local.store");
    ok(&convert(image.to_str().unwrap(), &local, &[]));
    let remote = dir.0.join("remote.store");
    ok(&convert("s3://bucket/deep/path/img.zarr", &remote, &env));
    assert_eq!(
        std::fs::read(&remote).unwrap(),
        std::fs::read(&local).unwrap()
    );
    // Without the endpoint's AWS_ALLOW_HTTP the plain-HTTP endpoint is refused, with a message.
    let strict: Vec<(&str, &str)> = env[..4].to_vec();
    let out = convert(
        "s3://bucket/deep/path/img.zarr",
        &dir.0.join("strict.store"),
        &strict,
    );
    assert!(!out.status.success());
    assert!(!dir.0.join("strict.store").exists());
}

#[test]
fn a_stalled_server_times_out_and_a_bad_url_is_refused_by_name() {
    let dir = TempDir::new("cli-stall");
    spec().write(&dir.0.join("img.zarr"));
    let server = range_server(&dir.0);
    let url = format!("{}/stall/img.zarr", server.base());
    let store = dir.0.join("x.store");
    let start = Instant::now();
    let out = convert(
        &url,
        &store,
        &[
            ("MIXVOL_REMOTE_TIMEOUT_MS", "300"),
            ("MIXVOL_REMOTE_RETRIES", "1"),
        ],
    );
    assert!(start.elapsed() < Duration::from_secs(20));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("{url}/0/c/0/0/0")), "{err}");
    assert!(!store.exists());

    let out = convert("ftp://host/img.zarr", &store, &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("ftp://host/img.zarr") && err.contains("unsupported scheme"),
        "{err}"
    );
    let out = convert(&url, &store, &[("MIXVOL_REMOTE_RETRIES", "many")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("MIXVOL_REMOTE_RETRIES"));
}

/// Mean absolute difference of two PNGs' RGBA8 channels, in 1/255 units.
fn png_difference(a: &Path, b: &Path) -> f64 {
    let a = image::open(a).unwrap().to_rgba8();
    let b = image::open(b).unwrap().to_rgba8();
    assert_eq!(a.dimensions(), b.dimensions());
    let sum: u64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| u64::from(x.abs_diff(y)))
        .sum();
    sum as f64 / a.as_raw().len() as f64
}

#[test]
fn render_stream_over_http_draws_the_converted_store_and_fetches_only_chunks() {
    let dir = TempDir::new("cli-stream");
    let image = dir.0.join("img.zarr");
    spec().write(&image);
    let server = range_server(&dir.0);
    let url = format!("{}/ok/img.zarr", server.base());
    let store = dir.0.join("img.mvl");
    ok(&convert(image.to_str().unwrap(), &store, &[]));
    let render = |volume: &str, png: &Path, stream: bool| {
        let mut args = vec![
            "render",
            "--volume",
            volume,
            "--width",
            "32",
            "--height",
            "32",
            "--frames",
            "1",
            "--brick-size",
            "8",
            "--gpu-budget-mb",
            "4",
            "--ram-budget-mb",
            "8",
            "--output",
            png.to_str().unwrap(),
        ];
        if stream {
            args.push("--stream");
        }
        ok(&mixvol(&args, &[]))
    };
    let streamed = dir.0.join("streamed.png");
    let text = render(&url, &streamed, true);
    assert!(text.contains("(streamed OME-Zarr)"), "{text}");
    // Drawn through the level cache from the image's own (one-level) pyramid: nothing waits.
    assert!(text.contains("from the image's pyramid"), "{text}");
    assert!(text.contains(", 0 bricks still waiting"), "{text}");
    // Every chunk read once (3 x 3 x 3), the missing one costing no bytes: 26 of 8^3 u16. The
    // missing one is counted, and said on stderr (review D7).
    assert!(
        text.contains("fetched 27 chunks (1 absent: the fill value), 0.03 MB stored bytes"),
        "{text}"
    );
    assert!(
        text.contains("warning: ") && text.contains("1 of the 27 chunks fetched do not exist"),
        "{text}"
    );
    let stored = dir.0.join("store.png");
    render(store.to_str().unwrap(), &stored, false);
    let d = png_difference(&streamed, &stored);
    assert!(
        d < 0.5,
        "streamed and stored images differ by {d} / 255 on average"
    );
    // A folder that is not an OME-Zarr image is refused by name.
    let out = mixvol(
        &["render", "--volume", store.to_str().unwrap(), "--stream"],
        &[],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--stream applies to OME-Zarr"));
}

/// Issue 42, item 1 (review D1): `render --stream` of an image whose chunk fetches fail never
/// writes a blank image with exit 0. Every chunk answering 500: exit 1, no PNG, the message
/// names the failed loads and that the view draws nothing. One chunk answering 500: the image
/// is written with its region drawn coarser or not at all, and stderr says so; `--strict`
/// refuses that image (exit 1, no PNG).
#[test]
fn a_streamed_render_with_failed_fetches_never_writes_a_blank_image_with_exit_0() {
    let dir = TempDir::new("cli-stream-500");
    // 5^3 chunks of 8^3 voxels, bricks of 8: a corner chunk feeds only the bricks beside it.
    let image = ImageSpec {
        shape: [40, 40, 40],
        chunks: [8, 8, 8],
        v3: true,
        missing: None,
        fill: 0,
    };
    image.write(&dir.0.join("img.zarr"));
    let server = range_server(&dir.0);
    let quick = [
        ("MIXVOL_REMOTE_TIMEOUT_MS", "2000"),
        ("MIXVOL_REMOTE_RETRIES", "1"),
    ];
    let render = |mode: &str, png: &Path, strict: bool| {
        let url = format!("{}/{mode}/img.zarr", server.base());
        let mut args = vec![
            "render",
            "--volume",
            &url,
            "--stream",
            "--width",
            "32",
            "--height",
            "32",
            "--frames",
            "1",
            "--brick-size",
            "8",
            "--gpu-budget-mb",
            "4",
            "--output",
            png.to_str().unwrap(),
        ];
        if strict {
            args.push("--strict");
        }
        let out = mixvol(&args, &quick);
        let text = format!(
            "{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out, text)
    };
    let png = dir.0.join("all500.png");
    let (out, text) = render("500", &png, false);
    assert!(!out.status.success(), "{text}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bricks failed to load") && err.contains("draws nothing"),
        "{text}"
    );
    assert!(err.contains("500"), "the failure is named: {text}");
    assert!(!png.exists(), "no blank image: {text}");

    // The corner chunk fails, the others are served.
    let key = image.chunk_key([0, 0, 0]).replace('/', "~");
    let one = format!("500@{key}");
    let png = dir.0.join("one500.png");
    let (out, text) = render(&one, &png, false);
    assert!(out.status.success(), "{text}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warning: ") && err.contains("bricks failed to load"),
        "{text}"
    );
    assert!(png.exists(), "{text}");
    let strict = dir.0.join("strict.png");
    let (out, text) = render(&one, &strict, true);
    assert!(!out.status.success(), "{text}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--strict"),
        "{text}"
    );
    assert!(!strict.exists(), "{text}");
    // All chunks served: no warning.
    let (out, text) = render("ok", &dir.0.join("ok.png"), true);
    assert!(out.status.success(), "{text}");
    assert!(
        !String::from_utf8_lossy(&out.stderr).contains("failed to load"),
        "{text}"
    );
}

/// Review H3: a level store behind HTTP renders through the CLI as the local file does: routed
/// to the level store (not the Zarr loader), its stored bricks streamed in the background, the
/// frame matching the CPU reference over the levels read back, validation-clean.
#[test]
fn a_level_store_over_http_renders_and_matches_the_cpu_reference() {
    let dir = TempDir::new("cli-level-http");
    let volume = mixvol::volume::SyntheticField::MarschnerLobb
        .generate(glam::UVec3::splat(32), mixvol::volume::ScalarType::U8)
        .unwrap();
    mixvol::store::write_level_store(
        &dir.0.join("v.mvl"),
        &volume,
        8,
        None,
        mixvol::bricks::DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    let server = range_server(&dir.0);
    let url = format!("{}/ok/v.mvl", server.base());
    let png = dir.0.join("r.png");
    let out = mixvol(
        &[
            "render",
            "--volume",
            &url,
            "--width",
            "32",
            "--height",
            "32",
            "--frames",
            "1",
            "--compare",
            "--validation",
            "-o",
            png.to_str().unwrap(),
        ],
        &[],
    );
    let text = ok(&out);
    assert!(text.contains("(level store)"), "{text}");
    assert!(text.contains("level stream:"), "{text}");
    let line = text
        .lines()
        .find(|l| l.starts_with("cpu reference:"))
        .unwrap_or_else(|| panic!("no comparison in:\n{text}"));
    let max: f64 = line
        .split("difference ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    // The tolerance of the local level-store renders (tests/residency.rs).
    assert!(max < 0.06, "{line}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("validation: 0 warnings/errors")
            || text.contains("validation: 0 warnings/errors"),
        "{text}"
    );
    assert!(png.exists());
}
