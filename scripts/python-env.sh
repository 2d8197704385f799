#!/usr/bin/env bash
# Creates the Python virtual environment the tests use ($MIXVOL_PYENV, default target/pyenv) and
# installs the pinned requirements files into it, idempotently: a requirements file already
# installed (its checksum recorded in the venv) is not installed again, so a second run needs no
# network.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${MIXVOL_PYENV:-target/pyenv}"
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
install() { # install REQUIREMENTS_FILE
  local stamp sum
  stamp="$venv/.installed-$(basename "$1")"
  sum="$(sha256sum "$1" | cut -d' ' -f1)"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$sum" ]; then
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$1"
    echo "$sum" >"$stamp"
  fi
}
install scripts/requirements-servers.txt
