#!/usr/bin/env bash
# Every frame-time figure the project reports, measured in one call on a machine with a real GPU
# (the `device` tool of the development workplace; any Linux machine with an NVIDIA or AMD
# Vulkan driver works the same). Two steps:
#
#   scripts/gpu-bench.sh prepare      # here: a stripped release binary into .gpu/ and the Vulkan
#                                     # loader's .deb files into .gl/ (both git-ignored)
#   scripts/gpu-bench.sh run [OUT]    # there: unpacks the loader, then the benches below, each
#                                     # result as JSON / CSV in OUT (default: $OUT, else out/gpu)
#
# With the device tool: run(command="scripts/gpu-bench.sh run", carry=[".gpu", ".gl"],
# timeout_s=540). The benches (all side by side in one run, so their ratios hold):
#   1. `bench` of one view, 1920x1080, Marschner-Lobb 256^3 u8: the plain texture, the brick
#      cache all hi-res, half hi-res with smooth and with discontinuous transitions;
#   2. `bench` along a 60-view orbit, 1920x1080, 512^3 u8 under a 64 MiB GPU budget: two-level
#      camera-driven residency and levels from the camera (smooth and discontinuous each).
# The device name, driver and every command go into OUT/gpu-bench.log.
set -euo pipefail
cd "$(dirname "$0")/.."

prepare() {
    scripts/setup.sh
    cargo build --release --locked
    mkdir -p .gpu .gl
    grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >>.git/info/exclude
    grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo '/.gl/' >>.git/info/exclude
    strip -o .gpu/mixvol target/release/mixvol
    local lists=/tmp/amd64-lists
    mkdir -p "$lists/partial"
    local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
    apt-get "${o[@]}" update -qq
    (cd .gl && apt-get "${o[@]}" download libvulkan1)
    du -sh .gpu .gl
}

run() {
    local out=${1:-${OUT:-out/gpu}}
    mkdir -p "$out"
    local log="$out/gpu-bench.log"
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    if [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
        export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    fi
    local bin=.gpu/mixvol
    {
        date -u
        nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>/dev/null || true
    } | tee "$log"
    local size=(--width 1920 --height 1080)
    step() {
        echo "+ $*" | tee -a "$log"
        "$@" 2>&1 | tee -a "$log"
    }
    local view=(bench --volume ml --dims 256,256,256 "${size[@]}" --frames 30)
    step "$bin" "${view[@]}" --json "$out/view-plain.json"
    step "$bin" "${view[@]}" --levels all-hi --brick-size 32 --json "$out/view-all-hi.json"
    step "$bin" "${view[@]}" --levels half --brick-size 32 --transition smooth \
        --json "$out/view-half-smooth.json"
    step "$bin" "${view[@]}" --levels half --brick-size 32 --transition discontinuous \
        --json "$out/view-half-discontinuous.json"
    local path=(bench --volume ml --dims 512,512,512 "${size[@]}" --orbit 60 --elevation 20
        --gpu-budget-mb 64 --brick-size 32)
    step "$bin" "${path[@]}" --json "$out/orbit-two-level.json"
    step "$bin" "${path[@]}" --levels camera --json "$out/orbit-levels.json"
}

case "${1:-}" in
prepare) prepare ;;
run) run "${2:-}" ;;
*)
    echo "usage: $0 prepare | run [OUT]" >&2
    exit 2
    ;;
esac
