//! Bad and awkward inputs through the binary, as one table (issue 16, "What must exist" item 8):
//! each row is the command line, the environment, the exit code and the fragments the message
//! must hold. A new case is one line in [`CASES`].
//!
//! Every run has a deadline, so an input that blocks (a FIFO opened before its type is checked)
//! fails the test instead of hanging it. `MIXVOL_BIN` points the table at another build of the
//! binary (how the cases were checked against the code before the fixes).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// One bad input: `args` with `{d}` standing for the fixture folder.
struct Case {
    /// What the row checks.
    name: &'static str,
    args: &'static [&'static str],
    env: &'static [(&'static str, &'static str)],
    /// The expected exit code (1: a refused command, 2: a usage error).
    code: i32,
    /// Fragments the output (stdout, then stderr) must contain (case-sensitive).
    fragments: &'static [&'static str],
    /// Fragments the output must not contain (the misleading old message).
    absent: &'static [&'static str],
}

const NO_ENV: &[(&str, &str)] = &[];
/// A 1 MiB host-memory limit: every 4 MiB fixture volume is over it.
const SMALL_RAM: &[(&str, &str)] = &[("MIXVOL_HOST_MEMORY_MB", "1")];
/// The test hook that makes one deliberately invalid Vulkan call when validation is on.
const INVALID_CALL: &[(&str, &str)] = &[("MIXVOL_TEST_INVALID_VULKAN_CALL", "1")];

#[rustfmt::skip]
const CASES: &[Case] = &[
    // Item 2: FIFOs are refused without being opened (opening one blocks until a writer comes).
    Case { name: "fifo as the volume", args: &["render", "--volume", "{d}/vol.fifo", "--dims", "4,4,4"], env: NO_ENV, code: 1, fragments: &["vol.fifo", "FIFO"], absent: &[] },
    Case { name: "fifo as an NRRD's data file", args: &["render", "--volume", "{d}/fifo_data.nhdr"], env: NO_ENV, code: 1, fragments: &["data.fifo", "FIFO"], absent: &[] },
    Case { name: "fifo with a volume extension", args: &["render", "--volume", "{d}/pipe.nrrd"], env: NO_ENV, code: 1, fragments: &["pipe.nrrd", "FIFO"], absent: &[] },
    // Item 7 / item 3: the host-memory limit is checked where the header gives the size.
    Case { name: "raw over the host-memory limit", args: &["render", "--volume", "{d}/big.raw", "--dims", "128,128,256"], env: SMALL_RAM, code: 1, fragments: &["big.raw", "host-memory limit", "4194304"], absent: &[] },
    Case { name: "NRRD over the host-memory limit", args: &["render", "--volume", "{d}/big.nhdr"], env: SMALL_RAM, code: 1, fragments: &["big.nhdr", "host-memory limit"], absent: &[] },
    Case { name: "Zarr array over the host-memory limit", args: &["render", "--volume", "{d}/big.zarr"], env: SMALL_RAM, code: 1, fragments: &["big.zarr", "host-memory limit"], absent: &[] },
    // Item 4 / item 3: a synthetic field over the device's maxMemoryAllocationSize is refused
    // before it is generated (it used to be generated for minutes first). The limit is capped
    // at 128 MiB (MIXVOL_GPU_MAX_ALLOCATION_MB) so the same request is refused on every device,
    // and the host-memory limit is set so that only the GPU limit can refuse it.
    Case { name: "a synthetic field over maxMemoryAllocationSize", args: &["render", "--volume", "ml", "--dims", "520,520,520"], env: &[("MIXVOL_HOST_MEMORY_MB", "4096"), ("MIXVOL_GPU_MAX_ALLOCATION_MB", "128")], code: 1, fragments: &["'volume' needs 140608000 bytes", "maxMemoryAllocationSize as capped by MIXVOL_GPU_MAX_ALLOCATION_MB"], absent: &[] },
    Case { name: "a bench field over maxMemoryAllocationSize", args: &["bench", "--volume", "ml", "--dims", "520,520,520", "--frames", "1"], env: &[("MIXVOL_HOST_MEMORY_MB", "4096"), ("MIXVOL_GPU_MAX_ALLOCATION_MB", "128")], code: 1, fragments: &["'volume' needs 140608000 bytes", "maxMemoryAllocationSize as capped by MIXVOL_GPU_MAX_ALLOCATION_MB"], absent: &[] },
    Case { name: "a bad allocation cap", args: &["render", "--volume", "ml", "--dims", "8,8,8"], env: &[("MIXVOL_GPU_MAX_ALLOCATION_MB", "lots")], code: 1, fragments: &["MIXVOL_GPU_MAX_ALLOCATION_MB=\"lots\"", "whole number of MiB"], absent: &[] },
    Case { name: "a brick size no cache can hold", args: &["render", "--volume", "ml", "--dims", "32,32,32", "--levels", "checker", "--brick-size", "1024"], env: NO_ENV, code: 1, fragments: &["cache budget", "one slot"], absent: &[] },
    // Item 5: parameters that gave a wrong image with exit 0 are refused, naming what to change.
    Case { name: "--early-termination 0", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--early-termination", "0"], env: NO_ENV, code: 1, fragments: &["early termination"], absent: &[] },
    Case { name: "negative --early-termination", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--early-termination=-1"], env: NO_ENV, code: 1, fragments: &["early termination"], absent: &[] },
    Case { name: "a voxel side 1e-30 of the others", args: &["render", "--volume", "{d}/small.raw", "--dims", "4,4,4", "--spacing", "1e-30,1,1"], env: NO_ENV, code: 1, fragments: &["voxel spacing"], absent: &[] },
    Case { name: "--clip with a zero normal", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--clip", "0,0,0,0"], env: NO_ENV, code: 1, fragments: &["--clip", "zero normal"], absent: &[] },
    Case { name: "more samples per ray than supported", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--samples-per-voxel", "1e9"], env: NO_ENV, code: 1, fragments: &["samples per voxel", "at most 16777216"], absent: &[] },
    // Item 9: messages that named the wrong cause.
    Case { name: "huge --header-bytes", args: &["render", "--volume", "{d}/small.raw", "--dims", "4,4,4", "--header-bytes", "18446744073709551615"], env: NO_ENV, code: 1, fragments: &["small.raw", "18446744073709551615 header bytes"], absent: &["dimensions"] },
    // Issue 36: one GPU budget flag for every scene (--cache-mb is gone), fractions allowed.
    Case { name: "--gpu-budget-mb past u64 bytes", args: &["render", "--volume", "ml", "--dims", "16,16,16", "--levels", "checker", "--gpu-budget-mb", "17592186044416"], env: NO_ENV, code: 1, fragments: &["--gpu-budget-mb 17592186044416: expected a positive number of MiB (at most 1e9)"], absent: &[] },
    Case { name: "--gpu-budget-mb zero", args: &["render", "--volume", "ml", "--dims", "16,16,16", "--levels", "checker", "--gpu-budget-mb", "0"], env: NO_ENV, code: 1, fragments: &["--gpu-budget-mb 0: expected a positive number of MiB"], absent: &[] },
    Case { name: "--gpu-budget-mb takes fractions for a fixed pattern", args: &["render", "--volume", "ml", "--dims", "16,16,16", "--levels", "checker", "--brick-size", "8", "--gpu-budget-mb", "0.3", "--upload-mb", "0.05", "--width", "16", "--height", "16", "-o", "{d}/fraction.png"], env: NO_ENV, code: 0, fragments: &["brick cache: 8 bricks of 8^3 at levels 0..=1 ([4, 4] bricks per level)"], absent: &[] },
    Case { name: "--cache-mb is gone", args: &["render", "--volume", "ml", "--dims", "16,16,16", "--levels", "checker", "--cache-mb", "1"], env: NO_ENV, code: 2, fragments: &["--cache-mb"], absent: &[] },
    Case { name: "corrupt gzip NRRD", args: &["render", "--volume", "{d}/corrupt_gzip.nrrd"], env: NO_ENV, code: 1, fragments: &["corrupt_gzip.nrrd", "corrupt gzip data"], absent: &["holds more than"] },
    Case { name: "longer gzip NRRD", args: &["render", "--volume", "{d}/long_gzip.nrrd"], env: NO_ENV, code: 1, fragments: &["long_gzip.nrrd", "decodes intact to 65 bytes", "64 bytes described"], absent: &[] },
    Case { name: "NaN in a raw file", args: &["render", "--volume", "{d}/nan.raw", "--dims", "2,2,2", "--scalar", "f32"], env: NO_ENV, code: 1, fragments: &["nan.raw: voxel 2", "NaN"], absent: &[] },
    Case { name: "NaN in an NRRD", args: &["render", "--volume", "{d}/nan.nrrd"], env: NO_ENV, code: 1, fragments: &["nan.nrrd: voxel 2", "NaN"], absent: &[] },
    Case { name: "folder without Zarr metadata", args: &["render", "--volume", "{d}/plain_folder"], env: NO_ENV, code: 1, fragments: &["plain_folder", "folder without Zarr metadata"], absent: &["not a regular file"] },
    Case { name: "unknown extension read as raw", args: &["render", "--volume", "{d}/v.xyz"], env: NO_ENV, code: 1, fragments: &["v.xyz", "matches no known format", "headerless raw", "--dims 128,128,128"], absent: &[] },
    // Item 8: validation summaries on success and failure, and a logger.
    Case { name: "bench --validation prints the summary", args: &["bench", "--volume", "ml", "--dims", "16,16,16", "--frames", "2", "--validation"], env: NO_ENV, code: 0, fragments: &["validation: 0 warnings/errors"], absent: &[] },
    Case { name: "a failing render prints the summary", args: &["render", "--volume", "ml", "--dims", "16,16,16", "--validation", "-o", "/dev/full"], env: NO_ENV, code: 1, fragments: &["validation (the command failed): 0 warnings/errors", "/dev/full"], absent: &[] },
    // Items 6 / 8: a real validation-layer message (one deliberately invalid vkCreateBuffer,
    // the MIXVOL_TEST_INVALID_VULKAN_CALL hook) reaches stderr as it arrives (through the
    // logger) and in the summary, which counts it and fails the command. The VUID and "The
    // Vulkan spec states" are the layer's words, not mixvol's.
    Case { name: "a validation message reaches stderr and the summary", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--frames", "1", "--validation"], env: INVALID_CALL, code: 1, fragments: &["[ERROR mixvol::gpu::validation] [vulkan] VUID-VkBufferCreateInfo-", "The Vulkan spec states", "validation: 1 warnings/errors", "  Error VUID-VkBufferCreateInfo-", "validation reported 1 problem(s)"], absent: &[] },
    Case { name: "a failing render lists the layer's message", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--frames", "1", "--validation", "-o", "/dev/full"], env: INVALID_CALL, code: 1, fragments: &["validation (the command failed): 1 warnings/errors", "  Error VUID-VkBufferCreateInfo-", "The Vulkan spec states", "/dev/full"], absent: &[] },
    Case { name: "bench --validation reads the message log", args: &["bench", "--volume", "ml", "--dims", "8,8,8", "--frames", "1", "--width", "32", "--height", "32", "--validation"], env: INVALID_CALL, code: 1, fragments: &["validation: 1 warnings/errors", "  Error VUID-VkBufferCreateInfo-", "The Vulkan spec states"], absent: &[] },
    Case { name: "the invalid-call hook needs validation", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--frames", "1"], env: INVALID_CALL, code: 0, fragments: &["wrote "], absent: &["VUID", "validation:"] },
    Case { name: "RUST_LOG reaches the library's log", args: &["render", "--volume", "ml", "--dims", "8,8,8"], env: &[("RUST_LOG", "info")], code: 0, fragments: &["[INFO mixvol::gpu::context] device: "], absent: &[] },
    Case { name: "--verbose logs at info", args: &["render", "--verbose", "--volume", "ml", "--dims", "8,8,8"], env: NO_ENV, code: 0, fragments: &["[INFO mixvol::gpu::context] device: "], absent: &[] },
    // Issue 42, item 7 (review D10): nothing waits forever: a camera path on a FIFO is refused
    // without being opened, and --frames has the bound --orbit has.
    Case { name: "--path on a FIFO", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--path", "{d}/path.fifo"], env: NO_ENV, code: 1, fragments: &["path.fifo", "not a regular file (a FIFO, device or socket)", "camera path JSON file"], absent: &[] },
    Case { name: "--path on a folder", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--path", "{d}/plain_folder"], env: NO_ENV, code: 1, fragments: &["plain_folder", "not a regular file (a folder)"], absent: &[] },
    Case { name: "render --frames past the bound", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--frames", "4294967295"], env: NO_ENV, code: 1, fragments: &["--frames 4294967295: expected 1 to 100000 frames"], absent: &[] },
    Case { name: "bench --frames past the bound", args: &["bench", "--volume", "ml", "--dims", "8,8,8", "--frames", "100001"], env: NO_ENV, code: 1, fragments: &["--frames 100001: expected 1 to 100000 frames"], absent: &[] },
    Case { name: "render --frames 0", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--frames", "0"], env: NO_ENV, code: 1, fragments: &["--frames 0: expected 1 to 100000 frames"], absent: &[] },
    // Issue 42, item 8 (review D20, D23, D24): the real cause, or the folder made.
    Case { name: "--frames-dir naming a file", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--orbit", "2", "--frames-dir", "{d}/small.raw"], env: NO_ENV, code: 1, fragments: &["--frames-dir", "small.raw is a file, not a folder"], absent: &["File exists"] },
    Case { name: "convert a damaged old brick store", args: &["convert", "{d}/made.mvb", "{d}/again.mvl"], env: NO_ENV, code: 1, fragments: &["made.mvb", "brick store"], absent: &["no known header", "panicked"] },
    Case { name: "render an old brick store", args: &["render", "--volume", "{d}/made.mvb"], env: NO_ENV, code: 1, fragments: &["made.mvb is a two-level brick store", "made.mvb NEW.mvl`"], absent: &["headerless raw"] },
    Case { name: "convert a level store", args: &["convert", "{d}/made.mvl", "{d}/again.mvl"], env: NO_ENV, code: 1, fragments: &["made.mvl is a level store", "converted already", "mixvol render --volume"], absent: &["no known header"] },
    Case { name: "convert into folders not made yet", args: &["convert", "ml", "{d}/nodir/sub/x.mvl", "--dims", "16,16,16"], env: NO_ENV, code: 0, fragments: &["nodir/sub/x.mvl (16x16x16 voxels"], absent: &[] },
    // Issue 42, item 8 (review D17, D29): option variables are checked by name, never ignored,
    // and not called synthetic-field parameters.
    Case { name: "MIXVOL_HOST_MEMORY_MB not a number", args: &["render", "--volume", "ml", "--dims", "8,8,8"], env: &[("MIXVOL_HOST_MEMORY_MB", "abc")], code: 1, fragments: &["environment variable MIXVOL_HOST_MEMORY_MB=\"abc\": expected a whole number of MiB"], absent: &[] },
    Case { name: "MIXVOL_REMOTE_TIMEOUT_MS zero", args: &["render", "--volume", "http://127.0.0.1:9/img.zarr"], env: &[("MIXVOL_REMOTE_TIMEOUT_MS", "0")], code: 1, fragments: &["environment variable MIXVOL_REMOTE_TIMEOUT_MS=\"0\": a timeout must be at least 1 ms"], absent: &["synthetic field"] },
    Case { name: "MIXVOL_REMOTE_RETRIES not a number", args: &["render", "--volume", "http://127.0.0.1:9/img.zarr"], env: &[("MIXVOL_REMOTE_RETRIES", "abc")], code: 1, fragments: &["environment variable MIXVOL_REMOTE_RETRIES=\"abc\": expected a whole number"], absent: &["synthetic field"] },
    // Issue 42, item 8 (review D19): a JSON or CSV output that fails to write is named as what
    // it is, not as an image.
    Case { name: "--stats-json on a full device", args: &["convert", "ml", "{d}/stats.mvl", "--dims", "16,16,16", "--stats-json", "/dev/full"], env: NO_ENV, code: 1, fragments: &["cannot write the stats JSON /dev/full"], absent: &["image"] },
    Case { name: "bench --json on a full device", args: &["bench", "--volume", "ml", "--dims", "8,8,8", "--frames", "1", "--width", "16", "--height", "16", "--json", "/dev/full"], env: NO_ENV, code: 1, fragments: &["cannot write the results JSON /dev/full"], absent: &["cannot write image"] },
    Case { name: "the frame log on a full device", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--width", "16", "--height", "16", "--frame-log", "/dev/full"], env: NO_ENV, code: 1, fragments: &["cannot write the frame log /dev/full"], absent: &["cannot write image"] },
    // Issue 42, item 8 (review D29): a background colour outside [0, 1] is refused (NaN gave
    // black, 5 gave white, without a word).
    Case { name: "--background NaN", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--background", "NaN,0,0"], env: NO_ENV, code: 2, fragments: &["--background", "expected r,g,b each in [0, 1], got 'NaN,0,0'"], absent: &[] },
    Case { name: "--background past 1", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--background", "5,5,5"], env: NO_ENV, code: 2, fragments: &["expected r,g,b each in [0, 1], got '5,5,5'"], absent: &[] },
    // Issue 42, item 8 (review D22): a store whose magic is damaged is not read as raw data.
    Case { name: "a store with a damaged magic", args: &["render", "--volume", "{d}/damaged.mvb"], env: NO_ENV, code: 1, fragments: &["damaged.mvb", "\"MIXVOLBX\"", "neither a brick store (MIXVOLBS) nor a level store"], absent: &["headerless raw"] },
    // Issue 42, item 8 (review D26): an empty chunk file is named as such, not blamed on a field.
    Case { name: "an empty Zarr chunk file", args: &["render", "--volume", "{d}/empty_chunk.zarr"], env: NO_ENV, code: 1, fragments: &["empty_chunk.zarr/0.0.0", "is empty (0 bytes), where 64 bytes decoded are expected"], absent: &["chunk_grid", "`chunks`"] },
    Case { name: "a Zarr array of millions of one-voxel chunks (D8)", args: &["render", "--volume", "{d}/tiny_chunks.zarr"], env: NO_ENV, code: 1, fragments: &["tiny_chunks.zarr/.zarray", "field `chunks`", "2097152 chunks of 1 bytes", "rechunk"], absent: &["panicked"] },
    Case { name: "a gzip Zarr chunk that inflates past its size (D9)", args: &["render", "--volume", "{d}/gzip_bomb.zarr"], env: NO_ENV, code: 1, fragments: &["gzip_bomb.zarr/0.0.0", "inflates past the 64 bytes the chunk holds"], absent: &["panicked"] },
    // Issue 42, item 3 (review D4): convert replaces only a regular file, even with --force.
    Case { name: "convert onto a FIFO with --force", args: &["convert", "ml", "{d}/store.fifo", "--dims", "16,16,16", "--force"], env: NO_ENV, code: 1, fragments: &["store.fifo", "not a regular file", "even with --force"], absent: &[] },
    Case { name: "convert onto a link with --force", args: &["convert", "ml", "{d}/store_link.mvl", "--dims", "16,16,16", "--force"], env: NO_ENV, code: 1, fragments: &["store_link.mvl", "symbolic link"], absent: &[] },
    // Issue 42, items 1 and 5 (review D1, D6): a brick that fails its check is an outcome the
    // caller sees: with --strict the image is refused, naming the failure.
    Case { name: "corrupt stored bricks under --strict", args: &["render", "--volume", "{d}/corrupt.mvl", "--gpu-budget-mb", "0.3", "--width", "16", "--height", "16", "--frames", "1", "--strict", "-o", "{d}/strict.png"], env: NO_ENV, code: 1, fragments: &["bricks failed to load", "is corrupt", "--strict", "no image written"], absent: &["wrote "] },
    // Issue 42, item 8 (review D21, D22, D28): one stated brick-size range, a level store's
    // errors named as such, an empty source and a path file that is not an object named.
    Case { name: "--brick-size 2 with a brick cache", args: &["render", "--volume", "ml", "--dims", "64,64,64", "--gpu-budget-mb", "4", "--brick-size", "2"], env: NO_ENV, code: 1, fragments: &["--brick-size 2: expected a power of two between 4 and 1024"], absent: &[] },
    Case { name: "--brick-size 0 with a brick cache", args: &["render", "--volume", "ml", "--dims", "64,64,64", "--gpu-budget-mb", "4", "--brick-size", "0"], env: NO_ENV, code: 1, fragments: &["--brick-size 0: expected a power of two between 4 and 1024"], absent: &["between 2 and"] },
    Case { name: "a level store cut short", args: &["render", "--volume", "{d}/cut.mvl"], env: NO_ENV, code: 1, fragments: &["level store ", "cut.mvl", "field `file_size`"], absent: &["brick store"] },
    Case { name: "an empty --volume", args: &["render", "--volume", ""], env: NO_ENV, code: 2, fragments: &["'--volume <VOLUME>': empty: expected a file, folder, URL or synthetic field"], absent: &["cannot read volume file"] },
    Case { name: "an empty convert INPUT", args: &["convert", "", "{d}/empty.mvl"], env: NO_ENV, code: 2, fragments: &["empty: expected a file, folder, URL"], absent: &[] },
    Case { name: "a path file holding an array", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--path", "{d}/array_top.json"], env: NO_ENV, code: 1, fragments: &["array_top.json", "must be a JSON object with \"keyframes\""], absent: &["expected struct PathJson"] },
    // Issue 42, item 6 (review D7): a Zarr level whose chunks are all absent is an error, one
    // with some absent a warning (both gave a blank image, exit 0, without a word).
    Case { name: "Zarr chunks under another separator", args: &["render", "--volume", "{d}/separator.zarr", "--width", "16", "--height", "16"], env: NO_ENV, code: 1, fragments: &["separator.zarr", "none of the 1 chunks of the level exists", "dimension_separator"], absent: &["wrote "] },
    Case { name: "streamed Zarr chunks under another separator", args: &["render", "--volume", "{d}/separator.zarr", "--stream", "--brick-size", "4", "--width", "16", "--height", "16"], env: NO_ENV, code: 1, fragments: &["separator.zarr", "none of the 1 chunks fetched exists", "dimension_separator", "no image written"], absent: &["wrote "] },
    Case { name: "Zarr level with a chunk absent", args: &["render", "--volume", "{d}/half.zarr", "--width", "16", "--height", "16"], env: NO_ENV, code: 0, fragments: &["warning: ", "half.zarr: 1 of 2 chunks exist; the rest read as the fill value"], absent: &[] },
    Case { name: "--device matching nothing", args: &["render", "--volume", "ml", "--dims", "8,8,8", "--device", "no-such-gpu-x"], env: NO_ENV, code: 1, fragments: &["matching 'no-such-gpu-x'", "devices present: "], absent: &["rejected: []"] },
];

/// The binary under test: `MIXVOL_BIN` when set, else this build's.
fn binary() -> PathBuf {
    std::env::var_os("MIXVOL_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_mixvol")))
}

/// Makes a FIFO at `path` (through `mkfifo`, as a user would).
fn mkfifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(status.success(), "mkfifo {}", path.display());
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(bytes).unwrap();
    enc.finish().unwrap()
}

/// An attached NRRD header of a 4x4x4 (or `sizes`) volume of `ty` in `encoding`.
fn nrrd_header(ty: &str, sizes: &str, encoding: &str, data_file: Option<&str>) -> Vec<u8> {
    let mut h =
        format!("NRRD0004\ntype: {ty}\ndimension: 3\nsizes: {sizes}\nencoding: {encoding}\n");
    if let Some(f) = data_file {
        h.push_str(&format!("data file: {f}\n"));
    } else {
        h.push('\n');
    }
    h.into_bytes()
}

/// Makes the folder of a Zarr v2 array of u8 (raw chunks, fill value 0) of `shape` in chunks of
/// `chunks` (JSON arrays), with no chunk written.
fn zarr_u8(dir: &Path, shape: &str, chunks: &str) {
    std::fs::create_dir(dir).unwrap();
    std::fs::write(
        dir.join(".zarray"),
        format!(
            r#"{{"zarr_format":2,"shape":{shape},"chunks":{chunks},"dtype":"|u1","compressor":null,"fill_value":0,"order":"C","filters":null}}"#
        ),
    )
    .unwrap();
}

/// Writes every fixture the table names into `d`.
fn fixtures(d: &Path) {
    mkfifo(&d.join("vol.fifo"));
    mkfifo(&d.join("data.fifo"));
    mkfifo(&d.join("pipe.nrrd"));
    mkfifo(&d.join("store.fifo"));
    mkfifo(&d.join("path.fifo"));
    // Files that start like mixvol's stores (convert reads the magic only to refuse them).
    std::fs::write(d.join("made.mvb"), b"MIXVOLBS and then not a store").unwrap();
    std::fs::write(d.join("made.mvl"), b"MIXVOLLV and then not a store").unwrap();
    std::fs::write(d.join("damaged.mvb"), b"MIXVOLBX and then a store's bytes").unwrap();
    std::os::unix::fs::symlink(d.join("small.raw"), d.join("store_link.mvl")).unwrap();
    std::fs::write(
        d.join("fifo_data.nhdr"),
        nrrd_header("uint8", "4 4 4", "raw", Some("data.fifo")),
    )
    .unwrap();
    // 4 MiB of zeros, sparse.
    let big = std::fs::File::create(d.join("big.raw")).unwrap();
    big.set_len(128 * 128 * 256).unwrap();
    std::fs::write(
        d.join("big.nhdr"),
        nrrd_header("uint8", "128 128 256", "raw", Some("big.raw")),
    )
    .unwrap();
    // A Zarr v2 array of 4 MiB with no chunk written (all fill value).
    zarr_u8(&d.join("big.zarr"), "[256,128,128]", "[64,128,128]");
    std::fs::write(d.join("small.raw"), [0u8; 64]).unwrap();
    // A Zarr v2 array of one 4x4x4 raw chunk whose file is empty.
    zarr_u8(&d.join("empty_chunk.zarr"), "[4,4,4]", "[4,4,4]");
    std::fs::write(d.join("empty_chunk.zarr/0.0.0"), b"").unwrap();
    // A Zarr v2 array of 128^3 one-voxel chunks, none written.
    zarr_u8(&d.join("tiny_chunks.zarr"), "[128,128,128]", "[1,1,1]");
    // A Zarr v2 array of one 4x4x4 gzip chunk that inflates to 16 MiB of zeros.
    zarr_u8(&d.join("gzip_bomb.zarr"), "[4,4,4]", "[4,4,4]");
    let zarray = std::fs::read_to_string(d.join("gzip_bomb.zarr/.zarray")).unwrap();
    std::fs::write(
        d.join("gzip_bomb.zarr/.zarray"),
        zarray.replace(
            r#""compressor":null"#,
            r#""compressor":{"id":"gzip","level":1}"#,
        ),
    )
    .unwrap();
    let mut bomb = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut bomb, &vec![0u8; 16 << 20]).unwrap();
    std::fs::write(d.join("gzip_bomb.zarr/0.0.0"), bomb.finish().unwrap()).unwrap();
    // A gzip stream of 65 bytes whose CRC is wrong: it decodes past the 64 bytes described
    // and then fails its checksum (the data is corrupt, not longer).
    let mut corrupt = gzip(&[7u8; 65]);
    let crc_at = corrupt.len() - 8;
    corrupt[crc_at] ^= 0xff;
    let mut file = nrrd_header("uint8", "4 4 4", "gzip", None);
    file.extend_from_slice(&corrupt);
    std::fs::write(d.join("corrupt_gzip.nrrd"), file).unwrap();
    let mut file = nrrd_header("uint8", "4 4 4", "gzip", None);
    file.extend_from_slice(&gzip(&[7u8; 65]));
    std::fs::write(d.join("long_gzip.nrrd"), file).unwrap();
    let floats: Vec<u8> = [0.0f32, 1.0, f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(d.join("nan.raw"), &floats).unwrap();
    let mut file = nrrd_header("float", "2 2 2", "raw", None);
    file.splice(
        b"NRRD0004\n".len()..b"NRRD0004\n".len(),
        b"endian: little\n".iter().copied(),
    );
    file.extend_from_slice(&floats);
    std::fs::write(d.join("nan.nrrd"), file).unwrap();
    std::fs::create_dir(d.join("plain_folder")).unwrap();
    // A level store of 32^3 voxels whose every level-0 stored brick (the first in the file)
    // has one byte flipped: the coarser levels still read.
    let volume = mixvol::volume::SyntheticField::MarschnerLobb
        .generate(glam::UVec3::splat(32), mixvol::volume::ScalarType::U8)
        .unwrap();
    let store = d.join("corrupt.mvl");
    let summary = mixvol::store::write_level_store(
        &store,
        &volume,
        16,
        None,
        mixvol::bricks::DownsampleFilter::Mean2,
        &mut |_, _| {},
    )
    .unwrap();
    let h = summary.header;
    let mut bytes = std::fs::read(&store).unwrap();
    for brick in 0..8 {
        let at = h.data_offset + brick * h.stored_bytes(0) + 7;
        bytes[at as usize] ^= 0x5A;
    }
    std::fs::write(&store, &bytes).unwrap();
    std::fs::write(d.join("v.xyz"), [0u8; 64]).unwrap();
    // A Zarr v2 array whose .zarray says "/" while its chunk is stored as 0.0.0, and one of
    // two chunks with only the first written.
    zarr_u8(&d.join("separator.zarr"), "[4,4,4]", "[4,4,4]");
    let zarray = std::fs::read_to_string(d.join("separator.zarr/.zarray")).unwrap();
    std::fs::write(
        d.join("separator.zarr/.zarray"),
        zarray.replace(r#""order":"C""#, r#""order":"C","dimension_separator":"/""#),
    )
    .unwrap();
    std::fs::write(d.join("separator.zarr/0.0.0"), [9u8; 64]).unwrap();
    zarr_u8(&d.join("half.zarr"), "[8,4,4]", "[4,4,4]");
    std::fs::write(d.join("half.zarr/0.0.0"), [200u8; 64]).unwrap();
    // A level store cut 100 bytes short, and a camera path that is a JSON array.
    let mut cut = std::fs::read(&store).unwrap();
    cut.truncate(cut.len() - 100);
    std::fs::write(d.join("cut.mvl"), cut).unwrap();
    std::fs::write(d.join("array_top.json"), "[2]").unwrap();
}

/// Runs `args` with `env` and a deadline; returns the exit code and the output (stdout, then
/// stderr), or `None` when the run did not end in time (it is killed).
fn run(args: &[String], env: &[(&str, &str)], deadline: Duration) -> Option<(i32, String)> {
    let mut cmd = Command::new(binary());
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .env_remove("MIXVOL_HOST_MEMORY_MB")
        .env_remove("MIXVOL_TEST_INVALID_VULKAN_CALL")
        .env_remove("MIXVOL_REMOTE_TIMEOUT_MS")
        .env_remove("MIXVOL_REMOTE_RETRIES")
        .env_remove("RUST_LOG");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().unwrap();
    // Read both pipes on threads, so a chatty child never blocks on a full pipe.
    let drain = |mut pipe: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            pipe.read_to_string(&mut s).ok();
            s
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let text = out.join().unwrap() + &err.join().unwrap();
            return Some((status.code().unwrap_or(-1), text));
        }
        if start.elapsed() > deadline {
            child.kill().ok();
            child.wait().ok();
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn every_bad_input_is_refused_with_its_reason() {
    let dir = std::env::temp_dir().join(format!("mixvol-bad-inputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    fixtures(&dir);
    let d = dir.to_str().unwrap();
    let mut failures = Vec::new();
    for case in CASES {
        let mut args: Vec<String> = case.args.iter().map(|a| a.replace("{d}", d)).collect();
        if args[0] == "render" && !args.iter().any(|a| a == "-o") {
            args.extend(["-o".to_string(), format!("{d}/out.png")]);
        }
        match run(&args, case.env, Duration::from_secs(60)) {
            None => failures.push(format!(
                "{}: still running after 60 s (it hangs)",
                case.name
            )),
            Some((code, err)) => {
                let missing: Vec<_> = case
                    .fragments
                    .iter()
                    .filter(|f| !err.contains(*f))
                    .collect();
                let present: Vec<_> = case.absent.iter().filter(|f| err.contains(*f)).collect();
                if code != case.code || !missing.is_empty() || !present.is_empty() {
                    failures.push(format!(
                        "{}: exit {code} (want {}), missing {missing:?}, misleading {present:?}; \
                         output:\n{err}",
                        case.name, case.code
                    ));
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        CASES.len(),
        failures.join("\n\n")
    );
}
