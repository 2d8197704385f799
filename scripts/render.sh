#!/usr/bin/env bash
# The main job: renders the built-in default scene to out/render.png and prints its frame timing
# and residency. Without arguments the scene shows the method: Marschner-Lobb 128^3 drawn
# through the brick cache with camera-driven residency under a 1 MiB GPU budget (the planner
# mixes hi-res and low-res bricks), smooth transitions and Blinn-Phong shading. Arguments replace
# that default and go to `mixvol render` (see `--help`).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
if [ "$#" -eq 0 ]; then
    set -- --gpu-budget-mb 1 --brick-size 16 --transition smooth --shading --frames 3
fi
cargo run --release --locked -- render "$@"
