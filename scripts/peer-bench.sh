#!/usr/bin/env bash
# The peer benchmark (optional; not part of the README's two commands): VTK's GPU ray-cast mapper
# and mixvol on the same volumes, camera, transfer function, step and image size, interleaved in
# one run, printing ratios and writing both images side by side (scripts/peer/vtk_vs_mixvol.py
# says exactly what is compared). Installs what it needs, idempotently: the EGL packages VTK's
# headless window needs (through scripts/setup.sh), a Python venv at target/peer-venv with the
# pinned scripts/peer/requirements.txt (VTK from PyPI), the MNI152 template
# (scripts/fetch-datasets.sh), and a release build of the CLI.
#
#   scripts/peer-bench.sh                       # both scenes, unshaded and shaded, 512x512
#   scripts/peer-bench.sh --size 256 --rounds 1 --frames 3 --scenes ml --shading on
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/setup.sh libegl1 libegl-mesa0 libgl1-mesa-dri
scripts/fetch-datasets.sh

venv=target/peer-venv
requirements=scripts/peer/requirements.txt
stamp="$venv/.requirements"
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$requirements" "$stamp"; then
  echo "peer-bench: installing $(grep -v '^#' "$requirements" | tr '\n' ' ')into $venv"
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$requirements"
  cp "$requirements" "$stamp"
fi

cargo build --release --locked -p mixvol-cli
data="${MIXVOL_DATA_DIR:-target/datasets}"
exec env VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow "$venv/bin/python" scripts/peer/vtk_vs_mixvol.py \
  --mixvol target/release/mixvol --mni "$data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii" "$@"
