#!/usr/bin/env bash
# CPU time per frame of `mixvol render`, for comparing binaries on a loaded machine where wall
# times mean little: user + sys of a 5-frame run minus a 1-frame run, / 4 (start-up, shader
# compile and the warm-up frame cancel out). Binaries alternate configuration by configuration,
# round by round. Scene: Marschner-Lobb 128^3 f32, fire TF, Blinn-Phong shading, 2 samples per
# voxel; configurations: plain texture, brick cache all hi-res, half hi-res smooth and
# discontinuous (docs/performance.md, "Fewer gradient reads"). CONFIGS (space-separated) picks
# others: all-lo (every brick low-res), all-lo-coarse and smooth-coarse (LaMar's coarse sampling
# in low-res bricks, --coarse-low-res); SHADING=0 renders unshaded.
#
#   scripts/cpu-bench.sh ROUNDS SIZE BINARY...
#   scripts/cpu-bench.sh 2 256 /tmp/mixvol-before target/release/mixvol
#   CONFIGS="all-hi all-lo all-lo-coarse" SHADING=0 scripts/cpu-bench.sh 2 256 target/release/mixvol
set -euo pipefail
if [ $# -lt 3 ]; then
  echo "usage: $0 ROUNDS SIZE BINARY..." >&2
  exit 2
fi
rounds=$1
size=$2
shift 2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
declare -A flags=(
  [plain]=""
  [all-hi]="--levels all-hi"
  [smooth]="--levels half --transition smooth"
  [discontinuous]="--levels half --transition discontinuous"
  [all-lo]="--levels all-lo"
  [all-lo-coarse]="--levels all-lo --coarse-low-res"
  [smooth-coarse]="--levels half --transition smooth --coarse-low-res"
)
read -r -a configs <<<"${CONFIGS:-plain all-hi smooth discontinuous}"
for cfg in "${configs[@]}"; do
  if [ -z "${flags[$cfg]+set}" ]; then
    echo "$0: unknown configuration '$cfg' in CONFIGS (known: ${!flags[*]})" >&2
    exit 2
  fi
done
shading=--shading
if [ "${SHADING:-1}" = 0 ]; then
  shading=
fi
cpu_seconds() {
  /usr/bin/time -f "%U %S" -o "$work/time" "$@" >/dev/null 2>"$work/stderr" || {
    cat "$work/stderr" >&2
    exit 1
  }
  awk '{print $1 + $2}' "$work/time"
}
for r in $(seq "$rounds"); do
  for cfg in "${configs[@]}"; do
    for bin in "$@"; do
      # shellcheck disable=SC2086
      args=(render --volume ml --dims 128,128,128 --scalar f32 --tf fire --window 0,1
        --samples-per-voxel 2 --width "$size" --height "$size" $shading ${flags[$cfg]}
        -o "$work/out.png")
      one=$(cpu_seconds "$bin" "${args[@]}" --frames 1)
      five=$(cpu_seconds "$bin" "${args[@]}" --frames 5)
      awk -v r="$r" -v c="$cfg" -v b="$bin" -v a="$one" -v f="$five" -v l="$(cut -d' ' -f1 /proc/loadavg)" \
        'BEGIN { printf "round %s %-13s %-40s %6.0f ms/frame (load %s)\n", r, c, b, (f - a) / 4 * 1000, l }'
    done
  done
done
