#!/usr/bin/env bash
# Creates (once) the Python virtual environment the tests use, target/python-venv, and installs the
# pinned PyPI packages of every requirements file listed below into it. Idempotent: when the venv
# already holds exactly these requirement files (a stamp of their contents), nothing is run.
# Prints the venv's python on stdout (the only line on stdout; pip's output goes to stderr), for
# scripts/test.sh to export as MIXVOL_PYTHON.
set -euo pipefail
cd "$(dirname "$0")/.."

# One line per requirements file; each is installed into the same venv.
requirements=(
  scripts/requirements-zarr.txt
  scripts/requirements-servers.txt
  scripts/requirements-nifti.txt
  scripts/requirements-tiff.txt
  scripts/requirements-dicom.txt
)

venv="$PWD/target/python-venv"
python="$venv/bin/python"
stamp="$venv/.mixvol-requirements.sha256"
want="$(cat "${requirements[@]}" | sha256sum | cut -d' ' -f1)"

if [ -x "$python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  echo "python-env: $venv is up to date" >&2
else
  if [ ! -x "$python" ]; then
    echo "python-env: creating $venv" >&2
    mkdir -p "$(dirname "$venv")"
    # Debian's python3 (python3-venv, installed by scripts/setup.sh), not whatever shim is first
    # on PATH.
    base=/usr/bin/python3
    [ -x "$base" ] || base="$(command -v python3)"
    "$base" -m venv "$venv"
  fi
  args=()
  for r in "${requirements[@]}"; do args+=(-r "$r"); done
  echo "python-env: installing ${requirements[*]} into $venv" >&2
  "$python" -m pip install --disable-pip-version-check --no-input -q "${args[@]}" >&2
  echo "$want" >"$stamp"
fi
echo "$python"
