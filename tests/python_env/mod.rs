//! The Python of the tests that run real writers and servers (zarr-python, ome-zarr-py, nibabel,
//! moto): `MIXVOL_PYTHON`, which scripts/test.sh exports, else the venv scripts/python-env.sh
//! creates at target/python-venv. Included by the library's tests and, through
//! tests/remote_util, by the CLI crate's.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The environment variable naming the venv's python.
pub const PYTHON_ENV: &str = "MIXVOL_PYTHON";

/// The repository root (this file is compiled into tests of the library and of crates/*).
pub fn repo_root() -> PathBuf {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    if here.join("scripts/python-env.sh").is_file() {
        here
    } else {
        here.join("../..")
    }
}

/// The python to run generators and servers with; panics (the test fails, never skips) with
/// what to run when neither `MIXVOL_PYTHON` nor the venv exists. `needs` says what the caller
/// wants from it, for the message.
pub fn python(needs: &str) -> PathBuf {
    let python = std::env::var_os(PYTHON_ENV)
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("target/python-venv/bin/python"));
    assert!(
        python.is_file(),
        "the test Python {} does not exist: run scripts/python-env.sh (scripts/test.sh does, and \
         exports {PYTHON_ENV}) to install {needs}",
        python.display()
    );
    python
}

/// Runs the fixture generator `tests/fixtures/SCRIPT` into a fresh folder `dir_name` under the
/// test target's temporary folder and returns that folder; panics with the generator's output
/// when it fails (`requirements`: the requirements file its packages come from).
pub fn write_fixtures(script: &str, dir_name: &str, requirements: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(dir_name);
    let _ = std::fs::remove_dir_all(&dir);
    let script = repo_root().join("tests/fixtures").join(script);
    let python = python(requirements);
    let out = Command::new(&python)
        .arg(&script)
        .arg(&dir)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run {} ({PYTHON_ENV}): {e}; scripts/python-env.sh makes the venv and \
                 prints its python",
                python.display()
            )
        });
    assert!(
        out.status.success(),
        "{} {} failed ({}; is it the venv of scripts/python-env.sh, with {requirements}?):\n{}\n{}",
        python.display(),
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}
