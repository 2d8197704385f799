#!/usr/bin/env bash
# Runs the whole test suite: unit tests, CPU-reference tests and the GPU tests, which create
# their Vulkan contexts with VK_LAYER_KHRONOS_validation (synchronization validation on) and fail
# on any validation warning or error. Installs what it needs first, and fetches the real test
# volumes (scripts/fetch-datasets.sh: PyPI and Debian packages, checksummed, idempotent) and the
# Python packages of the fixture writers and the loopback test servers (scripts/python-env.sh: a
# venv under target/ with zarr-python, ome-zarr-py, moto, boto3, nibabel and pydicom, pinned,
# idempotent; the
# remote-store tests start the servers themselves).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
scripts/fetch-datasets.sh
# The Python venv of the tests that run real writers (zarr-python, ome-zarr-py) and real servers
# (moto, the Range server); pinned.
MIXVOL_PYTHON="$(scripts/python-env.sh)"
export MIXVOL_PYTHON
echo "test: MIXVOL_PYTHON=$MIXVOL_PYTHON"
cargo test --release --locked "$@"
