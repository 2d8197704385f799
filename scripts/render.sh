#!/usr/bin/env bash
# The main job: renders the built-in default scene to out/render.png and prints its frame timing
# and residency. Without arguments the scene shows the method: Marschner-Lobb 128^3 drawn
# through the brick cache with levels chosen from the camera under a 1.25 MiB GPU budget (the
# planner mixes levels 0, 1 and 2 and prints the bricks at each), smooth transitions and
# Blinn-Phong shading. Arguments replace that default and go to `mixvol render` (see `--help`).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
if [ "$#" -eq 0 ]; then
    set -- --levels camera --gpu-budget-mb 1.25 --upload-mb 0.25 --brick-size 16 \
        --eye 0.9,0.6,0.9 --transition smooth --shading --frames 3
fi
cargo run --release --locked -- render "$@"
