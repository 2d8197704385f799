#!/usr/bin/env bash
# Runs the whole test suite: unit tests, CPU-reference tests and the GPU tests, which create
# their Vulkan contexts with VK_LAYER_KHRONOS_validation (synchronization validation on) and fail
# on any validation warning or error. Installs what it needs first, and fetches the real test
# volumes (scripts/fetch-datasets.sh: PyPI and Debian packages, checksummed, idempotent), and
# the Python environment of the loopback test servers (scripts/python-env.sh: target/pyenv with
# moto and boto3 from PyPI; the remote-store tests start the servers themselves).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
scripts/fetch-datasets.sh
scripts/python-env.sh
cargo test --release --locked "$@"
