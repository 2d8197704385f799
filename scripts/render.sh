#!/usr/bin/env bash
# The main job: renders the built-in default scene (Marschner-Lobb, 128^3) to out/render.png and
# prints its frame timing. Extra arguments go to `mixvol render` (see `--help`).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo run --release --locked -- render "$@"
