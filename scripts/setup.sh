#!/usr/bin/env bash
# Installs what building and running mixvol needs on Debian bookworm, idempotently: the Vulkan
# loader and headers, Mesa's lavapipe (a CPU Vulkan device), the Khronos validation layers, and
# cmake + ninja + python3 for building shaderc/glslang from source, python3-venv for the test
# servers' environment (scripts/python-env.sh). Packages already present are
# not touched; apt-get update runs only when something is missing.
set -euo pipefail

packages=(libvulkan1 libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers cmake ninja-build python3 python3-venv g++ pkg-config)
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ "${#missing[@]}" -gt 0 ]; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
      echo "setup: missing packages ${missing[*]} and not root (no sudo)" >&2; exit 1
    fi
  fi
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found; install a Rust toolchain (rustup) first" >&2
  exit 1
fi
