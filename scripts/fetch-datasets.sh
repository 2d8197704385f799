#!/usr/bin/env bash
# Fetches the real volumes used by tests/formats.rs and demos into $MIXVOL_DATA_DIR (default
# target/datasets), from the package registries, and checks their SHA-256 sums:
#
#   mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz  MNI ICBM152 2009a T1 template, 197x233x189
#       u8, 1 mm; from the nilearn wheel on PyPI (pip download --no-deps).
#   mni_icbm152_t1_tal_nlin_sym_09a_converted.nii     the same, decompressed (converted here).
#   brainsmall.den     VolPack's MRI head, 128x128x84 u8 with a 62-byte header; from Debian's
#       libvolpack1-dev examples (apt-get download, no root needed once the lists are present).
#   brainsmall.nhdr    a detached NRRD header for brainsmall.den (byte skip 62), written here.
#   LICENSE.nilearn, icbm152_2009.rst, copyright.volpack   the licence texts that come with them.
#
# Idempotent: when every file is present with the recorded checksum it only says so (no network).
# A checksum mismatch after a download is an error. See docs/datasets.md for the licences.
set -euo pipefail
cd "$(dirname "$0")/.."

dest="${MIXVOL_DATA_DIR:-target/datasets}"

NILEARN_VERSION=0.14.1
MNI_MEMBER=nilearn/datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz
MNI_GZ=mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz
MNI_NII=mni_icbm152_t1_tal_nlin_sym_09a_converted.nii
MNI_GZ_SHA256=421a10e872fd6cadae7f61d358dffbcc1795a497d61ee76c5dda2503e1a1e9e6
MNI_NII_SHA256=eeb8a792a93948c83462305c71db783800e95eb3f6ce35975a4dd0f374f79bff

VOLPACK_PACKAGE=libvolpack1-dev
VOLPACK_VERSION=1.0b3-9
DEN=brainsmall.den
DEN_SHA256=eebfa050a1775f556718c2c9716cb624bc2270392e82176b1ce4812b36d4f286

# "NAME SHA256" for every checked file.
checked=(
  "$MNI_GZ $MNI_GZ_SHA256"
  "$MNI_NII $MNI_NII_SHA256"
  "$DEN $DEN_SHA256"
)
extras=(brainsmall.nhdr LICENSE.nilearn icbm152_2009.rst copyright.volpack)

ok() { # ok NAME SHA256: the file exists with that checksum
  [ -f "$dest/$1" ] && [ "$(sha256sum "$dest/$1" | cut -d' ' -f1)" = "$2" ]
}

verify() { # verify FILE SHA256: fail loudly on a mismatch
  local got
  got="$(sha256sum "$1" | cut -d' ' -f1)"
  if [ "$got" != "$2" ]; then
    echo "fetch-datasets: checksum mismatch for $1: got $got, expected $2" >&2
    exit 1
  fi
}

all_ok=1
for entry in "${checked[@]}"; do
  ok ${entry} || all_ok=0
done
for f in "${extras[@]}"; do
  [ -f "$dest/$f" ] || all_ok=0
done
if [ "$all_ok" = 1 ]; then
  echo "fetch-datasets: up to date in $dest"
  exit 0
fi

mkdir -p "$dest"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

as_root() { # runs a command as root (directly or with sudo)
  if [ "$(id -u)" -eq 0 ]; then "$@"; elif command -v sudo >/dev/null 2>&1; then sudo "$@"; else
    echo "fetch-datasets: need root or sudo for: $*" >&2; return 1
  fi
}

python=python3
command -v "$python" >/dev/null 2>&1 || { echo "fetch-datasets: python3 is needed" >&2; exit 1; }

# --- MNI ICBM152 2009a T1 template from the nilearn wheel (PyPI) -------------------------------
if ! ok "$MNI_GZ" "$MNI_GZ_SHA256" || ! [ -f "$dest/LICENSE.nilearn" ] \
   || ! [ -f "$dest/icbm152_2009.rst" ]; then
  if ! "$python" -m pip --version >/dev/null 2>&1; then
    echo "fetch-datasets: installing python3-pip (for pip download)"
    as_root apt-get update -qq
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq --no-install-recommends python3-pip
  fi
  echo "fetch-datasets: downloading nilearn $NILEARN_VERSION wheel from PyPI"
  "$python" -m pip download --quiet --no-deps --only-binary=:all: --ignore-requires-python \
    --disable-pip-version-check "nilearn==$NILEARN_VERSION" -d "$tmp/wheel"
  wheel="$(ls "$tmp"/wheel/nilearn-"$NILEARN_VERSION"-*.whl)"
  "$python" - "$wheel" "$tmp/mni" "$MNI_MEMBER" "$NILEARN_VERSION" <<'EOF'
import sys, zipfile, os
wheel, out, member, version = sys.argv[1:]
os.makedirs(out, exist_ok=True)
with zipfile.ZipFile(wheel) as z:
    names = {
        member: "data.nii.gz",
        f"nilearn-{version}.dist-info/licenses/LICENSE": "LICENSE.nilearn",
        "nilearn/datasets/description/icbm152_2009.rst": "icbm152_2009.rst",
    }
    for name, target in names.items():
        with z.open(name) as src, open(os.path.join(out, target), "wb") as dst:
            dst.write(src.read())
EOF
  verify "$tmp/mni/data.nii.gz" "$MNI_GZ_SHA256"
  mv "$tmp/mni/data.nii.gz" "$dest/$MNI_GZ"
  mv "$tmp/mni/LICENSE.nilearn" "$tmp/mni/icbm152_2009.rst" "$dest/"
fi

# Converted: the decompressed .nii (tests the uncompressed NIfTI path on real data).
if ! ok "$MNI_NII" "$MNI_NII_SHA256"; then
  "$python" -c 'import gzip, shutil, sys
with gzip.open(sys.argv[1], "rb") as s, open(sys.argv[2], "wb") as d: shutil.copyfileobj(s, d)' \
    "$dest/$MNI_GZ" "$tmp/mni.nii"
  verify "$tmp/mni.nii" "$MNI_NII_SHA256"
  mv "$tmp/mni.nii" "$dest/$MNI_NII"
fi

# --- VolPack brainsmall.den from Debian's libvolpack1-dev -------------------------------------
if ! ok "$DEN" "$DEN_SHA256" || ! [ -f "$dest/copyright.volpack" ]; then
  echo "fetch-datasets: downloading $VOLPACK_PACKAGE $VOLPACK_VERSION from Debian"
  mkdir -p "$tmp/deb"
  if ! (cd "$tmp/deb" && apt-get download -qq "$VOLPACK_PACKAGE=$VOLPACK_VERSION" 2>/dev/null); then
    # No package lists yet (fresh machine): refresh them once and retry.
    as_root apt-get update -qq
    (cd "$tmp/deb" && apt-get download -qq "$VOLPACK_PACKAGE=$VOLPACK_VERSION")
  fi
  deb="$(ls "$tmp"/deb/"$VOLPACK_PACKAGE"_*.deb)"
  dpkg-deb -x "$deb" "$tmp/deb/root"
  doc="$tmp/deb/root/usr/share/doc/$VOLPACK_PACKAGE"
  verify "$doc/examples/$DEN" "$DEN_SHA256"
  cp "$doc/copyright" "$dest/copyright.volpack"
  mv "$doc/examples/$DEN" "$dest/$DEN"
fi

# Converted: a detached NRRD header over the .den file (62-byte header skipped).
cat > "$dest/brainsmall.nhdr" <<'EOF'
NRRD0004
# VolPack brainsmall.den (128x128x84 u8 after a 62-byte header); written by fetch-datasets.sh
type: uchar
dimension: 3
sizes: 128 128 84
encoding: raw
spacings: 1 1 1
data file: brainsmall.den
byte skip: 62
EOF

for entry in "${checked[@]}"; do
  set -- $entry
  verify "$dest/$1" "$2"
done
echo "fetch-datasets: datasets ready in $dest"
